//! The layers of the crate point one way: files, range < map < world < sim < vehicles, io, render < app < cli.
//! This test reads every file under `src/` and fails on any `crate::` path (in a `use` or
//! inline) from a module to one on its own level or above; its checker is itself tested on a
//! fake tree so that it can fail.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Level of each top-level module; a module may use only modules of a lower level. The three
/// peers on level 3 (vehicles, io, render) must not use each other either.
fn level(module: &str) -> Option<u32> {
    Some(match module {
        "files" | "range" => 0,
        "map" => 1,
        "world" => 2,
        "sim" => 3,
        "vehicles" | "io" | "render" => 4,
        "app" => 5,
        "cli" | "main" => 6,
        "lib" => 7,
        _ => return None,
    })
}

/// The top-level module a file under `src/` belongs to (`src/sim/v2v.rs` -> `sim`,
/// `src/main.rs` -> `main`).
fn module_of(relative: &Path) -> String {
    let first = relative.components().next().map(|c| c.as_os_str().to_string_lossy().into_owned()).unwrap_or_default();
    first.trim_end_matches(".rs").to_string()
}

/// Top-level modules named by `crate::` paths in `text`, with their line numbers; comment
/// lines (doc links are not imports) are skipped. `crate::{a::X, b::Y}` yields a and b.
fn crate_paths(text: &str) -> Vec<(usize, String)> {
    let mut out = Vec::new();
    let mut in_group: Option<(usize, u32)> = None;
    for (n, line) in text.lines().enumerate() {
        let code = line.trim_start();
        if code.starts_with("//") {
            continue;
        }
        let code = code.split("//").next().unwrap_or("");
        if let Some((start, depth)) = in_group.as_mut() {
            for word in group_heads(code, depth) {
                out.push((*start, word));
            }
            if *depth == 0 {
                in_group = None;
            }
            continue;
        }
        let mut rest = code;
        while let Some(i) = rest.find("crate::") {
            let after = &rest[i + "crate::".len()..];
            if let Some(group) = after.strip_prefix('{') {
                let mut depth = 1;
                for word in group_heads(group, &mut depth) {
                    out.push((n + 1, word));
                }
                if depth > 0 {
                    in_group = Some((n + 1, depth));
                }
                break;
            }
            let name: String = after.chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect();
            if !name.is_empty() {
                out.push((n + 1, name));
            }
            rest = after;
        }
    }
    out
}

/// The first path segments at brace depth 1 of a `crate::{...}` group (`depth` carries over
/// lines; it reaches 0 at the closing brace).
fn group_heads(text: &str, depth: &mut u32) -> Vec<String> {
    let mut heads = Vec::new();
    let mut at_head = *depth == 1;
    let mut word = String::new();
    for c in text.chars() {
        if *depth == 0 {
            break;
        }
        match c {
            '{' => {
                *depth += 1;
                at_head = false;
            }
            '}' => *depth -= 1,
            ',' if *depth == 1 => at_head = true,
            c if c.is_alphanumeric() || c == '_' => {
                if at_head {
                    word.push(c);
                }
            }
            _ => {
                if !word.is_empty() {
                    heads.push(std::mem::take(&mut word));
                }
                if c != ' ' && c != '\n' {
                    at_head = false;
                }
            }
        }
    }
    if !word.is_empty() {
        heads.push(word);
    }
    heads
}

/// Every import from a module to one on its own level or above, as "file:line: a -> b".
fn upward_imports(files: &BTreeMap<PathBuf, String>) -> Vec<String> {
    let mut bad = Vec::new();
    for (path, text) in files {
        let from = module_of(path);
        let Some(from_level) = level(&from) else { continue };
        for (line, to) in crate_paths(text) {
            if to == from || to == "prelude" {
                continue;
            }
            match level(&to) {
                Some(to_level) if to_level < from_level => {}
                Some(_) => bad.push(format!("src/{}:{line}: {from} -> {to}", path.display())),
                None => {}
            }
        }
    }
    bad
}

fn read_tree(root: &Path) -> BTreeMap<PathBuf, String> {
    let mut files = BTreeMap::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).expect("src/ is readable") {
            let path = entry.expect("entry").path();
            if path.is_dir() {
                stack.push(path);
            } else if path.extension().is_some_and(|e| e == "rs") {
                let text = std::fs::read_to_string(&path).expect("a readable source file");
                files.insert(path.strip_prefix(root).expect("under root").to_path_buf(), text);
            }
        }
    }
    files
}

#[test]
fn no_module_imports_its_own_level_or_above() {
    let files = read_tree(&Path::new(env!("CARGO_MANIFEST_DIR")).join("src"));
    assert!(files.len() > 40, "read the whole tree ({} files)", files.len());
    let bad = upward_imports(&files);
    assert!(
        bad.is_empty(),
        "imports that run against the layers (files < map < world < sim < vehicles, io, render < app < cli):\n{}",
        bad.join("\n")
    );
}

#[test]
fn the_checker_finds_upward_and_sideways_imports_in_a_fake_tree() {
    let fake: BTreeMap<PathBuf, String> = [
        ("map/routing.rs", "use crate::map::lanelet::LaneletMap;\nuse crate::world::VehicleId;\n"),
        ("sim/dynamics.rs", "use crate::world::VehicleState;\n// see crate::app::Sim\n/// [`crate::app::Plugin`]\n"),
        ("sim/v2v.rs", "fn f() { let s = crate::app::Scenario::load(p); }\n"),
        (
            "io/lab.rs",
            "use crate::{\n    map::Path,\n    vehicles::Longitudinal,\n    world::{VehicleId, VehicleState},\n};\n",
        ),
        ("vehicles/acc.rs", "use crate::{sim::{Plugin, SimBuilder}, world::VehicleState};\n"),
        ("app/mod.rs", "use crate::io::lab::VizStreamPlugin;\npub use crate::sim::{Plugin, Sim};\n"),
        ("render/view.rs", "use crate::map::LaneletMap; use crate::render::gpu::Gpu;\n"),
    ]
    .into_iter()
    .map(|(p, t)| (PathBuf::from(p), t.to_string()))
    .collect();
    let bad = upward_imports(&fake);
    assert_eq!(
        bad,
        vec![
            "src/io/lab.rs:1: io -> vehicles".to_string(),
            "src/map/routing.rs:2: map -> world".to_string(),
            "src/sim/v2v.rs:1: sim -> app".to_string(),
        ],
        "comments and doc links are not imports; a grouped use is read by its heads"
    );
}

//! Every `smlworld` command in the shell blocks of README.md, CONTRIBUTING.md and docs/*.md runs
//! (issue 60 §2 and §4: an example in the docs cannot rot). Each page's commands run in order in
//! a scratch project of their own (the shipped `scenarios/`, `maps/`, `tests/` and `assets/`
//! beside a `../shared`), so commands that read what an earlier one wrote (`replay out/...`,
//! `plot out/...`) find it and nothing is written into the checkout.
//!
//! What is changed, and why: `cargo run --release --` is the `smlworld` binary; `/tmp/` is the
//! scratch folder's `tmp/`; `$N` is sumo-rl's nets folder (as the docs' `N=$(...)` line computes
//! it); optional parts written `[--flag value]` are left out. A run is capped at 5 s of sim time
//! (`--duration`), a bench at 1 s, a viewer at 1 s (under Xvfb): the test checks that each command
//! works as written, not how long a demo lasts. Other programs in the blocks (`cargo`, `bash
//! scripts/...`, `pip`, `python`, `ros2`) are not run here: the suite itself, pytest and the
//! example tests run those.

mod scratch_support;
mod xvfb_support;

use std::path::{Path, PathBuf};
use std::process::Command;

use scratch_support::Scratch;

const ROOT: &str = env!("CARGO_MANIFEST_DIR");
/// Longest sim time a documented run gets here \[s\].
const RUN_CAP: f64 = 5.0;

/// One documented command: its page and line, and its words.
#[derive(Debug, Clone, PartialEq)]
struct DocCommand {
    line: usize,
    words: Vec<String>,
}

/// Words of a shell line, with '...' and "..." quoting (no escapes inside), a comment cut off at
/// an unquoted `#` that starts a word.
fn shell_words(line: &str) -> Vec<String> {
    let (mut words, mut word, mut quote, mut in_word) = (Vec::new(), String::new(), None, false);
    for c in line.chars() {
        match (quote, c) {
            (Some(q), c) if c == q => quote = None,
            (Some(_), c) => word.push(c),
            (None, '\'' | '"') => {
                quote = Some(c);
                in_word = true;
            }
            (None, '#') if !in_word => break,
            (None, c) if c.is_whitespace() => {
                if in_word {
                    words.push(std::mem::take(&mut word));
                    in_word = false;
                }
            }
            (None, c) => {
                word.push(c);
                in_word = true;
            }
        }
    }
    if in_word {
        words.push(word);
    }
    words
}

/// The `smlworld` commands of the `sh`/`bash` blocks of `text` (continuation lines joined,
/// `cargo run --release --` read as `smlworld`, `[optional parts]` left out).
fn commands(text: &str) -> Vec<DocCommand> {
    let mut out = Vec::new();
    let mut in_block = false;
    let mut pending: Option<(usize, String)> = None;
    for (i, line) in text.lines().enumerate() {
        if !in_block {
            in_block = line == "```sh" || line == "```bash";
            continue;
        }
        if line.starts_with("```") {
            in_block = false;
            continue;
        }
        let (start, joined) = match pending.take() {
            Some((start, head)) => (start, format!("{head} {}", line.trim())),
            None => (i + 1, line.trim().to_string()),
        };
        if let Some(head) = joined.strip_suffix('\\') {
            pending = Some((start, head.to_string()));
            continue;
        }
        let mut words = shell_words(&joined);
        if words.starts_with(&["cargo".into(), "run".into(), "--release".into(), "--".into()]) {
            words.splice(0..4, ["smlworld".to_string()]);
        }
        if words.first().is_none_or(|w| w != "smlworld") {
            continue;
        }
        let mut kept = Vec::new();
        let mut optional = false;
        for w in words {
            if w.starts_with('[') {
                optional = true;
            }
            if !optional {
                kept.push(w.clone());
            }
            if w.ends_with(']') {
                optional = false;
            }
        }
        out.push(DocCommand { line: start, words: kept });
    }
    out
}

#[test]
fn commands_are_read_as_a_reader_would_type_them() {
    let text = "x\n```sh\nsmlworld run a.toml --set 'v.*.x=1'   # comment\n\
                cargo run --release -- map info m.osm [--json]\nN=$(python -c 'x')\n\
                smlworld map route m \\\n    --from 1 [--lane-change-penalty 50] --json\n```\n\
                smlworld not in a block\n```toml\nsmlworld = 1\n```\n";
    let got = commands(text);
    let words = |c: &DocCommand| c.words.join(" ");
    assert_eq!(got.len(), 3, "{got:?}");
    assert_eq!(words(&got[0]), "smlworld run a.toml --set v.*.x=1");
    assert_eq!(words(&got[1]), "smlworld map info m.osm");
    assert_eq!((got[2].line, words(&got[2]).as_str()), (6, "smlworld map route m --from 1 --json"));
}

/// sumo-rl's nets folder, as the docs' `N=$(.venv/bin/python -c ...)` line computes it
/// (`$SUMO_RL_NETS` first, as tests/sumo.rs).
fn sumo_nets() -> String {
    if let Some(dir) = std::env::var_os("SUMO_RL_NETS") {
        return dir.to_string_lossy().into_owned();
    }
    let out = Command::new(Path::new(ROOT).join(".venv/bin/python"))
        .args([
            "-c",
            "import importlib.util;print(importlib.util.find_spec('sumo_rl').submodule_search_locations[0]+'/nets')",
        ])
        .output()
        .expect("the docs' SUMO commands need .venv with sumo-rl: run `bash scripts/test.sh` once or set SUMO_RL_NETS");
    assert!(out.status.success(), "sumo-rl is not in .venv: {}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8_lossy(&out.stdout).trim().to_string()
}

/// A scratch project: `proj/` with the shipped folders (maps copied, so a documented `map
/// generate --out maps/...` cannot touch the checkout's), `shared` beside it, `proj/tmp/`.
fn scratch_project(name: &str) -> (Scratch, PathBuf) {
    let dir = Scratch::new("smlworld-docs-commands", name);
    let proj = dir.join("proj");
    std::fs::create_dir_all(proj.join("tmp")).unwrap();
    std::fs::create_dir_all(proj.join("maps")).unwrap();
    for entry in std::fs::read_dir(Path::new(ROOT).join("maps")).unwrap() {
        let entry = entry.unwrap();
        std::fs::copy(entry.path(), proj.join("maps").join(entry.file_name())).unwrap();
    }
    for shipped in ["scenarios", "tests", "assets", "python", "examples"] {
        std::os::unix::fs::symlink(Path::new(ROOT).join(shipped), proj.join(shipped)).unwrap();
    }
    let shared = Path::new(ROOT).join("../shared");
    std::os::unix::fs::symlink(shared.canonicalize().expect("../shared beside the checkout"), dir.join("shared"))
        .unwrap();
    (dir, proj)
}

/// `words` as this test runs them (see the module documentation).
fn adapted(words: &[String], proj: &Path, nets: &dyn Fn() -> String) -> Vec<String> {
    let tmp = format!("{}/", proj.join("tmp").display());
    let mut args: Vec<String> = words[1..]
        .iter()
        .map(|w| {
            let w = w.replace("/tmp/", &tmp);
            if w.contains("$N") { w.replace("$N", &nets()) } else { w }
        })
        .collect();
    let cap = match args.first().map(String::as_str) {
        Some("run") => Some(RUN_CAP),
        Some("bench") | Some("view") => Some(1.0),
        _ => None,
    };
    if let Some(cap) = cap {
        match args.iter().position(|a| a == "--duration") {
            Some(i) if i + 1 < args.len() => {
                let given: f64 = args[i + 1].parse().unwrap_or(cap);
                args[i + 1] = given.min(cap).to_string();
            }
            _ => args.extend(["--duration".to_string(), cap.to_string()]),
        }
    }
    args
}

/// Run every `smlworld` command of `page` (relative to the checkout) in order; returns how many.
fn run_page(page: &str) -> usize {
    let text = std::fs::read_to_string(Path::new(ROOT).join(page)).unwrap();
    let cmds = commands(&text);
    let name = page.replace(['/', '.'], "_");
    let (dir, proj) = scratch_project(&name);
    let mut display: Option<(xvfb_support::Xvfb, String)> = None;
    let mut failed = Vec::new();
    for c in &cmds {
        let args = adapted(&c.words, &proj, &sumo_nets);
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_smlworld"));
        cmd.args(&args).current_dir(&proj).env("NO_COLOR", "1");
        if args.first().is_some_and(|a| a == "view") {
            let (_, name) = display.get_or_insert_with(|| xvfb_support::start_xvfb(&dir));
            cmd.env("DISPLAY", name.clone());
        }
        let out = cmd.output().expect("runs smlworld");
        if !out.status.success() {
            let stderr = String::from_utf8_lossy(&out.stderr);
            let tail: String =
                stderr.lines().rev().take(6).collect::<Vec<_>>().into_iter().rev().collect::<Vec<_>>().join("\n");
            failed.push(format!(
                "{page}:{}: {}\n  ran: smlworld {}\n{tail}",
                c.line,
                c.words.join(" "),
                args.join(" ")
            ));
        }
    }
    assert!(failed.is_empty(), "documented commands that fail:\n{}", failed.join("\n\n"));
    cmds.len()
}

#[test]
fn readme_commands_run() {
    assert!(run_page("README.md") >= 20);
}

#[test]
fn contributing_commands_run() {
    assert!(run_page("CONTRIBUTING.md") >= 1);
}

/// Every page of docs/ with shell blocks, run page by page.
#[test]
fn docs_commands_run() {
    let mut pages: Vec<PathBuf> = std::fs::read_dir(Path::new(ROOT).join("docs"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "md"))
        .collect();
    pages.sort();
    let mut total = 0;
    for page in pages {
        let rel = page.strip_prefix(ROOT).unwrap().to_str().unwrap().to_string();
        total += run_page(&rel);
    }
    assert!(total >= 40, "{total} commands in docs/");
}

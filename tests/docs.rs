//! The documentation a newcomer reads (issue 60): a README that guides in at most 400 lines and
//! links into docs/, links that resolve, and a scenario reference that names every key the
//! parser accepts.

use std::path::{Path, PathBuf};
use std::process::Command;

const ROOT: &str = env!("CARGO_MANIFEST_DIR");

/// README.md, CONTRIBUTING.md and every page of docs/.
fn pages() -> Vec<PathBuf> {
    let mut pages = vec![Path::new(ROOT).join("README.md"), Path::new(ROOT).join("CONTRIBUTING.md")];
    let mut docs: Vec<PathBuf> = std::fs::read_dir(Path::new(ROOT).join("docs"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "md"))
        .collect();
    docs.sort();
    pages.extend(docs);
    pages
}

/// The targets of the Markdown links and images of `text`: `[label](target)`, `![alt](target)`.
fn link_targets(text: &str) -> Vec<String> {
    let mut targets = Vec::new();
    let mut rest = text;
    while let Some(i) = rest.find("](") {
        let after = &rest[i + 2..];
        let end = after.find(')').unwrap_or(after.len());
        let target = &after[..end];
        if !target.is_empty() && !target.contains(char::is_whitespace) {
            targets.push(target.to_string());
        }
        rest = &after[end.min(after.len())..];
    }
    targets
}

#[test]
fn link_targets_are_found_in_markdown() {
    let found = link_targets("see [a](docs/a.md) and ![b](../assets/b.png), [web](https://x.y/z) and [x] (not)");
    assert_eq!(found, ["docs/a.md", "../assets/b.png", "https://x.y/z"]);
}

/// Every relative link of README.md, CONTRIBUTING.md and docs/*.md names a file or folder that
/// exists (anchors and web addresses aside).
#[test]
fn every_relative_link_resolves() {
    let mut broken = Vec::new();
    for page in pages() {
        let text = std::fs::read_to_string(&page).unwrap();
        for target in link_targets(&text) {
            if target.contains("://") || target.starts_with('#') || target.starts_with("mailto:") {
                continue;
            }
            let path = target.split('#').next().unwrap();
            if !page.parent().unwrap().join(path).exists() {
                broken.push(format!("{}: {target}", page.strip_prefix(ROOT).unwrap().display()));
            }
        }
    }
    assert!(broken.is_empty(), "links to nothing:\n{}", broken.join("\n"));
}

/// The README is a guide: at most 400 lines, and it links to every page of docs/ and to
/// CONTRIBUTING.md, so nothing documented is out of a reader's reach.
#[test]
fn the_readme_is_short_and_links_every_docs_page() {
    let readme = std::fs::read_to_string(Path::new(ROOT).join("README.md")).unwrap();
    let lines = readme.lines().count();
    assert!(lines <= 400, "README.md has {lines} lines; details belong in docs/");
    let targets = link_targets(&readme);
    for page in pages().iter().skip(1) {
        let rel = page.strip_prefix(ROOT).unwrap().to_str().unwrap().to_string();
        assert!(targets.contains(&rel), "README.md does not link {rel}");
    }
}

/// The keys the scenario parser accepts in the table at `path` of `scenario` (`""`: the top
/// level), read from its error for an unknown key, which lists them.
fn accepted_keys(scenario: &str, path: &str) -> Vec<String> {
    let set = if path.is_empty() { "no_such_key=1".to_string() } else { format!("{path}.no_such_key=1") };
    keys_refused_with(scenario, &set)
}

/// The keys the parser lists when `--set SET` (which must add the key `no_such_key`) is refused.
fn keys_refused_with(scenario: &str, set: &str) -> Vec<String> {
    let out = Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["run", &format!("{ROOT}/scenarios/{scenario}"), "--duration", "0.1", "--out"])
        .arg(std::env::temp_dir().join("smlworld-docs-keys-never-written"))
        .args(["--set", set])
        .output()
        .expect("runs smlworld");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "--set {set} was accepted");
    // serde lists them: "expected one of `a`, `b`", or "expected `a`" when there is one.
    let after = stderr.split("unknown field `no_such_key`, expected ").nth(1);
    let list = after.unwrap_or_else(|| panic!("--set {set}: no key list in {stderr}"));
    // The list ends at the line's end or at a `;` that starts a hint.
    let list = list.lines().next().unwrap_or("").split(';').next().unwrap_or("");
    backticked(list)
}

/// The words between pairs of backticks: "one of `a`, `b`" and "`a` or `b`" both give [a, b].
fn backticked(list: &str) -> Vec<String> {
    list.split('`').skip(1).step_by(2).map(str::to_string).filter(|k| !k.is_empty()).collect()
}

#[test]
fn key_lists_are_read_in_each_of_serdes_wordings() {
    assert_eq!(backticked("one of `kp`, `ki`, `dip`"), ["kp", "ki", "dip"]);
    assert_eq!(backticked("`ttc` or `deceleration`"), ["ttc", "deceleration"]);
    assert_eq!(backticked("`mcap`"), ["mcap"]);
}

/// docs/scenarios.md names every key the parser accepts at the top level, in `[rates]`,
/// `[[vehicles]]`, `lane_change`, `[[traffic]]`, `[[rsu]]`, `[junctions]` and `[emergency]`: a
/// key added to the parser without a line in the reference fails here.
#[test]
fn the_scenario_reference_names_every_key_the_parser_accepts() {
    let reference = std::fs::read_to_string(Path::new(ROOT).join("docs/scenarios.md")).unwrap();
    let tables = [
        ("highway.toml", "", ""),
        ("highway.toml", "rates", ""),
        ("highway.toml", "vehicles.0", ""),
        ("overtaking.toml", "vehicles.0.lane_change", ""),
        ("highway_traffic.toml", "traffic.0", ""),
        ("gcdc_merge.toml", "rsu.0", "rsu."),
        ("highway.toml", "junctions", "junctions."),
        ("highway.toml", "emergency", "emergency."),
    ];
    let mut missing = Vec::new();
    for (scenario, path, prefix) in tables {
        let keys = accepted_keys(scenario, path);
        assert!(!keys.is_empty(), "{scenario} {path}: {keys:?}");
        for k in keys {
            let named = format!("`{prefix}{k}`");
            // A row may name several keys in one cell: `length`, `width`.
            if !reference.contains(&named) {
                missing.push(format!("{path}: {named}"));
            }
        }
    }
    assert!(missing.is_empty(), "docs/scenarios.md lacks:\n{}", missing.join("\n"));
}

/// The `keys` that the row of `reference` labelled `` `label` `` does not name, each as
/// "label: `key`"; a reference without that row fails.
fn row_lacks(reference: &str, label: &str, keys: &[String]) -> Vec<String> {
    let row = reference
        .lines()
        .find(|l| l.starts_with(&format!("| `{label}` |")))
        .unwrap_or_else(|| panic!("docs/scenarios.md has no row for `{label}`"));
    keys.iter().filter(|k| !row.contains(&format!("`{k}`"))).map(|k| format!("{label}: `{k}`")).collect()
}

/// The controllers table of docs/scenarios.md names, in each type's row, every key the parser
/// accepts for that type (read from its error for an unknown key, as above).
#[test]
fn the_scenario_reference_names_every_controller_key() {
    let reference = std::fs::read_to_string(Path::new(ROOT).join("docs/scenarios.md")).unwrap();
    let mut missing = Vec::new();
    for kind in ["cruise_control", "acc", "platoon", "idm", "gcdc"] {
        let set = format!("vehicles.0.controller={{ type = \"{kind}\", no_such_key = 1 }}");
        let keys = keys_refused_with("highway.toml", &set);
        assert!(keys.len() >= 3, "{kind}: {keys:?}");
        missing.extend(row_lacks(&reference, kind, &keys));
    }
    assert!(missing.is_empty(), "docs/scenarios.md's controllers table lacks:\n{}", missing.join("\n"));
}

/// The "Tables inside tables" reference of docs/scenarios.md names, in each table's row, every
/// key the parser accepts there (the controllers' own tables, models, routes, sensors, channels
/// and their loss models, light programs and the lab), read from the parser's error as above.
#[test]
fn the_scenario_reference_names_every_key_of_the_tables_inside_tables() {
    let page = std::fs::read_to_string(Path::new(ROOT).join("docs/scenarios.md")).unwrap();
    let reference =
        page.split("## Tables inside tables").nth(1).expect("docs/scenarios.md has a \"Tables inside tables\" section");
    let ctl = |kind: &str, inner: &str| format!("vehicles.0.controller={{ type = \"{kind}\", {inner} }}");
    let probes = [
        ("controller.cruise", ctl("cruise_control", "cruise = { no_such_key = 1 }")),
        ("controller.cruise.dip", ctl("cruise_control", "cruise = { dip = { no_such_key = 1 } }")),
        ("controller.acc", ctl("acc", "acc = { no_such_key = 1 }")),
        ("controller.platoon", ctl("platoon", "role = \"leader\", platoon = { no_such_key = 1 }")),
        ("controller.fallback", ctl("platoon", "role = \"leader\", fallback = { no_such_key = 1 }")),
        ("controller.emergency", ctl("acc", "emergency = { no_such_key = 1 }")),
        ("controller.crossing", ctl("acc", "crossing = { no_such_key = 1 }")),
        ("controller.intersection", ctl("acc", "intersection = { no_such_key = 1 }")),
        ("controller.merge", ctl("gcdc", "merge = { no_such_key = 1 }")),
        ("controller.merge.gap_rule", ctl("gcdc", "merge = { gap_rule = { no_such_key = 1 } }")),
        ("model", "vehicles.0.model={ type = \"acceleration\", no_such_key = 1 }".into()),
        ("route", "vehicles.0.route={ loop = \"x\", no_such_key = 1 }".into()),
        ("start", "vehicles.0.start={ offset = 1.0, no_such_key = 1 }".into()),
        ("sensors.radar", "vehicles.0.sensors.radar.no_such_key=1".into()),
        ("sensors.velodyne", "vehicles.0.sensors.velodyne.no_such_key=1".into()),
        ("sensors.*.noise", "vehicles.0.sensors.radar.noise.no_such_key=1".into()),
        ("v2v", "v2v.no_such_key=1".into()),
        ("v2v.wifi`, `v2v.network", "v2v.wifi.no_such_key=1".into()),
        ("v2v.wifi`, `v2v.network", "v2v.network.no_such_key=1".into()),
        ("loss.model = \"constant\"", "v2v.wifi.loss={ model = \"constant\", no_such_key = 1 }".into()),
        ("loss.model = \"distance\"", "v2v.wifi.loss={ model = \"distance\", no_such_key = 1 }".into()),
        ("loss.model = \"gilbert_elliott\"", "v2v.wifi.loss={ model = \"gilbert_elliott\", no_such_key = 1 }".into()),
        ("loss.model = \"gilbert_elliott\"", "v2v.wifi.burst.no_such_key=1".into()),
        (
            "traffic_lights.program",
            "traffic_lights=[{ junction = 0, program = [{ state = \"G\", duration = 1.0, no_such_key = 1 }] }]".into(),
        ),
        ("lab", "lab.no_such_key=1".into()),
        ("lab.mocap", "lab.mocap.no_such_key=1".into()),
        ("lab.trucks", "lab.trucks.no_such_key=1".into()),
    ];
    let mut missing = Vec::new();
    for (table, set) in probes {
        let keys = keys_refused_with("highway.toml", &set);
        assert!(!keys.is_empty(), "{table}: no keys listed");
        missing.extend(row_lacks(reference, table, &keys));
    }
    assert!(missing.is_empty(), "docs/scenarios.md's tables inside tables lack:\n{}", missing.join("\n"));
}

/// The README's performance table is derived from docs/performance.md's generated one, never
/// typed: `scripts/perf_table.py --readme --check` fails when the two disagree.
#[test]
fn the_readme_performance_table_is_the_generated_ones_medians() {
    let out = Command::new("python3")
        .arg(Path::new(ROOT).join("scripts/perf_table.py"))
        .args(["--readme", "--check"])
        .output()
        .expect("runs python3");
    assert!(out.status.success(), "{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
}

/// The items `src/app/mod.rs` re-exports (`app::Session`, `app::run_scenario`, ...), read from its
/// `pub use` lines.
fn app_facade_items() -> Vec<String> {
    let text = std::fs::read_to_string(Path::new(ROOT).join("src/app/mod.rs")).unwrap();
    let mut items = Vec::new();
    for stmt in text.split(';').filter_map(|s| s.trim().strip_prefix("pub use ")) {
        let names = stmt.rsplit("::").next().unwrap_or("").trim_matches(|c| c == '{' || c == '}');
        items.extend(names.split(',').map(|n| n.trim().to_string()).filter(|n| !n.is_empty()));
    }
    items
}

/// Files a user or a contributor reads: everything outside `src/app/` (whose own modules use
/// each other's paths) that can name an app item.
fn sources_outside_app(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_string_lossy().to_string();
        if path.is_dir() {
            if !(name.starts_with('.') || name == "target" || name == "node_modules" || path.ends_with("src/app")) {
                sources_outside_app(&path, out);
            }
        } else if name.ends_with(".rs") || name.ends_with(".md") {
            out.push(path);
        }
    }
}

/// One path each (issue 60 §5): an item `app` re-exports is named by that one path
/// (`smlworld::app::Session`) outside `src/app/`, never by its module path under `running` or
/// `results` beside it.
#[test]
fn app_items_are_named_by_their_one_public_path() {
    let items = app_facade_items();
    assert!(items.iter().any(|i| i == "Session") && items.len() >= 20, "{items:?}");
    let mut files = Vec::new();
    for dir in ["src", "tests", "examples", "benches", "python/src", "docs"] {
        sources_outside_app(&Path::new(ROOT).join(dir), &mut files);
    }
    files.extend(["README.md", "CONTRIBUTING.md"].map(|f| Path::new(ROOT).join(f)));
    let mut long = Vec::new();
    for file in files {
        let text = std::fs::read_to_string(&file).unwrap();
        for (n, line) in text.lines().enumerate() {
            for module in ["app::running::", "app::results::"] {
                for (i, _) in line.match_indices(module) {
                    // The path's last segment(s): `session::Session` or `session::{A, B}`.
                    let path: String =
                        line[i..].chars().take_while(|c| c.is_alphanumeric() || "_:{}, ".contains(*c)).collect();
                    let tail = path.rsplit("::").next().unwrap_or("");
                    for name in tail.trim_matches(|c| c == '{' || c == '}' || c == ' ').split(',') {
                        let name = name.trim().trim_end_matches(['}', ' ']);
                        if items.iter().any(|i| i == name) {
                            let rel = file.strip_prefix(ROOT).unwrap().display();
                            long.push(format!("{rel}:{}: `{name}` (use `app::{name}`)", n + 1));
                        }
                    }
                }
            }
        }
    }
    assert!(long.is_empty(), "app items named by a second path:\n{}", long.join("\n"));
}

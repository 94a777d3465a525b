//! The student examples (`examples/student_sensor.rs`, `examples/student_channel.rs`) are
//! plugins of their own: adding one touches no file of the simulator (issue 58 §3).
//!
//! `cargo test` and `cargo nextest` build every file of `examples/` as a crate of its own that
//! sees only the `smlworld` library's public API (and `tests/student_sensor.rs`,
//! `tests/student_channel.rs` compile them into tests the same way), so an example that needed
//! a change of the simulator's private code would not build. What a build cannot see is the
//! other direction: the simulator naming the example (a registry entry, a match arm, a `use`).
//! This test reads each example, takes the names it defines, and fails when a file of the
//! simulator (`src/`, `python/src/`) names one, but for the benchmark, which compiles the camera
//! in on purpose (`bench --plugin-sensor-share`).

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

/// Files allowed to name an example's items: the benchmark compiles the student camera in.
const MAY_NAME_THE_EXAMPLES: &[&str] = &["src/app/running/bench.rs"];

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The types, traits and functions a Rust file defines at its top level (`pub struct Camera`,
/// `pub fn sense_cameras`, ...), but `main`.
fn defined_names(text: &str) -> BTreeSet<String> {
    let mut names = BTreeSet::new();
    for line in text.lines() {
        let line = line.trim_start_matches("pub ").trim_start_matches("pub(crate) ");
        for keyword in ["struct ", "enum ", "trait ", "fn ", "type ", "const ", "static "] {
            if let Some(rest) = line.strip_prefix(keyword) {
                let name: String = rest.chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect();
                if !name.is_empty() && name != "main" {
                    names.insert(name);
                }
            }
        }
    }
    names
}

/// The names a scenario uses to pick an example's plugin: the string given to
/// `register_sensor`, `register_channel_model` or `register_controller`.
fn registered_names(text: &str) -> BTreeSet<String> {
    let mut names = BTreeSet::new();
    for (at, _) in text.match_indices("register_") {
        let rest = &text[at..];
        if let Some(open) = rest.find("(\"") {
            let name: String = rest[open + 2..].chars().take_while(|c| *c != '"').collect();
            if !name.is_empty() && !rest[..open].contains('\n') {
                names.insert(name);
            }
        }
    }
    names
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    for entry in entries.flatten() {
        let path = entry.path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// Whether `text` holds `name` as a whole word (identifier characters on neither side).
fn names_word(text: &str, name: &str) -> bool {
    let word = |c: char| c.is_alphanumeric() || c == '_';
    text.match_indices(name).any(|(at, _)| {
        let before = text[..at].chars().next_back().is_none_or(|c| !word(c));
        let after = text[at + name.len()..].chars().next().is_none_or(|c| !word(c));
        before && after
    })
}

/// The simulator's files (relative paths) that name any of `names` they do not define
/// themselves as a word, or any of `quoted` as a quoted string, apart from
/// [`MAY_NAME_THE_EXAMPLES`].
fn simulator_files_naming(names: &BTreeSet<String>, quoted: &BTreeSet<String>) -> Vec<String> {
    let mut files = Vec::new();
    rust_files(&root().join("src"), &mut files);
    rust_files(&root().join("python/src"), &mut files);
    // A name the simulator defines itself (its own `Camera` of the renderer, a serde default
    // `yes`) is its own, not the example's.
    let texts: Vec<(PathBuf, String)> =
        files.into_iter().map(|f| (f.clone(), std::fs::read_to_string(&f).unwrap_or_default())).collect();
    let own: BTreeSet<String> = texts.iter().flat_map(|(_, t)| defined_names(t)).collect();
    let mut hits = Vec::new();
    for (file, text) in &texts {
        let relative = file.strip_prefix(root()).unwrap_or(file).to_string_lossy().replace('\\', "/");
        if MAY_NAME_THE_EXAMPLES.contains(&relative.as_str()) {
            continue;
        }
        for name in names.difference(&own) {
            if names_word(text, name) {
                hits.push(format!("{relative} names `{name}`"));
            }
        }
        for name in quoted {
            if text.contains(&format!("\"{name}\"")) {
                hits.push(format!("{relative} names \"{name}\""));
            }
        }
    }
    hits
}

fn check_example(example: &str, expected_registered: &str) {
    let text = std::fs::read_to_string(root().join("examples").join(example)).expect("the example");
    let names = defined_names(&text);
    let registered = registered_names(&text);
    assert!(registered.contains(expected_registered), "{example} registers {registered:?}");
    assert!(names.len() >= 2, "{example} defines {names:?}");
    // The example reaches the simulator only through the library's public API.
    for line in text.lines().filter(|l| l.starts_with("use ") || l.contains("#[path") || l.contains("include!")) {
        assert!(
            line.starts_with("use smlworld::") || line.starts_with("use std::"),
            "{example} reaches outside the smlworld crate: {line}"
        );
    }
    let hits = simulator_files_naming(&names, &registered);
    assert!(hits.is_empty(), "adding {example} should touch no file of the simulator, but {hits:#?}");
}

#[test]
fn the_student_sensor_is_named_by_no_file_of_the_simulator() {
    check_example("student_sensor.rs", "camera");
}

#[test]
fn the_student_channel_model_is_named_by_no_file_of_the_simulator() {
    check_example("student_channel.rs", "log_distance");
}

#[test]
fn a_simulator_file_naming_an_example_is_found() {
    // The check itself: a registered name the simulator does use is found, as is a word it uses
    // but defines nowhere (a type of bevy's), and a name it defines is its own.
    let radar: BTreeSet<String> = ["radar".to_string()].into();
    assert!(!simulator_files_naming(&BTreeSet::new(), &radar).is_empty());
    let borrowed: BTreeSet<String> = ["ResMut".to_string()].into();
    assert!(!simulator_files_naming(&borrowed, &BTreeSet::new()).is_empty());
    let own: BTreeSet<String> = ["SensorReadings".to_string()].into();
    assert!(simulator_files_naming(&own, &BTreeSet::new()).is_empty());
    let bench = std::fs::read_to_string(root().join(MAY_NAME_THE_EXAMPLES[0])).expect("the benchmark");
    assert!(names_word(&bench, "CameraPlugin") && !names_word(&bench, "CameraPlug"));
    let sensor = std::fs::read_to_string(root().join("examples/student_sensor.rs")).expect("the example");
    assert!(defined_names(&sensor).contains("CameraPlugin"));
}

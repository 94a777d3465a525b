//! Helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::PathBuf;

/// `../shared/data` beside the project (as CI lays it out), else `/work/shared/data`.
/// Panics with a clear message when neither exists: a test that needs the real maps must fail,
/// not pass silently.
pub fn shared_data() -> PathBuf {
    let beside = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/data"));
    if beside.is_dir() {
        return beside;
    }
    let fallback = PathBuf::from("/work/shared/data");
    if fallback.is_dir() {
        return fallback;
    }
    panic!(
        "the real test maps are missing: expected ../shared/data beside the project ({}); \
         clone the project next to the `shared` folder",
        beside.display()
    );
}

/// A file of the shared data, e.g. `sml2015/HighwaySML.xml`.
pub fn shared(rel: &str) -> PathBuf {
    let p = shared_data().join(rel);
    assert!(p.is_file(), "missing test map {}", p.display());
    p
}

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

/// xorshift64*: a small deterministic generator for garbage input in the fuzz-style tests.
pub struct Rng(pub u64);

impl Rng {
    /// The next 64 random bits.
    pub fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }

    /// A number in `0..n`.
    pub fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }
}

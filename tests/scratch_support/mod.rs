//! A test's scratch folder under the system's temporary folder, removed when the test passes.

use std::path::{Path, PathBuf};

/// A folder made afresh for one test (named after the test binary's process and `name`); it is
/// removed when dropped, unless the test is failing (then it stays, to look at). The render
/// tests write tens of megabytes of frames a run: kept, they filled gigabytes of `/tmp` on a
/// machine that runs the suite again and again.
pub struct Scratch(PathBuf);

impl Scratch {
    pub fn new(prefix: &str, name: &str) -> Scratch {
        let dir = std::env::temp_dir().join(format!("{prefix}-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("create the test's scratch folder");
        Scratch(dir)
    }
}

impl std::ops::Deref for Scratch {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<Path> for Scratch {
    fn as_ref(&self) -> &Path {
        &self.0
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        if !std::thread::panicking() {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}

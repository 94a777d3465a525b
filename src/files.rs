//! Atomic output files: everything a command writes goes to a temporary file in the target's
//! own folder and is renamed over the target only once complete, so a failed or interrupted
//! command never leaves a half-written file where a good one was (a rename within one folder
//! replaces the old file in one step on POSIX file systems).

use std::ffi::OsString;
use std::io::Write;
use std::path::{Path, PathBuf};

/// A file being written under a temporary name beside its target: write to [`AtomicFile::path`],
/// then [`AtomicFile::commit`] renames it over the target. Dropped without a commit (an error,
/// a panic), the temporary file is removed and the target keeps what it had.
#[derive(Debug)]
pub struct AtomicFile {
    tmp: PathBuf,
    target: PathBuf,
}

impl AtomicFile {
    /// Prepare to write `target`: creates its parent folders and names the temporary file
    /// `.NAME.partial.EXT` in the same folder (the extension stays last, so writers that pick
    /// the format from the file name still see `.png` or `.svg`).
    pub fn new(target: &Path) -> std::io::Result<AtomicFile> {
        let name = target.file_name().ok_or_else(|| {
            std::io::Error::new(std::io::ErrorKind::InvalidInput, format!("{} names no file", target.display()))
        })?;
        if let Some(parent) = target.parent().filter(|p| !p.as_os_str().is_empty()) {
            std::fs::create_dir_all(parent)?;
        }
        let name = Path::new(name);
        let mut tmp_name = OsString::from(".");
        tmp_name.push(name.file_stem().unwrap_or(name.as_os_str()));
        tmp_name.push(".partial");
        if let Some(ext) = name.extension() {
            tmp_name.push(".");
            tmp_name.push(ext);
        }
        Ok(AtomicFile { tmp: target.with_file_name(tmp_name), target: target.to_path_buf() })
    }

    /// The temporary file to write.
    pub fn path(&self) -> &Path {
        &self.tmp
    }

    /// The file it becomes.
    pub fn target(&self) -> &Path {
        &self.target
    }

    /// Rename the written temporary file over the target.
    pub fn commit(self) -> std::io::Result<()> {
        let result = std::fs::rename(&self.tmp, &self.target);
        if result.is_ok() {
            std::mem::forget(self);
        }
        result
    }
}

impl Drop for AtomicFile {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.tmp);
    }
}

/// Write `bytes` to `path` atomically (parent folders created).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let file = AtomicFile::new(path)?;
    let mut out = std::fs::File::create(file.path())?;
    out.write_all(bytes)?;
    out.sync_data()?;
    drop(out);
    file.commit()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("smlworld-files-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        dir
    }

    #[test]
    fn a_commit_replaces_the_target_and_creates_its_folder() {
        let dir = scratch("commit");
        let target = dir.join("a/b/out.png");
        write_atomic(&target, b"new").expect("writes");
        assert_eq!(std::fs::read(&target).expect("the target reads"), b"new");
        assert_eq!(
            std::fs::read_dir(target.parent().expect("the target is in a folder")).expect("the folder lists").count(),
            1,
            "no temporary file left"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_file_dropped_before_its_commit_leaves_the_old_target() {
        let dir = scratch("drop");
        let target = dir.join("summary.json");
        write_atomic(&target, b"old").expect("writes");
        {
            let file = AtomicFile::new(&target).expect("a temporary file beside the target");
            assert_eq!(file.path(), dir.join(".summary.partial.json"));
            std::fs::write(file.path(), b"half").expect("the temporary file writes");
        }
        assert_eq!(std::fs::read(&target).expect("the target reads"), b"old");
        assert!(!dir.join(".summary.partial.json").exists());
        let _ = std::fs::remove_dir_all(&dir);
    }
}

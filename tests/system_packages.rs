//! The README's test command on a fresh machine (issue 61, section 5): `scripts/test.sh` installs
//! the system packages its tests need (`scripts/system_packages.sh`), or names them when it
//! cannot. A machine without `xwd` is faked by a PATH that lacks it.

use std::os::unix::fs::{PermissionsExt, symlink};
use std::path::{Path, PathBuf};
use std::process::Command;

/// A directory of links to the commands the script uses, without `xwd`, plus a fake `apt-get`
/// that logs its arguments into `apt.log` beside it.
fn path_without_xwd(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("smlworld-syspkg-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    for tool in ["bash", "ldconfig", "grep", "ls", "python3", "id", "dirname", "Xvfb"] {
        let found = ["/usr/bin", "/bin", "/usr/sbin", "/sbin", "/usr/local/bin"]
            .iter()
            .map(|d| Path::new(d).join(tool))
            .find(|p| p.exists());
        if let Some(found) = found {
            symlink(found, dir.join(tool)).unwrap();
        }
    }
    let fake = dir.join("apt-get");
    std::fs::write(&fake, format!("#!/bin/bash\necho \"$@\" >> {}/apt.log\n", dir.display())).unwrap();
    std::fs::set_permissions(&fake, std::fs::Permissions::from_mode(0o755)).unwrap();
    dir
}

fn system_packages(path: &Path, apt_get: &str) -> (bool, String) {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/system_packages.sh");
    let out = Command::new(path.join("bash"))
        .arg(script)
        .env("PATH", path)
        .env("SMLWORLD_APT_GET", apt_get)
        .env_remove("SMLWORLD_NO_APT")
        .output()
        .expect("runs bash");
    (out.status.success(), String::from_utf8_lossy(&out.stderr).into())
}

fn is_root() -> bool {
    let out = Command::new("id").arg("-u").output().expect("runs id");
    String::from_utf8_lossy(&out.stdout).trim() == "0"
}

#[test]
fn a_missing_xwd_is_installed_with_apt_get_as_root() {
    let dir = path_without_xwd("root");
    let (ok, stderr) = system_packages(&dir, dir.join("apt-get").to_str().unwrap());
    let log = std::fs::read_to_string(dir.join("apt.log")).unwrap_or_default();
    let _ = std::fs::remove_dir_all(&dir);
    if is_root() {
        assert!(ok, "{stderr}");
        assert!(log.contains("update"), "apt-get update first: {log}");
        let install = log.lines().find(|l| l.starts_with("install")).unwrap_or("");
        assert!(install.split(' ').any(|w| w == "x11-apps"), "installs x11-apps (xwd): {log}");
        assert!(stderr.contains("x11-apps"), "says what it installs: {stderr}");
    } else {
        assert!(!ok, "not root: stops and names the package");
        assert!(stderr.contains("x11-apps"), "{stderr}");
        assert!(log.is_empty(), "no apt-get call without root: {log}");
    }
}

#[test]
fn without_apt_get_the_message_names_the_package() {
    let dir = path_without_xwd("noapt");
    let (ok, stderr) = system_packages(&dir, "/nonexistent/apt-get");
    let _ = std::fs::remove_dir_all(&dir);
    assert!(!ok, "a missing package it cannot install fails the command");
    assert!(stderr.contains("missing here: ") && stderr.contains("x11-apps"), "{stderr}");
    assert!(stderr.contains("apt-get install"), "says how: {stderr}");
}

#[test]
fn ci_run_calls_the_test_command_and_installs_nothing_itself() {
    let ci = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join(".ci/run")).unwrap();
    assert!(ci.contains("bash scripts/test.sh"), "{ci}");
    assert!(!ci.contains("apt-get install"), ".ci/run installs nothing test.sh needs: {ci}");
    let test_sh = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/test.sh")).unwrap();
    assert!(test_sh.contains("bash scripts/system_packages.sh"), "{test_sh}");
}

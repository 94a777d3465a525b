//! A virtual X server for the tests that open windows (`smlworld view`): started on a display it
//! picks itself, stopped with SIGTERM.

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// A running Xvfb, stopped with SIGTERM so that it removes its lock file and socket: SIGKILL
/// (what `ChildGuard` sends) leaves `/tmp/.X<n>-lock` behind, and on a machine whose `/tmp`
/// outlives the runs (CI's does) those stale locks once filled every display an earlier
/// version of this test was willing to try.
pub struct Xvfb(Child);

impl Drop for Xvfb {
    fn drop(&mut self) {
        if let Ok(pid) = libc::pid_t::try_from(self.0.id()) {
            // SAFETY: kill(2) on our own child's pid; it has not been reaped yet (no wait).
            unsafe { libc::kill(pid, libc::SIGTERM) };
        }
        let deadline = Instant::now() + Duration::from_secs(5);
        while Instant::now() < deadline {
            if let Ok(Some(_)) = self.0.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Start Xvfb on a display it picks itself (`-displayfd`: the server takes the first display
/// whose lock is free or stale, and writes its number once it accepts connections); returns
/// the guard and the display name. Panics with Xvfb's own log when it does not come up.
pub fn start_xvfb(dir: &Path) -> (Xvfb, String) {
    let log = dir.join("xvfb.log");
    let child = Command::new("Xvfb")
        .args(["-displayfd", "1", "-screen", "0", "800x600x24", "-nolisten", "tcp"])
        .stdout(Stdio::piped())
        .stderr(std::fs::File::create(&log).expect("log"))
        .spawn()
        .unwrap_or_else(|e| {
            panic!(
                "cannot start Xvfb ({e}): the viewer test needs it; install it with \
                 `apt-get install xvfb x11-apps` (.ci/run does)"
            )
        });
    let mut guard = Xvfb(child);
    let stdout = guard.0.stdout.take().expect("piped stdout");
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        let mut line = String::new();
        let _ = BufReader::new(stdout).read_line(&mut line);
        let _ = tx.send(line);
    });
    let line = rx.recv_timeout(Duration::from_secs(30)).unwrap_or_default();
    match line.trim().parse::<u32>() {
        Ok(n) => (guard, format!(":{n}")),
        Err(_) => {
            drop(guard);
            panic!(
                "Xvfb did not report a display within 30 s; its log: {}",
                std::fs::read_to_string(&log).unwrap_or_default()
            )
        }
    }
}

//! Bridges to the lab: UDP visualisation stream, motion capture input, real-truck output.
//!
//! The protocol modules are plain Rust (no ECS); [`lab`] wraps each bridge in a plugin that
//! copies world state in or out. Every socket binds to loopback unless the caller gives an
//! address; a bad packet is logged and dropped, never fatal.
//! - [`viz`]: the 2015 visualisation datagram over UDP (sender, receiver, split extension);
//! - [`qualisys`]: Qualisys Track Manager real-time protocol 1.11 client and body tracker;
//! - [`mock_mocap`]: a mock Qualisys server streaming scripted trajectories;
//! - [`trucks`]: one TCP server per real truck sending the 2015 status line at 20 Hz;
//! - [`lab`]: the ECS plugins that wire these bridges into a simulation.

pub mod lab;
pub mod mock_mocap;
pub mod qualisys;
pub mod trucks;
pub mod viz;

use std::sync::{Mutex, MutexGuard};
use std::time::{Duration, Instant};

/// Lock a mutex, recovering the data if a thread panicked while holding it.
fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// Logs a warning at most once per interval, counting the ones it held back (so a flood of bad
/// packets does not flood the log).
#[derive(Debug)]
struct WarnLimiter {
    interval: Duration,
    last: Option<Instant>,
    suppressed: u64,
}

impl WarnLimiter {
    fn new(interval: Duration) -> Self {
        Self { interval, last: None, suppressed: 0 }
    }

    fn warn(&mut self, message: &str) {
        let now = Instant::now();
        if self.last.is_some_and(|l| now.duration_since(l) < self.interval) {
            self.suppressed += 1;
            return;
        }
        if self.suppressed > 0 {
            tracing::warn!("{message} ({} similar warnings suppressed)", self.suppressed);
        } else {
            tracing::warn!("{message}");
        }
        self.last = Some(now);
        self.suppressed = 0;
    }
}

//! Ctrl-C (SIGINT) and SIGTERM during long commands: the first signal asks the run to stop after
//! its current step and write what it has (the runners, `replay` and `bench` poll
//! [`requested`]); a second one ends the process at once, leaving the output folder as it was
//! (outputs are written aside and renamed into place only at the end).
//!
//! Only the command-line tool calls [`install`]: a library user (Python included, whose own
//! SIGINT handler raises `KeyboardInterrupt`) keeps the process's handlers, and [`requested`]
//! then stays `None`.

use std::sync::atomic::{AtomicI32, Ordering};

/// The first stop signal received (0: none).
static SIGNAL: AtomicI32 = AtomicI32::new(0);

extern "C" fn on_signal(signal: libc::c_int) {
    // Only async-signal-safe work here: an atomic swap, and `_exit` on the second signal.
    if SIGNAL.swap(signal, Ordering::SeqCst) != 0 {
        // SAFETY: `_exit` is async-signal-safe; it ends the process without running destructors,
        // so no output file is renamed into place.
        unsafe { libc::_exit(128 + signal) };
    }
}

/// Catch SIGINT and SIGTERM for the rest of the process (the command-line tool calls this once).
pub fn install() {
    let handler: extern "C" fn(libc::c_int) = on_signal;
    for signal in [libc::SIGINT, libc::SIGTERM] {
        // SAFETY: the handler only touches an atomic and calls `_exit`, both async-signal-safe.
        unsafe { libc::signal(signal, handler as libc::sighandler_t) };
    }
}

/// The stop signal received so far (SIGINT or SIGTERM), if any.
pub fn requested() -> Option<i32> {
    match SIGNAL.load(Ordering::SeqCst) {
        0 => None,
        s => Some(s),
    }
}

/// The exit status of a command stopped by `signal`: 128 + its number (130 for SIGINT, 143 for
/// SIGTERM), as shells report it.
pub fn exit_code(signal: i32) -> i32 {
    128 + signal
}

/// The signal's name for messages.
pub fn name(signal: i32) -> &'static str {
    match signal {
        libc::SIGINT => "Ctrl-C (SIGINT)",
        libc::SIGTERM => "SIGTERM",
        _ => "a signal",
    }
}

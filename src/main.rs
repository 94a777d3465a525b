//! `smlworld`: the command-line front end. Parses arguments and calls the library; nothing else.

mod cli;

use clap::Parser;

fn main() -> std::process::ExitCode {
    cli::huge_pages::restart_with_huge_pages();
    restore_default_sigpipe();
    let args = cli::Cli::parse_from(cli::join_optional_values(std::env::args_os()));
    cli::init_logging(args.verbose);
    match cli::dispatch(args.command) {
        // A run stopped by Ctrl-C or SIGTERM wrote its outputs and ends as shells expect: 130 / 143.
        Ok(()) => match smlworld::app::running::interrupt::requested() {
            Some(signal) => std::process::ExitCode::from(smlworld::app::running::interrupt::exit_code(signal) as u8),
            None => std::process::ExitCode::SUCCESS,
        },
        Err(e) => {
            eprintln!("error: {}", cli::error_line(&e));
            std::process::ExitCode::FAILURE
        }
    }
}

/// Rust ignores SIGPIPE, so a `println!` to a closed pipe (`smlworld map info ... | head`) panics
/// with a backtrace; with the default disposition the process ends quietly, like `cat`.
fn restore_default_sigpipe() {
    #[cfg(unix)]
    // SAFETY: called first thing in `main`, before any thread exists; SIG_DFL is a valid handler.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

//! Command-line interface: one file per subcommand, each a thin layer over the library.

mod bench;
pub mod huge_pages;
mod map;
mod map_generate;
mod map_render;
mod mock_mocap;
mod plot;
mod replay;
mod run;
mod view;

use clap::{Parser, Subcommand};
use smlworld::range;

/// SML World: simulate autonomous and cooperative vehicles on lanelet maps drawn in JOSM.
#[derive(Debug, Parser)]
#[command(name = "smlworld", version, about, long_about = None)]
pub struct Cli {
    /// More log output (-v: debug, -vv: trace). RUST_LOG overrides it.
    #[arg(short, long, action = clap::ArgAction::Count, global = true)]
    pub verbose: u8,
    #[command(subcommand)]
    pub command: Command,
}

/// The subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Inspect, route on, generate and render lanelet maps.
    #[command(subcommand)]
    Map(map::MapCommand),
    /// Run a scenario (TOML) headless or in real time.
    Run(run::RunArgs),
    /// Figures of a finished run (speed, gaps, platoons, lateral deviation, trace) as PNG and SVG.
    Plot(plot::PlotArgs),
    /// Redraw a finished run (its trajectories.csv and summary.json) as frames, a GIF or a UDP stream.
    Replay(replay::ReplayArgs),
    /// Benchmark the whole simulation with N vehicles; prints JSON.
    Bench(bench::BenchArgs),
    /// Live bird's-eye viewer for the UDP visualisation stream.
    View(view::ViewArgs),
    /// A mock Qualisys motion-capture server streaming scripted trajectories (for demos).
    MockMocap(mock_mocap::MockMocapArgs),
}

/// The command line with `--overlay VALUE` (a space, as most flags take their value) joined into
/// `--overlay=VALUE` when VALUE is one of the overlay's values: the flag's value is optional
/// (a bare `--overlay` means `all`), so clap takes it only after `=`, and `--overlay none` was
/// refused with "unexpected argument 'none'" (issue 60 §5). Anything else passes unchanged.
pub fn join_optional_values(args: impl IntoIterator<Item = std::ffi::OsString>) -> Vec<std::ffi::OsString> {
    let mut out: Vec<std::ffi::OsString> = Vec::new();
    for arg in args {
        let joins =
            out.last().is_some_and(|last| last == "--overlay") && ["gif", "all", "none"].iter().any(|v| arg == *v);
        if joins && let Some(last) = out.last_mut() {
            last.push("=");
            last.push(&arg);
        } else {
            out.push(arg);
        }
    }
    out
}

/// Log to stderr, in colour only when stderr is a terminal; `RUST_LOG` wins over `-v`.
pub fn init_logging(verbose: u8) {
    let default = match verbose {
        0 => "info",
        1 => "debug",
        _ => "trace",
    };
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default));
    use std::io::IsTerminal;
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal())
        .with_target(false)
        .init();
}

/// Run one subcommand.
pub fn dispatch(command: Command) -> anyhow::Result<()> {
    match command {
        Command::Map(c) => map::main(c),
        Command::Run(a) => run::main(a),
        Command::Replay(a) => replay::main(a),
        Command::Plot(a) => plot::main(a),
        Command::Bench(a) => bench::main(a),
        Command::View(a) => view::main(a),
        Command::MockMocap(a) => mock_mocap::main(a),
    }
}

/// An error and its causes as one line, each cause once: many of our errors already print their
/// source in their own message, so a cause whose text the line holds already is left out.
pub fn error_line(e: &anyhow::Error) -> String {
    let mut line = String::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if line.contains(&text) {
            continue;
        }
        if !line.is_empty() {
            line.push_str(": ");
        }
        line.push_str(&text);
    }
    line
}

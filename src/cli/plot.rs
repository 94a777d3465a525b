//! `smlworld plot OUT_DIR [--out DIR]`: figures of a finished run (a thin caller of
//! [`smlworld::app::plot_run`]).

use std::path::PathBuf;

/// Arguments of `smlworld plot`.
#[derive(Debug, clap::Args)]
pub struct PlotArgs {
    /// Output folder of a run (holds trajectories.csv and summary.json).
    pub out_dir: PathBuf,
    /// Folder for the figures (default OUT_DIR/plots).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
}

/// Run the subcommand.
pub fn main(args: PlotArgs) -> anyhow::Result<()> {
    let dest = args.out.unwrap_or_else(|| args.out_dir.join("plots"));
    let written = smlworld::app::plot_run(&args.out_dir, &dest)?;
    for png in &written {
        println!("{} (+ .svg)", png.display());
    }
    Ok(())
}

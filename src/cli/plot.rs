//! `smlworld plot OUT_DIR [--out DIR]`: figures of a finished run (a thin caller of
//! [`smlworld::app::plot_run`]).

use std::path::PathBuf;

/// Arguments of `smlworld plot`.
#[derive(Debug, clap::Args)]
pub struct PlotArgs {
    /// Output folder of a run (holds trajectories.csv and summary.json); several with --compare.
    #[arg(required = true, value_name = "OUT_DIR")]
    pub out_dirs: Vec<PathBuf>,
    /// Folder for the figures (default OUT_DIR/plots; with --compare, the first run's
    /// plots/compare).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Overlay the same figures of all the runs given (one colour per run, the legend naming
    /// each by its sweep parameters in params.json or its folder name).
    #[arg(long)]
    pub compare: bool,
}

/// Run the subcommand.
pub fn main(args: PlotArgs) -> anyhow::Result<()> {
    let first = args.out_dirs[0].clone();
    let written = if args.compare {
        let dest = args.out.unwrap_or_else(|| first.join("plots").join("compare"));
        smlworld::app::plot_compare(&args.out_dirs, &dest)?
    } else {
        anyhow::ensure!(
            args.out_dirs.len() == 1,
            "{} run folders given: plot one, or overlay them with --compare",
            args.out_dirs.len()
        );
        let dest = args.out.unwrap_or_else(|| first.join("plots"));
        smlworld::app::plot_run(&first, &dest)?
    };
    for png in &written {
        println!("{} (+ .svg)", png.display());
    }
    Ok(())
}

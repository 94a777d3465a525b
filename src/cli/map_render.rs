//! `smlworld map render MAP --out FILE.png|FILE.bmp`: the environment image plus the original's `.meta` file.

use std::path::PathBuf;

use anyhow::Context;
use glam::DVec2;
use smlworld::app::results::output::{Fixed, LENGTH_DECIMALS};
use smlworld::map::LaneletMap;
use smlworld::render::{BirdseyeView, Environment, PatternSet, Renderer, write_image_with_meta};

/// `smlworld map render MAP --out FILE [--width W --height H --pixels-per-meter P] [--center X,Y] [--patterns DIR]`.
#[derive(Debug, clap::Args)]
pub struct RenderArgs {
    /// Map file (.osm or .xml, as saved by JOSM).
    pub map: PathBuf,
    /// Output image: `.png`, or `.bmp` for the original's bitmap format. `FILE.meta` is written beside it.
    #[arg(long)]
    pub out: PathBuf,
    /// Image width [px].
    #[arg(long, default_value_t = 1920, value_parser = super::range::pixels())]
    pub width: u32,
    /// Image height [px].
    #[arg(long, default_value_t = 1080, value_parser = super::range::pixels())]
    pub height: u32,
    /// Scale [px/m]. Without it the whole map is fitted into the image; with it and no `--center`
    /// the image is centred on the map's origin, as the 2015 tool did.
    #[arg(long, value_parser = super::range::positive)]
    pub pixels_per_meter: Option<f64>,
    /// World point at the image centre, `X,Y` [m] (needs `--pixels-per-meter`).
    #[arg(long, value_parser = super::range::point, allow_hyphen_values = true, requires = "pixels_per_meter")]
    pub center: Option<DVec2>,
    /// Directory with your own pattern images (`forest.png`, `road.png`, `mud.png`, `iron.png`,
    /// `parking_lot.png`, `free_space.png`); missing ones use the built-in patterns.
    #[arg(long)]
    pub patterns: Option<PathBuf>,
}

/// Run the subcommand.
pub fn main(args: RenderArgs) -> anyhow::Result<()> {
    let map = LaneletMap::load(&args.map).with_context(|| format!("loading {}", args.map.display()))?;
    for w in &map.warnings {
        tracing::warn!("{w}");
    }
    let view = match args.pixels_per_meter {
        Some(ppm) => BirdseyeView::new(args.width, args.height, ppm, args.center.unwrap_or(DVec2::ZERO))?,
        None => BirdseyeView::fit_map(args.width, args.height, &map)?,
    };
    let patterns = match &args.patterns {
        Some(dir) => PatternSet::from_dir(dir)?,
        None => PatternSet::builtin(),
    };
    let mut renderer = Renderer::new()?;
    tracing::debug!(adapter = %renderer.adapter_name(), "rendering");
    let layer = renderer.environment_layer(&Environment::from_map(&map), &view, &patterns)?;
    let image = renderer.read_environment(&layer)?;
    let meta = write_image_with_meta(&args.out, &image, &view)?;
    println!(
        "wrote {} ({}x{} px, {} px/m, centre {},{} m) and {}",
        args.out.display(),
        view.width,
        view.height,
        Fixed(view.pixels_per_meter, 3),
        Fixed(view.center.x, LENGTH_DECIMALS),
        Fixed(view.center.y, LENGTH_DECIMALS),
        meta.display()
    );
    Ok(())
}

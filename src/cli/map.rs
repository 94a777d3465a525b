//! `smlworld map ...`: info, route, loop (generate and render live in their own files).

use clap::Subcommand;

use super::{map_generate, map_render};

/// Map subcommands.
#[derive(Debug, Subcommand)]
pub enum MapCommand {
    /// Write a parametric map (ring highway, intersections, grid city) as JOSM-compatible OSM XML.
    Generate(map_generate::GenerateArgs),
    /// Render the environment image of a map (PNG or BMP plus the original's .meta file).
    Render(map_render::RenderArgs),
}

/// Run a map subcommand.
pub fn main(command: MapCommand) -> anyhow::Result<()> {
    match command {
        MapCommand::Generate(a) => map_generate::main(a),
        MapCommand::Render(a) => map_render::main(a),
    }
}

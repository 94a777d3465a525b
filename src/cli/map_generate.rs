//! `smlworld map generate KIND [params] --out FILE`: write a parametric map as JOSM-compatible XML.

use std::fs::File;
use std::path::PathBuf;

use anyhow::Context;
use clap::{Args, ValueEnum};
use smlworld::files::AtomicFile;
use smlworld::map::generate::{self, GridParams, IntersectionParams, LaneDropParams, MapStats, RingParams};

/// Which map to generate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum MapKind {
    /// Ring highway around the origin, like HighwaySML (--lanes, --radius, --lane-width,
    /// --clockwise, --node-spacing).
    Ring,
    /// T junction with arms east, west, south and every legal turn (--lanes, --arm-length,
    /// --lane-width, --corner-radius, --node-spacing).
    Intersection3,
    /// 4-way junction with every legal turn (same flags as intersection3).
    Intersection4,
    /// Grid city of ROWS x COLS blocks with all turns at every junction (--rows, --cols, --block,
    /// --lanes, --lane-width, --corner-radius, --node-spacing).
    Grid,
    /// Straight two-lane road whose left lane ends, for the GCDC merge (--length, --drop-at,
    /// --lane-width, --node-spacing).
    LaneDrop,
}

/// Arguments of `map generate`. Flags left out take the defaults shown; a flag that does not
/// apply to KIND is an error.
#[derive(Debug, Args)]
#[command(after_help = "Examples:\n  smlworld map generate ring --out ring.osm\n  \
    smlworld map generate grid --rows 30 --cols 30 --out city.osm\n\n\
    Destination tags: ring lanes right_lane_node/center_lane_node/left_lane_node (3 lanes) or \
    lane_<k>_node; intersections <arm>_start and <arm>_end; grids r<row>c<col>_<arm>; lane-drop \
    lane_drop_right_start, lane_drop_left_start, lane_drop_left_end, lane_drop_end.")]
pub struct GenerateArgs {
    /// Kind of map.
    #[arg(value_enum)]
    pub kind: MapKind,
    /// Output file (.osm or .xml), overwritten if it exists.
    #[arg(long, value_name = "FILE")]
    pub out: PathBuf,
    /// Lanes (ring: in total, default 3; intersections and grid: per direction, default 1).
    #[arg(long, value_parser = super::range::count::<usize>(1, 1000))]
    pub lanes: Option<usize>,
    /// Lane width [m] (ring default 4.0; others 3.5).
    #[arg(long, value_name = "M", value_parser = super::range::positive)]
    pub lane_width: Option<f64>,
    /// Largest distance between nodes [m] (ring and grid default 2.0; intersections 1.0).
    #[arg(long, value_name = "M", value_parser = super::range::positive)]
    pub node_spacing: Option<f64>,
    /// Ring only: radius of the innermost road edge [m] (default 50.0).
    #[arg(long, value_name = "M", value_parser = super::range::positive)]
    pub radius: Option<f64>,
    /// Ring only: drive clockwise (default counter-clockwise).
    #[arg(long)]
    pub clockwise: bool,
    /// Intersections only: length of each arm beyond the junction [m] (default 30.0).
    #[arg(long, value_name = "M", value_parser = super::range::positive)]
    pub arm_length: Option<f64>,
    /// Intersections and grid: radius of the road edge in junction corners [m] (default 6.0).
    #[arg(long, value_name = "M", value_parser = super::range::positive)]
    pub corner_radius: Option<f64>,
    /// Grid only: blocks from south to north (default 3).
    #[arg(long, value_parser = super::range::count::<usize>(1, 100_000))]
    pub rows: Option<usize>,
    /// Grid only: blocks from west to east (default 3).
    #[arg(long, value_parser = super::range::count::<usize>(1, 100_000))]
    pub cols: Option<usize>,
    /// Grid only: distance between neighbouring junction centres [m] (default 50.0).
    #[arg(long, value_name = "M", value_parser = super::range::positive)]
    pub block: Option<f64>,
    /// Lane drop only: length of the road [m] (default 500.0).
    #[arg(long, value_name = "M", value_parser = super::range::positive)]
    pub length: Option<f64>,
    /// Lane drop only: where the left lane ends [m from the start] (default 300.0).
    #[arg(long, value_name = "M", value_parser = super::range::positive)]
    pub drop_at: Option<f64>,
    /// Intersections and grid: traffic lights at every junction of 3 or more arms (turn lanelets
    /// tagged `traffic_light=yes`; a fixed-time program runs unless a scenario gives one).
    #[arg(long)]
    pub traffic_lights: bool,
    /// Intersections and grid: the road along this axis is major and the other yields (turn
    /// lanelets tagged `priority=major|minor`); default: all arms equal (right before left).
    #[arg(long, value_enum, value_name = "AXIS")]
    pub major_road: Option<MajorRoad>,
}

/// `--major-road`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum MajorRoad {
    /// The east and west arms.
    EastWest,
    /// The north and south arms.
    NorthSouth,
}

/// Run `map generate`: one match arm per generator, each a few lines of argument checks (81
/// lines in all; the arms share the writing at the end).
pub fn main(a: GenerateArgs) -> anyhow::Result<()> {
    let kind_name = a.kind.to_possible_value().map(|v| v.get_name().to_string()).unwrap_or_default();
    let given = [
        ("--radius", a.radius.is_some(), a.kind == MapKind::Ring),
        ("--clockwise", a.clockwise, a.kind == MapKind::Ring),
        ("--arm-length", a.arm_length.is_some(), matches!(a.kind, MapKind::Intersection3 | MapKind::Intersection4)),
        ("--corner-radius", a.corner_radius.is_some(), a.kind != MapKind::Ring),
        ("--rows", a.rows.is_some(), a.kind == MapKind::Grid),
        ("--cols", a.cols.is_some(), a.kind == MapKind::Grid),
        ("--block", a.block.is_some(), a.kind == MapKind::Grid),
        ("--length", a.length.is_some(), a.kind == MapKind::LaneDrop),
        ("--drop-at", a.drop_at.is_some(), a.kind == MapKind::LaneDrop),
        ("--lanes", a.lanes.is_some(), a.kind != MapKind::LaneDrop),
        (
            "--traffic-lights",
            a.traffic_lights,
            matches!(a.kind, MapKind::Intersection3 | MapKind::Intersection4 | MapKind::Grid),
        ),
        (
            "--major-road",
            a.major_road.is_some(),
            matches!(a.kind, MapKind::Intersection3 | MapKind::Intersection4 | MapKind::Grid),
        ),
    ];
    let control = generate::JunctionMarks {
        traffic_lights: a.traffic_lights,
        major: a.major_road.map(|m| match m {
            MajorRoad::EastWest => generate::Axis::EastWest,
            MajorRoad::NorthSouth => generate::Axis::NorthSouth,
        }),
    };
    for (flag, set, applies) in given {
        if set && !applies {
            anyhow::bail!("{flag} does not apply to `{kind_name}` maps; see `smlworld map generate --help`");
        }
    }
    // Written beside the target and renamed at the end, so bad parameters or a failed write
    // never leave a truncated map behind.
    let partial = AtomicFile::new(&a.out).with_context(|| format!("cannot write {}", a.out.display()))?;
    let file = File::create(partial.path()).with_context(|| format!("cannot create {}", partial.path().display()))?;
    let written: Result<MapStats, generate::GenerateError> = match a.kind {
        MapKind::Ring => {
            let d = RingParams::default();
            let p = RingParams {
                lanes: a.lanes.unwrap_or(d.lanes),
                radius: a.radius.unwrap_or(d.radius),
                lane_width: a.lane_width.unwrap_or(d.lane_width),
                clockwise: a.clockwise,
                node_spacing: a.node_spacing.unwrap_or(d.node_spacing),
            };
            generate::write_ring_highway(&p, file)
        }
        MapKind::Intersection3 | MapKind::Intersection4 => {
            let d = IntersectionParams::default();
            let p = IntersectionParams {
                arms: if a.kind == MapKind::Intersection3 { 3 } else { 4 },
                lanes: a.lanes.unwrap_or(d.lanes),
                arm_length: a.arm_length.unwrap_or(d.arm_length),
                lane_width: a.lane_width.unwrap_or(d.lane_width),
                corner_radius: a.corner_radius.unwrap_or(d.corner_radius),
                node_spacing: a.node_spacing.unwrap_or(d.node_spacing),
                control,
            };
            generate::write_intersection(&p, file)
        }
        MapKind::Grid => {
            let d = GridParams::default();
            let p = GridParams {
                rows: a.rows.unwrap_or(d.rows),
                cols: a.cols.unwrap_or(d.cols),
                block: a.block.unwrap_or(d.block),
                lanes: a.lanes.unwrap_or(d.lanes),
                lane_width: a.lane_width.unwrap_or(d.lane_width),
                corner_radius: a.corner_radius.unwrap_or(d.corner_radius),
                node_spacing: a.node_spacing.unwrap_or(d.node_spacing),
                control,
            };
            generate::write_grid_city(&p, file)
        }
        MapKind::LaneDrop => {
            let d = LaneDropParams::default();
            let p = LaneDropParams {
                length: a.length.unwrap_or(d.length),
                drop_at: a.drop_at.unwrap_or(d.drop_at),
                lane_width: a.lane_width.unwrap_or(d.lane_width),
                node_spacing: a.node_spacing.unwrap_or(d.node_spacing),
                ..d
            };
            generate::write_lane_drop(&p, file)
        }
    };
    let stats = match written {
        Ok(stats) => stats,
        // The temporary file is removed when `partial` drops; the target keeps what it had.
        Err(e) => return Err(e).with_context(|| format!("generating {}", a.out.display())),
    };
    partial.commit().with_context(|| format!("cannot move the new map to {}", a.out.display()))?;
    println!(
        "wrote {}: {} map, {} nodes, {} ways, {} lanelets, {} bytes",
        a.out.display(),
        kind_name,
        stats.nodes,
        stats.ways,
        stats.lanelets,
        stats.bytes
    );
    Ok(())
}

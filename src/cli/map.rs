//! `smlworld map ...`: info, route, loop (generate and render live in their own files).

use std::collections::BTreeMap;
use std::path::PathBuf;

use anyhow::Context;
use clap::{Args, Subcommand};
use serde::Serialize;
use smlworld::map::{LaneChange, LaneChangeOptions, LaneletMap, Path, Place, RouteOptions};

use super::{map_generate, map_render};

/// Map subcommands.
#[derive(Debug, Subcommand)]
pub enum MapCommand {
    /// Summarise a map: counts, origin, UTM zone, node tags, lanelets, warnings.
    Info(InfoArgs),
    /// Shortest route between two nodes (ids or tag values), as resampled centre-line points.
    #[command(allow_negative_numbers = true)]
    Route(RouteArgs),
    /// Shortest closed loop through a node (id or tag value), back to the lanelet it started on.
    #[command(allow_negative_numbers = true)]
    Loop(LoopArgs),
    /// Write a parametric map (ring highway, intersections, grid city) as JOSM-compatible OSM XML.
    Generate(map_generate::GenerateArgs),
    /// Render the environment image of a map (PNG or BMP plus the original's .meta file).
    Render(map_render::RenderArgs),
}

/// `smlworld map info MAP [--json]`.
#[derive(Debug, Args)]
pub struct InfoArgs {
    /// Map file (.osm or .xml, as saved by JOSM).
    pub map: PathBuf,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

/// `smlworld map route MAP (--from ID | --from-tag T) (--to ID | --to-tag T)`.
#[derive(Debug, Args)]
pub struct RouteArgs {
    /// Map file (.osm or .xml).
    pub map: PathBuf,
    /// Start node id (negative ids are fine: `--from -142`).
    #[arg(long, required_unless_present = "from_tag", conflicts_with = "from_tag")]
    pub from: Option<i64>,
    /// Start node tag value (e.g. `right_lane_node` for `destination=right_lane_node`).
    #[arg(long)]
    pub from_tag: Option<String>,
    /// End node id.
    #[arg(long, required_unless_present = "to_tag", conflicts_with = "to_tag")]
    pub to: Option<i64>,
    /// End node tag value.
    #[arg(long)]
    pub to_tag: Option<String>,
    /// Resampling density of the path [points per metre].
    #[arg(long, default_value_t = 5.0)]
    pub points_per_meter: f64,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
    /// Allow lane changes into neighbours whose shared line allows it; lists them
    /// (`lane_changes: [{from, to, at_m}]` in JSON).
    #[arg(long)]
    pub lane_changes: bool,
    /// Cost of one lane change [m of driving] (with --lane-changes).
    #[arg(long, default_value_t = 50.0, requires = "lane_changes")]
    pub lane_change_penalty: f64,
}

/// `smlworld map loop MAP (--node ID | --tag T)`.
#[derive(Debug, Args)]
pub struct LoopArgs {
    /// Map file (.osm or .xml).
    pub map: PathBuf,
    /// Node id the loop passes through.
    #[arg(long, required_unless_present = "tag", conflicts_with = "tag")]
    pub node: Option<i64>,
    /// Node tag value the loop passes through.
    #[arg(long)]
    pub tag: Option<String>,
    /// Resampling density of the path [points per metre].
    #[arg(long, default_value_t = 5.0)]
    pub points_per_meter: f64,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

/// Run a map subcommand.
pub fn main(command: MapCommand) -> anyhow::Result<()> {
    match command {
        MapCommand::Info(a) => info(a),
        MapCommand::Route(a) => {
            let map = load(&a.map)?;
            let from = place(a.from, a.from_tag);
            let to = place(a.to, a.to_tag);
            if a.lane_changes {
                let opts = LaneChangeOptions {
                    points_per_meter: a.points_per_meter,
                    change_penalty_m: a.lane_change_penalty,
                    ..LaneChangeOptions::default()
                };
                let route = map.route_with_lane_changes(&from, &to, &opts)?;
                return print_path_with_changes(&route.path, Some(&route.lane_changes), a.json);
            }
            let path = map.route_places(&from, &to, &RouteOptions { points_per_meter: a.points_per_meter })?;
            print_path(&path, a.json)
        }
        MapCommand::Loop(a) => {
            let map = load(&a.map)?;
            let at = place(a.node, a.tag);
            let path = map.closed_loop_at(&at, &RouteOptions { points_per_meter: a.points_per_meter })?;
            print_path(&path, a.json)
        }
        MapCommand::Generate(a) => map_generate::main(a),
        MapCommand::Render(a) => map_render::main(a),
    }
}

fn load(path: &std::path::Path) -> anyhow::Result<LaneletMap> {
    let map = LaneletMap::load(path)?;
    for w in &map.warnings {
        tracing::warn!("{w}");
    }
    Ok(map)
}

/// clap guarantees exactly one of the two is given.
fn place(id: Option<i64>, tag: Option<String>) -> Place {
    match (id, tag) {
        (Some(id), _) => Place::Node(id),
        (None, Some(t)) => Place::Tag(t),
        (None, None) => unreachable!("clap requires one of the two"),
    }
}

#[derive(Serialize)]
struct Origin {
    lat: f64,
    lon: f64,
    node: Option<i64>,
}

#[derive(Serialize)]
struct LaneletInfo<'a> {
    id: i64,
    length_m: f64,
    successors: Vec<i64>,
    left: i64,
    right: i64,
    tags: &'a BTreeMap<String, String>,
}

#[derive(Serialize)]
struct Info<'a> {
    nodes: usize,
    ways: usize,
    lanelets: usize,
    successor_pairs: usize,
    origin: Origin,
    utm_zone: String,
    tags: &'a BTreeMap<String, Vec<i64>>,
    lanelet_list: Vec<LaneletInfo<'a>>,
    warnings: Vec<String>,
}

fn info(a: InfoArgs) -> anyhow::Result<()> {
    let map = LaneletMap::load(&a.map)?;
    let info = Info {
        nodes: map.nodes.len(),
        ways: map.ways.len(),
        lanelets: map.lanelets.len(),
        successor_pairs: map.successor_pairs(),
        origin: Origin { lat: map.projector.origin_lat, lon: map.projector.origin_lon, node: map.origin_node },
        utm_zone: map.projector.zone_name(),
        tags: &map.tag_index,
        lanelet_list: map
            .lanelets
            .iter()
            .map(|l| LaneletInfo {
                id: l.id.0,
                length_m: l.length,
                successors: l.successors.iter().map(|s| s.0).collect(),
                left: l.left_way,
                right: l.right_way,
                tags: &l.tags,
            })
            .collect(),
        warnings: map.warnings.iter().map(ToString::to_string).collect(),
    };
    if a.json {
        println!("{}", serde_json::to_string_pretty(&info).context("writing JSON")?);
        return Ok(());
    }
    println!("map        {}", a.map.display());
    println!("nodes      {}", info.nodes);
    println!("ways       {}", info.ways);
    println!("lanelets   {} ({} successor pairs)", info.lanelets, info.successor_pairs);
    let origin = match info.origin.node {
        Some(n) => format!("node {n} (tagged origin=true)"),
        None => "mean of all nodes".to_string(),
    };
    println!("origin     {:.8} N {:.8} E, {origin}, UTM zone {}", info.origin.lat, info.origin.lon, info.utm_zone);
    if !info.tags.is_empty() {
        println!("node tags  (usable with --from-tag/--to-tag/--tag)");
        for (value, ids) in info.tags {
            println!("  {value:<28} nodes {ids:?}");
        }
    }
    println!("lanelets   id: length -> successors [left way | right way]");
    for l in &info.lanelet_list {
        println!("  {:>10}: {:>8.2} m -> {:?} [{} | {}]", l.id, l.length_m, l.successors, l.left, l.right);
    }
    if !info.warnings.is_empty() {
        println!("warnings   {}", info.warnings.len());
        for w in &info.warnings {
            println!("  {w}");
        }
    }
    Ok(())
}

#[derive(Serialize)]
struct PathJson {
    lanelets: Vec<i64>,
    length_m: f64,
    points: Vec<[f64; 2]>,
    #[serde(skip_serializing_if = "Option::is_none")]
    lane_changes: Option<Vec<LaneChangeJson>>,
}

#[derive(Serialize)]
struct LaneChangeJson {
    from: i64,
    to: i64,
    at_m: f64,
}

fn print_path(path: &Path, json: bool) -> anyhow::Result<()> {
    print_path_with_changes(path, None, json)
}

fn print_path_with_changes(path: &Path, changes: Option<&[LaneChange]>, json: bool) -> anyhow::Result<()> {
    let out = PathJson {
        lanelets: path.lanelets.iter().map(|l| l.0).collect(),
        length_m: path.length,
        points: path.points.iter().map(|p| [p.x, p.y]).collect(),
        lane_changes: changes
            .map(|c| c.iter().map(|c| LaneChangeJson { from: c.from.0, to: c.to.0, at_m: c.at_m }).collect()),
    };
    if json {
        println!("{}", serde_json::to_string(&out).context("writing JSON")?);
        return Ok(());
    }
    println!(
        "{} {:.2} m through {} lanelets: {:?}",
        if path.closed { "loop" } else { "route" },
        out.length_m,
        out.lanelets.len(),
        out.lanelets
    );
    println!("{} points, {:.3} m apart", out.points.len(), path.spacing());
    for c in out.lane_changes.iter().flatten() {
        println!("lane change {} -> {} at {:.2} m", c.from, c.to, c.at_m);
    }
    if let (Some(a), Some(b)) = (path.points.first(), path.points.last()) {
        println!("from ({:.2}, {:.2}) to ({:.2}, {:.2}) [m]", a.x, a.y, b.x, b.y);
    }
    Ok(())
}

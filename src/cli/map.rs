//! `smlworld map ...`: info, route, loop (generate and render live in their own files).

use std::collections::BTreeMap;
use std::path::PathBuf;

use anyhow::Context;
use clap::{Args, Subcommand};
use serde::Serialize;
use smlworld::app::results::output::{LENGTH_DECIMALS, rounded};
use smlworld::map::commonroad::{CommonRoadScenario, CommonRoadState, is_commonroad};
use smlworld::map::{LaneChange, LaneChangeOptions, LaneletMap, MapError, Place, RouteOptions, Routed};

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
    /// Convert an OpenDRIVE map (.xodr) to a Lanelet2 OSM map (origin node with its UTM zone).
    Convert(ConvertArgs),
}

/// `smlworld map convert MAP.xodr --out MAP.osm`.
#[derive(Debug, Args)]
pub struct ConvertArgs {
    /// OpenDRIVE file (.xodr).
    pub map: PathBuf,
    /// Output Lanelet2 OSM file (.osm), overwritten if it exists; never the input.
    #[arg(long)]
    pub out: PathBuf,
}

/// `smlworld map info MAP [--json]`.
#[derive(Debug, Args)]
pub struct InfoArgs {
    /// Map file (.osm or .xml, as saved by JOSM, a CommonRoad scenario .xml, or OpenDRIVE .xodr).
    pub map: PathBuf,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

/// `smlworld map route MAP (--from ID | --from-tag T) (--to ID | --to-tag T)`.
#[derive(Debug, Args)]
pub struct RouteArgs {
    /// Map file (.osm or .xml, or OpenDRIVE .xodr).
    pub map: PathBuf,
    /// Start node id (negative ids are fine: `--from -142`).
    #[arg(long, required_unless_present_any = ["from_tag", "from_lane"], conflicts_with_all = ["from_tag", "from_lane"])]
    pub from: Option<i64>,
    /// Start node tag value (e.g. `right_lane_node` for `destination=right_lane_node`).
    #[arg(long, conflicts_with = "from_lane")]
    pub from_tag: Option<String>,
    /// OpenDRIVE maps: start at the start of lane `ROAD:LANE` (the road's first lane section)
    /// or `ROAD:SECTION:LANE` (section index from 0), e.g. `--from-lane 5:-1`.
    #[arg(long, allow_hyphen_values = true)]
    pub from_lane: Option<String>,
    /// End node id.
    #[arg(long, required_unless_present_any = ["to_tag", "to_lane"], conflicts_with_all = ["to_tag", "to_lane"])]
    pub to: Option<i64>,
    /// End node tag value.
    #[arg(long, conflicts_with = "to_lane")]
    pub to_tag: Option<String>,
    /// OpenDRIVE maps: end at the end of lane `ROAD:LANE` or `ROAD:SECTION:LANE`.
    #[arg(long, allow_hyphen_values = true)]
    pub to_lane: Option<String>,
    /// Resampling density of the path [points per metre].
    #[arg(long, default_value_t = 5.0, value_parser = super::range::positive)]
    pub points_per_meter: f64,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
    /// Allow lane changes into neighbours whose shared line allows it; lists them
    /// (`lane_changes: [{from, to, at_m}]` in JSON).
    #[arg(long)]
    pub lane_changes: bool,
    /// Cost of one lane change [m of driving] (with --lane-changes).
    #[arg(long, default_value_t = 50.0, requires = "lane_changes", value_parser = super::range::non_negative)]
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
    #[arg(long, default_value_t = 5.0, value_parser = super::range::positive)]
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
            let from = lane_place(a.from_lane.as_deref(), false)?.unwrap_or_else(|| place(a.from, a.from_tag));
            let to = lane_place(a.to_lane.as_deref(), true)?.unwrap_or_else(|| place(a.to, a.to_tag));
            if a.lane_changes {
                let opts = LaneChangeOptions {
                    points_per_meter: a.points_per_meter,
                    change_penalty_m: a.lane_change_penalty,
                    ..LaneChangeOptions::default()
                };
                let route = map.route_with_lane_changes(&from, &to, &opts)?;
                let first = |p: &Place| map.place_nodes(p).ok().and_then(|n| n.first().copied()).unwrap_or_default();
                let routed = Routed { path: route.path, from_node: first(&from), to_node: first(&to), note: None };
                return print_path_with_changes(&routed, Some(&route.lane_changes), a.json);
            }
            let routed =
                match map.route_places_routed(&from, &to, &RouteOptions { points_per_meter: a.points_per_meter }) {
                    Err(MapError::NoRoute { .. }) => {
                        return Err(no_route_in_lane(&map, &from, &to, a.points_per_meter));
                    }
                    r => r?,
                };
            print_path(&routed, a.json)
        }
        MapCommand::Loop(a) => {
            let map = load(&a.map)?;
            let at = place(a.node, a.tag);
            let routed = map.closed_loop_routed(&at, &RouteOptions { points_per_meter: a.points_per_meter })?;
            print_path(&routed, a.json)
        }
        MapCommand::Generate(a) => map_generate::main(a),
        MapCommand::Render(a) => map_render::main(a),
        MapCommand::Convert(a) => convert(&a),
    }
}

/// `map convert`: refuses to write over its input and to convert what is not OpenDRIVE; writes
/// beside the target and renames, so a failure leaves no truncated map.
fn convert(a: &ConvertArgs) -> anyhow::Result<()> {
    use smlworld::files::AtomicFile;
    let same = a.out == a.map
        || matches!((std::fs::canonicalize(&a.map), std::fs::canonicalize(&a.out)), (Ok(x), Ok(y)) if x == y);
    if same {
        anyhow::bail!("--out {} is the input file; refusing to overwrite it (name another file)", a.out.display());
    }
    let text = std::fs::read_to_string(&a.map).with_context(|| format!("cannot read {}", a.map.display()))?;
    if !smlworld::map::opendrive::is_opendrive(&text) {
        anyhow::bail!(
            "{} is not an OpenDRIVE file (no <OpenDRIVE> root element); `map convert` reads .xodr only",
            a.map.display()
        );
    }
    let map = load(&a.map)?;
    let partial = AtomicFile::new(&a.out).with_context(|| format!("cannot write {}", a.out.display()))?;
    let file =
        std::fs::File::create(partial.path()).with_context(|| format!("cannot create {}", partial.path().display()))?;
    let stats = smlworld::map::opendrive::osm_out::write_osm(&map, file)
        .with_context(|| format!("writing {}", a.out.display()))?;
    partial.commit().with_context(|| format!("cannot move the new map to {}", a.out.display()))?;
    if stats.unmerged_links > 0 {
        tracing::warn!(
            "{} lane link(s) join bounds more than {} m apart; they are not joined in the OSM map",
            stats.unmerged_links,
            smlworld::map::opendrive::osm_out::MERGE_DISTANCE
        );
    }
    println!("wrote {}: {} nodes, {} ways, {} lanelets", a.out.display(), stats.nodes, stats.ways, stats.lanelets);
    Ok(())
}

/// The error of a route that does not exist in lane: when one with lane changes does, say so
/// and name the flag that finds it.
fn no_route_in_lane(map: &LaneletMap, from: &Place, to: &Place, points_per_meter: f64) -> anyhow::Error {
    let in_lane = MapError::NoRoute { from: from.to_string(), to: to.to_string() };
    let opts = LaneChangeOptions { points_per_meter, ..LaneChangeOptions::default() };
    match map.route_with_lane_changes(from, to, &opts) {
        Ok(route) => anyhow::anyhow!(
            "no route from {from} to {to}: no route in lane; try --lane-changes (a route with {} lane change{} exists)",
            route.lane_changes.len(),
            if route.lane_changes.len() == 1 { "" } else { "s" }
        ),
        Err(_) => in_lane.into(),
    }
}

fn load(path: &std::path::Path) -> anyhow::Result<LaneletMap> {
    let map = LaneletMap::load(path)?;
    for w in &map.warnings {
        tracing::warn!("{w}");
    }
    Ok(map)
}

/// An OpenDRIVE lane given as `ROAD:LANE` or `ROAD:SECTION:LANE`: the tag at its start (or end).
fn lane_place(spec: Option<&str>, end: bool) -> anyhow::Result<Option<Place>> {
    Ok(match spec {
        Some(s) => Some(Place::Tag(smlworld::map::opendrive::lane_spec_tag(s, end)?)),
        None => None,
    })
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
    /// Junctions: links (lanelets), conflicts and control ([`smlworld::map::junctions`]).
    junctions: Vec<JunctionInfo>,
    warnings: Vec<String>,
    /// CommonRoad files only: dynamic obstacles (every recorded state), static and environment
    /// obstacles, and planning problems.
    #[serde(skip_serializing_if = "Option::is_none")]
    commonroad: Option<serde_json::Value>,
}

#[derive(Serialize)]
struct ConflictInfo {
    a: i64,
    b: i64,
    kind: smlworld::map::junctions::ConflictKind,
    s_a: f64,
    s_b: f64,
    yields: smlworld::map::junctions::Yield,
}

#[derive(Serialize)]
struct JunctionInfo {
    id: u32,
    lanelets: Vec<i64>,
    conflicts: Vec<ConflictInfo>,
    control: &'static str,
    centre: [f64; 2],
}

/// A length rounded to the millimetre (what the map's geometry is good for).
fn mm(x: f64) -> f64 {
    (x * 1000.0).round() / 1000.0
}

fn junction_info(j: &smlworld::map::Junction) -> JunctionInfo {
    JunctionInfo {
        id: j.id,
        lanelets: j.links.iter().map(|l| l.lanelet.0).collect(),
        conflicts: j
            .conflicts
            .iter()
            .map(|c| ConflictInfo {
                a: c.a.0,
                b: c.b.0,
                kind: c.kind,
                s_a: mm(c.s_a),
                s_b: mm(c.s_b),
                yields: c.yields,
            })
            .collect(),
        control: j.control.name(),
        centre: [mm(j.centre.x), mm(j.centre.y)],
    }
}

fn state_json(s: &CommonRoadState) -> serde_json::Value {
    serde_json::json!({
        "time_step": s.time_step, "x": s.position.x, "y": s.position.y,
        "orientation": s.orientation, "velocity": s.velocity,
    })
}

/// The scenario part of a CommonRoad file as JSON (what `map info --json` adds for such files).
fn commonroad_json(sc: &CommonRoadScenario) -> serde_json::Value {
    let obstacles: Vec<_> = sc
        .obstacles
        .iter()
        .map(|o| {
            serde_json::json!({
                "id": o.id, "type": o.kind, "length": o.length, "width": o.width,
                "states": o.states.iter().map(state_json).collect::<Vec<_>>(),
            })
        })
        .collect();
    let statics: Vec<_> = sc
        .static_obstacles
        .iter()
        .map(|o| {
            serde_json::json!({
                "id": o.id, "type": o.kind, "x": o.position.x, "y": o.position.y,
                "orientation": o.orientation, "length": o.length, "width": o.width, "shapes": o.outlines.len(),
            })
        })
        .collect();
    let environment: Vec<_> = sc
        .environment_obstacles
        .iter()
        .map(|o| serde_json::json!({"id": o.id, "type": o.kind, "shapes": o.outlines.len()}))
        .collect();
    let problems: Vec<_> = sc
        .planning_problems
        .iter()
        .map(|p| {
            let goals: Vec<_> = p
                .goals
                .iter()
                .map(|g| serde_json::json!({"time_start": g.time_start, "time_end": g.time_end, "shapes": g.shapes.len()}))
                .collect();
            serde_json::json!({"id": p.id, "initial_state": state_json(&p.initial_state), "goals": goals})
        })
        .collect();
    serde_json::json!({
        "version": sc.version, "time_step_size": sc.time_step_size,
        "obstacles": obstacles, "planning_problems": problems,
        "static_obstacles": statics, "environment_obstacles": environment,
    })
}

fn info(a: InfoArgs) -> anyhow::Result<()> {
    let text =
        std::fs::read_to_string(&a.map).with_context(|| format!("{}: cannot read the map file", a.map.display()))?;
    let (map, commonroad) = if is_commonroad(&text) {
        let sc = CommonRoadScenario::parse_str(&text, &a.map)?;
        let json = commonroad_json(&sc);
        (sc.map, Some(json))
    } else {
        (LaneletMap::parse_str(&text, &a.map)?, None)
    };
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
        junctions: map.junctions().list.iter().map(junction_info).collect(),
        warnings: map.warnings.iter().map(ToString::to_string).collect(),
        commonroad,
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
    if info.commonroad.is_some() {
        println!("origin     (0, 0) of the file: CommonRoad is in Cartesian metres, no projection");
    } else {
        println!("origin     {:.8} N {:.8} E, {origin}, UTM zone {}", info.origin.lat, info.origin.lon, info.utm_zone);
    }
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
    if !info.junctions.is_empty() {
        println!("junctions  id: control, links (lanelets; one signal character each, in this order), conflicts");
        for j in &info.junctions {
            let crossing =
                j.conflicts.iter().filter(|c| c.kind == smlworld::map::junctions::ConflictKind::Crossing).count();
            println!(
                "  {:>4}: {}, {} links {:?}, {} conflicts ({} crossing, {} merging), centre ({:.1}, {:.1})",
                j.id,
                j.control,
                j.lanelets.len(),
                j.lanelets,
                j.conflicts.len(),
                crossing,
                j.conflicts.len() - crossing,
                j.centre[0],
                j.centre[1]
            );
        }
    }
    if let Some(cr) = &info.commonroad {
        let n = |k: &str| cr[k].as_array().map_or(0, Vec::len);
        println!(
            "commonroad version {}, time step {} s, {} dynamic obstacles, {} static obstacles, {} environment \
             obstacles, {} planning problems",
            cr["version"],
            cr["time_step_size"],
            n("obstacles"),
            n("static_obstacles"),
            n("environment_obstacles"),
            n("planning_problems")
        );
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
struct PathJson<'a> {
    lanelets: Vec<i64>,
    length_m: f64,
    /// Node the path starts at (a tag may name several; this is the one used).
    from_node: i64,
    /// Node the path ends at.
    to_node: i64,
    /// Present when a node was matched on a lanelet's left bound (no right bound holds it).
    #[serde(skip_serializing_if = "Option::is_none")]
    note: Option<&'a str>,
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

fn print_path(routed: &Routed, json: bool) -> anyhow::Result<()> {
    print_path_with_changes(routed, None, json)
}

fn print_path_with_changes(routed: &Routed, changes: Option<&[LaneChange]>, json: bool) -> anyhow::Result<()> {
    let path = &routed.path;
    let out = PathJson {
        lanelets: path.lanelets.iter().map(|l| l.0).collect(),
        length_m: rounded(path.length, LENGTH_DECIMALS),
        from_node: routed.from_node,
        to_node: routed.to_node,
        note: routed.note.as_deref(),
        // Millimetres, as the trajectory CSV: 17 digits of float noise made 2,500 points unreadable.
        points: path.points.iter().map(|p| [rounded(p.x, LENGTH_DECIMALS), rounded(p.y, LENGTH_DECIMALS)]).collect(),
        lane_changes: changes.map(|c| {
            c.iter()
                .map(|c| LaneChangeJson { from: c.from.0, to: c.to.0, at_m: rounded(c.at_m, LENGTH_DECIMALS) })
                .collect()
        }),
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
        println!(
            "from node {} ({:.2}, {:.2}) to node {} ({:.2}, {:.2}) [m]",
            out.from_node, a.x, a.y, out.to_node, b.x, b.y
        );
    }
    if let Some(note) = out.note {
        println!("note: {note}");
    }
    Ok(())
}

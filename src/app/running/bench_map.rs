//! Map benchmarks of `smlworld bench` (issue 25 item 3): routing between random node pairs
//! (`--routing MAP --routes N`, routes per second) and loading a map (`--map-load MAP`, MB/s of
//! XML). The pairs come from the counter-based random stream of `--seed`, so two runs with the
//! same seed route the same pairs.

use std::path::{Path as FsPath, PathBuf};
use std::time::Instant;

use crate::map::{LaneletMap, MapError, Place, RouteOptions, RouteSearch};
use crate::world::random::uniform;

/// Stream of the routing benchmark's pair draws.
const PAIR_STREAM: u64 = 0x526f_7574;

/// What `bench --routing` measured.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct RoutingReport {
    /// The map file.
    pub map: PathBuf,
    /// Lanelets of the map.
    pub lanelets: usize,
    /// Nodes the pairs were drawn from (on a drivable lanelet's right bound).
    pub candidate_nodes: usize,
    /// Seed of the pairs.
    pub seed: u64,
    /// Routes asked for.
    pub routes: usize,
    /// Routes found (the others have no route: `no_route`).
    pub found: usize,
    /// Pairs without a route between them (one-way streets, disconnected parts).
    pub no_route: usize,
    /// Mean points of a found route's path.
    pub mean_points: f64,
    /// Wall time of all the routes \[s\] (the map loaded before).
    pub seconds: f64,
    /// Routes (found or not) per second of wall time.
    pub routes_per_second: f64,
    /// Seconds to load the map (not in `seconds`).
    pub load_seconds: f64,
}

/// What `bench --map-load` measured.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct MapLoadReport {
    /// The map file.
    pub map: PathBuf,
    /// Its size \[bytes\].
    pub bytes: u64,
    /// Lanelets loaded.
    pub lanelets: usize,
    /// Loads timed.
    pub runs: usize,
    /// Wall time of each load \[s\], in order.
    pub seconds: Vec<f64>,
    /// Megabytes (10⁶ bytes) of XML per second of the median load.
    pub mb_per_second: f64,
}

/// Route `routes` random node pairs of the map at `path` (pairs from `seed`) with A*.
pub fn bench_routing(path: &FsPath, routes: usize, seed: u64) -> Result<RoutingReport, MapError> {
    let started = Instant::now();
    let map = LaneletMap::load(path)?;
    let load_seconds = started.elapsed().as_secs_f64();
    let nodes = map.routable_nodes();
    if nodes.len() < 2 {
        return Err(MapError::InvalidOption(format!(
            "--routing {}: fewer than two nodes on a drivable lanelet's right bound to route between; give a map with lanelets",
            path.display()
        )));
    }
    let pick = |k: usize, draw: u64| {
        let u = uniform(seed, PAIR_STREAM, k as u64, draw);
        nodes[((u * nodes.len() as f64) as usize).min(nodes.len() - 1)]
    };
    let pairs: Vec<(i64, i64)> = (0..routes).map(|k| (pick(k, 0), pick(k, 1))).collect();
    let opts = RouteOptions::default();
    let (mut found, mut points) = (0usize, 0usize);
    let started = Instant::now();
    for &(from, to) in &pairs {
        match map.route_places_with(&Place::Node(from), &Place::Node(to), &opts, RouteSearch::AStar) {
            Ok(path) => {
                found += 1;
                points += path.points.len();
            }
            Err(MapError::NoRoute { .. }) => {}
            Err(e) => return Err(e),
        }
    }
    let seconds = started.elapsed().as_secs_f64();
    Ok(RoutingReport {
        map: path.to_path_buf(),
        lanelets: map.lanelets.len(),
        candidate_nodes: nodes.len(),
        seed,
        routes,
        found,
        no_route: routes - found,
        mean_points: if found > 0 { points as f64 / found as f64 } else { 0.0 },
        seconds,
        routes_per_second: if seconds > 0.0 { routes as f64 / seconds } else { f64::INFINITY },
        load_seconds,
    })
}

/// Load the map at `path` `runs` times (at least 1) and report the median rate.
pub fn bench_map_load(path: &FsPath, runs: usize) -> Result<MapLoadReport, MapError> {
    let bytes = std::fs::metadata(path).map_err(|source| MapError::Io { path: path.to_path_buf(), source })?.len();
    let mut seconds = Vec::new();
    let mut lanelets = 0;
    for _ in 0..runs.max(1) {
        let started = Instant::now();
        let map = LaneletMap::load(path)?;
        seconds.push(started.elapsed().as_secs_f64());
        lanelets = map.lanelets.len();
    }
    let median = upper_median(&seconds);
    Ok(MapLoadReport {
        map: path.to_path_buf(),
        bytes,
        lanelets,
        runs: seconds.len(),
        seconds,
        mb_per_second: if median > 0.0 { bytes as f64 / 1e6 / median } else { f64::INFINITY },
    })
}

/// The median of `xs` (the upper one of an even count; 0 when empty), the order left as it is.
pub fn upper_median(xs: &[f64]) -> f64 {
    let mut sorted = xs.to_vec();
    sorted.sort_by(f64::total_cmp);
    sorted.get(sorted.len() / 2).copied().unwrap_or(0.0)
}

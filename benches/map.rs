//! Map benchmarks on a generated grid city of at least 20 MB: generating it (MB/s), loading it
//! (MB/s) and routing between far-apart junctions (routes/s, A* and the Dijkstra reference).
//!
//! Run: `cargo bench --bench map -- --warm-up-time 1 --measurement-time 5`.

use std::hint::black_box;
use std::path::PathBuf;

use criterion::{Criterion, SamplingMode, Throughput, criterion_group, criterion_main};
use smlworld::map::generate::{Arm, GridParams, grid_junction_tag, write_grid_city};
use smlworld::map::{LaneletMap, Place, RouteOptions, RouteSearch};

/// Blocks per side of the benchmark grid: about 35 MB and 16 000 lanelets.
const BLOCKS: usize = 32;
/// The loading benchmark must read at least this much XML [bytes] (issue 2).
const MIN_BYTES: u64 = 20_000_000;

fn params() -> GridParams {
    GridParams { rows: BLOCKS, cols: BLOCKS, ..GridParams::default() }
}

/// Writes the benchmark grid into a temporary file and returns its path and size [bytes].
fn grid_file() -> (PathBuf, u64) {
    let path = std::env::temp_dir().join(format!("smlworld-bench-grid-{}.osm", std::process::id()));
    let file = std::fs::File::create(&path).expect("temporary directory is writable");
    let stats = write_grid_city(&params(), file).expect("benchmark grid parameters are valid");
    assert!(stats.bytes >= MIN_BYTES, "benchmark grid is only {} bytes; raise BLOCKS", stats.bytes);
    (path, stats.bytes)
}

fn bench_map(c: &mut Criterion) {
    let (path, bytes) = grid_file();

    let mut group = c.benchmark_group("map");
    group.sample_size(10).sampling_mode(SamplingMode::Flat).throughput(Throughput::Bytes(bytes));
    group.bench_function(format!("generate_grid_{BLOCKS}x{BLOCKS}"), |b| {
        b.iter(|| write_grid_city(black_box(&params()), std::io::sink()).expect("valid parameters"))
    });
    group.bench_function(format!("load_grid_{BLOCKS}x{BLOCKS}"), |b| {
        b.iter(|| LaneletMap::load(black_box(&path)).expect("generated grid loads"))
    });
    group.finish();

    let map = LaneletMap::load(&path).expect("generated grid loads");
    let _ = std::fs::remove_file(&path);
    // Corner to opposite corner, both diagonals and both ways: the longest routes in the grid.
    let n = BLOCKS;
    let tag_node = |r, c, arm| {
        let tag = grid_junction_tag(r, c, arm);
        map.tag_index.get(&tag).and_then(|ids| ids.first().copied()).unwrap_or_else(|| panic!("tag {tag} missing"))
    };
    let pairs = [
        (tag_node(0, 0, Arm::East), tag_node(n, n, Arm::West)),
        (tag_node(n, n, Arm::South), tag_node(0, 0, Arm::North)),
        (tag_node(0, n, Arm::North), tag_node(n, 0, Arm::South)),
        (tag_node(n, 0, Arm::East), tag_node(0, n, Arm::West)),
    ];
    let opts = RouteOptions::default();
    let mut group = c.benchmark_group("map");
    group.throughput(Throughput::Elements(pairs.len() as u64));
    for (name, search) in [("route_corners", RouteSearch::AStar), ("route_corners_dijkstra", RouteSearch::Dijkstra)] {
        group.bench_function(format!("{name}_grid_{BLOCKS}x{BLOCKS}"), |b| {
            b.iter(|| {
                for &(from, to) in &pairs {
                    let (from, to) = (Place::Node(from), Place::Node(to));
                    let route = map.route_places_with(&from, &to, &opts, search);
                    black_box(route.expect("corners of a grid are connected"));
                }
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench_map);
criterion_main!(benches);

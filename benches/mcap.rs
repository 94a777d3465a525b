//! What recording a run as MCAP costs (issue 57: at most 25 % more wall time at 1,000 vehicles
//! logged at 10 Hz): the benchmark world (every module on) with the trajectory log at 10 Hz
//! alone, and with the Foxglove recorder beside it writing every channel (`/vehicles`, `/tf`,
//! `/vehicle/<id>/state`, `/gps/<id>`, ...) into a zstd MCAP file, for the world's vehicles
//! following their paths and for them driving the IDM with MOBIL lane changes. Each iteration
//! runs 1 s of sim time (10 log ticks). After the timings it records 6 s (100 vehicle-minutes) into a fresh
//! file and prints its size per vehicle-minute.
//! Run: `cargo bench --bench mcap`.

use criterion::{Criterion, criterion_group, criterion_main};
use smlworld::app::results::foxglove::{FoxgloveOutput, FoxgloveRecordPlugin, FoxgloveRecorder};
use smlworld::app::running::bench::BenchWorld;
use smlworld::app::{TrajectoryLog, TrajectoryLogPlugin};
use smlworld::prelude::*;

const VEHICLES: usize = 1000;
const LOG_RATE: f64 = 10.0;

/// The bench world (path following, or with `lane_change` the IDM and MOBIL lane changes) with
/// the CSV log at 10 Hz (into nothing) and, with `mcap`, the recorder.
fn sim(lane_change: bool, mcap: Option<&std::path::Path>) -> Sim {
    let world = BenchWorld { vehicles: VEHICLES, lane_change, ..Default::default() };
    let mut b = world.builder().expect("the bench world builds");
    b.insert_resource(TrajectoryLog::new(Box::new(std::io::sink())));
    b.add_plugin(TrajectoryLogPlugin { rate: LOG_RATE });
    if let Some(path) = mcap {
        let (map, _) = world.map_and_lanes().expect("the bench map builds");
        let output = FoxgloveOutput { mcap: Some(path.to_path_buf()), ..FoxgloveOutput::default() };
        b.insert_resource(FoxgloveRecorder::open(&output, Some(path), Some(map.clone())).expect("the file opens"));
        b.add_plugin(FoxgloveRecordPlugin { images: None, map: Some(map) });
    }
    let mut s = b.build();
    s.run_for(1.0); // warm the buffers (and create the per-vehicle channels)
    s
}

fn bench_mcap(c: &mut Criterion) {
    let dir = std::env::temp_dir().join(format!("smlworld-bench-mcap-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("a temporary folder");
    let mut group = c.benchmark_group("record_1000_vehicles_10hz_1s");
    group.sample_size(10);
    for (name, lane_change) in [("path_following", false), ("idm_lane_changes", true)] {
        let mut plain = sim(lane_change, None);
        group.bench_function(format!("{name}/csv_only"), |b| b.iter(|| plain.run_for(1.0)));
        drop(plain);
        let mut recorded = sim(lane_change, Some(&dir.join(format!("{name}.mcap"))));
        group.bench_function(format!("{name}/csv_and_mcap"), |b| b.iter(|| recorded.run_for(1.0)));
        drop(recorded);
    }
    group.finish();

    // File size per vehicle-minute: 6 s of 1,000 vehicles.
    let path = dir.join("size.mcap");
    let mut s = sim(false, Some(&path));
    s.run_for(5.0); // 6 s in all with the warm-up second
    let rec = s.world_mut().remove_resource::<FoxgloveRecorder>().expect("the recorder");
    rec.finish(None, s.now().0).expect("the file closes");
    let bytes = std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0);
    let vehicle_minutes = VEHICLES as f64 * s.now().as_secs() / 60.0;
    eprintln!(
        "mcap size: {bytes} bytes for {vehicle_minutes:.0} vehicle-minutes at {LOG_RATE} Hz = {:.1} kB per vehicle-minute",
        bytes as f64 / vehicle_minutes / 1000.0
    );
    let _ = std::fs::remove_dir_all(&dir);
}

criterion_group!(benches, bench_mcap);
criterion_main!(benches);

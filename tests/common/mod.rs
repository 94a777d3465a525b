//! Helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::PathBuf;

/// `../shared/data` beside the project (as CI lays it out), else `/work/shared/data`.
/// Panics with a clear message when neither exists: a test that needs the real maps must fail,
/// not pass silently.
pub fn shared_data() -> PathBuf {
    let beside = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/data"));
    if beside.is_dir() {
        return beside;
    }
    let fallback = PathBuf::from("/work/shared/data");
    if fallback.is_dir() {
        return fallback;
    }
    panic!(
        "the real test maps are missing: expected ../shared/data beside the project ({}); \
         clone the project next to the `shared` folder",
        beside.display()
    );
}

/// A file of the shared data, e.g. `sml2015/HighwaySML.xml`.
pub fn shared(rel: &str) -> PathBuf {
    let p = shared_data().join(rel);
    assert!(p.is_file(), "missing test map {}", p.display());
    p
}

/// xorshift64*: a small deterministic generator for garbage input in the fuzz-style tests.
pub struct Rng(pub u64);

impl Rng {
    /// The next 64 random bits.
    pub fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }

    /// A number in `0..n`.
    pub fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }
}

/// What [`red_entries`] saw.
#[derive(Debug, Clone, Default)]
pub struct RedCheck {
    /// Vehicles that moved onto a junction link from a lanelet that is none.
    pub entries: usize,
    /// Of them, those whose link showed red then.
    pub on_red: usize,
    /// Steps in which some link showed red.
    pub red_steps: usize,
    /// The first few entries on red (time, vehicle, lanelets), for the failure message.
    pub first_reds: Vec<String>,
}

/// The simulated time now.
fn world_now(sim: &smlworld::sim::Sim) -> smlworld::prelude::SimTime {
    sim.world().resource::<smlworld::sim::SimClock>().now
}

/// Runs `sim` until `end` \[s\]; each step, every vehicle that moved from a lanelet that is no
/// junction link onto a junction link must see that link's signal not red. Counted from the
/// vehicles' lanelets and the lights' states, not from the junction plugin's own figures.
pub fn red_entries(sim: &mut smlworld::sim::Sim, end: f64) -> RedCheck {
    use smlworld::prelude::*;
    use smlworld::vehicles::right_of_way::{JunctionNetwork, TrafficLights};
    let end = SimTime::from_secs(end);
    let mut last: std::collections::BTreeMap<i32, Option<smlworld::map::LaneletId>> = Default::default();
    let mut out = RedCheck::default();
    while sim.scheduler().peek().is_some_and(|(_, due, _, _)| due < end) {
        sim.step();
        let now = world_now(sim);
        let world = sim.world_mut();
        let network = world.resource::<JunctionNetwork>().clone();
        let lights = world.resource::<TrafficLights>().clone();
        out.red_steps += lights.state.iter().filter(|c| **c == b'r').count().min(1);
        let mut q = world.query::<(&VehicleId, &smlworld::vehicles::LanePosition)>();
        for (id, pos) in q.iter(world) {
            let before = last.insert(id.0, pos.lanelet).flatten();
            let link = |l: Option<smlworld::map::LaneletId>| {
                l.and_then(|l| network.map.lanelet_index(l))
                    .map(|i| network.link_of_lanelet[i])
                    .filter(|g| *g != u32::MAX)
            };
            if let (Some(g), None) = (link(pos.lanelet), link(before))
                && before.is_some()
            {
                out.entries += 1;
                if lights.state[g as usize] == b'r' {
                    out.on_red += 1;
                    if out.first_reds.len() < 5 {
                        out.first_reds.push(format!(
                            "t = {:.2} s: vehicle {} from lanelet {:?} onto {:?}",
                            now.as_secs(),
                            id.0,
                            before.map(|l| l.0),
                            pos.lanelet.map(|l| l.0)
                        ));
                    }
                }
            }
        }
    }
    out
}

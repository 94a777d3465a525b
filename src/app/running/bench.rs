//! The benchmark world: N vehicles on a generated three-lane ring highway
//! ([`crate::map::generate::ring_highway`]) whose radius grows with N so the spacing stays at
//! highway gaps, with every module on (dynamics, radar + velodyne, wifi and network with one
//! beacon per vehicle per round, path following). Used by `smlworld bench` and the criterion benches.
//! `degraded` (`smlworld bench --degraded`) puts [`DEGRADED_WIFI`] and [`DEGRADED_NETWORK`] on
//! the V2V channels and [`degraded_radar`] on every vehicle's radar (issue 21 item 7), to
//! measure what per-reception and per-detection randomness costs.

use std::sync::Arc;

use bevy_ecs::prelude::{Query, Res};
use bevy_ecs::schedule::{IntoScheduleConfigs, ScheduleLabel};

use crate::map::generate::{GenerateError, RingParams, ring_highway, ring_lane_tag};
use crate::map::{LaneletMap, MapError, Path, RouteOptions};
use crate::sim::sensor_plugins::attach_sensor;
use crate::sim::v2v::channel::{ChannelModel, Loss};
use crate::sim::{
    ChannelStats, Control, Dynamics, Parallelism, Rates, SensorStats, SimClock, SimSeed, SimSystems, V2vChannelStats,
    V2vConfig,
};
use crate::vehicles::{
    FollowLaw, Idm, IdmController, IdmPlugin, LaneChangeLog, LaneChangeParams, LaneChangePlugin, LaneChanger,
    LanePosition, LanesPlugin, RouteGoal,
};
use crate::vehicles::{PathFollower, PathFollowing, PathFollowingPlugin};
use crate::world::{
    Channel, Mailbox, Radar, SensorError, SensorErrors, SensorSet, SimTime, VehicleId, VehicleSpec, VehicleState,
    Velodyne,
};

use crate::sim::{SimBuilder, default_plugins};

/// Why the benchmark world could not be built (the generated map did not load: a bug).
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    /// The ring highway generator refused the parameters.
    #[error("generating the benchmark ring highway: {0}")]
    Generate(#[from] GenerateError),
    /// The generated map did not load or had no loop through a lane's tagged node.
    #[error("loading the generated benchmark ring highway: {0}")]
    Map(#[from] MapError),
}

/// Shape of the benchmark world.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BenchWorld {
    /// Number of vehicles.
    pub vehicles: usize,
    /// Gap between consecutive vehicles of a lane \[m\] (2 s at 20 m/s).
    pub spacing: f64,
    /// Cruise speed [m/s].
    pub speed: f64,
    /// Smallest radius of the ring's inner edge \[m\]; the ring grows beyond it to give every
    /// vehicle `spacing` metres of lane.
    pub ring_radius: f64,
    /// Lanes of the ring.
    pub lanes: usize,
    /// Lane width \[m\].
    pub lane_width: f64,
    /// Centre-line resolution [points per metre].
    pub points_per_meter: f64,
    /// Largest distance between the generated map's boundary and a true circle \[m\]: sets the
    /// map's node spacing (coarser for bigger rings, so the map stays small).
    pub chord_error: f64,
    /// Every vehicle drives the IDM (desired speeds spread ±20 % around `speed`) and changes
    /// lanes (MOBIL, the lane-change plugin's defaults), instead of plain path following.
    pub lane_change: bool,
    /// Loss, delay and jitter on wifi ([`DEGRADED_WIFI`]), loss on the network
    /// ([`DEGRADED_NETWORK`]), noise and dropout on every radar ([`degraded_radar`]), seed 1.
    pub degraded: bool,
    /// Share of the vehicles (spread evenly along the road) that also carry the student camera
    /// of `examples/student_sensor.rs` (90°, 80 m, occlusion), a plugin sensor [0, 1].
    pub plugin_sensor_share: f64,
}

/// The student camera of `examples/student_sensor.rs`, compiled in for
/// [`BenchWorld::plugin_sensor_share`]: the benchmark measures the example itself.
#[allow(dead_code)] // its main() is the example's own entry point
#[path = "../../../examples/student_sensor.rs"]
mod student_sensor;

/// The wifi of a degraded benchmark: 10 % loss, 10 ms delay, 5 ms jitter (issue 21's example).
pub const DEGRADED_WIFI: ChannelModel =
    ChannelModel { loss: Loss::Constant(0.1), burst: None, delay_ms: 10.0, jitter_ms: 5.0 };

/// The network of a degraded benchmark: 10 % loss, no delay. Every vehicle's beacon goes to
/// every vehicle, so a delay would hold one pending reception per (sender, receiver): N² per
/// round (10⁸ at 10,000 vehicles), which the shared-batch delivery of a perfect round avoids.
pub const DEGRADED_NETWORK: ChannelModel =
    ChannelModel { loss: Loss::Constant(0.1), burst: None, delay_ms: 0.0, jitter_ms: 0.0 };

/// The radar errors of a degraded benchmark: issue 21's example noise (0.2 m, 0.5°, 0.1 m/s)
/// and 2 % dropout; no occlusion.
pub fn degraded_radar() -> SensorErrors {
    let radar =
        SensorError { range_sd: 0.2, bearing_sd: 0.5f64.to_radians(), speed_sd: 0.1, dropout: 0.02, occlusion: false };
    SensorErrors { radar, ..Default::default() }
}

impl Default for BenchWorld {
    fn default() -> Self {
        BenchWorld {
            vehicles: 1000,
            spacing: 40.0,
            speed: 20.0,
            ring_radius: 500.0,
            lanes: 3,
            lane_width: 3.5,
            points_per_meter: 0.5,
            chord_error: 0.1,
            lane_change: false,
            degraded: false,
            plugin_sensor_share: 0.0,
        }
    }
}

/// Schedule of the benchmark's beacons (one network message per vehicle per network round).
#[derive(ScheduleLabel, Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Beacons;

/// Queue one small network message (the vehicle's speed [m/s]) per vehicle.
pub fn send_beacons(
    clock: Res<SimClock>,
    parallelism: Option<Res<Parallelism>>,
    mut vehicles: Query<(&VehicleState, &mut Mailbox)>,
) {
    send_speeds(Channel::Network, clock.now, parallelism.map_or(Parallelism::single(), |p| *p), &mut vehicles);
}

/// Queue every vehicle's speed [m/s] on `channel`, the vehicles split over the threads (each
/// writes only its own out-box: the same out-boxes on any thread count).
fn send_speeds(
    channel: Channel,
    now: SimTime,
    parallelism: Parallelism,
    vehicles: &mut Query<(&VehicleState, &mut Mailbox)>,
) {
    let send = |states: &[VehicleState], boxes: &mut [Mailbox]| {
        for (state, mailbox) in states.iter().zip(boxes) {
            mailbox.send_copy(channel, now, state.speed());
        }
    };
    if let Ok(tables) = vehicles.contiguous_iter_mut() {
        for (states, mut boxes) in tables {
            parallelism
                .for_each_chunk_at(&mut boxes, &mut Vec::<()>::new(), |start, chunk, _| send(&states[start..], chunk));
        }
    } else {
        // Only if a component were stored sparsely (none is): one at a time.
        for (state, mut mailbox) in vehicles.iter_mut() {
            send(std::slice::from_ref(state), std::slice::from_mut(&mut *mailbox));
        }
    }
}

/// Run condition: true at the ticks that are multiples of `1 / rate` [Hz] (from t = 0).
fn at_rate(rate: f64) -> impl FnMut(Res<SimClock>) -> bool + Clone {
    let period = SimTime::from_secs(1.0 / rate).0.max(1);
    move |clock: Res<SimClock>| clock.now.0.is_multiple_of(period)
}

/// Queue one small wifi message (the vehicle's speed [m/s]) per vehicle: the cooperative
/// awareness beacon every CACC vehicle sends each wifi round, so the wifi fan-out (and, when
/// degraded, its per-reception loss and delay) is inside the benchmark's figures.
pub fn send_wifi_beacons(
    clock: Res<SimClock>,
    parallelism: Option<Res<Parallelism>>,
    mut vehicles: Query<(&VehicleState, &mut Mailbox)>,
) {
    send_speeds(Channel::Wifi, clock.now, parallelism.map_or(Parallelism::single(), |p| *p), &mut vehicles);
}

impl BenchWorld {
    /// The generated ring: inner edge radius \[m\] large enough for every vehicle to have about
    /// `spacing` metres of lane, and the node spacing \[m\] that keeps the chord error.
    pub fn ring(&self) -> RingParams {
        let lanes = self.lanes.max(1);
        let per_lane = self.vehicles.div_ceil(lanes) as f64;
        let radius = (per_lane * self.spacing / std::f64::consts::TAU).max(self.ring_radius);
        let outer = radius + lanes as f64 * self.lane_width;
        // A chord of length c on a circle of radius R strays c² / (8 R) from it.
        let node_spacing = (8.0 * outer * self.chord_error).sqrt().max(1.0);
        RingParams { lanes, radius, lane_width: self.lane_width, clockwise: false, node_spacing }
    }

    /// The closed loops of the generated ring's lanes, rightmost first.
    pub fn lanes(&self) -> Result<Vec<Arc<Path>>, BenchError> {
        Ok(self.map_and_lanes()?.1)
    }

    /// The generated ring's map and the closed loops of its lanes, rightmost first.
    pub fn map_and_lanes(&self) -> Result<(Arc<LaneletMap>, Vec<Arc<Path>>), BenchError> {
        let ring = self.ring();
        let xml = ring_highway(&ring)?;
        let map = LaneletMap::parse_str(&xml, std::path::Path::new("generated bench ring"))?;
        let options = RouteOptions { points_per_meter: self.points_per_meter };
        let lanes = (0..ring.lanes)
            .map(|k| Ok(Arc::new(map.closed_loop_tag(&ring_lane_tag(ring.lanes, k), &options)?)))
            .collect::<Result<_, BenchError>>()?;
        Ok((Arc::new(map), lanes))
    }

    /// A builder with every module on at the default rates and the vehicles spawned.
    pub fn builder(&self) -> Result<SimBuilder, BenchError> {
        self.builder_in(SpawnOrder::Road)
    }

    /// [`BenchWorld::builder`], the vehicles spawned in `order`.
    fn builder_in(&self, order: SpawnOrder) -> Result<SimBuilder, BenchError> {
        let rates = Rates::default();
        let mut b = SimBuilder::with_rates(rates);
        b.add_plugin(default_plugins).add_plugin(PathFollowingPlugin);
        // Beacons go out from the controllers' own schedule at their channel's rate: a module
        // of their own in the control phase would hold the V2V in-boxes until it ran.
        b.add_systems(Control, send_beacons.in_set(SimSystems::Control).run_if(at_rate(rates.network)));
        b.add_systems(Control, send_wifi_beacons.in_set(SimSystems::Control).run_if(at_rate(rates.wifi)));
        if self.plugin_sensor_share > 0.0 {
            b.add_plugin(student_sensor::CameraPlugin);
        }
        if self.degraded {
            let wifi_range = V2vConfig::default().wifi_range;
            b.insert_resource(V2vConfig { wifi_range, wifi: DEGRADED_WIFI.clone(), network: DEGRADED_NETWORK.clone() });
            b.insert_resource(SimSeed(1));
        }
        self.spawn_in(&mut b, order)?;
        Ok(b)
    }

    /// Spawn the vehicles into `b` (ids −1, −2, ...), evenly spread over the lanes and along
    /// each lane, lane after lane.
    pub fn spawn(&self, b: &mut SimBuilder) -> Result<(), BenchError> {
        self.spawn_in(b, SpawnOrder::Road)
    }

    /// [`BenchWorld::spawn`] in `order`.
    fn spawn_in(&self, b: &mut SimBuilder, order: SpawnOrder) -> Result<(), BenchError> {
        let (map, lanes) = self.map_and_lanes()?;
        if self.lane_change {
            b.add_plugin(LanesPlugin { map }).add_plugin(IdmPlugin);
            b.add_plugin(LaneChangePlugin { points_per_meter: self.points_per_meter });
            // No summary is written: count the changes, keep no list that grows with them.
            b.world_mut().resource_mut::<LaneChangeLog>().keep_events = false;
        }
        let params = PathFollowing { speed: self.speed, ..Default::default() };
        let sensors =
            SensorSet { radar: Some(Radar::default()), velodyne: Some(Velodyne::default()), omniscient: false };
        // Lane k gets an equal share, the first lanes one more when N does not divide. They are
        // spawned in road order across the lanes (the j-th of every lane, then the next j):
        // vehicles near each other on the road are near each other in the ECS tables, so the
        // per-vehicle systems read their neighbours from cache. Vehicle j of lane k has id
        // −1 − (j·lanes + k), its rank in road order (so the V2V batches, sorted by sender id,
        // come in sorted already), and the desired speed of number `first[k] + j` counted lane
        // after lane, as before the order changed (the same traffic). Which vehicle is where,
        // its id and its speed do not depend on the order the vehicles are spawned in.
        let count = |k: usize| self.vehicles / lanes.len() + usize::from(k < self.vehicles % lanes.len());
        let first: Vec<usize> = (0..lanes.len()).scan(0, |at, k| Some(std::mem::replace(at, *at + count(k)))).collect();
        let places: Vec<(usize, usize)> = match order {
            SpawnOrder::Road => (0..count(0)).flat_map(|j| (0..lanes.len()).map(move |k| (j, k))).collect(),
            SpawnOrder::Lanes => (0..lanes.len()).flat_map(|k| (0..count(k)).map(move |j| (j, k))).collect(),
        };
        for (j, k) in places {
            let path = &lanes[k];
            {
                let count = count(k);
                if j >= count {
                    continue;
                }
                let (rank, next) = (j * lanes.len() + k, first[k] + j);
                let s = path.length * j as f64 / count as f64;
                let (p, heading) = path.sample(s);
                let mut spec = VehicleSpec::new(VehicleId(-1 - rank as i32), VehicleState::new(p, heading, self.speed));
                spec.sensors = sensors;
                if self.degraded {
                    spec.sensor_errors = degraded_radar();
                }
                spec.route = Some(Arc::clone(path));
                if let Ok(e) = b.spawn_vehicle(spec) {
                    b.world_mut().entity_mut(e).insert(PathFollower::starting_at(params, s));
                    // Every vehicle whose rank crosses a multiple of 1 / share: evenly spread.
                    let share = self.plugin_sensor_share;
                    if share > 0.0 && ((rank + 1) as f64 * share).floor() > (rank as f64 * share).floor() {
                        let camera = student_sensor::Camera {
                            fov_deg: 90.0,
                            range: 80.0,
                            occlusion: true,
                            range_sd: 0.0,
                            dropout: 0.0,
                        };
                        attach_sensor(&mut b.world_mut().entity_mut(e), "camera", camera);
                    }
                    if self.lane_change {
                        // Desired speeds spread by a fixed low-discrepancy sequence, so faster
                        // vehicles catch up and overtake.
                        let spread = (next as f64 * 0.618_033_988_749_895).fract();
                        let idm = Idm { speed: self.speed * (0.8 + 0.4 * spread), ..Idm::default() };
                        let law = FollowLaw::Idm(idm);
                        b.world_mut().entity_mut(e).insert((
                            IdmController { params: idm },
                            LanePosition::default(),
                            LaneChanger::new(LaneChangeParams::default(), law, RouteGoal::Loop),
                        ));
                    }
                }
            }
        }
        Ok(())
    }
}

/// In which order [`BenchWorld::spawn_in`] spawns the same vehicles.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum SpawnOrder {
    /// The j-th vehicle of every lane, then the next j (what the bench does).
    Road,
    /// Lane after lane (what the bench did before; for the test that the order changes nothing).
    #[cfg_attr(not(test), allow(dead_code))]
    Lanes,
}

/// The map a benchmark ran on.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct BenchMap {
    /// What generated it (`ring_highway`).
    pub kind: &'static str,
    /// Lanes, all in one direction.
    pub lanes: usize,
    /// Radius of the ring's inner edge \[m\].
    pub radius_m: f64,
    /// Lane width \[m\].
    pub lane_width_m: f64,
    /// Length of one lane's closed loop (the middle one's centre line) \[m\].
    pub lane_length_m: f64,
}

/// The sensors every benchmark vehicle carries.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct BenchSensors {
    /// Radar range \[m\].
    pub radar_range_m: f64,
    /// Radar full opening angle \[deg\].
    pub radar_angle_deg: f64,
    /// Velodyne range \[m\].
    pub velodyne_range_m: f64,
}

/// Rates of the modules \[Hz\].
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct BenchRates {
    /// Dynamics \[Hz\].
    pub dynamics: f64,
    /// Sensors (radar + velodyne) \[Hz\].
    pub sensors: f64,
    /// Controllers (path following, beacons) \[Hz\].
    pub control: f64,
    /// Wifi rounds \[Hz\].
    pub wifi: f64,
    /// Network rounds \[Hz\].
    pub network: f64,
}

/// Wall time of one module's schedule over the run.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ModuleTime {
    /// Module name (`sensors`, `wifi`, `network`, `control`, `dynamics`).
    pub module: String,
    /// Wall time its schedule ran \[s\].
    pub seconds: f64,
    /// Its share of the run's wall time (0..1); what is left to 1 is the scheduler itself.
    pub share: f64,
}

/// What one benchmark run measured, and on what: printed as JSON by `smlworld bench`.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct BenchReport {
    /// The map.
    pub map: BenchMap,
    /// Number of vehicles.
    pub vehicles: usize,
    /// Whether channels and radars were degraded (`--degraded`: [`DEGRADED_WIFI`],
    /// [`DEGRADED_NETWORK`], [`degraded_radar`] on every radar).
    pub degraded: bool,
    /// Share of the vehicles that carry the student camera (`--plugin-sensor-share`).
    pub plugin_sensor_share: f64,
    /// Sensors of every vehicle.
    pub sensors: BenchSensors,
    /// Module rates \[Hz\].
    pub rates: BenchRates,
    /// Threads the per-vehicle systems were allowed.
    pub threads: usize,
    /// Threads they used at this vehicle count (1 below [`Parallelism::min_vehicles`]).
    pub threads_used: usize,
    /// Sim time run \[s\] (the time reached when interrupted).
    pub sim_seconds: f64,
    /// Whether Ctrl-C or SIGTERM stopped the benchmark early (the figures cover what ran).
    pub interrupted: bool,
    /// Wall time of the run, set-up excluded \[s\].
    pub wall_seconds: f64,
    /// Processor time of the run, all threads together, set-up excluded \[s\] (Linux and other
    /// Unix; `None` elsewhere): on a busy machine a steadier measure than the wall time.
    pub cpu_seconds: Option<f64>,
    /// Vehicle dynamics steps per processor second (all threads together).
    pub vehicle_steps_per_cpu_second: Option<f64>,
    /// Sim seconds per wall second.
    pub real_time_factor: f64,
    /// Vehicle dynamics steps (vehicles x dynamics ticks) per wall second.
    pub vehicle_steps_per_second: f64,
    /// Wall time per vehicle per sim second \[µs\]: flat in N when the cost is linear.
    pub us_per_vehicle_sim_second: f64,
    /// Where the wall time went, module by module, in the order the modules were added.
    pub modules: Vec<ModuleTime>,
    /// Peak resident memory of the process \[MB\] (Linux only).
    pub peak_rss_mb: Option<f64>,
    /// Resident memory on transparent huge pages at the end of the run \[MB\] (Linux
    /// `AnonHugePages`): the heap's, when `smlworld` restarted itself with glibc's malloc on
    /// huge pages (see `SMLWORLD_HUGE_PAGES` in docs/performance.md); 0 without.
    pub huge_pages_mb: Option<f64>,
    /// What the V2V channels carried, counted per receiver (as `summary.json`'s
    /// `metrics.v2v`): the evidence that the wifi fan-out, and a degraded run's loss and delay,
    /// are inside the figures.
    pub v2v: BenchV2v,
    /// What the sensors detected and missed (as `summary.json`'s `metrics.sensors`).
    pub sensor_stats: SensorStats,
    /// Lane changes ended during the run (aborted ones included), with `--lane-change`; `None`
    /// without. The evidence of what a `--lane-change` figure holds: every vehicle weighs MOBIL
    /// every control tick either way, and on the bench's evenly spaced start the first changes
    /// come only after vehicles of different desired speeds have closed up (none in 10 sim s).
    pub lane_changes: Option<u64>,
}

/// One channel's receptions in a benchmark run.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct BenchChannel {
    /// Receptions attempted (message, receiver in range).
    pub sent: u64,
    /// Receptions not lost.
    pub delivered: u64,
    /// Mean delivery delay \[ms\].
    pub delay_ms_mean: f64,
}

impl From<&ChannelStats> for BenchChannel {
    fn from(c: &ChannelStats) -> Self {
        BenchChannel { sent: c.sent, delivered: c.delivered, delay_ms_mean: c.delay_ms_mean() }
    }
}

/// Both channels' receptions in a benchmark run.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct BenchV2v {
    /// The wifi channel (one beacon per vehicle per round).
    pub wifi: BenchChannel,
    /// The network channel (one beacon per vehicle per round).
    pub network: BenchChannel,
}

/// Processor time this process has used so far, user and system, all threads \[s\].
pub fn process_cpu_seconds() -> Option<f64> {
    #[cfg(unix)]
    {
        let mut usage = std::mem::MaybeUninit::<libc::rusage>::zeroed();
        // SAFETY: getrusage writes a whole `rusage` into the pointer it is given, which points to
        // one; RUSAGE_SELF is always valid.
        let ok = unsafe { libc::getrusage(libc::RUSAGE_SELF, usage.as_mut_ptr()) } == 0;
        if !ok {
            return None;
        }
        // SAFETY: getrusage succeeded, so it initialised the struct.
        let usage = unsafe { usage.assume_init() };
        let secs = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
        Some(secs(usage.ru_utime) + secs(usage.ru_stime))
    }
    #[cfg(not(unix))]
    None
}

/// A size this process's `/proc/self/{file}` gives in kB on the line `key:`, in MB (Linux), if
/// known: the memory figures of the bench and the soak.
pub(crate) fn proc_self_mb(file: &str, key: &str) -> Option<f64> {
    let text = std::fs::read_to_string(format!("/proc/self/{file}")).ok()?;
    let line = text.lines().find(|l| l.strip_prefix(key).is_some_and(|rest| rest.starts_with(':')))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

/// Peak resident memory of this process \[MB\] (Linux `VmHWM`), if known.
pub fn peak_rss_mb() -> Option<f64> {
    proc_self_mb("status", "VmHWM")
}

/// Resident memory of this process on transparent huge pages \[MB\] (Linux `AnonHugePages`), if
/// known.
pub fn huge_pages_mb() -> Option<f64> {
    proc_self_mb("smaps_rollup", "AnonHugePages")
}

impl BenchWorld {
    /// Build the world, run it for `duration` sim seconds with `parallelism` (the default when
    /// `None`) and the scheduler's per-module timing on, and say what was measured.
    pub fn run(&self, duration: f64, parallelism: Option<Parallelism>) -> Result<BenchReport, BenchError> {
        // The middle lane's length, its map dropped before the world builds its own (two copies
        // of a 100,000-vehicle ring's lanes would double the setup's memory peak).
        let lane_length_m = {
            let lanes = self.lanes()?;
            lanes[lanes.len() / 2].length
        };
        let ring = self.ring();
        let mut builder = self.builder()?;
        let parallelism = parallelism.unwrap_or_default();
        builder.insert_resource(parallelism);
        let rates = Rates::default();
        let mut sim = builder.build();
        sim.scheduler_mut().set_timing(true);
        let cpu = process_cpu_seconds();
        let wall = std::time::Instant::now();
        let run = super::runner::run_headless(&mut sim, duration, duration, |_| {});
        let wall_seconds = wall.elapsed().as_secs_f64();
        let cpu_seconds = cpu.zip(process_cpu_seconds()).map(|(a, b)| b - a);
        let duration = run.sim_seconds;
        let steps = sim.scheduler().ticks(Dynamics).unwrap_or(0) as f64 * self.vehicles as f64;
        let modules = sim
            .scheduler()
            .module_times()
            .map(|(name, seconds)| ModuleTime { module: name.to_string(), seconds, share: seconds / wall_seconds })
            .collect();
        let radar = Radar::default();
        Ok(BenchReport {
            map: BenchMap {
                kind: "ring_highway",
                lanes: ring.lanes,
                radius_m: ring.radius,
                lane_width_m: ring.lane_width,
                lane_length_m,
            },
            vehicles: self.vehicles,
            degraded: self.degraded,
            plugin_sensor_share: self.plugin_sensor_share,
            sensors: BenchSensors {
                radar_range_m: radar.range,
                radar_angle_deg: radar.angle.to_degrees(),
                velodyne_range_m: Velodyne::default().range,
            },
            rates: BenchRates {
                dynamics: rates.dynamics,
                sensors: rates.sensors,
                control: rates.control,
                wifi: rates.wifi,
                network: rates.network,
            },
            threads: parallelism.threads,
            threads_used: parallelism.threads_for(self.vehicles),
            sim_seconds: duration,
            interrupted: run.interrupted,
            wall_seconds,
            cpu_seconds,
            vehicle_steps_per_cpu_second: cpu_seconds.filter(|&c| c > 0.0).map(|c| steps / c),
            real_time_factor: duration / wall_seconds,
            vehicle_steps_per_second: steps / wall_seconds,
            us_per_vehicle_sim_second: wall_seconds * 1e6 / (self.vehicles as f64 * duration),
            modules,
            peak_rss_mb: peak_rss_mb(),
            huge_pages_mb: huge_pages_mb(),
            v2v: {
                let c = sim.world().resource::<V2vChannelStats>();
                BenchV2v { wifi: (&c.wifi).into(), network: (&c.network).into() }
            },
            sensor_stats: *sim.world().resource::<SensorStats>(),
            lane_changes: self
                .lane_change
                .then(|| sim.world().get_resource::<LaneChangeLog>().map_or(0, |log| log.count() as u64)),
        })
    }
}

#[cfg(test)]
mod tests {
    use bevy_ecs::prelude::With;

    use super::*;
    use crate::sim::{DelayedMessages, Parallelism, V2vStats};
    use crate::vehicles::PathFollower;
    use crate::world::{ControlCommand, SensorReadings};

    /// `world` built on `parallelism`'s threads (not yet run).
    fn sim_of(world: BenchWorld, parallelism: Parallelism) -> crate::sim::Sim {
        let mut b = world.builder().expect("the bench world builds");
        b.insert_resource(parallelism);
        b.build()
    }

    #[test]
    fn a_tenth_of_the_vehicles_carry_the_student_camera_and_it_sees() {
        let world = BenchWorld { vehicles: 300, plugin_sensor_share: 0.1, ..Default::default() };
        let mut sim = sim_of(world, Parallelism::single());
        sim.run_for(1.0);
        let mut carriers = sim.world_mut().query::<&crate::sim::sensor_plugins::CarriesPluginSensor>();
        assert_eq!(carriers.iter(sim.world()).count(), 30, "a tenth of 300");
        let stats = sim.world().resource::<crate::sim::PluginSensorStats>();
        assert!(stats.0.get("camera").is_some_and(|c| c.detections > 0), "{stats:?}");
    }

    #[test]
    fn the_cameras_read_from_their_own_lists_what_the_grid_gives_them() {
        // A tenth of 1,000 vehicles with the camera, IDM and lane changes (the built-in lists
        // are built again now and then, and the cameras' with them), 2 threads: once with the
        // carriers' lists, once with the grid alone; the same readings and counts, bit for bit.
        use crate::sim::sensor_plugins::NearbyIndex;
        let runs: Vec<_> = [false, true]
            .into_iter()
            .map(|grid_only| {
                let world =
                    BenchWorld { vehicles: 1000, plugin_sensor_share: 0.1, lane_change: true, ..Default::default() };
                let mut sim = sim_of(world, Parallelism::split(2));
                sim.world_mut().resource_mut::<NearbyIndex>().grid_only = grid_only;
                sim.run_for(6.0);
                let served = sim.world().resource::<NearbyIndex>().ticks_served_by_lists();
                let stats = sim.world().resource::<crate::sim::PluginSensorStats>().clone();
                let builds = sim.world().resource::<crate::sim::grid::lists::SensorGrid>().neighbours.lists.builds;
                if !grid_only {
                    // After the last tick (served by the lists): any point's query builds a grid
                    // of its own, and it agrees with every carrier's list.
                    use crate::sim::sensor_plugins::{CarriesPluginSensor, Nearby};
                    assert!(sim.world().resource::<NearbyIndex>().served_by_lists(), "the last tick");
                    let world = sim.world_mut();
                    let mut carriers = world.query_filtered::<(&VehicleId, &VehicleState), With<CarriesPluginSensor>>();
                    let at: Vec<(VehicleId, glam::DVec2)> =
                        carriers.iter(world).map(|(&id, s)| (id, s.position)).collect();
                    let mut state = bevy_ecs::system::SystemState::<Nearby>::new(world);
                    let nearby = state.get(world).expect("the index exists");
                    let (mut listed, mut gridded) = (Vec::new(), Vec::new());
                    for &(id, p) in &at {
                        nearby.around(id, p, 80.0, &mut listed);
                        nearby.within(p, 80.0, &mut gridded);
                        assert!(listed.len() > 1 && listed == gridded, "carrier {id:?}: {listed:?} {gridded:?}");
                    }
                    assert_eq!(at.len(), 100);
                }
                (fingerprint_of(&mut sim), stats, served, builds)
            })
            .collect();
        let (lists, grid) = (&runs[0], &runs[1]);
        assert!(lists.2 >= 100, "the lists served {} of 120 sensor ticks", lists.2);
        assert!(lists.3 >= 2, "the built-in lists were built {} times: the cameras' never made again", lists.3);
        assert_eq!(grid.2, 0, "grid_only was not obeyed");
        assert!(
            lists.1.0.get("camera").is_some_and(|c| c.detections > 1000 && c.missed_by_occlusion > 0),
            "{:?}",
            lists.1
        );
        assert_eq!(lists.1, grid.1, "other counts from the lists than from the grid");
        assert!(lists.0 == grid.0, "other readings from the lists than from the grid");
    }

    /// Everything the heavy systems write, per vehicle, in id order, as exact bits.
    fn fingerprint(parallelism: Parallelism) -> Vec<(i32, Vec<u64>)> {
        let mut sim = sim_of(BenchWorld { vehicles: 600, ..Default::default() }, parallelism);
        sim.run_for(2.0);
        fingerprint_of(&mut sim)
    }

    #[test]
    fn the_order_the_bench_spawns_its_vehicles_in_changes_no_result() {
        // Lane changes and losses on: the most order-dependent world the bench builds.
        let world = BenchWorld { vehicles: 300, lane_change: true, degraded: true, ..Default::default() };
        let runs: Vec<_> = [SpawnOrder::Road, SpawnOrder::Lanes]
            .into_iter()
            .map(|order| {
                let mut b = world.builder_in(order).expect("the bench world builds");
                b.insert_resource(Parallelism::single());
                let mut sim = b.build();
                let entities: Vec<i32> = {
                    let world = sim.world_mut();
                    world.query::<&VehicleId>().iter(world).map(|id| id.0).collect()
                };
                sim.run_for(3.0);
                let stats = *sim.world().resource::<V2vStats>();
                (entities, fingerprint_of(&mut sim), stats)
            })
            .collect();
        assert_ne!(runs[0].0, runs[1].0, "both orders put the vehicles in the same order");
        assert_eq!(runs[0].1.len(), 300);
        assert!(runs[0].1 == runs[1].1, "the spawn order changed a vehicle's state, command or readings");
        assert_eq!(runs[0].2, runs[1].2);
    }

    /// [`fingerprint`]'s rows of a run.
    fn fingerprint_of(sim: &mut crate::sim::Sim) -> Vec<(i32, Vec<u64>)> {
        let world = sim.world_mut();
        let mut query = world.query_filtered::<(&VehicleId, &VehicleState, &ControlCommand, &SensorReadings, &PathFollower), With<Mailbox>>();
        let mut rows: Vec<(i32, Vec<u64>)> = query
            .iter(world)
            .map(|(id, s, c, r, f)| {
                let mut bits =
                    vec![s.position.x, s.position.y, s.yaw, s.velocity.x, s.velocity.y, c.steering, c.speed, f.s];
                for d in &r.0 {
                    bits.extend([d.id.0 as f64, d.position.x, d.position.y, d.velocity.x, d.velocity.y]);
                }
                (id.0, bits.into_iter().map(f64::to_bits).collect())
            })
            .collect();
        rows.sort_by_key(|r| r.0);
        rows
    }

    #[test]
    fn the_report_names_what_it_measured_and_where_the_time_went() {
        let world = BenchWorld { vehicles: 300, ..Default::default() };
        let report = world.run(1.0, Some(Parallelism::single())).expect("the bench world runs");
        assert_eq!(report.vehicles, 300);
        assert_eq!((report.threads, report.threads_used), (1, 1));
        assert_eq!(report.map.lanes, 3);
        // 100 vehicles per lane at 40 m need 4 km of lane, more than a 500 m ring gives.
        assert!((report.map.lane_length_m / 100.0 - 40.0).abs() < 1.0, "{} m", report.map.lane_length_m);
        assert_eq!(report.rates.dynamics, 50.0);
        assert_eq!(report.sensors.radar_range_m, 100.0);
        let names: Vec<&str> = report.modules.iter().map(|m| m.module.as_str()).collect();
        assert_eq!(names, ["sensors", "wifi", "network", "control", "dynamics"]);
        assert!(report.modules.iter().all(|m| m.seconds > 0.0), "{:?}", report.modules);
        let shares: f64 = report.modules.iter().map(|m| m.share).sum();
        assert!(shares > 0.5 && shares <= 1.0, "module shares sum to {shares}");
        let json = serde_json::to_value(&report).expect("the report serialises");
        let cpu = report.cpu_seconds.expect("processor time is measured on Linux");
        assert!(cpu > 0.0 && cpu < 60.0, "{cpu} s of processor time for 1 sim s of 300 vehicles");
        for key in ["map", "vehicles", "sensors", "rates", "threads", "modules", "vehicle_steps_per_cpu_second"] {
            assert!(json.get(key).is_some(), "JSON lacks `{key}`");
        }
    }

    #[test]
    fn the_bench_sends_wifi_beacons_that_a_degraded_run_loses_and_delays() {
        let plain = BenchWorld { vehicles: 300, ..Default::default() };
        let degraded = BenchWorld { degraded: true, ..plain };
        let (p, d) = (plain.run(2.0, None).expect("runs"), degraded.run(2.0, None).expect("runs"));
        // 300 vehicles 40 m apart on three lanes each hear a few others within 50 m, 20 rounds.
        for r in [&p, &d] {
            assert!(r.v2v.wifi.sent > 300 * 20 * 2, "wifi receptions {}", r.v2v.wifi.sent);
            assert!(r.v2v.network.sent >= 300 * 299, "network receptions {}", r.v2v.network.sent);
        }
        assert_eq!(p.v2v.wifi.delivered, p.v2v.wifi.sent);
        assert_eq!(p.v2v.wifi.delay_ms_mean, 0.0);
        assert_eq!(p.sensor_stats.missed_by_dropout, 0);
        let share = d.v2v.wifi.delivered as f64 / d.v2v.wifi.sent as f64;
        assert!((share - 0.9).abs() < 0.02, "degraded wifi delivered {share} (10 % loss)");
        // 10 ms delay plus uniform [0, 5) ms of jitter.
        assert!((d.v2v.wifi.delay_ms_mean - 12.5).abs() < 0.2, "mean delay {}", d.v2v.wifi.delay_ms_mean);
        let dropped = d.sensor_stats.missed_by_dropout as f64 / (d.sensor_stats.detections as f64);
        assert!(dropped > 0.001 && dropped < 0.02, "radar dropout share {dropped}");
    }

    #[test]
    fn a_degraded_run_delivers_its_delayed_wifi_and_keeps_no_backlog() {
        // The degraded V2vConfig is inserted after default_plugins built the V2V plugin with a
        // perfect one: the delayed receptions must still reach the in-boxes when due.
        let mut sim = sim_of(BenchWorld { vehicles: 300, degraded: true, ..Default::default() }, Parallelism::single());
        sim.run_for(3.0);
        let world = sim.world();
        let (stats, channel) = (world.resource::<V2vStats>(), world.resource::<V2vChannelStats>());
        let in_flight = world.resource::<DelayedMessages>().len() as u64;
        assert!(channel.wifi.delivered > 0, "nothing delivered");
        assert_eq!(
            stats.wifi_delivered + in_flight,
            channel.wifi.delivered,
            "delivered into in-boxes plus in flight is every reception not lost"
        );
        // 10-15 ms of delay: at most the last round's receptions are still in flight.
        assert!(in_flight * 10 < channel.wifi.delivered, "{in_flight} receptions in flight");
    }

    #[test]
    fn the_lane_change_bench_counts_changes_without_a_list_that_grows() {
        let mut sim =
            sim_of(BenchWorld { vehicles: 300, lane_change: true, ..Default::default() }, Parallelism::single());
        sim.run_for(60.0);
        let log = sim.world().resource::<LaneChangeLog>();
        assert!(log.count() > 0, "vehicles of different desired speeds change lanes");
        assert!(log.events.is_empty(), "{} events kept by a run that writes no summary", log.events.len());
        // One loop per lane, whatever lanelet the changes happened at (each is a whole lane).
        let paths = sim.world().resource::<crate::vehicles::lane_changing::LanePaths>();
        assert!(paths.cached() <= 3, "{} lane paths kept for a 3-lane ring", paths.cached());
    }

    #[test]
    fn lane_changers_added_before_the_first_tick_or_during_the_run_get_their_goal_lanes() {
        use crate::vehicles::{LaneChanger, NewLaneChangers};
        let world = BenchWorld { vehicles: 30, lane_change: true, ..Default::default() };
        let mut b = world.builder().expect("the bench world builds");
        b.insert_resource(Parallelism::single());
        // The changers' hook noted the 30 spawned after the plugin; forget them, as if they had
        // been added before the plugin installed the list: the first tick must find them anyway.
        assert_eq!(b.world_mut().resource::<NewLaneChangers>().0.len(), 30);
        b.world_mut().resource_mut::<NewLaneChangers>().0.clear();
        let mut sim = b.build();
        let knowing = |sim: &mut crate::sim::Sim| {
            let world = sim.world_mut();
            let mut q = world.query::<(&VehicleId, &LaneChanger)>();
            q.iter(world).filter(|(_, ch)| ch.knows_its_goal_lanes()).map(|(id, _)| id.0).collect::<Vec<_>>()
        };
        assert!(knowing(&mut sim).is_empty());
        sim.run_for(0.1);
        assert_eq!(knowing(&mut sim).len(), 30, "every changer present at the first tick");
        // One more, spawned mid-run beside the others (as traffic enters): only the hook tells.
        let lane = world.lanes().expect("the bench world builds").remove(1);
        let s = 0.5 * lane.length + 20.0;
        let (p, heading) = lane.sample(s);
        let mut spec = VehicleSpec::new(VehicleId(1000), VehicleState::new(p, heading, world.speed));
        spec.route = Some(Arc::clone(&lane));
        let e = sim.spawn_vehicle(spec).expect("spawns");
        let law = FollowLaw::Idm(Idm::default());
        sim.world_mut().entity_mut(e).insert((
            PathFollower::starting_at(PathFollowing { speed: world.speed, ..Default::default() }, s),
            IdmController { params: Idm::default() },
            LanePosition::default(),
            LaneChanger::new(LaneChangeParams::default(), law, RouteGoal::Loop),
        ));
        sim.run_for(0.1);
        let known = knowing(&mut sim);
        assert_eq!(known.len(), 31);
        assert!(known.contains(&1000), "the changer added during the run has its goal's lanelets");
    }

    #[test]
    fn the_report_counts_the_lane_changes_of_a_lane_change_run_and_none_without() {
        let plain = BenchWorld { vehicles: 300, ..Default::default() };
        let changing = BenchWorld { lane_change: true, ..plain };
        let single = Some(Parallelism::single());
        let (p, c) = (plain.run(1.0, single).expect("runs"), changing.run(60.0, single).expect("runs"));
        assert_eq!(p.lane_changes, None);
        assert!(c.lane_changes.is_some_and(|n| n > 0), "lane changes {:?}", c.lane_changes);
        let json = serde_json::to_value(&c).expect("the report serialises");
        assert_eq!(json["lane_changes"].as_u64(), c.lane_changes);
    }

    #[test]
    fn the_ring_grows_to_give_every_vehicle_its_gap() {
        // 10,000 vehicles per lane around an inner edge of radius 10,000 * 40 m / 2π: each lane
        // is 2π (R + (k + 1/2) 3.5 m) long, i.e. 40 m per vehicle plus at most 2π 8.75 m / 10,000.
        let world = BenchWorld { vehicles: 30_000, ..Default::default() };
        let lanes = world.lanes().expect("the bench world builds");
        assert_eq!(lanes.len(), 3);
        for path in &lanes {
            assert!(path.closed);
            let gap = path.length / 10_000.0;
            assert!((gap - 40.0).abs() < 0.02, "{gap} m per vehicle");
        }
    }

    #[test]
    fn results_do_not_depend_on_the_thread_count() {
        let single = fingerprint(Parallelism::single());
        assert_eq!(single.len(), 600);
        assert!(single.iter().any(|(_, bits)| bits.len() > 8), "some vehicle must detect others");
        for threads in [2, 3, 7] {
            let split = fingerprint(Parallelism { threads, min_vehicles: 0 });
            assert!(single == split, "{threads} threads changed the results");
        }
    }
}

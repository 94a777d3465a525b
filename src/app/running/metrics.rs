//! Per-run metrics for `summary.json`: collisions, gaps of every follower, speed errors and the
//! string stability of every platoon, recorded after each dynamics step.
//!
//! - Collisions: footprints are oriented rectangles (length along the heading, centred on the
//!   vehicle's position) tested by separating axes; pairs come from a spatial grid, so a tick is
//!   O(N). Each contact is recorded once, when it starts, with both ids and the time. Two
//!   [`Stationary`] obstacles touching each other (adjacent road-boundary blocks) are no collision.
//! - Followers: every vehicle whose speed controller sees a leader on its route
//!   ([`Longitudinal::leader`]); its bumper-to-bumper gap is measured from ground truth (both
//!   real lengths), time gap = gap / speed (above 1 m/s), speed error = leader speed − own speed.
//! - Platoons: per platoon (leader id) and member, the range of its speed (max − min) after the
//!   warm-up; the platoon is string stable when no member's range exceeds the range of the
//!   member ahead of it (by more than 1% + 0.01 m/s), i.e. a disturbance does not grow.
//!
//! Statistics other than collisions skip the first `warmup` seconds (start-up transients).

use std::collections::{BTreeMap, BTreeSet};

use bevy_ecs::prelude::{Has, Query, Res, ResMut, Resource, Without};
use bevy_ecs::schedule::IntoScheduleConfigs;
use glam::DVec2;

use crate::sim::{Dynamics, GridEntry, Padded, Parallelism, Plugin, SimBuilder, SimClock, SimSystems, SpatialGrid};
use crate::vehicles::lanes::PREFETCH_AHEAD;
use crate::vehicles::{
    LaneChangeEvent, LaneChangeLog, LaneMap, LanePosition, Longitudinal, PathFollower, PlatoonMember,
};
use crate::world::{IdMap, Route, Stationary, VehicleId, VehicleSize, VehicleState};

/// One collision: two footprints started to overlap.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Collision {
    /// Lower id of the pair.
    pub a: VehicleId,
    /// Higher id of the pair.
    pub b: VehicleId,
    /// Sim time the overlap started \[s\].
    pub t: f64,
}

/// Statistics of one follower.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct FollowerStats {
    /// The follower.
    pub id: VehicleId,
    /// Its leader at the last sample.
    pub leader: VehicleId,
    /// Smallest bumper-to-bumper gap \[m\].
    pub min_gap: f64,
    /// Smallest time gap \[s\] (samples above 1 m/s; none if it never moved that fast).
    pub min_time_gap: Option<f64>,
    /// Mean time gap \[s\] (samples above 1 m/s).
    pub mean_time_gap: Option<f64>,
    /// Root mean square of leader speed − own speed [m/s].
    pub speed_error_rms: f64,
    /// Number of samples.
    pub samples: u64,
    /// Time it spent in platoon fallback (ACC because the beacons of the member ahead were
    /// stale, [`PlatoonMember::degraded`]) after the warm-up \[s\]; 0 for a vehicle that is no
    /// platoon follower.
    pub degraded_s: f64,
    /// Largest age of the newest beacon of the member ahead \[s\] while a platoon follower, after
    /// the warm-up; `None` (JSON `null`) for a vehicle that never was one.
    pub beacon_age_max_s: Option<f64>,
    #[serde(skip)]
    time_gap_sum: f64,
    #[serde(skip)]
    time_gap_samples: u64,
    #[serde(skip)]
    speed_error_sq: f64,
}

/// A leader speed range below this [m/s] is no disturbance: `amplification` is not computed.
/// The same 0.01 m/s as the string-stability tolerance.
pub const NO_DISTURBANCE: f64 = 0.01;

/// Speed range of one platoon member.
#[derive(Debug, Clone, Copy, PartialEq)]
struct MemberStats {
    index: u32,
    min_speed: f64,
    max_speed: f64,
}

/// String stability of one platoon.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct PlatoonStats {
    /// The leader (the platoon's id).
    pub leader: VehicleId,
    /// Members in platoon order, leader first.
    pub members: Vec<VehicleId>,
    /// Range of each member's speed (max − min) after the warm-up [m/s], same order.
    pub speed_amplitudes: Vec<f64>,
    /// Last member's range over the leader's [-]: below 1 means the disturbance shrank. `None`
    /// (JSON `null`) when the leader's range is below [`NO_DISTURBANCE`]: there was nothing to
    /// amplify, and a ratio of two near-zero ranges would be noise.
    pub amplification: Option<f64>,
    /// `"no disturbance"` when the leader's speed range stayed below [`NO_DISTURBANCE`] (for
    /// example a run that ends before the leader brakes), else `None` (not written).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub note: Option<&'static str>,
    /// Whether no member's range exceeds the one ahead of it (1% + 0.01 m/s tolerance).
    pub string_stable: bool,
}

/// What goes into `summary.json` under `metrics`.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct MetricsSummary {
    /// Statistics skip this start-up time \[s\] (collisions do not).
    pub warmup: f64,
    /// Number of collisions.
    pub collision_count: usize,
    /// Every collision, in time order.
    pub collisions: Vec<Collision>,
    /// Every vehicle that collided (JSON keys are its id as a string): the sim time of its first
    /// collision \[s\].
    pub collided: BTreeMap<i32, f64>,
    /// Every follower, in id order.
    pub followers: Vec<FollowerStats>,
    /// Every platoon, in leader id order.
    pub platoons: Vec<PlatoonStats>,
    /// Every lane change, in the order they ended (runs on a map only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lane_changes: Option<Vec<LaneChangeEvent>>,
    /// Lane changes counted (runs on a map only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lane_change_summary: Option<LaneChangeSummary>,
    /// Background traffic placed, inserted and removed (with `[[traffic]]` only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub traffic: Option<super::traffic::TrafficSummary>,
    /// Vehicles that left at their route's end (with `[[traffic]]` only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub throughput: Option<super::traffic::Throughput>,
    /// Trips of the vehicles on routes: inserted, arrived, travel and waiting times, stops
    /// (with [`super::trips::TripsPlugin`] only; every row of `trips.csv` counts).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub trips: Option<super::trips::TripsSummary>,
    /// What each V2V channel sent, delivered and lost, per receiver (set by the run summary).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub v2v: Option<V2vMetrics>,
    /// The emergency vehicle's travel time, delay against free flow, closest approach and the
    /// vehicles that made way (with an emergency vehicle only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub emergency: Option<crate::vehicles::EmergencySummary>,
    /// Detections of all sensors and the misses by dropout and by occlusion, summed over
    /// observers and sensor ticks, and each plugin sensor's by name (`None` without the sensor
    /// plugin).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sensors: Option<SensorMetrics>,
    /// The GCDC merge: vehicles to merge and merged, pairs, duration, smallest gaps, zipper
    /// order, aborts (only when a `gcdc` vehicle heard a merge zone).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub merge: Option<crate::vehicles::MergeSummary>,
    /// Per junction: vehicles through, mean and longest wait, longest queue (maps with
    /// junctions only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub junctions: Option<Vec<crate::vehicles::right_of_way::JunctionMetric>>,
    /// Vehicles that passed a stop line showing red (maps with traffic lights only; 0 unless a
    /// vehicle could not stop).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub red_light_crossings: Option<u64>,
    /// The GCDC 2016 cooperative intersection: participants, crossed, entry order, smallest gap
    /// and post-encroachment time of conflicting pairs, mean delay, platoon splits (only with
    /// vehicles that have `controller.intersection` and heard the roadside unit).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub intersection: Option<IntersectionSummary>,
}

/// `metrics.lane_change_summary` of `summary.json`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct LaneChangeSummary {
    /// Lane changes (aborted ones included).
    pub count: usize,
    /// Of which discretionary (MOBIL).
    pub discretionary: usize,
    /// Of which mandatory (the lane did not lead to the destination).
    pub mandatory: usize,
    /// Of which aborted back to the old lane.
    pub aborted: usize,
    /// Vehicles that reached the end of a lane they had to leave.
    pub missed_exits: usize,
    /// Longest time a vehicle stood (below 0.5 m/s) waiting for a gap \[s\].
    pub max_wait_s: f64,
}

impl LaneChangeSummary {
    /// Count the changes of `log`.
    pub fn of(log: &LaneChangeLog) -> LaneChangeSummary {
        LaneChangeSummary {
            count: log.count(),
            discretionary: log.counts[0],
            mandatory: log.counts[1],
            aborted: log.aborted,
            missed_exits: log.missed_exits.len(),
            max_wait_s: log.max_wait_s,
        }
    }
}

/// `metrics.v2v`: both channels, counted per receiver (a broadcast heard by five is five sent).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct V2vMetrics {
    /// The wifi channel.
    pub wifi: ChannelMetrics,
    /// The network channel.
    pub network: ChannelMetrics,
}

/// `metrics.sensors`: the built-in sensors' counts (radar, velodyne and omniscient together, at
/// the top level as before) and each plugin sensor's, by name.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct SensorMetrics {
    /// The built-in sensors' counts.
    #[serde(flatten)]
    pub built_in: crate::sim::SensorStats,
    /// Each plugin sensor's counts, by its registered name (empty without plugin sensors).
    #[serde(skip_serializing_if = "std::collections::BTreeMap::is_empty")]
    pub by_sensor: std::collections::BTreeMap<String, crate::sim::SensorStats>,
}

/// One channel of [`V2vMetrics`].
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct ChannelMetrics {
    /// Receptions attempted (message x receiver in range).
    pub sent: u64,
    /// Receptions not lost.
    pub delivered: u64,
    /// `sent - delivered`.
    pub lost: u64,
    /// Mean delivery delay \[ms\].
    pub delay_ms_mean: f64,
    /// 95th percentile of the delivery delay \[ms\] (0.5 ms resolution).
    pub delay_ms_p95: f64,
    /// Mean age of a message when it reaches the in-box \[ms\]: out-box wait plus delay.
    pub age_of_information_ms_mean: f64,
}

impl V2vMetrics {
    /// From the V2V systems' counters.
    pub fn of(stats: &crate::sim::V2vChannelStats) -> V2vMetrics {
        let channel = |c: &crate::sim::ChannelStats| ChannelMetrics {
            sent: c.sent,
            delivered: c.delivered,
            lost: c.lost(),
            delay_ms_mean: c.delay_ms_mean(),
            delay_ms_p95: c.delay_ms_p95(),
            age_of_information_ms_mean: c.age_of_information_ms_mean(),
        };
        V2vMetrics { wifi: channel(&stats.wifi), network: channel(&stats.network) }
    }
}

/// The metrics being recorded.
#[derive(Resource, Debug, Default)]
pub struct Metrics {
    /// Start-up time skipped by the statistics \[s\].
    pub warmup: f64,
    /// Collisions so far.
    pub collisions: Vec<Collision>,
    /// Sim time of each vehicle's first collision \[s\].
    pub collided: BTreeMap<VehicleId, f64>,
    /// Routed vehicles that no path follower measures (driven from Python, a student's
    /// controller, none): where each was on its route and its largest distance to the route's
    /// centre line so far, after every dynamics step.
    pub route_deviation: BTreeMap<VehicleId, RouteTrack>,
    /// Followers so far, in the order first seen (the summary sorts them by id); where each
    /// is in `followers` is in `follower_slot`.
    pub followers: Vec<FollowerStats>,
    /// Where each follower's statistics are in `followers`.
    follower_slot: IdMap<u32>,
    /// The ids of the follower query's vehicles at the last step, in the query's order, and
    /// where each one's statistics are in `followers` (`u32::MAX`: none yet): while the query
    /// holds the same vehicles in the same order (most steps), no id is looked up. Every
    /// follower is updated at the dynamics rate, 10,000 in a town, and the hash lookups, each
    /// a cache miss, were half of this system's serial time.
    query_ids: Vec<VehicleId>,
    query_slots: Vec<u32>,
    /// This step's ids of the follower query (the buffer kept between steps).
    ids_now: Vec<VehicleId>,
    /// Each follower's sample this step (leader, gap, speed, speed error), in the query's
    /// order (the buffer kept between steps).
    samples: Vec<Option<(VehicleId, f64, f64, f64)>>,
    platoons: BTreeMap<VehicleId, BTreeMap<VehicleId, MemberStats>>,
    contacts: BTreeSet<(VehicleId, VehicleId)>,
    touching: Vec<(VehicleId, VehicleId)>,
    /// Each chunk's touching pairs of the parallel search, merged into `touching`.
    touching_chunks: Vec<Padded<Vec<(VehicleId, VehicleId)>>>,
    boxes: Vec<Footprint>,
    /// Scratch of the parallel pass that turns the boxes' headings into axes (none needed).
    axis_chunks: Vec<()>,
    /// Map index of the lanelet under each of `boxes` (`u32::MAX` off the road or unknown).
    box_lanelets: Vec<u32>,
    grid: SpatialGrid,
    /// Pairs of `boxes` (indices, lower id first) that may touch: see [`Metrics::record_collisions`].
    near: Vec<(u32, u32)>,
    /// Each chunk's pairs of the parallel search, merged into `near`.
    near_chunks: Vec<Padded<Vec<(u32, u32)>>>,
    /// Each box's vehicle and centre when `near` was made.
    near_at: Vec<(VehicleId, DVec2)>,
    /// Where each vehicle's box is in `boxes` (made with `near`, which is made again whenever
    /// the vehicles or their order change).
    box_of: IdMap<u32>,
    /// The near list's margin \[m\] ([`near_margin`] of the dynamics step; 0: [`NEAR_MARGIN`]),
    /// and the one `near` was made with.
    margin: f64,
    near_margin: f64,
    /// The widest footprint's radius when `near` was made in full \[m\] (its grid's reach).
    near_widest: f64,
    /// Vehicles added to `near` by [`Metrics::patch_near_list`] since it was made in full (not
    /// on its grid).
    unlisted: Vec<VehicleId>,
    /// Scratch of [`Metrics::patch_near_list`]: each old box's new index, the new anchors, the
    /// new boxes' indices.
    old_to_new: Vec<u32>,
    new_at: Vec<(VehicleId, DVec2)>,
    added: Vec<u32>,
}

/// Where a routed vehicle without a path follower was on its route (see
/// [`Metrics::route_deviation`]).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RouteTrack {
    /// Arc length of its projection on the route at the last step \[m\].
    pub s: f64,
    /// Largest distance to the route's centre line so far \[m\].
    pub max_offset: f64,
}

/// After every dynamics step: the distance to its route's centre line of every routed vehicle
/// that no [`PathFollower`] measures. The first step projects onto the whole route; later ones
/// search around the last arc length, as far as the vehicle can have moved.
pub fn record_route_deviation(
    clock: Res<SimClock>,
    mut metrics: ResMut<Metrics>,
    routed: Query<(&VehicleId, &VehicleState, &Route), Without<PathFollower>>,
) {
    for (&id, state, route) in &routed {
        let path = &route.0;
        let track = metrics.route_deviation.get(&id).copied();
        let projection = match track {
            Some(t) => path.project_near(state.position, t.s, state.speed() * clock.dt + path.spacing()),
            None => path.project(state.position),
        };
        let max_offset = track.map_or(0.0, |t| t.max_offset).max(projection.lateral.abs());
        metrics.route_deviation.insert(id, RouteTrack { s: projection.s, max_offset });
    }
}

/// An oriented rectangle.
#[derive(Debug, Clone, Copy)]
struct Footprint {
    id: VehicleId,
    /// A [`Stationary`] obstacle (two of them never collide).
    fixed: bool,
    centre: DVec2,
    axis: DVec2,
    half: DVec2,
    /// Its velocity [m/s] (read by the follower gaps, not by the overlap test).
    velocity: DVec2,
}

impl Footprint {
    /// The footprint of a vehicle of `size` at `centre`, heading `yaw` \[rad\], standing still.
    fn of(id: VehicleId, fixed: bool, centre: DVec2, yaw: f64, size: &VehicleSize) -> Footprint {
        Footprint {
            id,
            fixed,
            centre,
            axis: DVec2::from_angle(yaw),
            half: 0.5 * DVec2::new(size.length, size.width),
            velocity: DVec2::ZERO,
        }
    }

    fn radius(&self) -> f64 {
        self.half.length()
    }
}

/// Whether two oriented rectangles overlap (separating axis test over their four axes).
pub fn rectangles_overlap(
    centre_a: DVec2,
    yaw_a: f64,
    size_a: &VehicleSize,
    centre_b: DVec2,
    yaw_b: f64,
    size_b: &VehicleSize,
) -> bool {
    let a = Footprint::of(VehicleId(0), false, centre_a, yaw_a, size_a);
    let b = Footprint::of(VehicleId(0), false, centre_b, yaw_b, size_b);
    overlap(&a, &b)
}

fn overlap(a: &Footprint, b: &Footprint) -> bool {
    let d = b.centre - a.centre;
    let (ua, va) = (a.axis, a.axis.perp());
    let (ub, vb) = (b.axis, b.axis.perp());
    for n in [ua, va, ub, vb] {
        let ra = a.half.x * ua.dot(n).abs() + a.half.y * va.dot(n).abs();
        let rb = b.half.x * ub.dot(n).abs() + b.half.y * vb.dot(n).abs();
        if d.dot(n).abs() > ra + rb {
            return false;
        }
    }
    true
}

impl Metrics {
    /// Empty metrics skipping `warmup` \[s\] in the statistics.
    pub fn new(warmup: f64) -> Metrics {
        Metrics { warmup, ..Default::default() }
    }

    /// The summary for `summary.json`.
    pub fn summary(&self) -> MetricsSummary {
        let platoons = self
            .platoons
            .iter()
            .map(|(&leader, members)| {
                let mut order: Vec<(u32, VehicleId, f64)> =
                    members.iter().map(|(&id, m)| (m.index, id, (m.max_speed - m.min_speed).max(0.0))).collect();
                order.sort_by_key(|&(index, id, _)| (index, id));
                let amplitudes: Vec<f64> = order.iter().map(|o| o.2).collect();
                let string_stable = amplitudes.windows(2).all(|w| w[1] <= w[0] * 1.01 + 0.01);
                let amplification = match (amplitudes.first(), amplitudes.last()) {
                    (Some(&first), Some(&last)) if first >= NO_DISTURBANCE => Some(last / first),
                    _ => None,
                };
                PlatoonStats {
                    leader,
                    members: order.iter().map(|o| o.1).collect(),
                    speed_amplitudes: amplitudes,
                    amplification,
                    note: amplification.is_none().then_some("no disturbance"),
                    string_stable,
                }
            })
            .collect();
        MetricsSummary {
            warmup: self.warmup,
            collision_count: self.collisions.len(),
            collisions: self.collisions.clone(),
            collided: self.collided.iter().map(|(id, t)| (id.0, *t)).collect(),
            followers: {
                let mut all: Vec<FollowerStats> = self.followers.clone();
                all.sort_unstable_by_key(|f| f.id);
                all
            },
            platoons,
            lane_changes: None,
            lane_change_summary: None,
            traffic: None,
            throughput: None,
            trips: None,
            v2v: None,
            emergency: None,
            merge: None,
            sensors: None,
            junctions: None,
            red_light_crossings: None,
            intersection: None,
        }
    }
}

/// A follower's bumper-to-bumper gap [m] to its leader along its route, its speed [m/s] and the
/// leader's speed along the route minus its own [m/s]; `None` where the leader is not near the
/// route. The leader is walked to from where the leader search put it (`s + distance`: a few
/// segments), the 10 m window searched only when the walk leaves it.
fn follower_gap(
    state: &VehicleState,
    size: &VehicleSize,
    path: &crate::map::Path,
    s: f64,
    distance: f64,
    leader: &Footprint,
) -> Option<(f64, f64, f64)> {
    let (leader_s, _, _, direction) = path.near_within(leader.centre, s + distance, 10.0, f64::INFINITY)?;
    let mut ahead = leader_s - s;
    if path.closed {
        ahead = ahead.rem_euclid(path.length);
    }
    let gap = ahead - 0.5 * size.length - leader.half.x;
    let v = state.speed();
    Some((gap, v, leader.velocity.dot(direction) - v))
}

/// Record collisions, follower gaps and platoon speeds after a dynamics step.
#[allow(clippy::type_complexity, clippy::too_many_arguments)]
pub fn record_metrics(
    clock: Res<SimClock>,
    mut metrics: ResMut<Metrics>,
    everyone: Query<(&VehicleId, &VehicleState, &VehicleSize, Has<Stationary>, Option<&LanePosition>)>,
    followers: Query<(
        &VehicleId,
        &VehicleState,
        &VehicleSize,
        &Route,
        &PathFollower,
        &Longitudinal,
        Option<&PlatoonMember>,
    )>,
    members: Query<(&VehicleId, &VehicleState, &PlatoonMember)>,
    parallelism: Option<Res<Parallelism>>,
    lanes: Option<Res<LaneMap>>,
) {
    // The step just integrated ends at now + dt.
    let t = clock.now.as_secs() + clock.dt;
    let m = &mut *metrics;
    let parallelism = parallelism.as_deref().copied().unwrap_or_else(Parallelism::single);
    m.margin = near_margin(clock.dt);
    // Footprints that overlap on lanelets at different levels (a bridge over a road) do not
    // touch; checked only for overlapping pairs.
    let junctions = lanes.as_deref().map(|l| l.map.junctions());
    let separated = |a: u32, b: u32| junctions.as_ref().is_some_and(|j| j.levels_apart(a as usize, b as usize));
    m.record_collisions(
        t,
        parallelism,
        everyone
            .iter()
            .map(|(&id, state, size, fixed, lane)| (id, state, size, fixed, lane.map_or(u32::MAX, |l| l.index))),
        &separated,
    );
    if t < m.warmup {
        return;
    }
    // Each follower's gap and speed error, split over threads (lookups and a walk along its
    // route: a third of a 10,000-vehicle town's time on one thread, at the dynamics rate),
    // then added to its statistics in the query's order. The leader's footprint is read from
    // the collision search's boxes (one table lookup, where the registry and the ECS were four
    // or five dependent cache misses a follower). Each follower's place in the query goes with
    // it, for the place of its statistics (kept while the query's vehicles stay the same).
    // Straight in the ECS tables' slices, a sample a row into a buffer kept between steps: a
    // list of each follower's components made anew every step (64 bytes a follower, fresh
    // pages each time) was half of this system's serial time in a town.
    let mut samples = std::mem::take(&mut m.samples);
    samples.clear();
    let mut ids = std::mem::take(&mut m.ids_now);
    ids.clear();
    let (boxes, box_of) = (&m.boxes, &m.box_of);
    let sample =
        |state: &VehicleState, size: &VehicleSize, route: &Route, follower: &PathFollower, lon: &Longitudinal| {
            lon.leader.and_then(|l| {
                let leader = boxes.get(*box_of.get(&l.id)? as usize)?;
                let (gap, v, error) = follower_gap(state, size, &route.0, follower.s, l.distance, leader)?;
                Some((l.id, gap, v, error))
            })
        };
    if let Ok(tables) = followers.contiguous_iter() {
        let mut scratch: Vec<()> = Vec::new();
        for (tids, states, sizes, routes, fols, lons, _) in tables {
            let start = samples.len();
            ids.extend_from_slice(tids);
            samples.resize(start + tids.len(), None);
            parallelism.for_each_chunk_at(&mut samples[start..], &mut scratch, |from, chunk, _| {
                for (k, out) in chunk.iter_mut().enumerate() {
                    let n = from + k;
                    // What a follower a few places on will read, each its own route (in a
                    // town, far apart and out of cache): the route's fields two steps before
                    // its points near the leader, which need them.
                    if let Some(route) = routes.get(n + 2 * PREFETCH_AHEAD) {
                        crate::world::prefetch_value(&*route.0);
                    }
                    let a = n + PREFETCH_AHEAD;
                    if let (Some(route), Some(follower), Some(l)) =
                        (routes.get(a), fols.get(a), lons.get(a).and_then(|lon| lon.leader))
                    {
                        crate::world::prefetch_all(route.0.points_near(follower.s + l.distance));
                    }
                    *out = sample(&states[n], &sizes[n], &routes[n], &fols[n], &lons[n]);
                }
            });
        }
    } else {
        // Only if a component were stored sparsely (none is): one at a time.
        for (&id, state, size, route, follower, lon, _) in &followers {
            ids.push(id);
            samples.push(sample(state, size, route, follower, lon));
        }
    }
    if ids != m.query_ids {
        m.query_slots.clear();
        let slot_of = &m.follower_slot;
        m.query_slots.extend(ids.iter().map(|id| slot_of.get(id).copied().unwrap_or(u32::MAX)));
    }
    m.ids_now = std::mem::replace(&mut m.query_ids, ids);
    let mut add = |k: usize, id: VehicleId, member: Option<&PlatoonMember>| {
        let Some((leader, gap, v, error)) = samples[k] else { return };
        let slot = match m.query_slots[k] {
            u32::MAX => {
                let slot = m.followers.len() as u32;
                m.followers.push(FollowerStats::new(id, leader));
                m.follower_slot.insert(id, slot);
                m.query_slots[k] = slot;
                slot
            }
            slot => slot,
        };
        let stats = &mut m.followers[slot as usize];
        stats.sample(leader, gap, v, error);
        if let Some(member) = member {
            stats.sample_platoon(member, clock.dt);
        }
    };
    match followers.contiguous_iter() {
        Ok(tables) => {
            let mut k = 0;
            for (tids, .., members) in tables {
                for (n, &id) in tids.iter().enumerate() {
                    add(k + n, id, members.map(|ms| &ms[n]));
                }
                k += tids.len();
            }
        }
        Err(_) => {
            for (k, (&id, .., member)) in followers.iter().enumerate() {
                add(k, id, member);
            }
        }
    }
    m.samples = samples;
    for (&id, state, member) in &members {
        let Some(platoon) = member.platoon else { continue };
        let v = state.speed();
        let entry = m.platoons.entry(platoon).or_default().entry(id).or_insert(MemberStats {
            index: member.index,
            min_speed: v,
            max_speed: v,
        });
        entry.index = member.index;
        entry.min_speed = entry.min_speed.min(v);
        entry.max_speed = entry.max_speed.max(v);
    }
}

impl FollowerStats {
    fn new(id: VehicleId, leader: VehicleId) -> FollowerStats {
        FollowerStats {
            id,
            leader,
            min_gap: f64::INFINITY,
            min_time_gap: None,
            mean_time_gap: None,
            speed_error_rms: 0.0,
            samples: 0,
            degraded_s: 0.0,
            beacon_age_max_s: None,
            time_gap_sum: 0.0,
            time_gap_samples: 0,
            speed_error_sq: 0.0,
        }
    }

    /// Add one sample: bumper-to-bumper `gap` [m] to `leader`, own speed `v` [m/s], leader
    /// speed minus own speed `error` [m/s].
    fn sample(&mut self, leader: VehicleId, gap: f64, v: f64, error: f64) {
        self.leader = leader;
        self.samples += 1;
        self.min_gap = self.min_gap.min(gap);
        if v > 1.0 {
            let time_gap = gap / v;
            self.min_time_gap = Some(self.min_time_gap.map_or(time_gap, |t| t.min(time_gap)));
            self.time_gap_sum += time_gap;
            self.time_gap_samples += 1;
            self.mean_time_gap = Some(self.time_gap_sum / self.time_gap_samples as f64);
        }
        self.speed_error_sq += error * error;
        self.speed_error_rms = (self.speed_error_sq / self.samples as f64).sqrt();
    }
}

impl FollowerStats {
    /// Add the platoon state of one dynamics step of `dt` [s].
    fn sample_platoon(&mut self, member: &PlatoonMember, dt: f64) {
        if member.degraded {
            self.degraded_s += dt;
        }
        if let Some(age) = member.beacon_age {
            self.beacon_age_max_s = Some(self.beacon_age_max_s.map_or(age, |a| a.max(age)));
        }
    }
}

impl Metrics {
    /// Find the vehicle pairs whose footprints overlap at time `t` [s] and record each contact
    /// that is new since the last step.
    ///
    /// Only pairs on the near list are tested: pairs whose centres were within their two radii
    /// plus [`NEAR_MARGIN`] when the list was made (a grid of the widest footprint plus the
    /// margin, O(N)). The list is made again when the vehicles changed (added, removed,
    /// reordered) or one of them moved more than half the margin since: until then no pair off
    /// the list can have come within its radii, so the contacts are those a search of every
    /// neighbour finds, at a fraction of the cost (a Verlet list, as molecular dynamics keeps
    /// them: Verlet 1967, Phys. Rev. 159, 98). At the dynamics rate the full search was a sixth
    /// of a 10,000-vehicle town's time.
    fn record_collisions<'a>(
        &mut self,
        t: f64,
        parallelism: Parallelism,
        everyone: impl Iterator<Item = (VehicleId, &'a VehicleState, &'a VehicleSize, bool, u32)>,
        separated: &(dyn Fn(u32, u32) -> bool + Sync),
    ) {
        self.boxes.clear();
        self.box_lanelets.clear();
        let mut widest: f64 = 0.0;
        // The headings' sines and cosines (a tenth of this serial pass) are taken after it, split
        // over threads: the axis here holds the yaw until then.
        for (id, state, size, fixed, lanelet) in everyone {
            self.box_lanelets.push(lanelet);
            let half = 0.5 * DVec2::new(size.length, size.width);
            let b = Footprint {
                id,
                fixed,
                centre: state.position,
                axis: DVec2::new(state.yaw, 0.0),
                half,
                velocity: state.velocity,
            };
            widest = widest.max(b.radius());
            self.boxes.push(b);
        }
        parallelism.for_each_chunk(&mut self.boxes, &mut self.axis_chunks, |chunk, _| {
            for b in chunk {
                b.axis = DVec2::from_angle(b.axis.x);
            }
        });
        if self.near_is_stale() && !self.patch_near_list(widest) {
            self.make_near_list(widest, parallelism);
        }
        // Every pair of the list tested, split over threads (read-only; each chunk keeps its own
        // pairs, then sorted: the same list on any thread count).
        let boxes = &self.boxes;
        let lanelets = &self.box_lanelets;
        parallelism.for_each_chunk_at(&mut self.near, &mut self.touching_chunks, |_, chunk, found| {
            found.0.clear();
            for &(i, j) in chunk.iter() {
                let (a, b) = (&boxes[i as usize], &boxes[j as usize]);
                if !(a.fixed && b.fixed) && overlap(a, b) && !separated(lanelets[i as usize], lanelets[j as usize]) {
                    found.0.push((a.id, b.id));
                }
            }
        });
        // This call's chunks only: values past them hold an earlier call's pairs (a call with
        // more chunks, before the world fell under `min_vehicles`).
        let chunks = parallelism.chunks_for(self.near.len());
        self.touching.clear();
        for found in self.touching_chunks.iter().take(chunks) {
            self.touching.extend_from_slice(&found.0);
        }
        self.touching.sort_unstable();
        for &pair in &self.touching {
            if !self.contacts.contains(&pair) {
                self.collisions.push(Collision { a: pair.0, b: pair.1, t });
                self.collided.entry(pair.0).or_insert(t);
                self.collided.entry(pair.1).or_insert(t);
            }
        }
        self.contacts.clear();
        self.contacts.extend(self.touching.iter().copied());
    }

    /// The near list's margin now \[m\].
    fn margin(&self) -> f64 {
        if self.margin > 0.0 { self.margin } else { NEAR_MARGIN }
    }

    /// Whether the near list no longer covers every pair that can touch: the vehicles are not
    /// the ones it was made for, in the same order, or one moved more than half the margin
    /// (or to a position that is not a number).
    fn near_is_stale(&self) -> bool {
        let half2 = 0.25 * self.near_margin * self.near_margin;
        self.near_margin != self.margin()
            || self.near_at.len() != self.boxes.len()
            || self.boxes.iter().zip(&self.near_at).any(|(b, &(id, at))| {
                b.id != id || b.centre.distance_squared(at).partial_cmp(&half2) != Some(std::cmp::Ordering::Less)
            })
    }

    /// Make the near list: each pair (box indices, lower id first) whose centres are within
    /// their radii plus [`NEAR_MARGIN`], found on a grid of the widest footprint plus the margin.
    fn make_near_list(&mut self, widest: f64, parallelism: Parallelism) {
        let margin = self.margin();
        self.near_margin = margin;
        let boxes = &self.boxes;
        let reach = 2.0 * widest + margin;
        self.grid.rebuild(
            reach.max(1.0),
            boxes.iter().enumerate().map(|(i, b)| GridEntry {
                position: b.centre,
                velocity: DVec2::ZERO,
                id: b.id,
                index: i as u32,
            }),
        );
        let grid = &self.grid;
        let mut none = vec![(); boxes.len()];
        parallelism.for_each_chunk_at(&mut none, &mut self.near_chunks, |start, chunk, found| {
            found.0.clear();
            for (k, a) in boxes[start..start + chunk.len()].iter().enumerate() {
                let i = (start + k) as u32;
                grid.for_each_within(a.centre, a.radius() + widest + margin, |_, e, d2| {
                    let b = &boxes[e.index as usize];
                    let r = a.radius() + b.radius() + margin;
                    if a.id < b.id && d2 <= r * r {
                        found.0.push((i, e.index));
                    }
                });
            }
        });
        // This call's chunks only: on the 20x20 SUMO grid, once fewer than 2,000 vehicles were
        // left (one chunk), the chunks of the last split call still held pairs of indices past
        // the end of the boxes, and the run panicked (issue 54).
        let chunks = parallelism.chunks_for(boxes.len());
        self.near.clear();
        for found in self.near_chunks.iter().take(chunks) {
            self.near.extend_from_slice(&found.0);
        }
        self.near_at.clear();
        self.near_at.extend(boxes.iter().map(|b| (b.id, b.centre)));
        self.box_of.clear();
        self.box_of.extend(boxes.iter().enumerate().map(|(i, b)| (b.id, i as u32)));
        self.near_widest = widest;
        self.unlisted.clear();
    }

    /// Bring the near list up to date with vehicles added, removed or reordered since it was
    /// made, without searching every vehicle's neighbours again: the pairs of the vehicles
    /// still there are kept (renumbered), and each new vehicle's are found on the list's grid
    /// and among the vehicles added since the grid was made. Every vehicle keeps the anchor
    /// it was listed at (`near_at`), so the list still holds every pair whose anchors lie
    /// within their radii plus the margin. Returns false, changing nothing, where the list must
    /// be made in full: a vehicle moved half the margin from its anchor, one is wider than the
    /// grid's reach, the margin changed, or many were added since the last full making. (With
    /// SUMO demand a vehicle enters or leaves nearly every step: the list was made in full every
    /// step, a tenth of a 20 x 20 town's time.)
    fn patch_near_list(&mut self, widest: f64) -> bool {
        /// More vehicles added since the last full making than this: make it in full.
        const MAX_UNLISTED: usize = 64;
        let margin = self.near_margin;
        if margin != self.margin() || widest > self.near_widest || self.near_at.is_empty() {
            return false;
        }
        let half2 = 0.25 * margin * margin;
        let n_old = self.near_at.len();
        self.old_to_new.clear();
        self.old_to_new.resize(n_old, u32::MAX);
        self.new_at.clear();
        self.added.clear();
        for (k, b) in self.boxes.iter().enumerate() {
            let old = if self.near_at.get(k).is_some_and(|&(id, _)| id == b.id) {
                Some(k)
            } else {
                self.box_of
                    .get(&b.id)
                    .map(|&o| o as usize)
                    .filter(|&o| self.near_at.get(o).is_some_and(|&(id, _)| id == b.id))
            };
            match old {
                Some(o) if self.old_to_new[o] == u32::MAX => {
                    let at = self.near_at[o].1;
                    if b.centre.distance_squared(at).partial_cmp(&half2) != Some(std::cmp::Ordering::Less) {
                        return false;
                    }
                    self.old_to_new[o] = k as u32;
                    self.new_at.push((b.id, at));
                }
                // A vehicle listed twice under one id: no renumbering can say which is which.
                Some(_) => return false,
                None => {
                    if !b.centre.is_finite() {
                        return false;
                    }
                    self.added.push(k as u32);
                    self.new_at.push((b.id, b.centre));
                }
            }
        }
        if self.unlisted.len() + self.added.len() > MAX_UNLISTED {
            return false;
        }
        // From here on the patch goes through.
        let old_to_new = &self.old_to_new;
        self.near.retain_mut(|(i, j)| match (old_to_new[*i as usize], old_to_new[*j as usize]) {
            (u32::MAX, _) | (_, u32::MAX) => false,
            (a, b) => {
                (*i, *j) = (a, b);
                true
            }
        });
        for (o, &k) in self.old_to_new.iter().enumerate() {
            if k == u32::MAX {
                let id = self.near_at[o].0;
                if self.box_of.get(&id) == Some(&(o as u32)) {
                    self.box_of.remove(&id);
                }
            }
        }
        for (k, b) in self.boxes.iter().enumerate() {
            if self.near_at.get(k).is_none_or(|&(id, _)| id != b.id) {
                self.box_of.insert(b.id, k as u32);
            }
        }
        std::mem::swap(&mut self.near_at, &mut self.new_at);
        // Pairs of each added vehicle: with those on the grid (anchored where the grid has them),
        // with those added before it since (not on it), and with each other.
        let (boxes, near_at, box_of, added, unlisted) =
            (&self.boxes, &self.near_at, &self.box_of, &self.added, &self.unlisted);
        let pair = |i: u32, j: u32| {
            let (a, b) = (&boxes[i as usize], &boxes[j as usize]);
            let r = a.radius() + b.radius() + margin;
            let d2 = near_at[i as usize].1.distance_squared(near_at[j as usize].1);
            (i != j && d2 <= r * r).then(|| if a.id < b.id { (i, j) } else { (j, i) })
        };
        for (n, &k) in added.iter().enumerate() {
            let a = &boxes[k as usize];
            let near = &mut self.near;
            self.grid.for_each_within(a.centre, a.radius() + self.near_widest + margin, |_, e, _| {
                let Some(&j) = box_of.get(&e.id) else { return };
                // Only one still anchored where the grid has it (not one that left and came
                // back), and once: not one found below.
                if near_at[j as usize].1 == e.position
                    && !unlisted.contains(&e.id)
                    && !added.contains(&j)
                    && let Some(p) = pair(k, j)
                {
                    near.push(p);
                }
            });
            for id in unlisted {
                if let Some(&j) = box_of.get(id)
                    && !added.contains(&j)
                    && let Some(p) = pair(k, j)
                {
                    near.push(p);
                }
            }
            for &j in &added[..n] {
                if let Some(p) = pair(k, j) {
                    near.push(p);
                }
            }
        }
        self.unlisted.extend(self.added.iter().map(|&k| boxes[k as usize].id));
        true
    }
}

/// How much nearer than their radii two vehicles' centres may be to be on the collision near
/// list \[m\]: the list is made again when a vehicle has moved half of it (every fifth step at
/// 14 m/s and 50 Hz); a wider margin lists more pairs.
const NEAR_MARGIN: f64 = 3.0;

/// The near list's margin \[m\] at a dynamics step of `dt` \[s\]: [`NEAR_MARGIN`] at 50 Hz, and
/// wider at coarser steps, so that the list lasts as many steps of a vehicle at 14 m/s (at
/// SUMO's 0.1 s a 3 m list was made again every step or two, a tenth of a 20 x 20 town's time).
fn near_margin(dt: f64) -> f64 {
    (NEAR_MARGIN * dt / 0.02).clamp(NEAR_MARGIN, 5.0 * NEAR_MARGIN)
}

/// `metrics.intersection` of `summary.json`: the GCDC 2016 cooperative intersection (vehicles
/// with `controller.intersection`, from the moment they heard the roadside unit).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct IntersectionSummary {
    /// Participants: vehicles whose route passes the announced junction.
    pub vehicles: usize,
    /// Of which the rear has left the zone (the end of its last junction link).
    pub crossed: usize,
    /// Participants in the order their fronts entered the zone (passed the stop line).
    pub order: Vec<VehicleId>,
    /// Smallest distance between the footprints of two participants on conflicting links
    /// (crossing or merging) while one of them is in the conflict area of the point where their
    /// links meet (front within `CLEAR` = 2.5 m before it, rear not 2.5 m past it) \[m\]; `None`
    /// (JSON `null`) if that never happened. Away from the conflict areas their paths do not
    /// meet: a left turner that has reached the far arm passes the vehicles waiting there on the
    /// opposite lane at a lane's width minus a car's (1.8 m here), as on any two-way road.
    pub min_gap_m: Option<f64>,
    /// Smallest post-encroachment time over the conflict points \[s\]: the time from the first
    /// vehicle's rear clearing a point to the second's front reaching it (0 if both were on it
    /// at once); `None` if no two conflicting participants passed a common point.
    pub min_time_gap_s: Option<f64>,
    /// Mean delay of the participants that crossed \[s\]: the time from hearing the unit to the
    /// rear leaving the zone, minus driving the same distance at its starting speed (its cruise
    /// speed if it started below 1 m/s), slowed to the links' curve speeds inside the zone.
    pub mean_delay_s: Option<f64>,
    /// Platoon members that entered the zone with a vehicle on a conflicting link between them
    /// and the member of their platoon before them (the platoon was cut: some of it waited for a
    /// foe): 0 when every platoon crossed as one. Vehicles on links that never meet theirs may
    /// enter in between without cutting it.
    pub platoon_splits: usize,
}

/// One participant as the intersection metrics follow it.
#[derive(Debug, Clone, PartialEq)]
struct IntersectionTrack {
    start_t: f64,
    free_time: f64,
    link: u32,
    platoon: Option<VehicleId>,
    entered: Option<f64>,
    cleared: Option<f64>,
    /// Per conflict point of its first link: the foe link, the route arc length of the point
    /// \[m\], when the front reached it and when the rear cleared it \[s\].
    points: Vec<(u32, f64, Option<f64>, Option<f64>)>,
}

/// What [`record_intersection`] has measured so far.
#[derive(Resource, Debug, Default)]
pub struct IntersectionLog {
    tracks: BTreeMap<VehicleId, IntersectionTrack>,
    /// Pairs of participants' links that conflict (both orders), as met.
    conflicts: BTreeSet<(u32, u32)>,
    order: Vec<VehicleId>,
    min_gap: Option<f64>,
    near: Vec<(VehicleId, u32, f64, f64, Footprint)>,
}

/// Distance between two oriented rectangles \[m\] (0 when they overlap): the shortest from a
/// corner of one to an edge of the other.
fn footprint_distance(a: &Footprint, b: &Footprint) -> f64 {
    if overlap(a, b) {
        return 0.0;
    }
    let corners = |f: &Footprint| {
        let (u, v) = (f.axis * f.half.x, f.axis.perp() * f.half.y);
        [f.centre + u + v, f.centre - u + v, f.centre - u - v, f.centre + u - v]
    };
    let to_segment = |p: DVec2, q0: DVec2, q1: DVec2| {
        let d = q1 - q0;
        let t = if d.length_squared() > 0.0 { ((p - q0).dot(d) / d.length_squared()).clamp(0.0, 1.0) } else { 0.0 };
        p.distance(q0 + t * d)
    };
    let (ca, cb) = (corners(a), corners(b));
    let mut best = f64::INFINITY;
    for (from, to) in [(&ca, &cb), (&cb, &ca)] {
        for &p in from {
            for k in 0..4 {
                best = best.min(to_segment(p, to[k], to[(k + 1) % 4]));
            }
        }
    }
    best
}

/// Post-encroachment time \[s\] of two passages of one conflict point, each (front reaches,
/// rear clears) \[s\]: from the first one's clearing to the second one's reaching; 0 when they
/// were on it at once.
pub fn post_encroachment(a: (f64, f64), b: (f64, f64)) -> f64 {
    if a.1 <= b.0 {
        b.0 - a.1
    } else if b.1 <= a.0 {
        a.0 - b.1
    } else {
        0.0
    }
}

/// Whether links `a` and `b` of `network` conflict.
fn links_conflict(network: &crate::vehicles::JunctionNetwork, a: u32, b: u32) -> bool {
    network.links.get(a as usize).is_some_and(|l| l.conflicts.iter().any(|c| c.foe == b))
}

/// After every dynamics step: entries, clearings and conflict-point passages of the
/// intersection participants, and the smallest footprint distance of conflicting pairs at their
/// conflict areas (pairs among the few vehicles at the zone only, so the step stays O(N)).
#[allow(clippy::type_complexity)]
pub fn record_intersection(
    clock: Res<SimClock>,
    network: Option<Res<crate::vehicles::JunctionNetwork>>,
    mut log: ResMut<IntersectionLog>,
    vehicles: Query<(
        &VehicleId,
        &VehicleState,
        &VehicleSize,
        &PathFollower,
        &crate::vehicles::IntersectionNegotiator,
        Option<&PlatoonMember>,
    )>,
) {
    let Some(net) = network else { return };
    let t = clock.now.as_secs() + clock.dt;
    let log = &mut *log;
    log.near.clear();
    for (&id, state, size, follower, neg, member) in &vehicles {
        let Some(zone) = &neg.zone else { continue };
        let Some(&(link, link_start)) = zone.links.first() else { continue };
        let half = 0.5 * size.length;
        let (front, rear) = (follower.s + half, follower.s - half);
        let track = log.tracks.entry(id).or_insert_with(|| {
            let v0 = state.speed();
            let v_free = if v0 > 1.0 { v0 } else { follower.params.speed.max(1.0) };
            let v_in = zone
                .links
                .iter()
                .filter_map(|&(g, _)| net.links.get(g as usize).map(|l| l.curve_speed))
                .fold(v_free, f64::min)
                .max(0.5);
            let approach = (zone.entry - front).max(0.0);
            let through = zone.exit - zone.entry.max(front) + size.length;
            let points = net
                .links
                .get(link as usize)
                .map(|l| l.conflicts.iter().map(|c| (c.foe, link_start + c.s_mine, None, None)).collect())
                .unwrap_or_default();
            IntersectionTrack {
                start_t: t,
                free_time: approach / v_free + through.max(0.0) / v_in,
                link,
                platoon: None,
                entered: None,
                cleared: None,
                points,
            }
        });
        if track.entered.is_none() && front >= zone.entry {
            if let Some(l) = net.links.get(link as usize) {
                log.conflicts.extend(l.conflicts.iter().flat_map(|c| [(link, c.foe), (c.foe, link)]));
            }
            track.entered = Some(t);
            track.platoon = member.and_then(|m| if m.lead { Some(id) } else { m.platoon });
            log.order.push(id);
        }
        if track.cleared.is_none() && rear > zone.exit {
            track.cleared = Some(t);
        }
        for p in &mut track.points {
            if p.2.is_none() && front >= p.1 {
                p.2 = Some(t);
            }
            if p.3.is_none() && rear >= p.1 {
                p.3 = Some(t);
            }
        }
        if front >= zone.entry - 10.0 && rear <= zone.exit + 10.0 {
            let f = Footprint::of(id, false, state.position, state.yaw, size);
            log.near.push((id, link, front, rear, f));
        }
    }
    let tracks = &log.tracks;
    // Whether vehicle `v` is in the conflict area of its link's meeting point with `foe`.
    let at_point = |v: &(VehicleId, u32, f64, f64, Footprint), foe: u32| {
        tracks.get(&v.0).is_some_and(|k| {
            k.points.iter().any(|p| {
                p.0 == foe
                    && v.2 >= p.1 - crate::vehicles::right_of_way::CLEAR
                    && v.3 <= p.1 + crate::vehicles::right_of_way::CLEAR
            })
        })
    };
    let mut best = log.min_gap;
    for i in 0..log.near.len() {
        for j in i + 1..log.near.len() {
            let (a, b) = (&log.near[i], &log.near[j]);
            if (at_point(a, b.1) || at_point(b, a.1)) && links_conflict(&net, a.1, b.1) {
                let d = footprint_distance(&a.4, &b.4);
                if best.is_none_or(|m| d < m) {
                    tracing::debug!(target: "intersection", "gap {d:.2} m between {} and {} at {t:.2} s", a.0, b.0);
                    best = Some(d);
                }
            }
        }
    }
    log.min_gap = best;
}

impl IntersectionLog {
    /// `metrics.intersection`, or `None` when nobody took part.
    pub fn summary(&self) -> Option<IntersectionSummary> {
        if self.tracks.is_empty() {
            return None;
        }
        let delays: Vec<f64> =
            self.tracks.values().filter_map(|k| Some(k.cleared? - k.start_t - k.free_time)).collect();
        let entries: Vec<(Option<VehicleId>, u32)> =
            self.order.iter().filter_map(|id| self.tracks.get(id)).map(|k| (k.platoon, k.link)).collect();
        let mut min_pet: Option<f64> = None;
        let list: Vec<&IntersectionTrack> = self.tracks.values().collect();
        for (i, a) in list.iter().enumerate() {
            for b in &list[i + 1..] {
                let on_a = a.points.iter().find(|p| p.0 == b.link);
                let on_b = b.points.iter().find(|p| p.0 == a.link);
                if let (Some(&(_, _, Some(ra), Some(ca))), Some(&(_, _, Some(rb), Some(cb)))) = (on_a, on_b) {
                    let pet = post_encroachment((ra, ca), (rb, cb));
                    min_pet = Some(min_pet.map_or(pet, |m| m.min(pet)));
                }
            }
        }
        Some(IntersectionSummary {
            vehicles: self.tracks.len(),
            crossed: self.tracks.values().filter(|k| k.cleared.is_some()).count(),
            order: self.order.clone(),
            min_gap_m: self.min_gap,
            min_time_gap_s: min_pet,
            mean_delay_s: (!delays.is_empty()).then(|| delays.iter().sum::<f64>() / delays.len() as f64),
            platoon_splits: platoon_splits(&entries, |a, b| self.conflicts.contains(&(a, b))),
        })
    }
}

/// Members of a platoon that entered with a vehicle on a conflicting link between them and the
/// member of their platoon that entered before them. `entries`: (platoon, link) of each vehicle
/// in entry order; `conflict(a, b)`: whether links `a` and `b` meet.
pub fn platoon_splits(entries: &[(Option<VehicleId>, u32)], conflict: impl Fn(u32, u32) -> bool) -> usize {
    let mut last: BTreeMap<VehicleId, usize> = BTreeMap::new();
    let mut splits = 0;
    for (k, &(platoon, link)) in entries.iter().enumerate() {
        let Some(p) = platoon else { continue };
        if let Some(&before) = last.get(&p)
            && entries[before + 1..k].iter().any(|e| e.0 != Some(p) && conflict(e.1, link))
        {
            splits += 1;
        }
        last.insert(p, k);
    }
    splits
}

/// Records [`Metrics`] after every dynamics step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MetricsPlugin {
    /// Start-up time skipped by the statistics (not by collisions) \[s\].
    pub warmup: f64,
}

impl Default for MetricsPlugin {
    fn default() -> Self {
        MetricsPlugin { warmup: 5.0 }
    }
}

impl Plugin for MetricsPlugin {
    fn build(&self, sim: &mut SimBuilder) {
        sim.insert_resource(Metrics::new(self.warmup));
        sim.insert_resource(IntersectionLog::default());
        sim.add_systems(
            Dynamics,
            (record_metrics, record_route_deviation, record_intersection).after(SimSystems::Integrate),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn footprint(x: f64, y: f64, yaw: f64) -> Footprint {
        Footprint::of(VehicleId(0), false, DVec2::new(x, y), yaw, &VehicleSize { length: 4.0, width: 2.0 })
    }

    /// Each follower's statistics stay its own while the query's vehicles change: a follower
    /// removed (the last vehicle moves into its row, the query's order changes), one that
    /// changes leader, one that appears later. Counts and smallest gaps per follower, from
    /// the ground truth of a straight road.
    #[test]
    fn follower_statistics_follow_their_vehicle_when_the_query_changes() {
        use bevy_ecs::prelude::{Entity, World};
        use bevy_ecs::system::RunSystemOnce;

        use crate::vehicles::{LeaderGap, PathFollowing};
        use crate::world::SimTime;

        let points: Vec<DVec2> = (0..=500).map(|i| DVec2::new(i as f64, 0.0)).collect();
        let route = Route(std::sync::Arc::new(crate::map::Path::from_points(Vec::new(), points, false)));
        let size = VehicleSize { length: 4.0, width: 2.0 };
        let mut world = World::new();
        world.insert_resource(SimClock { now: SimTime::from_secs(0.0), dt: 0.02 });
        world.insert_resource(Metrics::new(0.0));
        // Vehicle i stands at x = 20 i, following vehicle `leader` (centre to centre along the road).
        let spawn = |world: &mut World, i: i32, leader: Option<i32>| -> Entity {
            let x = 20.0 * i as f64;
            let leader = leader.map(|l| LeaderGap {
                id: VehicleId(l),
                distance: 20.0 * (l - i) as f64,
                gap: 0.0,
                speed: 0.0,
                acceleration: 0.0,
            });
            world
                .spawn((
                    VehicleId(i),
                    VehicleState::new(DVec2::new(x, 0.0), 0.0, 2.0),
                    size,
                    route.clone(),
                    PathFollower::starting_at(PathFollowing::default(), x),
                    Longitudinal { leader, ..Default::default() },
                ))
                .id()
        };
        let entities: Vec<Entity> = (1..=5).map(|i| spawn(&mut world, i, (i < 5).then_some(i + 1))).collect();
        let run = |world: &mut World, steps: usize| {
            for _ in 0..steps {
                world.run_system_once(record_metrics).expect("the system runs");
            }
        };
        run(&mut world, 10);
        // Vehicle 2 leaves; 1 now follows 3 (at 40 m); 4 loses its leader; 6 appears behind 1.
        world.despawn(entities[1]);
        world.entity_mut(entities[0]).get_mut::<Longitudinal>().expect("1 drives").leader =
            Some(LeaderGap { id: VehicleId(3), distance: 40.0, gap: 0.0, speed: 0.0, acceleration: 0.0 });
        world.entity_mut(entities[3]).get_mut::<Longitudinal>().expect("4 drives").leader = None;
        spawn(&mut world, 0, Some(1));
        run(&mut world, 7);
        let followers = world.resource::<Metrics>().summary().followers;
        let got: Vec<(i32, i32, u64, f64)> =
            followers.iter().map(|f| (f.id.0, f.leader.0, f.samples, f.min_gap)).collect();
        assert_eq!(got, vec![(0, 1, 7, 16.0), (1, 3, 17, 16.0), (2, 3, 10, 16.0), (3, 4, 17, 16.0), (4, 5, 10, 16.0)]);
        let one = followers.iter().find(|f| f.id == VehicleId(1)).expect("1 follows");
        // All drive at 2 m/s: no speed error.
        assert_eq!(one.speed_error_rms, 0.0);
    }

    /// The touching pairs (lower id first, sorted) a test of every pair of `metrics`' boxes
    /// finds: what the near list must give.
    fn touching_by_every_pair(metrics: &Metrics) -> Vec<(VehicleId, VehicleId)> {
        let mut expected = Vec::new();
        for (k, a) in metrics.boxes.iter().enumerate() {
            for b in &metrics.boxes[k + 1..] {
                let (a, b) = if a.id < b.id { (a, b) } else { (b, a) };
                if !(a.fixed && b.fixed) && overlap(a, b) {
                    expected.push((a.id, b.id));
                }
            }
        }
        expected.sort_unstable();
        expected
    }

    /// The near list finds exactly the overlapping pairs a test of every pair finds, step after
    /// step, while vehicles drift (slowly: the list lives for several steps; and in jumps that
    /// must remake it), one is removed and the others are reordered. On two threads split from
    /// 200 vehicles: the removal leaves 199, one chunk (the run that read the split call's
    /// chunks too panicked there).
    #[test]
    fn collisions_from_the_near_list_are_those_of_every_pair() {
        let mut next = crate::world::random::draws(0x2545_f491_4f6c_dd1d);
        let size = VehicleSize { length: 4.5, width: 1.8 };
        let mut cars: Vec<(VehicleId, VehicleState, bool)> = (0..200)
            .map(|i| {
                let state = VehicleState::new(DVec2::new(60.0 * next(), 60.0 * next()), 6.3 * next(), 0.0);
                (VehicleId(i), state, i % 17 == 0)
            })
            .collect();
        let mut metrics = Metrics::new(0.0);
        let mut remade = 0;
        let mut found = 0;
        for step in 0..300 {
            let jump = if step % 50 == 49 { 4.0 } else { 0.3 };
            for (_, state, _) in cars.iter_mut() {
                let position = state.position + jump * DVec2::new(next() - 0.5, next() - 0.5);
                *state = VehicleState::new(position, state.yaw + 0.1 * (next() - 0.5), 0.0);
            }
            if step == 120 {
                cars.remove(7);
                cars.reverse();
            }
            let before = metrics.near_at.clone();
            metrics.record_collisions(
                step as f64,
                Parallelism { threads: 2, min_vehicles: 200 },
                cars.iter().map(|(id, st, fixed)| (*id, st, &size, *fixed, u32::MAX)),
                &|_, _| false,
            );
            remade += usize::from(metrics.near_at != before);
            let expected = touching_by_every_pair(&metrics);
            assert_eq!(metrics.touching, expected, "step {step}");
            found += expected.len();
        }
        assert!(found > 100, "the vehicles touched {found} times: the test needs contacts");
        assert!((10..250).contains(&remade), "the near list was made {remade} times in 300 steps");
    }

    /// With vehicles entering and leaving every step (SUMO demand), the near list still finds
    /// exactly the overlapping pairs a test of every pair finds, but is patched (the vehicles
    /// still there keep their anchors) instead of made in full at every step: before the patch
    /// every step with a new or a gone vehicle made it in full.
    #[test]
    fn the_near_list_follows_vehicles_entering_and_leaving_without_being_made_in_full_each_step() {
        let mut next = crate::world::random::draws(0x9e37_79b9_7f4a_7c15);
        let size = VehicleSize { length: 4.5, width: 1.8 };
        let car = |id: i32, next: &mut dyn FnMut() -> f64| {
            let state = VehicleState::new(DVec2::new(80.0 * next(), 80.0 * next()), 6.3 * next(), 0.0);
            (VehicleId(id), state, id % 13 == 0)
        };
        let mut cars: Vec<(VehicleId, VehicleState, bool)> = (0..300).map(|i| car(i, &mut next)).collect();
        let mut metrics = Metrics::new(0.0);
        let (mut full, mut found, mut new_id) = (0, 0, 300);
        for step in 0..200 {
            for (_, state, _) in cars.iter_mut() {
                let position = state.position + 0.2 * DVec2::new(next() - 0.5, next() - 0.5);
                *state = VehicleState::new(position, state.yaw + 0.1 * (next() - 0.5), 0.0);
            }
            // One leaves (anywhere in the list), one or two enter (at the end, or in the middle).
            let gone = (next() * cars.len() as f64) as usize % cars.len();
            cars.swap_remove(gone);
            for _ in 0..1 + step % 2 {
                let entering = car(new_id, &mut next);
                new_id += 1;
                let at = if step % 3 == 0 { cars.len() / 2 } else { cars.len() };
                cars.insert(at, entering);
            }
            metrics.record_collisions(
                step as f64,
                Parallelism { threads: 2, min_vehicles: 100 },
                cars.iter().map(|(id, st, fixed)| (*id, st, &size, *fixed, u32::MAX)),
                &|_, _| false,
            );
            full += usize::from(metrics.near_at.iter().zip(&metrics.boxes).all(|(a, b)| a.1 == b.centre));
            let expected = touching_by_every_pair(&metrics);
            assert_eq!(metrics.touching, expected, "step {step}");
            found += expected.len();
            // The follower statistics find each vehicle's box by its id.
            for (k, b) in metrics.boxes.iter().enumerate() {
                assert_eq!(metrics.box_of.get(&b.id), Some(&(k as u32)), "step {step}: box of {}", b.id);
            }
            assert_eq!(metrics.box_of.len(), metrics.boxes.len(), "step {step}: boxes of vehicles that left");
        }
        assert!(found > 100, "the vehicles touched {found} times: the test needs contacts");
        assert!((2..100).contains(&full), "the near list was made in full {full} times in 200 steps");
    }

    #[test]
    fn footprint_distance_is_zero_on_overlap_and_the_clearance_otherwise() {
        // 4 x 2 m boxes: side by side 3.5 m apart (centres) leave 1.5 m; nose to tail 10 m
        // apart leave 6 m; overlapping: 0.
        assert!((footprint_distance(&footprint(0.0, 0.0, 0.0), &footprint(0.0, 3.5, 0.0)) - 1.5).abs() < 1e-12);
        assert!((footprint_distance(&footprint(0.0, 0.0, 0.0), &footprint(10.0, 0.0, 0.0)) - 6.0).abs() < 1e-12);
        assert_eq!(footprint_distance(&footprint(0.0, 0.0, 0.0), &footprint(1.0, 0.5, 0.3)), 0.0);
        // Crossing at right angles: a corner of the turned box 1 m from the other's nose.
        let d = footprint_distance(&footprint(0.0, 0.0, 0.0), &footprint(4.0, 0.0, std::f64::consts::FRAC_PI_2));
        assert!((d - 1.0).abs() < 1e-9, "{d}");
    }

    #[test]
    fn post_encroachment_runs_from_the_first_clearing_to_the_second_reaching() {
        assert_eq!(post_encroachment((1.0, 2.0), (3.5, 4.0)), 1.5);
        assert_eq!(post_encroachment((3.5, 4.0), (1.0, 2.0)), 1.5);
        // On the point at once.
        assert_eq!(post_encroachment((1.0, 3.0), (2.0, 4.0)), 0.0);
    }

    #[test]
    fn a_platoon_is_split_only_by_a_conflicting_vehicle_entering_between_its_members() {
        let (p, q) = (Some(VehicleId(-1)), Some(VehicleId(-11)));
        // Links 0 and 1 meet, 2 meets neither.
        let conflict = |a: u32, b: u32| matches!((a, b), (0, 1) | (1, 0));
        // Platoon p on link 0 with a vehicle on link 2 in between: together.
        assert_eq!(platoon_splits(&[(p, 0), (None, 2), (p, 0), (p, 0)], conflict), 0);
        // A vehicle on link 1 in between: cut once.
        assert_eq!(platoon_splits(&[(p, 0), (None, 1), (p, 0), (p, 0)], conflict), 1);
        // Two platoons alternating on conflicting links: each member after the first is cut.
        assert_eq!(platoon_splits(&[(p, 0), (q, 1), (p, 0), (q, 1)], conflict), 2);
        assert_eq!(platoon_splits(&[], conflict), 0);
    }

    fn platoon(ranges: &[(f64, f64)]) -> Metrics {
        let mut m = Metrics::new(0.0);
        let members = ranges
            .iter()
            .enumerate()
            .map(|(k, &(min_speed, max_speed))| {
                (VehicleId(-(k as i32) - 1), MemberStats { index: k as u32, min_speed, max_speed })
            })
            .collect();
        m.platoons.insert(VehicleId(-1), members);
        m
    }

    /// Issue 10: a run that ends before the leader brakes has a leader range of ~1e-13 m/s; the
    /// summary says "no disturbance" instead of a ratio of two rounding errors.
    #[test]
    fn a_leader_that_never_changed_speed_is_no_disturbance() {
        let s = platoon(&[(15.0, 15.0 + 6.6e-14), (15.0, 15.0 + 1.6e-1)]).summary();
        assert_eq!(s.platoons[0].amplification, None);
        assert_eq!(s.platoons[0].note, Some("no disturbance"));
        let json = serde_json::to_value(&s.platoons[0]).expect("a platoon summary serialises");
        assert!(json["amplification"].is_null() && json["note"] == "no disturbance", "{json}");
        let s = platoon(&[(10.0, 15.0), (11.0, 14.0)]).summary();
        assert_eq!(s.platoons[0].amplification, Some(3.0 / 5.0));
        assert_eq!(s.platoons[0].note, None);
    }
}

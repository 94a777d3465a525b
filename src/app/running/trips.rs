//! Trips, as SUMO's tripinfo counts them: every vehicle that drives a route (background traffic,
//! and scenario vehicles on an open route) carries a [`Trip`] from its departure: when it left,
//! how long its route is, how long it stood (speed below [`WAITING_SPEED`]) and how often it
//! came to a stand, and when it arrived (reached its route's end; traffic vehicles are then
//! removed and their trip moves into the [`TripLog`]). The run writes one row per vehicle into
//! `trips.csv` and the totals into `metrics.trips` of `summary.json`.
//!
//! Counting is sampled at the control rate: at every control tick a vehicle below
//! [`WAITING_SPEED`] adds the tick's step to its waiting time; a stop is a change from moving to
//! standing (a vehicle that departs standing has not stopped, as SUMO's `waitingCount` counts
//! the times the speed went below the threshold).

use bevy_ecs::prelude::{Component, Entity, Query, Res, Resource, World};
use bevy_ecs::schedule::{IntoScheduleConfigs, SystemSet};

use crate::sim::{Control, Plugin, SimBuilder, SimClock, SimSystems};
use crate::vehicles::PathFollower;
use crate::vehicles::lanes::PREFETCH_AHEAD;
use crate::world::{Route, VehicleId, VehicleState, Vehicles};

/// Below this speed a vehicle is waiting [m/s] (SUMO's threshold).
pub const WAITING_SPEED: f64 = 0.1;
/// A vehicle this close to the end of its open route has arrived \[m\] (the distance at which
/// traffic vehicles leave the world).
pub const ARRIVED_WITHIN: f64 = 5.0;

/// Time spent standing and stops, counted sample by sample ([`Waiting::sample`]).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Waiting {
    /// Time spent below [`WAITING_SPEED`] \[s\].
    pub time_s: f64,
    /// Changes from moving to standing.
    pub stops: u32,
    /// Whether the last sample was standing.
    pub standing: bool,
}

impl Waiting {
    /// Counting that starts at `speed` [m/s]: a vehicle that departs standing has not stopped.
    pub fn starting_at(speed: f64) -> Waiting {
        Waiting { time_s: 0.0, stops: 0, standing: speed < WAITING_SPEED }
    }

    /// One sample: the vehicle drives at `speed` [m/s] for the next `dt` \[s\].
    pub fn sample(&mut self, speed: f64, dt: f64) {
        let standing = speed < WAITING_SPEED;
        if standing {
            self.time_s += dt;
            if !self.standing {
                self.stops += 1;
            }
        }
        self.standing = standing;
    }
}

/// The trip of a vehicle on a route.
#[derive(Component, Debug, Clone, Copy, PartialEq)]
pub struct Trip {
    /// Sim time it departed \[s\].
    pub depart: f64,
    /// Length of its route from where it departed to the end \[m\] (one lap of a closed loop).
    pub route_length: f64,
    /// Sim time it reached its route's end \[s\]; `None` while driving.
    pub arrival: Option<f64>,
    /// Its waiting time and stops.
    pub waiting: Waiting,
    /// Where along the vehicle's route the trip ends \[m\], where the route runs on past its
    /// end (a town's vehicle whose next trip was drawn before it arrived); `None`: at the
    /// route's end.
    pub ends_at: Option<f64>,
}

impl Trip {
    /// A trip departing at `depart` \[s\] at `speed` [m/s] with `route_length` \[m\] to drive.
    pub fn new(depart: f64, route_length: f64, speed: f64) -> Trip {
        Trip { depart, route_length, arrival: None, waiting: Waiting::starting_at(speed), ends_at: None }
    }
}

/// One row of `trips.csv`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TripRecord {
    /// The vehicle.
    pub id: VehicleId,
    /// Its trip.
    pub trip: Trip,
}

impl TripRecord {
    /// Arrival − departure \[s\], `None` while driving.
    pub fn travel_time(&self) -> Option<f64> {
        self.trip.arrival.map(|a| a - self.trip.depart)
    }
}

/// Trips of the vehicles that have left the world.
#[derive(Resource, Debug, Clone, Default)]
pub struct TripLog {
    /// In the order they left.
    pub finished: Vec<TripRecord>,
}

/// End the trip of vehicle `id` (entity `entity`) at `t` \[s\] before it is removed: its trip,
/// arrived at `t` unless it arrived earlier, moves into the [`TripLog`]. Nothing happens for a
/// vehicle without a [`Trip`] or a world without the log.
pub fn end_trip(world: &mut World, id: VehicleId, entity: Entity, t: f64) {
    let Some(mut trip) = world.get::<Trip>(entity).copied() else { return };
    trip.arrival.get_or_insert(t);
    if let Some(mut log) = world.get_resource_mut::<TripLog>() {
        log.finished.push(TripRecord { id, trip });
    }
}

/// Sample every trip's waiting at this control tick and mark the vehicles that reached the end
/// of their open route as arrived (they no longer count waiting).
pub fn track_trips(
    clock: Res<SimClock>,
    mut trips: Query<(&VehicleState, &mut Trip, Option<&Route>, Option<&PathFollower>)>,
) {
    let (t, dt) = (clock.now.as_secs(), clock.dt);
    let track = |state: &VehicleState, trip: &mut Trip, route: Option<&Route>, follower: Option<&PathFollower>| {
        if trip.arrival.is_some() {
            return;
        }
        if let (Some(route), Some(follower)) = (route, follower)
            && !route.0.closed
            && trip.ends_at.unwrap_or(route.0.length) - follower.s < ARRIVED_WITHIN
        {
            trip.arrival = Some(t);
            return;
        }
        trip.waiting.sample(state.speed(), dt);
    };
    // Table by table, so that the route of a vehicle a few places on (its own, behind an `Arc`:
    // a cache miss each in a town, on one thread) is fetched while this one is looked at.
    if let Ok(tables) = trips.contiguous_iter_mut() {
        for (states, mut trips, routes, followers) in tables {
            let trips: &mut [Trip] = &mut trips;
            for (k, trip) in trips.iter_mut().enumerate() {
                if let Some(route) = routes.and_then(|r| r.get(k + PREFETCH_AHEAD)) {
                    crate::world::prefetch_value(&*route.0);
                }
                track(&states[k], trip, routes.map(|r| &r[k]), followers.map(|f| &f[k]));
            }
        }
        return;
    }
    // Only if a component were stored sparsely (none is): one at a time.
    for (state, mut trip, route, follower) in &mut trips {
        track(state, &mut trip, route, follower);
    }
}

/// Every trip of the run so far, in vehicle id order: those of the vehicles that left and of
/// those still in the world.
pub fn trip_records(world: &World) -> Vec<TripRecord> {
    let mut out: Vec<TripRecord> = world.get_resource::<TripLog>().map(|l| l.finished.clone()).unwrap_or_default();
    if let Some(vehicles) = world.get_resource::<Vehicles>() {
        out.extend(vehicles.iter().filter_map(|(id, e)| Some(TripRecord { id, trip: *world.get::<Trip>(e)? })));
    }
    out.sort_by_key(|r| r.id);
    out
}

/// Round `x` to `decimals` decimals (for figures written out).
fn round(x: f64, decimals: i32) -> f64 {
    let f = 10f64.powi(decimals);
    (x * f).round() / f + 0.0
}

/// `metrics.trips` of `summary.json`: travel times over the vehicles that arrived, waiting and
/// stops over every vehicle with a trip; times to 0.01 s. Means of nothing are `null`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct TripsSummary {
    /// Vehicles with a trip (traffic inserted or placed, scenario vehicles on open routes).
    pub inserted: u64,
    /// Of which reached their route's end.
    pub arrived: u64,
    /// Mean travel time of the arrived vehicles \[s\].
    pub mean_travel_time_s: Option<f64>,
    /// 95th percentile (nearest rank) of their travel times \[s\].
    pub p95_travel_time_s: Option<f64>,
    /// Mean waiting time (speed below 0.1 m/s) over every vehicle with a trip \[s\].
    pub mean_waiting_time_s: Option<f64>,
    /// Mean number of stops over every vehicle with a trip.
    pub mean_stops: Option<f64>,
}

impl TripsSummary {
    /// The totals of `records`.
    pub fn of(records: &[TripRecord]) -> TripsSummary {
        let mut travel: Vec<f64> = records.iter().filter_map(TripRecord::travel_time).collect();
        travel.sort_by(f64::total_cmp);
        let mean = |sum: f64, n: usize| (n > 0).then(|| round(sum / n as f64, 2));
        let p95 = (!travel.is_empty()).then(|| {
            let rank = ((0.95 * travel.len() as f64).ceil() as usize).clamp(1, travel.len());
            round(travel[rank - 1], 2)
        });
        TripsSummary {
            inserted: records.len() as u64,
            arrived: travel.len() as u64,
            mean_travel_time_s: mean(travel.iter().sum(), travel.len()),
            p95_travel_time_s: p95,
            mean_waiting_time_s: mean(records.iter().map(|r| r.trip.waiting.time_s).sum(), records.len()),
            mean_stops: mean(records.iter().map(|r| f64::from(r.trip.waiting.stops)).sum(), records.len()),
        }
    }
}

/// Header of `trips.csv`.
pub const TRIPS_HEADER: &str = "id,depart,arrival,route_length_m,travel_time_s,waiting_time_s,stops";

/// `trips.csv`: [`TRIPS_HEADER`], then one row per record: times \[s\] to 0.01 s, the route
/// length \[m\] to 0.1 m; `arrival` and `travel_time_s` empty for a vehicle still driving.
pub fn trips_csv(records: &[TripRecord]) -> String {
    use crate::app::results::output::Fixed;
    use std::fmt::Write;
    let mut out = String::with_capacity(64 * (records.len() + 1));
    out.push_str(TRIPS_HEADER);
    out.push('\n');
    for r in records {
        let t = &r.trip;
        let opt = |x: Option<f64>| x.map_or(String::new(), |x| Fixed(x, 2).to_string());
        // Writing into a String cannot fail.
        let _ = writeln!(
            out,
            "{},{},{},{},{},{},{}",
            r.id,
            Fixed(t.depart, 2),
            opt(t.arrival),
            Fixed(t.route_length, 1),
            opt(r.travel_time()),
            Fixed(t.waiting.time_s, 2),
            t.waiting.stops
        );
    }
    out
}

/// The set [`track_trips`] runs in; the traffic plugin orders its insertions and removals before
/// it (they depart and arrive at that tick).
#[derive(SystemSet, Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct TripsSystems;

/// Trip counting: the [`TripLog`] and [`track_trips`] at every control tick, after the traffic
/// systems (whose insertions depart and whose removals arrive at that tick).
#[derive(Debug, Clone, Copy, Default)]
pub struct TripsPlugin;

impl Plugin for TripsPlugin {
    fn build(&self, sim: &mut SimBuilder) {
        sim.world_mut().init_resource::<TripLog>();
        sim.configure_sets(Control, TripsSystems.in_set(SimSystems::Control));
        sim.add_systems(Control, track_trips.in_set(TripsSystems));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn waiting_counts_time_below_the_threshold_and_each_change_to_standing() {
        let mut w = Waiting::starting_at(10.0);
        for speed in [10.0, 0.05, 0.0, 5.0, 0.09, 0.1, 0.0] {
            w.sample(speed, 0.05);
        }
        // Standing at 0.05, 0.0 (one stop), 0.09 (two), 0.0 again after 0.1 (three); 0.1 is moving.
        assert_eq!(w.stops, 3);
        assert!((w.time_s - 4.0 * 0.05).abs() < 1e-12, "{}", w.time_s);
    }

    #[test]
    fn a_vehicle_departing_standing_waits_but_has_not_stopped() {
        let mut w = Waiting::starting_at(0.0);
        w.sample(0.0, 0.5);
        w.sample(0.0, 0.5);
        assert_eq!((w.stops, w.time_s), (0, 1.0));
        w.sample(3.0, 0.5);
        w.sample(0.0, 0.5);
        assert_eq!((w.stops, w.time_s), (1, 1.5));
    }

    fn record(id: i32, depart: f64, arrival: Option<f64>, waiting: f64, stops: u32) -> TripRecord {
        let waiting = Waiting { time_s: waiting, stops, standing: false };
        TripRecord { id: VehicleId(id), trip: Trip { depart, route_length: 123.456, arrival, waiting, ends_at: None } }
    }

    #[test]
    fn the_summary_takes_travel_times_of_the_arrived_and_waiting_of_everyone() {
        let mut records: Vec<TripRecord> = (0..20).map(|k| record(k, 0.0, Some(f64::from(k + 1)), 0.0, 0)).collect();
        records.push(record(100, 5.0, None, 21.0, 2));
        let s = TripsSummary::of(&records);
        assert_eq!((s.inserted, s.arrived), (21, 20));
        assert_eq!(s.mean_travel_time_s, Some(10.5));
        assert_eq!(s.p95_travel_time_s, Some(19.0), "nearest rank: the 19th of 20");
        assert_eq!(s.mean_waiting_time_s, Some(1.0));
        assert_eq!(s.mean_stops, Some(round(2.0 / 21.0, 2)));
        let none = TripsSummary::of(&[]);
        assert_eq!((none.mean_travel_time_s, none.p95_travel_time_s, none.mean_stops), (None, None, None));
    }

    #[test]
    fn the_csv_rounds_and_leaves_a_driving_vehicle_without_arrival() {
        let csv = trips_csv(&[record(-3, 1.234, Some(61.5), 2.0049, 1), record(7, 0.0, None, 0.0, 0)]);
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(lines, [TRIPS_HEADER, "-3,1.23,61.5,123.5,60.27,2,1", "7,0,,123.5,,0,0"]);
    }
}

//! Random traffic and trips (issue 53, items 5 and 6): `route = "random"` on a generated grid,
//! `trips.csv` and `metrics.trips`, routes `via` places, and bad route values refused by key.

use std::path::{Path, PathBuf};

use serde_json::Value;
use smlworld::app::Scenario;
use smlworld::app::running::random_trips::{MIN_TRIP_M, RandomTrips, random_route};
use smlworld::map::LaneletMap;
use smlworld::prelude::*;
use smlworld::world::Route;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn grid() -> LaneletMap {
    LaneletMap::load(&root().join("maps/grid_3x3.osm")).expect("the shipped grid loads")
}

/// A scenario on the 3 x 3 grid with random traffic: 8 placed at t = 0, 900 veh/h inserted.
fn random_scenario(dir: &Path) -> PathBuf {
    let text = format!(
        r#"map = "{}"
duration = 90.0
seed = 1

[[traffic]]
route = "random"
count = 8
rate = 900.0
until = 60.0
speed = [8.0, 12.0]
"#,
        root().join("maps/grid_3x3.osm").display()
    );
    std::fs::create_dir_all(dir).unwrap();
    let path = dir.join("random.toml");
    std::fs::write(&path, text).unwrap();
    path
}

/// Run the random scenario with `seed`; summary.json and the rows of trips.csv.
fn run(seed: u64, name: &str) -> (Value, Vec<Vec<String>>) {
    let dir = std::env::temp_dir().join(format!("smlworld-random-trips-{name}-{}", std::process::id()));
    let scenario = random_scenario(&dir);
    let out = dir.join("out");
    let options = RunOptions { progress: false, seed: Some(seed), ..RunOptions::default() }.out(&out);
    run_scenario(scenario.as_path(), options).expect("the random scenario runs");
    let summary = serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let csv = std::fs::read_to_string(out.join("trips.csv")).expect("trips.csv beside trajectories.csv");
    let _ = std::fs::remove_dir_all(&dir);
    let mut lines = csv.lines();
    assert_eq!(lines.next(), Some("id,depart,arrival,route_length_m,travel_time_s,waiting_time_s,stops"));
    (summary, lines.map(|l| l.split(',').map(str::to_string).collect()).collect())
}

fn num(v: &str) -> f64 {
    v.parse().unwrap_or_else(|_| panic!("{v:?} is not a number"))
}

#[test]
fn random_traffic_drives_many_routes_and_its_trips_follow_the_seed() {
    let (summary, rows) = run(1, "a");
    let trips = &summary["metrics"]["trips"];
    let inserted = trips["inserted"].as_u64().unwrap();
    let arrived = trips["arrived"].as_u64().unwrap();
    // 8 placed, about 15 inserted in 60 s at 900 veh/h (some may still wait for their entry).
    assert!(inserted >= 15, "{trips}");
    assert!(arrived >= 8, "most short grid trips end within 90 s: {trips}");
    assert_eq!(summary["metrics"]["traffic"]["inserted"], inserted, "traffic vehicles are the only trips");
    // trips.csv has a row per trip; its arrived rows and their travel times make the summary.
    assert_eq!(rows.len() as u64, inserted);
    let done: Vec<&Vec<String>> = rows.iter().filter(|r| !r[2].is_empty()).collect();
    assert_eq!(done.len() as u64, arrived);
    assert!(rows.iter().all(|r| r[2].is_empty() == r[4].is_empty()), "arrival and travel time go together");
    let mean = done.iter().map(|r| num(&r[4])).sum::<f64>() / done.len() as f64;
    assert!((mean - trips["mean_travel_time_s"].as_f64().unwrap()).abs() < 0.01, "{mean} vs {trips}");
    let waiting = rows.iter().map(|r| num(&r[5])).sum::<f64>() / rows.len() as f64;
    assert!((waiting - trips["mean_waiting_time_s"].as_f64().unwrap()).abs() < 0.01, "{waiting} vs {trips}");
    let stops = rows.iter().map(|r| num(&r[6])).sum::<f64>() / rows.len() as f64;
    assert!((stops - trips["mean_stops"].as_f64().unwrap()).abs() < 0.01, "{stops} vs {trips}");
    let p95 = trips["p95_travel_time_s"].as_f64().unwrap();
    assert!(p95 >= mean && done.iter().any(|r| num(&r[4]) == p95), "{trips}");
    // Different routes: route lengths spread, every one at least MIN_TRIP_M long (those placed
    // at t = 0 start part way along their first lanelet, at most one lanelet of 31 m in).
    let mut lengths: Vec<i64> = rows.iter().map(|r| (num(&r[3]) * 10.0) as i64).collect();
    lengths.sort_unstable();
    lengths.dedup();
    assert!(lengths.len() >= 8, "{lengths:?}");
    assert!(rows.iter().all(|r| num(&r[3]) >= MIN_TRIP_M - 35.0), "{rows:?}");
    // No trip is faster than its route at the top desired speed (12 m/s) allows.
    for r in &done {
        assert!(num(&r[4]) * 12.0 >= num(&r[3]) - 6.0, "{r:?}");
    }
    let (again, same_rows) = run(1, "b");
    assert_eq!(same_rows, rows, "the same seed gives the same trips");
    assert_eq!(again["metrics"]["trips"], *trips);
    let (_, other_rows) = run(2, "c");
    assert_ne!(other_rows, rows, "another seed gives other trips");
}

#[test]
fn a_random_route_joins_its_origin_to_its_destination_by_successors() {
    let map = grid();
    let trips = RandomTrips::new(&map, 5.0);
    assert!(!trips.is_empty());
    let mut starts = std::collections::BTreeSet::new();
    for k in 0..40 {
        let trip = trips.trip(&map, 7, 0, k).expect("the grid is strongly connected");
        let path = &trip.path;
        assert!(path.length >= MIN_TRIP_M && trip.origin != trip.destination);
        assert_eq!(path.lanelets.first(), Some(&trip.origin));
        assert_eq!(path.lanelets.last(), Some(&trip.destination));
        for w in path.lanelets.windows(2) {
            let l = &map.lanelets[map.lanelet_index(w[0]).unwrap()];
            assert!(l.successors.contains(&w[1]), "{} does not follow {}", w[1], w[0]);
        }
        // The route starts where the origin's centre line starts.
        let o = &map.lanelets[map.lanelet_index(trip.origin).unwrap()];
        assert!(path.points[0].distance(o.centre[0]) < 0.01);
        starts.insert(trip.origin);
        // The public draw gives the same route for the same counter.
        let again = random_route(&map, 7, 0, k).unwrap();
        assert_eq!((again.lanelets.clone(), again.length), (path.lanelets.clone(), path.length));
    }
    assert!(starts.len() >= 15, "40 trips start on many lanelets: {}", starts.len());
}

const VIA: &str = r#"
map = "../maps/grid_3x3.osm"
duration = 1.0
[[vehicles]]
id = -1
route = { from = "r0c0_east", to = "r0c2_east"ROUTE_VIA }
controller = { type = "path_following" }
"#;

fn route_of(via: &str) -> std::sync::Arc<smlworld::map::Path> {
    let text = VIA.replace("ROUTE_VIA", via);
    let scenario = Scenario::parse_str(&text, &root().join("scenarios/test.toml")).expect("parses");
    let sim = scenario.builder().expect("assembles").build();
    let world = sim.world();
    let e = world.resource::<smlworld::world::Vehicles>().get(smlworld::world::VehicleId(-1)).unwrap();
    world.get::<Route>(e).unwrap().0.clone()
}

#[test]
fn a_route_via_places_passes_them_in_order() {
    let direct = route_of("");
    let via = route_of(", via = [\"r1c1_east\"]");
    let map = grid();
    let node = map.nodes_with_tag("r1c1_east").unwrap()[0];
    let p = map.nodes[&node].position;
    let nearest = |path: &smlworld::map::Path| path.points.iter().map(|q| q.distance(p)).fold(f64::INFINITY, f64::min);
    assert!(nearest(&via) < 3.0, "the route passes r1c1_east: {} m off", nearest(&via));
    assert!(nearest(&direct) > 20.0, "the direct route does not");
    assert!(via.length > direct.length + 50.0, "{} vs {}", via.length, direct.length);
    // Equally spaced points (the path follower relies on it).
    let spacing = via.spacing();
    assert!(via.points.windows(2).all(|w| (w[0].distance(w[1]) - spacing).abs() < 0.05), "{spacing}");
}

fn traffic_error(table: &str) -> String {
    let text = format!("map = \"../maps/grid_3x3.osm\"\nduration = 1.0\n[[traffic]]\n{table}\n");
    match Scenario::parse_str(&text, &root().join("scenarios/test.toml")) {
        Ok(s) => match s.builder() {
            Ok(_) => panic!("accepted: {table}"),
            Err(e) => e.to_string(),
        },
        Err(e) => e.to_string(),
    }
}

#[test]
fn bad_random_routes_are_refused_naming_the_key() {
    let cases = [
        ("route = \"randomm\"\ncount = 2", "route", "randomm"),
        ("route = 5\ncount = 2", "route", "random"),
        ("route = { form = \"r0c0_east\", to = \"r0c2_east\" }\ncount = 2", "form", ""),
        ("route = \"random\"\ncount = 2\nlanes = [\"r0c0_east\"]", "traffic[0].lanes", "random"),
        ("route = { loop = \"r0c0_east\", via = [\"r1c1_east\"] }\ncount = 2", "traffic[0].route.via", "from"),
        ("route = \"random\"\ncount = 100000", "traffic[0].count", "fit"),
    ];
    for (table, key, also) in cases {
        let err = traffic_error(table);
        assert!(err.contains(key) && err.contains(also), "{table}\n-> {err}");
    }
}

const STALLED: &str = r#"
map = "../maps/grid_3x3.osm"
duration = 60.0
[[vehicles]]
id = -1
route = { from = "r0c1_east", to = "r0c2_east" }
start = { offset = 15.0 }

[[traffic]]
route = { from = "r0c0_east", to = "r0c2_east" }
rate = 600.0
until = 30.0
speed = [8.0, 10.0]
"#;

#[test]
fn vehicles_held_up_behind_a_stalled_car_wait_and_stop() {
    use smlworld::app::running::trips::{TripsSummary, trip_records};
    let scenario = Scenario::parse_str(STALLED, &root().join("scenarios/test.toml")).expect("parses");
    let mut sim = scenario.builder().expect("assembles").build();
    sim.run_for(60.0);
    let records = trip_records(sim.world());
    // The stalled car (no controller) departed standing: it waited the whole run, never stopped.
    let stalled = records.iter().find(|r| r.id.0 == -1).expect("a scenario vehicle on an open route has a trip");
    assert_eq!((stalled.trip.arrival, stalled.trip.waiting.stops), (None, 0));
    assert!((stalled.trip.waiting.time_s - 60.0).abs() < 0.11, "{:?}", stalled.trip);
    // The traffic behind it came to a stand once each and has waited since.
    // Traffic ids are virtual by default: -1000, -1001, ... (the first inserted is -1000).
    let queued: Vec<_> = records.iter().filter(|r| r.id.0 <= -1000).collect();
    assert!(queued.len() >= 2, "{records:?}");
    assert!(queued.iter().all(|r| r.trip.arrival.is_none() && r.trip.waiting.stops >= 1), "{queued:?}");
    let first = queued.iter().max_by_key(|r| r.id.0).expect("queued");
    assert!(first.trip.waiting.time_s > 30.0, "{first:?}");
    let s = TripsSummary::of(&records);
    assert_eq!((s.inserted, s.arrived, s.mean_travel_time_s), (records.len() as u64, 0, None));
    assert!(s.mean_stops.unwrap() > 0.5 && s.mean_waiting_time_s.unwrap() > 20.0, "{s:?}");
}

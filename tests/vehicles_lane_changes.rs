//! Lane changes in runs (issue 19): the overtaking scenario's figures, the sensor requirement of
//! controllers that follow a leader, and the shipped scenarios without `lane_change` driving
//! exactly as before lane changes existed.

use std::path::PathBuf;
use std::process::Command;

use serde_json::Value;
use smlworld::app::Scenario;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Run `smlworld run scenarios/<name>.toml`; return summary.json and the trajectory rows.
fn run(name: &str) -> (Value, Vec<Vec<String>>) {
    run_with(name, &[])
}

/// [`run`] with extra command-line arguments.
fn run_with(name: &str, args: &[&str]) -> (Value, Vec<Vec<String>>) {
    let tag = args.join("").replace(|c: char| !c.is_ascii_alphanumeric(), "");
    let out = std::env::temp_dir().join(format!("smlworld-lc-{name}-{tag}-{}", std::process::id()));
    let output = Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .arg("run")
        .arg(root().join("scenarios").join(format!("{name}.toml")))
        .args(args)
        .arg("--out")
        .arg(&out)
        .current_dir(root())
        .output()
        .expect("the smlworld binary runs");
    assert!(output.status.success(), "{name}: {}", String::from_utf8_lossy(&output.stderr));
    let summary = serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let csv = std::fs::read_to_string(out.join("trajectories.csv")).unwrap();
    let mut lines = csv.lines();
    assert_eq!(lines.next(), Some("t,id,x,y,yaw,vx,vy,lanelet,lane_offset"));
    let rows = lines.map(|l| l.split(',').map(str::to_string).collect()).collect();
    let _ = std::fs::remove_dir_all(&out);
    (summary, rows)
}

fn num(v: &str) -> f64 {
    v.parse().unwrap_or_else(|_| panic!("{v:?} is not a number"))
}

/// Unwrapped angle [rad] round the origin of vehicle `id` at every logged time.
fn ring_angles(rows: &[Vec<String>], id: &str) -> Vec<(f64, f64)> {
    let mut out: Vec<(f64, f64)> = Vec::new();
    for r in rows.iter().filter(|r| r[1] == id) {
        let a = num(&r[3]).atan2(num(&r[2]));
        let a = match out.last() {
            Some(&(_, last)) => {
                last + (a - last + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI
            }
            None => a,
        };
        out.push((num(&r[0]), a));
    }
    out
}

#[test]
fn overtaking_car_changes_left_passes_the_truck_and_returns_right() {
    let (summary, rows) = run("overtaking");
    let m = &summary["metrics"];
    assert_eq!(m["collision_count"], 0, "{m}");
    let changes = m["lane_changes"].as_array().expect("lane_changes listed");
    let car: Vec<&Value> = changes.iter().filter(|c| c["id"] == -2).collect();
    assert!(changes.iter().all(|c| c["id"] == -2), "only the car changes lanes: {changes:?}");
    let left = car.iter().position(|c| c["direction"] == "left" && c["aborted"] == false).expect("a change left");
    let right = car[left..].iter().find(|c| c["direction"] == "right" && c["aborted"] == false).expect("then right");
    assert_eq!(car[left]["kind"], "discretionary");
    assert!(num(&car[left]["t_start"].to_string()) <= 10.0, "starts overtaking early: {car:?}");
    for c in &car {
        let peak = c["peak_lateral_accel"].as_f64().unwrap();
        assert!(peak > 0.0 && peak <= 1.1 * 1.5, "peak lateral acceleration {peak} over 1.1 x 1.5: {c}");
    }
    // It passed: when it is back on the right lane it is ahead of the truck round the ring.
    let t_back = right["t_end"].as_f64().unwrap();
    let at = |angles: &[(f64, f64)], t: f64| angles.iter().find(|(tt, _)| *tt >= t - 1e-9).unwrap().1;
    let (car_a, truck_a) = (ring_angles(&rows, "-2"), ring_angles(&rows, "-1"));
    assert!(at(&car_a, 0.0) < at(&truck_a, 0.0), "the car starts behind the truck");
    assert!(at(&car_a, t_back) > at(&truck_a, t_back), "back right at {t_back} s ahead of the truck");
    // The CSV says which lane: the car ends on a lanelet of the truck's lane (they share it).
    let summary_of = &m["lane_change_summary"];
    assert_eq!(summary_of["count"].as_u64().unwrap() as usize, changes.len());
    assert_eq!(summary_of["missed_exits"], 0);
    let last_lanelet = |id: &str| rows.iter().rev().find(|r| r[1] == id).unwrap()[7].clone();
    assert!(!last_lanelet("-2").is_empty() && !last_lanelet("-1").is_empty(), "on the road at the end");
}

/// Final (x, y) of every vehicle, as the run before lane changes existed wrote them (commit
/// d24ab97, `smlworld run`; the last row of each vehicle in trajectories.csv).
/// (id, x, y) of each vehicle at the end of a run.
type Ends = &'static [(i64, f64, f64)];

const BEFORE: [(&str, Ends); 3] = [
    (
        "highway",
        &[
            (-12, -47.883909, 20.265328),
            (-11, 19.637688, 48.144501),
            (-10, 48.395422, -19.010494),
            (-9, -18.376830, -48.639643),
            (-8, 46.747048, 30.824714),
            (-7, 31.376985, -46.378517),
            (-6, -46.006162, -31.920037),
            (-5, -32.461532, 45.625438),
            (-4, -31.584492, -51.007750),
            (-3, -51.343075, 31.036907),
            (-2, 30.486444, 51.671358),
            (-1, 51.996810, -29.928308),
        ],
    ),
    (
        "platoon_brake",
        &[
            (-5, -59.984609, -1.109566),
            (-4, -55.784952, -22.077627),
            (-3, -44.496568, -40.242164),
            (-2, -27.553597, -53.293233),
            (-1, -7.270126, -59.552679),
        ],
    ),
    (
        "acc_highway",
        &[
            (-14, -48.207389, 28.486406),
            (-13, -55.056714, 10.207471),
            (-12, -55.215342, -9.311856),
            (-11, -48.664005, -27.699861),
            (-10, -36.198770, -42.721522),
            (-4, -43.775655, 41.025225),
            (-3, -57.298818, 17.782520),
            (-2, -59.310977, -9.032691),
            (-1, -49.407613, -34.033306),
        ],
    ),
];

#[test]
fn shipped_scenarios_without_lane_change_drive_as_before() {
    for (name, before) in BEFORE {
        let (_, rows) = run(name);
        for &(id, x, y) in before {
            let last = rows.iter().rev().find(|r| num(&r[1]) as i64 == id).unwrap();
            let (gx, gy) = (num(&last[2]), num(&last[3]));
            assert!(
                // The CSV holds positions to 1 mm (issue 22 item 13): half a millimetre of rounding,
                // and since the dynamics turn the heading by the angle-sum formulas instead of a
                // `sin_cos` of the yaw (issue 25), rounding-level differences that grow to 2 mm over
                // platoon_brake's 70 s of hard braking. A behaviour change moves vehicles metres.
                (gx - x).abs() < 5e-3 && (gy - y).abs() < 5e-3,
                "{name}: vehicle {id} ends at ({gx}, {gy}), before ({x}, {y})"
            );
        }
    }
}

fn load(text: &str) -> Result<Scenario, String> {
    Scenario::parse_str(text, &root().join("scenarios/test.toml")).map_err(|e| e.to_string())
}

const RING_VEHICLE: &str = r#"
map = "../maps/highway_ring.osm"
[[vehicles]]
id = -7
route = { loop = "right_lane_node" }
"#;

#[test]
fn a_controller_that_follows_a_leader_needs_a_sensor_that_sees_it() {
    for controller in [
        r#"{ type = "acc", speed = 10.0 }"#,
        r#"{ type = "idm", speed = 10.0 }"#,
        r#"{ type = "platoon", role = "follower", speed = 10.0 }"#,
    ] {
        let err = load(&format!("{RING_VEHICLE}controller = {controller}\n")).expect_err(controller);
        assert!(err.contains("vehicles[0] (id -7).sensors") && err.contains("radar"), "{controller}: {err}");
        for sensors in ["{ radar = {} }", "{ velodyne = {} }", "{ omniscient = true }"] {
            load(&format!("{RING_VEHICLE}controller = {controller}\nsensors = {sensors}\n"))
                .unwrap_or_else(|e| panic!("{controller} with {sensors}: {e}"));
        }
    }
    // Cruise control and path following do not look ahead.
    load(&format!("{RING_VEHICLE}controller = {{ type = \"cruise_control\" }}\n")).unwrap();
}

#[test]
fn lane_change_tables_are_parsed_strictly() {
    let base = format!("{RING_VEHICLE}controller = {{ type = \"idm\" }}\nsensors = {{ radar = {{}} }}\n");
    load(&format!("{base}lane_change = false\n")).unwrap();
    load(&format!("{base}lane_change = true\n")).unwrap();
    load(&format!("{base}lane_change = {{ politeness = 0.5, keep_right = false, min_interval = 2.0 }}\n")).unwrap();
    let err = load(&format!("{base}lane_change = {{ politenes = 0.5 }}\n")).unwrap_err();
    assert!(err.contains("politenes"), "{err}");
    let err = load(&format!("{base}lane_change = {{ safe_deceleration = -1.0 }}\n")).unwrap_err();
    assert!(err.contains("lane_change.safe_deceleration"), "{err}");
    let err = load(
        &format!("{base}controller = {{ type = \"idm\", speeed = 3.0 }}\n")
            .replace("controller = { type = \"idm\" }\n", ""),
    )
    .unwrap_err();
    assert!(err.contains("speeed"), "{err}");
}

#[test]
fn lane_drop_merges_everyone_without_missing_the_exit() {
    let (summary, rows) = run("lane_drop");
    let m = &summary["metrics"];
    assert_eq!(m["collision_count"], 0, "{}", m["collisions"]);
    let traffic = &m["traffic"];
    let inserted = traffic["inserted"].as_u64().unwrap();
    assert!(inserted >= 60, "{traffic}");
    assert_eq!(traffic["removed"], inserted, "every inserted vehicle leaves by the end: {traffic}");
    assert_eq!(m["throughput"]["vehicles_out"], inserted);
    let end = rows.last().unwrap()[0].clone();
    assert!(rows.iter().filter(|r| r[0] == end).count() == 0 || summary["vehicles"] == 0, "nobody left at the end");
    let lc = &m["lane_change_summary"];
    assert_eq!(lc["missed_exits"], 0, "{lc}");
    // Nobody waits long for the gap (30.95 s at most since insertion keeps a stopping margin
    // behind the leader it sees, issue 55's 1 s steps; 30 s bound before).
    assert!(lc["max_wait_s"].as_f64().unwrap() <= 35.0, "{lc}");
    assert!(lc["mandatory"].as_u64().unwrap() >= 10, "{lc}");
    // Every mandatory change is to the right (the left lane ends) and starts before the drop.
    for c in m["lane_changes"].as_array().unwrap().iter().filter(|c| c["kind"] == "mandatory" && c["aborted"] == false)
    {
        assert_eq!(c["direction"], "right", "{c}");
    }
    // Vehicles on the left lane after the drop (x > 300 m, y > 3.5 m) would have driven off the road.
    assert!(
        rows.iter().all(|r| !(num(&r[2]) > 301.0 && num(&r[3]) > 3.6)),
        "a vehicle drove on where the left lane has ended"
    );
}

/// Issue 61 §1: the shipped highway scenario is traffic that flows and overtakes, not the
/// standing jam of 105 vehicles on the 377 m ring (mean speed 0.4-0.9 m/s after 400 s, lane
/// changes of up to 88 s): after the start-up, every vehicle keeps moving, the mean speed is
/// well above a jam's, and every lane change ends within 8 s.
#[test]
fn highway_traffic_flows_and_changes_lanes_in_mixed_traffic_without_collisions() {
    let (summary, rows) = run("highway_traffic");
    let m = &summary["metrics"];
    assert_eq!(m["collision_count"], 0, "{}", m["collisions"]);
    assert_eq!(m["traffic"]["inserted"].as_u64().unwrap(), 45, "{}", m["traffic"]);
    assert!(m["lane_change_summary"]["count"].as_u64().unwrap() >= 20, "{}", m["lane_change_summary"]);
    for c in m["lane_changes"].as_array().unwrap() {
        let took = c["t_end"].as_f64().unwrap() - c["t_start"].as_f64().unwrap();
        assert!(took <= 8.0, "a lane change took {took:.1} s: {c}");
    }
    let vehicles = summary["replay"]["vehicles"].as_array().unwrap();
    let classes: std::collections::BTreeSet<&str> = vehicles.iter().map(|v| v["class"].as_str().unwrap()).collect();
    assert!(classes.len() >= 2, "mixed classes: {classes:?}");
    // Background traffic has negative ids (real vehicles are the lab's).
    assert!(rows.iter().all(|r| r[1].parse::<i32>().unwrap() < 0), "traffic ids");
    // Mixed speeds: the vehicles' mean speeds over the run spread by more than 1 m/s; after the
    // first minute nobody stands and the mean speed is a flowing road's.
    let mut mean: std::collections::BTreeMap<&str, (f64, f64)> = Default::default();
    let (mut late, mut n, mut slowest) = (0.0, 0.0, f64::INFINITY);
    for r in &rows {
        let v = num(&r[5]).hypot(num(&r[6]));
        let e = mean.entry(r[1].as_str()).or_default();
        e.0 += v;
        e.1 += 1.0;
        if num(&r[0]) >= 60.0 {
            late += v;
            n += 1.0;
            slowest = slowest.min(v);
        }
    }
    let speeds: Vec<f64> = mean.values().map(|(s, n)| s / n).collect();
    let (lo, hi) = speeds.iter().fold((f64::INFINITY, 0.0f64), |(a, b), &v| (a.min(v), b.max(v)));
    assert!(speeds.len() == 45 && hi - lo > 1.0, "{lo} .. {hi}");
    assert!(late / n > 7.0, "mean speed after 60 s: {:.2} m/s", late / n);
    assert!(slowest > 1.0, "a vehicle slowed to {slowest:.2} m/s after 60 s");
}

mod determinism {
    use smlworld::app::running::session::load_scenario_with_overrides;
    use smlworld::sim::Parallelism;
    use smlworld::vehicles::LaneChangeLog;
    use smlworld::world::{VehicleId, VehicleState};

    /// Every vehicle's state bits and every lane change after `seconds` of `name` with `seed`
    /// on `threads` threads (split at any vehicle count).
    fn fingerprint(name: &str, seed: u64, threads: usize, seconds: f64) -> (Vec<(i32, [u64; 5])>, String) {
        let path = super::root().join("scenarios").join(format!("{name}.toml"));
        let scenario = load_scenario_with_overrides(&path, Some(seed), &[]).unwrap();
        let mut b = scenario.builder().unwrap();
        b.insert_resource(Parallelism { threads, min_vehicles: 0 });
        let mut sim = b.build();
        sim.run_for(seconds);
        let world = sim.world_mut();
        let mut q = world.query::<(&VehicleId, &VehicleState)>();
        let mut states: Vec<(i32, [u64; 5])> = q
            .iter(world)
            .map(|(id, s)| {
                let bits = [s.position.x, s.position.y, s.yaw, s.velocity.x, s.velocity.y].map(|v: f64| v.to_bits());
                (id.0, bits)
            })
            .collect();
        states.sort();
        let log = format!("{:?}", world.resource::<LaneChangeLog>().events);
        (states, log)
    }

    #[test]
    fn traffic_and_lane_changes_are_bit_identical_on_one_and_two_threads_and_follow_the_seed() {
        for (name, seconds) in [("lane_drop", 90.0), ("highway_traffic", 60.0)] {
            let one = fingerprint(name, 7, 1, seconds);
            let two = fingerprint(name, 7, 2, seconds);
            assert!(!one.0.is_empty(), "{name}: traffic on the road");
            assert!(name != "lane_drop" || one.1.contains("t_start"), "{name}: lane changes happened");
            assert_eq!(one, two, "{name}: 1 and 2 threads differ");
            let other = fingerprint(name, 8, 1, seconds);
            assert_ne!(one.0, other.0, "{name}: seeds 7 and 8 gave the same traffic");
        }
    }
}

/// Lane changes of the overtaking scenario on its map with the line between the lanes retagged
/// `tag` (the OSM text of the tag that replaces `line_type=interior`).
fn overtaking_changes_with_line(tag: &str) -> Vec<(String, bool)> {
    let dir = std::env::temp_dir().join(format!("smlworld-lc-lines-{}-{}", tag.len(), std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let map = std::fs::read_to_string(root().join("maps/two_lane_ring.osm")).unwrap();
    let retagged = map.replace("<tag k='line_type' v='interior' />", tag);
    assert!(map.contains("<tag k='line_type' v='interior' />"), "the map has an interior line to retag");
    std::fs::write(dir.join("ring.osm"), retagged).unwrap();
    let text = std::fs::read_to_string(root().join("scenarios/overtaking.toml"))
        .unwrap()
        .replace("../maps/two_lane_ring.osm", "ring.osm");
    let scenario = Scenario::parse_str(&text, &dir.join("overtaking.toml")).unwrap();
    let mut sim = scenario.builder().unwrap().build();
    sim.run_for(60.0);
    let log = sim.world().resource::<smlworld::vehicles::LaneChangeLog>();
    let out = log.events.iter().map(|e| (format!("{:?}", e.direction), e.aborted)).collect();
    let _ = std::fs::remove_dir_all(&dir);
    out
}

#[test]
fn lines_between_lanes_decide_which_changes_are_allowed() {
    // Interior (dashed) line: left and back right.
    let both = overtaking_changes_with_line("<tag k='line_type' v='interior' />");
    assert!(both.iter().any(|c| c.0 == "Left") && both.iter().any(|c| c.0 == "Right"), "{both:?}");
    // A solid line: no change at all (the car follows the truck).
    assert_eq!(overtaking_changes_with_line("<tag k='line_type' v='exterior' />"), vec![]);
    assert_eq!(overtaking_changes_with_line("<tag k='subtype' v='solid' />"), vec![]);
    // Solid on one side, dashed on the other: one direction only.
    for one_way in ["<tag k='subtype' v='solid_dashed' />", "<tag k='subtype' v='dashed_solid' />"] {
        let changes = overtaking_changes_with_line(one_way);
        let left = changes.iter().any(|c| c.0 == "Left");
        let right = changes.iter().any(|c| c.0 == "Right");
        assert!(!(left && right), "{one_way}: both directions crossed: {changes:?}");
    }
}

const TRAFFIC_RING: &str = r#"
map = "../maps/highway_ring.osm"
duration = 10.0
[[vehicles]]
id = 1005
route = { loop = "right_lane_node" }
controller = { type = "path_following" }
"#;

fn traffic_error(table: &str) -> String {
    let text = format!("{TRAFFIC_RING}[[traffic]]\n{table}\n");
    match Scenario::parse_str(&text, &root().join("scenarios/test.toml")) {
        Ok(s) => match s.builder() {
            Ok(_) => panic!("accepted: {table}"),
            Err(e) => e.to_string(),
        },
        Err(e) => e.to_string(),
    }
}

/// Ids of the vehicles `table` (a `[[traffic]]` table, or two) adds to the ring, sorted.
fn traffic_ids(table: &str) -> Vec<i32> {
    let text = format!("{TRAFFIC_RING}{table}\n");
    let scenario = Scenario::parse_str(&text, &root().join("scenarios/test.toml")).expect("parses");
    let sim = scenario.builder().expect("assembles").build();
    let mut ids: Vec<i32> = sim
        .world()
        .resource::<smlworld::world::Vehicles>()
        .iter()
        .map(|(id, _)| id.0)
        .filter(|id| *id != 1005)
        .collect();
    ids.sort_unstable();
    ids
}

#[test]
fn traffic_ids_are_negative_unless_id_start_is_given() {
    // Issue 61 §1: background traffic is virtual, so its ids default to negative numbers.
    let ids = traffic_ids("[[traffic]]\nroute = { loop = \"right_lane_node\" }\ncount = 3");
    assert_eq!(ids, vec![-1002, -1001, -1000]);
    // A second table takes the next thousand down; an explicit id_start counts up as given.
    let two = traffic_ids(
        "[[traffic]]\nroute = { loop = \"right_lane_node\" }\ncount = 2\n\
         [[traffic]]\nroute = { loop = \"right_lane_node\" }\ncount = 2",
    );
    assert_eq!(two, vec![-2001, -2000, -1001, -1000]);
    let given = traffic_ids("[[traffic]]\nroute = { loop = \"right_lane_node\" }\ncount = 3\nid_start = 2000");
    assert_eq!(given, vec![2000, 2001, 2002]);
}

#[test]
fn bad_traffic_tables_are_refused_naming_the_key() {
    let cases = [
        ("route = { loop = \"right_lane_node\" }\ncount = 10\nid_start = 1000", "traffic[0].id_start", "1005"),
        ("route = { loop = \"right_lane_node\" }\ncount = 500\nid_start = 2000", "traffic[0].count", "fit"),
        ("route = { loop = \"right_lane_node\" }\ncount = 5\nspeeed = [1.0, 2.0]\nid_start = 2000", "speeed", ""),
        (
            "route = { loop = \"right_lane_node\" }\ncount = 5\nspeed = [9.0, 2.0]\nid_start = 2000",
            "traffic[0].speed",
            "",
        ),
        ("route = { loop = \"no_such_tag\" }\ncount = 5\nid_start = 2000", "traffic[0].route", "no_such_tag"),
        ("route = { loop = \"right_lane_node\" }\nid_start = 2000", "traffic[0].count", "rate"),
        (
            "route = { loop = \"right_lane_node\" }\ncount = 5\nsensors = {}\nid_start = 2000",
            "traffic[0].sensors",
            "radar",
        ),
        (
            "route = { loop = \"right_lane_node\" }\ncount = 5\ncontroller = { type = \"path_following\" }\nid_start = 2000",
            "traffic[0].controller.type",
            "idm",
        ),
    ];
    for (table, key, also) in cases {
        let err = traffic_error(table);
        assert!(err.contains(key) && err.contains(also), "{table}\n-> {err}");
    }
}

#[test]
fn a_session_reports_lanes_and_carries_out_requested_changes() {
    use smlworld::app::{Session, StateColumns};
    let mut s = Session::from_scenario(&root().join("scenarios/overtaking.toml"), None, &[]).unwrap();
    s.step(30.0).unwrap();
    let mut cols = StateColumns::default();
    s.states_into(&mut cols);
    assert!(cols.lanelet.iter().all(|l| l.is_finite()) && cols.lane_offset.iter().all(|o| o.abs() < 2.0), "{cols:?}");
    // The truck has no lane_change table: the error says how to add one.
    let err = s.change_lane(-1, "left").unwrap_err().to_string();
    assert!(err.contains("lane_change"), "{err}");
    assert!(s.change_lane(-2, "up").is_err());
    // Back on the right lane after overtaking: nothing to its right, the left lane is free.
    assert!(!s.change_lane(-2, "right").unwrap(), "no lane right of the right lane");
    assert!(s.change_lane(-2, "left").unwrap());
    s.step(10.0).unwrap();
    let changes = s.summary().metrics.unwrap().lane_changes.unwrap();
    let requested: Vec<_> = changes.iter().filter(|c| c.kind == smlworld::vehicles::ChangeKind::Requested).collect();
    assert_eq!(requested.len(), 1, "{changes:?}");
    assert_eq!(requested[0].direction, smlworld::vehicles::Side::Left);
}

/// Issue 61 §1: in dense traffic a lane change ends in bounded time and nobody stands across
/// two lanes. The ring of `highway_traffic.toml` with 80 and 90 vehicles (13 and 12 m of lane
/// per vehicle: stop-and-go waves) for 600 s: every change ends within 8 s, no vehicle stands
/// (below 0.5 m/s) more than 0.5 m from its lanelet's centre for more than 5 s, and changes do
/// happen. Before (distance-only profile, no room check) changes there took up to 50 s and a
/// vehicle stood across two lanes for 37 s.
#[test]
fn dense_ring_lane_changes_end_within_8_s_and_nobody_stands_across_lanes() {
    for (count, seed) in [("80", "2"), ("90", "2015")] {
        let set = format!("traffic.0.count={count}");
        let (summary, rows) = run_with("highway_traffic", &["--set", &set, "--seed", seed]);
        let m = &summary["metrics"];
        assert_eq!(m["collision_count"], 0, "{count} vehicles: {}", m["collisions"]);
        let changes = m["lane_changes"].as_array().unwrap();
        assert!(changes.len() >= 3, "{count} vehicles: only {} lane changes", changes.len());
        for c in changes {
            let took = c["t_end"].as_f64().unwrap() - c["t_start"].as_f64().unwrap();
            assert!(took <= 8.0, "{count} vehicles: a lane change took {took:.1} s: {c}");
        }
        // Per vehicle, since when it has stood across lanes.
        let mut since: std::collections::BTreeMap<&str, f64> = Default::default();
        for r in &rows {
            let (t, v) = (num(&r[0]), num(&r[5]).hypot(num(&r[6])));
            let across = !r[8].is_empty() && num(&r[8]).abs() > 0.5 && v < 0.5;
            if across {
                let start = *since.entry(r[1].as_str()).or_insert(t);
                assert!(t - start <= 5.0, "{count} vehicles: {} stood across lanes from {start} to {t} s", r[1]);
            } else {
                since.remove(r[1].as_str());
            }
        }
    }
}

/// A mandatory change begun in the last metres of the lane that ends has no way back: asked to
/// abort there (a cooperative plugin's `abort`, or the target gap closing), it goes on with the
/// change. Before, the abort put the vehicle back on its old lane's route, which ends under it:
/// it stood there for good with its abort never done (an abort ends by distance), and never
/// changed again (issue 54's 20x20 grid: a vehicle stood in a junction until the end, 115
/// behind it). On the lane drop with a queue at the drop: the first change under way within 5 m
/// of the old lane's end is asked to abort; within 20 s that vehicle has finished its change.
/// (Asked to abort 4-5 m before the end, where a way back fits, one went back and then, its
/// route ending there, arrived and left the world in the middle of the road: a way back must
/// also leave room to stand and begin again.)
#[test]
fn a_mandatory_change_at_the_very_end_of_its_lane_is_not_aborted_back_onto_it() {
    use smlworld::app::Session;
    use smlworld::vehicles::{ChangeKind, LaneChanger, PathFollower};
    use smlworld::world::{Route, VehicleId};
    // Twice the rate the one lane takes: a queue stands at the drop, and its left-lane vehicles
    // change in the last metres.
    let rate = [("traffic.0.rate".to_string(), toml::Value::Float(3600.0))];
    let mut s = Session::from_scenario(&root().join("scenarios/lane_drop.toml"), None, &rate).unwrap();
    // A mandatory change under way, not halfway yet (where an abort is taken), less than 5 m
    // before the end of the lane it leaves: shorter than a way back across most of a lane.
    let late = |m: &smlworld::vehicles::lane_state::Manoeuvre, route: &Route, s: f64| {
        m.kind == ChangeKind::Mandatory
            && !m.aborted
            && !m.old_route.closed
            && m.old_route.length - m.old_s < 5.0
            && m.driven(&route.0, s) < 0.4 * m.profile.length
    };
    let mut found: Option<VehicleId> = None;
    let hit = s
        .step_until(120.0, |world| {
            // None until the first lane changer is in the world.
            let Some(mut q) = world.try_query::<(&VehicleId, &LaneChanger, &Route, &PathFollower)>() else {
                return false;
            };
            found = q
                .iter(world)
                .find(|(_, ch, route, f)| ch.active.as_ref().is_some_and(|m| late(m, route, f.s)))
                .map(|(id, ..)| *id);
            found.is_some()
        })
        .unwrap();
    assert!(hit, "no mandatory change under way within 5 m of the end of the left lane in 120 s");
    let id = found.expect("the vehicle found");
    let world = s.sim_mut().world_mut();
    let mut q = world.query::<(&VehicleId, &mut LaneChanger)>();
    for (v, mut ch) in q.iter_mut(world) {
        if *v == id {
            ch.abort = true;
        }
    }
    s.step(20.0).unwrap();
    let world = s.sim_mut().world_mut();
    let mut q = world.query::<(&VehicleId, &LaneChanger, &smlworld::world::VehicleState)>();
    if let Some((_, ch, state)) = q.iter(world).find(|(v, ..)| **v == id) {
        let m = ch.active.as_ref().map(|m| (m.kind, m.aborted, m.old_route.length - m.old_s));
        assert!(m.is_none(), "{id:?} is still changing 20 s later (kind, aborted, m left on the old route): {m:?}");
        assert!(state.speed() > 0.5, "{id:?} stands at {:?}", state.position);
    }
    let changes = s.summary().metrics.unwrap().lane_changes.unwrap();
    let mine: Vec<_> = changes.iter().filter(|c| c.id == id).collect();
    assert!(mine.iter().any(|c| !c.aborted), "its change ended, not aborted: {mine:?}");
}

//! Junctions, right of way and traffic lights (issue 53): conflicts found on every generated
//! junction kind and on Lanelet2's example map (counts checked by hand), a saturated junction for
//! 30 minutes without deadlock, no vehicle past a red stop line (checked from the vehicles'
//! lanelets and the lights, not from the plugin's own count), the three city scenarios with the
//! figures the issue asks for, and bad light programs refused by key.

mod common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde_json::Value;
use smlworld::app::Scenario;
use smlworld::map::LaneletMap;
use smlworld::map::generate::{self, GridParams, IntersectionParams, JunctionMarks};
use smlworld::map::junctions::{ConflictKind, JunctionControl, Yield, find_junctions};
use smlworld::prelude::*;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn map_of(text: &str) -> LaneletMap {
    LaneletMap::parse_str(text, Path::new("generated.osm")).expect("generated maps load")
}

fn counts(map: &LaneletMap) -> Vec<(usize, usize, usize)> {
    map.junctions()
        .list
        .iter()
        .map(|j| {
            let crossing = j.conflicts.iter().filter(|c| c.kind == ConflictKind::Crossing).count();
            (j.links.len(), crossing, j.conflicts.len() - crossing)
        })
        .collect()
}

#[test]
fn conflicts_of_generated_junctions_are_the_textbook_counts() {
    // A T junction of two-way roads: 6 movements, 3 crossing and 3 merging conflicts (the
    // classic count: each of the 3 exits is entered by 2 movements).
    let t = map_of(&generate::intersection(&IntersectionParams { arms: 3, ..IntersectionParams::default() }).unwrap());
    assert_eq!(counts(&t), vec![(6, 3, 3)]);
    // A 4-way junction: 12 movements, 16 crossing conflicts, and 3 merging pairs at each of
    // the 4 exits.
    let x = map_of(&generate::intersection(&IntersectionParams::default()).unwrap());
    assert_eq!(counts(&x), vec![(12, 16, 12)]);
    let j = &x.junctions().list[0];
    assert_eq!(j.control, JunctionControl::RightBeforeLeft, "equal arms and nothing said: right before left");
    // Every conflict point lies inside the junction (the turns start 9.5 m from the centre).
    for c in &j.conflicts {
        assert!(c.point.length() < 9.5, "conflict {c:?} outside the junction");
        assert!(c.s_a >= 0.0 && c.s_b >= 0.0);
    }
    // A 3 x 3 grid: 4 inner 4-way junctions, 8 T junctions on the border, the 4 corners (two
    // arms, turns that meet nothing) are no junctions.
    let g = map_of(&generate::grid_city(&GridParams::default()).unwrap());
    let c = counts(&g);
    assert_eq!(c.len(), 12);
    assert_eq!(c.iter().filter(|k| **k == (12, 16, 12)).count(), 4);
    assert_eq!(c.iter().filter(|k| **k == (6, 3, 3)).count(), 8);
}

#[test]
fn a_major_road_has_priority_and_equal_arms_yield_to_the_right() {
    let marks = JunctionMarks { major: Some(generate::Axis::EastWest), ..JunctionMarks::default() };
    let map = map_of(
        &generate::intersection(&IntersectionParams { control: marks, ..IntersectionParams::default() }).unwrap(),
    );
    let junctions = map.junctions();
    let j = &junctions.list[0];
    assert_eq!(j.control, JunctionControl::Priority);
    let major = |id| j.links.iter().find(|l| l.lanelet == id).unwrap().major;
    for c in &j.conflicts {
        if major(c.a) != major(c.b) {
            let minor = if major(c.a) { c.b } else { c.a };
            assert_eq!(c.yields_from(minor), Some(true), "the minor link yields in {c:?}");
        }
    }
    // Without marks: every crossing of two straight links is decided by who comes from the right.
    let plain = map_of(&generate::intersection(&IntersectionParams::default()).unwrap());
    let j = &plain.junctions().list[0];
    for c in j.conflicts.iter().filter(|c| c.kind == ConflictKind::Crossing) {
        let (la, lb) =
            (j.links.iter().find(|l| l.lanelet == c.a).unwrap(), j.links.iter().find(|l| l.lanelet == c.b).unwrap());
        if la.turn == smlworld::map::junctions::Turn::Straight && lb.turn == smlworld::map::junctions::Turn::Straight {
            // b comes from a's right when b's heading is a's turned left by 90°.
            let d = smlworld::map::junctions::wrap_angle(lb.heading_in - la.heading_in);
            let expected = if d > 0.0 { Yield::A } else { Yield::B };
            assert_eq!(c.yields, expected, "{c:?}");
        }
    }
    // A scenario may ask for first come, first served instead.
    let rules = smlworld::map::junctions::JunctionRules {
        fallback: smlworld::map::junctions::Fallback::FirstCome,
        left_hand: None,
    };
    let fc = find_junctions(&plain, &rules);
    assert_eq!(fc.list[0].control, JunctionControl::FirstCome);
    assert!(fc.list[0].conflicts.iter().all(|c| c.yields == Yield::FirstCome));
}

#[test]
fn lanelet2_example_junctions_take_their_lights_from_the_regulatory_elements() {
    let map = LaneletMap::load(&common::shared("lanelet2/mapping_example.osm")).expect("Lanelet2 example loads");
    // The file's regulatory elements, counted by hand: 6 traffic lights, 2 right of way, 1 speed limit.
    let subtypes: Vec<&str> = map.regulatory.values().map(|r| r.subtype.as_str()).collect();
    assert_eq!(subtypes.iter().filter(|s| **s == "traffic_light").count(), 6);
    assert_eq!(subtypes.iter().filter(|s| **s == "right_of_way").count(), 2);
    // Lanelets 44968, 44970, 44972 refer to the lights 45224/45222 (and to both right-of-way
    // elements): the file's `regulatory_element` members.
    assert_eq!(map.regulatory[&45224].lanelets.iter().map(|l| l.0).collect::<Vec<_>>(), vec![44968, 44970]);
    let junctions = map.junctions();
    let lit: Vec<_> = junctions.list.iter().filter(|j| j.control == JunctionControl::TrafficLight).collect();
    assert!(!lit.is_empty());
    // Every light's lanelets lead into a junction whose links carry that light.
    for re in map.regulatory.values().filter(|r| r.subtype == "traffic_light") {
        let carried = lit.iter().any(|j| j.links.iter().any(|l| l.signal == Some(re.id)));
        assert!(carried, "traffic light {} controls no junction link", re.id);
    }
    // Junctions are disjoint: each link is in one.
    let mut seen = BTreeMap::new();
    for j in &junctions.list {
        for l in &j.links {
            assert!(seen.insert(l.lanelet, j.id).is_none(), "lanelet {} in two junctions", l.lanelet);
        }
    }
}

/// Write `text` as a scenario in a fresh folder; its path.
fn scenario_file(name: &str, text: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("smlworld-junctions-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join(format!("{name}.toml"));
    std::fs::write(&path, text).unwrap();
    path
}

/// Run a scenario file into a fresh folder: summary.json and the path of its outputs.
fn run(scenario: &Path, name: &str) -> (Value, PathBuf) {
    let out = std::env::temp_dir().join(format!("smlworld-junctions-out-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    run_scenario(scenario, RunOptions { progress: false, ..RunOptions::default() }.out(&out))
        .expect("the scenario runs");
    let summary = serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    (summary, out)
}

/// Per vehicle, the longest time it stood (speed under 0.1 m/s) without a break [s], from
/// trajectories.csv; and the vehicles of the last row time.
fn longest_standstill(out: &Path) -> (f64, i64) {
    let text = std::fs::read_to_string(out.join("trajectories.csv")).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |k: &str| header.iter().position(|h| *h == k).unwrap();
    let (t, id, vx, vy) = (col("t"), col("id"), col("vx"), col("vy"));
    let mut since: BTreeMap<i64, f64> = BTreeMap::new();
    let mut longest = (0.0, 0);
    for line in lines {
        let f: Vec<&str> = line.split(',').collect();
        let (time, v): (f64, i64) = (f[t].parse().unwrap(), f[id].parse().unwrap());
        let speed = f[vx].parse::<f64>().unwrap().hypot(f[vy].parse::<f64>().unwrap());
        if speed < 0.1 {
            let start = *since.entry(v).or_insert(time);
            if time - start > longest.0 {
                longest = (time - start, v);
            }
        } else {
            since.remove(&v);
        }
    }
    longest
}

/// The figures every city scenario must hold: no collision, nobody stood longer than 120 s at
/// once, nobody past a red stop line, every inserted vehicle arrived or still in the world.
fn assert_city_figures(summary: &Value, out: &Path, what: &str) {
    let m = &summary["metrics"];
    assert_eq!(m["collision_count"], 0, "{what}: {}", m["collisions"]);
    let (stood, who) = longest_standstill(out);
    assert!(stood <= 120.0, "{what}: vehicle {who} stood {stood} s at once");
    if let Some(red) = m.get("red_light_crossings") {
        assert_eq!(red, 0, "{what}: vehicles passed red stop lines");
    }
    let trips = &m["trips"];
    let (inserted, arrived) = (trips["inserted"].as_u64().unwrap(), trips["arrived"].as_u64().unwrap());
    let present = summary["vehicles"].as_u64().unwrap();
    assert!(inserted > 0);
    assert_eq!(inserted, arrived + present, "{what}: every inserted vehicle arrived or is still driving");
    let through: u64 = m["junctions"].as_array().unwrap().iter().map(|j| j["vehicles_through"].as_u64().unwrap()).sum();
    assert!(through > 0, "{what}: nobody drove through a junction");
}

#[test]
fn intersection_traffic_scenario_flows_without_collisions() {
    let (summary, out) = run(&root().join("scenarios/intersection_traffic.toml"), "intersection");
    assert_city_figures(&summary, &out, "intersection_traffic");
    // 1,200 veh/h for 10 minutes: about 200 vehicles, nearly all through.
    let trips = &summary["metrics"]["trips"];
    assert!(trips["arrived"].as_u64().unwrap() >= 180, "{trips}");
    let j = &summary["metrics"]["junctions"][0];
    assert_eq!(j["id"], 1);
    assert!(j["max_queue"].as_u64().unwrap() >= 1, "somebody waited at the minor road: {j}");
}

#[test]
fn city_grid_scenario_runs_thirty_minutes_with_lights() {
    let (summary, out) = run(&root().join("scenarios/city_grid.toml"), "city");
    assert_city_figures(&summary, &out, "city_grid");
    let trips = &summary["metrics"]["trips"];
    // 3,000 veh/h for 28 minutes.
    assert!(trips["inserted"].as_u64().unwrap() >= 1300, "{trips}");
    assert!(trips["arrived"].as_u64().unwrap() >= 1200, "{trips}");
    assert_eq!(summary["metrics"]["red_light_crossings"], 0);
    assert!(summary["metrics"]["junctions"].as_array().unwrap().len() >= 30, "traffic at most of the 32 junctions");
}

#[test]
fn lanelet2_town_scenario_runs_on_the_example_map() {
    let (summary, out) = run(&root().join("scenarios/lanelet2_town.toml"), "lanelet2");
    assert_city_figures(&summary, &out, "lanelet2_town");
    assert!(summary["metrics"]["trips"]["arrived"].as_u64().unwrap() >= 80);
}

fn saturated_text(map: &Path, rate: f64, duration: f64) -> String {
    let arms = ["east", "north", "west", "south"];
    let mut text = format!("seed = 3\nduration = {duration}\nmap = \"{}\"\n", map.display());
    for a in arms {
        for b in arms.iter().filter(|b| **b != a) {
            text += &format!(
                "\n[[traffic]]\nroute = {{ from = \"{a}_start\", to = \"{b}_end\" }}\nrate = {rate}\nspeed = [8.0, 14.0]\n"
            );
        }
    }
    text
}

#[test]
fn a_saturated_four_arm_junction_keeps_flowing_for_thirty_minutes() {
    // Every movement from every arm, 1,800 veh/h offered in all, right before left.
    let path = scenario_file("saturated", &saturated_text(&root().join("maps/intersection4.osm"), 150.0, 1800.0));
    let (summary, out) = run(&path, "saturated");
    let m = &summary["metrics"];
    assert_eq!(m["collision_count"], 0, "{}", m["collisions"]);
    let j = &m["junctions"][0];
    assert!(j["vehicles_through"].as_u64().unwrap() >= 700, "a deadlock stops the flow: {j}");
    // No deadlock: nobody stands for ever. Offered more than a right-before-left junction
    // passes, its queues grow, and an arm whose right-hand arm streams without a gap waits on
    // it: the longest single wait over seeds 1 to 6 was 89 to 154 s before the route-aware
    // leader search (issue 54) and 86 to 162 s after it, with the same throughput (817 to 865
    // through). The issue's 120 s is a figure of its scenarios, which are not saturated.
    let (stood, who) = longest_standstill(&out);
    assert!(stood <= 240.0, "vehicle {who} stood {stood} s at once");
    // Still flowing at the end: vehicles left in the last five minutes.
    let trips = std::fs::read_to_string(out.join("trips.csv")).unwrap();
    let late = trips
        .lines()
        .skip(1)
        .filter(|l| l.split(',').nth(2).and_then(|a| a.parse::<f64>().ok()).is_some_and(|a| a > 1500.0))
        .count();
    assert!(late >= 60, "only {late} arrivals in the last 5 minutes");
}

#[test]
fn no_vehicle_passes_a_red_stop_line() {
    // A 4-way junction with lights and every movement; each control tick, each vehicle that moved
    // from a lanelet that is no link onto a junction link must see that link's signal not red.
    let dir = std::env::temp_dir().join(format!("smlworld-junctions-red-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let map_path = dir.join("lights.osm");
    let marks = JunctionMarks { traffic_lights: true, ..JunctionMarks::default() };
    std::fs::write(
        &map_path,
        generate::intersection(&IntersectionParams {
            arm_length: 80.0,
            control: marks,
            ..IntersectionParams::default()
        })
        .unwrap(),
    )
    .unwrap();
    let text = saturated_text(&map_path, 100.0, 400.0);
    let scenario = Scenario::parse_str(&text, &dir.join("red.toml")).expect("scenario parses");
    let mut sim = scenario.builder().expect("builds").build();
    let seen = common::red_entries(&mut sim, 400.0);
    assert!(seen.red_steps > 0, "the lights showed red");
    assert!(seen.entries >= 80, "only {} vehicles entered the junction", seen.entries);
    assert_eq!(seen.on_red, 0, "{} of {} vehicles entered on red: {:?}", seen.on_red, seen.entries, seen.first_reds);
}

/// A scenario on the generated 4-way junction with one `[[traffic_lights]]` table.
fn with_lights(lights: &str) -> Result<Scenario, ScenarioError> {
    let text =
        format!("map = \"{}\"\n\n[[traffic_lights]]\n{lights}\n", root().join("maps/intersection4.osm").display());
    Scenario::parse_str(&text, Path::new("lights.toml"))
}

#[test]
fn bad_light_programs_are_refused_with_the_key_and_the_reason() {
    let ok = with_lights(
        r#"junction = 1
program = [{ state = "GGGrrrGGGrrr", duration = 30.0 }, { state = "yyyrrryyyrrr", duration = 3.0 }, { state = "rrrGGGrrrGGG", duration = 30.0 }]"#,
    );
    assert!(ok.is_ok(), "{:?}", ok.err());
    let cases = [
        (
            r#"junction = 1
program = [{ state = "GGrr", duration = 30.0 }]"#,
            "traffic_lights[0].program[0].state",
            "12 links",
        ),
        (
            r#"junction = 7
program = [{ state = "GGGrrrGGGrrr", duration = 30.0 }]"#,
            "traffic_lights[0].junction",
            "not a junction",
        ),
        (
            r#"junction = 1
program = [{ state = "GGGrrrGGGrrr", duration = -3.0 }]"#,
            "traffic_lights[0].program[0].duration",
            "",
        ),
        (
            r#"junction = 1
program = [{ state = "GGGrrrGGGxrr", duration = 3.0 }]"#,
            "traffic_lights[0].program[0].state",
            "`x`",
        ),
        (
            r#"junction = 1
program = []"#,
            "traffic_lights[0].program",
            "empty",
        ),
        (
            r#"junction = 1
program = [{ state = "GGGrrrGGGrrr", duration = 3.0, colour = "red" }]"#,
            "colour",
            "",
        ),
    ];
    for (table, key, reason) in cases {
        let err = with_lights(table).err().unwrap_or_else(|| panic!("{table} was accepted")).to_string();
        assert!(err.contains(key), "{table}: {err}");
        assert!(err.contains(reason), "{table}: {err}");
    }
}

#[test]
fn map_info_json_lists_junctions_with_links_conflicts_and_control() {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["map", "info", "--json"])
        .arg(root().join("maps/intersection4_major.osm"))
        .output()
        .expect("smlworld runs");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let info: Value = serde_json::from_slice(&out.stdout).unwrap();
    let j = &info["junctions"][0];
    assert_eq!(j["id"], 1);
    assert_eq!(j["control"], "priority");
    assert_eq!(j["lanelets"].as_array().unwrap().len(), 12);
    let c = &j["conflicts"][0];
    for k in ["a", "b", "kind", "s_a", "s_b"] {
        assert!(!c[k].is_null(), "conflict field {k} missing: {c}");
    }
    let text = std::process::Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["map", "info"])
        .arg(root().join("maps/grid_5x5_lights.osm"))
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&text.stdout);
    assert_eq!(text.lines().filter(|l| l.contains(": traffic_light,")).count(), 32, "{text}");
}

/// Random traffic never starts within 25 m of a stop line: a car placed at speed just before
/// one could not stop for a red light or a foe (a 10 x 10 town had two placed there, 2 m and
/// 3 m before a red light, which crept over it and collided turning into the same street). Long
/// lanelets that end at a junction are origins; only their last 25 m are not.
#[test]
fn random_traffic_starts_clear_of_stop_lines() {
    let dir = std::env::temp_dir().join(format!("smlworld-junctions-clear-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let map_path = dir.join("town.osm");
    let params = GridParams {
        rows: 3,
        cols: 3,
        block: 200.0,
        lanes: 2,
        control: JunctionMarks { traffic_lights: true, major: None },
        ..GridParams::default()
    };
    std::fs::write(&map_path, generate::grid_city(&params).unwrap()).unwrap();
    let text = format!(
        "seed = 3\nduration = 1\nmap = \"{}\"\n\n[[traffic]]\nroute = \"random\"\ncount = 600\nspeed = [10.0, 14.0]\nclasses = {{ car = 1.0 }}\nlane_change = false\n",
        map_path.display()
    );
    let scenario = Scenario::parse_str(&text, &dir.join("clear.toml")).expect("scenario parses");
    let map = LaneletMap::load(&map_path).unwrap();
    let junctions = map.junctions();
    let mut sim = scenario.builder().expect("scenario builds").build();
    let world = sim.world_mut();
    let mut query = world.query::<(&VehicleId, &VehicleState, &Route)>();
    let (mut checked, mut long_before_junction) = (0, 0);
    for (id, state, route) in query.iter(world) {
        let origin = map.lanelet(route.0.lanelets[0]).expect("the origin is on the map");
        let to_junction = origin.successors.iter().any(|&next| junctions.of_lanelet(next).is_some());
        if !to_junction {
            continue;
        }
        let s = route.0.project(state.position).s;
        assert!(
            s <= origin.length - 25.0 + 1e-6,
            "vehicle {id:?} starts {:.1} m before the end of lanelet {:?}, which ends at a junction",
            origin.length - s,
            origin.id
        );
        checked += 1;
        long_before_junction += usize::from(origin.length > 100.0);
    }
    let _ = std::fs::remove_dir_all(&dir);
    assert!(checked > 50 && long_before_junction > 50, "too few vehicles on lanelets up to a junction: {checked}");
}

/// Lanelet2 `traffic_sign` regulatory elements rank the arms that carry them (issue 53 item 2):
/// a stop sign (`subtype=de206`) on the north and south approaches of the generated 4-way
/// junction makes those 6 links minor and the east-west ones major; a sign the rules do not
/// know (a speed limit) leaves the equal arms right-before-left.
#[test]
fn lanelet2_traffic_sign_elements_make_their_arms_minor() {
    let text = generate::intersection(&IntersectionParams::default()).unwrap();
    let plain = map_of(&text);
    let is_incoming = |l: &smlworld::map::Lanelet| l.successors.len() > 1;
    let north_south = |l: &smlworld::map::Lanelet| {
        let n = l.centre.len();
        let d = l.centre[n - 1] - l.centre[n - 2];
        d.y.abs() > d.x.abs()
    };
    let signed_ids: Vec<i64> =
        plain.lanelets.iter().filter(|l| is_incoming(l) && north_south(l)).map(|l| l.id.0).collect();
    assert_eq!(signed_ids.len(), 2, "one approach lanelet each from north and south");
    let with_sign = |subtype: &str| {
        let mut t = text.clone();
        for id in &signed_ids {
            let head = format!("<relation id='{id}'>");
            assert!(t.contains(&head), "lanelet relation {id} in the generated text");
            t = t.replace(
                &head,
                &format!("{head}\n    <member type='relation' ref='-90002' role='regulatory_element' />"),
            );
        }
        let sign = format!(
            "  <node id='-90010' lat='0.0001' lon='0.0001' />\n  <node id='-90011' lat='0.0001' lon='0.00012' />\n  \
             <way id='-90001'>\n    <nd ref='-90010' />\n    <nd ref='-90011' />\n    <tag k='type' v='traffic_sign' />\n    \
             <tag k='subtype' v='{subtype}' />\n  </way>\n  <relation id='-90002'>\n    \
             <member type='way' ref='-90001' role='refers' />\n    <tag k='type' v='regulatory_element' />\n    \
             <tag k='subtype' v='traffic_sign' />\n  </relation>\n</osm>"
        );
        map_of(&t.replace("</osm>", &sign))
    };
    assert_eq!(plain.junctions().list[0].control, JunctionControl::RightBeforeLeft);
    let stop = with_sign("de206");
    let j = stop.junctions();
    assert_eq!(j.list[0].control, JunctionControl::Priority);
    for link in &j.list[0].links {
        let from = stop.lanelet(link.from.expect("every link has an approach")).unwrap();
        assert_eq!(link.major, !north_south(from), "link {:?} from {:?}", link.lanelet, from.id);
    }
    assert_eq!(j.list[0].links.iter().filter(|l| l.major).count(), 6);
    let speed = with_sign("de274");
    assert_eq!(speed.junctions().list[0].control, JunctionControl::RightBeforeLeft);
}

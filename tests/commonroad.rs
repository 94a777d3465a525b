//! CommonRoad scenario files (2018b and 2020a, hand-made in tests/commonroad/): they load with
//! the file's lanelet ids and successor lists, route, render with their line markings, and their
//! obstacles sit at their recorded positions at every time step.

use std::path::{Path, PathBuf};
use std::process::Command;

use glam::DVec2;
use smlworld::map::commonroad::CommonRoadScenario;
use smlworld::map::{LaneletId, LaneletMap, MapError, Place, RouteOptions};
use smlworld::render::BirdseyeView;

fn file(version: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("tests/commonroad/two_lanes_{version}.xml"))
}

/// Obstacle 100 as tests/commonroad/make_files.py writes it (4 decimals in the file).
fn obstacle_100_at(k: i64) -> DVec2 {
    let k = k as f64;
    DVec2::new(10.0 + 1.0123 * k, 5.25 + 0.3 * (k / 5.0).sin())
}

#[test]
fn both_formats_load_with_the_files_ids_successors_and_obstacles() {
    for version in ["2018b", "2020a"] {
        let sc = CommonRoadScenario::load(&file(version)).unwrap();
        assert_eq!(sc.version, version);
        assert_eq!(sc.time_step_size, 0.1);
        let ids: Vec<i64> = sc.map.lanelets.iter().map(|l| l.id.0).collect();
        assert_eq!(ids, vec![1, 2, 3, 4, 5]);
        let succ = |id| sc.map.lanelet(LaneletId(id)).unwrap().successors.iter().map(|s| s.0).collect::<Vec<_>>();
        assert_eq!((succ(1), succ(2), succ(3), succ(4), succ(5)), (vec![2], vec![5], vec![4], vec![], vec![]));
        // Lanelet 1: right bound y = 0, left bound y = 3.5 from x = 0 to 50: centre line at 1.75 m.
        let l1 = sc.map.lanelet(LaneletId(1)).unwrap();
        assert!((l1.length - 50.0).abs() < 1e-9);
        assert!(l1.centre.iter().all(|p| (p.y - 1.75).abs() < 1e-9));
        assert_eq!(l1.tags["adjacent_left"], "3");
        assert_eq!(l1.tags["adjacent_left_driving_dir"], "same");
        assert_eq!(sc.map.ways[&l1.left_way].tags["line_marking"], "dashed");
        assert_eq!(sc.map.ways[&l1.right_way].tags["line_marking"], "solid");

        assert_eq!(sc.obstacles.iter().map(|o| o.id).collect::<Vec<_>>(), vec![100, 101]);
        let o = &sc.obstacles[0];
        assert_eq!((o.kind.as_str(), o.length, o.width), ("car", 4.5, 1.8));
        assert_eq!(o.states.len(), 41);
        for k in [0, 1, 10, 25, 40] {
            let s = o.state_at(k).unwrap();
            assert!(s.position.distance(obstacle_100_at(k)) < 1e-3, "{version} obstacle 100 at step {k}: {s:?}");
            assert_eq!(s.velocity, 10.123);
        }
        assert!(o.state_at(41).is_none());
        assert_eq!(sc.obstacles[1].state_at(80).unwrap().position, DVec2::new(80.0, 1.75));

        let pp = &sc.planning_problems[0];
        assert_eq!(pp.id, 200);
        assert_eq!(pp.initial_state.position, DVec2::new(5.0, 1.75));
        assert_eq!(pp.initial_state.velocity, 12.0);
        let goal = &pp.goals[0];
        assert_eq!((goal.time_start, goal.time_end), (0, 200));
        assert!(goal.shapes[0].contains(DVec2::new(73.0, 2.0), &sc.map));
        assert!(!goal.shapes[0].contains(DVec2::new(64.0, 1.75), &sc.map));
        assert!(!goal.shapes[0].contains(DVec2::new(70.0, 4.0), &sc.map));
    }
}

#[test]
fn routes_follow_the_successor_lists() {
    let map = LaneletMap::load(&file("2020a")).unwrap();
    let opts = RouteOptions::default();
    let path = map.route_places(&Place::Tag("start_1".into()), &Place::Tag("end_5".into()), &opts).unwrap();
    assert_eq!(path.lanelets, vec![LaneletId(1), LaneletId(2), LaneletId(5)]);
    // 100 m straight plus lanelet 5's centre line, a 45 degree arc of radius 38.25 m.
    let arc = 38.25 * std::f64::consts::FRAC_PI_4;
    assert!((path.length - (100.0 + arc)).abs() < 0.2, "{}", path.length);
    // Lanelet 3 leads only to 4: there is no lane change in a lanelet graph of successors.
    let err = map.route_places(&Place::Tag("start_3".into()), &Place::Tag("end_5".into()), &opts).unwrap_err();
    assert!(matches!(err, MapError::NoRoute { .. }), "{err}");
}

#[test]
fn render_draws_the_road_and_its_markings() {
    let dir = std::env::temp_dir().join(format!("smlworld-commonroad-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let png = dir.join("cr.png");
    let out = Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["map", "render"])
        .arg(file("2018b"))
        .args(["--out", png.to_str().unwrap(), "--width", "800", "--height", "500"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let img = image::open(&png).unwrap().to_rgba8();
    let view = BirdseyeView::fit_map(800, 500, &LaneletMap::load(&file("2018b")).unwrap()).unwrap();
    let px = |x: f64, y: f64| {
        let p = view.world_to_pixel(DVec2::new(x, y));
        img.get_pixel(p.x.round() as u32, p.y.round() as u32).0
    };
    let grey = |c: [u8; 4]| c[0].abs_diff(c[1]) < 20 && c[1].abs_diff(c[2]) < 20 && c[0] > 50 && c[0] < 140;
    // Road surface in the middle of each lane, forest beside the road.
    assert!(grey(px(25.0, 1.75)) && grey(px(25.0, 5.25)), "{:?} {:?}", px(25.0, 1.75), px(25.0, 5.25));
    let forest = px(25.0, 20.0);
    assert!(forest[1] > forest[0] && forest[1] > forest[2], "{forest:?}");
    // The solid outer edges (y = 0 and y = 7) are yellow; the dashed centre line (y = 3.5) is
    // white where painted (dash period 6 m: painted from 0 to 3 m of each period).
    // (A 0.3 m line is about 1.7 px wide here: one of the pixel rows at and next to it is fully yellow.)
    let yellow = |c: [u8; 4]| c[0] > 200 && c[1] > 160 && c[2] < 90;
    let per_px = 1.0 / view.pixels_per_meter;
    for y in [0.0, 7.0] {
        let rows = [px(25.0, y - per_px), px(25.0, y), px(25.0, y + per_px)];
        assert!(rows.iter().any(|c| yellow(*c)), "edge at y = {y} m: {rows:?}");
    }
    let white = |c: [u8; 4]| c.iter().take(3).all(|&v| v > 180);
    let painted = (0..100).filter(|i| white(px(*i as f64 * 0.5, 3.5))).count();
    assert!((30..=70).contains(&painted), "{painted} of 100 samples of the dashed line are white");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_files_name_file_line_and_what_is_missing() {
    let good = std::fs::read_to_string(file("2020a")).unwrap();
    let name = Path::new("bad.xml");
    // A lanelet without a right bound.
    let start = good.find("    <rightBound>").unwrap();
    let end = good.find("    </rightBound>").unwrap() + "    </rightBound>\n".len();
    let bad = format!("{}{}", &good[..start], &good[end..]);
    let err = CommonRoadScenario::parse_str(&bad, name).unwrap_err().to_string();
    let line = bad.lines().position(|l| l.contains("<lanelet id=\"1\">")).unwrap() + 1;
    assert!(err.starts_with(&format!("bad.xml:{line}: CommonRoad: lanelet 1 has no <rightBound>")), "{err}");
    // A duplicate lanelet id.
    let bad = good.replacen("<lanelet id=\"2\">", "<lanelet id=\"1\">", 1);
    let err = CommonRoadScenario::parse_str(&bad, name).unwrap_err().to_string();
    assert!(err.contains("duplicate lanelet id 1"), "{err}");
    // A coordinate that is not a number names its line.
    let bad = good.replacen("<x>0.0000</x>", "<x>zero</x>", 1);
    let line = bad.lines().position(|l| l.contains("zero")).unwrap() + 1;
    let err = CommonRoadScenario::parse_str(&bad, name).unwrap_err().to_string();
    assert!(err.starts_with(&format!("bad.xml:{line}: CommonRoad: <x> \"zero\" is not a finite number")), "{err}");
    // No time step size.
    let bad = good.replacen("timeStepSize=\"0.1\"", "", 1);
    let err = CommonRoadScenario::parse_str(&bad, name).unwrap_err().to_string();
    assert!(err.contains("no `timeStepSize`"), "{err}");
    // An OSM file is not a CommonRoad file.
    let err = CommonRoadScenario::parse_str("<osm version='0.6'></osm>", name).unwrap_err().to_string();
    assert!(err.contains("no <commonRoad> root element"), "{err}");
}

fn run(scenario: &str, out: &Path) -> serde_json::Value {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios").join(scenario);
    let o = Command::new(env!("CARGO_BIN_EXE_smlworld")).arg("run").arg(&path).arg("--out").arg(out).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap()
}

fn collisions(summary: &serde_json::Value) -> Vec<(i64, i64)> {
    let list = summary["metrics"]["collisions"].as_array().unwrap();
    list.iter().map(|c| (c["a"].as_i64().unwrap(), c["b"].as_i64().unwrap())).collect()
}

#[test]
fn replayed_obstacles_follow_their_trajectories_and_acc_avoids_them() {
    let dir = std::env::temp_dir().join(format!("smlworld-commonroad-run-{}", std::process::id()));
    let acc = run("commonroad_acc.toml", &dir.join("acc"));

    // Obstacles -100 and -101 at their time steps (log rate 10 Hz = 1 / timeStepSize): to 1 mm.
    let csv = std::fs::read_to_string(dir.join("acc/trajectories.csv")).unwrap();
    let mut checked = 0;
    for line in csv.lines().skip(1) {
        let f: Vec<f64> = line.split(',').take(7).map(|v| v.parse().unwrap()).collect(); // t..vy (lanelet may be empty)
        let k = (f[0] / 0.1).round() as i64;
        let p = DVec2::new(f[2], f[3]);
        let expected = match f[1] as i32 {
            -100 if k <= 40 => obstacle_100_at(k),
            -101 if k <= 80 => DVec2::new(40.0 + 0.5 * k as f64, 1.75),
            _ => continue,
        };
        assert!(p.distance(expected) < 1e-3, "obstacle {} at step {k}: {p} instead of {expected}", f[1]);
        checked += 1;
    }
    assert_eq!(checked, 41 + 81);

    // The ACC ego follows the slow obstacle -101 without touching anything and reaches the goal
    // region (x 65..75 m) once -101 has moved on.
    assert_eq!(collisions(&acc), vec![]);
    let follower = &acc["metrics"]["followers"][0];
    assert_eq!((follower["id"].as_i64(), follower["leader"].as_i64()), (Some(-1), Some(-101)));
    assert!(follower["min_gap"].as_f64().unwrap() > 2.0, "{follower}");
    let goal = &acc["commonroad"]["goals"]["-1"];
    assert_eq!((goal["planning_problem"].as_i64(), goal["reached"].as_bool()), (Some(200), Some(true)), "{goal}");
    assert_eq!(acc["commonroad"]["obstacles"].as_u64(), Some(2));

    // The same ego without ACC (path following at 12 m/s) runs into -101 (5 m/s, 35 m ahead):
    // closing at 7 m/s over 35 m - 4.5 m of car lengths, at about 4.4 s.
    let ignore = run("commonroad_ignore.toml", &dir.join("ignore"));
    assert_eq!(collisions(&ignore), vec![(-101, -1)]);
    let t = ignore["metrics"]["collisions"][0]["t"].as_f64().unwrap();
    assert!((t - 30.5 / 7.0).abs() < 0.15, "collision at {t} s");
    // Issue 22 item 7: it drives on into the goal region at 5 s, but a goal reached after a
    // collision does not count; summary.json marks both collided vehicles.
    let goal = &ignore["commonroad"]["goals"]["-1"];
    assert_eq!(goal["reached"].as_bool(), Some(false), "{goal}");
    assert_eq!(goal["collision"].as_f64(), Some(t), "{goal}");
    let collided = ignore["metrics"]["collided"].as_object().expect("metrics.collided");
    let ids: Vec<&str> = collided.keys().map(String::as_str).collect();
    assert_eq!(ids, vec!["-1", "-101"], "{collided:?}");
    assert_eq!(collided["-1"].as_f64(), Some(t));
    assert_eq!(acc["metrics"]["collided"].as_object().map(|o| o.len()), Some(0));
    assert_eq!(acc["commonroad"]["goals"]["-1"]["collision"], serde_json::Value::Null);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn commonroad_keys_need_a_commonroad_map_and_known_problems() {
    use smlworld::app::Scenario;
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios");
    let text = std::fs::read_to_string(dir.join("commonroad_acc.toml")).unwrap();
    let path = dir.join("probe.toml");
    let bad = text.replace("planning_problem = 200", "planning_problem = 7");
    let err = Scenario::parse_str(&bad, &path).unwrap_err().to_string();
    assert!(
        err.contains("`vehicles[0] (id -1).planning_problem` 7 is not a planning problem of the map (it has: 200)"),
        "{err}"
    );
    let bad =
        text.replace("two_lanes_2020a.xml", "../../maps/highway_ring.osm").replace("planning_problem = 200\n", "");
    let err = Scenario::parse_str(&bad, &path).unwrap_err().to_string();
    assert!(err.contains("`obstacles` needs a CommonRoad scenario file as `map`"), "{err}");
    let bad = text.replace("obstacles = \"replay\"", "obstacles = \"ignore\"");
    let err = Scenario::parse_str(&bad, &path).unwrap_err().to_string();
    assert!(err.contains("replay"), "{err}");
}

/// The generated 4-way junction written as a CommonRoad 2020a file (ids 1.., bounds and
/// successors as generated), with `extra(lanelet, heading at its end)` added inside each
/// lanelet element, and `root_extra` after the lanelets.
fn intersection_as_commonroad(extra: &dyn Fn(&smlworld::map::Lanelet, f64) -> String, root_extra: &str) -> String {
    use smlworld::map::generate::{self, IntersectionParams};
    let text = generate::intersection(&IntersectionParams::default()).unwrap();
    let map = LaneletMap::parse_str(&text, Path::new("x.osm")).unwrap();
    let id = |l: LaneletId| map.lanelets.iter().position(|m| m.id == l).unwrap() + 1;
    let points =
        |ps: &[DVec2]| ps.iter().map(|p| format!("<point><x>{}</x><y>{}</y></point>", p.x, p.y)).collect::<String>();
    let mut out = String::from(
        r#"<?xml version="1.0" encoding="UTF-8"?>
<commonRoad timeStepSize="0.1" commonRoadVersion="2020a" author="t" affiliation="t" source="t" benchmarkID="ZAM_Junction-1_1_T-1" date="2026-12-05">
"#,
    );
    for l in &map.lanelets {
        let n = l.centre.len();
        let d = l.centre[n - 1] - l.centre[n - 2];
        let successors: String = l.successors.iter().map(|s| format!("<successor ref=\"{}\"/>", id(*s))).collect();
        out += &format!(
            "<lanelet id=\"{}\"><leftBound>{}</leftBound><rightBound>{}</rightBound>{successors}<laneletType>urban</laneletType>{}</lanelet>\n",
            id(l.id),
            points(&l.left),
            points(&l.right),
            extra(l, d.y.atan2(d.x))
        );
    }
    out + root_extra + "</commonRoad>\n"
}

/// CommonRoad's traffic lights and signs decide a junction's control (issue 53 item 2 and 4):
/// lights referenced by the incoming lanelets make it signalled, stop signs (206) on two arms
/// make those arms minor and the others major; without either the equal arms are
/// right-before-left. Counted by hand: the generated junction has 12 links, 3 per arm.
#[test]
fn traffic_lights_and_signs_of_a_commonroad_file_set_the_junction_control() {
    use smlworld::map::junctions::JunctionControl;
    let load = |text: String| CommonRoadScenario::parse_str(&text, Path::new("junction.xml")).unwrap().map;
    let is_incoming = |l: &smlworld::map::Lanelet| l.successors.len() > 1;
    let north_south = |heading: f64| heading.sin().abs() > 0.7;

    let plain = load(intersection_as_commonroad(&|_, _| String::new(), ""));
    let j = plain.junctions();
    assert_eq!(j.list.len(), 1);
    assert_eq!(j.list[0].links.len(), 12);
    assert_eq!(j.list[0].control, JunctionControl::RightBeforeLeft);

    let light = r#"<trafficLight id="900"><cycle><cycleElement><duration>300</duration><color>green</color></cycleElement><cycleElement><duration>300</duration><color>red</color></cycleElement></cycle></trafficLight>"#;
    let lit = load(intersection_as_commonroad(
        &|l, _| if is_incoming(l) { "<trafficLightRef ref=\"900\"/>".into() } else { String::new() },
        light,
    ));
    let j = lit.junctions();
    assert_eq!(j.list[0].control, JunctionControl::TrafficLight);
    assert!(j.list[0].links.iter().all(|l| l.signal.is_some()));
    let incoming = lit.lanelets.iter().find(|l| is_incoming(l)).unwrap();
    assert_eq!(incoming.tags.get("commonroad:traffic_light").map(String::as_str), Some("900"));

    let stop = r#"<trafficSign id="800"><trafficSignElement><trafficSignID>206</trafficSignID></trafficSignElement></trafficSign>"#;
    let signed = load(intersection_as_commonroad(
        &|l, h| if is_incoming(l) && north_south(h) { "<trafficSignRef ref=\"800\"/>".into() } else { String::new() },
        stop,
    ));
    let j = signed.junctions();
    assert_eq!(j.list[0].control, JunctionControl::Priority);
    let majors: Vec<bool> = j.list[0].links.iter().map(|l| l.major).collect();
    assert_eq!(majors.iter().filter(|m| **m).count(), 6, "east and west arms major: {majors:?}");
    for link in &j.list[0].links {
        assert_eq!(link.major, !north_south(link.heading_in), "link {:?} heading {}", link.lanelet, link.heading_in);
    }

    // A reference to a light or sign the file does not have is a warning, not a silent tag.
    let dangling = load(intersection_as_commonroad(
        &|l, _| if is_incoming(l) { "<trafficLightRef ref=\"901\"/>".into() } else { String::new() },
        "",
    ));
    assert_eq!(dangling.junctions().list[0].control, JunctionControl::RightBeforeLeft);
    assert!(dangling.warnings.iter().any(|w| w.message.contains("trafficLightRef 901")), "{:?}", dangling.warnings);
}

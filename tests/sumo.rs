//! SUMO networks and demand (issue 54 §1) on sumo-rl's nets (PyPI `sumo-rl`, installed into
//! `.venv` by `scripts/test.sh`): lane, link and light counts against the files, right of way
//! and signal programs from the file, bad input named by file, line and id, and a run of
//! `2way-single-intersection` with its `vhvh` demand.

use std::path::{Path, PathBuf};
use std::process::Command;

use smlworld::map::junctions::map_program;
use smlworld::map::sumo::demand::Demand;
use smlworld::map::{JunctionControl, LaneletMap};

/// sumo-rl's `nets` folder: `$SUMO_RL_NETS`, else asked of `.venv/bin/python` (without importing
/// sumo_rl, which needs SUMO_HOME). Fails, never skips, when neither finds it.
fn nets() -> PathBuf {
    if let Some(dir) = std::env::var_os("SUMO_RL_NETS") {
        return PathBuf::from(dir);
    }
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let python = root.join(".venv/bin/python");
    let out = Command::new(&python)
        .args([
            "-c",
            "import importlib.util;print(importlib.util.find_spec('sumo_rl').submodule_search_locations[0]+'/nets')",
        ])
        .output()
        .unwrap_or_else(|e| {
            panic!(
                "cannot run {} ({e}): the SUMO tests need sumo-rl's nets; run `bash scripts/test.sh` once (it installs python/requirements-test.txt into .venv) or set SUMO_RL_NETS",
                python.display()
            )
        });
    let dir = PathBuf::from(String::from_utf8_lossy(&out.stdout).trim());
    assert!(
        out.status.success() && dir.is_dir(),
        "sumo-rl is not installed in .venv ({}): `.venv/bin/pip install sumo-rl` (python/requirements-test.txt) or set SUMO_RL_NETS",
        String::from_utf8_lossy(&out.stderr).trim()
    );
    dir
}

fn net(rel: &str) -> PathBuf {
    let p = nets().join(rel);
    assert!(p.is_file(), "{} is missing from sumo-rl's nets", p.display());
    p
}

fn load(rel: &str) -> LaneletMap {
    let p = net(rel);
    LaneletMap::load(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

/// What the file says, counted from its text alone (not by our reader): normal vehicle lanes,
/// connections with a `via` from a normal lane, lights (`tlLogic` ids), and junctions of type
/// `traffic_light*`.
struct FileCounts {
    lanes: usize,
    links: usize,
    lights: usize,
    light_junctions: usize,
}

fn attr<'a>(line: &'a str, name: &str) -> Option<&'a str> {
    let key = format!(" {name}=\"");
    let start = line.find(&key)? + key.len();
    line[start..].split('"').next()
}

fn count(path: &Path) -> FileCounts {
    let text = std::fs::read_to_string(path).unwrap();
    let mut c = FileCounts { lanes: 0, links: 0, lights: 0, light_junctions: 0 };
    let mut lights = std::collections::BTreeSet::new();
    let mut in_pedestrian = false;
    for line in text.lines().map(str::trim) {
        if line.starts_with("<edge ") {
            in_pedestrian = matches!(attr(line, "function"), Some("crossing" | "walkingarea"));
        } else if line.starts_with("<lane ") && !in_pedestrian && !attr(line, "id").unwrap().starts_with(':') {
            c.lanes += 1;
        } else if line.starts_with("<connection ")
            && attr(line, "via").is_some()
            && !attr(line, "from").unwrap().starts_with(':')
        {
            c.links += 1;
        } else if line.starts_with("<tlLogic ") {
            lights.insert(attr(line, "id").unwrap().to_string());
        } else if line.starts_with("<junction ") && attr(line, "type").is_some_and(|t| t.starts_with("traffic_light")) {
            c.light_junctions += 1;
        }
    }
    c.lights = lights.len();
    c
}

fn check_counts(rel: &str) -> LaneletMap {
    check_counts_at(&net(rel), rel)
}

fn check_counts_at(path: &Path, rel: &str) -> LaneletMap {
    let map = LaneletMap::load(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let file = count(path);
    let lanes = map.lanelets.iter().filter(|l| !l.tags.contains_key("sumo:function")).count();
    let links = map.lanelets.iter().filter(|l| l.tags.contains_key("sumo:function")).count();
    assert_eq!(lanes, file.lanes, "{rel}: lanes");
    assert_eq!(links, file.links, "{rel}: connections through a junction");
    assert_eq!(map.signal_programs.len(), file.lights, "{rel}: tlLogic programs");
    let junctions = map.junctions();
    let lit = junctions.list.iter().filter(|j| j.control == JunctionControl::TrafficLight).count();
    assert_eq!(lit, file.light_junctions, "{rel}: signalled junctions");
    for l in &map.lanelets {
        assert!(l.tags.contains_key("sumo:lane") && l.tags.contains_key("sumo:edge"), "{rel}: lanelet {} tags", l.id);
    }
    // Every signalled junction runs the file's program, not the default one.
    for j in junctions.list.iter().filter(|j| j.control == JunctionControl::TrafficLight) {
        assert!(map_program(&map, j).is_some(), "{rel}: junction {} has no program from the file", j.id);
    }
    map
}

#[test]
fn two_way_single_intersection_loads_with_its_lanes_links_and_light() {
    let map = check_counts("2way-single-intersection/single-intersection.net.xml");
    assert_eq!(map.lanelets.len(), 16 + 16);
    let by_lane = |id: &str| map.lanelets.iter().find(|l| l.tags["sumo:lane"] == id).unwrap();
    // Lane n_t_0 (index 0, the right one) has n_t_1 on its left; 13.90 m/s is 50.04 km/h.
    let n0 = by_lane("n_t_0");
    let n1 = by_lane("n_t_1");
    let neighbours = map.neighbours_of(n0.id).unwrap();
    assert_eq!(neighbours.left, Some(n1.id));
    assert!(neighbours.change_left);
    assert_eq!(n0.tags["speed_limit"], "50.04");
    assert!((n0.length - 141.95).abs() < 0.05, "length {}", n0.length);
    // Its width is SUMO's default 3.2 m on the outside; the border it shares with n_t_1 (3.3 m
    // apart) lies midway: 1.6 + 1.65 m.
    assert!((n0.left[0].distance(n0.right[0]) - 3.25).abs() < 1e-6, "{}", n0.left[0].distance(n0.right[0]));
    // n_t_0 leads through :t_0_0 (right) and :t_1_0 (straight) to t_w_0 and t_s_0.
    let via: Vec<&str> = n0.successors.iter().map(|s| map.lanelet(*s).unwrap().tags["sumo:lane"].as_str()).collect();
    assert_eq!(via, [":t_0_0", ":t_1_0"]);
    assert_eq!(map.lanelet(map.lanelet(n0.successors[1]).unwrap().successors[0]).unwrap().tags["sumo:lane"], "t_s_0");

    let junctions = map.junctions();
    assert_eq!(junctions.len(), 1);
    let j = &junctions.list[0];
    assert_eq!(j.control, JunctionControl::TrafficLight);
    assert_eq!(j.links.len(), 12);
    // The program is the file's, each state re-ordered into link order: link with internal
    // lane :t_k_0 shows character k of the tlLogic state.
    let (program, offset) = map_program(&map, j).unwrap();
    assert_eq!(offset, 0.0);
    let file_states = ["GGrrrrGGrrrr", "yyrrrryyrrrr", "rrGrrrrrGrrr", "rryrrrrryrrr"];
    assert_eq!(program.len(), 8);
    assert_eq!(program.iter().map(|p| p.duration).collect::<Vec<_>>(), [33.0, 2.0, 6.0, 2.0, 33.0, 2.0, 6.0, 2.0]);
    for (phase, file) in program.iter().zip(file_states) {
        for (link, c) in j.links.iter().zip(phase.state.chars()) {
            let lane = &map.lanelet(link.lanelet).unwrap().tags["sumo:lane"];
            let k: usize = lane[3..lane.len() - 2].parse().unwrap();
            assert_eq!(c, file.as_bytes()[k] as char, "link {lane}");
        }
    }
    // Right of way from the file's <request>: the left turn from the east (:t_5_0, request 5,
    // response 011110000110) yields to the straight link from the west (:t_10_0, bit 10).
    let id_of = |lane: &str| by_lane(lane).id;
    let (left, straight) = (id_of(":t_5_0"), id_of(":t_10_0"));
    let c = j.conflicts.iter().find(|c| (c.a, c.b) == (left.min(straight), left.max(straight))).unwrap();
    assert_eq!(c.yields_from(left), Some(true));
    // The opposite left turns (:t_2_0 and :t_8_0) are no foes in the file: no conflict here.
    let (a, b) = (id_of(":t_2_0"), id_of(":t_8_0"));
    assert!(!j.conflicts.iter().any(|c| (c.a == a && c.b == b) || (c.a == b && c.b == a)));
}

#[test]
fn four_by_four_lucas_and_resco_grid4x4_load_with_their_counts() {
    check_counts("4x4-Lucas/4x4.net.xml");
    let grid = check_counts("RESCO/grid4x4/grid4x4.net.xml");
    assert_eq!(grid.signal_programs.len(), 16);
}

#[test]
fn map_info_json_lists_the_sumo_tags_and_the_light() {
    let path = net("2way-single-intersection/single-intersection.net.xml");
    let out = Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["map", "info", "--json"])
        .arg(&path)
        .output()
        .expect("runs smlworld");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let lanelets = v["lanelet_list"].as_array().unwrap();
    assert!(lanelets.iter().any(|l| l["tags"]["sumo:lane"] == "w_t_1" && l["tags"]["sumo:edge"] == "w_t"));
    assert_eq!(v["junctions"][0]["control"], "traffic_light");
}

/// The 2way-single-intersection net with `from` replaced by `to`.
fn edited_net(from: &str, to: &str) -> (String, PathBuf) {
    let path = net("2way-single-intersection/single-intersection.net.xml");
    let text = std::fs::read_to_string(&path).unwrap();
    assert!(text.contains(from), "the net no longer has `{from}`");
    (text.replacen(from, to, 1), path)
}

#[test]
fn a_connection_to_an_unknown_lane_is_refused_with_file_line_and_ids() {
    let (text, path) = edited_net(
        r#"to="t_w" fromLane="0" toLane="0" via=":t_4_0""#,
        r#"to="t_w" fromLane="0" toLane="7" via=":t_4_0""#,
    );
    let line = text.lines().position(|l| l.contains(r#"toLane="7""#)).unwrap() + 1;
    let e = LaneletMap::parse_str(&text, &path).unwrap_err().to_string();
    assert!(e.contains(&format!("single-intersection.net.xml:{line}")), "{e}");
    assert!(e.contains("lane 7 of edge t_w") && e.contains("from e_t lane 0"), "{e}");
}

#[test]
fn bad_demand_is_refused_with_file_line_and_id() {
    let map = load("2way-single-intersection/single-intersection.net.xml");
    let file = Path::new("bad.rou.xml");
    let cases = [
        // n_t leads to t_s, not back into the north (t_n) from n_t.
        (
            r#"<routes><route id="r" edges="n_t t_n"/><vehicle id="v1" depart="0" route="r"/></routes>"#,
            "vehicle v1",
            "no connection leads from edge n_t to edge t_n",
        ),
        (
            r#"<routes>
<flow id="f1" begin="0" end="100">
<route edges="n_t t_s"/></flow></routes>"#,
            "flow f1",
            "needs a rate",
        ),
        (
            r#"<routes><trip id="t1" depart="0" from="n_t" to="nowhere"/></routes>"#,
            "trip t1",
            "edge nowhere is not in the network",
        ),
        (
            r#"<routes><vehicle id="v2" depart="0" route="missing"/></routes>"#,
            "vehicle v2",
            "route missing is not defined",
        ),
    ];
    for (text, id, why) in cases {
        let e = Demand::parse_str(text, file, &map, 3600.0).unwrap_err().to_string();
        let line = text.lines().position(|l| l.contains(id.split(' ').nth(1).unwrap())).unwrap() + 1;
        assert!(e.contains(&format!("bad.rou.xml:{line}")), "{e}");
        assert!(e.contains(id) && e.contains(why), "{e}");
    }
}

#[test]
fn demand_reads_types_flows_and_trips() {
    let map = load("2way-single-intersection/single-intersection.net.xml");
    let text = r#"<routes>
  <vType id="idm" carFollowModel="IDM" length="4.5" minGap="2" accel="1.5" decel="3" maxSpeed="20" tau="1.2" delta="4"/>
  <flow id="f" type="idm" begin="10" end="70" vehsPerHour="120" departSpeed="max"><route edges="w_t t_e"/></flow>
  <flow id="n" begin="0" end="100" number="4" departLane="1" departSpeed="5"><route edges="n_t t_e"/></flow>
  <trip id="t" depart="3" from="s_t" to="t_n"/>
</routes>"#;
    let d = Demand::parse_str(text, Path::new("ok.rou.xml"), &map, 3600.0).unwrap();
    assert_eq!(d.types[1].length, 4.5);
    assert_eq!(d.types[1].tau, 1.2);
    let times = |k: usize| match &d.groups[k].departures {
        smlworld::map::sumo::demand::Departures::Times(t) => t.clone(),
        other => panic!("{other:?}"),
    };
    // 120 veh/h from 10 s to 70 s: every 30 s.
    assert_eq!(times(0), [10.0, 40.0]);
    // 4 vehicles over 100 s: every 25 s.
    assert_eq!(times(1), [0.0, 25.0, 50.0, 75.0]);
    assert_eq!(times(2), [3.0]);
    // The straight flow may start on either lane from which t_e is reached: only lane 0 of w_t.
    assert_eq!(d.groups[0].routes.len(), 1);
    // The trip was routed s_t -> t_n: lane, junction link, lane.
    assert_eq!(d.groups[2].routes[0].len(), 3);
}

#[test]
fn two_way_single_intersection_runs_its_vhvh_demand_without_collisions() {
    let dir = nets().join("2way-single-intersection");
    let out = std::env::temp_dir().join(format!("smlworld-sumo-vhvh-{}", std::process::id()));
    std::fs::create_dir_all(&out).unwrap();
    let scenario = out.join("vhvh.toml");
    let end = 1000.0;
    std::fs::write(
        &scenario,
        format!(
            "map = {:?}\ndemand = [{:?}]\nduration = {end}\n",
            dir.join("single-intersection.net.xml"),
            dir.join("single-intersection-vhvh.rou.xml")
        ),
    )
    .unwrap();
    let summary = run_summary(&scenario, &out.join("out"));
    let m = &summary["metrics"];
    assert_eq!(m["collision_count"], 0, "{}", m["collisions"]);
    assert_eq!(m["red_light_crossings"], 0);
    let (inserted, removed) = inserted_and_arrived(m);
    // SUMO 1.28 on the same files inserts 396 of the 422 vehicles due in 600 s; the left
    // turns (300 veh/h for 6 s of green in 86 s) queue in both.
    assert!(inserted > 450 && removed > 400, "inserted {inserted}, arrived {removed}");
    // SUMO 1.28 on these files for 1000 s (`sumo -n .. -r .. --end 1000 --step-length 0.1
    // --seed 42`): 638 inserted, 579 arrived, mean duration 76.5 s. The issue asks for our mean
    // travel time within +-15 % of SUMO's. Its turns are 3 m arcs whose internal lanes say
    // 13.9 m/s, and SUMO drives them so: with a lateral limit of our own we inserted 492 and took
    // 135 s (2 m/s²), 562 and 122 s (5.5 m/s²); driven at the file's speeds (`sumo_lateral_accel`
    // 0, the default), 636 and 77.3 s.
    assert!(inserted as f64 >= 0.95 * 638.0, "inserted {inserted} of SUMO's 638");
    let travel = m["trips"]["mean_travel_time_s"].as_f64().unwrap();
    assert!((travel / 76.5 - 1.0).abs() <= 0.15, "mean travel time {travel:.1} s against SUMO's 76.5 s");
    // Every vehicle that had time to finish arrived: those inserted in the first 200 s (the
    // longest left-turn queue takes under 800 s to clear).
    let trips = std::fs::read_to_string(out.join("out/trips.csv")).unwrap();
    let mut early = 0;
    for row in trips.lines().skip(1) {
        let cols: Vec<&str> = row.split(',').collect();
        let depart: f64 = cols[1].parse().unwrap();
        if depart < 200.0 {
            early += 1;
            assert!(!cols[2].is_empty(), "vehicle {} inserted at {depart} s has not arrived by {end} s", cols[0]);
        }
    }
    assert!(early > 100, "{early} vehicles inserted in the first 200 s");
    std::fs::remove_dir_all(&out).ok();
}

#[test]
fn resco_grid4x4_runs_from_its_sumocfg_like_sumo() {
    let cfg = net("RESCO/grid4x4/grid4x4.sumocfg");
    let out = std::env::temp_dir().join(format!("smlworld-sumo-grid4x4-{}", std::process::id()));
    let summary = run_summary_with(&cfg, &out, &["--duration", "600"]);
    let m = &summary["metrics"];
    assert_eq!(m["collision_count"], 0, "{}", m["collisions"]);
    assert_eq!(m["red_light_crossings"], 0);
    // SUMO 1.28 (`sumo -c grid4x4.sumocfg --end 600`): 141 inserted, 94 arrived, mean duration
    // 181.59 s. Ours must insert as many and match the travel time within 15 %.
    assert_eq!(m["traffic"]["inserted"], 141);
    let trips = std::fs::read_to_string(out.join("trips.csv")).unwrap();
    let times: Vec<f64> = trips
        .lines()
        .skip(1)
        .filter_map(|row| row.split(',').nth(4).filter(|t| !t.is_empty()).map(|t| t.parse().unwrap()))
        .collect();
    assert!(times.len() >= 85, "{} arrived", times.len());
    let mean = times.iter().sum::<f64>() / times.len() as f64;
    assert!((mean / 181.59 - 1.0).abs() < 0.15, "mean travel time {mean:.1} s against SUMO's 181.59 s");
    std::fs::remove_dir_all(&out).ok();
}

#[test]
fn map_route_and_render_take_a_sumo_net() {
    let path = net("2way-single-intersection/single-intersection.net.xml");
    let out = Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["map", "route"])
        .arg(&path)
        .args(["--from-tag", "start:n_t_0", "--to-tag", "end:t_s_0", "--json"])
        .output()
        .expect("runs smlworld");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    // n_t_0, the straight link :t_1_0, t_s_0: 141.95 + 16.10 + 141.95 m.
    assert_eq!(v["lanelets"].as_array().unwrap().len(), 3);
    assert!((v["length_m"].as_f64().unwrap() - 300.0).abs() < 0.5, "{}", v["length_m"]);
    let png = std::env::temp_dir().join(format!("smlworld-sumo-render-{}.png", std::process::id()));
    let out = Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["map", "render"])
        .arg(&path)
        .arg("--out")
        .arg(&png)
        .output()
        .expect("runs smlworld");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(std::fs::metadata(&png).unwrap().len() > 1000);
    std::fs::remove_file(&png).ok();
    std::fs::remove_file(png.with_extension("meta")).ok();
}

/// A netgenerate grid of `n` x `n` nodes `length` m apart, 2 lanes per edge, lights guessed, at
/// `out` (eclipse-sumo's netgenerate from `.venv`).
/// SUMO_HOME of the eclipse-sumo in `.venv` (its binaries and tools).
fn sumo_home() -> PathBuf {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let home = Command::new(root.join(".venv/bin/python"))
        .args(["-c", "import sumo;print(sumo.SUMO_HOME)"])
        .output()
        .expect("runs .venv/bin/python");
    assert!(
        home.status.success(),
        "eclipse-sumo is not installed in .venv: `.venv/bin/pip install eclipse-sumo` (python/requirements-test.txt): {}",
        String::from_utf8_lossy(&home.stderr)
    );
    PathBuf::from(String::from_utf8_lossy(&home.stdout).trim())
}

/// [`netgenerate_grid`]'s `n` x `n` grid (200 m blocks) loaded as a map (its file removed).
fn netgenerate_grid_map(n: usize, tag: &str) -> LaneletMap {
    let out = std::env::temp_dir().join(format!("smlworld-sumo-{tag}-{}.net.xml", std::process::id()));
    netgenerate_grid(n, 200.0, &out);
    let map = LaneletMap::load(&out).unwrap();
    std::fs::remove_file(&out).ok();
    map
}

fn netgenerate_grid(n: usize, length: f64, out: &Path) {
    let home = sumo_home();
    let generated = Command::new(home.join("bin/netgenerate"))
        .env("SUMO_HOME", &home)
        .args(["--grid", "--grid.number", &n.to_string(), "--grid.length", &length.to_string()])
        .args(["--default.lanenumber", "2", "--tls.guess", "-o"])
        .arg(out)
        .output()
        .expect("runs netgenerate");
    assert!(generated.status.success(), "{}", String::from_utf8_lossy(&generated.stderr));
}

#[test]
fn a_netgenerate_grid_loads_with_its_counts() {
    let out = std::env::temp_dir().join(format!("smlworld-sumo-grid-{}.net.xml", std::process::id()));
    netgenerate_grid(4, 150.0, &out);
    let map = check_counts_at(&out, "netgenerate 4 x 4 grid");
    // 4 x 4 nodes: the 12 with three or four arms get lights, the 4 corners none.
    assert_eq!(map.signal_programs.len(), 12);
    std::fs::remove_file(&out).ok();
}

/// Every vehicle that drives off the end of a lanelet onto a successor is placed on that
/// successor ([`LaneMap::locate`] from the lanelet it was on), on a 5x5 netgenerate grid, and one
/// in a lane that diverges from its siblings is placed on its own lane once it is a little off
/// the sibling's centre. A left turner leaving the junction was placed on the U-turn beside it
/// (its loop passes the exit), so the vehicle inserted at the exit's start was not blocked by
/// it, and a right turner was kept on the straight lane it left beside (issue 54: the grid's
/// collisions).
#[test]
fn a_vehicle_is_placed_on_the_lane_it_drives_onto_at_a_junction() {
    use smlworld::vehicles::LaneMap;
    let map = netgenerate_grid_map(5, "locate");
    let lanes = LaneMap::new(std::sync::Arc::new(map));
    let (mut onto, mut diverged) = (0, 0);
    for i in 0..lanes.successors.len() as u32 {
        let end = lanes.length(i);
        for &j in &lanes.successors[i as usize] {
            let p = lanes.centres[j as usize].sample_point(0.3);
            let found = lanes.locate(p, Some((i, end - 0.2)), 0.5).map(|f| f.0);
            // Where lanes diverge they start as one: the sibling placed first is as good there.
            let as_good = found.is_some_and(|f| f == j || lanes.siblings(j).iter().any(|&(k, _)| k == f));
            let name = |k: Option<u32>| k.map(|k| lanes.id(k));
            assert!(as_good, "0.3 m onto {:?} from the end of {:?}: {:?}", name(Some(j)), name(Some(i)), name(found));
            onto += 1;
        }
        // On its centre line where its siblings are over 1.2 m away (within the 0.8 m it took
        // before to leave the first one), driving along it from its start, where it was placed
        // on the first of them.
        for &(k, _) in lanes.siblings(i) {
            let centre = &lanes.centres[i as usize];
            let Some(s) = (1..(centre.length as usize)).map(|s| s as f64).find(|&s| {
                let p = centre.sample_point(s);
                lanes
                    .siblings(i)
                    .iter()
                    .all(|&(o, _)| lanes.centres[o as usize].points.iter().all(|q| q.distance(p) > 1.2))
            }) else {
                continue;
            };
            let p = centre.sample_point(s);
            let found = lanes.locate(p, Some((k, s - 0.5)), 0.5).map(|f| f.0);
            assert_eq!(found, Some(i), "on {:?} at {s} m, placed on {:?} before", lanes.id(i), lanes.id(k));
            diverged += 1;
        }
    }
    assert!(onto > 500 && diverged > 100, "{onto} successors, {diverged} diverging siblings checked");
}

/// A turnaround (drawn wide round the junction) conflicts with every link of its junction that
/// its centre line comes within 2.2 m of (two cars 2 m wide would touch), unless they share a
/// start or an end (one queue, or a merge): on a 3x3 netgenerate grid, the distances measured
/// here between the centre lines, against the junctions' conflicts. Before, a turnaround met
/// only the links it crossed: its loop swept into the right turn of the arm beside it, and on
/// issue 54's 20x20 grid 8 of 12 collisions were that.
#[test]
fn a_turnaround_conflicts_with_every_link_it_passes_close_to() {
    use smlworld::map::polyline::project_polyline;
    let map = netgenerate_grid_map(3, "near");
    let junctions = map.junctions();
    let lanelet = |id: smlworld::map::LaneletId| &map.lanelets[map.lanelet_index(id).unwrap()];
    let leads_into = |a: smlworld::map::LaneletId, b: smlworld::map::LaneletId| {
        map.lanelets.iter().any(|l| l.successors.contains(&a) && l.successors.contains(&b))
    };
    let mut near = 0;
    for j in &junctions.list {
        let links = j.lanelets();
        for &t in &links {
            if lanelet(t).tags.get("sumo:shape").map(String::as_str) != Some("turnaround") {
                continue;
            }
            for &o in &links {
                let (lt, lo) = (lanelet(t), lanelet(o));
                let shares_end = lt.successors.iter().any(|s| lo.successors.contains(s));
                if o == t || leads_into(t, o) || shares_end {
                    continue;
                }
                // Closest approach of the two centre lines, point by point both ways.
                let gap = lt
                    .centre
                    .iter()
                    .map(|p| project_polyline(&lo.centre, *p).1)
                    .chain(lo.centre.iter().map(|p| project_polyline(&lt.centre, *p).1))
                    .fold(f64::INFINITY, f64::min);
                if gap < 2.0 {
                    near += 1;
                    let met = j.conflicts.iter().any(|c| (c.a, c.b) == (t, o) || (c.a, c.b) == (o, t));
                    assert!(met, "turnaround {t:?} passes {gap:.2} m from {o:?} in junction {} with no conflict", j.id);
                }
            }
        }
    }
    assert!(near > 10, "{near} links a turnaround passes close to");
}

/// SUMO's IDM follower behind an imposed leader (cruise at 15 m/s, brake at 2 m/s² to 5 m/s,
/// accelerate back), recorded by `scripts/record_sumo_following.py` into
/// `tests/data/sumo_following.csv` (SUMO 1.28, step 0.1 s, its default Euler update: speed
/// v + a·dt, then position x + v(t+dt)·dt). Ours: the same IDM law ([`Idm::acceleration`]) with
/// the same parameters, integrated as our kinematic model is driven (speed command v + a·dt at
/// the control step, position advanced by the commanded speed: the same Euler scheme), fed the
/// recorded leader speeds. Returns the RMS of the follower's gap difference over the 120 s [m].
fn following_gap_rms(idm: smlworld::vehicles::Idm) -> f64 {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let text =
        std::fs::read_to_string(root.join("tests/data/sumo_following.csv")).expect("tests/data/sumo_following.csv");
    let rows: Vec<[f64; 4]> = text
        .lines()
        .skip(1)
        .map(|l| {
            let c: Vec<f64> = l.split(',').map(|x| x.parse().expect("a number")).collect();
            [c[0], c[1], c[2], c[3]]
        })
        .collect();
    assert!(rows.len() > 1000, "{} rows", rows.len());
    let dt = rows[1][0] - rows[0][0];
    let (mut gap, mut v) = (rows[0][3], rows[0][2]);
    let mut sum = 0.0;
    for w in rows.windows(2) {
        let (now, next) = (w[0], w[1]);
        sum += (gap - now[3]).powi(2);
        let a = idm.acceleration(v, Some((gap, now[1])));
        v = (v + a * dt).max(0.0);
        // The leader moves by its next speed (SUMO's Euler update for it too).
        gap += (next[1] - v) * dt;
    }
    sum += (gap - rows[rows.len() - 1][3]).powi(2);
    (sum / rows.len() as f64).sqrt()
}

#[test]
fn idm_following_matches_sumos_recorded_follower() {
    use smlworld::vehicles::Idm;
    // The recording's vType: accel 1.5, decel 3, tau 1.2, minGap 2, delta 4, maxSpeed 20.
    let idm = Idm { speed: 20.0, time_gap: 1.2, min_gap: 2.0, accel: 1.5, decel: 3.0, delta: 4.0 };
    let rms = following_gap_rms(idm);
    assert!(rms <= 0.5, "gap differs from SUMO's by {rms:.3} m RMS");
    // The comparison can fail: a time gap of 1.5 s instead of SUMO's 1.2 s follows farther.
    let wrong = following_gap_rms(Idm { time_gap: 1.5, ..idm });
    assert!(wrong > 0.5, "a wrong time gap still matches ({wrong:.3} m RMS)");
}

/// A 4 x 4 netgenerate grid of 150 m blocks in a fresh temporary folder named after `tag`,
/// with `flows` (`<flow>` lines of the car type below) as its demand: the folder, the net, the
/// route file, and a scenario running them for `duration` s.
fn grid_with_flows(tag: &str, flows: &str, duration: f64) -> (PathBuf, PathBuf, PathBuf, PathBuf) {
    let dir = std::env::temp_dir().join(format!("smlworld-sumo-grid-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let net = dir.join("grid.net.xml");
    netgenerate_grid(4, 150.0, &net);
    let demand = format!(
        "<routes>\n  <vType id=\"car\" carFollowModel=\"IDM\" accel=\"2.6\" decel=\"4.5\" tau=\"1\" minGap=\"2.5\" length=\"5\" maxSpeed=\"15\"/>\n{flows}</routes>\n"
    );
    let routes = dir.join(format!("{tag}.rou.xml"));
    std::fs::write(&routes, demand).unwrap();
    let scenario = dir.join(format!("{tag}.toml"));
    std::fs::write(&scenario, format!("map = {net:?}\ndemand = [{routes:?}]\nduration = {duration}\n")).unwrap();
    (dir, net, routes, scenario)
}

/// On netgenerate's 2-lane grids a right turn leaves from lane 0 only and a left turn from lane 1
/// only, so a right turn followed by a left one (and the reverse) needs a lane change on the
/// edge between: the route is driven with the lane-change plugin's mandatory changes.
#[test]
fn a_grid_route_that_needs_lane_changes_is_driven_to_its_end() {
    // East on A1B1, right at B1 (arrives on lane 0 of B1B0), left at B0 (leaves from lane 1);
    // east on A1B1, left at B1 (arrives on lane 1 of B1B2), right at B2 (leaves from lane 0).
    let flows = r#"  <flow id="right_left" type="car" begin="0" end="300" vehsPerHour="360" departLane="best"><route edges="A1B1 B1B0 B0C0"/></flow>
  <flow id="left_right" type="car" begin="0" end="300" vehsPerHour="360" departLane="best"><route edges="A1B1 B1B2 B2C2"/></flow>
"#;
    let (dir, net, routes, scenario) = grid_with_flows("lc", flows, 400.0);
    let map = LaneletMap::load(&net).unwrap();
    let d = Demand::load(std::slice::from_ref(&routes), &map, 0.0, 1000.0).unwrap();
    for g in &d.groups {
        let lr = g.lane_route.as_ref().unwrap_or_else(|| panic!("flow {} needs no lane change?", g.id));
        // The start route ends on the middle edge, in the lane the next turn is not made from.
        let last = *g.routes[0].last().unwrap();
        assert!(!lr.reach.contains(&last), "flow {}: its start route reaches the end without a change", g.id);
        assert_eq!(map.lanelet(last).unwrap().tags["sumo:edge"], if g.id == "right_left" { "B1B0" } else { "B1B2" });
    }
    let summary = run_summary(&scenario, &dir.join("out"));
    let m = &summary["metrics"];
    assert_eq!(m["collision_count"], 0, "{}", m["collisions"]);
    let (inserted, removed) = inserted_and_arrived(m);
    // 2 x 360 veh/h for 300 s: 60 due; each route is 450 m, so all arrive well within 400 s.
    assert!(inserted >= 55, "inserted {inserted}");
    assert_eq!(removed, inserted, "inserted {inserted}, arrived {removed}");
    // Each vehicle changed lanes on the middle edge (a mandatory change), none missed its turn.
    let lc = &m["lane_change_summary"];
    assert!(lc["mandatory"].as_u64().unwrap() >= inserted, "{lc}");
    assert_eq!(lc["missed_exits"], 0, "{lc}");
    let trips = std::fs::read_to_string(dir.join("out/trips.csv")).unwrap();
    let arrived = trips.lines().skip(1).filter(|r| !r.split(',').nth(2).unwrap_or("").is_empty()).count();
    assert_eq!(arrived as u64, inserted);
    std::fs::remove_dir_all(&dir).ok();
}

/// Two turning flows that enter one edge side by side, each in the lane the other must reach
/// (left turners arrive on lane 1 and turn right at the next junction, right turners the
/// reverse), released together by the same green: pairs reached their lane ends abreast and
/// waited there for ever (1 of 64 arrived in 900 s; the 5x5 SUMO grid gridlocked from such
/// pairs). The one behind now holds back a standstill gap behind its swap partner, which
/// changes first.
#[test]
fn turners_that_must_swap_lanes_on_one_edge_do_not_wait_for_ever() {
    let flows = r#"  <flow id="left_right" type="car" begin="0" end="600" vehsPerHour="240" departLane="best"><route edges="A1B1 B1B2 B2C2"/></flow>
  <flow id="right_left" type="car" begin="0" end="600" vehsPerHour="240" departLane="best"><route edges="C1B1 B1B2 B2A2"/></flow>
"#;
    let (dir, _, _, scenario) = grid_with_flows("swap", flows, 900.0);
    let summary = run_summary(&scenario, &dir.join("out"));
    let m = &summary["metrics"];
    assert_eq!(m["collision_count"], 0, "{}", m["collisions"]);
    let (inserted, removed) = inserted_and_arrived(m);
    // 2 x 240 veh/h for 600 s: 80 due; each route is 450 m, 300 s left after the last.
    assert!(inserted >= 75, "inserted {inserted}");
    assert_eq!(removed, inserted, "inserted {inserted}, arrived {removed}");
    let lc = &m["lane_change_summary"];
    assert!(lc["mandatory"].as_u64().unwrap() >= inserted, "{lc}");
    // The issue's bound on a single wait (issue 53 §7: no vehicle waits longer than 120 s).
    assert!(lc["max_wait_s"].as_f64().unwrap() < 120.0, "{lc}");
    std::fs::remove_dir_all(&dir).ok();
}

/// An `n` x `n` netgenerate grid of 200 m blocks ([`netgenerate_grid`]) in a fresh temporary
/// folder named after `tag`, and SUMO's randomTrips.py on it with `args`, its routes (`-r`)
/// beside it: the folder, the net and the route file.
fn grid_with_random_trips(tag: &str, n: usize, args: &[&str]) -> (PathBuf, PathBuf, PathBuf) {
    let dir = std::env::temp_dir().join(format!("smlworld-sumo-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let net = dir.join("grid.net.xml");
    netgenerate_grid(n, 200.0, &net);
    let routes = dir.join("grid.rou.xml");
    let home = sumo_home();
    let made = Command::new(Path::new(env!("CARGO_MANIFEST_DIR")).join(".venv/bin/python"))
        .env("SUMO_HOME", &home)
        .arg(home.join("tools/randomTrips.py"))
        .arg("-n")
        .arg(&net)
        .args(args)
        .arg("-r")
        .arg(&routes)
        .arg("-o")
        .arg(dir.join("grid.trips.xml"))
        .output()
        .expect("runs randomTrips.py");
    assert!(made.status.success(), "{}", String::from_utf8_lossy(&made.stderr));
    (dir, net, routes)
}

/// A 5x5 netgenerate grid (200 m blocks, 2 lanes, `--tls.guess`) with randomTrips demand (`-p 0.5
/// -e 900 --seed 42`, SUMO's own generator, 1,800 vehicles), run for 1500 s; the routes with a
/// U-turn (edge XY followed by YX) left out unless `u_turns`. Returns the vehicles kept, those
/// left out, and the run's metrics.
fn random_trips_grid(tag: &str, u_turns: bool) -> (usize, usize, serde_json::Value) {
    let (dir, net, routes) =
        grid_with_random_trips(&format!("random-grid-{tag}"), 5, &["-p", "0.5", "-e", "900", "--seed", "42"]);
    let text = std::fs::read_to_string(&routes).unwrap();
    let mut kept = String::new();
    let (mut n, mut dropped) = (0, 0);
    for (k, piece) in text.split("<vehicle ").enumerate() {
        if k == 0 {
            kept.push_str(piece);
            continue;
        }
        let edges: Vec<&str> =
            piece.split("edges=\"").nth(1).and_then(|e| e.split('"').next()).unwrap_or("").split(' ').collect();
        let turns_back = edges
            .windows(2)
            .any(|w| w[0].len() == 4 && w[1].len() == 4 && w[0][..2] == w[1][2..] && w[0][2..] == w[1][..2]);
        if turns_back && !u_turns {
            dropped += 1;
            // Keep what follows the vehicle (the closing </routes>).
            if let Some(end) = piece.find("</vehicle>") {
                kept.push_str(&piece[end + "</vehicle>".len()..]);
            }
        } else {
            n += 1;
            kept.push_str("<vehicle ");
            kept.push_str(piece);
        }
    }
    std::fs::write(&routes, kept).unwrap();
    let scenario = dir.join("grid5.toml");
    std::fs::write(&scenario, format!("map = {net:?}\ndemand = [{routes:?}]\nduration = 1500\n")).unwrap();
    let summary = run_summary(&scenario, &dir.join("out"));
    std::fs::remove_dir_all(&dir).ok();
    // Nobody passes a red stop line. A lane change given up hands its vehicle back the route it
    // had driven before; its junctions were walked again from the first, each counted as entered
    // anew and, where the light now showed red, as a red light crossed.
    assert_eq!(summary["metrics"]["red_light_crossings"], 0, "{tag}: vehicles passed red stop lines");
    (n, dropped, summary["metrics"].clone())
}

/// The longest wait at a junction and to change lanes \[s\] of a run's metrics.
fn longest_waits(m: &serde_json::Value) -> (f64, f64) {
    let junction =
        m["junctions"].as_array().unwrap().iter().map(|j| j["max_wait_s"].as_f64().unwrap()).fold(0.0, f64::max);
    (junction, m["lane_change_summary"]["max_wait_s"].as_f64().unwrap())
}

/// [`random_trips_grid`] without its U-turn routes: every vehicle arrives and none waits longer
/// than the 120 s issue 53 §7 allows. Before lane swaps were settled (a vehicle holding back
/// behind its swap partner) and SUMO's links were turned at netconvert's lateral acceleration,
/// 1,182 of 1,454 arrived and one waited 310 s at a junction.
#[test]
fn a_random_trips_grid_without_u_turns_flows_to_the_end() {
    let (n, dropped, m) = random_trips_grid("no-u", false);
    assert!(n > 1000 && dropped > 100, "{n} vehicles kept, {dropped} with a U-turn");
    let (inserted, removed) = inserted_and_arrived(&m);
    assert_eq!(inserted, n as u64, "inserted {inserted} of {n}");
    assert_eq!(removed, inserted, "inserted {inserted}, arrived {removed}");
    let (junction, lane_change) = longest_waits(&m);
    assert!(junction <= 120.0, "a vehicle waited {junction:.1} s at a junction");
    assert!(lane_change <= 120.0, "a vehicle waited {lane_change:.1} s to change lanes");
}

/// [`random_trips_grid`] with all its routes, U-turns (337 of 1,800) included, as SUMO runs it
/// (SUMO brings all 1,800 home, mean 145.8 s): every vehicle arrives, nobody stands for ever. At
/// the twelfth session's start the grid locked (1,244 of 1,764 inserted arrived); with SUMO's
/// turn speeds and SUMO demand's leader from the lane index all 1,800 arrive, the longest wait
/// at a junction 175.8 s (a U-turner waiting for a gap in the oncoming flow).
#[test]
fn a_random_trips_grid_with_its_u_turns_flows_to_the_end() {
    let (n, dropped, m) = random_trips_grid("u", true);
    assert!(n == 1800 && dropped == 0, "{n} vehicles, {dropped} left out");
    let (inserted, removed) = inserted_and_arrived(&m);
    assert_eq!(inserted, n as u64, "inserted {inserted} of {n}");
    assert_eq!(removed, inserted, "inserted {inserted}, arrived {removed}");
    let (junction, lane_change) = longest_waits(&m);
    assert!(
        junction <= 300.0 && lane_change <= 300.0,
        "waited {junction:.1} s at a junction, {lane_change:.1} s to change lanes"
    );
}

/// Issue 54's grid: netgenerate's 20x20 (200 m blocks, 2 lanes, `--tls.guess`, 400 junctions)
/// with randomTrips demand (`-p 0.07 -e 900 --seed 42 -r`: 12,858 vehicles, 14 a second), run
/// for 2400 s as `compare_sumo.py` runs it (a `.sumocfg`, step 0.1 s, every vType on SUMO's
/// defaults with the IDM). SUMO 1.28 brings all 12,858 home, 6,810 in the network at the peak,
/// mean travel time 455.7 s (`python3 scripts/compare_sumo.py grid20.net.xml grid20.rou.xml --end
/// 2400`). The issue asks for every vehicle home and our mean within +-15 % of SUMO's. Before:
/// two vehicles at their lanes' ends wanting each other's lanes, the one behind stopped 0.7 m
/// short of a slot, waited for ever with 97 behind them (12,759 arrived); and on two threads the
/// run panicked once fewer than 2,000 vehicles were left (the collision near list read the
/// chunks of an earlier tick).
#[test]
fn a_20x20_random_trips_grid_brings_every_vehicle_home_within_15_percent_of_sumo() {
    let (dir, net, routes) = grid_with_random_trips("grid20", 20, &["-p", "0.07", "-e", "900", "--seed", "42"]);
    // As compare_sumo.py writes them: a configuration, every vType (here SUMO's default one) on the IDM.
    let text = std::fs::read_to_string(&routes).unwrap();
    let n = text.matches("<vehicle ").count();
    assert_eq!(n, 12_858, "randomTrips made another demand");
    let idm = text.replacen("<vehicle ", "<vType id=\"DEFAULT_VEHTYPE\" carFollowModel=\"IDM\"/>\n    <vehicle ", 1);
    std::fs::write(&routes, idm).unwrap();
    let cfg = dir.join("grid20.sumocfg");
    std::fs::write(
        &cfg,
        format!(
            "<configuration><input><net-file value={net:?}/><route-files value={routes:?}/></input>\
             <time><begin value=\"0\"/><end value=\"2400\"/><step-length value=\"0.1\"/></time></configuration>\n"
        ),
    )
    .unwrap();
    // Two threads (the chunked passes of a world that grows past 2,000 vehicles and shrinks
    // again); one trajectory row a vehicle every 100 s.
    let out = dir.join("out");
    let summary = run_summary_with(&cfg, &out, &["--threads", "2", "--log-rate", "0.01"]);
    let m = &summary["metrics"];
    let (inserted, removed) = inserted_and_arrived(m);
    assert_eq!(inserted, n as u64, "inserted {inserted} of {n}");
    assert_eq!(removed, inserted, "inserted {inserted}, arrived {removed}");
    let travel = m["trips"]["mean_travel_time_s"].as_f64().unwrap();
    assert!((travel / 455.7 - 1.0).abs() <= 0.15, "mean travel time {travel:.1} s against SUMO's 455.7 s");
    // Before a route switch kept the passages behind the vehicle as passed, 93 given-up
    // lane changes here counted as red lights crossed.
    assert_eq!(m["red_light_crossings"], 0);
    std::fs::remove_dir_all(&dir).ok();
}

/// netgenerate draws a turnaround between a road's inner lanes as a 1.6 m half circle, which
/// a steered car cannot follow (they swung up to 7 m off it into the oncoming lanes). Drawn
/// round the junction instead ([`smlworld::map::sumo`]'s turnaround), U-turners stay on it and
/// cross the oncoming flow that shares their exit without a collision.
#[test]
fn u_turns_on_a_netgenerate_grid_are_driven_on_their_lane_without_collisions() {
    // East on A1B1 and back at B1; the oncoming flow west on C1B1 into the same edge B1A1.
    let flows = r#"  <flow id="uturn" type="car" begin="0" end="300" vehsPerHour="240" departLane="best"><route edges="A1B1 B1A1"/></flow>
  <flow id="oncoming" type="car" begin="0" end="300" vehsPerHour="360" departLane="best"><route edges="C1B1 B1A1"/></flow>
"#;
    let (dir, _, _, scenario) = grid_with_flows("uturn", flows, 420.0);
    let summary = run_summary(&scenario, &dir.join("out"));
    let m = &summary["metrics"];
    assert_eq!(m["collision_count"], 0, "{}", m["collisions"]);
    let (inserted, removed) = inserted_and_arrived(m);
    assert!(inserted >= 45, "inserted {inserted}");
    assert_eq!(removed, inserted, "inserted {inserted}, arrived {removed}");
    let off = summary["max_distance_to_centre_line"]
        .as_object()
        .expect("per-vehicle distances")
        .values()
        .filter_map(|v| v.as_f64())
        .fold(0.0, f64::max);
    assert!(off < 2.0, "a vehicle was {off:.2} m off its centre line");
    std::fs::remove_dir_all(&dir).ok();
}

/// Vehicles inserted and arrived (removed at their route's end) of a run's metrics.
fn inserted_and_arrived(m: &serde_json::Value) -> (u64, u64) {
    (m["traffic"]["inserted"].as_u64().unwrap(), m["traffic"]["removed"].as_u64().unwrap())
}

/// `smlworld run SCENARIO --out OUT`, which must succeed, and its summary.json.
fn run_summary(scenario: &Path, out: &Path) -> serde_json::Value {
    run_summary_with(scenario, out, &[])
}

/// [`run_summary`] with more options (`--duration`, `--threads` ...) before `--out`.
fn run_summary_with(scenario: &Path, out: &Path, options: &[&str]) -> serde_json::Value {
    let run = Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .arg("run")
        .arg(scenario)
        .args(options)
        .arg("--out")
        .arg(out)
        .output()
        .expect("runs smlworld");
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap()
}

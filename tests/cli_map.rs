//! `smlworld map info|route|loop` as a user runs them: JSON fields, exit codes, error messages.

mod common;

use std::process::Command;

fn smlworld(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_smlworld")).args(args).output().expect("runs smlworld");
    (out.status.success(), String::from_utf8_lossy(&out.stdout).into(), String::from_utf8_lossy(&out.stderr).into())
}

fn json(args: &[&str]) -> serde_json::Value {
    let (ok, stdout, stderr) = smlworld(args);
    assert!(ok, "smlworld {args:?} failed: {stderr}");
    serde_json::from_str(&stdout).unwrap_or_else(|e| panic!("not JSON ({e}): {stdout}"))
}

#[test]
fn info_json_has_the_documented_fields() {
    let map = common::shared("sml2015/HighwaySML.xml");
    let v = json(&["map", "info", map.to_str().unwrap(), "--json"]);
    assert_eq!(v["nodes"], 273);
    assert_eq!(v["ways"], 16);
    assert_eq!(v["lanelets"], 12);
    assert_eq!(v["successor_pairs"], 12);
    assert_eq!(v["origin"]["node"], -552);
    assert!((v["origin"]["lat"].as_f64().unwrap() - 59.15374861144).abs() < 1e-12);
    assert!((v["origin"]["lon"].as_f64().unwrap() - 17.6606166112).abs() < 1e-12);
    assert_eq!(v["utm_zone"], "33V");
    assert_eq!(v["tags"]["right_lane_node"], serde_json::json!([-142]));
    let list = v["lanelet_list"].as_array().unwrap();
    assert_eq!(list.len(), 12);
    let first = &list[0];
    for key in ["id", "length_m", "successors", "left", "right", "tags"] {
        assert!(first.get(key).is_some(), "lanelet_list entries have `{key}`: {first}");
    }
    assert_eq!(first["tags"]["type"], "lanelet");
    assert_eq!(v["warnings"], serde_json::json!([]));
}

#[test]
fn loop_and_route_json() {
    let map = common::shared("sml2015/HighwaySML.xml");
    let m = map.to_str().unwrap();
    let v = json(&["map", "loop", m, "--tag", "center_lane_node", "--json"]);
    let len = v["length_m"].as_f64().unwrap();
    assert!((len - 349.2).abs() < 0.5, "{len}");
    assert_eq!(v["lanelets"].as_array().unwrap().len(), 4);
    let points = v["points"].as_array().unwrap();
    assert!(
        (points.len() as f64 - len * 5.0).abs() <= 2.0,
        "5 points per metre by default: {} points for {len} m",
        points.len()
    );
    assert_eq!(points[0].as_array().unwrap().len(), 2);

    // --points-per-meter 2 and a negative node id as a plain argument.
    let v = json(&["map", "loop", m, "--node", "-142", "--points-per-meter", "2", "--json"]);
    let len = v["length_m"].as_f64().unwrap();
    assert!((len - 374.4).abs() < 0.5, "{len}");
    assert!((v["points"].as_array().unwrap().len() as f64 - len * 2.0).abs() <= 2.0);

    let v = json(&["map", "route", m, "--from-tag", "right_lane_node", "--to", "-138", "--json"]);
    let route_len = v["length_m"].as_f64().unwrap();
    assert!(route_len > 10.0 && route_len < 374.4, "{route_len}");
}

/// The most decimals of any number in `text` (digits after a `.` that follows a digit).
fn most_decimals(text: &str) -> usize {
    let b = text.as_bytes();
    let mut most = 0;
    for i in 1..b.len() {
        if b[i] == b'.' && b[i - 1].is_ascii_digit() {
            most = most.max(b[i + 1..].iter().take_while(|c| c.is_ascii_digit()).count());
        }
    }
    most
}

/// Issue 61: `map route --json` printed ~2,500 points of 17 digits; lengths and points are in
/// millimetres, as the trajectory CSV.
#[test]
fn route_json_numbers_are_millimetres() {
    let map = common::shared("sml2015/HighwaySML.xml");
    let m = map.to_str().unwrap();
    for args in [
        vec!["map", "route", m, "--from-tag", "right_lane_node", "--to", "-138", "--json"],
        vec!["map", "loop", m, "--tag", "center_lane_node", "--json"],
    ] {
        let (ok, stdout, stderr) = smlworld(&args);
        assert!(ok, "{stderr}");
        assert!(most_decimals(&stdout) <= 3, "{args:?}: more than 3 decimals in {}", &stdout[..stdout.len().min(400)]);
    }
}

/// Issue 61: `map render` printed `12.428076922573725 px/m, centre 0.0000016964040696620941, ...`.
#[test]
fn map_render_prints_rounded_figures() {
    let map = common::shared("sml2015/HighwaySML.xml");
    let out = std::env::temp_dir().join(format!("smlworld-render-figures-{}.png", std::process::id()));
    let (ok, stdout, stderr) = smlworld(&[
        "map",
        "render",
        map.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--width",
        "320",
        "--height",
        "240",
    ]);
    let _ = std::fs::remove_file(&out);
    let _ = std::fs::remove_file(out.with_extension("meta"));
    assert!(ok, "{stderr}");
    assert!(stdout.contains("px/m, centre "), "{stdout}");
    assert!(most_decimals(&stdout) <= 3, "more than 3 decimals: {stdout}");
}

#[test]
fn errors_are_messages_not_panics() {
    let map = common::shared("sml2015/HighwaySML.xml");
    let m = map.to_str().unwrap();
    for (args, needle) in [
        (vec!["map", "route", m, "--from", "-142", "--to", "-999"], "unknown node id -999"),
        (vec!["map", "loop", m, "--tag", "nowhere"], "unknown tag `nowhere`"),
        (
            vec!["map", "route", m, "--from-tag", "right_lane_node", "--to-tag", "left_lane_node"],
            "no route from tag `right_lane_node` to tag `left_lane_node`",
        ),
        (vec!["map", "info", "/nonexistent/map.osm"], "/nonexistent/map.osm"),
        (vec!["map", "loop", m, "--tag", "right_lane_node", "--points-per-meter", "-1"], "--points-per-meter"),
    ] {
        let (ok, _, stderr) = smlworld(&args);
        assert!(!ok, "{args:?} must fail");
        assert!(stderr.contains(needle), "{args:?}: expected {needle:?} in {stderr}");
        assert!(!stderr.contains("panicked"), "{args:?} panicked: {stderr}");
    }
}

/// Issue 10: the README's `map route` example works on the map it names, and `--json` reports
/// the nodes actually used.
#[test]
fn readme_route_example_works_and_reports_its_nodes() {
    let readme = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/README.md")).unwrap();
    let line = readme.lines().find(|l| l.starts_with("smlworld map route ")).expect("README has a route example");
    let cmd = line.split('#').next().unwrap();
    let args: Vec<String> = cmd
        .split_whitespace()
        .skip(1)
        .map(|a| a.replace("../shared/data/", &format!("{}/", common::shared_data().display())))
        .collect();
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    assert!(args.contains(&"--json"), "the example prints JSON: {line}");
    let v = json(&args);
    assert!(v["length_m"].as_f64().unwrap() > 1.0, "{line}: {}", v["length_m"]);
    assert_eq!(v["from_node"], -142);
    assert!(v.get("note").is_none(), "HighwaySML follows the 2015 rule: {v}");
}

/// Issue 22 item 11: a route that exists only with lane changes says so and names the flag.
#[test]
fn route_between_lanes_suggests_lane_changes() {
    let map = concat!(env!("CARGO_MANIFEST_DIR"), "/maps/highway_ring.osm");
    let args = ["map", "route", map, "--from-tag", "right_lane_node", "--to-tag", "left_lane_node"];
    let (ok, _, stderr) = smlworld(&args);
    assert!(!ok);
    assert!(stderr.contains("no route in lane; try --lane-changes"), "{stderr}");
    assert!(stderr.contains("right_lane_node") && stderr.contains("left_lane_node"), "{stderr}");
    let mut with = args.to_vec();
    with.push("--lane-changes");
    let (ok, _, stderr) = smlworld(&with);
    assert!(ok, "the suggested flag finds the route: {stderr}");
}

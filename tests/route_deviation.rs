//! Issue 22 item 8: the deviation from the route is measured for every routed vehicle (not only
//! path followers), and a start off its route is warned about when the scenario loads.

use std::process::Command;

/// Run `scenario` (text) for 2 s; returns (stderr, summary.json).
fn run(name: &str, scenario: &str) -> (String, serde_json::Value) {
    let dir = std::env::temp_dir().join(format!("smlworld-deviation-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("s.toml");
    let map = concat!(env!("CARGO_MANIFEST_DIR"), "/maps/highway_ring.osm");
    std::fs::write(&file, format!("map = \"{map}\"\n{scenario}")).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["run", file.to_str().unwrap(), "--duration", "2", "--out", dir.to_str().unwrap()])
        .env_remove("RUST_LOG")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.success(), "{stderr}");
    let summary = serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap()).unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    (stderr, summary)
}

#[test]
fn a_vehicle_without_a_path_follower_reports_its_deviation() {
    // -1 has a route but no controller, and starts at (72, 0) m: about 12 m outside the right
    // lane of the ring (radius about 60 m). -2 follows the same lane from a node on it.
    let (stderr, summary) = run(
        "nocontroller",
        r#"
[[vehicles]]
id = -1
route = { loop = "right_lane_node" }
start = { x = 72.0, y = 0.0 }
speed = 3.0
[[vehicles]]
id = -2
route = { loop = "right_lane_node" }
start = { at = "right_lane_node", offset = 60.0 }
controller = { type = "path_following", speed = 8.0 }
"#,
    );
    let d = &summary["max_distance_to_centre_line"];
    let off = d["-1"].as_f64().unwrap_or_else(|| panic!("no deviation for -1: {d}"));
    assert!(off > 8.0 && off < 16.0, "{off} m");
    assert!(d["-2"].as_f64().unwrap() < 0.5, "{d}");
    let warning = stderr.lines().find(|l| l.contains("WARN") && l.contains("vehicle -1")).unwrap_or_else(|| {
        panic!("no load-time warning for the start off the route:\n{stderr}");
    });
    assert!(warning.contains("off its route") && warning.contains("start"), "{warning}");
    assert!(!stderr.contains("vehicle -2"), "-2 starts on its route: {stderr}");
    assert!(stderr.contains("max distance to centre line 1"), "the closing line shows the worst: {stderr}");
}

/// Issue 10's repeated and leaking messages: each cause once, no Rust debug values.
#[test]
fn route_errors_say_each_cause_once() {
    let dir = std::env::temp_dir().join(format!("smlworld-deviation-err-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("s.toml");
    let map = concat!(env!("CARGO_MANIFEST_DIR"), "/maps/highway_ring.osm");
    std::fs::write(&file, format!("map = \"{map}\"\n[[vehicles]]\nid = -1\nroute = {{ loop = -1 }}\n")).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["run", file.to_str().unwrap(), "--duration", "1", "--out", dir.to_str().unwrap()])
        .output()
        .unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert_eq!(stderr.matches("node -1").count(), 1, "{stderr}");
    assert!(!stderr.contains("Some("), "{stderr}");
}

//! Scenario values that used to pass validation and then panic, hang or write NaN inside the
//! simulation (issue 15): each must now be refused at load with an error naming the key, exit
//! code 1, no backtrace, and no output written.

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// A one-vehicle scenario on the shipped ring with `vehicle` as the `[[vehicles]]` body and
/// `extra` as top-level tables, written under the test's own temp folder.
fn scenario(name: &str, vehicle: &str, extra: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("reliability").join(name);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let map = Path::new(env!("CARGO_MANIFEST_DIR")).join("maps/highway_ring.osm");
    let text = format!(
        "seed = 1\nduration = 3.0\nmap = {map:?}\n{extra}\n[[vehicles]]\nid = -1\nroute = {{ loop = \"right_lane_node\" }}\n{vehicle}\n",
        map = map.display().to_string()
    );
    let path = dir.join("s.toml");
    std::fs::write(&path, text).unwrap();
    path
}

/// Run `smlworld run` on `path` with a 30 s limit; (exit code, stderr, the out folder).
fn run(path: &Path) -> (Option<i32>, String, PathBuf) {
    let out = path.parent().unwrap().join("out");
    let mut child = Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["run", path.to_str().unwrap(), "--out", out.to_str().unwrap()])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if start.elapsed() > Duration::from_secs(30) {
            child.kill().unwrap();
            child.wait().unwrap();
            panic!("{}: `smlworld run` still running after 30 s (hang)", path.display());
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let mut err = String::new();
    child.stderr.take().unwrap().read_to_string(&mut err).unwrap();
    (status.code(), err, out)
}

/// The run is refused with exit code 1, an error naming `key`, no panic, no output.
fn assert_refused(name: &str, vehicle: &str, extra: &str, key: &str) {
    let path = scenario(name, vehicle, extra);
    let (code, err, out) = run(&path);
    assert!(!err.contains("panicked"), "{name}: panicked:\n{err}");
    assert_eq!(code, Some(1), "{name}: exit code {code:?}, stderr:\n{err}");
    assert!(err.contains(key), "{name}: the error does not name `{key}`:\n{err}");
    assert!(!out.join("trajectories.csv").exists(), "{name}: a refused run wrote trajectories.csv");
}

#[test]
fn negative_cruise_deceleration_is_refused() {
    assert_refused(
        "cruise_neg_decel",
        r#"controller = { type = "cruise_control", speed = 10.0, cruise = { max_deceleration = -5.0 } }"#,
        "",
        "cruise.max_deceleration",
    );
}

#[test]
fn nan_max_acceleration_is_refused_on_every_smart_controller() {
    for (kind, table) in [("cruise_control", "cruise"), ("acc", "acc"), ("platoon", "platoon")] {
        let role = if kind == "platoon" { r#"role = "leader", "# } else { "" };
        assert_refused(
            &format!("nan_accel_{kind}"),
            &format!(
                r#"controller = {{ type = "{kind}", {role}speed = 10.0, {table} = {{ max_acceleration = nan }} }}"#
            ),
            "",
            &format!("{table}.max_acceleration"),
        );
    }
}

#[test]
fn huge_lab_stale_timeout_is_refused() {
    assert_refused(
        "lab_stale",
        "model = { type = \"none\" }",
        "[lab]\nmocap = { mock = true, stale_after = 1e300 }\n",
        "lab.mocap.stale_after",
    );
}

#[test]
fn huge_vehicle_length_is_refused_not_a_hang() {
    assert_refused("huge_length", "length = 1e300", "", "length");
}

#[test]
fn nan_start_offset_is_refused() {
    assert_refused("nan_offset", r#"start = { at = "right_lane_node", offset = nan }"#, "", "start.offset");
}

#[test]
fn far_start_position_is_refused() {
    assert_refused("far_start", "start = { x = 1e308, y = 0.0 }", "", "start.x");
}

#[test]
fn huge_drag_is_refused() {
    assert_refused("huge_drag", r#"model = { type = "acceleration", drag = 1e308 }"#, "", "model.drag");
}

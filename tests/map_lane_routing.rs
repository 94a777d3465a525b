//! Routes with lane changes and the lane-drop map (GCDC merge): the route the left lane needs,
//! where it changes, how smoothly its path blends, and the CLI's `--lane-changes` JSON.

use std::path::{Path, PathBuf};
use std::process::Command;

use smlworld::map::generate::{
    LANE_DROP_END, LANE_DROP_LEFT_END, LANE_DROP_LEFT_START, LANE_DROP_RIGHT_START, LaneDropParams, lane_drop,
};
use smlworld::map::{LaneChangeOptions, LaneletMap, MapError, Place, RouteOptions};

fn lane_drop_map(params: &LaneDropParams) -> LaneletMap {
    LaneletMap::parse_str(&lane_drop(params).unwrap(), Path::new("lane_drop.osm")).unwrap()
}

fn tag(t: &str) -> Place {
    Place::Tag(t.to_string())
}

#[test]
fn lane_drop_map_has_the_left_lane_beside_the_right_until_the_drop() {
    let p = LaneDropParams::default();
    let map = lane_drop_map(&p);
    assert!(map.warnings.is_empty(), "{:?}", map.warnings);
    // 300 m in 6 pairs of 50 m lanelets, then 200 m of one lane in 4.
    assert_eq!(map.lanelets.len(), 6 * 2 + 4);
    let table = map.neighbours();
    let (mut beside, mut alone) = (0, 0);
    for (i, l) in map.lanelets.iter().enumerate() {
        let y = l.centre[l.centre.len() / 2].y;
        let x_end = l.centre[l.centre.len() - 1].x;
        let n = table[i];
        if (y - 1.5 * p.lane_width).abs() < 1e-3 {
            // Left lane: only a right neighbour, change allowed; ends at the drop.
            assert!(x_end <= p.drop_at + 1e-3);
            assert!(n.right.is_some() && n.change_right && n.left.is_none(), "{}: {n:?}", l.id);
            beside += 1;
        } else {
            assert!((y - 0.5 * p.lane_width).abs() < 1e-3, "{}: centre at y = {y}", l.id);
            assert!(n.right.is_none(), "{}: nothing right of the right lane", l.id);
            if x_end <= p.drop_at + 1e-3 {
                assert!(n.left.is_some() && n.change_left, "{}: {n:?}", l.id);
            } else {
                assert!(n.left.is_none() && !n.change_left, "{}: alone after the drop: {n:?}", l.id);
                alone += 1;
            }
        }
    }
    assert_eq!((beside, alone), (6, 4));
}

#[test]
fn the_left_lane_needs_a_lane_change_to_reach_the_end() {
    let p = LaneDropParams::default();
    let map = lane_drop_map(&p);
    let (from, to) = (tag(LANE_DROP_LEFT_START), tag(LANE_DROP_END));
    // Without lane changes there is no route: the left lane ends.
    let err = map.route_places(&from, &to, &RouteOptions::default()).unwrap_err();
    assert!(matches!(err, MapError::NoRoute { .. }), "{err}");

    let opts = LaneChangeOptions::default();
    let route = map.route_with_lane_changes(&from, &to, &opts).unwrap();
    assert_eq!(route.lane_changes.len(), 1, "{:?}", route.lane_changes);
    let change = route.lane_changes[0];
    let table = map.neighbours();
    let from_n = table[map.lanelet_index(change.from).unwrap()];
    assert_eq!(from_n.right, Some(change.to), "the change goes into the right neighbour");
    assert!(change.at_m < p.drop_at - 1.0, "change at {} m, before the drop at {} m", change.at_m, p.drop_at);
    // Cost: the length driven plus one penalty.
    assert!((route.cost_m - (p.length + opts.change_penalty_m)).abs() < 0.01, "cost {}", route.cost_m);
    let path = &route.path;
    assert!((path.length - p.length).abs() < 1.0, "the path is about the road long: {}", path.length);
    let (first, last) = (path.points[0], path.points[path.points.len() - 1]);
    assert!((first.y - 1.5 * p.lane_width).abs() < 1e-3 && first.x.abs() < 1e-3, "starts in the left lane: {first}");
    assert!((last.y - 0.5 * p.lane_width).abs() < 1e-3, "ends in the right lane: {last}");
    // Blended, not a jump: the lateral offset moves at most ~1.5 * width / blend per metre
    // (the smoothstep's steepest slope), never a lane width at once.
    let mut steepest: f64 = 0.0;
    for w in path.points.windows(2) {
        let d = w[1] - w[0];
        steepest = steepest.max((d.y / d.x.abs().max(1e-9)).abs());
        assert!(w[0].y >= 0.5 * p.lane_width - 1e-3 && w[0].y <= 1.5 * p.lane_width + 1e-3);
    }
    let bound = 1.5 * p.lane_width / opts.blend_m * 1.05;
    assert!(steepest <= bound && steepest > 0.5 * bound, "steepest lateral slope {steepest}, bound {bound}");
    // The lanelets list names both lanes around the change.
    let k = path.lanelets.iter().position(|l| *l == change.from).unwrap();
    assert_eq!(path.lanelets[k + 1], change.to);
}

#[test]
fn routes_that_need_no_change_have_none_and_match_the_plain_route() {
    let map = lane_drop_map(&LaneDropParams::default());
    let (from, to) = (tag(LANE_DROP_RIGHT_START), tag(LANE_DROP_END));
    let plain = map.route_places(&from, &to, &RouteOptions::default()).unwrap();
    let route = map.route_with_lane_changes(&from, &to, &LaneChangeOptions::default()).unwrap();
    assert!(route.lane_changes.is_empty());
    assert_eq!(route.path.lanelets, plain.lanelets);
    assert!((route.path.length - plain.length).abs() < 1e-6);
    // The left lane's own end is reachable without a change.
    let left = map.route_with_lane_changes(&tag(LANE_DROP_LEFT_START), &tag(LANE_DROP_LEFT_END), &Default::default());
    assert!(left.unwrap().lane_changes.is_empty());
}

#[test]
fn bad_lane_change_options_name_the_option_and_what_is_allowed() {
    let map = lane_drop_map(&LaneDropParams::default());
    let opts = LaneChangeOptions { change_penalty_m: 0.0, ..Default::default() };
    let err = map.route_with_lane_changes(&tag(LANE_DROP_LEFT_START), &tag(LANE_DROP_END), &opts).unwrap_err();
    let text = err.to_string();
    assert!(text.contains("penalty") && text.contains("(0, inf)"), "{text}");
    let bad = LaneDropParams { drop_at: 600.0, ..Default::default() };
    let text = lane_drop(&bad).unwrap_err().to_string();
    assert!(text.contains("drop_at") && text.contains("below length"), "{text}");
}

#[test]
fn shipped_lane_drop_map_is_the_generated_one() {
    let shipped = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("maps/lane_drop.osm");
    let shipped = LaneletMap::load(&shipped).expect("maps/lane_drop.osm loads");
    let generated = lane_drop_map(&LaneDropParams::default());
    assert_eq!(shipped.lanelets.len(), generated.lanelets.len());
    for (a, b) in shipped.lanelets.iter().zip(&generated.lanelets) {
        assert_eq!(a.id, b.id);
        assert!((a.length - b.length).abs() < 1e-6);
    }
}

#[test]
fn cli_route_lists_lane_changes_in_json() {
    let dir = std::env::temp_dir().join(format!("smlworld-lane-drop-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let map = dir.join("lane_drop.osm");
    let bin = env!("CARGO_BIN_EXE_smlworld");
    let out =
        Command::new(bin).args(["map", "generate", "lane-drop", "--out", map.to_str().unwrap()]).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let args = ["map", "route", map.to_str().unwrap(), "--from-tag", LANE_DROP_LEFT_START, "--to-tag", LANE_DROP_END];
    let plain = Command::new(bin).args(args).output().unwrap();
    assert!(!plain.status.success(), "without --lane-changes the left lane cannot reach the end");
    assert!(String::from_utf8_lossy(&plain.stderr).contains("no route"));
    let out = Command::new(bin).args(args).args(["--lane-changes", "--json"]).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let changes = v["lane_changes"].as_array().expect("lane_changes array");
    assert_eq!(changes.len(), 1);
    for key in ["from", "to", "at_m"] {
        assert!(changes[0].get(key).is_some(), "lane change has `{key}`: {}", changes[0]);
    }
    assert!(changes[0]["at_m"].as_f64().unwrap() < 300.0);
    // Routes without --lane-changes keep their JSON as it was: no lane_changes key.
    let right = ["map", "route", map.to_str().unwrap(), "--from-tag", LANE_DROP_RIGHT_START, "--to-tag", LANE_DROP_END];
    let out = Command::new(bin).args(right).arg("--json").output().unwrap();
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(v.get("lane_changes").is_none());
    std::fs::remove_dir_all(&dir).ok();
}

//! Public CommonRoad files (tests/fixtures/commonroad/, from commonroad-io) and the hand-made ones
//! load with the lanelets and obstacles a plain tag scan finds; positions given as shapes are read
//! at their centres; malformed shapes are errors naming file, line and obstacle; static obstacles
//! stand still, are seen by radar and collide.

use std::path::{Path, PathBuf};
use std::process::Command;

use glam::DVec2;
use smlworld::map::commonroad::CommonRoadScenario;
use smlworld::prelude::*;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Every CommonRoad file the tests have: the public fixtures and the hand-made files.
fn all_files() -> Vec<PathBuf> {
    let mut files = Vec::new();
    for dir in ["tests/fixtures/commonroad", "tests/commonroad"] {
        for e in std::fs::read_dir(root().join(dir)).unwrap() {
            let p = e.unwrap().path();
            if p.extension().is_some_and(|x| x == "xml") {
                files.push(p);
            }
        }
    }
    files.sort();
    files
}

/// Counts by a plain scan of the XML text, independent of the reader under test.
#[derive(Debug, Default, PartialEq)]
struct TagCounts {
    lanelets: usize,
    dynamic: usize,
    statics: usize,
    environment: usize,
}

fn scan(text: &str) -> TagCounts {
    let mut c = TagCounts {
        lanelets: text.matches("<lanelet id=").count(),
        dynamic: text.matches("<dynamicObstacle ").count(),
        statics: text.matches("<staticObstacle ").count(),
        environment: text.matches("<environmentObstacle ").count(),
    };
    // 2018b: <obstacle id=..> with <role>static|dynamic</role> inside.
    for chunk in text.split("<obstacle ").skip(1) {
        let body = &chunk[..chunk.find("</obstacle>").unwrap_or(chunk.len())];
        if body.contains("<role>static</role>") {
            c.statics += 1;
        } else if body.contains("<role>dynamic</role>") {
            c.dynamic += 1;
        }
    }
    c
}

#[test]
fn every_file_loads_with_the_lanelets_and_obstacles_of_a_tag_scan() {
    let files = all_files();
    assert!(files.len() >= 4, "{files:?}");
    let mut total = TagCounts::default();
    let mut versions = Vec::new();
    for path in &files {
        let text = std::fs::read_to_string(path).unwrap();
        let expected = scan(&text);
        let sc = CommonRoadScenario::load(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let got = TagCounts {
            lanelets: sc.map.lanelets.len(),
            dynamic: sc.obstacles.len(),
            statics: sc.static_obstacles.len(),
            environment: sc.environment_obstacles.len(),
        };
        assert_eq!(got, expected, "{}", path.display());
        total.lanelets += expected.lanelets;
        total.dynamic += expected.dynamic;
        total.statics += expected.statics;
        total.environment += expected.environment;
        versions.push(sc.version);
    }
    // The files cover both formats and every kind of obstacle (else this test proves little).
    assert!(versions.iter().any(|v| v == "2018b") && versions.iter().any(|v| v == "2020a"), "{versions:?}");
    assert!(total.dynamic > 0 && total.statics > 0 && total.environment > 0, "{total:?}");
}

#[test]
fn public_2020a_file_static_and_environment_obstacles_are_read_and_in_the_map() {
    let path = root().join("tests/fixtures/commonroad/ZAM_TestReadingAll-1_1_T-1.xml");
    let sc = CommonRoadScenario::load(&path).unwrap();
    // Static obstacle 3: a circle of radius 2 m at the origin -> a 4 m x 4 m box.
    let s = &sc.static_obstacles[0];
    assert_eq!((s.id, s.kind.as_str()), (3, "unknown"));
    assert!(s.position.length() < 1e-9 && (s.length - 4.0).abs() < 1e-9 && (s.width - 4.0).abs() < 1e-9, "{s:?}");
    // Environment obstacle 1234: the building triangle (0,0) (8,0) (4,-4).
    let b = &sc.environment_obstacles[0];
    assert_eq!((b.id, b.kind.as_str()), (1234, "building"));
    assert_eq!(b.outlines, vec![vec![DVec2::ZERO, DVec2::new(8.0, 0.0), DVec2::new(4.0, -4.0)]]);
    // Both are closed ways of the map, so every view draws them.
    let tagged: Vec<(&str, &str)> = sc
        .map
        .ways
        .values()
        .filter_map(|w| Some((w.tags.get("obstacle")?.as_str(), w.tags.get("obstacle_role")?.as_str())))
        .collect();
    assert_eq!(tagged.len(), 2, "{tagged:?}");
    assert!(tagged.contains(&("unknown", "static")) && tagged.contains(&("building", "environment")));
    assert!(sc.map.ways.values().filter(|w| w.tags.contains_key("obstacle")).all(|w| w.is_closed()));
    // Dynamic obstacle 1 has an initial state and an occupancy set (not read): one state.
    assert_eq!(sc.obstacles.iter().map(|o| (o.id, o.states.len())).collect::<Vec<_>>(), vec![(1, 1), (2, 2)]);
}

#[test]
fn loading_bay_blocks_keep_their_size_and_place() {
    // The loading bay's road-boundary blocks are slightly rotated quadrilaterals given as
    // polygons at a (0, 0) state: each becomes a rectangle along its longest edge with the
    // polygon's area and centre.
    let path = root().join("tests/fixtures/commonroad/ZAM_Loading_Bay-1_1_T-1.excerpt.xml");
    let sc = CommonRoadScenario::load(&path).unwrap();
    assert_eq!(sc.static_obstacles.len(), 18);
    for o in &sc.static_obstacles {
        let ring = &o.outlines[0];
        let area = 0.5 * (0..ring.len()).map(|i| ring[i].perp_dot(ring[(i + 1) % ring.len()])).sum::<f64>().abs();
        let mean = ring.iter().copied().sum::<DVec2>() / ring.len() as f64;
        assert_eq!(ring.len(), 4, "obstacle {}: the closing point is not a corner", o.id);
        assert!(
            (o.length * o.width - area).abs() < 0.03 * area,
            "obstacle {}: {} x {} vs area {area}",
            o.id,
            o.length,
            o.width
        );
        assert!(o.position.distance(mean) < 0.5, "obstacle {}: {} vs {mean}", o.id, o.position);
        assert!(o.length >= o.width && o.length > 20.0, "{o:?}");
    }
}

/// `text` with the `<point>` element holding `<x>{x}</x>` replaced by `with`.
fn replace_point(text: &str, x: &str, with: &str) -> String {
    let at = text.find(&format!("<x>{x}</x>")).unwrap_or_else(|| panic!("no point with x {x}"));
    let start = text[..at].rfind("<point>").unwrap();
    let end = at + text[at..].find("</point>").unwrap() + "</point>".len();
    format!("{}{with}{}", &text[..start], &text[end..])
}

fn rectangle(c: DVec2, length: f64, width: f64, orientation: f64) -> String {
    format!(
        "<rectangle><length>{length}</length><width>{width}</width><orientation>{orientation}</orientation>\
         <center><x>{}</x><y>{}</y></center></rectangle>",
        c.x, c.y
    )
}

fn circle(c: DVec2, r: f64) -> String {
    format!("<circle><radius>{r}</radius><center><x>{}</x><y>{}</y></center></circle>", c.x, c.y)
}

fn polygon(points: &[DVec2]) -> String {
    let pts: String = points.iter().map(|p| format!("<point><x>{}</x><y>{}</y></point>", p.x, p.y)).collect();
    format!("<polygon>{pts}</polygon>")
}

#[test]
fn positions_given_as_shapes_are_read_at_the_shape_centres() {
    let path = root().join("tests/fixtures/commonroad/ZAM_TestReadingKsState-1_1_T-1.xml");
    let text = std::fs::read_to_string(&path).unwrap();
    let original = CommonRoadScenario::parse_str(&text, &path).unwrap();
    let expected: Vec<DVec2> = original.obstacles[0].states.iter().map(|s| s.position).collect();
    assert_eq!(expected.len(), 4);
    // The file's four point positions of obstacle 1, each rewritten as a different shape (or
    // two) centred on the same point.
    let xs = ["-105.42349", "-104.32677", "-103.23005", "-102.13313"];
    let p = |k: usize| expected[k];
    let square: Vec<DVec2> = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0), (-1.0, -1.0)]
        .iter()
        .map(|&(dx, dy)| p(2) + DVec2::new(dx, dy))
        .collect();
    let shapes = [
        rectangle(p(0), 5.0, 2.0, 0.3),
        circle(p(1), 1.5),
        polygon(&square),
        rectangle(p(3) + DVec2::new(1.0, 0.5), 4.0, 2.0, 0.0) + &circle(p(3) - DVec2::new(1.0, 0.5), 1.0),
    ];
    let mut shaped = text.clone();
    for (x, shape) in xs.iter().zip(&shapes) {
        shaped = replace_point(&shaped, x, shape);
    }
    assert_eq!(shaped.matches("<point><x>").count(), 5, "the square's corners are the only points left in states");
    let sc = CommonRoadScenario::parse_str(&shaped, &path).unwrap();
    let got: Vec<DVec2> = sc.obstacles[0].states.iter().map(|s| s.position).collect();
    for (k, (g, e)) in got.iter().zip(&expected).enumerate() {
        assert!(g.distance(*e) < 1e-9, "state {k}: {g} instead of {e}");
    }
    // Times, orientations and speeds are untouched.
    let steps =
        |s: &CommonRoadScenario| s.obstacles[0].states.iter().map(|s| (s.time_step, s.velocity)).collect::<Vec<_>>();
    assert_eq!(steps(&sc), steps(&original));
}

#[test]
fn malformed_shapes_name_file_line_and_obstacle() {
    let path = root().join("tests/fixtures/commonroad/ZAM_TestReadingKsState-1_1_T-1.xml");
    let text = std::fs::read_to_string(&path).unwrap();
    let line_of = |t: &str, needle: &str| t.lines().position(|l| l.contains(needle)).unwrap() + 1;
    // Each bad shape opens with a comment naming it, so the test finds its line.
    let cases = [
        // A rectangle position without a width.
        (
            "-104.32677",
            "<rectangle><!--bad-->\n<length>4</length>\n<center><x>1</x><y>2</y></center></rectangle>",
            "width",
        ),
        // A polygon position with two points.
        (
            "-103.23005",
            "<polygon><!--bad-->\n<point><x>1</x><y>2</y></point><point><x>3</x><y>4</y></point></polygon>",
            "at least 3",
        ),
        // An unknown shape.
        ("-102.13313", "<ellipse><!--bad-->\n<a>1</a></ellipse>", "unknown shape <ellipse>"),
        // A negative radius.
        ("-105.42349", "<circle><!--bad-->\n<radius>-1</radius></circle>", "must be positive"),
    ];
    for (x, bad, what) in cases {
        let broken = replace_point(&text, x, bad);
        let err = CommonRoadScenario::parse_str(&broken, &path).unwrap_err().to_string();
        let at = format!("{}:{}", path.display(), line_of(&broken, "<!--bad-->"));
        assert!(err.contains(&at), "{err}\nshould name {at}");
        assert!(err.contains("obstacle 1") && err.contains(what), "{err}");
    }
    // A static obstacle without a shape.
    let extra = "  <staticObstacle id=\"7\">\n    <type>parkedVehicle</type>\n    <initialState><position><point><x>0</x><y>0</y></point></position><time><exact>0</exact></time></initialState>\n  </staticObstacle>\n</commonRoad>";
    let broken = text.replace("</commonRoad>", extra);
    let err = CommonRoadScenario::parse_str(&broken, &path).unwrap_err().to_string();
    assert!(err.contains(&format!(":{}", line_of(&broken, "<staticObstacle id=\"7\">"))), "{err}");
    assert!(err.contains("static obstacle 7") && err.contains("no <shape>"), "{err}");
}

/// The hand-made two-lane file plus a parked car (static obstacle 300, 4.5 m x 1.8 m) on the
/// right lane at x = 30 m, and two overlapping road-boundary blocks (301, 302) off the road.
fn with_static_obstacles(dir: &Path) -> PathBuf {
    let text = std::fs::read_to_string(root().join("tests/commonroad/two_lanes_2020a.xml")).unwrap();
    let state = |x: f64, y: f64| {
        format!(
            "<initialState><position><point><x>{x}</x><y>{y}</y></point></position>\
             <orientation><exact>0.0</exact></orientation><time><exact>0</exact></time></initialState>"
        )
    };
    let block = |id: i64, x: f64| {
        let corners =
            [(0.0, 0.0), (10.0, 0.0), (10.0, 5.0), (0.0, 5.0), (0.0, 0.0)].map(|(a, b)| DVec2::new(x + a, 20.0 + b));
        format!(
            "  <staticObstacle id=\"{id}\">\n    <type>roadBoundary</type>\n    <shape>{}</shape>\n    {}\n  </staticObstacle>\n",
            polygon(&corners),
            state(0.0, 0.0)
        )
    };
    let parked = format!(
        "  <staticObstacle id=\"300\">\n    <type>parkedVehicle</type>\n    <shape><rectangle><length>4.5</length><width>1.8</width></rectangle></shape>\n    {}\n  </staticObstacle>\n",
        state(30.0, 1.75)
    );
    let extra = format!("{parked}{}{}</commonRoad>", block(301, 60.0), block(302, 69.0));
    let path = dir.join("two_lanes_parked.xml");
    std::fs::write(&path, text.replace("</commonRoad>", &extra)).unwrap();
    path
}

/// `scenarios/commonroad_ignore.toml` (ego -1 at 12 m/s on the right lane, ignoring obstacles,
/// radar 100 m) on `map`.
fn scenario_on(dir: &Path, map: &Path) -> PathBuf {
    let text = std::fs::read_to_string(root().join("scenarios/commonroad_ignore.toml")).unwrap();
    let text = text.replace("\"../tests/commonroad/two_lanes_2020a.xml\"", &format!("{:?}", map.display().to_string()));
    assert!(text.contains("two_lanes_parked.xml"), "the scenario's map line changed");
    let path = dir.join("parked.toml");
    std::fs::write(&path, text).unwrap();
    path
}

#[test]
fn static_obstacles_stand_still_are_seen_by_radar_and_collide() {
    let dir = std::env::temp_dir().join(format!("smlworld-commonroad-static-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let map = with_static_obstacles(&dir);
    let toml = scenario_on(&dir, &map);

    // Radar: at the first sensor tick the ego (x = 5 m, heading east, 60 deg, 100 m) sees the
    // parked car 25 m ahead.
    let scenario = smlworld::app::Scenario::load(&toml).unwrap();
    let mut sim = scenario.builder().unwrap().build();
    sim.run_for(0.01);
    let ego = sim.entity(VehicleId(-1)).unwrap();
    let seen: Vec<i32> = sim.world().get::<SensorReadings>(ego).unwrap().0.iter().map(|d| d.id.0).collect();
    assert!(seen.contains(&-300), "radar readings {seen:?}");

    // A run: the ego drives into the parked car; the touching blocks are no collision.
    let out = dir.join("out");
    let o = Command::new(env!("CARGO_BIN_EXE_smlworld")).arg("run").arg(&toml).arg("--out").arg(&out).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let first = &summary["metrics"]["collisions"][0];
    assert_eq!((first["a"].as_i64(), first["b"].as_i64()), (Some(-300), Some(-1)), "{summary}");
    // Front bumper at 5 + 2.25 m (ego 4.5 m long) meets the car's rear at 30 - 2.25 m: 20.5 m at 12 m/s.
    let t = first["t"].as_f64().unwrap();
    assert!((t - 20.5 / 12.0).abs() < 0.2, "collision at {t} s");
    let pairs: Vec<(i64, i64)> = summary["metrics"]["collisions"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| (c["a"].as_i64().unwrap(), c["b"].as_i64().unwrap()))
        .collect();
    assert!(!pairs.contains(&(-302, -301)), "{pairs:?}");
    assert_eq!(summary["commonroad"]["obstacles"].as_u64(), Some(2 + 3), "two dynamic, three static");

    // summary.json tells replays which vehicles are stationary (the map draws those).
    let replayed = summary["replay"]["vehicles"].as_array().unwrap();
    let stationary = |id: i64| replayed.iter().find(|v| v["id"].as_i64() == Some(id)).map(|v| v["stationary"].clone());
    assert_eq!(stationary(-300), Some(serde_json::Value::Bool(true)));
    assert_eq!(stationary(-1), Some(serde_json::Value::Null), "only stationary vehicles carry the flag");

    // Plots leave stationary obstacles out (a flat line each), not the collision with one.
    let o = Command::new(env!("CARGO_BIN_EXE_smlworld")).arg("plot").arg(&out).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let speed = std::fs::read_to_string(out.join("plots/speed.svg")).unwrap();
    assert!(speed.lines().any(|l| l.trim() == "vehicle -1"), "the ego is in the legend");
    assert!(!speed.contains("vehicle -300"), "the parked car is not");

    // The parked car never moves.
    let csv = std::fs::read_to_string(out.join("trajectories.csv")).unwrap();
    let rows: Vec<Vec<f64>> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').take(4).map(|v| v.parse().unwrap()).collect())
        .filter(|f: &Vec<f64>| f[1] == -300.0)
        .collect();
    assert!(rows.len() > 100, "{} rows of -300", rows.len());
    assert!(rows.iter().all(|f| f[2] == 30.0 && f[3] == 1.75), "{:?}", rows.iter().find(|f| f[2] != 30.0));

    // With ACC (scenarios/commonroad_acc.toml) the ego takes the parked car as its leader and
    // stops behind it.
    let text = std::fs::read_to_string(root().join("scenarios/commonroad_acc.toml")).unwrap();
    let text = text.replace("\"../tests/commonroad/two_lanes_2020a.xml\"", &format!("{:?}", map.display().to_string()));
    let acc_toml = dir.join("parked_acc.toml");
    std::fs::write(&acc_toml, text).unwrap();
    let out = dir.join("acc");
    let o =
        Command::new(env!("CARGO_BIN_EXE_smlworld")).arg("run").arg(&acc_toml).arg("--out").arg(&out).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let acc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(acc["metrics"]["collision_count"].as_u64(), Some(0), "{acc}");
    let follower = &acc["metrics"]["followers"][0];
    assert_eq!((follower["id"].as_i64(), follower["leader"].as_i64()), (Some(-1), Some(-300)), "{follower}");
    assert!(follower["min_gap"].as_f64().unwrap() > 1.0, "{follower}");
    let _ = std::fs::remove_dir_all(&dir);
}

//! Traffic lights in pictures and outputs (issue 53, item 4): frames of `smlworld run` draw each
//! signalised stop line in its signal's colour, the colour changes with the program's phase,
//! the run writes `lights.csv`, and `smlworld replay` draws the same colours from it.

mod scratch_support;

use std::path::Path;
use std::process::Command;

use glam::DVec2;
use scratch_support::Scratch;
use smlworld::map::LaneletMap;
use smlworld::map::junctions::default_program;
use smlworld::render::{BirdseyeView, SIGNAL_GREEN, SIGNAL_RED};

fn smlworld(args: &[&str]) {
    let out = Command::new(env!("CARGO_BIN_EXE_smlworld")).args(args).output().expect("runs smlworld");
    assert!(out.status.success(), "smlworld {args:?} failed: {}", String::from_utf8_lossy(&out.stderr));
}

/// 640 x 640 px at 4 px/m around the origin: the whole junction and its approaches (PNG frames
/// carry no overlay by default).
const VIEW: [&str; 8] = ["--width", "640", "--height", "640", "--pixels-per-meter", "4", "--center", "0,0"];

/// The colour at the middle of every link's stop line (the segment from its lanelet's left bound
/// start to its right bound start), in link order.
fn stop_line_colours(png: &Path, map: &LaneletMap) -> Vec<[u8; 4]> {
    let img = image::open(png).unwrap_or_else(|e| panic!("{}: {e}", png.display())).to_rgba8();
    let view = BirdseyeView::new(640, 640, 4.0, DVec2::ZERO).expect("a valid view");
    let junction = &map.junctions().list[0];
    junction
        .links
        .iter()
        .map(|l| {
            let lanelet = map.lanelet(l.lanelet).expect("a link's lanelet is on the map");
            let p = view.world_to_pixel((lanelet.left[0] + lanelet.right[0]) * 0.5);
            img.get_pixel(p.x as u32, p.y as u32).0
        })
        .collect()
}

/// Green for `G`/`g`, red for `r`, as the frames draw them.
fn expected(state: &str) -> Vec<[u8; 4]> {
    state.chars().map(|c| if c == 'r' { SIGNAL_RED } else { SIGNAL_GREEN }).collect()
}

#[test]
fn stop_lines_show_their_signals_in_run_and_replay_frames() {
    let dir = Scratch::new("smlworld-render-lights", "run");
    let map_path = dir.join("x.osm");
    smlworld(&["map", "generate", "intersection4", "--traffic-lights", "--out", map_path.to_str().unwrap()]);
    let scenario = dir.join("lights.toml");
    std::fs::write(
        &scenario,
        "seed = 7\nduration = 60.0\nmap = \"x.osm\"\n\n[[traffic]]\nroute = \"random\"\nrate = 600.0\n\
         speed = [10.0, 12.0]\nclasses = { car = 1.0 }\nlane_change = false\n",
    )
    .unwrap();
    let (out, frames) = (dir.join("out"), dir.join("frames"));
    let mut args = vec![
        "run",
        scenario.to_str().unwrap(),
        "--duration",
        "40",
        "--out",
        out.to_str().unwrap(),
        "--frames",
        frames.to_str().unwrap(),
        "--frame-rate",
        "0.1",
    ];
    args.extend(VIEW);
    smlworld(&args);

    // The default program (27 s green, 3 s yellow, 2 s all red per axis): at t = 10 s the first
    // axis is green, at t = 40 s the second.
    let map = LaneletMap::load(&map_path).unwrap();
    let program = default_program(&map.junctions().list[0], false);
    let (first, second) = (&program[0].state, &program[3].state);
    assert!(first.contains('G') && first.contains('r'), "{first}");
    let at_10 = stop_line_colours(&frames.join("frame_000001.png"), &map);
    let at_40 = stop_line_colours(&frames.join("frame_000004.png"), &map);
    assert_eq!(at_10, expected(first), "t = 10 s shows {first}");
    assert_eq!(at_40, expected(second), "t = 40 s shows {second}");
    assert!(at_10.iter().zip(&at_40).any(|(a, b)| *a == SIGNAL_RED && *b == SIGNAL_GREEN), "a red line turned green");

    // lights.csv: the state at t = 0 and one row per change (green, yellow, all red, green).
    let csv = std::fs::read_to_string(out.join("lights.csv")).unwrap();
    let rows: Vec<&str> = csv.lines().collect();
    assert_eq!(rows[0], "t,junction,state");
    assert_eq!(rows[1], format!("0,1,{first}"), "t with trailing zeros dropped (README)");
    assert_eq!(rows.len(), 5, "{csv}");
    assert!(rows[4].starts_with("32,1,"), "{csv}");

    // The replay draws the same colours from lights.csv.
    let replayed = dir.join("replayed");
    let mut args = vec!["replay", out.to_str().unwrap(), "--frames", replayed.to_str().unwrap(), "--frame-rate", "0.1"];
    args.extend(VIEW);
    smlworld(&args);
    assert_eq!(stop_line_colours(&replayed.join("frame_000001.png"), &map), at_10);
    assert_eq!(stop_line_colours(&replayed.join("frame_000004.png"), &map), at_40);

    // A run without lights removes an earlier run's lights.csv (a replay would draw them).
    let plain = concat!(env!("CARGO_MANIFEST_DIR"), "/scenarios/highway.toml");
    smlworld(&["run", plain, "--duration", "1", "--out", out.to_str().unwrap()]);
    assert!(!out.join("lights.csv").exists());
}

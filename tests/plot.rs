//! `smlworld plot OUT_DIR` and `run --plots`: every figure exists as PNG and SVG, is not blank,
//! and the speed plot's curve moves when the data change.

use std::path::{Path, PathBuf};
use std::process::Command;

use image::RgbImage;

fn smlworld(args: &[&str]) {
    let out = Command::new(env!("CARGO_BIN_EXE_smlworld")).args(args).output().expect("runs smlworld");
    assert!(out.status.success(), "smlworld {args:?} failed: {}", String::from_utf8_lossy(&out.stderr));
}

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("smlworld-plot-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Mean image row of the pixels drawn in `color` (the first vehicle's curve), and their count.
fn curve_rows(img: &RgbImage, color: [u8; 3]) -> (f64, usize) {
    let rows: Vec<u32> = img.enumerate_pixels().filter(|(_, _, p)| p.0 == color).map(|(_, y, _)| y).collect();
    (rows.iter().map(|&y| f64::from(y)).sum::<f64>() / rows.len().max(1) as f64, rows.len())
}

#[test]
fn run_plots_writes_every_figure_and_the_speed_curve_follows_the_data() {
    let dir = tmp("platoon");
    let scenario = concat!(env!("CARGO_MANIFEST_DIR"), "/scenarios/platoon_brake.toml");
    smlworld(&["run", scenario, "--duration", "20", "--out", s(&dir), "--plots"]);
    let plots = dir.join("plots");
    for name in ["speed", "gaps", "platoon_-1", "lateral", "time_space", "trace"] {
        let png = image::open(plots.join(format!("{name}.png"))).unwrap().to_rgb8();
        assert_eq!(png.dimensions(), smlworld::app::FIGURE_SIZE);
        // Not blank: white background plus axes, text and curves in many colours.
        let mut colours: Vec<[u8; 3]> = png.pixels().map(|p| p.0).collect();
        colours.sort_unstable();
        colours.dedup();
        assert!(colours.len() > 50, "{name}.png has only {} colours", colours.len());
        let non_white = png.pixels().filter(|p| p.0 != [255, 255, 255]).count();
        assert!(non_white > 20_000, "{name}.png: {non_white} drawn pixels");
        let svg = std::fs::read_to_string(plots.join(format!("{name}.svg"))).unwrap();
        let drawn = if name == "time_space" { "<circle" } else { "<polyline" };
        assert!(svg.starts_with("<svg") && svg.contains(drawn), "{name}.svg");
    }
    // Axis labels carry units and a legend names the vehicles (the SVG keeps the text).
    let svg = std::fs::read_to_string(plots.join("speed.svg")).unwrap();
    for text in ["time [s]", "speed [m/s]", "vehicle -5", "vehicle -1"] {
        assert!(svg.contains(text), "speed.svg lacks {text:?}");
    }

    // One colour per vehicle in every figure: vehicle -5, the first in id order, has the first
    // colour in speed, platoon, lateral, trace and no other vehicle has it.
    let colour = smlworld::app::PALETTE[0];
    assert_eq!(smlworld::app::pen(0).color, colour);
    for name in ["speed", "platoon_-1", "lateral", "trace"] {
        let (_, n) = curve_rows(&image::open(plots.join(format!("{name}.png"))).unwrap().to_rgb8(), colour);
        assert!(n > 300, "{name}.png: {n} px of vehicle -5's colour");
    }
    // Legends sit right of the plot (x > 1300 px of 1600), never over a curve; titles name the
    // disturbance.
    for cap in svg.split("<text").skip(1).filter(|t| t.contains(">vehicle ")) {
        let x: f64 = cap.split("x=\"").nth(1).and_then(|v| v.split('"').next()).unwrap().parse().unwrap();
        assert!(x > 1300.0, "legend entry at x = {x}: {cap}");
    }
    assert!(svg.contains("Speed: "), "the title says what the run shows");

    // Halve the first vehicle's (-5's) speed from 10 s on: its curve moves down in the image;
    // the others keep the axes (the leader's 15 m/s stays the maximum).
    let before = curve_rows(&image::open(plots.join("speed.png")).unwrap().to_rgb8(), colour);
    let csv = dir.join("trajectories.csv");
    let text = std::fs::read_to_string(&csv).unwrap();
    let mut changed = String::new();
    for (i, line) in text.lines().enumerate() {
        let f: Vec<&str> = line.split(',').collect();
        if i > 0 && f[1] == "-5" && f[0].parse::<f64>().unwrap() >= 10.0 {
            let half = |v: &str| (v.parse::<f64>().unwrap() / 2.0).to_string();
            changed.push_str(&format!("{},{},{},{},{},{},{}\n", f[0], f[1], f[2], f[3], f[4], half(f[5]), half(f[6])));
        } else {
            changed.push_str(line);
            changed.push('\n');
        }
    }
    std::fs::write(&csv, changed).unwrap();
    let other = tmp("changed");
    smlworld(&["plot", s(&dir), "--out", s(&other)]);
    let after = curve_rows(&image::open(other.join("speed.png")).unwrap().to_rgb8(), colour);
    assert!(before.1 > 500 && after.1 > 500, "curve pixels: {before:?} {after:?}");
    assert!(after.0 > before.0 + 50.0, "the curve did not move down: mean row {} -> {}", before.0, after.0);
    let _ = std::fs::remove_dir_all(&dir);
    let _ = std::fs::remove_dir_all(&other);
}

#[test]
fn plot_of_a_folder_without_a_run_names_the_missing_file() {
    let dir = tmp("empty");
    std::fs::create_dir_all(&dir).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_smlworld")).args(["plot", s(&dir)]).output().unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("summary.json"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn titles_name_the_disturbance_lanes_are_plotted_and_runs_compare() {
    let brake = tmp("brake");
    let scenario = concat!(env!("CARGO_MANIFEST_DIR"), "/scenarios/platoon_brake.toml");
    smlworld(&["run", scenario, "--duration", "40", "--out", s(&brake), "--plots"]);
    let svg = std::fs::read_to_string(brake.join("plots/speed.svg")).unwrap();
    // The leader brakes at 30 s (scenario file): the first to slow down.
    assert!(
        svg.contains("vehicle -1 slows from 15.0 to 0.0 m/s at 30."),
        "speed.svg title: {}",
        &svg[..svg.len().min(3000)]
    );

    // Cut off as the brake begins, the run's only change is the followers settling their gaps
    // in the first second (about 7 % of their speed): no event to name.
    let short = tmp("brake-short");
    smlworld(&["run", scenario, "--duration", "29", "--out", s(&short), "--plots"]);
    let svg = std::fs::read_to_string(short.join("plots/speed.svg")).unwrap();
    assert!(svg.contains("Speed: steady speeds"), "speed.svg title: {}", &svg[..svg.len().min(3000)]);

    let lanes = tmp("lanes");
    let overtaking = concat!(env!("CARGO_MANIFEST_DIR"), "/scenarios/overtaking.toml");
    smlworld(&["run", overtaking, "--out", s(&lanes), "--plots"]);
    let svg = std::fs::read_to_string(lanes.join("plots/lanes.svg")).expect("a run with lane changes plots lanes");
    for text in ["lanelet id [-]", "lane offset [m]", "time [s]", "lane change"] {
        assert!(svg.contains(text), "lanes.svg lacks {text:?}");
    }

    let slow = tmp("brake-slow");
    smlworld(&["run", scenario, "--duration", "40", "--out", s(&slow), "--set", "vehicles.*.speed=10.0"]);
    std::fs::write(slow.join("params.json"), r#"{"speed": 10.0}"#).unwrap();
    let out = tmp("compare");
    smlworld(&["plot", "--compare", s(&brake), s(&slow), "--out", s(&out)]);
    let svg = std::fs::read_to_string(out.join("compare_speed.svg")).unwrap();
    let brake_name = brake.file_name().unwrap().to_str().unwrap();
    assert!(svg.contains(brake_name) && svg.contains("speed=10.0"), "legend names both runs");
    let png = image::open(out.join("compare_speed.png")).unwrap().to_rgb8();
    for c in [[31, 119, 180], [214, 39, 40]] {
        assert!(curve_rows(&png, c).1 > 300, "a colour per run: {c:?}");
    }
    assert!(out.join("compare_gaps.png").exists() && out.join("compare_lateral.png").exists());
    let one = Command::new(env!("CARGO_BIN_EXE_smlworld")).args(["plot", s(&brake), s(&slow)]).output().unwrap();
    assert!(!one.status.success() && String::from_utf8_lossy(&one.stderr).contains("--compare"));
    for d in [brake, short, lanes, slow, out] {
        let _ = std::fs::remove_dir_all(d);
    }
}

/// The GCDC merge's time-space diagram has a panel per lane, and the mergers' dots leave lane 2
/// (position along the 2 km road rising, speeds coloured): the figure draws the run's data.
#[test]
fn the_time_space_diagram_has_a_panel_per_lane_coloured_by_speed() {
    let dir = tmp("gcdc");
    let scenario = concat!(env!("CARGO_MANIFEST_DIR"), "/scenarios/gcdc_merge.toml");
    smlworld(&["run", scenario, "--out", s(&dir), "--plots"]);
    let svg = std::fs::read_to_string(dir.join("plots/time_space.svg")).unwrap();
    for text in ["lane 1 (rightmost)", "lane 2", "position [m]", "speed [m/s]"] {
        assert!(svg.contains(text), "time_space.svg lacks {text:?}");
    }
    // Dots in the colours of a range of speeds, not one.
    let mut fills: Vec<&str> =
        svg.split("<circle").skip(1).filter_map(|c| c.split("fill=\"").nth(1)?.split('"').next()).collect();
    fills.sort_unstable();
    fills.dedup();
    assert!(fills.len() > 20, "{} dot colours", fills.len());
    // The long road: the trace's axes are not to scale, and it says so.
    let trace = std::fs::read_to_string(dir.join("plots/trace.svg")).unwrap();
    assert!(trace.contains("axes not to scale"), "trace.svg title");
    let _ = std::fs::remove_dir_all(&dir);
}

//! Views of a run (issue 23 items 1 and 3): `--follow` keeps the vehicle on the image centre,
//! auto-fit frames the vehicles when the whole map would be unreadable, every vehicle in view
//! carries its id label at 640x360, and a collision of a replayed run is a red ring for 2 s.

mod scratch_support;

use scratch_support::Scratch;
use std::path::Path;
use std::process::Command;

use glam::DVec2;
use image::RgbaImage;
use smlworld::map::LaneletMap;
use smlworld::render::{BirdseyeView, VehicleSprite, label_boxes};

const PLATOON: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/scenarios/platoon_brake.toml");

fn smlworld(args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_smlworld")).args(args).output().expect("runs smlworld");
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "smlworld {args:?} failed: {stderr}");
    stderr
}

fn tmp(name: &str) -> Scratch {
    Scratch::new("smlworld-render-views", name)
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn frame(dir: &Path, k: usize) -> RgbaImage {
    image::open(dir.join(format!("frame_{k:06}.png"))).unwrap().to_rgba8()
}

/// Whether a pixel is the trucks' orange ([242, 128, 24], hatched with white on virtual ones).
fn orange(p: &image::Rgba<u8>) -> bool {
    let [r, g, b, _] = p.0;
    r > 200 && (100..=190).contains(&g) && b < 110 && r as i32 - b as i32 > 120
}

/// Rows `t,id,x,y,...` of a trajectories.csv at time `t` [s]: id -> position.
fn positions(csv: &Path, t: f64) -> Vec<(i32, DVec2)> {
    let text = std::fs::read_to_string(csv).unwrap();
    text.lines()
        .skip(1)
        .filter_map(|line| {
            let f: Vec<f64> = line.split(',').take(4).map(|v| v.parse().unwrap()).collect();
            ((f[0] - t).abs() < 1e-9).then(|| (f[1] as i32, DVec2::new(f[2], f[3])))
        })
        .collect()
}

#[test]
fn follow_keeps_the_vehicle_on_the_image_centre_while_the_ground_moves() {
    let dir = tmp("follow");
    let frames = dir.join("frames");
    smlworld(&[
        "run",
        PLATOON,
        "--duration",
        "4",
        "--out",
        s(&dir),
        "--frames",
        s(&frames),
        "--width",
        "640",
        "--height",
        "360",
        "--follow",
        "-3",
        "--pixels-per-meter",
        "4",
    ]);
    let mut centroids = Vec::new();
    for k in [5, 15, 25, 35] {
        let img = frame(&frames, k);
        // The followed truck is the orange blob around the centre; its neighbours in the
        // platoon are more than 10 m (40 px) away, outside a 30 px radius.
        let (mut sum, mut n) = (DVec2::ZERO, 0.0);
        for (x, y, p) in img.enumerate_pixels() {
            let d = DVec2::new(f64::from(x) + 0.5 - 320.0, f64::from(y) + 0.5 - 180.0);
            if d.length() < 30.0 && orange(p) {
                sum += d;
                n += 1.0;
            }
        }
        assert!(n > 20.0, "frame {k}: no truck near the centre ({n} px)");
        let c = sum / n;
        assert!(c.x.abs() < 0.05 * 640.0 && c.y.abs() < 0.05 * 360.0, "frame {k}: truck centroid {c} px off centre");
        centroids.push(c);
    }
    // Smooth: the truck does not wander from frame to frame (2 px: its outline turns with it).
    for w in centroids.windows(2) {
        assert!((w[1] - w[0]).length() < 2.0, "jitter: {:?}", centroids);
    }
    // The camera moved with it: the ground under a corner changed between frames 5 and 35.
    let (a, b) = (frame(&frames, 5), frame(&frames, 35));
    let changed = (0..360).filter(|&y| a.get_pixel(600, y) != b.get_pixel(600, y)).count();
    assert!(changed > 100, "the ground did not move ({changed} of 360 px changed)");

    // A vehicle the run does not have is refused, naming it and the ones it has.
    let out = Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["run", PLATOON, "--duration", "1", "--out", s(&dir.join("bad")), "--gif"])
        .arg(dir.join("bad.gif"))
        .args(["--follow", "42"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && stderr.contains("--follow 42") && stderr.contains("-3"), "{stderr}");
}

#[test]
fn auto_fit_frames_the_vehicles_when_the_map_would_be_under_one_pixel_per_metre() {
    let dir = tmp("floor");
    let frames = dir.join("frames");
    // 64 px for the ~160 m ring: 0.4 px/m.
    let stderr = smlworld(&[
        "run",
        PLATOON,
        "--duration",
        "1",
        "--out",
        s(&dir),
        "--frames",
        s(&frames),
        "--width",
        "64",
        "--height",
        "36",
    ]);
    // The ring in 64 px is under 1 px/m: the view follows the traffic.
    assert!(stderr.contains("following the traffic"), "{stderr}");
    let img = frame(&frames, 0);
    let trucks = img.pixels().filter(|p| orange(p)).count();
    assert!(trucks >= 5, "the trucks are drawn large enough to see: {trucks} orange px");
}

#[test]
fn every_vehicle_in_view_has_its_label_at_640x360_on_the_platoon() {
    let dir = tmp("labels");
    let frames = dir.join("frames");
    smlworld(&["run", PLATOON, "--duration", "3", "--out", s(&dir)]);
    smlworld(&["replay", s(&dir), "--frames", s(&frames), "--width", "640", "--height", "360"]);
    // Frame 20 is t = 2.0 s (frame k at k / 10 Hz from t = 0), a logged time: the replay draws
    // the logged positions exactly.
    let at = positions(&dir.join("trajectories.csv"), 2.0);
    assert_eq!(at.len(), 5);
    let map = LaneletMap::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("maps/highway_ring.osm")).unwrap();
    let view = BirdseyeView::fit_map(640, 360, &map).unwrap();
    let sprites: Vec<VehicleSprite> =
        at.iter().map(|(id, p)| VehicleSprite::new(*id, *p, 0.0, 12.0, 2.5, "Truck")).collect();
    let boxes = label_boxes(&view, &sprites);
    let mut ids: Vec<i32> = boxes.iter().map(|b| b.0).collect();
    ids.sort_unstable();
    assert_eq!(ids, vec![-5, -4, -3, -2, -1], "a label for each of the five trucks");
    let img = frame(&frames, 20);
    for (id, [x0, y0, x1, y1]) in boxes {
        // White glyph pixels and their outline in the vehicle's colour inside the box.
        let c = smlworld::render::vehicle_color(id);
        let (mut white, mut outline) = (0, 0);
        for y in y0 as u32..y1 as u32 {
            for x in x0 as u32..x1 as u32 {
                let p = img.get_pixel(x, y).0;
                white += usize::from(p[0] > 230 && p[1] > 230 && p[2] > 230);
                outline += usize::from((0..3).all(|k| (i32::from(p[k]) - i32::from(c[k])).abs() < 40));
            }
        }
        assert!(white >= 8 && outline >= 8, "label {id} at ({x0}, {y0}): {white} white and {outline} outline px");
    }
}

#[test]
fn a_replayed_collision_is_a_red_ring_for_two_seconds() {
    let dir = tmp("collision");
    let map = Path::new(env!("CARGO_MANIFEST_DIR")).join("maps/highway_ring.osm");
    // Two cars drive into each other at (0, -50) m, meeting at t = 1 s, and stand there.
    let mut csv = String::from("t,id,x,y,yaw,vx,vy\n");
    for k in 0..=40 {
        let t = f64::from(k) * 0.1;
        let d = (10.0 * (1.0 - t)).max(2.0);
        csv += &format!("{t:.1},1,{},-50,0,0,0\n{t:.1},2,{},-50,3.14159,0,0\n", -d, d);
    }
    std::fs::write(dir.join("trajectories.csv"), csv).unwrap();
    let summary = serde_json::json!({
        "metrics": { "collisions": [ { "a": 1, "b": 2, "t": 0.8 } ] },
        "replay": {
            "map": map,
            "log_rate": 10.0,
            "vehicles": [
                { "id": 1, "class": "car", "length": 4.0, "width": 1.8 },
                { "id": 2, "class": "car", "length": 4.0, "width": 1.8 }
            ]
        }
    });
    std::fs::write(dir.join("summary.json"), summary.to_string()).unwrap();
    let frames = dir.join("frames");
    smlworld(&["replay", s(&dir), "--frames", s(&frames), "--width", "640", "--height", "360"]);
    let map = LaneletMap::load(&map).unwrap();
    let view = BirdseyeView::fit_map(640, 360, &map).unwrap();
    let c = view.world_to_pixel(DVec2::new(0.0, -50.0));
    let red_near = |img: &RgbaImage| {
        img.enumerate_pixels()
            .filter(|(x, y, p)| {
                let d = DVec2::new(f64::from(*x) + 0.5, f64::from(*y) + 0.5).distance(c);
                let [r, g, b, _] = p.0;
                // The ring's own red (235, 20, 20), not the red of vehicle 1's label (214, 39, 40).
                d < 40.0 && r > 225 && g < 32 && b < 32
            })
            .count()
    };
    // Frames k are at k / 10 s: 0.3 s before, 1 s and 2.7 s after the collision.
    assert_eq!(red_near(&frame(&frames, 5)), 0, "no ring before the collision");
    assert!(red_near(&frame(&frames, 18)) > 30, "a ring 1 s after it");
    assert_eq!(red_near(&frame(&frames, 35)), 0, "gone 2.7 s after it");
}

//! `Path` geometry, checked analytically on a circle and a straight line.

use std::f64::consts::{PI, TAU};

use glam::DVec2;
use smlworld::map::Path;
use smlworld::map::routing::{resample, resample_count};

fn circle(radius: f64, n: usize) -> Path {
    let points = (0..n).map(|k| DVec2::from_angle(TAU * k as f64 / n as f64) * radius).collect();
    Path::from_points(Vec::new(), points, true)
}

#[test]
fn circle_length_sample_and_projection() {
    let r = 50.0;
    let path = circle(r, 2000);
    // A polygon of 2000 sides is 2*pi*r to 1e-5 relative.
    assert!((path.length - TAU * r).abs() / (TAU * r) < 1e-5);
    // A quarter of the way round, counter-clockwise: (0, r), heading west (pi).
    let (p, heading) = path.sample(path.length / 4.0);
    assert!(p.distance(DVec2::new(0.0, r)) < 1e-3, "{p}");
    let wrapped = (heading - PI + PI).rem_euclid(TAU) - PI;
    assert!(wrapped.abs() < 1e-2, "heading {heading} is west");
    // Wraps around a loop.
    let (q, _) = path.sample(path.length * 1.25);
    assert!(q.distance(p) < 1e-9);
    // A point 2 m outside the circle is 2 m to the right of a counter-clockwise path.
    let outside = DVec2::from_angle(1.0) * (r + 2.0);
    let proj = path.project(outside);
    assert!((proj.lateral + 2.0).abs() < 1e-3, "{}", proj.lateral);
    assert!((proj.s - r).abs() < 1e-2, "arc length of angle 1 rad is r: {}", proj.s);
    // The windowed projection agrees when the hint is close, and costs O(window).
    let near = path.project_near(outside, r - 3.0, 10.0);
    assert!((near.s - proj.s).abs() < 1e-9 && (near.lateral - proj.lateral).abs() < 1e-9);
    // Across the seam of the loop.
    let seam = DVec2::new(r - 1.0, -0.01);
    let p1 = path.project_near(seam, 0.5, 5.0);
    assert!((p1.lateral - 1.0).abs() < 1e-2 && p1.s > path.length - 1.0, "{p1:?}");
}

#[test]
fn open_path_clamps_at_its_ends() {
    let path = Path::from_points(Vec::new(), vec![DVec2::ZERO, DVec2::new(10.0, 0.0)], false);
    assert_eq!(path.length, 10.0);
    assert_eq!(path.sample(-5.0).0, DVec2::ZERO);
    assert_eq!(path.sample(25.0).0, DVec2::new(10.0, 0.0));
    let proj = path.project(DVec2::new(4.0, 3.0));
    assert_eq!((proj.s, proj.lateral), (4.0, 3.0));
}

#[test]
fn resampling_is_equally_spaced_and_keeps_the_ends() {
    let line = [DVec2::ZERO, DVec2::new(3.0, 0.0), DVec2::new(3.0, 4.0)];
    let pts = resample(&line, 5.0);
    assert_eq!(pts.len(), 36, "7 m at 5 points per metre: 35 segments");
    assert_eq!(pts[0], line[0]);
    assert!(pts[35].distance(line[2]) < 1e-12);
    for w in pts.windows(2) {
        // Segments that cut the corner are shorter; all others are exactly 0.2 m.
        let d = w[0].distance(w[1]);
        assert!(d <= 0.2 + 1e-9 && d > 0.14, "{d}");
    }
    let five = resample_count(&line, 5);
    assert_eq!(five.len(), 5);
    assert!(five[2].distance(DVec2::new(3.0, 0.5)) < 1e-12, "half of 7 m is 0.5 m up the second leg");
}

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

/// A small deterministic generator for the property tests below (no dependency needed).
struct Lcg(u64);

impl Lcg {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// The first strictly nearest segment over all segments, as a plain scan: (arc length, lateral).
fn brute_force(path: &Path, p: DVec2) -> (f64, f64) {
    let n = if path.closed { path.points.len() } else { path.points.len() - 1 };
    let spacing = path.length / n as f64;
    let mut best = (f64::INFINITY, 0.0, 0.0);
    for i in 0..n {
        let (a, b) = (path.points[i], path.points[(i + 1) % path.points.len()]);
        let d = b - a;
        let t = ((p - a).dot(d) / d.length_squared()).clamp(0.0, 1.0);
        let d2 = p.distance_squared(a + d * t);
        if d2 < best.0 {
            let cross = d.x * (p - a).y - d.y * (p - a).x;
            best = (d2, (i as f64 + t) * spacing, d2.sqrt() * if cross >= 0.0 { 1.0 } else { -1.0 });
        }
    }
    (best.1, best.2)
}

#[test]
fn projections_that_skip_far_blocks_find_the_same_segment_as_a_full_scan() {
    let mut rng = Lcg(7);
    for case in 0..40 {
        // Wiggly paths with uneven spacing that come back near themselves, open and closed.
        let n = 20 + (rng.next() * 300.0) as usize;
        let mut p = DVec2::ZERO;
        let mut heading = 0.0;
        let mut points = Vec::with_capacity(n);
        for _ in 0..n {
            points.push(p);
            heading += (rng.next() - 0.5) * 1.5;
            p += DVec2::from_angle(heading) * (0.2 + 3.0 * rng.next());
        }
        let path = Path::from_points(Vec::new(), points, case % 2 == 0);
        for _ in 0..200 {
            let k = (rng.next() * n as f64) as usize % n;
            let q = path.points[k] + DVec2::new(rng.next() - 0.5, rng.next() - 0.5) * 20.0;
            let (s, lateral) = brute_force(&path, q);
            let full = path.project(q);
            assert_eq!((full.s, full.lateral), (s, lateral), "case {case}: project at {q}");
            let max = rng.next() * 6.0;
            let within = path.project_near_within(q, 0.0, 1e9, max);
            match within {
                Some(w) => assert!(lateral.abs() <= max && (w.s, w.lateral) == (s, lateral), "case {case}: {w:?}"),
                None => assert!(lateral.abs() > max, "case {case}: {lateral} within {max} missed"),
            }
        }
    }
}

#[test]
fn walking_from_a_close_hint_finds_the_nearest_point_of_a_lane() {
    let r = 80.0;
    let path = circle(r, 503);
    let mut rng = Lcg(11);
    for _ in 0..2000 {
        let angle = rng.next() * TAU;
        let offset = (rng.next() - 0.5) * 3.0;
        let q = DVec2::from_angle(angle) * (r + offset);
        let full = path.project(q);
        let hint = full.s + (rng.next() - 0.5) * 2.0;
        let (s, point, lateral, direction) = path.near_within(q, hint, 2.0, 1.75).expect("on the lane");
        assert_eq!((s, lateral), (full.s, full.lateral), "walk from {hint} to {q}");
        // At a vertex both segments meeting there are nearest: the direction may be either's.
        let turn = (TAU / 503.0 * 1.01).cos();
        assert!(point.distance(full.point) < 1e-12 && direction.dot(DVec2::from_angle(full.heading)) > turn);
    }
    // Farther from the path than allowed: nothing.
    assert!(path.near_within(DVec2::new(r + 3.0, 0.0), 0.0, 2.0, 1.75).is_none());
}

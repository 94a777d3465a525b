//! Polyline maths: length, resampling at equal arc-length spacing, projection, cutting.

use glam::DVec2;

/// Resample a polyline at equal arc-length spacing of about `1 / points_per_meter` metres,
/// keeping both end points. Returns at least the two end points.
pub fn resample(points: &[DVec2], points_per_meter: f64) -> Vec<DVec2> {
    let total = polyline_length(points);
    let segments = ((total * points_per_meter).round() as usize).max(1);
    resample_count(points, segments + 1)
}

/// Resample a polyline to exactly `count` (>= 2) points at equal arc-length spacing.
pub fn resample_count(points: &[DVec2], count: usize) -> Vec<DVec2> {
    let count = count.max(2);
    if points.len() < 2 {
        return vec![points.first().copied().unwrap_or(DVec2::ZERO); count];
    }
    let total = polyline_length(points);
    let mut out = Vec::with_capacity(count);
    let mut seg = 0;
    let mut seg_start = 0.0;
    for k in 0..count {
        let target = total * k as f64 / (count - 1) as f64;
        loop {
            let len = points[seg].distance(points[seg + 1]);
            if target <= seg_start + len || seg + 2 == points.len() {
                let t = if len > 0.0 { ((target - seg_start) / len).clamp(0.0, 1.0) } else { 0.0 };
                out.push(points[seg].lerp(points[seg + 1], t));
                break;
            }
            seg_start += len;
            seg += 1;
        }
    }
    out
}

/// Length of a polyline \[m\].
pub fn polyline_length(points: &[DVec2]) -> f64 {
    points.windows(2).map(|w| w[0].distance(w[1])).sum()
}

/// Project `p` onto a polyline: (arc length of the nearest point \[m\], distance \[m\]).
pub fn project_polyline(points: &[DVec2], p: DVec2) -> (f64, f64) {
    let mut best = (0.0, f64::INFINITY);
    let mut s0 = 0.0;
    for w in points.windows(2) {
        let d = w[1] - w[0];
        let len2 = d.length_squared();
        let t = if len2 > 0.0 { ((p - w[0]).dot(d) / len2).clamp(0.0, 1.0) } else { 0.0 };
        let dist = p.distance(w[0] + d * t);
        let len = len2.sqrt();
        if dist < best.1 {
            best = (s0 + t * len, dist);
        }
        s0 += len;
    }
    best
}

/// The part of a polyline between arc lengths `a0` <= `a1` \[m\].
pub fn sub_polyline(points: &[DVec2], a0: f64, a1: f64) -> Vec<DVec2> {
    let mut out = Vec::new();
    let mut s0 = 0.0;
    for w in points.windows(2) {
        let len = w[0].distance(w[1]);
        let s1 = s0 + len;
        let at = |a: f64| if len > 0.0 { w[0].lerp(w[1], ((a - s0) / len).clamp(0.0, 1.0)) } else { w[0] };
        if s1 >= a0 && s0 <= a1 {
            if out.is_empty() {
                out.push(at(a0.max(s0)));
            }
            if s1 <= a1 {
                out.push(w[1]);
            } else {
                out.push(at(a1));
                break;
            }
        }
        s0 = s1;
    }
    if out.len() == 1 {
        out.push(out[0]);
    }
    out
}

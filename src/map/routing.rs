//! Routing over lanelets: Dijkstra between nodes or tags, closed loops, stitched and resampled paths.

use glam::DVec2;

use super::lanelet::{LaneletId, LaneletMap};
use super::error::MapError;

/// Options of a route search.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RouteOptions {
    /// Resampling density of the returned path [points per metre]; raising it gives a finer path.
    pub points_per_meter: f64,
}

impl Default for RouteOptions {
    fn default() -> Self {
        Self { points_per_meter: 5.0 }
    }
}

/// A drivable path: the stitched centre lines of a lanelet sequence, resampled at equal spacing.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Path {
    /// Lanelets in driving order (for a loop, the first is not repeated at the end).
    pub lanelets: Vec<LaneletId>,
    /// Points [m] at equal arc-length spacing; for a closed loop the last point is not a copy
    /// of the first (the segment back to the start closes it).
    #[serde(serialize_with = "serialize_points")]
    pub points: Vec<DVec2>,
    /// Length [m] (for a loop, including the closing segment).
    pub length: f64,
    /// Whether the path is a closed loop.
    pub closed: bool,
}

fn serialize_points<S: serde::Serializer>(points: &[DVec2], s: S) -> Result<S::Ok, S::Error> {
    use serde::ser::SerializeSeq;
    let mut seq = s.serialize_seq(Some(points.len()))?;
    for p in points {
        seq.serialize_element(&[p.x, p.y])?;
    }
    seq.end()
}

/// Where a point lies relative to a [`Path`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PathProjection {
    /// Arc length of the nearest path point [m].
    pub s: f64,
    /// Nearest point on the path [m].
    pub point: DVec2,
    /// Signed lateral offset [m]: positive when the point lies left of the path.
    pub lateral: f64,
    /// Heading of the path at the nearest point [rad].
    pub heading: f64,
}

impl Path {
    /// A path through `points` (at least two), closed back to the first point if `closed`.
    pub fn from_points(lanelets: Vec<LaneletId>, points: Vec<DVec2>, closed: bool) -> Path {
        let mut length: f64 = points.windows(2).map(|w| w[0].distance(w[1])).sum();
        if closed && points.len() > 1 {
            length += points[points.len() - 1].distance(points[0]);
        }
        Path { lanelets, points, length, closed }
    }

    /// Number of segments (for a loop, including the closing one).
    pub fn segment_count(&self) -> usize {
        if self.points.len() < 2 {
            0
        } else if self.closed {
            self.points.len()
        } else {
            self.points.len() - 1
        }
    }

    /// End points of segment `i` (wrapping for a loop).
    fn segment(&self, i: usize) -> (DVec2, DVec2) {
        let n = self.points.len();
        (self.points[i % n], self.points[(i + 1) % n])
    }

    /// Mean segment length [m] (all segments are equal up to rounding after resampling).
    pub fn spacing(&self) -> f64 {
        match self.segment_count() {
            0 => 0.0,
            n => self.length / n as f64,
        }
    }

    /// Point and heading [rad] at arc length `s` [m]; wraps around a loop, clamps an open path.
    pub fn sample(&self, s: f64) -> (DVec2, f64) {
        let n = self.segment_count();
        if n == 0 {
            return (self.points.first().copied().unwrap_or(DVec2::ZERO), 0.0);
        }
        let s = if self.closed { s.rem_euclid(self.length) } else { s.clamp(0.0, self.length) };
        let spacing = self.spacing();
        let i = ((s / spacing) as usize).min(n - 1);
        let (a, b) = self.segment(i);
        let t = ((s - i as f64 * spacing) / spacing).clamp(0.0, 1.0);
        let d = b - a;
        (a + d * t, d.y.atan2(d.x))
    }

    /// Project `p` onto segments `from..from+count` (wrapping for loops).
    fn project_segments(&self, p: DVec2, from: isize, count: usize) -> PathProjection {
        let n = self.segment_count() as isize;
        let spacing = self.spacing();
        let mut best = PathProjection { s: 0.0, point: self.points[0], lateral: f64::INFINITY, heading: 0.0 };
        let mut best_d2 = f64::INFINITY;
        for k in 0..count as isize {
            let mut i = from + k;
            if self.closed {
                i = i.rem_euclid(n);
            } else if i < 0 || i >= n {
                continue;
            }
            let (a, b) = self.segment(i as usize);
            let d = b - a;
            let len2 = d.length_squared();
            let t = if len2 > 0.0 { ((p - a).dot(d) / len2).clamp(0.0, 1.0) } else { 0.0 };
            let q = a + d * t;
            let d2 = p.distance_squared(q);
            if d2 < best_d2 {
                best_d2 = d2;
                let cross = d.x * (p - a).y - d.y * (p - a).x;
                let lateral = d2.sqrt() * if cross >= 0.0 { 1.0 } else { -1.0 };
                best = PathProjection { s: (i as f64 + t) * spacing, point: q, lateral, heading: d.y.atan2(d.x) };
            }
        }
        best
    }

    /// Nearest point of the whole path to `p` (O(points)).
    pub fn project(&self, p: DVec2) -> PathProjection {
        if self.segment_count() == 0 {
            let q = self.points.first().copied().unwrap_or(DVec2::ZERO);
            return PathProjection { s: 0.0, point: q, lateral: p.distance(q), heading: 0.0 };
        }
        self.project_segments(p, 0, self.segment_count())
    }

    /// Nearest point to `p` within `window` [m] either side of arc length `hint` (O(window)):
    /// what a path follower calls every tick with its last projection as the hint.
    pub fn project_near(&self, p: DVec2, hint: f64, window: f64) -> PathProjection {
        let spacing = self.spacing();
        if self.segment_count() == 0 || spacing <= 0.0 {
            return self.project(p);
        }
        let half = (window / spacing).ceil() as isize + 1;
        let centre = (hint / spacing).floor() as isize;
        let count = (2 * half + 1) as usize;
        if count >= self.segment_count() {
            return self.project(p);
        }
        self.project_segments(p, centre - half, count)
    }
}

/// Resample a polyline at equal arc-length spacing of about `1 / points_per_meter` metres,
/// keeping both end points. Returns at least the two end points.
pub fn resample(points: &[DVec2], points_per_meter: f64) -> Vec<DVec2> {
    let total: f64 = points.windows(2).map(|w| w[0].distance(w[1])).sum();
    let segments = ((total * points_per_meter).round() as usize).max(1);
    resample_count(points, segments + 1)
}

/// Resample a polyline to exactly `count` (>= 2) points at equal arc-length spacing.
pub fn resample_count(points: &[DVec2], count: usize) -> Vec<DVec2> {
    let count = count.max(2);
    if points.len() < 2 {
        return vec![points.first().copied().unwrap_or(DVec2::ZERO); count];
    }
    let total: f64 = points.windows(2).map(|w| w[0].distance(w[1])).sum();
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

/// Length of a polyline [m].
pub fn polyline_length(points: &[DVec2]) -> f64 {
    points.windows(2).map(|w| w[0].distance(w[1])).sum()
}

//! [`Path`]: a drivable polyline at equal spacing (a route, a loop, or any points a user gives)
//! with arc-length sampling and projection.

use glam::DVec2;

use super::lanelet::LaneletId;
use super::polyline::{polyline_length, resample};

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
        let mut length = polyline_length(&points);
        if closed && points.len() > 1 {
            length += points[points.len() - 1].distance(points[0]);
        }
        Path { lanelets, points, length, closed }
    }

    /// An open path along `points` (at least two distinct ones), resampled every `spacing` [m]
    /// (rounded so the points are equally spaced; both ends kept). A road a controller should
    /// follow that does not come from a map: `Path::from_polyline(&[a, b, c], 0.5)`.
    pub fn from_polyline(points: &[DVec2], spacing: f64) -> Path {
        let spacing = if spacing.is_finite() && spacing > 0.0 { spacing } else { 0.2 };
        Path::from_points(Vec::new(), resample(points, 1.0 / spacing), false)
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
        let i = if i < n { i } else { i % n };
        let j = if i + 1 < n { i + 1 } else { 0 };
        (self.points[i], self.points[j])
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
        // (segment, t, nearest point, squared distance) of the best segment; the square root and
        // the heading's atan2 are computed once, for it only (path followers call this every tick).
        let mut best: Option<(isize, f64, DVec2, f64)> = None;
        // One division up front, then wrap by comparison (path followers call this every tick).
        let mut i = if self.closed { from.rem_euclid(n) } else { from } - 1;
        for _ in 0..count {
            i += 1;
            if self.closed && i == n {
                i = 0;
            }
            if i < 0 || i >= n {
                continue;
            }
            let (a, b) = self.segment(i as usize);
            let d = b - a;
            let len2 = d.length_squared();
            let t = if len2 > 0.0 { ((p - a).dot(d) / len2).clamp(0.0, 1.0) } else { 0.0 };
            let q = a + d * t;
            let d2 = p.distance_squared(q);
            if d2 < best.map_or(f64::INFINITY, |b| b.3) {
                best = Some((i, t, q, d2));
            }
        }
        let Some((i, t, q, d2)) = best else {
            return PathProjection { s: 0.0, point: self.points[0], lateral: f64::INFINITY, heading: 0.0 };
        };
        let (a, b) = self.segment(i as usize);
        let d = b - a;
        let cross = d.x * (p - a).y - d.y * (p - a).x;
        let lateral = d2.sqrt() * if cross >= 0.0 { 1.0 } else { -1.0 };
        PathProjection { s: (i as f64 + t) * spacing, point: q, lateral, heading: d.y.atan2(d.x) }
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

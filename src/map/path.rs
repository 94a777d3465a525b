//! [`Path`]: a drivable polyline at equal spacing (a route, a loop, or any points a user gives)
//! with arc-length sampling and projection.

use glam::DVec2;

use super::lanelet::LaneletId;
use super::polyline::{polyline_length, resample};

/// Segments per block of a projection's bounding test.
const BLOCK: usize = 8;

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
    /// Longest segment [m]: bounds how far a block of segments reaches from its middle point,
    /// so projections can skip blocks that cannot hold the nearest point.
    #[serde(skip)]
    max_segment: f64,
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
    /// Unit direction of the path at the nearest point (`heading` as a vector, without trig).
    pub direction: DVec2,
}

impl Path {
    /// A path through `points` (at least two), closed back to the first point if `closed`.
    pub fn from_points(lanelets: Vec<LaneletId>, points: Vec<DVec2>, closed: bool) -> Path {
        let mut length = polyline_length(&points);
        if closed && points.len() > 1 {
            length += points[points.len() - 1].distance(points[0]);
        }
        let mut max_segment = points.windows(2).map(|w| w[0].distance(w[1])).fold(0.0, f64::max);
        if closed && points.len() > 1 {
            max_segment = max_segment.max(points[points.len() - 1].distance(points[0]));
        }
        Path { lanelets, points, length, closed, max_segment }
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

    /// Nearest segment to `p` among segments `from..from+count` (wrapping for loops), as
    /// (segment, t along it, nearest point, squared distance), among those no farther than
    /// `cutoff2` [m²] (`f64::INFINITY`: any). Blocks of [`BLOCK`] segments whose bounding circle
    /// (around their middle point, radius half the block times the longest segment) lies
    /// beyond the best distance so far or the cutoff are skipped: the same segment wins as in
    /// a scan of all of them (first strictly nearest in scan order), at a fraction of the cost.
    fn nearest(&self, p: DVec2, from: isize, count: usize, cutoff2: f64) -> Option<(isize, f64, DVec2, f64)> {
        let n = self.segment_count() as isize;
        let mut best: Option<(isize, f64, DVec2, f64)> = None;
        // One division up front, then wrap by comparison (path followers call this every tick).
        let start = if self.closed { from.rem_euclid(n) } else { from };
        let wrap = |i: isize| if self.closed && i >= n { i - n } else { i };
        // A point of a block lies within BLOCK / 2 segments of the block's middle vertex; the
        // margin covers rounding in the distances compared.
        let reach = 0.5 * BLOCK as f64 * self.max_segment * (1.0 + 1e-9) + 1e-9;
        let mut k = 0usize;
        while k < count {
            let len = BLOCK.min(count - k);
            if len == BLOCK {
                let mid = wrap(start + (k + BLOCK / 2) as isize);
                if mid >= 0 && mid < self.points.len() as isize {
                    let bound = (p.distance(self.points[mid as usize]) - reach).max(0.0);
                    let limit = best.map_or(cutoff2, |b| b.3.min(cutoff2));
                    if bound * bound > limit {
                        k += len;
                        continue;
                    }
                }
            }
            for j in k..k + len {
                let i = wrap(start + j as isize);
                if i < 0 || i >= n {
                    continue;
                }
                let (a, b) = self.segment(i as usize);
                let d = b - a;
                let len2 = d.length_squared();
                let t = if len2 > 0.0 { ((p - a).dot(d) / len2).clamp(0.0, 1.0) } else { 0.0 };
                let q = a + d * t;
                let d2 = p.distance_squared(q);
                if d2 < best.map_or(f64::INFINITY, |b| b.3) && d2 <= cutoff2 {
                    best = Some((i, t, q, d2));
                }
            }
            k += len;
        }
        best
    }

    /// The projection of `p` on segment `i` at `t`, `q` the nearest point, `d2` its squared distance.
    fn projection(&self, p: DVec2, (i, t, q, d2): (isize, f64, DVec2, f64)) -> PathProjection {
        let (a, b) = self.segment(i as usize);
        let d = b - a;
        let cross = d.x * (p - a).y - d.y * (p - a).x;
        let lateral = d2.sqrt() * if cross >= 0.0 { 1.0 } else { -1.0 };
        let direction = d.try_normalize().unwrap_or(DVec2::X);
        PathProjection { s: (i as f64 + t) * self.spacing(), point: q, lateral, heading: d.y.atan2(d.x), direction }
    }

    /// Project `p` onto segments `from..from+count` (wrapping for loops).
    fn project_segments(&self, p: DVec2, from: isize, count: usize) -> PathProjection {
        match self.nearest(p, from, count, f64::INFINITY) {
            Some(best) => self.projection(p, best),
            None => PathProjection {
                s: 0.0,
                point: self.points[0],
                lateral: f64::INFINITY,
                heading: 0.0,
                direction: DVec2::X,
            },
        }
    }

    /// [`Path::project_near`] when only a point within `max_distance` [m] of the path is of
    /// use: `None` when the nearest point in the window is farther (same result as
    /// `project_near` filtered by `|lateral| <= max_distance`, found faster: blocks of the
    /// window that cannot come that near are skipped).
    pub fn project_near_within(&self, p: DVec2, hint: f64, window: f64, max_distance: f64) -> Option<PathProjection> {
        let (from, count) = self.window(hint, window);
        self.nearest(p, from, count, max_distance * max_distance).map(|best| self.projection(p, best))
    }

    /// Squared distance from `p` to segment `i`, with `t` along it and the nearest point.
    fn to_segment(&self, p: DVec2, i: isize) -> (isize, f64, DVec2, f64) {
        let (a, b) = self.segment(i as usize);
        let d = b - a;
        let len2 = d.length_squared();
        let t = if len2 > 0.0 { ((p - a).dot(d) / len2).clamp(0.0, 1.0) } else { 0.0 };
        let q = a + d * t;
        (i, t, q, p.distance_squared(q))
    }

    /// Nearest segment to `p` found by walking from the segment at `hint` [m] towards nearer
    /// segments, at most `window` [m] either way: O(1) for a point that moved little along a
    /// smooth path. `None` when the walk reaches the window's edge (the caller then searches
    /// the whole window) or the path has no segment.
    fn walk(&self, p: DVec2, hint: f64, window: f64) -> Option<(isize, f64, DVec2, f64)> {
        let n = self.segment_count() as isize;
        let spacing = self.spacing();
        if n == 0 || spacing <= 0.0 || !hint.is_finite() {
            return None;
        }
        let steps = (window / spacing).ceil() as isize;
        let wrap = |i: isize| if self.closed { Some(i.rem_euclid(n)) } else { (0..n).contains(&i).then_some(i) };
        let start = (hint / spacing).floor() as isize;
        let start = if self.closed { start } else { start.clamp(0, n - 1) };
        let mut best = self.to_segment(p, wrap(start)?);
        for dir in [1, -1] {
            let mut k = start;
            let mut moved = false;
            loop {
                k += dir;
                if (k - start).abs() > steps {
                    return None;
                }
                let Some(i) = wrap(k) else { break };
                let c = self.to_segment(p, i);
                if c.3 < best.3 {
                    best = c;
                    moved = true;
                } else {
                    break;
                }
            }
            if moved {
                break;
            }
        }
        Some(best)
    }

    /// Where `p` lies near arc length `hint` [m] on a smooth path, when within `max_distance`
    /// [m] of it: arc length [m], nearest point [m], signed lateral offset [m] and the path's
    /// unit direction there (no trigonometry). Walks from `hint` to the nearest segment (the
    /// nearest within `window` [m] when the distance has one minimum there, as along a lane's
    /// centre line near a vehicle on it), else searches the window like
    /// [`Path::project_near_within`].
    pub fn near_within(&self, p: DVec2, hint: f64, window: f64, max_distance: f64) -> Option<(f64, DVec2, f64, DVec2)> {
        let (i, t, q, d2) = match self.walk(p, hint, window) {
            Some(found) => (found.3 <= max_distance * max_distance).then_some(found)?,
            None => {
                let (from, count) = self.window(hint, window);
                self.nearest(p, from, count, max_distance * max_distance)?
            }
        };
        let (a, b) = self.segment(i as usize);
        let d = b - a;
        let cross = d.x * (p - a).y - d.y * (p - a).x;
        let lateral = d2.sqrt() * if cross >= 0.0 { 1.0 } else { -1.0 };
        Some(((i as f64 + t) * self.spacing(), q, lateral, d.try_normalize().unwrap_or(DVec2::X)))
    }

    /// First segment and segment count of the window of `window` [m] either side of `hint` [m]
    /// (the whole path when the window covers it).
    fn window(&self, hint: f64, window: f64) -> (isize, usize) {
        let spacing = self.spacing();
        let all = (0, self.segment_count());
        if self.segment_count() == 0 || spacing <= 0.0 {
            return all;
        }
        let half = (window / spacing).ceil() as isize + 1;
        let centre = (hint / spacing).floor() as isize;
        let count = (2 * half + 1) as usize;
        if count >= self.segment_count() { all } else { (centre - half, count) }
    }

    /// Nearest point of the whole path to `p` (O(points)).
    pub fn project(&self, p: DVec2) -> PathProjection {
        if self.segment_count() == 0 {
            let q = self.points.first().copied().unwrap_or(DVec2::ZERO);
            return PathProjection { s: 0.0, point: q, lateral: p.distance(q), heading: 0.0, direction: DVec2::X };
        }
        self.project_segments(p, 0, self.segment_count())
    }

    /// Nearest point to `p` within `window` [m] either side of arc length `hint` (O(window)):
    /// what a path follower calls every tick with its last projection as the hint.
    pub fn project_near(&self, p: DVec2, hint: f64, window: f64) -> PathProjection {
        if self.segment_count() == 0 {
            return self.project(p);
        }
        let (from, count) = self.window(hint, window);
        self.project_segments(p, from, count)
    }
}

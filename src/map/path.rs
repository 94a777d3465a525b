//! [`Path`]: a drivable polyline at equal spacing (a route, a loop, or any points a user gives)
//! with arc-length sampling and projection.

use glam::DVec2;

use super::lanelet::LaneletId;
use super::polyline::{polyline_length, resample};

/// Segments per block of a projection's bounding test.
const BLOCK: usize = 8;

/// `x.floor() as isize` without a call to libm's `floor` (the baseline x86-64 target has no
/// rounding instruction, and a projection's two calls were a tenth of a lane position's time):
/// the same value for every finite `x` in `isize`'s range, saturating like `as` beyond it.
#[inline]
pub(crate) fn floor_index(x: f64) -> isize {
    let t = x as isize;
    if (t as f64) > x { t.saturating_sub(1) } else { t }
}

/// `x.ceil() as isize`, as [`floor_index`].
#[inline]
pub(crate) fn ceil_index(x: f64) -> isize {
    let t = x as isize;
    if (t as f64) < x { t.saturating_add(1) } else { t }
}

/// A drivable path: the stitched centre lines of a lanelet sequence, resampled at equal spacing.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Path {
    /// Lanelets in driving order (for a loop, the first is not repeated at the end).
    pub lanelets: Vec<LaneletId>,
    /// Points \[m\] at equal arc-length spacing; for a closed loop the last point is not a copy
    /// of the first (the segment back to the start closes it).
    #[serde(serialize_with = "serialize_points")]
    pub points: Vec<DVec2>,
    /// Length \[m\] (for a loop, including the closing segment).
    pub length: f64,
    /// Whether the path is a closed loop.
    pub closed: bool,
    /// Longest segment [m]: bounds how far a block of segments reaches from its middle point,
    /// so projections can skip blocks that cannot hold the nearest point.
    #[serde(skip)]
    max_segment: f64,
    /// [`Path::spacing`], computed once: every projection needs it, and a division per call
    /// was a measurable share of the lane systems' per-vehicle work (issue 19 item 8).
    #[serde(skip)]
    spacing: f64,
    /// 1 / [`Path::spacing`] (0 without segments): where a point near an arc length lies, for
    /// prefetches that must not wait on a division ([`Path::segment_near`]).
    #[serde(skip)]
    per_meter: f64,
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
    /// Arc length of the nearest path point \[m\].
    pub s: f64,
    /// Nearest point on the path \[m\].
    pub point: DVec2,
    /// Signed lateral offset \[m\]: positive when the point lies left of the path.
    pub lateral: f64,
    /// Heading of the path at the nearest point \[rad\].
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
        let mut path = Path { lanelets, points, length, closed, max_segment, spacing: 0.0, per_meter: 0.0 };
        if let n @ 1.. = path.segment_count() {
            path.spacing = length / n as f64;
            path.per_meter = n as f64 / length;
        }
        path
    }

    /// An open path along `points` (at least two distinct ones), resampled every `spacing` \[m\]
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
    pub(crate) fn segment(&self, i: usize) -> (DVec2, DVec2) {
        let n = self.points.len();
        let i = if i < n { i } else { i % n };
        let j = if i + 1 < n { i + 1 } else { 0 };
        (self.points[i], self.points[j])
    }

    /// The point about arc length `s` [m] of the path, as a place in `points` (clamped to the
    /// last; 0 for a NaN): found by a multiplication, so it may be a point off the one
    /// [`Path::spacing`] would give. For hints (prefetches), not for geometry.
    pub(crate) fn segment_near(&self, s: f64) -> usize {
        ((s * self.per_meter) as usize).min(self.points.len().saturating_sub(1))
    }

    /// The points a walk from arc length `s` \[m\] reads: two segments either side of the one
    /// at `s` (six points, two or three cache lines), for prefetch hints
    /// (the world's `prefetch_all`). On a town of 10,000 vehicles each on its own 2-3 km
    /// route, the first read of a route near a vehicle's leader missed the cache every time;
    /// the per-vehicle loops ask for it a few vehicles ahead, so those misses overlap other
    /// vehicles' work.
    pub(crate) fn points_near(&self, s: f64) -> &[DVec2] {
        let k = self.segment_near(s).saturating_sub(2);
        self.points.get(k..(k + 6).min(self.points.len())).unwrap_or(&[])
    }

    /// Mean segment length \[m\] (all segments are equal up to rounding after resampling).
    pub fn spacing(&self) -> f64 {
        self.spacing
    }

    /// Point and heading \[rad\] at arc length `s` \[m\]; wraps around a loop, clamps an open path.
    pub fn sample(&self, s: f64) -> (DVec2, f64) {
        let (point, d) = self.sample_direction(s);
        (point, d.y.atan2(d.x))
    }

    /// Point at arc length `s` \[m\], as [`Path::sample`] gives it, without the heading's `atan2`
    /// (a path follower samples its look-ahead point every tick and needs the heading only to
    /// aim beside the path).
    pub fn sample_point(&self, s: f64) -> DVec2 {
        self.sample_direction(s).0
    }

    /// Point at arc length `s` [m] and the (unnormalised) vector of its segment.
    fn sample_direction(&self, s: f64) -> (DVec2, DVec2) {
        let n = self.segment_count();
        if n == 0 {
            return (self.points.first().copied().unwrap_or(DVec2::ZERO), DVec2::X);
        }
        let s = if self.closed { wrap_length(s, self.length) } else { s.clamp(0.0, self.length) };
        let spacing = self.spacing();
        let i = ((s / spacing) as usize).min(n - 1);
        let (a, b) = self.segment(i);
        along_segment(s, i as f64, spacing, a, b)
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
        let start = if self.closed && !(0..n).contains(&from) { from.rem_euclid(n) } else { from };
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
                let (t, q, d2) = onto_segment(p, a, b);
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
        let lateral = self.lateral(p, i, d2);
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

    /// [`Path::project_near`] when only a point within `max_distance` \[m\] of the path is of
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
        let (t, q, d2) = onto_segment(p, a, b);
        (i, t, q, d2)
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
        let steps = ceil_index(window / spacing);
        // Walks stay within a few segments of [0, n): wrap by comparison, not by an integer
        // division per segment (a third of a lane position's time on a big map).
        let wrap = |i: isize| {
            if (0..n).contains(&i) {
                Some(i)
            } else if self.closed {
                Some(i.rem_euclid(n))
            } else {
                None
            }
        };
        let start = floor_index(hint / spacing);
        let start = if self.closed { start } else { start.clamp(0, n - 1) };
        let mut best = self.to_segment(p, wrap(start)?);
        if steps < 1 {
            return None;
        }
        // Both neighbours at once: three independent projections instead of a chain of
        // dependent ones (each waits on a division), the same choice as walking forward first.
        let next = wrap(start + 1).map(|i| self.to_segment(p, i));
        let previous = wrap(start - 1).map(|i| self.to_segment(p, i));
        let dir = match (next, previous) {
            (Some(c), _) if c.3 < best.3 => {
                best = c;
                1
            }
            (_, Some(c)) if c.3 < best.3 => {
                best = c;
                -1
            }
            _ => return Some(best),
        };
        // Walk on while the segments come nearer.
        let mut k = start + dir;
        loop {
            k += dir;
            if (k - start).abs() > steps {
                return None;
            }
            let Some(i) = wrap(k) else { break };
            let c = self.to_segment(p, i);
            if c.3 < best.3 {
                best = c;
            } else {
                break;
            }
        }
        Some(best)
    }

    /// Where `p` lies near arc length `hint` \[m\] on a smooth path, when within `max_distance`
    /// \[m\] of it: arc length \[m\], nearest point \[m\], signed lateral offset \[m\] and the path's
    /// unit direction there (no trigonometry). Walks from `hint` to the nearest segment (the
    /// nearest within `window` \[m\] when the distance has one minimum there, as along a lane's
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
        let lateral = lateral_of(p, a, b, d2);
        Some(((i as f64 + t) * self.spacing(), q, lateral, (b - a).try_normalize().unwrap_or(DVec2::X)))
    }

    /// First segment and segment count of the window of `window` [m] either side of `hint` [m]
    /// (the whole path when the window covers it).
    fn window(&self, hint: f64, window: f64) -> (isize, usize) {
        let spacing = self.spacing();
        let all = (0, self.segment_count());
        if self.segment_count() == 0 || spacing <= 0.0 {
            return all;
        }
        let half = ceil_index(window / spacing) + 1;
        let centre = floor_index(hint / spacing);
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

    /// Nearest point to `p` within `window` \[m\] either side of arc length `hint` (O(window)):
    /// what a path follower calls every tick with its last projection as the hint.
    pub fn project_near(&self, p: DVec2, hint: f64, window: f64) -> PathProjection {
        if self.segment_count() == 0 {
            return self.project(p);
        }
        let (from, count) = self.window(hint, window);
        self.project_segments(p, from, count)
    }

    /// Arc length \[m\] and signed lateral offset \[m\] of [`Path::project_near`]'s projection, the
    /// same numbers without its heading and direction (an `atan2`, a square root and a division
    /// that a path follower, calling this every tick, never reads).
    pub fn locate_near(&self, p: DVec2, hint: f64, window: f64) -> (f64, f64) {
        if self.segment_count() == 0 {
            let q = self.project(p);
            return (q.s, q.lateral);
        }
        let (from, count) = self.window(hint, window);
        match self.nearest(p, from, count, f64::INFINITY) {
            Some((i, t, _, d2)) => ((i as f64 + t) * self.spacing(), self.lateral(p, i, d2)),
            None => (0.0, f64::INFINITY),
        }
    }

    /// [`Path::locate_near`] found by walking from `hint` to the nearest segment (`Path::walk`:
    /// two or three segments for a vehicle that moved a little along a smooth path, instead of
    /// every segment of the window), the window searched only when the walk reaches its edge.
    /// The same as `locate_near` wherever the distance to the path has one minimum in the
    /// window; where it has several (a hairpin within the window), the minimum nearest the
    /// hint, which is where a vehicle that was at `hint` is.
    pub fn locate_walking(&self, p: DVec2, hint: f64, window: f64) -> (f64, f64) {
        match self.walk(p, hint, window) {
            Some((i, t, _, d2)) => ((i as f64 + t) * self.spacing(), self.lateral(p, i, d2)),
            None => self.locate_near(p, hint, window),
        }
    }

    /// Signed distance [m] of `p` at squared distance `d2` from segment `i`: positive left of it.
    fn lateral(&self, p: DVec2, i: isize, d2: f64) -> f64 {
        let (a, b) = self.segment(i as usize);
        lateral_of(p, a, b, d2)
    }
}

/// Lanes of the four-wide passes: points a [`walk_four`] places at once, vehicles the path
/// following, the lane positions and the kinematic steps take at once.
pub(crate) const LANES: usize = 4;

/// `[f(0), f(1), f(2), f(3)]`, written out: `std::array::from_fn` in the four-wide passes was
/// left as a call (perf: the five route segments loaded through it, written to the stack by the
/// call and read back in 32-byte loads that could not be forwarded from its smaller stores,
/// were 15 % of the path following's samples).
#[inline(always)]
pub(crate) fn per_lane<T>(mut f: impl FnMut(usize) -> T) -> [T; LANES] {
    [f(0), f(1), f(2), f(3)]
}

/// The groups of [`LANES`] consecutive places of `0..n` (the last one shorter when `n` is not a
/// multiple of it): how a four-wide pass goes through its chunk, each group four at once or,
/// where it cannot, one at a time.
pub(crate) fn groups_of_four(n: usize) -> impl Iterator<Item = std::ops::Range<usize>> {
    (0..n).step_by(LANES).map(move |k| k..(k + LANES).min(n))
}

/// Where [`walk_four`] placed four points.
pub(crate) struct Walked {
    /// Arc length of each point's nearest path point [m].
    pub s: [f64; LANES],
    /// Signed lateral offset [m], positive left of the path.
    pub lateral: [f64; LANES],
}

/// [`Path::walk`] (then [`Path::locate_walking`]'s arc length and lateral offset) for four
/// points at once, each on its own path, when all four take the walk's common path: the
/// segment at the hint and the two either side all within the path (no wrapping, no edge of
/// the window reached), and the walk ending on the segment at the hint or one step from it.
/// Then the same bits as four walks (the same operations in the same order, lane by lane; the
/// projections are [`onto_segment`] and [`lateral_of`]), else `None`.
///
/// A walk is a chain of divisions (the hint's segment, then a projection on each segment
/// looked at); inside a [`crate::sim::grid::Pass`] run with AVX2 the four points share each
/// division. Used by the path following and the lane positions, which walk every vehicle every
/// control tick.
#[inline(always)]
pub(crate) fn walk_four(
    paths: [&Path; LANES],
    p: [DVec2; LANES],
    hint: [f64; LANES],
    window: [f64; LANES],
) -> Option<Walked> {
    let spacing: [f64; LANES] = per_lane(|l| paths[l].spacing());
    let (mut steps, mut from) = ([0.0; LANES], [0.0; LANES]);
    for l in 0..LANES {
        steps[l] = window[l] / spacing[l];
        from[l] = hint[l] / spacing[l];
    }
    // The walk's segments: the one at the hint and two either side, none wrapping.
    let mut segments = [[(DVec2::ZERO, DVec2::ZERO); 5]; LANES];
    // The candidate segments' numbers as floats, converted here: vector code has no
    // instruction for 64-bit integers to floats.
    let (mut numbers, mut far) = ([[0.0; 3]; LANES], [false; LANES]);
    for l in 0..LANES {
        let (path, n) = (paths[l], paths[l].segment_count() as isize);
        // Five segments at least (else no hint has two either side), checked before the clamp
        // to 0..n, which an empty path would not allow.
        let walks = n >= 5 && spacing[l] > 0.0 && hint[l].is_finite() && ceil_index(steps[l]) >= 1;
        if !walks {
            return None;
        }
        let i = floor_index(from[l]);
        let i = if path.closed { i } else { i.clamp(0, n - 1) };
        if !(i >= 2 && i + 2 < n) {
            return None;
        }
        // A step to a neighbour goes on to the next one only within the window.
        far[l] = ceil_index(steps[l]) >= 2;
        numbers[l] = [(i - 1) as f64, i as f64, (i + 1) as f64];
        let b = (i - 2) as usize;
        segments[l] = match path.points.get(b..b + 6) {
            // The six points in a row (all but the segment closing a loop): one bounds check
            // instead of two and a wrap test per point (a fifth of the lane positions' samples).
            Some(&[p0, p1, p2, p3, p4, p5]) => [(p0, p1), (p1, p2), (p2, p3), (p3, p4), (p4, p5)],
            _ => [path.segment(b), path.segment(b + 1), path.segment(b + 2), path.segment(b + 3), path.segment(b + 4)],
        };
    }
    let mut out = Walked { s: [0.0; LANES], lateral: [0.0; LANES] };
    let mut walked = [true; LANES];
    for l in 0..LANES {
        let p = p[l];
        let [back2, back, this, next, next2] = segments[l];
        let (t, _, d2) = onto_segment(p, this.0, this.1);
        let (next_t, _, next_d2) = onto_segment(p, next.0, next.1);
        let (back_t, _, back_d2) = onto_segment(p, back.0, back.1);
        let (_, _, next2_d2) = onto_segment(p, next2.0, next2.1);
        let (_, _, back2_d2) = onto_segment(p, back2.0, back2.1);
        // `Path::walk`: the next segment if nearer, else the previous one if nearer, else this
        // one; from a neighbour the walk goes on while the segments come nearer (here: not).
        let forward = next_d2 < d2;
        let backward = !forward & (back_d2 < d2);
        let (on_forward, on_backward) = (next2_d2 < next_d2, back2_d2 < back_d2);
        walked[l] = (!forward | (far[l] & !on_forward)) & (!backward | (far[l] & !on_backward));
        let [before, at, after] = numbers[l];
        let (i, t, d2, (a, b)) = if forward {
            (after, next_t, next_d2, next)
        } else if backward {
            (before, back_t, back_d2, back)
        } else {
            (at, t, d2, this)
        };
        out.s[l] = (i + t) * spacing[l];
        out.lateral[l] = lateral_of(p, a, b, d2);
    }
    (walked == [true; LANES]).then_some(out)
}

/// The nearest point to `p` of the segment from `a` to `b`: (how far along it, 0..1; the
/// point; its squared distance to `p`). Every projection on a [`Path`] goes through here, the
/// four-at-a-time path following too, so all give the same bits.
#[inline(always)]
pub(crate) fn onto_segment(p: DVec2, a: DVec2, b: DVec2) -> (f64, DVec2, f64) {
    let d = b - a;
    let len2 = d.length_squared();
    let t = if len2 > 0.0 { ((p - a).dot(d) / len2).clamp(0.0, 1.0) } else { 0.0 };
    let q = a + d * t;
    (t, q, p.distance_squared(q))
}

/// Signed distance [m] of `p`, at squared distance `d2` from the segment `a`→`b`: positive left.
#[inline(always)]
pub(crate) fn lateral_of(p: DVec2, a: DVec2, b: DVec2, d2: f64) -> f64 {
    let d = b - a;
    let cross = d.x * (p - a).y - d.y * (p - a).x;
    d2.sqrt() * if cross >= 0.0 { 1.0 } else { -1.0 }
}

/// The point a share `(s - i·spacing) / spacing` (clamped to 0..1) along the segment `a`→`b`
/// (the `i`th of a path of that spacing, `i` given as a float) and the segment's vector:
/// [`Path::sample_direction`]'s last step, shared with the four-at-a-time path following.
#[inline(always)]
pub(crate) fn along_segment(s: f64, i: f64, spacing: f64, a: DVec2, b: DVec2) -> (DVec2, DVec2) {
    let t = ((s - i * spacing) / spacing).clamp(0.0, 1.0);
    let d = b - a;
    (a + d * t, d)
}

/// `s.rem_euclid(length)` (for `length` > 0), without the library `fmod` call for the arc
/// lengths a follower asks, which lie less than one lap outside `[0, length)`: there the
/// subtraction or addition of one lap is exact (Sterbenz) and is what `rem_euclid` gives.
#[inline]
fn wrap_length(s: f64, length: f64) -> f64 {
    if (0.0..length).contains(&s) {
        s
    } else if s >= length && s < 2.0 * length {
        s - length
    } else if s < 0.0 && s > -length {
        s + length
    } else {
        s.rem_euclid(length)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_point_near_an_arc_length_is_the_sampled_segment_within_one() {
        // Spacings that are not powers of two (so the inverse rounds), a loop and an open path.
        for (n, length, closed) in [(700, 1000.0, true), (333, 137.5, false), (2, 3.0, false)] {
            let points: Vec<DVec2> =
                (0..n).map(|k| DVec2::new(k as f64 * length / (n - usize::from(!closed)) as f64, 0.0)).collect();
            let path = Path::from_points(Vec::new(), points, closed);
            let last = path.points.len() - 1;
            for k in 0..4000 {
                let s = length * k as f64 / 3999.0;
                let exact = ((s / path.spacing()) as usize).min(last);
                let near = path.segment_near(s);
                assert!(near.abs_diff(exact) <= 1, "n {n}, s {s}: {near} against {exact}");
            }
            assert_eq!(path.segment_near(2.0 * length), last);
            assert_eq!(path.segment_near(-5.0), 0);
            assert_eq!(path.segment_near(f64::NAN), 0);
            assert_eq!(path.segment_near(f64::INFINITY), last);
        }
        assert_eq!(Path::from_points(Vec::new(), vec![DVec2::ZERO], false).segment_near(1.0), 0, "no segment");
    }

    #[test]
    fn wrapping_an_arc_length_is_rem_euclid_to_the_bit() {
        let lengths = [1.0, 0.3, 133_392.771_040_226_5, 1e-300, 7.25];
        for length in lengths {
            let mut xs: Vec<f64> = (-4000..4000).map(|k| k as f64 * length / 997.0).collect();
            xs.extend([0.0, -0.0, length, -length, 2.0 * length, -2.0 * length, 3.0 * length]);
            xs.extend([length.next_down(), length.next_up(), (2.0 * length).next_down(), (-length).next_up()]);
            xs.extend([f64::NAN, f64::INFINITY, f64::NEG_INFINITY, 1e300, -1e300, f64::MIN_POSITIVE]);
            for s in xs {
                let (got, want) = (wrap_length(s, length), s.rem_euclid(length));
                assert!(
                    got.to_bits() == want.to_bits() || got.is_nan() && want.is_nan(),
                    "{s} mod {length}: {got} vs {want}"
                );
            }
        }
    }

    #[test]
    fn index_rounding_matches_floor_and_ceil() {
        let mut xs = vec![0.0, -0.0, 0.5, -0.5, 1.0, -1.0, 2.999_999, -2.999_999, 1e-300, -1e-300, 1e300, -1e300];
        xs.extend([f64::NAN, f64::INFINITY, f64::NEG_INFINITY, 9.3e18, -9.3e18, 4_503_599_627_370_495.5]);
        xs.extend((0..2000).map(|k| (k as f64 - 1000.0) * 0.37));
        for x in xs {
            assert_eq!(floor_index(x), x.floor() as isize, "floor of {x}");
            assert_eq!(ceil_index(x), x.ceil() as isize, "ceil of {x}");
        }
    }

    /// The walk as it was before it projected on both neighbours at once: forward first, then
    /// backward, one dependent projection after another.
    fn walk_one_by_one(path: &Path, p: DVec2, hint: f64, window: f64) -> Option<(isize, f64, DVec2, f64)> {
        let n = path.segment_count() as isize;
        let spacing = path.spacing();
        if n == 0 || spacing <= 0.0 || !hint.is_finite() {
            return None;
        }
        let steps = (window / spacing).ceil() as isize;
        let wrap = |i: isize| if path.closed { Some(i.rem_euclid(n)) } else { (0..n).contains(&i).then_some(i) };
        let start = (hint / spacing).floor() as isize;
        let start = if path.closed { start } else { start.clamp(0, n - 1) };
        let mut best = path.to_segment(p, wrap(start)?);
        for dir in [1, -1] {
            let mut k = start;
            let mut moved = false;
            loop {
                k += dir;
                if (k - start).abs() > steps {
                    return None;
                }
                let Some(i) = wrap(k) else { break };
                let c = path.to_segment(p, i);
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

    #[test]
    fn four_walks_on_paths_too_short_to_walk_give_way_to_the_one_by_one_walk() {
        // An empty path, one point, and too few segments for two either side of the hint:
        // `walk_four` leaves them to `Path::walk` (it clamped an empty open path's segment
        // number to 0..-1 before it checked its length, which panics).
        let long = Path::from_points(Vec::new(), (0..50).map(|k| DVec2::new(k as f64, 0.0)).collect(), false);
        let short: Vec<Path> = [0, 1, 2, 5]
            .iter()
            .map(|&n| Path::from_points(Vec::new(), (0..n).map(|k| DVec2::new(k as f64, 0.0)).collect(), false))
            .collect();
        let (p, hint, window) = ([DVec2::new(20.5, 0.5); LANES], [20.0; LANES], [2.0; LANES]);
        assert!(walk_four([&long; LANES], p, hint, window).is_some());
        for path in &short {
            let paths = [&long, path, &long, &long];
            assert!(walk_four(paths, p, hint, window).is_none(), "{} points", path.points.len());
        }
    }

    #[test]
    fn four_walks_give_the_one_walks_bits_all_round_a_loop_and_along_an_open_path() {
        // Every segment of a loop as the hint's, the segments closing the loop included (their
        // points are not in a row in memory), and of an open path up to its ends; points off
        // the path at either side, four different ones at once.
        let circle: Vec<DVec2> =
            (0..90).map(|k| DVec2::from_angle(k as f64 * std::f64::consts::TAU / 90.0) * 15.0).collect();
        let wavy: Vec<DVec2> = (0..90).map(|k| DVec2::new(k as f64 * 0.9, (k as f64 * 0.3).sin())).collect();
        let paths = [Path::from_points(Vec::new(), circle, true), Path::from_points(Vec::new(), wavy, false)];
        let (mut walked, mut closing_walked) = ([0usize; 2], false);
        for (c, path) in paths.iter().enumerate() {
            let n = path.segment_count();
            for i in 0..n {
                let at = |l: usize| (i as f64 + 0.2 * l as f64 + 0.05) * path.spacing();
                let p: [DVec2; LANES] = per_lane(|l| {
                    let (q, heading) = path.sample(at(l));
                    q + DVec2::from_angle(heading + std::f64::consts::FRAC_PI_2) * (l as f64 - 1.5) * 0.3
                });
                // Hints on the point's segment, and behind it (the walk steps on, and whether
                // it goes on past the next segment is read from the one after).
                for behind in [-0.1, 0.9, 1.6] {
                    let hint: [f64; LANES] = per_lane(|l| at(l) - behind * path.spacing());
                    let window = [2.5 * path.spacing(); LANES];
                    let Some(got) = walk_four([path; LANES], p, hint, window) else { continue };
                    for l in 0..LANES {
                        let want = path.locate_walking(p[l], hint[l], window[l]);
                        assert_eq!(
                            (got.s[l].to_bits(), got.lateral[l].to_bits()),
                            (want.0.to_bits(), want.1.to_bits()),
                            "segment {i} of {n}, lane {l}, {behind} behind, closed {}",
                            path.closed
                        );
                    }
                    walked[c] += 1;
                    // The hint's segment three before a loop's end: its walk reads the closing one.
                    closing_walked |= path.closed && i + 3 == n && behind < 0.0;
                }
            }
        }
        assert!(walked[0] > 150 && walked[1] > 150, "walked {walked:?}");
        assert!(closing_walked, "no walk read the segment closing the loop");
    }

    #[test]
    fn the_walk_finds_what_the_one_by_one_walk_found() {
        // A wavy open path and a closed circle, points off them at every side, hints off by up
        // to a few segments, windows narrower and wider than the offset.
        let wavy: Vec<DVec2> = (0..200).map(|k| DVec2::new(k as f64 * 0.7, (k as f64 * 0.2).sin() * 3.0)).collect();
        let circle: Vec<DVec2> =
            (0..150).map(|k| DVec2::from_angle(k as f64 * std::f64::consts::TAU / 150.0) * 20.0).collect();
        let paths = [Path::from_points(Vec::new(), wavy, false), Path::from_points(Vec::new(), circle, true)];
        let mut compared = 0;
        for path in &paths {
            for k in 0..3000 {
                let s = (k as f64 * 0.618_033_988_7).fract() * path.length * 1.1 - 0.05 * path.length;
                let (q, heading) = path.sample(s);
                let side = ((k % 7) as f64 - 3.0) * 0.8;
                let p = q + DVec2::from_angle(heading + std::f64::consts::FRAC_PI_2) * side;
                let hint = s + ((k % 11) as f64 - 5.0) * 0.6;
                for window in [0.0, 0.5, 2.0, 6.0] {
                    let want = walk_one_by_one(path, p, hint, window);
                    let got = path.walk(p, hint, window);
                    assert_eq!(
                        got.map(|g| (g.0, g.1.to_bits(), g.3.to_bits())),
                        want.map(|w| (w.0, w.1.to_bits(), w.3.to_bits())),
                        "s {s}, hint {hint}, window {window}, closed {}",
                        path.closed
                    );
                    compared += usize::from(want.is_some());
                }
            }
        }
        assert!(compared > 10_000, "only {compared} walks found a segment");
    }

    #[test]
    fn a_follower_walking_to_its_place_finds_what_the_window_search_finds_on_a_smooth_path() {
        // A lane-like loop (radius 200 m, 2 m segments): the distance has one minimum near any
        // vehicle close to it, so walking gives locate_near's bits.
        let circle: Vec<DVec2> =
            (0..628).map(|k| DVec2::from_angle(k as f64 * std::f64::consts::TAU / 628.0) * 200.0).collect();
        let path = Path::from_points(Vec::new(), circle, true);
        let mut walked = 0;
        for k in 0..5000 {
            let s = (k as f64 * 0.618_033_988_7).fract() * path.length * 1.1 - 0.05 * path.length;
            let (q, heading) = path.sample(s);
            let p = q + DVec2::from_angle(heading + std::f64::consts::FRAC_PI_2) * (((k % 9) as f64 - 4.0) * 0.4);
            for (hint, window) in [(s + 0.7, 3.0), (s - 1.9, 3.0), (s, 0.5), (s + 9.0, 3.0), (f64::NAN, 2.0)] {
                let want = path.locate_near(p, hint, window);
                let got = path.locate_walking(p, hint, window);
                assert_eq!(
                    (got.0.to_bits(), got.1.to_bits()),
                    (want.0.to_bits(), want.1.to_bits()),
                    "s {s}, hint {hint}"
                );
                walked += usize::from(path.walk(p, hint, window).is_some());
            }
        }
        assert!(walked > 12_000, "only {walked} walks ended inside the window");
        // A hairpin: two legs 1 m apart. A vehicle on the lower leg near its end stays on it,
        // where the window search takes the nearer point of the upper leg.
        let mut hairpin: Vec<DVec2> = (0..=20).map(|k| DVec2::new(k as f64, 0.0)).collect();
        hairpin.extend((0..=20).rev().map(|k| DVec2::new(k as f64, 1.0)));
        let path = Path::from_points(Vec::new(), hairpin, false);
        let p = DVec2::new(10.0, 0.6);
        let (s_near, _) = path.locate_near(p, 10.0, 30.0);
        let (s_walk, lateral) = path.locate_walking(p, 10.0, 30.0);
        assert!(
            (s_walk - 10.0).abs() < 1e-9 && (lateral - 0.6).abs() < 1e-9,
            "walked to s {s_walk}, lateral {lateral}"
        );
        assert!(s_near > 25.0, "the window search took s {s_near}");
    }

    #[test]
    fn locate_near_and_sample_point_give_project_near_and_sample_to_the_bit() {
        let wavy: Vec<DVec2> = (0..200).map(|k| DVec2::new(k as f64 * 0.7, (k as f64 * 0.2).sin() * 3.0)).collect();
        let circle: Vec<DVec2> =
            (0..150).map(|k| DVec2::from_angle(k as f64 * std::f64::consts::TAU / 150.0) * 20.0).collect();
        let paths = [
            Path::from_points(Vec::new(), wavy, false),
            Path::from_points(Vec::new(), circle, true),
            Path::from_points(Vec::new(), vec![DVec2::new(1.0, 2.0)], false),
        ];
        let mut left = 0;
        for path in &paths {
            for k in 0..2000 {
                let s = (k as f64 * 0.618_033_988_7).fract() * path.length * 1.2 - 0.1 * path.length;
                let (q, heading) = path.sample(s);
                assert_eq!(path.sample_point(s), q, "s {s}");
                let p = q + DVec2::from_angle(heading + std::f64::consts::FRAC_PI_2) * (((k % 9) as f64 - 4.0) * 0.7);
                for (hint, window) in [(s, 1.0), (s + 3.0, 0.5), (s - 10.0, 4.0), (f64::NAN, 2.0)] {
                    let want = path.project_near(p, hint, window);
                    let (got_s, got_lateral) = path.locate_near(p, hint, window);
                    assert_eq!((got_s.to_bits(), got_lateral.to_bits()), (want.s.to_bits(), want.lateral.to_bits()));
                    left += usize::from(want.lateral > 0.0);
                }
            }
        }
        assert!(left > 1000, "too few points left of the paths: {left}");
    }
}

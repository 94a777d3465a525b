//! Geometry checks of lanelet bounds at load time: what XML and ids allow but no road looks like
//! (both bounds one way, a bound of one point, repeated nodes, a bound crossing itself, one
//! bound far longer than the other: a misplaced node). Each finding is a warning naming the
//! lanelet, the way and, where one is to blame, the node; the loader skips the lanelets that
//! cannot be driven at all.

use glam::DVec2;

use super::lanelet::MapWay;

/// Shorter than this a bound is "all its nodes at one place" [m].
const DEGENERATE_LENGTH: f64 = 0.01;
/// A lanelet whose longer bound is this many times its shorter one (and longer by at least
/// [`MISMATCH_MIN_DIFFERENCE`]) is reported: lanes do not do that, misplaced nodes do [-].
const MISMATCH_RATIO: f64 = 3.0;
/// See [`MISMATCH_RATIO`] [m]: real maps have lanelets whose bounds differ by ~100 m (Lanelet2's
/// example has 126 m beside 24 m); a misplaced coordinate is off by kilometres.
const MISMATCH_MIN_DIFFERENCE: f64 = 500.0;

/// Why a lanelet cannot be driven at all (the loader skips it), if so. Each bound comes with
/// the length of its polyline [m] (the loader computes it once per way).
pub(crate) fn unusable(lanelet: i64, left: (&MapWay, f64), right: (&MapWay, f64)) -> Option<String> {
    if left.0.id == right.0.id {
        return Some(format!(
            "lanelet {lanelet}: its left and right bounds are the same way {}; skipped (a lane needs two bounds)",
            left.0.id
        ));
    }
    for (way, length) in [left, right] {
        if length < DEGENERATE_LENGTH {
            return Some(format!(
                "lanelet {lanelet}: bound way {} has zero length (all its nodes at one place); skipped",
                way.id
            ));
        }
    }
    None
}

/// Problems of one bound way that still let it be used: the same node (or the same place)
/// twice in a row, and a bound that crosses itself.
pub(crate) fn way_problems(way: &MapWay) -> Vec<String> {
    let mut out = Vec::new();
    for i in 1..way.nodes.len() {
        if way.nodes[i] == way.nodes[i - 1] {
            out.push(format!("way {} repeats node {} (twice in a row)", way.id, way.nodes[i]));
        } else if way.points[i].distance(way.points[i - 1]) < 1e-6 {
            out.push(format!(
                "way {}: nodes {} and {} lie at one place (a duplicated node?)",
                way.id,
                way.nodes[i - 1],
                way.nodes[i]
            ));
        }
    }
    if let Some(node) = self_crossing(way) {
        out.push(format!(
            "way {} crosses itself near node {node}; a lane bound must not loop over itself (check the node order)",
            way.id
        ));
    }
    out
}

/// A bound far longer than the other: names the node of the longer bound farthest from the
/// shorter one (the misplaced one, e.g. a latitude typo). Each bound comes with its length [m].
pub(crate) fn length_mismatch(lanelet: i64, left: (&MapWay, f64), right: (&MapWay, f64)) -> Option<String> {
    let ((left, l), (right, r)) = (left, right);
    let (long, short, long_len, short_len) = if l >= r { (left, right, l, r) } else { (right, left, r, l) };
    if long_len < MISMATCH_RATIO * short_len || long_len - short_len < MISMATCH_MIN_DIFFERENCE {
        return None;
    }
    let (node, far) = long
        .nodes
        .iter()
        .zip(&long.points)
        .map(|(&n, &p)| (n, distance_to_polyline(p, &short.points)))
        .fold((long.nodes[0], f64::NEG_INFINITY), |best, x| if x.1 > best.1 { x } else { best });
    Some(format!(
        "lanelet {lanelet}: bound way {} is {long_len:.1} m long but way {} only {short_len:.1} m; node {node} lies {far:.0} m from the other bound (misplaced? check its lat/lon)",
        long.id, short.id
    ))
}

fn distance_to_polyline(p: DVec2, line: &[DVec2]) -> f64 {
    if line.len() == 1 {
        return p.distance(line[0]);
    }
    line.windows(2)
        .map(|w| {
            let d = w[1] - w[0];
            let t =
                if d.length_squared() > 0.0 { ((p - w[0]).dot(d) / d.length_squared()).clamp(0.0, 1.0) } else { 0.0 };
            p.distance(w[0] + d * t)
        })
        .fold(f64::INFINITY, f64::min)
}

/// The first node at which `way` crosses one of its own earlier segments (segments that share
/// an end, including a closed way's first and last, do not count). O(n²) with a bounding-box
/// test; bounds have tens to hundreds of nodes. A way whose x or y only rises or only falls
/// (a straight street, a quarter circle: most bounds) is answered at once: the bounding boxes
/// of its segments that share no end lie apart, so the test below would reject every pair.
fn self_crossing(way: &MapWay) -> Option<i64> {
    let p = &way.points;
    let n = p.len();
    if n < 4 {
        return None;
    }
    let monotone = |coord: fn(&DVec2) -> f64| {
        p.windows(2).all(|w| coord(&w[0]) < coord(&w[1])) || p.windows(2).all(|w| coord(&w[0]) > coord(&w[1]))
    };
    if monotone(|q| q.x) || monotone(|q| q.y) {
        return None;
    }
    let closed = way.nodes.first() == way.nodes.last();
    for j in 2..n - 1 {
        for i in 0..j - 1 {
            if closed && i == 0 && j == n - 2 {
                continue;
            }
            if segments_cross(p[i], p[i + 1], p[j], p[j + 1]) {
                return Some(way.nodes[j]);
            }
        }
    }
    None
}

/// Whether segments ab and cd cross at a point inside both (touching ends do not count).
fn segments_cross(a: DVec2, b: DVec2, c: DVec2, d: DVec2) -> bool {
    if a.x.max(b.x) < c.x.min(d.x)
        || c.x.max(d.x) < a.x.min(b.x)
        || a.y.max(b.y) < c.y.min(d.y)
        || c.y.max(d.y) < a.y.min(b.y)
    {
        return false;
    }
    let cross = |o: DVec2, p: DVec2, q: DVec2| (p - o).perp_dot(q - o);
    let (d1, d2) = (cross(a, b, c), cross(a, b, d));
    let (d3, d4) = (cross(c, d, a), cross(c, d, b));
    d1 * d2 < 0.0 && d3 * d4 < 0.0
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::polyline::polyline_length;

    fn way(id: i64, pts: &[(f64, f64)]) -> MapWay {
        MapWay {
            id,
            nodes: (1..=pts.len() as i64).collect(),
            points: pts.iter().map(|&(x, y)| DVec2::new(x, y)).collect(),
            tags: Default::default(),
        }
    }

    #[test]
    fn a_figure_eight_crosses_itself_and_a_zigzag_does_not() {
        let eight = way(1, &[(0.0, 0.0), (10.0, 10.0), (10.0, 0.0), (0.0, 10.0)]);
        assert_eq!(self_crossing(&eight), Some(3));
        let zigzag = way(2, &[(0.0, 0.0), (10.0, 1.0), (20.0, 0.0), (30.0, 1.0), (40.0, 0.0)]);
        assert_eq!(self_crossing(&zigzag), None);
        let square = way(3, &[(0.0, 0.0), (10.0, 0.0), (10.0, 10.0), (0.0, 10.0), (0.0, 0.0)]);
        assert_eq!(self_crossing(&MapWay { nodes: vec![1, 2, 3, 4, 1], ..square }), None, "closed, not crossing");
    }

    #[test]
    fn a_way_rising_in_x_or_y_never_crosses_itself() {
        // Rising x, wildly zigzagging y: the shortcut answers, and the pairwise test agrees.
        let zigzag: Vec<(f64, f64)> = (0..40).map(|i| (i as f64, if i % 2 == 0 { 0.0 } else { 100.0 })).collect();
        assert_eq!(self_crossing(&way(4, &zigzag)), None);
        // Rising y, x going back and forth so far that segments overlap in x: still no crossing.
        let spiral: Vec<(f64, f64)> = (0..40).map(|i| (if i % 2 == 0 { -50.0 } else { 50.0 }, i as f64)).collect();
        assert_eq!(self_crossing(&way(5, &spiral)), None);
        // A loop that rises in neither crosses itself and is found.
        let knot = way(6, &[(0.0, 0.0), (10.0, 0.0), (10.0, 10.0), (5.0, -5.0)]);
        assert_eq!(self_crossing(&knot), Some(3));
    }

    #[test]
    fn a_misplaced_node_is_named_and_a_curve_is_not() {
        let left = way(10, &[(0.0, 3.5), (50.0, 3.5), (100.0, 3.5)]);
        let mut right = way(11, &[(0.0, 0.0), (50.0, 0.0), (100.0, 0.0)]);
        let with_length = |w: &MapWay| (w.clone(), polyline_length(&w.points));
        let ((left, l), (r, rl)) = (with_length(&left), with_length(&right));
        assert_eq!(length_mismatch(7, (&left, l), (&r, rl)), None);
        right.points[1] = DVec2::new(50.0, 99_000.0);
        let (right, rl) = with_length(&right);
        let m = length_mismatch(7, (&left, l), (&right, rl)).expect("reported");
        assert!(m.contains("lanelet 7") && m.contains("way 11") && m.contains("node 2"), "{m}");
    }
}

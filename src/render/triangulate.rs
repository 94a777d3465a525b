//! Ear-clipping triangulation of simple polygons (convex or not, either orientation).

use glam::DVec2;

fn cross(o: DVec2, a: DVec2, b: DVec2) -> f64 {
    (a - o).perp_dot(b - o)
}

/// Twice the signed area; positive for counter-clockwise.
fn signed_area2(points: &[DVec2], idx: &[usize]) -> f64 {
    let n = idx.len();
    (0..n).map(|i| points[idx[i]].perp_dot(points[idx[(i + 1) % n]])).sum()
}

fn inside_or_on(p: DVec2, a: DVec2, b: DVec2, c: DVec2) -> bool {
    cross(a, b, p) >= 0.0 && cross(b, c, p) >= 0.0 && cross(c, a, p) >= 0.0
}

/// Triangles (indices into `points`) covering a simple polygon. A repeated closing point and
/// consecutive duplicates are ignored; fewer than 3 distinct points give no triangles. When no ear
/// exists (a self-intersecting or degenerate outline) the most convex vertex is clipped anyway,
/// so the result is always finite and at most `n - 2` triangles: bad input draws oddly, never hangs.
pub fn triangulate(points: &[DVec2]) -> Vec<[usize; 3]> {
    let mut idx: Vec<usize> = Vec::with_capacity(points.len());
    for (i, p) in points.iter().enumerate() {
        if !(p.x.is_finite() && p.y.is_finite()) {
            continue;
        }
        if idx.last().is_none_or(|&j| points[j] != *p) {
            idx.push(i);
        }
    }
    while idx.len() > 1 && points[idx[0]] == points[idx[idx.len() - 1]] {
        idx.pop();
    }
    let mut out = Vec::with_capacity(idx.len().saturating_sub(2));
    if idx.len() < 3 {
        return out;
    }
    if signed_area2(points, &idx) < 0.0 {
        idx.reverse();
    }
    while idx.len() > 3 {
        let n = idx.len();
        let mut ear = None;
        let mut best = (f64::NEG_INFINITY, 0);
        for i in 0..n {
            let (ia, ib, ic) = (idx[(i + n - 1) % n], idx[i], idx[(i + 1) % n]);
            let (a, b, c) = (points[ia], points[ib], points[ic]);
            let turn = cross(a, b, c);
            if turn > best.0 {
                best = (turn, i);
            }
            if turn <= 0.0 {
                continue;
            }
            let blocked = idx.iter().any(|&j| {
                j != ia
                    && j != ib
                    && j != ic
                    && points[j] != a
                    && points[j] != b
                    && points[j] != c
                    && inside_or_on(points[j], a, b, c)
            });
            if !blocked {
                ear = Some(i);
                break;
            }
        }
        let i = ear.unwrap_or(best.1);
        out.push([idx[(i + n - 1) % n], idx[i], idx[(i + 1) % n]]);
        idx.remove(i);
    }
    out.push([idx[0], idx[1], idx[2]]);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn area(points: &[DVec2], tris: &[[usize; 3]]) -> f64 {
        tris.iter().map(|t| 0.5 * cross(points[t[0]], points[t[1]], points[t[2]]).abs()).sum()
    }

    #[test]
    fn square_is_two_triangles_of_total_area() {
        let sq = [DVec2::new(0.0, 0.0), DVec2::new(2.0, 0.0), DVec2::new(2.0, 3.0), DVec2::new(0.0, 3.0)];
        let t = triangulate(&sq);
        assert_eq!(t.len(), 2);
        assert!((area(&sq, &t) - 6.0).abs() < 1e-12);
    }

    #[test]
    fn non_convex_u_shape_keeps_its_area_and_orientation_does_not_matter() {
        // A U: 3x3 square minus the 1x2 notch at the top middle -> area 9 - 2 = 7.
        let u = [
            DVec2::new(0.0, 0.0),
            DVec2::new(3.0, 0.0),
            DVec2::new(3.0, 3.0),
            DVec2::new(2.0, 3.0),
            DVec2::new(2.0, 1.0),
            DVec2::new(1.0, 1.0),
            DVec2::new(1.0, 3.0),
            DVec2::new(0.0, 3.0),
            DVec2::new(0.0, 0.0),
        ];
        let t = triangulate(&u);
        assert_eq!(t.len(), 6);
        assert!((area(&u, &t) - 7.0).abs() < 1e-12);
        let mut rev = u;
        rev.reverse();
        assert!((area(&rev, &triangulate(&rev)) - 7.0).abs() < 1e-12);
        // No triangle covers the notch centre (1.5, 2).
        let notch = DVec2::new(1.5, 2.0);
        for tri in t {
            let [a, b, c] = tri.map(|i| u[i]);
            assert!(!(inside_or_on(notch, a, b, c)), "triangle {tri:?} covers the notch");
        }
    }

    #[test]
    fn degenerate_input_gives_no_or_finite_triangles() {
        assert!(triangulate(&[]).is_empty());
        assert!(triangulate(&[DVec2::ZERO, DVec2::ZERO, DVec2::X]).is_empty());
        let bowtie = [DVec2::new(0.0, 0.0), DVec2::new(1.0, 1.0), DVec2::new(1.0, 0.0), DVec2::new(0.0, 1.0)];
        assert_eq!(triangulate(&bowtie).len(), 2);
    }
}

//! The reference line of an OpenDRIVE road: `line`, `arc`, `spiral` (clothoid), `poly3` and
//! `paramPoly3`, each evaluated at a distance along it to a position and a heading.
//!
//! Formulas follow the ASAM OpenDRIVE 1.8 specification (§9.3-9.7) as esmini (`esmini/esmini`,
//! `RoadManager/RoadManager.cpp`) and libOpenDRIVE (`pageldev/libOpenDRIVE`, `src/Geometries/`)
//! implement them, with two choices of ours:
//! - a spiral is integrated numerically (composite 5-point Gauss-Legendre on pieces short
//!   enough that the heading turns at most 0.1 rad in each), which is accurate to well below a
//!   micrometre on the files' spirals and needs no Fresnel approximation; the unit tests check
//!   it against Fresnel integrals computed by their power series;
//! - `poly3` and `paramPoly3` map arc length to their parameter through a table of cumulative
//!   arc lengths (as libOpenDRIVE's `ParamPoly3` and esmini's `S2P` table do) refined by Newton
//!   steps, so a point `ds` along the geometry is `ds` along the curve. A `paramPoly3` whose
//!   own arc length differs from the `length` attribute is stretched evenly so its end is where
//!   the curve ends.

use glam::DVec2;

/// Nodes and weights of 5-point Gauss-Legendre quadrature on [-1, 1].
const GAUSS: [(f64, f64); 5] = [
    (0.0, 0.568_888_888_888_888_9),
    (-0.538_469_310_105_683_1, 0.478_628_670_499_366_5),
    (0.538_469_310_105_683_1, 0.478_628_670_499_366_5),
    (-0.906_179_845_938_664, 0.236_926_885_056_189_1),
    (0.906_179_845_938_664, 0.236_926_885_056_189_1),
];

/// Integral of `f` over [a, b] with 5-point Gauss-Legendre on `pieces` equal pieces.
fn integrate(a: f64, b: f64, pieces: usize, f: impl Fn(f64) -> DVec2) -> DVec2 {
    let h = (b - a) / pieces as f64;
    let mut sum = DVec2::ZERO;
    for k in 0..pieces {
        let mid = a + (k as f64 + 0.5) * h;
        for (x, w) in GAUSS {
            sum += f(mid + 0.5 * h * x) * w;
        }
    }
    sum * 0.5 * h
}

/// Points of an arc-length table for `poly3`/`paramPoly3` (more for longer curves).
const TABLE_MIN: usize = 64;

/// The shape of one `<geometry>` record.
#[derive(Debug, Clone, PartialEq)]
pub enum Shape {
    /// `<line/>`.
    Line,
    /// `<arc curvature>` [1/m], positive turning left.
    Arc {
        /// Curvature [1/m].
        curvature: f64,
    },
    /// `<spiral curvStart curvEnd>`: curvature changing linearly with distance [1/m].
    Spiral {
        /// Curvature at the start [1/m].
        start: f64,
        /// Curvature at the end [1/m].
        end: f64,
    },
    /// `<poly3>` (v(u) = a + b u + c u² + d u³) or `<paramPoly3>` (u(p), v(p)) in the
    /// geometry's local frame (u along `hdg`, v to its left), with the arc-length table.
    Cubic(Cubic),
}

/// A cubic curve in a geometry's local frame with its arc-length table.
#[derive(Debug, Clone, PartialEq)]
pub struct Cubic {
    /// u(p) coefficients a, b, c, d.
    pub u: [f64; 4],
    /// v(p) coefficients a, b, c, d.
    pub v: [f64; 4],
    /// Parameter values of the table, rising from 0.
    params: Vec<f64>,
    /// Arc length from p = 0 to each parameter value [m].
    lengths: Vec<f64>,
}

fn poly(c: &[f64; 4], p: f64) -> f64 {
    c[0] + p * (c[1] + p * (c[2] + p * c[3]))
}

fn dpoly(c: &[f64; 4], p: f64) -> f64 {
    c[1] + p * (2.0 * c[2] + p * 3.0 * c[3])
}

fn ddpoly(c: &[f64; 4], p: f64) -> f64 {
    2.0 * c[2] + 6.0 * c[3] * p
}

impl Cubic {
    /// A `paramPoly3` over p in [0, `p_end`] (`p_end` = length for `pRange="arcLength"`, 1 for
    /// `normalized`).
    pub fn param(u: [f64; 4], v: [f64; 4], p_end: f64, length: f64) -> Cubic {
        let n = TABLE_MIN.max((length / 2.0).ceil() as usize).min(1 << 16);
        let mut c = Cubic { u, v, params: Vec::with_capacity(n + 1), lengths: Vec::with_capacity(n + 1) };
        c.params.push(0.0);
        c.lengths.push(0.0);
        for k in 1..=n {
            let (a, b) = (p_end * (k - 1) as f64 / n as f64, p_end * k as f64 / n as f64);
            let last = c.lengths[k - 1];
            c.params.push(b);
            c.lengths.push(last + c.arc(a, b));
        }
        c
    }

    /// A `poly3` v(u) = a + b u + c u² + d u³, over u from 0 to where its arc length is `length`.
    pub fn poly3(v: [f64; 4], length: f64) -> Cubic {
        let u = [0.0, 1.0, 0.0, 0.0];
        let n = TABLE_MIN.max((length / 2.0).ceil() as usize).min(1 << 16);
        // u never runs ahead of the arc length, so `length` in steps of `length / n` in u reaches
        // the end; the last step is cut where the arc length is exactly `length`.
        let step = length / n as f64;
        let mut c = Cubic { u, v, params: vec![0.0], lengths: vec![0.0] };
        let mut p = 0.0;
        let mut s = 0.0;
        while s < length {
            let mut next = p + step;
            let mut ds = c.arc(p, next);
            if s + ds > length {
                // Bisect the step so the table ends at `length`.
                let (mut lo, mut hi) = (p, next);
                for _ in 0..60 {
                    let mid = 0.5 * (lo + hi);
                    if s + c.arc(p, mid) > length {
                        hi = mid;
                    } else {
                        lo = mid;
                    }
                }
                next = 0.5 * (lo + hi);
                ds = length - s;
            }
            p = next;
            s += ds;
            c.params.push(p);
            c.lengths.push(s);
            if c.params.len() > (1 << 20) {
                break;
            }
        }
        c
    }

    fn speed(&self, p: f64) -> f64 {
        DVec2::new(dpoly(&self.u, p), dpoly(&self.v, p)).length()
    }

    /// Arc length between parameters a and b [m].
    fn arc(&self, a: f64, b: f64) -> f64 {
        integrate(a, b, 2, |p| DVec2::new(self.speed(p), 0.0)).x
    }

    /// Total arc length of the table \[m\].
    pub fn total(&self) -> f64 {
        self.lengths.last().copied().unwrap_or(0.0)
    }

    /// The parameter at arc length `s` from the start.
    fn param_at(&self, s: f64) -> f64 {
        let s = s.clamp(0.0, self.total());
        let k = self.lengths.partition_point(|&l| l <= s).clamp(1, self.lengths.len() - 1);
        let (s0, s1) = (self.lengths[k - 1], self.lengths[k]);
        let (p0, p1) = (self.params[k - 1], self.params[k]);
        let mut p = if s1 > s0 { p0 + (p1 - p0) * (s - s0) / (s1 - s0) } else { p0 };
        for _ in 0..3 {
            let v = self.speed(p);
            if v <= 1e-12 {
                break;
            }
            p = (p - (s0 + self.arc(p0, p) - s) / v).clamp(p0, p1);
        }
        p
    }

    /// Position (local frame) and local heading at arc length `s`.
    fn eval(&self, s: f64) -> (DVec2, f64) {
        let p = self.param_at(s);
        let pos = DVec2::new(poly(&self.u, p), poly(&self.v, p));
        (pos, dpoly(&self.v, p).atan2(dpoly(&self.u, p)))
    }

    /// Largest |curvature| at the table's points [1/m].
    fn max_curvature(&self) -> f64 {
        self.params
            .iter()
            .map(|&p| {
                let (du, dv) = (dpoly(&self.u, p), dpoly(&self.v, p));
                let (ddu, ddv) = (ddpoly(&self.u, p), ddpoly(&self.v, p));
                let speed = (du * du + dv * dv).sqrt();
                if speed > 1e-9 { (du * ddv - dv * ddu).abs() / speed.powi(3) } else { 0.0 }
            })
            .fold(0.0, f64::max)
    }
}

/// One `<geometry>` record of a road's `<planView>`.
#[derive(Debug, Clone, PartialEq)]
pub struct Geometry {
    /// Start along the reference line \[m\].
    pub s: f64,
    /// Start position \[m\].
    pub start: DVec2,
    /// Start heading \[rad\].
    pub hdg: f64,
    /// Length \[m\].
    pub length: f64,
    /// Its shape.
    pub shape: Shape,
}

impl Geometry {
    /// Position \[m\] and heading \[rad\] at `ds` \[m\] from the geometry's start (clamped to it).
    pub fn eval(&self, ds: f64) -> (DVec2, f64) {
        let ds = ds.clamp(0.0, self.length);
        let (sin, cos) = self.hdg.sin_cos();
        let to_world =
            |local: DVec2| self.start + DVec2::new(cos * local.x - sin * local.y, sin * local.x + cos * local.y);
        match &self.shape {
            Shape::Line => (to_world(DVec2::new(ds, 0.0)), self.hdg),
            Shape::Arc { curvature: k } if k.abs() < 1e-12 => (to_world(DVec2::new(ds, 0.0)), self.hdg),
            Shape::Arc { curvature: k } => {
                let turn = k * ds;
                (to_world(DVec2::new(turn.sin() / k, (1.0 - turn.cos()) / k)), self.hdg + turn)
            }
            Shape::Spiral { start, end } => {
                let rate = if self.length > 0.0 { (end - start) / self.length } else { 0.0 };
                let heading = |t: f64| start * t + 0.5 * rate * t * t;
                let turn = start.abs() * ds + 0.5 * rate.abs() * ds * ds;
                let pieces = ((turn / 0.1).ceil() as usize).max((ds / 50.0).ceil() as usize).clamp(1, 1 << 16);
                let local = integrate(0.0, ds, pieces, |t| {
                    let (s, c) = heading(t).sin_cos();
                    DVec2::new(c, s)
                });
                (to_world(local), self.hdg + heading(ds))
            }
            Shape::Cubic(c) => {
                let total = c.total();
                let s = if self.length > 0.0 { ds * total / self.length } else { 0.0 };
                let (local, h) = c.eval(s);
                (to_world(local), self.hdg + h)
            }
        }
    }

    /// Largest |curvature| along the geometry [1/m].
    pub fn max_curvature(&self) -> f64 {
        match &self.shape {
            Shape::Line => 0.0,
            Shape::Arc { curvature } => curvature.abs(),
            Shape::Spiral { start, end } => start.abs().max(end.abs()),
            Shape::Cubic(c) => {
                let stretch = if self.length > 0.0 && c.total() > 0.0 { c.total() / self.length } else { 1.0 };
                c.max_curvature() * stretch * stretch
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn geometry(shape: Shape, length: f64) -> Geometry {
        Geometry { s: 0.0, start: DVec2::new(1.0, 2.0), hdg: 0.3, length, shape }
    }

    /// Fresnel integrals S(x) = ∫0^x sin(π t²/2) dt, C(x) = ∫0^x cos(π t²/2) dt by their power
    /// series (Abramowitz & Stegun 7.3.11-7.3.13), independent of the quadrature under test.
    fn fresnel(x: f64) -> (f64, f64) {
        let z = std::f64::consts::FRAC_PI_2 * x * x;
        let (mut c, mut s) = (0.0, 0.0);
        // term_n = (-1)^n z^(2n) / (2n)!, and z^(2n+1) / (2n+1)! for sine.
        let mut even = 1.0;
        let mut odd = z;
        for n in 0..60 {
            c += even / (4 * n + 1) as f64;
            s += odd / (4 * n + 3) as f64;
            let (a, b) = ((2 * n + 1) as f64, (2 * n + 2) as f64);
            even *= -z * z / (a * b);
            odd *= -z * z / (b * (b + 1.0));
        }
        (x * s, x * c)
    }

    #[test]
    fn clothoid_from_zero_curvature_matches_fresnel_integrals() {
        // A clothoid with curvature k(t) = c t has heading c t²/2 and position
        // a (C(t/a), S(t/a)) with a = sqrt(π / c) (the standard Fresnel form).
        let (length, k_end) = (120.0, 0.02);
        let c = k_end / length;
        let g =
            Geometry { s: 0.0, start: DVec2::ZERO, hdg: 0.0, length, shape: Shape::Spiral { start: 0.0, end: k_end } };
        let a = (std::f64::consts::PI / c).sqrt();
        for ds in [0.0, 10.0, 37.5, 80.0, 120.0] {
            let (p, h) = g.eval(ds);
            let (s, cc) = fresnel(ds / a);
            let expected = DVec2::new(a * cc, a * s);
            assert!(p.distance(expected) < 1e-6, "at {ds}: {p} vs {expected}");
            assert!((h - 0.5 * c * ds * ds).abs() < 1e-12);
        }
    }

    #[test]
    fn clothoid_with_start_curvature_is_a_piece_of_the_fresnel_spiral() {
        // curvStart k0 = c t0: the same spiral entered at t0, moved and turned to the start.
        let (k0, k1, length) = (0.01, -0.03, 50.0);
        let c = (k1 - k0) / length;
        let g = Geometry { s: 0.0, start: DVec2::ZERO, hdg: 0.0, length, shape: Shape::Spiral { start: k0, end: k1 } };
        let a = (std::f64::consts::PI / c.abs()).sqrt();
        let t0 = k0 / c;
        // Reference spiral of |c| (mirrored for negative c): point at t.
        let sign = c.signum();
        let at = |t: f64| {
            let (s, cc) = fresnel(t / a);
            (DVec2::new(a * cc, sign * a * s), sign * 0.5 * c.abs() * t * t)
        };
        let (p0, h0) = at(t0);
        for ds in [12.0, 25.0, 50.0] {
            let (p1, _) = at(t0 + ds);
            let d = p1 - p0;
            let (sin, cos) = (-h0).sin_cos();
            let expected = DVec2::new(cos * d.x - sin * d.y, sin * d.x + cos * d.y);
            let (p, _) = g.eval(ds);
            assert!(p.distance(expected) < 1e-6, "at {ds}: {p} vs {expected}");
        }
    }

    #[test]
    fn arc_is_a_circle_and_line_is_straight() {
        let r = 40.0;
        let g = geometry(Shape::Arc { curvature: 1.0 / r }, 100.0);
        let centre = g.start + r * DVec2::new(-(0.3f64).sin(), (0.3f64).cos());
        for ds in [0.0, 30.0, 100.0] {
            let (p, h) = g.eval(ds);
            assert!((p.distance(centre) - r).abs() < 1e-9);
            assert!((h - 0.3 - ds / r).abs() < 1e-12);
        }
        let g = geometry(Shape::Line, 10.0);
        let (p, _) = g.eval(10.0);
        assert!(p.distance(DVec2::new(1.0 + 10.0 * 0.3f64.cos(), 2.0 + 10.0 * 0.3f64.sin())) < 1e-12);
    }

    #[test]
    fn poly3_follows_its_arc_length() {
        // v(u) = 0.01 u²: its arc length from 0 to U is ∫ sqrt(1 + (0.02 u)²) du, in closed form
        // (x sqrt(1+x²) + asinh x) / (2 * 0.02) with x = 0.02 U.
        let arc = |u: f64| {
            let x = 0.02 * u;
            (x * (1.0 + x * x).sqrt() + x.asinh()) / 0.04
        };
        let u_end = 60.0;
        let length = arc(u_end);
        let c = Cubic::poly3([0.0, 0.0, 0.01, 0.0], length);
        let g = Geometry { s: 0.0, start: DVec2::ZERO, hdg: 0.0, length, shape: Shape::Cubic(c) };
        for u in [0.0, 20.0, 45.0, 60.0] {
            let (p, h) = g.eval(arc(u));
            assert!(p.distance(DVec2::new(u, 0.01 * u * u)) < 1e-6, "u {u}: {p}");
            assert!((h - (0.02 * u).atan()).abs() < 1e-9);
        }
    }

    #[test]
    fn param_poly3_normalized_and_arc_length_agree() {
        // A straight line written both ways, and a quarter-ish curve both ways.
        let length = 30.0;
        let by_length = Cubic::param([0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0], length, length);
        let g = Geometry { s: 0.0, start: DVec2::ZERO, hdg: 0.0, length, shape: Shape::Cubic(by_length) };
        assert!(g.eval(12.0).0.distance(DVec2::new(12.0, 0.0)) < 1e-9);
        let normal = Cubic::param([0.0, length, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0], 1.0, length);
        let g = Geometry { s: 0.0, start: DVec2::ZERO, hdg: 0.0, length, shape: Shape::Cubic(normal) };
        assert!(g.eval(12.0).0.distance(DVec2::new(12.0, 0.0)) < 1e-9);
        // u = 10 p, v = 5 p² over p in [0, 1]: the point at half the arc length lies on the
        // curve, at arc length (closed form of ∫ sqrt(100 + 100 p²) dp) equal to half the total.
        let arc = |p: f64| 5.0 * (p * (1.0 + p * p).sqrt() + p.asinh());
        let total = arc(1.0);
        let c = Cubic::param([0.0, 10.0, 0.0, 0.0], [0.0, 0.0, 5.0, 0.0], 1.0, total);
        assert!((c.total() - total).abs() < 1e-9);
        let g = Geometry { s: 0.0, start: DVec2::ZERO, hdg: 0.0, length: total, shape: Shape::Cubic(c) };
        let (p, _) = g.eval(0.5 * total);
        let param = p.x / 10.0;
        assert!((p.y - 5.0 * param * param).abs() < 1e-9);
        assert!((arc(param) - 0.5 * total).abs() < 1e-6);
    }
}

//! The radar model: a cone of half the opening angle around the heading.

use glam::DVec2;

/// Whether a target at offset `relative` \[m\] from the sensor lies inside a radar cone facing
/// `heading` (a unit vector) with full opening angle `angle` \[rad\] (edges inclusive).
///
/// Every angle here is in radians. The 2015 Python code compared an angle in degrees with one in
/// radians in this test, so its radar cone was not the configured one; this one is.
pub fn in_radar_cone(relative: DVec2, heading: DVec2, angle: f64) -> bool {
    Cone::new(heading, angle).contains(relative, relative.length_squared())
}

/// A radar cone prepared for many tests: no trigonometry or square root per target. A plugin
/// sensor with a field of view makes one per vehicle and tick ([`Cone::new`]) and tests each
/// neighbour with [`Cone::contains`] (what [`in_radar_cone`] does for one target).
#[derive(Debug, Clone, Copy)]
pub struct Cone {
    pub(super) heading: DVec2,
    /// cos of the half opening angle, and its square.
    pub(super) cos_half: f64,
    pub(super) cos_half2: f64,
    pub(super) everything: bool,
}

/// The cosine of half a radar's opening angle, remembered for the last angle asked: radars of
/// one kind share their angle, and a library `cos` per vehicle and tick was 1 % of a 10,000
/// vehicle bench.
#[derive(Debug, Default, Clone, Copy)]
pub(super) struct HalfCos(pub(super) Option<(f64, f64)>);

impl HalfCos {
    pub(super) fn of(&mut self, angle: f64) -> f64 {
        match self.0 {
            Some((a, cos)) if a.to_bits() == angle.to_bits() => cos,
            _ => {
                let cos = (0.5 * angle).cos();
                self.0 = Some((angle, cos));
                cos
            }
        }
    }
}

impl Cone {
    /// The cone around unit vector `heading` with full opening `angle` \[rad\] (2π or more:
    /// every direction).
    pub fn new(heading: DVec2, angle: f64) -> Cone {
        Cone::with_cos(heading, angle, (0.5 * angle).cos())
    }

    /// [`Cone::new`] given `cos_half`, the cosine of half of `angle` ([`HalfCos`]).
    pub(super) fn with_cos(heading: DVec2, angle: f64, cos_half: f64) -> Cone {
        Cone { heading, cos_half, cos_half2: cos_half * cos_half, everything: 0.5 * angle >= std::f64::consts::PI }
    }

    /// `relative` at squared distance `d2`: is its angle to the heading at most the half angle?
    /// That is dot >= |rel| cos(half), compared squared with the signs handled. Written without
    /// branches on the target (the sensor loop tests ~25 targets per vehicle and tick, and which
    /// ones are seen is unpredictable).
    pub fn contains(&self, relative: DVec2, d2: f64) -> bool {
        let dot = relative.dot(self.heading);
        let ahead = dot >= 0.0;
        let (dot2, limit) = (dot * dot, d2 * self.cos_half2);
        let inside = if self.cos_half >= 0.0 { ahead & (dot2 >= limit) } else { ahead | (dot2 <= limit) };
        self.everything | ((d2 != 0.0) & inside)
    }
}
/// The cone of a vehicle without a radar (never consulted: its radar range is negative).
pub(super) const NO_CONE: Cone = Cone { heading: DVec2::ZERO, cos_half: 1.0, cos_half2: 1.0, everything: false };

//! Imperfect sensors: counter-based draws (dropout, Gaussian noise) keyed by seed, sensor,
//! observer, target and tick, and occlusion by angular extents of footprints.

use glam::DVec2;
use std::f64::consts::{PI, TAU};

use crate::sim::random::{key, mix, normal_half};
use crate::world::{Detection, SensorError, SensorErrors, VehicleId, VehicleSize};

/// Random stream of radar draws ("Rada").
pub(super) const RADAR_STREAM: u64 = 0x5261_6461;
/// Random stream of velodyne draws ("Velo").
pub(super) const VELODYNE_STREAM: u64 = 0x5665_6c6f;
/// Footprint of a grid entry for occlusion: half length, half width \[m\] and yaw \[rad\].
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Footprint {
    pub(super) half_length: f64,
    pub(super) half_width: f64,
    pub(super) yaw: f64,
}

impl Footprint {
    /// The footprint of a vehicle of `size` heading `yaw` \[rad\].
    pub fn new(size: VehicleSize, yaw: f64) -> Footprint {
        Footprint { half_length: 0.5 * size.length, half_width: 0.5 * size.width, yaw }
    }

    /// Half its length along its heading and half its width across it, as vectors [m].
    pub(crate) fn axes(&self) -> (DVec2, DVec2) {
        let heading = DVec2::from_angle(self.yaw);
        (heading * self.half_length, heading.perp() * self.half_width)
    }
}

/// Angle wrapped into (−π, π] [rad].
pub(super) fn wrap(a: f64) -> f64 {
    let a = a.rem_euclid(TAU);
    if a > PI { a - TAU } else { a }
}

/// The angular extent of footprint `f` centred at `relative` [m] from the sensor: the bearing
/// of its centre and the lowest and highest bearing of its corners relative to it [rad].
pub(crate) fn extent(relative: DVec2, f: &Footprint) -> (f64, f64, f64) {
    let centre = relative.y.atan2(relative.x);
    let (along, across) = (DVec2::from_angle(f.yaw) * f.half_length, DVec2::from_angle(f.yaw).perp() * f.half_width);
    let (mut lo, mut hi) = (0.0f64, 0.0f64);
    for corner in [along + across, along - across, -along + across, -along - across] {
        let c = relative + corner;
        let a = wrap(c.y.atan2(c.x) - centre);
        lo = lo.min(a);
        hi = hi.max(a);
    }
    (centre, lo, hi)
}

/// Whether extent `inner` lies inside extent `outer` (both as [`extent`] gives them).
pub(crate) fn covers(outer: (f64, f64, f64), inner: (f64, f64, f64)) -> bool {
    let d = wrap(inner.0 - outer.0);
    d + inner.1 >= outer.1 && d + inner.2 <= outer.2
}

/// The rotation by `angle` [rad] as (cos, sin): by Taylor polynomials when the angle is as
/// small as a bearing error (|angle| <= 0.1 rad: truncation below 3e-15, under a double's
/// rounding of the angle itself), else by `sin_cos`. A bearing error of 0.5° sd rotates every
/// noisy detection; `sin_cos` was a fifth of a degraded benchmark's time.
pub(super) fn small_rotation(angle: f64) -> DVec2 {
    if angle.abs() > 0.1 {
        return DVec2::from_angle(angle);
    }
    // Estrin's form of the Taylor polynomials (multiplications only: no division): the terms
    // pair up on a² and a⁴ rather than Horner's chain of one multiply-add per term, so the
    // rotation waits for about half as many dependent operations (it is on the longest path of
    // a noisy detection: hash, normal, rotation, position).
    const S: [f64; 4] = [-1.0 / 6.0, 1.0 / 120.0, -1.0 / 5040.0, 1.0 / 362_880.0];
    const C: [f64; 5] = [-1.0 / 2.0, 1.0 / 24.0, -1.0 / 720.0, 1.0 / 40_320.0, -1.0 / 3_628_800.0];
    let a2 = angle * angle;
    let a4 = a2 * a2;
    let sin = angle * ((1.0 + a2 * S[0]) + a4 * ((S[1] + a2 * S[2]) + a4 * S[3]));
    let cos = (1.0 + a2 * C[0]) + a4 * ((C[1] + a2 * C[2]) + a4 * (C[3] + a2 * C[4]));
    DVec2::new(cos, sin)
}

/// What the errors of all sensing vehicles need at one tick: each sensor's tick keys
/// ([`SensorKeys`]), made once per tick.
#[derive(Debug, Clone, Copy)]
pub(super) struct Draws {
    pub(super) radar: SensorKeys,
    pub(super) velodyne: SensorKeys,
}

impl Draws {
    pub(super) fn new(seed: u64, now_us: u64) -> Draws {
        Draws {
            radar: SensorKeys::new(seed, RADAR_STREAM, now_us),
            velodyne: SensorKeys::new(seed, VELODYNE_STREAM, now_us),
        }
    }

    pub(super) fn pair(observer: VehicleId, target: VehicleId) -> u64 {
        ((observer.0 as u32 as u64) << 32) | target.0 as u32 as u64
    }
}

/// The keys of one sensor's draws at one tick: `word[k] = mix(key(seed, stream, now_us) ^ k)`
/// for the two words of a pair and the key of its rare further words. Word `k` of the pair
/// (observer, target) is `mix(word[k] ^ pair)`: one hash each, neither waiting for the other,
/// so the draws stay a pure function of (seed, sensor, observer, target, tick), counter-based
/// as REFERENCE "Channels" asks (nothing depends on threads or order), at two hashes per noisy
/// kept detection instead of a per-pair counter hash and a hash per word after it.
#[derive(Debug, Clone, Copy)]
pub(crate) struct SensorKeys {
    pub(super) word: [u64; 3],
}

impl SensorKeys {
    pub(crate) fn new(seed: u64, stream: u64, now_us: u64) -> SensorKeys {
        let tick = key(seed, stream, now_us);
        SensorKeys { word: std::array::from_fn(|k| mix(tick ^ k as u64)) }
    }

    /// The draws of the pair (observer, target) this tick ([`PairDraws`]).
    #[inline]
    pub(crate) fn pair(&self, observer: VehicleId, target: VehicleId) -> PairDraws<'_> {
        let pair = Draws::pair(observer, target);
        PairDraws { keys: self, pair, first: mix(self.word[0] ^ pair) }
    }
}

/// One pair's draws of one sensor at one tick: 128 bits in two words. Word 0
/// ([`PairDraws::first`]) decides dropout from its high 16 bits (a probability of 2⁻¹⁶
/// resolution) and gives the range and bearing errors' normals from 24 bits each (a 16-bit
/// uniform within the ziggurat's layer: steps below 10⁻⁴ of the layer's width, far under any
/// sensor's resolution); word 1's halves give the x and y velocity's ([`normal_half`], each its
/// own part of the rare continuation, keyed by word 2's key and the pair). So a dropped
/// detection costs one hash and a kept noisy one two.
#[derive(Debug, Clone, Copy)]
pub(crate) struct PairDraws<'a> {
    pub(super) keys: &'a SensorKeys,
    pub(super) pair: u64,
    pub(super) first: u64,
}

impl PairDraws<'_> {
    /// Whether the detection survives a dropout of probability `dropout`: the high 16 bits of
    /// word 0 as a uniform of 2⁻¹⁶ resolution at or above it.
    #[inline]
    pub(crate) fn kept(&self, dropout: f64) -> bool {
        // Through u32: its conversion to f64 is one instruction, a u64's a branchy sequence.
        f64::from((self.first >> 48) as u32) >= dropout * 65_536.0
    }

    /// The four standard normals of the noise: range, bearing, x and y velocity. Always
    /// inlined: returned through memory, the four were read back before their stores retired.
    #[inline(always)]
    pub(crate) fn normals(&self) -> [f64; 4] {
        let w1 = mix(self.keys.word[1] ^ self.pair);
        let more = self.keys.word[2] ^ self.pair;
        // 24 bits as `normal_half`'s 32: the high 16 as its uniform's top, the low 8 its layer.
        let widen = |b: u64| (((b as u32) & 0x00ff_ff00) << 8) | ((b as u32) & 0xff);
        [
            normal_half(widen(self.first >> 24), more, 0),
            normal_half(widen(self.first), more, 1),
            normal_half((w1 >> 32) as u32, more, 2),
            normal_half(w1 as u32, more, 3),
        ]
    }
}
/// Move `detection` (of a target at `relative` [m], squared distance `d2`, from a sensor at
/// `position`) by the range, bearing and velocity errors of `err`, with the standard normals
/// `normals` (range, bearing, x and y velocity: [`PairDraws::normals`]).
#[inline]
pub(crate) fn add_noise(
    detection: &mut Detection,
    position: DVec2,
    relative: DVec2,
    d2: f64,
    err: &SensorError,
    normals: [f64; 4],
) {
    let [n_range, n_bearing, n_vx, n_vy] = normals;
    // Range and bearing errors: scale the offset, then rotate it by the bearing error. The
    // scale is 1 + error / d with 1 / d = d / d²: the square root and the division start
    // together rather than one after the other (they were the longest wait of a detection).
    let (d, inv_d2) = (d2.sqrt(), 1.0 / d2);
    let scale = if d2 > 0.0 { 1.0 + err.range_sd * n_range * (d * inv_d2) } else { 1.0 };
    let scaled = relative * scale;
    detection.position = position + small_rotation(err.bearing_sd * n_bearing).rotate(scaled);
    detection.velocity += DVec2::new(n_vx, n_vy) * err.speed_sd;
}
/// Whether either sensor of `e` hides targets behind nearer ones (then every vehicle's
/// [`Footprint`] is needed).
pub(super) fn occludes(e: &SensorErrors) -> bool {
    e.radar.occlusion || e.velodyne.occlusion
}

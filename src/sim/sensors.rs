//! Simulated sensors: radar cone, velodyne circle and omniscient, over one spatial grid per tick.
//!
//! Every sensor tick the grid is rebuilt from all vehicles with cells as large as the typical
//! (median) sensor range, then each sensing vehicle scans only the cells its own range reaches:
//! its 3 x 3 neighbourhood when its range is typical, a wider square for the few with a longer
//! range, so a few long-range sensors cost only their own wider search, never a coarser grid for
//! everyone. O(N) for bounded ranges. An [`Omniscient`] vehicle scans everyone (O(N) per such
//! vehicle).
//!
//! Where every vehicle senses with a bounded range from one ECS table (the common case), the
//! grid is built only now and then, for Verlet neighbour lists (`NeighbourLists`): each
//! vehicle's list holds those within its range plus a skin, kept while no two neighbours have
//! closed in on each other by the skin (traffic moves together: seconds at a time), so most
//! ticks test a short list per vehicle and rebuild nothing. The readings are the grid scan's,
//! bit for bit.
//!
//! Imperfect sensors ([`SensorErrors`], issue 21) cost only their own vehicles: after the
//! candidates are found as above, occlusion compares each with the nearer ones found (a target
//! whose angular extent lies inside one nearer target's is hidden), dropout drops a detection
//! with its probability, and Gaussian noise moves range, bearing and velocity. Every draw is
//! counter-based ([`super::random`]), keyed by (seed, sensor, observer and target, tick): no
//! allocation, the same bits for any thread count; two hashes per noisy detection
//! (`SensorKeys`). The normals come from the ziggurat on 24 or 32 bits of a hash each
//! ([`super::random::normal_half`]: a multiplication each, mostly) and the bearing error's
//! rotation from a short polynomial, so noise costs no `ln` or `sin_cos` per detection.
//! [`SensorStats`] counts detections and the misses of each kind.

use bevy_ecs::prelude::{Has, Local, Query, Res, ResMut, Resource};
use glam::DVec2;
use std::f64::consts::{PI, TAU};

use super::{Plugin, SimBuilder};
use crate::world::{
    Detection, Omniscient, Radar, SensorError, SensorErrors, SensorReadings, SimTime, VehicleId, VehicleSize,
    VehicleState, Velodyne,
};

use bevy_ecs::schedule::IntoScheduleConfigs;

use super::grid::{Pass, pack, vectorised, within_reach};
use super::random::{key, mix, normal_half};
use super::{Candidates, GridEntry, Parallelism, Sensors, SimClock, SimSeed, SimSystems, SpatialGrid};

/// Random stream of radar draws ("Rada").
const RADAR_STREAM: u64 = 0x5261_6461;
/// Random stream of velodyne draws ("Velo").
const VELODYNE_STREAM: u64 = 0x5665_6c6f;

/// Detections and misses of all sensors since the start, summed over observers and ticks
/// (`summary.json` `metrics.sensors`).
#[derive(Resource, Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct SensorStats {
    /// Detections written into readings.
    pub detections: u64,
    /// Targets within a sensor's reach, not hidden, missed because every sensor that saw them
    /// dropped them.
    pub missed_by_dropout: u64,
    /// Targets within a sensor's reach hidden behind a nearer target from every sensor that
    /// reached them.
    pub missed_by_occlusion: u64,
}

impl SensorStats {
    fn add(&mut self, other: &SensorStats) {
        self.detections += other.detections;
        self.missed_by_dropout += other.missed_by_dropout;
        self.missed_by_occlusion += other.missed_by_occlusion;
    }
}

/// Footprint of a grid entry for occlusion: half length, half width \[m\] and yaw \[rad\].
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Footprint {
    half_length: f64,
    half_width: f64,
    yaw: f64,
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
fn wrap(a: f64) -> f64 {
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
fn small_rotation(angle: f64) -> DVec2 {
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
struct Draws {
    radar: SensorKeys,
    velodyne: SensorKeys,
}

impl Draws {
    fn new(seed: u64, now_us: u64) -> Draws {
        Draws {
            radar: SensorKeys::new(seed, RADAR_STREAM, now_us),
            velodyne: SensorKeys::new(seed, VELODYNE_STREAM, now_us),
        }
    }

    fn pair(observer: VehicleId, target: VehicleId) -> u64 {
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
    word: [u64; 3],
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
    keys: &'a SensorKeys,
    pair: u64,
    first: u64,
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

/// Whether a target at offset `relative` \[m\] from the sensor lies inside a radar cone facing
/// `heading` (a unit vector) with full opening angle `angle` \[rad\] (edges inclusive).
///
/// Every angle here is in radians. The 2015 Python code compared an angle in degrees with one in
/// radians in this test, so its radar cone was not the configured one; this one is.
pub fn in_radar_cone(relative: DVec2, heading: DVec2, angle: f64) -> bool {
    Cone::new(heading, angle).contains(relative, relative.length_squared())
}

/// A radar cone prepared for many tests: no trigonometry or square root per target.
#[derive(Debug, Clone, Copy)]
struct Cone {
    heading: DVec2,
    /// cos of the half opening angle, and its square.
    cos_half: f64,
    cos_half2: f64,
    everything: bool,
}

/// The cosine of half a radar's opening angle, remembered for the last angle asked: radars of
/// one kind share their angle, and a library `cos` per vehicle and tick was 1 % of a 10,000
/// vehicle bench.
#[derive(Debug, Default, Clone, Copy)]
struct HalfCos(Option<(f64, f64)>);

impl HalfCos {
    fn of(&mut self, angle: f64) -> f64 {
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
    fn new(heading: DVec2, angle: f64) -> Cone {
        Cone::with_cos(heading, angle, (0.5 * angle).cos())
    }

    /// [`Cone::new`] given `cos_half`, the cosine of half of `angle` ([`HalfCos`]).
    fn with_cos(heading: DVec2, angle: f64, cos_half: f64) -> Cone {
        Cone { heading, cos_half, cos_half2: cos_half * cos_half, everything: 0.5 * angle >= std::f64::consts::PI }
    }

    /// `relative` at squared distance `d2`: is its angle to the heading at most the half angle?
    /// That is dot >= |rel| cos(half), compared squared with the signs handled. Written without
    /// branches on the target (the sensor loop tests ~25 targets per vehicle and tick, and which
    /// ones are seen is unpredictable).
    fn contains(&self, relative: DVec2, d2: f64) -> bool {
        let dot = relative.dot(self.heading);
        let ahead = dot >= 0.0;
        let (dot2, limit) = (dot * dot, d2 * self.cos_half2);
        let inside = if self.cos_half >= 0.0 { ahead & (dot2 >= limit) } else { ahead | (dot2 <= limit) };
        self.everything | ((d2 != 0.0) & inside)
    }
}

/// The grid all sensors query and the neighbour lists built over it (`NeighbourLists`),
/// kept between sensor ticks: the grid is rebuilt every tick where the lists are not used,
/// else with the lists.
#[derive(Resource, Debug, Default)]
pub struct SensorGrid {
    grid: SpatialGrid,
    neighbours: Neighbours,
}

/// Scratch buffers of one thread of [`sense_vehicles`], kept between ticks.
/// On cache lines of its own (see [`crate::sim::parallel::Padded`]).
#[derive(Default)]
#[repr(align(128))]
pub struct SenseScratch {
    /// Candidates around the current cell.
    around: Candidates,
    /// Every candidate's key (or [`UNSEEN`]), then the detections of the current vehicle as
    /// sort keys, see [`detection_key`].
    keys: Vec<u64>,
    found: Vec<u64>,
    /// A neighbour list's coordinates [m] and keys where the processor has no AVX2
    /// ([`Sight::consider_listed`]).
    xs: Vec<f64>,
    ys: Vec<f64>,
    list_keys: Vec<u64>,
    /// A neighbour list's build: which candidates lie within reach, and scratch for finding them.
    marks: Vec<u32>,
    slots: Vec<u32>,
    /// The lists this thread built this tick (its chunk's, from vehicle `built_from` on), one
    /// after the other, and where each ends.
    built: Vec<u32>,
    built_ends: Vec<u32>,
    built_from: Option<usize>,
    /// Angular extents of the targets found so far nearer than the current one (occlusion).
    extents: Vec<(f64, f64, f64)>,
    /// Counts of this thread's vehicles this tick.
    stats: SensorStats,
    half_cos: HalfCos,
    /// With kept lists ([`sense_with_kept_lists`]): this chunk's displacements since the build
    /// and whether its vehicles' sensors are the build's.
    drift: DriftPart,
    shapes_held: bool,
}

/// Cells each side a vehicle of sensor range `range` [m] must search on a grid of `cell` [m]:
/// a point within `range` of a vehicle lies at most `ceil(range / cell)` cells away.
fn reach(range: f64, cell: f64) -> i32 {
    ((range / cell).ceil() as i32).max(1)
}

/// Which candidates [`SenseScratch::around`] holds: those of the square of cells `reach` cells
/// around a cell, or the whole grid's.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Gathered {
    Square((i32, i32), i32),
    All,
}

/// Gather the candidates of the square of cells `reach` cells around `centre`, or of the whole
/// grid when that square has more cells than the grid has entries; returns which.
fn gather(grid: &SpatialGrid, centre: (i32, i32), reach: i32, around: &mut Candidates) -> Gathered {
    around.clear();
    let side = 2.0 * reach as f64 + 1.0;
    if side * side > grid.len() as f64 {
        grid.gather_all(around);
        return Gathered::All;
    }
    grid.gather_cells(centre.0 - reach..=centre.0 + reach, centre.1 - reach..=centre.1 + reach, around);
    Gathered::Square(centre, reach)
}

/// Gather into `around` the candidates of the cells that `range` [m] reaches around `p`, unless
/// it holds them already (`gathered` says what it holds: consecutive vehicles mostly share a
/// cell).
fn gather_within(grid: &SpatialGrid, p: DVec2, range: f64, gathered: &mut Option<Gathered>, around: &mut Candidates) {
    let centre = grid.cell_of(p);
    let reach = reach(range, grid.cell_size());
    if gathered.is_none_or(|g| g != Gathered::Square(centre, reach) && g != Gathered::All) {
        *gathered = Some(gather(grid, centre, reach, around));
    }
}

/// One detection as an integer sort key: the squared distance rounded to an f32 (a
/// non-negative float's bits order like the number, and rounding keeps the order but for
/// ties), then `low` (the grid slot and which sensors reach it, see [`REACH`]). Eight bytes
/// sort faster than the sixteen of the exact distance with the id; [`sort_nearest_first`]
/// puts the rare ties of the rounded distance in exact order.
fn detection_key(d2: f64, low: u32) -> u64 {
    (u64::from((d2 as f32).to_bits()) << 32) | u64::from(low)
}

/// Sort detection keys nearest first, ties by id: as by the exact squared distance from `from`
/// and then the id. The keys hold the distance rounded to an f32, so detections whose
/// distances round alike (within about 1e-7 of each other, or equal) are put in exact order
/// among themselves afterwards, from their grid entries.
fn sort_nearest_first(found: &mut [u64], grid: &impl Targets, from: DVec2) {
    found.sort_unstable();
    let mut k = 0;
    while k + 1 < found.len() {
        let rounded = found[k] >> 32;
        if found[k + 1] >> 32 != rounded {
            k += 1;
            continue;
        }
        let mut end = k + 2;
        while end < found.len() && found[end] >> 32 == rounded {
            end += 1;
        }
        found[k..end].sort_unstable_by_key(|&key| {
            let e = grid.target(key as u32 & !REACH);
            ((e.position - from).length_squared().to_bits(), e.id.0)
        });
        k = end;
    }
}

/// The first `n` items of `buffer`, grown to hold them if it is shorter. A sensor tick's
/// buffers only grow (no zero-filling per vehicle) and are used up to the length.
fn first<T: Copy + Default>(buffer: &mut Vec<T>, n: usize) -> &mut [T] {
    if buffer.len() < n {
        buffer.resize(n, T::default());
    }
    &mut buffer[..n]
}

/// What one vehicle's sensors see of the candidates (slot, position, id) around it.
struct Sight {
    id: VehicleId,
    position: DVec2,
    /// The radar cone (any cone without a radar: `radar_range2` < 0 then rules it out).
    cone: Cone,
    radar_range2: f64,
    velodyne_range2: f64,
    /// Whether the sensor is omniscient (bit 0, [`Sight::omniscient`]) and the cone's
    /// `everything` (bit 1) as one word, written whole, for [`Sight::key`]: the key pass reads
    /// them as a word, and a word read over two separate byte stores of the flags just made
    /// waited for those stores to leave the store buffer (perf: a seventh of the key pass's
    /// samples on that load).
    flags: u32,
}

impl Sight {
    fn new(
        id: VehicleId,
        state: &VehicleState,
        radar: Option<&Radar>,
        velodyne: Option<&Velodyne>,
        omniscient: bool,
        half_cos: &mut HalfCos,
    ) -> Sight {
        let cone = radar.map_or(NO_CONE, |r| Cone::with_cos(state.heading(), r.angle, half_cos.of(r.angle)));
        Sight {
            id,
            position: state.position,
            cone,
            radar_range2: radar.map_or(-1.0, |r| r.range * r.range),
            velodyne_range2: velodyne.map_or(-1.0, |v| v.range * v.range),
            flags: u32::from(omniscient) | (u32::from(cone.everything) << 1),
        }
    }

    /// Whether the sensor sees everyone ([`Omniscient`]).
    fn omniscient(&self) -> bool {
        self.flags & 1 != 0
    }

    /// The detection keys of the candidates it sees (with which sensors reach each, see
    /// [`REACH`]), in candidate order, at the front of `found`; returns that front.
    ///
    /// Two passes: the first tests every candidate and writes its key, or [`UNSEEN`], without a
    /// branch on the candidate (which ones are seen is unpredictable), over the candidates'
    /// arrays, so the compiler turns it into vector code (four candidates an instruction where
    /// the processor has AVX2, chosen at run time; the same operations in the same order as
    /// the one-at-a-time code, so the same bits); the second packs the seen keys to the front.
    fn consider_all<'f>(&self, around: &Candidates, keys: &mut Vec<u64>, found: &'f mut Vec<u64>) -> &'f mut [u64] {
        let n = around.len();
        let keys = first(keys, n);
        first(found, n);
        vectorised(KeysPass { sight: self, around, found: keys });
        let seen = pack(keys, found, UNSEEN);
        &mut found[..seen]
    }

    /// Each candidate's detection key, or [`UNSEEN`]: the first pass of [`Sight::consider_all`].
    /// The arithmetic is [`Cone::contains`]'s and `DVec2`'s (differences, then `x*x + y*y`),
    /// written on the coordinates.
    #[inline(always)]
    fn keys(&self, around: &Candidates, found: &mut [u64]) {
        let candidates = around.xs.iter().zip(&around.ys).zip(&around.slots).zip(&around.ids);
        for (key, (((&x, &y), &slot), &other)) in found.iter_mut().zip(candidates) {
            *key = self.key(x, y, slot, other);
        }
    }

    /// The detection key of the candidate `other` at (`x`, `y`) [m] in slot `slot`, or
    /// [`UNSEEN`]: written without a branch on the candidate, so that [`Sight::keys`] turns
    /// into vector code, and shared with [`Sight::consider_listed`] so both give the same bits.
    #[inline(always)]
    fn key(&self, x: f64, y: f64, slot: u32, other: VehicleId) -> u64 {
        let (p, h, cone) = (self.position, self.cone.heading, &self.cone);
        let acute = cone.cos_half >= 0.0;
        let (rx, ry) = (x - p.x, y - p.y);
        let d2 = rx * rx + ry * ry;
        let dot = rx * h.x + ry * h.y;
        let ahead = dot >= 0.0;
        let (dot2, limit) = (dot * dot, d2 * cone.cos_half2);
        let inside = (acute & ahead & (dot2 >= limit)) | (!acute & (ahead | (dot2 <= limit)));
        let (omniscient, everything) = (self.omniscient(), self.flags & 2 != 0);
        let in_cone = everything | ((d2 != 0.0) & inside);
        let radar = (d2 <= self.radar_range2) & in_cone;
        let velodyne = d2 <= self.velodyne_range2;
        let seen = (omniscient | velodyne | radar) & (other != self.id);
        let flags = (u32::from(radar) << 31) | (u32::from(velodyne) << 30);
        if seen { detection_key(d2, slot | flags) } else { UNSEEN }
    }

    /// The detection keys of the neighbours `list` (places in `everyone`) it sees, in list
    /// order, at the front of `found`; returns that front.
    ///
    /// Where the processor has AVX2, one pass four neighbours at a time
    /// ([`listed_keys_avx2`]: gather, keys and packing in registers). Else three passes: the
    /// neighbours' coordinates into arrays ([`gather_positions`]), every neighbour's key (or
    /// [`UNSEEN`], [`ListKeysPass`]), then the seen keys packed to the front. Both give the
    /// same keys in the same order (the same operations on each neighbour).
    ///
    /// With `near` (a squared range [m²] and a mask, for lists of at most 64), bit k of the mask
    /// is set when the k-th neighbour lies within that range ([`within_reach`]).
    fn consider_listed<'f>(
        &self,
        list: &[u32],
        everyone: Everyone<'_>,
        (xs, ys, keys): (&mut Vec<f64>, &mut Vec<f64>, &mut Vec<u64>),
        near: Option<(f64, &mut u64)>,
        found: &'f mut Vec<u64>,
    ) -> &'f mut [u64] {
        let n = list.len();
        let near = near.filter(|_| n <= NEAR_MASK_BITS);
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // Room for the last group's four keys, stored whole.
            let room = first(found, n.next_multiple_of(4));
            let r2 = near.as_ref().map(|(r2, _)| *r2);
            // SAFETY: the processor has AVX2, checked just above.
            let (seen, mask) = unsafe { listed_keys_avx2(self, everyone.states, list, r2, room) };
            if let Some((_, m)) = near {
                *m = mask;
            }
            return &mut room[..seen];
        }
        let (xs, ys, keys) = (first(xs, n), first(ys, n), first(keys, n));
        first(found, n);
        gather_positions(everyone.states, list, xs, ys);
        if let Some((r2, mask)) = near {
            *mask = near_of(xs, ys, (self.position, r2));
        }
        vectorised(ListKeysPass { sight: self, xs, ys, slots: list, keys });
        let seen = pack(keys, found, UNSEEN);
        &mut found[..seen]
    }
}

/// The coordinates of the vehicles at places `slots` of `states` into `xs` and `ys`: the first
/// pass of [`Sight::consider_listed`] where the processor has no AVX2.
#[inline]
fn gather_positions(states: &[VehicleState], slots: &[u32], xs: &mut [f64], ys: &mut [f64]) {
    for ((x, y), &j) in xs.iter_mut().zip(ys.iter_mut()).zip(slots) {
        let p = states[j as usize].position;
        (*x, *y) = (p.x, p.y);
    }
}

/// The `near` of [`Sight::consider_listed`] for neighbours at (`xs`, `ys`): bit k for the k-th
/// (of at most 64) within `r2` [m²] of `p`.
fn near_of(xs: &[f64], ys: &[f64], (p, r2): (DVec2, f64)) -> u64 {
    xs.iter()
        .zip(ys)
        .take(NEAR_MASK_BITS)
        .enumerate()
        .fold(0, |mask, (k, (&x, &y))| mask | u64::from(within_reach(p, x, y, r2)) << k)
}

/// [`Sight::consider_listed`] in AVX2 registers, four neighbours at a time: each four's
/// coordinates loaded from `states`, their detection keys worked out as [`Sight::key`] works
/// them out (the same subtractions, products, sums and comparisons, no fused multiply-add, so
/// the same bits; NaN compares as there), and the seen ones stored to the front of `found`
/// (which must hold `slots.len()` rounded up to four) in list order, by a permutation
/// ([`PACK_FOUR`]). Returns how many were seen and, with `near_r2`, which of the first 64 lie
/// within it ([`within_reach`]: the same squared distance).
///
/// It replaced three passes (coordinates into arrays, keys into an array, packing) and
/// their loop set-ups, alias checks and one-at-a-time remainders, for lists of about 14.
///
/// # Safety
/// Only on a processor with AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn listed_keys_avx2(
    sight: &Sight,
    states: &[VehicleState],
    slots: &[u32],
    near_r2: Option<f64>,
    found: &mut [u64],
) -> (usize, u64) {
    use std::arch::x86_64::{
        _CMP_GE_OQ, _CMP_LE_OQ, _CMP_NEQ_UQ, _mm_castps_si128, _mm_loadu_pd, _mm_loadu_si128, _mm_set_epi32,
        _mm256_add_pd, _mm256_and_pd, _mm256_and_si256, _mm256_castpd_si256, _mm256_cmp_pd, _mm256_cvtepu32_epi64,
        _mm256_cvtpd_ps, _mm256_loadu_si256, _mm256_movemask_pd, _mm256_mul_pd, _mm256_or_pd, _mm256_or_si256,
        _mm256_permutevar8x32_epi32, _mm256_set_m128d, _mm256_set1_epi64x, _mm256_set1_pd, _mm256_slli_epi64,
        _mm256_storeu_si256, _mm256_sub_pd, _mm256_unpackhi_pd, _mm256_unpacklo_pd,
    };
    let n = slots.len();
    assert!(found.len() >= n.next_multiple_of(4), "room for whole groups of four");
    let (p, cone) = (sight.position, &sight.cone);
    let (px, py) = (_mm256_set1_pd(p.x), _mm256_set1_pd(p.y));
    let (hx, hy) = (_mm256_set1_pd(cone.heading.x), _mm256_set1_pd(cone.heading.y));
    let cos_half2 = _mm256_set1_pd(cone.cos_half2);
    let (radar2, velodyne2) = (_mm256_set1_pd(sight.radar_range2), _mm256_set1_pd(sight.velodyne_range2));
    let near2 = _mm256_set1_pd(near_r2.unwrap_or(f64::NEG_INFINITY));
    let zero = _mm256_set1_pd(0.0);
    let acute = cone.cos_half >= 0.0;
    // Whole-lane masks for `everything` and `omniscient` (all ones or none).
    let lanes = |on: bool| _mm256_set1_pd(f64::from_bits(if on { u64::MAX } else { 0 }));
    let (everything, omniscient) = (lanes(sight.flags & 2 != 0), lanes(sight.omniscient()));
    let (radar_bit, velodyne_bit) =
        (_mm256_set1_epi64x(i64::from(RADAR_REACH)), _mm256_set1_epi64x(i64::from(VELODYNE_REACH)));
    let (mut seen, mut near) = (0usize, 0u64);
    for g in (0..n).step_by(4) {
        // The group's four places (as an array and in a register); past the list's end, the
        // last one again (masked out by `valid`). Where the list holds four more, the register
        // is loaded from the list itself (a load of an array just written place by place would
        // wait for those stores to leave the store buffer).
        let (four, places, valid): ([u32; 4], _, u32) = match slots.get(g..g + 4) {
            Some(whole @ &[a, b, c, d]) => {
                // SAFETY: `whole` is four u32s (16 bytes); the load needs no alignment.
                ([a, b, c, d], unsafe { _mm_loadu_si128(whole.as_ptr().cast()) }, 0b1111)
            }
            _ => {
                let four: [u32; 4] = std::array::from_fn(|l| slots[(g + l).min(n - 1)]);
                let places = _mm_set_epi32(four[3] as i32, four[2] as i32, four[1] as i32, four[0] as i32);
                (four, places, (1 << (n - g)) - 1)
            }
        };
        // (x, y) of vehicle j: a `DVec2` is two f64 side by side (`#[repr(C)]`, x first).
        let at = |l: usize| {
            let q: &DVec2 = &states[four[l] as usize].position;
            // SAFETY: `q` points at two initialised f64s (x, then y); the load needs no alignment.
            unsafe { _mm_loadu_pd(std::ptr::from_ref(q).cast::<f64>()) }
        };
        // (x0, y0, x2, y2) and (x1, y1, x3, y3), then their even and odd lanes interleaved.
        let (even, odd) = (_mm256_set_m128d(at(2), at(0)), _mm256_set_m128d(at(3), at(1)));
        let (x, y) = (_mm256_unpacklo_pd(even, odd), _mm256_unpackhi_pd(even, odd));
        // `Sight::key`, lane by lane.
        let (rx, ry) = (_mm256_sub_pd(x, px), _mm256_sub_pd(y, py));
        let d2 = _mm256_add_pd(_mm256_mul_pd(rx, rx), _mm256_mul_pd(ry, ry));
        let dot = _mm256_add_pd(_mm256_mul_pd(rx, hx), _mm256_mul_pd(ry, hy));
        let ahead = _mm256_cmp_pd::<_CMP_GE_OQ>(dot, zero);
        let (dot2, limit) = (_mm256_mul_pd(dot, dot), _mm256_mul_pd(d2, cos_half2));
        let inside = if acute {
            _mm256_and_pd(ahead, _mm256_cmp_pd::<_CMP_GE_OQ>(dot2, limit))
        } else {
            _mm256_or_pd(ahead, _mm256_cmp_pd::<_CMP_LE_OQ>(dot2, limit))
        };
        let in_cone = _mm256_or_pd(everything, _mm256_and_pd(_mm256_cmp_pd::<_CMP_NEQ_UQ>(d2, zero), inside));
        let radar = _mm256_and_pd(_mm256_cmp_pd::<_CMP_LE_OQ>(d2, radar2), in_cone);
        let velodyne = _mm256_cmp_pd::<_CMP_LE_OQ>(d2, velodyne2);
        let visible = _mm256_or_pd(omniscient, _mm256_or_pd(velodyne, radar));
        let kept = (_mm256_movemask_pd(visible) as u32 & valid) as usize;
        if near_r2.is_some() && g < NEAR_MASK_BITS {
            let within = _mm256_movemask_pd(_mm256_cmp_pd::<_CMP_LE_OQ>(d2, near2)) as u32 & valid;
            near |= u64::from(within) << g;
        }
        // Keys: the f32 bits of d² high, the place and the reach bits low (`detection_key`).
        let high = _mm256_slli_epi64::<32>(_mm256_cvtepu32_epi64(_mm_castps_si128(_mm256_cvtpd_ps(d2))));
        let places = _mm256_cvtepu32_epi64(places);
        let reach = _mm256_or_si256(
            _mm256_and_si256(_mm256_castpd_si256(radar), radar_bit),
            _mm256_and_si256(_mm256_castpd_si256(velodyne), velodyne_bit),
        );
        let keys = _mm256_or_si256(high, _mm256_or_si256(places, reach));
        // SAFETY: `PACK_FOUR[kept]` is eight i32s (32 bytes); the load needs no alignment.
        let order = unsafe { _mm256_loadu_si256(PACK_FOUR[kept].as_ptr().cast()) };
        // SAFETY: `seen` <= `g` and `g + 4` <= `found.len()` (asserted): four u64s in bounds.
        unsafe { _mm256_storeu_si256(found.as_mut_ptr().add(seen).cast(), _mm256_permutevar8x32_epi32(keys, order)) };
        seen += kept.count_ones() as usize;
    }
    (seen, near)
}

/// For each set of four lanes kept (bit l for lane l), the 32-bit halves of those 64-bit lanes
/// moved to the front in order: the permutation [`listed_keys_avx2`] packs a group's seen keys
/// with (the rest of the lanes repeat lane 0, never read).
#[cfg(target_arch = "x86_64")]
const PACK_FOUR: [[i32; 8]; 16] = {
    let mut table = [[0; 8]; 16];
    let mut kept = 0;
    while kept < 16 {
        let mut at = 0;
        let mut lane = 0;
        while lane < 4 {
            if kept & (1 << lane) != 0 {
                table[kept][2 * at] = 2 * lane;
                table[kept][2 * at + 1] = 2 * lane + 1;
                at += 1;
            }
            lane += 1;
        }
        kept += 1;
    }
    table
};

/// The keys of a neighbour list's vehicles at (`xs`, `ys`): the second pass of
/// [`Sight::consider_listed`] where the processor has no AVX2, [`Sight::key`] on each (and the
/// reference [`listed_keys_avx2`] is tested against).
struct ListKeysPass<'a> {
    sight: &'a Sight,
    xs: &'a [f64],
    ys: &'a [f64],
    slots: &'a [u32],
    keys: &'a mut [u64],
}

impl Pass for ListKeysPass<'_> {
    type Output = ();
    #[inline(always)]
    fn run(self) {
        // A list never holds its own vehicle (`Candidates::within` leaves its id out when the
        // list is built), so no neighbour's id is read: an id that differs from ours stands in.
        let other = VehicleId(!self.sight.id.0);
        let neighbours = self.xs.iter().zip(self.ys).zip(self.slots);
        for (key, ((&x, &y), &slot)) in self.keys.iter_mut().zip(neighbours) {
            *key = self.sight.key(x, y, slot, other);
        }
    }
}

/// Where the readings find a target by the slot its detection key holds: the grid's entry, or
/// (with neighbour lists, [`NeighbourLists`]) the vehicle at that place of the query.
trait Targets: Sync {
    fn target(&self, slot: u32) -> GridEntry;
}

impl Targets for SpatialGrid {
    #[inline]
    fn target(&self, slot: u32) -> GridEntry {
        *self.get(slot)
    }
}

/// Every vehicle of the (single) ECS table, in query order.
#[derive(Clone, Copy)]
struct Everyone<'a> {
    ids: &'a [VehicleId],
    states: &'a [VehicleState],
}

impl Targets for Everyone<'_> {
    #[inline]
    fn target(&self, slot: u32) -> GridEntry {
        let (id, state) = (self.ids[slot as usize], &self.states[slot as usize]);
        GridEntry { position: state.position, velocity: state.velocity, id, index: slot }
    }
}

/// [`Sight::keys`] as a [`Pass`].
struct KeysPass<'a> {
    sight: &'a Sight,
    around: &'a Candidates,
    found: &'a mut [u64],
}

impl Pass for KeysPass<'_> {
    type Output = ();
    #[inline(always)]
    fn run(self) {
        self.sight.keys(self.around, self.found)
    }
}

/// What [`Sight::keys`] writes for a candidate not seen: no detection key is all ones (a key's
/// high word is the f32 bits of a squared distance, never all ones; its low word is a slot
/// below 2³⁰ with the reach bits, which an unseen candidate would not have set).
const UNSEEN: u64 = u64::MAX;

/// The low word of a detection key: the grid slot in the low 30 bits (grids hold fewer than
/// 2³⁰ vehicles), bit 31 set when the radar reaches the target, bit 30 when the velodyne does,
/// so the imperfect sensors need not test range and cone again.
const REACH: u32 = 0b11 << 30;
const RADAR_REACH: u32 = 1 << 31;
const VELODYNE_REACH: u32 = 1 << 30;

/// The name of the radar's detections ([`Detection::sensor`]).
pub const RADAR: &str = "radar";
/// The name of the velodyne's detections.
pub const VELODYNE: &str = "velodyne";
/// The name of an omniscient sensor's detections.
pub const OMNISCIENT: &str = "omniscient";

/// Which built-in sensor a detection with key low word `low` is named after: the radar where it
/// reaches the target, else the velodyne where it does, else the omniscient sensor (by the two
/// reach bits, one table look-up).
#[inline]
fn reached_by(low: u32) -> &'static str {
    const BY_REACH: [&str; 4] = [OMNISCIENT, VELODYNE, RADAR, RADAR];
    BY_REACH[(low >> 30) as usize]
}

/// The cone of a vehicle without a radar (never consulted: its radar range is negative).
const NO_CONE: Cone = Cone { heading: DVec2::ZERO, cos_half: 1.0, cos_half2: 1.0, everything: false };

/// Sort `found` nearest first from `from` (ties by id) and write it into `readings`.
fn write_readings(found: &mut [u64], grid: &impl Targets, from: DVec2, readings: &mut SensorReadings) {
    sort_nearest_first(found, grid, from);
    readings.0.clear();
    readings.0.extend(found.iter().map(|&key| {
        let e = grid.target(key as u32 & !REACH);
        Detection { id: e.id, position: e.position, velocity: e.velocity, sensor: reached_by(key as u32) }
    }));
}

/// Sort `found` nearest first and write what the imperfect sensors of `sight` see of it into
/// `readings`: occlusion, then dropout, then noise (the radar's when the radar sees the target,
/// else the velodyne's; an omniscient sensor is perfect), counting into `s.stats`.
#[allow(clippy::too_many_arguments)]
fn write_imperfect_readings(
    sight: &Sight,
    errors: &SensorErrors,
    draws: Draws,
    footprints: &[Footprint],
    grid: &impl Targets,
    found: &mut [u64],
    extents: &mut Vec<(f64, f64, f64)>,
    stats: &mut SensorStats,
    readings: &mut SensorReadings,
) {
    sort_nearest_first(found, grid, sight.position);
    readings.0.clear();
    extents.clear();
    let occlusion = errors.radar.occlusion || errors.velodyne.occlusion;
    for &key in found.iter() {
        let low = key as u32;
        let e = grid.target(low & !REACH);
        let relative = e.position - sight.position;
        let d2 = relative.length_squared();
        let mut hidden = false;
        if occlusion {
            let ext = extent(relative, &footprints[e.index as usize]);
            hidden = extents.iter().any(|&nearer| covers(nearer, ext));
            extents.push(ext);
        }
        // Each sensor's draws of this pair: word 0 for dropout, the others for noise.
        let sees = |reach: bool, err: &SensorError, keys: &SensorKeys| -> (bool, bool) {
            let visible = reach && !(hidden && err.occlusion);
            let kept = visible && (err.dropout <= 0.0 || keys.pair(sight.id, e.id).kept(err.dropout));
            (visible, kept)
        };
        let (radar_visible, radar_kept) = sees(low & RADAR_REACH != 0, &errors.radar, &draws.radar);
        let (velodyne_visible, velodyne_kept) = sees(low & VELODYNE_REACH != 0, &errors.velodyne, &draws.velodyne);
        let noise = if sight.omniscient() {
            None
        } else if radar_kept {
            Some((&errors.radar, &draws.radar))
        } else if velodyne_kept {
            Some((&errors.velodyne, &draws.velodyne))
        } else {
            if radar_visible || velodyne_visible {
                stats.missed_by_dropout += 1;
            } else {
                stats.missed_by_occlusion += 1;
            }
            continue;
        };
        let sensor = match (radar_kept, velodyne_kept) {
            (true, _) => RADAR,
            (false, true) => VELODYNE,
            _ => reached_by(low),
        };
        let mut detection = Detection { id: e.id, position: e.position, velocity: e.velocity, sensor };
        if let Some((err, keys)) = noise.filter(|(err, _)| err.is_noisy()) {
            add_noise(&mut detection, sight.position, relative, d2, err, keys.pair(sight.id, e.id).normals());
        }
        readings.0.push(detection);
        stats.detections += 1;
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

/// Whether [`write_radar_error_readings`] gives what [`write_imperfect_readings`] gives: no
/// occlusion, and a perfect velodyne (errors on the radar only, the common case).
fn radar_errors_only(errors: &SensorErrors) -> bool {
    let v = &errors.velodyne;
    !errors.radar.occlusion && !v.occlusion && v.dropout <= 0.0 && !v.is_noisy()
}

/// [`write_imperfect_readings`] when only the radar has errors ([`radar_errors_only`]): the
/// same readings and counts, the same draws, in one straight loop (no occlusion extents, no
/// per-sensor choice of draws to carry).
#[allow(clippy::too_many_arguments)]
fn write_radar_error_readings(
    sight: &Sight,
    err: &SensorError,
    draws: Draws,
    grid: &impl Targets,
    found: &mut [u64],
    stats: &mut SensorStats,
    readings: &mut SensorReadings,
) {
    sort_nearest_first(found, grid, sight.position);
    readings.0.clear();
    readings.0.reserve(found.len());
    let (dropout, noisy) = (err.dropout > 0.0, err.is_noisy());
    for &key in found.iter() {
        let low = key as u32;
        let e = grid.target(low & !REACH);
        let mut detection = Detection { id: e.id, position: e.position, velocity: e.velocity, sensor: reached_by(low) };
        if !sight.omniscient() && low & RADAR_REACH != 0 && (dropout || noisy) {
            let pair = draws.radar.pair(sight.id, e.id);
            if !dropout || pair.kept(err.dropout) {
                if noisy {
                    let relative = e.position - sight.position;
                    let d2 = relative.length_squared();
                    add_noise(&mut detection, sight.position, relative, d2, err, pair.normals());
                }
            } else if low & VELODYNE_REACH == 0 {
                stats.missed_by_dropout += 1;
                continue;
            } else {
                detection.sensor = VELODYNE;
            }
        }
        readings.0.push(detection);
        stats.detections += 1;
    }
}

/// One ECS table of sensing vehicles as bevy's contiguous access hands it out: a slice of each
/// component (of the optional ones when the table has them), whether the table's vehicles are
/// omniscient, and the readings to write.
#[derive(Clone, Copy)]
struct SensingTable<'a> {
    ids: &'a [VehicleId],
    states: &'a [VehicleState],
    radars: Option<&'a [Radar]>,
    velodynes: Option<&'a [Velodyne]>,
    omniscient: bool,
    errors: Option<&'a [SensorErrors]>,
}

/// What every chunk reads: the grid, the footprints of its entries (filled only when some
/// sensor has occlusion on) and the tick's draws.
#[derive(Clone, Copy)]
struct SenseInput<'a> {
    grid: &'a SpatialGrid,
    footprints: &'a [Footprint],
    draws: Draws,
}

/// Fill the readings of a contiguous chunk of sensing vehicles (items `start..` of `table`)
/// from the (read-only) grid.
fn sense_chunk(
    input: SenseInput<'_>,
    table: SensingTable<'_>,
    start: usize,
    chunk: &mut [SensorReadings],
    s: &mut SenseScratch,
) {
    let grid = input.grid;
    let mut gathered: Option<Gathered> = None;
    let omniscient = table.omniscient;
    for (k, readings) in chunk.iter_mut().enumerate() {
        let i = start + k;
        let (id, state) = (&table.ids[i], &table.states[i]);
        let (radar, velodyne) = (table.radars.map(|r| &r[i]), table.velodynes.map(|v| &v[i]));
        let errors = table.errors.map(|e| &e[i]);
        let sight = Sight::new(*id, state, radar, velodyne, omniscient, &mut s.half_cos);
        if omniscient {
            if gathered != Some(Gathered::All) {
                s.around.clear();
                grid.gather_all(&mut s.around);
                gathered = Some(Gathered::All);
            }
        } else {
            gather_within(grid, state.position, Shape::of(radar, velodyne).range(), &mut gathered, &mut s.around);
        }
        let found = sight.consider_all(&s.around, &mut s.keys, &mut s.found);
        write_found(&sight, errors, input, grid, found, (&mut s.extents, &mut s.stats), readings);
    }
}

/// Write what `sight` sees of the targets `found` (detection keys of `targets`' slots) into
/// `readings`, through the errors of its sensors if it has some, counting into `stats`.
fn write_found(
    sight: &Sight,
    errors: Option<&SensorErrors>,
    input: SenseInput<'_>,
    targets: &impl Targets,
    found: &mut [u64],
    (extents, stats): (&mut Vec<(f64, f64, f64)>, &mut SensorStats),
    readings: &mut SensorReadings,
) {
    match errors {
        Some(errors) if radar_errors_only(errors) => {
            write_radar_error_readings(sight, &errors.radar, input.draws, targets, found, stats, readings)
        }
        Some(errors) => write_imperfect_readings(
            sight,
            errors,
            input.draws,
            input.footprints,
            targets,
            found,
            extents,
            stats,
            readings,
        ),
        None => {
            stats.detections += found.len() as u64;
            write_readings(found, targets, sight.position, readings);
        }
    }
}

/// Verlet neighbour lists of the sensing vehicles ("skin" lists, Verlet 1967; the cell-list
/// and skin scheme of molecular dynamics, e.g. Allen & Tildesley, *Computer Simulation of
/// Liquids*, §5.3): each vehicle's list holds every vehicle that was within its sensor range
/// plus a skin when the lists were built. While no two vehicles that could meet have closed
/// in on each other by the skin since then, every vehicle within a sensor's range now is on
/// its list, so a sensor tick tests only its list: no grid rebuild, no gather of the cells
/// around, and a circle of candidates rather than a square of cells (about 18 instead of 30 on
/// the benchmark's highway). A tick checks the displacements (in the pass that senses,
/// [`sense_with_kept_lists`], or one of their own, [`NeighbourLists::moved_together`]) and
/// rebuilds the lists over a grid when two neighbours'
/// displacements differ by the skin or one moved far, when the vehicles or their sensors'
/// ranges changed, or when the typical range did.
///
/// The test is on displacements relative to each other, not on each vehicle's own: traffic
/// moves together (a highway's vehicles at 20-30 m/s drift apart by a few m/s), so lists that
/// a test of each vehicle's own displacement against half the skin rebuilt every half second
/// hold for seconds (the "moving frame" of Verlet lists in a flowing system).
///
/// The readings are those of the grid scan, bit for bit: the same vehicles pass the same range
/// and cone tests on the same coordinates, and the detections are ordered by distance, then
/// id, whichever order the candidates came in. Used when every vehicle lies in one ECS table
/// and every one of them senses with a bounded range (the common case); otherwise every tick
/// scans the grid.
#[derive(Debug, Default)]
struct NeighbourLists {
    /// Every vehicle's id at the build, in query order (a list names vehicles by place).
    ids: Vec<VehicleId>,
    /// Every vehicle's position at the build [m].
    anchors: Vec<DVec2>,
    /// Every vehicle's sensors at the build.
    shapes: Vec<Shape>,
    /// Every vehicle's heading at the build (a unit vector).
    headings: Vec<DVec2>,
    /// The wifi range at the build [m] (0 without V2V): every list holds at least that far
    /// all around (or its whole sensor range, when shorter), so the wifi round can use them.
    floor: f64,
    /// Skin of the build [m] (0: no lists built yet).
    skin: f64,
    /// How far every list reaches all around (the shortest of [`Reach::around`]) [m].
    around: f64,
    /// Every vehicle's neighbours, nearest first at the build (so that a tick's detections
    /// arrive nearly sorted), as places in the query: vehicle i's are
    /// `neighbours[starts[i]..starts[i + 1]]`. One array, in query order, so that a pass over
    /// the vehicles reads it straight through (a list per vehicle, each its own allocation,
    /// made every list a cache miss: two thirds of a wifi round's samples).
    lists: Lists,
    /// Each vehicle's drift cell (see [`NeighbourLists::moved_together`]), in query order: an
    /// index into the cells occupied at the build.
    cell_of: Vec<u32>,
    /// How many drift cells are occupied.
    cells: usize,
    /// The pairs of occupied drift cells that touch (a cell with itself too), each once.
    touching: Vec<[u32; 2]>,
    /// Farthest any vehicle may move from its anchor before the lists are built again [m]:
    /// vehicles in drift cells that do not touch cannot come within sensor range until then.
    max_drift: f64,
    /// Builds so far.
    builds: u64,
    /// Sensor ticks that kept the lists in one pass ([`sense_with_kept_lists`]), and those whose
    /// one pass was thrown away.
    kept_in_one_pass: u64,
    thrown_away: u64,
    /// Sensor ticks since the last build that kept the lists.
    kept_since_build: u32,
    /// Which neighbours on each vehicle's list (bit k: the list's k-th; lists of at most 64)
    /// lay within the wifi range (squared: `near_r2` [m²]) at the instant `near_at`, in query
    /// order: noted by the sensor tick at the instant the wifi round asked for ([`NearWanted`])
    /// from the coordinates it gathered for its keys, for the round to take ([`SensorGrid::near`])
    /// instead of testing every neighbour on the list again.
    near: Vec<u64>,
    near_at: Option<SimTime>,
    near_r2: f64,
    /// The instant the sensors last found the lists to hold (or built them) for the vehicles'
    /// states then. States change only in the dynamics, at the end of an instant (after sensing,
    /// communication and control, see [`crate::vehicles::LanePositionsAt`]), so the lists hold
    /// for every module at that instant: the wifi round then need not test the drift again.
    held_at: Option<SimTime>,
}

/// Per drift cell, the smallest and largest displacement since the build of its vehicles along
/// x and y [m]: `[min x, max x, min y, max y]`.
type DriftBox = [f64; 4];

/// A box holding nothing yet.
const EMPTY_BOX: DriftBox = [f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY];

/// Scratch of [`NeighbourLists::moved_together`], kept between ticks.
#[derive(Debug, Default)]
pub(crate) struct DriftScratch {
    boxes: Vec<DriftBox>,
    parts: Vec<DriftPart>,
}

/// What one chunk of vehicles found of their displacements since the build (none yet: 0, all
/// finite, no runs).
#[derive(Debug)]
struct DriftPart {
    /// The largest squared displacement [m²].
    farthest: f64,
    /// Whether every displacement is finite.
    finite: bool,
    /// Whether a vehicle turned by [`TURN`] or more.
    turned: bool,
    /// Each run of vehicles in one drift cell: the cell and their box of displacements.
    runs: Vec<(u32, DriftBox)>,
}

impl Default for DriftPart {
    fn default() -> Self {
        DriftPart { farthest: 0.0, finite: true, turned: false, runs: Vec::new() }
    }
}

impl DriftPart {
    /// Empty again, as [`DriftPart::default`] (keeping the runs' allocation).
    fn clear(&mut self) {
        self.runs.clear();
        (self.farthest, self.finite, self.turned) = (0.0, true, false);
    }

    /// Add the displacements of the vehicles at `states` from their `anchors`, in drift cells
    /// `cells`, and whether one turned from its heading `headings` by [`TURN`]. Vehicles near
    /// each other are mostly next to each other in the query: a run of them in one cell is
    /// boxed in registers and noted once (a merge into memory per vehicle waited on the last
    /// one's store).
    fn add(&mut self, anchors: &[DVec2], headings: &[DVec2], states: &[VehicleState], cells: &[u32]) {
        let Some(&first) = cells.first() else { return };
        let (mut current, mut run) = (first, EMPTY_BOX);
        let (mut farthest, mut finite, mut turned) = (self.farthest, self.finite, self.turned);
        let cos_turn = TURN.cos();
        for (((anchor, heading), state), &cell) in anchors.iter().zip(headings).zip(states).zip(cells) {
            // (A NaN heading counts as turned.)
            let along = state.heading().dot(*heading);
            turned |= along.is_nan() | (along <= cos_turn);
            let d = state.position - *anchor;
            let d2 = d.length_squared();
            finite &= d2.is_finite();
            farthest = farthest.max(d2);
            if cell != current {
                self.runs.push((current, run));
                (current, run) = (cell, EMPTY_BOX);
            }
            run = [run[0].min(d.x), run[1].max(d.x), run[2].min(d.y), run[3].max(d.y)];
        }
        self.runs.push((current, run));
        (self.farthest, self.finite, self.turned) = (farthest, finite, turned);
    }
}

/// How far all around each vehicle the neighbour lists must reach for the modules that read
/// them besides the sensors \[m\] (the wifi round asks for its range, [`super::v2v`]); within the
/// sensors' own largest range, the lists then hold everyone that close (see `Reach`). A
/// resource those modules set, so that sensing depends on none of them. 0: the sensors' needs.
#[derive(Resource, Debug, Clone, Copy, Default, PartialEq)]
pub struct ListFloor(pub f64);

/// The instant the wifi round expects to run next (its last round plus the spacing of its last
/// two, [`super::v2v`]): the sensor tick at that instant notes which neighbours on each list
/// lie within the [`ListFloor`] (`SensorGrid::near`). A wrong guess costs only that the
/// round tests the neighbours itself.
#[derive(Resource, Debug, Clone, Copy, Default, PartialEq)]
pub struct NearWanted(pub Option<SimTime>);

/// The longest neighbour list whose neighbours within the wifi range are noted ([`NearWanted`]):
/// one bit each in a `u64`. A longer list's mask stays 0, and the wifi round tests it itself.
pub(crate) const NEAR_MASK_BITS: usize = u64::BITS as usize;

/// The drift cells' side as a multiple of the widest list's radius (range plus skin): wider
/// cells let vehicles move farther between builds (`max_drift`), narrower ones hold fewer
/// vehicles, whose displacements differ less on a curve.
const DRIFT_CELL: f64 = 4.0;

/// How far a vehicle may turn from its heading at the build of the lists [rad] before they are
/// built again: a list leaves out what lies behind the radar cone beyond the all-around reach
/// ([`Reach`]), which a turn brings into view. 30°: lane changes and long bends keep them.
const TURN: f64 = std::f64::consts::FRAC_PI_6;

/// A vehicle's sensors as its neighbour list was built for: radar range [m] and full opening
/// angle [rad] (0 and 0 without a radar), velodyne range [m] (0 without).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Shape {
    radar: f64,
    angle: f64,
    velodyne: f64,
}

/// What `typical_range` and the neighbour lists need to know of a run of `Shape`s, found
/// in the pass that makes them (split over the threads) and merged in order: the first bounded
/// range, whether every bounded range equals it, and whether every range is finite.
#[derive(Debug, Clone, Copy)]
#[repr(align(128))]
pub struct ShapeSummary {
    first: Option<u64>,
    uniform: bool,
    finite: bool,
    /// Every shape equals the one at its place in the neighbour lists' last build (their
    /// [`NeighbourLists::hold`] compared the whole slice again, serially, every sensor tick).
    as_built: bool,
}

impl Default for ShapeSummary {
    fn default() -> Self {
        ShapeSummary { first: None, uniform: true, finite: true, as_built: true }
    }
}

impl ShapeSummary {
    fn add(&mut self, shape: &Shape) {
        let r = shape.range();
        self.finite &= r.is_finite();
        if bounded(&r) {
            match self.first {
                None => self.first = Some(r.to_bits()),
                Some(bits) => self.uniform &= bits == r.to_bits(),
            }
        }
    }

    /// This run followed by `next`.
    fn then(&mut self, next: &ShapeSummary) {
        self.finite &= next.finite;
        self.as_built &= next.as_built;
        match (self.first, next.first) {
            (None, _) => (self.first, self.uniform) = (next.first, next.uniform),
            (Some(_), None) => {}
            (Some(a), Some(b)) => self.uniform &= next.uniform && a == b,
        }
    }

    /// [`typical_range`] of the bounded ranges, when every one is the same (or there is none).
    fn typical(&self) -> Option<f64> {
        match self.first {
            None => Some(typical_range(&mut [])),
            Some(bits) => self.uniform.then_some(f64::from_bits(bits)),
        }
    }
}

impl Shape {
    /// No radar, no velodyne.
    const NONE: Shape = Shape { radar: 0.0, angle: 0.0, velodyne: 0.0 };

    fn of(radar: Option<&Radar>, velodyne: Option<&Velodyne>) -> Shape {
        Shape {
            radar: radar.map_or(0.0, |r| r.range),
            angle: radar.map_or(0.0, |r| r.angle),
            velodyne: velodyne.map_or(0.0, |v| v.range),
        }
    }

    /// Its largest range [m] (0 without radar and velodyne).
    fn range(&self) -> f64 {
        self.radar.max(self.velodyne)
    }

    /// How far its list reaches all around [m]: the velodyne's range, or the wifi range
    /// `floor` [m] where that is longer (within the sensors' largest range).
    fn around(&self, floor: f64) -> f64 {
        self.velodyne.max(floor.min(self.range()))
    }
}

/// Which vehicles around one vehicle its neighbour list holds: all within its all-around reach
/// plus the skin, and, up to its radar's range plus the skin, those within the radar cone
/// widened by the turn the lists allow ([`TURN`]) and by the bearing a relative displacement
/// under the skin can change (asin(skin / d) at distance d). While the lists hold (no two
/// vehicles closed in by the skin, nobody turned by [`TURN`]), any vehicle that comes within the
/// velodyne's or the wifi's range or into the radar cone was within this reach at the build:
/// the angle between where it was and the heading then is at most the cone's half angle, plus
/// the turn, plus the bearing change. On a road this leaves out the vehicles behind beyond the
/// velodyne (a fifth of the list on the benchmark's highway).
struct Reach {
    around2: f64,
    heading: DVec2,
    /// Half the radar's opening angle plus [`TURN`] [rad] (none without a radar), and its
    /// cosine and sine.
    half: Option<(f64, f64, f64)>,
    skin: f64,
}

impl Reach {
    fn new(shape: &Shape, heading: DVec2, floor: f64, skin: f64) -> Reach {
        let around = shape.around(floor) + skin;
        let half = (shape.radar > 0.0).then(|| {
            let half = 0.5 * shape.angle + TURN;
            let (sin, cos) = half.sin_cos();
            (half, cos, sin)
        });
        Reach { around2: around * around, heading, half, skin }
    }

    /// Whether the vehicle at `relative` [m] (squared distance `d2`, within the list's radius)
    /// belongs on the list.
    fn holds(&self, relative: DVec2, d2: f64) -> bool {
        let Some((half, cos, sin)) = self.half.filter(|_| d2 > self.around2) else {
            return d2 <= self.around2;
        };
        let d = d2.sqrt();
        // sin of the bearing change; under 1 beyond the all-around reach (d > skin).
        let x = (self.skin / d).min(1.0);
        if half <= std::f64::consts::FRAC_PI_2 {
            // The limit half + asin(x) is under π: its cosine by the angle-sum formula (a build
            // tests every neighbour beyond the velodyne: no asin and cos each).
            return relative.dot(self.heading) >= d * (cos * (1.0 - x * x).sqrt() - sin * x);
        }
        let limit = half + x.asin();
        // (A NaN limit, from a NaN angle, keeps everything.)
        limit.is_nan() || limit >= std::f64::consts::PI || relative.dot(self.heading) >= d * limit.cos()
    }
}

/// Neighbour lists in one array ([`NeighbourLists::lists`]).
#[derive(Debug, Default)]
pub(crate) struct Lists {
    starts: Vec<u32>,
    neighbours: Vec<u32>,
}

impl Lists {
    /// Number of vehicles.
    pub(crate) fn len(&self) -> usize {
        self.starts.len().saturating_sub(1)
    }

    /// The neighbours of the vehicle at place `i`.
    #[inline]
    pub(crate) fn of(&self, i: usize) -> &[u32] {
        &self.neighbours[self.starts[i] as usize..self.starts[i + 1] as usize]
    }
}

/// The neighbour lists and this tick's ranges (scratch), kept between ticks.
#[derive(Debug, Default)]
struct Neighbours {
    lists: NeighbourLists,
    shapes_now: Vec<Shape>,
    /// Scratch of [`NeighbourLists::moved_together`] and of the drift cells' build.
    drift: DriftScratch,
    keys: Vec<(i64, i64)>,
}

/// The skin of the neighbour lists as a share of the typical sensor range: wider lists cost
/// more tests per tick, narrower ones more builds. At 100 m, 20 m: a build once neighbours
/// 10 m/s apart in speed have driven 2 s.
const SKIN_SHARE: f64 = 0.2;

impl SensorGrid {
    /// The neighbour lists of the vehicles `ids` at `states` (every vehicle, in query order),
    /// when they hold every vehicle within `range` [m] of each: the lists of the same vehicles
    /// in the same order, each at least `range` plus the skin wide, and no two neighbours
    /// closed in by the skin since they were built ([`NeighbourLists::moved_together`], on
    /// `parallelism`, with its `scratch`). For modules that look around the vehicles at the
    /// same instant as the sensors (the wifi round), so that one search serves both.
    ///
    /// At the instant `now` of a sensor tick that found them holding (or built them), only that
    /// the vehicles are the build's is checked: the states are the ones the sensors tested.
    pub(crate) fn lists_within(
        &self,
        ids: &[VehicleId],
        states: &[VehicleState],
        range: f64,
        (parallelism, now): (Parallelism, SimTime),
        scratch: &mut DriftScratch,
    ) -> Option<&Lists> {
        let lists = &self.neighbours.lists;
        // `moved_together` also checks that these are the vehicles of the build (one list each).
        let wide = lists.skin > 0.0 && lists.around >= range;
        let tested = || lists.held_at == Some(now) && lists.of_vehicles(Everyone { ids, states });
        (wide && (tested() || lists.moved_together(Everyone { ids, states }, parallelism, scratch)))
            .then_some(&lists.lists)
    }
}

impl SensorGrid {
    /// Which neighbours on each vehicle's list lie within `range` [m] (bit k: the list's k-th,
    /// for lists of at most 64), by place in the query, when the sensor tick at `now` noted
    /// them ([`NearWanted`]) for that range: the same test as [`super::grid::within_reach`] on
    /// the same coordinates (states change only in the dynamics, after every other module).
    /// Only with the lists [`SensorGrid::lists_within`] gave at `now`.
    pub(crate) fn near(&self, range: f64, now: SimTime) -> Option<&[u64]> {
        let lists = &self.neighbours.lists;
        let noted = lists.near_at == Some(now) && lists.held_at == Some(now) && lists.near_r2 == range * range;
        (noted && lists.near.len() == lists.lists.len()).then_some(&lists.near[..])
    }
}

impl NeighbourLists {
    /// The wifi masks `near` sized for `n` vehicles: longer only while the world grows, and
    /// written only when asked for.
    fn size_near(&mut self, n: usize) {
        if self.near.len() != n {
            self.near.resize(n, 0);
        }
    }

    /// Whether the lists still hold every vehicle within sensor range of each: the same
    /// vehicles in the same order, the same sensors, wifi range and skin, and the vehicles moved
    /// together ([`NeighbourLists::moved_together`], on `parallelism`, with its `scratch`).
    ///
    /// `shapes_as_built`: whether this tick's shapes are the build's (`self.shapes`), found by
    /// the pass that made them ([`ShapeSummary`]).
    fn hold(
        &self,
        everyone: Everyone<'_>,
        (shapes_as_built, floor, skin): (bool, f64, f64),
        parallelism: Parallelism,
        scratch: &mut DriftScratch,
    ) -> bool {
        self.skin == skin
            && self.floor == floor
            && shapes_as_built
            && self.moved_together(everyone, parallelism, scratch)
    }

    /// Whether `everyone` are the vehicles of the build, in the same order (one list each).
    fn of_vehicles(&self, everyone: Everyone<'_>) -> bool {
        self.ids == everyone.ids && everyone.states.len() == self.anchors.len()
    }

    /// Whether `everyone` are the vehicles of the build, in the same order, and no two of them
    /// that could now be within sensor range of each other have closed in by (just under) the
    /// skin since: then every vehicle within range of another now was within its range plus
    /// the skin at the build, on its list (the margin covers rounding; a NaN or infinite
    /// position fails).
    ///
    /// With d_i a vehicle's displacement since the build, two vehicles closed in by at most
    /// |d_i - d_j|. The anchors (positions at the build) lie in square drift cells, each side
    /// [`DRIFT_CELL`] times the widest list radius. Two vehicles in cells that do not touch were
    /// more than a side apart, so while no vehicle moved more than `max_drift` they are still
    /// farther apart than any sensor reaches. For two in cells that touch, |d_i - d_j| is at
    /// most the distance across the two cells' boxes of displacements (each cell's smallest
    /// and largest x and y), which must stay under the skin. Vehicles driving together move
    /// alike whatever their speed, so their lists hold until speeds that differ have opened or
    /// closed a gap of the skin, or a vehicle drove `max_drift`; when every displacement is
    /// under half the skin (the test of each vehicle on its own) they hold whatever the cells.
    /// One pass over the positions, then one over the touching cells.
    pub(crate) fn moved_together(
        &self,
        everyone: Everyone<'_>,
        parallelism: Parallelism,
        scratch: &mut DriftScratch,
    ) -> bool {
        let n = self.anchors.len();
        if !self.of_vehicles(everyone) || self.cell_of.len() != n || self.headings.len() != n {
            return false;
        }
        // The pass over the positions (most of the test: they come from memory) split over
        // the threads, each chunk boxing its runs; the runs merged in chunk order.
        let DriftScratch { boxes, parts } = scratch;
        let chunks = parallelism.chunks_for(n);
        parts.iter_mut().take(chunks).for_each(DriftPart::clear);
        // (Parts made for this call start empty too: `DriftPart::default`.)
        parallelism.for_each_chunk_at(&mut vec![(); n], parts, |start, chunk, part| {
            let r = start..start + chunk.len();
            part.add(
                &self.anchors[r.clone()],
                &self.headings[r.clone()],
                &everyone.states[r.clone()],
                &self.cell_of[r],
            );
        });
        self.drifted_together(parts.iter().take(chunks), boxes)
    }

    /// The second half of [`NeighbourLists::moved_together`]: whether the displacements every
    /// chunk found (`parts`, in chunk order) keep the lists; `boxes` is scratch.
    fn drifted_together<'p>(&self, parts: impl Iterator<Item = &'p DriftPart>, boxes: &mut Vec<DriftBox>) -> bool {
        boxes.clear();
        boxes.resize(self.cells, EMPTY_BOX);
        let (mut farthest, mut finite, mut turned) = (0.0f64, true, false);
        for part in parts {
            farthest = farthest.max(part.farthest);
            finite &= part.finite;
            turned |= part.turned;
            for (cell, run) in &part.runs {
                let b = &mut boxes[*cell as usize];
                *b = [b[0].min(run[0]), b[1].max(run[1]), b[2].min(run[2]), b[3].max(run[3])];
            }
        }
        let half = 0.49 * self.skin;
        if !finite || turned || farthest > self.max_drift * self.max_drift {
            return false;
        }
        if farthest <= half * half {
            return true;
        }
        let limit = (2.0 * half) * (2.0 * half);
        self.touching.iter().all(|&[a, b]| {
            let (p, q) = (&boxes[a as usize], &boxes[b as usize]);
            let dx = (p[1] - q[0]).max(q[1] - p[0]);
            let dy = (p[3] - q[2]).max(q[3] - p[2]);
            dx * dx + dy * dy <= limit
        })
    }

    /// Place the anchors (just built, with `shapes` and `skin` [m]) in drift cells and find
    /// the cells that touch (see [`NeighbourLists::moved_together`]); `keys` is scratch.
    fn place_in_drift_cells(&mut self, keys: &mut Vec<(i64, i64)>) {
        let widest = self.shapes.iter().map(Shape::range).fold(0.0, f64::max) + self.skin;
        let side = DRIFT_CELL * widest;
        // Non-touching cells are more than a side apart; each of two vehicles may close in by
        // `max_drift`, and must stay farther apart than the widest range (a margin for rounding).
        self.max_drift = 0.49 * (side - (widest - self.skin));
        let key = |p: DVec2| ((p.x / side).floor() as i64, (p.y / side).floor() as i64);
        keys.clear();
        keys.extend(self.anchors.iter().map(|&p| key(p)));
        keys.sort_unstable();
        keys.dedup();
        self.cells = keys.len();
        let place = |k: (i64, i64)| keys.binary_search(&k).ok().map(|c| c as u32);
        self.cell_of.clear();
        self.cell_of.extend(self.anchors.iter().map(|&p| place(key(p)).unwrap_or(0)));
        self.touching.clear();
        for (a, &(x, y)) in keys.iter().enumerate() {
            // Each touching pair once: the cell itself and the neighbours after it.
            for (dx, dy) in [(0, 0), (0, 1), (1, -1), (1, 0), (1, 1)] {
                if let Some(b) = place((x.saturating_add(dx), y.saturating_add(dy))) {
                    self.touching.push([a as u32, b]);
                }
            }
        }
    }
}

/// Where a sensor tick finds the neighbour lists: built this tick over the grid with the skin
/// [m] and the wifi range `floor` [m] ([`Reach`]; each chunk into its thread's
/// [`SenseScratch::built`], joined after the tick), or kept.
#[derive(Clone, Copy)]
enum Listing<'a> {
    Build { skin: f64, floor: f64 },
    Kept(&'a Lists),
}

/// Fill the readings of a contiguous chunk of sensing vehicles (items `start..` of `table`,
/// which is every vehicle, `everyone`) from their neighbour lists; with `near_r2` [m²], also
/// note in `near` which neighbours on each list lie that close ([`Sight::consider_listed`]).
fn sense_listed(
    input: SenseInput<'_>,
    table: SensingTable<'_>,
    everyone: Everyone<'_>,
    (listing, near_r2): (Listing<'_>, Option<f64>),
    (start, chunk, near): (usize, &mut [SensorReadings], &mut [u64]),
    s: &mut SenseScratch,
) {
    let grid = input.grid;
    let mut gathered: Option<Gathered> = None;
    s.built.clear();
    s.built_ends.clear();
    s.built_from = matches!(listing, Listing::Build { .. }).then_some(start);
    for (k, readings) in chunk.iter_mut().enumerate() {
        let i = start + k;
        let (id, state) = (table.ids[i], &table.states[i]);
        let (radar, velodyne) = (table.radars.map(|r| &r[i]), table.velodynes.map(|v| &v[i]));
        let list = match listing {
            Listing::Kept(lists) => lists.of(i),
            Listing::Build { skin, floor } => {
                let shape = Shape::of(radar, velodyne);
                let radius = shape.range() + skin;
                gather_within(grid, state.position, radius, &mut gathered, &mut s.around);
                s.around.within(state.position, radius, id, &mut s.marks, &mut s.slots);
                let reach = Reach::new(&shape, state.heading(), floor, skin);
                s.keys.clear();
                s.keys.extend(s.slots.iter().filter_map(|&slot| {
                    let e = grid.get(slot);
                    let relative = e.position - state.position;
                    let d2 = relative.length_squared();
                    reach.holds(relative, d2).then(|| detection_key(d2, e.index))
                }));
                s.keys.sort_unstable();
                let begin = s.built.len();
                s.built.extend(s.keys.iter().map(|&key| key as u32));
                s.built_ends.push(s.built.len() as u32);
                &s.built[begin..]
            }
        };
        let sight = Sight::new(id, state, radar, velodyne, false, &mut s.half_cos);
        // (A list longer than a mask is left to the wifi round: its mask stays 0.)
        let near = near_r2.map(|r2| {
            near[k] = 0;
            (r2, &mut near[k])
        });
        let found = sight.consider_listed(list, everyone, (&mut s.xs, &mut s.ys, &mut s.list_keys), near, &mut s.found);
        let errors = table.errors.map(|e| &e[i]);
        write_found(&sight, errors, input, &everyone, found, (&mut s.extents, &mut s.stats), readings);
    }
}

/// Whether either sensor of `e` hides targets behind nearer ones (then every vehicle's
/// [`Footprint`] is needed).
fn occludes(e: &SensorErrors) -> bool {
    e.radar.occlusion || e.velodyne.occlusion
}

/// Whether a sensor range `r` [m] bounds what the sensor sees (positive and finite): the ranges
/// [`typical_range`] takes the median of.
fn bounded(r: &f64) -> bool {
    *r > 0.0 && r.is_finite()
}

/// Side of the sensor grid's cells [m]: the median of the sensing vehicles' positive ranges
/// (100 m when none has one). `ranges` is scratch space, reused between ticks.
fn typical_range(ranges: &mut [f64]) -> f64 {
    let Some(&first) = ranges.first() else {
        return 100.0;
    };
    // Mostly every vehicle carries the same sensors: one pass that compares (a tenth of the
    // selection's time, which ran on one thread every sensor tick).
    if ranges.iter().all(|r| r.to_bits() == first.to_bits()) {
        return first;
    }
    let middle = ranges.len() / 2;
    let (_, median, _) = ranges.select_nth_unstable_by(middle, f64::total_cmp);
    *median
}

/// Rebuild the sensor grid and fill every sensing vehicle's [`SensorReadings`], nearest first.
///
/// The grid's cells are as large as the median bounded range, so a typical vehicle sees only
/// vehicles of its own cell and the eight around it, and one of longer range searches as many
/// cells around it as its range reaches. Vehicles are visited in query order (spawn order,
/// which keeps each one's components in cache lines next to the previous one's); the candidates
/// around a cell are gathered into a small buffer and reused while consecutive vehicles share
/// that cell. The vehicles are cut into contiguous chunks over [`Parallelism::threads`]
/// threads; each vehicle's readings depend only on the grid and itself, so the split never
/// changes them.
#[allow(clippy::type_complexity, clippy::too_many_arguments)]
pub fn sense_vehicles(
    mut grid: ResMut<SensorGrid>,
    parallelism: Res<Parallelism>,
    clock: Res<SimClock>,
    seed: Option<Res<SimSeed>>,
    mut stats: ResMut<SensorStats>,
    everyone: EveryoneQuery,
    mut sensing: SensingQuery,
    mut scratch: Local<Vec<SenseScratch>>,
    mut shape_parts: Local<Vec<ShapeSummary>>,
    mut ranges: Local<Vec<f64>>,
    mut footprints: Local<Vec<Footprint>>,
    asked: Option<Res<ListFloor>>,
    near_wanted: Option<Res<NearWanted>>,
) {
    let SensorGrid { grid, neighbours } = &mut *grid;
    if sensing.is_empty() {
        return;
    }
    let draws = Draws::new(seed.map_or(0, |s| s.0), clock.now.0);
    let floor = asked.map_or(0.0, |f| f.0);
    let near_r2 = (near_wanted.is_some_and(|w| w.0 == Some(clock.now)) && floor > 0.0).then_some(floor * floor);
    let input = (&*grid, draws, floor, near_r2);
    let kept =
        sense_with_kept_lists(neighbours, input, (*parallelism, clock.now), &everyone, &mut sensing, &mut scratch);
    if !kept {
        sense_by_shapes(
            (grid, neighbours),
            (*parallelism, clock.now),
            (draws, floor, near_r2),
            (&everyone, &mut sensing),
            (&mut scratch, &mut shape_parts, &mut ranges, &mut footprints),
        );
    }
    for s in scratch.iter_mut() {
        stats.add(&s.stats);
        s.stats = SensorStats::default();
    }
}

/// The query of the vehicles that sense ([`sense_vehicles`]).
type SensingQuery<'w, 's> = Query<
    'w,
    's,
    (
        &'static VehicleId,
        &'static VehicleState,
        Option<&'static Radar>,
        Option<&'static Velodyne>,
        Has<Omniscient>,
        Option<&'static SensorErrors>,
        &'static mut SensorReadings,
    ),
>;

/// The query of every vehicle (the targets, [`sense_vehicles`]).
type EveryoneQuery<'w, 's> = Query<'w, 's, (&'static VehicleId, &'static VehicleState, Option<&'static VehicleSize>)>;

/// Whether the sensing vehicles are one non-empty ECS table holding every vehicle, `ids` (those
/// of [`one_table`]), none of them omniscient: where the neighbour lists serve.
fn senses_everyone(sensing: &SensingQuery<'_, '_>, ids: &[VehicleId]) -> bool {
    let readonly = sensing.as_readonly();
    let Ok(tables) = readonly.contiguous_iter() else { return false };
    let mut full = tables.filter(|t| !t.0.is_empty());
    match (full.next(), full.next()) {
        (Some((sensing_ids, _, _, _, omniscient, _, _)), None) => !omniscient && sensing_ids == ids,
        _ => false,
    }
}

/// The ids and states of the one non-empty ECS table of every vehicle, if they are all in one.
fn one_table<'a>(everyone: &'a EveryoneQuery<'_, '_>) -> Option<(&'a [VehicleId], &'a [VehicleState])> {
    let mut full = everyone.contiguous_iter().ok()?.filter(|(ids, _, _)| !ids.is_empty());
    let (ids, states, _) = full.next()?;
    full.next().is_none().then_some((ids, states))
}

/// A sensor tick over the neighbour lists as they are, in one pass: each chunk of vehicles
/// senses from its lists and, beside that, adds up its displacements since the build and
/// checks that its sensors are the build's; the lists are kept when all hold
/// ([`NeighbourLists::drifted_together`]), else the tick is thrown away (nothing written but
/// the readings, the wifi masks and the counts in `scratch`, which the tick made again
/// overwrites and this resets) and `false` returned, for [`sense_by_shapes`] to build them.
/// The same readings as that path bit for bit: where the lists hold, it senses from the same
/// lists with the same sight.
///
/// That path finds the sensors' shapes and the displacements in two passes of their own over
/// the threads before sensing: two hand-overs to the helpers per tick, each of a few
/// microseconds' work per thousand vehicles, where the caller waited for a helper's late
/// start and its last chunk (10,000 vehicles, 2 threads, instrumented: the two passes and the
/// gaps before them were 7 % of a run). Lists are built every few seconds of simulated time;
/// a tick thrown away costs one tick's sensing then.
///
/// `input`: the grid, the tick's draws, the wifi range the lists must reach and, at a wifi
/// round's instant, its square ([`NearWanted`]).
fn sense_with_kept_lists(
    neighbours: &mut Neighbours,
    (grid, draws, floor, near_r2): (&SpatialGrid, Draws, f64, Option<f64>),
    (parallelism, now): (Parallelism, SimTime),
    everyone: &EveryoneQuery<'_, '_>,
    sensing: &mut SensingQuery<'_, '_>,
    scratch: &mut Vec<SenseScratch>,
) -> bool {
    let lists = &mut neighbours.lists;
    if lists.skin <= 0.0 || lists.floor != floor || lists.kept_since_build < ONE_PASS_AFTER {
        return false;
    }
    let Some((ids, states)) = one_table(everyone) else { return false };
    let everyone = Everyone { ids, states };
    let n = ids.len();
    let built = |len: usize| len == n;
    let as_built = built(lists.cell_of.len()) && built(lists.headings.len()) && built(lists.shapes.len());
    if !as_built || !lists.of_vehicles(everyone) || lists.lists.len() != n {
        return false;
    }
    if !senses_everyone(sensing, ids) {
        return false;
    }
    let Ok(mut tables) = sensing.contiguous_iter_mut() else { return false };
    let Some((sensing_ids, sensing_states, radars, velodynes, omniscient, errors, mut readings)) =
        tables.find(|t| !t.0.is_empty())
    else {
        return false;
    };
    // Occlusion needs every vehicle's footprint ([`sense_by_shapes`] gathers them).
    if errors.is_some_and(|e| e.iter().any(occludes)) {
        return false;
    }
    let table = SensingTable { ids: sensing_ids, states: sensing_states, radars, velodynes, omniscient, errors };
    let input = SenseInput { grid, footprints: &[], draws };
    lists.size_near(n);
    let NeighbourLists { lists: kept, anchors, headings, cell_of, shapes, near, .. } = &mut *lists;
    let (kept, anchors, headings, cell_of, shapes) = (&*kept, &anchors[..], &headings[..], &cell_of[..], &shapes[..]);
    parallelism.for_each_chunk_pair_at(&mut readings, near, scratch, |start, chunk, near, s| {
        let r = start..start + chunk.len();
        let drift = &mut s.drift;
        drift.clear();
        drift.add(&anchors[r.clone()], &headings[r.clone()], &states[r.clone()], &cell_of[r.clone()]);
        let shape = |i: usize| Shape::of(radars.map(|x| &x[i]), velodynes.map(|v| &v[i]));
        s.shapes_held = r.into_iter().all(|i| shape(i) == shapes[i]);
        sense_listed(input, table, everyone, (Listing::Kept(kept), near_r2), (start, chunk, near), s);
    });
    let chunks = parallelism.chunks_for(n);
    let held = scratch.iter().take(chunks).all(|s| s.shapes_held)
        && lists.drifted_together(scratch.iter().take(chunks).map(|s| &s.drift), &mut neighbours.drift.boxes);
    if !held {
        scratch.iter_mut().for_each(|s| s.stats = SensorStats::default());
        lists.thrown_away += 1;
        return false;
    }
    lists.held_at = Some(now);
    if let Some(r2) = near_r2 {
        (lists.near_at, lists.near_r2) = (Some(now), r2);
    }
    lists.kept_in_one_pass += 1;
    lists.kept_since_build += 1;
    true
}

/// Sensor ticks that must have kept the lists since their build before one tries to keep them
/// in one pass ([`sense_with_kept_lists`]). A pass thrown away costs about a tick's sensing, a
/// kept one saves about a tenth of it (the two passes of [`sense_by_shapes`] and the waits
/// around them): where lists are built every few ticks (vehicles closing in fast, sensors
/// changed often), trying every tick would sense twice as often as it saves. With this many
/// first, builds every `ONE_PASS_AFTER` ticks or sooner never try, and the worst (one build
/// every `ONE_PASS_AFTER + 1` ticks) throws away a pass in that many ticks; traffic that moves
/// together builds every few seconds (hundreds of ticks) and loses only these first ticks.
const ONE_PASS_AFTER: u32 = 8;

/// A sensor tick that first finds every vehicle's sensors ([`Shape`]) and the typical range,
/// then senses over the neighbour lists (kept if they hold, else built) or, where they cannot
/// serve, over the grid.
fn sense_by_shapes(
    (grid, neighbours): (&mut SpatialGrid, &mut Neighbours),
    (parallelism, now): (Parallelism, SimTime),
    (draws, floor, near_r2): (Draws, f64, Option<f64>),
    (everyone, sensing): (&EveryoneQuery<'_, '_>, &mut SensingQuery<'_, '_>),
    (scratch, shape_parts, ranges, footprints): (
        &mut Vec<SenseScratch>,
        &mut Vec<ShapeSummary>,
        &mut Vec<f64>,
        &mut Vec<Footprint>,
    ),
) {
    ranges.clear();
    let mut occlusion = false;
    // Every sensing vehicle's sensors in query order (what the neighbour lists keep), and the
    // bounded ranges (for the typical range).
    let mut summary = ShapeSummary::default();
    let mut cell = None;
    if let Ok(tables) = sensing.as_readonly().contiguous_iter() {
        // Table by table, over the components' slices, split over the threads (a serial pass
        // every sensor tick before); each chunk sums up its shapes, merged in chunk order.
        let (shapes_now, built) = (&mut neighbours.shapes_now, &neighbours.lists.shapes);
        let mut end = 0;
        for (ids, _, radars, velodynes, _, errors, _) in tables {
            occlusion |= errors.is_some_and(|e| e.iter().any(occludes));
            let start = end;
            end += ids.len();
            // Longer only while the world grows: last tick's shapes are overwritten.
            if shapes_now.len() < end {
                shapes_now.resize(end, Shape::NONE);
            }
            let chunks = parallelism.chunks_for(ids.len());
            shape_parts.iter_mut().for_each(|p| *p = ShapeSummary::default());
            parallelism.for_each_chunk_at(&mut shapes_now[start..end], shape_parts, |k0, chunk, part| {
                let was = built.get(start + k0..).unwrap_or(&[]);
                for (k, shape) in chunk.iter_mut().enumerate() {
                    *shape = Shape::of(radars.map(|r| &r[k0 + k]), velodynes.map(|v| &v[k0 + k]));
                    part.add(shape);
                    part.as_built &= was.get(k) == Some(shape);
                }
            });
            shape_parts.iter().take(chunks).for_each(|part| summary.then(part));
        }
        shapes_now.truncate(end);
        summary.as_built &= built.len() == end;
        cell = summary.typical();
        if cell.is_none() {
            ranges.extend(shapes_now.iter().map(Shape::range).filter(bounded));
        }
    } else {
        neighbours.shapes_now.clear();
        summary.as_built = neighbours.lists.shapes.is_empty();
        ranges.extend(
            sensing
                .iter()
                .inspect(|item| occlusion |= item.5.is_some_and(occludes))
                .map(|(_, _, radar, velodyne, _, _, _)| Shape::of(radar, velodyne).range())
                .filter(bounded),
        );
    }
    footprints.clear();
    if occlusion {
        footprints.extend(everyone.iter().map(|(_, state, size)| {
            let size = size.copied().unwrap_or_default();
            Footprint { half_length: 0.5 * size.length, half_width: 0.5 * size.width, yaw: state.yaw }
        }));
    }
    let cell = cell.unwrap_or_else(|| typical_range(ranges));
    let entry = |i: usize, id: VehicleId, state: &VehicleState| GridEntry {
        position: state.position,
        velocity: state.velocity,
        id,
        index: i as u32,
    };
    // Split over the threads when every vehicle lies in one ECS table (the common case; the
    // tables a vehicle left when a component was added stay, empty; the index of each vehicle
    // is its place in query order either way).
    let one_table = one_table(everyone);
    // Neighbour lists when every vehicle senses, from that one table, with a bounded range.
    // (The shapes summed up above are then this one table's.)
    let listed = one_table
        .filter(|&(ids, _)| summary.finite && senses_everyone(sensing, ids))
        .map(|(ids, states)| Everyone { ids, states });
    if let Some(everyone) = listed {
        let skin = SKIN_SHARE * cell;
        let n = neighbours.shapes_now.len();
        let Neighbours { lists, shapes_now, drift, keys } = neighbours;
        // (At a wifi round's instant, `near_r2` notes who is within its range.)
        let build = !lists.hold(everyone, (summary.as_built, floor, skin), parallelism, drift);
        if build {
            grid.rebuild_on(parallelism, cell + skin, n, |i| entry(i, everyone.ids[i], &everyone.states[i]));
            lists.ids.clear();
            lists.ids.extend_from_slice(everyone.ids);
            lists.anchors.clear();
            lists.anchors.extend(everyone.states.iter().map(|s| s.position));
            lists.headings.clear();
            lists.headings.extend(everyone.states.iter().map(VehicleState::heading));
            lists.shapes.clear();
            lists.shapes.extend_from_slice(shapes_now);
            (lists.skin, lists.floor) = (skin, floor);
            lists.around = shapes_now.iter().map(|s| s.around(floor)).fold(f64::INFINITY, f64::min);
            lists.place_in_drift_cells(keys);
            lists.builds += 1;
            lists.kept_since_build = 0;
        } else {
            lists.kept_since_build = lists.kept_since_build.saturating_add(1);
        }
        let input = SenseInput { grid, footprints, draws };
        lists.size_near(n);
        let tables = sensing.contiguous_iter_mut().ok().into_iter().flatten();
        for (ids, states, radars, velodynes, omniscient, errors, mut readings) in tables {
            if ids.is_empty() {
                continue;
            }
            let table = SensingTable { ids, states, radars, velodynes, omniscient, errors };
            let listing = if build { Listing::Build { skin, floor } } else { Listing::Kept(&lists.lists) };
            parallelism.for_each_chunk_pair_at(&mut readings, &mut lists.near, scratch, |start, chunk, near, s| {
                sense_listed(input, table, everyone, (listing, near_r2), (start, chunk, near), s)
            });
        }
        if build {
            // Each chunk's lists, in chunk order, into the one array.
            let Lists { starts, neighbours } = &mut lists.lists;
            starts.clear();
            starts.push(0);
            neighbours.clear();
            // Scratch value k is chunk k's whichever thread ran it (`Parallelism::for_each_chunk`),
            // so the scratches are in chunk order already.
            debug_assert!(scratch.iter().filter_map(|s| s.built_from).is_sorted());
            for s in scratch.iter_mut().filter(|s| s.built_from.is_some()) {
                let base = neighbours.len() as u32;
                neighbours.extend_from_slice(&s.built);
                starts.extend(s.built_ends.iter().map(|&end| base + end));
                s.built_from = None;
            }
            debug_assert_eq!(starts.len(), n + 1);
        }
        lists.held_at = Some(now);
        if let Some(r2) = near_r2 {
            (lists.near_at, lists.near_r2) = (Some(now), r2);
        }
    } else {
        match one_table {
            Some((ids, states)) => {
                grid.rebuild_on(parallelism, cell, ids.len().min(states.len()), |i| entry(i, ids[i], &states[i]))
            }
            None => grid.rebuild(cell, everyone.iter().enumerate().map(|(i, (&id, state, _))| entry(i, id, state))),
        }
        let input = SenseInput { grid, footprints, draws };
        if let Ok(tables) = sensing.contiguous_iter_mut() {
            for (ids, states, radars, velodynes, omniscient, errors, mut readings) in tables {
                let table = SensingTable { ids, states, radars, velodynes, omniscient, errors };
                parallelism.for_each_chunk_at(&mut readings, scratch, |start, chunk, s| {
                    sense_chunk(input, table, start, chunk, s)
                });
            }
        } else {
            // Only if a component were stored sparsely (none is): one at a time.
            if scratch.is_empty() {
                scratch.push(SenseScratch::default());
            }
            for (id, state, radar, velodyne, omniscient, errors, mut readings) in sensing.iter_mut() {
                let table = SensingTable {
                    ids: std::slice::from_ref(id),
                    states: std::slice::from_ref(state),
                    radars: radar.map(std::slice::from_ref),
                    velodynes: velodyne.map(std::slice::from_ref),
                    omniscient,
                    errors: errors.map(std::slice::from_ref),
                };
                sense_chunk(input, table, 0, std::slice::from_mut(&mut *readings), &mut scratch[0]);
            }
        }
    }
}

/// Radar, velodyne and omniscient sensing in the [`Sensors`] schedule.
#[derive(Debug, Clone, Copy, Default)]
pub struct SensorsPlugin;

impl Plugin for SensorsPlugin {
    fn build(&self, sim: &mut SimBuilder) {
        sim.insert_resource(SensorGrid::default());
        sim.insert_resource(SensorStats::default());
        sim.world_mut().init_resource::<Parallelism>();
        sim.add_systems(Sensors, sense_vehicles.in_set(SimSystems::Sense));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shapes_summed_up_in_any_chunks_give_the_typical_range_of_all_of_them() {
        let shape = |radar: f64, velodyne: f64| Shape { radar, angle: 1.0, velodyne };
        let cases: Vec<Vec<Shape>> = vec![
            vec![shape(100.0, 50.0); 7],
            vec![shape(0.0, 0.0), shape(100.0, 50.0), shape(0.0, 0.0), shape(40.0, 100.0)],
            vec![shape(100.0, 50.0), shape(100.0, 50.0), shape(30.0, 20.0), shape(100.0, 0.0), shape(0.0, 70.0)],
            vec![shape(0.0, 0.0); 3],
            vec![shape(100.0, 50.0), shape(f64::INFINITY, 0.0), shape(100.0, 0.0)],
            vec![shape(100.0, 0.0), shape(100.0, 0.0), shape(30.0, 0.0), shape(30.0, 0.0), shape(0.0, 30.0)],
            vec![],
        ];
        for shapes in cases {
            let mut ranges: Vec<f64> = shapes.iter().map(Shape::range).filter(bounded).collect();
            let expected = typical_range(&mut ranges);
            let finite = shapes.iter().all(|s| s.range().is_finite());
            // Chunks of every size, and two chunks split at every place.
            let fixed = (1..=shapes.len().max(1)).map(|cut| shapes.chunks(cut).collect::<Vec<_>>());
            let split = (0..=shapes.len()).map(|k| vec![&shapes[..k], &shapes[k..]]);
            for chunks in fixed.chain(split) {
                let cut = chunks.iter().map(|c| c.len()).collect::<Vec<_>>();
                let mut summary = ShapeSummary::default();
                for chunk in chunks {
                    let mut part = ShapeSummary::default();
                    chunk.iter().for_each(|s| part.add(s));
                    summary.then(&part);
                    summary.then(&ShapeSummary::default());
                }
                assert_eq!(summary.finite, finite, "{shapes:?} in chunks of {cut:?}");
                if let Some(cell) = summary.typical() {
                    assert_eq!(cell, expected, "{shapes:?} in chunks of {cut:?}");
                } else {
                    assert!(ranges.iter().any(|r| *r != ranges[0]), "only mixed ranges leave it to the median");
                }
            }
        }
    }

    /// A vehicle `k` at (`x`, 0) facing east, standing still (no dynamics), with the default
    /// radar and velodyne.
    fn sensing_at(k: i32, x: f64) -> crate::world::VehicleSpec {
        use crate::world::{SensorSet, VehicleModel, VehicleSpec};
        let mut spec = VehicleSpec::new(VehicleId(k), VehicleState::new(DVec2::new(x, 0.0), 0.0, 0.0));
        spec.model = VehicleModel::None;
        let (radar, velodyne) = (Some(Radar::default()), Some(Velodyne::default()));
        spec.sensors = SensorSet { radar, velodyne, omniscient: false };
        spec
    }

    #[test]
    fn the_neighbour_lists_are_kept_while_the_vehicles_move_together_and_built_again_when_two_close_in() {
        let spec = sensing_at;
        let mut b = SimBuilder::new();
        b.add_plugin(SensorsPlugin);
        for k in 0..50 {
            b.spawn_vehicle(spec(k, 30.0 * f64::from(k))).expect("unique ids");
        }
        let mut sim = b.build();
        let builds = |sim: &crate::sim::Sim| sim.world().resource::<SensorGrid>().neighbours.lists.builds;
        let move_to = |sim: &mut crate::sim::Sim, x: f64| {
            let e = sim.entity(VehicleId(7)).expect("vehicle 7");
            *sim.world_mut().get_mut::<VehicleState>(e).expect("state") =
                VehicleState::new(DVec2::new(x, 0.0), 0.0, 0.0);
        };
        let move_all_by = |sim: &mut crate::sim::Sim, dx: f64| {
            for k in 0..50 {
                let e = sim.entity(VehicleId(k)).expect("vehicle");
                sim.world_mut().get_mut::<VehicleState>(e).expect("state").position.x += dx;
            }
        };
        sim.run_for(0.5);
        assert_eq!(builds(&sim), 1, "ten ticks, nobody moved: one build");
        // 100 m ranges: a 20 m skin, kept while no two neighbours closed in by 19.6 m.
        move_to(&mut sim, 210.0 + 9.0);
        sim.run_for(0.1);
        assert_eq!(builds(&sim), 1, "9 m is within half the skin");
        move_to(&mut sim, 210.0 + 19.0);
        sim.run_for(0.1);
        assert_eq!(builds(&sim), 1, "19 m closer to its neighbours: still under the skin");
        move_to(&mut sim, 210.0 + 21.0);
        sim.run_for(0.05);
        assert_eq!(builds(&sim), 2, "21 m is not");
        // Everyone 150 m on together (drift cells 480 m wide: up to 186 m), then 40 m more.
        move_all_by(&mut sim, 150.0);
        sim.run_for(0.1);
        assert_eq!(builds(&sim), 2, "everyone moved alike: the lists hold");
        move_all_by(&mut sim, 40.0);
        sim.run_for(0.05);
        assert_eq!(builds(&sim), 3, "190 m from where the lists were built: too far to tell");
        move_all_by(&mut sim, 1.0);
        move_to(&mut sim, f64::NAN);
        sim.run_for(0.05);
        assert_eq!(builds(&sim), 4, "a NaN position");
        move_to(&mut sim, 400.0);
        sim.run_for(0.05);
        assert_eq!(builds(&sim), 5, "and back");
        sim.spawn_vehicle(spec(50, -30.0)).expect("unique id");
        sim.run_for(0.05);
        assert_eq!(builds(&sim), 6, "a new vehicle");
        let e = sim.entity(VehicleId(3)).expect("vehicle 3");
        sim.world_mut().get_mut::<Velodyne>(e).expect("velodyne").range = 60.0;
        sim.run_for(0.05);
        assert_eq!(builds(&sim), 7, "a longer velodyne: a list reaches that far behind");
        sim.world_mut().get_mut::<Radar>(e).expect("radar").range = 150.0;
        sim.run_for(0.05);
        assert_eq!(builds(&sim), 8, "a longer radar");
        sim.run_for(0.2);
        assert_eq!(builds(&sim), 8);
        // Vehicle 20 turns: kept at 29° from its heading at the build, built again at 30.4°.
        let e = sim.entity(VehicleId(20)).expect("vehicle 20");
        let turn = |sim: &mut crate::sim::Sim, yaw: f64| {
            let mut state = sim.world_mut().get_mut::<VehicleState>(e).expect("state");
            *state = VehicleState::new(state.position, yaw, 0.0);
        };
        turn(&mut sim, 0.5);
        sim.run_for(0.05);
        assert_eq!(builds(&sim), 8, "turned 29°");
        turn(&mut sim, 0.53);
        sim.run_for(0.05);
        assert_eq!(builds(&sim), 9, "turned 30.4°");
        // Each list leaves out what lies behind beyond the velodyne (50 m) and its skin (20 m):
        // on a line of vehicles 30 m apart facing along it, two behind and four ahead (up to
        // 120 m), not the four behind up to 120 m.
        let grid = sim.world().resource::<SensorGrid>();
        let lists = &grid.neighbours.lists;
        let place = lists.ids.iter().position(|&id| id == VehicleId(10)).expect("vehicle 10 listed");
        let mut listed: Vec<i32> = lists.lists.of(place).iter().map(|&j| lists.ids[j as usize].0).collect();
        listed.sort_unstable();
        assert_eq!(listed, [8, 9, 11, 12, 13, 14]);
    }

    /// Sixty sensing vehicles 30 m apart in a row, on `threads` threads.
    fn sixty_in_a_row(threads: usize) -> crate::sim::Sim {
        let mut b = SimBuilder::new();
        b.add_plugin(SensorsPlugin);
        b.insert_resource(Parallelism::split(threads));
        for k in 0..60 {
            b.spawn_vehicle(sensing_at(k, 30.0 * f64::from(k))).expect("unique ids");
        }
        b.build()
    }

    #[test]
    fn a_sensor_changed_in_any_chunk_builds_the_lists_again_on_any_thread_count() {
        // The sensing pass over kept lists (or the shapes pass) tells whether this tick's
        // sensors are the build's, chunk by chunk: a change in the first, a middle or the last
        // chunk must be seen.
        for threads in [1, 2, 3] {
            for changed in [0, 31, 59] {
                let mut sim = sixty_in_a_row(threads);
                let builds = |sim: &crate::sim::Sim| sim.world().resource::<SensorGrid>().neighbours.lists.builds;
                sim.run_for(0.2);
                assert_eq!(builds(&sim), 1, "{threads} threads: nobody moved");
                let e = sim.entity(VehicleId(changed)).expect("vehicle");
                sim.world_mut().get_mut::<Radar>(e).expect("radar").range = 120.0;
                sim.run_for(0.05);
                assert_eq!(builds(&sim), 2, "{threads} threads, vehicle {changed}'s radar longer");
                sim.run_for(0.2);
                assert_eq!(builds(&sim), 2, "{threads} threads, vehicle {changed}: the same again");
                sim.world_mut().get_mut::<Velodyne>(e).expect("velodyne").range = 49.0;
                sim.run_for(0.05);
                assert_eq!(builds(&sim), 3, "{threads} threads, vehicle {changed}'s velodyne shorter");
            }
        }
    }

    #[test]
    fn kept_lists_sense_in_one_pass_and_a_tick_thrown_away_counts_its_detections_once() {
        // Lists kept for `ONE_PASS_AFTER` ticks are then kept in one pass; a tick that finds them
        // no longer hold (a vehicle closed in by the skin, a radar changed) throws that pass
        // away and senses again over lists built anew: its detections count once, as many as
        // the readings hold. Right after a build, the two-pass path.
        for threads in [1, 2, 3] {
            let mut sim = sixty_in_a_row(threads);
            let counts = |sim: &crate::sim::Sim| {
                let lists = &sim.world().resource::<SensorGrid>().neighbours.lists;
                (lists.builds, lists.kept_in_one_pass, lists.thrown_away)
            };
            let detections = |sim: &mut crate::sim::Sim| {
                let counted = sim.world().resource::<SensorStats>().detections;
                let world = sim.world_mut();
                let read: usize = world.query::<&SensorReadings>().iter(world).map(|r| r.0.len()).sum();
                (counted, read as u64)
            };
            sim.run_for(0.05);
            assert_eq!(counts(&sim), (1, 0, 0), "{threads} threads: the first tick builds");
            let (mut last, read) = detections(&mut sim);
            assert_eq!(last, read, "{threads} threads: the first tick");
            for step in 0..30 {
                match step {
                    12 => {
                        let e = sim.entity(VehicleId(7)).expect("vehicle 7");
                        sim.world_mut().get_mut::<VehicleState>(e).expect("state").position.x += 21.0;
                    }
                    24 => {
                        let e = sim.entity(VehicleId(40)).expect("vehicle 40");
                        sim.world_mut().get_mut::<Radar>(e).expect("radar").range = 120.0;
                    }
                    _ => {}
                }
                sim.run_for(0.05);
                let (counted, read) = detections(&mut sim);
                assert_eq!(counted - last, read, "{threads} threads, step {step}");
                last = counted;
            }
            // Ticks 0-7 after each build on two passes, then one (steps 8-11 and 21-23), the
            // passes of steps 12 and 24 thrown away for builds.
            assert_eq!(counts(&sim), (3, 7, 2), "{threads} threads: builds, kept in one pass, thrown away");
        }
    }

    #[test]
    fn at_the_instant_the_sensors_tested_the_lists_the_wifi_round_takes_them_without_testing_again() {
        let mut b = SimBuilder::new();
        b.add_plugin(SensorsPlugin);
        for k in 0..50 {
            b.spawn_vehicle(sensing_at(k, 30.0 * f64::from(k))).expect("unique ids");
        }
        let mut sim = b.build();
        sim.run_for(0.12);
        let mut query = sim.world_mut().query::<(&VehicleId, &VehicleState)>();
        let (ids, mut states): (Vec<VehicleId>, Vec<VehicleState>) =
            query.iter(sim.world()).map(|(id, state)| (*id, *state)).unzip();
        let grid = sim.world().resource::<SensorGrid>();
        let tested = grid.neighbours.lists.held_at.expect("the sensors tested the lists");
        let later = SimTime(tested.0 + 1);
        let mut scratch = DriftScratch::default();
        let mut within = |ids: &[VehicleId], states: &[VehicleState], now| {
            grid.lists_within(ids, states, 10.0, (Parallelism::single(), now), &mut scratch).is_some()
        };
        assert!(within(&ids, &states, tested), "as the sensors left them");
        assert!(within(&ids, &states, later), "nobody moved: they hold at any instant");
        // Vehicle 7 25 m on (more than the 20 m skin): at the sensors' instant the states are
        // the ones they tested (only the dynamics moves vehicles, after every other module), so
        // no drift test; at any other instant the drift test finds the lists stale.
        states[7].position.x += 25.0;
        assert!(within(&ids, &states, tested), "the sensors' instant: taken without a test");
        assert!(!within(&ids, &states, later), "another instant: tested, and stale");
        let mut swapped = ids.clone();
        swapped.swap(3, 4);
        assert!(!within(&swapped, &states, tested), "other vehicles than the build's");
        assert!(!within(&ids[1..], &states[1..], tested), "fewer vehicles than the build's");
    }

    #[test]
    fn a_list_holds_all_around_the_velodyne_or_the_wifi_range_and_the_widened_radar_cone_ahead() {
        let shape = Shape { radar: 100.0, angle: std::f64::consts::FRAC_PI_3, velodyne: 50.0 };
        let east = DVec2::X;
        let holds = |reach: &Reach, x: f64, y: f64| reach.holds(DVec2::new(x, y), x * x + y * y);
        let reach = Reach::new(&shape, east, 0.0, 20.0);
        assert!(holds(&reach, -70.0, 0.0) && !holds(&reach, -70.1, 0.0), "behind: velodyne and skin");
        assert!(holds(&reach, 0.0, 69.9) && !holds(&reach, 0.0, 80.0), "beside");
        // Ahead at 100 m: half the cone (30°), the turn (30°), asin(20 / 100) = 11.5°.
        let at = |deg: f64| DVec2::from_angle(deg.to_radians()) * 100.0;
        assert!(holds(&reach, at(71.0).x, at(71.0).y) && !holds(&reach, at(72.0).x, at(72.0).y));
        assert!(holds(&reach, at(-71.0).x, at(-71.0).y) && !holds(&reach, at(-72.0).x, at(-72.0).y));
        // A radar of 150°: 75° + 30° + 11.5°.
        let wide = Shape { angle: 150f64.to_radians(), ..shape };
        let reach_wide = Reach::new(&wide, east, 0.0, 20.0);
        assert!(holds(&reach_wide, at(116.0).x, at(116.0).y) && !holds(&reach_wide, at(117.0).x, at(117.0).y));
        // With the wifi at 60 m, 80 m all around; a wifi range beyond the sensors' adds nothing.
        let reach = Reach::new(&shape, east, 60.0, 20.0);
        assert!(holds(&reach, -80.0, 0.0) && !holds(&reach, -80.1, 0.0));
        assert_eq!(shape.around(500.0), 100.0);
        // Without a radar, the velodyne's circle; with a NaN angle (which sees all ahead), all.
        let no_radar = Shape { radar: 0.0, angle: 1.0, velodyne: 50.0 };
        assert!(!holds(&Reach::new(&no_radar, east, 0.0, 20.0), 80.0, 0.0));
        let nan = Shape { angle: f64::NAN, ..shape };
        assert!(holds(&Reach::new(&nan, east, 0.0, 20.0), -100.0, 10.0));
    }

    #[test]
    fn the_typical_range_is_the_median_whether_or_not_all_ranges_agree() {
        assert_eq!(typical_range(&mut []), 100.0);
        assert_eq!(typical_range(&mut [80.0; 5]), 80.0);
        assert_eq!(typical_range(&mut [50.0, 100.0, 100.0]), 100.0);
        assert_eq!(typical_range(&mut [100.0, 50.0, 50.0, 200.0, 30.0]), 50.0);
        // One differing range among many equal ones: still the median, not the first.
        let mut ranges = vec![100.0; 9];
        ranges.extend([20.0; 10]);
        assert_eq!(typical_range(&mut ranges), 20.0);
    }

    #[test]
    fn pair_draws_are_keyed_by_seed_sensor_pair_and_tick() {
        let (a, b) = (VehicleId(-3), VehicleId(7));
        let first =
            |seed, stream, now, observer, target| SensorKeys::new(seed, stream, now).pair(observer, target).first;
        let base = first(42, RADAR_STREAM, 1_500_000, a, b);
        assert_eq!(base, first(42, RADAR_STREAM, 1_500_000, a, b));
        for other in [
            first(43, RADAR_STREAM, 1_500_000, a, b),
            first(42, VELODYNE_STREAM, 1_500_000, a, b),
            first(42, RADAR_STREAM, 1_550_000, a, b),
            first(42, RADAR_STREAM, 1_500_000, b, a),
            first(42, RADAR_STREAM, 1_500_000, a, VehicleId(8)),
        ] {
            assert_ne!(base, other);
        }
        let d = Draws::new(42, 1_500_000);
        assert_eq!(d.radar.pair(a, b).first, base);
        assert_eq!(d.velodyne.pair(a, b).first, first(42, VELODYNE_STREAM, 1_500_000, a, b));
    }

    #[test]
    fn pair_draws_drop_their_share_and_give_independent_standard_normals() {
        // Many (observer, target) pairs over a few ticks, as a bench run draws them.
        let (dropout, mut dropped, mut n) = (0.02, 0u32, 0u32);
        let mut normals: Vec<[f64; 4]> = Vec::new();
        for tick in 0..20u64 {
            let keys = SensorKeys::new(1, RADAR_STREAM, tick * 50_000);
            for observer in 0..100 {
                for target in 0..100 {
                    let pair = keys.pair(VehicleId(-1 - observer), VehicleId(-1 - target));
                    n += 1;
                    if pair.kept(dropout) {
                        normals.push(pair.normals());
                    } else {
                        dropped += 1;
                    }
                }
            }
        }
        let share = f64::from(dropped) / f64::from(n);
        let sd = (dropout * (1.0 - dropout) / f64::from(n)).sqrt();
        assert!((share - dropout).abs() < 4.0 * sd, "dropout share {share} of {n}");
        let m = normals.len() as f64;
        for k in 0..4 {
            let mean = normals.iter().map(|x| x[k]).sum::<f64>() / m;
            let var = normals.iter().map(|x| x[k] * x[k]).sum::<f64>() / m;
            assert!(mean.abs() < 4.0 / m.sqrt(), "normal {k}: mean {mean}");
            assert!((var - 1.0).abs() < 0.02, "normal {k}: variance {var}");
            let beyond = normals.iter().filter(|x| x[k].abs() > 2.0).count() as f64 / m;
            assert!((beyond - 0.0455).abs() < 0.003, "normal {k}: P(|X| > 2) {beyond}");
            for j in 0..k {
                let c = normals.iter().map(|x| x[j] * x[k]).sum::<f64>() / m;
                assert!(c.abs() < 4.0 / m.sqrt(), "normals {j} and {k} correlate: {c}");
            }
        }
    }

    /// A grid of `n` vehicles scattered around the origin and a sensing vehicle at the origin
    /// facing +x with a radar and a velodyne: its candidates as `Sight::consider` keys.
    fn scene(n: u32) -> (SpatialGrid, Sight, Vec<u64>) {
        let mut grid = SpatialGrid::default();
        let entries = (0..n).map(|k| {
            let a = f64::from(k) * 2.399_963; // golden angle: spread in every direction
            let r = 3.0 + f64::from(k % 37) * 3.1;
            GridEntry {
                position: DVec2::new(r * a.cos(), r * a.sin()),
                velocity: DVec2::new(f64::from(k % 5), -1.0),
                id: VehicleId(k as i32 + 1),
                index: k,
            }
        });
        grid.rebuild(100.0, entries);
        let state = VehicleState::new(DVec2::ZERO, 0.0, 10.0);
        let radar = Some(&Radar::default());
        let sight =
            Sight::new(VehicleId(-1), &state, radar, Some(&Velodyne::default()), false, &mut HalfCos::default());
        let (mut around, mut found) = (Candidates::default(), Vec::new());
        grid.gather_all(&mut around);
        let seen = sight.consider_all(&around, &mut Vec::new(), &mut found).len();
        found.truncate(seen);
        (grid, sight, found)
    }

    #[test]
    fn listed_keys_four_at_a_time_are_the_keys_of_the_three_passes() {
        // Neighbours all around at 0 m (on top of the sensor) to 130 m, one at NaN; lists of
        // every length to 70 (every remainder of four, past the near mask's 64 bits) in an
        // order that jumps about the states; an acute radar cone, one wider than a half turn,
        // one all around, none; with and without a velodyne.
        let p = DVec2::new(12.5, -3.25);
        let states: Vec<VehicleState> = (0..101)
            .map(|k| {
                let (a, r) = (k as f64 * 2.399_963, (k % 29) as f64 * 4.7);
                let q = if k == 50 { DVec2::new(f64::NAN, 1.0) } else { p + DVec2::new(r * a.cos(), r * a.sin()) };
                VehicleState::new(q, 0.0, 1.0)
            })
            .collect();
        let state = VehicleState::new(p, 0.7, 10.0);
        let radars = [
            Some(Radar::default()),
            Some(Radar { angle: 4.0, range: 80.0 }),
            Some(Radar { angle: TAU, range: 60.0 }),
            None,
        ];
        let (mut lengths_compared, mut reach_seen) = (0, 0u32);
        for radar in &radars {
            for velodyne in [Some(Velodyne::default()), None] {
                let sight = Sight::new(
                    VehicleId(-1),
                    &state,
                    radar.as_ref(),
                    velodyne.as_ref(),
                    false,
                    &mut HalfCos::default(),
                );
                for n in 0..=70 {
                    let list: Vec<u32> = (0..n).map(|k| ((k * 37 + 11) % 101) as u32).collect();
                    // The three passes, one neighbour at a time.
                    let (mut xs, mut ys, mut keys) = (vec![0.0; n], vec![0.0; n], vec![0; n]);
                    gather_positions(&states, &list, &mut xs, &mut ys);
                    ListKeysPass { sight: &sight, xs: &xs, ys: &ys, slots: &list, keys: &mut keys }.run();
                    let want: Vec<u64> = keys.iter().copied().filter(|&k| k != UNSEEN).collect();
                    let want_near = near_of(&xs, &ys, (p, 900.0));
                    reach_seen |= want.iter().fold(0, |r, &k| r | k as u32 & REACH);
                    #[cfg(target_arch = "x86_64")]
                    if std::arch::is_x86_feature_detected!("avx2") {
                        for r2 in [None, Some(900.0)] {
                            let mut found = vec![0; n.next_multiple_of(4)];
                            // SAFETY: the processor has AVX2, checked just above.
                            let (seen, near) = unsafe { listed_keys_avx2(&sight, &states, &list, r2, &mut found) };
                            assert_eq!(
                                found[..seen],
                                want[..],
                                "{n} neighbours, radar {radar:?}, velodyne {velodyne:?}"
                            );
                            assert_eq!(near, if r2.is_some() { want_near } else { 0 }, "{n} neighbours' near mask");
                        }
                        lengths_compared += 1;
                    }
                    if n == 70 {
                        // Some seen, some not (none without a sensor).
                        let blind = radar.is_none() && velodyne.is_none();
                        assert!(blind == want.is_empty() && want.len() < n, "{} of {n} seen", want.len());
                    }
                }
            }
        }
        // Both reach bits turned up; every case compared where the processor has AVX2.
        assert_eq!(reach_seen, REACH);
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            assert_eq!(lengths_compared, 4 * 2 * 71);
        }
    }

    #[test]
    fn the_gather_marks_the_neighbours_within_the_wifi_range_as_within_reach_tests_them() {
        // Neighbours inside, outside and exactly on the circle (a 3-4-5 offset at r = 5 m:
        // d² = 25 = r² exactly, inclusive), a NaN one (never within), lists of every length up
        // to 64 (all bits of the mask) in an order that jumps about the states.
        let p = DVec2::new(100.25, -40.5);
        let offsets = [(3.0, 4.0), (-3.0, 4.0), (1.0, 1.0), (4.0, 3.1), (0.0, -5.0), (6.0, 0.0), (f64::NAN, 0.0)];
        let states: Vec<VehicleState> = (0..97)
            .map(|k| {
                let (dx, dy) = offsets[k % offsets.len()];
                VehicleState::new(p + DVec2::new(dx, dy) * (1.0 + (k / 50) as f64 * 1e-9), 0.0, 1.0)
            })
            .collect();
        let r2 = 25.0;
        let ids: Vec<VehicleId> = (0..97).map(VehicleId).collect();
        let everyone = Everyone { ids: &ids, states: &states };
        let sight =
            Sight::new(VehicleId(-1), &VehicleState::new(p, 0.0, 1.0), None, None, false, &mut HalfCos::default());
        let mut bits_seen = 0u64;
        for n in 0..=64 {
            let slots: Vec<u32> = (0..n).map(|k| ((k * 31 + 5) % 97) as u32).collect();
            let want = slots.iter().enumerate().fold(0u64, |m, (k, &j)| {
                m | u64::from(within_reach(p, states[j as usize].position.x, states[j as usize].position.y, r2)) << k
            });
            let mut near = u64::MAX;
            let mut buffers = (Vec::new(), Vec::new(), Vec::new());
            sight.consider_listed(
                &slots,
                everyone,
                (&mut buffers.0, &mut buffers.1, &mut buffers.2),
                Some((r2, &mut near)),
                &mut Vec::new(),
            );
            assert_eq!(near, want, "{n} neighbours");
            let (mut xs, mut ys) = (vec![0.0; n], vec![0.0; n]);
            gather_positions(&states, &slots, &mut xs, &mut ys);
            assert_eq!(near_of(&xs, &ys, (p, r2)), want, "{n} neighbours, one at a time");
            bits_seen |= near;
        }
        // Both kinds at every length, up to the mask's last bit.
        assert!((20..44).contains(&bits_seen.count_ones()) && bits_seen >> 63 == 1, "{bits_seen:#x}");
    }

    #[test]
    fn a_neighbour_list_is_seen_as_the_grid_scan_sees_it_in_vector_and_scalar_code() {
        let n = 400;
        let (grid, sight, found) = scene(n);
        // Everyone at their places (a list names vehicles by place), the list all of them.
        let (ids, states): (Vec<_>, Vec<_>) =
            (0..n).map(|slot| grid.get(slot)).map(|e| (e.id, VehicleState::new(e.position, 0.0, 0.0))).unzip();
        let everyone = Everyone { ids: &ids, states: &states };
        let list: Vec<u32> = (0..n).rev().collect();
        let mut buffers = (Vec::new(), Vec::new(), Vec::new());
        let mut listed = Vec::new();
        let listed =
            sight.consider_listed(&list, everyone, (&mut buffers.0, &mut buffers.1, &mut buffers.2), None, &mut listed);
        // The same targets, distances and reach bits as the grid scan's keys.
        let named = |keys: &[u64], id_of: &dyn Fn(u32) -> VehicleId| {
            let mut named: Vec<_> =
                keys.iter().map(|&k| (id_of(k as u32 & !REACH).0, k >> 32, k as u32 & REACH)).collect();
            named.sort_unstable();
            named
        };
        let from_list = named(listed, &|place| ids[place as usize]);
        assert_eq!(from_list, named(&found, &|slot| grid.get(slot).id));
        assert!(from_list.len() > 50 && from_list.len() < n as usize, "{} of {n} seen", from_list.len());
        // The key pass gives the same bits compiled as it is and with AVX2.
        let (mut xs, mut ys) = (vec![0.0; n as usize], vec![0.0; n as usize]);
        gather_positions(&states, &list, &mut xs, &mut ys);
        let (xs, ys) = (&xs[..], &ys[..]);
        let (mut plain, mut wide) = (vec![0; n as usize], vec![0; n as usize]);
        ListKeysPass { sight: &sight, xs, ys, slots: &list, keys: &mut plain }.run();
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the processor has AVX2, checked just above.
            unsafe {
                crate::sim::grid::with_avx2(ListKeysPass { sight: &sight, xs, ys, slots: &list, keys: &mut wide })
            };
            assert_eq!(plain, wide);
        }
        assert_eq!(plain.iter().filter(|&&k| k != UNSEEN).count(), from_list.len());
    }

    #[test]
    fn the_radar_only_loop_reads_what_the_general_one_reads() {
        let (grid, sight, found) = scene(400);
        assert!(found.len() > 50, "{} candidates seen", found.len());
        for (dropout, range_sd) in [(0.3, 0.5), (0.0, 0.5), (0.3, 0.0), (0.0, 0.0)] {
            let radar = SensorError { range_sd, bearing_sd: 0.02, speed_sd: 0.3, dropout, occlusion: false };
            let errors = SensorErrors { radar, ..Default::default() };
            assert!(radar_errors_only(&errors));
            for tick in [0, 50_000, 1_000_000] {
                let draws = Draws::new(7, tick);
                let (mut general, mut fast) = (SensorReadings::default(), SensorReadings::default());
                let (mut general_stats, mut fast_stats) = (SensorStats::default(), SensorStats::default());
                let mut extents = Vec::new();
                let (mut a, mut b) = (found.clone(), found.clone());
                write_imperfect_readings(
                    &sight,
                    &errors,
                    draws,
                    &[],
                    &grid,
                    &mut a,
                    &mut extents,
                    &mut general_stats,
                    &mut general,
                );
                write_radar_error_readings(&sight, &errors.radar, draws, &grid, &mut b, &mut fast_stats, &mut fast);
                let bits = |r: &SensorReadings| -> Vec<(i32, [u64; 4])> {
                    r.0.iter()
                        .map(|d| (d.id.0, [d.position.x, d.position.y, d.velocity.x, d.velocity.y].map(f64::to_bits)))
                        .collect()
                };
                assert_eq!(bits(&general), bits(&fast), "dropout {dropout}, range sd {range_sd}, tick {tick}");
                assert_eq!(general_stats, fast_stats);
                if dropout > 0.0 {
                    assert!(fast_stats.missed_by_dropout > 0, "dropout {dropout} missed nothing");
                }
            }
        }
    }

    /// Targets `entries` (position, id) in a grid of `cell` [m], all seen by a velodyne of
    /// `range` [m] at the origin: their readings come by the exact squared distance, then id.
    fn assert_seen_nearest_first(entries: &[(DVec2, i32)], cell: f64, range: f64) {
        let mut grid = SpatialGrid::default();
        grid.rebuild(
            cell,
            entries.iter().enumerate().map(|(i, &(position, id))| GridEntry {
                position,
                velocity: DVec2::ZERO,
                id: VehicleId(id),
                index: i as u32,
            }),
        );
        let state = VehicleState::new(DVec2::ZERO, 0.0, 0.0);
        let velodyne = Velodyne { range };
        let sight = Sight::new(VehicleId(-1), &state, None, Some(&velodyne), false, &mut HalfCos::default());
        let (mut around, mut found) = (Candidates::default(), Vec::new());
        grid.gather_all(&mut around);
        let n = sight.consider_all(&around, &mut Vec::new(), &mut found).len();
        found.truncate(n);
        assert_eq!((n, found.len()), (entries.len(), n));
        let mut readings = SensorReadings::default();
        write_readings(&mut found, &grid, DVec2::ZERO, &mut readings);
        let mut want: Vec<(u64, i32)> = entries.iter().map(|&(p, id)| (p.length_squared().to_bits(), id)).collect();
        want.sort_unstable();
        let got: Vec<i32> = readings.0.iter().map(|d| d.id.0).collect();
        assert_eq!(got, want.iter().map(|w| w.1).collect::<Vec<_>>());
    }

    #[test]
    fn detections_come_nearest_first_by_the_exact_distance_then_id_even_where_an_f32_ties() {
        // Targets at 20 m + k * 1e-9 m (distinct doubles, one f32 squared distance), and pairs
        // at exactly equal distances with ids in both orders, slots shuffled by the grid.
        let mut entries = Vec::new();
        for k in 0..12u32 {
            let r = 20.0 + f64::from((k * 7) % 12) * 1e-9;
            let a = f64::from(k) * 0.5;
            entries.push((DVec2::new(r * a.cos(), r * a.sin()), 100 - k as i32));
        }
        for (k, id) in [(0, 7), (1, 3), (2, 9), (3, 1)] {
            let a = 1.0 + f64::from(k) * std::f64::consts::FRAC_PI_2;
            // Exactly 30 m: 30 (cos, sin) rounded may differ by an ulp, so mirror one point.
            let p = DVec2::new(30.0 * a.cos(), 30.0 * a.sin());
            entries.push((p, id));
            entries.push((-p, id + 200));
        }
        assert_seen_nearest_first(&entries, 100.0, 50.0);
        // The f32 keys did tie: the first twelve share one rounded distance.
        let rounded: std::collections::HashSet<u32> =
            entries[..12].iter().map(|(p, _)| (p.length_squared() as f32).to_bits()).collect();
        assert_eq!(rounded.len(), 1);
        let exact: std::collections::HashSet<u64> =
            entries[..12].iter().map(|(p, _)| p.length_squared().to_bits()).collect();
        assert!(exact.len() > 6, "only {} distinct distances", exact.len());
    }

    #[test]
    fn runs_of_tied_distances_of_any_length_and_place_come_in_exact_order() {
        // Groups of targets whose squared distances round to one f32 (radius r + k * 1e-9 m,
        // and mirrored pairs at exactly equal distances), of 1 to 150 targets, so that runs
        // start and end at and across the 64-key windows of the tie search; ids descending
        // within a group, so the exact order is not the order they were made in.
        let mut entries = Vec::new();
        let mut id = 10_000;
        let sizes = [1usize, 2, 3, 61, 1, 64, 2, 65, 1, 1, 150, 2, 4];
        for (g, size) in sizes.into_iter().enumerate() {
            let r = 10.0 + g as f64 * 7.0;
            for k in 0..size {
                let a = k as f64 * 0.37 + g as f64;
                let p = if k % 3 == 2 {
                    // Mirror the one before: exactly the same distance, another id.
                    -entries.last().map(|&(p, _): &(DVec2, i32)| p).expect("k > 0")
                } else {
                    let r = r + ((k * 5) % 7) as f64 * 1e-9;
                    DVec2::new(r * a.cos(), r * a.sin())
                };
                entries.push((p, id));
                id -= 1;
            }
        }
        assert_seen_nearest_first(&entries, 50.0, 1000.0);
        // The groups did tie in the f32 keys (each rounds to one value).
        let mut start = 0;
        for size in sizes {
            let group = &entries[start..start + size];
            let rounded: std::collections::HashSet<u32> =
                group.iter().map(|(p, _)| (p.length_squared() as f32).to_bits()).collect();
            assert_eq!(rounded.len(), 1, "the group of {size} at {start} rounds to one f32");
            start += size;
        }
    }

    /// One candidate's key as the sensors decided before their test was vectorised (one at a
    /// time, through `Cone::contains` and `DVec2`), `None` when not seen.
    fn one_key(sight: &Sight, slot: u32, position: DVec2, id: VehicleId) -> Option<u64> {
        let relative = position - sight.position;
        let d2 = relative.length_squared();
        let radar = (d2 <= sight.radar_range2) && sight.cone.contains(relative, d2);
        let velodyne = d2 <= sight.velodyne_range2;
        let flags = (u32::from(radar) << 31) | (u32::from(velodyne) << 30);
        ((sight.omniscient() || velodyne || radar) && id != sight.id).then(|| detection_key(d2, slot | flags))
    }

    #[test]
    fn the_vectorised_candidate_test_keeps_what_the_one_at_a_time_test_keeps() {
        let (grid, _, _) = scene(500);
        let mut around = Candidates::default();
        grid.gather_all(&mut around);
        // Sensors at a target's spot (distance 0), facing every way, with acute, obtuse, full and
        // no radar cones, with and without a velodyne, omniscient or not.
        let radars = [
            None,
            Some(Radar::default()),
            Some(Radar { range: 60.0, angle: 4.0 }),
            Some(Radar { range: 80.0, angle: TAU }),
        ];
        let mut seen_any = [false; 2];
        for (k, (&radar, velodyne)) in
            radars.iter().zip([None, Some(Velodyne { range: 30.0 })]).cycle().take(8).enumerate()
        {
            for (j, omniscient) in [false, true].into_iter().enumerate() {
                let at = grid.get((k * 37 % grid.len()) as u32).position;
                let state = VehicleState::new(at, k as f64 * 0.9 - 3.0, 5.0);
                let sight = Sight::new(
                    VehicleId(k as i32),
                    &state,
                    radar.as_ref(),
                    velodyne.as_ref(),
                    omniscient,
                    &mut HalfCos::default(),
                );
                let want: Vec<u64> = (0..around.len())
                    .filter_map(|c| {
                        one_key(&sight, around.slots[c], DVec2::new(around.xs[c], around.ys[c]), around.ids[c])
                    })
                    .collect();
                // Buffers longer than needed from an earlier vehicle: only the seen part counts.
                let (mut keys, mut got) = (vec![7; around.len() + 3], vec![9; around.len() + 5]);
                let seen = sight.consider_all(&around, &mut keys, &mut got);
                assert_eq!(seen, &want[..], "sensor {k}, omniscient {omniscient}");
                // Both compilations of the first pass, whichever the processor runs.
                let mut plain = vec![0; around.len()];
                sight.keys(&around, &mut plain);
                #[cfg(target_arch = "x86_64")]
                if std::arch::is_x86_feature_detected!("avx2") {
                    let mut wide = vec![0; around.len()];
                    // SAFETY: checked just above.
                    unsafe {
                        crate::sim::grid::with_avx2(KeysPass { sight: &sight, around: &around, found: &mut wide })
                    };
                    assert_eq!(wide, plain);
                }
                assert_eq!(plain.iter().filter(|&&k| k != UNSEEN).count(), want.len());
                seen_any[j] |= !want.is_empty() && want.len() < around.len() - 1;
            }
        }
        assert!(seen_any[0], "no sensor saw some but not all");
    }

    #[test]
    fn the_remembered_half_cosine_follows_the_angle_asked() {
        let mut half = HalfCos::default();
        for angle in [1.0, 1.0, 0.5, 1.0, std::f64::consts::TAU, 0.5] {
            assert_eq!(half.of(angle).to_bits(), (0.5 * angle).cos().to_bits(), "angle {angle}");
        }
    }

    #[test]
    fn small_rotation_is_the_rotation() {
        for k in -2000..=2000 {
            let a = f64::from(k) * 1e-4; // -0.2 ..= 0.2 rad, both sides of the switch
            let (r, exact) = (small_rotation(a), DVec2::from_angle(a));
            assert!((r - exact).abs().max_element() < 1e-15, "angle {a}: {r} vs {exact}");
        }
    }
}

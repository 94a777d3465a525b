//! The Verlet neighbour lists over the grid, shared by the sensors and the wifi round
//! ([`SensorGrid`]): each vehicle's list holds those within its sensors' range (or the wifi
//! range) plus a skin, kept while no two neighbours closed in on each other by the skin.

use bevy_ecs::prelude::Resource;
use glam::DVec2;

use crate::sim::{Parallelism, SpatialGrid};
use crate::world::{Radar, SimTime, VehicleId, VehicleState, Velodyne};

/// The grid all sensors query and the neighbour lists built over it (`NeighbourLists`),
/// kept between sensor ticks: the grid is rebuilt every tick where the lists are not used,
/// else with the lists.
#[derive(Resource, Debug, Default)]
pub struct SensorGrid {
    pub(crate) grid: SpatialGrid,
    pub(crate) neighbours: Neighbours,
}
/// Every vehicle of the (single) ECS table, in query order.
#[derive(Clone, Copy)]
pub(crate) struct Everyone<'a> {
    pub(crate) ids: &'a [VehicleId],
    pub(crate) states: &'a [VehicleState],
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
pub(crate) struct NeighbourLists {
    /// Every vehicle's id at the build, in query order (a list names vehicles by place).
    pub(crate) ids: Vec<VehicleId>,
    /// Every vehicle's position at the build [m].
    pub(crate) anchors: Vec<DVec2>,
    /// Every vehicle's sensors at the build.
    pub(crate) shapes: Vec<Shape>,
    /// Every vehicle's heading at the build (a unit vector).
    pub(crate) headings: Vec<DVec2>,
    /// The wifi range at the build [m] (0 without V2V): every list holds at least that far
    /// all around (or its whole sensor range, when shorter), so the wifi round can use them.
    pub(crate) floor: f64,
    /// Skin of the build [m] (0: no lists built yet).
    pub(crate) skin: f64,
    /// How far every list reaches all around (the shortest of [`Reach::around`]) [m].
    pub(crate) around: f64,
    /// Every vehicle's neighbours, nearest first at the build (so that a tick's detections
    /// arrive nearly sorted), as places in the query: vehicle i's are
    /// `neighbours[starts[i]..starts[i + 1]]`. One array, in query order, so that a pass over
    /// the vehicles reads it straight through (a list per vehicle, each its own allocation,
    /// made every list a cache miss: two thirds of a wifi round's samples).
    pub(crate) lists: Lists,
    /// Each vehicle's drift cell (see [`NeighbourLists::moved_together`]), in query order: an
    /// index into the cells occupied at the build.
    pub(crate) cell_of: Vec<u32>,
    /// How many drift cells are occupied.
    pub(crate) cells: usize,
    /// The pairs of occupied drift cells that touch (a cell with itself too), each once.
    pub(crate) touching: Vec<[u32; 2]>,
    /// Farthest any vehicle may move from its anchor before the lists are built again [m]:
    /// vehicles in drift cells that do not touch cannot come within sensor range until then.
    pub(crate) max_drift: f64,
    /// The widest sensor range of the build [m]: while the lists hold, no two vehicles within
    /// this of each other now have closed in by the skin since the build (vehicles in drift cells
    /// that do not touch stay farther apart), what the plugin sensors' lists rely on
    /// ([`crate::sim::sensor_plugins::Nearby::around`]).
    pub(crate) guarded: f64,
    /// Builds so far.
    pub(crate) builds: u64,
    /// Sensor ticks that kept the lists in one pass ([`sense_with_kept_lists`]), and those whose
    /// one pass was thrown away.
    pub(crate) kept_in_one_pass: u64,
    pub(crate) thrown_away: u64,
    /// Sensor ticks since the last build that kept the lists.
    pub(crate) kept_since_build: u32,
    /// Which neighbours on each vehicle's list (bit k: the list's k-th; lists of at most 64)
    /// lay within the wifi range (squared: `near_r2` [m²]) at the instant `near_at`, in query
    /// order: noted by the sensor tick at the instant the wifi round asked for ([`NearWanted`])
    /// from the coordinates it gathered for its keys, for the round to take ([`SensorGrid::near`])
    /// instead of testing every neighbour on the list again.
    pub(crate) near: Vec<u64>,
    pub(crate) near_at: Option<SimTime>,
    pub(crate) near_r2: f64,
    /// The instant the sensors last found the lists to hold (or built them) for the vehicles'
    /// states then. States change only in the dynamics, at the end of an instant (after sensing,
    /// communication and control, see [`crate::vehicles::LanePositionsAt`]), so the lists hold
    /// for every module at that instant: the wifi round then need not test the drift again.
    pub(crate) held_at: Option<SimTime>,
}

/// Per drift cell, the smallest and largest displacement since the build of its vehicles along
/// x and y [m]: `[min x, max x, min y, max y]`.
pub(crate) type DriftBox = [f64; 4];

/// A box holding nothing yet.
pub(crate) const EMPTY_BOX: DriftBox = [f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY];

/// Scratch of [`NeighbourLists::moved_together`], kept between ticks.
#[derive(Debug, Default)]
pub(crate) struct DriftScratch {
    pub(crate) boxes: Vec<DriftBox>,
    pub(crate) parts: Vec<DriftPart>,
}

/// What one chunk of vehicles found of their displacements since the build (none yet: 0, all
/// finite, no runs).
#[derive(Debug)]
pub(crate) struct DriftPart {
    /// The largest squared displacement [m²].
    pub(crate) farthest: f64,
    /// Whether every displacement is finite.
    pub(crate) finite: bool,
    /// Whether a vehicle turned by [`TURN`] or more.
    pub(crate) turned: bool,
    /// Each run of vehicles in one drift cell: the cell and their box of displacements.
    pub(crate) runs: Vec<(u32, DriftBox)>,
}

impl Default for DriftPart {
    fn default() -> Self {
        DriftPart { farthest: 0.0, finite: true, turned: false, runs: Vec::new() }
    }
}

impl DriftPart {
    /// Empty again, as [`DriftPart::default`] (keeping the runs' allocation).
    pub(crate) fn clear(&mut self) {
        self.runs.clear();
        (self.farthest, self.finite, self.turned) = (0.0, true, false);
    }

    /// Add the displacements of the vehicles at `states` from their `anchors`, in drift cells
    /// `cells`, and whether one turned from its heading `headings` by [`TURN`]. Vehicles near
    /// each other are mostly next to each other in the query: a run of them in one cell is
    /// boxed in registers and noted once (a merge into memory per vehicle waited on the last
    /// one's store).
    pub(crate) fn add(&mut self, anchors: &[DVec2], headings: &[DVec2], states: &[VehicleState], cells: &[u32]) {
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
pub(crate) const DRIFT_CELL: f64 = 4.0;

/// How far a vehicle may turn from its heading at the build of the lists [rad] before they are
/// built again: a list leaves out what lies behind the radar cone beyond the all-around reach
/// ([`Reach`]), which a turn brings into view. 30°: lane changes and long bends keep them.
pub(crate) const TURN: f64 = std::f64::consts::FRAC_PI_6;

/// A vehicle's sensors as its neighbour list was built for: radar range [m] and full opening
/// angle [rad] (0 and 0 without a radar), velodyne range [m] (0 without).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Shape {
    pub(crate) radar: f64,
    pub(crate) angle: f64,
    pub(crate) velodyne: f64,
}

/// What `typical_range` and the neighbour lists need to know of a run of `Shape`s, found
/// in the pass that makes them (split over the threads) and merged in order: the first bounded
/// range, whether every bounded range equals it, and whether every range is finite.
#[derive(Debug, Clone, Copy)]
#[repr(align(128))]
pub struct ShapeSummary {
    pub(crate) first: Option<u64>,
    pub(crate) uniform: bool,
    pub(crate) finite: bool,
    /// Every shape equals the one at its place in the neighbour lists' last build (their
    /// [`NeighbourLists::hold`] compared the whole slice again, serially, every sensor tick).
    pub(crate) as_built: bool,
}

impl Default for ShapeSummary {
    fn default() -> Self {
        ShapeSummary { first: None, uniform: true, finite: true, as_built: true }
    }
}

impl ShapeSummary {
    pub(crate) fn add(&mut self, shape: &Shape) {
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
    pub(crate) fn then(&mut self, next: &ShapeSummary) {
        self.finite &= next.finite;
        self.as_built &= next.as_built;
        match (self.first, next.first) {
            (None, _) => (self.first, self.uniform) = (next.first, next.uniform),
            (Some(_), None) => {}
            (Some(a), Some(b)) => self.uniform &= next.uniform && a == b,
        }
    }

    /// [`typical_range`] of the bounded ranges, when every one is the same (or there is none).
    pub(crate) fn typical(&self) -> Option<f64> {
        match self.first {
            None => Some(typical_range(&mut [])),
            Some(bits) => self.uniform.then_some(f64::from_bits(bits)),
        }
    }
}

impl Shape {
    /// No radar, no velodyne.
    pub(crate) const NONE: Shape = Shape { radar: 0.0, angle: 0.0, velodyne: 0.0 };

    pub(crate) fn of(radar: Option<&Radar>, velodyne: Option<&Velodyne>) -> Shape {
        Shape {
            radar: radar.map_or(0.0, |r| r.range),
            angle: radar.map_or(0.0, |r| r.angle),
            velodyne: velodyne.map_or(0.0, |v| v.range),
        }
    }

    /// Its largest range [m] (0 without radar and velodyne).
    pub(crate) fn range(&self) -> f64 {
        self.radar.max(self.velodyne)
    }

    /// How far its list reaches all around [m]: the velodyne's range, or the wifi range
    /// `floor` [m] where that is longer (within the sensors' largest range).
    pub(crate) fn around(&self, floor: f64) -> f64 {
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
pub(crate) struct Reach {
    pub(crate) around2: f64,
    pub(crate) heading: DVec2,
    /// Half the radar's opening angle plus [`TURN`] [rad] (none without a radar), and its
    /// cosine and sine.
    pub(crate) half: Option<(f64, f64, f64)>,
    pub(crate) skin: f64,
}

impl Reach {
    pub(crate) fn new(shape: &Shape, heading: DVec2, floor: f64, skin: f64) -> Reach {
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
    pub(crate) fn holds(&self, relative: DVec2, d2: f64) -> bool {
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
    pub(crate) starts: Vec<u32>,
    pub(crate) neighbours: Vec<u32>,
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
pub(crate) struct Neighbours {
    pub(crate) lists: NeighbourLists,
    pub(crate) shapes_now: Vec<Shape>,
    /// Scratch of [`NeighbourLists::moved_together`] and of the drift cells' build.
    pub(crate) drift: DriftScratch,
    pub(crate) keys: Vec<(i64, i64)>,
}

/// The skin of the neighbour lists as a share of the typical sensor range: wider lists cost
/// more tests per tick, narrower ones more builds. At 100 m, 20 m: a build once neighbours
/// 10 m/s apart in speed have driven 2 s.
pub(crate) const SKIN_SHARE: f64 = 0.2;

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
    pub(crate) fn size_near(&mut self, n: usize) {
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
    pub(crate) fn hold(
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
    pub(crate) fn of_vehicles(&self, everyone: Everyone<'_>) -> bool {
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
    pub(crate) fn drifted_together<'p>(
        &self,
        parts: impl Iterator<Item = &'p DriftPart>,
        boxes: &mut Vec<DriftBox>,
    ) -> bool {
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
    pub(crate) fn place_in_drift_cells(&mut self, keys: &mut Vec<(i64, i64)>) {
        let widest = self.shapes.iter().map(Shape::range).fold(0.0, f64::max) + self.skin;
        let side = DRIFT_CELL * widest;
        // Non-touching cells are more than a side apart; each of two vehicles may close in by
        // `max_drift`, and must stay farther apart than the widest range (a margin for rounding).
        self.max_drift = 0.49 * (side - (widest - self.skin));
        self.guarded = widest - self.skin;
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
/// Whether a sensor range `r` [m] bounds what the sensor sees (positive and finite): the ranges
/// [`typical_range`] takes the median of.
pub(crate) fn bounded(r: &f64) -> bool {
    *r > 0.0 && r.is_finite()
}

/// Side of the sensor grid's cells [m]: the median of the sensing vehicles' positive ranges
/// (100 m when none has one). `ranges` is scratch space, reused between ticks.
pub(crate) fn typical_range(ranges: &mut [f64]) -> f64 {
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

//! Sensors by name: the trait a student's sensor implements ([`ScenarioSensor`]), the registry
//! from a vehicle's `sensors = { NAME = { ... } }` to it, the neighbour query a sensor system
//! reads ([`Nearby`]) and the helpers that give a plugin sensor the built-in sensors' noise,
//! dropout and occlusion ([`PluginDraws`], [`Occlusion`]).
//!
//! A plugin sensor's parameters live on its vehicles as [`Sensor<S>`], stored sparsely: a
//! component stored in the vehicles' table would split them into two tables, and the built-in
//! sensors' neighbour lists serve only vehicles of one table, so a camera on a tenth of the
//! vehicles would slow every vehicle's radar. Its system runs in [`PluginSensorSystems::Sense`]
//! (after the built-in sensors wrote their readings) and writes its detections, named, into
//! the vehicle's [`SensorReadings`] ([`SensorReadings::set_sensor`]). [`PluginSense::each`]
//! runs it over the simulator's threads ([`Parallelism`]), as the built-in sensors run, with
//! the same readings for any thread count.
//!
//! ```
//! use smlworld::prelude::*;
//! use smlworld::sim::sensor_plugins::{Nearby, ScenarioSensor, Sensor};
//!
//! #[derive(serde::Deserialize, Clone)]
//! #[serde(deny_unknown_fields)]
//! struct Ring {
//!     range: f64,
//! }
//!
//! impl ScenarioSensor for Ring {
//!     fn range(&self) -> f64 {
//!         self.range
//!     }
//! }
//!
//! let mut sim = SimBuilder::new();
//! sim.register_sensor::<Ring>("ring");
//! assert!(sim.controllers().sensors().contains("ring"));
//! ```

use std::cell::Cell;
use std::collections::BTreeMap;
use std::sync::OnceLock;

use bevy_ecs::prelude::{Component, EntityWorldMut, Local, Query, Res, ResMut, Resource, With};
use bevy_ecs::schedule::SystemSet;
use bevy_ecs::system::SystemParam;
use glam::DVec2;
use serde::de::DeserializeOwned;

use super::errors::{Footprint, SensorKeys, add_noise};
use super::readings::SensorStats;
use super::tick::{EveryoneQuery, one_table};
use crate::sim::grid::lists::{Everyone, NeighbourLists, SensorGrid};
use crate::sim::grid::{GridEntry, SpatialGrid};
use crate::sim::params::{ControllerParamError, parse_plugin_params};
use crate::sim::random::{key, mix};
use crate::sim::{Parallelism, SimClock, SimSeed};
use crate::world::{Detection, IdMap, SensorError, SensorReadings, SimTime, VehicleId, VehicleSize, VehicleState};

/// A sensor a scenario can name: the keys of its table in a vehicle's `sensors` are
/// deserialised into the type (`deny_unknown_fields` refuses a misspelt key, naming it).
pub trait ScenarioSensor: DeserializeOwned + Clone + Send + Sync + 'static {
    /// Check the values after parsing: `Err((key, problem))` names the key (relative to the
    /// sensor's table) and what is allowed. The default accepts everything.
    fn check(&self) -> Result<(), (String, String)> {
        Ok(())
    }

    /// The farthest it sees \[m\]: [`Nearby`] keeps its grid's cells at least this large.
    fn range(&self) -> f64;
}

/// A plugin sensor on a vehicle: its registered name and its parameters. Stored sparsely, so
/// the vehicles that carry one stay in the table of those that do not (see the module docs).
#[derive(Component, Debug, Clone)]
#[component(storage = "SparseSet")]
pub struct Sensor<S: Send + Sync + 'static> {
    /// The name it was registered under (what its detections say, [`Detection::sensor`]).
    pub name: &'static str,
    /// Its parameters, from the scenario.
    pub params: S,
}

impl<S: Send + Sync + 'static> std::ops::Deref for Sensor<S> {
    type Target = S;
    fn deref(&self) -> &S {
        &self.params
    }
}

/// Marks a vehicle that carries at least one plugin sensor (stored sparsely): [`Nearby`]'s grid
/// is built only while there is one.
#[derive(Component, Debug, Clone, Copy, Default)]
#[component(storage = "SparseSet")]
pub struct CarriesPluginSensor;

/// A parsed, checked sensor of a registered type, ready to put on a vehicle.
pub trait AttachSensor: Send + Sync {
    /// Insert the [`Sensor`] (and [`SensorReadings`] where the vehicle has none).
    fn attach(&self, vehicle: &mut EntityWorldMut<'_>);
}

struct Parsed<S> {
    name: &'static str,
    params: S,
}

impl<S: ScenarioSensor> AttachSensor for Parsed<S> {
    fn attach(&self, vehicle: &mut EntityWorldMut<'_>) {
        attach_sensor(vehicle, self.name, self.params.clone());
    }
}

/// Put sensor `params`, registered as `name`, on `vehicle`, as a scenario does.
pub fn attach_sensor<S: ScenarioSensor>(vehicle: &mut EntityWorldMut<'_>, name: &'static str, params: S) {
    let range = params.range();
    vehicle.insert((Sensor { name, params }, CarriesPluginSensor));
    if !vehicle.contains::<SensorReadings>() {
        vehicle.insert(SensorReadings::default());
    }
    vehicle.world_scope(|w| {
        let mut index = w.get_resource_or_insert_with(NearbyIndex::default);
        index.reach = index.reach.max(range);
    });
}

type Parse = fn(&'static str, toml::Table) -> Result<Box<dyn AttachSensor>, ControllerParamError>;

fn parse_as<S: ScenarioSensor>(
    name: &'static str,
    params: toml::Table,
) -> Result<Box<dyn AttachSensor>, ControllerParamError> {
    Ok(Box::new(Parsed { name, params: parse_plugin_params::<S>(params, S::check)? }))
}

/// The names of the built-in sensors; a plugin cannot register them.
pub const BUILT_IN_SENSORS: [&str; 3] = ["radar", "velodyne", "omniscient"];

/// A sensor name is taken already.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("sensor name `{0}` is taken (built in or registered twice): register it under another name")]
pub struct DuplicateSensor(pub String);

/// Sensors registered by plugins, by name (in name order).
#[derive(Clone, Default)]
pub struct SensorRegistry {
    entries: BTreeMap<&'static str, Parse>,
}

impl std::fmt::Debug for SensorRegistry {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_list().entries(self.entries.keys()).finish()
    }
}

impl SensorRegistry {
    /// Register `S` under `name`; a built-in name or one registered already is an error. The
    /// name is kept for the rest of the process (each detection refers to it).
    pub fn register<S: ScenarioSensor>(&mut self, name: &str) -> Result<(), DuplicateSensor> {
        if BUILT_IN_SENSORS.contains(&name) || self.entries.contains_key(name) {
            return Err(DuplicateSensor(name.to_string()));
        }
        let name: &'static str = Box::leak(name.to_owned().into_boxed_str());
        self.entries.insert(name, parse_as::<S>);
        Ok(())
    }

    /// Whether `name` is registered.
    pub fn contains(&self, name: &str) -> bool {
        self.entries.contains_key(name)
    }

    /// Parse and check `params` (the sensor's table) as sensor `name`; `None` when no such
    /// sensor is registered.
    pub fn parse(
        &self,
        name: &str,
        params: toml::Table,
    ) -> Option<Result<Box<dyn AttachSensor>, ControllerParamError>> {
        self.entries.get_key_value(name).map(|(name, parse)| parse(name, params))
    }

    /// "built in: radar, ...; registered by plugins: ..." for error messages.
    pub fn known_list(&self) -> String {
        let registered: Vec<&str> = self.entries.keys().copied().collect();
        let mut s = format!("built in: {}", BUILT_IN_SENSORS.join(", "));
        if registered.is_empty() {
            s.push_str("; none registered by plugins");
        } else {
            s.push_str(&format!("; registered by plugins: {}", registered.join(", ")));
        }
        s
    }
}

/// The phases of plugin sensing inside [`crate::sim::SimSystems::Sense`], after the built-in sensors:
/// [`Nearby`]'s grid is built, then the plugin sensors sense.
#[derive(SystemSet, Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PluginSensorSystems {
    /// The neighbour grid is rebuilt ([`index_nearby`]).
    Index,
    /// Plugin sensors read [`Nearby`] and write readings: put a sensor's system here.
    Sense,
}

/// What [`Nearby`] answers from, made once per sensor tick while any vehicle carries a plugin
/// sensor ([`index_nearby`]): each carrier's own neighbour list where the built-in sensors'
/// lists hold ([`Nearby::around`]), else a grid of every vehicle.
#[derive(Resource, Debug, Default)]
pub struct NearbyIndex {
    grid: SpatialGrid,
    /// Footprints by grid index, for occlusion.
    footprints: Vec<Footprint>,
    /// The longest plugin sensor range [m] (the cells are at least this large).
    reach: f64,
    /// When it was built.
    built_at: Option<SimTime>,
    /// Vehicles in the world at that tick.
    vehicles: usize,
    /// Whether this tick's carriers are served by their lists ([`CarrierLists`]); the grid
    /// is then not rebuilt, and [`Nearby::within`] builds one of its own on first use (`lazy`).
    serving: bool,
    lazy: OnceLock<Box<(SpatialGrid, Vec<Footprint>)>>,
    carriers: CarrierLists,
    /// Never serve from the lists (tests compare both ways).
    pub(crate) grid_only: bool,
}

impl NearbyIndex {
    /// Sensor ticks whose carriers were served by their lists.
    pub fn ticks_served_by_lists(&self) -> u64 {
        self.carriers.ticks_served
    }

    /// Whether the last sensor tick was served by the lists.
    pub fn served_by_lists(&self) -> bool {
        self.serving
    }
}

/// Each plugin sensor carrier's Verlet neighbour list, made over the positions at the built-in
/// sensors' last list build ([`crate::sim::grid::lists::NeighbourLists`]) with their skin.
///
/// While those lists hold, no two vehicles within the widest built-in sensor range of each
/// other have closed in by the skin since the build (`NeighbourLists::moved_together`). So
/// for a plugin reach within that range, every vehicle within the reach of a carrier now lay
/// within the reach plus the skin of it then: on its list. A sensor tick that finds the
/// built-in lists held at its instant (they were just tested or built by the built-in sensors)
/// reads the lists, with no O(N) work of its own; they are made again after each build of the
/// built-in lists, or when the carriers or the reach change.
#[derive(Debug, Default)]
struct CarrierLists {
    /// The built-in lists' build they were made from (`NeighbourLists::builds`).
    build: Option<u64>,
    /// The plugin reach they were made for [m].
    reach: f64,
    /// The carriers, in query order, when they were made.
    ids: Vec<VehicleId>,
    /// Each carrier's list: `rows[starts[k]..starts[k + 1]]`, places in the vehicles' table.
    of: IdMap<u32>,
    starts: Vec<u32>,
    rows: Vec<u32>,
    /// The anchors' grid of the last making (kept for its allocation).
    grid: SpatialGrid,
    /// Sensor ticks served by the lists.
    ticks_served: u64,
}

impl CarrierLists {
    /// Whether the lists serve this tick (made again first where stale): the built-in lists
    /// held at `now` for every vehicle, in one table, with a skin, guarding `reach`.
    fn serve(
        &mut self,
        sensors: &SensorGrid,
        carriers: &Query<&VehicleId, With<CarriesPluginSensor>>,
        everyone: &EveryoneQuery,
        (reach, now): (f64, SimTime),
    ) -> bool {
        let lists = &sensors.neighbours.lists;
        let Some((ids, states)) = one_table(everyone) else { return false };
        let holds = lists.skin > 0.0
            && lists.held_at == Some(now)
            && reach <= lists.guarded
            && lists.of_vehicles(Everyone { ids, states });
        if !holds {
            return false;
        }
        if self.build != Some(lists.builds) || self.reach != reach || !carriers.iter().eq(self.ids.iter()) {
            self.make(lists, carriers, reach);
        }
        true
    }

    /// Each carrier's list: every vehicle within `reach` plus the skin of it at the build.
    fn make(&mut self, lists: &NeighbourLists, carriers: &Query<&VehicleId, With<CarriesPluginSensor>>, reach: f64) {
        (self.build, self.reach) = (Some(lists.builds), reach);
        self.ids.clear();
        self.ids.extend(carriers.iter().copied());
        let row_of: IdMap<u32> = lists.ids.iter().enumerate().map(|(i, &id)| (id, i as u32)).collect();
        let radius = reach + lists.skin;
        let entry = |i: usize| GridEntry {
            position: lists.anchors[i],
            velocity: DVec2::ZERO,
            id: lists.ids[i],
            index: i as u32,
        };
        self.grid.rebuild(radius, (0..lists.ids.len()).map(entry));
        self.of.clear();
        self.rows.clear();
        self.starts.clear();
        self.starts.push(0);
        for id in &self.ids {
            // (Every carrier is one of the vehicles; one that is not gets no list.)
            let Some(&row) = row_of.get(id) else { continue };
            let (at, from) = (lists.anchors[row as usize], self.rows.len());
            self.grid.for_each_within(at, radius, |_, point, _| self.rows.push(point.index));
            // Nearest first at the build, so that a tick's neighbours come nearly sorted (the
            // sort of [`Nearby::around`] then moves few of them), as the built-in lists are kept.
            let d2 = |j: &u32| lists.anchors[*j as usize].distance_squared(at);
            self.rows[from..].sort_unstable_by(|a, b| d2(a).total_cmp(&d2(b)).then(a.cmp(b)));
            self.of.insert(*id, self.starts.len() as u32 - 1);
            self.starts.push(self.rows.len() as u32);
        }
    }

    /// The list of carrier `id`, if it has one.
    fn of(&self, id: VehicleId) -> Option<&[u32]> {
        let k = *self.of.get(&id)? as usize;
        Some(&self.rows[self.starts[k] as usize..self.starts[k + 1] as usize])
    }
}

/// One vehicle near a query's position.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Neighbour {
    /// Its id.
    pub id: VehicleId,
    /// Its position \[m\].
    pub position: DVec2,
    /// Its velocity [m/s].
    pub velocity: DVec2,
    /// Squared distance from the query's position \[m²\].
    pub distance_squared: f64,
    footprint: Footprint,
}

impl Neighbour {
    /// The ground-truth detection of it by sensor `sensor`.
    pub fn detection(&self, sensor: &'static str) -> Detection {
        Detection { id: self.id, position: self.position, velocity: self.velocity, sensor }
    }
}

/// The neighbour query of plugin sensors: every vehicle within a range of a position, O(k) for
/// the k found (plus their sort), from each carrier's own list ([`Nearby::around`]) or a grid
/// of every vehicle built this sensor tick ([`Nearby::within`]).
#[derive(SystemParam)]
pub struct Nearby<'w, 's> {
    index: Res<'w, NearbyIndex>,
    everyone: EveryoneQuery<'w, 's>,
}

impl Nearby<'_, '_> {
    /// Every vehicle within `range` \[m\] of `position` (inclusive), nearest first (ties by id),
    /// into `out` (cleared first; keep one buffer per system to allocate nothing per tick). The
    /// vehicle at `position` itself is among them: skip your own id. Any position; a sensor on
    /// a vehicle asks [`Nearby::around`], which costs no grid.
    pub fn within(&self, position: DVec2, range: f64, out: &mut Vec<Neighbour>) {
        let index = &*self.index;
        let (grid, footprints) = if index.serving {
            let live = index.lazy.get_or_init(|| {
                let mut live = Box::<(SpatialGrid, Vec<Footprint>)>::default();
                let (grid, footprints) = &mut *live;
                fill_grid(grid, footprints, &self.everyone, Parallelism::single(), index.reach);
                live
            });
            (&live.0, &live.1)
        } else {
            (&index.grid, &index.footprints)
        };
        out.clear();
        grid.for_each_within(position, range, |slot, point, d2| {
            let e = grid.get(slot);
            let footprint = footprints[point.index as usize];
            out.push(Neighbour {
                id: point.id,
                position: point.position,
                velocity: e.velocity,
                distance_squared: d2,
                footprint,
            });
        });
        sort_nearest_first(out);
    }

    /// What [`Nearby::within`] gives for `position`, the place of vehicle `me` (which carries
    /// a plugin sensor), and `range` up to the longest plugin range: the same vehicles in the
    /// same order, read from `me`'s own neighbour list where the built-in sensors' lists hold
    /// ([`NearbyIndex`]), else from the grid.
    pub fn around(&self, me: VehicleId, position: DVec2, range: f64, out: &mut Vec<Neighbour>) {
        self.around_where(me, position, range, |_, _| true, out);
    }

    /// [`Nearby::around`] keeping only the vehicles for which `keep(relative, d2)` holds (their
    /// position relative to `position` \[m\] and its squared length \[m²\]: a field of view,
    /// [`crate::sim::Cone::contains`]): the same as filtering `around`'s answer, but the others are never
    /// gathered or sorted.
    pub fn around_where(
        &self,
        me: VehicleId,
        position: DVec2,
        range: f64,
        keep: impl Fn(DVec2, f64) -> bool,
        out: &mut Vec<Neighbour>,
    ) {
        let index = &*self.index;
        let listed = if index.serving && range <= index.carriers.reach { index.carriers.of(me) } else { None };
        let (Some(rows), Some((ids, states, sizes))) = (listed, self.table()) else {
            self.within(position, range, out);
            return out.retain(|n| keep(n.position - position, n.distance_squared));
        };
        out.clear();
        let r2 = range * range;
        for &j in rows {
            let (j, state) = (j as usize, &states[j as usize]);
            let relative = state.position - position;
            let d2 = relative.length_squared();
            if d2 <= r2 && keep(relative, d2) {
                let size = sizes.map_or_else(VehicleSize::default, |sizes| sizes[j]);
                out.push(Neighbour {
                    id: ids[j],
                    position: state.position,
                    velocity: state.velocity,
                    distance_squared: d2,
                    footprint: Footprint::new(size, state.yaw),
                });
            }
        }
        sort_nearest_first(out);
    }

    /// The ids, states and sizes of the one non-empty ECS table of every vehicle, if they are
    /// all in one.
    #[allow(clippy::type_complexity)]
    fn table(&self) -> Option<(&[VehicleId], &[VehicleState], Option<&[VehicleSize]>)> {
        let mut full = self.everyone.contiguous_iter().ok()?.filter(|(ids, _, _)| !ids.is_empty());
        let table = full.next()?;
        full.next().is_none().then_some(table)
    }

    /// When it was built (`None`: no vehicle carries a plugin sensor yet).
    pub fn built_at(&self) -> Option<SimTime> {
        self.index.built_at
    }
}

/// Nearest first, ties by id: the order of [`Nearby::within`].
fn sort_nearest_first(out: &mut [Neighbour]) {
    out.sort_unstable_by(|a, b| a.distance_squared.total_cmp(&b.distance_squared).then(a.id.cmp(&b.id)));
}

/// Fill `grid` and `footprints` with every vehicle, cells of side `reach` (50 m when 0): split
/// over `parallelism`'s threads when every vehicle lies in one ECS table, the common case.
fn fill_grid(
    grid: &mut SpatialGrid,
    footprints: &mut Vec<Footprint>,
    everyone: &EveryoneQuery,
    parallelism: Parallelism,
    reach: f64,
) {
    let cell = if reach > 0.0 { reach } else { 50.0 };
    footprints.clear();
    footprints.extend(everyone.iter().map(|(_, s, size)| Footprint::new(size.copied().unwrap_or_default(), s.yaw)));
    let entry = |i: usize, id: VehicleId, s: &VehicleState| GridEntry {
        position: s.position,
        velocity: s.velocity,
        id,
        index: i as u32,
    };
    match one_table(everyone) {
        Some((ids, states)) => {
            grid.rebuild_on(parallelism, cell, ids.len().min(states.len()), |i| entry(i, ids[i], &states[i]))
        }
        None => grid.rebuild(cell, everyone.iter().enumerate().map(|(i, (&id, s, _))| entry(i, id, s))),
    }
}

/// What a plugin sensor system reads each sensor tick ([`Nearby`], the time, the seed) and
/// the threads it runs on: [`PluginSense::each`] calls the sensor's code for every vehicle
/// that carries it, the vehicles cut into chunks shared out over [`Parallelism`] as the
/// built-in sensors' are. Each vehicle's readings depend only on the grid, its own components
/// and counter-based draws ([`PluginDraws`]), and the counts are summed chunk by chunk, so one
/// thread or four give the same readings and the same [`PluginSensorStats`].
#[derive(SystemParam)]
pub struct PluginSense<'w, 's> {
    nearby: Nearby<'w, 's>,
    clock: Res<'w, SimClock>,
    seed: Option<Res<'w, SimSeed>>,
    parallelism: Option<Res<'w, Parallelism>>,
    stats: ResMut<'w, PluginSensorStats>,
    scratch: Local<'s, Vec<PluginScratch>>,
}

/// One chunk's buffers of [`PluginSense::each`], kept between ticks (so the steady state
/// allocates nothing per vehicle), on cache lines of its own ([`crate::sim::Padded`]).
#[derive(Debug, Default)]
#[repr(align(128))]
pub struct PluginScratch {
    found: Vec<Neighbour>,
    occlusion: Occlusion,
    stats: PluginSensorStats,
}

/// What [`PluginSense::each`] hands a plugin sensor's code with each vehicle: the neighbour
/// query, the tick, the seed, and buffers and counts of its own (one per chunk of vehicles).
pub struct Sensing<'a, 'w, 's> {
    /// The neighbour query ([`Nearby::around`], [`Nearby::within`]).
    pub nearby: &'a Nearby<'w, 's>,
    /// The sensor tick's time.
    pub now: SimTime,
    /// The run's seed (what [`PluginDraws::new`] takes).
    pub seed: u64,
    /// A buffer for [`Nearby::within`].
    pub found: &'a mut Vec<Neighbour>,
    /// Occlusion of this vehicle's targets ([`Occlusion::clear`] it per vehicle).
    pub occlusion: &'a mut Occlusion,
    /// Counts to add to ([`PluginSensorStats::of`]), summed into the run's after the tick.
    pub stats: &'a mut PluginSensorStats,
    /// The last sensor name's draws ([`Sensing::draws`]), by the name's address and length.
    last_draws: Cell<Option<((usize, usize), PluginDraws)>>,
}

impl Sensing<'_, '_, '_> {
    /// The noise and dropout draws of sensor `name` at this tick ([`PluginDraws::new`]); the
    /// last name's are kept, so a sensor asking for every vehicle hashes its name once a chunk.
    pub fn draws(&self, name: &str) -> PluginDraws {
        let key = (name.as_ptr() as usize, name.len());
        match self.last_draws.get() {
            Some((k, draws)) if k == key => draws,
            _ => {
                let draws = PluginDraws::new(self.seed, name, self.now);
                self.last_draws.set(Some((key, draws)));
                draws
            }
        }
    }
}

impl PluginSense<'_, '_> {
    /// Call `sense(item, sensing)` for every item of `items` (a sensor's query, `iter_mut()`),
    /// split over the threads: `sense` may write only through its item (the vehicle's own
    /// components) and `sensing`. One vector of the items is gathered per call (per tick, not
    /// per vehicle); each item is taken from it once, by whichever chunk holds it.
    pub fn each<T: Send>(&mut self, items: impl IntoIterator<Item = T>, sense: impl Fn(T, &mut Sensing) + Sync) {
        let mut slots: Vec<Option<T>> = items.into_iter().map(Some).collect();
        // Split as the whole world's sensing is split (the grid holds every vehicle), not by the
        // carriers' count: a camera on a tenth of 10,000 vehicles is 1,000 items, under the
        // threshold of a split, and ran on one thread while the other waited.
        let world = self.nearby.index.vehicles;
        let parallelism = self.parallelism.as_deref().copied().unwrap_or_else(Parallelism::single).for_share_of(world);
        let (nearby, now, seed) = (&self.nearby, self.clock.now, self.seed.as_deref().map_or(0, |s| s.0));
        parallelism.for_each_chunk(&mut slots, &mut self.scratch, |chunk, scratch| {
            let PluginScratch { found, occlusion, stats } = scratch;
            let last_draws = Cell::new(None);
            let mut sensing = Sensing { nearby, now, seed, found, occlusion, stats, last_draws };
            for item in chunk.iter_mut().filter_map(Option::take) {
                sense(item, &mut sensing);
            }
        });
        // In chunk order, reset in place (the names stay: nothing allocated next tick).
        for scratch in self.scratch.iter_mut() {
            for (name, counts) in scratch.stats.0.iter_mut() {
                self.stats.of(name).add(counts);
                *counts = SensorStats::default();
            }
        }
    }
}

/// Make [`NearbyIndex`] once per sensor tick while some vehicle carries a plugin sensor: the
/// carriers' own lists where the built-in sensors' lists hold ([`Nearby::around`]; no O(N) work but
/// after their builds), else a grid of every vehicle (O(N), split over the threads).
pub fn index_nearby(
    mut index: ResMut<NearbyIndex>,
    clock: Res<SimClock>,
    parallelism: Option<Res<Parallelism>>,
    sensors: Option<Res<SensorGrid>>,
    carriers: Query<&VehicleId, With<CarriesPluginSensor>>,
    everyone: EveryoneQuery,
) {
    if carriers.is_empty() {
        return;
    }
    let index = &mut *index;
    index.lazy = OnceLock::new();
    index.built_at = Some(clock.now);
    let reach = index.reach;
    let served = !index.grid_only
        && sensors.is_some_and(|sensors| index.carriers.serve(&sensors, &carriers, &everyone, (reach, clock.now)));
    index.serving = served;
    if served {
        index.carriers.ticks_served += 1;
        index.vehicles = index.carriers.grid.len();
        return;
    }
    let parallelism = parallelism.as_deref().copied().unwrap_or_else(Parallelism::single);
    fill_grid(&mut index.grid, &mut index.footprints, &everyone, parallelism, reach);
    index.vehicles = index.grid.len();
}

/// Counter-based noise and dropout of a plugin sensor at one tick, the built-in sensors' own
/// ([`SensorError`]): every draw a pure function of (seed, the sensor's name, observer,
/// target, tick), so any thread count and any order give the same readings.
#[derive(Debug, Clone, Copy)]
pub struct PluginDraws {
    keys: SensorKeys,
}

impl PluginDraws {
    /// The draws of sensor `name` at tick `now` of a run with `seed`.
    pub fn new(seed: u64, name: &str, now: SimTime) -> PluginDraws {
        PluginDraws { keys: SensorKeys::new(seed, stream_of(name), now.0) }
    }

    /// Apply `err`'s dropout and noise to `detection` as seen by `observer` at `from`: `false`
    /// when it is dropped (then leave it out), else `detection` carries the noise.
    pub fn apply(&self, err: &SensorError, observer: VehicleId, from: DVec2, detection: &mut Detection) -> bool {
        let pair = self.keys.pair(observer, detection.id);
        if err.dropout > 0.0 && !pair.kept(err.dropout) {
            return false;
        }
        if err.is_noisy() {
            let relative = detection.position - from;
            add_noise(detection, from, relative, relative.length_squared(), err, pair.normals());
        }
        true
    }
}

/// A sensor's random stream from its name: FNV-1a of the name's bytes, mixed with the seed by
/// [`key`].
fn stream_of(name: &str) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in name.bytes() {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    mix(key(h, 0x504c_5547, 0))
}

/// Occlusion as the built-in sensors judge it: a target is hidden when its angular extent lies
/// inside one nearer target's. Feed the candidates nearest first; one per observer and tick
/// ([`Occlusion::clear`]), its buffer reused. The extents are kept as the directions of their
/// outermost corners and compared by cross products (no trigonometry but one `sin_cos` per
/// target): the same containment as the built-in sensors' angles for any target that spans
/// less than a right angle, as every vehicle does from outside it.
#[derive(Debug, Clone, Default)]
pub struct Occlusion {
    /// Each nearer target's (clockwise-most, counter-clockwise-most) corner [m], relative to the
    /// observer.
    extents: Vec<(DVec2, DVec2)>,
}

impl Occlusion {
    /// Start a new observer.
    pub fn clear(&mut self) {
        self.extents.clear();
    }

    /// Whether `target` (nearer than every one given after it) is hidden from `from` by one
    /// given before; it then hides those behind it in turn.
    pub fn hidden(&mut self, from: DVec2, target: &Neighbour) -> bool {
        let (inner_right, inner_left) = corner_extent(target.position - from, &target.footprint);
        let inside = |&(right, left): &(DVec2, DVec2)| {
            right.dot(inner_right) > 0.0
                && left.dot(inner_left) > 0.0
                && right.perp_dot(inner_right) >= 0.0
                && inner_left.perp_dot(left) >= 0.0
        };
        let hidden = self.extents.iter().any(inside);
        self.extents.push((inner_right, inner_left));
        hidden
    }
}

/// The clockwise-most and counter-clockwise-most corners of footprint `f` centred at
/// `relative` [m] from the observer.
fn corner_extent(relative: DVec2, f: &Footprint) -> (DVec2, DVec2) {
    let (along, across) = f.axes();
    let corners =
        [relative + along + across, relative + along - across, relative - along + across, relative - along - across];
    let (mut right, mut left) = (corners[0], corners[0]);
    for &c in &corners[1..] {
        if right.perp_dot(c) < 0.0 {
            right = c;
        }
        if left.perp_dot(c) > 0.0 {
            left = c;
        }
    }
    (right, left)
}

/// Detections and misses of each plugin sensor, by name (`summary.json`
/// `metrics.sensors.by_sensor`); a sensor's system adds its counts.
#[derive(Resource, Debug, Clone, Default, PartialEq, Eq)]
pub struct PluginSensorStats(pub BTreeMap<&'static str, SensorStats>);

impl PluginSensorStats {
    /// The counts of sensor `name`, to add to.
    pub fn of(&mut self, name: &'static str) -> &mut SensorStats {
        self.0.entry(name).or_default()
    }
}

impl SensorReadings {
    /// Replace the detections of sensor `name` by `detections` (the other sensors' stay): what a
    /// plugin sensor's system does each tick.
    pub fn set_sensor(&mut self, name: &str, detections: impl IntoIterator<Item = Detection>) {
        self.0.retain(|d| d.sensor != name);
        self.0.extend(detections);
    }

    /// The detections of sensor `name`.
    pub fn of<'a>(&'a self, name: &'a str) -> impl Iterator<Item = &'a Detection> + 'a {
        self.0.iter().filter(move |d| d.sensor == name)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::random::uniform;
    use crate::sim::sensors::errors::{covers, extent};

    #[test]
    fn occlusion_by_corners_is_the_built_in_rule_of_angles() {
        let neighbour = |k: u64, near: bool| {
            let (d, spread) =
                if near { (8.0 + 20.0 * uniform(5, 1, k, 0), 0.3) } else { (30.0 + 40.0 * uniform(5, 1, k, 0), 0.3) };
            let bearing = spread * (uniform(5, 1, k, 1) - 0.5);
            let size = VehicleSize { length: 3.0 + 10.0 * uniform(5, 1, k, 2), width: 1.5 + uniform(5, 1, k, 3) };
            let yaw = std::f64::consts::TAU * uniform(5, 1, k, 4);
            let position = DVec2::from_angle(bearing) * d;
            let footprint = Footprint::new(size, yaw);
            Neighbour { id: VehicleId(k as i32), position, velocity: DVec2::ZERO, distance_squared: d * d, footprint }
        };
        let (mut agree, mut hidden) = (0, 0);
        for k in 0..20_000u64 {
            let (near, far) = (neighbour(2 * k, true), neighbour(2 * k + 1, false));
            let mut occlusion = Occlusion::default();
            occlusion.hidden(DVec2::ZERO, &near);
            let ours = occlusion.hidden(DVec2::ZERO, &far);
            let built_in = covers(extent(near.position, &near.footprint), extent(far.position, &far.footprint));
            assert_eq!(ours, built_in, "pair {k}: {near:?} {far:?}");
            agree += 1;
            hidden += usize::from(ours);
        }
        assert!(hidden > 1000 && hidden < agree - 1000, "{hidden} of {agree} hidden: both outcomes tested");
    }
}

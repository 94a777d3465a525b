//! The simulation's skeleton: [`Plugin`], [`SimBuilder`] and [`Sim`], the seed and the default
//! plugin list. It lives at the bottom of the plugin layers (below `vehicles`, `io` and `app`)
//! so that every plugin, built in or a student's, imports it downward; `app` and the prelude
//! re-export it.
//!
//! # Building and running a simulation
//! ```
//! use smlworld::prelude::*;
//!
//! let mut builder = SimBuilder::new();
//! builder.add_plugin(default_plugins);
//! builder
//!     .spawn_vehicle(VehicleSpec::new(VehicleId(-1), VehicleState::new(DVec2::ZERO, 0.0, 0.0)))
//!     .expect("fresh id");
//! let mut sim = builder.build();
//! let entity = sim.entity(VehicleId(-1)).expect("vehicle -1 was spawned");
//! sim.world_mut().get_mut::<ControlCommand>(entity).expect("every vehicle has a command").speed = 10.0;
//! sim.run_for(2.0);
//! let state = sim.state(VehicleId(-1)).expect("vehicle -1 has a state");
//! assert!((state.position.x - 20.0).abs() < 1e-9);
//! ```

use bevy_ecs::prelude::{Entity, EntityWorldMut, Resource, World};
use bevy_ecs::schedule::{InternedSystemSet, IntoScheduleConfigs, ScheduleLabel};
use bevy_ecs::system::ScheduleSystem;

use super::controllers::{ControllerRegistry, ScenarioController};
use super::schedule::DuplicateModule;
use super::sensor_plugins::{NearbyIndex, PluginSensorStats, PluginSensorSystems, ScenarioSensor, index_nearby};
use super::v2v::channel::ChannelLossModel;
use super::{
    Control, ControlEpoch, Dynamics, DynamicsPlugin, Network, Phase, Rates, Scheduler, Sensors, SensorsPlugin,
    SimClock, SimSystems, V2vPlugin, Wifi, WifiRate,
};
use crate::world::{SimTime, VehicleId, VehicleSpec, VehicleState, Vehicles, WorldError, spawn_vehicle};

/// A feature of the simulation: adds resources, modules and systems to a [`SimBuilder`].
/// A plain `fn(&mut SimBuilder)` is a plugin too.
pub trait Plugin {
    /// Add this plugin's resources, modules and systems.
    fn build(&self, sim: &mut SimBuilder);
}

impl<F: Fn(&mut SimBuilder)> Plugin for F {
    fn build(&self, sim: &mut SimBuilder) {
        self(sim)
    }
}

/// The seed of the run: every random choice of a plugin must derive from it.
#[derive(Resource, Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SimSeed(pub u64);

/// The built-in modules as one plugin: dynamics, sensors and V2V (default wifi range).
pub fn default_plugins(sim: &mut SimBuilder) {
    sim.add_plugin(DynamicsPlugin).add_plugin(SensorsPlugin).add_plugin(V2vPlugin::default());
}

/// Assembles a [`Sim`]: the world, the modules with their rates and the plugins' systems.
pub struct SimBuilder {
    world: World,
    scheduler: Scheduler,
    controllers: ControllerRegistry,
}

impl Default for SimBuilder {
    fn default() -> Self {
        SimBuilder::new()
    }
}

impl SimBuilder {
    /// An empty world with the five standard modules at the default [`Rates`] and no systems.
    pub fn new() -> SimBuilder {
        SimBuilder::with_rates(Rates::default())
    }

    /// An empty world with the five standard modules at `rates` (each > 0 Hz).
    pub fn with_rates(rates: Rates) -> SimBuilder {
        let mut world = World::new();
        world.insert_resource(SimClock::default());
        world.insert_resource(ControlEpoch::default());
        world.insert_resource(Vehicles::default());
        world.insert_resource(SimSeed::default());
        let scheduler = Scheduler::default();
        let mut builder = SimBuilder { world, scheduler, controllers: ControllerRegistry::default() };
        builder
            .add_module("sensors", Sensors, Phase::Sense, rates.sensors)
            .add_module("wifi", Wifi, Phase::Communicate, rates.wifi)
            .add_module("network", Network, Phase::Communicate, rates.network)
            .add_module("control", Control, Phase::Control, rates.control)
            .add_module("dynamics", Dynamics, Phase::Dynamics, rates.dynamics);
        builder
    }

    /// Add a plugin (runs its `build` now).
    pub fn add_plugin(&mut self, plugin: impl Plugin) -> &mut Self {
        plugin.build(self);
        self
    }

    /// Add a module of your own: a new schedule `label` running at `rate` \[Hz\] in `phase`. Its
    /// schedule chains the `SimSystems` sets like the built-in ones.
    ///
    /// # Panics
    /// If a module with `label` already exists (two plugins claiming one module is a programming
    /// error; [`SimBuilder::try_add_module`] returns it instead), or `rate` is not positive and
    /// finite.
    pub fn add_module(&mut self, name: &str, label: impl ScheduleLabel, phase: Phase, rate: f64) -> &mut Self {
        if let Err(e) = self.try_add_module(name, label, phase, rate) {
            panic!("{e}");
        }
        self
    }

    /// [`SimBuilder::add_module`] that returns a duplicate label as an error (nothing is added).
    pub fn try_add_module(
        &mut self,
        name: &str,
        label: impl ScheduleLabel,
        phase: Phase,
        rate: f64,
    ) -> Result<&mut Self, DuplicateModule> {
        self.scheduler.add_module(name, label, phase, rate)?;
        Ok(self)
    }

    /// Configure system sets in the schedule of module `label` (e.g. chain a plugin's own sets
    /// inside `SimSystems::Control`).
    ///
    /// # Panics
    /// If there is no such module.
    pub fn configure_sets<M>(
        &mut self,
        label: impl ScheduleLabel + Clone,
        sets: impl IntoScheduleConfigs<InternedSystemSet, M>,
    ) -> &mut Self {
        match self.scheduler.schedule_mut(label.clone()) {
            Some(schedule) => {
                schedule.configure_sets(sets);
            }
            None => panic!("no module with schedule label {label:?}: add it with SimBuilder::add_module"),
        }
        self
    }

    /// Set the rate of module `label` \[Hz\].
    ///
    /// # Panics
    /// If there is no such module or the rate is not positive and finite.
    pub fn set_rate(&mut self, label: impl ScheduleLabel + Clone, rate: f64) -> &mut Self {
        let known = self.scheduler.set_rate(label.clone(), rate);
        assert!(known, "no module with schedule label {label:?}");
        self
    }

    /// Rate of module `label` \[Hz\].
    pub fn rate(&self, label: impl ScheduleLabel) -> Option<f64> {
        self.scheduler.rate(label)
    }

    /// Add systems to the schedule of module `label` (e.g. [`Control`]).
    ///
    /// # Panics
    /// If there is no such module (add it first with [`SimBuilder::add_module`]).
    pub fn add_systems<M>(
        &mut self,
        label: impl ScheduleLabel + Clone,
        systems: impl IntoScheduleConfigs<ScheduleSystem, M>,
    ) -> &mut Self {
        match self.scheduler.schedule_mut(label.clone()) {
            Some(schedule) => {
                schedule.add_systems(systems);
            }
            None => panic!("no module with schedule label {label:?}: add it with SimBuilder::add_module"),
        }
        self
    }

    /// Insert (or replace) a resource.
    pub fn insert_resource<R: Resource>(&mut self, resource: R) -> &mut Self {
        self.world.insert_resource(resource);
        self
    }

    /// The world being built.
    pub fn world_mut(&mut self) -> &mut World {
        &mut self.world
    }

    /// Spawn a vehicle now (see [`spawn_vehicle`]); returns its entity.
    pub fn spawn_vehicle(&mut self, spec: VehicleSpec) -> Result<Entity, WorldError> {
        spawn_vehicle(&mut self.world, spec)
    }

    /// Spawn a vehicle now and return a handle on which more components (a controller's own)
    /// can be inserted: `sim.spawn(spec)?.insert(MyController::default())`.
    pub fn spawn(&mut self, spec: VehicleSpec) -> Result<EntityWorldMut<'_>, WorldError> {
        let entity = spawn_vehicle(&mut self.world, spec)?;
        Ok(self.world.entity_mut(entity))
    }

    /// Register a controller type under `name` so that scenario files can name it like a
    /// built-in one: `controller = { type = "NAME", ... }`, the other keys deserialised into `C`.
    /// A plugin registers its controller and adds its systems in one `build`.
    ///
    /// # Panics
    /// If `name` is already registered (two controllers cannot share a name).
    pub fn register_controller<C: ScenarioController>(&mut self, name: &str) -> &mut Self {
        if let Err(e) = self.controllers.register::<C>(name) {
            panic!("{e}");
        }
        self
    }

    /// Register a channel model under `name` so that scenario files can name it like a
    /// built-in one: `[v2v.wifi] loss = { model = "NAME", ... }` (or `[v2v.network]`), the other
    /// keys deserialised into `M`.
    ///
    /// # Panics
    /// If `name` is taken already (a built-in model's or one registered twice).
    pub fn register_channel_model<M: ChannelLossModel>(&mut self, name: &str) -> &mut Self {
        if let Err(e) = self.controllers.channel_models_mut().register::<M>(name) {
            panic!("{e}");
        }
        self
    }

    /// Register a sensor under `name` so that scenario files can put it on a vehicle like a
    /// built-in one: `sensors = { NAME = { ... } }`, the keys deserialised into `S` and the
    /// vehicle given a [`Sensor<S>`](super::sensor_plugins::Sensor). The first registration also
    /// adds the [`Nearby`](super::sensor_plugins::Nearby) grid's system and the
    /// [`PluginSensorSystems`] sets (after the built-in sensors); the plugin adds its own
    /// system in [`PluginSensorSystems::Sense`] of [`Sensors`].
    ///
    /// # Panics
    /// If `name` is taken already (a built-in sensor's or one registered twice).
    pub fn register_sensor<S: ScenarioSensor>(&mut self, name: &str) -> &mut Self {
        if let Err(e) = self.controllers.sensors_mut().register::<S>(name) {
            panic!("{e}");
        }
        if !self.world.contains_resource::<PluginSensorStats>() {
            self.world.insert_resource(PluginSensorStats::default());
            self.world.init_resource::<NearbyIndex>();
            self.configure_sets(
                Sensors,
                (PluginSensorSystems::Index, PluginSensorSystems::Sense)
                    .chain()
                    .in_set(SimSystems::Sense)
                    .after(super::sensors::sense_vehicles),
            );
            self.add_systems(Sensors, index_nearby.in_set(PluginSensorSystems::Index));
        }
        self
    }

    /// The controllers registered so far (by plugins), and the channel models
    /// ([`ControllerRegistry::channel_models`]).
    pub fn controllers(&self) -> &ControllerRegistry {
        &self.controllers
    }

    /// Finish: the simulation at t = 0 (with the [`WifiRate`] resource when there is a wifi
    /// module).
    pub fn build(mut self) -> Sim {
        if let Some(rate) = self.scheduler.rate(Wifi) {
            self.world.insert_resource(WifiRate(rate));
        }
        Sim { world: self.world, scheduler: self.scheduler, rate_warnings: 0 }
    }
}

/// A built simulation: the world plus its scheduler. Run it with [`Sim::run_for`] (headless) or
/// a `RealtimeRunner`.
pub struct Sim {
    world: World,
    pub(crate) scheduler: Scheduler,
    pub(crate) rate_warnings: u64,
}

impl Sim {
    /// The world (read it between runs: states, readings, resources).
    pub fn world(&self) -> &World {
        &self.world
    }

    /// The world, mutably (spawn vehicles, set commands, change resources between runs).
    pub fn world_mut(&mut self) -> &mut World {
        &mut self.world
    }

    /// Current sim time.
    pub fn now(&self) -> SimTime {
        self.scheduler.now()
    }

    /// The scheduler (module rates and tick counts).
    pub fn scheduler(&self) -> &Scheduler {
        &self.scheduler
    }

    /// The scheduler, to switch on per-module timing ([`Scheduler::set_timing`]).
    pub fn scheduler_mut(&mut self) -> &mut Scheduler {
        &mut self.scheduler
    }

    /// Run the module due next; returns its due time.
    pub fn step(&mut self) -> Option<SimTime> {
        self.scheduler.run_next(&mut self.world)
    }

    /// Run headless until sim time `end`: every tick due before `end` runs.
    pub fn run_until(&mut self, end: SimTime) {
        self.scheduler.run_until(&mut self.world, end);
    }

    /// Run headless for `seconds` \[s\] of sim time from now.
    pub fn run_for(&mut self, seconds: f64) {
        let end = SimTime(self.now().0 + SimTime::from_secs(seconds).0);
        self.run_until(end);
    }

    /// Spawn a vehicle (see [`spawn_vehicle`]).
    pub fn spawn_vehicle(&mut self, spec: VehicleSpec) -> Result<Entity, WorldError> {
        spawn_vehicle(&mut self.world, spec)
    }

    /// Entity of vehicle `id`.
    pub fn entity(&self, id: VehicleId) -> Option<Entity> {
        self.world.resource::<Vehicles>().get(id)
    }

    /// State of vehicle `id`.
    pub fn state(&self, id: VehicleId) -> Option<VehicleState> {
        self.world.get::<VehicleState>(self.entity(id)?).copied()
    }

    /// All vehicles' states, in id order.
    pub fn states(&self) -> Vec<(VehicleId, VehicleState)> {
        let vehicles = self.world.resource::<Vehicles>();
        vehicles.iter().filter_map(|(id, e)| Some((id, *self.world.get::<VehicleState>(e)?))).collect()
    }

    /// FNV-1a hash of the time and of every vehicle's id and state bits, in id order: equal
    /// hashes mean identical runs (bit for bit).
    pub fn state_hash(&self) -> u64 {
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        let mut eat = |x: u64| {
            for b in x.to_le_bytes() {
                h ^= b as u64;
                h = h.wrapping_mul(0x0000_0100_0000_01b3);
            }
        };
        eat(self.now().0);
        for (id, s) in self.states() {
            eat(id.0 as i64 as u64);
            for v in [s.position.x, s.position.y, s.yaw, s.velocity.x, s.velocity.y] {
                eat(v.to_bits());
            }
        }
        h
    }

    /// Rate warnings logged by real-time runs so far.
    pub fn rate_warnings(&self) -> u64 {
        self.rate_warnings
    }
}

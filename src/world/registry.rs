//! The vehicle registry (id -> entity) and the spawning API.

use std::collections::BTreeMap;
use std::sync::Arc;

use bevy_ecs::prelude::{Entity, Resource, World};

use super::{
    ControlCommand, Mailbox, Omniscient, Radar, Route, SensorErrors, SensorReadings, VehicleClass, VehicleId,
    VehicleModel, VehicleSize, VehicleState, Velodyne,
};
use crate::map::Path;

/// Errors of the world API.
#[derive(Debug, thiserror::Error)]
pub enum WorldError {
    /// A vehicle with this id already exists.
    #[error("vehicle id {0} is already taken: every vehicle needs a unique id")]
    DuplicateId(VehicleId),
    /// No vehicle has this id.
    #[error("no vehicle with id {0}")]
    UnknownId(VehicleId),
}

/// Registry of all vehicles: id -> entity, in id order.
#[derive(Resource, Debug, Clone, Default)]
pub struct Vehicles {
    by_id: BTreeMap<VehicleId, Entity>,
}

impl Vehicles {
    /// The entity of vehicle `id`.
    pub fn get(&self, id: VehicleId) -> Option<Entity> {
        self.by_id.get(&id).copied()
    }

    /// All (id, entity) pairs in id order.
    pub fn iter(&self) -> impl Iterator<Item = (VehicleId, Entity)> + '_ {
        self.by_id.iter().map(|(&id, &e)| (id, e))
    }

    /// Number of vehicles.
    pub fn len(&self) -> usize {
        self.by_id.len()
    }

    /// Whether there are no vehicles.
    pub fn is_empty(&self) -> bool {
        self.by_id.is_empty()
    }
}

/// Which sensors a spawned vehicle carries.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SensorSet {
    /// A radar cone, if any.
    pub radar: Option<Radar>,
    /// A velodyne circle, if any.
    pub velodyne: Option<Velodyne>,
    /// Whether it sees every vehicle.
    pub omniscient: bool,
}

impl SensorSet {
    /// Whether any sensor is on.
    pub fn any(&self) -> bool {
        self.radar.is_some() || self.velodyne.is_some() || self.omniscient
    }
}

/// Everything needed to spawn a vehicle; build with [`VehicleSpec::new`] and set fields.
#[derive(Debug, Clone)]
pub struct VehicleSpec {
    /// Unique id (>= 0 real, < 0 virtual).
    pub id: VehicleId,
    /// Class (car by default).
    pub class: VehicleClass,
    /// Footprint (4.12 m x 1.7 m by default).
    pub size: VehicleSize,
    /// Initial state.
    pub state: VehicleState,
    /// Dynamics model (kinematic unicycle by default; [`VehicleModel::None`] for real vehicles).
    pub model: VehicleModel,
    /// Sensors (none by default); any sensor adds [`SensorReadings`].
    pub sensors: SensorSet,
    /// Noise, dropout and occlusion of its radar and velodyne (perfect by default; adds
    /// [`SensorErrors`] when not perfect).
    pub sensor_errors: SensorErrors,
    /// Whether the vehicle takes part in V2V (adds a [`Mailbox`]; on by default).
    pub mailbox: bool,
    /// Path to drive, if any (adds a [`Route`]).
    pub route: Option<Arc<Path>>,
}

impl VehicleSpec {
    /// A car with id `id` in `state`, kinematic unicycle, no sensors, a mailbox, no route.
    pub fn new(id: VehicleId, state: VehicleState) -> VehicleSpec {
        VehicleSpec {
            id,
            class: VehicleClass::default(),
            size: VehicleSize::default(),
            state,
            model: VehicleModel::default(),
            sensors: SensorSet::default(),
            sensor_errors: SensorErrors::default(),
            mailbox: true,
            route: None,
        }
    }
}

/// Spawn a vehicle and register it; a duplicate id is an error and spawns nothing.
/// Returns the entity, to which callers may add more components (a controller's state).
pub fn spawn_vehicle(world: &mut World, spec: VehicleSpec) -> Result<Entity, WorldError> {
    if world.get_resource::<Vehicles>().is_none() {
        world.insert_resource(Vehicles::default());
    }
    if world.resource::<Vehicles>().by_id.contains_key(&spec.id) {
        return Err(WorldError::DuplicateId(spec.id));
    }
    let mut e = world.spawn((spec.id, spec.state, ControlCommand::default(), spec.size, spec.class));
    match spec.model {
        VehicleModel::None => {}
        VehicleModel::Kinematic(m) => {
            e.insert(m);
        }
        VehicleModel::Acceleration(m) => {
            e.insert(m);
        }
    }
    if let Some(radar) = spec.sensors.radar {
        e.insert(radar);
    }
    if let Some(velodyne) = spec.sensors.velodyne {
        e.insert(velodyne);
    }
    if spec.sensors.omniscient {
        e.insert(Omniscient);
    }
    if spec.sensors.any() {
        e.insert(SensorReadings::default());
    }
    if !spec.sensor_errors.is_perfect() {
        e.insert(spec.sensor_errors);
    }
    if spec.mailbox {
        e.insert(Mailbox::new(spec.id));
    }
    if let Some(path) = spec.route {
        e.insert(Route(path));
    }
    let entity = e.id();
    world.resource_mut::<Vehicles>().by_id.insert(spec.id, entity);
    Ok(entity)
}

/// Despawn vehicle `id` and unregister it.
pub fn despawn_vehicle(world: &mut World, id: VehicleId) -> Result<(), WorldError> {
    let entity =
        world.get_resource_mut::<Vehicles>().and_then(|mut v| v.by_id.remove(&id)).ok_or(WorldError::UnknownId(id))?;
    world.despawn(entity);
    Ok(())
}

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
    /// The same pairs in a hash table for [`Vehicles::get`]: leader, foe and sender lookups ask
    /// it for every vehicle every tick, and a B-tree of 10,000 ids was four or five dependent
    /// cache misses a lookup (issue 53 item 8: the town bench).
    lookup: IdMap<Entity>,
}

/// A hash map keyed by [`VehicleId`] with [`IdHasher`]: a multiplication instead of SipHash
/// (ids are small integers we chose, not attacker input).
pub type IdMap<V> = std::collections::HashMap<VehicleId, V, std::hash::BuildHasherDefault<IdHasher>>;

/// Fibonacci hashing of a vehicle id (Knuth, TAOCP vol. 3, 6.4): one multiplication by 2⁶⁴/φ;
/// the high bits hashbrown reads for its control bytes are well mixed.
#[derive(Debug, Clone, Copy, Default)]
pub struct IdHasher(u64);

impl std::hash::Hasher for IdHasher {
    fn finish(&self) -> u64 {
        self.0
    }

    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0.rotate_left(8) ^ u64::from(b)).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        }
    }

    fn write_i32(&mut self, i: i32) {
        self.0 = (self.0 ^ u64::from(i as u32)).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    }
}

impl Vehicles {
    /// The entity of vehicle `id`.
    pub fn get(&self, id: VehicleId) -> Option<Entity> {
        self.lookup.get(&id).copied()
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
    let mut registry = world.resource_mut::<Vehicles>();
    registry.by_id.insert(spec.id, entity);
    registry.lookup.insert(spec.id, entity);
    Ok(entity)
}

/// Despawn vehicle `id` and unregister it.
pub fn despawn_vehicle(world: &mut World, id: VehicleId) -> Result<(), WorldError> {
    let entity = world
        .get_resource_mut::<Vehicles>()
        .and_then(|mut v| {
            v.lookup.remove(&id);
            v.by_id.remove(&id)
        })
        .ok_or(WorldError::UnknownId(id))?;
    world.despawn(entity);
    Ok(())
}

//! ECS data: vehicle components, resources, the vehicle registry and spawning.
//!
//! A vehicle is an entity carrying a [`VehicleId`], a [`VehicleState`], a [`ControlCommand`],
//! its [`VehicleSize`] and [`VehicleClass`], and optionally a dynamics model
//! ([`KinematicUnicycle`] or [`AccelerationUnicycle`]), sensors ([`Radar`], [`Velodyne`],
//! [`Omniscient`]) with their [`SensorReadings`], a [`Mailbox`] and a [`Route`]. The
//! [`Vehicles`] resource maps ids to entities; [`spawn_vehicle`] is the one way in.

mod mailbox;
mod models;
mod payload;
pub mod random;
mod registry;
mod sensors;
mod time;
mod vehicle;

pub(crate) use mailbox::BatchRef;
pub use mailbox::{Channel, Inbox, InboxIter, Mailbox, Message, Payload};
pub use models::{AccelerationUnicycle, KinematicUnicycle, VehicleModel};
pub use registry::{IdHasher, IdMap, SensorSet, VehicleSpec, Vehicles, WorldError, despawn_vehicle, spawn_vehicle};
pub use sensors::{Detection, Omniscient, Radar, SensorError, SensorErrors, SensorReadings, Velodyne};
pub use time::SimTime;
pub use vehicle::{
    ControlCommand, LabDriven, Route, Stationary, TurnSignal, VehicleClass, VehicleId, VehicleSize, VehicleState,
};

/// Hint to the processor that the memory at `p` will be read soon (no effect off x86-64): the
/// per-vehicle loops ask for what a vehicle a few places on will read (its centre line, its
/// detections), so those loads, far apart in memory on a big world, overlap this vehicle's work.
#[inline]
pub fn prefetch<T>(p: *const T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: a prefetch is only a hint; it never faults, whatever the address.
    unsafe {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        _mm_prefetch::<_MM_HINT_T0>(p.cast::<i8>());
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = p;
}

/// [`prefetch_bytes`] of a value's own bytes (a path's fields behind its `Arc`: the first of
/// two dependent misses of a read of a route that is not shared).
#[inline]
pub fn prefetch_value<T>(value: &T) {
    prefetch_bytes((value as *const T).cast(), std::mem::size_of::<T>());
}

/// [`prefetch_bytes`] of every item of `items` (a route's points near a place).
#[inline]
pub fn prefetch_all<T>(items: &[T]) {
    prefetch_bytes(items.as_ptr().cast(), std::mem::size_of_val(items));
}

/// [`prefetch`] every cache line of the `len` bytes at `p` (a value's leading fields, a
/// buffer's first entries): a line each 64 bytes, and the last byte's, which lies on a line of
/// its own when `p` is not on a line's start.
#[inline]
pub fn prefetch_bytes(p: *const u8, len: usize) {
    for offset in (0..len).step_by(64) {
        prefetch(p.wrapping_add(offset));
    }
    if len > 0 {
        prefetch(p.wrapping_add(len - 1));
    }
}

//! Motion-capture tracker: maps QTM bodies to vehicle ids, scales lab metres to world metres,
//! estimates velocity from successive frames and marks bodies unseen for too long as stale.

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use glam::DVec2;

use super::wire::DataFrame;

/// Which vehicle id each QTM body drives. Bodies are named by QTM's 1-based body number
/// ([`super::Body6DEuler::number`]: body 1 is the first 6DOF body).
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub enum BodyMapping {
    /// Body k is real vehicle k (k >= 1).
    #[default]
    Identity,
    /// Body number -> vehicle id (the scenario's `[lab] bodies`); bodies not listed are ignored.
    Table(BTreeMap<u32, i32>),
}

impl BodyMapping {
    /// The vehicle id of body `number` (1-based), if it is tracked.
    pub fn id_of(&self, number: u32) -> Option<i32> {
        match self {
            Self::Identity => i32::try_from(number).ok().filter(|&n| n >= 1),
            Self::Table(t) => t.get(&number).copied(),
        }
    }

    /// The body number (1-based) that drives vehicle `id`, if any.
    pub fn body_of(&self, id: i32) -> Option<u32> {
        match self {
            Self::Identity => u32::try_from(id).ok().filter(|&n| n >= 1),
            Self::Table(t) => t.iter().find(|(_, v)| **v == id).map(|(b, _)| *b),
        }
    }
}

/// Settings of a [`Tracker`].
#[derive(Debug, Clone, PartialEq)]
pub struct TrackerConfig {
    /// Body -> vehicle id (default: body k is vehicle k).
    pub mapping: BodyMapping,
    /// Lab floor to world factor (default 32, the trucks' scale): world \[m\] = lab \[m\] * scale.
    pub scale: f64,
    /// A body unseen for longer than this is reported stale (default 0.5 s; raising it hides
    /// short occlusions, lowering it reports losses sooner).
    pub stale_after: Duration,
}

impl Default for TrackerConfig {
    fn default() -> Self {
        Self { mapping: BodyMapping::Identity, scale: 32.0, stale_after: Duration::from_millis(500) }
    }
}

/// A real vehicle as motion capture sees it, in world units.
#[derive(Debug, Clone, PartialEq)]
pub struct TrackedBody {
    /// Vehicle id (from the body mapping).
    pub id: i32,
    /// QTM body number (1-based).
    pub body: u32,
    /// World position \[m\] (lab position scaled by the factor).
    pub position: DVec2,
    /// Heading, the third Euler angle \[rad\].
    pub yaw: f64,
    /// World velocity from successive frames [m/s]; zero on the first sighting or after a loss.
    pub velocity: DVec2,
    /// True when the body has not been seen for longer than the timeout; the vehicle keeps its
    /// last state.
    pub stale: bool,
    /// QTM frame number of the last sighting.
    pub frame: i32,
    /// QTM timestamp of the last sighting \[µs\].
    pub timestamp_us: i64,
    /// When the last sighting arrived.
    pub last_seen: Instant,
}

/// Turns frames into tracked vehicles: mapping, scaling, velocity, staleness.
#[derive(Debug, Clone)]
pub struct Tracker {
    config: TrackerConfig,
    bodies: BTreeMap<i32, TrackedBody>,
}

impl Tracker {
    /// An empty tracker.
    pub fn new(config: TrackerConfig) -> Self {
        Self { config, bodies: BTreeMap::new() }
    }

    /// Take one frame received at `received_at`. A sample with the same timestamp as a body's
    /// last one (the same frame polled twice) is ignored; an older timestamp means QTM restarted
    /// its measurement: the sample is taken with zero velocity.
    pub fn update(&mut self, frame: &DataFrame, received_at: Instant) {
        let s = self.config.scale / 1000.0;
        for b in &frame.bodies {
            let Some(id) = self.config.mapping.id_of(b.number()) else { continue };
            let position = DVec2::new(f64::from(b.x_mm) * s, f64::from(b.y_mm) * s);
            let yaw = f64::from(b.yaw_deg).to_radians();
            match self.bodies.get_mut(&id) {
                Some(t) if frame.timestamp_us == t.timestamp_us => {}
                Some(t) => {
                    let dt = (frame.timestamp_us - t.timestamp_us) as f64 * 1e-6;
                    // dt < 0: QTM started a new measurement (timestamps restart): no velocity yet.
                    t.velocity = if t.stale || dt < 0.0 { DVec2::ZERO } else { (position - t.position) / dt };
                    if t.stale {
                        tracing::info!("motion capture: vehicle {id} (body {}) tracked again", b.number());
                    }
                    t.position = position;
                    t.yaw = yaw;
                    t.stale = false;
                    t.frame = frame.frame;
                    t.timestamp_us = frame.timestamp_us;
                    t.last_seen = received_at;
                }
                None => {
                    self.bodies.insert(
                        id,
                        TrackedBody {
                            id,
                            body: b.number(),
                            position,
                            yaw,
                            velocity: DVec2::ZERO,
                            stale: false,
                            frame: frame.frame,
                            timestamp_us: frame.timestamp_us,
                            last_seen: received_at,
                        },
                    );
                }
            }
        }
    }

    /// Mark bodies unseen for longer than the timeout at `now` as stale (logged once per loss).
    /// Returns how many became stale in this call.
    pub fn refresh(&mut self, now: Instant) -> usize {
        let mut n = 0;
        for t in self.bodies.values_mut() {
            if !t.stale && now.saturating_duration_since(t.last_seen) > self.config.stale_after {
                t.stale = true;
                t.velocity = DVec2::ZERO;
                n += 1;
                tracing::warn!(
                    "motion capture: vehicle {} (body {}) lost for more than {:?}; marked stale",
                    t.id,
                    t.body,
                    self.config.stale_after
                );
            }
        }
        n
    }

    /// All vehicles ever tracked, by id (stale ones included).
    pub fn bodies(&self) -> impl Iterator<Item = &TrackedBody> {
        self.bodies.values()
    }

    /// One vehicle by id.
    pub fn get(&self, id: i32) -> Option<&TrackedBody> {
        self.bodies.get(&id)
    }

    /// The tracked vehicles whose last sighting is `frame` (after [`Tracker::update`] took it),
    /// in the frame's body order: each found by its mapped id, so a frame of n bodies costs
    /// O(n log n), not a scan of every body per body (issue 24: 20,000 bodies without a stall).
    pub fn seen_in<'a>(&'a self, frame: &'a DataFrame) -> impl Iterator<Item = &'a TrackedBody> + 'a {
        frame.bodies.iter().filter_map(move |b| {
            let t = self.bodies.get(&self.config.mapping.id_of(b.number())?)?;
            (t.timestamp_us == frame.timestamp_us).then_some(t)
        })
    }
}

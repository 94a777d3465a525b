//! Reassembly of the visualisation stream: drops stale counters and joins the parts of split
//! frames into whole frames.

use std::collections::BTreeMap;

use super::codec::{VizDatagram, VizLight, VizVehicle, decode_datagram, decode_lights, is_lights_datagram};

/// One complete frame, as a receiver delivers it.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct VizFrame {
    /// Frame counter.
    pub counter: u64,
    /// All vehicles of the frame, in the order they were sent.
    pub vehicles: Vec<VizVehicle>,
    /// The latest state of every junction the stream's lights extension has reported, by
    /// junction id (empty for a stream without lights).
    pub lights: Vec<VizLight>,
}

/// Counters of what a receiver saw.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct VizStats {
    /// Datagrams received (good or bad).
    pub datagrams: u64,
    /// Complete frames delivered.
    pub frames: u64,
    /// Datagrams that could not be decoded.
    pub decode_errors: u64,
    /// Datagrams dropped because their counter was not newer than the last frame.
    pub stale: u64,
    /// Split frames abandoned before all their parts arrived.
    pub incomplete: u64,
    /// Times the sender was taken as restarted (its counter went back and stayed back).
    pub restarts: u64,
    /// Vehicles dropped by the caps ([`MAX_VEHICLES_PER_DATAGRAM`], [`MAX_VEHICLES_PER_FRAME`]).
    pub vehicles_dropped: u64,
}

/// Most vehicles taken from one datagram: our sender puts about 150 in its 4 KiB datagrams and
/// the 2015 sender all of a frame's in one (a UDP datagram holds at most ~2,000 records); the
/// rest of a larger one is dropped with a warning.
pub const MAX_VEHICLES_PER_DATAGRAM: usize = 2_000;

/// Most vehicles in one frame (split frames included), so a malformed or hostile stream cannot
/// make the viewer allocate gigabytes (a 4 M-vehicle frame crashed it in a GPU allocation).
pub const MAX_VEHICLES_PER_FRAME: usize = 100_000;

/// Consecutive stale datagrams, each at or after the previous one's counter, after which the
/// sender is taken as restarted (a second `run --stream`, a counter that jumped to u64::MAX):
/// the receiver follows the new counters instead of dropping them forever. Reordering on a
/// network swaps a datagram or two, never ten in order.
pub const RESTART_AFTER: u32 = 10;

#[derive(Debug)]
struct Pending {
    counter: u64,
    parts: Vec<Option<Vec<VizVehicle>>>,
    missing: u32,
}

/// Turns decoded datagrams into frames: drops stale counters, reassembles split frames.
///
/// Rules: a datagram whose counter is not newer than the last delivered frame is stale. A plain
/// datagram is a whole frame. A part starts assembling its frame (abandoning an older unfinished
/// one); parts of the frame being assembled are not stale; the frame is delivered when all
/// its parts are in. Any datagram older than the frame being assembled is stale.
#[derive(Debug, Default)]
pub struct VizReassembler {
    last: Option<u64>,
    pending: Option<Pending>,
    stats: VizStats,
    /// Consecutive stale datagrams in counter order, and the last one's counter.
    stale_run: (u32, u64),
    /// Whether the caps' warning was logged (once per receiver; later drops are counted).
    warned_cap: bool,
    /// Latest state of each junction (the lights extension), by id.
    lights: BTreeMap<u32, String>,
}

/// Most junctions a receiver keeps states of (bounds the memory a hostile sender can claim).
pub const MAX_LIGHTS: usize = 100_000;

impl VizReassembler {
    /// A receiver state that has seen nothing yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Decode raw bytes and feed them in; decode errors are counted and logged at debug level.
    pub fn push_bytes(&mut self, bytes: &[u8]) -> Option<VizFrame> {
        self.stats.datagrams += 1;
        if is_lights_datagram(bytes) {
            match decode_lights(bytes) {
                Ok((_, lights)) => {
                    for l in lights {
                        if self.lights.len() < MAX_LIGHTS || self.lights.contains_key(&l.junction) {
                            self.lights.insert(l.junction, l.state);
                        }
                    }
                }
                Err(e) => {
                    self.stats.decode_errors += 1;
                    tracing::debug!("dropping visualisation lights datagram: {e}");
                }
            }
            return None;
        }
        match decode_datagram(bytes) {
            Ok(d) => self.push_decoded(d),
            Err(e) => {
                self.stats.decode_errors += 1;
                tracing::debug!("dropping visualisation datagram: {e}");
                None
            }
        }
    }

    /// Feed one decoded datagram; returns a frame when one is complete.
    pub fn push(&mut self, datagram: VizDatagram) -> Option<VizFrame> {
        self.stats.datagrams += 1;
        self.push_decoded(datagram)
    }

    fn push_decoded(&mut self, mut d: VizDatagram) -> Option<VizFrame> {
        let older_than_pending = self.pending.as_ref().is_some_and(|p| d.counter < p.counter);
        if older_than_pending || self.last.is_some_and(|l| d.counter <= l) {
            let (run, previous) = self.stale_run;
            self.stale_run = (if run > 0 && d.counter >= previous { run + 1 } else { 1 }, d.counter);
            if self.stale_run.0 < RESTART_AFTER {
                self.stats.stale += 1;
                return None;
            }
            tracing::info!(
                "visualisation stream: the sender's counter went back (now {}, was {}); taking it as restarted",
                d.counter,
                self.last.unwrap_or(0)
            );
            self.stats.restarts += 1;
            self.last = None;
            self.pending = None;
        }
        self.stale_run = (0, 0);
        if d.vehicles.len() > MAX_VEHICLES_PER_DATAGRAM {
            self.drop_vehicles(d.vehicles.len() - MAX_VEHICLES_PER_DATAGRAM, "datagram", MAX_VEHICLES_PER_DATAGRAM);
            d.vehicles.truncate(MAX_VEHICLES_PER_DATAGRAM);
        }
        let Some(part) = d.part else {
            if self.pending.take().is_some() {
                self.stats.incomplete += 1;
            }
            return Some(self.deliver(d.counter, d.vehicles));
        };
        match &self.pending {
            Some(p) if p.counter == d.counter && p.parts.len() == part.count as usize => {}
            other => {
                if other.is_some() {
                    self.stats.incomplete += 1;
                }
                self.pending =
                    Some(Pending { counter: d.counter, parts: vec![None; part.count as usize], missing: part.count });
            }
        }
        let pending = self.pending.as_mut()?;
        if pending.parts[part.index as usize].is_some() {
            self.stats.stale += 1;
            return None;
        }
        let so_far: usize = pending.parts.iter().flatten().map(Vec::len).sum();
        let room = MAX_VEHICLES_PER_FRAME.saturating_sub(so_far);
        let mut vehicles = d.vehicles;
        let excess = vehicles.len().saturating_sub(room);
        vehicles.truncate(room);
        pending.parts[part.index as usize] = Some(vehicles);
        pending.missing -= 1;
        if excess > 0 {
            self.drop_vehicles(excess, "frame", MAX_VEHICLES_PER_FRAME);
        }
        let pending = self.pending.as_mut()?;
        if pending.missing > 0 {
            return None;
        }
        let done = self.pending.take()?;
        let vehicles = done.parts.into_iter().flatten().flatten().collect();
        Some(self.deliver(done.counter, vehicles))
    }

    /// Count vehicles dropped by a cap; warn the first time.
    fn drop_vehicles(&mut self, n: usize, what: &str, cap: usize) {
        self.stats.vehicles_dropped += n as u64;
        if !self.warned_cap {
            self.warned_cap = true;
            tracing::warn!(
                "visualisation stream: a {what} holds more than {cap} vehicles; {n} dropped (later drops are only counted)"
            );
        }
    }

    fn deliver(&mut self, counter: u64, vehicles: Vec<VizVehicle>) -> VizFrame {
        self.last = Some(counter);
        self.stats.frames += 1;
        let lights = self.lights.iter().map(|(&junction, state)| VizLight { junction, state: state.clone() }).collect();
        VizFrame { counter, vehicles, lights }
    }

    /// What was seen so far.
    pub fn stats(&self) -> VizStats {
        self.stats
    }
}

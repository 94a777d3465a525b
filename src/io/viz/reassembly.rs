//! Reassembly of the visualisation stream: drops stale counters and joins the parts of split
//! frames into whole frames.

use super::codec::{VizDatagram, VizVehicle, decode_datagram};

/// One complete frame, as a receiver delivers it.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct VizFrame {
    /// Frame counter.
    pub counter: u64,
    /// All vehicles of the frame, in the order they were sent.
    pub vehicles: Vec<VizVehicle>,
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
}

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
}

impl VizReassembler {
    /// A receiver state that has seen nothing yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Decode raw bytes and feed them in; decode errors are counted and logged at debug level.
    pub fn push_bytes(&mut self, bytes: &[u8]) -> Option<VizFrame> {
        self.stats.datagrams += 1;
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

    fn push_decoded(&mut self, d: VizDatagram) -> Option<VizFrame> {
        let older_than_pending = self.pending.as_ref().is_some_and(|p| d.counter < p.counter);
        if older_than_pending || self.last.is_some_and(|l| d.counter <= l) {
            self.stats.stale += 1;
            return None;
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
        let slot = &mut pending.parts[part.index as usize];
        if slot.is_some() {
            self.stats.stale += 1;
            return None;
        }
        *slot = Some(d.vehicles);
        pending.missing -= 1;
        if pending.missing > 0 {
            return None;
        }
        let done = self.pending.take()?;
        let vehicles = done.parts.into_iter().flatten().flatten().collect();
        Some(self.deliver(done.counter, vehicles))
    }

    fn deliver(&mut self, counter: u64, vehicles: Vec<VizVehicle>) -> VizFrame {
        self.last = Some(counter);
        self.stats.frames += 1;
        VizFrame { counter, vehicles }
    }

    /// What was seen so far.
    pub fn stats(&self) -> VizStats {
        self.stats
    }
}

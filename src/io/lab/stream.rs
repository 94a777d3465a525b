//! [`VizStreamPlugin`]: the world's vehicles over UDP in the 2015 visualisation format.

use std::net::SocketAddr;
use std::sync::Mutex;
use std::time::Duration;

use bevy_ecs::prelude::{Query, ResMut, Resource, Without};
use bevy_ecs::schedule::ScheduleLabel;

use crate::io::viz::{
    DEFAULT_VIZ_ADDR, DEFAULT_VIZ_RATE_HZ, StreamFormat, VizError, VizLight, VizSender, VizSenderConfig, VizVehicle,
};
use crate::io::{WarnLimiter, lock};
use crate::sim::Phase;
use crate::sim::{Plugin, SimBuilder};
use crate::world::{Stationary, TurnSignal, VehicleClass, VehicleId, VehicleSize, VehicleState};

/// Schedule of the visualisation stream ([`Phase::Sense`]: it sends the state at its tick time).
#[derive(ScheduleLabel, Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Stream;

/// The sender of the stream and its reusable frame buffer.
#[derive(Resource, Debug)]
pub struct VizStream {
    sender: VizSender,
    frame: Vec<VizVehicle>,
    warn: WarnLimiter,
    /// Class names and reference point of the datagrams.
    pub format: StreamFormat,
    /// What every signalised junction shows, sent before each frame in our format (the lights
    /// extension, see [`crate::io::viz`]); whoever owns the lights fills it before
    /// [`stream_vehicles`] runs (empty: no lights datagram).
    pub lights: Vec<VizLight>,
    /// Frames sent so far.
    pub frames_sent: u64,
    /// Frames that could not be sent (nobody listening is not an error on UDP, but a full
    /// buffer or an unreachable address is); logged, never fatal.
    pub send_errors: u64,
}

impl VizStream {
    /// A stream to `target` (bound on loopback for a loopback target).
    pub fn new(target: SocketAddr) -> Result<VizStream, VizError> {
        let sender = VizSender::new(&VizSenderConfig { target, ..Default::default() })?;
        Ok(VizStream {
            sender,
            frame: Vec::new(),
            warn: WarnLimiter::new(Duration::from_secs(5)),
            format: StreamFormat::default(),
            lights: Vec::new(),
            frames_sent: 0,
            send_errors: 0,
        })
    }
}

/// What [`stream_vehicles`] reads of a vehicle.
type StreamedVehicle = (
    &'static VehicleId,
    &'static VehicleState,
    &'static VehicleClass,
    Option<&'static VehicleSize>,
    Option<&'static TurnSignal>,
);

/// Each [`Stream`] tick: send every vehicle but [`Stationary`] obstacles (a viewer draws their
/// outlines from the map), with its [`TurnSignal`] in our format (id order is not needed by receivers; entity order)
/// in the stream's [`StreamFormat`]. The frame buffer and its class-name strings are reused, so
/// steady state does not allocate.
pub fn stream_vehicles(mut stream: ResMut<VizStream>, vehicles: Query<StreamedVehicle, Without<Stationary>>) {
    let stream = &mut *stream;
    let format = stream.format;
    let mut n = 0;
    for (id, s, class, size, signal) in &vehicles {
        if n == stream.frame.len() {
            stream.frame.push(VizVehicle {
                id: 0,
                x: 0.0,
                y: 0.0,
                yaw_deg: 0.0,
                class_name: String::new(),
                indicator: TurnSignal::Off,
            });
        }
        let v = &mut stream.frame[n];
        v.id = id.0;
        let length = size.copied().unwrap_or_default().length;
        let p = format.point_from_centre(s.position, s.yaw, length);
        v.x = p.x;
        v.y = p.y;
        v.yaw_deg = s.yaw.to_degrees();
        let name = format.class_name(id.0, *class);
        if v.class_name != name {
            v.class_name.clear();
            v.class_name.push_str(name);
        }
        // The 2015 viewers know no indicator: only our format carries it.
        v.indicator = match format {
            StreamFormat::Y2015 => TurnSignal::Off,
            StreamFormat::Smlworld => signal.copied().unwrap_or_default(),
        };
        n += 1;
    }
    stream.frame.truncate(n);
    // The 2015 viewers know no lights: only our format carries them.
    if format == StreamFormat::Smlworld
        && !stream.lights.is_empty()
        && let Err(e) = stream.sender.send_lights(&stream.lights)
    {
        stream.send_errors += 1;
        stream.warn.warn(&format!("visualisation stream (lights): {e}"));
    }
    match stream.sender.send(&stream.frame) {
        Ok(_) => stream.frames_sent += 1,
        Err(e) => {
            stream.send_errors += 1;
            stream.warn.warn(&format!("visualisation stream: {e}"));
        }
    }
}

/// Streams the world's vehicles over UDP to `target` at `rate` \[Hz\] of sim time (a module of
/// its own; in a real-time run, of wall time too).
#[derive(Debug)]
pub struct VizStreamPlugin {
    stream: Mutex<Option<VizStream>>,
    rate: f64,
}

impl VizStreamPlugin {
    /// Bind the sending socket now (so a bad address is an error here, not in the run).
    ///
    /// `rate` \[Hz\] must be positive and at most 1e6.
    pub fn new(target: SocketAddr, rate: f64) -> Result<VizStreamPlugin, VizError> {
        if !(rate.is_finite() && rate > 0.0 && rate <= 1e6) {
            return Err(VizError::BadRate(rate));
        }
        Ok(VizStreamPlugin { stream: Mutex::new(Some(VizStream::new(target)?)), rate })
    }

    /// Send in `format` (default: ours).
    pub fn with_format(self, format: StreamFormat) -> VizStreamPlugin {
        if let Some(stream) = lock(&self.stream).as_mut() {
            stream.format = format;
        }
        self
    }

    /// The 2015 defaults: 127.0.0.1:38008 at 50 Hz.
    pub fn with_defaults() -> Result<VizStreamPlugin, VizError> {
        VizStreamPlugin::new(DEFAULT_VIZ_ADDR, DEFAULT_VIZ_RATE_HZ)
    }
}

impl Plugin for VizStreamPlugin {
    fn build(&self, sim: &mut SimBuilder) {
        let Some(stream) = lock(&self.stream).take() else { return };
        sim.insert_resource(stream);
        sim.add_module("stream", Stream, Phase::Sense, self.rate);
        sim.add_systems(Stream, stream_vehicles);
    }
}

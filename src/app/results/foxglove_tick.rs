//! The recorder on the simulation's side (issue 57): the log-tick system that fills a
//! [`Snapshot`](super::snapshot::Snapshot) from the world and gathers the events since the last tick, the plugin that
//! schedules it after the trajectory log's rows, and the bird's-eye images of
//! `/camera/birdseye`. The [`FoxgloveRecorder`] resource hands each tick to its own thread.

use std::path::{Path as FsPath, PathBuf};
use std::sync::Arc;

use bevy_ecs::prelude::{Query, Res, ResMut, Resource, World};
use bevy_ecs::schedule::{IntoScheduleConfigs, ScheduleLabel};

use super::foxglove::FoxgloveRecorder;
use super::snapshot::{Event, VehicleSnapshot};
use crate::map::LaneletMap;
use crate::sim::{Phase, Plugin, Sim, SimBuilder, SimClock};
use crate::vehicles::{LaneChanger, LanePosition, Longitudinal, TrafficLights};
use crate::world::{LabDriven, TurnSignal, VehicleClass, VehicleSize, VehicleState, Vehicles};

/// Schedule of the recorder when it runs apart from the trajectory log (a replay, a test).
#[derive(ScheduleLabel, Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Record;

/// Schedule of `/camera/birdseye` (`--mcap-images HZ`).
#[derive(ScheduleLabel, Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct BirdseyeImages;

/// The recorder on the trajectory log's ticks ([`super::output::Log`], after the CSV rows):
/// insert a [`FoxgloveRecorder`] resource first. With `images` \[Hz\], a module of its own draws
/// the bird's-eye view into `/camera/birdseye`.
pub struct FoxgloveRecordPlugin {
    /// `--mcap-images` \[Hz\].
    pub images: Option<f64>,
    /// The map the images draw.
    pub map: Option<Arc<LaneletMap>>,
}

impl Plugin for FoxgloveRecordPlugin {
    fn build(&self, sim: &mut SimBuilder) {
        sim.add_systems(super::output::Log, record_tick.after(super::output::log_trajectories));
        if let (Some(hz), Some(map)) = (self.images, self.map.as_ref()) {
            let options = crate::render::FrameOutput::default();
            match crate::render::FrameRecorder::new(map, &options) {
                Ok(rec) => {
                    sim.insert_resource(BirdseyeCamera(rec));
                    sim.add_module("mcap_images", BirdseyeImages, Phase::Sense, hz);
                    sim.add_systems(BirdseyeImages, record_birdseye);
                }
                Err(e) => tracing::warn!("--mcap-images: no bird's-eye view ({e}); recording without /camera/birdseye"),
            }
        }
    }
}

/// The off-screen renderer of `/camera/birdseye`.
#[derive(Resource)]
struct BirdseyeCamera(crate::render::FrameRecorder);

/// Draw the bird's-eye view into `/camera/birdseye` (PNG).
fn record_birdseye(world: &mut World) {
    let wants = world.get_resource::<FoxgloveRecorder>().is_some_and(|r| r.wants_images());
    if !wants {
        return;
    }
    let t_us = world.get_resource::<SimClock>().map_or(0, |c| c.now.0);
    let image =
        world.resource_scope(|world, mut camera: bevy_ecs::prelude::Mut<BirdseyeCamera>| camera.0.render(world));
    match image.map_err(|e| e.to_string()).and_then(|img| png_bytes(&img)) {
        Ok(png) => {
            if let Some(mut rec) = world.get_resource_mut::<FoxgloveRecorder>() {
                rec.record_image(png, t_us);
            }
        }
        Err(e) => tracing::warn!("--mcap-images at t = {} s: {e}", t_us as f64 * 1e-6),
    }
}

/// `image` as PNG bytes (fast compression: a frame per tick).
fn png_bytes(image: &image::RgbaImage) -> Result<Vec<u8>, String> {
    use image::ImageEncoder;
    let mut out = Vec::new();
    image::codecs::png::PngEncoder::new_with_quality(
        &mut out,
        image::codecs::png::CompressionType::Fast,
        image::codecs::png::FilterType::Adaptive,
    )
    .write_image(image.as_raw(), image.width(), image.height(), image::ExtendedColorType::Rgba8)
    .map_err(|e| e.to_string())?;
    Ok(out)
}

/// What drives a vehicle now, for `/vehicle/<id>/state`.
fn mode(lab: bool, lon: Option<&Longitudinal>, yielding: bool, changing: bool) -> &'static str {
    match lon {
        _ if lab => "lab",
        Some(l) if l.emergency => "emergency_braking",
        _ if yielding => "yielding",
        _ if changing => "lane_change",
        Some(l) if l.leader.is_some() => "following",
        Some(_) => "cruise",
        None => "none",
    }
}

/// Log-tick system: fill the snapshot from the world, gather the events since the last tick
/// (collisions, lane changes and merges, emergency braking, making way for an emergency
/// vehicle, light changes, vehicles that appear or leave) and record them. O(N) in the vehicles.
#[allow(clippy::type_complexity)]
pub fn record_tick(
    clock: Res<SimClock>,
    vehicles: Res<Vehicles>,
    q: Query<(
        &VehicleState,
        Option<&VehicleSize>,
        Option<&VehicleClass>,
        Option<&LabDriven>,
        Option<&LanePosition>,
        Option<&Longitudinal>,
        Option<&LaneChanger>,
        Option<&crate::vehicles::YieldToEmergency>,
    )>,
    metrics: Option<Res<crate::app::running::metrics::Metrics>>,
    lights: Option<Res<TrafficLights>>,
    (v2v, v2v_channels): (Option<Res<crate::sim::v2v::V2vStats>>, Option<Res<crate::sim::v2v::V2vChannelStats>>),
    recorder: Option<ResMut<FoxgloveRecorder>>,
) {
    let Some(mut rec) = recorder else { return };
    let t_us = clock.now.0;
    if rec.last_t == Some(t_us) {
        return;
    }
    let rec = &mut *rec;
    let mut snapshot = rec.take_snapshot();
    let mut events = Vec::new();
    snapshot.t_us = t_us;
    snapshot.vehicles.clear();
    events.clear();
    let mut merges: Vec<(i32, String, &'static str)> = Vec::new();
    for (id, e) in vehicles.iter() {
        let Ok((s, size, class, lab, lane, lon, changer, yields)) = q.get(e) else { continue };
        let yielding = yields.is_some_and(|y| y.requested || y.slow_to.is_some());
        let size = size.copied().unwrap_or_default();
        let manoeuvre = changer.and_then(|c| c.active.as_ref());
        let signal = changer.map_or(TurnSignal::Off, |c| c.signal());
        if let Some(m) = manoeuvre
            && signal != TurnSignal::Off
        {
            let kind = match m.kind {
                crate::vehicles::lane_state::ChangeKind::Mandatory => "merge",
                _ => "lane_change",
            };
            merges.push((
                id.0,
                format!(
                    "lanelet {} -> {} ({:?}{})",
                    m.from.0,
                    m.to.0,
                    m.kind,
                    if m.aborted { ", aborted" } else { "" }
                ),
                kind,
            ));
        }
        snapshot.vehicles.push(VehicleSnapshot {
            id: id.0,
            position: s.position,
            yaw: s.yaw,
            velocity: s.velocity,
            accel: lon.map_or(f64::NAN, |l| l.accel),
            lanelet: lane.and_then(|l| l.lanelet).map(|l| l.0),
            lane_offset: lane.filter(|l| l.lanelet.is_some()).map(|l| l.offset),
            length: size.length,
            width: size.width,
            class: class.copied().unwrap_or_default(),
            real: lab.is_some(),
            signal,
            mode: mode(lab.is_some(), lon, yielding, manoeuvre.is_some()),
        });
    }
    // Changes against the last tick (both lists in id order).
    let mut j = 0;
    for v in &snapshot.vehicles {
        while j < rec.previous.len() && rec.previous[j].0 < v.id {
            let id = rec.previous[j].0;
            events.push(Event::info(t_us, "vehicle", format!("vehicle {id} left")));
            j += 1;
        }
        let before = rec.previous.get(j).filter(|p| p.0 == v.id).copied();
        if before.is_some() {
            j += 1;
        } else if rec.ticks > 0 {
            events.push(Event::info(t_us, "vehicle", format!("vehicle {} appeared", v.id)));
        }
        let (was_signal, was_mode) = before.map_or((TurnSignal::Off, ""), |b| (b.1, b.2));
        if was_signal == TurnSignal::Off
            && v.signal != TurnSignal::Off
            && let Some((_, text, kind)) = merges.iter().find(|m| m.0 == v.id)
        {
            let side = if v.signal == TurnSignal::Left { "left" } else { "right" };
            events.push(Event::info(t_us, kind, format!("vehicle {} changes lanes {side}: {text}", v.id)));
        }
        if v.mode == "yielding" && was_mode != "yielding" {
            events.push(Event::info(t_us, "emergency", format!("vehicle {} makes way for an emergency vehicle", v.id)));
        }
        if v.mode == "emergency_braking" && was_mode != "emergency_braking" {
            events.push(Event::warning(t_us, "emergency", format!("vehicle {} brakes hard (emergency braking)", v.id)));
        }
    }
    for p in &rec.previous[j..] {
        events.push(Event::info(t_us, "vehicle", format!("vehicle {} left", p.0)));
    }
    if let Some(m) = &metrics {
        for c in m.collisions.iter().skip(rec.collisions_seen) {
            events.push(Event::warning(
                crate::world::SimTime::from_secs(c.t).0.min(t_us),
                "collision",
                format!("collision: vehicles {} and {}", c.a.0, c.b.0),
            ));
        }
        rec.collisions_seen = m.collisions.len();
    }
    if let Some(lights) = &lights
        && rec.lights_seen != Some(lights.changes)
    {
        rec.lights_seen = Some(lights.changes);
        rec.light_states.resize(lights.controllers.len(), String::new());
        for (i, c) in lights.controllers.iter().enumerate() {
            let now = lights.state_of(c.junction).unwrap_or_default();
            if rec.light_states[i] != now {
                events.push(Event::info(t_us, "light", format!("junction {}: {now}", c.junction + 1)));
                rec.light_states[i] = now;
            }
        }
    }
    if let (Some(stats), Some(ch)) = (&v2v, &v2v_channels) {
        rec.record_v2v(
            t_us,
            (stats.wifi_rounds, stats.network_rounds),
            (ch.wifi.sent, ch.wifi.delivered),
            (ch.network.sent, ch.network.delivered),
        );
    }
    rec.record(snapshot, events);
}

/// Record the state at the end of a run (unless the log's own tick already did), as
/// [`super::output::log_final_state`] does for the CSV.
pub fn record_final_state(sim: &mut Sim) {
    use bevy_ecs::system::RunSystemOnce;
    if sim.world().get_resource::<FoxgloveRecorder>().is_some() {
        let _ = sim.world_mut().run_system_once(record_tick);
    }
}

/// Where `[output] mcap` or `--mcap` puts the file: the CLI's path as given, the scenario's
/// relative to the output folder.
pub fn mcap_path(cli: Option<&FsPath>, scenario: Option<&FsPath>, out: &FsPath) -> Option<PathBuf> {
    match (cli, scenario) {
        (Some(p), _) => Some(p.to_path_buf()),
        (None, Some(p)) if p.is_absolute() => Some(p.to_path_buf()),
        (None, Some(p)) => Some(out.join(p)),
        (None, None) => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cli_path_wins_and_the_scenario_path_is_under_the_output_folder() {
        let out = FsPath::new("out/x");
        assert_eq!(mcap_path(None, Some(FsPath::new("a.mcap")), out), Some(PathBuf::from("out/x/a.mcap")));
        assert_eq!(mcap_path(Some(FsPath::new("b.mcap")), Some(FsPath::new("a.mcap")), out), Some("b.mcap".into()));
        assert_eq!(super::super::mcap_file::partial_path(FsPath::new("d/r.mcap")), PathBuf::from("d/.r.mcap.partial"));
    }
}

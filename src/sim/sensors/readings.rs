//! Writing detections into [`SensorReadings`], perfect or through the [`SensorErrors`], and
//! the counts of detections and misses ([`SensorStats`]).

use bevy_ecs::prelude::Resource;
use glam::DVec2;

use super::errors::{Draws, Footprint, SensorKeys, add_noise, covers, extent};
use super::keys::{RADAR, RADAR_REACH, REACH, Targets, VELODYNE, VELODYNE_REACH, reached_by, sort_nearest_first};
use super::sight::Sight;
use crate::world::{Detection, SensorError, SensorErrors, SensorReadings};

/// Detections and misses of all sensors since the start, summed over observers and ticks
/// (`summary.json` `metrics.sensors`).
#[derive(Resource, Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct SensorStats {
    /// Detections written into readings.
    pub detections: u64,
    /// Targets within a sensor's reach, not hidden, missed because every sensor that saw them
    /// dropped them.
    pub missed_by_dropout: u64,
    /// Targets within a sensor's reach hidden behind a nearer target from every sensor that
    /// reached them.
    pub missed_by_occlusion: u64,
}

impl SensorStats {
    pub(super) fn add(&mut self, other: &SensorStats) {
        self.detections += other.detections;
        self.missed_by_dropout += other.missed_by_dropout;
        self.missed_by_occlusion += other.missed_by_occlusion;
    }
}
/// Sort `found` nearest first from `from` (ties by id) and write it into `readings`.
pub(super) fn write_readings(found: &mut [u64], grid: &impl Targets, from: DVec2, readings: &mut SensorReadings) {
    sort_nearest_first(found, grid, from);
    readings.0.clear();
    readings.0.extend(found.iter().map(|&key| {
        let e = grid.target(key as u32 & !REACH);
        Detection { id: e.id, position: e.position, velocity: e.velocity, sensor: reached_by(key as u32) }
    }));
}

/// Sort `found` nearest first and write what the imperfect sensors of `sight` see of it into
/// `readings`: occlusion, then dropout, then noise (the radar's when the radar sees the target,
/// else the velodyne's; an omniscient sensor is perfect), counting into `s.stats`.
#[allow(clippy::too_many_arguments)]
pub(super) fn write_imperfect_readings(
    sight: &Sight,
    errors: &SensorErrors,
    draws: Draws,
    footprints: &[Footprint],
    grid: &impl Targets,
    found: &mut [u64],
    extents: &mut Vec<(f64, f64, f64)>,
    stats: &mut SensorStats,
    readings: &mut SensorReadings,
) {
    sort_nearest_first(found, grid, sight.position);
    readings.0.clear();
    extents.clear();
    let occlusion = errors.radar.occlusion || errors.velodyne.occlusion;
    for &key in found.iter() {
        let low = key as u32;
        let e = grid.target(low & !REACH);
        let relative = e.position - sight.position;
        let d2 = relative.length_squared();
        let mut hidden = false;
        if occlusion {
            let ext = extent(relative, &footprints[e.index as usize]);
            hidden = extents.iter().any(|&nearer| covers(nearer, ext));
            extents.push(ext);
        }
        // Each sensor's draws of this pair: word 0 for dropout, the others for noise.
        let sees = |reach: bool, err: &SensorError, keys: &SensorKeys| -> (bool, bool) {
            let visible = reach && !(hidden && err.occlusion);
            let kept = visible && (err.dropout <= 0.0 || keys.pair(sight.id, e.id).kept(err.dropout));
            (visible, kept)
        };
        let (radar_visible, radar_kept) = sees(low & RADAR_REACH != 0, &errors.radar, &draws.radar);
        let (velodyne_visible, velodyne_kept) = sees(low & VELODYNE_REACH != 0, &errors.velodyne, &draws.velodyne);
        let noise = if sight.omniscient() {
            None
        } else if radar_kept {
            Some((&errors.radar, &draws.radar))
        } else if velodyne_kept {
            Some((&errors.velodyne, &draws.velodyne))
        } else {
            if radar_visible || velodyne_visible {
                stats.missed_by_dropout += 1;
            } else {
                stats.missed_by_occlusion += 1;
            }
            continue;
        };
        let sensor = match (radar_kept, velodyne_kept) {
            (true, _) => RADAR,
            (false, true) => VELODYNE,
            _ => reached_by(low),
        };
        let mut detection = Detection { id: e.id, position: e.position, velocity: e.velocity, sensor };
        if let Some((err, keys)) = noise.filter(|(err, _)| err.is_noisy()) {
            add_noise(&mut detection, sight.position, relative, d2, err, keys.pair(sight.id, e.id).normals());
        }
        readings.0.push(detection);
        stats.detections += 1;
    }
}
/// Whether [`write_radar_error_readings`] gives what [`write_imperfect_readings`] gives: no
/// occlusion, and a perfect velodyne (errors on the radar only, the common case).
pub(super) fn radar_errors_only(errors: &SensorErrors) -> bool {
    let v = &errors.velodyne;
    !errors.radar.occlusion && !v.occlusion && v.dropout <= 0.0 && !v.is_noisy()
}

/// [`write_imperfect_readings`] when only the radar has errors ([`radar_errors_only`]): the
/// same readings and counts, the same draws, in one straight loop (no occlusion extents, no
/// per-sensor choice of draws to carry).
#[allow(clippy::too_many_arguments)]
pub(super) fn write_radar_error_readings(
    sight: &Sight,
    err: &SensorError,
    draws: Draws,
    grid: &impl Targets,
    found: &mut [u64],
    stats: &mut SensorStats,
    readings: &mut SensorReadings,
) {
    sort_nearest_first(found, grid, sight.position);
    readings.0.clear();
    readings.0.reserve(found.len());
    let (dropout, noisy) = (err.dropout > 0.0, err.is_noisy());
    for &key in found.iter() {
        let low = key as u32;
        let e = grid.target(low & !REACH);
        let mut detection = Detection { id: e.id, position: e.position, velocity: e.velocity, sensor: reached_by(low) };
        if !sight.omniscient() && low & RADAR_REACH != 0 && (dropout || noisy) {
            let pair = draws.radar.pair(sight.id, e.id);
            if !dropout || pair.kept(err.dropout) {
                if noisy {
                    let relative = e.position - sight.position;
                    let d2 = relative.length_squared();
                    add_noise(&mut detection, sight.position, relative, d2, err, pair.normals());
                }
            } else if low & VELODYNE_REACH == 0 {
                stats.missed_by_dropout += 1;
                continue;
            } else {
                detection.sensor = VELODYNE;
            }
        }
        readings.0.push(detection);
        stats.detections += 1;
    }
}

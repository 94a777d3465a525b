//! Run outputs written while a run goes: the trajectory log (`trajectories.csv`, its own module at
//! the log rate). The run's `summary.json` is [`crate::app::running::summary::RunSummary`].

use std::io::Write;

use bevy_ecs::prelude::{Entity, Local, Query, Res, ResMut, Resource};
use bevy_ecs::schedule::{IntoScheduleConfigs, ScheduleLabel};

use crate::sim::{Parallelism, Phase, Plugin, Sim, SimBuilder, SimClock};
use crate::vehicles::LanePosition;
use crate::world::{VehicleId, VehicleState, Vehicles};

/// Schedule of the trajectory logger ([`Phase::Sense`]: it sees the state at its tick time).
#[derive(ScheduleLabel, Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Log;

/// Where trajectory rows go: `t,id,x,y,yaw,vx,vy,lanelet,lane_offset` [s, -, m, m, rad, m/s,
/// m/s, -, m], vehicles in id order, each number with the precision of its unit ([`Fixed`]: `t`
/// to the clock's 1 µs, then 1 mm, 1e-5 rad, 1 mm/s; trailing zeros dropped: `0.1`, `12`); `lanelet` is the id of the lanelet
/// under the reference point and `lane_offset` the signed offset from its centre line (left
/// positive), both empty off-road or without a map.
#[derive(Resource)]
pub struct TrajectoryLog {
    writer: Box<dyn Write + Send + Sync>,
    rows: u64,
    error: Option<std::io::Error>,
    /// Sim time of the last rows written [s], so the final state is logged exactly once.
    last_t: Option<f64>,
}

impl TrajectoryLog {
    /// Log into `writer` (the header is written at once).
    pub fn new(mut writer: Box<dyn Write + Send + Sync>) -> TrajectoryLog {
        let error = writeln!(writer, "t,id,x,y,yaw,vx,vy,lanelet,lane_offset").err();
        TrajectoryLog { writer, rows: 0, error, last_t: None }
    }

    /// Rows written so far.
    pub fn rows(&self) -> u64 {
        self.rows
    }

    /// Flush the writer; returns the first write error of the run, if any.
    pub fn finish(&mut self) -> std::io::Result<()> {
        if let Some(e) = self.error.take() {
            return Err(e);
        }
        self.writer.flush()
    }
}

/// Decimals of lengths \[m\] and speeds [m/s] in `trajectories.csv`: 1 mm and 1 mm/s.
pub const LENGTH_DECIMALS: usize = 3;
/// Decimals of angles \[rad\] in `trajectories.csv`: 1e-5 rad (0.6 mdeg, 1 mm at 100 m).
pub const ANGLE_DECIMALS: usize = 5;

/// A number written with at most `.1` decimals, trailing zeros dropped (`12.5`, `0`, `-3.142`),
/// never `-0`: a CSV carries the precision of its unit, not 17 digits of float noise.
pub struct Fixed(pub f64, pub usize);

impl std::fmt::Display for Fixed {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut text = Vec::with_capacity(32);
        self.push_to(&mut text);
        f.write_str(std::str::from_utf8(&text).map_err(|_| std::fmt::Error)?)
    }
}

impl Fixed {
    /// Append the text to `out`, with no allocation of its own (the trajectory log writes seven
    /// numbers a vehicle and row).
    pub fn push_to(&self, out: &mut Vec<u8>) {
        let start = out.len();
        // Writing to a vector cannot fail.
        let _ = write!(out, "{:.*}", self.1, self.0);
        let text = &out[start..];
        if text.contains(&b'.') {
            let kept = text.len() - text.iter().rev().take_while(|&&c| c == b'0').count();
            let kept = if text[kept - 1] == b'.' { kept - 1 } else { kept };
            out.truncate(start + kept);
        }
        // A value that rounds to zero from below prints as `-0`: a sign that is not there.
        if &out[start..] == b"-0" {
            out.truncate(start);
            out.push(b'0');
        }
    }
}

/// `x` rounded to `decimals` decimals, as the nearest `f64` (which JSON writes in the fewest
/// digits: `0.1`, not `0.09999999999999999`); `-0` becomes `0`; a non-finite `x` is returned as is.
pub fn rounded(x: f64, decimals: usize) -> f64 {
    if !x.is_finite() {
        return x;
    }
    let r: f64 = format!("{:.*}", decimals, x).parse().unwrap_or(x);
    if r == 0.0 { 0.0 } else { r }
}

/// Decimals of times \[s\] in outputs: the clock's 1 µs.
pub const TIME_DECIMALS: usize = 6;

/// Append every vehicle's state at this tick to the [`TrajectoryLog`].
pub fn log_trajectories(
    clock: Res<SimClock>,
    vehicles: Res<Vehicles>,
    states: Query<(&VehicleState, Option<&LanePosition>)>,
    log: Option<ResMut<TrajectoryLog>>,
    parallelism: Option<Res<Parallelism>>,
    mut chunks: Local<Vec<(Vec<u8>, u64)>>,
) {
    let Some(mut log) = log else { return };
    if log.error.is_some() {
        return;
    }
    let t = clock.now.as_secs();
    if log.last_t == Some(t) {
        return;
    }
    log.last_t = Some(t);
    // The rows are formatted in chunks of vehicles on the threads (the numbers' text is most of
    // a town's logging, on one thread), then written in order.
    let mut list: Vec<(VehicleId, Entity)> = vehicles.iter().collect();
    let mut time = Vec::with_capacity(16);
    Fixed(t, TIME_DECIMALS).push_to(&mut time);
    let parallelism = parallelism.as_deref().copied().unwrap_or_else(Parallelism::single);
    for (text, rows) in chunks.iter_mut() {
        text.clear();
        *rows = 0;
    }
    parallelism.for_each_chunk(&mut list, &mut chunks, |part, (out, rows)| {
        for &mut (id, e) in part {
            let Ok((s, lane)) = states.get(e) else { continue };
            out.extend_from_slice(&time);
            // Writing to a vector cannot fail.
            let _ = write!(out, ",{id},");
            for (x, decimals) in [
                (s.position.x, LENGTH_DECIMALS),
                (s.position.y, LENGTH_DECIMALS),
                (s.yaw, ANGLE_DECIMALS),
                (s.velocity.x, LENGTH_DECIMALS),
                (s.velocity.y, LENGTH_DECIMALS),
            ] {
                Fixed(x, decimals).push_to(out);
                out.push(b',');
            }
            match lane.and_then(|l| Some((l.lanelet?, l.offset))) {
                Some((lanelet, offset)) => {
                    let _ = write!(out, "{},", lanelet.0);
                    Fixed(offset, LENGTH_DECIMALS).push_to(out);
                    out.push(b'\n');
                }
                None => out.extend_from_slice(b",\n"),
            }
            *rows += 1;
        }
    });
    for (text, rows) in chunks.iter() {
        if let Err(e) = log.writer.write_all(text) {
            log.error = Some(e);
            return;
        }
        log.rows += rows;
    }
}

/// Log the state at the end of a run (unless the logger's own tick already did): a 600 s run
/// ends with rows at t = 600, not at the last tick of the log rate.
pub fn log_final_state(sim: &mut Sim) {
    use bevy_ecs::system::RunSystemOnce;
    // The system's parameters are all resources and a query, always valid: the error is
    // unreachable, and a write error is kept in the log for `finish` to report.
    crate::vehicles::refresh_lane_positions(sim.world_mut());
    let _ = sim.world_mut().run_system_once(log_trajectories);
}

/// The trajectory logger as a module of its own at `rate` \[Hz\]; insert a [`TrajectoryLog`]
/// resource to say where the rows go.
#[derive(Debug, Clone, Copy)]
pub struct TrajectoryLogPlugin {
    /// Log rate \[Hz\].
    pub rate: f64,
}

impl Plugin for TrajectoryLogPlugin {
    fn build(&self, sim: &mut SimBuilder) {
        sim.add_module("log", Log, Phase::Sense, self.rate);
        // Lane positions are found where they are read (see `update_lane_positions`).
        sim.add_systems(Log, (crate::vehicles::lanes::update_lane_positions, log_trajectories).chain());
    }
}

#[cfg(test)]
mod tests {
    use super::Fixed;

    /// The numbers of `trajectories.csv`: rounded to their decimals, trailing zeros and a bare
    /// point dropped, no `-0`; appended after what the buffer already holds.
    #[test]
    fn fixed_numbers_drop_trailing_zeros_and_the_sign_of_zero() {
        let text = |x: f64, d: usize| Fixed(x, d).to_string();
        assert_eq!(text(0.1, 3), "0.1");
        assert_eq!(text(12.0, 3), "12");
        assert_eq!(text(100.0, 0), "100");
        assert_eq!(text(-1.25, 3), "-1.25");
        assert_eq!(text(-0.0004, 3), "0");
        assert_eq!(text(0.00049, 3), "0");
        assert_eq!(text(2.0004, 3), "2");
        assert_eq!(text(1.23456789, 6), "1.234568");
        assert_eq!(text(f64::NAN, 3), "NaN");
        let mut out = b"x,".to_vec();
        Fixed(3.10, 3).push_to(&mut out);
        Fixed(-0.0, 3).push_to(&mut out);
        assert_eq!(out, b"x,3.10");
    }
}

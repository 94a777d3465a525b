//! Run outputs written while a run goes: the trajectory log (`trajectories.csv`, its own module at
//! the log rate). The run's `summary.json` is [`crate::app::running::summary::RunSummary`].

use std::io::Write;

use bevy_ecs::prelude::{Query, Res, ResMut, Resource};
use bevy_ecs::schedule::{IntoScheduleConfigs, ScheduleLabel};

use crate::sim::{Phase, Plugin, Sim, SimBuilder, SimClock};
use crate::vehicles::LanePosition;
use crate::world::{VehicleState, Vehicles};

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
        let text = format!("{:.*}", self.1, self.0);
        let text = if text.contains('.') { text.trim_end_matches('0').trim_end_matches('.') } else { &text };
        // A value that rounds to zero from below prints as `-0`: a sign that is not there.
        f.write_str(if text == "-0" { "0" } else { text })
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
    for (id, e) in vehicles.iter() {
        if let Ok((s, lane)) = states.get(e) {
            let r = write!(
                log.writer,
                "{},{id},{},{},{},{},{}",
                Fixed(t, TIME_DECIMALS),
                Fixed(s.position.x, LENGTH_DECIMALS),
                Fixed(s.position.y, LENGTH_DECIMALS),
                Fixed(s.yaw, ANGLE_DECIMALS),
                Fixed(s.velocity.x, LENGTH_DECIMALS),
                Fixed(s.velocity.y, LENGTH_DECIMALS)
            )
            .and_then(|()| match lane.and_then(|l| Some((l.lanelet?, l.offset))) {
                Some((id, offset)) => writeln!(log.writer, ",{},{}", id.0, Fixed(offset, LENGTH_DECIMALS)),
                None => writeln!(log.writer, ",,"),
            });
            if let Err(e) = r {
                log.error = Some(e);
                return;
            }
            log.rows += 1;
        }
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

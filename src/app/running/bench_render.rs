//! `smlworld bench --render WxH` (issue 25 item 2): after the simulation bench, the same world
//! drawn by the bird's-eye renderer (whole-map view, the environment layer cached after the first
//! frame) a few times, each frame timed from reading the vehicles to the image read back, as a
//! frame writer would.

use std::time::Instant;

use super::bench::{BenchError, BenchWorld};
use super::bench_map::upper_median;
use super::runner::run_headless;
use crate::render::{FrameOutput, FrameRecorder, RenderError, sprites_from_world};
use crate::sim::{Parallelism, SimClock};

/// Frames timed (after one untimed first frame that builds the environment layer).
pub const RENDER_FRAMES: usize = 10;

/// Sim time between two rendered frames [s].
const FRAME_GAP_S: f64 = 0.5;

/// What `bench --render` measured.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct RenderBench {
    /// Image width \[px\].
    pub width: u32,
    /// Image height \[px\].
    pub height: u32,
    /// Vehicles drawn.
    pub vehicles: usize,
    /// Frames timed.
    pub frames: usize,
    /// Wall time of the first frame \[ms\] (builds the cached environment layer; not timed below).
    pub first_frame_ms: f64,
    /// Each timed frame's wall time \[ms\], in order.
    pub frame_ms: Vec<f64>,
    /// Median of `frame_ms`.
    pub median_ms: f64,
    /// The graphics adapter (on a machine without a GPU: Mesa's lavapipe).
    pub adapter: String,
}

/// Errors of the render benchmark.
#[derive(Debug, thiserror::Error)]
pub enum RenderBenchError {
    /// The benchmark world could not be built.
    #[error(transparent)]
    World(#[from] BenchError),
    /// The renderer failed (no Vulkan adapter, a bad size).
    #[error("rendering the benchmark world: {0}")]
    Render(#[from] RenderError),
}

/// Draw `world` at `width` x `height` px [`RENDER_FRAMES`] times, `FRAME_GAP_S` of sim time
/// apart (the sim steps between frames are not timed).
pub fn bench_render(
    world: &BenchWorld,
    width: u32,
    height: u32,
    parallelism: Option<Parallelism>,
) -> Result<RenderBench, RenderBenchError> {
    let (map, _) = world.map_and_lanes()?;
    let mut builder = world.builder()?;
    builder.insert_resource(parallelism.unwrap_or_default());
    let mut sim = builder.build();
    let output = FrameOutput { width, height, ..FrameOutput::default() };
    let mut recorder = FrameRecorder::new(&map, &output)?;
    let adapter = recorder.adapter_name();
    let mut sprites = Vec::new();
    let mut frame = |sim: &crate::sim::Sim| -> Result<f64, RenderError> {
        let started = Instant::now();
        sprites_from_world(sim.world(), false, &mut sprites);
        let t = sim.world().get_resource::<SimClock>().map_or(0.0, |c| c.now.as_secs());
        recorder.draw(&sprites, t)?;
        Ok(started.elapsed().as_secs_f64() * 1e3)
    };
    let first_frame_ms = frame(&sim)?;
    let mut frame_ms = Vec::with_capacity(RENDER_FRAMES);
    for _ in 0..RENDER_FRAMES {
        run_headless(&mut sim, FRAME_GAP_S, FRAME_GAP_S, |_| {});
        frame_ms.push(frame(&sim)?);
    }
    Ok(RenderBench {
        width,
        height,
        vehicles: world.vehicles,
        frames: frame_ms.len(),
        first_frame_ms,
        median_ms: upper_median(&frame_ms),
        frame_ms,
        adapter,
    })
}

/// `WxH` as (width, height) \[px\], each in 1..=16384.
pub fn parse_size(text: &str) -> Result<(u32, u32), String> {
    let bad = || format!("--render takes WIDTHxHEIGHT in pixels, e.g. 1920x1080; got '{text}'");
    let (w, h) = text.split_once(['x', 'X']).ok_or_else(bad)?;
    let (w, h): (u32, u32) = (w.trim().parse().map_err(|_| bad())?, h.trim().parse().map_err(|_| bad())?);
    if !(1..=16384).contains(&w) || !(1..=16384).contains(&h) {
        return Err(format!("--render: each side must be 1 to 16384 px, got {w}x{h}"));
    }
    Ok((w, h))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse_and_bad_ones_say_what_is_expected() {
        assert_eq!(parse_size("1920x1080"), Ok((1920, 1080)));
        assert_eq!(parse_size("640X360"), Ok((640, 360)));
        for bad in ["1920", "x1080", "0x10", "20000x10", "axb", ""] {
            assert!(parse_size(bad).is_err(), "{bad} accepted");
        }
        assert!(parse_size("1920").unwrap_err().contains("WIDTHxHEIGHT"));
    }
}

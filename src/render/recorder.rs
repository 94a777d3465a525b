//! Recording a running simulation as numbered PNG frames and/or an animated GIF.
//!
//! The recorder only reads the world: `smlworld run --frames DIR --gif FILE.gif` calls
//! [`FrameRecorder::record`] between chunks of sim time, so the simulation's results do not
//! depend on whether (or at what rate) it is recorded.

use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use bevy_ecs::prelude::{Entity, World};
use image::codecs::gif::{GifEncoder, Repeat};

use super::{BirdseyeView, Environment, EnvironmentLayer, Overlays, PatternSet, RadarCone, RenderError, Renderer, VehicleSprite};
use super::output::frame_path;
use crate::map::LaneletMap;
use crate::world::{Radar, VehicleClass, VehicleId, VehicleSize, VehicleState, Velodyne};

/// What to record and how.
#[derive(Debug, Clone, PartialEq)]
pub struct RecorderOptions {
    /// Folder for numbered PNG frames (`frame_000000.png`, ...), created if missing.
    pub frames_dir: Option<PathBuf>,
    /// Animated GIF file.
    pub gif: Option<PathBuf>,
    /// Frames per second of sim time [Hz]; raising it gives smoother but bigger output.
    pub frame_rate: f64,
    /// Image width [px].
    pub width: u32,
    /// Image height [px].
    pub height: u32,
    /// Draw radar cones and velodyne circles.
    pub sensor_ranges: bool,
}

impl Default for RecorderOptions {
    fn default() -> Self {
        RecorderOptions { frames_dir: None, gif: None, frame_rate: 10.0, width: 1280, height: 720, sensor_ranges: false }
    }
}

/// Renders frames of a running simulation over the map's environment layer.
pub struct FrameRecorder {
    renderer: Renderer,
    layer: EnvironmentLayer,
    frames_dir: Option<PathBuf>,
    gif: Option<(PathBuf, GifEncoder<BufWriter<File>>)>,
    delay: image::Delay,
    sensor_ranges: bool,
    sprites: Vec<VehicleSprite>,
    frames: u64,
}

fn write_error(path: &Path, e: impl std::fmt::Display) -> RenderError {
    RenderError::Write { path: path.to_path_buf(), message: e.to_string() }
}

impl FrameRecorder {
    /// A recorder whose view fits the whole map; creates the frame folder and the GIF file.
    pub fn new(map: &LaneletMap, opts: &RecorderOptions) -> Result<FrameRecorder, RenderError> {
        if !(opts.frame_rate.is_finite() && opts.frame_rate > 0.0) {
            let what = opts.gif.clone().or_else(|| opts.frames_dir.clone()).unwrap_or_default();
            return Err(write_error(&what, format!("frame rate {} Hz must be finite and > 0", opts.frame_rate)));
        }
        let renderer = Renderer::new()?;
        let view = BirdseyeView::fit_map(opts.width, opts.height, map)?;
        let layer = renderer.environment_layer(&Environment::from_map(map), &view, &PatternSet::builtin())?;
        if let Some(dir) = &opts.frames_dir {
            std::fs::create_dir_all(dir).map_err(|e| write_error(dir, e))?;
        }
        let gif = match &opts.gif {
            Some(path) => {
                let file = File::create(path).map_err(|e| write_error(path, e))?;
                // Speed 10 of 1..30: good colours at a tolerable encoding time.
                let mut encoder = GifEncoder::new_with_speed(BufWriter::new(file), 10);
                encoder.set_repeat(Repeat::Infinite).map_err(|e| write_error(path, e))?;
                Some((path.clone(), encoder))
            }
            None => None,
        };
        // GIF delays are in hundredths of a second; 10 ms is the shortest most viewers honour.
        let delay = image::Delay::from_numer_denom_ms((1000.0 / opts.frame_rate).round().max(10.0) as u32, 1);
        Ok(FrameRecorder {
            renderer,
            layer,
            frames_dir: opts.frames_dir.clone(),
            gif,
            delay,
            sensor_ranges: opts.sensor_ranges,
            sprites: Vec::new(),
            frames: 0,
        })
    }

    /// Render the world as it is now and append the frame to the outputs.
    pub fn record(&mut self, world: &World) -> Result<(), RenderError> {
        sprites_from_world(world, self.sensor_ranges, &mut self.sprites);
        let image = self.renderer.render_frame(&self.layer, &self.sprites)?;
        if let Some(dir) = &self.frames_dir {
            let path = frame_path(dir, self.frames);
            super::write_image(&path, &image)?;
        }
        if let Some((path, encoder)) = &mut self.gif {
            encoder
                .encode_frame(image::Frame::from_parts(image, 0, 0, self.delay))
                .map_err(|e| write_error(path, e))?;
        }
        self.frames += 1;
        Ok(())
    }

    /// Number of frames recorded so far.
    pub fn frames(&self) -> u64 {
        self.frames
    }
}

/// The world's vehicles as sprites, sorted by id (so frames do not depend on entity order).
/// `out` is cleared and reused.
pub fn sprites_from_world(world: &World, sensor_ranges: bool, out: &mut Vec<VehicleSprite>) {
    out.clear();
    let Some(mut query) = world.try_query::<(Entity, &VehicleId, &VehicleState)>() else { return };
    for (entity, id, state) in query.iter(world) {
        let size = world.get::<VehicleSize>(entity).copied().unwrap_or_default();
        let class = world.get::<VehicleClass>(entity).copied().unwrap_or_default();
        let mut sprite = VehicleSprite::new(id.0, state.position, state.yaw, size.length, size.width, class.name());
        if sensor_ranges {
            sprite.overlays = Overlays {
                radar: world.get::<Radar>(entity).map(|r| RadarCone { range: r.range, angle: r.angle }),
                velodyne: world.get::<Velodyne>(entity).map(|v| v.range),
                ..Overlays::default()
            };
        }
        out.push(sprite);
    }
    out.sort_by_key(|s| s.id);
}

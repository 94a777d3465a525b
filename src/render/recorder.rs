//! Recording a running simulation as numbered PNG frames and/or an animated GIF.
//!
//! The recorder only reads the world: `smlworld run --frames DIR --gif FILE.gif` calls
//! [`FrameRecorder::record`] between chunks of sim time, so the simulation's results do not
//! depend on whether (or at what rate) it is recorded.

use std::path::PathBuf;

use bevy_ecs::prelude::{Entity, World};

use super::output::{GifWriter, frame_path, write_error};
use super::{
    BirdseyeView, Environment, EnvironmentLayer, Overlays, PatternSet, RadarCone, RenderError, Renderer, VehicleSprite,
};
use crate::map::LaneletMap;
use crate::sim::SimClock;
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
    /// Time stamp and legend in the top-left corner ([`super::draw_overlay`]): `Some(true)` on
    /// every output, `Some(false)` on none, `None` (default) on the GIF only.
    pub overlay: Option<bool>,
    /// Scale [px/m] of a fixed window instead of the whole map (with `center`, default the
    /// map's origin); `None` fits the whole map.
    pub pixels_per_meter: Option<f64>,
    /// World point at the image centre [m] (with `pixels_per_meter`).
    pub center: Option<glam::DVec2>,
}

impl Default for RecorderOptions {
    fn default() -> Self {
        RecorderOptions {
            frames_dir: None,
            gif: None,
            frame_rate: 10.0,
            width: 1280,
            height: 720,
            sensor_ranges: false,
            overlay: None,
            pixels_per_meter: None,
            center: None,
        }
    }
}

/// Renders frames of a running simulation over the map's environment layer.
pub struct FrameRecorder {
    renderer: Renderer,
    layer: EnvironmentLayer,
    frames_dir: Option<PathBuf>,
    gif: Option<GifWriter>,
    sensor_ranges: bool,
    overlay: Option<bool>,
    sprites: Vec<VehicleSprite>,
    frames: u64,
}

/// The one range check of a frame rate a user gives (`--frame-rate` on run, replay and view):
/// `Err` with the message naming the option and the allowed range (0, 1000] Hz.
pub fn check_frame_rate(hz: f64) -> Result<(), String> {
    if hz.is_finite() && hz > 0.0 && hz <= 1000.0 {
        Ok(())
    } else {
        Err(format!("--frame-rate must be in (0, 1000] Hz, got {hz}"))
    }
}

impl FrameRecorder {
    /// A recorder whose view fits the whole map (or shows the window `pixels_per_meter` and
    /// `center` give); creates the frame folder and the GIF file.
    pub fn new(map: &LaneletMap, opts: &RecorderOptions) -> Result<FrameRecorder, RenderError> {
        if !(opts.frame_rate.is_finite() && opts.frame_rate > 0.0) {
            let what = opts.gif.clone().or_else(|| opts.frames_dir.clone()).unwrap_or_default();
            return Err(write_error(&what, format!("frame rate {} Hz must be finite and > 0", opts.frame_rate)));
        }
        let renderer = Renderer::new()?;
        let view = match opts.pixels_per_meter {
            Some(ppm) => BirdseyeView::new(opts.width, opts.height, ppm, opts.center.unwrap_or(glam::DVec2::ZERO))?,
            None => BirdseyeView::fit_map(opts.width, opts.height, map)?,
        };
        let layer = renderer.environment_layer(&Environment::from_map(map), &view, &PatternSet::builtin())?;
        if let Some(dir) = &opts.frames_dir {
            std::fs::create_dir_all(dir).map_err(|e| write_error(dir, e))?;
        }
        let gif = match &opts.gif {
            Some(path) => Some(GifWriter::create(path, opts.width, opts.height, opts.frame_rate)?),
            None => None,
        };
        Ok(FrameRecorder {
            renderer,
            layer,
            frames_dir: opts.frames_dir.clone(),
            gif,
            sensor_ranges: opts.sensor_ranges,
            overlay: opts.overlay,
            sprites: Vec::new(),
            frames: 0,
        })
    }

    /// Render the world as it is now and append the frame to the outputs.
    pub fn record(&mut self, world: &World) -> Result<(), RenderError> {
        let mut sprites = std::mem::take(&mut self.sprites);
        sprites_from_world(world, self.sensor_ranges, &mut sprites);
        let t = world.get_resource::<SimClock>().map_or(0.0, |c| c.now.as_secs());
        let result = self.record_sprites(&sprites, t);
        self.sprites = sprites;
        result
    }

    /// Render `sprites` (sorted by id, as [`sprites_from_world`] gives them) at sim time `t` [s]
    /// over the map and append the frame to the outputs: `smlworld replay` draws a finished
    /// run's rows this way.
    pub fn record_sprites(&mut self, sprites: &[VehicleSprite], t: f64) -> Result<(), RenderError> {
        let mut image = self.renderer.render_frame(&self.layer, sprites)?;
        let mut overlaid = false;
        if let Some(dir) = &self.frames_dir {
            if self.overlay == Some(true) {
                super::draw_overlay(&mut image, t, sprites);
                overlaid = true;
            }
            let path = frame_path(dir, self.frames);
            super::write_image(&path, &image)?;
        }
        if let Some(gif) = &mut self.gif {
            if self.overlay != Some(false) && !overlaid {
                super::draw_overlay(&mut image, t, sprites);
            }
            gif.push(image)?;
        }
        self.frames += 1;
        Ok(())
    }

    /// Render the world as it is now and return the frame, without writing it anywhere.
    pub fn render(&mut self, world: &World) -> Result<image::RgbaImage, RenderError> {
        sprites_from_world(world, self.sensor_ranges, &mut self.sprites);
        self.renderer.render_frame(&self.layer, &self.sprites)
    }

    /// Finish the outputs: the GIF is completed and renamed into place (frames are written one by
    /// one as they come). A recorder dropped without this leaves an earlier GIF of the same name.
    pub fn finish(self) -> Result<(), RenderError> {
        match self.gif {
            Some(gif) => gif.finish(),
            None => Ok(()),
        }
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

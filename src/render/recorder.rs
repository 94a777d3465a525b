//! Recording a running simulation as numbered PNG frames and/or an animated GIF.
//!
//! The recorder only reads the world: `smlworld run --frames DIR --gif FILE.gif` calls
//! [`FrameRecorder::record`] between chunks of sim time, so the simulation's results do not
//! depend on whether (or at what rate) it is recorded.

use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use bevy_ecs::prelude::{Entity, World};

use super::output::frame_path;
use super::{
    BirdseyeView, Environment, EnvironmentLayer, Overlays, PatternSet, RadarCone, RenderError, Renderer, VehicleSprite,
};
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
        RecorderOptions {
            frames_dir: None,
            gif: None,
            frame_rate: 10.0,
            width: 1280,
            height: 720,
            sensor_ranges: false,
        }
    }
}

/// Renders frames of a running simulation over the map's environment layer.
pub struct FrameRecorder {
    renderer: Renderer,
    layer: EnvironmentLayer,
    frames_dir: Option<PathBuf>,
    gif: Option<(PathBuf, gif::Encoder<BufWriter<File>>)>,
    /// The last frame written to the GIF: later frames store only what changed since.
    previous: Option<image::RgbaImage>,
    /// Frame delay [1/100 s].
    delay: u16,
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
                let (w, h) = (gif_side(opts.width, path)?, gif_side(opts.height, path)?);
                let mut encoder =
                    gif::Encoder::new(BufWriter::new(file), w, h, &[]).map_err(|e| write_error(path, e))?;
                encoder.set_repeat(gif::Repeat::Infinite).map_err(|e| write_error(path, e))?;
                Some((path.clone(), encoder))
            }
            None => None,
        };
        // GIF delays are in hundredths of a second; 2 is the shortest most viewers honour.
        let delay = (100.0 / opts.frame_rate).round().clamp(2.0, f64::from(u16::MAX)) as u16;
        Ok(FrameRecorder {
            renderer,
            layer,
            frames_dir: opts.frames_dir.clone(),
            gif,
            previous: None,
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
            let frame = gif_frame(self.previous.as_ref(), &image, self.delay);
            encoder.write_frame(&frame).map_err(|e| write_error(path, e))?;
            self.previous = Some(image);
        }
        self.frames += 1;
        Ok(())
    }

    /// Number of frames recorded so far.
    pub fn frames(&self) -> u64 {
        self.frames
    }
}

fn gif_side(px: u32, path: &Path) -> Result<u16, RenderError> {
    u16::try_from(px).map_err(|_| write_error(path, format!("{px} px is too large for a GIF (at most 65535)")))
}

/// A GIF frame holding only what changed since `prev` (the whole image for the first frame):
/// the bounding box of the changed pixels, with unchanged pixels inside it transparent, kept on
/// screen by the `Keep` disposal. The static ground then costs nothing after the first frame,
/// which makes GIFs tens of times smaller and faster to write.
fn gif_frame(prev: Option<&image::RgbaImage>, next: &image::RgbaImage, delay: u16) -> gif::Frame<'static> {
    let (w, h) = next.dimensions();
    let (mut x0, mut y0, mut x1, mut y1) = (0, 0, w - 1, h - 1);
    if let Some(prev) = prev {
        (x0, y0, x1, y1) = (w, h, 0, 0);
        for (x, y, p) in next.enumerate_pixels() {
            if prev.get_pixel(x, y) != p {
                (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x), y1.max(y));
            }
        }
        if x0 > x1 {
            // Nothing changed: one transparent pixel keeps the frame's place in time.
            (x0, y0, x1, y1) = (0, 0, 0, 0);
        }
    }
    let mut sub: Vec<u8> = Vec::with_capacity(((x1 - x0 + 1) * (y1 - y0 + 1) * 4) as usize);
    for y in y0..=y1 {
        for x in x0..=x1 {
            let p = next.get_pixel(x, y);
            let same = prev.is_some_and(|prev| prev.get_pixel(x, y) == p);
            sub.extend_from_slice(if same { &[0, 0, 0, 0] } else { &p.0 });
        }
    }
    // Speed 10 of 1..30: good colours at a tolerable encoding time.
    let mut frame = gif::Frame::from_rgba_speed((x1 - x0 + 1) as u16, (y1 - y0 + 1) as u16, &mut sub, 10);
    frame.left = x0 as u16;
    frame.top = y0 as u16;
    frame.delay = delay;
    frame.dispose = gif::DisposalMethod::Keep;
    frame
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

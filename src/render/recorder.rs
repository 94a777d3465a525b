//! Recording a running simulation (or a replay, or the live view's stream) as numbered PNG
//! frames and/or an animated GIF, through the [`Camera`] that [`FrameOutput`] sets up.
//!
//! The recorder only reads the world: `smlworld run --frames DIR --gif FILE.gif` calls
//! [`FrameRecorder::record`] between chunks of sim time, so the simulation's results do not
//! depend on whether (or at what rate) it is recorded.

use std::path::PathBuf;

use bevy_ecs::prelude::{Entity, Without, World};
use glam::DVec2;
use image::RgbaImage;

use super::camera::{Camera, FrameOutput, Overlay};
use super::output::{GifWriter, frame_path, write_error};
use super::video::VideoWriter;
use super::{
    BirdseyeView, Environment, EnvironmentLayer, Overlays, PatternSet, RadarCone, RenderError, Renderer, SignalLine,
    VehicleSprite,
};
use crate::map::LaneletMap;
use crate::sim::SimClock;
use crate::world::{LabDriven, Radar, Stationary, VehicleClass, VehicleId, VehicleSize, VehicleState, Velodyne};

/// How long a collision's red ring stays in the frames [s of sim time].
pub const COLLISION_RING_SECONDS: f64 = 2.0;

/// Renders frames over an environment (a map's, usually) and writes them as PNGs and/or a GIF.
pub struct FrameRecorder {
    renderer: Renderer,
    env: Environment,
    patterns: PatternSet,
    camera: Camera,
    layer: Option<EnvironmentLayer>,
    frames_dir: Option<PathBuf>,
    gif: Option<GifWriter>,
    gif_path: Option<PathBuf>,
    gif_size: (u32, u32),
    /// The GIF takes every `n`-th frame, scaled to this size ([`FrameOutput::gif_sampling`]).
    gif_sampling: (u64, u32, u32),
    /// The MP4 video: every frame at full size.
    video: Option<(VideoWriter, PathBuf)>,
    sensor_ranges: bool,
    overlay: Overlay,
    sprites: Vec<VehicleSprite>,
    image: RgbaImage,
    /// Collisions drawn as red rings: place [m] and sim time [s].
    collisions: Vec<(DVec2, f64)>,
    /// Stop lines drawn in their signal's colour ([`FrameRecorder::set_signals`]).
    signals: Vec<SignalLine>,
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
    /// A recorder of `map` with the view, outputs and overlay `frames` asks for (see
    /// [`FrameOutput`] and [`Camera`]); creates the frame folder and the GIF file.
    pub fn new(map: &LaneletMap, frames: &FrameOutput) -> Result<FrameRecorder, RenderError> {
        let map_box = if map.nodes.is_empty() { None } else { Some(map.bounding_box()) };
        if map_box.is_none() && frames.pixels_per_meter.is_none() {
            return Err(RenderError::InvalidView(
                "cannot fit a view to a map without nodes; give --pixels-per-meter and --center".into(),
            ));
        }
        FrameRecorder::with_environment(Environment::from_map(map), map_box, frames)
    }

    /// A recorder of any environment; `map_box` (min, max) \[m\] is what the whole-map view fits
    /// (`None`: origin-centred at 4 px/m unless `frames` gives a scale).
    pub fn with_environment(
        env: Environment,
        map_box: Option<(DVec2, DVec2)>,
        frames: &FrameOutput,
    ) -> Result<FrameRecorder, RenderError> {
        let what = || frames.gif.clone().or_else(|| frames.frames.clone()).unwrap_or_default();
        frames.check().map_err(|e| write_error(&what(), e))?;
        let camera = Camera::new(frames, map_box)?;
        let renderer = Renderer::new()?;
        if let Some(dir) = &frames.frames {
            std::fs::create_dir_all(dir).map_err(|e| write_error(dir, e))?;
        }
        let gif_sampling = frames.gif_sampling();
        let gif = match &frames.gif {
            Some(path) => {
                let (every, w, h) = gif_sampling;
                if gif_sampling != (1, frames.width, frames.height) {
                    tracing::info!(
                        "following a vehicle: the GIF takes {} Hz at {w}x{h} px to stay small (its ground moves in every frame); --full-gif for every frame at full size",
                        frames.frame_rate / every as f64
                    );
                }
                Some(GifWriter::create(path, w, h, frames.frame_rate / every as f64)?)
            }
            None => None,
        };
        let video = match &frames.video {
            Some(path) => {
                Some((VideoWriter::create(path, frames.width, frames.height, frames.frame_rate)?, path.clone()))
            }
            None => None,
        };
        Ok(FrameRecorder {
            renderer,
            env,
            patterns: PatternSet::builtin(),
            camera,
            layer: None,
            frames_dir: frames.frames.clone(),
            gif,
            gif_path: frames.gif.clone(),
            gif_size: (frames.width, frames.height),
            gif_sampling,
            video,
            sensor_ranges: false,
            overlay: frames.overlay,
            sprites: Vec::new(),
            image: RgbaImage::new(1, 1),
            collisions: Vec::new(),
            signals: Vec::new(),
            frames: 0,
        })
    }

    /// Draw radar cones and velodyne circles of the vehicles [`FrameRecorder::record`] reads.
    pub fn with_sensor_ranges(mut self, on: bool) -> FrameRecorder {
        self.sensor_ranges = on;
        self
    }

    /// Mark a collision at `place` \[m\] that happened at sim time `t` \[s\]: frames from `t` to
    /// `t` + [`COLLISION_RING_SECONDS`] draw a red ring there.
    pub fn add_collision(&mut self, place: DVec2, t: f64) {
        if place.is_finite() && t.is_finite() {
            self.collisions.push((place, t));
        }
    }

    /// Draw `lines` (stop lines and what their signals show now) in the frames from now on,
    /// until set again; an empty slice draws none.
    pub fn set_signals(&mut self, lines: &[SignalLine]) {
        self.signals.clear();
        self.signals.extend_from_slice(lines);
    }

    /// The graphics adapter drawing the frames.
    pub fn adapter_name(&self) -> String {
        self.renderer.adapter_name()
    }

    /// The camera (for a window that changes size: [`FrameRecorder::resize`]).
    pub fn camera(&self) -> &Camera {
        &self.camera
    }

    /// Draw later frames at `width` x `height` px (a resized window; the GIF keeps its size
    /// and skips frames of another size).
    pub fn resize(&mut self, width: u32, height: u32) -> Result<(), RenderError> {
        self.camera = self.camera.resized(width, height)?;
        Ok(())
    }

    /// The view of the last frame drawn.
    pub fn view(&self) -> Option<BirdseyeView> {
        self.layer.as_ref().map(|l| *l.view())
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

    /// Render `sprites` (sorted by id, as [`sprites_from_world`] gives them) at sim time `t` \[s\]
    /// and append the frame to the outputs: `smlworld replay` draws a finished run's rows this way.
    pub fn record_sprites(&mut self, sprites: &[VehicleSprite], t: f64) -> Result<(), RenderError> {
        self.draw(sprites, t)?;
        self.write_drawn(sprites, t)
    }

    /// Render `sprites` at sim time `t` \[s\] (with the stop lines of [`FrameRecorder::set_signals`]
    /// and collision rings, without the overlay) and
    /// return the image, writing nothing.
    pub fn draw(&mut self, sprites: &[VehicleSprite], t: f64) -> Result<&RgbaImage, RenderError> {
        let view = self.camera.view(sprites)?;
        match &mut self.layer {
            Some(layer) => self.renderer.redraw_environment(layer, &self.env, &view, &self.patterns)?,
            None => self.layer = Some(self.renderer.environment_layer(&self.env, &view, &self.patterns)?),
        }
        let Some(layer) = &self.layer else { return Err(RenderError::InvalidView("no environment layer".into())) };
        self.renderer.render_frame_into(layer, sprites, &mut self.image)?;
        super::draw_signal_lines(&mut self.image, &view, &self.signals);
        self.collisions.retain(|(_, t0)| t - t0 <= COLLISION_RING_SECONDS);
        for (place, t0) in &self.collisions {
            if *t0 <= t + 1e-9 {
                super::draw_collision_ring(&mut self.image, &view, *place);
            }
        }
        Ok(&self.image)
    }

    /// Append the image [`FrameRecorder::draw`] drew last to the outputs, with the overlay (for
    /// time `t` \[s\] and the classes of `sprites`) on the outputs [`FrameOutput::overlay`] names;
    /// the drawn image itself stays without it.
    pub fn write_drawn(&mut self, sprites: &[VehicleSprite], t: f64) -> Result<(), RenderError> {
        let overlaid = |image: &RgbaImage| {
            let mut image = image.clone();
            super::draw_overlay(&mut image, t, sprites);
            image
        };
        let mut with_overlay = None;
        if let Some(dir) = &self.frames_dir {
            let path = frame_path(dir, self.frames);
            if self.overlay == Overlay::All {
                let image = overlaid(&self.image);
                super::write_image(&path, &image)?;
                with_overlay = Some(image);
            } else {
                super::write_image(&path, &self.image)?;
            }
        }
        if let Some((video, _)) = self.video.as_mut()
            && fits(&self.image, self.gif_size, "video")
        {
            match &with_overlay {
                Some(image) => video.push(image)?,
                None if self.overlay != Overlay::None => {
                    let image = overlaid(&self.image);
                    video.push(&image)?;
                    with_overlay = Some(image);
                }
                None => video.push(&self.image)?,
            }
        }
        let (every, gif_w, gif_h) = self.gif_sampling;
        if let Some(gif) = self.gif.as_mut().filter(|_| self.frames.is_multiple_of(every))
            && fits(&self.image, self.gif_size, "GIF")
        {
            let image = match with_overlay {
                Some(image) => image,
                None if self.overlay != Overlay::None => overlaid(&self.image),
                None => self.image.clone(),
            };
            let image = if image.dimensions() == (gif_w, gif_h) {
                image
            } else {
                image::imageops::resize(&image, gif_w, gif_h, image::imageops::FilterType::Triangle)
            };
            gif.push(image)?;
        }
        self.frames += 1;
        Ok(())
    }

    /// The image [`FrameRecorder::draw`] drew last.
    pub fn drawn(&self) -> &RgbaImage {
        &self.image
    }

    /// Draw the overlay (time `t` \[s\], the classes of `sprites`) onto the image drawn last (a
    /// live window showing it).
    pub fn overlay_drawn(&mut self, sprites: &[VehicleSprite], t: f64) {
        super::draw_overlay(&mut self.image, t, sprites);
    }

    /// Render the world as it is now and return the frame, without writing it anywhere.
    pub fn render(&mut self, world: &World) -> Result<RgbaImage, RenderError> {
        self.render_with(world, false)
    }

    /// [`FrameRecorder::render`], and every pair of vehicles whose footprints overlap now gets a
    /// collision ring (as a live view marks them): for callers that record no collision events,
    /// such as a learning environment that stopped the metrics and checks its own collisions.
    pub fn render_marking_overlaps(&mut self, world: &World) -> Result<RgbaImage, RenderError> {
        self.render_with(world, true)
    }

    fn render_with(&mut self, world: &World, mark_overlaps: bool) -> Result<RgbaImage, RenderError> {
        let mut sprites = std::mem::take(&mut self.sprites);
        sprites_from_world(world, self.sensor_ranges, &mut sprites);
        let t = world.get_resource::<SimClock>().map_or(0.0, |c| c.now.as_secs());
        if mark_overlaps {
            for (_, _, place) in super::overlapping_pairs(&sprites) {
                if !self.collisions.iter().any(|&(p, t0)| t0 == t && p == place) {
                    self.add_collision(place, t);
                }
            }
        }
        let image = self.draw(&sprites, t).cloned();
        self.sprites = sprites;
        image
    }

    /// Finish the outputs: the video and the GIF are completed and renamed into place (frames are written one by
    /// one as they come). A recorder dropped without this leaves an earlier GIF of the same name.
    /// Logs the GIF's size: a followed view's moving ground makes every frame new.
    pub fn finish(self) -> Result<(), RenderError> {
        if let Some((video, path)) = self.video {
            let frames = video.frames();
            let bytes = video.finish()?;
            tracing::info!("wrote {} ({frames} frames, {:.1} MB)", path.display(), bytes as f64 / 1e6);
        }
        let (Some(gif), Some(path)) = (self.gif, self.gif_path) else { return Ok(()) };
        let bytes = gif.finish()?;
        let frames = self.frames.div_ceil(self.gif_sampling.0);
        tracing::info!("wrote {} ({frames} frames, {:.1} MB)", path.display(), bytes as f64 / 1e6);
        Ok(())
    }

    /// Number of frames recorded so far.
    pub fn frames(&self) -> u64 {
        self.frames
    }
}

/// Whether `image` has the `size` \[px\] of the `what` output (GIF, video) it goes into; warns
/// that it is left out when not (a window resized under a recording).
fn fits(image: &RgbaImage, size: (u32, u32), what: &str) -> bool {
    let fits = image.dimensions() == size;
    if !fits {
        tracing::warn!(
            "a {}x{} px frame does not fit the {}x{} px {what}: left out of it",
            image.width(),
            image.height(),
            size.0,
            size.1
        );
    }
    fits
}

/// The world's vehicles as sprites, sorted by id (so frames do not depend on entity order);
/// [`Stationary`] obstacles are left out (the map layer draws their outlines). `out` is cleared
/// and reused.
pub fn sprites_from_world(world: &World, sensor_ranges: bool, out: &mut Vec<VehicleSprite>) {
    out.clear();
    // Before any schedule has run (the frame at t = 0) `Stationary` may not be registered yet:
    // then no vehicle is stationary, and the filter would make the query fail.
    let stationary_known = world.components().component_id::<Stationary>().is_some();
    let vehicles: Vec<(Entity, &VehicleId, &VehicleState)> = if stationary_known {
        match world.try_query_filtered::<(Entity, &VehicleId, &VehicleState), Without<Stationary>>() {
            Some(mut query) => query.iter(world).collect(),
            None => return,
        }
    } else {
        match world.try_query::<(Entity, &VehicleId, &VehicleState)>() {
            Some(mut query) => query.iter(world).collect(),
            None => return,
        }
    };
    for (entity, id, state) in vehicles {
        let size = world.get::<VehicleSize>(entity).copied().unwrap_or_default();
        let class = world.get::<VehicleClass>(entity).copied().unwrap_or_default();
        let mut sprite = VehicleSprite::new(id.0, state.position, state.yaw, size.length, size.width, class.name());
        sprite.real = world.get::<LabDriven>(entity).is_some();
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn real_is_where_the_state_comes_from_not_the_id_sign() {
        // Issue 61 §1: a vehicle of id >= 0 that no lab bridge drives is virtual; one the lab
        // drives (motion capture, a truck) is real whatever its id.
        let mut world = World::new();
        world.spawn((VehicleId(1000), VehicleState::default()));
        world.spawn((VehicleId(-3), VehicleState::default(), LabDriven));
        world.spawn((VehicleId(2), VehicleState::default(), LabDriven));
        let mut sprites = Vec::new();
        sprites_from_world(&world, false, &mut sprites);
        let mut real: Vec<(i32, bool)> = sprites.iter().map(|s| (s.id, s.real)).collect();
        real.sort_unstable();
        assert_eq!(real, vec![(-3, true), (2, true), (1000, false)]);
    }
}

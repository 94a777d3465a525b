//! Off-screen wgpu bird's-eye renderer: reads the world and the map, never writes them.
//!
//! A [`Renderer`] owns the wgpu device and queue (any adapter; Mesa's software lavapipe is fine).
//! A [`BirdseyeView`] maps metres to pixels. The [`Environment`] of a map (background pattern,
//! road pattern inside lanelets, area patterns, painted lines) is drawn once per view into an
//! [`EnvironmentLayer`]; each frame copies that layer and draws [`VehicleSprite`]s on top (bodies,
//! ids, sensor ranges, routes: one draw call per kind, whatever the number of vehicles: the
//! per-vehicle data sits in a storage buffer that the vertex shader reads, six vertices per
//! vehicle) and reads the image back.
//!
//! ```no_run
//! use smlworld::render::{BirdseyeView, Environment, PatternSet, Renderer, VehicleSprite};
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let map = smlworld::map::LaneletMap::load(std::path::Path::new("map.osm"))?;
//! let mut renderer = Renderer::new()?;
//! let view = BirdseyeView::fit_map(1920, 1080, &map)?;
//! let layer = renderer.environment_layer(&Environment::from_map(&map), &view, &PatternSet::builtin())?;
//! let truck = VehicleSprite::new(1, glam::DVec2::new(10.0, 0.0), 0.0, 8.0, 2.5, "Truck");
//! let frame = renderer.render_frame(&layer, &[truck])?;
//! smlworld::render::write_image(std::path::Path::new("frame.png"), &frame)?;
//! # Ok(()) }
//! ```

mod camera;
mod environment;
mod font;
mod gpu;
mod output;
mod overlay;
mod patterns;
mod recorder;
mod signals;
mod sprites;
mod triangulate;
mod video;
mod view;

use std::path::PathBuf;

pub use camera::{Camera, FOLLOW_GIF_RATE, FOLLOW_GIF_WIDTH, FOLLOW_PPM, FrameOutput, MIN_AUTO_FIT_PPM, Overlay};
pub use environment::{
    Area, Environment, Fill, Line, LineStyle, RoadStrip, lanelet2_lines, obstacle_color, subtype_tint,
};
pub use gpu::{EnvironmentLayer, Renderer};
pub use output::{GifWriter, frame_path, write_gif, write_image, write_image_with_meta, write_meta};
pub use overlay::{FONT_TTF, OVERLAY_BACKGROUND, OVERLAY_TEXT_PX, draw_collision_ring, draw_overlay};
pub use patterns::{PATTERN_SIZE, Pattern, PatternKind, PatternSet};
pub use recorder::{COLLISION_RING_SECONDS, FrameRecorder, check_frame_rate, sprites_from_world};
pub use signals::{SIGNAL_GREEN, SIGNAL_RED, SIGNAL_YELLOW, SignalLine, draw_signal_lines, signal_color, stop_lines};
pub use sprites::{Overlays, RadarCone, VehicleSprite, class_color, label_boxes, overlapping_pairs, vehicle_color};
pub use triangulate::triangulate;
pub use video::VideoWriter;
pub use view::{BirdseyeView, MAX_IMAGE_SIDE};

/// What can go wrong while rendering.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    /// No graphics adapter at all.
    #[error(
        "no graphics adapter found ({0}); the renderer needs Vulkan: on Debian/Ubuntu install Mesa's \
         software driver with `apt-get install libvulkan1 mesa-vulkan-drivers`"
    )]
    NoAdapter(String),
    /// The adapter refused to open a device.
    #[error("could not open the graphics device on adapter {0}")]
    Device(String),
    /// A view that cannot be drawn.
    #[error("invalid view: {0}")]
    InvalidView(String),
    /// The pattern directory does not exist.
    #[error("pattern directory {0} does not exist or is not a directory")]
    PatternDir(PathBuf),
    /// A pattern image could not be read.
    #[error("pattern image {path}: {source}; give a readable PNG/BMP or remove it to use the built-in one")]
    Pattern {
        /// The image file.
        path: PathBuf,
        /// Why it could not be read.
        source: image::ImageError,
    },
    /// Reading a frame back from the GPU failed.
    #[error("reading the frame back from the GPU failed: {0}")]
    Readback(String),
    /// Writing an output file failed.
    #[error("writing {path}: {message}")]
    Write {
        /// The output file.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
}

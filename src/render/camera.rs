//! What frames show and where they go: [`FrameOutput`] (the frame options of `run`, `replay` and
//! `view`, one clap argument group flattened into each) and the [`Camera`] that picks each
//! frame's view from them: a fixed window, the whole map, the vehicles when the map is too big
//! to read, or a window that follows one vehicle.

use std::path::PathBuf;

use glam::DVec2;

use super::view::BirdseyeView;
use super::{RenderError, VehicleSprite};

/// Scale below which a whole-map view is unreadable [px/m]: auto-fit frames the vehicles instead.
pub const MIN_AUTO_FIT_PPM: f64 = 1.0;
/// Shortest a vehicle may be drawn by the default view [px] (issue 61: the fitted 500 m lane
/// drop and 2 km GCDC road drew cars 2-3 px wide, their labels covering the road). When the
/// whole map would draw the shortest vehicle shorter, the view follows the traffic (the
/// vehicles' mean position, kept within the map) at this size.
pub const MIN_VEHICLE_PX: f64 = 6.0;
/// Scale of `--follow` without `--pixels-per-meter` [px/m] (or the whole map's, if larger).
pub const FOLLOW_PPM: f64 = 5.0;

/// Where the time stamp and legend are drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum Overlay {
    /// On the GIF and the video only (the default).
    #[default]
    Gif,
    /// On every output: PNG frames, the GIF, the video and the live window.
    All,
    /// On none.
    None,
}

/// The frame options shared by `smlworld run`, `replay` and `view` (`#[command(flatten)]` into
/// each one's arguments; the library's run and replay options hold one too).
#[derive(Debug, Clone, PartialEq, clap::Args)]
pub struct FrameOutput {
    /// Write numbered PNG frames of the bird's-eye view into this folder (created with its parents).
    #[arg(long, value_name = "DIR")]
    pub frames: Option<PathBuf>,
    /// Write an animated GIF (parent folders created).
    #[arg(long, value_name = "FILE.gif")]
    pub gif: Option<PathBuf>,
    /// Write an MP4 video (H.264; parent folders created): every frame at full size, also when
    /// following a vehicle (a followed minute at 1280x720: about 20 MB, where a GIF took 459 MB).
    #[arg(long, value_name = "FILE.mp4")]
    pub video: Option<PathBuf>,
    /// Frames per second of sim time for --frames, --gif and --video \[Hz\] (`view`: the most frames per
    /// wall-clock second written); does not change the results.
    #[arg(long, default_value_t = 10.0, value_parser = crate::range::positive)]
    pub frame_rate: f64,
    /// Frame width \[px\].
    #[arg(long, default_value_t = 1280, value_parser = crate::range::pixels())]
    pub width: u32,
    /// Frame height \[px\].
    #[arg(long, default_value_t = 720, value_parser = crate::range::pixels())]
    pub height: u32,
    /// Time stamp and legend (classes; real vs virtual): `gif` (default: on the GIF and video only),
    /// `all` (also PNG frames and the window; a bare `--overlay` means this) or `none`.
    #[arg(long, value_enum, default_value_t = Overlay::Gif, num_args = 0..=1, require_equals = true,
          default_missing_value = "all", value_name = "WHERE")]
    pub overlay: Overlay,
    /// Keep vehicle ID at the centre of every frame (at --pixels-per-meter, default 5 px/m).
    #[arg(long, value_name = "ID", allow_hyphen_values = true, conflicts_with = "center")]
    pub follow: Option<i32>,
    /// Scale [px/m]: a window of this scale instead of the whole map (centred on --center,
    /// default the map's centre), or the scale of --follow.
    #[arg(long, value_parser = crate::range::positive)]
    pub pixels_per_meter: Option<f64>,
    /// World point at the image centre, `X,Y` \[m\] (needs --pixels-per-meter).
    #[arg(long, value_parser = crate::range::point, allow_hyphen_values = true, requires = "pixels_per_meter")]
    pub center: Option<DVec2>,
    /// With --follow, write the GIF at every frame and the full size too (by default a followed
    /// GIF takes frames at most [`FOLLOW_GIF_RATE`] Hz, at most [`FOLLOW_GIF_WIDTH`] px wide:
    /// its ground moves in every frame, so each frame is stored whole).
    #[arg(long)]
    pub full_gif: bool,
}

/// Most frames per second of sim time of a followed view's GIF unless --full-gif \[Hz\].
pub const FOLLOW_GIF_RATE: f64 = 5.0;
/// Widest followed view's GIF unless --full-gif \[px\] (the height keeps the aspect ratio).
pub const FOLLOW_GIF_WIDTH: u32 = 640;

impl Default for FrameOutput {
    fn default() -> Self {
        FrameOutput {
            frames: None,
            gif: None,
            video: None,
            frame_rate: 10.0,
            width: 1280,
            height: 720,
            overlay: Overlay::Gif,
            follow: None,
            pixels_per_meter: None,
            center: None,
            full_gif: false,
        }
    }
}

impl FrameOutput {
    /// How the GIF samples the frames: every `n`-th frame, at `width` x `height` px. A followed
    /// view without --full-gif takes at most [`FOLLOW_GIF_RATE`] Hz and [`FOLLOW_GIF_WIDTH`] px
    /// (a 60 s followed run at 10 Hz and 1280x720 wrote 459 MB); otherwise every frame, full size.
    pub fn gif_sampling(&self) -> (u64, u32, u32) {
        if self.follow.is_none() || self.full_gif {
            return (1, self.width, self.height);
        }
        let every = (self.frame_rate / FOLLOW_GIF_RATE).ceil().max(1.0) as u64;
        if self.width <= FOLLOW_GIF_WIDTH {
            return (every, self.width, self.height);
        }
        let height = (f64::from(self.height) * f64::from(FOLLOW_GIF_WIDTH) / f64::from(self.width)).round().max(1.0);
        (every, FOLLOW_GIF_WIDTH, height as u32)
    }

    /// Whether frames, a GIF or a video are asked for.
    pub fn any(&self) -> bool {
        self.frames.is_some() || self.gif.is_some() || self.video.is_some()
    }

    /// The range checks the library makes for callers that do not go through clap; `Err` names
    /// the option and what is allowed.
    pub fn check(&self) -> Result<(), String> {
        super::check_frame_rate(self.frame_rate)?;
        let sides = 1..=super::MAX_IMAGE_SIDE;
        if !sides.contains(&self.width) || !sides.contains(&self.height) {
            return Err(format!(
                "--width and --height must be 1..={} px, got {}x{}",
                super::MAX_IMAGE_SIDE,
                self.width,
                self.height
            ));
        }
        if let Some(p) = self.pixels_per_meter
            && !(p.is_finite() && p > 0.0)
        {
            return Err(format!("--pixels-per-meter must be a finite number above 0, got {p}"));
        }
        if let Some(c) = self.center
            && !(c.x.is_finite() && c.y.is_finite())
        {
            return Err(format!("--center must be two finite coordinates, got {c}"));
        }
        if let Some(gif) = &self.gif
            && !gif.extension().is_some_and(|e| e.eq_ignore_ascii_case("gif"))
        {
            return Err(format!("--gif writes GIF data: name the file with a .gif extension, got {}", gif.display()));
        }
        if let Some(video) = &self.video
            && !video.extension().is_some_and(|e| e.eq_ignore_ascii_case("mp4"))
        {
            return Err(format!(
                "--video writes an MP4 (H.264) video: name the file with a .mp4 extension, got {}",
                video.display()
            ));
        }
        Ok(())
    }
}

/// How the camera picks its view.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Mode {
    /// One view for every frame.
    Fixed(BirdseyeView),
    /// No window asked for: the whole map (`map`) if it draws every vehicle of the first frame
    /// that has any at least [`MIN_VEHICLE_PX`] long (and is at least [`MIN_AUTO_FIT_PPM`]), else
    /// the traffic followed at that size, within the map's window.
    Auto { map: BirdseyeView, chosen: Option<Auto> },
    /// Centre every frame on vehicle `id` at `ppm` [px/m]; where it is absent, the last centre.
    Follow { id: i32, ppm: f64, last: DVec2 },
}

/// What [`Mode::Auto`] chose.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Auto {
    /// The same view in every frame (the whole map).
    Fixed(BirdseyeView),
    /// Centred on the vehicles' mean position at `ppm` [px/m], moved only when that leaves the
    /// middle half of the window (a view that moves every frame defeats GIF's frame
    /// differencing: a followed 2 min lane-drop GIF took 49 MB, this one under 1 MB).
    Traffic { ppm: f64, center: Option<DVec2> },
}

/// Picks the view of each frame (see [`FrameOutput`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Camera {
    width: u32,
    height: u32,
    mode: Mode,
}

impl Camera {
    /// The camera for `frames` over a map whose nodes span `map_box` (min, max) \[m\]; `None`
    /// without a map (origin-centred at 4 px/m unless a scale is given).
    pub fn new(frames: &FrameOutput, map_box: Option<(DVec2, DVec2)>) -> Result<Camera, RenderError> {
        let (width, height) = (frames.width, frames.height);
        let whole = match map_box {
            Some((min, max)) => BirdseyeView::fit(width, height, min, max, 0.05 * (max - min).max_element())?,
            None => BirdseyeView::centered_on_origin(width, height, 4.0)?,
        };
        let mode = match (frames.follow, frames.pixels_per_meter) {
            (Some(id), ppm) => {
                Mode::Follow { id, ppm: ppm.unwrap_or(whole.pixels_per_meter.max(FOLLOW_PPM)), last: whole.center }
            }
            (None, Some(ppm)) => {
                Mode::Fixed(BirdseyeView::new(width, height, ppm, frames.center.unwrap_or(whole.center))?)
            }
            (None, None) if map_box.is_some() => Mode::Auto { map: whole, chosen: None },
            (None, None) => Mode::Fixed(whole),
        };
        if let Mode::Follow { ppm, .. } = mode {
            BirdseyeView::new(width, height, ppm, DVec2::ZERO)?;
        }
        Ok(Camera { width, height, mode })
    }

    /// The same camera for another image size \[px\] (a resized window); a fixed view keeps its
    /// scale and centre.
    pub fn resized(&self, width: u32, height: u32) -> Result<Camera, RenderError> {
        let resize = |v: &BirdseyeView| BirdseyeView::new(width, height, v.pixels_per_meter, v.center);
        let mode = match &self.mode {
            Mode::Fixed(v) => Mode::Fixed(resize(v)?),
            Mode::Auto { map, chosen } => Mode::Auto {
                map: resize(map)?,
                chosen: match chosen {
                    Some(Auto::Fixed(v)) => Some(Auto::Fixed(resize(v)?)),
                    other => *other,
                },
            },
            Mode::Follow { .. } => self.mode,
        };
        Ok(Camera { width, height, mode })
    }

    /// Image width and height \[px\].
    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// The vehicle the camera follows, if any.
    pub fn follows(&self) -> Option<i32> {
        match self.mode {
            Mode::Follow { id, .. } => Some(id),
            _ => None,
        }
    }

    /// The view of a frame that shows `sprites`.
    pub fn view(&mut self, sprites: &[VehicleSprite]) -> Result<BirdseyeView, RenderError> {
        let (width, height) = (self.width, self.height);
        match &mut self.mode {
            Mode::Fixed(v) => Ok(*v),
            Mode::Follow { id, ppm, last } => {
                // The vehicle's own (logged or interpolated) position: it sits on the centre
                // pixel exactly, with no lag, and the ground slides under it as smoothly as
                // the vehicle moves.
                if let Some(s) = sprites.iter().find(|s| s.id == *id && s.position.is_finite()) {
                    *last = s.position;
                }
                BirdseyeView::new(width, height, *ppm, *last)
            }
            Mode::Auto { map, chosen } => {
                let mut points = sprites.iter().map(|s| s.position).filter(|p| p.is_finite());
                match chosen {
                    Some(Auto::Fixed(v)) => return Ok(*v),
                    Some(Auto::Traffic { ppm, center }) => {
                        let (sum, n) = points.fold((DVec2::ZERO, 0.0), |(s, n), p| (s + p, n + 1.0));
                        let mean = if n > 0.0 { sum / n } else { center.unwrap_or(map.center) };
                        // Within the whole map's window: a road a little longer than the view
                        // hardly moves; entering and leaving vehicles do not swing it about.
                        let size = DVec2::new(f64::from(width), f64::from(height));
                        let room = (0.5 * size / map.pixels_per_meter - 0.5 * size / *ppm).max(DVec2::ZERO);
                        let wanted = mean.clamp(map.center - room, map.center + room);
                        let moved = center.is_none_or(|c| {
                            let off = (wanted - c).abs();
                            off.x > 0.25 * size.x / *ppm || off.y > 0.25 * size.y / *ppm
                        });
                        if moved {
                            *center = Some(wanted);
                        }
                        return BirdseyeView::new(width, height, *ppm, center.unwrap_or(wanted));
                    }
                    None => {}
                }
                if points.next().is_none() {
                    return Ok(*map);
                }
                let shortest = sprites
                    .iter()
                    .map(|s| s.length)
                    .filter(|l| l.is_finite() && *l > 0.0)
                    .fold(f64::INFINITY, f64::min);
                let needed = (MIN_VEHICLE_PX / shortest).max(MIN_AUTO_FIT_PPM);
                if map.pixels_per_meter >= needed {
                    *chosen = Some(Auto::Fixed(*map));
                    return Ok(*map);
                }
                tracing::info!(
                    "the whole map would be drawn at {:.2} px/m, vehicles under {MIN_VEHICLE_PX} px long: following the \
                     traffic (the vehicles' mean position, within the map) at {needed:.2} px/m; give \
                     --pixels-per-meter and --center, or --follow ID, to choose the window",
                    map.pixels_per_meter
                );
                *chosen = Some(Auto::Traffic { ppm: needed, center: None });
                self.view(sprites)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sprite(id: i32, x: f64, y: f64) -> VehicleSprite {
        VehicleSprite::new(id, DVec2::new(x, y), 0.0, 4.0, 1.8, "Car")
    }

    #[test]
    fn follow_centres_the_vehicle_and_keeps_its_last_place_when_it_is_gone() {
        let frames = FrameOutput { follow: Some(-3), pixels_per_meter: Some(8.0), ..FrameOutput::default() };
        let mut cam =
            Camera::new(&frames, Some((DVec2::ZERO, DVec2::splat(100.0)))).expect("a camera over a 100 m map");
        let v = cam.view(&[sprite(1, 0.0, 0.0), sprite(-3, 40.0, 12.5)]).expect("a view of the sprites");
        assert_eq!((v.pixels_per_meter, v.center), (8.0, DVec2::new(40.0, 12.5)));
        assert_eq!(v.world_to_pixel(DVec2::new(40.0, 12.5)), DVec2::new(640.0, 360.0));
        let v = cam.view(&[sprite(1, 0.0, 0.0)]).expect("a view of the sprites");
        assert_eq!(v.center, DVec2::new(40.0, 12.5));
    }

    #[test]
    fn a_map_too_big_to_read_frames_the_vehicles() {
        // 20 km wide in 640 px: 0.03 px/m.
        let map = Some((DVec2::ZERO, DVec2::new(20_000.0, 100.0)));
        let frames = FrameOutput { width: 640, height: 360, ..FrameOutput::default() };
        let mut cam = Camera::new(&frames, map).expect("a camera over the map");
        let v = cam.view(&[sprite(1, 5000.0, 50.0), sprite(2, 5100.0, 50.0)]).expect("a view of the sprites");
        assert!(v.pixels_per_meter >= MIN_AUTO_FIT_PPM, "{v:?}");
        for x in [5000.0, 5100.0] {
            let p = v.world_to_pixel(DVec2::new(x, 50.0));
            assert!(p.x > 0.0 && p.x < 640.0 && p.y > 0.0 && p.y < 360.0, "{p}");
        }
        // The view follows the traffic afterwards, at the same scale.
        let later = cam.view(&[sprite(1, 9000.0, 50.0)]).expect("a view of the sprites");
        assert_eq!((later.pixels_per_meter, later.center.x), (v.pixels_per_meter, 9000.0));
        // A small map is fitted whole as before.
        let mut small =
            Camera::new(&frames, Some((DVec2::ZERO, DVec2::splat(100.0)))).expect("a camera over a 100 m map");
        assert!(small.view(&[sprite(1, 5.0, 5.0)]).expect("a view of the sprites").pixels_per_meter > 3.0);
    }

    /// Issue 61: a 500 m road fitted into 640 px drew 4.5 m cars under 6 px long. The default
    /// view follows the traffic at 6 px per car, within the map's window.
    #[test]
    fn the_default_view_draws_every_vehicle_at_least_6_px_long() {
        let road = Some((DVec2::ZERO, DVec2::new(2000.0, 7.0)));
        let frames = FrameOutput { width: 640, height: 360, ..FrameOutput::default() };
        let car = |id, x| VehicleSprite::new(id, DVec2::new(x, 3.5), 0.0, 4.5, 1.8, "Car");
        let mut cam = Camera::new(&frames, road).unwrap();
        let near: Vec<VehicleSprite> = (0..10).map(|k| car(-k - 1, 800.0 + 10.0 * k as f64)).collect();
        let v = cam.view(&near).unwrap();
        assert!((v.pixels_per_meter * 4.5 - MIN_VEHICLE_PX).abs() < 1e-9, "{v:?}");
        assert!((v.center.x - 845.0).abs() < 1e-9, "centred on the cars' mean: {v:?}");
        for s in &near {
            let p = v.world_to_pixel(s.position);
            assert!(p.x > 0.0 && p.x < 640.0, "{p}");
        }
        // Within the middle half of the window the view stays; past it, it re-centres.
        let window = 640.0 / v.pixels_per_meter;
        let stay = cam.view(&[car(-1, 845.0 + 0.2 * window)]).unwrap();
        assert_eq!(stay, v, "a small move keeps the view");
        let later = cam.view(&[car(-1, 1000.0), car(-2, 1100.0)]).unwrap();
        assert!((later.center.x - 1050.0).abs() < 1e-9, "the view follows the traffic: {later:?}");
        // Near the end of the road the window stays on the map.
        let end = cam.view(&[car(-1, 1990.0)]).unwrap();
        let right = end.pixel_to_world(DVec2::new(640.0, 180.0)).x;
        assert!(end.center.x < 1990.0 && right <= 2000.0 + 0.15 * 2000.0, "{end:?} {right}");
        // A map that draws them big enough is shown whole, as before.
        let mut small = Camera::new(&frames, Some((DVec2::ZERO, DVec2::new(100.0, 50.0)))).unwrap();
        let whole = small.view(&near[..1]).unwrap();
        assert!(whole.pixels_per_meter > 3.0 && (whole.center - DVec2::new(50.0, 25.0)).length() < 1e-9, "{whole:?}");
    }
}

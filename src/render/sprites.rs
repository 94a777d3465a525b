//! What a frame draws on top of the environment: vehicles, their ids and sensor overlays.

use std::sync::Arc;

use glam::DVec2;

use super::environment::{GroundVertex, LineStyle, Tessellator};
use super::font;
use super::view::BirdseyeView;

/// A radar cone in front of a vehicle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RadarCone {
    /// Range [m].
    pub range: f64,
    /// Full opening angle [rad], centred on the vehicle's heading.
    pub angle: f64,
}

/// Optional overlays drawn with a vehicle.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Overlays {
    /// Radar cone.
    pub radar: Option<RadarCone>,
    /// 360° "velodyne" range [m].
    pub velodyne: Option<f64>,
    /// Wifi (short-range V2V) range [m].
    pub wifi: Option<f64>,
    /// The vehicle's route [m]; shared, so building sprites every frame copies nothing.
    pub route: Option<Arc<[DVec2]>>,
}

/// One vehicle as the renderer sees it (plain data, no ECS).
#[derive(Debug, Clone, PartialEq)]
pub struct VehicleSprite {
    /// Vehicle id: >= 0 real (drawn solid with a dark outline), < 0 virtual (hatched, light outline).
    pub id: i32,
    /// Centre of the body [m].
    pub position: DVec2,
    /// Heading [rad], counter-clockwise from east.
    pub yaw: f64,
    /// Body length [m].
    pub length: f64,
    /// Body width [m].
    pub width: f64,
    /// Class name (`Truck`, `Car`, `Bus`, ...): picks the colour.
    pub class: String,
    /// Sensor ranges and route to draw.
    pub overlays: Overlays,
}

impl VehicleSprite {
    /// A sprite without overlays.
    pub fn new(id: i32, position: DVec2, yaw: f64, length: f64, width: f64, class: &str) -> VehicleSprite {
        VehicleSprite { id, position, yaw, length, width, class: class.to_string(), overlays: Overlays::default() }
    }
}

/// Body colour of a vehicle class (sRGB): fixed for the classes of the 2015 tool, else a stable
/// pick from a palette by the class name.
pub fn class_color(class: &str) -> [u8; 4] {
    const PALETTE: [[u8; 4]; 8] = [
        [232, 64, 58, 255],
        [64, 160, 232, 255],
        [160, 96, 220, 255],
        [240, 200, 40, 255],
        [60, 200, 160, 255],
        [240, 130, 180, 255],
        [140, 200, 60, 255],
        [200, 200, 210, 255],
    ];
    // Case-insensitive without allocating: this runs for every vehicle in every frame.
    let is = |name: &str| class.eq_ignore_ascii_case(name);
    if is("truck") {
        [242, 128, 24, 255]
    } else if is("car") {
        [40, 116, 230, 255]
    } else if is("bus") {
        [214, 40, 40, 255]
    } else if is("bicycle") || is("bike") {
        [60, 180, 75, 255]
    } else {
        // FNV-1a: stable across runs and platforms.
        let h = class.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| (h ^ u64::from(b)).wrapping_mul(0x100_0000_01b3));
        PALETTE[(h % PALETTE.len() as u64) as usize]
    }
}

/// Overlay colours (sRGB with alpha).
const RADAR_COLOR: [u8; 4] = [255, 70, 60, 70];
const VELODYNE_COLOR: [u8; 4] = [80, 200, 255, 55];
const WIFI_COLOR: [u8; 4] = [170, 120, 255, 40];

/// Instance of the vehicle pipeline.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct VehicleInstance {
    /// Centre relative to the view centre [m].
    pub pos: [f32; 2],
    /// Heading as (cos, sin).
    pub dir: [f32; 2],
    /// Length and width [m].
    pub size: [f32; 2],
    /// sRGB colour.
    pub color: [u8; 4],
    /// 1 = real vehicle, 0 = virtual.
    pub real: u32,
}

/// Instance of the overlay pipeline: a disc sector around a vehicle.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct SectorInstance {
    /// Centre relative to the view centre [m].
    pub pos: [f32; 2],
    /// Heading as (cos, sin).
    pub dir: [f32; 2],
    /// Range [m].
    pub range: f32,
    /// Half opening angle [rad]; π for a full circle.
    pub half_angle: f32,
    /// sRGB colour with alpha.
    pub color: [u8; 4],
}

/// Instance of the text pipeline: a glyph (or a label's backing box) in pixels next to an anchor.
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct GlyphInstance {
    /// Anchor relative to the view centre [m].
    pub anchor: [f32; 2],
    /// Top-left corner relative to the anchor's pixel [px], y down.
    pub offset: [f32; 2],
    /// Size [px].
    pub size: [f32; 2],
    /// Glyph index in the atlas; [`BOX_GLYPH`] for the backing box.
    pub glyph: u32,
    /// sRGB colour with alpha.
    pub color: [u8; 4],
}

/// Glyph value of a label's backing box.
pub(crate) const BOX_GLYPH: u32 = u32::MAX;
/// Screen pixels per font pixel: 5x7 glyphs become 10x14 px.
pub(crate) const TEXT_SCALE: f32 = 2.0;

/// Per-frame instance lists, reused between frames so steady-state frames allocate nothing.
#[derive(Debug, Default)]
pub(crate) struct FrameBatches {
    pub vehicles: Vec<VehicleInstance>,
    pub sectors: Vec<SectorInstance>,
    pub glyphs: Vec<GlyphInstance>,
    pub routes: Vec<GroundVertex>,
}

impl FrameBatches {
    /// Fill the lists for `sprites` seen through `view`. Sprites with non-finite poses or sizes are
    /// skipped (and counted in the return value) rather than drawn somewhere random.
    pub fn build(&mut self, view: &BirdseyeView, sprites: &[VehicleSprite]) -> usize {
        self.vehicles.clear();
        self.sectors.clear();
        self.glyphs.clear();
        self.routes.clear();
        let mut skipped = 0;
        let mut digits = [0u32; 12];
        for s in sprites {
            let finite = [s.position.x, s.position.y, s.yaw, s.length, s.width].iter().all(|v| v.is_finite());
            if !finite || s.length <= 0.0 || s.width <= 0.0 {
                skipped += 1;
                continue;
            }
            let rel = s.position - view.center;
            let pos = [rel.x as f32, rel.y as f32];
            let dir = [s.yaw.cos() as f32, s.yaw.sin() as f32];
            let color = class_color(&s.class);
            if let Some(route) = &s.overlays.route {
                let mut c = color;
                c[3] = 150;
                let style = LineStyle { color: c, width: 0.35, dash: None };
                Tessellator { view, out: &mut self.routes }.polyline(route, &style);
            }
            let mut sector = |range: Option<f64>, half: f64, color: [u8; 4]| {
                if let Some(r) = range.filter(|r| r.is_finite() && *r > 0.0) {
                    self.sectors.push(SectorInstance { pos, dir, range: r as f32, half_angle: half as f32, color });
                }
            };
            sector(s.overlays.wifi, std::f64::consts::PI, WIFI_COLOR);
            sector(s.overlays.velodyne, std::f64::consts::PI, VELODYNE_COLOR);
            if let Some(radar) = s.overlays.radar {
                let half = (0.5 * radar.angle).clamp(0.0, std::f64::consts::PI);
                sector(Some(radar.range), half, RADAR_COLOR);
            }
            self.vehicles.push(VehicleInstance {
                pos,
                dir,
                size: [s.length as f32, s.width as f32],
                color,
                real: u32::from(s.id >= 0),
            });
            // The id, centred above the vehicle's screen footprint.
            let n = format_id(s.id, &mut digits);
            let advance = (font::GLYPH_W + 1) as f32 * TEXT_SCALE;
            let text_w = n as f32 * advance - TEXT_SCALE;
            let pad = TEXT_SCALE * 2.0;
            let reach_px = (0.5 * s.length.hypot(s.width) * view.pixels_per_meter.max(view.pixels_per_meter_y())) as f32;
            let box_h = font::GLYPH_H as f32 * TEXT_SCALE + 2.0 * pad;
            let top = -(reach_px + 4.0 + box_h);
            let left = -(0.5 * text_w + pad).round();
            let label_color = if s.id >= 0 { [20, 20, 24, 200] } else { [40, 40, 90, 200] };
            self.glyphs.push(GlyphInstance {
                anchor: pos,
                offset: [left, top.round()],
                size: [text_w + 2.0 * pad, box_h],
                glyph: BOX_GLYPH,
                color: label_color,
            });
            for (i, &g) in digits[..n].iter().enumerate() {
                self.glyphs.push(GlyphInstance {
                    anchor: pos,
                    offset: [left + pad + i as f32 * advance, top.round() + pad],
                    size: [font::GLYPH_W as f32 * TEXT_SCALE, font::GLYPH_H as f32 * TEXT_SCALE],
                    glyph: g,
                    color: [255, 255, 255, 255],
                });
            }
        }
        skipped
    }
}

/// Writes the glyph indices of `id`'s decimal text into `out`; returns how many.
fn format_id(id: i32, out: &mut [u32; 12]) -> usize {
    let mut n = 0;
    let mut v = i64::from(id).unsigned_abs();
    let mut rev = [0u32; 10];
    let mut k = 0;
    loop {
        rev[k] = (v % 10) as u32;
        k += 1;
        v /= 10;
        if v == 0 {
            break;
        }
    }
    if id < 0 {
        out[n] = font::MINUS_GLYPH;
        n += 1;
    }
    for d in rev[..k].iter().rev() {
        out[n] = *d;
        n += 1;
    }
    n
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_become_glyph_indices() {
        let mut d = [0u32; 12];
        let n = format_id(-107, &mut d);
        assert_eq!(&d[..n], &[10, 1, 0, 7]);
        let n = format_id(i32::MIN, &mut d);
        assert_eq!(n, 11);
        let n = format_id(0, &mut d);
        assert_eq!(&d[..n], &[0]);
    }

    #[test]
    fn class_colours_are_stable_and_distinct() {
        assert_ne!(class_color("Truck"), class_color("Car"));
        assert_eq!(class_color("Tractor"), class_color("Tractor"));
        assert_eq!(class_color("TRUCK"), class_color("truck"));
    }
}

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
    } else if is("emergency") {
        // White with a red/blue light bar across the roof (drawn by the shader, see `LIGHT_BAR`).
        [238, 238, 242, 255]
    } else {
        // FNV-1a: stable across runs and platforms.
        let h = class.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| (h ^ u64::from(b)).wrapping_mul(0x100_0000_01b3));
        PALETTE[(h % PALETTE.len() as u64) as usize]
    }
}

/// Flag in [`VehicleInstance::real`]: draw a light bar across the roof (red on the left half,
/// blue on the right), the mark of an emergency vehicle.
pub(crate) const LIGHT_BAR: u32 = 2;

/// Overlay fill colours (sRGB with the fill's alpha at the centre; the rim is drawn at 0.7).
const RADAR_COLOR: [u8; 4] = [255, 70, 60, 72];
const VELODYNE_COLOR: [u8; 4] = [80, 200, 255, 40];
const WIFI_COLOR: [u8; 4] = [170, 120, 255, 32];

/// One vehicle as the vehicle shader reads it (`Vehicle` in shaders.wgsl).
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
    /// Bit 0: 1 = real vehicle, 0 = virtual; bit 1: [`LIGHT_BAR`].
    pub real: u32,
}

/// A disc sector around a vehicle as the sector shader reads it (`Sector` in shaders.wgsl).
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
    /// Padding to the 8-byte alignment of the shader's struct.
    pub pad: u32,
}

/// One vehicle id in a backing box, in pixels next to an anchor (`Label` in shaders.wgsl).
#[repr(C)]
#[derive(Debug, Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct LabelInstance {
    /// Anchor relative to the view centre [m].
    pub anchor: [f32; 2],
    /// Top-left corner of the box relative to the anchor's pixel [px], y down.
    pub offset: [f32; 2],
    /// Glyph indices, 4 bits each, 8 per word, first character in the lowest bits.
    pub glyphs: [u32; 2],
    /// Number of characters (at most 11: `-2147483648`).
    pub count: u32,
    /// Box colour, sRGB with alpha.
    pub color: [u8; 4],
}

/// Screen pixels per font pixel: 5x7 glyphs become 10x14 px (`TEXT_SCALE` in shaders.wgsl).
pub(crate) const TEXT_SCALE: f32 = 2.0;
/// Padding around a label's text [font px] (`LABEL_PAD` in shaders.wgsl).
pub(crate) const LABEL_PAD: f32 = 1.0;

/// Side of a cell of the label occupancy grid [px].
const LABEL_CELL: u32 = 8;

/// Which cells of the image are covered by a label already (one bit per 8x8 px cell).
#[derive(Debug, Default)]
struct LabelGrid {
    cols: u32,
    rows: u32,
    bits: Vec<u64>,
}

impl LabelGrid {
    fn reset(&mut self, width: u32, height: u32) {
        self.cols = width.div_ceil(LABEL_CELL);
        self.rows = height.div_ceil(LABEL_CELL);
        self.bits.clear();
        self.bits.resize((self.cols * self.rows).div_ceil(64) as usize, 0);
    }

    /// Claim the cells under the box `x0..x1`, `y0..y1` [px] unless one is taken; `false` if
    /// the box overlaps an earlier label. Parts outside the image are free.
    fn claim(&mut self, x0: f32, y0: f32, x1: f32, y1: f32) -> bool {
        let (w, h) = ((self.cols * LABEL_CELL) as f32, (self.rows * LABEL_CELL) as f32);
        if x1 <= 0.0 || y1 <= 0.0 || x0 >= w || y0 >= h {
            return true;
        }
        let cell = |v: f32, n: u32| ((v / LABEL_CELL as f32).floor().max(0.0) as u32).min(n);
        let (c0, c1) = (cell(x0, self.cols), cell(x1, self.cols.saturating_sub(1)) + 1);
        let (r0, r1) = (cell(y0, self.rows), cell(y1, self.rows.saturating_sub(1)) + 1);
        let (cols, rows) = (self.cols, self.rows);
        let cells =
            move || (r0..r1.min(rows)).flat_map(move |r| (c0..c1.min(cols)).map(move |c| (r * cols + c) as usize));
        if cells().any(|i| self.bits[i / 64] & (1 << (i % 64)) != 0) {
            return false;
        }
        for i in cells() {
            self.bits[i / 64] |= 1 << (i % 64);
        }
        true
    }
}

/// Per-frame instance lists, reused between frames so steady-state frames allocate nothing.
#[derive(Debug, Default)]
pub(crate) struct FrameBatches {
    pub vehicles: Vec<VehicleInstance>,
    pub sectors: Vec<SectorInstance>,
    pub labels: Vec<LabelInstance>,
    pub routes: Vec<GroundVertex>,
    grid: LabelGrid,
}

impl FrameBatches {
    /// Fill the lists for `sprites` seen through `view`. Sprites with non-finite poses or sizes are
    /// skipped (and counted in the return value) rather than drawn somewhere random. An id label
    /// that would overlap an earlier sprite's label is left out (an unreadable pile of labels
    /// costs most of a crowded frame), so list the vehicles whose ids matter most first.
    pub fn build(&mut self, view: &BirdseyeView, sprites: &[VehicleSprite]) -> usize {
        self.vehicles.clear();
        self.sectors.clear();
        self.labels.clear();
        self.routes.clear();
        self.grid.reset(view.width, view.height);
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
                    self.sectors.push(SectorInstance {
                        pos,
                        dir,
                        range: r as f32,
                        half_angle: half as f32,
                        color,
                        pad: 0,
                    });
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
                real: u32::from(s.id >= 0) | if s.class.eq_ignore_ascii_case("emergency") { LIGHT_BAR } else { 0 },
            });
            // The id, centred above the vehicle's screen footprint.
            let n = format_id(s.id, &mut digits);
            let mut glyphs = [0u32; 2];
            for (i, &g) in digits[..n].iter().enumerate() {
                glyphs[i / 8] |= g << (4 * (i % 8));
            }
            let box_w = ((n * (font::GLYPH_W as usize + 1)) as f32 - 1.0 + 2.0 * LABEL_PAD) * TEXT_SCALE;
            let box_h = (font::GLYPH_H as f32 + 2.0 * LABEL_PAD) * TEXT_SCALE;
            let reach_px =
                (0.5 * s.length.hypot(s.width) * view.pixels_per_meter.max(view.pixels_per_meter_y())) as f32;
            let offset = [-(0.5 * box_w).round(), -(reach_px + 3.0 + box_h).round()];
            let at = view.world_to_pixel(s.position);
            let (x0, y0) = (at.x.floor() as f32 + offset[0], at.y.floor() as f32 + offset[1]);
            if self.grid.claim(x0, y0, x0 + box_w, y0 + box_h) {
                self.labels.push(LabelInstance {
                    anchor: pos,
                    offset,
                    glyphs,
                    count: n as u32,
                    color: if s.id >= 0 { [20, 20, 24, 210] } else { [36, 36, 100, 210] },
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
    fn overlapping_labels_are_left_out_and_separate_ones_kept() {
        let mut g = LabelGrid::default();
        g.reset(100, 50);
        assert!(g.claim(0.0, 0.0, 30.0, 10.0));
        assert!(!g.claim(20.0, 5.0, 50.0, 15.0), "overlaps the first");
        assert!(g.claim(40.0, 0.0, 60.0, 10.0), "separate");
        // Partly or wholly outside the image is allowed.
        assert!(g.claim(-30.0, 30.0, 5.0, 40.0));
        assert!(g.claim(500.0, 500.0, 600.0, 520.0));
        assert!(g.claim(90.0, 45.0, 120.0, 60.0));
        assert!(g.claim(-30.0, -30.0, -1.0, -1.0));
        assert!(g.claim(0.0, 0.0, 4.0, 4.0) == false, "the first label still holds cell (0, 0)");
    }

    #[test]
    fn only_emergency_vehicles_carry_a_light_bar() {
        let view = BirdseyeView::new(200, 100, 10.0, DVec2::ZERO).unwrap();
        let sprites = [
            VehicleSprite::new(-1, DVec2::ZERO, 0.0, 5.5, 2.0, "Emergency"),
            VehicleSprite::new(2, DVec2::new(8.0, 0.0), 0.0, 4.0, 1.7, "Car"),
        ];
        let mut batches = FrameBatches::default();
        batches.build(&view, &sprites);
        assert_eq!(batches.vehicles[0].real, LIGHT_BAR, "virtual emergency vehicle: light bar, not real");
        assert_eq!(batches.vehicles[1].real, 1, "real car: no light bar");
        assert_ne!(class_color("Emergency"), class_color("Car"));
    }

    #[test]
    fn class_colours_are_stable_and_distinct() {
        assert_ne!(class_color("Truck"), class_color("Car"));
        assert_eq!(class_color("Tractor"), class_color("Tractor"));
        assert_eq!(class_color("TRUCK"), class_color("truck"));
    }
}

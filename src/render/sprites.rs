//! What a frame draws on top of the environment: vehicles, their ids and sensor overlays.

use std::sync::Arc;

use glam::DVec2;

use crate::world::TurnSignal;

use super::environment::{GroundVertex, LineStyle, Tessellator};
use super::font;
use super::view::BirdseyeView;

/// A radar cone in front of a vehicle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RadarCone {
    /// Range \[m\].
    pub range: f64,
    /// Full opening angle \[rad\], centred on the vehicle's heading.
    pub angle: f64,
}

/// Optional overlays drawn with a vehicle.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Overlays {
    /// Radar cone.
    pub radar: Option<RadarCone>,
    /// 360° "velodyne" range \[m\].
    pub velodyne: Option<f64>,
    /// Wifi (short-range V2V) range \[m\].
    pub wifi: Option<f64>,
    /// The vehicle's route \[m\]; shared, so building sprites every frame copies nothing.
    pub route: Option<Arc<[DVec2]>>,
    /// A lane change in progress: the indicator on that side (amber front and rear corners).
    pub indicator: TurnSignal,
}

/// One vehicle as the renderer sees it (plain data, no ECS).
#[derive(Debug, Clone, PartialEq)]
pub struct VehicleSprite {
    /// Vehicle id (the label).
    pub id: i32,
    /// Whether its state comes from the lab (motion capture, a real truck): drawn solid with a
    /// dark outline; otherwise virtual, hatched with a light outline. [`VehicleSprite::new`]
    /// makes it virtual; the id's sign says nothing.
    pub real: bool,
    /// Centre of the body \[m\].
    pub position: DVec2,
    /// Heading \[rad\], counter-clockwise from east.
    pub yaw: f64,
    /// Body length \[m\].
    pub length: f64,
    /// Body width \[m\].
    pub width: f64,
    /// Class name (`Truck`, `Car`, `Bus`, ...): picks the colour.
    pub class: String,
    /// Sensor ranges and route to draw.
    pub overlays: Overlays,
}

impl VehicleSprite {
    /// A sprite without overlays.
    pub fn new(id: i32, position: DVec2, yaw: f64, length: f64, width: f64, class: &str) -> VehicleSprite {
        VehicleSprite {
            id,
            position,
            yaw,
            length,
            width,
            real: false,
            class: class.to_string(),
            overlays: Overlays::default(),
        }
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

/// Colour of vehicle `id` wherever one colour per vehicle is drawn (its id label in the view,
/// its curves in `smlworld plot`): twelve hues dark enough to read on white and under white
/// text, so ids `n` and `n + 1` always differ.
pub fn vehicle_color(id: i32) -> [u8; 4] {
    const PALETTE: [[u8; 4]; 12] = [
        [31, 119, 180, 255],
        [214, 39, 40, 255],
        [44, 140, 44, 255],
        [148, 83, 189, 255],
        [220, 105, 0, 255],
        [140, 86, 75, 255],
        [200, 40, 150, 255],
        [90, 90, 90, 255],
        [120, 120, 0, 255],
        [0, 128, 128, 255],
        [20, 40, 140, 255],
        [160, 30, 80, 255],
    ];
    PALETTE[id.rem_euclid(PALETTE.len() as i32) as usize]
}

/// Flag in [`VehicleInstance::real`]: draw a light bar across the roof (red on the left half,
/// blue on the right), the mark of an emergency vehicle.
pub(crate) const LIGHT_BAR: u32 = 2;
/// Flags in [`VehicleInstance::real`]: amber indicator lights at the front and rear corners of
/// the left (4) or right (8) side.
pub(crate) const LEFT_INDICATOR: u32 = 4;
/// See [`LEFT_INDICATOR`].
pub(crate) const RIGHT_INDICATOR: u32 = 8;

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
    /// Bit 0: 1 = real vehicle, 0 = virtual; bit 1: [`LIGHT_BAR`]; bits 2, 3: indicators.
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
    /// Outline colour around the white glyphs ([`vehicle_color`]), sRGB with alpha.
    pub color: [u8; 4],
    /// Screen pixels per font pixel ([`text_scale`]).
    pub scale: f32,
    /// Padding to the 8-byte alignment of the shader's struct.
    pub pad: u32,
}

/// Screen pixels per font pixel for an image of `width` x `height` px: the 5x7 glyphs become
/// 10x14 px on images 600 px high or more, 5x7 px (with a 1 px outline) on smaller ones, so the
/// labels of a 640x360 frame stay small beside their vehicles.
pub(crate) fn text_scale(width: u32, height: u32) -> f32 {
    if width.min(height) >= 600 { 2.0 } else { 1.0 }
}
/// Padding around a label's text, where its outline goes [font px] (`LABEL_PAD` in shaders.wgsl).
pub(crate) const LABEL_PAD: f32 = 1.0;
/// Gap between a vehicle's footprint and its label [px].
const LABEL_GAP: f32 = 2.0;

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
    /// Vehicles in view: squared distance from the image centre [px²], id, index in the sprites.
    order: Vec<(f32, i32, usize)>,
    /// The labels placed: id and box [px].
    placed: Vec<(i32, [f32; 4])>,
}

impl FrameBatches {
    /// Fill the lists for `sprites` seen through `view`. Sprites with non-finite poses or sizes are
    /// skipped (and counted in the return value) rather than drawn somewhere random. Every
    /// vehicle in view gets its id beside it (right, left, above or below, the first place
    /// free, kept inside the image); labels go nearest the image centre (the camera) first, and
    /// a label is left out only when all its places overlap labels placed before it.
    pub fn build(&mut self, view: &BirdseyeView, sprites: &[VehicleSprite]) -> usize {
        self.vehicles.clear();
        self.sectors.clear();
        self.labels.clear();
        self.routes.clear();
        self.grid.reset(view.width, view.height);
        self.order.clear();
        self.placed.clear();
        let mut skipped = 0;
        let (w, h) = (view.width as f32, view.height as f32);
        for (k, s) in sprites.iter().enumerate() {
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
            let indicator = match s.overlays.indicator {
                TurnSignal::Left => LEFT_INDICATOR,
                TurnSignal::Right => RIGHT_INDICATOR,
                TurnSignal::Off => 0,
            };
            self.vehicles.push(VehicleInstance {
                pos,
                dir,
                size: [s.length as f32, s.width as f32],
                color,
                real: u32::from(s.real)
                    | if s.class.eq_ignore_ascii_case("emergency") { LIGHT_BAR } else { 0 }
                    | indicator,
            });
            let at = view.world_to_pixel(s.position);
            let (x, y) = (at.x as f32, at.y as f32);
            if x >= 0.0 && y >= 0.0 && x < w && y < h {
                let (dx, dy) = (x - 0.5 * w, y - 0.5 * h);
                self.order.push((dx * dx + dy * dy, s.id, k));
            }
        }
        self.order.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let scale = text_scale(view.width, view.height);
        let mut digits = [0u32; 12];
        for &(_, _, k) in &self.order {
            let s = &sprites[k];
            let n = format_id(s.id, &mut digits);
            let mut glyphs = [0u32; 2];
            for (i, &g) in digits[..n].iter().enumerate() {
                glyphs[i / 8] |= g << (4 * (i % 8));
            }
            let (box_w, box_h) = label_size(n, scale);
            // Half the screen extent of the rotated body [px]; vehicles are drawn at least 4 px
            // long and wide (shaders.wgsl), so never less than 2.
            let (c, sn) = (s.yaw.cos().abs(), s.yaw.sin().abs());
            let ex = (0.5 * (s.length * c + s.width * sn) * view.pixels_per_meter).max(2.0) as f32 + LABEL_GAP;
            let ey = (0.5 * (s.length * sn + s.width * c) * view.pixels_per_meter_y()).max(2.0) as f32 + LABEL_GAP;
            let at = view.world_to_pixel(s.position);
            let (ax, ay) = (at.x.floor() as f32, at.y.floor() as f32);
            let places =
                [(ex, -0.5 * box_h), (-ex - box_w, -0.5 * box_h), (-0.5 * box_w, -ey - box_h), (-0.5 * box_w, ey)];
            for (ox, oy) in places {
                let x0 = (ax + ox).round().clamp(0.0, (w - box_w).max(0.0));
                let y0 = (ay + oy).round().clamp(0.0, (h - box_h).max(0.0));
                if self.grid.claim(x0, y0, x0 + box_w, y0 + box_h) {
                    self.labels.push(LabelInstance {
                        anchor: [(s.position.x - view.center.x) as f32, (s.position.y - view.center.y) as f32],
                        offset: [x0 - ax, y0 - ay],
                        glyphs,
                        count: n as u32,
                        color: vehicle_color(s.id),
                        scale,
                        pad: 0,
                    });
                    self.placed.push((s.id, [x0, y0, x0 + box_w, y0 + box_h]));
                    break;
                }
            }
        }
        skipped
    }
}

/// Width and height [px] of the label of an `n`-character id at `scale` screen px per font px.
fn label_size(n: usize, scale: f32) -> (f32, f32) {
    (
        ((n * (font::GLYPH_W as usize + 1)) as f32 - 1.0 + 2.0 * LABEL_PAD) * scale,
        (font::GLYPH_H as f32 + 2.0 * LABEL_PAD) * scale,
    )
}

/// Where the id labels of `sprites` go in `view`: (id, [x0, y0, x1, y1] \[px\]) for every label
/// drawn, in the order they were placed (see `FrameBatches::build`); vehicles out of view
/// and labels left out for overlapping have none.
pub fn label_boxes(view: &BirdseyeView, sprites: &[VehicleSprite]) -> Vec<(i32, [f32; 4])> {
    let mut batches = FrameBatches::default();
    batches.build(view, sprites);
    batches.placed
}

/// The pairs of `sprites` whose footprints (oriented rectangles) overlap: lower id, higher id
/// and the midpoint of their centres \[m\], sorted by the ids. For a live view, which gets no
/// collision events: a pair that starts to overlap has collided. A sweep along x: O(n log n)
/// plus the pairs close in x.
pub fn overlapping_pairs(sprites: &[VehicleSprite]) -> Vec<(i32, i32, DVec2)> {
    let corners = |s: &VehicleSprite| {
        let (f, l) = (DVec2::from_angle(s.yaw) * 0.5 * s.length, DVec2::from_angle(s.yaw).perp() * 0.5 * s.width);
        [s.position + f + l, s.position + f - l, s.position - f - l, s.position - f + l]
    };
    // Separating axis test on the four edge normals.
    let separated = |a: &VehicleSprite, b: &VehicleSprite| {
        let (ca, cb) = (corners(a), corners(b));
        [a.yaw, a.yaw + std::f64::consts::FRAC_PI_2, b.yaw, b.yaw + std::f64::consts::FRAC_PI_2].iter().any(|&ang| {
            let axis = DVec2::from_angle(ang);
            let span = |c: &[DVec2; 4]| {
                c.iter()
                    .map(|p| p.dot(axis))
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| (lo.min(v), hi.max(v)))
            };
            let ((a0, a1), (b0, b1)) = (span(&ca), span(&cb));
            a1 < b0 || b1 < a0
        })
    };
    let ok = |s: &VehicleSprite| {
        [s.position.x, s.position.y, s.yaw, s.length, s.width].iter().all(|v| v.is_finite())
            && s.length > 0.0
            && s.width > 0.0
    };
    // Swept along x: a pair is tested only when its centres are within the two largest half
    // diagonals of each other in x (a session's frame tests every vehicle of a town each call).
    let half = |s: &VehicleSprite| 0.5 * s.length.hypot(s.width);
    let mut order: Vec<&VehicleSprite> = sprites.iter().filter(|s| ok(s)).collect();
    order.sort_by(|a, b| a.position.x.total_cmp(&b.position.x));
    let widest = order.iter().map(|s| half(s)).fold(0.0, f64::max);
    let mut out = Vec::new();
    for (i, a) in order.iter().enumerate() {
        for b in order[i + 1..].iter().take_while(|b| b.position.x - a.position.x <= half(a) + widest) {
            let reach = half(a) + half(b);
            if a.position.distance(b.position) <= reach && !separated(a, b) {
                let (lo, hi) = if a.id < b.id { (a.id, b.id) } else { (b.id, a.id) };
                out.push((lo, hi, (a.position + b.position) * 0.5));
            }
        }
    }
    out.sort_by_key(|p| (p.0, p.1));
    out
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
        assert!(!g.claim(0.0, 0.0, 4.0, 4.0), "the first label still holds cell (0, 0)");
    }

    #[test]
    fn only_emergency_vehicles_carry_a_light_bar() {
        let view = BirdseyeView::new(200, 100, 10.0, DVec2::ZERO).expect("a valid view");
        let mut real_car = VehicleSprite::new(2, DVec2::new(8.0, 0.0), 0.0, 4.0, 1.7, "Car");
        real_car.real = true;
        let sprites = [VehicleSprite::new(-1, DVec2::ZERO, 0.0, 5.5, 2.0, "Emergency"), real_car];
        let mut batches = FrameBatches::default();
        batches.build(&view, &sprites);
        assert_eq!(batches.vehicles[0].real, LIGHT_BAR, "virtual emergency vehicle: light bar, not real");
        assert_eq!(batches.vehicles[1].real, 1, "real car: no light bar");
        // The id's sign says nothing: a vehicle of id >= 0 the lab does not drive is virtual.
        batches.build(&view, &[VehicleSprite::new(1000, DVec2::ZERO, 0.0, 4.0, 1.7, "Car")]);
        assert_eq!(batches.vehicles[0].real, 0, "traffic of a positive id is virtual");
        assert_ne!(class_color("Emergency"), class_color("Car"));
    }

    #[test]
    fn overlapping_footprints_pair_up_and_separate_ones_do_not() {
        let car = |id, x: f64, y: f64, yaw: f64| VehicleSprite::new(id, DVec2::new(x, y), yaw, 4.0, 2.0, "Car");
        // Rear bumper of 2 touches the front of 1; 3 is 1 m clear beside it, diagonal boxes
        // whose circles overlap but whose rectangles do not.
        let pairs = overlapping_pairs(&[car(1, 0.0, 0.0, 0.0), car(2, 3.9, 0.0, 0.0), car(3, 0.0, 3.0, 0.0)]);
        assert_eq!(pairs, vec![(1, 2, DVec2::new(1.95, 0.0))]);
        let d = std::f64::consts::FRAC_PI_4;
        assert!(overlapping_pairs(&[car(1, 0.0, 0.0, d), car(2, 2.9, -2.9, d)]).is_empty());
    }

    #[test]
    fn the_sweep_finds_the_pairs_every_pair_test_finds() {
        // 400 cars, trucks and buses scattered on 200 m x 20 m at any heading, checked against a
        // test of every pair (the sweep skips pairs far apart in x only).
        let mut w = crate::world::random::Words::new(7);
        let sprites: Vec<VehicleSprite> = (0..400)
            .map(|id| {
                let (length, width) = [(4.0, 1.8), (12.0, 2.5), (18.0, 2.55)][id as usize % 3];
                let at = DVec2::new(200.0 * w.uniform(), 20.0 * w.uniform());
                VehicleSprite::new(id, at, std::f64::consts::TAU * w.uniform(), length, width, "Car")
            })
            .collect();
        let mut every = Vec::new();
        for (i, a) in sprites.iter().enumerate() {
            for b in &sprites[i + 1..] {
                if !overlapping_pairs(&[a.clone(), b.clone()]).is_empty() {
                    every.push((a.id.min(b.id), a.id.max(b.id)));
                }
            }
        }
        let swept: Vec<(i32, i32)> = overlapping_pairs(&sprites).iter().map(|p| (p.0, p.1)).collect();
        assert!(every.len() > 20, "the scatter has overlaps to find: {}", every.len());
        assert_eq!(swept, every);
    }

    #[test]
    fn every_vehicle_in_view_gets_a_label_and_labels_never_overlap() {
        // A platoon at 640x360 px and 2 px/m: 8 m apart, 16 px, room for every label.
        let view = BirdseyeView::new(640, 360, 2.0, DVec2::ZERO).expect("a valid view");
        let sprites: Vec<VehicleSprite> = (0..8)
            .map(|i| VehicleSprite::new(-i - 1, DVec2::new(8.0 * f64::from(i) - 10.0, 0.0), 0.0, 2.0, 1.0, "Truck"))
            .chain([VehicleSprite::new(7, DVec2::new(5000.0, 0.0), 0.0, 4.0, 2.0, "Car")])
            .collect();
        let boxes = label_boxes(&view, &sprites);
        let mut ids: Vec<i32> = boxes.iter().map(|b| b.0).collect();
        ids.sort_unstable();
        assert_eq!(ids, (-8..=-1).collect::<Vec<_>>(), "all eight in view, not the one far away");
        for (i, (_, a)) in boxes.iter().enumerate() {
            assert!(a[0] >= 0.0 && a[1] >= 0.0 && a[2] <= 640.0 && a[3] <= 360.0, "{a:?} inside");
            for (_, b) in &boxes[i + 1..] {
                assert!(a[2] <= b[0] || b[2] <= a[0] || a[3] <= b[1] || b[3] <= a[1], "{a:?} overlaps {b:?}");
            }
        }
        // Nearest to the centre is placed first, right beside its vehicle.
        let first = boxes[0];
        assert_eq!(first.0, -2, "x = -2 m is nearest the centre");
        // x = 316 px, half its 4 px length + 2 px gap.
        assert_eq!(first.1[0], 320.0);
        // Packed tighter (3 m, 6 px apart) not all fit: those left out are the ones whose every
        // place overlaps a label nearer the centre, and the one at the centre keeps its own.
        let tight: Vec<VehicleSprite> = (0..8)
            .map(|i| VehicleSprite::new(-i - 1, DVec2::new(3.0 * f64::from(i) - 10.0, 0.0), 0.0, 2.0, 1.0, "Truck"))
            .collect();
        let boxes = label_boxes(&view, &tight);
        assert!(boxes.len() >= 3 && boxes[0].0 == -4, "{boxes:?}");
    }

    #[test]
    fn class_colours_are_stable_and_distinct() {
        assert_ne!(class_color("Truck"), class_color("Car"));
        assert_eq!(class_color("Tractor"), class_color("Tractor"));
        assert_eq!(class_color("TRUCK"), class_color("truck"));
    }
}

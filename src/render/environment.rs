//! The environment layer's geometry: roads, areas and painted lines in metres, and their tessellation.

use glam::DVec2;

use super::patterns::{PatternKind, PatternSet};
use super::triangulate::triangulate;
use super::view::BirdseyeView;
use crate::map::LaneletMap;

/// A road surface between a left and a right bound [m]; `left[k]` and `right[k]` are paired when
/// both have the same length (then it is drawn as a strip), else the polygon is triangulated.
#[derive(Debug, Clone, PartialEq)]
pub struct RoadStrip {
    /// Left bound [m], in driving direction.
    pub left: Vec<DVec2>,
    /// Right bound [m], in driving direction.
    pub right: Vec<DVec2>,
}

/// A closed area painted with a pattern (mud, iron, parking lot, free space).
#[derive(Debug, Clone, PartialEq)]
pub struct Area {
    /// Ground pattern inside the outline.
    pub pattern: PatternKind,
    /// Outline [m]; closing point optional; simple (non-self-intersecting), any orientation.
    pub outline: Vec<DVec2>,
}

/// How a painted line looks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LineStyle {
    /// Colour, sRGB with alpha.
    pub color: [u8; 4],
    /// Line width [m]; never drawn thinner than 1.5 px so it stays visible when zoomed out.
    pub width: f64,
    /// Dash period [m] (half painted, half gap); `None` for a solid line.
    pub dash: Option<f64>,
}

impl LineStyle {
    /// `line_type=exterior`: the road edge, solid yellow.
    pub const EXTERIOR: LineStyle = LineStyle { color: [236, 190, 40, 255], width: 0.3, dash: None };
    /// `line_type=interior`: between lanes, white and dashed (3 m paint, 3 m gap).
    pub const INTERIOR: LineStyle = LineStyle { color: [242, 242, 236, 255], width: 0.2, dash: Some(6.0) };

    /// The style of a way's `line_type` value; `None` (no line) for anything else.
    pub fn for_line_type(value: &str) -> Option<LineStyle> {
        match value {
            "exterior" => Some(LineStyle::EXTERIOR),
            "interior" => Some(LineStyle::INTERIOR),
            _ => None,
        }
    }
}

/// A painted polyline.
#[derive(Debug, Clone, PartialEq)]
pub struct Line {
    /// How it is painted.
    pub style: LineStyle,
    /// Points [m] in order.
    pub points: Vec<DVec2>,
}

/// Everything the environment layer draws, in metres, independent of how it was loaded.
#[derive(Debug, Clone, PartialEq)]
pub struct Environment {
    /// Pattern tiled over the whole image under everything else.
    pub background: PatternKind,
    /// Areas, drawn in order over the background.
    pub areas: Vec<Area>,
    /// Road surfaces, drawn over the areas.
    pub roads: Vec<RoadStrip>,
    /// Painted lines, drawn last.
    pub lines: Vec<Line>,
}

impl Environment {
    /// The environment of a lanelet map, as the 2015 road module drew it: road pattern inside every
    /// lanelet; patterns inside closed ways tagged (`line_type` or `region`) `mud`/`pile_stuff`,
    /// `iron`, `parking_lot`, `free_space`; yellow lines on `line_type=exterior` ways and white ones
    /// on `interior` ways; ways without such tags draw nothing.
    pub fn from_map(map: &LaneletMap) -> Environment {
        let roads = map.lanelets.iter().map(|l| RoadStrip { left: l.left.clone(), right: l.right.clone() }).collect();
        let mut areas = Vec::new();
        let mut lines = Vec::new();
        for way in map.ways.values() {
            let Some(kind) = way.line_type() else { continue };
            if let Some(style) = way.tags.get("line_type").and_then(|v| LineStyle::for_line_type(v)) {
                lines.push(Line { style, points: way.points.clone() });
            } else if way.is_closed()
                && let Some(pattern) = PatternKind::from_area_tag(kind)
            {
                areas.push(Area { pattern, outline: way.points.clone() });
            }
        }
        Environment { background: PatternKind::Forest, areas, roads, lines }
    }
}

/// Vertex of the ground pipeline (environment and routes): position relative to the view centre,
/// pattern coordinates, colour, and line parameters for anti-aliasing and dashes.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub(crate) struct GroundVertex {
    /// Position relative to the view centre [m].
    pub pos: [f32; 2],
    /// Pattern coordinates (tiles) and texture layer; layer < 0 means plain colour.
    pub tex: [f32; 3],
    /// sRGB colour (0..1) multiplied with the pattern (or the plain colour), with alpha.
    pub color: [f32; 4],
    /// Lines: signed distance across [px], half width [px] (0: not a line), distance along [m],
    /// dash period [m] (0: solid).
    pub line: [f32; 4],
}

/// Appends triangles to a vertex list for one view.
pub(crate) struct Tessellator<'a> {
    pub view: &'a BirdseyeView,
    pub out: &'a mut Vec<GroundVertex>,
}

/// sRGB colour with alpha as the 0..1 values the shaders work with (they blend in sRGB space).
pub(crate) fn rgba(c: [u8; 4]) -> [f32; 4] {
    c.map(|v| f32::from(v) / 255.0)
}

impl Tessellator<'_> {
    fn rel(&self, p: DVec2) -> [f32; 2] {
        let r = p - self.view.center;
        [r.x as f32, r.y as f32]
    }

    fn pattern_vertex(&self, p: DVec2, kind: PatternKind, tile_m: f64) -> GroundVertex {
        GroundVertex {
            pos: self.rel(p),
            tex: [(p.x / tile_m) as f32, (-p.y / tile_m) as f32, kind.layer() as f32],
            color: [1.0; 4],
            line: [0.0; 4],
        }
    }

    /// The whole view filled with a pattern.
    pub fn background(&mut self, kind: PatternKind, patterns: &PatternSet) {
        let (min, max) = self.view.world_rect();
        let tile = patterns.get(kind).tile_meters;
        let [a, b, c, d] =
            [min, DVec2::new(max.x, min.y), max, DVec2::new(min.x, max.y)].map(|p| self.pattern_vertex(p, kind, tile));
        self.out.extend_from_slice(&[a, b, c, a, c, d]);
    }

    /// A road strip (or its polygon when the bounds are not paired) filled with a pattern.
    pub fn strip(&mut self, road: &RoadStrip, kind: PatternKind, patterns: &PatternSet) {
        let tile = patterns.get(kind).tile_meters;
        if road.left.len() == road.right.len() && road.left.len() >= 2 {
            for k in 0..road.left.len() - 1 {
                let [l0, r0, l1, r1] = [road.left[k], road.right[k], road.left[k + 1], road.right[k + 1]]
                    .map(|p| self.pattern_vertex(p, kind, tile));
                self.out.extend_from_slice(&[l0, r0, l1, r0, r1, l1]);
            }
        } else {
            let poly: Vec<DVec2> = road.left.iter().chain(road.right.iter().rev()).copied().collect();
            self.polygon(&poly, kind, patterns);
        }
    }

    /// A simple polygon filled with a pattern.
    pub fn polygon(&mut self, outline: &[DVec2], kind: PatternKind, patterns: &PatternSet) {
        let tile = patterns.get(kind).tile_meters;
        for [a, b, c] in triangulate(outline) {
            let t = [outline[a], outline[b], outline[c]].map(|p| self.pattern_vertex(p, kind, tile));
            self.out.extend_from_slice(&t);
        }
    }

    /// A polyline with anti-aliased edges, round joins (solid lines) and optional dashes.
    pub fn polyline(&mut self, points: &[DVec2], style: &LineStyle) {
        let ppm = self.view.pixels_per_meter;
        let half_px = (0.5 * style.width * ppm).max(0.75) as f32;
        // One extra pixel on each side for the anti-aliased fringe.
        let ext_m = (f64::from(half_px) + 1.0) / ppm;
        let ext_px = half_px + 1.0;
        let color = rgba(style.color);
        let dash = style.dash.filter(|d| d.is_finite() && *d > 0.0).unwrap_or(0.0) as f32;
        let mut along = 0.0f64;
        for (k, w) in points.windows(2).enumerate() {
            let (a, b) = (w[0], w[1]);
            let seg = b - a;
            let len = seg.length();
            // Also skips NaN lengths.
            if len.is_nan() || len <= 1e-9 {
                continue;
            }
            let n = DVec2::new(-seg.y, seg.x) / len * ext_m;
            let v = |p: DVec2, across: f32, s: f64| GroundVertex {
                pos: self.rel(p),
                tex: [0.0, 0.0, -1.0],
                color,
                line: [across, half_px, s as f32, dash],
            };
            let (s0, s1) = (along, along + len);
            let q = [v(a + n, ext_px, s0), v(a - n, -ext_px, s0), v(b + n, ext_px, s1), v(b - n, -ext_px, s1)];
            self.out.extend_from_slice(&[q[0], q[1], q[2], q[1], q[3], q[2]]);
            if dash == 0.0 && k + 2 < points.len() {
                self.disc(b, ext_m, ext_px, half_px, color);
            }
            along = s1;
        }
    }

    fn disc(&mut self, c: DVec2, r_m: f64, r_px: f32, half_px: f32, color: [f32; 4]) {
        const SEGMENTS: usize = 12;
        let centre_m = self.view.center;
        let v = |p: DVec2, across: f32| GroundVertex {
            pos: [(p.x - centre_m.x) as f32, (p.y - centre_m.y) as f32],
            tex: [0.0, 0.0, -1.0],
            color,
            line: [across, half_px, 0.0, 0.0],
        };
        let centre = v(c, 0.0);
        for i in 0..SEGMENTS {
            let a0 = std::f64::consts::TAU * i as f64 / SEGMENTS as f64;
            let a1 = std::f64::consts::TAU * (i + 1) as f64 / SEGMENTS as f64;
            let p0 = v(c + DVec2::from_angle(a0) * r_m, r_px);
            let p1 = v(c + DVec2::from_angle(a1) * r_m, r_px);
            self.out.extend_from_slice(&[centre, p0, p1]);
        }
    }

    /// The whole environment, back to front.
    pub fn environment(&mut self, env: &Environment, patterns: &PatternSet) {
        self.background(env.background, patterns);
        for area in &env.areas {
            self.polygon(&area.outline, area.pattern, patterns);
        }
        for road in &env.roads {
            self.strip(road, PatternKind::Road, patterns);
        }
        for line in &env.lines {
            self.polyline(&line.points, &line.style);
        }
    }
}

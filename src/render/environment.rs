//! The environment layer's geometry: roads, areas, tinted or filled polygons and painted lines in
//! metres, and their tessellation.
//!
//! What a map's tags turn into (see [`Environment::from_map`]):
//! - SML maps: `line_type=exterior` (yellow edge) and `interior` (white dashes); closed ways
//!   tagged `mud`, `iron`, `parking_lot`, `free_space` are patterned areas.
//! - Lanelet2 line strings by `type`/`subtype`: `line_thin`/`line_thick` `solid`, `dashed`,
//!   `solid_solid`, `solid_dashed` (solid on the left of the way's direction), `dashed_solid`;
//!   `curbstone` and `road_border` (kerb grey), `stop_line` (broad white), `pedestrian_marking`
//!   and `bike_marking` (short white dashes), `guard_rail`, `fence`, `wall` (dark grey);
//!   `virtual` and anything else: not drawn.
//! - Lanelet subtypes (Lanelet2 `subtype`, CommonRoad `laneletType`): `crosswalk` striped as a
//!   zebra crossing; `walkway`/`sidewalk`, `bicycle_lane`/`bicycleLane`, `parking`,
//!   `bus_lane`/`busLane` tinted; roads and highways plain.
//! - OpenDRIVE lanes (lanelets tagged `opendrive:type`) tinted by lane type
//!   ([`lane_type_tint`]): driving lanes plain, sidewalks, shoulders, borders, medians, parking,
//!   biking, restricted and other lanes each in their own tint; and road marks as the file gives
//!   them (ways tagged `opendrive:marks`: each piece along the way solid, broken, double or
//!   bold, in its `color`, see [`mark_color`]), whatever lane changes the `laneChange`
//!   attribute allows.
//! - CommonRoad obstacle outlines (closed ways tagged `obstacle`): filled, buildings and other
//!   environment obstacles in brown-grey, parked vehicles in blue-grey, other static obstacles
//!   (road boundaries, construction zones) in orange-grey, each with a dark outline.

use glam::DVec2;

use super::patterns::{PatternKind, PatternSet};
use super::triangulate::triangulate;
use super::view::BirdseyeView;
use crate::map::LaneletMap;

/// A road surface between a left and a right bound \[m\]; `left[k]` and `right[k]` are paired when
/// both have the same length (then it is drawn as a strip), else the polygon is triangulated.
#[derive(Debug, Clone, PartialEq)]
pub struct RoadStrip {
    /// Left bound \[m\], in driving direction.
    pub left: Vec<DVec2>,
    /// Right bound \[m\], in driving direction.
    pub right: Vec<DVec2>,
}

/// A closed area painted with a pattern (mud, iron, parking lot, free space).
#[derive(Debug, Clone, PartialEq)]
pub struct Area {
    /// Ground pattern inside the outline.
    pub pattern: PatternKind,
    /// Outline \[m\]; closing point optional; simple (non-self-intersecting), any orientation.
    pub outline: Vec<DVec2>,
}

/// How a painted line looks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LineStyle {
    /// Colour, sRGB with alpha.
    pub color: [u8; 4],
    /// Line width \[m\]; never drawn thinner than 1.5 px so it stays visible when zoomed out.
    pub width: f64,
    /// Dash period \[m\] (half painted, half gap); `None` for a solid line.
    pub dash: Option<f64>,
}

impl LineStyle {
    /// `line_type=exterior`: the road edge, solid yellow.
    pub const EXTERIOR: LineStyle = LineStyle { color: [236, 190, 40, 255], width: 0.3, dash: None };
    /// `line_type=interior`: between lanes, white and dashed (3 m paint, 3 m gap).
    pub const INTERIOR: LineStyle = LineStyle { color: [242, 242, 236, 255], width: 0.2, dash: Some(6.0) };

    /// A white painted line (Lanelet2 `line_thin`): solid.
    pub const THIN_SOLID: LineStyle = LineStyle { color: WHITE, width: 0.12, dash: None };
    /// A white painted line (Lanelet2 `line_thin`): dashed (3 m paint, 3 m gap).
    pub const THIN_DASHED: LineStyle = LineStyle { color: WHITE, width: 0.12, dash: Some(6.0) };
    /// A kerb (Lanelet2 `curbstone`, `road_border`): light grey.
    pub const KERB: LineStyle = LineStyle { color: [200, 198, 190, 255], width: 0.25, dash: None };
    /// A stop line: broad white.
    pub const STOP_LINE: LineStyle = LineStyle { color: WHITE, width: 0.4, dash: None };
    /// Pedestrian and bicycle crossing edges: short white dashes (0.5 m paint, 0.5 m gap).
    pub const CROSSING_EDGE: LineStyle = LineStyle { color: WHITE, width: 0.12, dash: Some(1.0) };
    /// A barrier (guard rail, fence, wall): dark grey.
    pub const BARRIER: LineStyle = LineStyle { color: [80, 80, 80, 255], width: 0.2, dash: None };
    /// The outline of a filled obstacle: dark grey, thin.
    pub const OUTLINE: LineStyle = LineStyle { color: [50, 50, 50, 255], width: 0.1, dash: None };

    /// The style of a way's `line_type` value; `None` (no line) for anything else.
    pub fn for_line_type(value: &str) -> Option<LineStyle> {
        match value {
            "exterior" => Some(LineStyle::EXTERIOR),
            "interior" => Some(LineStyle::INTERIOR),
            _ => None,
        }
    }

    /// The same style `factor` times as wide.
    pub fn widened(self, factor: f64) -> LineStyle {
        LineStyle { width: self.width * factor, ..self }
    }
}

/// White paint.
const WHITE: [u8; 4] = [242, 242, 236, 255];

/// The lines of a Lanelet2 line string with `type` and `subtype` (see the module docs): each
/// style with its offset to the left of the way's direction \[m\]. Empty when nothing is drawn.
pub fn lanelet2_lines(kind: &str, subtype: Option<&str>) -> Vec<(LineStyle, f64)> {
    let painted = |thick: bool| {
        let (solid, dashed) = if thick {
            (LineStyle::THIN_SOLID.widened(2.0), LineStyle::THIN_DASHED.widened(2.0))
        } else {
            (LineStyle::THIN_SOLID, LineStyle::THIN_DASHED)
        };
        // Double lines: two lines a line width apart on each side of the way.
        let d = solid.width;
        match subtype.unwrap_or("solid") {
            "dashed" => vec![(dashed, 0.0)],
            "solid_solid" => vec![(solid, d), (solid, -d)],
            "solid_dashed" => vec![(solid, d), (dashed, -d)],
            "dashed_solid" => vec![(dashed, d), (solid, -d)],
            _ => vec![(solid, 0.0)],
        }
    };
    match kind {
        "line_thin" => painted(false),
        "line_thick" => painted(true),
        "curbstone" | "road_border" => vec![(LineStyle::KERB, 0.0)],
        "stop_line" => vec![(LineStyle::STOP_LINE, 0.0)],
        "pedestrian_marking" | "bike_marking" => vec![(LineStyle::CROSSING_EDGE, 0.0)],
        "guard_rail" | "fence" | "wall" => vec![(LineStyle::BARRIER, 0.0)],
        _ => Vec::new(),
    }
}

/// The tint of a lanelet subtype (Lanelet2 `subtype` or a CommonRoad `laneletType`), drawn over
/// the road pattern; `None` for roads, highways and unknown subtypes.
pub fn subtype_tint(subtype: &str) -> Option<[u8; 4]> {
    match subtype {
        "walkway" | "sidewalk" => Some([214, 200, 170, 170]),
        "bicycle_lane" | "bicycleLane" => Some([196, 70, 60, 110]),
        "parking" => Some([70, 110, 200, 90]),
        "bus_lane" | "busLane" => Some([200, 150, 50, 100]),
        _ => None,
    }
}

/// The tint of an OpenDRIVE lane `type`, drawn over the road pattern; `None` (plain asphalt)
/// for the lanes cars drive (driving, entry, exit, ramps, bidirectional) and `none`.
pub fn lane_type_tint(kind: &str) -> Option<[u8; 4]> {
    match kind {
        "sidewalk" | "walking" => Some([214, 200, 170, 200]),
        "shoulder" => Some([150, 130, 95, 150]),
        "border" => Some([40, 40, 42, 200]),
        "median" => Some([90, 140, 70, 200]),
        "curb" => Some([200, 198, 190, 220]),
        "parking" => Some([70, 110, 200, 110]),
        "biking" => Some([196, 70, 60, 130]),
        "restricted" => Some([200, 90, 160, 110]),
        "bus" | "taxi" | "HOV" => Some([200, 150, 50, 110]),
        "stop" => Some([200, 60, 60, 90]),
        "tram" | "rail" => Some([120, 100, 90, 150]),
        "special1" | "special2" | "special3" => Some([150, 110, 190, 110]),
        _ => None,
    }
}

/// The paint of an OpenDRIVE road mark `color` (`standard` and unknown names: white).
pub fn mark_color(name: &str) -> [u8; 4] {
    match name {
        "yellow" => [236, 190, 40, 255],
        "blue" => [60, 110, 220, 255],
        "green" => [60, 170, 80, 255],
        "red" => [210, 50, 40, 255],
        "orange" => [240, 140, 30, 255],
        "black" => [20, 20, 20, 255],
        "violet" => [140, 80, 190, 255],
        _ => WHITE,
    }
}

/// The lines of a way's `opendrive:marks` pieces (`NODE TYPE SUBTYPE COLOR;...`, written by the
/// OpenDRIVE reader): each piece's points with its styles and offsets; `None` when the value
/// does not parse (the way is then drawn from its `type`/`subtype` like any Lanelet2 line).
fn opendrive_mark_lines(value: &str, points: &[DVec2]) -> Option<Vec<Line>> {
    let mut pieces: Vec<(usize, &str, Option<&str>, &str)> = Vec::new();
    for piece in value.split(';') {
        let f: Vec<&str> = piece.split_whitespace().collect();
        let [node, kind, sub, color] = f.as_slice() else { return None };
        let node: usize = node.parse().ok()?;
        pieces.push((node.min(points.len().saturating_sub(1)), kind, (*sub != "-").then_some(*sub), color));
    }
    let mut lines = Vec::new();
    for (k, &(from, kind, sub, color)) in pieces.iter().enumerate() {
        let to = pieces.get(k + 1).map_or(points.len() - 1, |p| p.0);
        if to <= from {
            continue;
        }
        let part = &points[from..=to];
        for (style, d) in lanelet2_lines(kind, sub) {
            let style = LineStyle { color: mark_color(color), ..style };
            lines.push(Line { style, points: offset_polyline(part, d) });
        }
    }
    Some(lines)
}

/// Fill colour of a CommonRoad obstacle outline (a way's `obstacle` and `obstacle_role` tags).
pub fn obstacle_color(kind: &str, role: Option<&str>) -> [u8; 4] {
    match (kind, role) {
        ("parkedVehicle", _) => [96, 110, 140, 255],
        (_, Some("environment")) | ("building", _) => [150, 136, 120, 255],
        _ => [196, 132, 80, 255],
    }
}

/// `points` moved `d` [m] to their left (per segment normal, averaged at the joints).
fn offset_polyline(points: &[DVec2], d: f64) -> Vec<DVec2> {
    if d == 0.0 || points.len() < 2 {
        return points.to_vec();
    }
    let normal = |a: DVec2, b: DVec2| (b - a).perp().try_normalize().unwrap_or(DVec2::ZERO);
    (0..points.len())
        .map(|i| {
            let before = (i > 0).then(|| normal(points[i - 1], points[i]));
            let after = (i + 1 < points.len()).then(|| normal(points[i], points[i + 1]));
            let n = match (before, after) {
                (Some(a), Some(b)) => (a + b).try_normalize().unwrap_or(a),
                (Some(a), None) | (None, Some(a)) => a,
                (None, None) => DVec2::ZERO,
            };
            points[i] + n * d
        })
        .collect()
}

/// A polygon filled with a plain colour (alpha blends it over what is below).
#[derive(Debug, Clone, PartialEq)]
pub struct Fill {
    /// sRGB colour with alpha.
    pub color: [u8; 4],
    /// Outline \[m\]; closing point optional; simple, any orientation.
    pub outline: Vec<DVec2>,
}

/// A painted polyline.
#[derive(Debug, Clone, PartialEq)]
pub struct Line {
    /// How it is painted.
    pub style: LineStyle,
    /// Points \[m\] in order.
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
    /// Plain-colour polygons over the roads: lanelet tints, then obstacles.
    pub fills: Vec<Fill>,
    /// Painted lines, drawn last.
    pub lines: Vec<Line>,
}

impl Environment {
    /// The environment of a lanelet map: road pattern inside every lanelet, as the 2015 road
    /// module drew it (patterns inside closed ways tagged (`line_type` or `region`)
    /// `mud`/`pile_stuff`, `iron`, `parking_lot`, `free_space`; yellow lines on
    /// `line_type=exterior` ways and white ones on `interior` ways, `broad_` CommonRoad markings
    /// wider), plus Lanelet2 line types, lanelet subtypes and CommonRoad obstacles as the module
    /// docs list them; other ways draw nothing.
    pub fn from_map(map: &LaneletMap) -> Environment {
        let roads = map.lanelets.iter().map(|l| RoadStrip { left: l.left.clone(), right: l.right.clone() }).collect();
        let mut areas = Vec::new();
        let mut fills = Vec::new();
        let mut lines = Vec::new();
        for l in &map.lanelets {
            let subtypes = l.tags.get("subtype").or_else(|| l.tags.get("lanelet_type"));
            let subtypes: Vec<&str> = subtypes.map(|s| s.split(';').map(str::trim).collect()).unwrap_or_default();
            if subtypes.contains(&"crosswalk") {
                // Zebra stripes: a dash pattern as wide as the crossing along its centre line.
                let width =
                    l.left.iter().zip(&l.right).map(|(a, b)| a.distance(*b)).sum::<f64>() / l.left.len().max(1) as f64;
                let style = LineStyle { color: WHITE, width: 0.9 * width, dash: Some(1.0) };
                lines.push(Line { style, points: l.centre.clone() });
            } else if let Some(kind) = l.tags.get("opendrive:type") {
                if let Some(color) = lane_type_tint(kind) {
                    fills.push(Fill { color, outline: l.polygon() });
                }
            } else if let Some(color) = subtypes.iter().find_map(|s| subtype_tint(s)) {
                fills.push(Fill { color, outline: l.polygon() });
            }
        }
        let mut obstacles = Vec::new();
        for way in map.ways.values() {
            if let Some(kind) = way.tags.get("obstacle") {
                let color = obstacle_color(kind, way.tags.get("obstacle_role").map(String::as_str));
                obstacles.push(Fill { color, outline: way.points.clone() });
                lines.push(Line { style: LineStyle::OUTLINE, points: way.points.clone() });
            } else if let Some(kind) = way.line_type() {
                if let Some(style) = way.tags.get("line_type").and_then(|v| LineStyle::for_line_type(v)) {
                    let broad = way.tags.get("line_marking").is_some_and(|m| m.starts_with("broad_"));
                    lines.push(Line {
                        style: if broad { style.widened(1.5) } else { style },
                        points: way.points.clone(),
                    });
                } else if way.is_closed()
                    && let Some(pattern) = PatternKind::from_area_tag(kind)
                {
                    areas.push(Area { pattern, outline: way.points.clone() });
                }
            } else if let Some(marks) =
                way.tags.get("opendrive:marks").and_then(|v| opendrive_mark_lines(v, &way.points))
            {
                lines.extend(marks);
            } else if let Some(kind) = way.tags.get("type") {
                for (style, d) in lanelet2_lines(kind, way.tags.get("subtype").map(String::as_str)) {
                    lines.push(Line { style, points: offset_polyline(&way.points, d) });
                }
            }
        }
        fills.extend(obstacles);
        Environment { background: PatternKind::Forest, areas, roads, fills, lines }
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

    /// A simple polygon filled with a plain colour.
    pub fn fill(&mut self, fill: &Fill) {
        let color = rgba(fill.color);
        let outline = &fill.outline;
        for [a, b, c] in triangulate(outline) {
            let t = [outline[a], outline[b], outline[c]].map(|p| GroundVertex {
                pos: self.rel(p),
                tex: [0.0, 0.0, -1.0],
                color,
                line: [0.0; 4],
            });
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
        for fill in &env.fills {
            self.fill(fill);
        }
        for line in &env.lines {
            self.polyline(&line.points, &line.style);
        }
    }
}

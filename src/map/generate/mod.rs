//! Parametric maps (ring highway, intersections, grid city) written as JOSM-compatible OSM XML.
//!
//! Every generator builds the map in metres and writes it the way JOSM saves a new drawing:
//! single-quoted attributes, negative ids (unique over nodes, ways and relations together),
//! `<osm version='0.6' generator='smlworld'>`, 10 decimals of lat/lon (about 10 µm) from
//! [`Projector::reverse`](super::Projector::reverse), which the loader's
//! [`Projector::forward`](super::Projector::forward) maps back onto the metres they were built
//! from, around the fixed origin ([`ORIGIN_LAT`], [`ORIGIN_LON`], the SML lab), which is written
//! as the first node tagged `origin=true` at local (0, 0). The private `osm_writer` module writes
//! the XML.
//!
//! Conventions shared by all maps, so that they load in SML World, the 2015 tool and Lanelet2:
//! - a lanelet is a relation `type=lanelet` with the member roles `left` and `right` (Lanelet2's
//!   roles; the loader also accepts the 2015 `left_lane_marking`/`right_lane_marking`);
//! - right bounds are drawn in the driving direction; a left bound shared by two opposite
//!   directions (the centre line of a two-way street) is drawn one way and reversed by the loader;
//! - both bounds of a lanelet have the same number of nodes (the 2015 loader required it);
//! - consecutive lanelets share the bound nodes at their joint, so the loader's successor rule
//!   (first right/left node of the next = last right/left node of the previous) links them;
//! - boundary ways are tagged `line_type=exterior` (road edge) or `line_type=interior` (between
//!   lanes), as in the SML maps; the unpainted bounds of turn lanelets inside a junction are
//!   tagged Lanelet2's `type=virtual` instead, so renderers draw no line there;
//! - named nodes carry `destination=<name>` for routing by tag.
//!
//! The maps are built in memory (about 100 bytes per node) and streamed to any [`Write`] at
//! about 35-70 MB/s (`benches/map.rs`), so a 20 MB grid city takes under a second.

mod lane_drop;
mod osm_writer;

use std::f64::consts::{FRAC_PI_2, TAU};
use std::io::{self, Write};

use glam::DVec2;

use self::osm_writer::{Builder, EXTERIOR, INTERIOR, VIRTUAL, to_string};
pub use lane_drop::{
    LANE_DROP_END, LANE_DROP_LEFT_END, LANE_DROP_LEFT_START, LANE_DROP_RIGHT_START, LaneDropParams, lane_drop,
    write_lane_drop,
};

/// Latitude of the origin of every generated map \[deg\] (the SML lab, Södertälje).
pub const ORIGIN_LAT: f64 = 59.15;
/// Longitude of the origin of every generated map \[deg\].
pub const ORIGIN_LON: f64 = 17.66;

/// Invalid generator parameters, or a failed write.
#[derive(Debug, thiserror::Error)]
pub enum GenerateError {
    /// A parameter is out of range; the message names it, its value and what is allowed.
    #[error("invalid map parameter {name} = {value}: {allowed}")]
    InvalidParameter {
        /// Parameter name as in the parameter struct (and the CLI flag).
        name: &'static str,
        /// The value given.
        value: String,
        /// What values are allowed.
        allowed: String,
    },
    /// Writing the XML failed.
    #[error("cannot write the generated map: {0}")]
    Io(#[from] io::Error),
}

/// What a generator wrote.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct MapStats {
    /// Nodes written, the origin node included.
    pub nodes: usize,
    /// Ways written (lanelet bounds).
    pub ways: usize,
    /// Lanelet relations written.
    pub lanelets: usize,
    /// Size of the XML \[bytes\].
    pub bytes: u64,
}

/// Parameters of [`ring_highway`]: concentric circular lanes around the origin, like HighwaySML.
#[derive(Debug, Clone, PartialEq)]
pub struct RingParams {
    /// Number of lanes, all in the same direction (>= 1). More lanes widen the road outwards.
    pub lanes: usize,
    /// Radius of the innermost road edge \[m\] (> 0). Lane `m` (0 = innermost) has its centre line
    /// at `radius + (m + 0.5) * lane_width`.
    pub radius: f64,
    /// Width of every lane \[m\] (> 0).
    pub lane_width: f64,
    /// Drive clockwise; the default (false) is counter-clockwise as in HighwaySML, where the
    /// rightmost lane is the outermost.
    pub clockwise: bool,
    /// Largest distance between consecutive nodes on the outermost edge \[m\] (> 0). Every boundary
    /// gets the same node count, so inner boundaries are denser. Smaller = rounder and bigger.
    pub node_spacing: f64,
}

impl Default for RingParams {
    /// 3 lanes of 4 m around an inner edge of radius 50 m: closed loops of about 377 m (right
    /// lane), 352 m (centre) and 327 m (left), close to HighwaySML's 374 / 349 / 324 m.
    fn default() -> Self {
        RingParams { lanes: 3, radius: 50.0, lane_width: 4.0, clockwise: false, node_spacing: 2.0 }
    }
}

/// The `destination` tag value of the ring lane `k` counted from the right (0 = rightmost):
/// `right_lane_node`, `center_lane_node`, `left_lane_node` for 3 lanes (as in HighwaySML),
/// otherwise `lane_<k+1>_node` (`lane_1_node` is the rightmost).
pub fn ring_lane_tag(lanes: usize, k: usize) -> String {
    match (lanes, k) {
        (3, 0) => "right_lane_node".to_string(),
        (3, 1) => "center_lane_node".to_string(),
        (3, 2) => "left_lane_node".to_string(),
        _ => format!("lane_{}_node", k + 1),
    }
}

/// Ring highway as OSM XML; see [`write_ring_highway`].
pub fn ring_highway(params: &RingParams) -> Result<String, GenerateError> {
    to_string(|out| write_ring_highway(params, out))
}

/// Writes a ring highway centred on the origin.
///
/// Each lane is split into 4 lanelets (quarter circles, the first starting on the positive x
/// axis) that chain around the ring; boundary `b` (0 = innermost edge) is a circle of radius
/// `radius + b * lane_width` drawn as 4 quarter ways in the driving direction and shared by the
/// two lanes beside it; the two road edges are `line_type=exterior`, the lines between lanes
/// `interior`. Lane `k` from the right carries [`ring_lane_tag`] on the node where its first
/// lanelet starts, on its right bound (the outer circle when counter-clockwise, as in HighwaySML;
/// the inner one when clockwise): routing selects the lanes whose right bound holds a node (the
/// 2015 rule), so the node picks this lane in either direction.
///
/// Counts: `1 + 4 n (lanes + 1)` nodes with `n = max(2, ceil(pi/2 * r_outer / node_spacing))`
/// segments per quarter, `4 (lanes + 1)` ways, `4 lanes` lanelets and successor pairs.
pub fn write_ring_highway<W: Write>(params: &RingParams, out: W) -> Result<MapStats, GenerateError> {
    let p = params;
    check_count("lanes", p.lanes, 1, 1000)?;
    check_positive("radius", p.radius)?;
    check_positive("lane_width", p.lane_width)?;
    check_positive("node_spacing", p.node_spacing)?;
    let r_outer = p.radius + p.lanes as f64 * p.lane_width;
    let n = ((FRAC_PI_2 * r_outer / p.node_spacing).ceil() as usize).max(2);
    check_count("node_spacing (nodes per quarter)", n, 2, 10_000_000)?;
    let total = 4 * n;
    let sign = if p.clockwise { -1.0 } else { 1.0 };

    let mut b = Builder::new();
    // circles[bi][j]: node j (in driving order, j = 0 on the positive x axis) of boundary bi.
    let circles: Vec<Vec<usize>> = (0..=p.lanes)
        .map(|bi| {
            let r = p.radius + bi as f64 * p.lane_width;
            (0..total)
                .map(|j| {
                    let angle = sign * TAU * j as f64 / total as f64;
                    b.node(DVec2::new(r * angle.cos(), r * angle.sin()))
                })
                .collect()
        })
        .collect();
    // quarters[bi][q]: way of boundary bi over quarter q; quarter q + 1 starts where q ends.
    let quarters: Vec<Vec<usize>> = circles
        .iter()
        .enumerate()
        .map(|(bi, circle)| {
            let line = if bi == 0 || bi == p.lanes { EXTERIOR } else { INTERIOR };
            (0..4).map(|q| b.way((q * n..=(q + 1) * n).map(|j| circle[j % total]).collect(), line)).collect()
        })
        .collect();
    for m in 0..p.lanes {
        let (left, right) = if p.clockwise { (m + 1, m) } else { (m, m + 1) };
        for (&l, &r) in quarters[left].iter().zip(&quarters[right]) {
            b.lanelet(l, r);
        }
        let k = if p.clockwise { m } else { p.lanes - 1 - m };
        // On the lane's right marking: the 2015 rule selects the lane whose right bound holds it.
        b.tag(circles[right][0], "destination", ring_lane_tag(p.lanes, k));
    }
    Ok(b.write(out)?)
}

/// Parameters of [`intersection`]: one junction with straight arms and every legal turn.
#[derive(Debug, Clone, PartialEq)]
pub struct IntersectionParams {
    /// Number of arms: 4 (east, north, west, south) or 3 (east, west, south: a T whose stem
    /// points south).
    pub arms: usize,
    /// Lanes per direction on every arm (>= 1); lane `i` of an arm turns into lane `i` of the
    /// other arms (counted from the centre line).
    pub lanes: usize,
    /// Length of each arm from the edge of the junction to its far end \[m\] (> 0).
    pub arm_length: f64,
    /// Width of every lane \[m\] (> 0).
    pub lane_width: f64,
    /// Radius of the road edge in the corners \[m\] (> 0): the arms start `lanes * lane_width +
    /// corner_radius` from the centre. Larger = wider junction and gentler turns.
    pub corner_radius: f64,
    /// Largest distance between consecutive nodes \[m\] (> 0).
    pub node_spacing: f64,
    /// Junction control written on the turn lanelets.
    pub control: JunctionMarks,
}

/// What a generator writes on the turn lanelets of its junctions: traffic lights
/// (`traffic_light = yes`) and a major road (`priority = major|minor`), both read back by
/// [`crate::map::junctions::find_junctions`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct JunctionMarks {
    /// Every junction of 3 or more arms has traffic lights.
    pub traffic_lights: bool,
    /// The road along this axis is major (turns from its arms `priority = major`, from the
    /// others `minor`).
    pub major: Option<Axis>,
}

/// A direction of roads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Axis {
    /// The east and west arms.
    EastWest,
    /// The north and south arms.
    NorthSouth,
}

impl Axis {
    /// Whether `arm` lies on this axis.
    pub fn holds(self, arm: Arm) -> bool {
        match self {
            Axis::EastWest => matches!(arm, Arm::East | Arm::West),
            Axis::NorthSouth => matches!(arm, Arm::North | Arm::South),
        }
    }
}

impl Default for IntersectionParams {
    /// A 4-way junction of one-lane-each-way roads, 3.5 m lanes, 6 m corners, 30 m arms.
    fn default() -> Self {
        IntersectionParams {
            arms: 4,
            lanes: 1,
            arm_length: 30.0,
            lane_width: 3.5,
            corner_radius: 6.0,
            node_spacing: 1.0,
            control: JunctionMarks::default(),
        }
    }
}

/// The direction of a junction arm, as seen from the junction centre.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Arm {
    /// Towards +x.
    East,
    /// Towards +y.
    North,
    /// Towards -x.
    West,
    /// Towards -y.
    South,
}

impl Arm {
    /// All four arms, counter-clockwise from east.
    pub const ALL: [Arm; 4] = [Arm::East, Arm::North, Arm::West, Arm::South];

    /// Lower-case name used in tags: `east`, `north`, `west`, `south`.
    pub fn name(self) -> &'static str {
        match self {
            Arm::East => "east",
            Arm::North => "north",
            Arm::West => "west",
            Arm::South => "south",
        }
    }

    /// Unit vector pointing out of the junction along this arm.
    pub fn direction(self) -> DVec2 {
        match self {
            Arm::East => DVec2::X,
            Arm::North => DVec2::Y,
            Arm::West => -DVec2::X,
            Arm::South => -DVec2::Y,
        }
    }

    /// The arms of an intersection with `arms` arms (3 or 4), in writing order.
    pub fn of_intersection(arms: usize) -> &'static [Arm] {
        if arms == 3 { &[Arm::East, Arm::West, Arm::South] } else { &Arm::ALL }
    }
}

/// `destination` tag of the far start of the rightmost incoming lane of an arm of
/// [`intersection`]: `<arm>_start`, e.g. `north_start`.
pub fn intersection_start_tag(arm: Arm) -> String {
    format!("{}_start", arm.name())
}

/// `destination` tag of the far end of the rightmost outgoing lane of an arm of
/// [`intersection`]: `<arm>_end`, e.g. `south_end`.
pub fn intersection_end_tag(arm: Arm) -> String {
    format!("{}_end", arm.name())
}

/// Intersection as OSM XML; see [`write_intersection`].
pub fn intersection(params: &IntersectionParams) -> Result<String, GenerateError> {
    to_string(|out| write_intersection(params, out))
}

/// Writes a 3- or 4-way intersection centred on the origin, right-hand traffic.
///
/// Each arm has `lanes` incoming and `lanes` outgoing straight lanelets of length `arm_length`;
/// inside the junction every legal turn (straight, left, right; no U-turns) is a lanelet from
/// each incoming lane to the same lane of every other arm, its bounds cubic Bézier curves
/// (quarter circles for the 90° turns) tagged `type=virtual`. The far ends of the rightmost
/// lanes are tagged [`intersection_start_tag`] (where the incoming lane starts, on its right
/// bound) and [`intersection_end_tag`] (where the outgoing lane ends, on its right bound).
///
/// Counts: `2 arms lanes` arm lanelets plus `arms (arms - 1) lanes` turn lanelets; ways
/// `arms (2 lanes + 1) + arms (arms - 1) (lanes + 1)`; successor pairs `2 arms (arms - 1) lanes`.
pub fn write_intersection<W: Write>(params: &IntersectionParams, out: W) -> Result<MapStats, GenerateError> {
    let p = params;
    if p.arms != 3 && p.arms != 4 {
        return Err(invalid("arms", p.arms, "3 or 4"));
    }
    let road = RoadParams::new(p.lanes, p.lane_width, p.corner_radius, p.node_spacing)?;
    check_positive("arm_length", p.arm_length)?;
    let arms = Arm::of_intersection(p.arms);
    let mut b = Builder::new();
    let centre = DVec2::ZERO;
    let ends: Junction = arms.iter().map(|&arm| (arm, road.arm_ends(&mut b, centre, arm))).collect();
    let lanes = p.lanes as isize;
    for (arm, near) in &ends {
        let far_d = road.d0 + p.arm_length;
        let far: Vec<usize> =
            (-lanes..=lanes).map(|bi| b.node(road.arm_point(centre, *arm, far_d, bi as f64))).collect();
        road.street(&mut b, near, &far);
        // Only the rightmost lanes are tagged: their right bound is the road edge, which no other
        // lanelet touches, so a route between tags cannot slip into a neighbouring lane.
        b.tag(far[2 * p.lanes], "destination", intersection_start_tag(*arm));
        b.tag(far[0], "destination", intersection_end_tag(*arm));
    }
    road.turns(&mut b, centre, &ends, p.control);
    Ok(b.write(out)?)
}

/// Parameters of [`grid_city`]: a rectangular street grid with a junction at every crossing.
#[derive(Debug, Clone, PartialEq)]
pub struct GridParams {
    /// Blocks from south to north (>= 1); there are `rows + 1` east-west streets.
    pub rows: usize,
    /// Blocks from west to east (>= 1); there are `cols + 1` north-south streets.
    pub cols: usize,
    /// Distance between neighbouring junction centres \[m\]; must exceed twice the junction size
    /// `2 (lanes lane_width + corner_radius)`.
    pub block: f64,
    /// Lanes per direction on every street (>= 1).
    pub lanes: usize,
    /// Width of every lane \[m\] (> 0).
    pub lane_width: f64,
    /// Radius of the road edge in the corners \[m\] (> 0).
    pub corner_radius: f64,
    /// Largest distance between consecutive nodes \[m\] (> 0). Smaller = bigger file.
    pub node_spacing: f64,
    /// Junction control written on the turn lanelets (lights at junctions of 3 and 4 arms).
    pub control: JunctionMarks,
}

impl Default for GridParams {
    /// 3 x 3 blocks of 50 m, one 3.5 m lane each way, 6 m corners, nodes every 2 m.
    fn default() -> Self {
        GridParams {
            rows: 3,
            cols: 3,
            block: 50.0,
            lanes: 1,
            lane_width: 3.5,
            corner_radius: 6.0,
            node_spacing: 2.0,
            control: JunctionMarks::default(),
        }
    }
}

/// `destination` tag of the start of the street leaving junction (`row`, `col`) towards `arm`:
/// `r<row>c<col>_<arm>`, e.g. `r0c0_east`; on the right bound of its rightmost lane.
pub fn grid_junction_tag(row: usize, col: usize, arm: Arm) -> String {
    format!("r{row}c{col}_{}", arm.name())
}

/// Grid city as OSM XML; see [`write_grid_city`].
pub fn grid_city(params: &GridParams) -> Result<String, GenerateError> {
    to_string(|out| write_grid_city(params, out))
}

/// Writes a grid city: junction (`r`, `c`) at (`c block`, `r block`) for `r` in `0..=rows`, `c`
/// in `0..=cols`, so junction (0, 0) is at the origin; two-way streets between neighbours (one
/// lanelet per lane and direction, from junction edge to junction edge) and at every junction
/// every legal turn as in [`write_intersection`] (corners have 2 arms, border junctions 3).
/// Every street start is tagged [`grid_junction_tag`].
///
/// With `S = rows (cols + 1) + cols (rows + 1)` streets and `T = lanes (8 + 6 (2 (rows - 1) +
/// 2 (cols - 1)) + 12 (rows - 1) (cols - 1))` turn lanelets: `2 lanes S + T` lanelets,
/// `(2 lanes + 1) S + T (lanes + 1) / lanes` ways and `2 T` successor pairs.
pub fn write_grid_city<W: Write>(params: &GridParams, out: W) -> Result<MapStats, GenerateError> {
    let p = params;
    check_count("rows", p.rows, 1, 100_000)?;
    check_count("cols", p.cols, 1, 100_000)?;
    let road = RoadParams::new(p.lanes, p.lane_width, p.corner_radius, p.node_spacing)?;
    if !(p.block.is_finite() && p.block > 2.0 * road.d0) {
        return Err(invalid(
            "block",
            p.block,
            &format!("a distance [m] above 2 (lanes lane_width + corner_radius) = {}", 2.0 * road.d0),
        ));
    }
    let mut b = Builder::new();
    let centre = |r: usize, c: usize| DVec2::new(c as f64 * p.block, r as f64 * p.block);
    // ends[r][c]: the arms of junction (r, c) with their boundary nodes at the junction edge.
    let mut ends: Vec<Vec<Junction>> = Vec::with_capacity(p.rows + 1);
    for r in 0..=p.rows {
        let mut row = Vec::with_capacity(p.cols + 1);
        for c in 0..=p.cols {
            let present = |arm: Arm| match arm {
                Arm::East => c < p.cols,
                Arm::North => r < p.rows,
                Arm::West => c > 0,
                Arm::South => r > 0,
            };
            let arms = Arm::ALL.into_iter().filter(|&a| present(a));
            let junction: Junction = arms.map(|arm| (arm, road.arm_ends(&mut b, centre(r, c), arm))).collect();
            for (arm, e) in &junction {
                b.tag(e[0], "destination", grid_junction_tag(r, c, *arm));
            }
            row.push(junction);
        }
        ends.push(row);
    }
    let arm_of = |j: &Junction, arm: Arm| -> Vec<usize> {
        let (_, e) = j.iter().find(|(a, _)| *a == arm).expect("a junction has an arm towards each neighbour");
        e.clone()
    };
    for r in 0..=p.rows {
        for c in 0..=p.cols {
            if c < p.cols {
                let mut far = arm_of(&ends[r][c + 1], Arm::West);
                far.reverse();
                road.street(&mut b, &arm_of(&ends[r][c], Arm::East), &far);
            }
            if r < p.rows {
                let mut far = arm_of(&ends[r + 1][c], Arm::South);
                far.reverse();
                road.street(&mut b, &arm_of(&ends[r][c], Arm::North), &far);
            }
        }
    }
    for (r, row) in ends.iter().enumerate() {
        for (c, junction) in row.iter().enumerate() {
            road.turns(&mut b, centre(r, c), junction, p.control);
        }
    }
    Ok(b.write(out)?)
}

/// The arms of a junction, each with its boundary nodes at the junction edge (see
/// [`RoadParams::arm_ends`]).
type Junction = Vec<(Arm, Vec<usize>)>;

/// Cross-section shared by intersections and grid streets.
struct RoadParams {
    lanes: usize,
    lane_width: f64,
    spacing: f64,
    /// Distance from a junction centre to where its arms start [m].
    d0: f64,
}

impl RoadParams {
    fn new(lanes: usize, lane_width: f64, corner_radius: f64, spacing: f64) -> Result<RoadParams, GenerateError> {
        check_count("lanes", lanes, 1, 100)?;
        check_positive("lane_width", lane_width)?;
        check_positive("corner_radius", corner_radius)?;
        check_positive("node_spacing", spacing)?;
        Ok(RoadParams { lanes, lane_width, spacing, d0: lanes as f64 * lane_width + corner_radius })
    }

    /// Point `d` [m] out along `arm` from `centre`, `bi` lane widths to the left of the
    /// outward direction (incoming lanes are on the left of it: `bi > 0`).
    fn arm_point(&self, centre: DVec2, arm: Arm, d: f64, bi: f64) -> DVec2 {
        let u = arm.direction();
        centre + u * d + u.perp() * (bi * self.lane_width)
    }

    /// Nodes where the boundaries `-lanes..=lanes` of `arm` meet the junction edge; index
    /// `bi + lanes`.
    fn arm_ends(&self, b: &mut Builder, centre: DVec2, arm: Arm) -> Vec<usize> {
        let lanes = self.lanes as isize;
        (-lanes..=lanes).map(|bi| b.node(self.arm_point(centre, arm, self.d0, bi as f64))).collect()
    }

    /// A straight two-way street from the arm ends `near` to `far` (both indexed `bi + lanes`
    /// in the frame of the near arm): boundary ways and one lanelet per lane and direction.
    fn street(&self, b: &mut Builder, near: &[usize], far: &[usize]) {
        let lanes = self.lanes as isize;
        let len = b.nodes[near[0]].distance(b.nodes[far[0]]);
        let segments = ((len / self.spacing).ceil() as usize).max(1);
        let ways: Vec<usize> = (-lanes..=lanes)
            .map(|bi| {
                let i = (bi + lanes) as usize;
                let (a, z) = (b.nodes[near[i]], b.nodes[far[i]]);
                let mut nodes = Vec::with_capacity(segments + 1);
                nodes.push(near[i]);
                for s in 1..segments {
                    nodes.push(b.node(a.lerp(z, s as f64 / segments as f64)));
                }
                nodes.push(far[i]);
                if bi > 0 {
                    // Lanes towards the near junction: drawn in their driving direction.
                    nodes.reverse();
                }
                b.way(nodes, if bi.abs() == lanes { EXTERIOR } else { INTERIOR })
            })
            .collect();
        let way = |bi: isize| ways[(bi + lanes) as usize];
        for i in 0..lanes {
            b.lanelet(way(-i), way(-(i + 1)));
            b.lanelet(way(i), way(i + 1));
        }
    }

    /// Every legal turn at a junction: from each arm to each other arm, lane `i` to lane `i`.
    fn turns(&self, b: &mut Builder, centre: DVec2, arms: &Junction, marks: JunctionMarks) {
        let lanes = self.lanes as isize;
        for (from, from_ends) in arms {
            for (to, to_ends) in arms {
                if from == to {
                    continue;
                }
                // Curve c joins incoming boundary c of `from` to outgoing boundary -c of `to`.
                let curves: Vec<[DVec2; 4]> = (0..=lanes)
                    .map(|c| {
                        let p0 = self.arm_point(centre, *from, self.d0, c as f64);
                        let p3 = self.arm_point(centre, *to, self.d0, -c as f64);
                        bezier_turn(p0, -from.direction(), p3, to.direction())
                    })
                    .collect();
                let longest = curves.iter().map(bezier_length).fold(0.0, f64::max);
                let segments = ((longest / self.spacing).ceil() as usize).max(1);
                let ways: Vec<usize> = curves
                    .iter()
                    .enumerate()
                    .map(|(c, curve)| {
                        let mut nodes = Vec::with_capacity(segments + 1);
                        nodes.push(from_ends[(c as isize + lanes) as usize]);
                        for s in 1..segments {
                            nodes.push(b.node(bezier(curve, s as f64 / segments as f64)));
                        }
                        nodes.push(to_ends[(lanes - c as isize) as usize]);
                        b.way(nodes, VIRTUAL)
                    })
                    .collect();
                let mut tags = Vec::new();
                if marks.traffic_lights && arms.len() >= 3 {
                    tags.push(("traffic_light", "yes"));
                }
                if let Some(axis) = marks.major {
                    tags.push(("priority", if axis.holds(*from) { "major" } else { "minor" }));
                }
                for i in 0..self.lanes {
                    b.lanelet_tagged(ways[i], ways[i + 1], tags.clone());
                }
            }
        }
    }
}

/// Cubic Bézier from `p0` leaving along unit `a` to `p3` arriving along unit `b`: a straight
/// line when `a` = `b`, else control points on the tangents at `4/3 tan(theta/4)` times the
/// distance to the tangents' crossing, which is a circular arc when both distances are equal.
fn bezier_turn(p0: DVec2, a: DVec2, p3: DVec2, b: DVec2) -> [DVec2; 4] {
    let det = a.perp_dot(b);
    let theta = det.atan2(a.dot(b)).abs();
    if det.abs() < 1e-9 {
        let third = (p3 - p0) / 3.0;
        return [p0, p0 + third, p3 - third, p3];
    }
    // p0 + s a = p3 - r b: the tangents cross s after p0 and r before p3.
    let d = p3 - p0;
    let s = d.perp_dot(b) / det;
    let r = a.perp_dot(d) / det;
    let k = 4.0 / 3.0 * (theta / 4.0).tan();
    [p0, p0 + a * (k * s), p3 - b * (k * r), p3]
}

fn bezier(c: &[DVec2; 4], t: f64) -> DVec2 {
    let u = 1.0 - t;
    c[0] * (u * u * u) + c[1] * (3.0 * u * u * t) + c[2] * (3.0 * u * t * t) + c[3] * (t * t * t)
}

fn bezier_length(c: &[DVec2; 4]) -> f64 {
    const STEPS: usize = 64;
    (1..=STEPS).map(|s| bezier(c, s as f64 / STEPS as f64).distance(bezier(c, (s - 1) as f64 / STEPS as f64))).sum()
}

fn invalid(name: &'static str, value: impl std::fmt::Display, allowed: &str) -> GenerateError {
    GenerateError::InvalidParameter { name, value: value.to_string(), allowed: allowed.to_string() }
}

fn check_positive(name: &'static str, value: f64) -> Result<(), GenerateError> {
    if value.is_finite() && value > 0.0 { Ok(()) } else { Err(invalid(name, value, "a finite number above 0 [m]")) }
}

fn check_count(name: &'static str, value: usize, min: usize, max: usize) -> Result<(), GenerateError> {
    if (min..=max).contains(&value) {
        Ok(())
    } else {
        Err(invalid(name, value, &format!("an integer from {min} to {max}")))
    }
}

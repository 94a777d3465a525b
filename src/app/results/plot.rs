//! `smlworld plot OUT_DIR`: figures of a finished run for papers, from its `trajectories.csv`
//! and `summary.json`, as PNG and SVG (plotters; text in DejaVu Sans shipped in `assets/fonts`,
//! so figures look the same on every machine).
//!
//! Figures (each `NAME.png` and `NAME.svg` in the output folder):
//! - `speed`: speed over time per vehicle [m/s];
//! - `gaps`: per follower of `summary.json` `metrics.followers`, the bumper-to-bumper gap to its
//!   leader \[m\] (centre distance minus the half lengths) and the time gap (gap / own speed) \[s\];
//! - `platoon_<leader>`: per platoon, the speed of each member (the string-stability picture);
//! - `lateral`: each vehicle's distance from the nearest lanelet centre line of the map \[m\];
//! - `merge` (runs with `metrics.merge`, the GCDC merge): per participant, the gap along the road
//!   to the vehicle that is ahead of it after the merge (its predecessor in the zipper order; of
//!   the other lane until it merged) \[m\], and its speed [m/s], with the merge instants (the end of
//!   each merger's lane change) marked as dashed lines;
//! - `lanes` (runs with lane changes): the lanelet under each vehicle that changed lanes and
//!   its offset from that lanelet's centre line over time;
//! - `time_space`: the time-space diagram per lane (position along the road against time, dots
//!   coloured by speed), where stop-and-go waves show as bands running backwards;
//! - `trace`: a bird's-eye trace of every trajectory over the map's lanelets, equal scale (axes
//!   of their own scales for a long road, said in the title), with collisions marked.
//!
//! A vehicle has one pen (colour and dash) in every figure of a run: the vehicles take
//! [`PALETTE`]'s 20 colours in id order, then the colours again with dashes ([`pen`]); each
//! title names the largest event the run shows (the first vehicle to slow down markedly,
//! collisions, lane changes) and is shrunk or shortened to fit its panel. Legends sit in a column right of the plot,
//! never over a curve, and list at most [`MAX_LEGEND`] entries (the rest are drawn and counted).
//! [`plot_compare`] overlays the same figures of several runs, one colour per run.

use std::collections::BTreeMap;
use std::path::{Path as FsPath, PathBuf};
use std::sync::Once;

use glam::DVec2;
use plotters::coord::Shift;
use plotters::prelude::*;

use crate::files::AtomicFile;
use crate::map::LaneletMap;
use crate::map::polyline::project_polyline;

use super::replay::{ReplayError, read_replay_info};

/// Most legend entries per panel.
pub const MAX_LEGEND: usize = 12;
/// Figure size \[px\]: 1600 x 1000, readable when printed one column wide.
pub const FIGURE_SIZE: (u32, u32) = (1600, 1000);

fn register_font() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        // The bytes are a valid TrueType file shipped with the crate; a failure would only mean
        // text is missing, which the plot tests catch.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, crate::render::FONT_TTF);
    });
}

/// One row of `trajectories.csv`.
#[derive(Debug, Clone, Copy)]
struct Row {
    t: f64,
    position: DVec2,
    velocity: DVec2,
    /// Lanelet under the vehicle and the offset from its centre line [m] (runs on a map).
    lane: Option<(f64, f64)>,
}

/// A curve: legend label, points (a non-finite y breaks the line) and its pen.
type Series = (String, Vec<(f64, f64)>, Pen);

/// A curve: (x, y) points, x rising.
type Curve = Vec<(f64, f64)>;

/// Samples of a time-space diagram: (t [s], position along the road [m], speed [m/s]).
type Samples = Vec<(f64, f64, f64)>;

/// How a curve is drawn: its colour and its dash pattern.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Pen {
    /// Line colour (RGB).
    pub color: [u8; 3],
    /// Dash pattern: 0 solid, 1 dashed, 2 dotted, 3 dash-dotted.
    pub dash: u8,
}

impl Pen {
    fn solid(color: RGBColor) -> Pen {
        Pen { color: [color.0, color.1, color.2], dash: 0 }
    }

    fn rgb(self) -> RGBColor {
        RGBColor(self.color[0], self.color[1], self.color[2])
    }

    /// On/off lengths [px] of the dash pattern, repeated; `None` for a solid line.
    fn pattern(self) -> Option<&'static [f64]> {
        match self.dash % 4 {
            0 => None,
            1 => Some(&[14.0, 8.0]),
            2 => Some(&[3.0, 6.0]),
            _ => Some(&[14.0, 6.0, 3.0, 6.0]),
        }
    }
}

/// Twenty colours told apart on white (Tableau's ten, then ten darker or purer ones): the
/// vehicles of a run take them in id order, so up to 20 vehicles each have a colour of their
/// own; past 20 the colours repeat with another dash pattern ([`pen`]).
pub const PALETTE: [[u8; 3]; 20] = [
    [31, 119, 180],
    [255, 127, 14],
    [44, 160, 44],
    [214, 39, 40],
    [148, 103, 189],
    [140, 86, 75],
    [227, 119, 194],
    [127, 127, 127],
    [188, 189, 34],
    [23, 190, 207],
    [0, 0, 128],
    [128, 0, 0],
    [0, 110, 100],
    [110, 110, 0],
    [240, 50, 230],
    [255, 200, 0],
    [80, 40, 0],
    [90, 0, 160],
    [0, 220, 120],
    [0, 0, 0],
];

/// The pen of the `k`-th vehicle of a run (in id order): colour `k mod 20`, dash `k / 20`.
pub fn pen(k: usize) -> Pen {
    Pen { color: PALETTE[k % PALETTE.len()], dash: ((k / PALETTE.len()) % 4) as u8 }
}

/// A panel of curves over a shared x axis.
struct Lines {
    title: String,
    x_label: String,
    y_label: String,
    series: Vec<Series>,
    /// Instants [x units] marked by dashed vertical lines (the title says what they mark).
    marks: Vec<f64>,
}

/// What a figure shows.
enum Chart {
    /// Panels stacked top to bottom.
    Panels(Vec<Lines>),
    /// Trajectories over the lanelets' outlines at equal scale; collisions as red circles.
    Trace { title: String, roads: Vec<Vec<DVec2>>, series: Vec<Series>, collisions: Vec<DVec2> },
    /// Time-space diagram: per lane a panel of (t, position along the road, speed) samples,
    /// drawn as dots coloured by speed from 0 to `v_max`.
    TimeSpace { title: String, lanes: Vec<(String, Samples)>, v_max: f64 },
}

/// Width of the legend column right of every panel [px]: the legend never covers a curve.
const LEGEND_WIDTH: u32 = 300;

fn range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) =
        values.filter(|v| v.is_finite()).fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)));
    if lo > hi {
        return (0.0, 1.0);
    }
    let pad = ((hi - lo) * 0.05).max(1e-3);
    (lo - pad, hi + pad)
}

fn err<E: std::fmt::Debug>(e: E) -> String {
    format!("{e:?}")
}

type Axes<'a, DB> =
    ChartContext<'a, DB, Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>>;

/// Largest title font size [px].
const TITLE_SIZE: f64 = 30.0;
/// Smallest title font size [px]: a longer title is shortened with an ellipsis.
const TITLE_MIN_SIZE: f64 = 18.0;

/// `title` and the font size that fit it in `area`'s width less a margin of 20 px each side
/// (a centred caption wider than its panel was cut at both edges: issue 61's `lanes.png`).
fn fit_title<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, title: &str) -> (String, f64) {
    let room = f64::from(area.dim_in_pixel().0) - 40.0;
    let width = |text: &str, size: f64| {
        area.estimate_text_size(text, &("sans-serif", size).into_text_style(area)).map_or(0.0, |(w, _)| f64::from(w))
    };
    let full = width(title, TITLE_SIZE);
    if full <= room {
        return (title.to_string(), TITLE_SIZE);
    }
    let size = (TITLE_SIZE * room / full).max(TITLE_MIN_SIZE);
    if width(title, size) <= room {
        return (title.to_string(), size);
    }
    let mut text = title.to_string();
    loop {
        text.pop();
        let kept = text.trim_end_matches([' ', ',', ':']);
        let shortened = format!("{kept}\u{2026}");
        if kept.is_empty() || width(&shortened, size) <= room {
            return (shortened, size);
        }
    }
}

/// The one axis set-up of every figure: title, axis titles with units, tick labels, light grid.
fn axes<'a, DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    title: &str,
    x_label: &str,
    y_label: &str,
    (x0, x1): (f64, f64),
    (y0, y1): (f64, f64),
) -> Result<Axes<'a, DB>, String> {
    let (title, size) = fit_title(area, title);
    let mut chart = ChartBuilder::on(area)
        .caption(title, ("sans-serif", size))
        .margin(16)
        .x_label_area_size(70)
        .y_label_area_size(100)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc(x_label)
        .y_desc(y_label)
        .axis_desc_style(("sans-serif", 28))
        .label_style(("sans-serif", 22))
        .light_line_style(RGBColor(235, 235, 235))
        .draw()
        .map_err(err)?;
    Ok(chart)
}

/// `area` split into the plot (left) and its legend column (right).
fn with_legend<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>) -> (DrawingArea<DB, Shift>, DrawingArea<DB, Shift>) {
    let w = area.dim_in_pixel().0;
    area.split_horizontally(w.saturating_sub(LEGEND_WIDTH))
}

fn draw_lines<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, p: &Lines, cut_turns: bool) -> Result<(), String> {
    let (plot, legend) = with_legend(area);
    let x = range(p.series.iter().flat_map(|s| s.1.iter().map(|v| v.0)));
    let y = range(p.series.iter().flat_map(|s| s.1.iter().map(|v| v.1)));
    let mut chart = axes(&plot, &p.title, &p.x_label, &p.y_label, x, y)?;
    let style = BLACK.stroke_width(2);
    for &t in &p.marks {
        chart.draw_series(DashedLineSeries::new([(t, y.0), (t, y.1)], 12, 8, style)).map_err(err)?;
    }
    draw_series(&mut chart, &p.series, cut_turns)?;
    draw_legend(&legend, &p.series)
}

/// Pixel polylines that draw one unbroken curve given in pixel coordinates, with `pattern`
/// (on/off lengths \[px\]; `None` solid): a point closer than [`MIN_STEP`] to the last one kept is
/// dropped (detail finer than the line's width is invisible; a long run draws a few points per
/// pixel column, not every sample, and a jittering curve no zig-zag), the line cut wherever it turns by more than
/// 90 degrees (with `cut_turns`: for the bitmap; an SVG viewer limits its mitres itself, and
/// the cuts would multiply a jittering curve's elements), then cut into dashes, the pattern's phase carried along the whole curve. A
/// curve of one point comes back as one one-point polyline (a dot).
///
/// Why the cuts: plotters draws a thick line as one polygon whose joins are mitres without a
/// limit, so a noisy curve (a speed that jitters from sample to sample) drew thin spikes far
/// beyond its data, below 0 m/s and over the axis labels (issue 61). A polyline without turns
/// sharper than 90 degrees keeps every mitre within 0.71 line widths of its point.
pub fn strokes(points: &[(f64, f64)], pattern: Option<&[f64]>, cut_turns: bool) -> Vec<Vec<(f64, f64)>> {
    let mut pts: Vec<(f64, f64)> = Vec::with_capacity(points.len());
    for &p in points.iter().filter(|p| p.0.is_finite() && p.1.is_finite()) {
        if pts.last().is_none_or(|q: &(f64, f64)| (p.0 - q.0).hypot(p.1 - q.1) >= MIN_STEP) {
            pts.push(p);
        }
    }
    if pts.len() == 1 {
        return vec![pts];
    }
    let mut pieces: Vec<Vec<(f64, f64)>> = Vec::new();
    let mut cur: Vec<(f64, f64)> = Vec::new();
    for &p in &pts {
        if let [.., a, b] = cur[..]
            && cut_turns
            && (b.0 - a.0) * (p.0 - b.0) + (b.1 - a.1) * (p.1 - b.1) < 0.0
        {
            pieces.push(std::mem::replace(&mut cur, vec![b]));
        }
        cur.push(p);
    }
    if cur.len() >= 2 {
        pieces.push(cur);
    }
    let Some(pattern) = pattern.filter(|p| !p.is_empty() && p.iter().all(|&v| v > 0.0)) else { return pieces };
    // A curve that turns back at more than a quarter of its points (noise at the sampling
    // rate) shows no dashes, only a blur of thousands of them: it is drawn solid.
    let turns = pts
        .windows(3)
        .filter(|w| (w[1].0 - w[0].0) * (w[2].0 - w[1].0) + (w[1].1 - w[0].1) * (w[2].1 - w[1].1) < 0.0)
        .count();
    if turns * 4 > pts.len() {
        return pieces;
    }
    let mut out = Vec::new();
    let (mut k, mut left, mut on) = (0, pattern[0], true);
    for piece in pieces {
        let mut dash = if on { vec![piece[0]] } else { Vec::new() };
        for w in piece.windows(2) {
            let (a, b) = (w[0], w[1]);
            let len = (b.0 - a.0).hypot(b.1 - a.1);
            let mut s = 0.0;
            while len - s > left {
                s += left;
                let p = (a.0 + (b.0 - a.0) * s / len, a.1 + (b.1 - a.1) * s / len);
                if on {
                    dash.push(p);
                    out.push(std::mem::take(&mut dash));
                } else {
                    dash = vec![p];
                }
                on = !on;
                k = (k + 1) % pattern.len();
                left = pattern[k];
            }
            left -= len - s;
            if on {
                dash.push(b);
            }
        }
        if on && dash.len() >= 2 {
            out.push(dash);
        }
    }
    out
}

/// Shortest step \[px\] between the points of a drawn curve (see [`strokes`]).
pub const MIN_STEP: f64 = 2.0;

/// Line width of every curve [px].
const LINE_WIDTH: u32 = 3;

fn draw_series<DB: DrawingBackend>(chart: &mut Axes<'_, DB>, series: &[Series], cut_turns: bool) -> Result<(), String> {
    let area = chart.plotting_area();
    let (bx, by) = area.get_base_pixel();
    let pixels = area.strip_coord_spec();
    for (_, points, pen) in series {
        let style = pen.rgb().stroke_width(LINE_WIDTH);
        // A non-finite value breaks the curve (a vehicle that left, a lanelet change).
        for piece in points.split(|p| !(p.0.is_finite() && p.1.is_finite())) {
            let px: Vec<(f64, f64)> = piece
                .iter()
                .map(|p| {
                    let (x, y) = area.map_coordinate(p);
                    (f64::from(x - bx), f64::from(y - by))
                })
                .collect();
            for line in strokes(&px, pen.pattern(), cut_turns) {
                let line: Vec<(i32, i32)> = line.iter().map(|p| (p.0.round() as i32, p.1.round() as i32)).collect();
                if let [dot] = line[..] {
                    pixels.draw(&Circle::new(dot, LINE_WIDTH / 2 + 1, pen.rgb().filled())).map_err(err)?;
                } else {
                    pixels.draw(&PathElement::new(line, style)).map_err(err)?;
                }
            }
        }
    }
    Ok(())
}

/// The legend of `series` in its own column: at most [`MAX_LEGEND`] entries, then a count;
/// curves with an empty label share the entry of an earlier one.
fn draw_legend<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, series: &[Series]) -> Result<(), String> {
    let font = ("sans-serif", 22).into_font();
    let step = 32;
    let top = 80;
    let series: Vec<&Series> = series.iter().filter(|s| !s.0.is_empty()).collect();
    for (i, (label, _, pen)) in series.iter().take(MAX_LEGEND).enumerate() {
        let y = top + step * i as i32;
        for line in strokes(&[(8.0, f64::from(y)), (44.0, f64::from(y))], pen.pattern(), false) {
            let line: Vec<(i32, i32)> = line.iter().map(|p| (p.0.round() as i32, p.1.round() as i32)).collect();
            area.draw(&PathElement::new(line, pen.rgb().stroke_width(4))).map_err(err)?;
        }
        area.draw(&Text::new(label.clone(), (54, y - 11), font.clone())).map_err(err)?;
    }
    if series.len() > MAX_LEGEND {
        let y = top + step * MAX_LEGEND as i32;
        let more = format!("(+{} more)", series.len() - MAX_LEGEND);
        area.draw(&Text::new(more, (54, y - 11), font)).map_err(err)?;
    }
    Ok(())
}

/// Draw `chart` on `root`; `cut_turns` for a bitmap (see [`strokes`]).
fn draw_chart<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, chart: &Chart, cut_turns: bool) -> Result<(), String> {
    root.fill(&WHITE).map_err(err)?;
    match chart {
        Chart::Panels(panels) => {
            let areas = root.split_evenly((panels.len().max(1), 1));
            for (area, p) in areas.iter().zip(panels) {
                draw_lines(area, p, cut_turns)?;
            }
        }
        Chart::Trace { title, roads, series, collisions } => {
            let (plot, legend) = with_legend(&root);
            let all = roads
                .iter()
                .flatten()
                .copied()
                .chain(series.iter().flat_map(|s| s.1.iter().map(|&(x, y)| DVec2::new(x, y))));
            let pts: Vec<DVec2> = all.collect();
            let (pw, ph) = plot.dim_in_pixel();
            let (x, y, to_scale) = trace_axes(&pts, (f64::from(pw - 130), f64::from(ph - 150)));
            let title = if to_scale { title.clone() } else { format!("{title} (axes not to scale)") };
            let mut chart = axes(&plot, &title, "x [m]", "y [m]", x, y)?;
            let road = RGBColor(200, 200, 200);
            chart
                .draw_series(
                    roads
                        .iter()
                        .map(|poly| Polygon::new(poly.iter().map(|p| (p.x, p.y)).collect::<Vec<_>>(), road.filled())),
                )
                .map_err(err)?;
            draw_series(&mut chart, series, cut_turns)?;
            chart
                .draw_series(collisions.iter().map(|p| Circle::new((p.x, p.y), 14, RED.stroke_width(4))))
                .map_err(err)?;
            draw_legend(&legend, series)?;
        }
        Chart::TimeSpace { title, lanes, v_max } => {
            let (plot, legend) = with_legend(&root);
            let x = range(lanes.iter().flat_map(|l| l.1.iter().map(|p| p.0)));
            let y = range(lanes.iter().flat_map(|l| l.1.iter().map(|p| p.1)));
            let areas = plot.split_evenly((lanes.len().max(1), 1));
            for (k, (area, (lane, points))) in areas.iter().zip(lanes).enumerate() {
                let caption = if k == 0 { format!("{title}: {lane}") } else { lane.clone() };
                let chart = axes(area, &caption, "time [s]", "position [m]", x, y)?;
                let plotting = chart.plotting_area();
                let (bx, by) = plotting.get_base_pixel();
                let pixels = plotting.strip_coord_spec();
                // One dot per pixel and colour: a long run does not draw every sample.
                let mut seen = std::collections::HashSet::new();
                for &(t, s, v) in points {
                    let (px, py) = plotting.map_coordinate(&(t, s));
                    let color = speed_color(v / v_max);
                    if seen.insert((px, py, color.0, color.1)) {
                        pixels.draw(&Circle::new((px - bx, py - by), 2, color.filled())).map_err(err)?;
                    }
                }
            }
            draw_speed_scale(&legend, *v_max)?;
        }
    }
    root.present().map_err(err)
}

/// Colour of a speed `f` (a fraction of the run's top speed, clamped to [0, 1]) in a
/// time-space diagram: red (standing) through yellow to green (free flow), the traffic
/// engineer's reading of a jam.
pub fn speed_color(f: f64) -> RGBColor {
    const STOPS: [(f64, [f64; 3]); 3] =
        [(0.0, [215.0, 25.0, 28.0]), (0.5, [250.0, 200.0, 0.0]), (1.0, [26.0, 150.0, 65.0])];
    let f = if f.is_finite() { f.clamp(0.0, 1.0) } else { 0.0 };
    let k = usize::from(f > 0.5);
    let (a, b) = (STOPS[k], STOPS[k + 1]);
    let u = (f - a.0) / (b.0 - a.0);
    let c = |i: usize| (a.1[i] + (b.1[i] - a.1[i]) * u).round() as u8;
    RGBColor(c(0), c(1), c(2))
}

/// The speed scale of a time-space diagram in its legend column: a bar from 0 to `v_max`.
fn draw_speed_scale<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, v_max: f64) -> Result<(), String> {
    let font = ("sans-serif", 22).into_font();
    let (top, height) = (90, 400);
    area.draw(&Text::new("speed [m/s]", (8, top - 50), font.clone())).map_err(err)?;
    for i in 0..height {
        let f = 1.0 - f64::from(i) / f64::from(height - 1);
        area.draw(&Rectangle::new([(10, top + i), (50, top + i + 1)], speed_color(f).filled())).map_err(err)?;
    }
    for (f, y) in [(1.0, top), (0.5, top + height / 2), (0.0, top + height)] {
        area.draw(&Text::new(format!("{:.1}", f * v_max), (60, y - 11), font.clone())).map_err(err)?;
    }
    Ok(())
}

/// Most a trace's axes may differ in scale and still be drawn to equal scale: a road longer
/// than this many times its width (the 2 km GCDC road, 10 m wide) gets axes of their own
/// scales, or its lane changes would be invisible (issue 61).
pub const MAX_TRACE_STRETCH: f64 = 4.0;

/// The x and y ranges of a trace of `points` in a plot of `(w, h)` px and whether they are to
/// equal scale: equal scale (the narrower axis widened to the plot's aspect) unless that would
/// squeeze the data into less than 1 / [`MAX_TRACE_STRETCH`] of one axis.
pub fn trace_axes(points: &[DVec2], (w, h): (f64, f64)) -> ((f64, f64), (f64, f64), bool) {
    let (x0, x1) = range(points.iter().map(|p| p.x));
    let (y0, y1) = range(points.iter().map(|p| p.y));
    let (sx, sy) = ((x1 - x0) / w, (y1 - y0) / h);
    if sx.max(sy) > MAX_TRACE_STRETCH * sx.min(sy) {
        return ((x0, x1), (y0, y1), false);
    }
    let scale = sx.max(sy);
    let (cx, cy) = ((x0 + x1) / 2.0, (y0 + y1) / 2.0);
    ((cx - scale * w / 2.0, cx + scale * w / 2.0), (cy - scale * h / 2.0, cy + scale * h / 2.0), true)
}

/// Write `chart` as `dir/name.png` and `dir/name.svg`; returns the PNG path.
fn save(dir: &FsPath, name: &str, chart: &Chart) -> Result<PathBuf, ReplayError> {
    let (w, h) = FIGURE_SIZE;
    let png = dir.join(format!("{name}.png"));
    let svg = dir.join(format!("{name}.svg"));
    let plot_err =
        |path: &FsPath, message: String| ReplayError::Option(format!("drawing {}: {message}", path.display()));
    let mut buffer = vec![0u8; (w * h * 3) as usize];
    draw_chart(BitMapBackend::with_buffer(&mut buffer, (w, h)).into_drawing_area(), chart, true)
        .map_err(|m| plot_err(&png, m))?;
    let image = image::RgbImage::from_raw(w, h, buffer).ok_or_else(|| plot_err(&png, "buffer size".into()))?;
    // Both written aside and renamed into place: a failed plot keeps the earlier figure.
    let png_file = AtomicFile::new(&png).map_err(|e| plot_err(&png, e.to_string()))?;
    image.save_with_format(png_file.path(), image::ImageFormat::Png).map_err(|e| plot_err(&png, e.to_string()))?;
    png_file.commit().map_err(|e| plot_err(&png, e.to_string()))?;
    let svg_file = AtomicFile::new(&svg).map_err(|e| plot_err(&svg, e.to_string()))?;
    draw_chart(SVGBackend::new(svg_file.path(), (w, h)).into_drawing_area(), chart, false)
        .map_err(|m| plot_err(&svg, m))?;
    svg_file.commit().map_err(|e| plot_err(&svg, e.to_string()))?;
    Ok(png)
}

fn read_rows(out_dir: &FsPath) -> Result<BTreeMap<i32, Vec<Row>>, ReplayError> {
    let path = out_dir.join("trajectories.csv");
    let text = std::fs::read_to_string(&path).map_err(|source| ReplayError::Io { path: path.clone(), source })?;
    let mut rows: BTreeMap<i32, Vec<Row>> = BTreeMap::new();
    for (i, line) in text.lines().enumerate().skip(1) {
        let bad = |message: String| ReplayError::Row { path: path.clone(), line: i + 1, message };
        let f: Vec<&str> = line.split(',').collect();
        if f.len() != 7 && f.len() != 9 {
            return Err(bad(format!("{} fields", f.len())));
        }
        let num = |k: usize| f[k].parse::<f64>().map_err(|_| bad(format!("{:?} is not a number", f[k])));
        let id = f[1].parse::<i32>().map_err(|_| bad(format!("id {:?} is not an integer", f[1])))?;
        // Off the map the lane columns are empty.
        let lane = if f.len() == 9 && !f[7].is_empty() && !f[8].is_empty() { Some((num(7)?, num(8)?)) } else { None };
        rows.entry(id).or_default().push(Row {
            t: num(0)?,
            position: DVec2::new(num(2)?, num(3)?),
            velocity: DVec2::new(num(5)?, num(6)?),
            lane,
        });
    }
    Ok(rows)
}

fn label(id: i32) -> String {
    format!("vehicle {id}")
}

/// Smallest drop below a vehicle's top speed, as a share of it, that a title names as the run's
/// event (a platoon settling its gaps in the first second slows by about 7 %).
pub const MIN_EVENT_DROP: f64 = 0.15;

/// Farthest a sample may lie from the road of a time-space diagram and be drawn on it \[m\].
pub const ROAD_REACH: f64 = 12.0;
/// Most samples of one vehicle in a time-space diagram.
pub const TIME_SPACE_SAMPLES: usize = 1000;
/// Most lanes (panels) of a time-space diagram, from the right.
pub const TIME_SPACE_LANES: usize = 4;

/// A finished run as the figures read it.
struct RunData {
    info: crate::app::running::summary::ReplayInfo,
    rows: BTreeMap<i32, Vec<Row>>,
    summary: serde_json::Value,
    map: Option<LaneletMap>,
    /// Pen of each vehicle, by id order.
    pens: BTreeMap<i32, Pen>,
}

impl RunData {
    fn read(out_dir: &FsPath) -> Result<RunData, ReplayError> {
        let info = read_replay_info(out_dir)?;
        let rows = read_rows(out_dir)?;
        let summary_path = out_dir.join("summary.json");
        let summary: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(&summary_path)
                .map_err(|source| ReplayError::Io { path: summary_path.clone(), source })?,
        )
        .map_err(|e| ReplayError::Summary { path: summary_path.clone(), message: e.to_string() })?;
        let map = match &info.map {
            Some(path) => Some(
                LaneletMap::load(path).map_err(|e| ReplayError::Map { path: path.clone(), message: e.to_string() })?,
            ),
            None => None,
        };
        let pens = rows.keys().enumerate().map(|(k, &id)| (id, pen(k))).collect();
        Ok(RunData { info, rows, summary, map, pens })
    }

    /// The rows of every vehicle but stationary obstacles (parked cars, road boundaries: a flat
    /// line in every figure; collisions with them are still marked).
    fn moving(&self) -> impl Iterator<Item = (&i32, &Vec<Row>)> {
        self.rows.iter().filter(|(id, _)| !self.info.vehicles.iter().any(|v| v.id == **id && v.stationary))
    }

    /// The pen of vehicle `id` in every figure of this run: the vehicles take [`pen`]s in id
    /// order (the legend's order), so up to 20 vehicles have a colour each.
    fn pen(&self, id: i32) -> Pen {
        self.pens.get(&id).copied().unwrap_or(Pen { color: [0, 0, 0], dash: 0 })
    }

    fn speed(&self, id: i32) -> Vec<(f64, f64)> {
        self.rows.get(&id).map_or(Vec::new(), |r| r.iter().map(|r| (r.t, r.velocity.length())).collect())
    }

    /// (follower, leader) pairs of `metrics.followers`.
    fn followers(&self) -> Vec<(i32, i32)> {
        self.summary["metrics"]["followers"]
            .as_array()
            .map(|a| a.iter().filter_map(|f| Some((f["id"].as_i64()? as i32, f["leader"].as_i64()? as i32))).collect())
            .unwrap_or_default()
    }

    /// Bumper-to-bumper gap [m] and time gap [s] of `follower` to `leader` over time.
    fn gaps(&self, follower: i32, leader: i32) -> Option<(Curve, Curve)> {
        let (fr, lr) = (self.rows.get(&follower)?, self.rows.get(&leader)?);
        let length = |id: i32| self.info.vehicles.iter().find(|v| v.id == id).map_or(0.0, |v| v.length);
        let half = (length(follower) + length(leader)) / 2.0;
        let gap: Vec<(f64, f64)> =
            fr.iter().zip(lr).map(|(a, b)| (a.t, a.position.distance(b.position) - half)).collect();
        let tg = fr
            .iter()
            .zip(&gap)
            .filter(|(a, _)| a.velocity.length() > 0.5)
            .map(|(a, g)| (a.t, g.1 / a.velocity.length()))
            .collect();
        Some((gap, tg))
    }

    /// Each vehicle's distance from the nearest routable lanelet centre line over time [m].
    fn lateral(&self) -> Option<Vec<(i32, Curve)>> {
        let map = self.map.as_ref()?;
        let centres: Vec<&[DVec2]> = map.lanelets.iter().filter(|l| l.routable).map(|l| l.centre.as_slice()).collect();
        Some(
            self.moving()
                .map(|(&id, r)| {
                    let d = r
                        .iter()
                        .map(|r| {
                            let nearest = centres.iter().map(|c| project_polyline(c, r.position).1);
                            (r.t, nearest.fold(f64::INFINITY, f64::min))
                        })
                        .collect();
                    (id, d)
                })
                .collect(),
        )
    }

    /// The samples of a time-space diagram, per lane: (t, position along the road [m], speed
    /// [m/s]). The road is the path of the vehicle that drove farthest, up to its first return
    /// to where it started (one lap of a ring); positions are arc lengths of each sample's
    /// projection on it, and samples more than [`ROAD_REACH`] from it (vehicles on other roads)
    /// are left out. Lanes are counted from the right (by the map's right neighbours; one lane
    /// without a map). At most [`TIME_SPACE_SAMPLES`] samples per vehicle. `None` when no
    /// vehicle moved.
    fn time_space(&self) -> Option<Vec<(usize, Samples)>> {
        let travelled = |r: &[Row]| r.windows(2).map(|w| w[0].position.distance(w[1].position)).sum::<f64>();
        let (_, far) = self.moving().max_by(|a, b| travelled(a.1).total_cmp(&travelled(b.1)).then(b.0.cmp(a.0)))?;
        let start = far.first()?.position;
        let mut road: Vec<DVec2> = vec![start];
        let mut length = 0.0;
        for r in far {
            let last = *road.last()?;
            if r.position.distance(last) >= 1.0 {
                length += r.position.distance(last);
                road.push(r.position);
                if length > 20.0 && r.position.distance(start) < 5.0 {
                    road.push(start);
                    break;
                }
            }
        }
        if road.len() < 2 {
            return None;
        }
        // Lane index of each lanelet: right-neighbour hops to the rightmost lane.
        let lane_of: std::collections::HashMap<i64, usize> = match &self.map {
            Some(map) => {
                let neighbours = map.neighbours();
                map.lanelets
                    .iter()
                    .enumerate()
                    .map(|(i, l)| {
                        let (mut k, mut at) = (0, i);
                        while let Some(right) = neighbours[at].right.and_then(|r| map.lanelet_index(r)) {
                            k += 1;
                            at = right;
                            if k > map.lanelets.len() {
                                break;
                            }
                        }
                        (l.id.0, k)
                    })
                    .collect()
            }
            None => Default::default(),
        };
        let mut lanes: BTreeMap<usize, Samples> = BTreeMap::new();
        for (_, rows) in self.moving() {
            let stride = rows.len().div_ceil(TIME_SPACE_SAMPLES).max(1);
            for r in rows.iter().step_by(stride) {
                let (s, d) = project_polyline(&road, r.position);
                if d > ROAD_REACH {
                    continue;
                }
                let lane = r.lane.and_then(|l| lane_of.get(&(l.0 as i64)).copied()).unwrap_or(0);
                lanes.entry(lane).or_default().push((r.t, s, r.velocity.length()));
            }
        }
        Some(lanes.into_iter().collect())
    }

    /// Ids of the vehicles that changed lanes (`metrics.lane_changes`), in id order.
    fn lane_changers(&self) -> Vec<i32> {
        let mut ids: Vec<i32> = self.summary["metrics"]["lane_changes"]
            .as_array()
            .into_iter()
            .flatten()
            .filter_map(|l| l["id"].as_i64().map(|v| v as i32))
            .collect();
        ids.sort_unstable();
        ids.dedup();
        ids
    }

    /// What the run's figures show, in words, for their titles: the first vehicle to slow down
    /// markedly (by at least half the largest drop of any vehicle, 0.5 m/s and
    /// [`MIN_EVENT_DROP`] of its speed: a follower settling into its gap at start-up is no
    /// event), the
    /// collisions and the lane changes; "steady speeds" when nothing changed.
    fn disturbance(&self) -> String {
        // Per vehicle: largest drop below its running maximum [m/s], from and to [m/s], and
        // when it began (the first time 0.5 m/s under that maximum) [s].
        let drops: Vec<(i32, f64, f64, f64, f64)> = self
            .rows
            .iter()
            .filter_map(|(&id, r)| {
                let (mut peak, mut peak_at) = (f64::NEG_INFINITY, 0);
                let mut best: Option<(f64, f64, f64, usize)> = None;
                for (k, row) in r.iter().enumerate() {
                    let v = row.velocity.length();
                    if v > peak {
                        (peak, peak_at) = (v, k);
                    }
                    if best.is_none_or(|b| peak - v > b.0) {
                        best = Some((peak - v, peak, v, peak_at));
                    }
                }
                let (d, from, to, at) = best?;
                let began = r[at..].iter().find(|row| row.velocity.length() < from - 0.5).map_or(r[at].t, |row| row.t);
                Some((id, d, from, to, began))
            })
            .collect();
        let largest = drops.iter().map(|d| d.1).fold(0.0, f64::max);
        let mut parts = Vec::new();
        // The first to slow markedly is where the disturbance came from (the others react to it).
        let first = drops
            .iter()
            .filter(|d| largest >= 0.5 && d.1 >= 0.5 * largest && d.1 >= MIN_EVENT_DROP * d.2)
            .min_by(|a, b| a.4.total_cmp(&b.4).then(a.0.cmp(&b.0)));
        match first {
            Some(&(id, _, from, to, t)) => {
                parts.push(format!("vehicle {id} slows from {from:.1} to {to:.1} m/s at {t:.1} s"))
            }
            None => parts.push("steady speeds".to_string()),
        }
        let collisions = self.summary["metrics"]["collision_count"].as_u64().unwrap_or(0);
        if collisions > 0 {
            parts.push(format!("{collisions} collision{}", if collisions == 1 { "" } else { "s" }));
        }
        let changes = self.summary["metrics"]["lane_changes"].as_array().map_or(0, Vec::len);
        if changes > 0 {
            parts.push(format!("{changes} lane change{}", if changes == 1 { "" } else { "s" }));
        }
        parts.join(", ")
    }
}

fn time_lines(title: &str, y: &str, series: Vec<Series>) -> Lines {
    Lines { title: title.into(), x_label: "time [s]".into(), y_label: y.into(), series, marks: Vec::new() }
}

/// Write the figures of the run in `out_dir` into `dest` (created); returns the PNG paths.
/// Every vehicle has one colour in every figure (the colour of its id label in the view), and
/// every title says what disturbance the run shows.
pub fn plot_run(out_dir: &FsPath, dest: &FsPath) -> Result<Vec<PathBuf>, ReplayError> {
    register_font();
    let run = RunData::read(out_dir)?;
    std::fs::create_dir_all(dest).map_err(|source| ReplayError::Io { path: dest.to_path_buf(), source })?;
    let what = run.disturbance();
    let titled = |name: &str| format!("{name}: {what}");
    let mut written = Vec::new();

    let speeds: Vec<Series> = run.moving().map(|(&id, _)| (label(id), run.speed(id), run.pen(id))).collect();
    written.push(save(dest, "speed", &Chart::Panels(vec![time_lines(&titled("Speed"), "speed [m/s]", speeds)]))?);

    let followers = run.followers();
    if !followers.is_empty() {
        let (mut gaps, mut time_gaps) = (Vec::new(), Vec::new());
        for &(f, l) in &followers {
            let Some((gap, tg)) = run.gaps(f, l) else { continue };
            gaps.push((format!("{f} behind {l}"), gap, run.pen(f)));
            time_gaps.push((format!("{f} behind {l}"), tg, run.pen(f)));
        }
        let panels = vec![
            time_lines(&titled("Gap to the leader"), "gap [m]", gaps),
            time_lines(&titled("Time gap to the leader"), "time gap [s]", time_gaps),
        ];
        written.push(save(dest, "gaps", &Chart::Panels(panels))?);
    }

    for p in run.summary["metrics"]["platoons"].as_array().into_iter().flatten() {
        let members: Vec<i32> =
            p["members"].as_array().into_iter().flatten().filter_map(|m| m.as_i64()).map(|m| m as i32).collect();
        let Some(&leader) = members.first() else { continue };
        let series = members
            .iter()
            .enumerate()
            .map(|(k, &m)| (format!("{} {m}", if k == 0 { "leader" } else { "member" }), run.speed(m), run.pen(m)))
            .collect();
        let title = titled(&format!("Platoon {leader}, speed of each member"));
        written.push(save(
            dest,
            &format!("platoon_{leader}"),
            &Chart::Panels(vec![time_lines(&title, "speed [m/s]", series)]),
        )?);
    }

    if let Some(lateral) = run.lateral() {
        let series = lateral.into_iter().map(|(id, d)| (label(id), d, run.pen(id))).collect();
        let title = titled("Distance from the nearest centre line");
        written.push(save(dest, "lateral", &Chart::Panels(vec![time_lines(&title, "lateral deviation [m]", series)]))?);
    }

    let merge = &run.summary["metrics"]["merge"];
    let order: Vec<i32> =
        merge["order"].as_array().into_iter().flatten().filter_map(|v| v.as_i64()).map(|v| v as i32).collect();
    if order.len() >= 2 {
        let merges = merge["merges"].as_array().into_iter().flatten();
        let instants: Vec<f64> = merges.clone().filter_map(|m| m["t"].as_f64()).collect();
        let mergers: Vec<i64> = merges.filter_map(|m| m["id"].as_i64()).collect();
        let role = |id: i32| if mergers.contains(&i64::from(id)) { "merger" } else { "gap maker" };
        let length = |id: i32| run.info.vehicles.iter().find(|v| v.id == id).map_or(0.0, |v| v.length);
        let mut gaps = Vec::new();
        for pair in order.windows(2) {
            let (lead, me) = (pair[0], pair[1]);
            let (Some(mr), Some(lr)) = (run.rows.get(&me), run.rows.get(&lead)) else { continue };
            let half = (length(me) + length(lead)) / 2.0;
            // Along the road: the offset projected on our own heading (the lanes are side by side).
            let gap = mr
                .iter()
                .zip(lr)
                .map(|(a, b)| {
                    let heading = if a.velocity.length() > 0.1 { a.velocity.normalize() } else { DVec2::X };
                    (a.t, (b.position - a.position).dot(heading) - half)
                })
                .collect();
            gaps.push((format!("{me} behind {lead}"), gap, run.pen(me)));
        }
        let speeds = order.iter().map(|&id| (format!("{id} ({})", role(id)), run.speed(id), run.pen(id))).collect();
        let panels = vec![
            Lines {
                marks: instants.clone(),
                ..time_lines("Gap to the vehicle ahead in the merged order (dashed: merges)", "gap [m]", gaps)
            },
            Lines { marks: instants, ..time_lines("Speeds of both platoons (dashed: merges)", "speed [m/s]", speeds) },
        ];
        written.push(save(dest, "merge", &Chart::Panels(panels))?);
    }

    let changers = run.lane_changers();
    if !changers.is_empty() {
        let lane = |k: usize| -> Vec<Series> {
            changers
                .iter()
                .filter_map(|&id| {
                    let r = run.rows.get(&id)?;
                    // A break (NaN) where the lanelet changes: no line joins two lanelets'
                    // values (the offset jumps from one centre line to the next).
                    let mut pts = Vec::new();
                    let mut last = None;
                    for (t, l) in r.iter().filter_map(|r| Some((r.t, r.lane?))) {
                        if last.is_some_and(|id| id != l.0) {
                            pts.push((t, f64::NAN));
                        }
                        last = Some(l.0);
                        pts.push((t, if k == 0 { l.0 } else { l.1 }));
                    }
                    Some((label(id), pts, run.pen(id)))
                })
                .collect()
        };
        let panels = vec![
            time_lines(&titled("Lanelet under each vehicle that changed lanes"), "lanelet id [-]", lane(0)),
            time_lines(&titled("Offset from that lanelet's centre line"), "lane offset [m] (left +)", lane(1)),
        ];
        written.push(save(dest, "lanes", &Chart::Panels(panels))?);
    }

    if let Some(lanes) = run.time_space() {
        let v_max = lanes.iter().flat_map(|l| l.1.iter().map(|p| p.2)).fold(0.0, f64::max).max(1.0);
        let count = lanes.len();
        let lanes: Vec<(String, Samples)> = lanes
            .into_iter()
            .take(TIME_SPACE_LANES)
            .map(|(k, points)| {
                let name = match (k, count) {
                    (_, 1) => "every lane".to_string(),
                    (0, _) => "lane 1 (rightmost)".to_string(),
                    (k, _) => format!("lane {}", k + 1),
                };
                (name, points)
            })
            .collect();
        let title = titled("Time-space diagram, dots coloured by speed");
        written.push(save(dest, "time_space", &Chart::TimeSpace { title, lanes, v_max })?);
    }

    let roads = run.map.as_ref().map_or(Vec::new(), |m| m.lanelets.iter().map(|l| l.polygon()).collect());
    let traces = run
        .moving()
        .map(|(&id, r)| (label(id), r.iter().map(|r| (r.position.x, r.position.y)).collect(), run.pen(id)))
        .collect();
    let collisions = run.summary["metrics"]["collisions"]
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(|c| {
            let (a, t) = (c["a"].as_i64()? as i32, c["t"].as_f64()?);
            let r = run.rows.get(&a)?;
            r.iter().min_by(|p, q| (p.t - t).abs().total_cmp(&(q.t - t).abs())).map(|r| r.position)
        })
        .collect();
    let title = titled("Trajectories over the map");
    written.push(save(dest, "trace", &Chart::Trace { title, roads, series: traces, collisions })?);
    Ok(written)
}

/// Colours of the runs of [`plot_compare`], one per run (readable on white).
const RUN_COLORS: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 140, 44),
    RGBColor(148, 83, 189),
    RGBColor(220, 105, 0),
    RGBColor(90, 90, 90),
    RGBColor(0, 128, 128),
    RGBColor(200, 40, 150),
];

/// The legend name of a run: its sweep parameters when its folder holds a `params.json` object
/// (`key=value, ...`), else the folder's name.
fn run_name(out_dir: &FsPath) -> String {
    let params = std::fs::read_to_string(out_dir.join("params.json"))
        .ok()
        .and_then(|t| serde_json::from_str::<serde_json::Map<String, serde_json::Value>>(&t).ok());
    match params {
        Some(p) if !p.is_empty() => p.iter().map(|(k, v)| format!("{k}={v}")).collect::<Vec<_>>().join(", "),
        _ => out_dir.file_name().map_or_else(|| out_dir.display().to_string(), |n| n.to_string_lossy().into_owned()),
    }
}

/// Overlay the same figures of several runs (`smlworld plot --compare DIR1 DIR2 ...`) in `dest`:
/// `compare_speed` (every vehicle), `compare_gaps` (every follower, when the runs have any) and
/// `compare_lateral` (runs on a map), one colour per run, the legend naming each run once (its
/// sweep parameters or folder name). Returns the PNG paths.
pub fn plot_compare(out_dirs: &[PathBuf], dest: &FsPath) -> Result<Vec<PathBuf>, ReplayError> {
    register_font();
    if out_dirs.len() < 2 {
        return Err(ReplayError::Option(format!("--compare needs at least two run folders, got {}", out_dirs.len())));
    }
    let runs: Vec<(String, RunData)> =
        out_dirs.iter().map(|d| Ok((run_name(d), RunData::read(d)?))).collect::<Result<_, ReplayError>>()?;
    std::fs::create_dir_all(dest).map_err(|source| ReplayError::Io { path: dest.to_path_buf(), source })?;
    let names: Vec<&str> = runs.iter().map(|(n, _)| n.as_str()).collect();
    let title = |what: &str| format!("{what}: {}", names.join(" vs "));
    // One legend entry per run (its first curve); the other curves of the run share its colour.
    let per_run = |curves: &dyn Fn(&RunData) -> Vec<Curve>| -> Vec<Series> {
        let mut series = Vec::new();
        for (k, (name, run)) in runs.iter().enumerate() {
            let color = Pen::solid(RUN_COLORS[k % RUN_COLORS.len()]);
            for (i, pts) in curves(run).into_iter().enumerate() {
                series.push((if i == 0 { name.clone() } else { String::new() }, pts, color));
            }
        }
        series
    };
    let mut written = Vec::new();
    let speeds = per_run(&|run| run.moving().map(|(&id, _)| run.speed(id)).collect());
    written.push(save(
        dest,
        "compare_speed",
        &Chart::Panels(vec![time_lines(&title("Speed"), "speed [m/s]", speeds)]),
    )?);
    let gaps = per_run(&|run| run.followers().iter().filter_map(|&(f, l)| run.gaps(f, l).map(|g| g.0)).collect());
    if !gaps.is_empty() {
        let panel = time_lines(&title("Gap to the leader"), "gap [m]", gaps);
        written.push(save(dest, "compare_gaps", &Chart::Panels(vec![panel]))?);
    }
    let lateral = per_run(&|run| run.lateral().unwrap_or_default().into_iter().map(|(_, d)| d).collect());
    if !lateral.is_empty() {
        let panel = time_lines(&title("Distance from the nearest centre line"), "lateral deviation [m]", lateral);
        written.push(save(dest, "compare_lateral", &Chart::Panels(vec![panel]))?);
    }
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Pixels of `color` in a 1600 x 1000 bitmap of `chart` drawn with or without the cuts.
    fn pixels_of(chart: &Chart, color: [u8; 3], cut_turns: bool) -> Vec<(u32, u32)> {
        register_font();
        let (w, h) = FIGURE_SIZE;
        let mut buffer = vec![0u8; (w * h * 3) as usize];
        draw_chart(BitMapBackend::with_buffer(&mut buffer, (w, h)).into_drawing_area(), chart, cut_turns).unwrap();
        let image = image::RgbImage::from_raw(w, h, buffer).unwrap();
        // Left of the legend column (which shows each colour too).
        image
            .enumerate_pixels()
            .filter(|(x, _, p)| p.0 == color && *x < w - LEGEND_WIDTH)
            .map(|(x, y, _)| (x, y))
            .collect()
    }

    /// A speed that jitters between 1.0 and 1.2 m/s every sample (a stop-and-go ring's speed
    /// at 10 Hz), with one dip to 0.5: no drawn pixel lies far outside the values' rows.
    #[test]
    fn a_jittering_curve_draws_no_spikes_beyond_its_data() {
        let points: Curve =
            (0..2000).map(|k| (k as f64 * 0.1, if k == 1000 { 0.5 } else { 1.0 + 0.2 * (k % 2) as f64 })).collect();
        let reference = vec![(0.0, 0.0), (200.0, 0.0), (200.0, 2.0)];
        let pen = Pen { color: PALETTE[3], dash: 0 };
        let other = Pen { color: PALETTE[0], dash: 0 };
        let chart = |series: Vec<Series>| Chart::Panels(vec![time_lines("Speed", "speed [m/s]", series)]);
        // The y rows of 0 m/s and 2 m/s from a reference curve drawn alone: its corners.
        let corners = pixels_of(&chart(vec![("ref".into(), reference.clone(), other)]), other.color, true);
        let row_of_0 = corners.iter().map(|p| p.1).max().unwrap();
        let row_of_2 = corners.iter().map(|p| p.1).min().unwrap();
        let row = |v: f64| f64::from(row_of_0) + (v / 2.0) * (f64::from(row_of_2) - f64::from(row_of_0));
        let figure = chart(vec![("jitter".into(), points.clone(), pen), ("ref".into(), reference.clone(), other)]);
        let drawn = pixels_of(&figure, pen.color, true);
        assert!(drawn.len() > 2000, "{} pixels", drawn.len());
        let (low, high) = (row(0.5) + 3.0, row(1.2) - 3.0);
        let outside: Vec<_> = drawn.iter().filter(|p| f64::from(p.1) > low || f64::from(p.1) < high).collect();
        assert!(
            outside.is_empty(),
            "{} pixels beyond rows {high:.0}..{low:.0}: {:?}",
            outside.len(),
            &outside[..outside.len().min(5)]
        );
        // Plotters' own mitres (no cuts) do spike: the test sees what it guards against.
        let uncut = pixels_of(&figure, pen.color, false);
        assert!(uncut.iter().any(|p| f64::from(p.1) > low || f64::from(p.1) < high), "uncut curve drew no spike");
    }

    #[test]
    fn strokes_turn_by_at_most_90_degrees_and_dash_along_the_curve() {
        let zigzag: Vec<(f64, f64)> = (0..50).map(|k| (k as f64 * 3.0, if k % 2 == 0 { 0.0 } else { 40.0 })).collect();
        let lines = strokes(&zigzag, None, true);
        assert!(lines.len() >= 49, "{} pieces", lines.len());
        for line in &lines {
            for w in line.windows(3) {
                let (a, b, c) = (w[0], w[1], w[2]);
                assert!((b.0 - a.0) * (c.0 - b.0) + (b.1 - a.1) * (c.1 - b.1) >= 0.0, "sharp turn at {b:?}");
            }
        }
        // Points closer than MIN_STEP merge; a lone point is a dot.
        assert_eq!(strokes(&[(1.0, 1.0), (1.5, 1.2)], None, true), vec![vec![(1.0, 1.0)]]);
        // A 100 px line dashed 14 on / 8 off: 5 dashes, each 14 px but the last (100 = 4 * 22 + 12).
        let dashes = strokes(&[(0.0, 0.0), (100.0, 0.0)], Some(&[14.0, 8.0]), true);
        let lengths: Vec<f64> = dashes.iter().map(|d| d.last().unwrap().0 - d[0].0).collect();
        assert_eq!(lengths.len(), 5, "{dashes:?}");
        for l in &lengths[..4] {
            assert!((l - 14.0).abs() < 1e-9, "{lengths:?}");
        }
        assert!((lengths[4] - 12.0).abs() < 1e-9, "{lengths:?}");
    }

    #[test]
    fn twenty_vehicles_have_twenty_colours_then_colour_and_dash_differ() {
        let pens: Vec<Pen> = (0..60).map(pen).collect();
        for i in 0..20 {
            for j in 0..i {
                let (a, b) = (pens[i].color, pens[j].color);
                let d: f64 = (0..3).map(|c| (f64::from(a[c]) - f64::from(b[c])).powi(2)).sum::<f64>().sqrt();
                assert!(d > 60.0, "colours {j} and {i} too close: {a:?} {b:?}");
                assert_ne!(pens[i], pens[j]);
            }
        }
        for i in 20..60 {
            for j in 0..i {
                assert_ne!(pens[i], pens[j], "vehicles {j} and {i} drawn alike");
            }
        }
        assert!(pens[20].pattern().is_some() && pens[0].pattern().is_none());
    }

    #[test]
    fn long_titles_shrink_or_shorten_to_fit_their_panel() {
        register_font();
        let mut buffer = vec![0u8; 1300 * 500 * 3];
        let area = BitMapBackend::with_buffer(&mut buffer, (1300, 500)).into_drawing_area();
        let short = fit_title(&area, "Speed");
        assert_eq!(short, ("Speed".to_string(), TITLE_SIZE));
        let long = "Lanelet under each vehicle that changed lanes: vehicle -3 slows from 22.2 to 11.7 m/s at 3.9 s, 5 lane changes, 2 collisions";
        let (text, size) = fit_title(&area, long);
        assert!((TITLE_MIN_SIZE..TITLE_SIZE).contains(&size), "{size}");
        let width = area.estimate_text_size(&text, &("sans-serif", size).into_text_style(&area)).unwrap().0;
        assert!(f64::from(width) <= 1300.0 - 40.0, "{text:?} is {width} px wide");
        let endless = long.repeat(4);
        let (text, _) = fit_title(&area, &endless);
        assert!(text.ends_with('\u{2026}') && text.len() < endless.len(), "{text}");
    }

    #[test]
    fn a_long_road_gets_axes_of_their_own_a_square_town_equal_ones() {
        let road: Vec<DVec2> = (0..=200).map(|k| DVec2::new(k as f64 * 10.0, (k % 2) as f64 * 7.0)).collect();
        let (x, y, to_scale) = trace_axes(&road, (1170.0, 850.0));
        assert!(!to_scale);
        assert!(y.1 - y.0 < 10.0 && x.1 - x.0 > 2000.0, "{x:?} {y:?}");
        let town: Vec<DVec2> = vec![DVec2::new(0.0, 0.0), DVec2::new(400.0, 300.0)];
        let (x, y, to_scale) = trace_axes(&town, (1170.0, 850.0));
        assert!(to_scale);
        assert!(((x.1 - x.0) / 1170.0 - (y.1 - y.0) / 850.0).abs() < 1e-9, "{x:?} {y:?}");
    }

    #[test]
    fn speed_colours_run_from_red_at_rest_to_green_at_top_speed() {
        assert_eq!(speed_color(0.0), RGBColor(215, 25, 28));
        assert_eq!(speed_color(0.5), RGBColor(250, 200, 0));
        assert_eq!(speed_color(1.0), RGBColor(26, 150, 65));
        assert_eq!(speed_color(f64::NAN), speed_color(0.0));
        assert_eq!(speed_color(7.0), speed_color(1.0));
    }
}

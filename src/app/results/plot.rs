//! `smlworld plot OUT_DIR`: figures of a finished run for papers, from its `trajectories.csv`
//! and `summary.json`, as PNG and SVG (plotters; text in DejaVu Sans shipped in `assets/fonts`,
//! so figures look the same on every machine).
//!
//! Figures (each `NAME.png` and `NAME.svg` in the output folder):
//! - `speed`: speed over time per vehicle [m/s];
//! - `gaps`: per follower of `summary.json` `metrics.followers`, the bumper-to-bumper gap to its
//!   leader [m] (centre distance minus the half lengths) and the time gap (gap / own speed) [s];
//! - `platoon_<leader>`: per platoon, the speed of each member (the string-stability picture);
//! - `lateral`: each vehicle's distance from the nearest lanelet centre line of the map [m];
//! - `merge` (runs with `metrics.merge`, the GCDC merge): per participant, the gap along the road
//!   to the vehicle that is ahead of it after the merge (its predecessor in the zipper order; of
//!   the other lane until it merged) [m], and its speed [m/s], with the merge instants (the end of
//!   each merger's lane change) marked as dashed lines;
//! - `lanes` (runs with lane changes): the lanelet under each vehicle that changed lanes and
//!   its offset from that lanelet's centre line over time;
//! - `trace`: a bird's-eye trace of every trajectory over the map's lanelets, equal scale, with
//!   collisions marked.
//!
//! A vehicle has one colour in every figure, the colour of its id label in the view
//! ([`crate::render::vehicle_color`]); each title names the disturbance the run shows (the first
//! vehicle to slow down, collisions, lane changes). Legends sit in a column right of the plot,
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
/// Figure size [px]: 1600 x 1000, readable when printed one column wide.
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

/// A curve: legend label, points and colour.
type Series = (String, Vec<(f64, f64)>, RGBColor);

/// A curve: (x, y) points, x rising.
type Curve = Vec<(f64, f64)>;

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
}

/// Width of the legend column right of every panel [px]: the legend never covers a curve.
const LEGEND_WIDTH: u32 = 300;

/// Colour of vehicle `id` in every figure: the colour of its id label in the view.
fn id_color(id: i32) -> RGBColor {
    let [r, g, b, _] = crate::render::vehicle_color(id);
    RGBColor(r, g, b)
}

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

/// The one axis set-up of every figure: title, axis titles with units, tick labels, light grid.
fn axes<'a, DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    title: &str,
    x_label: &str,
    y_label: &str,
    (x0, x1): (f64, f64),
    (y0, y1): (f64, f64),
) -> Result<Axes<'a, DB>, String> {
    let mut chart = ChartBuilder::on(area)
        .caption(title, ("sans-serif", 30))
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

fn draw_lines<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, p: &Lines) -> Result<(), String> {
    let (plot, legend) = with_legend(area);
    let x = range(p.series.iter().flat_map(|s| s.1.iter().map(|v| v.0)));
    let y = range(p.series.iter().flat_map(|s| s.1.iter().map(|v| v.1)));
    let mut chart = axes(&plot, &p.title, &p.x_label, &p.y_label, x, y)?;
    let style = BLACK.stroke_width(2);
    for &t in &p.marks {
        chart.draw_series(DashedLineSeries::new([(t, y.0), (t, y.1)], 12, 8, style)).map_err(err)?;
    }
    draw_series(&mut chart, &p.series)?;
    draw_legend(&legend, &p.series)
}

fn draw_series<DB: DrawingBackend>(chart: &mut Axes<'_, DB>, series: &[Series]) -> Result<(), String> {
    for (_, points, color) in series {
        chart.draw_series(LineSeries::new(points.iter().copied(), color.stroke_width(3))).map_err(err)?;
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
    for (i, (label, _, color)) in series.iter().take(MAX_LEGEND).enumerate() {
        let y = top + step * i as i32;
        area.draw(&PathElement::new(vec![(8, y), (44, y)], color.stroke_width(4))).map_err(err)?;
        area.draw(&Text::new(label.clone(), (54, y - 11), font.clone())).map_err(err)?;
    }
    if series.len() > MAX_LEGEND {
        let y = top + step * MAX_LEGEND as i32;
        let more = format!("(+{} more)", series.len() - MAX_LEGEND);
        area.draw(&Text::new(more, (54, y - 11), font)).map_err(err)?;
    }
    Ok(())
}

fn draw_chart<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, chart: &Chart) -> Result<(), String> {
    root.fill(&WHITE).map_err(err)?;
    match chart {
        Chart::Panels(panels) => {
            let areas = root.split_evenly((panels.len().max(1), 1));
            for (area, p) in areas.iter().zip(panels) {
                draw_lines(area, p)?;
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
            let (mut x0, mut x1) = range(pts.iter().map(|p| p.x));
            let (mut y0, mut y1) = range(pts.iter().map(|p| p.y));
            // Equal scale: widen the narrower axis to the plot area's aspect (about w-130 x h-150).
            let (pw, ph) = plot.dim_in_pixel();
            let (w, h) = (f64::from(pw - 130), f64::from(ph - 150));
            let scale = ((x1 - x0) / w).max((y1 - y0) / h);
            let (cx, cy) = ((x0 + x1) / 2.0, (y0 + y1) / 2.0);
            (x0, x1, y0, y1) = (cx - scale * w / 2.0, cx + scale * w / 2.0, cy - scale * h / 2.0, cy + scale * h / 2.0);
            let mut chart = axes(&plot, title, "x [m]", "y [m]", (x0, x1), (y0, y1))?;
            let road = RGBColor(200, 200, 200);
            chart
                .draw_series(
                    roads
                        .iter()
                        .map(|poly| Polygon::new(poly.iter().map(|p| (p.x, p.y)).collect::<Vec<_>>(), road.filled())),
                )
                .map_err(err)?;
            draw_series(&mut chart, series)?;
            chart
                .draw_series(collisions.iter().map(|p| Circle::new((p.x, p.y), 14, RED.stroke_width(4))))
                .map_err(err)?;
            draw_legend(&legend, series)?;
        }
    }
    root.present().map_err(err)
}

/// Write `chart` as `dir/name.png` and `dir/name.svg`; returns the PNG path.
fn save(dir: &FsPath, name: &str, chart: &Chart) -> Result<PathBuf, ReplayError> {
    let (w, h) = FIGURE_SIZE;
    let png = dir.join(format!("{name}.png"));
    let svg = dir.join(format!("{name}.svg"));
    let plot_err =
        |path: &FsPath, message: String| ReplayError::Option(format!("drawing {}: {message}", path.display()));
    let mut buffer = vec![0u8; (w * h * 3) as usize];
    draw_chart(BitMapBackend::with_buffer(&mut buffer, (w, h)).into_drawing_area(), chart)
        .map_err(|m| plot_err(&png, m))?;
    let image = image::RgbImage::from_raw(w, h, buffer).ok_or_else(|| plot_err(&png, "buffer size".into()))?;
    // Both written aside and renamed into place: a failed plot keeps the earlier figure.
    let png_file = AtomicFile::new(&png).map_err(|e| plot_err(&png, e.to_string()))?;
    image.save_with_format(png_file.path(), image::ImageFormat::Png).map_err(|e| plot_err(&png, e.to_string()))?;
    png_file.commit().map_err(|e| plot_err(&png, e.to_string()))?;
    let svg_file = AtomicFile::new(&svg).map_err(|e| plot_err(&svg, e.to_string()))?;
    draw_chart(SVGBackend::new(svg_file.path(), (w, h)).into_drawing_area(), chart).map_err(|m| plot_err(&svg, m))?;
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

/// A finished run as the figures read it.
struct RunData {
    info: crate::app::running::summary::ReplayInfo,
    rows: BTreeMap<i32, Vec<Row>>,
    summary: serde_json::Value,
    map: Option<LaneletMap>,
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
        Ok(RunData { info, rows, summary, map })
    }

    /// The rows of every vehicle but stationary obstacles (parked cars, road boundaries: a flat
    /// line in every figure; collisions with them are still marked).
    fn moving(&self) -> impl Iterator<Item = (&i32, &Vec<Row>)> {
        self.rows.iter().filter(|(id, _)| !self.info.vehicles.iter().any(|v| v.id == **id && v.stationary))
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
    /// markedly (by at least half the largest drop of any vehicle, and 0.5 m/s), the
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
            .filter(|d| largest >= 0.5 && d.1 >= 0.5 * largest)
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

    let speeds: Vec<Series> = run.moving().map(|(&id, _)| (label(id), run.speed(id), id_color(id))).collect();
    written.push(save(dest, "speed", &Chart::Panels(vec![time_lines(&titled("Speed"), "speed [m/s]", speeds)]))?);

    let followers = run.followers();
    if !followers.is_empty() {
        let (mut gaps, mut time_gaps) = (Vec::new(), Vec::new());
        for &(f, l) in &followers {
            let Some((gap, tg)) = run.gaps(f, l) else { continue };
            gaps.push((format!("{f} behind {l}"), gap, id_color(f)));
            time_gaps.push((format!("{f} behind {l}"), tg, id_color(f)));
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
            .map(|(k, &m)| (format!("{} {m}", if k == 0 { "leader" } else { "member" }), run.speed(m), id_color(m)))
            .collect();
        let title = titled(&format!("Platoon {leader}, speed of each member"));
        written.push(save(
            dest,
            &format!("platoon_{leader}"),
            &Chart::Panels(vec![time_lines(&title, "speed [m/s]", series)]),
        )?);
    }

    if let Some(lateral) = run.lateral() {
        let series = lateral.into_iter().map(|(id, d)| (label(id), d, id_color(id))).collect();
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
            gaps.push((format!("{me} behind {lead}"), gap, id_color(me)));
        }
        let speeds = order.iter().map(|&id| (format!("{id} ({})", role(id)), run.speed(id), id_color(id))).collect();
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
                    let pts = r.iter().filter_map(|r| r.lane.map(|l| (r.t, if k == 0 { l.0 } else { l.1 }))).collect();
                    Some((label(id), pts, id_color(id)))
                })
                .collect()
        };
        let panels = vec![
            time_lines(&titled("Lanelet under each vehicle that changed lanes"), "lanelet id [-]", lane(0)),
            time_lines(&titled("Offset from that lanelet's centre line"), "lane offset [m] (left +)", lane(1)),
        ];
        written.push(save(dest, "lanes", &Chart::Panels(panels))?);
    }

    let roads = run.map.as_ref().map_or(Vec::new(), |m| m.lanelets.iter().map(|l| l.polygon()).collect());
    let traces = run
        .moving()
        .map(|(&id, r)| (label(id), r.iter().map(|r| (r.position.x, r.position.y)).collect(), id_color(id)))
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
            let color = RUN_COLORS[k % RUN_COLORS.len()];
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

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
//! - `trace`: a bird's-eye trace of every trajectory over the map's lanelets, equal scale, with
//!   collisions marked.
//!
//! Legends list at most [`MAX_LEGEND`] vehicles (the rest are drawn and counted in the legend).

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
}

/// A curve and its legend label.
type Series = (String, Vec<(f64, f64)>);

/// A panel of curves over a shared x axis.
struct Lines {
    title: String,
    x_label: String,
    y_label: String,
    series: Vec<Series>,
    /// Instants [x units] marked by dashed vertical lines, with the legend label of the marks.
    marks: Option<(String, Vec<f64>)>,
}

/// What a figure shows.
enum Chart {
    /// Panels stacked top to bottom.
    Panels(Vec<Lines>),
    /// Trajectories over the lanelets' outlines at equal scale; collisions as red circles.
    Trace { roads: Vec<Vec<DVec2>>, series: Vec<Series>, collisions: Vec<DVec2> },
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

fn draw_lines<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, p: &Lines) -> Result<(), String> {
    let (x0, x1) = range(p.series.iter().flat_map(|s| s.1.iter().map(|v| v.0)));
    let (y0, y1) = range(p.series.iter().flat_map(|s| s.1.iter().map(|v| v.1)));
    let mut chart = ChartBuilder::on(area)
        .caption(&p.title, ("sans-serif", 34))
        .margin(16)
        .x_label_area_size(70)
        .y_label_area_size(100)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc(&p.x_label)
        .y_desc(&p.y_label)
        .axis_desc_style(("sans-serif", 28))
        .label_style(("sans-serif", 22))
        .light_line_style(RGBColor(235, 235, 235))
        .draw()
        .map_err(err)?;
    if let Some((label, marks)) = &p.marks {
        let style = BLACK.stroke_width(2);
        for (k, &t) in marks.iter().enumerate() {
            let drawn = chart.draw_series(DashedLineSeries::new([(t, y0), (t, y1)], 12, 8, style)).map_err(err)?;
            if k == 0 {
                drawn.label(label.as_str()).legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 30, y)], style));
            }
        }
    }
    draw_series(&mut chart, &p.series)?;
    Ok(())
}

fn draw_series<'a, DB: DrawingBackend + 'a>(
    chart: &mut ChartContext<
        'a,
        DB,
        Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
    >,
    series: &[Series],
) -> Result<(), String> {
    for (i, (label, points)) in series.iter().enumerate() {
        let color = Palette99::pick(i).to_rgba();
        let drawn = chart.draw_series(LineSeries::new(points.iter().copied(), color.stroke_width(3))).map_err(err)?;
        if i < MAX_LEGEND {
            drawn
                .label(label.as_str())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 30, y)], color.stroke_width(3)));
        } else if i == MAX_LEGEND {
            let more = format!("(+{} more)", series.len() - MAX_LEGEND);
            drawn.label(more).legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 30, y)], color.stroke_width(3)));
        }
    }
    if !series.is_empty() {
        chart
            .configure_series_labels()
            .label_font(("sans-serif", 22))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .position(SeriesLabelPosition::UpperRight)
            .draw()
            .map_err(err)?;
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
        Chart::Trace { roads, series, collisions } => {
            let all = roads
                .iter()
                .flatten()
                .copied()
                .chain(series.iter().flat_map(|s| s.1.iter().map(|&(x, y)| DVec2::new(x, y))));
            let pts: Vec<DVec2> = all.collect();
            let (mut x0, mut x1) = range(pts.iter().map(|p| p.x));
            let (mut y0, mut y1) = range(pts.iter().map(|p| p.y));
            // Equal scale: widen the narrower axis to the figure's aspect (plot area about w-130 x h-150).
            let (w, h) = (f64::from(FIGURE_SIZE.0 - 130), f64::from(FIGURE_SIZE.1 - 150));
            let scale = ((x1 - x0) / w).max((y1 - y0) / h);
            let (cx, cy) = ((x0 + x1) / 2.0, (y0 + y1) / 2.0);
            (x0, x1, y0, y1) = (cx - scale * w / 2.0, cx + scale * w / 2.0, cy - scale * h / 2.0, cy + scale * h / 2.0);
            let mut chart = ChartBuilder::on(&root)
                .caption("Trajectories over the map", ("sans-serif", 34))
                .margin(16)
                .x_label_area_size(70)
                .y_label_area_size(100)
                .build_cartesian_2d(x0..x1, y0..y1)
                .map_err(err)?;
            chart
                .configure_mesh()
                .x_desc("x [m]")
                .y_desc("y [m]")
                .axis_desc_style(("sans-serif", 28))
                .label_style(("sans-serif", 22))
                .light_line_style(RGBColor(240, 240, 240))
                .draw()
                .map_err(err)?;
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
        rows.entry(id).or_default().push(Row {
            t: num(0)?,
            position: DVec2::new(num(2)?, num(3)?),
            velocity: DVec2::new(num(5)?, num(6)?),
        });
    }
    Ok(rows)
}

fn label(id: i32) -> String {
    format!("vehicle {id}")
}

/// Write the figures of the run in `out_dir` into `dest` (created); returns the PNG paths.
pub fn plot_run(out_dir: &FsPath, dest: &FsPath) -> Result<Vec<PathBuf>, ReplayError> {
    register_font();
    let info = read_replay_info(out_dir)?;
    let rows = read_rows(out_dir)?;
    let summary_path = out_dir.join("summary.json");
    let summary: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(&summary_path)
            .map_err(|source| ReplayError::Io { path: summary_path.clone(), source })?,
    )
    .map_err(|e| ReplayError::Summary { path: summary_path.clone(), message: e.to_string() })?;
    std::fs::create_dir_all(dest).map_err(|source| ReplayError::Io { path: dest.to_path_buf(), source })?;
    let length: BTreeMap<i32, f64> = info.vehicles.iter().map(|v| (v.id, v.length)).collect();
    let mut written = Vec::new();

    let speed = |id: i32| -> Vec<(f64, f64)> {
        rows.get(&id).map_or(Vec::new(), |r| r.iter().map(|r| (r.t, r.velocity.length())).collect())
    };
    let speeds: Vec<Series> = rows.keys().map(|&id| (label(id), speed(id))).collect();
    let lines = |title: &str, y: &str, series| Lines {
        title: title.into(),
        x_label: "time [s]".into(),
        y_label: y.into(),
        series,
        marks: None,
    };
    written.push(save(dest, "speed", &Chart::Panels(vec![lines("Speed", "speed [m/s]", speeds)]))?);

    let followers: Vec<(i32, i32)> = summary["metrics"]["followers"]
        .as_array()
        .map(|a| a.iter().filter_map(|f| Some((f["id"].as_i64()? as i32, f["leader"].as_i64()? as i32))).collect())
        .unwrap_or_default();
    if !followers.is_empty() {
        let (mut gaps, mut time_gaps) = (Vec::new(), Vec::new());
        for (f, l) in &followers {
            let (Some(fr), Some(lr)) = (rows.get(f), rows.get(l)) else { continue };
            let half = (length.get(f).copied().unwrap_or(0.0) + length.get(l).copied().unwrap_or(0.0)) / 2.0;
            let gap: Vec<(f64, f64)> =
                fr.iter().zip(lr).map(|(a, b)| (a.t, a.position.distance(b.position) - half)).collect();
            let tg = fr
                .iter()
                .zip(&gap)
                .filter(|(a, _)| a.velocity.length() > 0.5)
                .map(|(a, g)| (a.t, g.1 / a.velocity.length()))
                .collect();
            gaps.push((format!("{f} behind {l}"), gap));
            time_gaps.push((format!("{f} behind {l}"), tg));
        }
        let panels = vec![
            lines("Gap to the leader", "gap [m]", gaps),
            lines("Time gap to the leader", "time gap [s]", time_gaps),
        ];
        written.push(save(dest, "gaps", &Chart::Panels(panels))?);
    }

    for p in summary["metrics"]["platoons"].as_array().into_iter().flatten() {
        let members: Vec<i32> =
            p["members"].as_array().into_iter().flatten().filter_map(|m| m.as_i64()).map(|m| m as i32).collect();
        let Some(&leader) = members.first() else { continue };
        let series = members
            .iter()
            .enumerate()
            .map(|(k, &m)| (format!("{} {m}", if k == 0 { "leader" } else { "member" }), speed(m)))
            .collect();
        let title = format!("Platoon {leader}: speed of each member");
        written.push(save(
            dest,
            &format!("platoon_{leader}"),
            &Chart::Panels(vec![lines(&title, "speed [m/s]", series)]),
        )?);
    }

    let merge = &summary["metrics"]["merge"];
    let order: Vec<i32> =
        merge["order"].as_array().into_iter().flatten().filter_map(|v| v.as_i64()).map(|v| v as i32).collect();
    if order.len() >= 2 {
        let instants: Vec<f64> =
            merge["merges"].as_array().into_iter().flatten().filter_map(|m| m["t"].as_f64()).collect();
        let mergers: Vec<i64> =
            merge["merges"].as_array().into_iter().flatten().filter_map(|m| m["id"].as_i64()).collect();
        let role = |id: i32| if mergers.contains(&i64::from(id)) { "merger" } else { "gap maker" };
        let mut gaps = Vec::new();
        for pair in order.windows(2) {
            let (lead, me) = (pair[0], pair[1]);
            let (Some(mr), Some(lr)) = (rows.get(&me), rows.get(&lead)) else { continue };
            let half = (length.get(&me).copied().unwrap_or(0.0) + length.get(&lead).copied().unwrap_or(0.0)) / 2.0;
            // Along the road: the offset projected on our own heading (the lanes are side by side).
            let gap = mr
                .iter()
                .zip(lr)
                .map(|(a, b)| {
                    let heading = if a.velocity.length() > 0.1 { a.velocity.normalize() } else { DVec2::X };
                    (a.t, (b.position - a.position).dot(heading) - half)
                })
                .collect();
            gaps.push((format!("{me} ({}) behind {lead}", role(me)), gap));
        }
        let speeds = order.iter().map(|&id| (format!("{id} ({})", role(id)), speed(id))).collect();
        let marks = Some(("merge (lane change ends)".to_string(), instants));
        let panels = vec![
            Lines {
                marks: marks.clone(),
                ..lines("Gap to the vehicle ahead after the merge, along the road", "gap [m]", gaps)
            },
            Lines { marks, ..lines("Speed of the merging platoons", "speed [m/s]", speeds) },
        ];
        written.push(save(dest, "merge", &Chart::Panels(panels))?);
    }

    let map = match &info.map {
        Some(path) => {
            Some(LaneletMap::load(path).map_err(|e| ReplayError::Map { path: path.clone(), message: e.to_string() })?)
        }
        None => None,
    };
    if let Some(map) = &map {
        let centres: Vec<&[DVec2]> = map.lanelets.iter().filter(|l| l.routable).map(|l| l.centre.as_slice()).collect();
        let lateral = rows
            .iter()
            .map(|(&id, r)| {
                let d = r
                    .iter()
                    .map(|r| {
                        (r.t, centres.iter().map(|c| project_polyline(c, r.position).1).fold(f64::INFINITY, f64::min))
                    })
                    .collect();
                (label(id), d)
            })
            .collect();
        let title = "Distance from the nearest lanelet centre line";
        written.push(save(dest, "lateral", &Chart::Panels(vec![lines(title, "lateral deviation [m]", lateral)]))?);
    }
    let roads = map.as_ref().map_or(Vec::new(), |m| m.lanelets.iter().map(|l| l.polygon()).collect());
    let traces =
        rows.iter().map(|(&id, r)| (label(id), r.iter().map(|r| (r.position.x, r.position.y)).collect())).collect();
    let collisions = summary["metrics"]["collisions"]
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(|c| {
            let (a, t) = (c["a"].as_i64()? as i32, c["t"].as_f64()?);
            let r = rows.get(&a)?;
            r.iter().min_by(|p, q| (p.t - t).abs().total_cmp(&(q.t - t).abs())).map(|r| r.position)
        })
        .collect();
    written.push(save(dest, "trace", &Chart::Trace { roads, series: traces, collisions })?);
    Ok(written)
}

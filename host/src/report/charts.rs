//! The report's charts, as SVG and PNG: `error_vs_depth` (the paper's Fig. 7, with its bounds),
//! `stage_times` (Fig. 8: stacked stage means per mesh size) and `speed_vs_error` (CPU time per
//! step against e_mean, every run labelled). What they show is computed in [`data`] (tested
//! there); this file draws it. Text is drawn with DejaVu Sans, embedded in the binary (no system
//! font is needed).

pub(crate) mod data;
mod place;

use super::{ReportError, ReportRun, paper_time};
use data::{
    DepthLine, PointKind, RunFacts, STAGE_NAMES, default_settings, depth_lines, depth_references,
    measure_tick, paper_points, speed_points, stage_bars,
};
use place::{Rect, place_labels};
use plotters::coord::Shift;
use plotters::coord::types::RangedCoordf64;
use plotters::element::DashedPathElement;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::ops::Range;
use std::path::{Path, PathBuf};

/// Draws the three charts into `dir`, as SVG and PNG; returns the files written.
pub(super) fn write_charts(dir: &Path, runs: &[ReportRun]) -> Result<Vec<PathBuf>, ReportError> {
    let facts: Vec<RunFacts> = runs.iter().map(RunFacts::of).collect();
    write_charts_of(dir, &facts)
}

/// [`write_charts`] from the runs' facts.
pub(crate) fn write_charts_of(dir: &Path, facts: &[RunFacts]) -> Result<Vec<PathBuf>, ReportError> {
    register_fonts();
    let mut files = Vec::new();
    for (name, chart, size) in [
        ("error_vs_depth", Chart::ErrorVsDepth(facts), CHART_SIZE),
        ("stage_times", Chart::StageTimes(facts), CHART_SIZE),
        ("speed_vs_error", Chart::SpeedVsError(facts), SPEED_SIZE),
    ] {
        let svg = dir.join(format!("{name}.svg"));
        chart
            .draw(SVGBackend::new(&svg, size).into_drawing_area())
            .map_err(|reason| ReportError::Chart {
                file: svg.clone(),
                reason,
            })?;
        files.push(svg);
        let png = dir.join(format!("{name}.png"));
        chart
            .draw(BitMapBackend::new(&png, size).into_drawing_area())
            .map_err(|reason| ReportError::Chart {
                file: png.clone(),
                reason,
            })?;
        files.push(png);
    }
    Ok(files)
}

const CHART_SIZE: (u32, u32) = (1400, 560);
/// Speed against error is taller: every point carries a label.
const SPEED_SIZE: (u32, u32) = (1400, 1000);

const COLORS: [RGBColor; 7] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
];
/// The paper's reference lines and markers.
const PAPER: RGBColor = RGBColor(90, 90, 90);
/// Point labels and leader lines.
const LABEL: RGBColor = RGBColor(40, 40, 40);

/// Registers the embedded DejaVu Sans as plotters' `sans-serif` (once).
pub(crate) fn register_fonts() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        // DejaVu Sans ships inside the `dejavu` crate: no system font or fontconfig needed.
        let _ = plotters::style::register_font(
            "sans-serif",
            FontStyle::Normal,
            dejavu::sans::regular(),
        );
        let _ = plotters::style::register_font("sans-serif", FontStyle::Bold, dejavu::sans::bold());
    });
}

/// A chart and its data.
enum Chart<'a> {
    ErrorVsDepth(&'a [RunFacts]),
    StageTimes(&'a [RunFacts]),
    SpeedVsError(&'a [RunFacts]),
}

type DrawResult = Result<(), Box<dyn std::error::Error>>;

/// The legend box of every chart (series labels on a translucent white box), in `position`.
pub(crate) fn legend<'a, DB: DrawingBackend + 'a, CT: plotters::coord::CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
    font: u32,
    position: SeriesLabelPosition,
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    chart
        .configure_series_labels()
        .label_font(("sans-serif", font))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(position)
        .draw()?;
    Ok(())
}

impl Chart<'_> {
    fn draw<DB: DrawingBackend>(&self, root: DrawingArea<DB, Shift>) -> Result<(), String>
    where
        DB::ErrorType: 'static,
    {
        let r = match self {
            Chart::ErrorVsDepth(f) => error_vs_depth(&root, f),
            Chart::StageTimes(f) => stage_times(&root, f),
            Chart::SpeedVsError(f) => speed_vs_error(&root, f),
        };
        r.and_then(|()| root.present().map_err(Into::into))
            .map_err(|e| e.to_string())
    }
}

/// DejaVu Sans of `size` px.
fn text_style(size: u32) -> TextStyle<'static> {
    TextStyle::from(("sans-serif", size).into_font())
}

/// 10 % above `x` (1 when `x` is not a positive number).
fn nice_max(x: f64) -> f64 {
    if !(x.is_finite() && x > 0.0) {
        return 1.0;
    }
    x * 1.1
}

/// A horizontal dashed reference line at `y` over the chart's width, its label above its left
/// (`left`) or right end; returns the label's box [px].
fn reference_line<'a, DB: DrawingBackend + 'a>(
    chart: &mut ChartContext<'a, DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>,
    y: f64,
    label: &str,
    left: bool,
) -> Result<Rect, Box<dyn std::error::Error>>
where
    DB::ErrorType: 'static,
{
    let x = chart.x_range();
    chart.draw_series(DashedLineSeries::new(
        [(x.start, y), (x.end, y)],
        8,
        5,
        PAPER.stroke_width(2),
    ))?;
    let font = text_style(13).color(&PAPER);
    let (w, h) = chart.plotting_area().estimate_text_size(label, &font)?;
    let (w, h) = (w as i32, h as i32);
    let (end, dx, hpos) = if left {
        (x.start, 6, HPos::Left)
    } else {
        (x.end, -6, HPos::Right)
    };
    let (px, py) = chart.backend_coord(&(end, y));
    chart.plotting_area().draw(
        &(EmptyElement::at((end, y))
            + Text::new(
                label.to_owned(),
                (dx, -3),
                font.pos(Pos::new(hpos, VPos::Bottom)),
            )),
    )?;
    let x0 = if left { px + dx } else { px + dx - w };
    Ok(Rect::at(x0, py - 3 - h, w, h))
}

/// Fig. 7: error against depth, one panel per scene, inverse and naive, with the paper's bounds.
fn error_vs_depth<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    facts: &[RunFacts],
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let (title, body) = root.split_vertically(40);
    title.titled(
        "Tracking error against insertion depth (the paper's Fig. 7), with the paper's bounds",
        ("sans-serif", 22),
    )?;
    let panels = body.split_evenly((1, 2));
    for (panel, scene) in panels.iter().zip(["simple", "complex"]) {
        let lines: Vec<DepthLine> = depth_lines(facts, scene);
        let refs = depth_references(scene);
        let max_d = lines
            .iter()
            .flat_map(|l| l.points.iter().map(|p| p.0))
            .fold(0.0, f64::max);
        let hi = lines
            .iter()
            .flat_map(|l| l.points.iter().map(|p| p.1))
            .chain(refs.iter().map(|r| r.0))
            .fold(0.0, f64::max);
        let mut chart = ChartBuilder::on(panel)
            .caption(format!("{scene} path"), ("sans-serif", 18))
            .margin(12)
            .x_label_area_size(45)
            .y_label_area_size(60)
            // Headroom: the legend sits above the highest curve or bound.
            .build_cartesian_2d(0.0..nice_max(max_d).max(1.0), 0.0..nice_max(hi) * 1.2)?;
        chart
            .configure_mesh()
            .x_desc("insertion depth [mm]")
            .y_desc("tracking error |tip − target| [mm]")
            .x_label_formatter(&|x| measure_tick(*x))
            .y_label_formatter(&|y| measure_tick(*y))
            .light_line_style(BLACK.mix(0.04))
            .label_style(("sans-serif", 14))
            .axis_desc_style(("sans-serif", 15))
            .draw()?;
        for l in &lines {
            let color = if l.naive { COLORS[1] } else { COLORS[0] };
            chart
                .draw_series(LineSeries::new(
                    l.points.iter().copied(),
                    color.stroke_width(1),
                ))?
                .label(l.label.clone())
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
                });
        }
        for (y, label) in &refs {
            reference_line(&mut chart, *y, label, false)?;
        }
        if !refs.is_empty() {
            // One legend entry for both lines (each is labelled where it is drawn).
            chart
                .draw_series(std::iter::empty::<Circle<(f64, f64), i32>>())?
                .label("the paper's bounds (IROS 2016)")
                .legend(|(x, y)| {
                    DashedPathElement::new(vec![(x, y), (x + 20, y)], 5, 3, PAPER.stroke_width(2))
                });
        }
        legend(&mut chart, 14, SeriesLabelPosition::UpperLeft)?;
    }
    Ok(())
}

/// Fig. 8: the stage means of a step stacked per mesh size (they add up to the mean step), one
/// panel per scene, with the paper's time per step.
fn stage_times<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, facts: &[RunFacts]) -> DrawResult
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let (title, body) = root.split_vertically(40);
    title.titled(
        "Wall time per step by stage and mesh size: stage means, stacked to the mean step \
         (the paper's Fig. 8)",
        ("sans-serif", 22),
    )?;
    let panels = body.split_evenly((1, 2));
    let scenes = ["simple", "complex"];
    let all: Vec<_> = scenes.iter().map(|s| stage_bars(facts, s)).collect();
    let ymax = all
        .iter()
        .flatten()
        .flat_map(|b| [Some(b.step_mean_ms), paper_time(b.nodes_target)])
        .flatten()
        .fold(0.0, f64::max);
    // "other" is drawn and listed only where it is visible (the stages cover the step).
    let show_other = all.iter().flatten().any(|b| b.segments[5] > 0.005);
    for ((panel, scene), bars) in panels.iter().zip(scenes).zip(&all) {
        let labels: Vec<String> = bars.iter().map(|b| b.label.clone()).collect();
        let n = bars.len().max(1);
        let mut chart = ChartBuilder::on(panel)
            .caption(
                format!("{scene} path, inverse controller"),
                ("sans-serif", 18),
            )
            .margin(12)
            .x_label_area_size(45)
            .y_label_area_size(60)
            .build_cartesian_2d(-0.6..n as f64 - 0.4, 0.0..nice_max(ymax) * 1.05)?;
        chart
            .configure_mesh()
            .disable_x_mesh()
            .x_desc("gel mesh (node count of the mesh used)")
            .y_desc("wall time per step, mean [ms]")
            .x_labels(0)
            .y_label_formatter(&|y| measure_tick(*y))
            .light_line_style(BLACK.mix(0.04))
            .label_style(("sans-serif", 14))
            .axis_desc_style(("sans-serif", 15))
            .draw()?;
        // The categories under the axis: the node count of each mesh, an integer.
        for (i, l) in labels.iter().enumerate() {
            let (px, py) = chart.backend_coord(&(i as f64, 0.0));
            root.draw(&Text::new(
                l.clone(),
                (px, py + 8),
                text_style(14).pos(Pos::new(HPos::Center, VPos::Top)),
            ))?;
        }
        let half = 0.3;
        for (k, name) in STAGE_NAMES.iter().enumerate() {
            if k == 5 && !show_other {
                continue;
            }
            let color = if k == 5 {
                RGBColor(170, 170, 170)
            } else {
                COLORS[k]
            };
            chart
                .draw_series(bars.iter().enumerate().map(|(i, b)| {
                    let x = i as f64;
                    let y0: f64 = b.segments[..k].iter().sum();
                    let y1 = y0 + b.segments[k];
                    Rectangle::new([(x - half, y0), (x + half, y1)], color.filled())
                }))?
                .label(*name)
                .legend(move |(x, y)| {
                    Rectangle::new([(x, y - 5), (x + 14, y + 5)], color.filled())
                });
        }
        // The mean step on top of each stack.
        chart.draw_series(bars.iter().enumerate().map(|(i, b)| {
            Text::new(
                format!("{} ms", measure_tick(b.step_mean_ms)),
                (i as f64, b.step_mean_ms),
                text_style(14).pos(Pos::new(HPos::Center, VPos::Bottom)),
            )
        }))?;
        // The paper's time per step at the mesh size it gives it for.
        let paper: Vec<(f64, f64)> = bars
            .iter()
            .enumerate()
            .filter_map(|(i, b)| Some((i as f64, paper_time(b.nodes_target)?)))
            .collect();
        chart
            .draw_series(
                paper
                    .iter()
                    .map(|&(x, t)| Cross::new((x, t), 7, BLACK.stroke_width(2))),
            )?
            .label("the paper's time per step (SOFA, compliance on a GPU)")
            .legend(|(x, y)| Cross::new((x + 7, y), 5, BLACK.stroke_width(2)));
        chart.draw_series(paper.iter().map(|&(x, t)| {
            EmptyElement::at((x, t))
                + Text::new(
                    format!("the paper: {} ms", measure_tick(t)),
                    (0, -10),
                    text_style(13).pos(Pos::new(HPos::Center, VPos::Bottom)),
                )
        }))?;
        legend(&mut chart, 13, SeriesLabelPosition::UpperLeft)?;
    }
    Ok(())
}

/// The markers of speed against error (chart and legend alike).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Marker {
    Point(PointKind),
    Paper,
    /// A run that stopped early, in the legend.
    Hollow,
}

/// Draws `m` at `at` on `area`; `filled` false draws a hollow one (a run that stopped early).
fn draw_marker<DB: DrawingBackend, CT: plotters::coord::CoordTranslate>(
    area: &DrawingArea<DB, CT>,
    at: CT::From,
    m: Marker,
    filled: bool,
) -> DrawResult
where
    DB::ErrorType: 'static,
    CT::From: Clone,
{
    let fill = |c: RGBColor| {
        if filled {
            c.filled()
        } else {
            c.stroke_width(2)
        }
    };
    match m {
        Marker::Point(PointKind::Default) => {
            let d = vec![(0, -10), (10, 0), (0, 10), (-10, 0)];
            let mut outline = d.clone();
            outline.push(d[0]);
            area.draw(
                &(EmptyElement::at(at)
                    + Polygon::new(d, fill(COLORS[0]))
                    + PathElement::new(outline, BLACK.stroke_width(2))),
            )?;
        }
        Marker::Point(PointKind::Mesh) => {
            area.draw(&(EmptyElement::at(at) + Circle::new((0, 0), 6, fill(COLORS[0]))))?;
        }
        Marker::Point(PointKind::Setting) => {
            area.draw(&(EmptyElement::at(at) + Circle::new((0, 0), 6, fill(COLORS[3]))))?;
        }
        Marker::Point(PointKind::Naive) => {
            area.draw(
                &(EmptyElement::at(at) + Rectangle::new([(-6, -6), (6, 6)], fill(COLORS[1]))),
            )?;
        }
        Marker::Hollow => {
            area.draw(&(EmptyElement::at(at) + Circle::new((0, 0), 6, PAPER.stroke_width(2))))?;
        }
        Marker::Paper => {
            area.draw(&(EmptyElement::at(at) + Cross::new((0, 0), 7, BLACK.stroke_width(2))))?;
        }
    }
    Ok(())
}

/// The legend of speed against error: one row (wrapped when too long) of markers and texts.
fn legend_row<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    entries: &[(Option<(Marker, bool)>, String)],
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    let font = text_style(14);
    let (w, _) = area.dim_in_pixel();
    let (mut x, mut y) = (70i32, 14i32);
    for (marker, text) in entries {
        let (tw, _) = area.estimate_text_size(text, &font)?;
        let need = 26 + tw as i32 + 28;
        if x + need > w as i32 - 20 {
            x = 70;
            y += 24;
        }
        match marker {
            Some((m, filled)) => draw_marker(area, (x + 8, y), *m, *filled)?,
            None => {
                area.draw(&DashedPathElement::new(
                    vec![(x - 4, y), (x + 20, y)],
                    6,
                    4,
                    PAPER.stroke_width(2),
                ))?;
            }
        }
        area.draw(&Text::new(
            text.clone(),
            (x + 26, y),
            font.pos(Pos::new(HPos::Left, VPos::Center)),
        ))?;
        x += need;
    }
    Ok(())
}

/// Speed against error: CPU time per step summed over threads (a background thread is not
/// free) against e_mean, every run a labelled point, the paper's figures as labelled
/// references. Top: the simple and the complex path with the paper's points; below, the
/// complex path's runs enlarged (they lie close together, far from the paper's).
fn speed_vs_error<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    facts: &[RunFacts],
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let (title, rest) = root.split_vertically(40);
    title.titled(
        "Speed against error: every run of the report, CPU time per step against e_mean",
        ("sans-serif", 22),
    )?;
    let (legend_area, body) = rest.split_vertically(56);
    let defaults = default_settings(facts).map_or_else(
        || "the scene as shipped".into(),
        |d| format!("default: {d}"),
    );
    let mut entries = vec![
        (
            Some((Marker::Point(PointKind::Default), true)),
            format!("the controller's run ({defaults})"),
        ),
        (
            Some((Marker::Point(PointKind::Mesh), true)),
            "default settings, another mesh".into(),
        ),
        (
            Some((Marker::Point(PointKind::Setting), true)),
            "one setting changed (as labelled)".into(),
        ),
        (
            Some((Marker::Point(PointKind::Naive), true)),
            "naive baseline (rigid IK replayed)".into(),
        ),
        (
            Some((Marker::Paper, true)),
            "the paper (wall time per step; SOFA, compliance on a GPU)".into(),
        ),
        (None, "the paper's e_mean".into()),
    ];
    if facts.iter().any(|f| f.started && !f.completed) {
        entries.push((
            Some((Marker::Hollow, false)),
            "hollow: the run stopped early".into(),
        ));
    }
    legend_row(&legend_area, &entries)?;
    let (top, bottom) = body.split_vertically(body.dim_in_pixel().1 / 2);
    let panels = top.split_evenly((1, 2));
    let complex = speed_points(facts, "complex");
    // The enlarged window: the complex runs with a margin.
    let window = enclosing(complex.iter().map(|p| (p.cpu_ms, p.e_mean_mm)));
    speed_panel(
        root,
        &panels[0],
        facts,
        &Panel {
            scene: "simple",
            title: "simple path".into(),
            window: None,
            label_all: true,
            mark: None,
        },
    )?;
    speed_panel(
        root,
        &panels[1],
        facts,
        &Panel {
            scene: "complex",
            title: "complex path (the box: enlarged below)".into(),
            window: None,
            label_all: false,
            mark: window.clone(),
        },
    )?;
    speed_panel(
        root,
        &bottom,
        facts,
        &Panel {
            scene: "complex",
            title: "complex path, this project's runs enlarged".into(),
            window,
            label_all: true,
            mark: None,
        },
    )
}

/// The ranges around `pts` with a margin (none without points).
fn enclosing(pts: impl Iterator<Item = (f64, f64)>) -> Option<(Range<f64>, Range<f64>)> {
    let (mut x0, mut x1, mut y0, mut y1) = (f64::INFINITY, 0.0f64, f64::INFINITY, 0.0f64);
    for (x, y) in pts {
        (x0, x1, y0, y1) = (x0.min(x), x1.max(x), y0.min(y), y1.max(y));
    }
    if !(x0.is_finite() && y0.is_finite()) {
        return None;
    }
    let (dx, dy) = ((x1 - x0).max(0.5), (y1 - y0).max(0.05));
    Some((
        (x0 - 0.12 * dx).max(0.0)..x1 + 0.12 * dx,
        (y0 - 0.12 * dy).max(0.0)..y1 + 0.12 * dy,
    ))
}

/// What one panel of [`speed_vs_error`] shows.
struct Panel {
    scene: &'static str,
    title: String,
    /// The ranges shown (none: from 0 to past every point and the paper's).
    window: Option<(Range<f64>, Range<f64>)>,
    /// Whether every point is labelled (else the controller's, the naive and the paper's).
    label_all: bool,
    /// A window to outline (the one enlarged in another panel).
    mark: Option<(Range<f64>, Range<f64>)>,
}

/// One panel of [`speed_vs_error`]; the labels are drawn on `root` in pixels.
fn speed_panel<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    area: &DrawingArea<DB, Shift>,
    facts: &[RunFacts],
    panel: &Panel,
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    let scene = panel.scene;
    let pts = speed_points(facts, scene);
    let paper = paper_points(scene);
    let (xr, yr) = panel.window.clone().unwrap_or_else(|| {
        let xmax = pts
            .iter()
            .map(|p| p.cpu_ms)
            .chain(paper.iter().map(|p| p.ms))
            .fold(0.0, f64::max);
        let ymax = pts
            .iter()
            .map(|p| p.e_mean_mm)
            .chain(paper.iter().map(|p| p.e_mean_mm))
            .fold(0.0, f64::max);
        (0.0..nice_max(xmax) * 1.05, 0.0..nice_max(ymax) * 1.08)
    });
    let inside = |x: f64, y: f64| xr.contains(&x) && yr.contains(&y);
    let mut chart = ChartBuilder::on(area)
        .caption(&panel.title, ("sans-serif", 18))
        .margin(14)
        .x_label_area_size(48)
        .y_label_area_size(60)
        .build_cartesian_2d(xr.clone(), yr.clone())?;
    chart
        .configure_mesh()
        .x_desc("CPU time per step, all threads [ms] (the paper: wall time)")
        .y_desc("e_mean [mm]")
        .x_label_formatter(&|x| measure_tick(*x))
        .y_label_formatter(&|y| measure_tick(*y))
        .light_line_style(BLACK.mix(0.04))
        .label_style(("sans-serif", 14))
        .axis_desc_style(("sans-serif", 15))
        .draw()?;
    let mut reserved = Vec::new();
    if let Some((m, _)) = data::paper_bounds(scene).filter(|(m, _)| yr.contains(m)) {
        let label = format!("the paper's e_mean, {scene}: {} mm", measure_tick(m));
        reserved.push(reference_line(&mut chart, m, &label, true)?);
        // Keep the point labels off the line itself.
        let (_, py) = chart.backend_coord(&(xr.start, m));
        let (px0, _) = chart.backend_coord(&(xr.start, m));
        let (px1, _) = chart.backend_coord(&(xr.end, m));
        reserved.push(Rect {
            x0: px0,
            y0: py - 3,
            x1: px1,
            y1: py + 4,
        });
    }
    if let Some((mx, my)) = &panel.mark {
        chart.draw_series(std::iter::once(Rectangle::new(
            [(mx.start, my.start), (mx.end, my.end)],
            PAPER.stroke_width(1),
        )))?;
    }
    let plot = chart.plotting_area();
    // Markers, the controller's own run last (on top).
    let paper: Vec<_> = paper
        .into_iter()
        .filter(|p| inside(p.ms, p.e_mean_mm))
        .collect();
    let pts: Vec<_> = pts
        .into_iter()
        .filter(|p| inside(p.cpu_ms, p.e_mean_mm))
        .collect();
    for p in &paper {
        draw_marker(plot, (p.ms, p.e_mean_mm), Marker::Paper, true)?;
    }
    for p in &pts {
        draw_marker(
            plot,
            (p.cpu_ms, p.e_mean_mm),
            Marker::Point(p.kind),
            p.completed,
        )?;
    }
    // Labels: the controller's run first (the best place), then the paper's, then the rest.
    let mut labelled: Vec<((f64, f64), String, bool)> = Vec::new();
    for p in pts.iter().rev().filter(|p| p.kind == PointKind::Default) {
        labelled.push(((p.cpu_ms, p.e_mean_mm), p.label.clone(), true));
    }
    for p in &paper {
        labelled.push(((p.ms, p.e_mean_mm), p.label.clone(), false));
    }
    for p in pts.iter().filter(|p| p.kind != PointKind::Default) {
        if panel.label_all || p.kind == PointKind::Naive {
            labelled.push(((p.cpu_ms, p.e_mean_mm), p.label.clone(), false));
        }
    }
    // Markers without a label still keep labels off them.
    let unlabelled: Vec<(i32, i32)> = pts
        .iter()
        .filter(|p| !(panel.label_all || matches!(p.kind, PointKind::Default | PointKind::Naive)))
        .map(|p| chart.backend_coord(&(p.cpu_ms, p.e_mean_mm)))
        .collect();
    reserved.extend(unlabelled.iter().map(|&a| Rect::around(a, 9)));
    if let Some((mx, my)) = &panel.mark {
        let (x0, y1) = chart.backend_coord(&(mx.start, my.start));
        let (x1, y0) = chart.backend_coord(&(mx.end, my.end));
        reserved.push(Rect { x0, y0, x1, y1 });
    }
    let font = text_style(13).color(&LABEL);
    let bold = TextStyle::from(("sans-serif", 13).into_font().style(FontStyle::Bold)).color(&LABEL);
    let anchors: Vec<(i32, i32)> = labelled.iter().map(|l| chart.backend_coord(&l.0)).collect();
    let sizes = labelled
        .iter()
        .map(|(_, t, b)| root.estimate_text_size(t, if *b { &bold } else { &font }))
        .collect::<Result<Vec<_>, _>>()?;
    let (px, py) = chart.plotting_area().get_pixel_range();
    let bounds = Rect {
        x0: px.start + 2,
        y0: py.start + 2,
        x1: px.end - 2,
        y1: py.end - 2,
    };
    let placed = place_labels(&anchors, &sizes, 9, &reserved, bounds);
    for ((a, (_, text, b)), p) in anchors.iter().zip(&labelled).zip(&placed) {
        if p.leader {
            let end = p.rect.nearest(*a);
            root.draw(&PathElement::new(
                vec![*a, end],
                LABEL.mix(0.6).stroke_width(1),
            ))?;
        }
        root.draw(&Text::new(
            text.clone(),
            (p.rect.x0, p.rect.y0),
            if *b { &bold } else { &font },
        ))?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::super::Group;
    use super::*;

    /// Redraws the charts of a report folder from its `report.json` and `error_vs_depth.csv`
    /// (`NEEDLE_REPORT_DIR`, default: the committed `report/`) into `NEEDLE_CHARTS_OUT`
    /// (default: a temporary folder), without running anything:
    /// `NEEDLE_REPORT_DIR=report NEEDLE_CHARTS_OUT=report cargo test -p needle-host --lib
    /// redraw_charts -- --ignored`.
    #[test]
    #[ignore = "redraws the committed report's charts (release): run with --include-ignored"]
    fn redraw_charts_of_a_report_folder() {
        let dir = std::env::var("NEEDLE_REPORT_DIR").map_or_else(
            |_| PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../report")),
            PathBuf::from,
        );
        // Into `NEEDLE_CHARTS_OUT` when given (kept), else a temporary folder removed at the end.
        let temporary = (tempfile::Builder::new().prefix("needle-redraw-").tempdir()).unwrap();
        let out = std::env::var("NEEDLE_CHARTS_OUT")
            .map_or_else(|_| temporary.path().to_path_buf(), PathBuf::from);
        let json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join("report.json")).unwrap())
                .unwrap();
        let mut facts: Vec<RunFacts> = json["runs"]
            .as_array()
            .unwrap()
            .iter()
            .map(facts_of_json)
            .collect();
        let mut csv = ::csv::Reader::from_path(dir.join("error_vs_depth.csv")).unwrap();
        for rec in csv.records() {
            let rec = rec.unwrap();
            let run: usize = rec[0].parse().unwrap();
            facts[run]
                .error_by_depth
                .push((rec[4].parse().unwrap(), rec[5].parse().unwrap()));
        }
        std::fs::create_dir_all(&out).unwrap();
        let files = write_charts_of(&out, &facts).unwrap();
        assert!(!files.is_empty());
        for f in files {
            let bytes = std::fs::read(&f).unwrap();
            let png = f.extension().is_some_and(|e| e == "png");
            assert!(
                if png {
                    bytes.starts_with(b"\x89PNG")
                } else {
                    bytes.starts_with(b"<svg")
                },
                "{} is not a chart",
                f.display()
            );
            println!("{}", f.display());
        }
    }

    fn facts_of_json(r: &serde_json::Value) -> RunFacts {
        let num = |v: &serde_json::Value| v.as_f64().unwrap_or(f64::NAN);
        let s = &r["summary"];
        let t = &s["timing"];
        RunFacts {
            scene: r["scene"].as_str().unwrap().into(),
            naive: r["controller"] == "naive",
            nodes: s["gel_nodes"]
                .as_u64()
                .or(r["nodes_target"].as_u64())
                .unwrap_or(0) as usize,
            nodes_target: r["nodes_target"].as_u64().unwrap_or(0) as usize,
            groups: r["memberships"]
                .as_array()
                .unwrap()
                .iter()
                .filter_map(|m| Group::ALL.into_iter().find(|g| m["group"] == g.name()))
                .collect(),
            delta_q: num(&r["delta_q"]),
            blend_distance_mm: num(&r["blend_distance_mm"]),
            constraint_spacing_mm: num(&r["constraint_spacing_mm"]),
            overrides: r["overrides"]
                .as_array()
                .unwrap()
                .iter()
                .map(|o| (o[0].as_str().unwrap().into(), o[1].as_str().unwrap().into()))
                .collect(),
            started: s.is_object(),
            completed: s["completed"].as_bool().unwrap_or(false),
            steps: s["steps"].as_u64().unwrap_or(0) as usize,
            e_mean_mm: num(&s["e_mean_mm"]),
            e_max_mm: num(&s["e_max_mm"]),
            cpu_ms_per_step: num(&s["cpu_ms_per_step"]),
            stage_mean_ms: ["fm", "cd", "cc", "sc", "correction"].map(|k| num(&t[k]["mean_ms"])),
            step_mean_ms: num(&t["total"]["mean_ms"]),
            error_by_depth: Vec::new(),
        }
    }
}

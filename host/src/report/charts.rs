//! The report's charts, as SVG and PNG: `error_vs_depth` (the paper's Fig. 7), `stage_times`
//! (Fig. 8) and `speed_vs_error`. Text is drawn with DejaVu Sans, embedded in the binary (no
//! system font is needed).

use super::{
    Group, PAPER_COMPLEX_E_MEAN, PAPER_TIME_PER_STEP, ReportError, ReportRun, controller_name,
    paper_time,
};
use crate::run::ControllerKind;
use plotters::coord::Shift;
use plotters::prelude::*;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Draws the three charts into `dir`, as SVG and PNG; returns the files written.
pub(super) fn write_charts(dir: &Path, runs: &[ReportRun]) -> Result<Vec<PathBuf>, ReportError> {
    register_fonts();
    let mut files = Vec::new();
    for (name, chart) in [
        ("error_vs_depth", Chart::ErrorVsDepth(runs)),
        ("stage_times", Chart::StageTimes(runs)),
        ("speed_vs_error", Chart::SpeedVsError(runs)),
    ] {
        let svg = dir.join(format!("{name}.svg"));
        chart
            .draw(SVGBackend::new(&svg, CHART_SIZE).into_drawing_area())
            .map_err(|reason| ReportError::Chart {
                file: svg.clone(),
                reason,
            })?;
        files.push(svg);
        let png = dir.join(format!("{name}.png"));
        chart
            .draw(BitMapBackend::new(&png, CHART_SIZE).into_drawing_area())
            .map_err(|reason| ReportError::Chart {
                file: png.clone(),
                reason,
            })?;
        files.push(png);
    }
    Ok(files)
}

const CHART_SIZE: (u32, u32) = (1400, 560);

const COLORS: [RGBColor; 7] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
];

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
    ErrorVsDepth(&'a [ReportRun]),
    StageTimes(&'a [ReportRun]),
    SpeedVsError(&'a [ReportRun]),
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
            Chart::ErrorVsDepth(runs) => error_vs_depth(&root, runs),
            Chart::StageTimes(runs) => stage_times(&root, runs),
            Chart::SpeedVsError(runs) => speed_vs_error(&root, runs),
        };
        r.and_then(|()| root.present().map_err(Into::into))
            .map_err(|e| e.to_string())
    }
}

fn nice_max(x: f64) -> f64 {
    if !(x.is_finite() && x > 0.0) {
        return 1.0;
    }
    x * 1.1
}

/// Fig. 7: error against depth, one panel per scene, inverse and naive.
fn error_vs_depth<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    runs: &[ReportRun],
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let (title, body) = root.split_vertically(40);
    title.titled(
        "Tracking error against insertion depth (the paper's Fig. 7)",
        ("sans-serif", 22),
    )?;
    let panels = body.split_evenly((1, 2));
    for (panel, scene) in panels.iter().zip(["simple", "complex"]) {
        let lines: Vec<&ReportRun> = runs
            .iter()
            .filter(|r| r.scene == scene && r.parameter(Group::Controllers).is_some())
            .collect();
        let max_d = lines
            .iter()
            .flat_map(|r| r.error_by_depth.iter().map(|p| p.0))
            .fold(0.0, f64::max);
        let hi = lines
            .iter()
            .flat_map(|r| r.error_by_depth.iter().map(|p| p.1))
            .filter(|e| e.is_finite())
            .fold(0.0, f64::max);
        let hi = nice_max(hi);
        let mut chart = ChartBuilder::on(panel)
            .caption(format!("{scene} path"), ("sans-serif", 18))
            .margin(12)
            .x_label_area_size(45)
            .y_label_area_size(60)
            .build_cartesian_2d(0.0..nice_max(max_d).max(1.0), 0.0..hi)?;
        chart
            .configure_mesh()
            .x_desc("insertion depth [mm]")
            .y_desc("tracking error |tip − target| [mm]")
            .label_style(("sans-serif", 14))
            .axis_desc_style(("sans-serif", 15))
            .draw()?;
        for r in &lines {
            let color = match r.controller {
                ControllerKind::Inverse => COLORS[0],
                ControllerKind::Naive => COLORS[1],
            };
            let mut label = controller_name(r.controller).to_owned();
            if let Some(s) = &r.summary {
                let _ = write!(label, ": e_mean {:.2} mm", s.e_mean_mm);
                if !s.completed {
                    label.push_str(&format!(" (stopped at step {}: see summary.md)", s.steps));
                }
            }
            chart
                .draw_series(LineSeries::new(
                    r.error_by_depth.iter().filter(|p| p.1.is_finite()).copied(),
                    color.stroke_width(1),
                ))?
                .label(label)
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
                });
        }
        legend(&mut chart, 14, SeriesLabelPosition::UpperLeft)?;
    }
    Ok(())
}

/// The stages of a step, in the order they run.
const STAGE_NAMES: [&str; 5] = [
    "FM free motion",
    "CD proximity",
    "CC compliance",
    "SC constraint solves",
    "corr correction",
];

/// The mesh group's runs of `scene`: (gel nodes, the five stage medians), by node count.
fn stage_bars(runs: &[ReportRun], scene: &str) -> Vec<(f64, [f64; 5])> {
    let mut bars: Vec<(f64, [f64; 5])> = runs
        .iter()
        .filter(|r| r.scene == scene && r.parameter(Group::Mesh).is_some())
        .filter_map(|r| {
            let t = &r.summary.as_ref()?.timing;
            Some((
                r.nodes_target as f64,
                [
                    t.fm.median_ms,
                    t.cd.median_ms,
                    t.cc.median_ms,
                    t.sc.median_ms,
                    t.correction.median_ms,
                ],
            ))
        })
        .collect();
    bars.sort_by(|a, b| a.0.total_cmp(&b.0));
    bars
}

/// Fig. 8: stacked stage medians per mesh size, one panel per scene, with the paper's totals.
fn stage_times<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, runs: &[ReportRun]) -> DrawResult
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let (title, body) = root.split_vertically(40);
    title.titled(
        "Time per step by stage and mesh size (medians; the paper's Fig. 8)",
        ("sans-serif", 22),
    )?;
    let panels = body.split_evenly((1, 2));
    let ymax = runs
        .iter()
        .filter(|r| r.parameter(Group::Mesh).is_some())
        .filter_map(|r| r.summary.as_ref())
        .map(|s| {
            let t = &s.timing;
            t.fm.median_ms
                + t.cd.median_ms
                + t.cc.median_ms
                + t.sc.median_ms
                + t.correction.median_ms
        })
        .chain(PAPER_TIME_PER_STEP.iter().map(|p| p.1))
        .fold(0.0, f64::max);
    for (panel, scene) in panels.iter().zip(["simple", "complex"]) {
        let bars = stage_bars(runs, scene);
        let mut chart = ChartBuilder::on(panel)
            .caption(
                format!("{scene} path, inverse controller"),
                ("sans-serif", 18),
            )
            .margin(12)
            .x_label_area_size(45)
            .y_label_area_size(60)
            .build_cartesian_2d(300.0..2100.0, 0.0..ymax * 1.15)?;
        chart
            .configure_mesh()
            .x_desc("gel nodes (mesher target)")
            .y_desc("time per step [ms]")
            .label_style(("sans-serif", 14))
            .axis_desc_style(("sans-serif", 15))
            .draw()?;
        let half = 90.0;
        for (k, name) in STAGE_NAMES.iter().enumerate() {
            let color = COLORS[k];
            chart
                .draw_series(bars.iter().map(|(x, t)| {
                    let y0: f64 = t[..k].iter().sum();
                    let y1 = y0 + t[k];
                    Rectangle::new([(x - half, y0), (x + half, y1)], color.filled())
                }))?
                .label(*name)
                .legend(move |(x, y)| {
                    Rectangle::new([(x, y - 5), (x + 14, y + 5)], color.filled())
                });
        }
        chart
            .draw_series(
                PAPER_TIME_PER_STEP
                    .iter()
                    .map(|&(n, t)| Cross::new((n as f64, t), 7, BLACK.stroke_width(2))),
            )?
            .label("the paper's time per step (SOFA + GPU)")
            .legend(|(x, y)| Cross::new((x + 7, y), 5, BLACK.stroke_width(2)));
        legend(&mut chart, 13, SeriesLabelPosition::UpperLeft)?;
    }
    Ok(())
}

/// Speed against error: CPU time per step summed over threads (a background thread is not
/// free) against e_mean, every run, coloured by group; the paper's wall time per step beside.
fn speed_vs_error<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    runs: &[ReportRun],
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let pts: Vec<(&ReportRun, f64, f64)> =
        runs.iter()
            .filter_map(|r| {
                let s = r.summary.as_ref()?;
                (s.e_mean_mm.is_finite() && s.e_mean_mm > 0.0 && s.cpu_ms_per_step > 0.0)
                    .then_some((r, s.e_mean_mm, s.cpu_ms_per_step))
            })
            .collect();
    let (xlo, xhi) = pts
        .iter()
        .map(|p| p.1)
        .chain(PAPER_COMPLEX_E_MEAN.iter().map(|p| p.1))
        .fold((f64::INFINITY, 0.0f64), |(a, b), x| (a.min(x), b.max(x)));
    let ymax = pts
        .iter()
        .map(|p| p.2)
        .chain(PAPER_TIME_PER_STEP.iter().map(|p| p.1))
        .fold(0.0, f64::max);
    let (xlo, xhi) = if xlo.is_finite() && xhi > xlo {
        (xlo, xhi)
    } else {
        (0.1, 10.0)
    };
    let mut builder = ChartBuilder::on(root);
    builder
        .caption(
            "Speed against error: CPU time per step (all threads) against e_mean, every run",
            ("sans-serif", 22),
        )
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(60);
    // Log scale only when the errors span more than two decades (a naive run that
    // drifts far away); its tick labels are sparse, so the x label says so.
    if xhi / xlo > 100.0 {
        let mut chart =
            builder.build_cartesian_2d((xlo * 0.7..xhi * 1.4).log_scale(), 0.0..ymax * 1.15)?;
        chart
            .configure_mesh()
            .x_desc("e_mean [mm] (log scale)")
            .y_desc("CPU time per step, all threads [ms]")
            .x_labels(8)
            .x_label_formatter(&|x| format!("{x:.2}"))
            .label_style(("sans-serif", 14))
            .axis_desc_style(("sans-serif", 15))
            .draw()?;
        speed_series(&mut chart, &pts)
    } else {
        let pad = 0.08 * (xhi - xlo);
        let mut chart =
            builder.build_cartesian_2d((xlo - pad).max(0.0)..xhi + pad, 0.0..ymax * 1.15)?;
        chart
            .configure_mesh()
            .x_desc("e_mean [mm]")
            .y_desc("CPU time per step, all threads [ms]")
            .label_style(("sans-serif", 14))
            .axis_desc_style(("sans-serif", 15))
            .draw()?;
        speed_series(&mut chart, &pts)
    }
}

/// A series of [`speed_vs_error`]: (legend, colour index, simple scene, points (e_mean, time,
/// completed)).
type Series = (String, usize, bool, Vec<(f64, f64, bool)>);

/// One series per (group, controller, scene) so that every marker has a legend entry: the
/// colour says the group (the controllers group splits into inverse and naive), the shape the
/// scene (circle: complex, triangle: simple); a hollow marker is a run that did not complete.
fn speed_groups(pts: &[(&ReportRun, f64, f64)]) -> Vec<Series> {
    let mut series: Vec<Series> = Vec::new();
    for (r, x, y) in pts {
        for m in &r.memberships {
            let (name, colour) = match (m.group, r.controller) {
                // After every group's colour.
                (Group::Controllers, ControllerKind::Naive) => {
                    ("controllers (naive)".to_owned(), Group::ALL.len())
                }
                (Group::Controllers, ControllerKind::Inverse) => {
                    ("controllers (inverse)".to_owned(), 0)
                }
                (g, _) => (
                    g.name().to_owned(),
                    Group::ALL.iter().position(|a| *a == g).unwrap_or(0),
                ),
            };
            let key = format!("{name}, {}", r.scene);
            let done = r.completed();
            match series.iter_mut().find(|s| s.0 == key) {
                Some(s) => s.3.push((*x, *y, done)),
                None => series.push((key, colour, r.scene == "simple", vec![(*x, *y, done)])),
            }
        }
    }
    series.sort_by_key(|s| (s.1, s.2));
    series
}

/// Points of [`speed_vs_error`] and the paper's, on either x scale.
fn speed_series<'a, DB: DrawingBackend + 'a, X>(
    chart: &mut ChartContext<'a, DB, Cartesian2d<X, plotters::coord::types::RangedCoordf64>>,
    pts: &[(&ReportRun, f64, f64)],
) -> DrawResult
where
    DB::ErrorType: 'static,
    X: Ranged<ValueType = f64>,
{
    for (name, colour, simple, p) in &speed_groups(pts) {
        let color = COLORS[colour % COLORS.len()];
        let style = move |done: bool| {
            if done {
                color.filled()
            } else {
                color.stroke_width(2)
            }
        };
        if *simple {
            chart
                .draw_series(
                    p.iter()
                        .map(move |&(x, y, done)| TriangleMarker::new((x, y), 7, style(done))),
                )?
                .label(name.clone())
                .legend(move |(x, y)| TriangleMarker::new((x + 7, y), 6, color.filled()));
        } else {
            chart
                .draw_series(
                    p.iter()
                        .map(move |&(x, y, done)| Circle::new((x, y), 6, style(done))),
                )?
                .label(name.clone())
                .legend(move |(x, y)| Circle::new((x + 7, y), 5, color.filled()));
        }
    }
    chart
        .draw_series(
            PAPER_COMPLEX_E_MEAN.iter().filter_map(|&(n, e)| {
                Some(Cross::new((e, paper_time(n)?), 8, BLACK.stroke_width(2)))
            }),
        )?
        .label("the paper, complex path (600 / 1500 / 1800 nodes)")
        .legend(|(x, y)| Cross::new((x + 7, y), 5, BLACK.stroke_width(2)));
    legend(chart, 14, SeriesLabelPosition::UpperRight)?;
    Ok(())
}

//! The suite's chart (`suite.svg`, `suite.png`): e_mean, e_max and e_final of every scene, the
//! first controller's filled and the others' (by default the paper's update) hollow, the "must"
//! targets as lines, the first controller's obstacle hits and failures marked.

use super::SuiteRow;
use crate::output::{OutputError, OutputFailure};
use crate::run::Outcome;
use plotters::prelude::*;
use std::path::Path;

/// Chart size for `n` scenes: one row each.
fn size(n: usize) -> (u32, u32) {
    (1100, 140 + 24 * u32::try_from(n).unwrap_or(200).min(200))
}

/// The targets drawn: label, value [mm], colour of the metric.
const METRICS: [(&str, RGBColor); 3] = [
    ("e_mean", RGBColor(31, 119, 180)),
    ("e_max", RGBColor(214, 39, 40)),
    ("e_final", RGBColor(44, 160, 44)),
];

/// Draws the chart of `rows` into `dir/suite.svg` and `dir/suite.png`.
///
/// # Errors
/// [`OutputError`] naming the file.
pub fn write_chart(rows: &[SuiteRow], dir: &Path) -> Result<(), OutputError> {
    crate::report::charts::register_fonts();
    let scenes = scene_names(rows);
    let svg = dir.join("suite.svg");
    draw(
        rows,
        SVGBackend::new(&svg, size(scenes.len())).into_drawing_area(),
    )
    .map_err(|e| OutputError::new(&svg, OutputFailure::Chart(e.to_string())))?;
    let png = dir.join("suite.png");
    draw(
        rows,
        BitMapBackend::new(&png, size(scenes.len())).into_drawing_area(),
    )
    .map_err(|e| OutputError::new(&png, OutputFailure::Chart(e.to_string())))
}

/// The scenes of `rows`, in order of first appearance.
fn scene_names(rows: &[SuiteRow]) -> Vec<&str> {
    let mut names: Vec<&str> = Vec::new();
    for r in rows {
        if !names.contains(&r.scene.as_str()) {
            names.push(&r.scene);
        }
    }
    names
}

/// The metric `k` of [`METRICS`] of a run.
fn metric(s: &crate::run::RunSummary, k: usize) -> f64 {
    [s.e_mean_mm, s.e_max_mm, s.e_final_mm][k]
}

fn draw<DB: DrawingBackend>(
    rows: &[SuiteRow],
    root: DrawingArea<DB, plotters::coord::Shift>,
) -> Result<(), Box<dyn std::error::Error>>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let names = scene_names(rows);
    let n = names.len().max(1);
    let row_of = |r: &SuiteRow| names.iter().position(|s| *s == r.scene).unwrap_or(0) as f64;
    let first = rows.first().map_or("", |r| r.controller.as_str());
    let mut others: Vec<&str> = Vec::new();
    for r in rows.iter().filter(|r| r.controller != first) {
        if !others.contains(&r.controller.as_str()) {
            others.push(&r.controller);
        }
    }
    let others = others.join(", ");
    let ymax = rows
        .iter()
        .flat_map(|r| &r.summary)
        .flat_map(|s| (0..3).map(|k| metric(s, k)))
        .filter(|v| v.is_finite())
        .fold(3.5_f64, f64::max)
        * 1.08;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "The public suite: tracking errors per scene (lines: the targets)",
            ("sans-serif", 20),
        )
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(170)
        .build_cartesian_2d(0.0..ymax, -0.5..n as f64 - 0.5)?;
    chart
        .configure_mesh()
        .y_labels(n)
        .y_label_formatter(&|y| {
            let i = y.round();
            if (y - i).abs() < 1e-6 && i >= 0.0 {
                names
                    .get(i as usize)
                    .map_or(String::new(), |s| (*s).to_owned())
            } else {
                String::new()
            }
        })
        .disable_y_mesh()
        .x_desc("error [mm]")
        .label_style(("sans-serif", 13))
        .axis_desc_style(("sans-serif", 15))
        .draw()?;
    for (target, k, what) in [(1.0, 0, "e_mean, e_final ≤ 1 mm"), (3.0, 1, "e_max ≤ 3 mm")] {
        let colour = METRICS[k].1;
        chart
            .draw_series(LineSeries::new(
                [(target, -0.5), (target, n as f64 - 0.5)],
                colour.stroke_width(1),
            ))?
            .label(format!("target: {what}"))
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 16, y)], colour));
    }
    for (k, (label, colour)) in METRICS.iter().enumerate() {
        let offset = (1.0 - k as f64) * 0.22;
        let points = |mine: bool| -> Vec<(f64, f64)> {
            rows.iter()
                .filter(|r| (r.controller == first) == mine)
                .filter_map(|r| {
                    let v = metric(r.summary.as_ref()?, k);
                    v.is_finite().then_some((v, row_of(r) + offset))
                })
                .collect()
        };
        let c = *colour;
        chart
            .draw_series(points(true).iter().map(|&p| Circle::new(p, 5, c.filled())))?
            .label(format!("{label} ({first})"))
            .legend(move |(x, y)| Circle::new((x + 8, y), 5, c.filled()));
        let hollow = points(false);
        if !hollow.is_empty() {
            chart
                .draw_series(hollow.iter().map(|&p| Circle::new(p, 5, c.stroke_width(2))))?
                .label(format!("{label} ({others})"))
                .legend(move |(x, y)| Circle::new((x + 8, y), 5, c.stroke_width(2)));
        }
    }
    let hits: Vec<(f64, f64)> = rows
        .iter()
        .filter(|r| r.controller == first)
        .filter(|r| {
            r.summary
                .as_ref()
                .is_none_or(|s| s.outcome == Outcome::ObstacleHit)
        })
        .map(|r| (ymax * 0.97, row_of(r)))
        .collect();
    chart
        .draw_series(
            hits.iter()
                .map(|&p| Cross::new(p, 7, BLACK.stroke_width(2))),
        )?
        .label(format!(
            "obstacle hit (or the scene could not run), {first}"
        ))
        .legend(|(x, y)| Cross::new((x + 8, y), 5, BLACK.stroke_width(2)));
    crate::report::charts::legend(&mut chart, 13, SeriesLabelPosition::LowerRight)?;
    root.present()?;
    Ok(())
}

//! What the charts show, as plain data (no drawing): the points of speed against error with
//! their labels, the stacked stage means per mesh size, the error-against-depth lines, the
//! paper's reference figures, and the tick texts. The unit tests check these, not pixels.

use super::super::{
    Group, PAPER_BOUNDS, PAPER_COMPLEX_E_MEAN, ReportRun, controller_name, paper_time,
};
use crate::run::ControllerKind;

/// What a chart needs of one run (taken from a [`ReportRun`] by [`RunFacts::of`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct RunFacts {
    /// Scene name.
    pub scene: String,
    /// Whether the run is the naive baseline.
    pub naive: bool,
    /// Gel nodes of the mesh the run used (the mesher's result, e.g. 1485).
    pub nodes: usize,
    /// Gel nodes asked of the mesher (e.g. 1500; the paper's mesh sizes).
    pub nodes_target: usize,
    /// The groups the run belongs to.
    pub groups: Vec<Group>,
    /// δq [rad].
    pub delta_q: f64,
    /// Blend distance d [mm].
    pub blend_distance_mm: f64,
    /// Sliding-constraint spacing d_n [mm].
    pub constraint_spacing_mm: f64,
    /// The run's scene overrides (`field`, TOML value).
    pub overrides: Vec<(String, String)>,
    /// Whether the run started (it has a summary).
    pub started: bool,
    /// Whether it reached its last planned step.
    pub completed: bool,
    /// Steps run.
    pub steps: usize,
    /// e_mean [mm].
    pub e_mean_mm: f64,
    /// e_max [mm].
    pub e_max_mm: f64,
    /// CPU time per step, summed over the threads [ms].
    pub cpu_ms_per_step: f64,
    /// Mean wall time of each stage per step: FM, CD, CC, SC, corr [ms].
    pub stage_mean_ms: [f64; 5],
    /// Mean wall time of a whole step [ms].
    pub step_mean_ms: f64,
    /// Error against insertion depth `(depth, error)` [mm].
    pub error_by_depth: Vec<(f64, f64)>,
}

impl RunFacts {
    /// The facts of `r`.
    pub(crate) fn of(r: &ReportRun) -> Self {
        let mut f = Self {
            scene: r.scene.clone(),
            naive: r.controller == ControllerKind::Naive,
            nodes: r.nodes_target,
            nodes_target: r.nodes_target,
            groups: r.memberships.iter().map(|m| m.group).collect(),
            delta_q: r.delta_q,
            blend_distance_mm: r.blend_distance_mm,
            constraint_spacing_mm: r.constraint_spacing_mm,
            overrides: r.overrides.clone(),
            e_mean_mm: f64::NAN,
            e_max_mm: f64::NAN,
            cpu_ms_per_step: f64::NAN,
            step_mean_ms: f64::NAN,
            stage_mean_ms: [f64::NAN; 5],
            error_by_depth: r.error_by_depth.clone(),
            ..Self::default()
        };
        if let Some(s) = &r.summary {
            let t = &s.timing;
            f.started = true;
            f.completed = s.completed;
            f.steps = s.steps;
            f.nodes = s.gel_nodes;
            f.e_mean_mm = s.e_mean_mm;
            f.e_max_mm = s.e_max_mm;
            f.cpu_ms_per_step = s.cpu_ms_per_step;
            f.stage_mean_ms = [
                t.fm.mean_ms,
                t.cd.mean_ms,
                t.cc.mean_ms,
                t.sc.mean_ms,
                t.correction.mean_ms,
            ];
            f.step_mean_ms = t.total.mean_ms;
        }
        f
    }
}

// ---------------------------------------------------------------------------------------------
// Tick and category texts

/// A tick of an axis that measures (mm, ms): at most two decimals, trailing zeros dropped
/// (`25`, `2.5`, `0.25`; never `25.0`).
pub(crate) fn measure_tick(x: f64) -> String {
    let s = format!("{x:.2}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" { "0".into() } else { s.into() }
}

/// A tick of an axis that counts things: the nearest integer (`1485`, never `1485.0`).
pub(crate) fn count_tick(x: f64) -> String {
    let n = x.round();
    if n == 0.0 {
        "0".into()
    } else {
        format!("{n:.0}")
    }
}

/// The category of a mesh: `1485 nodes`.
pub(crate) fn nodes_label(nodes: usize) -> String {
    format!("{} nodes", count_tick(nodes as f64))
}

// ---------------------------------------------------------------------------------------------
// Speed against error

/// What a point of speed against error is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub(crate) enum PointKind {
    /// Every setting changed by one sweep (δq, d, d_n, factorisation).
    Setting,
    /// The default settings on another mesh size.
    Mesh,
    /// The naive baseline.
    Naive,
    /// The controller's own run: the scene as shipped (drawn last, on top).
    Default,
}

/// One run in speed against error.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct SpeedPoint {
    /// Scene name.
    pub scene: String,
    /// What the point is.
    pub kind: PointKind,
    /// CPU time per step, all threads [ms] (x).
    pub cpu_ms: f64,
    /// e_mean [mm] (y).
    pub e_mean_mm: f64,
    /// Whether the run completed (hollow marker otherwise).
    pub completed: bool,
    /// `1485 n, pipeline 1`: the mesh size and the setting.
    pub label: String,
}

/// The setting that sets a run apart: (kind, text), e.g. `(Setting, "δq 0.001 rad")`.
pub(crate) fn setting(f: &RunFacts) -> (PointKind, String) {
    if f.naive {
        return (PointKind::Naive, "naive baseline".into());
    }
    if f.groups.contains(&Group::Controllers) {
        return (PointKind::Default, "default".into());
    }
    // A run of several groups that is not the controllers' is the same run as one of them
    // (merged plans); its first group other than the mesh names its setting.
    match f.groups.iter().find(|g| **g != Group::Mesh) {
        None | Some(Group::Mesh | Group::Controllers) => (PointKind::Mesh, "default".into()),
        Some(Group::DeltaQ) => (PointKind::Setting, format!("δq {} rad", f.delta_q)),
        Some(Group::BlendDistance) => (
            PointKind::Setting,
            format!("d {} mm", measure_tick(f.blend_distance_mm)),
        ),
        Some(Group::ConstraintSpacing) => (
            PointKind::Setting,
            format!("d_n {} mm", measure_tick(f.constraint_spacing_mm)),
        ),
        Some(Group::Factorization) => (PointKind::Setting, factorization_setting(&f.overrides)),
    }
}

/// `adaptive 2` (background factorisation, the adaptive refresh with a pipeline of 2: the
/// default), `pipeline 2` (a factor every 2 steps, `solver.refresh_rotation = 0`) or
/// `synchronous`, from a run's overrides; `, f64` appended for a double-precision factor
/// (`solver.factor_precision = "double"`), `, far linear` for linear far elements
/// (`solver.far_elements`; the default: corotational).
pub(crate) fn factorization_setting(overrides: &[(String, String)]) -> String {
    let get = |field: &str| {
        overrides
            .iter()
            .rev()
            .find(|(f, _)| f == field)
            .map(|(_, v)| v.as_str())
    };
    let double = get("solver.factor_precision").map(|v| v.trim_matches('"')) == Some("double");
    let far = match get("solver.far_elements").map(|v| v.trim_matches('"')) {
        Some("linear") => ", far linear".to_string(),
        _ => String::new(),
    };
    let precision = format!("{}{far}", if double { ", f64" } else { "" });
    if get("solver.background_factorization") == Some("false") {
        return format!("synchronous{precision}");
    }
    let depth = get("solver.refactor_every").unwrap_or("2");
    let fixed = get("solver.refresh_rotation").and_then(|v| v.parse::<f64>().ok()) == Some(0.0);
    if fixed {
        format!("pipeline {depth}{precision}")
    } else {
        format!("adaptive {depth}{precision}")
    }
}

/// The point of a run (none when it did not start or has no finite e_mean or CPU time).
pub(crate) fn speed_point(f: &RunFacts) -> Option<SpeedPoint> {
    let ok = f.started
        && f.e_mean_mm.is_finite()
        && f.cpu_ms_per_step.is_finite()
        && f.cpu_ms_per_step > 0.0;
    if !ok {
        return None;
    }
    let (kind, text) = setting(f);
    let mut label = format!("{} n, {text}", count_tick(f.nodes as f64));
    if !f.completed {
        label.push_str(&format!(" (stopped at step {})", f.steps));
    }
    Some(SpeedPoint {
        scene: f.scene.clone(),
        kind,
        cpu_ms: f.cpu_ms_per_step,
        e_mean_mm: f.e_mean_mm,
        completed: f.completed,
        label,
    })
}

/// The points of `scene`, the controller's own run last (drawn on top).
pub(crate) fn speed_points(facts: &[RunFacts], scene: &str) -> Vec<SpeedPoint> {
    let mut v: Vec<SpeedPoint> = facts
        .iter()
        .filter(|f| f.scene == scene)
        .filter_map(speed_point)
        .collect();
    v.sort_by_key(|p| p.kind);
    v
}

/// The default settings in words, from the controller's own inverse run of any scene:
/// `δq 0.01 rad, d 20 mm, d_n 10 mm, adaptive 2`.
pub(crate) fn default_settings(facts: &[RunFacts]) -> Option<String> {
    let f = facts
        .iter()
        .find(|f| !f.naive && f.groups.contains(&Group::Controllers))?;
    Some(format!(
        "δq {} rad, d {} mm, d_n {} mm, {}",
        f.delta_q,
        measure_tick(f.blend_distance_mm),
        measure_tick(f.constraint_spacing_mm),
        factorization_setting(&f.overrides)
    ))
}

/// One of the paper's (time per step, e_mean) points.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct PaperPoint {
    /// The paper's wall time per step [ms].
    pub ms: f64,
    /// The paper's e_mean [mm].
    pub e_mean_mm: f64,
    /// `the paper, 1500 n: 12.92 ms, 2.6 mm`.
    pub label: String,
}

/// The paper's points of `scene` in speed against error: the complex path at 600, 1500 and
/// 1800 nodes, the simple path at 1500.
pub(crate) fn paper_points(scene: &str) -> Vec<PaperPoint> {
    let pts: Vec<(usize, f64)> = match scene {
        "complex" => PAPER_COMPLEX_E_MEAN.to_vec(),
        "simple" => paper_bounds(scene)
            .map(|(m, _)| vec![(1500, m)])
            .unwrap_or_default(),
        _ => Vec::new(),
    };
    pts.into_iter()
        .filter_map(|(n, e)| {
            let ms = paper_time(n)?;
            Some(PaperPoint {
                ms,
                e_mean_mm: e,
                label: format!(
                    "the paper, {} n: {} ms, {} mm",
                    count_tick(n as f64),
                    measure_tick(ms),
                    measure_tick(e)
                ),
            })
        })
        .collect()
}

/// The paper's (e_mean, e_max) of `scene` [mm].
pub(crate) fn paper_bounds(scene: &str) -> Option<(f64, f64)> {
    PAPER_BOUNDS
        .iter()
        .find(|(s, _, _)| *s == scene)
        .map(|&(_, m, x)| (m, x))
}

// ---------------------------------------------------------------------------------------------
// Stage times

/// The stages of a step, in the order they run, and the remainder of the step's mean.
pub(crate) const STAGE_NAMES: [&str; 6] = [
    "FM free motion",
    "CD proximity",
    "CC compliance",
    "SC constraint solves",
    "corr correction",
    "other (step mean − stage means)",
];

/// One stacked bar: the mean time of each stage per step, which add up to the mean step.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct StageBar {
    /// The category: `1485 nodes`.
    pub label: String,
    /// Gel nodes asked of the mesher (where the paper's time per step belongs).
    pub nodes_target: usize,
    /// Mean per step of each of [`STAGE_NAMES`] [ms]; the last is the step's mean less the
    /// stages' (zero when the stages cover the step).
    pub segments: [f64; 6],
    /// Mean wall time of a step [ms]: the segments' sum.
    pub step_mean_ms: f64,
}

/// The segments of a bar: the five stage means and what is left of the step mean (never
/// negative: the step's time is the sum of its stages', so the remainder is rounding).
pub(crate) fn stage_segments(stage_means: [f64; 5], step_mean: f64) -> [f64; 6] {
    let stages: f64 = stage_means.iter().sum();
    let other = (step_mean - stages).max(0.0);
    let [a, b, c, d, e] = stage_means;
    [a, b, c, d, e, other]
}

/// The bars of the mesh group's runs of `scene`, by node count.
pub(crate) fn stage_bars(facts: &[RunFacts], scene: &str) -> Vec<StageBar> {
    let mut bars: Vec<StageBar> = facts
        .iter()
        .filter(|f| f.scene == scene && f.started && f.groups.contains(&Group::Mesh))
        .filter(|f| f.step_mean_ms.is_finite() && f.stage_mean_ms.iter().all(|t| t.is_finite()))
        .map(|f| StageBar {
            label: nodes_label(f.nodes),
            nodes_target: f.nodes_target,
            segments: stage_segments(f.stage_mean_ms, f.step_mean_ms),
            step_mean_ms: f.step_mean_ms,
        })
        .collect();
    bars.sort_by_key(|b| b.nodes_target);
    bars
}

// ---------------------------------------------------------------------------------------------
// Error against depth

/// One line of error against depth.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct DepthLine {
    /// Whether it is the naive baseline.
    pub naive: bool,
    /// Legend: `inverse: e_mean 0.06 mm`.
    pub label: String,
    /// (depth, error) [mm], finite.
    pub points: Vec<(f64, f64)>,
}

/// The controllers' lines of `scene`.
pub(crate) fn depth_lines(facts: &[RunFacts], scene: &str) -> Vec<DepthLine> {
    facts
        .iter()
        .filter(|f| f.scene == scene && f.groups.contains(&Group::Controllers))
        .map(|f| {
            let c = if f.naive {
                ControllerKind::Naive
            } else {
                ControllerKind::Inverse
            };
            let mut label = controller_name(c).to_owned();
            if f.started {
                label.push_str(&format!(": e_mean {:.2} mm", f.e_mean_mm));
                if !f.completed {
                    label.push_str(&format!(" (stopped at step {}: see summary.md)", f.steps));
                }
            }
            DepthLine {
                naive: f.naive,
                label,
                points: f
                    .error_by_depth
                    .iter()
                    .copied()
                    .filter(|p| p.0.is_finite() && p.1.is_finite())
                    .collect(),
            }
        })
        .collect()
}

/// The paper's bounds of `scene` as labelled horizontal lines: (value [mm], label).
pub(crate) fn depth_references(scene: &str) -> Vec<(f64, String)> {
    paper_bounds(scene)
        .map(|(m, x)| {
            vec![
                (
                    m,
                    format!("the paper's e_mean, {scene}: {} mm", measure_tick(m)),
                ),
                (
                    x,
                    format!("the paper's e_max, {scene}: {} mm", measure_tick(x)),
                ),
            ]
        })
        .unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(scene: &str, groups: &[Group]) -> RunFacts {
        RunFacts {
            scene: scene.into(),
            nodes: 1485,
            nodes_target: 1500,
            groups: groups.to_vec(),
            delta_q: 0.01,
            blend_distance_mm: 20.0,
            constraint_spacing_mm: 10.0,
            started: true,
            completed: true,
            steps: 621,
            e_mean_mm: 0.9,
            e_max_mm: 4.4,
            cpu_ms_per_step: 4.8,
            stage_mean_ms: [3.1, 0.2, 0.9, 0.07, 0.3],
            step_mean_ms: 4.57,
            ..RunFacts::default()
        }
    }

    #[test]
    fn stacked_stage_means_add_up_to_the_mean_step() {
        // A remainder becomes the "other" segment.
        let s = stage_segments([1.0, 2.0, 3.0, 0.5, 0.25], 7.0);
        assert!((s[5] - 0.25).abs() < 1e-12);
        assert!((s.iter().sum::<f64>() - 7.0).abs() < 1e-9);
        // Stages that cover the step: no remainder.
        let s = stage_segments([3.1, 0.2, 0.9, 0.07, 0.3], 4.57);
        assert!(s[5] < 1e-9);
        assert!((s.iter().sum::<f64>() - 4.57).abs() < 1e-9);
        // Every bar of a scene adds up to its run's mean step.
        let mut facts = Vec::new();
        for (n, step) in [(609, 1.9), (1089, 3.3), (1485, 4.57), (1815, 6.8)] {
            let mut f = run("complex", &[Group::Mesh]);
            f.nodes = n;
            f.nodes_target = n + 10;
            // Stage means that leave 1 % of the step to "other".
            f.stage_mean_ms = [0.66, 0.04, 0.2, 0.02, 0.07].map(|x| x * step);
            f.step_mean_ms = step;
            facts.push(f);
        }
        let bars = stage_bars(&facts, "complex");
        assert_eq!(bars.len(), 4);
        for (b, f) in bars.iter().zip(&facts) {
            assert!((b.segments.iter().sum::<f64>() - f.step_mean_ms).abs() < 1e-9);
            assert_eq!(b.step_mean_ms, f.step_mean_ms);
            assert!(b.segments.iter().all(|t| *t >= 0.0));
            assert!((b.segments[5] - 0.01 * f.step_mean_ms).abs() < 1e-9);
        }
    }

    #[test]
    fn counts_are_integers_and_categories_name_the_node_count() {
        assert_eq!(count_tick(1485.0), "1485");
        assert_eq!(count_tick(400.0), "400");
        assert_eq!(count_tick(399.9999), "400");
        assert_eq!(count_tick(-0.2), "0");
        assert_eq!(nodes_label(1485), "1485 nodes");
        assert_eq!(measure_tick(25.0), "25");
        assert_eq!(measure_tick(2.5), "2.5");
        assert_eq!(measure_tick(0.25), "0.25");
        assert_eq!(measure_tick(-0.0001), "0");
    }

    #[test]
    fn every_speed_point_is_labelled_with_its_mesh_size_and_setting() {
        let mut facts = vec![
            run(
                "complex",
                &[Group::Controllers, Group::Mesh, Group::Factorization],
            ),
            run("complex", &[Group::DeltaQ]),
            run("complex", &[Group::Factorization]),
            run("complex", &[Group::Factorization]),
            run("complex", &[Group::Mesh]),
            run("complex", &[Group::Controllers]),
            run("simple", &[Group::Controllers]),
        ];
        facts[1].delta_q = 0.001;
        facts[2].overrides = vec![
            ("solver.refactor_every".into(), "3".into()),
            ("solver.refresh_rotation".into(), "0".into()),
        ];
        facts[3].overrides = vec![
            ("solver.background_factorization".into(), "false".into()),
            ("solver.factor_precision".into(), "\"double\"".into()),
        ];
        facts[4].nodes = 609;
        facts[5].naive = true;
        facts[5].completed = false;
        facts[5].steps = 256;
        let pts = speed_points(&facts, "complex");
        let labels: Vec<&str> = pts.iter().map(|p| p.label.as_str()).collect();
        assert_eq!(
            labels,
            [
                "1485 n, δq 0.001 rad",
                "1485 n, pipeline 3",
                "1485 n, synchronous, f64",
                "609 n, default",
                "1485 n, naive baseline (stopped at step 256)",
                "1485 n, default",
            ]
        );
        // The controller's own run is drawn last (on top of every other marker).
        assert_eq!(pts.last().map(|p| p.kind), Some(PointKind::Default));
        assert!(!pts[4].completed);
        // x is the CPU time per step, y e_mean.
        assert_eq!((pts[0].cpu_ms, pts[0].e_mean_mm), (4.8, 0.9));
        assert_eq!(
            default_settings(&facts).as_deref(),
            Some("δq 0.01 rad, d 20 mm, d_n 10 mm, adaptive 2")
        );
        // A run that did not start has no point.
        facts[1].started = false;
        assert_eq!(speed_points(&facts, "complex").len(), 5);
    }

    /// The factorisation group's settings name what differs from the default pipeline: the
    /// synchronous step, a double factor, linear far elements.
    #[test]
    fn factorisation_settings_name_the_far_elements_when_linear() {
        let o = |pairs: &[(&str, &str)]| -> Vec<(String, String)> {
            pairs
                .iter()
                .map(|(f, v)| (f.to_string(), v.to_string()))
                .collect()
        };
        assert_eq!(factorization_setting(&o(&[])), "adaptive 2");
        let paper = o(&[
            ("solver.background_factorization", "false"),
            ("solver.factor_precision", "\"double\""),
        ]);
        assert_eq!(factorization_setting(&paper), "synchronous, f64");
        let linear = o(&[("solver.far_elements", "\"linear\"")]);
        assert_eq!(factorization_setting(&linear), "adaptive 2, far linear");
        let corot = o(&[("solver.far_elements", "\"corotational\"")]);
        assert_eq!(factorization_setting(&corot), "adaptive 2");
    }

    #[test]
    fn the_papers_figures_are_the_references() {
        let complex = paper_points("complex");
        assert_eq!(complex.len(), 3);
        assert!(
            complex
                .iter()
                .any(|p| p.ms == 12.92 && p.e_mean_mm == 2.6 && p.label.contains("1500 n"))
        );
        let simple = paper_points("simple");
        assert_eq!((simple[0].ms, simple[0].e_mean_mm), (12.92, 0.5));
        let r = depth_references("simple");
        assert_eq!(r.iter().map(|x| x.0).collect::<Vec<_>>(), [0.5, 1.8]);
        assert!(r[1].1.contains("e_max") && r[1].1.contains("1.8 mm"));
        let r = depth_references("complex");
        assert_eq!(r.iter().map(|x| x.0).collect::<Vec<_>>(), [2.6, 6.0]);
        assert!(r[0].1.ends_with("2.6 mm") && r[1].1.ends_with("6 mm"));
    }
}

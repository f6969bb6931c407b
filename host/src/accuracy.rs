//! The gel pipeline's accuracy cost without the closed loop's amplification.
//!
//! A closed loop is chaotic: a step a hundredth of a millimetre off changes the next joints, a
//! contact opens a step earlier, and two pipelines that agree to round-off can end a run
//! millimetres apart. To measure what a pipeline (background factor, single precision, near
//! block, linear far field, …) costs, a scene runs closed loop once with the **exact step**
//! ([`EXACT_STEP`]: the whole corotational gel factorised at every step, in double precision),
//! then the joints of that run are replayed open loop through the pipeline under test
//! ([`run::replay`](crate::run::replay): one constraint solve at each step's joints). Both runs
//! then take the same joints; the differences of e_mean, e_max and e_final are the pipeline's
//! cost. Issue "speed" allows [`TOLERANCE_MM`].
//!
//! ```no_run
//! use needle_host::accuracy::{exact_run, replayed};
//! use needle_host::scene::Scene;
//!
//! let scene = Scene::builtin("simple").unwrap();
//! let exact = exact_run(&scene, None).unwrap();
//! let cost = replayed(&scene, &exact).unwrap();
//! println!("{:.3} mm", cost.largest_difference_mm());
//! ```

use crate::run::{RunError, RunOptions, RunSummary, replay, run};
use crate::scene::{Scene, SceneError};
use nalgebra::Vector3;
use serde::Serialize;

/// The exact step's scene overrides: the whole gel factorised at every step, synchronously, in
/// double precision, every element corotational.
pub const EXACT_STEP: [(&str, &str); 3] = [
    ("solver.background_factorization", "false"),
    ("solver.factor_precision", "\"double\""),
    ("solver.far_elements", "\"corotational\""),
];

/// The tolerance of issue "speed" on e_mean, e_max and e_final [mm].
pub const TOLERANCE_MM: f64 = 0.05;

/// A run's tracking errors [mm].
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Errors {
    /// Mean error with the tip inside the gel.
    pub e_mean_mm: f64,
    /// Largest error with the tip inside the gel.
    pub e_max_mm: f64,
    /// Error at the run's end.
    pub e_final_mm: f64,
}

impl Errors {
    /// The errors of a run's summary.
    pub fn of(s: &RunSummary) -> Self {
        Self {
            e_mean_mm: s.e_mean_mm,
            e_max_mm: s.e_max_mm,
            e_final_mm: s.e_final_mm,
        }
    }

    fn as_array(self) -> [f64; 3] {
        [self.e_mean_mm, self.e_max_mm, self.e_final_mm]
    }
}

/// A scene run closed loop with the exact step: its errors and its joints at every step.
#[derive(Clone, Debug)]
pub struct ExactRun {
    /// The closed loop's summary.
    pub summary: RunSummary,
    /// The joints of every step, in order.
    pub joints: Vec<[f64; 6]>,
    /// The tip's position at the end of every step [mm].
    pub tips: Vec<Vector3<f64>>,
}

/// The exact step's and a pipeline's errors on the same joints.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct AccuracyCost {
    /// The exact step, closed loop.
    pub exact: Errors,
    /// The pipeline, replaying the exact run's joints.
    pub pipeline: Errors,
    /// Steps replayed.
    pub steps: usize,
    /// Whether the exact closed loop reached its last planned step.
    pub exact_completed: bool,
    /// How many steps, from the first, end with the two tips within [`TOLERANCE_MM`] of each
    /// other (`steps` when all do): where the replay departs from the exact run, e.g. at a
    /// contact that slips in one and sticks in the other.
    pub agreeing_steps: usize,
    /// The largest distance between the two tips at the end of a step [mm] (NaN when a tip
    /// is not finite).
    pub tip_difference_max_mm: f64,
}

impl AccuracyCost {
    /// The largest of the three differences |exact − pipeline| [mm] (NaN when an error is not
    /// finite).
    pub fn largest_difference_mm(&self) -> f64 {
        let (a, b) = (self.exact.as_array(), self.pipeline.as_array());
        let d = [0, 1, 2].map(|k| (a[k] - b[k]).abs());
        if d.iter().any(|x| x.is_nan()) {
            return f64::NAN;
        }
        d.into_iter().fold(0.0, f64::max)
    }

    /// Whether the three differences are within `tolerance_mm`.
    pub fn within(&self, tolerance_mm: f64) -> bool {
        self.largest_difference_mm() <= tolerance_mm
    }
}

/// Why an accuracy comparison could not be made.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum AccuracyError {
    /// The exact step's overrides do not apply to the scene.
    #[error("the exact step's settings")]
    Scene(#[from] SceneError),
    /// A run could not be set up.
    #[error(transparent)]
    Run(#[from] RunError),
    /// The replay drives 6-joint arms only.
    #[error("only 6-joint arms are replayed (the scene's arm has {0} joints)")]
    Joints(usize),
}

/// Runs `scene` closed loop with the exact step ([`EXACT_STEP`] on top of the scene's own
/// settings), at most `steps` steps (default: the scene's whole insertion).
///
/// # Errors
/// [`AccuracyError`] when the scene cannot be set up or its arm does not have 6 joints.
pub fn exact_run(scene: &Scene, steps: Option<usize>) -> Result<ExactRun, AccuracyError> {
    let overrides: Vec<(String, String)> = (EXACT_STEP.iter())
        .map(|(f, v)| (f.to_string(), v.to_string()))
        .collect();
    let exact = scene.with_overrides(&overrides)?;
    let opts = RunOptions {
        steps,
        ..RunOptions::default()
    };
    let closed = run(&exact, &opts, |_| {})?;
    let joints = (closed.reports.iter())
        .map(|r| r.q.to_array::<6>().ok_or(AccuracyError::Joints(r.q.len())))
        .collect::<Result<Vec<_>, _>>()?;
    let tips = closed.reports.iter().map(|r| r.tip).collect();
    Ok(ExactRun {
        summary: closed.summary,
        joints,
        tips,
    })
}

/// Replays `exact`'s joints open loop through `scene` (the pipeline under test: the scene the
/// exact run was made from, with the pipeline's settings) and compares the errors.
///
/// # Errors
/// [`AccuracyError::Run`] when the scene cannot be set up.
pub fn replayed(scene: &Scene, exact: &ExactRun) -> Result<AccuracyCost, AccuracyError> {
    let replay = replay(scene, exact.joints.clone())?;
    let tips: Vec<Vector3<f64>> = replay.reports.iter().map(|r| r.tip).collect();
    let (agreeing_steps, tip_difference_max_mm) = tip_agreement(&exact.tips, &tips, TOLERANCE_MM);
    Ok(AccuracyCost {
        exact: Errors::of(&exact.summary),
        pipeline: Errors::of(&replay.summary),
        steps: replay.summary.steps,
        exact_completed: exact.summary.completed,
        agreeing_steps,
        tip_difference_max_mm,
    })
}

/// Over the steps both runs made: how many leading steps have their tips within `tolerance_mm`
/// of each other, and the largest distance between them (NaN when one is not finite; a
/// non-finite step ends the agreement).
pub fn tip_agreement(a: &[Vector3<f64>], b: &[Vector3<f64>], tolerance_mm: f64) -> (usize, f64) {
    let mut agreeing = None;
    let mut largest = 0.0f64;
    for (k, (x, y)) in a.iter().zip(b).enumerate() {
        let d = (x - y).norm();
        largest = if d.is_nan() || largest.is_nan() {
            f64::NAN
        } else {
            largest.max(d)
        };
        if agreeing.is_none() && (d.is_nan() || d > tolerance_mm) {
            agreeing = Some(k);
        }
    }
    (agreeing.unwrap_or(a.len().min(b.len())), largest)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn errors(e: [f64; 3]) -> Errors {
        Errors {
            e_mean_mm: e[0],
            e_max_mm: e[1],
            e_final_mm: e[2],
        }
    }

    #[test]
    fn the_largest_difference_is_the_worst_of_the_three_and_nan_is_never_within() {
        let cost = |a, b| AccuracyCost {
            exact: errors(a),
            pipeline: errors(b),
            steps: 10,
            exact_completed: true,
            agreeing_steps: 10,
            tip_difference_max_mm: 0.0,
        };
        let c = cost([0.1, 0.5, 0.02], [0.11, 0.47, 0.09]);
        assert!((c.largest_difference_mm() - 0.07).abs() < 1e-12);
        assert!(!c.within(0.05) && c.within(0.08));
        let n = cost([0.1, f64::NAN, 0.0], [0.1, 0.5, 0.0]);
        assert!(n.largest_difference_mm().is_nan());
        assert!(!n.within(1e9), "a NaN difference is never within");
    }

    #[test]
    fn tip_agreement_counts_the_steps_before_the_first_departure() {
        let v = |x| Vector3::new(x, 0.0, 0.0);
        let a = [v(0.0), v(1.0), v(2.0), v(3.0)];
        // Within the tolerance, then a departure at step 2; step 3 back within it does not
        // extend the agreement.
        let b = [v(0.01), v(1.04), v(2.2), v(3.0)];
        let (n, largest) = tip_agreement(&a, &b, 0.05);
        assert_eq!(n, 2);
        assert!((largest - 0.2).abs() < 1e-12, "{largest}");
        // All within: every step both runs made (the shorter one's count).
        assert_eq!(tip_agreement(&a, &a[..3], 0.05), (3, 0.0));
        // A non-finite tip ends the agreement and makes the largest difference NaN.
        let c = [v(0.0), v(f64::NAN), v(2.0), v(3.0)];
        let (n, largest) = tip_agreement(&a, &c, 0.05);
        assert_eq!(n, 1);
        assert!(largest.is_nan());
    }

    #[test]
    fn the_exact_replay_of_the_exact_step_costs_nothing() {
        // The exact step replaying its own joints: the same step, to the constraint solve's
        // tolerance (the replay's solve at each step's joints starts elsewhere than the closed
        // loop's final solve, so its λ agrees to the GS tolerance, not bit for bit: at 1e-7 the
        // errors agreed within 1e-9 mm until 2026-12-02, to 1.3e-9 mm on the trajectory of the
        // capped angles' damping; at the tolerance 1e-6, the default since, to 3.0e-8 mm), so
        // the bound is a tenth of the tolerance, in mm.
        let scene = Scene::builtin("simple")
            .unwrap()
            .with_overrides(&[("gel.box.nodes".into(), "300".into())])
            .unwrap();
        let exact = exact_run(&scene, Some(250)).unwrap();
        assert_eq!(exact.joints.len(), 250);
        let overrides: Vec<(String, String)> = (EXACT_STEP.iter())
            .map(|(f, v)| (f.to_string(), v.to_string()))
            .collect();
        let same = replayed(&scene.with_overrides(&overrides).unwrap(), &exact).unwrap();
        assert_eq!(same.steps, 250);
        assert_eq!(same.agreeing_steps, 250, "{same:?}");
        assert!(same.tip_difference_max_mm < 1e-6, "{same:?}");
        let bound = 0.1 * scene.solver.gs_tolerance;
        assert!(
            same.largest_difference_mm() < bound,
            "{same:?}: the exact step replayed is not the exact step (bound {bound:e} mm)"
        );
    }
}

//! The tuning of a step: one [`StepParams`] with `pub` fields and a `Default`, built from a scene
//! by [`crate::setup`] (the step never sees the scene).

/// Needle–gel interaction: the paper's constraints φ (tip contact, puncture) and ψ (sliding).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Interaction {
    /// Puncture threshold p_f: the tip's normal contact force at which the surface gives way [N].
    pub puncture_force: f64,
    /// Coulomb friction coefficient μ_s of the tip on the gel surface [-].
    pub surface_friction: f64,
    /// Shaft friction coefficient μ_n of each sliding point (axial force ≤ μ_n·lateral + r_0) [-].
    pub shaft_friction: f64,
    /// Constant axial resistance r_0 of each sliding point [N].
    pub shaft_resistance: f64,
    /// Spacing d_n between sliding points along the cut [mm] (at least the element size).
    pub constraint_spacing: f64,
}

impl Default for Interaction {
    fn default() -> Self {
        Self {
            puncture_force: 0.2,
            surface_friction: 0.3,
            shaft_friction: 0.1,
            shaft_resistance: 0.0,
            constraint_spacing: 10.0,
        }
    }
}

/// How the target parameter `c` moves along the path.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum TargetMotion {
    /// From the start to the end of the path, then held there.
    #[default]
    Insert,
    /// To the end of the path and back to the start (the tip in the air again), repeated.
    BackAndForth,
}

/// The insertion schedule: where the target is after each step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Insertion {
    /// Advance of the target per step, as path length [mm].
    pub advance_per_step: f64,
    /// How the target moves.
    pub motion: TargetMotion,
}

impl Default for Insertion {
    fn default() -> Self {
        Self {
            advance_per_step: 0.1,
            motion: TargetMotion::Insert,
        }
    }
}

impl Insertion {
    /// The target's arc length `c` after step `k` (0-based) on a path of `total` length [mm]:
    /// `(k + 1)·advance`, held at the end (`Insert`) or reflected back and forth.
    ///
    /// # Example
    /// ```
    /// use needle_host::step::{Insertion, TargetMotion};
    ///
    /// let there_and_back = Insertion { advance_per_step: 1.0, motion: TargetMotion::BackAndForth };
    /// let c: Vec<f64> = (0..22).map(|k| there_and_back.target_arc(10.0, k)).collect();
    /// assert_eq!((c[8], c[9], c[10], c[19], c[20]), (9.0, 10.0, 9.0, 0.0, 1.0));
    /// assert_eq!(Insertion { motion: TargetMotion::Insert, ..there_and_back }.target_arc(10.0, 500), 10.0);
    /// ```
    pub fn target_arc(&self, total: f64, k: usize) -> f64 {
        let s = (k + 1) as f64 * self.advance_per_step;
        match self.motion {
            TargetMotion::Insert => s.min(total),
            TargetMotion::BackAndForth => {
                if total <= 0.0 {
                    return 0.0;
                }
                let phase = s.rem_euclid(2.0 * total);
                if phase <= total {
                    phase
                } else {
                    2.0 * total - phase
                }
            }
        }
    }

    /// Steps of a whole insertion on a path of `total` length: to the end, or there and back.
    ///
    /// # Example
    /// ```
    /// use needle_host::step::{Insertion, TargetMotion};
    ///
    /// let i = Insertion { advance_per_step: 1.0, motion: TargetMotion::BackAndForth };
    /// assert_eq!(i.default_steps(10.0), 20);
    /// ```
    pub fn default_steps(&self, total: f64) -> usize {
        let one_way = (total / self.advance_per_step).ceil() as usize;
        match self.motion {
            TargetMotion::Insert => one_way,
            TargetMotion::BackAndForth => 2 * one_way,
        }
    }
}

/// The tuning of a step (rapier's `IntegrationParameters`): `pub` fields, a `Default`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepParams {
    /// Needle–gel interaction.
    pub interaction: Interaction,
    /// Where the target is after each step.
    pub insertion: Insertion,
    /// Control period: time between two steps [s] (carried in the frame: the core bounds the
    /// joint steps by `speed limit × dt`).
    pub dt: f64,
}

impl Default for StepParams {
    fn default() -> Self {
        Self {
            interaction: Interaction::default(),
            insertion: Insertion::default(),
            dt: 0.04,
        }
    }
}

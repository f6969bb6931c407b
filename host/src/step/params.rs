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
    /// How far the target may lead the tip along the path [mm] before it waits for the tip
    /// ([`Insertion::next_arc`]); infinite: the target keeps to its schedule
    /// ([`Insertion::target_arc`]) whatever the tip does.
    pub max_lead: f64,
}

impl Default for Insertion {
    fn default() -> Self {
        Self {
            advance_per_step: 0.1,
            motion: TargetMotion::Insert,
            max_lead: f64::INFINITY,
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
    /// let there_and_back = Insertion {
    ///     advance_per_step: 1.0,
    ///     motion: TargetMotion::BackAndForth,
    ///     ..Insertion::default()
    /// };
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

    /// The target's arc length after the step that starts with the target at `c` [mm] and the
    /// tip `lag` behind it along the path [mm] (the target minus the tip, along the path's
    /// tangent there), step `k` (0-based) of a path of `total` length: on schedule
    /// ([`Insertion::target_arc`]) with an infinite `max_lead` or back and forth; else `c`
    /// advances by `advance_per_step` (never faster), up to the path's end, but waits while the
    /// tip lags more than `max_lead` behind it. A tip held back (pressing on a stiff layer,
    /// blocked by an obstacle, slower than the schedule) then does not leave its target running
    /// away along the path: what the controller is asked stays a correction it can make.
    ///
    /// # Example
    /// ```
    /// use needle_host::step::Insertion;
    ///
    /// let follow = Insertion { advance_per_step: 0.1, max_lead: 0.5, ..Insertion::default() };
    /// assert_eq!(follow.next_arc(10.0, 0, 0.0, 0.0), 0.1); // the first step: on schedule
    /// assert!((follow.next_arc(10.0, 5, 3.0, 0.2) - 3.1).abs() < 1e-15); // the tip keeps up
    /// assert_eq!(follow.next_arc(10.0, 5, 3.0, 0.6), 3.0); // it lags: the target waits
    /// assert_eq!(follow.next_arc(10.0, 500, 10.0, 0.0), 10.0); // held at the end
    /// let schedule = Insertion { max_lead: f64::INFINITY, ..follow };
    /// assert!((schedule.next_arc(10.0, 5, 3.0, 0.6) - 0.6).abs() < 1e-15);
    /// ```
    pub fn next_arc(&self, total: f64, k: usize, c: f64, lag: f64) -> f64 {
        if !self.follows_tip() || k == 0 {
            return self.target_arc(total, k);
        }
        if lag > self.max_lead {
            c
        } else {
            (c + self.advance_per_step).min(total)
        }
    }

    /// Whether the target waits for the tip ([`Insertion::next_arc`]): a finite `max_lead` and
    /// an insertion (a back-and-forth motion keeps to its schedule).
    pub fn follows_tip(&self) -> bool {
        self.max_lead.is_finite() && self.motion == TargetMotion::Insert
    }

    /// Steps of a whole insertion on a path of `total` length: to the end, or there and back.
    ///
    /// # Example
    /// ```
    /// use needle_host::step::{Insertion, TargetMotion};
    ///
    /// let i = Insertion {
    ///     advance_per_step: 1.0,
    ///     motion: TargetMotion::BackAndForth,
    ///     ..Insertion::default()
    /// };
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
    /// The controller's trust region on the needle base per step [mm]
    /// (`inverse.max_base_step`; `+∞`: none): how far the needle may advance along itself in one
    /// step, so how far behind the needle point nearest to an obstacle its clearance rows reach
    /// ([`super::observe::clearance_observations`]).
    pub max_base_step: f64,
    /// The largest shift of the entry point from rest the controller plans
    /// (`inverse.max_entry_shift`; `+∞`: none) [mm]: a clearance row of the frame
    /// ([`super::observe::clearance_observations`]).
    pub max_entry_shift: f64,
    /// The needle's yield strain (`needle.yield_strain`; `+∞`: none) [-]: the most bent
    /// nodes' strains as clearance rows of the frame, so that the controller keeps the
    /// needle's bend under it ([`super::observe::bending_rows`]).
    pub yield_strain: f64,
    /// The largest angle [rad] between the target's heading shown to the controller and the
    /// gel's inward normal at the entry point once the tip has slid on the surface before
    /// puncture ([`crate::world::World::tip_slid`]; `inverse.entry_tilt`, by default 0.9 of
    /// the friction cone's half-angle `atan μ_s`; π/2 or more: never turned). A needle pushed
    /// at more than `atan μ_s` from the normal slides on the surface instead of indenting it.
    pub entry_tilt: f64,
}

impl Default for StepParams {
    fn default() -> Self {
        Self {
            interaction: Interaction::default(),
            insertion: Insertion::default(),
            dt: 0.04,
            max_base_step: 5.0,
            max_entry_shift: f64::INFINITY,
            yield_strain: f64::INFINITY,
            entry_tilt: EntryTilt::default().angle(Interaction::default().surface_friction),
        }
    }
}

/// The largest tilt of the heading shown to the controller from the entry's normal, once the
/// tip has slid on the surface before puncture (`inverse.entry_tilt`).
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub enum EntryTilt {
    /// [`ENTRY_TILT_FRACTION`] of the friction cone's half-angle `atan μ_s`.
    #[default]
    Auto,
    /// This angle [rad] (π/2 or more: the heading is never turned).
    Angle(f64),
}

/// The fraction of the friction cone's half-angle that [`EntryTilt::Auto`] allows: a margin
/// for the needle's bending, which tilts the tip's force from its heading.
pub const ENTRY_TILT_FRACTION: f64 = 0.9;

impl EntryTilt {
    /// The angle [rad] on a surface of friction coefficient `mu`.
    pub fn angle(self, mu: f64) -> f64 {
        match self {
            Self::Auto => ENTRY_TILT_FRACTION * mu.max(0.0).atan(),
            Self::Angle(a) => a,
        }
    }
}

//! The core's answer to one frame (core → host) and the report of the step.

use super::{Payload, VERSION};
use core::mem::MaybeUninit;

/// Status flags of a [`SolverReport`] (bit set in `flags`).
#[derive(Clone, Copy, Debug)]
pub struct StatusFlags;

impl StatusFlags {
    /// The step was scaled down to respect a joint speed limit.
    pub const SATURATED_SPEED: u32 = 1 << 0;
    /// A joint was clamped at a position limit.
    pub const SATURATED_LIMIT: u32 = 1 << 1;
    /// The linearised model predicts no useful decrease of the objective (target out of reach
    /// from here: singular, limited or saturated).
    pub const TARGET_UNREACHABLE: u32 = 1 << 2;
    /// At least one constraint solve hit its iteration cap.
    pub const NOT_CONVERGED: u32 = 1 << 3;
    /// The objective was within tolerance: no Jacobian, no motion.
    pub const WITHIN_TOLERANCE: u32 = 1 << 4;
    /// The damping of the pseudo-inverse was raised near a singularity.
    pub const NEAR_SINGULAR: u32 = 1 << 5;
    /// The step was scaled down to the trust region on the needle-base motion
    /// (`InverseParams::max_base_step`).
    pub const STEP_LIMITED: u32 = 1 << 6;
    /// An obstacle clearance row bounded the step ([`crate::inverse::StepMethod::Qp`]).
    pub const CLEARANCE_ACTIVE: u32 = 1 << 7;
    /// The quadratic program of the step had no solution, even with the clearance rows relaxed
    /// to "no closer": the joints were held.
    pub const QP_FAILED: u32 = 1 << 8;
    /// The constraint solve at the planned joints found the tip farther from the target than the
    /// linear model promised, or an obstacle closer than the margin: the step was shortened
    /// (halved, up to [`crate::inverse::MAX_BACKTRACKS`] times) or, failing that, the joints held.
    pub const BACKTRACKED: u32 = 1 << 9;
}

/// Report of one inverse step, carried in [`Command::report`].
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C)]
pub struct SolverReport<const N: usize = 6> {
    /// Gauss-Seidel sweeps summed over every solve of the step.
    pub iterations: u32,
    /// Number of constraint solves in the step (1 within tolerance; 8 with a Jacobian, more when
    /// the final solve rejects the plan and shorter steps are confirmed).
    pub solves: u32,
    /// Bit set of [`StatusFlags`].
    pub flags: u32,
    /// Sweeps of the final solve.
    pub final_iterations: u32,
    /// Residual of the final solve (largest `|W_ii Δλ_i|` of the last sweep over `‖δ‖∞`) [-].
    pub final_residual: f64,
    /// Objective `T(q)` at the frame's joints: e [mm] and weighted angle [mm].
    pub objective: [f64; 4],
    /// Objective at the commanded joints, from the final solve [mm].
    pub objective_after: [f64; 4],
    /// Applied joint step `Δq` [rad].
    pub delta_q: [f64; N],
}

impl<const N: usize> Default for SolverReport<N> {
    fn default() -> Self {
        Self {
            iterations: 0,
            solves: 0,
            flags: 0,
            final_iterations: 0,
            final_residual: 0.0,
            objective: [0.0; 4],
            objective_after: [0.0; 4],
            delta_q: [0.0; N],
        }
    }
}

/// The core's answer to one frame (core → host); `N` joints (default 6, the v2 layout of
/// `needle.Command.v2`).
#[derive(Clone, Copy, Debug)]
#[repr(C)]
pub struct Command<const M: usize, const N: usize = 6> {
    /// Layout version, [`VERSION`].
    pub version: u32,
    /// Number of rows of `lambda` used (the frame's `m`).
    pub m: u32,
    /// Sequence number of the frame this answers.
    pub frame_sequence: u64,
    /// Commanded joints [rad].
    pub q: [f64; N],
    /// Constraint forces at the commanded joints [N or N·mm], first `m` used; apply as
    /// `x = x_free + K⁻¹ Hᵀ λ`.
    pub lambda: [f64; M],
    /// How the step went.
    pub report: SolverReport<N>,
}

crate::zeroed::impl_zeroable!(SolverReport<const N> {
    iterations,
    solves,
    flags,
    final_iterations,
    final_residual,
    objective,
    objective_after,
    delta_q,
});
crate::zeroed::impl_zeroable!(Command<const M, const N> {
    version,
    m,
    frame_sequence,
    q,
    lambda,
    report,
});

impl<const M: usize, const N: usize> Payload for Command<M, N> {
    fn stamp(&mut self) {
        self.version = VERSION;
    }
}

impl<const M: usize, const N: usize> Command<M, N> {
    /// Initialises a command in place: all zero, `version = VERSION`.
    pub fn init_in_place(this: &mut MaybeUninit<Self>) -> &mut Self {
        super::init_in_place(this)
    }

    /// A command on the heap in the state of [`Self::init_in_place`], built there.
    ///
    /// # Example
    /// ```
    /// use needle_core::{Command, VERSION};
    ///
    /// let cmd = Command::<192>::new_boxed();
    /// assert_eq!(cmd.version, VERSION);
    /// assert_eq!(cmd.validate(), Ok(()));
    /// ```
    #[cfg(feature = "alloc")]
    pub fn new_boxed() -> alloc::boxed::Box<Self> {
        super::new_boxed()
    }

    /// Resets an existing command to the state of [`Self::init_in_place`].
    pub fn reset(&mut self) {
        super::reset(self);
    }
}

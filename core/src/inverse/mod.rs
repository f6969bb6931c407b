//! Inverse update (paper §IV): one damped Newton step of the joints `q` on the objective
//!
//! ```text
//! T(q) = ( e_x, e_y, e_z, w_θ · (k θ1 + (1 − k) θ2) ),   e = target − tip
//! ```
//!
//! evaluated through a constraint solve. Only the 6 base rows of `δ` depend on `q`
//! (`δ_base(q)`, docs/architecture.md); `W`, the other rows and the observation rows
//! `o = o_free + C λ` stay fixed within a step, so `T` at any `q` costs one Gauss-Seidel solve and
//! no mesh.
//!
//! One step ([`Controller::step`]):
//! 1. validate the frame and factor the diagonal blocks of `W` once ([`BlockGs::prepare_frame`]);
//! 2. solve at the frame's `q` (warm start: the previous step's `λ`) → `λ_q`, `T(q)`;
//! 3. if `‖T‖² ≤ tolerance`: stop, command `q` and `λ_q` (1 solve);
//! 4. Jacobian by forward differences, column `i` from a solve at `q + δq·e_i` warm-started from
//!    `λ_q` — more precisely from the linear prediction `λ_q + Z (δ_b(q + δq e_i) − δ_b(q))`, exact
//!    while no row changes status, where `Z` is the response of the rows left free by the base
//!    solve (one dense factorisation per frame, [`ActiveSet`]); Gauss-Seidel then confirms or
//!    repairs it to `jacobian_tolerance`: `J_i = (T(q + δq e_i) − T(q)) / δq`. (The paper's
//!    eq. 14 writes the negative, `(T(q) − T(q + δq_i)) / δq`, with `Δq = J⁻¹ T`; both give the
//!    same Newton step.)
//!    The angular row is differenced through the rotation vectors whose norms are θ1 and θ2
//!    (`dθ = φ̂ · dφ`, see [`Objective`]): differencing the angle itself is wrong once θ is
//!    smaller than the change δq causes (a norm's one-sided difference near its minimum gives
//!    `|dφ|`, not `φ̂ · dφ`), which stalls the Newton iteration at θ ≈ δq·|∂φ/∂q|.
//! 5. damped least squares `Δq = −Jᵀ (J Jᵀ + ε² I)⁻¹ T`, so that `T + J Δq ≈ 0`; `ε` grows when
//!    the smallest singular value σ of `J` falls below a threshold σ₀ (the RV-1A wrist is near
//!    singular in the benchmark pose): `ε² = ε_min² + (1 − (σ/σ₀)²) ε_max²` for `σ < σ₀`;
//! 6. scale `Δq` uniformly so that `|Δq_i| ≤ v_max,i · dt` (keeps the Newton direction), then clamp
//!    `q + Δq` into the joint limits; both are reported as saturation flags;
//! 7. final solve at `q + Δq` (started from the same prediction or, without the active-set
//!    factor, from `λ_q + Σ Δq_i ∂λ/∂q_i`, the sensitivities step 4's columns give; the next
//!    step's columns start from them too: `sensitivity.rs`) → the `λ` the host applies.
//!
//! Steps 5 and 6 are the paper's update (`InverseParams::method = StepMethod::Paper`). The default,
//! [`StepMethod::Qp`], replaces them by one small quadratic program (`qp_step.rs`): the tip error
//! and the two angles' rotation vectors as least squares with the same damping, the joint limits
//! and speeds as bounds, the trust region and the frame's obstacle clearances as linear rows.
//!
//! That is 1 + 6 + 1 = 8 solves. The base solve is done at this frame's `q` rather than reusing
//! the previous step's state as in the paper's Algorithm 1 (line 5): the previous state was
//! computed before this step's free motion, so differencing against it would mix this step's
//! free motion into `J` and into `T`. Solving at `q` with the current `W` and `δ_free` makes both
//! ends of every difference see the same free motion.
//!
//! The stages are methods of [`Controller`] named after them (`step.rs`); the solves share one
//! path (`solves.rs`); the objective and the tuning have their own files.

mod error;
mod objective;
mod params;
mod qp_step;
mod sensitivity;
mod solves;
mod step;
#[cfg(test)]
mod tests;

pub use error::StepError;
pub use objective::{Objective, blend_factor, evaluate_objective};
pub use params::{InverseParams, JacobianMode, StepMethod};
pub use qp_step::QP_MAX_JOINTS;
pub use solves::base_violation;
pub use step::{MAX_BACKTRACKS, MAX_HELD_HALVINGS, MAX_REPLANS, SUFFICIENT_DECREASE};

use crate::constraint::{ActiveSet, BlockGs, GsBatch};
use crate::kinematics::Robot;
use crate::reduce::BaseElimination;
use sensitivity::Sensitivity;
use solves::Target;

/// The inverse controller: owns the robot, the tuning and every scratch buffer of a step (block
/// factors, the active-set factor, λ buffers), so that [`Self::step`] allocates nothing. `M` is
/// the row capacity.
///
/// About `16 M²` bytes (≈ 660 KiB at `M = 192`) because of the dense active-set factor and the
/// reduced `W`: build it in place, with [`Self::init_in_place`] in a `static` or with `new_boxed`
/// (feature `alloc`) on the heap, not on a small stack.
#[derive(Clone, Debug)]
pub struct Controller<const M: usize, const N: usize = 6> {
    /// The robot (kinematics, limits, base and tool transforms).
    pub robot: Robot<N>,
    /// Tuning.
    pub params: InverseParams,
    /// Block factors of the problem the step iterates on (the reduced one with `eliminate_base`).
    gs: BlockGs<M>,
    /// Block factors of the full frame, for the active set when `gs` holds the reduced problem.
    gs_full: BlockGs<M>,
    /// The base rows eliminated from `W` (`W'`, `δ'`), with `eliminate_base`.
    red: BaseElimination<M>,
    /// Factor of the active set of the base solve and its response `Z` to the base rows.
    set: ActiveSet<M>,
    /// Whether `set` belongs to this step's base solution.
    set_valid: bool,
    /// `δ` of the full problem: `δ_free` with the base rows of the last solve.
    delta: [f64; M],
    /// `δ_base(q)` of the base solve.
    delta_base: [f64; 6],
    /// The λ buffers of the step.
    lambda: Lambdas<M>,
    /// Iterate of a reduced solve (rows `6..m` of the full λ, shifted to `0..n`).
    lr: [f64; M],
    /// The reduced solves of the Jacobian's columns, run together.
    columns: GsBatch<M, N>,
    /// `W' λ_q` (reduced rows), the start of every reduced solve that starts from `λ_q`.
    start_product: [f64; M],
    /// Whether `start_product` belongs to this step's `W'` and `λ_q`.
    start_product_ok: bool,
    /// `∂λ/∂q_i` of the last Jacobian: where the final solves and the next step's columns
    /// start.
    sens: Sensitivity<M, N>,
    /// The last step, when it held the joints ([`InverseParams::resume_held`]).
    held: Held<N>,
    /// What the model missed of the clearances of late ([`InverseParams::settling_margin`]).
    settling: Settling,
}

/// Per step, the fraction of the settling allowance kept for the next
/// ([`InverseParams::settling_margin`]): a shortfall is forgotten by a tenth per step (to a
/// third in about ten steps, 0.4 s at the benchmark's period).
pub const SETTLING_DECAY: f64 = 0.9;

/// The smallest obstacle clearance the last step's final solve predicted, and the allowance
/// added to the margin: the largest recent shortfall of a frame's clearance against the
/// prediction for it, decayed by [`SETTLING_DECAY`] per step.
#[derive(Clone, Copy, Debug)]
struct Settling {
    /// The last step's predicted smallest clearance [mm]; meaningful when `known`.
    predicted: f64,
    /// Whether `predicted` belongs to the last step (false: no prediction, e.g. no obstacle
    /// row or a step within tolerance).
    known: bool,
    /// Added to `clearance_margin` [mm], ≥ 0.
    allowance: f64,
}

impl Settling {
    const NONE: Self = Self {
        predicted: 0.0,
        known: false,
        allowance: 0.0,
    };

    /// Takes the frame's smallest clearance `now` (`None`: no obstacle row) into the
    /// allowance.
    fn observe(&mut self, now: Option<f64>) {
        let shortfall = match (self.known, now) {
            (true, Some(c)) if c.is_finite() && self.predicted.is_finite() => {
                (self.predicted - c).max(0.0)
            }
            _ => 0.0,
        };
        self.allowance = (self.allowance * SETTLING_DECAY).max(shortfall);
        self.known = false;
    }
}

crate::zeroed::impl_zeroable!(Settling {
    predicted,
    known,
    allowance
});

/// A step that held the joints because its confirming solves rejected every candidate: where,
/// and how far its halvings of the first stage's step went, so that the next step on the same
/// joints goes on from there instead of repeating them.
#[derive(Clone, Copy, Debug)]
struct Held<const N: usize> {
    /// The joints held (the frame's `q` of that step).
    q: [f64; N],
    /// Halvings of `Δq₁` of the smallest candidate it tried; 0: the last step did not hold.
    halvings: u32,
}

impl<const N: usize> Held<N> {
    const NONE: Self = Self {
        q: [0.0; N],
        halvings: 0,
    };
}

crate::zeroed::impl_zeroable!(Held<const N> { q, halvings });

/// The λ buffers of a step [N or N·mm].
#[derive(Clone, Debug)]
struct Lambdas<const M: usize> {
    /// `λ_q`, the solution at the frame's joints.
    base: [f64; M],
    /// The solution at other joints (perturbed, final).
    work: [f64; M],
    /// The answer of the previous step (warm start), its first `prev_rows` rows.
    prev: [f64; M],
    /// Rows of `prev` (0: no warm start).
    prev_rows: usize,
}

impl<const M: usize> Lambdas<M> {
    const fn new() -> Self {
        Self {
            base: [0.0; M],
            work: [0.0; M],
            prev: [0.0; M],
            prev_rows: 0,
        }
    }

    /// The buffer a solve into `target` writes.
    fn of(&mut self, target: Target) -> &mut [f64; M] {
        match target {
            Target::Base => &mut self.base,
            Target::Work => &mut self.work,
        }
    }
}

crate::zeroed::impl_zeroable!(Lambdas<const M> {
    base,
    work,
    prev,
    prev_rows
});
crate::zeroed::impl_zeroable!(Controller<const M, const N> {
    robot,
    params,
    gs,
    gs_full,
    red,
    set,
    set_valid,
    delta,
    delta_base,
    lambda,
    lr,
    columns,
    start_product,
    start_product_ok,
    sens,
    held,
    settling,
});

impl<const M: usize, const N: usize> Controller<M, N> {
    const CAPACITY_OK: () = assert!(
        M >= crate::payload::BASE_ROWS,
        "M must hold the 6 base rows"
    );

    /// A controller for `robot` (a [`crate::DhChain`], a [`crate::SerialChain`]) with tuning `params`, built by value (≈ `16 M²` bytes on the
    /// stack: prefer [`Self::init_in_place`] or `new_boxed` for large `M`).
    pub fn new(robot: impl Into<Robot<N>>, params: InverseParams) -> Self {
        let () = Self::CAPACITY_OK;
        Self {
            robot: robot.into(),
            params,
            gs: BlockGs::new(),
            gs_full: BlockGs::new(),
            red: BaseElimination::new(),
            set: ActiveSet::new(),
            set_valid: false,
            delta: [0.0; M],
            delta_base: [0.0; 6],
            lambda: Lambdas::new(),
            lr: [0.0; M],
            columns: GsBatch::new(),
            start_product: [0.0; M],
            start_product_ok: false,
            sens: Sensitivity::new(),
            held: Held::NONE,
            settling: Settling::NONE,
        }
    }

    /// Initialises a controller in place (no stack temporary) and returns it: all scratch
    /// zero, no warm start, `robot` and `params` set.
    ///
    /// # Example
    /// ```
    /// use core::mem::MaybeUninit;
    /// use needle_core::{Controller, DhChain, InverseParams};
    ///
    /// // On a controller without heap: a static (≈ 280 KiB at M = 120).
    /// static mut CONTROLLER: MaybeUninit<Controller<120>> = MaybeUninit::uninit();
    /// // SAFETY (of this example): the only borrow of the static.
    /// let slot = unsafe { &mut *(&raw mut CONTROLLER) };
    /// let ctrl = Controller::init_in_place(slot, DhChain::rv1a(), InverseParams::default());
    /// assert_eq!(ctrl.params, InverseParams::default());
    /// ```
    pub fn init_in_place(
        this: &mut core::mem::MaybeUninit<Self>,
        robot: impl Into<Robot<N>>,
        params: InverseParams,
    ) -> &mut Self {
        crate::zeroed::zeroed_in_place(this).configure(robot.into(), params)
    }

    /// A controller on the heap in the state of [`Self::init_in_place`], built there (never on
    /// the stack).
    ///
    /// # Example
    /// ```
    /// use needle_core::{Controller, DhChain, InverseParams};
    ///
    /// let ctrl = Controller::<192>::new_boxed(DhChain::rv1a(), InverseParams::default());
    /// assert_eq!(ctrl.robot, needle_core::Robot::Dh(DhChain::rv1a()));
    /// ```
    #[cfg(feature = "alloc")]
    pub fn new_boxed(robot: impl Into<Robot<N>>, params: InverseParams) -> alloc::boxed::Box<Self> {
        let mut b = crate::zeroed::boxed_zeroed::<Self>();
        b.configure(robot.into(), params);
        b
    }

    /// Sets the robot and the tuning of a zeroed controller.
    fn configure(&mut self, robot: Robot<N>, params: InverseParams) -> &mut Self {
        let () = Self::CAPACITY_OK;
        self.robot = robot;
        self.params = params;
        self
    }

    /// Forgets the previous step's `λ` (next step starts the solver from zero) and whether it
    /// held the joints.
    pub fn reset_warm_start(&mut self) {
        self.lambda.prev_rows = 0;
        self.sens.clear();
        self.held = Held::NONE;
        self.settling = Settling::NONE;
    }
}

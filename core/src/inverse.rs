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
//! 7. final solve at `q + Δq` (started from the same prediction) → the `λ` the host applies.
//!
//! That is 1 + 6 + 1 = 8 solves. The base solve is done at this frame's `q` rather than reusing
//! the previous step's state as in the paper's Algorithm 1 (line 5): the previous state was
//! computed before this step's free motion, so differencing against it would mix this step's
//! free motion into `J` and into `T`. Solving at `q` with the current `W` and `δ_free` makes both
//! ends of every difference see the same free motion.

use crate::constraint::{ActiveSet, BlockGs, GsParams, SolveReport};
use crate::kinematics::{DhChain, Pose};
use crate::math::{angle_between, rotation_log};
use crate::payload::{
    Command, ComplianceFrame, JOINTS, ObsIndex, SolverReport, StatusFlags, VERSION, ValidationError,
};
use crate::reduce::BaseElimination;
use core::fmt;
use nalgebra::{Matrix3, Matrix4, SMatrix, SVector, Vector3, Vector4};

/// Sweeps after which a reduced solve that has not converged is polished on its active set.
const POLISH_AFTER: u32 = 60;

/// How the Jacobian columns are obtained.
///
/// `#[repr(u8)]` with `Solve = 0`, so that a zeroed [`InverseParams`] (inside a controller built
/// in place) holds a valid mode.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum JacobianMode {
    /// The paper's eq. 14: a full constraint solve at each `q + δq e_i` (Gauss-Seidel, W fixed).
    /// Exact finite differences of the constrained simulation — including the contacts that
    /// open or close within the perturbation, which with `δq = 0.01 rad` (several mm at the
    /// needle base) makes `J` jump at the moment the tip touches the surface.
    Solve = 0,
    /// The same solve with the active set of the base solve frozen (rows at a bound stay there,
    /// free rows stay free, sliding friction stays saturated): a direct solve of the linearised
    /// problem, i.e. the exact one-sided derivative of `T` at `q` evaluated at the same `δq`.
    /// No contact flips inside a column, and 6 back-substitutions replace 6 Gauss-Seidel solves.
    /// Falls back to `Solve` when the active-set matrix is singular.
    Linearized,
    /// `Linearized` until the tip has punctured the surface (the contact opening and closing
    /// inside a finite difference is what makes `Solve` chatter there), `Solve` once inserted
    /// (where the frozen set mispredicts the shaft friction switching between stick and slip).
    Hybrid,
}

/// Tuning of the inverse update, `Default` gives the documented values.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InverseParams {
    /// Finite-difference joint perturbation δq [rad] (default 0.01).
    pub joint_step: f64,
    /// Depth d over which the angular objective blends from θ1 to θ2 [mm] (default 20).
    pub blend_depth: f64,
    /// Weight w_θ of the angular objective [mm/rad] (default 100: 1° counts like 1.75 mm).
    pub angle_weight: f64,
    /// Damping ε of the pseudo-inverse away from singularities [mm/rad] (default 1).
    pub damping: f64,
    /// Extra damping added at a singularity [mm/rad] (default 20).
    pub damping_max: f64,
    /// Smallest singular value of J below which the damping rises towards `damping_max`
    /// [mm/rad] (default 5).
    pub singular_threshold: f64,
    /// Skip the Jacobian when `‖T‖² ≤ tolerance` [mm²] (default 1e-6).
    pub tolerance: f64,
    /// Constraint-solve tuning for every solve of the step (default tolerance 1e-7, 400 sweeps,
    /// over-relaxation 1.2).
    pub gs: GsParams,
    /// Warm-start the first solve of a step from the previous step's `λ` (default true).
    pub warm_start: bool,
    /// Use the active-set factorisation to start every solve of the step at its linear
    /// prediction (default true; see [`ActiveSet`]). Gauss-Seidel still runs every solve to
    /// `gs.tolerance`, so this changes the cost, not the answer.
    pub active_set: bool,
    /// Tolerance of the first, loose Gauss-Seidel pass that finds the active set (default 1e-5).
    pub presolve_tolerance: f64,
    /// Eliminate the 6 base rows exactly before Gauss-Seidel (default true; see
    /// [`crate::reduce`]): removes the free needle's rigid-body compliance that every
    /// needle-side row shares, without which Gauss-Seidel stalls on real host frames. The
    /// active-set prediction is not used in this mode.
    pub eliminate_base: bool,
    /// Largest motion of the needle base per step [mm] (default `+∞`: off; the benchmark scenes
    /// use 3): `Δq` is scaled down so that
    /// the tool point moves at most this far (first order, `|J_tool,v Δq|`). A trust region for
    /// the one-iteration Newton step: where the constrained model is far from linear (a contact
    /// opening, friction saturating) the step stays where the linearisation holds, and the next
    /// step corrects from the new state. 3 mm per step is 75 mm/s at 40 ms per step.
    pub max_base_step: f64,
    /// How the Jacobian columns are computed (default [`JacobianMode::Hybrid`]).
    pub jacobian: JacobianMode,
    /// Gauss-Seidel tolerance of the 6 Jacobian solves (default 1e-5): their error enters `J`
    /// divided by `δq`, and a relative solve error of 1e-5 is far below the forward difference's
    /// own truncation error (of order `δq`). The base and final solves use `gs.tolerance`.
    pub jacobian_tolerance: f64,
}

// SAFETY: `#[repr(u8)]` and the variant `Solve` has the discriminant 0.
unsafe impl crate::zeroed::Zeroable for JacobianMode {}

crate::zeroed::impl_zeroable!(InverseParams {
    joint_step,
    blend_depth,
    angle_weight,
    damping,
    damping_max,
    singular_threshold,
    tolerance,
    gs,
    warm_start,
    active_set,
    presolve_tolerance,
    eliminate_base,
    max_base_step,
    jacobian,
    jacobian_tolerance,
});

impl Default for InverseParams {
    fn default() -> Self {
        Self {
            joint_step: 0.01,
            blend_depth: 20.0,
            angle_weight: 100.0,
            damping: 1.0,
            damping_max: 20.0,
            singular_threshold: 5.0,
            tolerance: 1e-6,
            gs: GsParams {
                tolerance: 1e-7,
                max_iterations: 400,
                polish: false,
                // Projected SOR: ~20 % fewer sweeps than plain GS on the synthetic frames of
                // `synthetic::random_frame` (1.4 is no better, 1.6 is worse).
                relaxation: 1.2,
            },
            warm_start: true,
            active_set: true,
            eliminate_base: true,
            max_base_step: f64::INFINITY,
            jacobian: JacobianMode::Hybrid,
            presolve_tolerance: 1e-5,
            jacobian_tolerance: 1e-5,
        }
    }
}

/// Why an inverse step failed; the command is then left untouched.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub enum StepError {
    /// The frame failed validation.
    InvalidFrame(ValidationError),
    /// A parameter is invalid (non-finite or non-positive where positivity is required).
    InvalidParameter {
        /// Parameter name.
        name: &'static str,
    },
    /// A computed quantity was not finite (should not happen on validated data).
    NonFinite {
        /// Where.
        stage: &'static str,
    },
}

impl fmt::Display for StepError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::InvalidFrame(e) => write!(f, "invalid frame: {e}"),
            Self::InvalidParameter { name } => write!(f, "invalid parameter {name}"),
            Self::NonFinite { stage } => write!(f, "non-finite result in {stage}"),
        }
    }
}

impl core::error::Error for StepError {
    fn source(&self) -> Option<&(dyn core::error::Error + 'static)> {
        match self {
            Self::InvalidFrame(e) => Some(e),
            _ => None,
        }
    }
}

impl From<ValidationError> for StepError {
    fn from(e: ValidationError) -> Self {
        Self::InvalidFrame(e)
    }
}

/// Blend factor `k` of the angular objective.
///
/// This follows the paper's *text* (§IV-A), not its eq. 13: in the air (not inserted) only the
/// tip angle θ1 counts (`k = 1`); once inserted, `k` falls linearly from 1 at the entry point to
/// 0 at depth `d`, beyond which only the base angle θ2 counts (`k = 0`). Eq. 13 as printed
/// (`k = 0` outside the gel, `k = l/d`, then 1) contradicts the text and would steer by θ2 in the
/// air, where θ2 is zero by construction.
pub fn blend_factor(inserted: bool, depth: f64, d: f64) -> f64 {
    if !inserted {
        return 1.0;
    }
    if !(d > 0.0) {
        return 0.0;
    }
    (1.0 - depth / d).clamp(0.0, 1.0)
}

/// Breakdown of an objective evaluation.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct Objective {
    /// `T = (e_x, e_y, e_z, w_θ (k θ1 + (1 − k) θ2))` [mm].
    pub t: [f64; 4],
    /// Tip-direction angle θ1 to the target tangent [rad].
    pub theta1: f64,
    /// Base-direction angle θ2 to the entry point [rad].
    pub theta2: f64,
    /// Blend factor k [-].
    pub k: f64,
    /// Rotation vector taking the target tangent onto the tip direction, `|φ1| = θ1` [rad].
    pub phi1: [f64; 3],
    /// Rotation vector taking the entry direction onto the base direction, `|φ2| = θ2` [rad].
    pub phi2: [f64; 3],
}

impl Objective {
    /// Derivative of the angular component `w_θ (k θ1 + (1 − k) θ2)` along a change of the
    /// rotation vectors, `perturbed` holding the values after a step `h`: the angles are norms
    /// of smooth rotation vectors, so the vectors are differenced and the norm is differentiated
    /// analytically, `dθ = φ̂ · dφ` (0 at θ = 0, where θ is minimal).
    fn angle_derivative(&self, perturbed: &Objective, h: f64, weight: f64) -> f64 {
        let dir = |phi: &[f64; 3], theta: f64| {
            if theta > 0.0 {
                Vector3::from(*phi) / theta
            } else {
                Vector3::zeros()
            }
        };
        let d1 = (Vector3::from(perturbed.phi1) - Vector3::from(self.phi1)) / h;
        let d2 = (Vector3::from(perturbed.phi2) - Vector3::from(self.phi2)) / h;
        let g1 = dir(&self.phi1, self.theta1).dot(&d1);
        let g2 = dir(&self.phi2, self.theta2).dot(&d2);
        weight * (self.k * g1 + (1.0 - self.k) * g2)
    }
}

/// Rotation vector taking `from` onto `to` (axis `from × to`, angle in `[0, π]`), with its
/// angle; zero when either vector is zero or they are parallel.
fn rotation_between(from: &Vector3<f64>, to: &Vector3<f64>) -> ([f64; 3], f64) {
    let theta = angle_between(from, to);
    let axis = from.cross(to);
    let n = axis.norm();
    if n > 0.0 && theta > 0.0 {
        ((axis * (theta / n)).into(), theta)
    } else {
        ([0.0; 3], theta)
    }
}

/// Rotation matrix from the frame's row-major array.
fn r_free(frame_r: &[[f64; 3]; 3]) -> Matrix3<f64> {
    let r = frame_r;
    Matrix3::new(
        r[0][0], r[0][1], r[0][2], r[1][0], r[1][1], r[1][2], r[2][0], r[2][1], r[2][2],
    )
}

/// The base-row violation `δ_base(q)` for the needle-base pose `b`: translation `p_B − p_free`
/// [mm], rotation `log(R_B R_freeᵀ)` [rad], world frame.
pub fn base_violation(b: &Pose, p_free: &[f64; 3], r_free_rows: &[[f64; 3]; 3]) -> [f64; 6] {
    let dp = b.translation - Vector3::from(*p_free);
    let dr = rotation_log(&(b.rotation * r_free(r_free_rows).transpose()));
    [dp[0], dp[1], dp[2], dr[0], dr[1], dr[2]]
}

/// The objective for constraint forces `lambda` and needle-base pose `b` (from forward
/// kinematics), see the module docs.
pub fn evaluate_objective<const M: usize>(
    frame: &ComplianceFrame<M>,
    lambda: &[f64; M],
    b: &Pose,
    params: &InverseParams,
) -> Objective {
    let v = |idx| Vector3::from(frame.observe(idx, lambda));
    let tip = v(ObsIndex::TIP_POSITION);
    let tip_dir = v(ObsIndex::TIP_DIRECTION);
    let target = v(ObsIndex::TARGET_POINT);
    let tangent = v(ObsIndex::TARGET_TANGENT);
    let entry = v(ObsIndex::ENTRY_POINT);
    let e = target - tip;
    let (phi1, theta1) = rotation_between(&tangent, &tip_dir);
    let (phi2, theta2) = rotation_between(&(entry - b.translation), &b.z_axis());
    let k = blend_factor(
        frame.inserted != 0,
        frame.insertion_depth,
        params.blend_depth,
    );
    let ang = params.angle_weight * (k * theta1 + (1.0 - k) * theta2);
    Objective {
        t: [e[0], e[1], e[2], ang],
        theta1,
        theta2,
        k,
        phi1,
        phi2,
    }
}

/// The inverse controller: owns the robot, the tuning and every scratch buffer of a step (block
/// factors, the active-set factor, λ buffers), so that [`Self::step`] allocates nothing. `M` is
/// the row capacity.
///
/// About `16 M²` bytes (≈ 660 KiB at `M = 192`) because of the dense active-set factor and the
/// reduced `W`: build it in place, with [`Self::init_in_place`] in a `static` or with `new_boxed`
/// (feature `alloc`) on the heap, not on a small stack.
#[derive(Clone, Debug)]
pub struct Controller<const M: usize> {
    /// The robot (DH chain, limits, base and tool transforms).
    pub chain: DhChain<JOINTS>,
    /// Tuning.
    pub params: InverseParams,
    gs: BlockGs<M>,
    delta: [f64; M],
    lambda_base: [f64; M],
    lambda_work: [f64; M],
    lambda_prev: [f64; M],
    prev_m: usize,
    set: ActiveSet<M>,
    set_valid: bool,
    delta_base: [f64; 6],
    red: BaseElimination<M>,
    lr_base: [f64; M],
    lr_work: [f64; M],
    gs_full: BlockGs<M>,
}

crate::zeroed::impl_zeroable!(Controller<const M> {
    chain,
    params,
    gs,
    delta,
    lambda_base,
    lambda_work,
    lambda_prev,
    prev_m,
    set,
    set_valid,
    delta_base,
    red,
    lr_base,
    lr_work,
    gs_full,
});

impl<const M: usize> Controller<M> {
    const CAPACITY_OK: () = assert!(
        M >= crate::payload::BASE_ROWS,
        "M must hold the 6 base rows"
    );

    /// A controller for `chain` with tuning `params`.
    pub fn new(chain: DhChain<JOINTS>, params: InverseParams) -> Self {
        let () = Self::CAPACITY_OK;
        Self {
            chain,
            params,
            gs: BlockGs::new(),
            delta: [0.0; M],
            lambda_base: [0.0; M],
            lambda_work: [0.0; M],
            lambda_prev: [0.0; M],
            prev_m: 0,
            set: ActiveSet::new(),
            set_valid: false,
            delta_base: [0.0; 6],
            red: BaseElimination::new(),
            lr_base: [0.0; M],
            lr_work: [0.0; M],
            gs_full: BlockGs::new(),
        }
    }

    /// Initialises a controller in place (no stack temporary) and returns it: all scratch
    /// zero, no warm start, `chain` and `params` set.
    pub fn init_in_place(
        this: &mut core::mem::MaybeUninit<Self>,
        chain: DhChain<JOINTS>,
        params: InverseParams,
    ) -> &mut Self {
        crate::zeroed::zeroed_in_place(this).configure(chain, params)
    }

    /// A controller on the heap in the state of [`Self::init_in_place`], built there (never on
    /// the stack).
    ///
    /// # Example
    /// ```
    /// use needle_core::{Controller, DhChain, InverseParams};
    ///
    /// let ctrl = Controller::<192>::new_boxed(DhChain::rv1a(), InverseParams::default());
    /// assert_eq!(ctrl.chain, DhChain::rv1a());
    /// ```
    #[cfg(feature = "alloc")]
    pub fn new_boxed(chain: DhChain<JOINTS>, params: InverseParams) -> alloc::boxed::Box<Self> {
        let mut b = crate::zeroed::boxed_zeroed::<Self>();
        b.configure(chain, params);
        b
    }

    /// Sets the robot and the tuning of a zeroed controller.
    fn configure(&mut self, chain: DhChain<JOINTS>, params: InverseParams) -> &mut Self {
        let () = Self::CAPACITY_OK;
        self.chain = chain;
        self.params = params;
        self
    }

    /// Forgets the previous step's `λ` (next step starts the solver from zero).
    pub fn reset_warm_start(&mut self) {
        self.prev_m = 0;
    }

    fn check_params(&self) -> Result<(), StepError> {
        let p = &self.params;
        let pos = |x: f64| x.is_finite() && x > 0.0;
        let nonneg = |x: f64| x.is_finite() && x >= 0.0;
        let checks = [
            (pos(p.joint_step), "joint_step"),
            (nonneg(p.blend_depth), "blend_depth"),
            (nonneg(p.angle_weight), "angle_weight"),
            (nonneg(p.damping), "damping"),
            (nonneg(p.damping_max), "damping_max"),
            (nonneg(p.singular_threshold), "singular_threshold"),
            (nonneg(p.tolerance), "tolerance"),
            (nonneg(p.presolve_tolerance), "presolve_tolerance"),
            (nonneg(p.jacobian_tolerance), "jacobian_tolerance"),
            (p.max_base_step > 0.0, "max_base_step"),
        ];
        for (ok, name) in checks {
            if !ok {
                return Err(StepError::InvalidParameter { name });
            }
        }
        Ok(())
    }

    /// Writes `δ_base(q)` into rows 0..6 and solves into `lambda_work` (warm start: its current
    /// content); returns the tool pose and the report.
    fn solve_at(&mut self, frame: &ComplianceFrame<M>, q: &[f64; JOINTS]) -> (Pose, SolveReport) {
        let b = self.chain.tool_pose(q);
        let d = base_violation(&b, &frame.p_free, &frame.r_free);
        self.delta[..6].copy_from_slice(&d);
        let rep = self.gs.solve(
            &frame.w,
            &self.delta,
            &mut self.lambda_work,
            &self.params.gs,
        );
        (b, rep)
    }

    /// The solve at the frame's joints into `lambda_base` (warm start: its content). With
    /// `active_set`, a loose Gauss-Seidel pass finds which rows are free, the free rows are solved
    /// exactly by a dense factorisation (also giving their response `Z` to the base rows), and
    /// Gauss-Seidel confirms the result to the full tolerance (repairing any status change).
    fn solve_base(&mut self, frame: &ComplianceFrame<M>, q: &[f64; JOINTS]) -> (Pose, SolveReport) {
        if self.params.eliminate_base {
            let n = self.red.rows();
            self.lr_base[..n].copy_from_slice(&self.lambda_base[6..6 + n]);
            return self.solve_reduced(frame, q, true, self.params.gs.tolerance);
        }
        let b = self.chain.tool_pose(q);
        let d = base_violation(&b, &frame.p_free, &frame.r_free);
        self.delta[..6].copy_from_slice(&d);
        self.delta_base = d;
        self.set_valid = false;
        let gs = self.params.gs;
        if !self.params.active_set {
            let rep = self
                .gs
                .solve(&frame.w, &self.delta, &mut self.lambda_base, &gs);
            return (b, rep);
        }
        let loose = GsParams {
            tolerance: gs.tolerance.max(self.params.presolve_tolerance),
            ..gs
        };
        let r1 = self
            .gs
            .solve(&frame.w, &self.delta, &mut self.lambda_base, &loose);
        if self
            .gs
            .factor_active_set(&frame.w, &self.lambda_base, &mut self.set)
        {
            let mut trial = self.lambda_base;
            if self
                .gs
                .refine_on_active_set(&frame.w, &self.delta, &mut trial, &mut self.set)
            {
                self.lambda_base = trial;
            }
        }
        let left = GsParams {
            max_iterations: gs.max_iterations.saturating_sub(r1.iterations),
            ..gs
        };
        let r2 = self
            .gs
            .solve(&frame.w, &self.delta, &mut self.lambda_base, &left);
        // A status changed during the confirmation: factor again at the final answer.
        if r2.iterations > 2 {
            self.gs
                .factor_active_set(&frame.w, &self.lambda_base, &mut self.set);
        }
        self.set_valid = self.set.is_valid();
        let rep = SolveReport {
            iterations: r1.iterations + r2.iterations,
            ..r2
        };
        (b, rep)
    }

    /// A solve at perturbed joints into `lambda_work`, started from the linear prediction
    /// `λ_q + Z (δ_b(q') − δ_b(q))` when the active-set factor is valid, else from `λ_q`.
    fn solve_perturbed(
        &mut self,
        frame: &ComplianceFrame<M>,
        q: &[f64; JOINTS],
        tolerance: f64,
    ) -> (Pose, SolveReport) {
        if self.params.eliminate_base {
            let n = self.red.rows();
            self.lr_work[..n].copy_from_slice(&self.lr_base[..n]);
            return self.solve_reduced(frame, q, false, tolerance);
        }
        let b = self.chain.tool_pose(q);
        let d = base_violation(&b, &frame.p_free, &frame.r_free);
        self.delta[..6].copy_from_slice(&d);
        let m = frame.rows();
        if self.set_valid {
            let mut dd = [0.0; 6];
            for i in 0..6 {
                dd[i] = d[i] - self.delta_base[i];
            }
            self.gs
                .predict_base_change(&self.set, &self.lambda_base, &dd, &mut self.lambda_work);
        } else {
            self.lambda_work[..m].copy_from_slice(&self.lambda_base[..m]);
        }
        let gs = GsParams {
            tolerance,
            ..self.params.gs
        };
        let rep = self
            .gs
            .solve(&frame.w, &self.delta, &mut self.lambda_work, &gs);
        (b, rep)
    }

    /// Builds the base elimination of a validated frame and prepares the reduced blocks.
    fn prepare_reduced(&mut self, frame: &ComplianceFrame<M>) -> Result<(), StepError> {
        if !self.red.prepare(frame) {
            return Err(StepError::NonFinite {
                stage: "base block of W (not positive definite)",
            });
        }
        let n = self.red.rows();
        if n > 0 {
            // The frame's own W passed validation, so a failure here is the Schur complement
            // of the base block: W is not positive definite (e.g. a corrupted diagonal).
            self.gs
                .prepare(&self.red.w, n, self.red.groups())
                .map_err(|_| StepError::NonFinite {
                    stage: "W without the base rows (not positive definite)",
                })?;
        }
        Ok(())
    }

    /// A solve on the reduced problem at joints `q` (warm start: `lr_base` or `lr_work`), its
    /// full λ written to `lambda_base` or `lambda_work`.
    fn solve_reduced(
        &mut self,
        frame: &ComplianceFrame<M>,
        q: &[f64; JOINTS],
        into_base: bool,
        tolerance: f64,
    ) -> (Pose, SolveReport) {
        let b = self.chain.tool_pose(q);
        let d = base_violation(&b, &frame.p_free, &frame.r_free);
        self.delta_base = d;
        self.set_valid = false;
        self.red.reduce_delta(frame, &d);
        let n = self.red.rows();
        let gs = GsParams {
            tolerance,
            ..self.params.gs
        };
        let lr = if into_base {
            &mut self.lr_base
        } else {
            &mut self.lr_work
        };
        let first = GsParams {
            max_iterations: gs.max_iterations.min(POLISH_AFTER),
            ..gs
        };
        let mut rep = if n > 0 {
            self.gs.solve(&self.red.w, &self.red.delta, lr, &first)
        } else {
            SolveReport {
                converged: true,
                ..SolveReport::default()
            }
        };
        let (lr, full) = if into_base {
            (&mut self.lr_base, &mut self.lambda_base)
        } else {
            (&mut self.lr_work, &mut self.lambda_work)
        };
        if !rep.converged {
            // Slow convergence (sliding points coupled through the stiff needle: rows close to
            // parallel): one Newton step on the active set of the current iterate — stick rows
            // bilateral, slipping axial rows tied to their bound — on the full problem, then
            // Gauss-Seidel confirms (and repairs any status the step got wrong).
            self.red.expand(frame, &d, lr, full);
            if self.params.active_set && self.gs_full.prepare_frame(frame).is_ok() {
                self.delta[..6].copy_from_slice(&d);
                let mut trial = *full;
                if self
                    .gs_full
                    .factor_active_set(&frame.w, full, &mut self.set)
                    && self.gs_full.refine_on_active_set(
                        &frame.w,
                        &self.delta,
                        &mut trial,
                        &mut self.set,
                    )
                {
                    lr[..n].copy_from_slice(&trial[6..6 + n]);
                }
                self.set_valid = false;
            }
            let left = GsParams {
                max_iterations: gs.max_iterations.saturating_sub(rep.iterations),
                ..gs
            };
            let r2 = self.gs.solve(&self.red.w, &self.red.delta, lr, &left);
            rep = SolveReport {
                iterations: rep.iterations + r2.iterations,
                ..r2
            };
        }
        self.red.expand(frame, &d, lr, full);
        (b, rep)
    }

    /// Factors the active set of the base solve (`lambda_base`) on the full frame for the
    /// linearised Jacobian; `false` if it is singular or the frame cannot be prepared.
    fn factor_linearized(&mut self, frame: &ComplianceFrame<M>) -> bool {
        if self.gs_full.prepare_frame(frame).is_err() {
            return false;
        }
        let ok = self
            .gs_full
            .factor_active_set(&frame.w, &self.lambda_base, &mut self.set);
        self.set_valid = ok && self.set.is_valid();
        self.set_valid
    }

    /// The frozen-active-set solution at joints `q` into `lambda_work`:
    /// `λ_q + Z (δ_b(q') − δ_b(q))`; returns the tool pose.
    fn predict_at(&mut self, frame: &ComplianceFrame<M>, q: &[f64; JOINTS]) -> Pose {
        let b = self.chain.tool_pose(q);
        let d = base_violation(&b, &frame.p_free, &frame.r_free);
        let mut dd = [0.0; 6];
        for i in 0..6 {
            dd[i] = d[i] - self.delta_base[i];
        }
        self.gs_full
            .predict_base_change(&self.set, &self.lambda_base, &dd, &mut self.lambda_work);
        b
    }

    /// The objective `T(q)` at joints `q` for `frame` (one constraint solve, from zero). For
    /// tests and diagnostics; not part of the real-time path.
    ///
    /// # Errors
    /// [`StepError::InvalidFrame`] when the frame fails validation.
    pub fn objective_at(
        &mut self,
        frame: &ComplianceFrame<M>,
        q: &[f64; JOINTS],
    ) -> Result<Objective, StepError> {
        self.gs.prepare_frame(frame)?;
        let m = frame.rows();
        self.delta[..m].copy_from_slice(&frame.delta_free[..m]);
        self.lambda_work.fill(0.0);
        let (b, _) = if self.params.eliminate_base {
            self.prepare_reduced(frame)?;
            self.lr_work.fill(0.0);
            self.solve_reduced(frame, q, false, self.params.gs.tolerance)
        } else {
            self.solve_at(frame, q)
        };
        Ok(evaluate_objective(
            frame,
            &self.lambda_work,
            &b,
            &self.params,
        ))
    }

    /// One inverse step for `frame`, written into the caller-owned `cmd` (see the module docs for
    /// the stages). Allocates nothing.
    ///
    /// # Errors
    /// [`StepError`] when the frame or the parameters are invalid; `cmd` is then untouched.
    pub fn step(
        &mut self,
        frame: &ComplianceFrame<M>,
        cmd: &mut Command<M>,
    ) -> Result<SolverReport, StepError> {
        // 1. validate + factor the diagonal blocks once for the 8 solves; 2. warm start.
        let m = self.begin(frame)?;
        let p = self.params;
        let q = frame.q;
        let mut report = SolverReport::default();
        let (b0, rep) = self.solve_base(frame, &q);
        let count = |report: &mut SolverReport, r: &SolveReport| {
            report.iterations = report.iterations.saturating_add(r.iterations);
            report.solves += 1;
            if !r.converged {
                report.flags |= StatusFlags::NOT_CONVERGED;
            }
        };
        count(&mut report, &rep);
        let obj0 = evaluate_objective(frame, &self.lambda_base, &b0, &p);
        let t0 = Vector4::from(obj0.t);
        report.objective = obj0.t;

        let mut q_new = q;
        let mut final_rep = rep;
        if t0.norm_squared() <= p.tolerance {
            // 3. within tolerance: hold, λ from the base solve.
            report.flags |= StatusFlags::WITHIN_TOLERANCE;
            self.lambda_work[..m].copy_from_slice(&self.lambda_base[..m]);
            report.objective_after = obj0.t;
        } else {
            // 4. Jacobian by forward differences, W fixed, warm start λ_q.
            let mut jac = SMatrix::<f64, 4, JOINTS>::zeros();
            let linearize = match p.jacobian {
                JacobianMode::Solve => false,
                JacobianMode::Linearized => true,
                JacobianMode::Hybrid => frame.inserted == 0,
            };
            let linear = linearize && self.factor_linearized(frame);
            for i in 0..JOINTS {
                let mut qi = q;
                qi[i] += p.joint_step;
                let tol = p.jacobian_tolerance.max(p.gs.tolerance);
                let bi = if linear {
                    report.solves += 1;
                    self.predict_at(frame, &qi)
                } else {
                    let (bi, r) = self.solve_perturbed(frame, &qi, tol);
                    count(&mut report, &r);
                    bi
                };
                let ti = evaluate_objective(frame, &self.lambda_work, &bi, &p);
                for r in 0..3 {
                    jac[(r, i)] = (ti.t[r] - obj0.t[r]) / p.joint_step;
                }
                jac[(3, i)] = obj0.angle_derivative(&ti, p.joint_step, p.angle_weight);
            }
            // 5. damped least squares with singularity-adaptive damping.
            let jjt: Matrix4<f64> = jac * jac.transpose();
            let sigma_min = libm::sqrt(smallest_eigenvalue(&jjt).max(0.0));
            let mut eps2 = p.damping * p.damping;
            if sigma_min < p.singular_threshold {
                let r = sigma_min / p.singular_threshold;
                eps2 += (1.0 - r * r) * p.damping_max * p.damping_max;
                report.flags |= StatusFlags::NEAR_SINGULAR;
            }
            // Joints at a limit that the step pushes further out are locked (their column
            // removed) and the step recomputed, so that the clamp below never turns the Newton
            // step into one that does not descend (e.g. J2 and J3 at their limits: the wrist alone
            // tilting the needle away from an unreachable target).
            let mut jac_free = jac;
            let mut dq = SVector::<f64, JOINTS>::zeros();
            for _ in 0..=JOINTS {
                let jjt: Matrix4<f64> = jac_free * jac_free.transpose();
                dq = match (jjt + Matrix4::identity() * eps2).cholesky() {
                    Some(ch) => -(jac_free.transpose() * ch.solve(&t0)),
                    None => SVector::zeros(),
                };
                let mut locked = false;
                for i in 0..JOINTS {
                    let l = &self.chain.limits[i];
                    let out = (q[i] >= l.upper && dq[i] > 0.0) || (q[i] <= l.lower && dq[i] < 0.0);
                    if out {
                        jac_free.set_column(i, &Vector4::zeros());
                        dq[i] = 0.0;
                        locked = true;
                    }
                }
                if !locked {
                    break;
                }
                report.flags |= StatusFlags::SATURATED_LIMIT;
            }
            if !dq.iter().all(|x| x.is_finite()) || dq.iter().all(|x| *x == 0.0) {
                dq.fill(0.0);
                report.flags |= StatusFlags::TARGET_UNREACHABLE;
            }
            // 6. trust region on the base motion, speed limit (uniform scaling), then joint limits.
            let (jt, _) = self.chain.jacobian_tool(&q);
            let base_motion = (jt.fixed_rows::<3>(0) * dq).norm();
            let mut scale = 1.0f64;
            if base_motion > p.max_base_step {
                dq *= p.max_base_step / base_motion;
                report.flags |= StatusFlags::STEP_LIMITED;
            }
            for i in 0..JOINTS {
                let lim = self.chain.limits[i].max_speed * frame.dt;
                let a = libm::fabs(dq[i]);
                if a > lim {
                    scale = scale.min(if lim > 0.0 { lim / a } else { 0.0 });
                }
            }
            if scale < 1.0 {
                dq *= scale;
                report.flags |= StatusFlags::SATURATED_SPEED;
            }
            for i in 0..JOINTS {
                q_new[i] = q[i] + dq[i];
            }
            if self.chain.clamp_to_limits(&mut q_new) {
                report.flags |= StatusFlags::SATURATED_LIMIT;
            }
            // A frame outside the limits must still respect the speed limit.
            for i in 0..JOINTS {
                let lim = self.chain.limits[i].max_speed * frame.dt;
                q_new[i] = q_new[i].max(q[i] - lim).min(q[i] + lim);
            }
            let mut applied = SVector::<f64, JOINTS>::zeros();
            for i in 0..JOINTS {
                applied[i] = q_new[i] - q[i];
            }
            // The clamps may have bent the step: keep the best multiple α ∈ [0, 1] of what is
            // left for the linear model, never a step it predicts to make the objective worse.
            let ja = jac * applied;
            let jj = ja.norm_squared();
            if jj > 0.0 {
                let alpha = (-t0.dot(&ja) / jj).clamp(0.0, 1.0);
                if alpha < 1.0 {
                    for i in 0..JOINTS {
                        q_new[i] = q[i] + alpha * applied[i];
                        applied[i] *= alpha;
                    }
                }
            }
            let predicted = t0 + jac * applied;
            if predicted.norm() > 0.99 * t0.norm() {
                report.flags |= StatusFlags::TARGET_UNREACHABLE;
            }
            // 7. final solve at q + Δq (from the linear prediction when there is one).
            let (bf, r) = if linear && p.eliminate_base {
                self.predict_at(frame, &q_new);
                let n = self.red.rows();
                self.lr_work[..n].copy_from_slice(&self.lambda_work[6..6 + n]);
                self.solve_reduced(frame, &q_new, false, p.gs.tolerance)
            } else {
                self.solve_perturbed(frame, &q_new, p.gs.tolerance)
            };
            count(&mut report, &r);
            final_rep = r;
            report.objective_after = evaluate_objective(frame, &self.lambda_work, &bf, &p).t;
        }
        report.final_iterations = final_rep.iterations;
        report.final_residual = final_rep.residual;
        for i in 0..JOINTS {
            report.delta_q[i] = q_new[i] - q[i];
        }
        if !q_new.iter().all(|x| x.is_finite())
            || !self.lambda_work[..m].iter().all(|x| x.is_finite())
        {
            return Err(StepError::NonFinite {
                stage: "final solve",
            });
        }
        self.answer(frame, &q_new, report, cmd);
        Ok(report)
    }

    /// One constraint solve at the given joints, without the inverse update: the open-loop step
    /// of a replayed trajectory. The same preparation, warm start and solver (base elimination,
    /// active-set polish) as the first solve of [`Self::step`]; the command carries `q` and λ.
    ///
    /// # Errors
    /// As [`Self::step`]: an invalid frame or parameters, a non-finite result.
    pub fn solve_open_loop(
        &mut self,
        frame: &ComplianceFrame<M>,
        q: &[f64; JOINTS],
        cmd: &mut Command<M>,
    ) -> Result<SolverReport, StepError> {
        let m = self.begin(frame)?;
        let (_, rep) = self.solve_base(frame, q);
        if !self.lambda_base[..m].iter().all(|x| x.is_finite()) {
            return Err(StepError::NonFinite {
                stage: "open-loop solve",
            });
        }
        self.lambda_work[..m].copy_from_slice(&self.lambda_base[..m]);
        let report = SolverReport {
            iterations: rep.iterations,
            solves: 1,
            flags: if rep.converged {
                0
            } else {
                StatusFlags::NOT_CONVERGED
            },
            final_iterations: rep.iterations,
            final_residual: rep.residual,
            ..SolverReport::default()
        };
        self.answer(frame, q, report, cmd);
        Ok(report)
    }

    /// Validates the parameters and the frame, factors the diagonal blocks (of the reduced
    /// problem when the base rows are eliminated) and warm-starts `lambda_base`. Returns `m`.
    fn begin(&mut self, frame: &ComplianceFrame<M>) -> Result<usize, StepError> {
        self.check_params()?;
        self.gs.prepare_frame(frame)?;
        if self.params.eliminate_base {
            self.prepare_reduced(frame)?;
        }
        let m = frame.rows();
        self.delta[..m].copy_from_slice(&frame.delta_free[..m]);
        if self.params.warm_start && self.prev_m > 0 {
            let n = self.prev_m.min(m);
            self.lambda_base[..n].copy_from_slice(&self.lambda_prev[..n]);
            self.lambda_base[n..m].fill(0.0);
        } else {
            self.lambda_base[..m].fill(0.0);
        }
        Ok(m)
    }

    /// Keeps λ (`lambda_work`) for the next warm start and writes the command.
    fn answer(
        &mut self,
        frame: &ComplianceFrame<M>,
        q: &[f64; JOINTS],
        report: SolverReport,
        cmd: &mut Command<M>,
    ) {
        let m = frame.rows();
        self.lambda_prev[..m].copy_from_slice(&self.lambda_work[..m]);
        self.prev_m = m;
        cmd.version = VERSION;
        cmd.m = frame.m;
        cmd.frame_sequence = frame.sequence;
        cmd.q = *q;
        cmd.lambda[..m].copy_from_slice(&self.lambda_work[..m]);
        cmd.lambda[m..].fill(0.0);
        cmd.report = report;
    }
}

/// Smallest eigenvalue of a symmetric 4×4 matrix (NaN-safe: 0 for non-finite input).
fn smallest_eigenvalue(a: &Matrix4<f64>) -> f64 {
    if !a.iter().all(|x| x.is_finite()) {
        return 0.0;
    }
    let eig = nalgebra::SymmetricEigen::new(*a);
    eig.eigenvalues.iter().fold(f64::INFINITY, |m, &x| m.min(x))
}

#[cfg(test)]
#[allow(clippy::expect_used, clippy::unwrap_used, clippy::panic)]
mod tests {
    use super::*;
    use crate::synthetic::rigid_needle_frame;

    #[test]
    fn rigid_needle_newton_converges() {
        let chain = DhChain::rv1a();
        let mut frame = ComplianceFrame::<12>::new_boxed();
        let mut cmd = Command::<12>::new_boxed();
        let q_target = [0.2, 0.35, 2.0, 0.1, 0.6, -0.2];
        let q_free = [0.25, 0.3, 2.05, 0.05, 0.55, -0.25];
        rigid_needle_frame(&mut frame, &chain, &q_free, &q_target, 120.0);
        let mut ctrl = Controller::<12>::new_boxed(chain, InverseParams::default());
        let mut q = q_free;
        let mut last = f64::INFINITY;
        for _ in 0..8 {
            frame.q = q;
            let rep = ctrl.step(&frame, &mut cmd).expect("valid");
            let n = Vector4::from(rep.objective).norm();
            std::println!(
                "{:?} |T| {n:e} flags {:#x} sweeps {}",
                rep.objective,
                rep.flags,
                rep.iterations
            );
            assert!(n <= last);
            last = n;
            q = cmd.q;
        }
        assert!(last < 1e-2);
    }

    #[test]
    fn blend_follows_the_text() {
        assert_eq!(blend_factor(false, 0.0, 20.0), 1.0);
        assert_eq!(blend_factor(false, 50.0, 20.0), 1.0);
        assert_eq!(blend_factor(true, 0.0, 20.0), 1.0);
        assert!((blend_factor(true, 5.0, 20.0) - 0.75).abs() < 1e-15);
        assert_eq!(blend_factor(true, 20.0, 20.0), 0.0);
        assert_eq!(blend_factor(true, 80.0, 20.0), 0.0);
    }
}

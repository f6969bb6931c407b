//! The default of every optional scene field (`docs/scene-format.md`): serde's
//! `#[serde(default = …)]` and the sections' `Default` impls both call these. Where the value
//! has a typed home — the step's [`StepParams`], [`Interaction`] and [`Insertion`], the core's
//! [`InverseParams`], the gel's [`GelParams`] — it is read from that type's `Default`, so it is
//! written once. The scene keeps its own value, on purpose, for the gel's Young's modulus (the
//! benchmark's 20 kPa; `GelParams` defaults to a softer 5 kPa test gel), the trust region
//! `max_base_step` (5 mm per step; the core's default is off, `+∞`), the FE time step and the
//! background factorisation (a run's choices; the FE model's defaults are the static Newton step,
//! synchronous); the needle's material and the path sampling have no other home.

use super::{FactorPrecisionSpec, FixedSpec, GelSolveSpec, JacobianSpec, MethodSpec};
use crate::free_motion::GelParams;
use crate::step::{Insertion, Interaction, StepParams};
use needle_core::inverse::InverseParams;

pub(super) fn default_preset() -> String {
    "rv1a".to_owned()
}
pub(super) fn default_dt() -> f64 {
    StepParams::default().dt
}
pub(super) fn default_gel_e() -> f64 {
    0.02
}
pub(super) fn default_gel_nu() -> f64 {
    GelParams::default().elasticity.poisson_ratio
}
pub(super) fn default_gel_rho() -> f64 {
    GelParams::default().density
}
pub(super) fn default_fixed() -> FixedSpec {
    FixedSpec {
        below_z: Some(0.0),
        nodes: Vec::new(),
    }
}
pub(super) fn default_needle_length() -> f64 {
    120.0
}
pub(super) fn default_needle_diameter() -> f64 {
    1.0
}
pub(super) fn default_needle_e() -> f64 {
    200_000.0
}
pub(super) fn default_needle_nu() -> f64 {
    0.3
}
pub(super) fn default_needle_rho() -> f64 {
    7.85e-9
}
pub(super) fn default_needle_beams() -> usize {
    40
}
pub(super) fn default_pf() -> f64 {
    Interaction::default().puncture_force
}
pub(super) fn default_mu_s() -> f64 {
    Interaction::default().surface_friction
}
pub(super) fn default_mu_n() -> f64 {
    Interaction::default().shaft_friction
}
pub(super) fn default_dn() -> f64 {
    Interaction::default().constraint_spacing
}
pub(super) fn default_dq() -> f64 {
    InverseParams::default().joint_step
}
pub(super) fn default_blend() -> f64 {
    InverseParams::default().blend_depth
}
pub(super) fn default_damping() -> f64 {
    InverseParams::default().damping
}
pub(super) fn default_angle_weight() -> f64 {
    InverseParams::default().angle_weight
}
pub(super) fn default_inverse_tol() -> f64 {
    InverseParams::default().tolerance
}
pub(super) fn default_max_base_step() -> f64 {
    5.0
}
pub(super) fn default_method() -> MethodSpec {
    MethodSpec::Qp
}
pub(super) fn default_clearance_margin() -> f64 {
    InverseParams::default().clearance_margin
}
pub(super) fn default_qp_angle_weight() -> f64 {
    InverseParams::default().qp_angle_weight
}
pub(super) fn default_qp_heading() -> bool {
    InverseParams::default().qp_heading
}

pub(super) fn default_aim_ahead() -> f64 {
    InverseParams::default().aim_ahead
}
pub(super) fn default_replan_rejected() -> bool {
    InverseParams::default().replan_rejected
}

pub(super) fn default_second_opinion() -> bool {
    InverseParams::default().second_opinion
}

pub(super) fn default_qp_angle_damping_max() -> f64 {
    InverseParams::default().qp_angle_damping_max
}

pub(super) fn default_qp_spin_weight() -> f64 {
    InverseParams::default().qp_spin_weight
}
pub(super) fn default_straighten_max_offset() -> f64 {
    crate::straighten::MAX_OFFSET_MM
}
pub(super) fn default_target_standoff() -> f64 {
    crate::straighten::TARGET_STANDOFF_MM
}
pub(super) fn default_bound_strain() -> bool {
    true
}
pub(super) fn default_resume_held() -> bool {
    InverseParams::default().resume_held
}
pub(super) fn default_settling_margin() -> bool {
    InverseParams::default().settling_margin
}
pub(super) fn default_limit_avoidance() -> f64 {
    InverseParams::default().limit_avoidance
}
pub(super) fn default_jacobian() -> JacobianSpec {
    JacobianSpec::Hybrid
}
pub(super) fn default_gs_tol() -> f64 {
    InverseParams::default().gs.tolerance
}
pub(super) fn default_gs_iter() -> u32 {
    InverseParams::default().gs.max_iterations
}
pub(super) fn default_gs_relaxation() -> f64 {
    InverseParams::default().gs.relaxation
}
pub(super) fn default_h() -> f64 {
    0.04
}
pub(super) fn default_background() -> bool {
    true
}
pub(super) fn default_gel_solve() -> GelSolveSpec {
    GelSolveSpec::Direct
}
pub(super) fn default_pcg_tolerance() -> f64 {
    1e-3
}
pub(super) fn default_pcg_max_iterations() -> u32 {
    30
}
pub(super) fn default_refresh_rotation() -> f64 {
    0.05
}
pub(super) fn default_far_residual_tolerance() -> f64 {
    1e-3
}
pub(super) fn default_defer_far() -> bool {
    true
}
pub(super) fn default_factor_precision() -> FactorPrecisionSpec {
    FactorPrecisionSpec::Single
}

pub(super) fn default_samples() -> usize {
    201
}
pub(super) fn default_approach() -> f64 {
    10.0
}
pub(super) fn default_advance() -> f64 {
    Insertion::default().advance_per_step
}
pub(super) fn default_max_lead() -> f64 {
    Insertion::default().max_lead
}
pub(super) fn default_vtk_every() -> usize {
    0
}

//! The documented default of every optional scene field (`docs/scene-format.md`), written once:
//! serde's `#[serde(default = …)]` and the sections' `Default` impls both call these.

use super::{FixedSpec, JacobianSpec};

pub(super) fn default_preset() -> String {
    "rv1a".to_owned()
}
pub(super) fn default_dt() -> f64 {
    0.04
}
pub(super) fn default_gel_e() -> f64 {
    0.02
}
pub(super) fn default_gel_nu() -> f64 {
    0.45
}
pub(super) fn default_gel_rho() -> f64 {
    1.0e-9
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
    0.2
}
pub(super) fn default_mu_s() -> f64 {
    0.3
}
pub(super) fn default_mu_n() -> f64 {
    0.1
}
pub(super) fn default_dn() -> f64 {
    10.0
}
pub(super) fn default_dq() -> f64 {
    0.01
}
pub(super) fn default_blend() -> f64 {
    20.0
}
pub(super) fn default_damping() -> f64 {
    1.0
}
pub(super) fn default_angle_weight() -> f64 {
    100.0
}
pub(super) fn default_inverse_tol() -> f64 {
    1.0e-6
}
pub(super) fn default_max_base_step() -> f64 {
    5.0
}
pub(super) fn default_jacobian() -> JacobianSpec {
    JacobianSpec::Hybrid
}
pub(super) fn default_gs_tol() -> f64 {
    1.0e-7
}
pub(super) fn default_gs_iter() -> u32 {
    400
}
pub(super) fn default_h() -> f64 {
    0.04
}
pub(super) fn default_background() -> bool {
    true
}

pub(super) fn default_samples() -> usize {
    201
}
pub(super) fn default_approach() -> f64 {
    10.0
}
pub(super) fn default_advance() -> f64 {
    0.1
}
pub(super) fn default_vtk_every() -> usize {
    0
}

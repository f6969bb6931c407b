//! Corotational linear tetrahedra (paper eq. 1): `K_e = R_e K0_e R_eᵀ`.
//!
//! Per element, once: the rest stiffness `K0_e = V_e Bᵀ D B` (isotropic, Lamé λ, μ; stored in
//! factored form, see [`CorotationalTetra`]) and the rest node positions relative to the element
//! centroid `X̄_a = X_a − X_c` (implicitly: `Σ_a X̄_a g_aᵀ = I`). Per step: the rotation
//! `R_e` from the polar decomposition of the deformation gradient `F = D_s D_m⁻¹`
//! ([`rotation_from_deformation`]), the internal force
//!
//! ```text
//! f_e = R K0 (Rᵀ (x − x_c) − X̄)        (node-wise, x_c the current centroid)
//! ```
//!
//! which vanishes for any rigid motion (the centring removes the translation, `R` the rotation),
//! and the tangent `K_e = R K0 Rᵀ` (exact at rigid configurations, `O(strain)` away from them:
//! the derivative of `R` is neglected, as in the paper and SOFA).
//!
//! Sign convention: `f_int` is the force the element needs to *be held* in place; equilibrium
//! is `f_int(x) = f_ext`, and one Newton step solves `K Δx = f_ext − f_int`.
//!
//! Storage is contiguous per quantity (struct of arrays): tets, `D_m⁻¹`, volumes, shape
//! gradients, rotations.

// Negated comparisons are deliberate: NaN must fail every validity check.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::nonminimal_bool)]

use super::{Elasticity, FemError};
use crate::mesh::TetMesh;
use nalgebra::{Matrix3, SMatrix, Vector3};

/// The ten upper 3×3 blocks `(a, b)`, `a ≤ b`, of a 12×12 element matrix, in storage order.
pub const BLOCK_PAIRS: [(usize, usize); 10] = [
    (0, 0),
    (0, 1),
    (0, 2),
    (0, 3),
    (1, 1),
    (1, 2),
    (1, 3),
    (2, 2),
    (2, 3),
    (3, 3),
];

/// Number of distinct entries of a symmetric 12×12 element stiffness written by assembly:
/// 6 off-diagonal blocks × 9 + 4 diagonal blocks × 6 (upper triangle).
pub const STIFFNESS_ENTRIES: usize = 78;

/// How element rotations are obtained.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Kinematics {
    /// Rotation from the polar decomposition of the deformation gradient (the paper's model).
    #[default]
    Corotational,
    /// `R = I` always: small-strain linear elasticity (for reference comparisons).
    Linear,
}

/// The Newton fast path of [`rotation_from_deformation`] takes `F` when `det F` exceeds this
/// fraction of `(|F|²/3)^(3/2)` (the determinant of `F`'s size as a pure stretch).
const FAST_PATH_DET_RATIO: f64 = 1e-3;

/// The polar iteration scales by `|det X|^(−1/3)` on its first step when `|det X − 1|` exceeds this.
const POLAR_SCALING_THRESHOLD: f64 = 1e-2;

/// The polar iteration has converged when a step changes no entry by more than this.
const POLAR_STEP_TOLERANCE: f64 = 1e-8;

/// Most polar iterations before the SVD path takes over.
const POLAR_MAX_ITERATIONS: usize = 30;

/// Rotation closest to the deformation gradient `f` (polar decomposition `F = R S`, `R = U Vᵀ`
/// for the SVD `F = U Σ Vᵀ`). For well-shaped elements with `det F > 0` it is computed by the
/// scaled Newton polar iteration (same factor, faster); otherwise through an SVD obtained from
/// the symmetric eigen-decomposition of `FᵀF` ([`rotation_from_deformation_svd`]).
///
/// Reflections: `V` is made a proper rotation and the last column of `U` is taken as
/// `u₀ × u₁` (not `F v₂ / σ₂`). When `det F > 0` this is the usual polar rotation; when the
/// element is inverted (`det F < 0`) it amounts to negating the smallest singular value
/// (Irving et al. 2004), so `R` stays a proper rotation and the elastic force pushes the element
/// back to positive volume instead of blowing up. Degenerate cases stay finite: if `F` has rank
/// one the second axis is any unit vector orthogonal to the first, if `F ≈ 0` the identity is returned.
pub fn rotation_from_deformation(f: &Matrix3<f64>) -> Matrix3<f64> {
    // Fast path for well-shaped, non-inverted elements: the scaled Newton iteration of Higham
    // (X ← ½(γX + X⁻ᵀ/γ)) converges quadratically to the same orthogonal polar factor U Vᵀ;
    // 3–4 iterations at small strain, far cheaper than an eigen-decomposition.
    // (|F|²/3)^(3/2) without `powf` (a tenth of the step's element update went to it).
    let t = f.norm_squared() / 3.0;
    let scale3 = t * t.sqrt();
    if f.determinant() > FAST_PATH_DET_RATIO * scale3
        && let Some(r) = polar_newton(f)
    {
        return r;
    }
    rotation_from_deformation_svd(f)
}

/// Orthogonal polar factor by the scaled Newton iteration; `None` if it does not converge.
///
/// `X⁻ᵀ = cof(X) / det X`; the determinant scaling `γ = |det X|^(−1/3)` (Higham) is applied on
/// the first iteration when `det X` is far from 1. Near convergence the error after a step is about (step size)²/2, so
/// a step below 1e-8 leaves an error at round-off level.
fn polar_newton(f: &Matrix3<f64>) -> Option<Matrix3<f64>> {
    let mut x = *f;
    for k in 0..POLAR_MAX_ITERATIONS {
        let c = cofactor(&x);
        let det = x[(0, 0)] * c[(0, 0)] + x[(1, 0)] * c[(1, 0)] + x[(2, 0)] * c[(2, 0)];
        if !(det > 0.0) {
            return None;
        }
        let g = if k == 0 && (det - 1.0).abs() > POLAR_SCALING_THRESHOLD {
            1.0 / det.cbrt()
        } else {
            1.0
        };
        let next = x * (0.5 * g) + c * (0.5 / (g * det));
        let diff = (next - x).abs().max();
        x = next;
        if diff <= POLAR_STEP_TOLERANCE {
            return Some(x);
        }
    }
    None
}

/// Elements whose polar iterations [`rotations_from_deformations`] runs side by side, one per
/// SIMD lane (eight `f64`: one AVX-512 vector, two AVX2 ones).
pub const POLAR_LANES: usize = 8;

/// [`rotation_from_deformation`] of each `f[i]` into `out[i]`, bit for bit, with the scaled
/// Newton iterations of up to [`POLAR_LANES`] elements run together, one per SIMD lane: each lane
/// does its element's operations in the scalar order and stops at its own convergence, so only
/// the instructions are shared. Elements off the fast path (inverted, flat, not converged) take
/// [`rotation_from_deformation_svd`] one by one, as in the scalar function. The iterations are a
/// chain of dependent divisions and products per element; side by side they fill the vector
/// units instead of waiting on each other.
///
/// # Panics
/// If `f` and `out` differ in length.
pub fn rotations_from_deformations(f: &[Matrix3<f64>], out: &mut [Matrix3<f64>]) {
    assert_eq!(f.len(), out.len(), "one rotation per deformation gradient");
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: AVX-512F support was checked at run time.
            return unsafe { polar_chunks_avx512(f, out) };
        }
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: AVX2 support was checked at run time.
            return unsafe { polar_chunks_avx2(f, out) };
        }
    }
    polar_chunks(f, out);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn polar_chunks_avx512(f: &[Matrix3<f64>], out: &mut [Matrix3<f64>]) {
    polar_chunks(f, out);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn polar_chunks_avx2(f: &[Matrix3<f64>], out: &mut [Matrix3<f64>]) {
    polar_chunks(f, out);
}

/// [`polar_lanes`] over consecutive chunks of [`POLAR_LANES`] gradients.
#[inline(always)]
fn polar_chunks(f: &[Matrix3<f64>], out: &mut [Matrix3<f64>]) {
    for (f, out) in f.chunks(POLAR_LANES).zip(out.chunks_mut(POLAR_LANES)) {
        polar_lanes(f, out);
    }
}

/// [`rotation_from_deformation`] of at most [`POLAR_LANES`] gradients, [`polar_newton`]'s
/// operations lane by lane on entry-major arrays (`x[k][lane]`, `k` the column-major entry).
#[inline(always)]
fn polar_lanes(f: &[Matrix3<f64>], out: &mut [Matrix3<f64>]) {
    const L: usize = POLAR_LANES;
    debug_assert!(f.len() <= L && f.len() == out.len());
    // Lanes off the fast path (and past `f.len()`) iterate on the identity: converged at once,
    // their result unused.
    let mut x = [[0.0f64; L]; 9];
    for k in [0, 4, 8] {
        x[k] = [1.0; L];
    }
    // The fast-path test of `rotation_from_deformation`, its square roots side by side.
    let mut t = [0.0f64; L];
    let mut det0 = [0.0f64; L];
    for (l, fl) in f.iter().enumerate() {
        t[l] = fl.norm_squared() / 3.0;
        det0[l] = fl.determinant();
    }
    let mut pending = [false; L];
    for l in 0..L {
        let scale3 = t[l] * t[l].sqrt();
        pending[l] = l < f.len() && det0[l] > FAST_PATH_DET_RATIO * scale3;
    }
    for (l, fl) in f.iter().enumerate() {
        if pending[l] {
            for (k, xk) in x.iter_mut().enumerate() {
                xk[l] = fl[k];
            }
        }
    }
    let mut newton = [false; L];
    for k in 0..POLAR_MAX_ITERATIONS {
        if !pending.contains(&true) {
            break;
        }
        // The cofactor, column by column: c0 = x1 × x2, c1 = x2 × x0, c2 = x0 × x1.
        let mut c = [[0.0f64; L]; 9];
        for l in 0..L {
            c[0][l] = x[4][l] * x[8][l] - x[5][l] * x[7][l];
            c[1][l] = x[5][l] * x[6][l] - x[3][l] * x[8][l];
            c[2][l] = x[3][l] * x[7][l] - x[4][l] * x[6][l];
            c[3][l] = x[7][l] * x[2][l] - x[8][l] * x[1][l];
            c[4][l] = x[8][l] * x[0][l] - x[6][l] * x[2][l];
            c[5][l] = x[6][l] * x[1][l] - x[7][l] * x[0][l];
            c[6][l] = x[1][l] * x[5][l] - x[2][l] * x[4][l];
            c[7][l] = x[2][l] * x[3][l] - x[0][l] * x[5][l];
            c[8][l] = x[0][l] * x[4][l] - x[1][l] * x[3][l];
        }
        let mut det = [0.0f64; L];
        for l in 0..L {
            det[l] = x[0][l] * c[0][l] + x[1][l] * c[1][l] + x[2][l] * c[2][l];
        }
        for l in 0..L {
            if !(det[l] > 0.0) {
                pending[l] = false;
            }
        }
        // The determinant scaling, on the first iteration only (a scalar cube root).
        let mut g = [1.0f64; L];
        if k == 0 {
            for l in 0..L {
                if pending[l] && (det[l] - 1.0).abs() > POLAR_SCALING_THRESHOLD {
                    g[l] = 1.0 / det[l].cbrt();
                }
            }
        }
        let mut a = [0.0f64; L];
        let mut b = [0.0f64; L];
        for l in 0..L {
            a[l] = 0.5 * g[l];
            b[l] = 0.5 / (g[l] * det[l]);
        }
        let mut next = [[0.0f64; L]; 9];
        for e in 0..9 {
            for l in 0..L {
                next[e][l] = x[e][l] * a[l] + c[e][l] * b[l];
            }
        }
        let mut diff = [0.0f64; L];
        for l in 0..L {
            diff[l] = (next[0][l] - x[0][l]).abs();
        }
        // The largest change (a plain compare: `f64::max`'s NaN handling costs a third of the
        // iteration; a pending lane's iterates are finite).
        for e in 1..9 {
            for l in 0..L {
                let d = (next[e][l] - x[e][l]).abs();
                diff[l] = if d > diff[l] { d } else { diff[l] };
            }
        }
        // Every lane steps (a converged one stays at its fixed point, a rotation; a failed one
        // restarts from the identity below): no masked writes, which would stall the loads of
        // the next iteration. A lane's result is taken when it converges.
        x = next;
        for l in 0..L {
            if pending[l] && diff[l] <= POLAR_STEP_TOLERANCE {
                pending[l] = false;
                newton[l] = true;
                out[l] = Matrix3::from_fn(|i, j| x[3 * j + i][l]);
            } else if !(det[l] > 0.0) {
                for (e, xe) in x.iter_mut().enumerate() {
                    xe[l] = if e % 4 == 0 { 1.0 } else { 0.0 };
                }
            }
        }
    }
    for (l, (fl, r)) in f.iter().zip(out.iter_mut()).enumerate() {
        if !newton[l] {
            *r = rotation_from_deformation_svd(fl);
        }
    }
}

/// Cofactor matrix (`det(X) X⁻ᵀ`).
#[inline(always)]
fn cofactor(x: &Matrix3<f64>) -> Matrix3<f64> {
    let c0 = x.column(1).cross(&x.column(2));
    let c1 = x.column(2).cross(&x.column(0));
    let c2 = x.column(0).cross(&x.column(1));
    // Rows of X⁻¹·det are c0, c1, c2, so cof(X) = det X⁻ᵀ has them as columns.
    Matrix3::from_columns(&[c0, c1, c2])
}

/// The SVD-based path of [`rotation_from_deformation`] (used for inverted, flat or very
/// distorted elements, and available on its own for testing).
pub fn rotation_from_deformation_svd(f: &Matrix3<f64>) -> Matrix3<f64> {
    let c = f.tr_mul(f);
    let eig = c.symmetric_eigen();
    let l = eig.eigenvalues;
    let mut order = [0usize, 1, 2];
    order.sort_unstable_by(|&a, &b| l[b].total_cmp(&l[a]));
    let v0: Vector3<f64> = eig.eigenvectors.column(order[0]).into();
    let v1: Vector3<f64> = eig.eigenvectors.column(order[1]).into();
    let v2 = v0.cross(&v1);
    let scale = f.norm();
    if !(scale > 0.0) || !scale.is_finite() {
        return Matrix3::identity();
    }
    let mut u0 = f * v0;
    let n0 = u0.norm();
    if n0 <= 1e-12 * scale {
        return Matrix3::identity();
    }
    u0 /= n0;
    let mut u1 = f * v1;
    u1 -= u0 * u0.dot(&u1);
    let n1 = u1.norm();
    if n1 <= 1e-12 * scale {
        // Rank one: any unit vector orthogonal to u0.
        let a = if u0.x.abs() < 0.9 {
            Vector3::x()
        } else {
            Vector3::y()
        };
        u1 = (a - u0 * u0.dot(&a)).normalize();
    } else {
        u1 /= n1;
    }
    let u2 = u0.cross(&u1);
    u0 * v0.transpose() + u1 * v1.transpose() + u2 * v2.transpose()
}

/// The largest angle between corresponding rotations of `a` and `b` [rad], from
/// `‖R − R'‖_F = 2√2 sin(θ/2)` (e.g. element rotations at two times: the corotational tangent
/// `R K0 Rᵀ` changes only through them).
pub fn largest_rotation_between(a: &[Matrix3<f64>], b: &[Matrix3<f64>]) -> f64 {
    largest_rotation_where(a, b, |_| true)
}

/// [`largest_rotation_between`] over the pairs whose index `keep` accepts (0 for none).
pub fn largest_rotation_where(
    a: &[Matrix3<f64>],
    b: &[Matrix3<f64>],
    keep: impl Fn(usize) -> bool,
) -> f64 {
    let largest = (a.iter().zip(b).enumerate())
        .filter(|(i, _)| keep(*i))
        .map(|(_, (r, s))| (r - s).norm_squared())
        .fold(0.0f64, f64::max);
    let chord = (largest.sqrt() / (2.0 * core::f64::consts::SQRT_2)).min(1.0);
    2.0 * chord.asin()
}

/// The smallest and largest singular values of `f` (principal stretches), from the closed-form
/// eigenvalues of `FᵀF` (Smith's trigonometric solution of the characteristic cubic): a
/// fraction of the cost of an SVD, accurate to about 1e-8 of `|F|²` in the worst case (two
/// nearly equal eigenvalues), which a strain statistic does not notice. NaN in, NaN out.
pub fn stretch_range(f: &Matrix3<f64>) -> (f64, f64) {
    let c = f.tr_mul(f);
    let q = c.trace() / 3.0;
    let p1 = c[(0, 1)] * c[(0, 1)] + c[(0, 2)] * c[(0, 2)] + c[(1, 2)] * c[(1, 2)];
    let (lo, hi) = if p1 == 0.0 {
        let d = [c[(0, 0)], c[(1, 1)], c[(2, 2)]];
        (d[0].min(d[1]).min(d[2]), d[0].max(d[1]).max(d[2]))
    } else {
        let (a, b, d) = (c[(0, 0)] - q, c[(1, 1)] - q, c[(2, 2)] - q);
        let p = ((a * a + b * b + d * d + 2.0 * p1) / 6.0).sqrt();
        let m = (c - Matrix3::identity() * q) / p;
        let r = (m.determinant() / 2.0).clamp(-1.0, 1.0);
        let phi = r.acos() / 3.0;
        let hi = q + 2.0 * p * phi.cos();
        let lo = q + 2.0 * p * (phi + 2.0 * core::f64::consts::FRAC_PI_3).cos();
        (lo, hi)
    };
    // Round-off may make a zero eigenvalue slightly negative; NaN passes through.
    let root = |e: f64| if e < 0.0 { 0.0 } else { e.sqrt() };
    (root(lo), root(hi))
}

/// See [`CorotationalTetra::strain_stats`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StrainStats {
    /// Largest principal strain `|σ − 1|` over the elements (NaN-free meshes: finite) [-].
    pub max_strain: f64,
    /// The element where it occurs.
    pub element: usize,
    /// Elements with `det F ≤ 0`.
    pub inverted: usize,
}

/// See [`CorotationalTetra::element_state`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ElementState {
    /// Corotational small strain `sym(Rᵀ F − I)` [-].
    pub strain: Matrix3<f64>,
    /// Von Mises equivalent stress [MPa].
    pub von_mises: f64,
    /// `det F ≤ 0`.
    pub inverted: bool,
}

/// Rest data of the gel's corotational tetrahedra.
///
/// `K0_e = V Bᵀ D B` is kept in factored form — the rest volume `V` and the four
/// shape-function gradients `g_a` (rows of `D_m⁻¹`, `g₀ = −Σ g_a`) — rather than as 78 numbers:
/// for an isotropic material `R K0_ab Rᵀ = V(λ h_a h_bᵀ + μ h_b h_aᵀ + μ (h_a·h_b) I)` with
/// `h_a = R g_a`, and the internal force is `f_a = V R σ g_a` with `σ = λ tr(ε) I + 2με`,
/// `ε = sym(Rᵀ F − I)` — the same as `R K0 (Rᵀ(x − x_c) − X̄)` node by node, at a fraction of
/// the memory traffic and flops (this is what makes the update + assembly of 1500 nodes ~1 ms).
#[derive(Clone, Debug)]
pub struct CorotationalTetra {
    kinematics: Kinematics,
    /// Lamé constants `[λ, μ]` of each element [MPa] (one material per region of the mesh).
    lame: Vec<[f64; 2]>,
    tets: Vec<[usize; 4]>,
    /// Rest edge matrix `D_m` [mm].
    dm: Vec<Matrix3<f64>>,
    /// Inverse rest edge matrix `D_m⁻¹` [1/mm].
    dm_inv: Vec<Matrix3<f64>>,
    /// Rest volumes [mm³].
    volumes: Vec<f64>,
    /// Shape-function gradients `g_a` in the rest frame [1/mm].
    grads: Vec<[Vector3<f64>; 4]>,
    /// Current element rotations (world ← rest).
    rotations: Vec<Matrix3<f64>>,
    /// Elements kept linear in a corotational mesh, one flag per element; empty: none
    /// ([`CorotationalTetra::keep_linear`]).
    linear: Vec<bool>,
}

impl CorotationalTetra {
    /// Precomputes the rest data (`D_m⁻¹`, `V`, shape gradients) of every element of `mesh`
    /// (its node positions are the rest configuration), all of one material.
    ///
    /// # Errors
    /// [`FemError::Material`] for invalid elastic constants, [`FemError::Mesh`] if the mesh is invalid.
    pub fn try_new(
        mesh: &TetMesh,
        material: &Elasticity,
        kinematics: Kinematics,
    ) -> Result<Self, FemError> {
        Self::try_new_per_element(mesh, &vec![*material; mesh.tets.len()], kinematics)
    }

    /// As [`CorotationalTetra::try_new`] with element `e` of material `materials[e]` (e.g. the
    /// material of its region).
    ///
    /// # Errors
    /// As [`CorotationalTetra::try_new`]; [`FemError::DimensionMismatch`] unless there is one
    /// material per element.
    pub fn try_new_per_element(
        mesh: &TetMesh,
        materials: &[Elasticity],
        kinematics: Kinematics,
    ) -> Result<Self, FemError> {
        mesh.validate().map_err(FemError::Mesh)?;
        if materials.len() != mesh.tets.len() {
            return Err(FemError::DimensionMismatch {
                what: "element materials",
                expected: mesh.tets.len(),
                got: materials.len(),
            });
        }
        let mut lame = Vec::with_capacity(materials.len());
        for material in materials {
            material.validate()?;
            let (lambda, mu) = material.lame();
            lame.push([lambda, mu]);
        }
        let m = mesh.tets.len();
        let mut dm_all = Vec::with_capacity(m);
        let mut dm_inv = Vec::with_capacity(m);
        let mut volumes = Vec::with_capacity(m);
        let mut grads = Vec::with_capacity(m);
        for (element, t) in mesh.tets.iter().enumerate() {
            let x = t.map(|i| mesh.nodes[i]);
            let dm = Matrix3::from_columns(&[x[1] - x[0], x[2] - x[0], x[3] - x[0]]);
            let inv = dm.try_inverse().ok_or(FemError::Mesh(
                crate::mesh::MeshError::DegenerateElement {
                    element,
                    volume: 0.0,
                    quality: 0.0,
                },
            ))?;
            let (g1, g2, g3) = (
                inv.row(0).transpose(),
                inv.row(1).transpose(),
                inv.row(2).transpose(),
            );
            let g = [-(g1 + g2 + g3), g1, g2, g3];
            dm_all.push(dm);
            dm_inv.push(inv);
            volumes.push(dm.determinant() / 6.0);
            grads.push(g);
        }
        Ok(Self {
            kinematics,
            lame,
            tets: mesh.tets.clone(),
            dm: dm_all,
            dm_inv,
            volumes,
            grads,
            rotations: vec![Matrix3::identity(); m],
            linear: Vec::new(),
        })
    }

    /// Keeps the elements flagged in `linear` (one flag per element) linear from now on:
    /// small-strain elasticity about the rest state, their rotation the identity whatever their
    /// deformation, in the forces, the tangent and [`CorotationalTetra::element_state`]; the
    /// element passes skip the polar decomposition of chunks of such elements. The others stay
    /// corotational (with [`Kinematics::Corotational`]). Meant at rest, before the first step.
    ///
    /// # Errors
    /// [`FemError::DimensionMismatch`] unless there is one flag per element.
    pub fn keep_linear(&mut self, linear: Vec<bool>) -> Result<(), FemError> {
        if linear.len() != self.tets.len() {
            return Err(FemError::DimensionMismatch {
                what: "linear element flags",
                expected: self.tets.len(),
                got: linear.len(),
            });
        }
        for (r, _) in self.rotations.iter_mut().zip(&linear).filter(|(_, l)| **l) {
            *r = Matrix3::identity();
        }
        self.linear = if linear.contains(&true) {
            linear
        } else {
            Vec::new()
        };
        Ok(())
    }

    /// Whether element `e` is kept linear ([`CorotationalTetra::keep_linear`]).
    #[inline]
    fn is_linear(&self, e: usize) -> bool {
        self.kinematics == Kinematics::Linear || self.linear.get(e).is_some_and(|l| *l)
    }

    /// Number of elements.
    pub fn len(&self) -> usize {
        self.tets.len()
    }

    /// Whether there is no element.
    pub fn is_empty(&self) -> bool {
        self.tets.is_empty()
    }

    /// Node indices of the elements.
    pub fn tets(&self) -> &[[usize; 4]] {
        &self.tets
    }

    /// Rest volume of element `e` [mm³].
    pub fn volume(&self, e: usize) -> f64 {
        self.volumes[e]
    }

    /// Current rotation of element `e` (world ← rest).
    pub fn rotation(&self, e: usize) -> &Matrix3<f64> {
        &self.rotations[e]
    }

    /// Current rotations of every element (world ← rest).
    pub fn rotations(&self) -> &[Matrix3<f64>] {
        &self.rotations
    }

    /// Rest stiffness `K0_e` as a full 12×12 matrix [N/mm] (dof order: node-major, xyz).
    pub fn rest_stiffness(&self, e: usize) -> SMatrix<f64, 12, 12> {
        self.full_matrix(e, &Matrix3::identity())
    }

    /// Current tangent `K_e = R K0 Rᵀ` as a full 12×12 matrix [N/mm].
    pub fn element_stiffness(&self, e: usize) -> SMatrix<f64, 12, 12> {
        self.full_matrix(e, &self.rotations[e])
    }

    /// Block `(a, b)` of `R K0 Rᵀ` of an element of volume `vol` and Lamé constants `lame`,
    /// from the rotated gradients `h`.
    #[inline(always)]
    fn block(vol: f64, lame: [f64; 2], h: &[Vector3<f64>; 4], a: usize, b: usize) -> Matrix3<f64> {
        let (ha, hb) = (&h[a], &h[b]);
        let l = vol * lame[0];
        let m = vol * lame[1];
        let d = m * ha.dot(hb);
        Matrix3::from_fn(|i, j| {
            l * ha[i] * hb[j] + m * hb[i] * ha[j] + if i == j { d } else { 0.0 }
        })
    }

    fn full_matrix(&self, e: usize, r: &Matrix3<f64>) -> SMatrix<f64, 12, 12> {
        let h = self.grads[e].map(|g| r * g);
        let mut k = SMatrix::<f64, 12, 12>::zeros();
        for &(a, b) in BLOCK_PAIRS.iter() {
            let blk = Self::block(self.volumes[e], self.lame[e], &h, a, b);
            k.fixed_view_mut::<3, 3>(3 * a, 3 * b).copy_from(&blk);
            if a != b {
                k.fixed_view_mut::<3, 3>(3 * b, 3 * a)
                    .copy_from(&blk.transpose());
            }
        }
        k
    }

    /// Deformation gradient `F = D_s D_m⁻¹` of element `e` at positions `x` [mm], computed
    /// as `I + (D_s − D_m) D_m⁻¹`: exactly `I` at the rest positions (`D_m D_m⁻¹` is `I` only
    /// to round-off), so a gel at rest has exactly zero strain and internal force, and a small
    /// strain is not the difference of two numbers near 1.
    #[inline]
    pub fn deformation_gradient(&self, e: usize, x: &[Vector3<f64>]) -> Matrix3<f64> {
        let t = self.tets[e];
        let x0 = x[t[0]];
        let ds = Matrix3::from_columns(&[x[t[1]] - x0, x[t[2]] - x0, x[t[3]] - x0]);
        Matrix3::identity() + (ds - self.dm[e]) * self.dm_inv[e]
    }

    /// Strain state of the mesh at positions `x`: the largest principal strain `|σᵢ(F) − 1|`
    /// over the elements (σ the singular values of the deformation gradient), and how many
    /// elements are inverted (`det F ≤ 0`).
    pub fn strain_stats(&self, x: &[Vector3<f64>]) -> StrainStats {
        let mut out = StrainStats::default();
        for e in 0..self.tets.len() {
            let f = self.deformation_gradient(e, x);
            if !(f.determinant() > 0.0) {
                out.inverted += 1;
            }
            let (smin, smax) = stretch_range(&f);
            for s in [smax, smin] {
                let strain = (s - 1.0).abs();
                if !(strain <= out.max_strain) {
                    out.max_strain = strain;
                    out.element = e;
                }
            }
        }
        out
    }

    /// State of element `e` at positions `x` [mm]: the corotational strain
    /// `ε = sym(Rᵀ F − I)` (`R` the polar rotation of `F`; `I` for [`Kinematics::Linear`]), the
    /// von Mises stress of `σ = λ tr(ε) I + 2μ ε` [MPa], and whether `det F ≤ 0`.
    pub fn element_state(&self, e: usize, x: &[Vector3<f64>]) -> ElementState {
        let f = self.deformation_gradient(e, x);
        let r = if self.is_linear(e) {
            Matrix3::identity()
        } else {
            rotation_from_deformation(&f)
        };
        let (strain, stress) = self.strain_stress(e, &r, &f);
        let dev = stress - Matrix3::identity() * (stress.trace() / 3.0);
        ElementState {
            strain,
            von_mises: (1.5 * dev.norm_squared()).sqrt(),
            inverted: !(f.determinant() > 0.0),
        }
    }

    /// Updates every element rotation from the positions `x` [mm] (no-op for [`Kinematics::Linear`]).
    pub fn update_rotations(&mut self, x: &[Vector3<f64>]) {
        if self.kinematics == Kinematics::Linear {
            return;
        }
        let mut f = [Matrix3::zeros(); POLAR_LANES];
        for e0 in (0..self.tets.len()).step_by(POLAR_LANES) {
            self.update_chunk(e0, x, &mut f, true);
        }
    }

    /// The deformation gradients of elements `e0..e0 + n` (`n` = [`POLAR_LANES`], or fewer at
    /// the end) into `f[..n]` and, when `rotate`, their rotations, computed together
    /// ([`rotations_from_deformations`]). Returns `n`.
    fn update_chunk(
        &mut self,
        e0: usize,
        x: &[Vector3<f64>],
        f: &mut [Matrix3<f64>; POLAR_LANES],
        rotate: bool,
    ) -> usize {
        let n = POLAR_LANES.min(self.tets.len() - e0);
        for (i, fi) in f[..n].iter_mut().enumerate() {
            *fi = self.deformation_gradient(e0 + i, x);
        }
        if rotate {
            let linear = self.linear.get(e0..e0 + n);
            if linear.is_some_and(|l| l.iter().all(|l| *l)) {
                return n;
            }
            rotations_from_deformations(&f[..n], &mut self.rotations[e0..e0 + n]);
            if let Some(l) = linear {
                for (r, _) in (self.rotations[e0..e0 + n].iter_mut())
                    .zip(l)
                    .filter(|(_, l)| **l)
                {
                    *r = Matrix3::identity();
                }
            }
        }
        n
    }

    /// Internal force of element `e` at positions `x` with the current rotation, node-major [N].
    #[inline]
    pub fn element_internal_force(&self, e: usize, x: &[Vector3<f64>]) -> [Vector3<f64>; 4] {
        let r = &self.rotations[e];
        let f = self.deformation_gradient(e, x);
        let (_, sigma) = self.strain_stress(e, r, &f);
        let p = (r * sigma) * self.volumes[e];
        self.grads[e].map(|g| p * g)
    }

    /// The corotated strain `ε = sym(Rᵀ F − I)` and the linear stress `σ = λ tr(ε) I + 2μ ε`
    /// [MPa] of element `e`.
    #[inline(always)]
    fn strain_stress(
        &self,
        e: usize,
        r: &Matrix3<f64>,
        f: &Matrix3<f64>,
    ) -> (Matrix3<f64>, Matrix3<f64>) {
        let [lambda, mu] = self.lame[e];
        let h = r.tr_mul(f) - Matrix3::identity();
        let eps = (h + h.transpose()) * 0.5;
        let sigma = eps * (2.0 * mu) + Matrix3::identity() * (lambda * eps.trace());
        (eps, sigma)
    }

    /// [`CorotationalTetra::update_rotations`] then [`CorotationalTetra::add_internal_forces`]
    /// in one pass over the elements (the deformation gradient computed once per element): the
    /// same rotations and forces, bit for bit.
    pub fn update_rotations_and_add_internal_forces(&mut self, x: &[Vector3<f64>], f: &mut [f64]) {
        let corotational = self.kinematics == Kinematics::Corotational;
        let mut fg = [Matrix3::zeros(); POLAR_LANES];
        for e0 in (0..self.tets.len()).step_by(POLAR_LANES) {
            let n = self.update_chunk(e0, x, &mut fg, corotational);
            for (i, fg) in fg[..n].iter().enumerate() {
                let e = e0 + i;
                let r = &self.rotations[e];
                let (_, sigma) = self.strain_stress(e, r, fg);
                let p = (r * sigma) * self.volumes[e];
                for (a, &n) in self.tets[e].iter().enumerate() {
                    let fa = p * self.grads[e][a];
                    for i in 0..3 {
                        f[3 * n + i] += fa[i];
                    }
                }
            }
        }
    }

    /// Adds the internal forces of all elements at positions `x` to `f` (3 dofs per node) [N].
    pub fn add_internal_forces(&self, x: &[Vector3<f64>], f: &mut [f64]) {
        for e in 0..self.tets.len() {
            let fe = self.element_internal_force(e, x);
            for (a, &n) in self.tets[e].iter().enumerate() {
                for i in 0..3 {
                    f[3 * n + i] += fe[a][i];
                }
            }
        }
    }

    /// Global `(row, col)` dof pairs of element `e`'s [`STIFFNESS_ENTRIES`] entries, in the order
    /// [`CorotationalTetra::assemble`] writes them.
    pub fn stiffness_entry_dofs(&self, e: usize) -> impl Iterator<Item = (usize, usize)> + '_ {
        let t = self.tets[e];
        BLOCK_PAIRS.iter().flat_map(move |&(a, b)| {
            (0..3).flat_map(move |i| {
                (0..3)
                    .filter(move |&j| a != b || i <= j)
                    .map(move |j| (3 * t[a] + i, 3 * t[b] + j))
            })
        })
    }

    /// Writes `scale · R K0 Rᵀ` of every element into `values` through `slots`
    /// (`STIFFNESS_ENTRIES` per element, [`CorotationalTetra::stiffness_entry_dofs`] order;
    /// `u32::MAX` marks an entry to skip, e.g. a Dirichlet dof). Values are added, not overwritten.
    pub fn assemble(&self, slots: &[u32], values: &mut [f64], scale: f64) {
        debug_assert_eq!(slots.len(), STIFFNESS_ENTRIES * self.tets.len());
        for e in 0..self.tets.len() {
            self.assemble_element(e, &self.rotations[e], slots, values, scale);
        }
    }

    /// Adds `scale · R K0_e Rᵀ`, element `e`'s stiffness at rotation `r` (not necessarily its
    /// current one), into `values` through the slots of [`CorotationalTetra::assemble`].
    #[inline(always)]
    pub fn assemble_element(
        &self,
        e: usize,
        r: &Matrix3<f64>,
        slots: &[u32],
        values: &mut [f64],
        scale: f64,
    ) {
        let h = self.grads[e].map(|g| r * g);
        let vol = scale * self.volumes[e];
        let lame = self.lame[e];
        let s = &slots[STIFFNESS_ENTRIES * e..STIFFNESS_ENTRIES * (e + 1)];
        let mut k = 0;
        for &(a, b) in BLOCK_PAIRS.iter() {
            let blk = Self::block(vol, lame, &h, a, b);
            for i in 0..3 {
                for j in 0..3 {
                    if a == b && j < i {
                        continue;
                    }
                    let slot = s[k];
                    k += 1;
                    if slot != u32::MAX {
                        values[slot as usize] += blk[(i, j)];
                    }
                }
            }
        }
    }

    /// Lumped nodal masses `ρ V / 4` summed per node [t] for density `density` [t/mm³].
    pub fn lumped_mass(&self, node_count: usize, density: f64) -> Vec<f64> {
        self.lumped_mass_per_element(node_count, |_| density)
    }

    /// Lumped nodal masses `ρ_e V_e / 4` summed per node [t], element `e` of density
    /// `density(e)` [t/mm³].
    pub fn lumped_mass_per_element(
        &self,
        node_count: usize,
        density: impl Fn(usize) -> f64,
    ) -> Vec<f64> {
        let mut m = vec![0.0; node_count];
        for (e, t) in self.tets.iter().enumerate() {
            let rho = density(e);
            for &n in t {
                m[n] += rho * self.volumes[e] / 4.0;
            }
        }
        m
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::box_mesh;
    use nalgebra::Rotation3;

    /// Deterministic deformation gradients: near identity, repeated and distinct stretches,
    /// rotations, shear, an inverted one.
    fn gradients() -> Vec<Matrix3<f64>> {
        let mut out = vec![
            Matrix3::identity(),
            Matrix3::from_diagonal(&Vector3::new(1.3, 1.3, 0.7)),
            Matrix3::from_diagonal(&Vector3::new(0.5, 2.0, 2.0)),
            Matrix3::from_diagonal(&Vector3::new(1.0 + 1e-9, 1.0, 1.0 - 1e-9)),
            Matrix3::new(1.0, 0.4, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0),
            Matrix3::from_diagonal(&Vector3::new(1.2, 0.9, -0.8)),
        ];
        for k in 0..40 {
            let t = k as f64;
            let r = Rotation3::from_scaled_axis(Vector3::new(0.3 * t, -0.2 * t, 0.1 + 0.05 * t));
            let s = Matrix3::new(
                1.0 + 0.02 * t,
                0.1 * (t * 0.7).sin(),
                0.05,
                0.1 * (t * 0.7).sin(),
                1.0 - 0.01 * t,
                0.2 * (t * 1.3).cos(),
                0.05,
                0.2 * (t * 1.3).cos(),
                0.8 + 0.03 * t,
            );
            out.push(r.matrix() * s);
        }
        out
    }

    #[test]
    fn polar_lanes_are_the_scalar_rotation_bit_for_bit() {
        // Every kind of gradient (fast path, inverted, flat, NaN) in every lane position, and a
        // partial last chunk.
        let mut f = gradients();
        f.push(Matrix3::zeros());
        f.push(Matrix3::from_element(f64::NAN));
        f.push(Matrix3::new(1.0, 2.0, 3.0, 2.0, 4.0, 6.0, 0.0, 0.0, 1e-30));
        for k in 0..23 {
            let t = k as f64;
            f.push(
                Matrix3::identity() * (1.0 + 1e-4 * t)
                    + Matrix3::new(0.0, 1e-3 * t, 0.0, -2e-5 * t, 0.0, 0.3, 0.0, 0.0, 0.0),
            );
        }
        for shift in 0..POLAR_LANES {
            let f = &f[shift..];
            let mut lanes = vec![Matrix3::zeros(); f.len()];
            rotations_from_deformations(f, &mut lanes);
            for (g, r) in f.iter().zip(&lanes) {
                let scalar = rotation_from_deformation(g);
                let same = scalar
                    .iter()
                    .zip(r.iter())
                    .all(|(a, b)| a.to_bits() == b.to_bits());
                assert!(same, "{g}: {r} vs {scalar}");
            }
        }
    }

    #[test]
    fn stretch_range_matches_the_svd() {
        for f in gradients() {
            let sv = f.singular_values();
            let (lo, hi) = stretch_range(&f);
            let (min, max) = (sv.min(), sv.max());
            let scale = f.norm().max(1.0);
            assert!((lo - min).abs() <= 1e-8 * scale, "{f}: {lo} vs {min}");
            assert!((hi - max).abs() <= 1e-8 * scale, "{f}: {hi} vs {max}");
        }
        let nan = Matrix3::from_element(f64::NAN);
        assert!(stretch_range(&nan).1.is_nan());
    }

    #[test]
    fn fused_element_update_is_the_two_passes_bit_for_bit() {
        let mesh = box_mesh(Vector3::zeros(), Vector3::new(10.0, 8.0, 6.0), 120);
        let material = Elasticity {
            young_modulus: 0.005,
            poisson_ratio: 0.45,
        };
        // A deformed state: a twist and a stretch growing along x, plus a shear.
        let x: Vec<Vector3<f64>> = mesh
            .nodes
            .iter()
            .map(|p| {
                let a = 0.05 * p.x;
                let r = Rotation3::from_axis_angle(&Vector3::x_axis(), a);
                r * Vector3::new(p.x * 1.1 + 0.1 * p.z, p.y, p.z * 0.95)
            })
            .collect();
        for kin in [Kinematics::Corotational, Kinematics::Linear] {
            let mut two = CorotationalTetra::try_new(&mesh, &material, kin).unwrap();
            let mut one = CorotationalTetra::try_new(&mesh, &material, kin).unwrap();
            let n = 3 * mesh.nodes.len();
            let (mut f2, mut f1) = (vec![0.0; n], vec![0.0; n]);
            two.update_rotations(&x);
            two.add_internal_forces(&x, &mut f2);
            one.update_rotations_and_add_internal_forces(&x, &mut f1);
            assert_eq!(one.rotations(), two.rotations());
            assert!(f1.iter().zip(&f2).all(|(a, b)| a.to_bits() == b.to_bits()));
            assert!(f1.iter().any(|v| v.abs() > 0.0));
        }
    }
    /// Elements kept linear (`keep_linear`) have the identity rotation and the forces of a
    /// [`Kinematics::Linear`] mesh, bit for bit, in both element passes and in
    /// `element_state`; the others keep the corotational mesh's rotations, forces and states.
    /// Chunks of every kind (all linear, none, mixed) are covered.
    #[test]
    fn kept_linear_elements_move_as_a_linear_mesh_and_the_others_as_a_corotational_one() {
        let mesh = box_mesh(Vector3::zeros(), Vector3::new(10.0, 8.0, 6.0), 120);
        let material = Elasticity {
            young_modulus: 0.005,
            poisson_ratio: 0.45,
        };
        // A large rigid turn about x growing along x, a stretch and a shear.
        let x: Vec<Vector3<f64>> = (mesh.nodes.iter())
            .map(|p| {
                let r = Rotation3::from_axis_angle(&Vector3::x_axis(), 0.05 * p.x);
                r * Vector3::new(p.x * 1.1 + 0.1 * p.z, p.y, p.z * 0.95)
            })
            .collect();
        let m = mesh.tets.len();
        // Elements 0..8 linear (a whole chunk), 8..16 corotational, then every third.
        let linear: Vec<bool> = (0..m).map(|e| e < 8 || (e >= 16 && e % 3 == 0)).collect();
        let mut mixed =
            CorotationalTetra::try_new(&mesh, &material, Kinematics::Corotational).unwrap();
        mixed.keep_linear(linear.clone()).unwrap();
        let corot = CorotationalTetra::try_new(&mesh, &material, Kinematics::Corotational).unwrap();
        let lin = CorotationalTetra::try_new(&mesh, &material, Kinematics::Linear).unwrap();
        let (mut corot, mut lin) = (corot, lin);
        corot.update_rotations(&x);
        lin.update_rotations(&x);
        let mut two = mixed.clone();
        two.update_rotations(&x);
        let n = 3 * mesh.nodes.len();
        let mut fused = vec![0.0; n];
        mixed.update_rotations_and_add_internal_forces(&x, &mut fused);
        assert_eq!(mixed.rotations(), two.rotations());
        let mut turned = 0;
        for (e, &kept) in linear.iter().enumerate() {
            let of = if kept { &lin } else { &corot };
            assert_eq!(mixed.rotation(e), of.rotation(e), "element {e}");
            let bits = |f: [Vector3<f64>; 4]| f.map(|v| v.map(f64::to_bits));
            assert_eq!(
                bits(mixed.element_internal_force(e, &x)),
                bits(of.element_internal_force(e, &x)),
                "element {e}"
            );
            assert_eq!(mixed.element_state(e, &x), of.element_state(e, &x));
            if !kept && (corot.rotation(e) - Matrix3::identity()).norm() > 0.1 {
                turned += 1;
            }
        }
        assert!(
            turned > 0,
            "no corotational element turned: the test is void"
        );
        // The fused pass sums the same element forces as the separate one.
        let mut separate = vec![0.0; n];
        two.add_internal_forces(&x, &mut separate);
        assert!(
            fused
                .iter()
                .zip(&separate)
                .all(|(a, b)| a.to_bits() == b.to_bits())
        );
        // A flag per element, or an error naming what is wrong.
        assert!(matches!(
            mixed.keep_linear(vec![true; m - 1]),
            Err(FemError::DimensionMismatch { .. })
        ));
    }
}

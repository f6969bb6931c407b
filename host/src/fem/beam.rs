//! Corotational 3-D Euler–Bernoulli beams for the needle: 2 nodes, 6 dofs per node
//! (translation [mm], rotation increment [rad]), node orientations as unit quaternions.
//!
//! **Kinematics (element-independent corotational formulation, Battini & Pacoste 2002).** Each
//! node `i` carries a rotation `R_i` (world ← node material frame). Per element and end, a
//! constant offset `C_i` maps the node frame onto the element's rest frame, so the current
//! end frames are `T_i = R_i C_i`. The corotated element frame `E = [e₁ e₂ e₃]` has
//! `e₁ = (x₂ − x₁)/ℓ`, `e₃ ∥ e₁ × ½(T₁ ê₂ + T₂ ê₂)`, `e₂ = e₃ × e₁`. The local deformational
//! rotations are `θ̄_i = log(Eᵀ T_i)` (evaluated as `v · asin|v|/|v|` with `v = vee(skew(Eᵀ T_i))`,
//! the series truncated after `|v|⁸`: relative error < 1e-8 for local rotations below 10°;
//! corotational elements keep them small), the local elongation is `ℓ − ℓ₀`.
//!
//! **Energy.** `Π = EA (ℓ−ℓ₀)²/(2ℓ₀) + GJ (θ̄₂ₓ−θ̄₁ₓ)²/(2ℓ₀)
//!   + Σ_{k=y,z} (EI_k/ℓ₀)(2θ̄₁ₖ² + 2θ̄₁ₖθ̄₂ₖ + 2θ̄₂ₖ²)` — the classic linear local beam.
//!
//! **Dofs and increments.** Rotation increments are world-frame rotation vectors applied as
//! `q ← exp(Δθ/2) ⊗ q` (left multiplication, i.e. `R ← exp([Δθ]×) R`). The internal force is
//! the gradient of `Π` with respect to `(Δx₁, Δθ₁, Δx₂, Δθ₂)` at zero (forces [N] and moments
//! [N·mm] in the world frame).
//!
//! **Tangent.** Force and Hessian are obtained *exactly* by second-order forward-mode automatic
//! differentiation of `Π` (hyper-dual numbers on the 9 variables `Δx₂ − Δx₁, Δθ₁, Δθ₂`, with
//! `exp([Δθ]×) = I + [Δθ]× + ½[Δθ]×²`, exact to second order) — no hand-derived `B`, `G`, `P`
//! matrices to get wrong, and no finite differences. The Hessian `H` is symmetric; the exact
//! derivative of the internal force under the multiplicative update is
//! `K = H − ½ [m_i]×` on each node's rotational diagonal block (`m_i` the internal moment),
//! from `log(exp(ω) exp(η)) = ω + η + ½ ω × η + …`. [`CorotationalBeams::element_tangent`]
//! returns that exact `K`; the assembled system uses its symmetric part `H` (the skew term is
//! the usual non-symmetric part of spin-variable tangents, which a Cholesky solver cannot take;
//! it vanishes for planar bending and Newton still converges fast).

// Negated comparisons are deliberate: NaN must fail every validity check.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::nonminimal_bool)]

use super::hyperdual::{self, Ad, D1, Hd, V3};
use super::{Elasticity, FemError};
use nalgebra::{Matrix3, SMatrix, SVector, UnitQuaternion, Vector3};

/// Number of distinct entries of a symmetric 12×12 beam matrix written by assembly (upper triangle).
pub const STIFFNESS_ENTRIES: usize = 78;

/// Solid or hollow circular cross-section and material of the needle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BeamSection {
    /// Elastic constants (E [MPa], ν).
    pub elasticity: Elasticity,
    /// Outer diameter [mm].
    pub outer_diameter: f64,
    /// Inner diameter [mm] (0 for a solid section).
    pub inner_diameter: f64,
    /// Density [t/mm³] (steel: 7.85e-9).
    pub density: f64,
}

impl BeamSection {
    /// Cross-section area [mm²].
    pub fn area(&self) -> f64 {
        std::f64::consts::PI / 4.0 * (self.outer_diameter.powi(2) - self.inner_diameter.powi(2))
    }

    /// Second moment of area about a diameter [mm⁴].
    pub fn second_moment(&self) -> f64 {
        std::f64::consts::PI / 64.0 * (self.outer_diameter.powi(4) - self.inner_diameter.powi(4))
    }

    /// Polar moment (torsion constant of a circular section) [mm⁴].
    pub fn polar_moment(&self) -> f64 {
        2.0 * self.second_moment()
    }

    /// Bending stiffness EI [N·mm²].
    pub fn bending_stiffness(&self) -> f64 {
        self.elasticity.young_modulus * self.second_moment()
    }

    /// Checks the constants.
    ///
    /// # Errors
    /// [`FemError::Material`] naming the bad constant.
    pub fn validate(&self) -> Result<(), FemError> {
        self.elasticity.validate()?;
        if !(self.outer_diameter > 0.0 && self.outer_diameter.is_finite()) {
            return Err(FemError::Material {
                what: "outer diameter must be positive",
            });
        }
        if !(self.inner_diameter >= 0.0 && self.inner_diameter < self.outer_diameter) {
            return Err(FemError::Material {
                what: "inner diameter must lie in [0, outer diameter)",
            });
        }
        if !(self.density >= 0.0 && self.density.is_finite()) {
            return Err(FemError::Material {
                what: "density must be non-negative",
            });
        }
        Ok(())
    }
}

/// Per-element result of an energy evaluation.
#[derive(Clone, Copy, Debug)]
pub struct BeamElementState {
    /// Element strain energy [N·mm].
    pub energy: f64,
    /// Internal force `∂Π/∂d`, dof order `[x₁, θ₁, x₂, θ₂]` [N, N·mm].
    pub force: SVector<f64, 12>,
    /// Symmetric Hessian `∂²Π/∂d²` (the assembled tangent by default) [N/mm, N, N·mm/rad];
    /// zero from [`CorotationalBeams::element_state_material`].
    pub hessian: SMatrix<f64, 12, 12>,
    /// Material part of the Hessian, `Bᵀ K_l B` with `B = ∂u/∂d` the derivative of the local
    /// deformations `u` and `K_l` the linear local beam stiffness: the corotational stiffness
    /// `R K0 Rᵀ` of the paper's eq. 1, without the geometric (initial-stress) terms. Positive
    /// semi-definite whatever the stress state.
    pub material: SMatrix<f64, 12, 12>,
}

/// The needle's beam elements: connectivity, rest data and the section constants.
#[derive(Clone, Debug)]
pub struct CorotationalBeams {
    elements: Vec<[usize; 2]>,
    rest_length: Vec<f64>,
    /// Node frame → element rest frame, per element end.
    offsets: Vec<[Matrix3<f64>; 2]>,
    ea: f64,
    gj: f64,
    ei: f64,
    section: BeamSection,
    states: Vec<BeamElementState>,
    geometric_stiffness: bool,
}

/// `d` index (0..12) → (`z` index, sign) with `z = [Δx₂ − Δx₁, Δθ₁, Δθ₂]`.
fn z_of_d(j: usize) -> (usize, f64) {
    match j {
        0..=2 => (j, -1.0),
        3..=5 => (j, 1.0),
        6..=8 => (j - 6, 1.0),
        _ => (j - 3, 1.0),
    }
}

fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

impl CorotationalBeams {
    /// Builds the elements from the rest configuration: node positions `x` [mm], node
    /// orientations `q` (world ← node frame) and 2-node connectivity.
    ///
    /// The element rest frame has `e₁` along the element and `e₂` the component of node 1's
    /// frame y axis orthogonal to `e₁` (any orthogonal axis if they are parallel).
    ///
    /// # Errors
    /// [`FemError::Material`] for a bad section, [`FemError::Parameter`] for a zero-length
    /// element or an out-of-range node index.
    pub fn try_new(
        x: &[Vector3<f64>],
        q: &[UnitQuaternion<f64>],
        elements: Vec<[usize; 2]>,
        section: BeamSection,
    ) -> Result<Self, FemError> {
        section.validate()?;
        if x.len() != q.len() {
            return Err(FemError::DimensionMismatch {
                what: "node orientations",
                expected: x.len(),
                got: q.len(),
            });
        }
        let mut rest_length = Vec::with_capacity(elements.len());
        let mut offsets = Vec::with_capacity(elements.len());
        for &[a, b] in &elements {
            if a >= x.len() || b >= x.len() || a == b {
                return Err(FemError::Parameter {
                    what: "beam element node index out of range or repeated",
                });
            }
            let d = x[b] - x[a];
            let l = d.norm();
            if !(l > 0.0 && l.is_finite()) {
                return Err(FemError::Parameter {
                    what: "beam element of zero length",
                });
            }
            let e1 = d / l;
            let ra = q[a].to_rotation_matrix().into_inner();
            let rb = q[b].to_rotation_matrix().into_inner();
            let mut y = ra.column(1).into_owned();
            y -= e1 * e1.dot(&y);
            if y.norm() < 1e-8 {
                let a = if e1.x.abs() < 0.9 {
                    Vector3::x()
                } else {
                    Vector3::y()
                };
                y = a - e1 * e1.dot(&a);
            }
            let e2 = y.normalize();
            let e0 = Matrix3::from_columns(&[e1, e2, e1.cross(&e2)]);
            rest_length.push(l);
            offsets.push([ra.transpose() * e0, rb.transpose() * e0]);
        }
        let e = section.elasticity.young_modulus;
        let n = elements.len();
        let zero = BeamElementState {
            energy: 0.0,
            force: SVector::zeros(),
            hessian: SMatrix::zeros(),
            material: SMatrix::zeros(),
        };
        Ok(Self {
            elements,
            rest_length,
            offsets,
            ea: e * section.area(),
            gj: section.elasticity.shear_modulus() * section.polar_moment(),
            ei: e * section.second_moment(),
            section,
            states: vec![zero; n],
            geometric_stiffness: true,
        })
    }

    /// Number of elements.
    pub fn len(&self) -> usize {
        self.elements.len()
    }

    /// Whether there is no element.
    pub fn is_empty(&self) -> bool {
        self.elements.is_empty()
    }

    /// Node pairs of the elements.
    pub fn elements(&self) -> &[[usize; 2]] {
        &self.elements
    }

    /// Rest length of element `e` [mm].
    pub fn rest_length(&self, e: usize) -> f64 {
        self.rest_length[e]
    }

    /// The section.
    pub fn section(&self) -> &BeamSection {
        &self.section
    }

    /// The corotational kinematics of element `e` as hyperdual functions of its 9 variables
    /// (relative translation, rotation of each end): the current length [mm] and the local end
    /// rotations `θ_1`, `θ_2` [rad] in the corotated frame.
    fn local_kinematics<T: Ad>(
        &self,
        e: usize,
        x: &[Vector3<f64>],
        q: &[UnitQuaternion<f64>],
    ) -> (T, [V3<T>; 2]) {
        let [a, b] = self.elements[e];
        let d0 = x[b] - x[a];
        let ends = [
            q[a].to_rotation_matrix().into_inner() * self.offsets[e][0],
            q[b].to_rotation_matrix().into_inner() * self.offsets[e][1],
        ];
        // Variables: z0..3 relative translation, z3..6 rotation of end 1, z6..9 rotation of end 2.
        let d: V3<T> = std::array::from_fn(|i| T::var(d0[i], i));
        // T_i(ω) = (I + W + ½W²) A_i, column by column, at ω = 0 with its exact derivatives.
        let t: [[V3<T>; 3]; 2] = std::array::from_fn(|i| {
            std::array::from_fn(|k| {
                let col = ends[i].column(k);
                hyperdual::rotated_column(&[col[0], col[1], col[2]], 3 + 3 * i)
            })
        });
        let l2 = hyperdual::dot(&d, &d);
        let l = l2.sqrt();
        let inv_l = l.recip();
        let e1 = hyperdual::scale(&d, inv_l);
        let p = hyperdual::scale_f(&hyperdual::add(&t[0][1], &t[1][1]), 0.5);
        let r3u = hyperdual::cross(&e1, &p);
        let r3 = hyperdual::scale(&r3u, hyperdual::dot(&r3u, &r3u).sqrt().recip());
        let r2 = hyperdual::cross(&r3, &e1);
        let frame = [e1, r2, r3];
        let theta: [V3<T>; 2] = std::array::from_fn(|i| {
            // `t[i]` depends on end i's rotation variables alone.
            let rb = |r: usize, c: usize| hyperdual::dot_local(&frame[r], &t[i][c], 3 + 3 * i);
            let v: V3<T> = [
                (rb(2, 1) - rb(1, 2)) * 0.5,
                (rb(0, 2) - rb(2, 0)) * 0.5,
                (rb(1, 0) - rb(0, 1)) * 0.5,
            ];
            // asin(s)/s as a series in t = s²: 1 + t/6 + 3t²/40 + 5t³/112 + 35t⁴/1152.
            let tt = hyperdual::dot(&v, &v);
            let g = ((((tt * (35.0 / 1152.0)) + 5.0 / 112.0) * tt + 3.0 / 40.0) * tt + 1.0 / 6.0)
                * tt
                + 1.0;
            hyperdual::scale(&v, g)
        });
        (l, theta)
    }

    /// The energy and the local deformations `u = (Δℓ, twist, θ̄₁y, θ̄₂y, θ̄₁z, θ̄₂z)` of element
    /// `e` as functions of its 9 variables, to the order `T` carries.
    fn energy_and_deformations<T: Ad>(
        &self,
        e: usize,
        x: &[Vector3<f64>],
        q: &[UnitQuaternion<f64>],
    ) -> (T, [T; 6]) {
        let (l, theta) = self.local_kinematics::<T>(e, x, q);
        let l0 = self.rest_length[e];
        let du = l + (-l0);
        let tw = theta[1][0] - theta[0][0];
        let mut energy = du * du * (0.5 * self.ea / l0) + tw * tw * (0.5 * self.gj / l0);
        for (&t1, &t2) in theta[0].iter().zip(&theta[1]).skip(1) {
            energy = energy + (t1 * t1 + t1 * t2 + t2 * t2) * (2.0 * self.ei / l0);
        }
        let u = [du, tw, theta[0][1], theta[1][1], theta[0][2], theta[1][2]];
        (energy, u)
    }

    /// Internal force `∂Π/∂d` and material stiffness `Bᵀ K_l B` from the energy and the local
    /// deformations (their gradients).
    fn force_and_material<T: Ad>(
        &self,
        e: usize,
        energy: &T,
        u: &[T; 6],
    ) -> (SVector<f64, 12>, SMatrix<f64, 12, 12>) {
        // Material stiffness Bᵀ K_l B over the local deformations u.
        let l0 = self.rest_length[e];
        let kb = self.ei / l0;
        let mut kl = SMatrix::<f64, 6, 6>::zeros();
        kl[(0, 0)] = self.ea / l0;
        kl[(1, 1)] = self.gj / l0;
        for o in [2, 4] {
            kl[(o, o)] = 4.0 * kb;
            kl[(o + 1, o + 1)] = 4.0 * kb;
            kl[(o, o + 1)] = 2.0 * kb;
            kl[(o + 1, o)] = 2.0 * kb;
        }
        let mut bz = SMatrix::<f64, 6, 9>::zeros();
        for (k, uk) in u.iter().enumerate() {
            for z in 0..9 {
                bz[(k, z)] = uk.grad()[z];
            }
        }
        let kz = bz.transpose() * kl * bz;
        let mut force = SVector::<f64, 12>::zeros();
        let mut material = SMatrix::<f64, 12, 12>::zeros();
        for i in 0..12 {
            let (zi, si) = z_of_d(i);
            force[i] = si * energy.grad()[zi];
            for j in 0..12 {
                let (zj, sj) = z_of_d(j);
                material[(i, j)] = si * sj * kz[(zi, zj)];
            }
        }
        (force, material)
    }

    /// Energy, internal force and symmetric Hessian of element `e` at node positions `x` [mm]
    /// and orientations `q`.
    pub fn element_state(
        &self,
        e: usize,
        x: &[Vector3<f64>],
        q: &[UnitQuaternion<f64>],
    ) -> BeamElementState {
        let (energy, u) = self.energy_and_deformations::<Hd>(e, x, q);
        let (force, material) = self.force_and_material(e, &energy, &u);
        let mut hessian = SMatrix::<f64, 12, 12>::zeros();
        for i in 0..12 {
            let (zi, si) = z_of_d(i);
            for j in 0..12 {
                let (zj, sj) = z_of_d(j);
                hessian[(i, j)] = si * sj * energy.hess(zi, zj);
            }
        }
        BeamElementState {
            energy: energy.v,
            force,
            hessian,
            material,
        }
    }

    /// [`CorotationalBeams::element_state`] without the Hessian (left zero): energy, force and
    /// material stiffness bit for bit the same, by first-order differentiation (dual numbers
    /// without the Hessian), at a sixth of the derivative entries. What a step needs when it
    /// assembles the material stiffness alone.
    pub fn element_state_material(
        &self,
        e: usize,
        x: &[Vector3<f64>],
        q: &[UnitQuaternion<f64>],
    ) -> BeamElementState {
        let (energy, u) = self.energy_and_deformations::<D1>(e, x, q);
        let (force, material) = self.force_and_material(e, &energy, &u);
        BeamElementState {
            energy: energy.v,
            force,
            hessian: SMatrix::zeros(),
            material,
        }
    }

    /// The largest bending strain at the needle's outer surface, `r_o |κ|`, over the elements'
    /// ends at positions `x` and orientations `q`, and the node (element end) where it is [-]. Within an
    /// element the linear local beam's curvature varies linearly, from `(4θ̄₁ + 2θ̄₂)/ℓ₀` at its
    /// first end to `(2θ̄₁ + 4θ̄₂)/ℓ₀` at its second in each bending plane (`θ̄ᵢ` the local end
    /// rotations of the corotated frame; a circular arc has `θ̄₁ = −θ̄₂` and both ends the same
    /// curvature), so its ends hold its largest. Axial and torsional strain are left out: a
    /// needle steered through gel is strained by bending.
    pub fn max_bending_strain(
        &self,
        x: &[Vector3<f64>],
        q: &[UnitQuaternion<f64>],
    ) -> (f64, usize) {
        let strains = self.bending_strains(x, q);
        let mut largest = (0.0, 0);
        for (node, &strain) in strains.iter().enumerate() {
            if strain > largest.0 || (strain.is_nan() && !largest.0.is_nan()) {
                largest = (strain, node);
            }
        }
        largest
    }

    /// The bending strain at the needle's outer surface at each node: the largest of its
    /// elements' ends there ([`Self::max_bending_strain`]; NaN where one is NaN) [-].
    pub fn bending_strains(&self, x: &[Vector3<f64>], q: &[UnitQuaternion<f64>]) -> Vec<f64> {
        let r_o = self.outer_radius();
        let mut strains = vec![0.0; x.len()];
        for e in 0..self.elements.len() {
            let (_, theta) = self.local_kinematics::<D1>(e, x, q);
            let l0 = self.rest_length[e];
            let end = |a: usize, b: usize| {
                let ky = (4.0 * theta[a][1].v + 2.0 * theta[b][1].v) / l0;
                let kz = (4.0 * theta[a][2].v + 2.0 * theta[b][2].v) / l0;
                r_o * ky.hypot(kz)
            };
            for (a, b) in [(0, 1), (1, 0)] {
                let strain = end(a, b);
                let s = &mut strains[self.elements[e][a]];
                if strain > *s || (strain.is_nan() && !s.is_nan()) {
                    *s = strain;
                }
            }
        }
        strains
    }

    /// The needle's outer radius [mm].
    pub fn outer_radius(&self) -> f64 {
        0.5 * self.section.outer_diameter
    }

    /// The rest length of the elements beyond `node` [mm]: for a chain numbered from the base
    /// (node 0) to the tip, the distance of `node` from the tip along the needle at rest.
    pub fn rest_length_beyond(&self, node: usize) -> f64 {
        self.elements
            .iter()
            .zip(&self.rest_length)
            .filter(|(e, _)| e[0].min(e[1]) >= node)
            .map(|(_, l)| l)
            .sum()
    }

    /// Exact tangent of element `e`: the derivative of its internal force under the
    /// multiplicative rotation update, `H − ½[m_i]×` on the rotational diagonal blocks (not
    /// symmetric away from `m = 0`).
    pub fn element_tangent(
        &self,
        e: usize,
        x: &[Vector3<f64>],
        q: &[UnitQuaternion<f64>],
    ) -> SMatrix<f64, 12, 12> {
        let s = self.element_state(e, x, q);
        let mut k = s.hessian;
        for off in [3, 9] {
            let m = Vector3::new(s.force[off], s.force[off + 1], s.force[off + 2]);
            let c = skew(&m) * 0.5;
            let mut blk = k.fixed_view_mut::<3, 3>(off, off);
            blk -= c;
        }
        k
    }

    /// Evaluates and caches every element's force and Hessian at `x`, `q` (without the geometric
    /// stiffness, [`CorotationalBeams::set_geometric_stiffness`], the Hessian is not computed and
    /// its cache holds zeros); returns the total strain energy [N·mm].
    pub fn update(&mut self, x: &[Vector3<f64>], q: &[UnitQuaternion<f64>]) -> f64 {
        let mut total = 0.0;
        for e in 0..self.elements.len() {
            // The Hessian only where the assembly uses it.
            let s = if self.geometric_stiffness {
                self.element_state(e, x, q)
            } else {
                self.element_state_material(e, x, q)
            };
            total += s.energy;
            self.states[e] = s;
        }
        total
    }

    /// Adds the cached internal forces (from [`CorotationalBeams::update`]) to `f`
    /// (6 dofs per node: force [N], moment [N·mm]).
    pub fn add_internal_forces(&self, f: &mut [f64]) {
        for (e, &[a, b]) in self.elements.iter().enumerate() {
            let fe = &self.states[e].force;
            for i in 0..6 {
                f[6 * a + i] += fe[i];
                f[6 * b + i] += fe[6 + i];
            }
        }
    }

    /// Global dof of element-local dof `i` (0..12) of element `e`.
    fn global_dof(&self, e: usize, i: usize) -> usize {
        let [a, b] = self.elements[e];
        if i < 6 { 6 * a + i } else { 6 * b + i - 6 }
    }

    /// Global `(row, col)` dof pairs of element `e`'s [`STIFFNESS_ENTRIES`] entries (upper
    /// triangle of the local matrix, row-major), in the order [`CorotationalBeams::assemble`] writes them.
    pub fn stiffness_entry_dofs(&self, e: usize) -> impl Iterator<Item = (usize, usize)> + '_ {
        (0..12)
            .flat_map(move |i| (i..12).map(move |j| (self.global_dof(e, i), self.global_dof(e, j))))
    }

    /// Whether [`CorotationalBeams::assemble`] includes the geometric (initial-stress) terms
    /// (default) or only the material stiffness `Bᵀ K_l B` (the paper's corotational `R K0 Rᵀ`).
    ///
    /// The simulation uses the material stiffness: the needle floats on its base constraint, so
    /// its `K` is regularised only by a tiny `M/h²`, and under compression (the tip pushing on
    /// the gel) the geometric terms make `K + M/h²` indefinite along the rigid modes — the
    /// Cholesky factorisation fails although the constrained system is stable. The internal
    /// forces stay exact, so equilibrium is unchanged; only the Newton step is less than quadratic.
    pub fn set_geometric_stiffness(&mut self, on: bool) {
        self.geometric_stiffness = on;
    }

    /// Adds `scale ·` the cached symmetric Hessians (or their material parts, see
    /// [`CorotationalBeams::set_geometric_stiffness`]) into `values` through `slots`
    /// (`u32::MAX` = skip).
    pub fn assemble(&self, slots: &[u32], values: &mut [f64], scale: f64) {
        debug_assert_eq!(slots.len(), STIFFNESS_ENTRIES * self.elements.len());
        for e in 0..self.elements.len() {
            let h = if self.geometric_stiffness {
                &self.states[e].hessian
            } else {
                &self.states[e].material
            };
            let s = &slots[STIFFNESS_ENTRIES * e..STIFFNESS_ENTRIES * (e + 1)];
            let mut k = 0;
            for i in 0..12 {
                for j in i..12 {
                    let slot = s[k];
                    k += 1;
                    if slot != u32::MAX {
                        values[slot as usize] += scale * h[(i, j)];
                    }
                }
            }
        }
    }

    /// Lumped mass per node: translational `ρAℓ/2` [t] and isotropic rotary inertia
    /// `ρ(I_y + I_z)ℓ/2` [t·mm²] summed over the elements at each node.
    pub fn lumped_mass(&self, node_count: usize) -> (Vec<f64>, Vec<f64>) {
        let mut m = vec![0.0; node_count];
        let mut j = vec![0.0; node_count];
        let rho = self.section.density;
        for (e, &[a, b]) in self.elements.iter().enumerate() {
            let l = self.rest_length[e];
            for n in [a, b] {
                m[n] += rho * self.section.area() * l / 2.0;
                j[n] += rho * self.section.polar_moment() * l / 2.0;
            }
        }
        (m, j)
    }
}

//! The needle: corotational beams, 6 dofs per node (translation [mm], world rotation increment
//! [rad]), node orientations as unit quaternions.

use super::{Elements, FeModel, ModelLayout};
use crate::fem::FemError;
use crate::fem::beam::{BeamSection, CorotationalBeams};
use crate::linalg::Precision;
use nalgebra::{Isometry3, Matrix3, UnitQuaternion, Vector3};

/// Parameters of the needle model.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NeedleParams {
    /// Section and material.
    pub section: BeamSection,
    /// Pseudo time step `h` [s] of the `M/h²` regularisation; required when no node is fixed.
    pub time_step: Option<f64>,
    /// Refactorise the matrix every this many steps (1 = every step).
    pub refactor_every: usize,
}

/// The needle's elements: corotational beams and the node orientations.
#[derive(Debug)]
pub struct Beams {
    beams: CorotationalBeams,
    orientations: Vec<UnitQuaternion<f64>>,
}

impl Elements for Beams {
    const NODE_DOFS: usize = 6;

    fn add_internal_forces(&mut self, positions: &[Vector3<f64>], f_int: &mut [f64]) {
        self.beams.update(positions, &self.orientations);
        self.beams.add_internal_forces(f_int);
    }

    fn entry_dofs(&self) -> impl Iterator<Item = (usize, usize)> + '_ {
        (0..self.beams.len()).flat_map(|e| self.beams.stiffness_entry_dofs(e))
    }

    fn assemble(&self, slots: &[u32], values: &mut [f64]) {
        self.beams.assemble(slots, values, 1.0);
    }

    /// `x_i += Δx_i`, `q_i ← exp(Δθ_i/2) ⊗ q_i` (world-frame rotation vector, left
    /// multiplication).
    fn displace(
        &mut self,
        positions: &mut [Vector3<f64>],
        dx: &[f64],
        free: &dyn Fn(usize) -> bool,
    ) {
        for (i, (p, o)) in positions.iter_mut().zip(&mut self.orientations).enumerate() {
            let mut t = Vector3::zeros();
            let mut w = Vector3::zeros();
            for k in 0..3 {
                if free(6 * i + k) {
                    t[k] = dx[6 * i + k];
                }
                if free(6 * i + 3 + k) {
                    w[k] = dx[6 * i + 3 + k];
                }
            }
            *p += t;
            let q = UnitQuaternion::from_scaled_axis(w) * *o;
            *o = UnitQuaternion::new_normalize(q.into_inner());
        }
    }
}

/// The needle: corotational beams, node orientations as unit quaternions, and its system.
pub type NeedleModel = FeModel<Beams>;

impl FeModel<Beams> {
    /// A straight needle of `length` [mm] with `elements` equal beams, starting at the base frame
    /// origin and pointing along its x axis; every node has the base orientation. Node 0 is the
    /// base, the last node the tip. `fixed_nodes` are clamped (all 6 dofs), e.g. `&[0]` for a
    /// cantilever.
    ///
    /// # Errors
    /// See [`NeedleModel::try_new`].
    pub fn straight(
        base: &Isometry3<f64>,
        length: f64,
        elements: usize,
        fixed_nodes: &[usize],
        params: &NeedleParams,
    ) -> Result<Self, FemError> {
        if elements == 0 || !(length > 0.0 && length.is_finite()) {
            return Err(FemError::Parameter {
                what: "needle needs a positive length and at least one element",
            });
        }
        let x = (0..=elements)
            .map(|i| base * nalgebra::Point3::new(length * i as f64 / elements as f64, 0.0, 0.0))
            .map(|p| p.coords)
            .collect();
        let q = vec![base.rotation; elements + 1];
        let conn = (0..elements).map(|i| [i, i + 1]).collect();
        Self::try_new(x, q, conn, fixed_nodes, params)
    }

    /// Builds the model from rest node positions [mm], orientations and 2-node elements.
    ///
    /// # Errors
    /// Invalid section or geometry, fixed node out of range, or a free-floating needle without
    /// regularisation (`time_step` and a positive density are then required).
    pub fn try_new(
        positions: Vec<Vector3<f64>>,
        orientations: Vec<UnitQuaternion<f64>>,
        elements: Vec<[usize; 2]>,
        fixed_nodes: &[usize],
        params: &NeedleParams,
    ) -> Result<Self, FemError> {
        let beams =
            CorotationalBeams::try_new(&positions, &orientations, elements, params.section)?;
        let n = positions.len();
        let regularization = match params.time_step {
            None => {
                if fixed_nodes.is_empty() {
                    return Err(FemError::Parameter {
                        what: "a needle without fixed node needs a time step (its stiffness alone is singular)",
                    });
                }
                vec![0.0; 6 * n]
            }
            Some(h) => {
                if !(h > 0.0 && h.is_finite()) {
                    return Err(FemError::Parameter {
                        what: "needle time step must be positive",
                    });
                }
                if fixed_nodes.is_empty() && !(params.section.density > 0.0) {
                    return Err(FemError::Parameter {
                        what: "a free-floating needle needs a positive density",
                    });
                }
                let (m, j) = beams.lumped_mass(n);
                (0..6 * n)
                    .map(|g| if g % 6 < 3 { m[g / 6] } else { j[g / 6] } / (h * h))
                    .collect()
            }
        };
        Self::build(
            Beams {
                beams,
                orientations,
            },
            positions,
            ModelLayout {
                fixed_nodes,
                regularization,
                refactor_every: params.refactor_every,
                dof_coords: None,
                background: false,
                asynchronous: false,
                pcg: None,
                refine: None,
                refresh: None,
                // The beams' matrix spans stiffnesses far apart (axial, bending, M/h²): in
                // f32 it is not numerically positive definite. It is small: always f64.
                precision: Precision::Double,
                near: None,
            },
        )
    }

    /// Node orientations (world ← node frame; the node x axis is the needle axis at rest).
    pub fn orientations(&self) -> &[UnitQuaternion<f64>] {
        &self.elements.orientations
    }

    /// Orientation of node `i` as a rotation matrix (node frame → world).
    pub fn rotation(&self, node: usize) -> Matrix3<f64> {
        self.elements.orientations[node]
            .to_rotation_matrix()
            .into_inner()
    }

    /// The needle's axis in a node's own frame: the beams run along their local x.
    pub fn axis(&self) -> Vector3<f64> {
        Vector3::x()
    }

    /// The beam elements.
    pub fn beams(&self) -> &CorotationalBeams {
        &self.elements.beams
    }

    /// The largest bending strain at the needle's surface in its current pose [-], and where it
    /// is: its distance from the tip along the needle [mm]
    /// ([`CorotationalBeams::max_bending_strain`]).
    pub fn max_bending_strain(&self) -> (f64, f64) {
        let beams = self.beams();
        let (strain, node) = beams.max_bending_strain(self.positions(), self.orientations());
        (strain, beams.rest_length_beyond(node))
    }

    /// The bending strain at the needle's surface at each node in its current pose [-]
    /// ([`CorotationalBeams::bending_strains`]).
    pub fn bending_strains(&self) -> Vec<f64> {
        self.beams()
            .bending_strains(self.positions(), self.orientations())
    }

    /// Includes (default) or drops the geometric stiffness of the beams in the factorised
    /// matrix (see [`CorotationalBeams::set_geometric_stiffness`]).
    pub fn set_geometric_stiffness(&mut self, on: bool) {
        self.elements.beams.set_geometric_stiffness(on);
    }
}

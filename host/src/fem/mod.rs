//! Finite elements of the free-motion stage (paper §III-B, eq. 1): corotational linear
//! tetrahedra for the gel ([`tetra`]) and corotational 3-D beams for the needle ([`beam`]).

// Units are written in brackets ([mm], [N]) as in the workspace style: not intra-doc links.
#![allow(rustdoc::broken_intra_doc_links)]
// Negated comparisons are deliberate: NaN must fail every validity check.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::nonminimal_bool)]

pub mod beam;
mod hyperdual;
pub mod tetra;

use crate::linalg::LinalgError;
use crate::mesh::MeshError;
use std::fmt;

/// Isotropic linear elastic constants.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Elasticity {
    /// Young's modulus E [MPa].
    pub young_modulus: f64,
    /// Poisson's ratio ν [-], in (−1, 0.5).
    pub poisson_ratio: f64,
}

impl Elasticity {
    /// Lamé constants `(λ, μ)` [MPa].
    pub fn lame(&self) -> (f64, f64) {
        let (e, nu) = (self.young_modulus, self.poisson_ratio);
        (
            e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu)),
            e / (2.0 * (1.0 + nu)),
        )
    }

    /// Shear modulus G = E / (2(1 + ν)) [MPa].
    pub fn shear_modulus(&self) -> f64 {
        self.young_modulus / (2.0 * (1.0 + self.poisson_ratio))
    }

    /// Checks `E > 0` and `−1 < ν < 0.5`.
    ///
    /// # Errors
    /// [`FemError::Material`] naming the bad constant.
    pub fn validate(&self) -> Result<(), FemError> {
        if !(self.young_modulus > 0.0 && self.young_modulus.is_finite()) {
            return Err(FemError::Material {
                what: "Young's modulus must be positive and finite",
            });
        }
        if !(self.poisson_ratio > -1.0 && self.poisson_ratio < 0.5) {
            return Err(FemError::Material {
                what: "Poisson's ratio must lie in (-1, 0.5)",
            });
        }
        Ok(())
    }
}

/// Why a finite-element model could not be built or stepped.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub enum FemError {
    /// A material or section constant is invalid.
    Material {
        /// What is wrong.
        what: &'static str,
    },
    /// A model parameter (time step, element count, …) is invalid.
    Parameter {
        /// What is wrong.
        what: &'static str,
    },
    /// The mesh is invalid.
    Mesh(MeshError),
    /// A fixed (Dirichlet) node index does not exist.
    FixedNodeOutOfRange {
        /// The offending node index.
        node: usize,
        /// Number of nodes.
        node_count: usize,
    },
    /// Every dof is fixed: there is nothing to solve.
    NoFreeDof,
    /// A vector argument has the wrong length.
    DimensionMismatch {
        /// Which argument.
        what: &'static str,
        /// Expected length.
        expected: usize,
        /// Length given.
        got: usize,
    },
    /// A force or displacement contains NaN or infinity.
    NonFinite {
        /// Which argument.
        what: &'static str,
    },
    /// The sparse factorisation or solve failed.
    Linalg(LinalgError),
}

impl fmt::Display for FemError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Material { what } => write!(f, "invalid material: {what}"),
            Self::Parameter { what } => write!(f, "invalid parameter: {what}"),
            Self::Mesh(e) => write!(f, "invalid mesh: {e}"),
            Self::FixedNodeOutOfRange { node, node_count } => {
                write!(
                    f,
                    "fixed node {node} does not exist (the model has {node_count} nodes)"
                )
            }
            Self::NoFreeDof => write!(f, "every degree of freedom is fixed"),
            Self::DimensionMismatch {
                what,
                expected,
                got,
            } => {
                write!(f, "{what} has length {got}, expected {expected}")
            }
            Self::NonFinite { what } => write!(f, "{what} contains NaN or infinity"),
            Self::Linalg(e) => write!(f, "linear solve failed: {e}"),
        }
    }
}

impl std::error::Error for FemError {}

impl From<LinalgError> for FemError {
    fn from(e: LinalgError) -> Self {
        Self::Linalg(e)
    }
}

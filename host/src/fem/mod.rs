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
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum FemError {
    /// A material or section constant is invalid.
    #[error("invalid material: {what}")]
    Material {
        /// What is wrong.
        what: &'static str,
    },
    /// A model parameter (time step, element count, …) is invalid.
    #[error("invalid parameter: {what}")]
    Parameter {
        /// What is wrong.
        what: &'static str,
    },
    /// The mesh is invalid.
    #[error("invalid mesh")]
    Mesh(#[source] MeshError),
    /// A fixed (Dirichlet) node index does not exist.
    #[error("fixed node {node} does not exist (the model has {node_count} nodes)")]
    FixedNodeOutOfRange {
        /// The offending node index.
        node: usize,
        /// Number of nodes.
        node_count: usize,
    },
    /// Every dof is fixed: there is nothing to solve.
    #[error("every degree of freedom is fixed")]
    NoFreeDof,
    /// A vector argument has the wrong length.
    #[error("{what} has length {got}, expected {expected}")]
    DimensionMismatch {
        /// Which argument.
        what: &'static str,
        /// Expected length.
        expected: usize,
        /// Length given.
        got: usize,
    },
    /// A force or displacement contains NaN or infinity.
    #[error("{what} contains NaN or infinity")]
    NonFinite {
        /// Which argument.
        what: &'static str,
    },
    /// The system matrix `K + M/h²` is not positive definite: the Cholesky factorisation met a
    /// non-positive pivot (e.g. inverted elements, or a free body without regularisation).
    #[error(
        "the system matrix is not positive definite (non-positive pivot at permuted column {pivot})"
    )]
    NotPositiveDefinite {
        /// Index of the failing pivot in the permuted ordering.
        pivot: usize,
    },
    /// Another sparse factorisation or solve failure (symbolic analysis, no factor yet, size).
    #[error("sparse linear algebra failed")]
    Linalg(#[source] LinalgError),
    /// The background factorisation thread could not be started.
    #[error("the background factorisation thread could not be started")]
    WorkerSpawn(#[source] std::io::Error),
    /// The background factorisation thread stopped (it panicked or was killed) while a job
    /// was in flight or about to be sent.
    #[error("the background factorisation thread stopped")]
    WorkerStopped,
}

impl From<LinalgError> for FemError {
    fn from(e: LinalgError) -> Self {
        match e {
            LinalgError::NotPositiveDefinite { pivot } => Self::NotPositiveDefinite { pivot },
            other => Self::Linalg(other),
        }
    }
}

//! Why an inverse step fails.

use crate::payload::ValidationError;
use core::fmt;

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
    /// The compliance `W` of a frame that passed validation (finite, symmetric, positive
    /// diagonal) is not positive definite: its needle-base block `W_bb`, or the Schur complement
    /// of that block (`W` without the base rows, [`crate::reduce`]), has no Cholesky factor or a
    /// non-positive diagonal. A compliance never looks like this; a corrupted frame may.
    NotPositiveDefinite {
        /// Which matrix.
        stage: &'static str,
    },
}

impl fmt::Display for StepError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::InvalidFrame(e) => write!(f, "invalid frame: {e}"),
            Self::InvalidParameter { name } => write!(f, "invalid parameter {name}"),
            Self::NonFinite { stage } => write!(f, "non-finite result in {stage}"),
            Self::NotPositiveDefinite { stage } => {
                write!(f, "W is not positive definite ({stage})")
            }
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

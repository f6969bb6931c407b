#![doc = include_str!("../README.md")]
#![cfg_attr(not(test), no_std)]
#![deny(missing_docs, clippy::unwrap_used, clippy::expect_used, clippy::panic)]
// `!(x > 0.0)` is deliberate throughout: it is true for NaN, which must take the safe branch.
#![allow(clippy::neg_cmp_op_on_partial_ord)]
// Units are written in brackets (`[mm]`, `[rad]`, STYLE.md), which rustdoc reads as links.
#![allow(rustdoc::broken_intra_doc_links)]
// Index loops over several parallel fixed arrays read better than zipped iterators here.
#![allow(clippy::needless_range_loop)]

#[cfg(feature = "alloc")]
extern crate alloc;

pub mod constraint;
pub mod ik;
pub mod inverse;
pub mod kinematics;
mod math;
pub mod payload;
pub mod qp;
pub mod reduce;
pub mod serial_chain;
pub mod simd;
pub mod synthetic;
pub mod zeroed;

pub use constraint::{ActiveSet, BlockGs, GsParams, SolveReport};
pub use ik::{IkError, IkParams, IkReport, solve_ik};
pub use inverse::{Controller, InverseParams, JacobianMode, Objective, StepError};
pub use kinematics::{DhChain, DhJoint, JointLimit, Kinematics, Pose, Robot};
pub use payload::{
    Command, ComplianceFrame, GroupKind, NCLEAR, NOBS, ObsIndex, RowGroup, SolverReport,
    StatusFlags, VERSION, ValidationError,
};
pub use serial_chain::{SerialChain, SerialJoint};
#[cfg(feature = "alloc")]
pub use zeroed::boxed_zeroed;
pub use zeroed::{Zeroable, zeroed_in_place};

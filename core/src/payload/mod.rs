//! Payloads exchanged between the FE host and the core: [`ComplianceFrame`] (host → core) and
//! [`Command`] (core → host).
//!
//! Both are `#[repr(C)]`, hold only plain scalars and fixed arrays (no `bool`, no enum, no
//! pointer) so that any bit pattern is a valid value and they can travel through shared memory;
//! every frame is therefore checked with [`ComplianceFrame::validate`] on receipt. The layout is
//! versioned: [`VERSION`] is written in the `version` field and bumped whenever a field changes.
//!
//! Sign convention (docs/architecture.md): `w = W λ − δ`; a positive `λ` opens the gap, the host
//! applies `x = x_free + K⁻¹ Hᵀ λ`. Rows `0..6` are the needle-base rows χ (translation x, y, z,
//! then small rotation about x, y, z, world frame); their violation is recomputed by the core from
//! `p_free`, `r_free` and the robot's forward kinematics:
//! `δ_0..3(q) = p_B(q) − p_free`, `δ_3..6(q) = log(R_B(q) R_freeᵀ)`.

//!
//! Files: `frame.rs` ([`ComplianceFrame`]), `command.rs` ([`Command`], [`SolverReport`],
//! [`StatusFlags`]), `validate.rs` (the checks on receipt and [`ValidationError`]).

mod command;
mod frame;
mod validate;

use crate::zeroed::{Zeroable, zero_out, zeroed_in_place};
use core::mem::MaybeUninit;

pub use command::{Command, SolverReport, StatusFlags};
pub use frame::ComplianceFrame;
pub(crate) use validate::validate_entries;
pub use validate::{
    LayoutFault, MAX_JOINT_ANGLE, ValidationError, validate_compliance, validate_groups,
};

/// A versioned payload ([`ComplianceFrame`], [`Command`], and the transports' wrappers of
/// them): its initial state is all zero with the layout version written, which is what
/// `init_in_place`, `reset` and `new_boxed` give.
pub trait Payload: Zeroable {
    /// Writes the layout version into a zeroed payload.
    fn stamp(&mut self);
}

/// [`Payload`]'s initial state in `slot`, without a stack temporary.
fn init_in_place<T: Payload>(slot: &mut MaybeUninit<T>) -> &mut T {
    let value = zeroed_in_place(slot);
    value.stamp();
    value
}

/// [`Payload`]'s initial state on the heap, built there.
#[cfg(feature = "alloc")]
fn new_boxed<T: Payload>() -> alloc::boxed::Box<T> {
    let mut value = crate::zeroed::boxed_zeroed::<T>();
    value.stamp();
    value
}

/// Puts a live payload back into its initial state, in place.
fn reset<T: Payload>(value: &mut T) {
    zero_out(value).stamp();
}

/// Layout version of [`ComplianceFrame`] and [`Command`]; bump it when a field changes.
pub const VERSION: u32 = 2;

/// Service-name style identifier of the frame layout (for transports).
pub const FRAME_TYPE_NAME: &str = "needle.ComplianceFrame.v2";

/// Service-name style identifier of the command layout (for transports).
pub const COMMAND_TYPE_NAME: &str = "needle.Command.v2";

/// Number of joints of the RV-1A, the default `N` of the payloads and of the controller.
///
/// Kept for code written before the joint count became a const generic: new code names the
/// count through the types (`ComplianceFrame<M, N>`, `Command<M, N>`, `Controller<M, N>`,
/// `DhChain<N>`), whose `N` defaults to 6.
pub const JOINTS: usize = 6;

/// Number of needle-base rows χ at the start of every frame.
pub const BASE_ROWS: usize = 6;

/// Capacity of the obstacle clearances of a frame (the nearest obstacles when a scene has
/// more).
pub const NCLEAR: usize = 8;

/// Number of observation rows (5 observed 3-vectors).
pub const NOBS: usize = 15;

/// Start indices of the observed 3-vectors in `o_free` and in the rows of `c`.
///
/// Each observation is `o = o_free + C λ`, world frame.
#[derive(Clone, Copy, Debug)]
pub struct ObsIndex;

impl ObsIndex {
    /// Needle tip position [mm], rows 0..3.
    pub const TIP_POSITION: usize = 0;
    /// Needle tip direction (unit-length to first order) [-], rows 3..6.
    pub const TIP_DIRECTION: usize = 3;
    /// Target point on the desired trajectory [mm], rows 6..9.
    pub const TARGET_POINT: usize = 6;
    /// Unit tangent of the desired trajectory at the target point [-], rows 9..12.
    pub const TARGET_TANGENT: usize = 9;
    /// Entry point of the needle into the gel [mm], rows 12..15.
    pub const ENTRY_POINT: usize = 12;
}

/// Kind of a row group, as stored in [`RowGroup::kind`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u32)]
pub enum GroupKind {
    /// Bilateral rows (`w = 0`, `λ` free), 1…6 rows solved as one exact block. The 6 base rows
    /// are one such group.
    Bilateral = 1,
    /// One unilateral row without friction (`w ≥ 0`, `λ ≥ 0`, `λ w = 0`).
    Unilateral = 2,
    /// Contact with Coulomb friction, 3 rows `[n, t1, t2]`: `λ_n ≥ 0`, `|λ_t| ≤ μ λ_n`.
    Contact = 3,
    /// Sliding point, 3 rows `[l1, l2, axial]`: lateral rows bilateral, axial row bounded by
    /// `|λ_a| ≤ μ_n |λ_l| + r_0`.
    Sliding = 4,
}

impl GroupKind {
    /// Decodes a raw kind; `None` for an unknown value.
    pub const fn from_raw(raw: u32) -> Option<Self> {
        match raw {
            1 => Some(Self::Bilateral),
            2 => Some(Self::Unilateral),
            3 => Some(Self::Contact),
            4 => Some(Self::Sliding),
            _ => None,
        }
    }

    /// Whether `len` rows is a valid length for this kind.
    pub const fn accepts_len(self, len: usize) -> bool {
        match self {
            Self::Bilateral => len >= 1 && len <= 6,
            Self::Unilateral => len == 1,
            Self::Contact | Self::Sliding => len == 3,
        }
    }
}

/// Descriptor of one group of consecutive constraint rows.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
#[repr(C)]
pub struct RowGroup {
    /// Raw [`GroupKind`] (`GroupKind::X as u32`).
    pub kind: u32,
    /// First row of the group.
    pub start: u32,
    /// Number of rows.
    pub len: u32,
    /// Reserved, write 0.
    pub reserved: u32,
    /// Friction coefficient [-]: μ of a contact, μ_n of a sliding point; ignored otherwise.
    pub mu: f64,
    /// Axial friction offset r_0 of a sliding point [N]; ignored otherwise.
    pub r0: f64,
}

impl RowGroup {
    /// A bilateral group.
    pub const fn bilateral(start: u32, len: u32) -> Self {
        Self {
            kind: GroupKind::Bilateral as u32,
            start,
            len,
            reserved: 0,
            mu: 0.0,
            r0: 0.0,
        }
    }
    /// A single frictionless unilateral row.
    pub const fn unilateral(start: u32) -> Self {
        Self {
            kind: GroupKind::Unilateral as u32,
            start,
            len: 1,
            reserved: 0,
            mu: 0.0,
            r0: 0.0,
        }
    }
    /// A frictional contact `[n, t1, t2]` with coefficient `mu`.
    pub const fn contact(start: u32, mu: f64) -> Self {
        Self {
            kind: GroupKind::Contact as u32,
            start,
            len: 3,
            reserved: 0,
            mu,
            r0: 0.0,
        }
    }
    /// A sliding point `[l1, l2, axial]` with resistance `mu_n` and offset `r0` [N].
    pub const fn sliding(start: u32, mu_n: f64, r0: f64) -> Self {
        Self {
            kind: GroupKind::Sliding as u32,
            start,
            len: 3,
            reserved: 0,
            mu: mu_n,
            r0,
        }
    }
}

crate::zeroed::impl_zeroable!(RowGroup {
    kind,
    start,
    len,
    reserved,
    mu,
    r0
});

#[cfg(test)]
#[allow(clippy::expect_used, clippy::unwrap_used, clippy::panic)]
mod tests {
    use super::*;
    use core::mem::{align_of, offset_of, size_of};

    /// The symmetry check of `W`: round-off within `1e-8 √(W_ii W_jj)` passes, and a matrix
    /// with two asymmetric pairs is rejected naming the first one in row order (row `i`, then
    /// column `j < i`).
    #[test]
    fn compliance_symmetry_names_the_first_asymmetric_entry() {
        let mut w = [[0.0f64; 8]; 8];
        for (i, row) in w.iter_mut().enumerate() {
            for (j, x) in row.iter_mut().enumerate() {
                *x = if i == j {
                    4.0 + i as f64
                } else {
                    0.1 * (i + j) as f64
                };
            }
        }
        w[5][2] += 1e-12;
        assert_eq!(validate_compliance(&w, 8), Ok(()));
        w[6][1] += 1e-3;
        w[4][3] -= 1e-3;
        assert_eq!(
            validate_compliance(&w, 8),
            Err(ValidationError::NotSymmetric { row: 4, col: 3 })
        );
        // Outside the used block the matrix is not looked at.
        assert_eq!(validate_compliance(&w, 4), Ok(()));
    }

    /// The `#[repr(C)]` layout of the v2 payloads (type names `needle.ComplianceFrame.v2`,
    /// `needle.Command.v2`): field offsets and sizes at `M = 192` as measured on the layout
    /// before the payload types became generic over the joint count (v1), with the obstacle
    /// clearances appended at the end of the frame (v2). A change here is a new layout and
    /// needs a new `VERSION`.
    #[test]
    fn v2_layout_is_unchanged() {
        type F = ComplianceFrame<192>;
        let frame = [
            offset_of!(F, version),
            offset_of!(F, m),
            offset_of!(F, sequence),
            offset_of!(F, group_count),
            offset_of!(F, inserted),
            offset_of!(F, groups),
            offset_of!(F, w),
            offset_of!(F, delta_free),
            offset_of!(F, p_free),
            offset_of!(F, r_free),
            offset_of!(F, o_free),
            offset_of!(F, c),
            offset_of!(F, insertion_depth),
            offset_of!(F, q),
            offset_of!(F, dt),
            offset_of!(F, clearance_count),
            offset_of!(F, reserved),
            offset_of!(F, clearance_free),
            offset_of!(F, clearance_c),
            size_of::<F>(),
            align_of::<F>(),
        ];
        let expected = [
            0, 4, 8, 16, 20, 24, 6168, 301080, 302616, 302640, 302712, 302832, 325872, 325880,
            325928, 325936, 325940, 325944, 326008, 338296, 8,
        ];
        assert_eq!(frame, expected);
        type C = Command<192>;
        let command = [
            offset_of!(C, version),
            offset_of!(C, m),
            offset_of!(C, frame_sequence),
            offset_of!(C, q),
            offset_of!(C, lambda),
            offset_of!(C, report),
            size_of::<C>(),
            align_of::<C>(),
        ];
        assert_eq!(command, [0, 4, 8, 16, 64, 1600, 1736, 8]);
        let report = [
            offset_of!(SolverReport, iterations),
            offset_of!(SolverReport, solves),
            offset_of!(SolverReport, flags),
            offset_of!(SolverReport, final_iterations),
            offset_of!(SolverReport, final_residual),
            offset_of!(SolverReport, objective),
            offset_of!(SolverReport, objective_after),
            offset_of!(SolverReport, delta_q),
            size_of::<SolverReport>(),
        ];
        assert_eq!(report, [0, 4, 8, 12, 16, 24, 56, 88, 136]);
        let group = [
            offset_of!(RowGroup, kind),
            offset_of!(RowGroup, start),
            offset_of!(RowGroup, len),
            offset_of!(RowGroup, reserved),
            offset_of!(RowGroup, mu),
            offset_of!(RowGroup, r0),
            size_of::<RowGroup>(),
        ];
        assert_eq!(group, [0, 4, 8, 12, 16, 24, 32]);
    }
}

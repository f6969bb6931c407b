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

use crate::zeroed::{zero_out, zeroed_in_place};
use core::fmt;
use core::mem::MaybeUninit;

/// Layout version of [`ComplianceFrame`] and [`Command`]; bump it when a field changes.
pub const VERSION: u32 = 1;

/// Service-name style identifier of the frame layout (for transports).
pub const FRAME_TYPE_NAME: &str = "needle.ComplianceFrame.v1";

/// Service-name style identifier of the command layout (for transports).
pub const COMMAND_TYPE_NAME: &str = "needle.Command.v1";

/// Number of robot joints carried by the payloads.
pub const JOINTS: usize = 6;

/// Number of needle-base rows χ at the start of every frame.
pub const BASE_ROWS: usize = 6;

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

/// What is wrong with a group layout (see [`ValidationError::GroupLayout`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum LayoutFault {
    /// The kind value is unknown.
    BadKind,
    /// The length does not fit the kind.
    LengthMismatch,
    /// The group does not start where the previous one ended (overlap or gap).
    NotContiguous,
    /// The group reaches past row `m`.
    OutOfRange,
    /// The groups end before row `m`.
    RowsNotCovered,
    /// Rows 0..6 are not one bilateral group of 6 (the needle-base rows).
    BaseRows,
}

/// Why a payload was rejected.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub enum ValidationError {
    /// The `version` field does not match [`VERSION`].
    VersionMismatch {
        /// Version found in the payload.
        found: u32,
        /// Version this build understands.
        expected: u32,
    },
    /// A count exceeds the capacity of the type.
    CapacityExceeded {
        /// Requested count (rows or groups).
        requested: usize,
        /// Capacity `M`.
        capacity: usize,
    },
    /// Fewer rows than the 6 base rows.
    TooFewRows {
        /// Rows given.
        m: usize,
        /// Rows required.
        min: usize,
    },
    /// The row-group table is inconsistent.
    GroupLayout {
        /// Index of the offending group.
        group: usize,
        /// What is wrong.
        fault: LayoutFault,
    },
    /// A used value is NaN or infinite.
    NonFinite {
        /// Field name.
        field: &'static str,
        /// Flat index within the field (row-major for matrices).
        index: usize,
    },
    /// A friction coefficient or offset is negative.
    NegativeFriction {
        /// Index of the offending group.
        group: usize,
    },
    /// A diagonal entry of W is not positive.
    NonPositiveDiagonal {
        /// Row of the entry.
        row: usize,
    },
    /// W is not symmetric (relative tolerance 1e-8 of `sqrt(W_ii W_jj)`).
    NotSymmetric {
        /// Row of the entry.
        row: usize,
        /// Column of the entry.
        col: usize,
    },
    /// `r_free` is not a rotation matrix (tolerance 1e-6).
    NotRotation,
    /// A scalar is outside its allowed range (e.g. `dt ≤ 0`, negative depth).
    OutOfRange {
        /// Field name.
        field: &'static str,
    },
}

impl fmt::Display for ValidationError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Self::VersionMismatch { found, expected } => {
                write!(f, "payload version {found}, expected {expected}")
            }
            Self::CapacityExceeded {
                requested,
                capacity,
            } => {
                write!(f, "{requested} exceeds the capacity {capacity}")
            }
            Self::TooFewRows { m, min } => write!(f, "{m} rows, at least {min} required"),
            Self::GroupLayout { group, fault } => write!(f, "row group {group}: {fault:?}"),
            Self::NonFinite { field, index } => write!(f, "non-finite value in {field}[{index}]"),
            Self::NegativeFriction { group } => write!(f, "negative friction in group {group}"),
            Self::NonPositiveDiagonal { row } => write!(f, "W[{row}][{row}] is not positive"),
            Self::NotSymmetric { row, col } => write!(f, "W[{row}][{col}] != W[{col}][{row}]"),
            Self::NotRotation => write!(f, "r_free is not a rotation matrix"),
            Self::OutOfRange { field } => write!(f, "{field} is out of range"),
        }
    }
}

impl core::error::Error for ValidationError {}

fn check_finite(field: &'static str, v: &[f64]) -> Result<(), ValidationError> {
    match v.iter().position(|x| !x.is_finite()) {
        Some(index) => Err(ValidationError::NonFinite { field, index }),
        None => Ok(()),
    }
}

/// Validates a row-group table for `m` rows and capacity `capacity`: known kinds, lengths fitting
/// their kind, groups contiguous from row 0 and covering exactly `0..m`, finite non-negative
/// friction. With `base_rows`, group 0 must be the 6-row bilateral base group.
///
/// # Errors
/// The first inconsistency found.
pub fn validate_groups(
    groups: &[RowGroup],
    m: usize,
    capacity: usize,
    base_rows: bool,
) -> Result<(), ValidationError> {
    if m > capacity {
        return Err(ValidationError::CapacityExceeded {
            requested: m,
            capacity,
        });
    }
    if groups.len() > capacity {
        return Err(ValidationError::CapacityExceeded {
            requested: groups.len(),
            capacity,
        });
    }
    let mut next = 0usize;
    for (g, grp) in groups.iter().enumerate() {
        let layout = |fault| ValidationError::GroupLayout { group: g, fault };
        let kind = GroupKind::from_raw(grp.kind).ok_or(layout(LayoutFault::BadKind))?;
        let len = grp.len as usize;
        if !kind.accepts_len(len) {
            return Err(layout(LayoutFault::LengthMismatch));
        }
        if grp.start as usize != next {
            return Err(layout(LayoutFault::NotContiguous));
        }
        next += len;
        if next > m {
            return Err(layout(LayoutFault::OutOfRange));
        }
        if g == 0 && base_rows && (kind != GroupKind::Bilateral || len != BASE_ROWS) {
            return Err(layout(LayoutFault::BaseRows));
        }
        if matches!(kind, GroupKind::Contact | GroupKind::Sliding) {
            if !grp.mu.is_finite() {
                return Err(ValidationError::NonFinite {
                    field: "groups.mu",
                    index: g,
                });
            }
            if !grp.r0.is_finite() {
                return Err(ValidationError::NonFinite {
                    field: "groups.r0",
                    index: g,
                });
            }
            if grp.mu < 0.0 || grp.r0 < 0.0 {
                return Err(ValidationError::NegativeFriction { group: g });
            }
        }
    }
    if next != m {
        return Err(ValidationError::GroupLayout {
            group: groups.len(),
            fault: LayoutFault::RowsNotCovered,
        });
    }
    Ok(())
}

/// Validates the used `m × m` block of a compliance matrix: finite, positive diagonal, symmetric.
///
/// # Errors
/// The first offending entry.
pub fn validate_compliance<const M: usize>(
    w: &[[f64; M]; M],
    m: usize,
) -> Result<(), ValidationError> {
    let m = m.min(M);
    for (i, row) in w.iter().enumerate().take(m) {
        if let Some(j) = row[..m].iter().position(|x| !x.is_finite()) {
            return Err(ValidationError::NonFinite {
                field: "w",
                index: i * M + j,
            });
        }
        if row[i] <= 0.0 {
            return Err(ValidationError::NonPositiveDiagonal { row: i });
        }
    }
    let mut root = [0.0f64; M];
    for i in 0..m {
        root[i] = libm::sqrt(w[i][i]);
    }
    for i in 0..m {
        let tol_i = 1e-8 * root[i];
        for j in 0..i {
            if libm::fabs(w[i][j] - w[j][i]) > tol_i * root[j] {
                return Err(ValidationError::NotSymmetric { row: i, col: j });
            }
        }
    }
    Ok(())
}

/// One compliance frame: everything the core needs for one inverse step (host → core).
///
/// `M` is the row capacity; only the first `m` rows/columns of the arrays are used. At `M = 192`
/// a frame is about 320 KiB: never build one on the stack, use [`Self::init_in_place`] on storage
/// you own (a `static`, a shared-memory sample) or `new_boxed` (feature `alloc`).
#[derive(Clone, Copy, Debug)]
#[repr(C)]
pub struct ComplianceFrame<const M: usize> {
    /// Layout version, [`VERSION`].
    pub version: u32,
    /// Number of rows used, `6 ≤ m ≤ M`.
    pub m: u32,
    /// Sequence number of the frame, increasing by one per host step.
    pub sequence: u64,
    /// Number of row groups used in `groups`.
    pub group_count: u32,
    /// 1 once the needle tip has punctured the gel surface, else 0.
    pub inserted: u32,
    /// Row groups, contiguous from row 0; group 0 is the 6 base rows (bilateral).
    pub groups: [RowGroup; M],
    /// Compliance `W = H K⁻¹ Hᵀ`, row-major, only `m × m` used [mm/N, rad/(N·mm) for rotation rows].
    pub w: [[f64; M]; M],
    /// Constraint violation after free motion `δ_free` [mm or rad]. Rows 0..6 are recomputed by
    /// the core from `q` (host: write `δ_base(q)` there for diagnostics).
    pub delta_free: [f64; M],
    /// Needle base node position after free motion, world frame [mm].
    pub p_free: [f64; 3],
    /// Needle base node orientation after free motion, row-major rotation matrix, world frame.
    pub r_free: [[f64; 3]; 3],
    /// Observations after free motion, laid out by [`ObsIndex`] (world frame, mm or unit vectors).
    pub o_free: [f64; NOBS],
    /// Observation sensitivity `C = O K⁻¹ Hᵀ`: `o = o_free + C λ`, row-major, `m` columns used.
    pub c: [[f64; M]; NOBS],
    /// Insertion depth of the tip past the entry point [mm] (0 before puncture).
    pub insertion_depth: f64,
    /// Robot joints at which the frame was built [rad].
    pub q: [f64; JOINTS],
    /// Robot control period [s].
    pub dt: f64,
}

crate::zeroed::impl_zeroable!(RowGroup {
    kind,
    start,
    len,
    reserved,
    mu,
    r0
});
crate::zeroed::impl_zeroable!(ComplianceFrame<const M> {
    version,
    m,
    sequence,
    group_count,
    inserted,
    groups,
    w,
    delta_free,
    p_free,
    r_free,
    o_free,
    c,
    insertion_depth,
    q,
    dt,
});

impl<const M: usize> ComplianceFrame<M> {
    /// Initialises a frame in place: all zero, `version = VERSION`. Returns the initialised frame.
    ///
    /// Use it on storage you own so that the (large) frame never transits the stack (a
    /// `static`, a shared-memory sample); on the heap, [`Self::new_boxed`] does it for you.
    ///
    /// # Example
    /// ```
    /// use core::mem::MaybeUninit;
    /// use needle_core::{ComplianceFrame, VERSION};
    ///
    /// static mut FRAME: MaybeUninit<ComplianceFrame<16>> = MaybeUninit::uninit();
    /// // SAFETY (of this example): the only borrow of the static.
    /// let frame = ComplianceFrame::init_in_place(unsafe { &mut *(&raw mut FRAME) });
    /// assert_eq!((frame.version, frame.m), (VERSION, 0));
    /// ```
    pub fn init_in_place(this: &mut MaybeUninit<Self>) -> &mut Self {
        zeroed_in_place(this).stamp()
    }

    /// A frame on the heap in the state of [`Self::init_in_place`], built there (no stack copy).
    ///
    /// # Example
    /// ```
    /// use needle_core::{ComplianceFrame, ValidationError, VERSION};
    ///
    /// let frame = ComplianceFrame::<192>::new_boxed(); // ≈ 320 KiB
    /// assert_eq!(frame.version, VERSION);
    /// // All zero: too few rows to be a frame.
    /// assert_eq!(frame.validate(), Err(ValidationError::TooFewRows { m: 0, min: 6 }));
    /// ```
    #[cfg(feature = "alloc")]
    pub fn new_boxed() -> alloc::boxed::Box<Self> {
        let mut b = crate::zeroed::boxed_zeroed::<Self>();
        b.stamp();
        b
    }

    /// Resets an existing frame to the state of [`Self::init_in_place`], without a stack copy.
    pub fn reset(&mut self) {
        zero_out(self).stamp();
    }

    /// Writes the layout version into a zeroed frame.
    fn stamp(&mut self) -> &mut Self {
        self.version = VERSION;
        self
    }

    /// Number of rows used, as `usize`.
    pub fn rows(&self) -> usize {
        self.m as usize
    }

    /// The used row groups (clamped to the capacity; call [`Self::validate`] first).
    pub fn used_groups(&self) -> &[RowGroup] {
        &self.groups[..(self.group_count as usize).min(M)]
    }

    /// The observed 3-vector starting at `index` (one of the [`ObsIndex`] constants) for `λ`:
    /// `o_free + C λ` over the first `m` rows.
    pub fn observe(&self, index: usize, lambda: &[f64]) -> [f64; 3] {
        let m = self.rows().min(M).min(lambda.len());
        let mut out = [0.0; 3];
        for (k, o) in out.iter_mut().enumerate() {
            let r = (index + k).min(NOBS - 1);
            *o = self.o_free[r] + crate::math::dot(&self.c[r][..m], &lambda[..m]);
        }
        out
    }

    /// Checks the frame on receipt.
    ///
    /// Checks: version, `6 ≤ m ≤ M`, group table (kinds, lengths, contiguous cover of `0..m`, base
    /// group first), finite values in every used entry, non-negative friction, positive diagonal
    /// and symmetry of W, `r_free` a rotation, `dt > 0`, `insertion_depth ≥ 0`.
    ///
    /// # Errors
    /// The first problem found, as a [`ValidationError`].
    pub fn validate(&self) -> Result<(), ValidationError> {
        if self.version != VERSION {
            return Err(ValidationError::VersionMismatch {
                found: self.version,
                expected: VERSION,
            });
        }
        let m = self.m as usize;
        if m > M {
            return Err(ValidationError::CapacityExceeded {
                requested: m,
                capacity: M,
            });
        }
        if m < BASE_ROWS {
            return Err(ValidationError::TooFewRows { m, min: BASE_ROWS });
        }
        let count = self.group_count as usize;
        if count > M {
            return Err(ValidationError::CapacityExceeded {
                requested: count,
                capacity: M,
            });
        }
        validate_groups(&self.groups[..count], m, M, true)?;
        validate_compliance(&self.w, m)?;
        check_finite("delta_free", &self.delta_free[..m])?;
        check_finite("p_free", &self.p_free)?;
        check_finite("r_free", self.r_free.as_flattened())?;
        check_finite("o_free", &self.o_free)?;
        for (k, row) in self.c.iter().enumerate() {
            if let Some(j) = row[..m].iter().position(|x| !x.is_finite()) {
                return Err(ValidationError::NonFinite {
                    field: "c",
                    index: k * M + j,
                });
            }
        }
        check_finite(
            "insertion_depth",
            core::slice::from_ref(&self.insertion_depth),
        )?;
        check_finite("q", &self.q)?;
        check_finite("dt", core::slice::from_ref(&self.dt))?;
        if self.dt <= 0.0 {
            return Err(ValidationError::OutOfRange { field: "dt" });
        }
        if self.insertion_depth < 0.0 {
            return Err(ValidationError::OutOfRange {
                field: "insertion_depth",
            });
        }
        let r = &self.r_free;
        for i in 0..3 {
            for j in 0..3 {
                let d = r[0][i] * r[0][j] + r[1][i] * r[1][j] + r[2][i] * r[2][j];
                let e = if i == j { 1.0 } else { 0.0 };
                if libm::fabs(d - e) > 1e-6 {
                    return Err(ValidationError::NotRotation);
                }
            }
        }
        let det = r[0][0] * (r[1][1] * r[2][2] - r[1][2] * r[2][1])
            - r[0][1] * (r[1][0] * r[2][2] - r[1][2] * r[2][0])
            + r[0][2] * (r[1][0] * r[2][1] - r[1][1] * r[2][0]);
        if det <= 0.0 {
            return Err(ValidationError::NotRotation);
        }
        Ok(())
    }
}

/// Status flags of a [`SolverReport`] (bit set in `flags`).
#[derive(Clone, Copy, Debug)]
pub struct StatusFlags;

impl StatusFlags {
    /// The step was scaled down to respect a joint speed limit.
    pub const SATURATED_SPEED: u32 = 1 << 0;
    /// A joint was clamped at a position limit.
    pub const SATURATED_LIMIT: u32 = 1 << 1;
    /// The linearised model predicts no useful decrease of the objective (target out of reach
    /// from here: singular, limited or saturated).
    pub const TARGET_UNREACHABLE: u32 = 1 << 2;
    /// At least one constraint solve hit its iteration cap.
    pub const NOT_CONVERGED: u32 = 1 << 3;
    /// The objective was within tolerance: no Jacobian, no motion.
    pub const WITHIN_TOLERANCE: u32 = 1 << 4;
    /// The damping of the pseudo-inverse was raised near a singularity.
    pub const NEAR_SINGULAR: u32 = 1 << 5;
    /// The step was scaled down to the trust region on the needle-base motion
    /// (`InverseParams::max_base_step`).
    pub const STEP_LIMITED: u32 = 1 << 6;
}

/// Report of one inverse step, carried in [`Command::report`].
#[derive(Clone, Copy, Debug, PartialEq, Default)]
#[repr(C)]
pub struct SolverReport {
    /// Gauss-Seidel sweeps summed over every solve of the step.
    pub iterations: u32,
    /// Number of constraint solves in the step (1, or 8 with a Jacobian).
    pub solves: u32,
    /// Bit set of [`StatusFlags`].
    pub flags: u32,
    /// Sweeps of the final solve.
    pub final_iterations: u32,
    /// Residual of the final solve (largest `|W_ii Δλ_i|` of the last sweep over `‖δ‖∞`) [-].
    pub final_residual: f64,
    /// Objective `T(q)` at the frame's joints: e [mm] and weighted angle [mm].
    pub objective: [f64; 4],
    /// Objective at the commanded joints, from the final solve [mm].
    pub objective_after: [f64; 4],
    /// Applied joint step `Δq` [rad].
    pub delta_q: [f64; JOINTS],
}

/// The core's answer to one frame (core → host).
#[derive(Clone, Copy, Debug)]
#[repr(C)]
pub struct Command<const M: usize> {
    /// Layout version, [`VERSION`].
    pub version: u32,
    /// Number of rows of `lambda` used (the frame's `m`).
    pub m: u32,
    /// Sequence number of the frame this answers.
    pub frame_sequence: u64,
    /// Commanded joints [rad].
    pub q: [f64; JOINTS],
    /// Constraint forces at the commanded joints [N or N·mm], first `m` used; apply as
    /// `x = x_free + K⁻¹ Hᵀ λ`.
    pub lambda: [f64; M],
    /// How the step went.
    pub report: SolverReport,
}

crate::zeroed::impl_zeroable!(SolverReport {
    iterations,
    solves,
    flags,
    final_iterations,
    final_residual,
    objective,
    objective_after,
    delta_q,
});
crate::zeroed::impl_zeroable!(Command<const M> {
    version,
    m,
    frame_sequence,
    q,
    lambda,
    report,
});

impl<const M: usize> Command<M> {
    /// Initialises a command in place: all zero, `version = VERSION`.
    pub fn init_in_place(this: &mut MaybeUninit<Self>) -> &mut Self {
        zeroed_in_place(this).stamp()
    }

    /// A command on the heap in the state of [`Self::init_in_place`], built there.
    ///
    /// # Example
    /// ```
    /// use needle_core::{Command, VERSION};
    ///
    /// let cmd = Command::<192>::new_boxed();
    /// assert_eq!(cmd.version, VERSION);
    /// assert_eq!(cmd.validate(), Ok(()));
    /// ```
    #[cfg(feature = "alloc")]
    pub fn new_boxed() -> alloc::boxed::Box<Self> {
        let mut b = crate::zeroed::boxed_zeroed::<Self>();
        b.stamp();
        b
    }

    /// Resets an existing command to the state of [`Self::init_in_place`].
    pub fn reset(&mut self) {
        zero_out(self).stamp();
    }

    /// Writes the layout version into a zeroed command.
    fn stamp(&mut self) -> &mut Self {
        self.version = VERSION;
        self
    }

    /// Checks a received command: version, `m ≤ M`, finite joints, forces and report.
    ///
    /// # Errors
    /// The first problem found.
    pub fn validate(&self) -> Result<(), ValidationError> {
        if self.version != VERSION {
            return Err(ValidationError::VersionMismatch {
                found: self.version,
                expected: VERSION,
            });
        }
        let m = self.m as usize;
        if m > M {
            return Err(ValidationError::CapacityExceeded {
                requested: m,
                capacity: M,
            });
        }
        check_finite("q", &self.q)?;
        check_finite("lambda", &self.lambda[..m])?;
        check_finite("report.delta_q", &self.report.delta_q)?;
        Ok(())
    }
}

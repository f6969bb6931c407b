//! Checks on receipt: every payload that crossed a process boundary is validated before use
//! ([`ComplianceFrame::validate`], [`Command::validate`]); what is wrong is a [`ValidationError`].

use super::{BASE_ROWS, Command, ComplianceFrame, GroupKind, NCLEAR, RowGroup, VERSION};
use core::fmt;

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

/// Whether every entry is finite: one branch-free pass (it vectorises); the index of a bad
/// entry is looked for only when there is one.
#[inline(always)]
fn all_finite(v: &[f64]) -> bool {
    v.iter().fold(true, |ok, x| ok & x.is_finite())
}

/// The index of the first non-finite entry, if any.
#[inline(always)]
fn first_non_finite(v: &[f64]) -> Option<usize> {
    if all_finite(v) {
        None
    } else {
        v.iter().position(|x| !x.is_finite())
    }
}

fn check_finite(field: &'static str, v: &[f64]) -> Result<(), ValidationError> {
    match first_non_finite(v) {
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
    check_capacity(m, capacity)?;
    check_capacity(groups.len(), capacity)?;
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
    #[cfg(target_arch = "x86_64")]
    if crate::math::use_avx2() {
        // SAFETY: AVX2 support was checked at run time.
        return unsafe { validate_compliance_avx2(w, m) };
    }
    validate_compliance_inline(w, m)
}

/// [`validate_compliance`] compiled for AVX2 (the same tests: the same verdict).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn validate_compliance_avx2<const M: usize>(
    w: &[[f64; M]; M],
    m: usize,
) -> Result<(), ValidationError> {
    validate_compliance_inline(w, m)
}

#[inline(always)]
fn validate_compliance_inline<const M: usize>(
    w: &[[f64; M]; M],
    m: usize,
) -> Result<(), ValidationError> {
    let m = m.min(M);
    validate_entries(w, m)?;
    let mut root = [0.0f64; M];
    for i in 0..m {
        root[i] = libm::sqrt(w[i][i]);
    }
    // The test of every pair without a branch (the common case: it passes), then, only when it
    // fails, the same test again stopping at the first offending entry (the error names it).
    let asymmetric = asymmetric_pairs(w, m, &root);
    if !asymmetric {
        return Ok(());
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

/// Whether some pair `j < i < m` fails `|w_ij − w_ji| ≤ 1e-8 √w_ii √w_jj` (`root` the square
/// roots of the diagonal), without a branch. By 4 × 4 tiles below the diagonal, so that both
/// tiles of a pair are read by rows (each pair's test as in the plain loop), then the diagonal
/// tiles and the rows past the last whole tile pair by pair.
#[inline(always)]
fn asymmetric_pairs<const M: usize>(w: &[[f64; M]; M], m: usize, root: &[f64; M]) -> bool {
    const T: usize = 4;
    let m = m.min(M);
    let whole = m / T * T;
    let mut bad = false;
    let pair = |i: usize, j: usize| libm::fabs(w[i][j] - w[j][i]) > 1e-8 * root[i] * root[j];
    let mut i0 = 0;
    while i0 < whole {
        let tol: [f64; T] = core::array::from_fn(|a| 1e-8 * root[i0 + a]);
        let mut j0 = 0;
        while j0 + T <= i0 {
            let lower: [&[f64]; T] = core::array::from_fn(|a| &w[i0 + a][j0..j0 + T]);
            let upper: [&[f64]; T] = core::array::from_fn(|b| &w[j0 + b][i0..i0 + T]);
            let rj = &root[j0..j0 + T];
            for a in 0..T {
                for b in 0..T {
                    bad |= libm::fabs(lower[a][b] - upper[b][a]) > tol[a] * rj[b];
                }
            }
            j0 += T;
        }
        for i in i0..i0 + T {
            for j in i0..i {
                bad |= pair(i, j);
            }
        }
        i0 += T;
    }
    for i in whole..m {
        for j in 0..i {
            bad |= pair(i, j);
        }
    }
    bad
}

/// The checks of [`validate_compliance`] but symmetry: the used `m × m` block finite, its
/// diagonal positive (for matrices symmetric by construction).
///
/// # Errors
/// The first offending entry.
#[inline(always)]
pub(crate) fn validate_entries<const M: usize>(
    w: &[[f64; M]; M],
    m: usize,
) -> Result<(), ValidationError> {
    let m = m.min(M);
    for (i, row) in w.iter().enumerate().take(m) {
        if let Some(j) = first_non_finite(&row[..m]) {
            return Err(ValidationError::NonFinite {
                field: "w",
                index: i * M + j,
            });
        }
        if row[i] <= 0.0 {
            return Err(ValidationError::NonPositiveDiagonal { row: i });
        }
    }
    Ok(())
}

impl<const M: usize, const N: usize> ComplianceFrame<M, N> {
    /// Checks the frame on receipt.
    ///
    /// Checks: version, `6 ≤ m ≤ M`, group table (kinds, lengths, contiguous cover of `0..m`, base
    /// group first), finite values in every used entry, non-negative friction, positive diagonal
    /// and symmetry of W, `r_free` a rotation, `dt > 0`, `insertion_depth ≥ 0`.
    ///
    /// # Errors
    /// The first problem found, as a [`ValidationError`].
    ///
    /// # Example
    /// ```
    /// use needle_core::synthetic::random_frame;
    /// use needle_core::{ComplianceFrame, DhChain, ValidationError};
    ///
    /// let mut frame = ComplianceFrame::<32>::new_boxed();
    /// let q = [0.1, 0.3, 2.0, 0.0, 0.5, 0.0];
    /// random_frame(&mut frame, &DhChain::rv1a(), &q, 24, 7, false);
    /// assert_eq!(frame.validate(), Ok(()));
    ///
    /// frame.w[7][7] = f64::NAN; // corrupted on the way
    /// let index = 7 * 32 + 7;
    /// assert_eq!(frame.validate(), Err(ValidationError::NonFinite { field: "w", index }));
    /// ```
    pub fn validate(&self) -> Result<(), ValidationError> {
        check_version(self.version)?;
        let m = self.m as usize;
        check_capacity(m, M)?;
        if m < BASE_ROWS {
            return Err(ValidationError::TooFewRows { m, min: BASE_ROWS });
        }
        let count = self.group_count as usize;
        check_capacity(count, M)?;
        validate_groups(&self.groups[..count], m, M, true)?;
        validate_compliance(&self.w, m)?;
        check_finite("delta_free", &self.delta_free[..m])?;
        check_finite("p_free", &self.p_free)?;
        check_finite("r_free", self.r_free.as_flattened())?;
        check_finite("o_free", &self.o_free)?;
        for (k, row) in self.c.iter().enumerate() {
            if let Some(j) = first_non_finite(&row[..m]) {
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
        check_joints(&self.q)?;
        check_finite("dt", core::slice::from_ref(&self.dt))?;
        if self.dt <= 0.0 {
            return Err(ValidationError::OutOfRange { field: "dt" });
        }
        if self.insertion_depth < 0.0 {
            return Err(ValidationError::OutOfRange {
                field: "insertion_depth",
            });
        }
        let k = self.clearance_count as usize;
        if k > NCLEAR {
            return Err(ValidationError::CapacityExceeded {
                requested: k,
                capacity: NCLEAR,
            });
        }
        check_finite("clearance_free", &self.clearance_free[..k])?;
        for (j, row) in self.clearance_c.iter().enumerate().take(k) {
            if let Some(i) = first_non_finite(&row[..m]) {
                return Err(ValidationError::NonFinite {
                    field: "clearance_c",
                    index: j * M + i,
                });
            }
        }
        check_rotation(&self.r_free)
    }
}

/// Largest joint angle a frame or a command may carry [rad] (two turns either way: beyond any
/// revolute joint's range).
pub const MAX_JOINT_ANGLE: f64 = 4.0 * core::f64::consts::PI;

/// Every joint finite and within ±[`MAX_JOINT_ANGLE`].
fn check_joints(q: &[f64]) -> Result<(), ValidationError> {
    check_finite("q", q)?;
    if q.iter().any(|v| libm::fabs(*v) > MAX_JOINT_ANGLE) {
        return Err(ValidationError::OutOfRange { field: "q" });
    }
    Ok(())
}

impl<const M: usize, const N: usize> Command<M, N> {
    /// Checks a received command, every field: version, `m ≤ M`, joints finite and within
    /// ±[`MAX_JOINT_ANGLE`], finite forces, and a finite report (residual ≥ 0, objectives,
    /// joint update).
    ///
    /// # Errors
    /// The first problem found.
    pub fn validate(&self) -> Result<(), ValidationError> {
        check_version(self.version)?;
        let m = self.m as usize;
        check_capacity(m, M)?;
        check_joints(&self.q)?;
        check_finite("lambda", &self.lambda[..m])?;
        let r = &self.report;
        check_finite("report.final_residual", &[r.final_residual])?;
        if r.final_residual < 0.0 {
            return Err(ValidationError::OutOfRange {
                field: "report.final_residual",
            });
        }
        check_finite("report.objective", &r.objective)?;
        check_finite("report.objective_after", &r.objective_after)?;
        check_finite("report.delta_q", &r.delta_q)?;
        Ok(())
    }
}

/// `r` (row-major) is a rotation: orthonormal to 1e-6 and `det > 0`.
fn check_rotation(r: &[[f64; 3]; 3]) -> Result<(), ValidationError> {
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

fn check_version(found: u32) -> Result<(), ValidationError> {
    if found != VERSION {
        return Err(ValidationError::VersionMismatch {
            found,
            expected: VERSION,
        });
    }
    Ok(())
}

fn check_capacity(requested: usize, capacity: usize) -> Result<(), ValidationError> {
    if requested > capacity {
        return Err(ValidationError::CapacityExceeded {
            requested,
            capacity,
        });
    }
    Ok(())
}

//! Physical plausibility of a frame that passed validation (finite, symmetric, well laid out):
//! its numbers must be of the size a needle in soft tissue produces, and the needle's own
//! compliance (the base block of `W`) must keep its scale within a host session. A frame with
//! `δ = 10³⁰⁰`, or with `W` scaled by 10⁶, is valid but no simulation of this set-up sent it.

use core::fmt;
use needle_core::payload::ComplianceFrame;

/// Largest constraint violation of a frame [mm]: a metre (nothing in the robot's workspace is
/// further off).
pub const MAX_VIOLATION_MM: f64 = 1e3;

/// Largest compliance entry [mm/N]: a gel of 1 Pa over a millimetre.
pub const MAX_COMPLIANCE: f64 = 1e8;

/// Largest position (needle base, observations) [mm]: 100 m.
pub const MAX_POSITION_MM: f64 = 1e5;

/// Largest control period [s].
pub const MAX_DT_S: f64 = 10.0;

/// Largest change of the needle base's compliance scale between two frames of a session.
pub const MAX_BASE_SCALE_CHANGE: f64 = 100.0;

/// What is implausible about a frame.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub enum Implausible {
    /// A constraint violation beyond [`MAX_VIOLATION_MM`].
    Violation {
        /// Row.
        row: usize,
        /// Value [mm].
        value: f64,
    },
    /// A compliance entry beyond [`MAX_COMPLIANCE`].
    Compliance {
        /// Row.
        row: usize,
        /// Column.
        col: usize,
        /// Value.
        value: f64,
    },
    /// A position (needle base, observation) beyond [`MAX_POSITION_MM`].
    Position {
        /// Value [mm].
        value: f64,
    },
    /// A control period beyond [`MAX_DT_S`].
    TimeStep {
        /// Value [s].
        dt: f64,
    },
    /// The needle base's compliance changed by more than [`MAX_BASE_SCALE_CHANGE`] since the
    /// last frame of the session.
    BaseScale {
        /// New scale over the previous one.
        ratio: f64,
    },
}

impl fmt::Display for Implausible {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Self::Violation { row, value } => write!(
                f,
                "violation δ[{row}] = {value:e} mm beyond {MAX_VIOLATION_MM:e} mm"
            ),
            Self::Compliance { row, col, value } => write!(
                f,
                "compliance W[{row}][{col}] = {value:e} beyond {MAX_COMPLIANCE:e}"
            ),
            Self::Position { value } => {
                write!(f, "position {value:e} mm beyond {MAX_POSITION_MM:e} mm")
            }
            Self::TimeStep { dt } => write!(f, "control period {dt:e} s beyond {MAX_DT_S} s"),
            Self::BaseScale { ratio } => write!(
                f,
                "the needle base's compliance changed {ratio:.3e} times since the last frame"
            ),
        }
    }
}

/// The plausibility checks of one host session: absolute bounds, and the needle base's
/// compliance scale of the last accepted frame.
#[derive(Clone, Copy, Debug, Default)]
pub struct Plausibility {
    base_scale: Option<f64>,
}

/// Largest translational diagonal entry of the base block of `W` (the needle's own compliance
/// at its base) [mm/N].
fn base_scale<const M: usize, const N: usize>(f: &ComplianceFrame<M, N>) -> f64 {
    (0..3).fold(0.0, |a: f64, i| a.max(f.w[i][i]))
}

impl Plausibility {
    /// Checks a validated frame; on success returns what [`Self::accept`] needs.
    ///
    /// # Errors
    /// The first implausible number.
    pub fn check<const M: usize, const N: usize>(
        &self,
        f: &ComplianceFrame<M, N>,
    ) -> Result<f64, Implausible> {
        let m = f.rows();
        if let Some(row) = (0..m).find(|&i| f.delta_free[i].abs() > MAX_VIOLATION_MM) {
            let value = f.delta_free[row];
            return Err(Implausible::Violation { row, value });
        }
        for row in 0..m {
            if let Some(col) = (0..m).find(|&j| f.w[row][j].abs() > MAX_COMPLIANCE) {
                let value = f.w[row][col];
                return Err(Implausible::Compliance { row, col, value });
            }
        }
        if let Some(value) = f
            .p_free
            .iter()
            .chain(&f.o_free)
            .copied()
            .find(|v| v.abs() > MAX_POSITION_MM)
        {
            return Err(Implausible::Position { value });
        }
        if f.dt > MAX_DT_S {
            return Err(Implausible::TimeStep { dt: f.dt });
        }
        let scale = base_scale(f);
        if let Some(prev) = self.base_scale {
            let ratio = scale / prev;
            if !(1.0 / MAX_BASE_SCALE_CHANGE..=MAX_BASE_SCALE_CHANGE).contains(&ratio) {
                return Err(Implausible::BaseScale { ratio });
            }
        }
        Ok(scale)
    }

    /// Records an accepted frame's base scale.
    pub fn accept(&mut self, scale: f64) {
        self.base_scale = Some(scale);
    }

    /// Forgets the session (a new host).
    pub fn reset(&mut self) {
        self.base_scale = None;
    }
}

//! The joint count of a scene's robot, at run time and as a type.
//!
//! The world, the step and the core are generic over the joint count `N` (a const generic:
//! fixed-size arrays, no allocation); a scene says it at run time (6 for the RV-1A or a DH
//! table, the movable joints of a URDF chain). [`crate::setup::AnySetup`] is the one place where
//! the count read from the scene becomes `N`. What leaves a run (a step's [`Joints`], the
//! summary, the files) carries the count at run time.

use serde::{Serialize, Serializer};
use std::fmt;
use std::ops::Deref;

/// The joint counts this host runs: 6 (the RV-1A, the KUKA KR 16-2, …) and 7 (the KUKA LBR
/// iiwa 14 R820, …).
pub const SUPPORTED_JOINTS: [usize; 2] = [6, 7];

/// Code generic over the joint count `N`, called by [`with_joints`] with a count read at run
/// time.
pub trait WithJoints {
    /// What the call gives.
    type Output;
    /// The call for an arm of `N` joints.
    fn with<const N: usize>(self) -> Self::Output;
}

/// Calls `f` with `N` = `n`: the one place where a joint count read at run time becomes the
/// const generic of the world, the step and the core. `None` for a count this host does not
/// run (see [`SUPPORTED_JOINTS`]).
pub fn with_joints<F: WithJoints>(n: usize, f: F) -> Option<F::Output> {
    match n {
        6 => Some(f.with::<6>()),
        7 => Some(f.with::<7>()),
        _ => None,
    }
}

/// The largest joint count a [`Joints`] holds.
pub const MAX_JOINTS: usize = 7;

/// Joint values of an arm of up to [`MAX_JOINTS`] joints [rad], by value, without allocation:
/// a slice of the arm's own length (`Deref<Target = [f64]>`).
#[derive(Clone, Copy, PartialEq)]
pub struct Joints {
    len: usize,
    values: [f64; MAX_JOINTS],
}

impl Joints {
    /// The joints of an `N`-joint arm (`N ≤ MAX_JOINTS`, checked at compile time).
    pub fn new<const N: usize>(q: &[f64; N]) -> Self {
        const { assert!(N <= MAX_JOINTS, "more joints than `Joints` holds") };
        let mut values = [0.0; MAX_JOINTS];
        values[..N].copy_from_slice(q);
        Self { len: N, values }
    }

    /// The values as an array of `N` joints; `None` when the arm has another count.
    pub fn to_array<const N: usize>(&self) -> Option<[f64; N]> {
        <[f64; N]>::try_from(&**self).ok()
    }
}

impl Default for Joints {
    /// Six zero joints (the RV-1A's count).
    fn default() -> Self {
        Self::new(&[0.0; 6])
    }
}

impl<const N: usize> From<[f64; N]> for Joints {
    fn from(q: [f64; N]) -> Self {
        Self::new(&q)
    }
}

impl Deref for Joints {
    type Target = [f64];
    fn deref(&self) -> &[f64] {
        &self.values[..self.len]
    }
}

impl fmt::Debug for Joints {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_list().entries(self.iter()).finish()
    }
}

impl Serialize for Joints {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        (**self).serialize(s)
    }
}

impl IntoIterator for Joints {
    type Item = f64;
    type IntoIter = std::iter::Take<std::array::IntoIter<f64, MAX_JOINTS>>;
    fn into_iter(self) -> Self::IntoIter {
        self.values.into_iter().take(self.len)
    }
}

impl<'a> IntoIterator for &'a Joints {
    type Item = &'a f64;
    type IntoIter = std::slice::Iter<'a, f64>;
    fn into_iter(self) -> Self::IntoIter {
        self.iter()
    }
}

/// The smallest distance of any joint to one of its position limits, as a fraction of that
/// joint's half range — 1 in the middle of the range, 0 at a limit, negative beyond it — and
/// that joint (0-based). Joints without finite limits (continuous) do not count; `(+∞, 0)`
/// when none has them.
pub fn normalised_limit_margin<const N: usize>(
    q: &[f64; N],
    limits: &[needle_core::kinematics::JointLimit; N],
) -> (f64, usize) {
    let mut best = (f64::INFINITY, 0);
    for (i, (v, l)) in q.iter().zip(limits).enumerate() {
        let half = 0.5 * (l.upper - l.lower);
        if !(half.is_finite() && half > 0.0) {
            continue;
        }
        let m = (v - l.lower).min(l.upper - v) / half;
        if m < best.0 {
            best = (m, i);
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use needle_core::kinematics::JointLimit;

    #[test]
    fn joints_are_a_slice_of_the_arms_length() {
        let q = Joints::new(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0]);
        assert_eq!(q.len(), 7);
        assert_eq!(q[6], 7.0);
        assert_eq!(q.to_array::<7>(), Some([1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0]));
        assert_eq!(q.to_array::<6>(), None);
        assert_eq!(q.into_iter().sum::<f64>(), 28.0);
        let six = Joints::from([0.5; 6]);
        assert_eq!(six.len(), 6);
        assert_eq!(format!("{six:?}"), "[0.5, 0.5, 0.5, 0.5, 0.5, 0.5]");
        assert_eq!(
            serde_json::to_string(&six).unwrap(),
            "[0.5,0.5,0.5,0.5,0.5,0.5]"
        );
    }

    #[test]
    fn the_normalised_margin_is_one_mid_range_and_zero_at_a_limit() {
        let l = [
            JointLimit::from_degrees(-90.0, 90.0, 100.0),
            JointLimit::from_degrees(0.0, 20.0, 100.0),
            JointLimit {
                lower: f64::NEG_INFINITY,
                upper: f64::INFINITY,
                max_speed: 1.0,
            },
        ];
        let (m, i) = normalised_limit_margin(&[0.0, 10f64.to_radians(), 50.0], &l);
        assert!((m - 1.0).abs() < 1e-12 && i == 0, "{m} {i}");
        let (m, i) = normalised_limit_margin(&[45f64.to_radians(), 19f64.to_radians(), 0.0], &l);
        assert!((m - 0.1).abs() < 1e-12 && i == 1, "{m} {i}");
        let (m, i) = normalised_limit_margin(&[100f64.to_radians(), 10f64.to_radians(), 0.0], &l);
        assert!(m < 0.0 && i == 0, "{m} {i}");
    }
}

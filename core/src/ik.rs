//! Inverse kinematics of the needle base: damped least squares for a position + axis target.
//!
//! The tool point (needle base `B`) must reach `p*` with its z axis along `a*`; the roll about
//! the axis is free. Each iteration solves the damped least-squares problem
//! `min ‖J Δq − e‖² + λ² ‖Δq‖²` for the 6-row task `e = [p* − p(q); w_a · (z(q) × a*)]`
//! (the axis error is the rotation taking `z` onto `a*`, its component along `z` — the roll — is
//! projected out of the task, so the task has rank 5), then adds a null-space motion towards the
//! seed (which the caller picks: the current joints, or mid-range), and clamps into the joint
//! limits. It places the needle at the start of a scene; the naive (rigid) baseline follows a
//! path with it.

use crate::kinematics::Kinematics;
use core::fmt;
use nalgebra::{SMatrix, SVector, Vector3};

/// Tuning of [`solve_ik`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IkParams {
    /// Iteration cap.
    pub max_iterations: u32,
    /// Converged when the position error is below this [mm] …
    pub position_tolerance: f64,
    /// … and the axis angle below this [rad].
    pub angle_tolerance: f64,
    /// Damping λ of the least-squares step [mm/rad].
    pub damping: f64,
    /// Weight of the axis rows (turns radians into mm) [mm/rad].
    pub axis_weight: f64,
    /// Gain of the null-space pull towards the seed per iteration [-], in `[0, 1]`.
    pub seed_gain: f64,
    /// Largest joint change per iteration [rad].
    pub max_step: f64,
}

impl Default for IkParams {
    fn default() -> Self {
        Self {
            max_iterations: 200,
            position_tolerance: 1e-6,
            angle_tolerance: 1e-8,
            damping: 1.0,
            axis_weight: 100.0,
            seed_gain: 0.1,
            max_step: 0.2,
        }
    }
}

/// Outcome of [`solve_ik`] (not converging is reported here, not an error).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IkReport<const N: usize> {
    /// Final joints, within the limits [rad].
    pub q: [f64; N],
    /// Whether both tolerances were met.
    pub converged: bool,
    /// Iterations performed.
    pub iterations: u32,
    /// Final tool-point position error [mm].
    pub position_error: f64,
    /// Final angle between the tool z axis and the target axis [rad].
    pub angle_error: f64,
}

/// Invalid IK input.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub enum IkError {
    /// A target, seed or parameter value is NaN or infinite.
    NonFinite {
        /// Which input.
        field: &'static str,
    },
    /// The target axis has zero length.
    ZeroAxis,
}

impl fmt::Display for IkError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::NonFinite { field } => write!(f, "non-finite IK input {field}"),
            Self::ZeroAxis => write!(f, "IK target axis has zero length"),
        }
    }
}

impl core::error::Error for IkError {}

/// Places the tool point at `position` [mm, world] with the tool z axis along `axis` (any
/// length), starting from and staying near `seed` [rad].
///
/// # Errors
/// [`IkError`] for non-finite input or a zero axis; failing to converge is reported in
/// [`IkReport::converged`].
///
/// # Example
/// ```
/// use needle_core::{DhChain, IkParams, Kinematics, solve_ik};
///
/// let chain = DhChain::rv1a();
/// let goal = chain.tool_pose(&[0.2, 0.4, 2.0, 0.3, 0.6, -0.5]); // a reachable needle-base pose
/// let seed = chain.mid_range();
/// let ik = solve_ik(&chain, goal.translation.into(), goal.z_axis().into(), &seed, &IkParams::default())?;
/// assert!(ik.converged && chain.within_limits(&ik.q));
/// let reached = chain.tool_pose(&ik.q);
/// assert!((reached.translation - goal.translation).norm() < 1e-5); // mm
/// assert!(reached.z_axis().dot(&goal.z_axis()) > 1.0 - 1e-12); // same axis, any roll
/// # Ok::<(), needle_core::IkError>(())
/// ```
pub fn solve_ik<const N: usize>(
    chain: &impl Kinematics<N>,
    position: [f64; 3],
    axis: [f64; 3],
    seed: &[f64; N],
    params: &IkParams,
) -> Result<IkReport<N>, IkError> {
    let a = check_input(&position, &axis, seed, params)?;
    let target = Vector3::from(position);
    let mut q = *seed;
    chain.clamp_to_limits(&mut q);
    let mut report = IkReport {
        q,
        converged: false,
        iterations: 0,
        position_error: 0.0,
        angle_error: 0.0,
    };
    loop {
        let (jac, b) = chain.jacobian_tool(&q);
        let z = b.z_axis();
        let ep = target - b.translation;
        let cross = z.cross(&a);
        report.position_error = ep.norm();
        report.angle_error = libm::atan2(cross.norm(), z.dot(&a));
        report.q = q;
        if report.position_error <= params.position_tolerance
            && report.angle_error <= params.angle_tolerance
        {
            report.converged = true;
            return Ok(report);
        }
        if report.iterations >= params.max_iterations {
            return Ok(report);
        }
        report.iterations += 1;
        let ea = axis_error(&z, &a, &cross, report.angle_error);
        let (jt, e) = weighted_task(&jac, &z, &ep, &ea, params.axis_weight);
        // The pull towards the seed is switched off for the final approach (within 0.1 mm and
        // 1 mrad): the damped projector leaks a little of it into the task.
        let far = report.position_error > 0.1 || report.angle_error > 1e-3;
        let Some(dq) = damped_step(&jt, &e, &q, seed, far, params) else {
            return Ok(report);
        };
        for i in 0..N {
            q[i] += dq[i];
        }
        chain.clamp_to_limits(&mut q);
    }
}

/// Checks the input; returns the unit target axis.
fn check_input<const N: usize>(
    position: &[f64; 3],
    axis: &[f64; 3],
    seed: &[f64; N],
    params: &IkParams,
) -> Result<Vector3<f64>, IkError> {
    let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
    if !finite(position) {
        return Err(IkError::NonFinite { field: "position" });
    }
    if !finite(axis) {
        return Err(IkError::NonFinite { field: "axis" });
    }
    if !finite(seed) {
        return Err(IkError::NonFinite { field: "seed" });
    }
    let pr = [
        params.position_tolerance,
        params.angle_tolerance,
        params.damping,
        params.axis_weight,
        params.seed_gain,
        params.max_step,
    ];
    if !finite(&pr) {
        return Err(IkError::NonFinite { field: "params" });
    }
    let a = Vector3::from(*axis);
    let an = a.norm();
    if !(an > 0.0) {
        return Err(IkError::ZeroAxis);
    }
    Ok(a / an)
}

/// Axis error: the rotation vector taking the tool axis `z` onto the target axis `a` (exact
/// angle, not its sine); any axis perpendicular to `z` when they are antiparallel.
fn axis_error(
    z: &Vector3<f64>,
    a: &Vector3<f64>,
    cross: &Vector3<f64>,
    angle: f64,
) -> Vector3<f64> {
    let sin = cross.norm();
    if sin > 1e-300 {
        *cross * (angle / sin)
    } else if z.dot(a) < 0.0 {
        // Antiparallel: any axis ⊥ z works; pick one.
        let t = if libm::fabs(z[0]) < 0.9 {
            Vector3::x()
        } else {
            Vector3::y()
        };
        z.cross(&t).normalize() * core::f64::consts::PI
    } else {
        Vector3::zeros()
    }
}

/// The 6-row task with the roll about `z` projected out (`P = I − z zᵀ`): Jacobian
/// `[J_v; w_a P J_ω]` and error `[e_p; w_a P e_a]`.
fn weighted_task<const N: usize>(
    jac: &SMatrix<f64, 6, N>,
    z: &Vector3<f64>,
    ep: &Vector3<f64>,
    ea: &Vector3<f64>,
    wa: f64,
) -> (SMatrix<f64, 6, N>, SVector<f64, 6>) {
    let proj = nalgebra::Matrix3::identity() - z * z.transpose();
    let mut jt = SMatrix::<f64, 6, N>::zeros();
    let jw = proj * jac.fixed_rows::<3>(3);
    jt.fixed_rows_mut::<3>(0).copy_from(&jac.fixed_rows::<3>(0));
    jt.fixed_rows_mut::<3>(3).copy_from(&(jw * wa));
    let mut e = SVector::<f64, 6>::zeros();
    e.fixed_rows_mut::<3>(0).copy_from(ep);
    e.fixed_rows_mut::<3>(3).copy_from(&(proj * ea * wa));
    (jt, e)
}

/// The damped least-squares step `Jᵀ (J Jᵀ + λ² I)⁻¹ e` plus, when `far`, the null-space pull
/// towards the seed `(I − J⁺J) k (q_seed − q)` (`J⁺` the damped inverse), scaled so that no
/// joint moves more than `max_step`. `None` when it cannot be computed.
fn damped_step<const N: usize>(
    jt: &SMatrix<f64, 6, N>,
    e: &SVector<f64, 6>,
    q: &[f64; N],
    seed: &[f64; N],
    far: bool,
    params: &IkParams,
) -> Option<SVector<f64, N>> {
    let lam2 = params.damping * params.damping;
    let m = jt * jt.transpose() + SMatrix::<f64, 6, 6>::identity() * lam2;
    let ch = m.cholesky()?;
    let mut dq: SVector<f64, N> = jt.transpose() * ch.solve(e);
    let mut pull = SVector::<f64, N>::zeros();
    if far {
        for i in 0..N {
            pull[i] = params.seed_gain * (seed[i] - q[i]);
        }
    }
    let jp: SVector<f64, N> = jt.transpose() * ch.solve(&(jt * pull));
    dq += pull - jp;
    let big = dq.amax();
    if big > params.max_step && big > 0.0 {
        dq *= params.max_step / big;
    }
    dq.iter().all(|x| x.is_finite()).then_some(dq)
}

#[cfg(test)]
#[allow(clippy::expect_used, clippy::unwrap_used, clippy::panic)]
mod tests {
    use super::*;
    use crate::kinematics::DhChain;
    use crate::synthetic::Rng;

    /// Random reachable targets (FK of random joints inside the limits) are reached from the
    /// mid-range seed; the axis matches, the roll is free.
    #[test]
    fn reaches_random_reachable_targets() {
        let chain = DhChain::rv1a();
        let mut rng = Rng(5);
        let mut converged = 0;
        let total = 40;
        for _ in 0..total {
            let mut q = [0.0; 6];
            for (v, l) in q.iter_mut().zip(&chain.limits) {
                // Stay a little inside the limits so the target is not on the boundary.
                let pad = 0.1 * (l.upper - l.lower);
                *v = rng.range(l.lower + pad, l.upper - pad);
            }
            let b = chain.tool_pose(&q);
            let axis = b.z_axis();
            let seed = chain.mid_range();
            let rep = solve_ik(
                &chain,
                b.translation.into(),
                axis.into(),
                &seed,
                &IkParams::default(),
            )
            .expect("valid input");
            assert!(chain.within_limits(&rep.q));
            if rep.converged {
                converged += 1;
                let got = chain.tool_pose(&rep.q);
                assert!((got.translation - b.translation).norm() < 1e-5);
                assert!(got.z_axis().dot(&axis) > 1.0 - 1e-12);
            }
        }
        std::println!("{converged}/{total} converged");
        // DLS from one seed cannot reach every pose (other IK branches); most must converge.
        assert!(converged * 10 >= total * 8, "{converged}/{total}");
    }

    #[test]
    fn seed_at_solution_stays() {
        let chain = DhChain::rv1a();
        let q = [0.2, 0.4, 2.0, 0.3, 0.6, -0.5];
        let b = chain.tool_pose(&q);
        let rep = solve_ik(
            &chain,
            b.translation.into(),
            b.z_axis().into(),
            &q,
            &IkParams::default(),
        )
        .expect("valid");
        assert!(rep.converged);
        assert_eq!(rep.iterations, 0);
        assert_eq!(rep.q, q);
    }

    #[test]
    fn bad_input_is_an_error_not_a_panic() {
        let chain = DhChain::rv1a();
        let seed = chain.mid_range();
        let p = IkParams::default();
        assert_eq!(
            solve_ik(&chain, [0.0; 3], [0.0; 3], &seed, &p),
            Err(IkError::ZeroAxis)
        );
        assert!(matches!(
            solve_ik(&chain, [f64::NAN, 0.0, 0.0], [0.0, 0.0, 1.0], &seed, &p),
            Err(IkError::NonFinite { .. })
        ));
        // Unreachable target: reported, not an error.
        let rep = solve_ik(&chain, [5000.0, 0.0, 0.0], [0.0, 0.0, -1.0], &seed, &p).expect("valid");
        assert!(!rep.converged);
        assert!(rep.q.iter().all(|v| v.is_finite()));
        assert!(chain.within_limits(&rep.q));
    }
}

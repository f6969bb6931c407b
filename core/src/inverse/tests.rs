//! Unit tests of the inverse update.
#![allow(clippy::expect_used, clippy::unwrap_used, clippy::panic)]

use super::{Controller, InverseParams, StepMethod, blend_factor};
use crate::kinematics::DhChain;
use crate::payload::{Command, ComplianceFrame};
use crate::synthetic::{rigid_needle_frame, rv1a_on_turntable};
use nalgebra::Vector4;

/// The RV-1A with a rigid 120 mm needle at joints `Q_FREE`, its target where the tip is at
/// `[0.2, 0.35, 2.0, 0.1, 0.6, -0.2]`: the frame and a command buffer.
fn rigid_needle_off_target() -> (
    DhChain<6>,
    alloc::boxed::Box<ComplianceFrame<12>>,
    alloc::boxed::Box<Command<12>>,
) {
    let chain = DhChain::rv1a();
    let mut frame = ComplianceFrame::<12>::new_boxed();
    let q_target = [0.2, 0.35, 2.0, 0.1, 0.6, -0.2];
    rigid_needle_frame(&mut frame, &chain, &Q_FREE, &q_target, 120.0);
    (chain, frame, Command::<12>::new_boxed())
}

/// The joints of [`rigid_needle_off_target`]'s frame.
const Q_FREE: [f64; 6] = [0.25, 0.3, 2.05, 0.05, 0.55, -0.25];

#[test]
fn rigid_needle_newton_converges() {
    let (chain, mut frame, mut cmd) = rigid_needle_off_target();
    let q_free = Q_FREE;
    let mut ctrl = Controller::<12>::new_boxed(chain, InverseParams::default());
    let mut q = q_free;
    let mut last = f64::INFINITY;
    for _ in 0..8 {
        frame.q = q;
        let rep = ctrl.step(&frame, &mut cmd).expect("valid");
        let n = Vector4::from(rep.objective).norm();
        std::println!(
            "{:?} |T| {n:e} flags {:#x} sweeps {}",
            rep.objective,
            rep.flags,
            rep.iterations
        );
        assert!(n <= last);
        last = n;
        q = cmd.q;
    }
    assert!(last < 1e-2);
}

#[test]
fn blend_follows_the_text() {
    assert_eq!(blend_factor(false, 0.0, 20.0), 1.0);
    assert_eq!(blend_factor(false, 50.0, 20.0), 1.0);
    assert_eq!(blend_factor(true, 0.0, 20.0), 1.0);
    assert!((blend_factor(true, 5.0, 20.0) - 0.75).abs() < 1e-15);
    assert_eq!(blend_factor(true, 20.0, 20.0), 0.0);
    assert_eq!(blend_factor(true, 80.0, 20.0), 0.0);
}

/// A 7-joint arm (`Controller<M, 7>`, the RV-1A on a turntable): repeated steps on the
/// rigid-needle frame are Newton iterations on a fixed objective, which falls at every step to
/// the (reachable) target, and the step moves the extra joint too.
#[test]
fn seven_joint_newton_reduces_the_objective() {
    let chain = rv1a_on_turntable();
    let mut frame = ComplianceFrame::<12, 7>::new_boxed();
    let mut cmd = Command::<12, 7>::new_boxed();
    let q_target = [0.1, 0.2, 0.35, 2.0, 0.1, 0.6, -0.2];
    let q_free = [0.05, 0.25, 0.3, 2.05, 0.05, 0.55, -0.25];
    rigid_needle_frame(&mut frame, &chain, &q_free, &q_target, 120.0);
    let mut ctrl = Controller::<12, 7>::new_boxed(chain, InverseParams::default());
    let mut q = q_free;
    let mut norms = std::vec::Vec::new();
    for k in 0..8 {
        frame.q = q;
        let rep = ctrl.step(&frame, &mut cmd).expect("valid");
        norms.push(Vector4::from(rep.objective).norm());
        if k == 0 {
            assert!(
                rep.delta_q[0] != 0.0,
                "the turntable joint moves: {:?}",
                rep.delta_q
            );
        }
        assert_eq!(rep.delta_q.len(), 7);
        q = cmd.q;
    }
    std::println!("|T| per step: {norms:.3?}");
    assert!(norms[0] > 1.0, "a non-trivial start: {norms:?}");
    assert!(norms.windows(2).all(|w| w[1] <= w[0]), "{norms:?}");
    assert!(norms[norms.len() - 1] < 1e-2, "{norms:?}");
}

/// The tip's displacement of one step, from the objective before and after (`e = target − tip`
/// with a fixed target).
fn tip_motion(rep: &crate::payload::SolverReport) -> nalgebra::Vector3<f64> {
    nalgebra::Vector3::from_fn(|r, _| rep.objective[r] - rep.objective_after[r])
}

/// An obstacle across the tip's way: a clearance row that falls as the tip moves the way the
/// paper's update takes it, set so that this update ends half its step inside the margin. The
/// Gives `frame` one obstacle clearance row across the direction `u`: `d(λ) = d_free − u ·
/// (C_tip λ)`, worth `d0` at the frame's joints, where the tip is `target − e` (`rep`: a step
/// on the frame without the row).
fn add_clearance_across(
    frame: &mut ComplianceFrame<12>,
    rep: &crate::payload::SolverReport,
    u: &nalgebra::Vector3<f64>,
    d0: f64,
) {
    use crate::payload::ObsIndex;
    let tip0: nalgebra::Vector3<f64> = nalgebra::Vector3::from_fn(|r, _| {
        frame.o_free[ObsIndex::TARGET_POINT + r] - rep.objective[r]
    });
    let free_tip: nalgebra::Vector3<f64> =
        nalgebra::Vector3::from_fn(|r, _| frame.o_free[ObsIndex::TIP_POSITION + r]);
    frame.clearance_count = 1;
    frame.clearance_free[0] = d0 + u.dot(&(tip0 - free_tip));
    for j in 0..frame.rows() {
        frame.clearance_c[0][j] = -(0..3)
            .map(|r| u[r] * frame.c[ObsIndex::TIP_POSITION + r][j])
            .sum::<f64>();
    }
    frame.validate().expect("a valid frame with a clearance");
}

/// With `settling_margin`, a frame whose clearance comes short of what the last step predicted
/// for it widens the margin by that shortfall: the next step keeps the needle that much further
/// from the obstacle than the same step without the rule;
/// the first step (nothing predicted yet) is the step without the rule, and the allowance
/// decays by `SETTLING_DECAY` over a step whose frame met its prediction.
#[test]
fn a_clearance_short_of_its_prediction_widens_the_next_margin() {
    let (chain, mut frame, mut cmd) = rigid_needle_off_target();
    let off = InverseParams::default();
    let on = InverseParams {
        settling_margin: true,
        ..off
    };
    let rep = Controller::<12>::new_boxed(chain, off)
        .step(&frame, &mut cmd)
        .expect("valid");
    let motion = tip_motion(&rep);
    let (u, travel) = (motion.normalize(), motion.norm());
    let margin = off.clearance_margin;
    let d0 = margin + 0.5 * travel;
    add_clearance_across(&mut frame, &rep, &u, d0);

    let mut ctrl = Controller::<12>::new_boxed(chain, on);
    ctrl.step(&frame, &mut cmd).expect("valid");
    let q_first = cmd.q;
    let predicted = frame.clearance(0, &cmd.lambda);
    let mut cmd_off = Command::<12>::new_boxed();
    Controller::<12>::new_boxed(chain, off)
        .step(&frame, &mut cmd_off)
        .expect("valid");
    assert_eq!(
        q_first, cmd_off.q,
        "the first step is the step without the rule"
    );
    assert!((predicted - margin).abs() < 0.02 * travel, "{predicted} mm");

    // The next frame (the same joints) comes with its clearance `shortfall` below the
    // prediction: the gel settled towards the obstacle.
    let shortfall = 0.1;
    frame.clearance_free[0] -= d0 - (predicted - shortfall);
    ctrl.step(&frame, &mut cmd).expect("valid");
    let widened = frame.clearance(0, &cmd.lambda);
    Controller::<12>::new_boxed(chain, off)
        .step(&frame, &mut cmd_off)
        .expect("valid");
    let plain = frame.clearance(0, &cmd_off.lambda);
    std::println!("clearance planned: {plain:.4} mm without, {widened:.4} mm with the rule");
    // The clearance row binds in both (the same frame, the same linear model), one at the
    // margin, the other at the margin plus the shortfall.
    assert!(
        (widened - plain - shortfall).abs() < 0.02 * travel,
        "{widened} − {plain} mm against {shortfall}"
    );
    assert!((ctrl.margin() - (margin + shortfall)).abs() < 1e-9);

    // A frame that meets the prediction: the allowance decays.
    let now = frame.clearance(0, &cmd.lambda);
    frame.clearance_free[0] += now - (predicted - shortfall);
    ctrl.step(&frame, &mut cmd).expect("valid");
    let expected = margin + shortfall * super::SETTLING_DECAY;
    assert!(
        (ctrl.margin() - expected).abs() < 1e-6,
        "{} mm",
        ctrl.margin()
    );
}

/// QP update keeps the clearance at the margin (to first order: the rows are exact in `λ`, `λ`
/// is nonlinear in `q` only through the robot's kinematics) and says so in its flags; the
/// paper's update, blind to obstacles, crosses it.
#[test]
fn qp_step_keeps_a_clearance_the_paper_step_crosses() {
    use crate::payload::StatusFlags;
    let chain = DhChain::rv1a();
    let mut frame = ComplianceFrame::<12>::new_boxed();
    let mut cmd = Command::<12>::new_boxed();
    let q_target = [0.2, 0.35, 2.0, 0.1, 0.6, -0.2];
    let q_free = [0.25, 0.3, 2.05, 0.05, 0.55, -0.25];
    rigid_needle_frame(&mut frame, &chain, &q_free, &q_target, 120.0);
    let paper = InverseParams {
        method: StepMethod::Paper,
        ..InverseParams::default()
    };
    let rep = Controller::<12>::new_boxed(chain, paper)
        .step(&frame, &mut cmd)
        .expect("valid");
    let motion = tip_motion(&rep);
    let (u, travel) = (motion.normalize(), motion.norm());
    assert!(travel > 1.0, "a real step: {travel} mm");
    let margin = InverseParams::default().clearance_margin;
    add_clearance_across(&mut frame, &rep, &u, margin + 0.5 * travel);

    let rep = Controller::<12>::new_boxed(chain, paper)
        .step(&frame, &mut cmd)
        .expect("valid");
    let d_paper = frame.clearance(0, &cmd.lambda);
    assert!(d_paper < margin - 0.4 * travel, "paper: {d_paper} mm");
    assert_eq!(rep.flags & StatusFlags::CLEARANCE_ACTIVE, 0);

    let rep = Controller::<12>::new_boxed(chain, InverseParams::default())
        .step(&frame, &mut cmd)
        .expect("valid");
    let d_qp = frame.clearance(0, &cmd.lambda);
    std::println!("travel {travel:.3} mm, clearance: paper {d_paper:.4} mm, QP {d_qp:.4} mm");
    assert!(
        (d_qp - margin).abs() < 0.02 * travel,
        "QP: {d_qp} mm against the margin {margin}"
    );
    assert_ne!(rep.flags & StatusFlags::CLEARANCE_ACTIVE, 0);
    // And it still went where it could: most of the way it could go along the obstacle.
    assert!(tip_motion(&rep).norm() > 0.3 * travel);
}

/// Joints at their limits and a target beyond them: the QP update never commands a joint past
/// a limit or faster than its speed limit, and flags the limit.
#[test]
fn qp_step_stays_within_joint_limits_and_speeds() {
    use crate::payload::StatusFlags;
    let mut chain = DhChain::rv1a();
    let q_free = [0.25, 0.3, 2.05, 0.05, 0.55, -0.25];
    let q_target = [0.6, 0.7, 2.4, 0.4, 0.9, 0.2];
    for (l, q) in chain.limits.iter_mut().zip(&q_free) {
        l.upper = q + 0.01;
        l.max_speed = 0.05;
    }
    let mut frame = ComplianceFrame::<12>::new_boxed();
    let mut cmd = Command::<12>::new_boxed();
    rigid_needle_frame(&mut frame, &chain, &q_free, &q_target, 120.0);
    frame.dt = 0.04;
    let rep = Controller::<12>::new_boxed(chain, InverseParams::default())
        .step(&frame, &mut cmd)
        .expect("valid");
    for i in 0..6 {
        let l = &chain.limits[i];
        assert!(cmd.q[i] <= l.upper + 1e-12 && cmd.q[i] >= l.lower - 1e-12);
        assert!((cmd.q[i] - q_free[i]).abs() <= l.max_speed * frame.dt * (1.0 + 1e-9));
    }
    assert_ne!(
        rep.flags & (StatusFlags::SATURATED_LIMIT | StatusFlags::SATURATED_SPEED),
        0
    );
}

/// The QP update ranks the tip before the angles: its second stage (the angles) moves the joints
/// only where the tip's predicted position does not change, so the tip ends where the first
/// stage alone (`qp_angle_weight = 0`) takes it, up to the second-order terms of the kinematics,
/// while the angles end closer to their aims.
#[test]
fn qp_step_ranks_the_tip_before_the_angles() {
    let chain = DhChain::rv1a();
    let mut frame = ComplianceFrame::<12>::new_boxed();
    let mut cmd = Command::<12>::new_boxed();
    let q_target = [0.2, 0.35, 2.0, 0.1, 0.6, -0.2];
    let q_free = [0.25, 0.3, 2.05, 0.05, 0.55, -0.25];
    rigid_needle_frame(&mut frame, &chain, &q_free, &q_target, 120.0);
    let tip_only = InverseParams {
        qp_angle_weight: 0.0,
        ..InverseParams::default()
    };
    let one = Controller::<12>::new_boxed(chain, tip_only)
        .step(&frame, &mut cmd)
        .expect("valid");
    let q_one = cmd.q;
    let two = Controller::<12>::new_boxed(chain, InverseParams::default())
        .step(&frame, &mut cmd)
        .expect("valid");
    let dq = |q: &[f64; 6]| {
        q.iter()
            .zip(&q_free)
            .map(|(a, b)| (a - b) * (a - b))
            .sum::<f64>()
            .sqrt()
    };
    let tip = |rep: &crate::payload::SolverReport| {
        nalgebra::Vector3::from_fn(|r, _| rep.objective_after[r]).norm()
    };
    let travel = tip_motion(&one).norm();
    std::println!(
        "tip error before {:.4} mm; after: tip only {:.4} mm, both stages {:.4} mm; \
         angle term after: tip only {:.4}, both {:.4}; |Δq| {:.4} / {:.4} rad",
        nalgebra::Vector3::from_fn(|r, _| one.objective[r]).norm(),
        tip(&one),
        tip(&two),
        one.objective_after[3],
        two.objective_after[3],
        dq(&q_one),
        dq(&cmd.q),
    );
    assert!(travel > 1.0, "a real step: {travel} mm");
    assert!(
        (tip(&two) - tip(&one)).abs() < 0.02 * travel,
        "the angles moved the tip"
    );
    assert!(
        two.objective_after[3] < 0.5 * one.objective_after[3],
        "the angles were not corrected"
    );
}

/// A 7-joint arm near a joint limit (the turntable at 160° of ±170°): the third stage moves the
/// joints away from it in the motion the task leaves free. The difference it makes to the step,
/// `d`, does not move the needle tip to first order: by finite differences of the forward
/// kinematics, `|tip(q + s d) − tip(q)| / (s |d|)` is below 1 % of the same rate along the task's
/// step, at two step sizes (the remainder, ≈ 0.1 % here, is the forward-difference Jacobian's own
/// error at δq = 0.01 rad, which the projector is built from).
#[test]
fn seven_joint_limit_stage_moves_in_the_null_space_of_the_tip() {
    use crate::kinematics::Kinematics;
    let chain = rv1a_on_turntable();
    let mut frame = ComplianceFrame::<12, 7>::new_boxed();
    let mut cmd = Command::<12, 7>::new_boxed();
    let lim = 160f64.to_radians();
    let q_target = [lim - 0.02, 0.2, 0.35, 2.0, 0.1, 0.6, -0.2];
    let q_free = [lim, 0.25, 0.3, 2.05, 0.05, 0.55, -0.25];
    rigid_needle_frame(&mut frame, &chain, &q_free, &q_target, 120.0);
    frame.q = q_free;
    let off = InverseParams {
        limit_avoidance: 0.0,
        ..InverseParams::default()
    };
    let with = Controller::<12, 7>::new_boxed(chain, InverseParams::default())
        .step(&frame, &mut cmd)
        .expect("valid");
    let without = Controller::<12, 7>::new_boxed(chain, off)
        .step(&frame, &mut cmd)
        .expect("valid");
    let d: nalgebra::SVector<f64, 7> =
        nalgebra::SVector::from(with.delta_q) - nalgebra::SVector::from(without.delta_q);
    std::println!("d = {d:?}");
    assert!(
        d[0] < -1e-4,
        "the turntable moves away from its limit: {d:?}"
    );
    let tip = |q: &[f64; 7]| {
        let b = chain.tool_pose(q);
        b.translation + 120.0 * b.z_axis()
    };
    let rate = |dir: &nalgebra::SVector<f64, 7>, s: f64| {
        let mut q = q_free;
        for i in 0..7 {
            q[i] += s * dir[i];
        }
        (tip(&q) - tip(&q_free)).norm() / (s * dir.norm())
    };
    let task = nalgebra::SVector::from(without.delta_q);
    let (r_task, r1, r2) = (rate(&task, 1e-3), rate(&d, 1e-3), rate(&d, 1e-4));
    std::println!("tip mm/rad: task step {r_task:e}, limit stage {r1:e} (s 1e-3), {r2:e} (s 1e-4)");
    assert!(r_task > 10.0, "{r_task}");
    assert!(r1 < 1e-2 * r_task, "{r1} vs {r_task}");
    assert!(r2 < 1e-2 * r_task, "{r2} vs {r_task}");
}

/// Asserts that the step `rep` left the tip no farther from its target than it found it (to
/// round-off); returns the tip error before and after [mm].
fn assert_tip_not_farther(rep: &crate::payload::SolverReport, seed: u64) -> (f64, f64) {
    let tip = |t: &[f64; 4]| (t[0] * t[0] + t[1] * t[1] + t[2] * t[2]).sqrt();
    let (before, after) = (tip(&rep.objective), tip(&rep.objective_after));
    assert!(
        after <= before * (1.0 + 1e-12),
        "seed {seed}: tip error {before} → {after} mm (flags {:#x})",
        rep.flags
    );
    (before, after)
}

/// The QP step is kept only when the constraint solve at the planned joints confirms it: on
/// random inserted frames (contacts, sliding friction, 30 rows), the tip's error after the step
/// is never larger than before it, whatever the linear model promised. Regression test for the
/// needle jumping 1–6 mm off the path at the end of an insertion (simple_y with the heading kept),
/// where the linear model promised a small decrease and the solve found a large increase.
#[test]
fn qp_step_never_leaves_the_tip_farther_than_it_found_it() {
    let chain = DhChain::rv1a();
    let q = [0.1, 0.3, 2.0, 0.0, 0.5, 0.0];
    let mut frame = ComplianceFrame::<48>::new_boxed();
    let mut cmd = Command::<48>::new_boxed();
    let params = InverseParams {
        method: StepMethod::Qp,
        ..InverseParams::default()
    };
    let mut shortened = 0;
    for seed in 0..300 {
        crate::synthetic::random_frame(&mut frame, &chain, &q, 30, seed, true);
        // A long period: the speed limits allow steps large enough for contacts and friction
        // to switch inside them, where the linear model is wrong.
        frame.dt = 1.0;
        let mut ctrl = Controller::<48>::new_boxed(chain, params);
        let rep = ctrl.step(&frame, &mut cmd).expect("valid frame");
        assert_tip_not_farther(&rep, seed);
        if rep.flags & crate::payload::StatusFlags::BACKTRACKED != 0 {
            shortened += 1;
        }
    }
    std::println!("{shortened} of 300 steps shortened");
    assert!(shortened > 0, "no frame exercised the test");
}

/// `InverseParams::aim_ahead`: once inserted, a tip off the path is asked to point back towards
/// it, at the point `l` ahead of the target along the tangent; the tangent alone in the air, with
/// no look-ahead, or on the path.
#[test]
fn aim_ahead_points_the_heading_back_towards_the_path() {
    use super::objective::aim_direction;
    use nalgebra::Vector3;
    let t = Vector3::new(0.0, 0.0, -2.0); // any length
    let e = Vector3::new(1.0, 0.0, 0.0); // target − tip: the tip 1 mm off in −x
    let aim = aim_direction(true, 5.0, &t, &e);
    let expect = Vector3::new(1.0, 0.0, -5.0);
    assert!(
        (aim.normalize() - expect.normalize()).norm() < 1e-15,
        "{aim:?}"
    );
    for (inserted, l) in [(false, 5.0), (true, 0.0)] {
        assert_eq!(aim_direction(inserted, l, &t, &e), t);
    }
    let on_path = aim_direction(true, 5.0, &t, &Vector3::zeros());
    assert!((on_path.normalize() - t.normalize()).norm() < 1e-15);
    // The heading error the QP corrects: 1 mm off over 5 mm ahead is atan(1/5).
    let theta = crate::math::angle_between(&aim, &t);
    assert!((theta - (0.2f64).atan()).abs() < 1e-12, "{theta}");
}

/// `InverseParams::qp_horizon`: once inserted, the position rows are the tip's error `s`
/// further along, the target carried along the path's tangent and the tip along its heading:
/// a tip inside a bend whose heading already closes the error predicts a smaller error than it
/// has now; the error itself in the air, with no horizon, or with no tangent (the path's end).
/// Its derivative, as the QP sees it, is the difference quotient of the same function, checked
/// here against the analytic one along a turn of the heading.
#[test]
fn qp_horizon_predicts_the_error_along_the_heading() {
    use super::objective::predicted_error;
    use nalgebra::Vector3;
    let t = Vector3::new(0.0, 0.0, -1.0); // the path goes down, |t| = 1 along it
    let e = Vector3::new(0.3, 0.0, 0.0); // target − tip: the tip 0.3 mm off in −x
    // The tip heads back towards the path at 0.1 rad: 3 mm on, the error has closed.
    let a = 0.1f64;
    let h = Vector3::new(libm::sin(a), 0.0, -libm::cos(a));
    let p = predicted_error(true, 3.0, &t, &(h * 2.0), &e); // the direction's length is free
    let expect = e + (t - h) * 3.0;
    assert!((p - expect).norm() < 1e-15, "{p:?}");
    assert!(p.x.abs() < e.x.abs(), "the heading closes the error: {p:?}");
    for (inserted, s) in [(false, 3.0), (true, 0.0)] {
        assert_eq!(predicted_error(inserted, s, &t, &h, &e), e);
    }
    // At the path's end the tangent's quotient vanishes, and the horizon with it.
    assert_eq!(predicted_error(true, 3.0, &Vector3::zeros(), &h, &e), e);
    let half = predicted_error(true, 3.0, &(t * 0.5), &h, &e);
    assert!((half - (e + (t - h) * 1.5)).norm() < 1e-15, "{half:?}");
    // d/da of the prediction as the heading turns: −s (cos a, 0, sin a).
    let at = |a: f64| {
        predicted_error(
            true,
            3.0,
            &t,
            &Vector3::new(libm::sin(a), 0.0, -libm::cos(a)),
            &e,
        )
    };
    let d = 1e-6;
    let fd = (at(a + d) - at(a - d)) / (2.0 * d);
    let exact = Vector3::new(libm::cos(a), 0.0, libm::sin(a)) * -3.0;
    assert!((fd - exact).norm() < 1e-8, "{fd:?} against {exact:?}");
}

/// `secant_update` (the model of `InverseParams::replan_rejected`): afterwards the tip rows of
/// `J` and the clearance gradients reproduce the change the solve found along the rejected step
/// exactly, and are unchanged on every direction orthogonal to it; the angular row is kept.
#[test]
fn secant_update_matches_the_rejected_step_and_keeps_the_other_directions() {
    use super::objective::Objective;
    use super::step::{Clearances, Jacobian, secant_update};
    use nalgebra::{SMatrix, SVector};
    let jac0 = Jacobian::<6>::from_fn(|r, i| ((r * 7 + i * 3) % 11) as f64 - 5.0);
    let mut clear0 = Clearances::<6> {
        count: 2,
        value: [0.0; crate::payload::NCLEAR],
        gradient: [[0.0; 6]; crate::payload::NCLEAR],
        phi1: SMatrix::zeros(),
        phi2: SMatrix::zeros(),
    };
    clear0.value[..2].copy_from_slice(&[1.5, 0.7]);
    clear0.gradient[0] = [1.0, -2.0, 0.5, 0.0, 0.3, 0.1];
    clear0.gradient[1] = [0.0, 1.0, 1.0, -1.0, 0.0, 2.0];
    let obj0 = Objective {
        t: [0.4, -1.2, 2.0, 0.3],
        ..Objective::default()
    };
    let dq = SVector::<f64, 6>::from([1e-3, -2e-3, 5e-4, 0.0, 1e-3, -1e-3]);
    // What the solve at q + dq found: not what J predicted.
    let after = [0.41, -1.25, 1.93, 9.9];
    let clear_after = [1.49, 0.72];
    let (mut jac, mut clear) = (jac0, clear0);
    secant_update(&mut jac, &mut clear, &dq, &obj0, &after, |k| clear_after[k]);
    let jdq = jac * dq;
    for r in 0..3 {
        assert!((jdq[r] - (after[r] - obj0.t[r])).abs() < 1e-15, "row {r}");
    }
    assert_eq!(jac.row(3), jac0.row(3), "the angular row is kept");
    for k in 0..2 {
        let g = SVector::<f64, 6>::from(clear.gradient[k]);
        assert!((g.dot(&dq) - (clear_after[k] - clear0.value[k])).abs() < 1e-15);
    }
    // A direction orthogonal to dq sees the old model.
    let v = SVector::<f64, 6>::from([2.0, 1.0, 0.0, 3.0, 0.0, 0.0]);
    assert!(v.dot(&dq).abs() < 1e-18);
    assert!((jac * v - jac0 * v).norm() < 1e-12);
    let (g, g0) = (
        SVector::<f64, 6>::from(clear.gradient[0]),
        SVector::<f64, 6>::from(clear0.gradient[0]),
    );
    assert!((g.dot(&v) - g0.dot(&v)).abs() < 1e-12);
    // A zero step changes nothing.
    let (mut j2, mut c2) = (jac0, clear0);
    secant_update(&mut j2, &mut c2, &SVector::zeros(), &obj0, &after, |k| {
        clear_after[k]
    });
    assert_eq!(j2, jac0);
}

/// One step of `params` and one of the default on each of 300 random inserted frames (those of
/// `qp_step_never_leaves_the_tip_farther_than_it_found_it`): asserts that the tip never ends
/// farther than it started under `params`, and returns, per frame, the two reports.
fn against_the_default(
    params: InverseParams,
) -> std::vec::Vec<(crate::payload::SolverReport, crate::payload::SolverReport)> {
    let chain = DhChain::rv1a();
    let q = [0.1, 0.3, 2.0, 0.0, 0.5, 0.0];
    let mut frame = ComplianceFrame::<48>::new_boxed();
    let mut cmd = Command::<48>::new_boxed();
    (0..300)
        .map(|seed| {
            crate::synthetic::random_frame(&mut frame, &chain, &q, 30, seed, true);
            frame.dt = 1.0;
            let mut ctrl = Controller::<48>::new_boxed(chain, params);
            let rep = ctrl.step(&frame, &mut cmd).expect("valid frame");
            assert_tip_not_farther(&rep, seed);
            let mut plain = Controller::<48>::new_boxed(chain, InverseParams::default());
            let rep0 = plain.step(&frame, &mut cmd).expect("valid frame");
            (rep0, rep)
        })
        .collect()
}

/// With `InverseParams::replan_rejected` the candidates a step tries include the re-planned
/// ones, and each is still confirmed by its solve: on the random inserted frames of
/// `qp_step_never_leaves_the_tip_farther_than_it_found_it`, the tip never ends farther than it
/// started, and some steps differ from the default's (the option does something).
#[test]
fn replanned_steps_are_confirmed_too() {
    let runs = against_the_default(InverseParams {
        replan_rejected: true,
        ..InverseParams::default()
    });
    let differ = runs.iter().filter(|(a, b)| a.delta_q != b.delta_q).count();
    std::println!("{differ} of 300 steps re-planned differently");
    assert!(differ > 0, "no frame exercised the re-plan");
}

/// [`against_the_default`] for `params`, asserting that a step differs from the default's only
/// where the default's report has `flag` (the option changes nothing else) and that some do
/// (the option does something). Returns the steps that differ and the steps with `flag`.
fn differs_only_where(params: InverseParams, flag: u32, what: &str) -> (usize, usize) {
    let runs = against_the_default(params);
    let mut differ = 0;
    for (seed, (rep0, rep)) in runs.iter().enumerate() {
        if rep0.delta_q != rep.delta_q {
            differ += 1;
            assert!(rep0.flags & flag != 0, "seed {seed}: a step {what} changed");
        }
    }
    let flagged = runs.iter().filter(|(a, _)| a.flags & flag != 0).count();
    assert!(differ > 0, "no frame exercised the option");
    (differ, flagged)
}

/// With `InverseParams::second_opinion` a step whose plan its solve rejected also tries the plan
/// of the frozen active set's (linearised) model, confirmed like every candidate: on the random
/// inserted frames of `qp_step_never_leaves_the_tip_farther_than_it_found_it`, the tip never
/// ends farther than it started, some steps differ from the default's (the option does
/// something) and no step differs without a rejected first plan (it changes nothing else).
#[test]
fn second_opinion_steps_are_confirmed_and_only_follow_a_rejected_plan() {
    use crate::payload::StatusFlags;
    assert!(!InverseParams::default().second_opinion, "off by default");
    let params = InverseParams {
        second_opinion: true,
        ..InverseParams::default()
    };
    let (differ, n) = differs_only_where(
        params,
        StatusFlags::BACKTRACKED,
        "whose first plan was kept",
    );
    std::println!("{differ} of 300 steps differ, {n} had their first plan rejected");
}

/// `InverseParams::qp_angle_damping_max` changes only the second stage's damping, and only
/// where the first stage's was raised: on the random inserted frames of
/// `qp_step_never_leaves_the_tip_farther_than_it_found_it`, the update with the second stage
/// damped as the first (the cap at `damping + damping_max`, above any raised `ε`: the update
/// before the cap)
/// never leaves the tip farther than it started, every step without `NEAR_SINGULAR` is the
/// default's bit for bit, and some steps with it differ (the cap does something).
#[test]
fn angle_damping_cap_changes_only_the_steps_whose_damping_was_raised() {
    use crate::payload::StatusFlags;
    let d = InverseParams::default();
    assert_eq!(d.qp_angle_damping_max, 5.0, "the default");
    let uncapped = InverseParams {
        qp_angle_damping_max: d.damping + d.damping_max,
        ..d
    };
    let (differ, n) = differs_only_where(
        uncapped,
        StatusFlags::NEAR_SINGULAR,
        "without raised damping",
    );
    std::println!("{differ} of 300 steps differ, {n} had their damping raised");
}

/// `InverseParams::resume_held`: a step that held the joints (its confirming solves rejected the
/// plan, `Δq₁` and its halvings) and the next frame at the same joints. Without the rule the
/// second step repeats the first one's decision exactly (the same candidates, the same solves,
/// held again), which on `helix_half` froze the needle for 96 steps in a row while its target
/// ran on. With it the second step goes on halving `Δq₁` (more solves), and where a smaller step
/// passes the confirmation it moves the joints, never leaving the tip farther than it found it.
/// Random inserted frames as in `qp_step_never_leaves_the_tip_farther_than_it_found_it`, with
/// the Jacobian differenced over 1 rad: a model that over-promises along its own step, as the
/// 0.01 rad differences did at `helix_half`'s held frames (the map sticks, then slips), where a
/// step of 1/8 of `Δq₁` still made the error larger and one of 1/16 made it smaller.
#[test]
fn held_step_is_not_repeated_on_an_unchanged_frame() {
    use crate::payload::StatusFlags;
    let chain = DhChain::rv1a();
    let q = [0.1, 0.3, 2.0, 0.0, 0.5, 0.0];
    let mut frame = ComplianceFrame::<48>::new_boxed();
    let mut cmd = Command::<48>::new_boxed();
    let on = InverseParams {
        joint_step: 1.0,
        resume_held: true,
        ..InverseParams::default()
    };
    assert!(InverseParams::default().resume_held, "on by default");
    let off = InverseParams {
        resume_held: false,
        ..on
    };
    let (mut held, mut moved) = (0, 0);
    for seed in 0..1000 {
        crate::synthetic::random_frame(&mut frame, &chain, &q, 30, seed, true);
        frame.dt = 1.0;
        let mut ctrl = Controller::<48>::new_boxed(chain, on);
        let first = ctrl.step(&frame, &mut cmd).expect("valid frame");
        let was_held =
            first.flags & StatusFlags::BACKTRACKED != 0 && first.delta_q.iter().all(|d| *d == 0.0);
        if !was_held {
            continue;
        }
        held += 1;
        // The same frame again: the joints as held, the gel as it was.
        assert_eq!(cmd.q, frame.q);
        let second = ctrl.step(&frame, &mut cmd).expect("valid frame");
        // Without the rule: the very same decision.
        let mut plain = Controller::<48>::new_boxed(chain, off);
        let a = plain.step(&frame, &mut cmd).expect("valid frame");
        let b = plain.step(&frame, &mut cmd).expect("valid frame");
        assert_eq!((a.delta_q, a.solves), (b.delta_q, b.solves), "seed {seed}");
        assert_eq!(
            a.delta_q, [0.0; 6],
            "seed {seed}: held without the rule too"
        );
        // With it: more candidates, each confirmed.
        assert!(
            second.solves > first.solves,
            "seed {seed}: {} solves, as many as the held step's {}",
            second.solves,
            first.solves
        );
        let (before, after) = assert_tip_not_farther(&second, seed);
        if second.delta_q.iter().any(|d| *d != 0.0) {
            moved += 1;
            assert!(after < before, "seed {seed}: moved without getting closer");
        }
    }
    std::println!("{held} of 1000 first steps held, {moved} moved on the second");
    assert!(held > 0, "no frame held the joints");
    assert!(moved > 0, "no held frame was left by a smaller step");
}

/// Starting the solves from the sensitivities (`InverseParams::sensitivity_start`) changes where
/// they start, not what they converge to: over a sequence of frames a control period apart
/// (two seeded frames in turn, the second with its violations moved by up to 1 % and its joints
/// by 0.002 rad), the commanded joints and forces agree with the plain starts' to the solves'
/// tolerance (measured: `Δq` within 1.4·10⁻⁴ of its size at the default ω = 1, 6·10⁻⁵ at
/// ω = 1.2, whose faster convergence leaves less behind the same sweep-size test; the Jacobian
/// solves' tolerance being 10⁻⁵; `λ` within 5.4·10⁻⁵), and the steps take fewer Gauss-Seidel
/// sweeps once the first step has recorded sensitivities.
#[test]
fn sensitivity_starts_give_the_same_steps_in_fewer_sweeps() {
    use crate::payload::StatusFlags;
    use crate::synthetic::random_frame;
    const M: usize = 64;
    const NOT_CONVERGED: u32 = StatusFlags::NOT_CONVERGED;
    let chain = DhChain::rv1a();
    let q0 = [0.1, 0.3, 2.0, 0.0, 0.5, 0.0];
    for seed in [3u64, 11, 17] {
        let mut frames = [
            ComplianceFrame::<M>::new_boxed(),
            ComplianceFrame::<M>::new_boxed(),
        ];
        for f in &mut frames {
            random_frame(f, &chain, &q0, 60, seed, seed % 2 == 1);
        }
        let rows = frames[1].rows();
        for (i, d) in frames[1].delta_free[6..rows].iter_mut().enumerate() {
            *d *= 1.0 + 0.02 * (((i * 37 + 11) % 19) as f64 / 18.0 - 0.5);
        }
        frames[1].q = core::array::from_fn(|i| q0[i] + 0.002);
        let plain = InverseParams {
            sensitivity_start: false,
            ..InverseParams::default()
        };
        let mut with = Controller::<M>::new_boxed(chain, InverseParams::default());
        let mut without = Controller::<M>::new_boxed(chain, plain);
        let (mut cmd_a, mut cmd_b) = (Command::<M>::new_boxed(), Command::<M>::new_boxed());
        let (mut sweeps_with, mut sweeps_without) = (0, 0);
        for k in 0..8 {
            let f = &frames[k % 2];
            let a = with.step(f, &mut cmd_a).expect("valid");
            let b = without.step(f, &mut cmd_b).expect("valid");
            assert_eq!(a.flags & NOT_CONVERGED, 0, "seed {seed} step {k}");
            assert_eq!(b.flags & NOT_CONVERGED, 0, "seed {seed} step {k}");
            let dq = a.delta_q.iter().fold(0.0_f64, |x, v| x.max(v.abs()));
            for i in 0..6 {
                let d = (a.delta_q[i] - b.delta_q[i]).abs();
                assert!(
                    d <= 3e-4 * dq + 1e-12,
                    "seed {seed} step {k}: Δq_{i} {} against {}",
                    a.delta_q[i],
                    b.delta_q[i]
                );
            }
            let scale = cmd_b.lambda[..rows]
                .iter()
                .fold(0.0_f64, |x, v| x.max(v.abs()));
            for i in 0..rows {
                let d = (cmd_a.lambda[i] - cmd_b.lambda[i]).abs();
                assert!(
                    d <= 1e-4 * scale,
                    "seed {seed} step {k}: λ_{i} differs by {d:e}"
                );
            }
            if k > 0 {
                sweeps_with += a.iterations;
                sweeps_without += b.iterations;
            }
        }
        std::println!("seed {seed}: sweeps {sweeps_with} with, {sweeps_without} without");
        assert!(sweeps_with < sweeps_without, "seed {seed}");
    }
}

/// `InverseParams::qp_spin_weight`: the needle lies along the tool's axis, so turning the
/// tool about that axis moves neither its tip nor its angles, and without the term only the
/// damping holds the spin. On the rigid needle off its target, the step with a weight of
/// 100 mm/rad turns the needle about its axis (`ẑᵀ J_ω Δq` from the tool's Jacobian) less than
/// a tenth as much as the step without it (the default), and its tip ends as close to the
/// target (within 2 % of the tip's travel).
#[test]
fn spin_weight_holds_the_needle_from_turning_about_its_axis() {
    use crate::kinematics::Kinematics;
    let (chain, frame, mut cmd) = rigid_needle_off_target();
    let off = InverseParams::default();
    assert_eq!(off.qp_spin_weight, 0.0, "off by default");
    let d = InverseParams {
        qp_spin_weight: 100.0,
        ..off
    };
    let (jt, tool) = chain.jacobian_tool(&Q_FREE);
    let z = tool.z_axis();
    let spin = |dq: &[f64; 6]| {
        let w = jt.fixed_rows::<3>(3) * nalgebra::SVector::<f64, 6>::from(*dq);
        z.dot(&w)
    };
    let tip = |rep: &crate::payload::SolverReport| {
        nalgebra::Vector3::from_fn(|r, _| rep.objective_after[r]).norm()
    };
    let with = Controller::<12>::new_boxed(chain, d)
        .step(&frame, &mut cmd)
        .expect("valid");
    let without = Controller::<12>::new_boxed(chain, off)
        .step(&frame, &mut cmd)
        .expect("valid");
    let (s1, s0) = (spin(&with.delta_q), spin(&without.delta_q));
    let travel = tip_motion(&without).norm();
    std::println!(
        "spin about the needle: {s1:.3e} rad with, {s0:.3e} rad without; tip error after \
         {:.4} / {:.4} mm (travel {travel:.3} mm)",
        tip(&with),
        tip(&without)
    );
    assert!(s0.abs() > 1e-3, "the unweighted step spins: {s0}");
    assert!(s1.abs() < 0.1 * s0.abs(), "{s1} vs {s0}");
    assert!(
        (tip(&with) - tip(&without)).abs() < 0.02 * travel,
        "the spin term moved the tip"
    );
}

/// Regression (public `tilt_large`, step 105): before the puncture the tip is held only by a
/// one-sided contact with the surface, and a step that turned the needle about its base swung
/// the tip 17.8 mm off its target in one step while the base stayed within its trust region.
/// The needle in the air (a rigid 120 mm needle, not inserted) asked to tilt its wrist by
/// 0.15 rad: the tip's rigid motion `(J_v − [r]× J_ω) Δq` keeps within `max_base_step` on
/// every axis (the base's bound alone let it move 27.5 mm on one axis, the base 2 mm).
#[test]
fn tip_swung_about_the_needle_base_is_bounded_by_the_trust_region() {
    use crate::kinematics::Kinematics;
    use crate::payload::StatusFlags;
    let chain = DhChain::rv1a();
    let mut q_target = Q_FREE;
    q_target[4] += 0.15;
    let mut frame = ComplianceFrame::<12>::new_boxed();
    let mut cmd = Command::<12>::new_boxed();
    rigid_needle_frame(&mut frame, &chain, &Q_FREE, &q_target, 120.0);
    assert_eq!(frame.inserted, 0, "in the air");
    let bound = 2.0;
    let params = InverseParams {
        max_base_step: bound,
        ..InverseParams::default()
    };
    let rep = Controller::<12>::new_boxed(chain, params)
        .step(&frame, &mut cmd)
        .expect("valid");
    let (jt, tool) = chain.jacobian_tool(&Q_FREE);
    let dq = nalgebra::SVector::<f64, 6>::from(rep.delta_q);
    let base = jt.fixed_rows::<3>(0) * dq;
    let r = nalgebra::Vector3::from_fn(|i, _| frame.o_free[i]) - tool.translation;
    let tip = base - r.cross(&(jt.fixed_rows::<3>(3) * dq));
    let amax = |v: &nalgebra::Vector3<f64>| v.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    std::println!(
        "largest axis of the step's motion: base {:.4} mm, tip (rigid) {:.4} mm; predicted \
         tip travel {:.4} mm; flags {:#x}",
        amax(&base),
        amax(&tip),
        tip_motion(&rep).norm(),
        rep.flags
    );
    assert!(amax(&tip) <= bound * (1.0 + 1e-6), "{tip:?}");
    assert!(amax(&tip) > 0.99 * bound, "the tip's bound holds the step");
    assert_ne!(rep.flags & StatusFlags::STEP_LIMITED, 0);
}

/// The tip's rows before the puncture (`ToolRows::tip`, `J_v − [r]× J_ω`) against central
/// differences of the forward kinematics: the tip carried rigidly by the tool,
/// `T(q) · (T(q₀)⁻¹ · tip₀)`, over 10⁻⁶ rad per joint, at two poses and needle lengths. Once
/// inserted there are no such rows.
#[test]
fn tip_rows_before_puncture_match_finite_differences_of_the_forward_kinematics() {
    use crate::kinematics::Kinematics;
    use crate::payload::ObsIndex;
    use nalgebra::Vector3;
    let chain = DhChain::rv1a();
    let mut frame = ComplianceFrame::<12>::new_boxed();
    let h = 1e-6;
    let poses = [
        (Q_FREE, [0.2, 0.35, 2.0, 0.1, 0.6, -0.2], 120.0),
        (
            [-0.4, 0.1, 1.7, 0.6, -0.9, 1.2],
            [-0.35, 0.15, 1.75, 0.5, -0.8, 1.1],
            60.0,
        ),
    ];
    for (q0, q_target, length) in poses {
        rigid_needle_frame(&mut frame, &chain, &q0, &q_target, length);
        let params = InverseParams {
            max_base_step: 5.0,
            ..InverseParams::default()
        };
        let ctrl = Controller::<12>::new_boxed(chain, params);
        let rows = ctrl
            .tool_rows(&frame)
            .tip
            .expect("rows before the puncture");
        let pose0 = chain.tool_pose(&q0);
        let tip0 = Vector3::from_column_slice(&frame.o_free[ObsIndex::TIP_POSITION..][..3]);
        let local = pose0.rotation.transpose() * (tip0 - pose0.translation);
        let mut largest = 0.0f64;
        for i in 0..6 {
            let (mut qp, mut qm) = (q0, q0);
            qp[i] += h;
            qm[i] -= h;
            let fd = (chain.tool_pose(&qp).transform_point(&local)
                - chain.tool_pose(&qm).transform_point(&local))
                / (2.0 * h);
            let col = rows.column(i);
            let err = (col - fd).norm();
            largest = largest.max(err / fd.norm().max(1.0));
            assert!(
                err <= 1e-5 * fd.norm().max(1.0),
                "joint {i}: rows {col:?}, differences {fd:?}"
            );
        }
        std::println!("length {length} mm: largest relative difference {largest:.2e}");
        frame.inserted = 1;
        assert!(
            ctrl.tool_rows(&frame).tip.is_none(),
            "inserted: no tip rows"
        );
    }
}

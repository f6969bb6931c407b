//! Unit tests of the inverse update.
#![allow(clippy::expect_used, clippy::unwrap_used, clippy::panic)]

use super::{Controller, InverseParams, blend_factor};
use crate::kinematics::DhChain;
use crate::payload::{Command, ComplianceFrame};
use crate::synthetic::{rigid_needle_frame, rv1a_on_turntable};
use nalgebra::Vector4;

#[test]
fn rigid_needle_newton_converges() {
    let chain = DhChain::rv1a();
    let mut frame = ComplianceFrame::<12>::new_boxed();
    let mut cmd = Command::<12>::new_boxed();
    let q_target = [0.2, 0.35, 2.0, 0.1, 0.6, -0.2];
    let q_free = [0.25, 0.3, 2.05, 0.05, 0.55, -0.25];
    rigid_needle_frame(&mut frame, &chain, &q_free, &q_target, 120.0);
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

//! Property tests: random and hostile frames never panic the core — they are rejected with an
//! error — and valid random SPD frames solve to finite forces.

use needle_core::constraint::{ActiveSet, BlockGs, GsParams};
use needle_core::payload::{GroupKind, RowGroup, ValidationError};
use needle_core::synthetic::random_frame;
use needle_core::{Command, ComplianceFrame, Controller, DhChain, InverseParams, StepError};
use proptest::prelude::*;

const M: usize = 30;

fn boxed_frame() -> Box<ComplianceFrame<M>> {
    ComplianceFrame::new_boxed()
}

fn boxed_command() -> Box<Command<M>> {
    Command::new_boxed()
}

const Q: [f64; 6] = [0.1, 0.3, 2.0, 0.0, 0.5, 0.0];

fn hostile_f64() -> impl Strategy<Value = f64> {
    prop_oneof![
        Just(f64::NAN),
        Just(f64::INFINITY),
        Just(f64::NEG_INFINITY),
        Just(0.0),
        Just(-1.0),
        Just(1e308),
        Just(-1e-308),
        any::<f64>(),
    ]
}

/// One corruption of a valid frame.
#[derive(Clone, Debug)]
enum Corruption {
    Version(u32),
    Rows(u32),
    GroupCount(u32),
    GroupKind(usize, u32),
    GroupStart(usize, u32),
    GroupLen(usize, u32),
    Mu(usize, f64),
    R0(usize, f64),
    W(usize, usize, f64),
    Delta(usize, f64),
    PFree(usize, f64),
    RFree(usize, usize, f64),
    OFree(usize, f64),
    C(usize, usize, f64),
    Depth(f64),
    Q(usize, f64),
    Dt(f64),
}

fn corruption() -> impl Strategy<Value = Corruption> {
    prop_oneof![
        any::<u32>().prop_map(Corruption::Version),
        any::<u32>().prop_map(Corruption::Rows),
        any::<u32>().prop_map(Corruption::GroupCount),
        (0..M, any::<u32>()).prop_map(|(g, k)| Corruption::GroupKind(g, k)),
        (0..M, any::<u32>()).prop_map(|(g, k)| Corruption::GroupStart(g, k)),
        (0..M, any::<u32>()).prop_map(|(g, k)| Corruption::GroupLen(g, k)),
        (0..M, hostile_f64()).prop_map(|(g, v)| Corruption::Mu(g, v)),
        (0..M, hostile_f64()).prop_map(|(g, v)| Corruption::R0(g, v)),
        (0..M, 0..M, hostile_f64()).prop_map(|(i, j, v)| Corruption::W(i, j, v)),
        (0..M, hostile_f64()).prop_map(|(i, v)| Corruption::Delta(i, v)),
        (0..3usize, hostile_f64()).prop_map(|(i, v)| Corruption::PFree(i, v)),
        (0..3usize, 0..3usize, hostile_f64()).prop_map(|(i, j, v)| Corruption::RFree(i, j, v)),
        (0..15usize, hostile_f64()).prop_map(|(i, v)| Corruption::OFree(i, v)),
        (0..15usize, 0..M, hostile_f64()).prop_map(|(i, j, v)| Corruption::C(i, j, v)),
        hostile_f64().prop_map(Corruption::Depth),
        (0..6usize, hostile_f64()).prop_map(|(i, v)| Corruption::Q(i, v)),
        hostile_f64().prop_map(Corruption::Dt),
    ]
}

fn apply(f: &mut ComplianceFrame<M>, c: &Corruption) {
    match *c {
        Corruption::Version(v) => f.version = v,
        Corruption::Rows(v) => f.m = v,
        Corruption::GroupCount(v) => f.group_count = v,
        Corruption::GroupKind(g, v) => f.groups[g].kind = v,
        Corruption::GroupStart(g, v) => f.groups[g].start = v,
        Corruption::GroupLen(g, v) => f.groups[g].len = v,
        Corruption::Mu(g, v) => f.groups[g].mu = v,
        Corruption::R0(g, v) => f.groups[g].r0 = v,
        Corruption::W(i, j, v) => f.w[i][j] = v,
        Corruption::Delta(i, v) => f.delta_free[i] = v,
        Corruption::PFree(i, v) => f.p_free[i] = v,
        Corruption::RFree(i, j, v) => f.r_free[i][j] = v,
        Corruption::OFree(i, v) => f.o_free[i] = v,
        Corruption::C(i, j, v) => f.c[i][j] = v,
        Corruption::Depth(v) => f.insertion_depth = v,
        Corruption::Q(i, v) => f.q[i] = v,
        Corruption::Dt(v) => f.dt = v,
    }
}

proptest! {
    // A fixed seed: CI runs the same cases every time (change it to explore others).
    #![proptest_config(ProptestConfig {
        cases: 400,
        rng_seed: proptest::test_runner::RngSeed::Fixed(2026),
        ..ProptestConfig::default()
    })]

    /// A valid frame with up to three corruptions: the step either succeeds with finite output
    /// or returns an error; it never panics.
    #[test]
    fn corrupted_frames_never_panic(seed in any::<u64>(), m in 6usize..=M, contact in any::<bool>(),
                                    cs in proptest::collection::vec(corruption(), 1..4)) {
        let mut frame = boxed_frame();
        let mut cmd = boxed_command();
        random_frame(&mut frame, &DhChain::rv1a(), &Q, m, seed, contact);
        for c in &cs {
            apply(&mut frame, c);
        }
        let mut ctrl = Controller::<M>::new(DhChain::rv1a(), InverseParams::default());
        let before = cmd.q;
        match ctrl.step(&frame, &mut cmd) {
            Ok(_) => {
                prop_assert!(frame.validate().is_ok());
                prop_assert!(cmd.q.iter().all(|x| x.is_finite()));
                prop_assert!(cmd.lambda[..frame.m as usize].iter().all(|x| x.is_finite()));
                // No NaN anywhere in an accepted command (issue "trust": 7 hostile frames got
                // Ok with NaN in the report's objective).
                prop_assert_eq!(cmd.validate(), Ok(()));
            }
            Err(e) => {
                // A frame that validates can still hold a W that is not positive definite (a
                // corrupted diagonal: see `tiny_w_diagonal_is_not_positive_definite`), or finite
                // values so extreme that the step overflows (e.g. `p_free = 1e308`).
                let explained = frame.validate().is_err()
                    || matches!(e, StepError::NotPositiveDefinite { .. } | StepError::NonFinite { .. });
                prop_assert!(explained, "unexplained error: {e:?}");
                prop_assert_eq!(cmd.q, before, "command untouched on error");
                let _ = format!("{e}");
            }
        }
    }

    /// A command with hostile values in any field passes `Command::validate` only when every
    /// field is finite and the joints within two turns.
    #[test]
    fn commands_validate_only_when_every_field_is_finite(
        m in 0u32..=M as u32,
        q in proptest::collection::vec(hostile_f64(), 6),
        lambda in hostile_f64(),
        row in 0usize..M,
        residual in hostile_f64(),
        objective in hostile_f64(),
        after in hostile_f64(),
        dq in hostile_f64(),
    ) {
        let mut cmd = boxed_command();
        cmd.m = m;
        cmd.q.copy_from_slice(&q);
        cmd.lambda[row] = lambda;
        cmd.report.final_residual = residual;
        cmd.report.objective[0] = objective;
        cmd.report.objective_after[1] = after;
        cmd.report.delta_q[2] = dq;
        if cmd.validate().is_ok() {
            let used = (row < m as usize).then_some(lambda);
            let report = [residual, objective, after, dq];
            let mut all = q.iter().chain(used.iter()).chain(report.iter());
            prop_assert!(all.all(|x| x.is_finite()));
            prop_assert!(q.iter().all(|x| x.abs() <= needle_core::payload::MAX_JOINT_ANGLE));
            prop_assert!(residual >= 0.0);
        }
    }

    /// Arbitrary bytes in the header and group table of an otherwise zero frame.
    #[test]
    fn garbage_headers_are_rejected(version in any::<u32>(), m in any::<u32>(), count in any::<u32>(),
                                    groups in proptest::collection::vec((any::<u32>(), any::<u32>(), any::<u32>(), hostile_f64(), hostile_f64()), 0..8)) {
        let mut frame = boxed_frame();
        frame.version = version;
        frame.m = m;
        frame.group_count = count;
        for (i, &(kind, start, len, mu, r0)) in groups.iter().enumerate() {
            frame.groups[i] = RowGroup { kind, start, len, reserved: 0, mu, r0 };
        }
        let mut ctrl = Controller::<M>::new(DhChain::rv1a(), InverseParams::default());
        let mut cmd = boxed_command();
        // Zero W has a zero diagonal, so nothing here can be valid.
        prop_assert!(ctrl.step(&frame, &mut cmd).is_err());
    }

    /// Valid random SPD problems (any mix of group kinds, any warm start) solve to finite λ that
    /// satisfy the group laws.
    #[test]
    fn random_spd_problems_solve_finite(seed in any::<u64>(), m in 6usize..=M, contact in any::<bool>(),
                                        warm in proptest::collection::vec(-1e3f64..1e3, M)) {
        let mut frame = boxed_frame();
        random_frame(&mut frame, &DhChain::rv1a(), &Q, m, seed, contact);
        let mut gs = Box::new(BlockGs::<M>::new());
        gs.prepare_frame(&frame).expect("valid");
        let mut lambda = [0.0; M];
        lambda.copy_from_slice(&warm);
        let rep = gs.solve(&frame.w, &frame.delta_free, &mut lambda, &GsParams { max_iterations: 2000, ..GsParams::default() });
        let m = frame.m as usize;
        prop_assert!(lambda[..m].iter().all(|x| x.is_finite()));
        prop_assert!(rep.residual.is_finite());
        for g in frame.used_groups() {
            let s = g.start as usize;
            match GroupKind::from_raw(g.kind) {
                Some(GroupKind::Contact) => {
                    prop_assert!(lambda[s] >= 0.0);
                    prop_assert!(lambda[s + 1].hypot(lambda[s + 2]) <= g.mu * lambda[s] * (1.0 + 1e-12) + 1e-300);
                }
                Some(GroupKind::Sliding) => {
                    let bound = g.mu * lambda[s].hypot(lambda[s + 1]) + g.r0;
                    prop_assert!(lambda[s + 2].abs() <= bound * (1.0 + 1e-12) + 1e-300);
                }
                _ => {}
            }
        }
    }
}

/// Every group's law on the residual `w = W λ − δ` directly, to `tol` (absolute, on `w`):
/// bilateral rows closed; a contact open (`w_n ≥ 0`), or pressed (`w_n = 0`) and sticking
/// (`w_t = 0` inside the disk) or sliding against its force (`w_t` opposite to `λ_t` on the disk
/// edge); a sliding point's lateral rows closed and its axial force inside its bound and still,
/// or on it and slipping against it.
fn laws_hold(frame: &ComplianceFrame<M>, lambda: &[f64; M], tol: f64) -> Result<(), String> {
    let m = frame.m as usize;
    let w: Vec<f64> = (0..m)
        .map(|i| (0..m).map(|j| frame.w[i][j] * lambda[j]).sum::<f64>() - frame.delta_free[i])
        .collect();
    let edge = |x: f64, bound: f64| x >= bound * (1.0 - 1e-7);
    for g in frame.used_groups() {
        let s = g.start as usize;
        let fail = |what: &str| {
            Err(format!(
                "group at row {s}: {what}; λ {:?}, w {:?}",
                &lambda[s..s + g.len as usize],
                &w[s..s + g.len as usize]
            ))
        };
        match GroupKind::from_raw(g.kind) {
            Some(GroupKind::Bilateral)
                if w[s..s + g.len as usize].iter().any(|x| x.abs() > tol) =>
            {
                return fail("bilateral row open");
            }
            Some(GroupKind::Contact) => {
                let (n, t) = (lambda[s], lambda[s + 1].hypot(lambda[s + 2]));
                if n < 0.0 || t > g.mu * n * (1.0 + 1e-9) {
                    return fail("force outside its cone");
                }
                if n == 0.0 {
                    if w[s] < -tol {
                        return fail("closed but penetrating");
                    }
                    continue;
                }
                if w[s].abs() > tol {
                    return fail("pressed but not closed");
                }
                let wt = w[s + 1].hypot(w[s + 2]);
                if !edge(t, g.mu * n) {
                    if wt > tol {
                        return fail("sticking but slipping");
                    }
                } else {
                    let (u1, u2) = (lambda[s + 1] / t, lambda[s + 2] / t);
                    let along = u1 * w[s + 1] + u2 * w[s + 2];
                    let across = u1 * w[s + 2] - u2 * w[s + 1];
                    if along > tol || across.abs() > tol {
                        return fail("sliding, but not against its force");
                    }
                }
            }
            Some(GroupKind::Sliding) => {
                if w[s].abs() > tol || w[s + 1].abs() > tol {
                    return fail("lateral row open");
                }
                let bound = g.mu * lambda[s].hypot(lambda[s + 1]) + g.r0;
                let a = lambda[s + 2];
                if a.abs() > bound * (1.0 + 1e-9) {
                    return fail("axial force beyond its bound");
                }
                if !edge(a.abs(), bound) {
                    if w[s + 2].abs() > tol {
                        return fail("axial force inside its bound but slipping");
                    }
                } else if a.signum() * w[s + 2] > tol {
                    return fail("axial force on its bound, slipping with it");
                }
            }
            _ => {}
        }
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: 256,
        failure_persistence: None,
        ..ProptestConfig::default()
    })]

    /// The active-set methods that polish a slow solve (`solve_on_active_sets`, the first
    /// polish; `solve_on_active_sets_feasible`, the later ones) on random frames with a tip
    /// contact and sliding points, from a rough Gauss-Seidel iterate: they never leave a
    /// non-finite force, and whenever one reports it finished, its answer meets every group's
    /// law on the residual directly and Gauss-Seidel confirms it in at most two sweeps.
    #[test]
    fn active_set_methods_finish_only_on_solutions(seed in any::<u64>(), m in 9usize..=M,
                                                   rough in 0u32..40, feasible in any::<bool>()) {
        let mut frame = boxed_frame();
        random_frame(&mut frame, &DhChain::rv1a(), &Q, m, seed, true);
        let mut gs = Box::new(BlockGs::<M>::new());
        gs.prepare_frame(&frame).expect("valid");
        let delta = frame.delta_free;
        let mut lambda = [0.0; M];
        gs.solve(&frame.w, &delta, &mut lambda, &GsParams { max_iterations: rough, ..GsParams::default() });
        let mut set = needle_core::boxed_zeroed::<ActiveSet<M>>();
        let done = if feasible {
            gs.solve_on_active_sets_feasible(&frame.w, &delta, &mut lambda, &mut set, 60)
        } else {
            gs.solve_on_active_sets(&frame.w, &delta, &mut lambda, &mut set, 30)
        };
        let m = frame.m as usize;
        prop_assert!(lambda[..m].iter().all(|x| x.is_finite()));
        if done {
            let scale = delta[..m].iter().fold(0.0f64, |a, x| a.max(x.abs()));
            let tol = 1e-9 * scale;
            if let Err(e) = laws_hold(&frame, &lambda, tol) {
                prop_assert!(false, "finished on a non-solution (feasible {}): {}", feasible, e);
            }
            let rep = gs.solve(&frame.w, &delta, &mut lambda, &GsParams { max_iterations: 10, ..GsParams::default() });
            prop_assert!(rep.converged && rep.iterations <= 2, "{:?}", rep);
        }
    }
}

/// Regression (the case kept in `core_proptest.proptest-regressions`): a frame whose W passes
/// validation (finite, symmetric, positive diagonal) but whose last diagonal entry is 1.9e-308
/// has a Schur complement of the base block that is not positive definite. The step used to
/// report it as `InvalidFrame(NonPositiveDiagonal)` of a frame that validates, then as
/// `NonFinite`; it is its own kind.
#[test]
fn tiny_w_diagonal_is_not_positive_definite() {
    let mut frame = boxed_frame();
    random_frame(&mut frame, &DhChain::rv1a(), &Q, 12, 0, false);
    frame.w[11][11] = 1.856838476935538e-308;
    assert_eq!(frame.validate(), Ok(()));
    let mut ctrl = Controller::<M>::new_boxed(DhChain::rv1a(), InverseParams::default());
    let mut cmd = boxed_command();
    let e = ctrl
        .step(&frame, &mut cmd)
        .expect_err("W is not positive definite");
    assert!(matches!(e, StepError::NotPositiveDefinite { .. }), "{e:?}");
    assert!(e.to_string().contains("not positive definite"), "{e}");
    assert_eq!(cmd.q, [0.0; 6], "command untouched on error");
}

#[test]
fn error_variants_carry_their_fields() {
    let mut frame = boxed_frame();
    random_frame(&mut frame, &DhChain::rv1a(), &Q, M, 7, true);
    assert_eq!(frame.validate(), Ok(()));
    let mut f = frame.clone();
    f.m = M as u32 + 1;
    assert_eq!(
        f.validate(),
        Err(ValidationError::CapacityExceeded {
            requested: M + 1,
            capacity: M
        })
    );
    let mut f = frame.clone();
    f.w[3][4] = f64::NAN;
    assert_eq!(
        f.validate(),
        Err(ValidationError::NonFinite {
            field: "w",
            index: 3 * M + 4
        })
    );
    let mut f = frame.clone();
    f.groups[1].mu = -0.1;
    assert_eq!(
        f.validate(),
        Err(ValidationError::NegativeFriction { group: 1 })
    );
    let mut f = frame.clone();
    f.w[7][7] = 0.0;
    assert_eq!(
        f.validate(),
        Err(ValidationError::NonPositiveDiagonal { row: 7 })
    );
    let mut f = frame.clone();
    f.version = 99;
    assert!(matches!(
        f.validate(),
        Err(ValidationError::VersionMismatch { found: 99, .. })
    ));
    let mut f = frame.clone();
    f.m = 5;
    assert!(matches!(
        f.validate(),
        Err(ValidationError::TooFewRows { m: 5, min: 6 })
    ));
    let mut f = frame.clone();
    f.groups[2].start += 1;
    assert!(matches!(
        f.validate(),
        Err(ValidationError::GroupLayout { group: 2, .. })
    ));
    // Commands are validated on receipt by the host.
    let mut cmd = boxed_command();
    assert_eq!(cmd.validate(), Ok(()));
    cmd.m = M as u32 + 1;
    assert!(matches!(
        cmd.validate(),
        Err(ValidationError::CapacityExceeded { .. })
    ));
    cmd.m = 3;
    cmd.lambda[2] = f64::INFINITY;
    assert_eq!(
        cmd.validate(),
        Err(ValidationError::NonFinite {
            field: "lambda",
            index: 2
        })
    );
    let e: &dyn std::error::Error = &ValidationError::NotRotation;
    assert!(!e.to_string().is_empty());
}

//! Unit tests of the QP solver.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use super::*;

/// KKT conditions of a solution: feasibility, `u ≥ 0`, complementarity, stationarity.
fn check_kkt<const N: usize, const C: usize>(qp: &Qp<N, C>, tol: f64) {
    let (n, m) = (qp.n, qp.m);
    let mut grad = [0.0; N];
    for i in 0..n {
        grad[i] = qp.g[i] + (0..n).map(|k| qp.h[i][k] * qp.x[k]).sum::<f64>();
    }
    for k in 0..m {
        let s = qp.row_dot(k) - qp.b[k];
        assert!(s >= -tol, "row {k} violated by {s}");
        let u = qp.multiplier(k);
        assert!(u >= -tol, "multiplier {u} of row {k}");
        assert!((u * s).abs() <= tol, "complementarity {u} {s}");
        for i in 0..n {
            grad[i] -= u * qp.a[k][i];
        }
    }
    for (i, g) in grad[..n].iter().enumerate() {
        assert!(g.abs() <= tol, "stationarity {i}: {g}");
    }
}

#[test]
fn unconstrained_is_the_newton_step() {
    let mut qp = Qp::<3, 4>::new();
    qp.reset(2).unwrap();
    qp.add_square(&[1.0, 0.0], -2.0, 0.5);
    qp.add_square(&[0.0, 1.0], 3.0, 0.5);
    let rep = qp.solve().unwrap();
    assert!(rep.optimal);
    assert!((qp.solution()[0] - 2.0).abs() < 1e-14);
    assert!((qp.solution()[1] + 3.0).abs() < 1e-14);
}

#[test]
fn bounds_and_a_general_row() {
    // min (x−2)² + (y−2)²  s.t.  x + y ≤ 2, 0 ≤ x ≤ 0.5: x = 0.5, y = 1.5.
    let mut qp = Qp::<2, 8>::new();
    qp.reset(2).unwrap();
    qp.add_square(&[1.0, 0.0], -2.0, 1.0);
    qp.add_square(&[0.0, 1.0], -2.0, 1.0);
    qp.add_row(&[-1.0, -1.0], -2.0).unwrap();
    qp.add_bounds(&[0.0, f64::NEG_INFINITY], &[0.5, f64::INFINITY])
        .unwrap();
    let rep = qp.solve().unwrap();
    assert!(rep.optimal);
    assert!((qp.solution()[0] - 0.5).abs() < 1e-12);
    assert!((qp.solution()[1] - 1.5).abs() < 1e-12);
    check_kkt(&qp, 1e-12);
}

#[test]
fn infeasible_rows_are_reported() {
    let mut qp = Qp::<2, 4>::new();
    qp.reset(2).unwrap();
    qp.add_diagonal(1.0);
    qp.add_row(&[1.0, 0.0], 1.0).unwrap();
    qp.add_row(&[-1.0, 0.0], 0.0).unwrap();
    assert!(matches!(qp.solve(), Err(QpError::Infeasible { .. })));
}

#[test]
fn indefinite_hessian_is_refused() {
    let mut qp = Qp::<2, 2>::new();
    qp.reset(2).unwrap();
    qp.hessian_mut()[0][0] = 1.0;
    qp.hessian_mut()[1][1] = -1.0;
    assert_eq!(qp.solve(), Err(QpError::NotPositiveDefinite { pivot: 1 }));
    qp.hessian_mut()[1][1] = f64::NAN;
    assert_eq!(qp.solve(), Err(QpError::NonFinite));
}

#[test]
fn capacity_is_checked() {
    let mut qp = Qp::<2, 1>::new();
    assert!(qp.reset(3).is_err());
    qp.reset(2).unwrap();
    qp.add_row(&[1.0, 0.0], 0.0).unwrap();
    assert!(qp.add_row(&[1.0, 0.0], 0.0).is_err());
}

/// Random strictly convex programs with a known feasible point: the solution satisfies the
/// KKT conditions, and no feasible sample point has a lower objective.
#[test]
fn random_programs_satisfy_kkt() {
    let mut seed = 0x2545F4914F6CDD1Du64;
    let mut rnd = move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        (seed >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    };
    for trial in 0..300 {
        let n = 1 + trial % 7;
        let m = trial % 17;
        let mut qp = Qp::<7, 30>::new();
        qp.reset(n).unwrap();
        for _ in 0..n + 2 {
            let c: [f64; 7] = core::array::from_fn(|_| rnd());
            qp.add_square(&c[..n], rnd(), 1.0);
        }
        qp.add_diagonal(1e-3);
        // Rows through a random feasible point x0 (slack ≥ 0).
        let x0: [f64; 7] = core::array::from_fn(|_| rnd());
        for _ in 0..m {
            let a: [f64; 7] = core::array::from_fn(|_| rnd());
            let ax0: f64 = (0..n).map(|i| a[i] * x0[i]).sum();
            qp.add_row(&a[..n], ax0 - 0.5 * (rnd() + 1.0)).unwrap();
        }
        let lo: [f64; 7] = core::array::from_fn(|i| x0[i] - 1.0 - rnd().abs());
        let hi: [f64; 7] = core::array::from_fn(|i| x0[i] + 1.0 + rnd().abs());
        qp.add_bounds(&lo[..n], &hi[..n]).unwrap();
        let rep = qp.solve().unwrap();
        assert!(rep.optimal, "trial {trial}");
        check_kkt(&qp, 1e-9);
    }
}

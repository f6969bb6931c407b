//! The faer wrapper: pattern, symmetric product, factorisation, solves and errors.

use needle_host::linalg::{Cholesky, LinalgError, SymmetricMatrix, SymmetricPattern};

/// 2-D Laplacian on a `k × k` grid plus `shift` on the diagonal (SPD for `shift > 0`).
fn laplacian(k: usize, shift: f64) -> SymmetricMatrix {
    let n = k * k;
    let id = |i: usize, j: usize| i + k * j;
    let mut entries = Vec::new();
    for j in 0..k {
        for i in 0..k {
            if i + 1 < k {
                entries.push((id(i + 1, j), id(i, j))); // lower triangle on purpose
            }
            if j + 1 < k {
                entries.push((id(i, j), id(i, j + 1)));
            }
        }
    }
    let pattern = SymmetricPattern::from_entries(n, entries.iter().copied());
    let mut a = SymmetricMatrix::zeros(pattern);
    for r in 0..n {
        let s = a.pattern().slot(r, r).unwrap();
        a.values[s] = 4.0 + shift;
    }
    for &(r, c) in &entries {
        let s = a.pattern().slot(r, c).unwrap();
        assert_eq!(Some(s), a.pattern().slot(c, r));
        a.values[s] = -1.0;
    }
    a
}

#[test]
fn factor_and_solve_reproduce_the_right_hand_side() {
    let a = laplacian(12, 0.1);
    let n = a.pattern().dim();
    let mut chol = Cholesky::try_new(a.pattern(), 1).unwrap();
    assert_eq!(
        chol.solve_in_place(&mut vec![0.0; n]),
        Err(LinalgError::NotFactorized)
    );
    chol.factorize(&a).unwrap();
    let x_true: Vec<f64> = (0..n)
        .map(|i| ((i * 7919) % 101) as f64 / 50.0 - 1.0)
        .collect();
    let mut b = vec![0.0; n];
    a.mul_vec(&x_true, &mut b).unwrap();
    let mut x = b.clone();
    chol.solve_in_place(&mut x).unwrap();
    let err = x
        .iter()
        .zip(&x_true)
        .map(|(u, v)| (u - v).abs())
        .fold(0.0, f64::max);
    assert!(err < 1e-12, "solve error {err:e}");
    // Several right-hand sides (scratch grows once beyond the construction size).
    let mut many = [b.clone(), b.clone(), b].concat();
    chol.solve_many_in_place(&mut many, 3).unwrap();
    for c in 0..3 {
        assert!(
            many[c * n..(c + 1) * n]
                .iter()
                .zip(&x)
                .all(|(u, v)| (u - v).abs() < 1e-14)
        );
    }
    // Refactorisation with new values on the same pattern.
    let mut a2 = a.clone();
    a2.values.iter_mut().for_each(|v| *v *= 2.0);
    chol.factorize(&a2).unwrap();
    let mut y = vec![0.0; n];
    a.mul_vec(&x_true, &mut y).unwrap();
    chol.solve_in_place(&mut y).unwrap();
    assert!(
        y.iter()
            .zip(&x_true)
            .all(|(u, v)| (u - 0.5 * v).abs() < 1e-12)
    );
}

#[test]
fn errors_are_reported_not_panicked() {
    let a = laplacian(5, -8.0); // indefinite
    let mut chol = Cholesky::try_new(a.pattern(), 1).unwrap();
    assert!(matches!(
        chol.factorize(&a),
        Err(LinalgError::NotPositiveDefinite { .. })
    ));
    assert!(!chol.is_factorized());
    let good = laplacian(5, 1.0);
    chol.factorize(&good).unwrap();
    assert_eq!(
        chol.solve_in_place(&mut [0.0; 3]),
        Err(LinalgError::DimensionMismatch {
            expected: 25,
            got: 3
        })
    );
    assert!(chol.factorize(&laplacian(4, 1.0)).is_err());
    assert!(
        LinalgError::NotPositiveDefinite { pivot: 3 }
            .to_string()
            .contains("positive definite")
    );
}

#[test]
fn pattern_is_upper_triangular_with_full_diagonal() {
    let p = SymmetricPattern::from_entries(4, [(3, 0), (0, 3), (1, 2)]);
    assert_eq!(p.nnz(), 4 + 2);
    assert!(p.slot(0, 3).is_some() && p.slot(3, 0) == p.slot(0, 3));
    assert!(p.slot(0, 1).is_none() && p.slot(9, 9).is_none());
}

#[test]
fn nested_dissection_is_a_permutation_and_solves_the_same() {
    let k = 20;
    let a = laplacian(k, 0.1);
    let n = a.pattern().dim();
    let coords: Vec<[f64; 3]> = (0..n)
        .map(|i| [(i % k) as f64, (i / k) as f64, 0.0])
        .collect();
    let order = needle_host::linalg::nested_dissection_order(a.pattern(), &coords);
    let mut seen = vec![false; n];
    order.iter().for_each(|&i| seen[i] = true);
    assert!(order.len() == n && seen.iter().all(|&s| s));
    let mut nd = Cholesky::try_new_ordered(a.pattern(), Some(&order), 1).unwrap();
    let mut amd = Cholesky::try_new(a.pattern(), 1).unwrap();
    nd.factorize(&a).unwrap();
    amd.factorize(&a).unwrap();
    let b: Vec<f64> = (0..n).map(|i| (i as f64).sin()).collect();
    let (mut x1, mut x2) = (b.clone(), b);
    nd.solve_in_place(&mut x1).unwrap();
    amd.solve_in_place(&mut x2).unwrap();
    assert!(x1.iter().zip(&x2).all(|(u, v)| (u - v).abs() < 1e-12));
    assert!(Cholesky::try_new_ordered(a.pattern(), Some(&order[1..]), 1).is_err());
}

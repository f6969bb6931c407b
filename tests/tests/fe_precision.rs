//! The single-precision factor (`solver.factor_precision = "single"`, [`Precision::Single`]):
//! its solves against the double factor's, its check and fallback to double on matrices it
//! cannot factorise well, and the gel pipeline with it reaching the double equilibrium.

use needle_host::free_motion::{GelModel, GelParams, RefreshParams};
use needle_host::linalg::{
    Cholesky, Precision, SINGLE_PROBE_TOLERANCE, SymmetricMatrix, SymmetricPattern,
};
use needle_host::mesh::{BoxDivisions, TetMesh};

fn clamped_box() -> (TetMesh, Vec<usize>) {
    needle_tests::clamped_box(BoxDivisions {
        nx: 8,
        ny: 4,
        nz: 4,
    })
}

fn params() -> GelParams {
    GelParams {
        time_step: Some(0.05),
        density: 1e-8,
        ..GelParams::default()
    }
}

fn rel_diff(a: &[f64], b: &[f64]) -> f64 {
    let d: f64 = a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum();
    let n: f64 = b.iter().map(|y| y * y).sum();
    (d / n).sqrt()
}

/// A 2 × 2 matrix `[[1, 1], [1, 1 + delta]]` (upper triangle stored).
fn two_by_two(a00: f64, delta: f64) -> SymmetricMatrix {
    let pattern = SymmetricPattern::from_entries(2, [(0, 1)]);
    let mut m = SymmetricMatrix::zeros(pattern.clone());
    m.values[pattern.slot(0, 0).unwrap()] = a00;
    m.values[pattern.slot(0, 1).unwrap()] = 1.0;
    m.values[pattern.slot(1, 1).unwrap()] = 1.0 + delta;
    m
}

/// Factorises `m` in single precision and solves `m x = m [1, 2]`; returns the factor and the
/// relative error of `x`.
fn single_solve(m: &SymmetricMatrix) -> (Cholesky, f64) {
    let mut chol = Cholesky::try_new_with_precision(m.pattern(), None, 1, Precision::Single)
        .expect("symbolic");
    chol.factorize(m).expect("double fallback factorises");
    let x = [1.0, 2.0];
    let mut b = [0.0; 2];
    m.mul_vec(&x, &mut b).unwrap();
    chol.solve_in_place(&mut b).unwrap();
    let err = rel_diff(&b, &x);
    (chol, err)
}

#[test]
fn single_factor_solves_the_gel_matrix_as_the_double_factor_does_to_single_precision() {
    let (mesh, bottom) = clamped_box();
    let mut model = GelModel::try_new(mesh, &bottom, &params()).unwrap();
    model.assemble();
    let a = model.matrix().clone();
    let n = a.pattern().dim();
    let mut single =
        Cholesky::try_new_with_precision(a.pattern(), None, 4, Precision::Single).unwrap();
    let mut double = Cholesky::try_new(a.pattern(), 4).unwrap();
    single.factorize(&a).unwrap();
    double.factorize(&a).unwrap();
    assert_eq!(single.precision(), Precision::Single);
    assert_eq!(single.precision_fallbacks(), 0);
    let probe = single
        .single_probe_error()
        .expect("a probe after the factorisation");
    assert!(
        probe > 0.0 && probe < SINGLE_PROBE_TOLERANCE,
        "probe {probe:e}"
    );
    assert_eq!(double.single_probe_error(), None);
    // Four right-hand sides at once and one alone.
    let b: Vec<f64> = (0..4 * n)
        .map(|i| ((i * 7919) % 101) as f64 - 50.0)
        .collect();
    let (mut xs, mut xd) = (b.clone(), b.clone());
    single.solve_many_in_place(&mut xs, 4).unwrap();
    double.solve_many_in_place(&mut xd, 4).unwrap();
    let err = rel_diff(&xs, &xd);
    println!("single vs double: relative difference {err:e}, probe {probe:e}");
    assert!(err > 0.0 && err < 1e-4, "{err:e}");
    let (mut one, mut one_d) = (b[..n].to_vec(), b[..n].to_vec());
    single.solve_in_place(&mut one).unwrap();
    double.solve_in_place(&mut one_d).unwrap();
    assert_eq!(&one[..], &xs[..n], "one column alone as among four");
    assert!(rel_diff(&one, &one_d) < 1e-4);
}

#[test]
fn single_factor_falls_back_to_double_on_a_pivot_that_vanishes_in_f32() {
    // 1 + 1e-10 rounds to 1 in f32: the second pivot is 0.
    let m = two_by_two(1.0, 1e-10);
    let (chol, err) = single_solve(&m);
    assert_eq!(chol.precision(), Precision::Double);
    assert_eq!(chol.precision_fallbacks(), 1);
    assert!(err < 1e-5, "the double factor's solve: {err:e}");
}

#[test]
fn single_factor_falls_back_to_double_when_the_probe_error_is_too_large() {
    // Positive definite in f32, but κ ≈ 4e5: the f32 solve errs by about 1e-2.
    let m = two_by_two(1.0, 1e-5);
    let (chol, err) = single_solve(&m);
    let probe = chol.single_probe_error().unwrap();
    println!("probe {probe:e}, solve after fallback {err:e}");
    assert!(probe > SINGLE_PROBE_TOLERANCE, "{probe:e}");
    assert_eq!(chol.precision(), Precision::Double);
    assert_eq!(chol.precision_fallbacks(), 1);
    assert!(err < 1e-9, "{err:e}");
    // A well-conditioned matrix stays single.
    let (ok, err) = single_solve(&two_by_two(4.0, 1.0));
    assert_eq!(ok.precision(), Precision::Single);
    assert_eq!(ok.precision_fallbacks(), 0);
    assert!(err < 1e-6, "{err:e}");
}

#[test]
fn single_factor_falls_back_to_double_on_a_value_beyond_the_f32_range() {
    // 1e39 is infinite in f32.
    let m = two_by_two(1e39, 1.0);
    let (chol, err) = single_solve(&m);
    assert_eq!(chol.precision(), Precision::Double);
    assert_eq!(chol.precision_fallbacks(), 1);
    assert!(err < 1e-9, "{err:e}");
    // The factor stays double: the next factorisation makes no second fallback.
    let mut chol = chol;
    chol.factorize(&two_by_two(4.0, 1.0)).unwrap();
    assert_eq!(chol.precision(), Precision::Double);
    assert_eq!(chol.precision_fallbacks(), 1);
}

/// The default pipeline (background factorisation, adaptive refresh) with a single-precision
/// factor ends at the equilibrium of the synchronous double Newton steps: the factor only
/// changes the path of the iteration, not where it converges.
#[test]
fn single_precision_gel_pipeline_reaches_the_double_equilibrium() {
    let (mesh, bottom) = clamped_box();
    let sync = params();
    let pipeline = GelParams {
        background_factorization: true,
        refactor_every: 2,
        refresh: Some(RefreshParams {
            rotation: 0.05,
            far_rotation: 0.05,
            ceiling: 16,
        }),
        factor_precision: Precision::Single,
        ..sync.clone()
    };
    let mut single = GelModel::try_new(mesh.clone(), &bottom, &pipeline).unwrap();
    let mut double = GelModel::try_new(mesh, &bottom, &sync).unwrap();
    let mut f = vec![0.0; single.dof_count()];
    for i in 0..single.positions().len() {
        f[3 * i] = 2e-4;
        f[3 * i + 2] = -1e-3;
    }
    for m in [&mut single, &mut double] {
        for _ in 0..400 {
            let dx = m.free_motion(&f).unwrap().to_vec();
            m.apply_displacement(&dx).unwrap();
        }
    }
    assert_eq!(single.factor_precision(), (Precision::Single, 0));
    assert_eq!(double.factor_precision(), (Precision::Double, 0));
    let moved = (single.positions().iter())
        .zip(&single.mesh().nodes)
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    let diff = (single.positions().iter())
        .zip(double.positions())
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    println!("moved {moved:.3} mm, single vs double equilibrium {diff:e} mm");
    assert!(moved > 0.1, "the load moved the gel: {moved}");
    assert!(diff < 1e-8, "{diff:e} mm");
}

/// A run reports its gel factor's precision: the default is single with no fallback, and on the
/// simple insertion's first 250 steps (the puncture, then 13 mm inside the gel) its tip and
/// tracking error stay within 0.05 mm of the double factor's at every step.
#[test]
fn a_run_reports_the_single_factor_and_tracks_as_the_double_one() {
    use needle_host::run::{RunOptions, run};
    use needle_tests::builtin_scene;
    let opts = RunOptions {
        steps: Some(250),
        ..RunOptions::default()
    };
    let single = run(&builtin_scene("simple", &[]), &opts, |_| {}).unwrap();
    let double = run(
        &builtin_scene("simple", &[("solver.factor_precision", "\"double\"")]),
        &opts,
        |_| {},
    )
    .unwrap();
    assert_eq!(single.summary.gel_factor_precision, "single");
    assert_eq!(single.summary.precision_fallbacks, 0);
    assert_eq!(double.summary.gel_factor_precision, "double");
    assert_eq!(single.reports.len(), double.reports.len());
    let (mut tip, mut err) = (0.0f64, 0.0f64);
    for (a, b) in single.reports.iter().zip(&double.reports) {
        tip = tip.max((a.tip - b.tip).norm());
        err = err.max((a.error - b.error).abs());
    }
    println!("single vs double: largest tip difference {tip:e} mm, error difference {err:e} mm");
    assert!(tip < 0.05 && err < 0.05, "tip {tip} mm, error {err} mm");
}

//! Regression: the constraint solves of sliding points along a stiff needle hit the sweep cap.
//!
//! The two problems are taken from real frames of the public suite's `gel_stiff` scene (an 80 kPa
//! gel, 15 and 18 rows: the 6 needle-base rows and 3 or 4 sliding points), the second at a joint
//! perturbed as a Jacobian column perturbs it. The sliding points, coupled through the stiff
//! needle, make rows nearly parallel: projected Gauss-Seidel still moves after 20 000 sweeps, and
//! a single Newton step on the active set of its iterate lands on the wrong statuses. Whole
//! steps of the scene hit the 400-sweep cap (148 of its steps before the fix). Newton's method on
//! the active set with the statuses corrected between steps
//! ([`BlockGs::solve_on_active_sets`]) solves both; Gauss-Seidel confirms the answer.
//!
//! A third problem (`cycling_sliding_m18.txt`) is a Jacobian column of a `helix_half` frame (4
//! sliding points, μ_n 0.1) with the iterate its active-set rounds started from in that run:
//! from there the rounds cycled between two statuses of one axial row (tied with two others,
//! then freed), every sliding point sticking being the solution.
//!
//! A fourth (`cycling_ties_m30.txt`) is a Jacobian column of a frame near the end of a held-out
//! insertion (`tools/gen_suite.py --seed 31`, slot `place_right`; 8 sliding points, μ_n 0.1),
//! with the iterate the column solve's second polish started from: five axial rows sit at the
//! transition between tied and free, the rounds cycle through several status sets and give up
//! (the run hit the sweep cap in 4 steps). [`BlockGs::solve_on_active_sets_feasible`] solves it.
//!
//! A fifth pair (`sliding_tip_contact_m9_a.txt`, `_b.txt`) are the final solves of two steps just
//! before puncture in a held-out insertion (`tools/gen_suite.py --seed 8128`, slot `scurve_y`):
//! the 6 base rows and the tip's Coulomb contact (μ 0.3), sliding on the gel's surface, with the
//! iterate the first polish started from. Through the stiff needle the contact's normal and
//! tangential rows are nearly parallel once the base rows are eliminated (the reduced 3 × 3
//! problem's eigenvalues 1.5 and 942): the sweeps crawl, and the polishes, which held a sliding
//! contact's pair at its value, could not move it, so both steps hit the sweep cap. The pair is
//! now tied to the normal force and the slip angle ([`ActiveSet`]).
//!
//! File format (`tests/data/*_m*.txt`): `m`; one line per row group
//! `kind start len mu r0`; the `m` rows of `W`; `δ` (base rows at the column's joints);
//! optionally the starting iterate.
#![allow(clippy::expect_used, clippy::unwrap_used, clippy::panic)]

use needle_core::{ActiveSet, BlockGs, GsParams, RowGroup};

const M: usize = 32;

struct Problem {
    m: usize,
    groups: Vec<RowGroup>,
    w: Box<[[f64; M]; M]>,
    delta: [f64; M],
    start: Option<[f64; M]>,
}

fn load(name: &str) -> Problem {
    let path = format!("{}/tests/data/{name}", env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(&path).expect("test data");
    let mut lines = text.lines();
    let m: usize = lines.next().unwrap().trim().parse().unwrap();
    let mut groups = Vec::new();
    let mut rows = 0;
    while rows < m {
        let f: Vec<&str> = lines.next().unwrap().split_whitespace().collect();
        let (kind, start, len): (u32, u32, u32) = (
            f[0].parse().unwrap(),
            f[1].parse().unwrap(),
            f[2].parse().unwrap(),
        );
        let (mu, r0): (f64, f64) = (f[3].parse().unwrap(), f[4].parse().unwrap());
        groups.push(match kind {
            1 => RowGroup::bilateral(start, len),
            3 => RowGroup::contact(start, mu),
            4 => RowGroup::sliding(start, mu, r0),
            k => panic!("{path}: group kind {k} not expected here"),
        });
        rows += len as usize;
    }
    let mut numbers = || -> Vec<f64> {
        let line = lines.next().unwrap();
        line.split_whitespace()
            .map(|x| x.parse().unwrap())
            .collect()
    };
    let mut w = Box::new([[0.0; M]; M]);
    for row in w.iter_mut().take(m) {
        row[..m].copy_from_slice(&numbers());
    }
    let mut delta = [0.0; M];
    delta[..m].copy_from_slice(&numbers());
    // An optional last line: the iterate a solve started its active-set rounds from.
    let start = lines.next().map(|line| {
        let mut start = [0.0; M];
        for (x, v) in start.iter_mut().zip(line.split_whitespace()) {
            *x = v.parse().unwrap();
        }
        start
    });
    Problem {
        m,
        groups,
        w,
        delta,
        start,
    }
}

const GS: GsParams = GsParams {
    tolerance: 1e-7,
    max_iterations: 400,
    polish: false,
    relaxation: 1.2,
};

/// Checks the solution's conditions directly (not through the solver's own test): every
/// bilateral row closed, every axial force within `μ_n |λ_l| + r_0`, closed when inside it and
/// slipping against the force on it.
fn assert_solution(p: &Problem, lambda: &[f64; M], what: &str, tolerance: f64) {
    let m = p.m;
    let scale = p.delta[..m].iter().fold(0.0f64, |a, x| a.max(x.abs()));
    let w: Vec<f64> = (0..m)
        .map(|i| (0..m).map(|j| p.w[i][j] * lambda[j]).sum::<f64>() - p.delta[i])
        .collect();
    let tol = 100.0 * tolerance * scale;
    for g in &p.groups {
        let s = g.start as usize;
        if g.kind == RowGroup::bilateral(0, 1).kind {
            for (i, wi) in w.iter().enumerate().skip(s).take(g.len as usize) {
                assert!(wi.abs() <= tol, "{what}: bilateral row {i} open by {wi:e}");
            }
            continue;
        }
        for i in [s, s + 1] {
            assert!(
                w[i].abs() <= tol,
                "{what}: lateral row {i} open by {:e}",
                w[i]
            );
        }
        let a = s + 2;
        let bound = g.mu * lambda[s].hypot(lambda[s + 1]) + g.r0;
        let x = lambda[a].abs();
        assert!(
            x <= bound * (1.0 + 1e-6),
            "{what}: axial row {a} beyond its bound"
        );
        if x < bound * (1.0 - 1e-6) {
            assert!(
                w[a].abs() <= tol,
                "{what}: sticking axial row {a} moves by {:e}",
                w[a]
            );
        } else {
            assert!(
                lambda[a].signum() * w[a] <= tol,
                "{what}: axial row {a} slips with its force"
            );
        }
    }
}

#[test]
fn stiff_sliding_points_stall_gauss_seidel_at_its_cap() {
    for name in ["stiff_sliding_m15.txt", "stiff_sliding_m18.txt"] {
        let p = load(name);
        let mut gs = BlockGs::<M>::new();
        gs.prepare(&p.w, p.m, &p.groups).unwrap();
        let mut lambda = [0.0; M];
        let r = gs.solve(&p.w, &p.delta, &mut lambda, &GS);
        assert!(
            !r.converged,
            "{name}: plain Gauss-Seidel converged: the problem no longer shows the stall"
        );
    }
}

#[test]
fn stiff_sliding_points_solved_by_active_set_rounds_within_the_sweep_cap() {
    // Each at the tolerance the controller solves it to: the frame's own solve (base and final
    // solves, 1e-7) and a Jacobian column's (`InverseParams::jacobian_tolerance`, 1e-5).
    for (name, tolerance) in [
        ("stiff_sliding_m15.txt", 1e-7),
        ("stiff_sliding_m18.txt", 1e-5),
    ] {
        let p = load(name);
        let gs_params = GsParams { tolerance, ..GS };
        let mut gs = BlockGs::<M>::new();
        gs.prepare(&p.w, p.m, &p.groups).unwrap();
        let mut set = Box::new(ActiveSet::<M>::new());
        let mut lambda = [0.0; M];
        // As the controller's solves do: 60 sweeps, the rounds, Gauss-Seidel for what is left.
        let first = GsParams {
            max_iterations: 60,
            ..gs_params
        };
        let r1 = gs.solve(&p.w, &p.delta, &mut lambda, &first);
        assert!(!r1.converged);
        gs.solve_on_active_sets(&p.w, &p.delta, &mut lambda, &mut set, 12);
        let rest = GsParams {
            max_iterations: GS.max_iterations - r1.iterations,
            ..gs_params
        };
        let r2 = gs.solve(&p.w, &p.delta, &mut lambda, &rest);
        assert!(r2.converged, "{name}: not converged: {r2:?}");
        assert_solution(&p, &lambda, name, tolerance);
    }
}

#[test]
fn cycling_axial_status_does_not_stop_the_active_set_rounds() {
    let name = "cycling_sliding_m18.txt";
    let p = load(name);
    let mut gs = BlockGs::<M>::new();
    gs.prepare(&p.w, p.m, &p.groups).unwrap();
    let mut set = Box::new(ActiveSet::<M>::new());
    let mut lambda = p.start.expect("a starting iterate");
    // As the controller polishes a Jacobian column: its 12 rounds, then Gauss-Seidel for the
    // 60 sweeps before the next polish. Before the fix the rounds ended on the set that asks for
    // the larger correction and those sweeps did not converge (nor did the 400 of the cap).
    gs.solve_on_active_sets(&p.w, &p.delta, &mut lambda, &mut set, 12);
    let tolerance = 1e-5;
    let gs_params = GsParams {
        tolerance,
        max_iterations: 60,
        ..GS
    };
    let r = gs.solve(&p.w, &p.delta, &mut lambda, &gs_params);
    assert!(r.converged, "{name}: {r:?}");
    assert_solution(&p, &lambda, name, tolerance);
}

#[test]
fn ties_at_the_transition_cycle_the_rounds_but_not_the_feasible_polish() {
    let name = "cycling_ties_m30.txt";
    let p = load(name);
    let mut gs = BlockGs::<M>::new();
    gs.prepare(&p.w, p.m, &p.groups).unwrap();
    let mut set = Box::new(ActiveSet::<M>::new());
    let start = p.start.expect("a starting iterate");
    // A Jacobian column: the columns' tolerance, the sweeps of the cap.
    let tolerance = 1e-5;
    let gs_params = GsParams { tolerance, ..GS };
    // What the step did: the rounds end in a cycle on an iterate from which Gauss-Seidel (on
    // the full problem here; the column's own solve is on the reduced one) runs into the cap.
    let mut lambda = start;
    assert!(!gs.solve_on_active_sets(&p.w, &p.delta, &mut lambda, &mut set, 12));
    let r = gs.solve(&p.w, &p.delta, &mut lambda, &gs_params);
    assert!(!r.converged, "{name}: the rounds now solve it: {r:?}");

    // The feasible polish finishes; Gauss-Seidel confirms it at once.
    let mut lambda = start;
    assert!(gs.solve_on_active_sets_feasible(&p.w, &p.delta, &mut lambda, &mut set, 40));
    assert!(set.tied_rows() > 0, "{name}: some axial rows slide");
    assert_solution(&p, &lambda, name, 1e-7);
    let r = gs.solve(&p.w, &p.delta, &mut lambda, &gs_params);
    assert!(r.converged && r.iterations <= 2, "{name}: {r:?}");
}

/// The one-contact problem solved independently of the solver: the base rows eliminated
/// (Schur complement), then the sliding law `λ_t = μ λ_n û(θ)`, `w_n = 0`, `w_t ∥ −û` scanned
/// over θ and bisected on the sign change of `w_t · û⊥`. Returns `(λ_n, θ)` of the sliding
/// solution (the stick solution lies outside the disk for both problems).
fn one_contact_slide(p: &Problem) -> (f64, f64) {
    use nalgebra::{Matrix3, Matrix6, Matrix6x3, Vector3, Vector6};
    let wbb = Matrix6::from_fn(|i, j| p.w[i][j]);
    let wbc = Matrix6x3::from_fn(|i, j| p.w[i][6 + j]);
    let wcc = Matrix3::from_fn(|i, j| p.w[6 + i][6 + j]);
    let db = Vector6::from_fn(|i, _| p.delta[i]);
    let dc = Vector3::from_fn(|i, _| p.delta[6 + i]);
    let chol = wbb.cholesky().expect("W_bb positive definite");
    let a = wcc - wbc.transpose() * chol.solve(&wbc);
    let b = dc - wbc.transpose() * chol.solve(&db);
    // What makes the sweeps crawl: the reduced problem's eigenvalues, and how far its softest
    // direction lies from the contact's normal (printed with --nocapture; docs/architecture.md).
    let eig = a.symmetric_eigen();
    let soft = eig.eigenvalues.imin();
    let normal_angle = eig.eigenvectors.column(soft)[0].abs().acos().to_degrees();
    let mut values: Vec<f64> = eig.eigenvalues.iter().copied().collect();
    values.sort_by(f64::total_cmp);
    eprintln!(
        "reduced contact problem: eigenvalues {values:.1?}, softest direction {normal_angle:.0}° from the normal"
    );
    let mu = p.groups[1].mu;
    // At angle θ: λ_n from w_n = 0, then the residual's component along û⊥ and along û.
    let at = |th: f64| {
        let u = Vector3::new(1.0, mu * th.cos(), mu * th.sin());
        let n = b[0] / (a.row(0) * u)[0];
        let r = a * (n * u) - b;
        let perp = -r[1] * th.sin() + r[2] * th.cos();
        let along = r[1] * th.cos() + r[2] * th.sin();
        (n, perp, along)
    };
    let valid = |(n, _, along): (f64, f64, f64)| n > 0.0 && along <= 0.0;
    let steps = 100_000;
    let mut found = None;
    for k in 0..steps {
        let (t0, t1) = (
            std::f64::consts::TAU * k as f64 / steps as f64,
            std::f64::consts::TAU * (k + 1) as f64 / steps as f64,
        );
        let (f0, f1) = (at(t0), at(t1));
        if valid(f0) && valid(f1) && f0.1.signum() != f1.1.signum() {
            let (mut lo, mut hi) = (t0, t1);
            for _ in 0..100 {
                let mid = 0.5 * (lo + hi);
                if at(mid).1.signum() == f0.1.signum() {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            assert!(found.is_none(), "{}: two sliding solutions", p.m);
            found = Some((at(lo).0, lo));
        }
    }
    found.expect("a sliding solution")
}

#[test]
fn sliding_tip_contact_before_puncture_hits_no_sweep_cap() {
    for name in [
        "sliding_tip_contact_m9_a.txt",
        "sliding_tip_contact_m9_b.txt",
    ] {
        let p = load(name);
        let mut gs = BlockGs::<M>::new();
        gs.prepare(&p.w, p.m, &p.groups).unwrap();
        let start = p.start.expect("a starting iterate");
        let gs_params = GsParams {
            relaxation: 1.0,
            ..GS
        };
        // The sweeps alone stall at the cap.
        let mut lambda = start;
        let r = gs.solve(&p.w, &p.delta, &mut lambda, &gs_params);
        assert!(!r.converged, "{name}: the sweeps alone converge: {r:?}");

        let (normal, angle) = one_contact_slide(&p);
        let mut set = Box::new(ActiveSet::<M>::new());
        for feasible in [false, true] {
            let mut lambda = start;
            let done = if feasible {
                gs.solve_on_active_sets_feasible(&p.w, &p.delta, &mut lambda, &mut set, 40)
            } else {
                gs.solve_on_active_sets(&p.w, &p.delta, &mut lambda, &mut set, 12)
            };
            assert!(
                done,
                "{name} (feasible {feasible}): the rounds did not finish"
            );
            assert_eq!(set.tied_rows(), 2, "{name}: the contact slides");
            // The sliding law, checked on the residual directly.
            let m = p.m;
            let w: Vec<f64> = (0..m)
                .map(|i| (0..m).map(|j| p.w[i][j] * lambda[j]).sum::<f64>() - p.delta[i])
                .collect();
            let scale = p.delta[..m].iter().fold(0.0f64, |a, x| a.max(x.abs()));
            let mu = p.groups[1].mu;
            let (n, t) = (lambda[6], lambda[7].hypot(lambda[8]));
            assert!(
                w[..7].iter().all(|x| x.abs() <= 1e-12 * scale),
                "{name}: {w:?}"
            );
            assert!(
                n > 0.0 && (t - mu * n).abs() <= 1e-12 * n,
                "{name}: off the disk"
            );
            let cross = lambda[7] * w[8] - lambda[8] * w[7];
            let dot = lambda[7] * w[7] + lambda[8] * w[8];
            assert!(
                cross.abs() <= 1e-9 * t * w[7].hypot(w[8]) && dot < 0.0,
                "{name}: the slip does not oppose the force"
            );
            // The independent solution.
            assert!(
                (n - normal).abs() <= 1e-9 * normal,
                "{name}: λ_n {n:e}, independent {normal:e}"
            );
            let theta = lambda[8].atan2(lambda[7]).rem_euclid(std::f64::consts::TAU);
            assert!(
                (theta - angle).abs() <= 1e-6,
                "{name}: θ {theta}, independent {angle}"
            );
            // Gauss-Seidel confirms it at once.
            let r = gs.solve(&p.w, &p.delta, &mut lambda, &gs_params);
            assert!(r.converged && r.iterations <= 1, "{name}: {r:?}");
        }
    }
}

/// The active-set rounds factor without the response `Z` to the base rows (six triangular
/// solves a round that nothing in the rounds reads): the set they leave is factored but not
/// valid for a prediction until `ActiveSet::complete_response`, which then predicts exactly
/// (bit for bit) what a factorisation with the response of the same statuses predicts.
#[test]
fn active_set_rounds_leave_the_response_to_complete_response() {
    let p = load("stiff_sliding_m15.txt");
    let mut gs = BlockGs::<M>::new();
    gs.prepare(&p.w, p.m, &p.groups).unwrap();
    let mut lambda = [0.0; M];
    let first = GsParams {
        max_iterations: 60,
        ..GS
    };
    gs.solve(&p.w, &p.delta, &mut lambda, &first);
    let mut rounds = Box::new(ActiveSet::<M>::new());
    let start = lambda;
    gs.solve_on_active_sets(&p.w, &p.delta, &mut lambda, &mut rounds, 1);
    assert!(
        !rounds.is_valid(),
        "the rounds computed the response they do not need"
    );
    assert!(
        rounds.complete_response(),
        "the factor of the rounds is not valid"
    );
    // The same statuses factored with the response in one go.
    let mut whole = Box::new(ActiveSet::<M>::new());
    assert!(gs.factor_active_set(&p.w, &p.delta, &start, &mut whole));
    let d_base = [0.01, -0.02, 0.005, 0.003, -0.001, 0.002];
    let (mut a, mut b) = ([0.0; M], [0.0; M]);
    assert!(gs.predict_base_change(&rounds, &start, &d_base, &mut a));
    assert!(gs.predict_base_change(&whole, &start, &d_base, &mut b));
    assert_eq!(a.map(f64::to_bits), b.map(f64::to_bits));
    assert!(a[..p.m] != start[..p.m], "the prediction moved nothing");
}

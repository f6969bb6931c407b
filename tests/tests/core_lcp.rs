//! `needle_core::constraint::BlockGs` against `lcp_ref.json` (OSQP / SciPy NNLS / Clarabel
//! references): every frictionless problem (rows as single unilateral groups, as the reference
//! does) and every friction problem (3-row Coulomb contacts `[n, t1, t2]`).

use needle_core::boxed_zeroed;
use needle_core::constraint::{BlockGs, GsParams};
use needle_core::payload::RowGroup;
use needle_tests::{arr, load_ref};
use serde_json::Value;

const M: usize = 150;

struct Problem {
    n: usize,
    w: Box<[[f64; M]; M]>,
    delta: [f64; M],
}

fn load_problem(p: &Value) -> Problem {
    let n = p["n"].as_u64().expect("n") as usize;
    assert!(n <= M);
    // Box the 180 KB matrix without a stack temporary.
    let mut w = boxed_zeroed::<[[f64; M]; M]>();
    for (i, row) in p["W"].as_array().expect("W").iter().enumerate() {
        for (j, x) in arr(row).into_iter().enumerate() {
            w[i][j] = x;
        }
    }
    let mut delta = [0.0; M];
    for (i, x) in arr(&p["delta"]).into_iter().enumerate() {
        delta[i] = x;
    }
    Problem { n, w, delta }
}

/// The problem behind six decoupled bilateral rows (`W_bb = I`, `δ_b = 0`), put first as a
/// frame's base rows are.
fn with_base_rows(pb: &Problem) -> (Box<[[f64; M]; M]>, [f64; M]) {
    let n = pb.n + 6;
    let mut w = boxed_zeroed::<[[f64; M]; M]>();
    let mut delta = [0.0; M];
    for i in 0..6 {
        w[i][i] = 1.0;
    }
    for i in 0..pb.n {
        w[6 + i][6..n].copy_from_slice(&pb.w[i][..pb.n]);
        delta[6 + i] = pb.delta[i];
    }
    (w, delta)
}

fn rel_err(a: &[f64], b: &[f64]) -> f64 {
    let scale = b.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    a.iter()
        .zip(b)
        .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()))
        / scale
}

#[test]
fn frictionless_problems_match_reference() {
    let r = load_ref("lcp_ref.json");
    let problems = r["problems"].as_array().expect("problems");
    assert_eq!(problems.len(), 30);
    let mut gs = Box::new(BlockGs::<M>::new());
    let mut worst = 0.0f64;
    for p in problems {
        let id = p["id"].as_u64().expect("id");
        let pb = load_problem(p);
        let groups: Vec<RowGroup> = (0..pb.n as u32).map(RowGroup::unilateral).collect();
        gs.prepare(&pb.w, pb.n, &groups).expect("valid problem");
        let mut lambda = [0.0; M];
        let params = GsParams {
            tolerance: 1e-12,
            max_iterations: 5000,
            polish: true,
            ..GsParams::default()
        };
        let rep = gs.solve(&pb.w, &pb.delta, &mut lambda, &params);
        let lref = arr(&p["frictionless"]["lambda"]);
        let e = rel_err(&lambda[..pb.n], &lref);
        // Plain GS without the polish, for the record (slow on ill-conditioned problems).
        let mut plain = [0.0; M];
        let plain_params = GsParams {
            polish: false,
            max_iterations: 20000,
            ..params
        };
        let prep = gs.solve(&pb.w, &pb.delta, &mut plain, &plain_params);
        println!(
            "           plain GS: {} sweeps, rel err {:.2e}",
            prep.iterations,
            rel_err(&plain[..pb.n], &lref)
        );
        worst = worst.max(e);
        println!(
            "problem {id:2} n={:3} cond={:9.1}: sweeps {:5} polished {} rel err {e:.2e}",
            pb.n,
            p["cond_W"].as_f64().unwrap_or(0.0),
            rep.iterations,
            rep.polished
        );
        assert!(rep.converged, "problem {id}: {rep:?}");
        assert!(e <= 1e-8, "problem {id}: λ relative error {e:e}");
        assert!(lambda[..pb.n].iter().all(|&x| x >= 0.0));
    }
    println!("worst relative error {worst:.2e}");
}

#[test]
fn friction_problems_match_reference() {
    let r = load_ref("lcp_ref.json");
    let ids: Vec<u64> = r["friction_problem_ids"]
        .as_array()
        .expect("ids")
        .iter()
        .map(|v| v.as_u64().expect("id"))
        .collect();
    assert_eq!(ids.len(), 8);
    let mut gs = Box::new(BlockGs::<M>::new());
    for p in r["problems"].as_array().expect("problems") {
        let id = p["id"].as_u64().expect("id");
        let f = &p["friction"];
        if f.is_null() {
            assert!(!ids.contains(&id));
            continue;
        }
        let pb = load_problem(p);
        let mu = f["mu"].as_f64().expect("mu");
        let groups: Vec<RowGroup> = (0..pb.n as u32 / 3)
            .map(|c| RowGroup::contact(3 * c, mu))
            .collect();
        gs.prepare(&pb.w, pb.n, &groups).expect("valid problem");
        let mut lambda = [0.0; M];
        let params = GsParams {
            tolerance: 1e-14,
            max_iterations: 20000,
            polish: false,
            ..GsParams::default()
        };
        let rep = gs.solve(&pb.w, &pb.delta, &mut lambda, &params);
        let rref = arr(&f["r"]);
        let e = rel_err(&lambda[..pb.n], &rref);
        println!(
            "friction problem {id:2} n={:3} mu={mu:.3}: sweeps {:5} residual {:.1e} rel err {e:.2e}",
            pb.n, rep.iterations, rep.residual
        );
        assert!(e <= 1e-6, "problem {id}: r relative error {e:e}");
        // Status per contact, classified from our own solution.
        let w = gs.last_residual();
        let scale = rref.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        for (c, st) in f["contact_status"]
            .as_array()
            .expect("status")
            .iter()
            .enumerate()
        {
            let (rn, t1, t2) = (lambda[3 * c], lambda[3 * c + 1], lambda[3 * c + 2]);
            let ours = if rn <= 1e-9 * scale {
                "separated"
            } else if (t1.hypot(t2) - mu * rn).abs() <= 1e-7 * scale
                && w[3 * c + 1].hypot(w[3 * c + 2]) > 1e-12
            {
                "slide"
            } else {
                "stick"
            };
            assert_eq!(
                ours,
                st.as_str().expect("status"),
                "problem {id} contact {c}: r = ({rn}, {t1}, {t2})"
            );
        }
    }
}

/// Regression (issue "trust"): the polish treated a sliding group's axial row as an equality and
/// reported `converged, residual 0` with λ_a = 5 against its bound μ_n |λ_lat| + r_0 = 0.1.
#[test]
fn polish_of_a_sliding_group_respects_the_axial_bound() {
    let mut w = boxed_zeroed::<[[f64; M]; M]>();
    for (i, row) in w.iter_mut().enumerate().take(3) {
        row[i] = 1.0;
    }
    let mut delta = [0.0; M];
    delta[..3].copy_from_slice(&[1.0, 0.0, 5.0]);
    let mut gs = Box::new(BlockGs::<M>::new());
    gs.prepare(&w, 3, &[RowGroup::sliding(0, 0.1, 0.0)])
        .expect("valid problem");
    let mut lambda = [0.0; M];
    let params = GsParams {
        tolerance: 1e-12,
        max_iterations: 1000,
        polish: true,
        ..GsParams::default()
    };
    let rep = gs.solve(&w, &delta, &mut lambda, &params);
    let bound = 0.1 * lambda[0].hypot(lambda[1]);
    assert!(rep.converged, "{rep:?}");
    assert!(
        !rep.polished,
        "a sliding group is not for the equality polish: {rep:?}"
    );
    assert!((lambda[0] - 1.0).abs() < 1e-9 && lambda[1].abs() < 1e-9);
    assert!(
        lambda[2].abs() <= bound + 1e-12,
        "λ_a = {} against the bound {bound}",
        lambda[2]
    );
}

/// The feasible active-set polish (`BlockGs::solve_on_active_sets_feasible`) on every
/// frictionless problem of the reference, six decoupled bilateral rows put first as a frame's
/// base rows: from λ = 0 (every row closed) it opens the row the residual calls for, steps only
/// as far as the first force that reaches zero, and finishes on the reference's answer
/// (a primal active-set method on a convex QP); Gauss-Seidel confirms it in one sweep.
#[test]
fn feasible_active_set_polish_reaches_the_reference_frictionless_solutions() {
    let r = load_ref("lcp_ref.json");
    let mut gs = Box::new(BlockGs::<M>::new());
    let mut set = boxed_zeroed::<needle_core::ActiveSet<M>>();
    let mut solved = 0;
    for p in r["problems"].as_array().expect("problems") {
        let id = p["id"].as_u64().expect("id");
        let pb = load_problem(p);
        let n = pb.n + 6;
        if n > M {
            continue;
        }
        let (w, delta) = with_base_rows(&pb);
        let mut groups = vec![RowGroup::bilateral(0, 6)];
        groups.extend((6..n as u32).map(RowGroup::unilateral));
        gs.prepare(&w, n, &groups).expect("valid problem");
        let mut lambda = [0.0; M];
        let done = gs.solve_on_active_sets_feasible(&w, &delta, &mut lambda, &mut set, 2 * n);
        assert!(done, "problem {id}: not finished in {} rounds", 2 * n);
        assert!(
            lambda[6..n].iter().all(|x| *x >= 0.0),
            "problem {id}: a negative force"
        );
        let e = rel_err(&lambda[6..n], &arr(&p["frictionless"]["lambda"]));
        let params = GsParams {
            tolerance: 1e-10,
            max_iterations: 10,
            polish: false,
            ..GsParams::default()
        };
        let rep = gs.solve(&w, &delta, &mut lambda, &params);
        println!(
            "problem {id:2} n={:3}: rel err {e:.2e}, then {} sweeps",
            pb.n, rep.iterations
        );
        assert!(e <= 1e-9, "problem {id}: relative error {e:e}");
        assert!(lambda[..6].iter().all(|x| x.abs() < 1e-12));
        assert!(
            rep.converged && rep.iterations <= 1,
            "problem {id}: {rep:?}"
        );
        solved += 1;
    }
    println!("{solved} problems");
    assert!(solved >= 20, "{solved} problems of up to {M} rows");
}

/// The active-set methods on every friction problem of the reference (3-D Coulomb contacts,
/// most of them sliding), six decoupled bilateral rows put first as a frame's base rows, from a
/// rough Gauss-Seidel iterate (20 sweeps): a sliding contact's pair is tied to its normal force
/// and its slip angle (Newton on the sliding law), so both the primal-dual rounds
/// (`solve_on_active_sets`) and the feasible polish (`solve_on_active_sets_feasible`) finish on
/// the reference's answer, which Gauss-Seidel then confirms in one sweep. Before the sliding
/// contacts were tied, their pairs were held at the rough iterate's values through the rounds:
/// problem 3 (2 sliding of 7 contacts) ended 11 % from the reference, unfinished.
#[test]
fn active_set_methods_reach_the_reference_friction_solutions_with_sliding_contacts() {
    let r = load_ref("lcp_ref.json");
    let mut gs = Box::new(BlockGs::<M>::new());
    let mut set = boxed_zeroed::<needle_core::ActiveSet<M>>();
    let mut solved = 0;
    for p in r["problems"].as_array().expect("problems") {
        let id = p["id"].as_u64().expect("id");
        let f = &p["friction"];
        if f.is_null() {
            continue;
        }
        let pb = load_problem(p);
        let n = pb.n + 6;
        if n > M {
            continue;
        }
        let mu = f["mu"].as_f64().expect("mu");
        let (w, delta) = with_base_rows(&pb);
        let mut groups = vec![RowGroup::bilateral(0, 6)];
        groups.extend((0..pb.n as u32 / 3).map(|c| RowGroup::contact(6 + 3 * c, mu)));
        gs.prepare(&w, n, &groups).expect("valid problem");
        let rough = GsParams {
            tolerance: 1e-14,
            max_iterations: 20,
            polish: false,
            ..GsParams::default()
        };
        let mut start = [0.0; M];
        gs.solve(&w, &delta, &mut start, &rough);
        let reference = arr(&f["r"]);
        let slides = f["n_slide"].as_u64().expect("n_slide");
        for feasible in [false, true] {
            let mut lambda = start;
            let done = if feasible {
                gs.solve_on_active_sets_feasible(&w, &delta, &mut lambda, &mut set, 4 * n)
            } else {
                gs.solve_on_active_sets(&w, &delta, &mut lambda, &mut set, 4 * n)
            };
            let e = rel_err(&lambda[6..n], &reference);
            let confirm = GsParams {
                tolerance: 1e-10,
                max_iterations: 10,
                ..rough
            };
            let rep = gs.solve(&w, &delta, &mut lambda, &confirm);
            println!(
                "friction problem {id:2} n={:3} sliding {slides:2} feasible {feasible}: \
                 finished {done}, rel err {e:.2e}, then {} sweeps",
                pb.n, rep.iterations
            );
            assert!(done, "problem {id} (feasible {feasible}): not finished");
            assert!(
                e <= 1e-8,
                "problem {id} (feasible {feasible}): rel err {e:e}"
            );
            assert!(
                rep.converged && rep.iterations <= 1,
                "problem {id} (feasible {feasible}): {rep:?}"
            );
        }
        solved += 1;
    }
    assert_eq!(
        solved, 8,
        "every friction problem of the reference fits {M} rows"
    );
}

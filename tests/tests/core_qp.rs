//! `needle_core::qp::Qp` (Goldfarb–Idnani dual active set) against `lcp_ref.json`: every
//! frictionless contact problem `w = W λ − δ, λ ≥ 0, w ≥ 0, λ·w = 0` is the convex program
//! `min ½ λᵀ W λ − δᵀ λ  s.t.  λ ≥ 0`, whose solution the reference gives (OSQP, SciPy NNLS and
//! Clarabel agree with it to 1e-9 or better).

use needle_core::qp::Qp;
use needle_tests::{arr, load_ref};

const N: usize = 150;

fn solve_all() {
    let r = load_ref("lcp_ref.json");
    let problems = r["problems"].as_array().expect("problems");
    assert_eq!(problems.len(), 30, "lcp_ref.json holds 30 problems");
    let mut qp = Box::new(Qp::<N, N>::new());
    let mut worst = 0.0f64;
    for p in problems {
        let n = p["n"].as_u64().expect("n") as usize;
        let delta = arr(&p["delta"]);
        let want = arr(&p["frictionless"]["lambda"]);
        qp.reset(n).expect("capacity");
        for (i, row) in p["W"].as_array().expect("W").iter().enumerate() {
            for (k, x) in arr(row).into_iter().enumerate() {
                qp.hessian_mut()[i][k] = x;
            }
        }
        for (l, d) in qp.linear_mut().iter_mut().zip(&delta).take(n) {
            *l = -d;
        }
        let zero = vec![0.0; n];
        let inf = vec![f64::INFINITY; n];
        qp.add_bounds(&zero, &inf).expect("rows");
        let rep = qp.solve().expect("solvable");
        assert!(rep.optimal, "problem {}", p["id"]);
        let scale = want.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        let err = qp
            .solution()
            .iter()
            .zip(&want)
            .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()))
            / scale;
        // The active set must be the reference's.
        let active: Vec<u64> = p["frictionless"]["active_set"]
            .as_array()
            .expect("active_set")
            .iter()
            .map(|v| v.as_u64().expect("index"))
            .collect();
        let mine: Vec<u64> = (0..n)
            .filter(|&i| qp.solution()[i] > 0.0 && !qp.is_active(i))
            .map(|i| i as u64)
            .collect();
        assert_eq!(mine, active, "problem {}: active set", p["id"]);
        assert!(err < 1e-10, "problem {}: relative λ error {err:e}", p["id"]);
        worst = worst.max(err);
    }
    println!("worst relative λ error over 30 problems: {worst:e}");
}

#[test]
fn frictionless_contact_problems_match_reference() {
    // The 150-unknown workspace is ≈ 0.7 MB: give the solve a thread with room for it.
    std::thread::Builder::new()
        .stack_size(64 << 20)
        .spawn(solve_all)
        .expect("thread")
        .join()
        .expect("the reference check failed");
}

//! Projected block Gauss-Seidel on seeded random SPD frames with the production layout
//! (6 base rows + sliding points): a cold solve from λ = 0, and a warm solve after a base
//! perturbation like the Jacobian's (δq = 0.01 rad on joint 2).

use criterion::{Criterion, criterion_group, criterion_main};
use needle_core::constraint::{BlockGs, GsParams};
use needle_core::inverse::base_violation;
use needle_core::kinematics::{DhChain, Kinematics};
use std::hint::black_box;

mod common;
use common::{M, Q, frame};

fn bench(c: &mut Criterion) {
    let params = GsParams::default();
    for m in [30usize, 120] {
        let f = frame(m, 7);
        let mut gs = Box::new(BlockGs::<M>::new());
        gs.prepare_frame(&f).expect("valid frame");
        let mut lambda = [0.0; M];
        let rep = gs.solve(&f.w, &f.delta_free, &mut lambda, &params);
        println!("pgs_m{m}: cold solve {rep:?}");
        c.bench_function(&format!("pgs_m{m}"), |b| {
            b.iter(|| {
                let mut l = [0.0; M];
                gs.solve(&f.w, black_box(&f.delta_free), &mut l, &params)
            })
        });
        // Warm: the base rows after a 0.01 rad step of joint 2.
        let mut delta = f.delta_free;
        let mut q = Q;
        q[1] += 0.01;
        let d = base_violation(&DhChain::rv1a().tool_pose(&q), &f.p_free, &f.r_free);
        delta[..6].copy_from_slice(&d);
        let mut l = lambda;
        let rep = gs.solve(&f.w, &delta, &mut l, &params);
        println!("pgs_m{m}_warm: {rep:?}");
        c.bench_function(&format!("pgs_m{m}_warm"), |b| {
            b.iter(|| {
                let mut l = lambda;
                gs.solve(&f.w, black_box(&delta), &mut l, &params)
            })
        });
        c.bench_function(&format!("pgs_prepare_m{m}"), |b| {
            b.iter(|| gs.prepare_frame(black_box(&f)))
        });
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);

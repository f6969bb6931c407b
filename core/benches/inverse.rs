//! The whole inverse step (validate, factor, 8 constraint solves, Newton step) at m = 30, 120
//! and the full capacity 192 on seeded random frames. The controller warm-starts from its previous λ, as in
//! production where consecutive frames are close; the `_cold` variant resets it every step; the
//! `_drifting` variant steps two frames a control period apart in turn, so that every warm start
//! (λ, the sensitivities) comes from the other frame; the `_avx2` and `_baseline` variants run the
//! narrower copies of the loops ([`needle_core::simd`]) on a machine that has wider ones.

use criterion::{Criterion, criterion_group, criterion_main};
use needle_core::simd::{self, SimdLevel};
use std::hint::black_box;

mod common;
use common::{command, controller, drifting_frames, frame};

fn bench(c: &mut Criterion) {
    for m in [30usize, 120, 192] {
        let f = frame(m, 11);
        let mut cmd = command();
        let mut ctrl = controller();
        let rep = ctrl.step(&f, &mut cmd).expect("valid frame");
        println!("inverse_step_m{m}: {rep:?}");
        c.bench_function(&format!("inverse_step_m{m}"), |b| {
            b.iter(|| ctrl.step(black_box(&f), &mut cmd))
        });
        c.bench_function(&format!("inverse_step_m{m}_cold"), |b| {
            b.iter(|| {
                ctrl.reset_warm_start();
                ctrl.step(black_box(&f), &mut cmd)
            })
        });
        // Without the active-set prediction (every solve plain warm-started GS).
        ctrl.params.active_set = false;
        c.bench_function(&format!("inverse_step_m{m}_plain_gs"), |b| {
            b.iter(|| ctrl.step(black_box(&f), &mut cmd))
        });
        ctrl.params.active_set = true;
        // The narrower copies of the loops, as a machine without AVX-512 (or AVX2) runs the
        // step: `inverse_step_m{m}_avx2`, `_baseline` (only where the machine has a wider copy).
        for level in [SimdLevel::Avx2, SimdLevel::Baseline] {
            if level < simd::detected() {
                simd::set_limit(level);
                c.bench_function(&format!("inverse_step_m{m}_{}", level.name()), |b| {
                    b.iter(|| ctrl.step(black_box(&f), &mut cmd))
                });
                simd::set_limit(SimdLevel::Avx512);
            }
        }
        // Two frames a control period apart, in turn: every warm start one frame old.
        let pair = drifting_frames(m, 11);
        let mut ctrl = controller();
        let mut k = 0usize;
        c.bench_function(&format!("inverse_step_m{m}_drifting"), |b| {
            b.iter(|| {
                k += 1;
                ctrl.step(black_box(&pair[k % 2]), &mut cmd)
            })
        });
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);

//! Forward kinematics and Jacobians of the RV-1A.

use criterion::{Criterion, criterion_group, criterion_main};
use needle_core::kinematics::{DhChain, Kinematics, Pose};
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let chain = DhChain::rv1a();
    let q = [0.1, 0.3, 2.0, 0.0, 0.5, 0.0];
    c.bench_function("fk_flange_rv1a", |b| {
        b.iter(|| chain.flange_pose(black_box(&q)))
    });
    c.bench_function("fk_link_frames_rv1a", |b| {
        b.iter(|| {
            let mut frames = [Pose::identity(); 6];
            chain.link_frames(black_box(&q), &mut frames);
            frames
        })
    });
    c.bench_function("jacobian_tool_rv1a", |b| {
        b.iter(|| chain.jacobian_tool(black_box(&q)))
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);

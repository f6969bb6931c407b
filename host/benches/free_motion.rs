//! Free-motion costs of the gel at the benchmark box x ∈ [260, 340], y ∈ [−30, 30],
//! z ∈ [0, 60] mm (bottom clamped), deformed by a seeded random displacement so that the
//! element rotations are non-trivial:
//!
//! - `assemble_gel_<n>_nodes`: corotational update (polar decompositions), internal forces and
//!   the values of `K + M/h²` written into the fixed pattern;
//! - `factor_gel_<n>_nodes`: the numeric sparse Cholesky factorisation (symbolic done once),
//!   `f64`; `…_f32`: the single-precision factor, with the probe solve that checks it;
//! - `solve_gel_<n>_nodes`: one solve with the current factor (and `…_30_rhs`: 30 at once;
//!   `…_f32`: with the single-precision factor); `…_f32_10_points`: the compliance columns of
//!   10 points on the insertion's line (30 right-hand sides, each a node's unit column: the
//!   forward substitution skips the supernodes they do not reach), against `…_f32_30_dense_rhs`;
//! - `factor_near_block_<n>_nodes_f32`: the refactorisation of the single-precision factor's
//!   near block alone (the nodes within 10 mm of the box's vertical centre line eliminated last;
//!   `solver.near_radius`);
//! - `polar/rotations_<n>_nodes`: the element rotations (polar decompositions of the deformation
//!   gradients) of the whole gel, eight elements per SIMD pass; `…_scalar`: one by one, the same
//!   rotations bit for bit; `polar/update_and_forces_<n>_nodes`: the rotations and the internal
//!   forces of every element (the gel's per-step element pass);
//! - `free_motion_needle_40_beams`: one full needle step as a run makes it (forces and
//!   material stiffness by first-order differentiation, factor, solve).
//!
//! Run: `cargo bench -p needle-host --bench free_motion` (add `-- --quick` for a fast pass).
//! Instruction counts of the element pass and the needle step: `element_instructions.rs`.

use criterion::{Criterion, criterion_group, criterion_main};
use needle_host::fem::tetra::{rotation_from_deformation, rotations_from_deformations};
use needle_host::free_motion::{FillOrdering, GelModel, GelParams};
use needle_host::linalg::{Cholesky, Precision, TrailingBlock, nested_dissection_order_with_last};
use std::hint::black_box;

mod common;

fn gel(target: usize) -> GelModel {
    gel_with(target, FillOrdering::NestedDissection, Precision::Double)
}

fn gel_with(target: usize, ordering: FillOrdering, precision: Precision) -> GelModel {
    let mesh = common::benchmark_box(target);
    let bottom = mesh.nodes_on_plane(2, 0.0, 1e-9);
    let params = GelParams {
        time_step: Some(0.01),
        factor_precision: precision,
        ..GelParams::default()
    };
    let mut model = GelModel::try_new_with_ordering(mesh, &bottom, &params, ordering)
        .expect("valid benchmark gel");
    let mut rng = common::Lcg(0x5eed_0001 + target as u64);
    // ±0.06 mm on ~5 mm cells: strains of ~1 %, the regime of the insertion benchmark.
    let dx: Vec<f64> = (0..model.dof_count()).map(|_| 0.06 * rng.next()).collect();
    model.apply_displacement(&dx).expect("finite displacement");
    model.refactor().expect("SPD");
    model
}

/// 30 column-major right-hand sides over `model`'s dofs: the 3 unit columns of each of the 10
/// nodes nearest to the box's vertical centre line at depths 5, 10, …, 50 mm; and 30 dense
/// seeded columns.
fn point_and_dense_columns(model: &GelModel, rng: &mut common::Lcg) -> (Vec<f64>, Vec<f64>) {
    let n = model.dof_count();
    let pos = model.positions();
    let mut points = vec![0.0; 30 * n];
    for k in 0..10 {
        let z = 55.0 - 5.0 * k as f64;
        let d2 =
            |p: &nalgebra::Vector3<f64>| (p.x - 300.0).powi(2) + p.y.powi(2) + (p.z - z).powi(2);
        let node = (0..pos.len())
            .min_by(|&a, &b| d2(&pos[a]).total_cmp(&d2(&pos[b])))
            .expect("nodes");
        for d in 0..3 {
            points[(3 * k + d) * n + 3 * node + d] = 1.0;
        }
    }
    let dense = (0..30 * n).map(|_| rng.next()).collect();
    (points, dense)
}

fn bench_gel(c: &mut Criterion) {
    for target in [600, 1100, 1500, 1800, 5000, 20_000] {
        let mut model = gel(target);
        let n = model.positions().len();
        let mut group = c.benchmark_group("gel");
        if target >= 5000 {
            group.sample_size(10);
        }
        group.bench_function(format!("assemble_gel_{target}_nodes"), |b| {
            b.iter(|| model.assemble())
        });
        if std::env::var_os("NEEDLE_BENCH_AMD").is_some() && target <= 5000 {
            let mut amd = gel_with(target, FillOrdering::Amd, Precision::Double);
            group.bench_function(format!("factor_gel_{target}_nodes_amd"), |b| {
                b.iter(|| amd.factorize().expect("SPD"))
            });
        }
        group.bench_function(format!("factor_gel_{target}_nodes"), |b| {
            b.iter(|| model.factorize().expect("SPD"))
        });
        let mut rng = common::Lcg(0xbeef + target as u64);
        let rhs: Vec<f64> = (0..model.dof_count()).map(|_| rng.next()).collect();
        let mut x = rhs.clone();
        group.bench_function(format!("solve_gel_{target}_nodes"), |b| {
            b.iter(|| {
                x.copy_from_slice(&rhs);
                model.solve(black_box(&mut x)).expect("factorised");
            })
        });
        // The single-precision factor (the scene default): its factorisation includes the
        // probe solve that checks it.
        let mut single = gel_with(target, FillOrdering::NestedDissection, Precision::Single);
        group.bench_function(format!("factor_gel_{target}_nodes_f32"), |b| {
            b.iter(|| single.factorize().expect("SPD"))
        });
        assert_eq!(single.factor_precision(), (Precision::Single, 0));
        group.bench_function(format!("solve_gel_{target}_nodes_f32"), |b| {
            b.iter(|| {
                x.copy_from_slice(&rhs);
                single.solve(black_box(&mut x)).expect("factorised");
            })
        });
        if target >= 1800 {
            // Compliance columns: 10 points along the insertion's line, each its node's 3 unit
            // columns (the forward substitution reaches only their supernodes' paths), against
            // 30 dense right-hand sides (every supernode).
            let (points, dense) = point_and_dense_columns(&single, &mut rng);
            for (name, cols) in [("10_points", &points), ("30_dense_rhs", &dense)] {
                let mut xm = cols.clone();
                group.bench_function(format!("solve_gel_{target}_nodes_f32_{name}"), |b| {
                    b.iter(|| {
                        xm.copy_from_slice(cols);
                        single
                            .solve_columns(black_box(&mut xm), 30)
                            .expect("factorised");
                    })
                });
            }
        }
        drop(single);
        if target <= 1800 {
            // Compliance needs one column per constraint row: 30 right-hand sides at once.
            let cols = 30;
            let rhs_many: Vec<f64> = (0..cols * model.dof_count()).map(|_| rng.next()).collect();
            let mut xm = rhs_many.clone();
            group.bench_function(format!("solve_gel_{target}_nodes_{cols}_rhs"), |b| {
                b.iter(|| {
                    xm.copy_from_slice(&rhs_many);
                    model
                        .solve_columns(black_box(&mut xm), cols)
                        .expect("factorised");
                })
            });
        }
        group.finish();
        eprintln!(
            "gel target {target}: {n} nodes, {} tets, {} free dofs",
            model.tetra().len(),
            model.free_dof_count()
        );
    }
}

/// `gel/factor_near_block_<n>_nodes_f32`: the refactorisation of the near block alone
/// (`solver.near_radius`, `linalg::TrailingBlock`) of the benchmark gel's single-precision
/// factor, the nodes within 10 mm of the box's vertical centre line (the insertion's path)
/// eliminated last; against `factor_gel_<n>_nodes_f32`, the whole factor.
fn bench_near_block(c: &mut Criterion) {
    let mut group = c.benchmark_group("gel");
    group.sample_size(10);
    for target in [1800, 5000, 20_000] {
        let model = gel(target);
        let a = model.matrix().clone();
        let fixed = model.fixed_nodes();
        // The reduced dofs: the free ones in global order.
        let free: Vec<usize> = (0..model.dof_count())
            .filter(|g| fixed.binary_search(&(g / 3)).is_err())
            .collect();
        let nodes = &model.mesh().nodes;
        let coords: Vec<[f64; 3]> = free.iter().map(|&g| nodes[g / 3].into()).collect();
        let near: Vec<bool> = (free.iter())
            .map(|&g| {
                let p = nodes[g / 3];
                ((p.x - 300.0).powi(2) + p.y.powi(2)).sqrt() <= 10.0
            })
            .collect();
        let order = nested_dissection_order_with_last(a.pattern(), &coords, &near);
        let mut chol =
            Cholesky::try_new_with_precision(a.pattern(), Some(&order), 1, Precision::Single)
                .expect("symbolic");
        chol.factorize(&a).expect("SPD");
        let n_near = near.iter().filter(|x| **x).count();
        let mut block =
            TrailingBlock::new(&chol, a.pattern(), free.len() - n_near).expect("supernodal");
        block.capture(&chol, &a).expect("captured");
        eprintln!(
            "gel target {target}: near block of {n_near} of {} dofs",
            free.len()
        );
        group.bench_function(format!("factor_near_block_{target}_nodes_f32"), |b| {
            b.iter(|| block.refactor(&mut chol, black_box(&a)).expect("SPD"))
        });
    }
    group.finish();
}

fn bench_needle(c: &mut Criterion) {
    let (mut needle, f) = common::loaded_needle();
    c.bench_function("free_motion_needle_40_beams", |b| {
        b.iter(|| black_box(needle.free_motion(&f).expect("SPD")[0]))
    });
}

fn bench_polar(c: &mut Criterion) {
    let mut group = c.benchmark_group("polar");
    for target in [1800, 5000] {
        let model = gel(target);
        let tetra = model.tetra();
        let f: Vec<_> = (0..tetra.len())
            .map(|e| tetra.deformation_gradient(e, model.positions()))
            .collect();
        let mut r = vec![nalgebra::Matrix3::zeros(); f.len()];
        group.bench_function(format!("rotations_{target}_nodes"), |b| {
            b.iter(|| rotations_from_deformations(black_box(&f), &mut r))
        });
        group.bench_function(format!("rotations_{target}_nodes_scalar"), |b| {
            b.iter(|| {
                for (f, r) in black_box(&f).iter().zip(r.iter_mut()) {
                    *r = rotation_from_deformation(f);
                }
            })
        });
        let mut tetra = tetra.clone();
        let mut forces = vec![0.0; 3 * model.positions().len()];
        group.bench_function(format!("update_and_forces_{target}_nodes"), |b| {
            b.iter(|| {
                forces.fill(0.0);
                tetra.update_rotations_and_add_internal_forces(
                    black_box(model.positions()),
                    &mut forces,
                )
            })
        });
    }
    group.finish();
}

criterion_group!(
    benches,
    bench_gel,
    bench_near_block,
    bench_polar,
    bench_needle
);
criterion_main!(benches);

//! Instruction counts (valgrind, through gungraun) of the host's two per-step kernels that are
//! pure CPU work — deterministic, unlike their wall time, so a regression shows as an exact
//! count change. CI gates them with the core's against `host/benches/instructions_baseline.json`:
//! `python3 tools/check_instructions.py` (needs valgrind and `gungraun-runner` 0.20.0;
//! `--update` rewrites the baselines).
//!
//! - `gel_element_pass_1500_nodes`: the gel's per-step element pass on the benchmark box (1485
//!   nodes, 6720 elements, seeded ±0.06 mm displacement): every element's rotation (polar
//!   decomposition, eight per SIMD pass) and internal force.
//! - `needle_free_motion_40_beams`: one free motion of the 40-beam needle under a tip load, as
//!   a run makes it (beam energies differentiated once for the forces and the material
//!   stiffness, assembly, factorisation, solve).
//!
//! Valgrind reports no AVX-512, so the counts are those of the AVX2 code path.

use gungraun::{library_benchmark, library_benchmark_group, main};
use nalgebra::Vector3;
use needle_host::fem::tetra::CorotationalTetra;
use needle_host::free_motion::NeedleModel;
use std::hint::black_box;

mod common;

struct Elements {
    tetra: CorotationalTetra,
    x: Vec<Vector3<f64>>,
    forces: Vec<f64>,
}

fn elements(target: usize) -> Elements {
    let (tetra, x) = common::deformed_box_elements(target);
    let forces = vec![0.0; 3 * x.len()];
    Elements { tetra, x, forces }
}

#[library_benchmark]
#[bench::gel_element_pass_1500_nodes(args = (1500,), setup = elements)]
fn element_pass(mut s: Elements) -> f64 {
    s.tetra
        .update_rotations_and_add_internal_forces(black_box(&s.x), &mut s.forces);
    black_box(s.forces[0])
}

fn needle(_: ()) -> (NeedleModel, Vec<f64>) {
    common::loaded_needle()
}

#[library_benchmark]
#[bench::needle_free_motion_40_beams(args = ((),), setup = needle)]
fn needle_free_motion(s: (NeedleModel, Vec<f64>)) -> f64 {
    let (mut needle, f) = s;
    black_box(needle.free_motion(black_box(&f)).expect("SPD")[0])
}

library_benchmark_group!(name = host; benchmarks = element_pass, needle_free_motion);

main!(library_benchmark_groups = host);

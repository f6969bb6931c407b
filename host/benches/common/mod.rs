//! Shared bench setup: a seeded pseudo-random source, the benchmark box's element set in a
//! seeded deformed state, and the 40-beam needle under a tip load.

#![allow(dead_code)]

use nalgebra::{Isometry3, Vector3};
use needle_host::fem::Elasticity;
use needle_host::fem::beam::BeamSection;
use needle_host::fem::tetra::{CorotationalTetra, Kinematics};
use needle_host::free_motion::{NeedleModel, NeedleParams};
use needle_host::mesh::{TetMesh, box_mesh};

/// Deterministic pseudo-random numbers in [−1, 1) (64-bit LCG, fixed seed).
pub struct Lcg(pub u64);

impl Lcg {
    pub fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((self.0 >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    }
}

/// The gel box of the insertion benchmark, x ∈ [260, 340], y ∈ [−30, 30], z ∈ [0, 60] mm, with
/// about `target` nodes.
pub fn benchmark_box(target: usize) -> TetMesh {
    box_mesh(
        Vector3::new(260.0, -30.0, 0.0),
        Vector3::new(340.0, 30.0, 60.0),
        target,
    )
}

/// The benchmark box's corotational elements (20 kPa, ν 0.45) and node positions moved by a
/// seeded ±0.06 mm (strains of about 1 %).
pub fn deformed_box_elements(target: usize) -> (CorotationalTetra, Vec<Vector3<f64>>) {
    let mesh = benchmark_box(target);
    let material = Elasticity {
        young_modulus: 0.02,
        poisson_ratio: 0.45,
    };
    let tetra = CorotationalTetra::try_new(&mesh, &material, Kinematics::Corotational)
        .expect("valid benchmark box");
    let mut rng = Lcg(0x5eed_0001 + target as u64);
    let x = mesh
        .nodes
        .iter()
        .map(|p| p + Vector3::from_fn(|_, _| 0.06 * rng.next()))
        .collect();
    (tetra, x)
}

/// A straight 150 mm steel needle of 40 beams (Ø 1 mm) and the tip's lateral load of 0.1 N,
/// after one free motion (factorised); with the material stiffness only, as a run's needle
/// (`NeedleModel::set_geometric_stiffness(false)`: no Hessian of the beam energies).
pub fn loaded_needle() -> (NeedleModel, Vec<f64>) {
    let section = BeamSection {
        elasticity: Elasticity {
            young_modulus: 200_000.0,
            poisson_ratio: 0.3,
        },
        outer_diameter: 1.0,
        inner_diameter: 0.0,
        density: 7.85e-9,
    };
    let params = NeedleParams {
        section,
        time_step: Some(0.01),
        refactor_every: 1,
    };
    let mut needle = NeedleModel::straight(&Isometry3::identity(), 150.0, 40, &[], &params)
        .expect("valid needle");
    needle.set_geometric_stiffness(false);
    let mut f = vec![0.0; needle.dof_count()];
    let tip = needle.node_count() - 1;
    f[6 * tip + 1] = 0.1;
    needle.free_motion(&f).expect("SPD");
    (needle, f)
}

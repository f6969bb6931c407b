//! The refactorisation of a factor's trailing block (`linalg::TrailingBlock`) against a full
//! factorisation of the same matrix: a gel-like matrix (three dofs per node of a box mesh,
//! weighted graph Laplacian plus a mass-like diagonal) whose rows near a vertical line are
//! eliminated last, changed only in the block of those rows.

use nalgebra::Vector3;
use needle_host::linalg::{
    Cholesky, LinalgError, Precision, SymmetricMatrix, SymmetricPattern, TrailingBlock,
    nested_dissection_order_with_last,
};
use needle_host::mesh::box_mesh;

/// Deterministic numbers in [0, 1).
struct Lcg(u64);

impl Lcg {
    fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// The problem: the pattern, each dof's position, which dofs are near the line, and the mesh's
/// edges as dof pairs.
struct Problem {
    pattern: SymmetricPattern,
    coords: Vec<[f64; 3]>,
    near: Vec<bool>,
    edges: Vec<(usize, usize)>,
}

fn problem() -> Problem {
    let mesh = box_mesh(Vector3::zeros(), Vector3::new(40.0, 30.0, 30.0), 1500);
    let n = 3 * mesh.nodes.len();
    let mut entries = Vec::new();
    let mut edges = Vec::new();
    for t in &mesh.tets {
        for &a in t {
            for &b in t {
                for da in 0..3 {
                    for db in 0..3 {
                        entries.push((3 * a + da, 3 * b + db));
                    }
                }
                if a < b {
                    for d in 0..3 {
                        edges.push((3 * a + d, 3 * b + d));
                    }
                }
            }
        }
    }
    edges.sort_unstable();
    edges.dedup();
    let pattern = SymmetricPattern::from_entries(n, entries);
    let mut coords = vec![[0.0; 3]; n];
    let mut near = vec![false; n];
    for (i, p) in mesh.nodes.iter().enumerate() {
        let r = ((p.x - 20.0).powi(2) + (p.y - 15.0).powi(2)).sqrt();
        for d in 0..3 {
            coords[3 * i + d] = [p.x, p.y, p.z];
            near[3 * i + d] = r <= 6.0;
        }
    }
    Problem {
        pattern,
        coords,
        near,
        edges,
    }
}

/// Weighted Laplacian of the edges (weights from `w`) plus `shift` on the diagonal: SPD.
fn matrix(
    p: &Problem,
    w: impl Fn(usize, usize) -> f64,
    shift: impl Fn(usize) -> f64,
) -> SymmetricMatrix {
    let mut a = SymmetricMatrix::zeros(p.pattern.clone());
    let slot = |i: usize, j: usize| p.pattern.slot(i.min(j), i.max(j)).expect("in the pattern");
    for &(i, j) in &p.edges {
        let k = w(i, j);
        a.values[slot(i, j)] -= k;
        a.values[slot(i, i)] += k;
        a.values[slot(j, j)] += k;
    }
    for i in 0..p.pattern.dim() {
        a.values[slot(i, i)] += shift(i);
    }
    a
}

fn relative_difference(a: &[f64], b: &[f64]) -> f64 {
    let d: f64 = a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum();
    let n: f64 = b.iter().map(|y| y * y).sum();
    (d / n).sqrt()
}

/// Factor of `a0` refactorised for `a1` (changed in the near block only) against a fresh
/// factor of `a1`: the solutions of one right-hand side.
fn check(precision: Precision, tolerance: f64) {
    let p = problem();
    let n = p.pattern.dim();
    let n_near = p.near.iter().filter(|x| **x).count();
    assert!(n_near > 50 && n_near < n / 5, "{n_near} near dofs of {n}");
    let order = nested_dissection_order_with_last(&p.pattern, &p.coords, &p.near);
    let mut rng = Lcg(7);
    let w0: Vec<f64> = (0..p.edges.len()).map(|_| 0.5 + rng.next()).collect();
    let index = |i: usize, j: usize| p.edges.binary_search(&(i, j)).expect("an edge");
    let a0 = matrix(&p, |i, j| w0[index(i, j)], |_| 0.1);
    // Only the edges and diagonals among near dofs change (by up to a factor of 2).
    let scale: Vec<f64> = (0..p.edges.len()).map(|_| 0.5 + 1.5 * rng.next()).collect();
    let a1 = matrix(
        &p,
        |i, j| {
            let k = index(i, j);
            if p.near[i] && p.near[j] {
                w0[k] * scale[k]
            } else {
                w0[k]
            }
        },
        |i| if p.near[i] { 0.3 } else { 0.1 },
    );
    let b: Vec<f64> = (0..n).map(|_| rng.next() - 0.5).collect();

    let mut chol =
        Cholesky::try_new_with_precision(&p.pattern, Some(&order), 1, precision).expect("symbolic");
    chol.factorize(&a0).expect("SPD");
    let mut block = TrailingBlock::new(&chol, &p.pattern, n - n_near).expect("supernodal");
    assert_eq!(block.size(), n_near);
    assert_eq!(
        block.refactor(&mut chol, &a1),
        Err(LinalgError::NotFactorized),
        "nothing captured yet"
    );
    block.capture(&chol, &a0).expect("captured");
    assert_eq!(block.captured(), chol.stamp());
    let stamp = chol.stamp();
    block.refactor(&mut chol, &a1).expect("SPD block");
    assert_ne!(
        chol.stamp(),
        stamp,
        "a refactorised factor is another factor"
    );
    assert_eq!(block.captured(), chol.stamp(), "the capture holds for it");
    // Another factor (of the same pattern and order) is not the captured one.
    let mut other =
        Cholesky::try_new_with_precision(&p.pattern, Some(&order), 1, precision).expect("symbolic");
    other.factorize(&a0).expect("SPD");
    assert_eq!(
        block.refactor(&mut other, &a1),
        Err(LinalgError::NotFactorized)
    );
    let mut x = b.clone();
    chol.solve_in_place(&mut x).expect("factorised");

    let mut full =
        Cholesky::try_new_with_precision(&p.pattern, Some(&order), 1, precision).expect("symbolic");
    full.factorize(&a1).expect("SPD");
    let mut want = b.clone();
    full.solve_in_place(&mut want).expect("factorised");
    let diff = relative_difference(&x, &want);
    assert!(
        diff < tolerance,
        "{precision:?}: {diff:e} from the full factor's solution"
    );

    // The factor of a0 solved a0's system before: it no longer does (the block changed).
    let mut x0 = b.clone();
    let mut f0 =
        Cholesky::try_new_with_precision(&p.pattern, Some(&order), 1, precision).expect("symbolic");
    f0.factorize(&a0).expect("SPD");
    f0.solve_in_place(&mut x0).expect("factorised");
    assert!(relative_difference(&x0, &want) > 100.0 * tolerance);

    // Refactorising again (back to a0) from the same capture gives a0's solution.
    block.refactor(&mut chol, &a0).expect("SPD block");
    let mut back = b.clone();
    chol.solve_in_place(&mut back).expect("factorised");
    let diff = relative_difference(&back, &x0);
    assert!(diff < tolerance, "{precision:?}: back to a0, {diff:e}");
}

#[test]
fn trailing_refactorisation_solves_as_the_full_factor_in_double() {
    check(Precision::Double, 1e-13);
}

#[test]
fn trailing_refactorisation_solves_as_the_full_factor_in_single() {
    check(Precision::Single, 1e-5);
}

#[test]
fn trailing_order_puts_the_marked_rows_last_and_keeps_the_plain_order_otherwise() {
    let p = problem();
    let n = p.pattern.dim();
    let order = nested_dissection_order_with_last(&p.pattern, &p.coords, &p.near);
    let n_near = p.near.iter().filter(|x| **x).count();
    let mut seen = vec![false; n];
    for &i in &order {
        assert!(!seen[i], "row {i} twice");
        seen[i] = true;
    }
    assert!(seen.iter().all(|s| *s));
    assert!(order[..n - n_near].iter().all(|&i| !p.near[i]));
    assert!(order[n - n_near..].iter().all(|&i| p.near[i]));
    // Nothing marked: the plain nested-dissection order.
    let none = vec![false; n];
    assert_eq!(
        nested_dissection_order_with_last(&p.pattern, &p.coords, &none),
        needle_host::linalg::nested_dissection_order(&p.pattern, &p.coords)
    );
}

/// The gel's near block in a run of the background pipeline (`GelParams::near_nodes`): every
/// step's free motion is the solve with a factor whose matrix is some step `j`'s with the
/// elements all of whose nodes are near turned to their rotations of a step `b` (`j ≤ b ≤ k`),
/// `b` being `j` or a step that refactorised the block; the block is refactorised, and such a
/// matrix with `b ≠ j` is used.
#[test]
fn near_block_steps_solve_with_a_far_matrix_and_a_later_near_block() {
    use needle_host::free_motion::{GelModel, GelParams, RefreshParams};
    let (mesh, bottom, near) = box_with_near_column();
    let plain = GelParams {
        time_step: Some(0.05),
        density: 1e-8,
        ..GelParams::default()
    };
    let params = GelParams {
        background_factorization: true,
        refactor_every: 2,
        refresh: Some(RefreshParams {
            rotation: 0.01,
            far_rotation: 0.01,
            ceiling: usize::MAX,
        }),
        near_nodes: Some(near.clone()),
        ..plain.clone()
    };
    let mut model = GelModel::try_new(mesh.clone(), &bottom, &params).unwrap();
    assert!(
        model.has_near_block(),
        "a supernodal factor keeps the block"
    );
    let mut by_hand = GelModel::try_new(mesh.clone(), &bottom, &plain).unwrap();
    // A load on the near column's top nodes, sideways then back: the column bends.
    let top = mesh.nodes_on_plane(2, 20.0, 1e-9);
    let load = |k: usize| {
        let mut f = vec![0.0; model_dofs(&mesh)];
        let fx = if k < 14 { 4e-3 } else { -4e-3 };
        for &i in &top {
            if near[i] {
                f[3 * i] = fx;
            }
        }
        f
    };
    let free: Vec<usize> = (0..3 * mesh.nodes.len())
        .filter(|g| !bottom.contains(&(g / 3)))
        .collect();
    let mut matrices: Vec<needle_host::linalg::SymmetricMatrix> = Vec::new();
    let mut rotations: Vec<Vec<nalgebra::Matrix3<f64>>> = Vec::new();
    let near_elements: Vec<usize> = (0..mesh.tets.len())
        .filter(|&e| mesh.tets[e].iter().all(|&v| near[v]))
        .collect();
    let reduced: std::collections::HashMap<usize, usize> =
        free.iter().enumerate().map(|(k, &g)| (g, k)).collect();
    let mut block_steps: Vec<usize> = Vec::new();
    let mut factors: std::collections::HashMap<(usize, usize), Cholesky> = Default::default();
    let (mut mixed_used, mut last_near) = (0, 0);
    for k in 0..28 {
        let f = load(k);
        let x = model.positions().to_vec();
        by_hand.positions_mut().copy_from_slice(&x);
        by_hand.refactor().unwrap();
        matrices.push(by_hand.matrix().clone());
        by_hand.compute_internal_forces();
        rotations.push(by_hand.tetra().rotations().to_vec());
        let dx = model.free_motion(&f).unwrap().to_vec();
        if model.near_refactorizations() > last_near {
            last_near = model.near_refactorizations();
            block_steps.push(k);
        }
        let f_int = by_hand.compute_internal_forces().to_vec();
        let rhs: Vec<f64> = free.iter().map(|&g| f[g] - f_int[g]).collect();
        let got: Vec<f64> = free.iter().map(|&g| dx[g]).collect();
        let mut found = None;
        'search: for j in (0..=k).rev() {
            let blocks = std::iter::once(j).chain(block_steps.iter().copied().filter(|&b| b > j));
            for b in blocks {
                let chol = factors.entry((j, b)).or_insert_with(|| {
                    let mut m = matrices[j].clone();
                    let pattern = m.pattern().clone();
                    let tetra = by_hand.tetra();
                    for &e in &near_elements {
                        let dofs: Vec<(usize, usize)> = tetra.stiffness_entry_dofs(e).collect();
                        let n = dofs.len();
                        let mut slots = vec![u32::MAX; n * tetra.len()];
                        for (k, s) in slots[n * e..n * (e + 1)].iter_mut().enumerate() {
                            *s = k as u32;
                        }
                        let mut change = vec![0.0; n];
                        tetra.assemble_element(e, &rotations[b][e], &slots, &mut change, 1.0);
                        tetra.assemble_element(e, &rotations[j][e], &slots, &mut change, -1.0);
                        for (&(r, c), d) in dofs.iter().zip(&change) {
                            if let (Some(&r), Some(&c)) = (reduced.get(&r), reduced.get(&c)) {
                                let s = pattern.slot(r.min(c), r.max(c)).expect("in the pattern");
                                m.values[s] += d;
                            }
                        }
                    }
                    let mut chol = Cholesky::try_new(&pattern, 1).unwrap();
                    chol.factorize(&m).unwrap();
                    chol
                });
                let mut want = rhs.clone();
                chol.solve_in_place(&mut want).unwrap();
                if relative_difference(&got, &want) < 1e-9 {
                    found = Some((j, b));
                    break 'search;
                }
            }
        }
        let (j, b) =
            found.unwrap_or_else(|| panic!("step {k}: no far and near matrix pair solves it"));
        mixed_used += usize::from(b != j);
        model.apply_displacement(&dx).unwrap();
    }
    println!("near refreshes at {block_steps:?}; {mixed_used} steps with a mixed matrix");
    assert!(
        block_steps.len() >= 2,
        "near refreshes at {block_steps:?}: the test is void"
    );
    assert!(
        mixed_used >= 2,
        "{mixed_used} steps with a mixed matrix: the test is void"
    );
}

/// The 637-node clamped box of the run-level tests, and its near column: the nodes within 5 mm
/// of the vertical line through the box's centre.
fn box_with_near_column() -> (needle_host::mesh::TetMesh, Vec<usize>, Vec<bool>) {
    let (mesh, bottom) = needle_tests::clamped_box(needle_host::mesh::BoxDivisions {
        nx: 12,
        ny: 6,
        nz: 6,
    });
    let near = (mesh.nodes.iter())
        .map(|p| ((p.x - 20.0).powi(2) + (p.y - 10.0).powi(2)).sqrt() <= 5.0)
        .collect();
    (mesh, bottom, near)
}

fn model_dofs(mesh: &needle_host::mesh::TetMesh) -> usize {
    3 * mesh.nodes.len()
}

/// `RefreshParams::far_rotation` drives the background pipeline when the gel has a near block:
/// the far elements then send fewer matrices to be factorised with a larger one, while the near
/// block is still refreshed at `rotation`.
#[test]
fn far_rotation_sends_fewer_far_matrices_and_keeps_the_near_refreshes() {
    use needle_host::free_motion::{GelModel, GelParams, RefreshParams};
    let (mesh, bottom, near) = box_with_near_column();
    let top = mesh.nodes_on_plane(2, 20.0, 1e-9);
    let run = |far_rotation: f64| {
        let params = GelParams {
            time_step: Some(0.05),
            density: 1e-8,
            background_factorization: true,
            refactor_every: 2,
            refresh: Some(RefreshParams {
                rotation: 0.01,
                far_rotation,
                ceiling: usize::MAX,
            }),
            near_nodes: Some(near.clone()),
            ..GelParams::default()
        };
        let mut model = GelModel::try_new(mesh.clone(), &bottom, &params).unwrap();
        for k in 0..28 {
            // The whole top face pushed sideways then back: near and far elements turn.
            let mut f = vec![0.0; model_dofs(&mesh)];
            for &i in &top {
                f[3 * i] = if k < 14 { 4e-3 } else { -4e-3 };
            }
            let dx = model.free_motion(&f).unwrap().to_vec();
            model.apply_displacement(&dx).unwrap();
        }
        let (background, immediate) = model.background_counts().unwrap();
        (background + immediate, model.near_refactorizations())
    };
    let (full_tight, near_tight) = run(0.01);
    let (full_loose, near_loose) = run(0.1);
    println!("full factorisations {full_tight} -> {full_loose}, near {near_tight} -> {near_loose}");
    assert!(
        full_loose < full_tight,
        "far_rotation 0.1 made {full_loose} full factorisations, 0.01 made {full_tight}"
    );
    assert!(near_loose >= 1, "the near block is still refreshed");
}

//! The refactorisation of a factor's trailing block (`linalg::TrailingBlock`) against a full
//! factorisation of the same matrix: a gel-like matrix (three dofs per node of a box mesh,
//! weighted graph Laplacian plus a mass-like diagonal) whose rows near a vertical line are
//! eliminated last, changed only in the block of those rows.

use nalgebra::Vector3;
use needle_host::linalg::{
    Cholesky, LinalgError, Precision, SymmetricMatrix, SymmetricPattern, TrailingBlock,
    nested_dissection_order_with_last, nested_dissection_order_with_last_two,
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

/// Two nested trailing blocks (the near rows, and the top of them, `z ≥ 15`, eliminated last of
/// all): the near block refactorised for a matrix changed among near rows, the inner block
/// captured from that factor and refactorised for a matrix changed among its own rows, then the
/// near block again from its carried capture; each factor solves as a fresh factorisation of its
/// matrix.
fn check_nested(precision: Precision, tolerance: f64) {
    let p = problem();
    let n = p.pattern.dim();
    let inner: Vec<bool> = (0..n)
        .map(|i| p.near[i] && p.coords[i][2] >= 15.0)
        .collect();
    let (n_near, n_inner) = (
        p.near.iter().filter(|x| **x).count(),
        inner.iter().filter(|x| **x).count(),
    );
    assert!(
        n_inner > 20 && n_inner < n_near,
        "{n_inner} inner rows of {n_near}"
    );
    let order = nested_dissection_order_with_last_two(&p.pattern, &p.coords, &p.near, &inner);
    assert!(order[n - n_inner..].iter().all(|&i| inner[i]));
    assert!(
        order[n - n_near..n - n_inner]
            .iter()
            .all(|&i| p.near[i] && !inner[i])
    );
    let mut rng = Lcg(11);
    let w0: Vec<f64> = (0..p.edges.len()).map(|_| 0.5 + rng.next()).collect();
    let index = |i: usize, j: usize| p.edges.binary_search(&(i, j)).expect("an edge");
    // The edges among the rows of `set` scaled by `scale`, the others as in w0.
    let changed = |set: &[bool], scale: &[f64], shift: f64| {
        matrix(
            &p,
            |i, j| {
                let k = index(i, j);
                if set[i] && set[j] {
                    w0[k] * scale[k]
                } else {
                    w0[k]
                }
            },
            |i| if set[i] { shift } else { 0.1 },
        )
    };
    let mut scale = || {
        (0..p.edges.len())
            .map(|_| 0.5 + 1.5 * rng.next())
            .collect::<Vec<_>>()
    };
    let (s1, s2, s3) = (scale(), scale(), scale());
    let a0 = changed(&p.near, &vec![1.0; p.edges.len()], 0.1);
    let a1 = changed(&p.near, &s1, 0.3);
    // a2: a1 changed again among the inner rows alone.
    let mut a2 = a1.clone();
    let a1_inner = changed(&inner, &s1, 0.3);
    let a2_inner = changed(&inner, &s2, 0.2);
    for (v, (x, y)) in a2
        .values
        .iter_mut()
        .zip(a2_inner.values.iter().zip(&a1_inner.values))
    {
        *v += x - y;
    }
    let a3 = changed(&p.near, &s3, 0.25);
    let b: Vec<f64> = (0..n).map(|_| rng.next() - 0.5).collect();
    let fresh = |a: &SymmetricMatrix| {
        let mut f = Cholesky::try_new_with_precision(&p.pattern, Some(&order), 1, precision)
            .expect("symbolic");
        f.factorize(a).expect("SPD");
        let mut x = b.clone();
        f.solve_in_place(&mut x).expect("factorised");
        x
    };
    let solve = |chol: &mut Cholesky| {
        let mut x = b.clone();
        chol.solve_in_place(&mut x).expect("factorised");
        x
    };

    let mut chol =
        Cholesky::try_new_with_precision(&p.pattern, Some(&order), 1, precision).expect("symbolic");
    chol.factorize(&a0).expect("SPD");
    let mut near = TrailingBlock::new(&chol, &p.pattern, n - n_near).expect("supernodal");
    let mut top = TrailingBlock::new(&chol, &p.pattern, n - n_inner).expect("supernodal");
    near.capture(&chol, &a0).expect("captured");
    top.capture(&chol, &a0).expect("captured");
    near.refactor(&mut chol, &a1).expect("SPD block");
    assert_eq!(
        top.refactor(&mut chol, &a2),
        Err(LinalgError::NotFactorized),
        "the inner capture is of the factor before the near refresh"
    );
    top.capture(&chol, &a1).expect("captured");
    let before = chol.stamp();
    top.refactor(&mut chol, &a2).expect("SPD block");
    let d = relative_difference(&solve(&mut chol), &fresh(&a2));
    assert!(d < tolerance, "{precision:?}: inner refresh {d:e}");
    assert_eq!(
        near.refactor(&mut chol, &a3),
        Err(LinalgError::NotFactorized),
        "not carried yet"
    );
    near.carry_capture(before + 1_000_000, &chol);
    assert_ne!(
        near.captured(),
        chol.stamp(),
        "another factor's stamp carries nothing"
    );
    near.carry_capture(before, &chol);
    assert_eq!(near.captured(), chol.stamp());
    near.refactor(&mut chol, &a3).expect("SPD block");
    let d = relative_difference(&solve(&mut chol), &fresh(&a3));
    assert!(
        d < tolerance,
        "{precision:?}: near refresh after the inner one {d:e}"
    );
    assert!(relative_difference(&fresh(&a2), &fresh(&a3)) > 100.0 * tolerance);
}

#[test]
fn nested_trailing_blocks_solve_as_full_factors_in_double() {
    check_nested(Precision::Double, 1e-13);
}

#[test]
fn nested_trailing_blocks_solve_as_full_factors_in_single() {
    check_nested(Precision::Single, 1e-5);
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
    let (_, _, near) = box_with_near_column();
    let load = |k: usize| if k < 14 { 4e-3 } else { -4e-3 };
    let (near_steps, entry_steps) = check_block_steps(&near, &near, None, load);
    assert!(entry_steps.is_empty());
    assert!(near_steps.len() >= 2);
}

/// As [`near_block_steps_solve_with_a_far_matrix_and_a_later_near_block`] with an entry block
/// (`GelParams::entry_nodes`: the nodes within 7.5 mm of the column's top centre, added to the
/// near block): every step's free motion is the solve with some step `j`'s matrix whose near
/// elements are turned to a later near refresh's rotations and whose entry elements to a still
/// later entry refresh's; the entry block is refactorised on its own, and the near block less
/// often than without it.
#[test]
fn entry_block_steps_solve_with_a_far_matrix_a_near_block_and_a_later_entry_block() {
    let (mesh, _, near) = box_with_near_column();
    let centre = Vector3::new(20.0, 10.0, 20.0);
    let entry: Vec<bool> = (mesh.nodes.iter())
        .map(|p| (p - centre).norm() <= 7.5)
        .collect();
    // A load on the top nodes within 3 mm of the column's centre: the gel turns most below it.
    let loaded: Vec<bool> = (mesh.nodes.iter())
        .map(|p| (p - centre).norm() <= 3.0)
        .collect();
    let load = |k: usize| 4e-3 * (1 + k.min(27 - k)) as f64;
    let (near_alone, _) = check_block_steps(&near, &loaded, None, load);
    let (near_steps, entry_steps) = check_block_steps(&near, &loaded, Some(entry), load);
    // An entry block as large as the near block is none: the near block's refreshes alone.
    let (whole, none) = check_block_steps(&near, &loaded, Some(near.clone()), load);
    assert!(none.is_empty(), "entry refreshes at {none:?}");
    assert_eq!(whole, near_alone);
    println!("near refreshes without an entry block at {near_alone:?}");
    assert!(
        entry_steps.len() >= 2,
        "entry refreshes at {entry_steps:?}: the test is void"
    );
    assert!(
        near_steps.len() < near_alone.len(),
        "near refreshes {near_steps:?} with the entry block, {near_alone:?} without"
    );
}

/// Runs the box with the near block `near` and the entry block `entry` (added to `near`), its
/// top nodes marked in `loaded` pushed sideways by `load(step)` per node, and checks every
/// step's free motion against the solves with the matrices the refresh rule allows (see the
/// tests above). Returns the steps that refreshed the near block and the entry block.
fn check_block_steps(
    near: &[bool],
    loaded: &[bool],
    entry: Option<Vec<bool>>,
    load: impl Fn(usize) -> f64,
) -> (Vec<usize>, Vec<usize>) {
    use needle_host::free_motion::{GelModel, GelParams};
    let (mesh, bottom, _) = box_with_near_column();
    let mut near = near.to_vec();
    if let Some(e) = &entry {
        for (n, x) in near.iter_mut().zip(e) {
            *n |= *x;
        }
    }
    let in_entry = |v: usize| entry.as_ref().is_some_and(|e| e[v]);
    let (plain, params) = block_params(&near);
    let params = GelParams {
        entry_nodes: entry.clone(),
        ..params
    };
    let mut model = GelModel::try_new(mesh.clone(), &bottom, &params).unwrap();
    assert!(
        model.has_near_block(),
        "a supernodal factor keeps the block"
    );
    let mut by_hand = GelModel::try_new(mesh.clone(), &bottom, &plain).unwrap();
    // The load on the marked top nodes, sideways then back.
    let top = mesh.nodes_on_plane(2, 20.0, 1e-9);
    let forces = |k: usize| {
        let mut f = vec![0.0; model_dofs(&mesh)];
        for &i in &top {
            if loaded[i] {
                f[3 * i] = load(k);
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
    let is_entry = |e: usize| mesh.tets[e].iter().all(|&v| in_entry(v));
    let reduced: std::collections::HashMap<usize, usize> =
        free.iter().enumerate().map(|(k, &g)| (g, k)).collect();
    let mut block_steps: Vec<usize> = Vec::new();
    let mut entry_steps: Vec<usize> = Vec::new();
    let mut factors: std::collections::HashMap<(usize, usize, usize), Cholesky> =
        Default::default();
    let (mut mixed_used, mut last_near, mut last_entry) = (0, 0, 0);
    for k in 0..28 {
        let f = forces(k);
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
        if model.entry_refactorizations() > last_entry {
            last_entry = model.entry_refactorizations();
            entry_steps.push(k);
        }
        let f_int = by_hand.compute_internal_forces().to_vec();
        let rhs: Vec<f64> = free.iter().map(|&g| f[g] - f_int[g]).collect();
        let got: Vec<f64> = free.iter().map(|&g| dx[g]).collect();
        let mut found = None;
        'search: for j in (0..=k).rev() {
            let blocks = std::iter::once(j).chain(block_steps.iter().copied().filter(|&b| b > j));
            for (b, c) in blocks.flat_map(|b| {
                std::iter::once((b, b)).chain(
                    (entry_steps.iter().copied())
                        .filter(move |&c| c > b)
                        .map(move |c| (b, c)),
                )
            }) {
                let chol = factors.entry((j, b, c)).or_insert_with(|| {
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
                        let to = if is_entry(e) { c } else { b };
                        tetra.assemble_element(e, &rotations[to][e], &slots, &mut change, 1.0);
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
                    found = Some((j, b, c));
                    break 'search;
                }
            }
        }
        let (j, b, c) =
            found.unwrap_or_else(|| panic!("step {k}: no far, near and entry matrices solve it"));
        mixed_used += usize::from(b != j || c != j);
        model.apply_displacement(&dx).unwrap();
    }
    println!(
        "near refreshes at {block_steps:?}, entry refreshes at {entry_steps:?}; \
         {mixed_used} steps with a mixed matrix"
    );
    assert!(
        mixed_used >= 2,
        "{mixed_used} steps with a mixed matrix: the test is void"
    );
    (block_steps, entry_steps)
}

/// The plain gel of the block tests (solved whole at every step, for reference) and the same
/// with the background pipeline, a refresh at 0.01 rad and the `near` block.
fn block_params(
    near: &[bool],
) -> (
    needle_host::free_motion::GelParams,
    needle_host::free_motion::GelParams,
) {
    use needle_host::free_motion::{GelParams, RefreshParams};
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
        near_nodes: Some(near.to_vec()),
        ..plain.clone()
    };
    (plain, params)
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

/// `GelParams::far_linear`: with the elements outside the near block kept linear, the far
/// field never makes the factor stale. Loads on near nodes only (the needle's) push the top of
/// the near column sideways and back, so that near and far elements turn (up to 0.48 rad): the
/// corotational far field sends matrices to the background factorisation, the linear one
/// factorises the whole gel once (the first factor) and refreshes the near block alone; and,
/// linear and solved with its own matrix, the far field is in equilibrium after every step
/// (its residual at round-off, where the corotational far field's is not).
#[test]
fn linear_far_elements_never_make_the_whole_factor_stale() {
    use needle_host::free_motion::{GelModel, GelParams};
    let (mesh, bottom, near) = box_with_near_column();
    let top: Vec<usize> = (mesh.nodes_on_plane(2, 20.0, 1e-9).into_iter())
        .filter(|&i| near[i])
        .collect();
    let (_, params) = block_params(&near);
    let run = |far_linear: bool| {
        let params = GelParams {
            far_linear,
            time_step: None,
            ..params.clone()
        };
        let mut model = GelModel::try_new(mesh.clone(), &bottom, &params).unwrap();
        // The same elements, kept linear or not, to evaluate the residual by hand.
        let plain = GelParams {
            background_factorization: false,
            refresh: None,
            ..params.clone()
        };
        let mut by_hand = GelModel::try_new(mesh.clone(), &bottom, &plain).unwrap();
        let (mut largest_turn, mut far_share) = (0.0f64, 0.0f64);
        for k in 0..28 {
            let mut f = vec![0.0; model_dofs(&mesh)];
            for &i in &top {
                f[3 * i] = if k < 14 { 2e-2 } else { -2e-2 };
            }
            let dx = model.free_motion(&f).unwrap().to_vec();
            model.apply_displacement(&dx).unwrap();
            by_hand.positions_mut().copy_from_slice(model.positions());
            let f_int = by_hand.compute_internal_forces().to_vec();
            let far2: f64 = (0..f_int.len())
                .filter(|&g| !near[g / 3] && !model.is_fixed_dof(g))
                .map(|g| f_int[g] * f_int[g])
                .sum();
            let load: f64 = f.iter().map(|v| v * v).sum();
            far_share = far_share.max((far2 / load).sqrt());
            for r in by_hand.tetra().rotations() {
                let c = ((r.trace() - 1.0) / 2.0).clamp(-1.0, 1.0);
                largest_turn = largest_turn.max(c.acos());
            }
        }
        let (background, immediate) = model.background_counts().unwrap();
        (
            background + immediate,
            model.near_refactorizations(),
            far_share,
            largest_turn,
        )
    };
    let (full_corot, near_corot, far_corot, turn) = run(false);
    let (full_linear, near_linear, far_linear, _) = run(true);
    println!(
        "corotational far field: {full_corot} full factorisations, {near_corot} near, far \
         residual up to {far_corot:.2e} of the load; linear: {full_linear}, {near_linear}, \
         {far_linear:.2e}; largest element turn {turn:.3} rad"
    );
    assert!(
        full_corot > 1,
        "the corotational far field made the factor stale: the test is void"
    );
    assert!(
        far_corot > 1e-3,
        "the corotational far field was in equilibrium: the test is void"
    );
    assert_eq!(
        full_linear, 1,
        "the linear far field factorises the whole gel once"
    );
    assert!(near_linear >= 1, "the near block is still refreshed");
    assert!(
        far_linear <= 1e-9,
        "the linear far field's residual {far_linear:.2e} of the load"
    );
}

/// `GelParams::far_residual_tolerance`: a free motion whose right-hand side is, outside the near
/// block, at most `τ` of its whole norm is solved with those entries dropped (bit for bit the
/// factor's solve of the right-hand side zeroed there); any other is solved whole; `τ = 0`
/// solves every one whole. Each step is an insertion's: the unloaded free motion, then a
/// corrective motion `K⁻¹ g` by the factor in use for a force `g` on near nodes (the needle's
/// constraint force), and every fourth step a force on a far node too, which the far field
/// is then out of equilibrium by.
#[test]
fn far_residual_is_dropped_only_below_its_tolerance() {
    use needle_host::free_motion::{GelModel, GelParams};
    let (mesh, bottom, near) = box_with_near_column();
    let top = mesh.nodes_on_plane(2, 20.0, 1e-9);
    let far_top = *top.iter().find(|&&i| !near[i]).expect("a far top node");
    let (plain, params) = block_params(&near);
    let run = |tolerance: f64| {
        let params = GelParams {
            far_residual_tolerance: tolerance,
            ..params.clone()
        };
        let mut model = GelModel::try_new(mesh.clone(), &bottom, &params).unwrap();
        assert!(model.has_near_block());
        let mut by_hand = GelModel::try_new(mesh.clone(), &bottom, &plain).unwrap();
        let (mut dropped, mut whole) = (0, 0);
        for k in 0..24 {
            by_hand.positions_mut().copy_from_slice(model.positions());
            let f_int = by_hand.compute_internal_forces().to_vec();
            let mut rhs: Vec<f64> = (0..f_int.len())
                .map(|g| {
                    if model.is_fixed_dof(g) {
                        0.0
                    } else {
                        -f_int[g]
                    }
                })
                .collect();
            let (mut far2, mut all2) = (0.0, 0.0);
            for (g, v) in rhs.iter().enumerate() {
                all2 += v * v;
                if !near[g / 3] {
                    far2 += v * v;
                }
            }
            let drops = model.far_residual_drops();
            let mut dx = model.free_motion_unloaded().unwrap().to_vec();
            let expect_drop = far2 > 0.0 && far2.sqrt() <= tolerance * all2.sqrt();
            if expect_drop {
                for (g, v) in rhs.iter_mut().enumerate() {
                    if !near[g / 3] {
                        *v = 0.0;
                    }
                }
                dropped += 1;
            } else {
                whole += 1;
            }
            assert_eq!(
                model.far_residual_drops(),
                drops + u64::from(expect_drop),
                "step {k}: far share {:.3e}, tolerance {tolerance}",
                (far2 / all2).sqrt()
            );
            model.solve(&mut rhs).unwrap();
            // Exactly equal (a zero may keep another sign).
            let same = dx.iter().zip(&rhs).all(|(a, b)| a == b);
            assert!(same, "step {k}: the free motion is not the factor's solve");
            // The corrective motion of a force on the near top nodes (and a far one).
            let mut g = vec![0.0; dx.len()];
            for &i in top.iter().filter(|&&i| near[i]) {
                g[3 * i] = if k < 12 { 4e-3 } else { -4e-3 };
            }
            if k % 4 == 3 {
                g[3 * far_top + 1] = 2e-3;
            }
            model.solve(&mut g).unwrap();
            for (d, c) in dx.iter_mut().zip(&g) {
                *d += c;
            }
            model.apply_displacement(&dx).unwrap();
        }
        (dropped, whole)
    };
    let (dropped, whole) = run(5e-3);
    println!("tolerance 5e-3: {dropped} free motions with the far residual dropped, {whole} whole");
    assert!(dropped >= 2 && whole >= 2, "the test is void");
    assert_eq!(run(0.0), (0, 24), "τ = 0 solves every step whole");
}

/// `GelParams::defer_far`: the free motion solved on the near block's rows only
/// (`free_motion_deferring_far`) is, bit for bit, the whole free motion there and zero on the
/// far dofs; a corrective motion for a force on near nodes, solved on the near rows only
/// (`solve_columns_near`) and added, then finished by `complete_far`, is the whole step (free
/// plus corrective motion, each solved whole) to round-off. Every fourth step the force also
/// reaches a far node: the free motion is then finished first and the force solved whole, as
/// the step pipeline does when a gel point of its frame lies outside the near rows. Both
/// models take the deferred model's steps.
#[test]
fn deferred_far_rows_give_the_whole_step() {
    use needle_host::free_motion::{GelModel, GelParams};
    let (mesh, bottom, near) = box_with_near_column();
    let top = mesh.nodes_on_plane(2, 20.0, 1e-9);
    let far_top = *top.iter().find(|&&i| !near[i]).expect("a far top node");
    let (_, params) = block_params(&near);
    let whole_params = GelParams {
        defer_far: false,
        ..params.clone()
    };
    let deferring = GelParams {
        defer_far: true,
        ..params
    };
    let mut whole = GelModel::try_new(mesh.clone(), &bottom, &whole_params).unwrap();
    let mut model = GelModel::try_new(mesh.clone(), &bottom, &deferring).unwrap();
    assert!(model.defers_far() && !whole.defers_far());
    let n = model.dof_count();
    let near_top: Vec<usize> = top.iter().copied().filter(|&i| near[i]).collect();
    assert!(
        near_top
            .iter()
            .all(|&i| (3 * i..3 * i + 3).all(|d| model.is_deferral_exact(d))),
        "the near top nodes are solved exactly"
    );
    assert!(!model.is_deferral_exact(3 * far_top));
    let mut worst: f64 = 0.0;
    for k in 0..24 {
        let free_whole = whole.free_motion_unloaded().unwrap().to_vec();
        let mut dx = model.free_motion_deferring_far().unwrap().to_vec();
        for g in 0..n {
            let expect = if model.is_deferral_exact(g) || model.is_fixed_dof(g) {
                free_whole[g]
            } else {
                0.0
            };
            assert!(dx[g] == expect, "step {k} dof {g}: {} vs {expect}", dx[g]);
        }
        let mut g = vec![0.0; n];
        for &i in &near_top {
            g[3 * i] = if k < 12 { 4e-3 } else { -4e-3 };
        }
        let far_load = k % 4 == 3;
        if far_load {
            g[3 * far_top + 1] = 2e-3;
        }
        let mut expect = g.clone();
        whole.solve(&mut expect).unwrap();
        for (e, f) in expect.iter_mut().zip(&free_whole) {
            *e += f;
        }
        let mut c = g.clone();
        if far_load {
            model.complete_far(&mut dx).unwrap();
            model.solve_columns(&mut c, 1).unwrap();
            for (d, v) in dx.iter_mut().zip(&c) {
                *d += v;
            }
        } else {
            model.solve_columns_near(&mut c, 1).unwrap();
            for (d, v) in dx.iter_mut().zip(&c) {
                *d += v;
            }
            model.complete_far(&mut dx).unwrap();
        }
        let scale = expect.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
        let err = dx
            .iter()
            .zip(&expect)
            .fold(0.0_f64, |m, (a, b)| m.max((a - b).abs()));
        assert!(err <= 1e-10 * scale, "step {k}: {err:e} of {scale:e}");
        worst = worst.max(err / scale);
        // Both models take the same step, so that the next free motions compare bit for bit.
        whole.apply_displacement(&dx).unwrap();
        model.apply_displacement(&dx).unwrap();
    }
    println!("deferred against whole steps: worst relative difference {worst:.2e}");
    assert!(
        worst > 0.0,
        "the far rows were solved another way: not bit for bit"
    );
}

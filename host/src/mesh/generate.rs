//! Structured box mesher: `nx × ny × nz` hexahedral cells, each split into six tetrahedra
//! around its main diagonal (Kuhn/Freudenthal subdivision). Every cell uses the same split, so
//! the face diagonals of neighbouring cells coincide and the mesh is conforming.

use super::{TetMesh, signed_volume};
use nalgebra::Vector3;

/// Number of hexahedral cells along x, y and z.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BoxDivisions {
    /// Cells along x.
    pub nx: usize,
    /// Cells along y.
    pub ny: usize,
    /// Cells along z.
    pub nz: usize,
}

impl BoxDivisions {
    /// Number of nodes of the resulting mesh, `(nx + 1)(ny + 1)(nz + 1)`.
    pub fn node_count(&self) -> usize {
        (self.nx + 1) * (self.ny + 1) * (self.nz + 1)
    }

    /// Number of tetrahedra of the resulting mesh, `6 nx ny nz`.
    pub fn tet_count(&self) -> usize {
        6 * self.nx * self.ny * self.nz
    }
}

/// Chooses divisions of the box `[min, max]` so that the cells are as cubic as possible and the
/// node count is close to `target_nodes`.
///
/// The cell size `h` solving `Π(L_i / h + 1) = target` is found by bisection; the candidates
/// `round(L_i / h) ± 1` are then scored by relative node-count error plus cell anisotropy
/// (`max edge / min edge − 1`, weighted by 0.05) plus 0.03 for each odd x or y count, and the
/// best is returned.
pub fn box_divisions_for_target(
    min: Vector3<f64>,
    max: Vector3<f64>,
    target_nodes: usize,
) -> BoxDivisions {
    let len = (max - min).abs();
    let target = target_nodes.max(8) as f64;
    let count = |h: f64| (0..3).map(|i| len[i] / h + 1.0).product::<f64>();
    let (mut lo, mut hi) = (1e-9 * len.max(), len.max());
    for _ in 0..200 {
        let mid = (lo * hi).sqrt();
        if count(mid) > target {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let h = (lo * hi).sqrt();
    let base: [usize; 3] = std::array::from_fn(|i| ((len[i] / h).round() as usize).max(1));
    let mut best = (
        f64::INFINITY,
        BoxDivisions {
            nx: base[0],
            ny: base[1],
            nz: base[2],
        },
    );
    for dx in -1i64..=1 {
        for dy in -1i64..=1 {
            for dz in -1i64..=1 {
                let n = [
                    base[0] as i64 + dx,
                    base[1] as i64 + dy,
                    base[2] as i64 + dz,
                ];
                if n.iter().any(|&v| v < 1) {
                    continue;
                }
                let d = BoxDivisions {
                    nx: n[0] as usize,
                    ny: n[1] as usize,
                    nz: n[2] as usize,
                };
                let cell = [
                    len[0] / n[0] as f64,
                    len[1] / n[1] as f64,
                    len[2] / n[2] as f64,
                ];
                let cmax = cell.iter().cloned().fold(0.0, f64::max);
                let cmin = cell.iter().cloned().fold(f64::INFINITY, f64::min);
                // Even x and y counts make the mesh mirror-symmetric about the box's mid planes
                // (see `box_mesh_with_divisions`): preferred unless it costs > 3 % of nodes each.
                let odd = (d.nx % 2 + d.ny % 2) as f64;
                let score = (d.node_count() as f64 - target).abs() / target
                    + 0.05 * (cmax / cmin - 1.0)
                    + 0.03 * odd;
                if score < best.0 {
                    best = (score, d);
                }
            }
        }
    }
    best.1
}

/// Tetrahedral mesh of the box `[min, max]` with about `target_nodes` nodes
/// (see [`box_divisions_for_target`]).
pub fn box_mesh(min: Vector3<f64>, max: Vector3<f64>, target_nodes: usize) -> TetMesh {
    box_mesh_with_divisions(min, max, box_divisions_for_target(min, max, target_nodes))
}

/// Tetrahedral mesh of the box `[min, max]` [mm] with the given divisions; node
/// `(i, j, k)` has index `i + (nx + 1)(j + (ny + 1) k)`. All elements are positively oriented.
pub fn box_mesh_with_divisions(min: Vector3<f64>, max: Vector3<f64>, div: BoxDivisions) -> TetMesh {
    let BoxDivisions { nx, ny, nz } = BoxDivisions {
        nx: div.nx.max(1),
        ny: div.ny.max(1),
        nz: div.nz.max(1),
    };
    let lo = min.inf(&max);
    let hi = min.sup(&max);
    let step = Vector3::new(
        (hi.x - lo.x) / nx as f64,
        (hi.y - lo.y) / ny as f64,
        (hi.z - lo.z) / nz as f64,
    );
    let idx = |i: usize, j: usize, k: usize| i + (nx + 1) * (j + (ny + 1) * k);
    let mut nodes = Vec::with_capacity((nx + 1) * (ny + 1) * (nz + 1));
    for k in 0..=nz {
        for j in 0..=ny {
            for i in 0..=nx {
                // Exact end coordinates on the box faces (no accumulated rounding).
                let c = |n: usize, count: usize, a: f64, b: f64, s: f64| {
                    if n == count { b } else { a + n as f64 * s }
                };
                nodes.push(Vector3::new(
                    c(i, nx, lo.x, hi.x, step.x),
                    c(j, ny, lo.y, hi.y, step.y),
                    c(k, nz, lo.z, hi.z, step.z),
                ));
            }
        }
    }
    const PERMS: [[usize; 3]; 6] = [
        [0, 1, 2],
        [0, 2, 1],
        [1, 0, 2],
        [1, 2, 0],
        [2, 0, 1],
        [2, 1, 0],
    ];
    let mut tets = Vec::with_capacity(6 * nx * ny * nz);
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                // Kuhn split mirrored by cell parity: cell (i, j, k) starts its six paths at
                // the corner reflected along every odd index. Neighbours then share mirrored
                // (hence identical) face diagonals, so the mesh stays conforming, and it is
                // symmetric under the reflections of the box whenever the division counts are
                // even (a straight insertion through the middle stays symmetric).
                let start = [i + i % 2, j + j % 2, k + k % 2];
                for p in PERMS {
                    let mut c = start;
                    let mut t = [idx(c[0], c[1], c[2]); 4];
                    for (s, &axis) in p.iter().enumerate() {
                        let odd = [i, j, k][axis] % 2 == 1;
                        if odd {
                            c[axis] -= 1;
                        } else {
                            c[axis] += 1;
                        }
                        t[s + 1] = idx(c[0], c[1], c[2]);
                    }
                    if signed_volume(&nodes[t[0]], &nodes[t[1]], &nodes[t[2]], &nodes[t[3]]) < 0.0 {
                        t.swap(2, 3);
                    }
                    tets.push(t);
                }
            }
        }
    }
    let regions = vec![0; tets.len()];
    TetMesh {
        nodes,
        tets,
        regions,
    }
}

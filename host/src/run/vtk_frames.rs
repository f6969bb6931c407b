//! The VTK frames of a run, for ParaView: every `every` steps, and always the first and the
//! last state, five compressed `.vtu` grids per frame and one `.pvd` time collection per object
//! (plus `run.pvd` holding all five as parts of one data set).
//!
//! | file | cells | point data | cell data |
//! |---|---|---|---|
//! | `gel_K.vtu` | tetrahedra, points **at rest** | `displacement` [mm] (warp by it) | `strain` (corotational, tensor), `von_mises_kPa`, `region`, `inverted` |
//! | `needle_K.vtu` | segments between the nodes | `constraint_force_N` (nodal), `arc_length_mm` | – |
//! | `path_K.vtu` | segments: the planned path in the deformed gel | `arc_length_mm` | – |
//! | `obstacles_K.vtu` | triangles: each sphere's surface around its deformed centre | – | `obstacle`, `radius_mm`, `clearance_mm` (+∞ before the needle enters the gel) |
//! | `constraints_K.vtu` | one vertex per row group, at its needle point | `force_N` (on the needle), `lambda_N`, `kind` (0 base, 1 tip contact, 2 sliding), `id` | – |
//!
//! Times are `K · dt` [s]; every file also holds its time as the `TimeValue` field.

use super::Observer;
use super::summary::RunSummary;
use crate::constraints::GroupRole;
use crate::output::OutputError;
use crate::output::vtu::{Array, CellKind, Collection, Grid, Values, unit_sphere};
use crate::step::{ConstraintForce, StepReport};
use crate::world::{Obstacle, World};
use nalgebra::Vector3;
use std::path::{Path, PathBuf};

/// The objects of a frame, in part order.
pub const PARTS: [&str; 5] = ["gel", "needle", "path", "obstacles", "constraints"];

/// The frame writer (an [`Observer`] of the run).
pub struct VtkFrames {
    dir: PathBuf,
    every: usize,
    dt: f64,
    /// `(time, files)` of the frames written.
    written: Collection,
    last_frame: usize,
    /// The forces of the last step seen (the final frame's).
    forces: (Vec<ConstraintForce>, Vec<Vector3<f64>>),
}

impl VtkFrames {
    /// Writes frame 0 of `world` into `dir`; then every `every` steps and the last state.
    ///
    /// # Errors
    /// [`OutputError`] naming the file.
    pub fn start<const N: usize>(
        dir: &Path,
        every: usize,
        dt: f64,
        world: &World<N>,
    ) -> Result<Self, OutputError> {
        let mut me = Self {
            dir: dir.to_owned(),
            every: every.max(1),
            dt,
            written: Collection::default(),
            last_frame: 0,
            forces: (Vec::new(), Vec::new()),
        };
        me.write(world, 0)?;
        Ok(me)
    }

    /// Writes frame `k` of `world` and rewrites the collections.
    fn write<const N: usize>(&mut self, world: &World<N>, k: usize) -> Result<(), OutputError> {
        let t = k as f64 * self.dt;
        let grids = [
            gel(world),
            needle(world, &self.forces.1),
            path(world),
            obstacles(world),
            constraints(&self.forces.0),
        ];
        let mut files = Vec::with_capacity(PARTS.len());
        for (name, mut grid) in PARTS.iter().zip(grids) {
            grid.time = Some(t);
            let file = format!("{name}_{k:05}.vtu");
            grid.write(&self.dir.join(&file))?;
            files.push(file);
        }
        self.written.frames.push((t, files));
        self.last_frame = k;
        // Rewritten at every frame: an interrupted run still leaves valid collections.
        for (part, name) in PARTS.iter().enumerate() {
            let one = Collection {
                frames: (self.written.frames.iter())
                    .map(|(t, f)| (*t, vec![f[part].clone()]))
                    .collect(),
            };
            one.write(&self.dir.join(format!("{name}.pvd")))?;
        }
        self.written.write(&self.dir.join("run.pvd"))
    }
}

impl<const N: usize> Observer<N> for VtkFrames {
    fn step(&mut self, world: &World<N>, r: &StepReport) -> Result<(), OutputError> {
        self.forces = (r.forces.clone(), r.needle_node_forces.clone());
        if (r.step + 1).is_multiple_of(self.every) {
            self.write(world, r.step + 1)?;
        }
        Ok(())
    }

    fn finish(&mut self, world: &World<N>, _: &RunSummary) -> Result<(), OutputError> {
        if world.steps != self.last_frame {
            self.write(world, world.steps)?;
        }
        Ok(())
    }
}

/// The gel at rest with its displacement, and the state of each element.
fn gel<const N: usize>(world: &World<N>) -> Grid {
    let gel = &world.gel;
    let rest = &gel.mesh().nodes;
    let x = gel.positions();
    let tetra = gel.tetra();
    let states: Vec<_> = (0..tetra.len())
        .map(|e| tetra.element_state(e, x))
        .collect();
    let displacement: Vec<Vector3<f64>> = x.iter().zip(rest).map(|(x, x0)| x - x0).collect();
    Grid {
        points: rest.clone(),
        cells: (gel.mesh().tets.iter())
            .map(|t| (CellKind::Tetra, t.to_vec()))
            .collect(),
        point_data: vec![Array::new("displacement", Values::vectors(&displacement))],
        cell_data: vec![
            Array::new(
                "strain",
                Values::F64 {
                    components: 9,
                    data: states
                        .iter()
                        .flat_map(|s| s.strain.as_slice().to_vec())
                        .collect(),
                },
            ),
            // [MPa] → [kPa].
            Array::new(
                "von_mises_kPa",
                Values::scalars(states.iter().map(|s| 1e3 * s.von_mises)),
            ),
            Array::new("region", Values::I32(gel.mesh().regions.clone())),
            Array::new(
                "inverted",
                Values::I32(states.iter().map(|s| i32::from(s.inverted)).collect()),
            ),
        ],
        time: None,
    }
}

/// Arc length along a polyline from its first point [mm].
fn arc_length(points: &[Vector3<f64>]) -> Vec<f64> {
    let mut s = 0.0;
    let mut out = Vec::with_capacity(points.len());
    for (k, p) in points.iter().enumerate() {
        if k > 0 {
            s += (p - points[k - 1]).norm();
        }
        out.push(s);
    }
    out
}

fn polyline(points: Vec<Vector3<f64>>) -> Grid {
    let n = points.len();
    Grid {
        point_data: vec![Array::new(
            "arc_length_mm",
            Values::scalars(arc_length(&points)),
        )],
        points,
        // Segments rather than one VTK polyline: meshio reads lines, not polylines.
        cells: (1..n).map(|k| (CellKind::Line, vec![k - 1, k])).collect(),
        ..Grid::default()
    }
}

/// The needle with the constraints' nodal forces (zero before the first step).
fn needle<const N: usize>(world: &World<N>, nodal: &[Vector3<f64>]) -> Grid {
    let x = world.needle.positions();
    let mut grid = polyline(x.to_vec());
    let forces: Vec<Vector3<f64>> = (0..x.len())
        .map(|k| nodal.get(k).copied().unwrap_or_else(Vector3::zeros))
        .collect();
    grid.point_data.insert(
        0,
        Array::new("constraint_force_N", Values::vectors(&forces)),
    );
    grid
}

/// The planned path in the deformed gel, 201 points from the entry approach to the end.
fn path<const N: usize>(world: &World<N>) -> Grid {
    polyline(
        (0..=200)
            .map(|i| world.target(world.path.approach + world.path.length() * i as f64 / 200.0))
            .collect(),
    )
}

/// Each obstacle as a triangle surface: a sphere around its deformed centre, a mesh at its
/// deformed vertices.
fn obstacles<const N: usize>(world: &World<N>) -> Grid {
    let (unit, tris) = unit_sphere(2);
    let clearance = world.clearances();
    let mut grid = Grid::default();
    let (mut id, mut radius, mut clear) = (Vec::new(), Vec::new(), Vec::new());
    for (k, o) in world.obstacles.iter().enumerate() {
        let base = grid.points.len();
        let (count, r) = match o {
            Obstacle::Sphere { centre, radius: r } => {
                let c = world.gel_point(centre);
                grid.points.extend(unit.iter().map(|u| c + u * *r));
                grid.cells.extend(
                    tris.iter()
                        .map(|t| (CellKind::Triangle, t.iter().map(|i| base + i).collect())),
                );
                (tris.len(), *r)
            }
            Obstacle::Mesh {
                vertices,
                triangles,
                ..
            } => {
                grid.points.extend(world.obstacle_vertices(vertices));
                grid.cells.extend(
                    triangles
                        .iter()
                        .map(|t| (CellKind::Triangle, t.iter().map(|i| base + i).collect())),
                );
                // A mesh has no radius.
                (triangles.len(), f64::NAN)
            }
        };
        id.extend(std::iter::repeat_n(k as i32, count));
        radius.extend(std::iter::repeat_n(r, count));
        clear.extend(std::iter::repeat_n(clearance[k], count));
    }
    grid.cell_data = vec![
        Array::new("obstacle", Values::I32(id)),
        Array::new("radius_mm", Values::scalars(radius)),
        Array::new("clearance_mm", Values::scalars(clear)),
    ];
    grid
}

/// One vertex per row group at its needle point, with its force on the needle.
fn constraints(forces: &[ConstraintForce]) -> Grid {
    let (kind, id): (Vec<i32>, Vec<i32>) = forces
        .iter()
        .map(|f| match f.role {
            GroupRole::Base => (0, -1),
            GroupRole::Contact => (1, -1),
            GroupRole::Sliding(id) => (2, id as i32),
        })
        .unzip();
    let force: Vec<Vector3<f64>> = forces.iter().map(|f| f.force).collect();
    Grid {
        points: forces.iter().map(|f| f.at).collect(),
        cells: (0..forces.len())
            .map(|k| (CellKind::Vertex, vec![k]))
            .collect(),
        point_data: vec![
            Array::new("force_N", Values::vectors(&force)),
            Array::new("lambda_N", Values::scalars(force.iter().map(|f| f.norm()))),
            Array::new("kind", Values::I32(kind)),
            Array::new("id", Values::I32(id)),
        ],
        ..Grid::default()
    }
}

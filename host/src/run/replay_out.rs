//! `replay.html` of a run (see [`crate::replay`]): about [`REPLAY_FRAMES`] frames spread over the
//! planned steps, the first (the start) and the last always among them, and the tracking error of
//! every step. Written at the end of every run with an output folder.

// Units are written in brackets ([mm], [s]) as in the workspace style: not intra-doc links.
#![allow(rustdoc::broken_intra_doc_links)]

use super::{Observer, RunSummary};
use crate::output::{OutputError, OutputFailure};
use crate::replay::{
    MeshObstacle, ReplayData, ReplayFrame, SphereObstacle, SurfaceMap, frame_stride, write_replay,
};
use crate::setup::Plan;
use crate::step::StepReport;
use crate::world::{Obstacle, World};
use std::path::{Path, PathBuf};

/// About how many frames a replay holds besides the last (its size grows with them: 1.9 MB for
/// the simple scene at 1485 nodes).
pub const REPLAY_FRAMES: usize = 120;

/// Records a run for its replay page.
pub struct ReplayRecorder {
    file: PathBuf,
    every: usize,
    dt: f64,
    surface: SurfaceMap,
    data: ReplayData,
    /// The latest step's frame when it was not recorded: the last frame of the run.
    pending: Option<ReplayFrame>,
}

fn invalid(file: &Path, e: impl std::fmt::Display) -> OutputError {
    OutputError::new(file, OutputFailure::Replay(e.to_string()))
}

impl ReplayRecorder {
    /// Starts the replay of `world` (its first frame, at rest) into `dir/replay.html`.
    ///
    /// # Errors
    /// [`OutputError`] when the gel's surface cannot be mapped.
    pub fn start<const N: usize>(
        dir: &Path,
        plan: &Plan,
        dt: f64,
        world: &World<N>,
    ) -> Result<Self, OutputError> {
        let file = dir.join("replay.html");
        let surface = SurfaceMap::from_triangles(&world.gel.mesh().surface_triangles())
            .map_err(|e| invalid(&file, e))?;
        let name = |k: usize| {
            plan.obstacle_names
                .get(k)
                .cloned()
                .unwrap_or_else(|| format!("obstacle {k}"))
        };
        let mut spheres = Vec::new();
        let mut meshes = Vec::new();
        for (k, o) in world.obstacles.iter().enumerate() {
            match o {
                Obstacle::Sphere { radius, .. } => spheres.push(SphereObstacle {
                    name: name(k),
                    radius: *radius,
                }),
                Obstacle::Mesh { triangles, .. } => meshes.push(MeshObstacle {
                    name: name(k),
                    triangles: triangles
                        .iter()
                        .map(|t| t.map(|i| u32::try_from(i).unwrap_or(u32::MAX)))
                        .collect(),
                }),
            }
        }
        let mut rec = Self {
            every: frame_stride(plan.steps, REPLAY_FRAMES),
            dt,
            data: ReplayData {
                title: format!("{} · {} gel nodes", plan.name, world.gel.node_count()),
                surface_triangles: surface.triangles.clone(),
                spheres,
                meshes,
                ..ReplayData::default()
            },
            surface,
            pending: None,
            file,
        };
        let first = rec.frame(world, 0, world.target(world.c))?;
        rec.data.frames.push(first);
        Ok(rec)
    }

    /// The frame of `world` after `steps` steps.
    fn frame<const N: usize>(
        &self,
        world: &World<N>,
        steps: usize,
        target: nalgebra::Vector3<f64>,
    ) -> Result<ReplayFrame, OutputError> {
        let path = (0..=200)
            .map(|i| world.target(world.path.approach + world.path.length() * i as f64 / 200.0))
            .collect();
        Ok(ReplayFrame {
            time: steps as f64 * self.dt,
            step: u32::try_from(steps).unwrap_or(u32::MAX),
            surface: self
                .surface
                .gather(world.gel.positions())
                .map_err(|e| invalid(&self.file, e))?,
            needle: world.needle.positions().to_vec(),
            path,
            target,
            sphere_centres: world
                .obstacles
                .iter()
                .filter_map(|o| match o {
                    Obstacle::Sphere { centre, .. } => Some(world.gel_point(centre)),
                    Obstacle::Mesh { .. } => None,
                })
                .collect(),
            mesh_nodes: world
                .obstacles
                .iter()
                .filter_map(|o| match o {
                    Obstacle::Mesh { vertices, .. } => Some(world.obstacle_vertices(vertices)),
                    Obstacle::Sphere { .. } => None,
                })
                .collect(),
        })
    }
}

impl<const N: usize> Observer<N> for ReplayRecorder {
    fn step(&mut self, world: &World<N>, r: &StepReport) -> Result<(), OutputError> {
        let e = &mut self.data.error;
        e.steps.push(u32::try_from(r.step).unwrap_or(u32::MAX));
        e.depth.push(r.depth);
        e.error
            .push(if r.tip_inside() { r.error } else { f64::NAN });
        let frame = self.frame(world, r.step + 1, r.target)?;
        if (r.step + 1).is_multiple_of(self.every) {
            self.data.frames.push(frame);
            self.pending = None;
        } else {
            self.pending = Some(frame);
        }
        Ok(())
    }

    fn finish(&mut self, _: &World<N>, s: &RunSummary) -> Result<(), OutputError> {
        if let Some(last) = self.pending.take() {
            self.data.frames.push(last);
        }
        let controller = format!("{:?}", s.controller).to_lowercase();
        self.data.title = format!("{} · {controller}", self.data.title);
        self.data.summary = summary_rows(s);
        write_replay(&self.file, &self.data).map_err(|e| invalid(&self.file, e))
    }
}

/// The summary shown beside the replay.
fn summary_rows(s: &RunSummary) -> Vec<(String, String)> {
    let mm = |v: f64| {
        if v.is_finite() {
            format!("{v:.3} mm")
        } else {
            "—".to_owned()
        }
    };
    let clearance = s
        .clearances
        .iter()
        .map(|c| c.min_mm)
        .fold(f64::INFINITY, f64::min);
    let mut rows = vec![
        ("outcome", s.outcome.name().to_owned()),
        ("steps", format!("{} / {}", s.steps, s.steps_planned)),
        ("e_mean", mm(s.e_mean_mm)),
        ("e_max", mm(s.e_max_mm)),
        ("e_final", mm(s.e_final_mm)),
        ("min clearance", mm(clearance)),
        (
            "puncture at step",
            s.puncture_step.map_or("—".to_owned(), |k| k.to_string()),
        ),
        ("e at puncture", s.e_puncture_mm.map_or("—".to_owned(), mm)),
        (
            "time per step",
            format!(
                "{:.2} ms wall, {:.2} ms CPU",
                s.timing.total.mean_ms, s.cpu_ms_per_step
            ),
        ),
    ];
    if let Some(why) = &s.stopped {
        rows.push(("stopped", why.clone()));
    }
    rows.into_iter().map(|(k, v)| (k.to_owned(), v)).collect()
}

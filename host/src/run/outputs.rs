//! The files of a run, each an [`Observer`] of its steps: the per-step metrics CSV
//! (`steps.csv`), the VTK frames, and `summary.json`.

use super::Observer;
use super::summary::RunSummary;
use crate::output::{
    MetricsWriter, OutputError, StepMetrics, write_points, write_polyline, write_tet_mesh,
};
use crate::step::StepReport;
use crate::world::World;
use std::path::{Path, PathBuf};

/// `steps.csv`: one row per step ([`StepMetrics`]).
pub struct MetricsCsv(MetricsWriter);

impl MetricsCsv {
    /// Creates `dir/steps.csv` with one clearance column per obstacle of `world`.
    ///
    /// # Errors
    /// [`OutputError`] naming the file.
    pub fn create(dir: &Path, world: &World) -> Result<Self, OutputError> {
        MetricsWriter::create(&dir.join("steps.csv"), world.obstacles.len()).map(Self)
    }
}

impl Observer for MetricsCsv {
    fn step(&mut self, world: &World, r: &StepReport) -> Result<(), OutputError> {
        self.0.write(&StepMetrics {
            step: r.step,
            c: r.c,
            tip: r.tip,
            target: r.target,
            error: r.error,
            depth: r.depth,
            clearance: world.clearances(),
            lambda_base: r.lambda_norms[0],
            lambda_contact: r.lambda_norms[1],
            lambda_sliding: r.lambda_norms[2],
            gs_iterations: r.solver.iterations,
            gs_residual: r.solver.final_residual,
            rows: r.rows,
            time_ms: [
                r.times.fm,
                r.times.cd,
                r.times.cc,
                r.times.sc,
                r.times.after_solve(),
            ],
            q: r.q,
        })
    }

    fn finish(&mut self, _: &RunSummary) -> Result<(), OutputError> {
        self.0.flush()
    }
}

/// VTK frames every `every` steps (and the start): the gel, the needle, the deformed path, the
/// obstacles and the sliding points (see [`crate::output`]).
pub struct VtkFrames {
    dir: PathBuf,
    every: usize,
}

impl VtkFrames {
    /// Writes frame 0 of `world` into `dir`; then every `every` steps.
    ///
    /// # Errors
    /// [`OutputError`] naming the file.
    pub fn start(dir: &Path, every: usize, world: &World) -> Result<Self, OutputError> {
        write_frame(world, dir, 0)?;
        Ok(Self {
            dir: dir.to_owned(),
            every,
        })
    }
}

impl Observer for VtkFrames {
    fn step(&mut self, world: &World, r: &StepReport) -> Result<(), OutputError> {
        if (r.step + 1).is_multiple_of(self.every) {
            write_frame(world, &self.dir, r.step + 1)?;
        }
        Ok(())
    }
}

/// Frame `k` of `world`: `gel_k`, `needle_k`, `path_k`, `obstacles_k`, `constraints_k`.
fn write_frame(world: &World, dir: &Path, k: usize) -> Result<(), OutputError> {
    let gel = &world.gel;
    write_tet_mesh(
        &dir.join(format!("gel_{k:05}.vtk")),
        gel.positions(),
        &gel.mesh().nodes,
        &gel.mesh().tets,
    )?;
    write_polyline(
        &dir.join(format!("needle_{k:05}.vtk")),
        "needle",
        world.needle.positions(),
    )?;
    let path: Vec<_> = (0..=200)
        .map(|i| world.target(world.path.approach + world.path.length() * i as f64 / 200.0))
        .collect();
    write_polyline(&dir.join(format!("path_{k:05}.vtk")), "path", &path)?;
    let (centres, radii): (Vec<_>, Vec<_>) = world
        .obstacles
        .iter()
        .map(|(e, r)| (world.gel_point(e), *r))
        .unzip();
    write_points(
        &dir.join(format!("obstacles_{k:05}.vtk")),
        "obstacles",
        &centres,
        "radius",
        &radii,
    )?;
    let pts: Vec<_> = world
        .sliding
        .iter()
        .map(|s| world.gel_point(&s.at))
        .collect();
    let ids: Vec<f64> = world.sliding.iter().map(|s| s.id as f64).collect();
    write_points(
        &dir.join(format!("constraints_{k:05}.vtk")),
        "sliding points",
        &pts,
        "id",
        &ids,
    )
}

/// `summary.json`: the run's summary, written at the end.
pub struct SummaryJson(pub PathBuf);

impl Observer for SummaryJson {
    fn step(&mut self, _: &World, _: &StepReport) -> Result<(), OutputError> {
        Ok(())
    }

    fn finish(&mut self, summary: &RunSummary) -> Result<(), OutputError> {
        let file = self.0.join("summary.json");
        let text = serde_json::to_string_pretty(summary).map_err(|e| OutputError::new(&file, e))?;
        std::fs::write(&file, text).map_err(|e| OutputError::new(&file, e))
    }
}

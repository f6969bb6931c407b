//! The files of a run, each an [`Observer`] of its steps: the per-step metrics CSV
//! (`steps.csv`) and `summary.json` (the VTK frames: [`super::vtk_frames`]).

use super::Observer;
use super::summary::RunSummary;
use crate::constraints::ClearanceKind;
use crate::output::{MetricsWriter, OutputError, StepMetrics};
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
    pub fn create<const N: usize>(dir: &Path, world: &World<N>) -> Result<Self, OutputError> {
        MetricsWriter::create(&dir.join("steps.csv"), world.obstacles.len(), N).map(Self)
    }
}

impl<const N: usize> Observer<N> for MetricsCsv {
    fn step(&mut self, world: &World<N>, r: &StepReport) -> Result<(), OutputError> {
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
            flags: r.solver.flags,
            rows: r.rows,
            time_ms: [
                r.times.fm,
                r.times.cd,
                r.times.cc,
                r.times.sc,
                r.times.after_solve(),
            ],
            q: r.q,
            limit_margin: r.limit_margin,
            needle_strain: r.needle_bend.0,
            held_by: r.holding.map(held_by).unwrap_or_default(),
        })
    }

    fn finish(&mut self, _: &World<N>, _: &RunSummary) -> Result<(), OutputError> {
        self.0.flush()
    }
}

/// The `held_by` entry of `steps.csv` for a row of `kind`.
fn held_by(kind: ClearanceKind) -> String {
    match kind {
        ClearanceKind::Obstacle(k) => format!("obstacle:{k}"),
        ClearanceKind::EntryShift => "entry_shift".to_owned(),
        ClearanceKind::Bending(node) => format!("bend:{node}"),
    }
}

/// `summary.json`: the run's summary, written at the end.
pub struct SummaryJson(pub PathBuf);

impl<const N: usize> Observer<N> for SummaryJson {
    fn step(&mut self, _: &World<N>, _: &StepReport) -> Result<(), OutputError> {
        Ok(())
    }

    fn finish(&mut self, _: &World<N>, summary: &RunSummary) -> Result<(), OutputError> {
        let file = self.0.join("summary.json");
        let text = serde_json::to_string_pretty(summary).map_err(|e| OutputError::new(&file, e))?;
        std::fs::write(&file, text).map_err(|e| OutputError::new(&file, e))
    }
}

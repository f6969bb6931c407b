//! Outputs of a run: VTK XML files that ParaView opens ([`vtu`]: compressed `.vtu` grids and
//! `.pvd` time collections; what each frame holds is written by `run::outputs`), and the
//! per-step metrics CSV (one row per step, see [`StepMetrics`]).

// Units are written in brackets ([mm], [N]) as in the workspace style: not intra-doc links.
#![allow(rustdoc::broken_intra_doc_links)]

use crate::joints::Joints;
use nalgebra::Vector3;
use std::fs::File;
use std::path::{Path, PathBuf};

pub mod vtu;

/// An output error: which file, and why (its source).
#[derive(Debug, thiserror::Error)]
#[error("{}", file.display())]
pub struct OutputError {
    /// The file (or folder) being written.
    pub file: PathBuf,
    /// Why it failed.
    #[source]
    pub source: OutputFailure,
}

/// Why an output could not be written.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum OutputFailure {
    /// The file or folder could not be created or written.
    #[error(transparent)]
    Io(#[from] std::io::Error),
    /// The CSV writer failed.
    #[error(transparent)]
    Csv(#[from] csv::Error),
    /// A VTK grid could not be built (says why).
    #[error("vtk: {0}")]
    Vtk(String),
    /// The summary could not be serialised.
    #[error(transparent)]
    Json(#[from] serde_json::Error),
    /// The replay page could not be built or written (says why).
    #[error("replay: {0}")]
    Replay(String),
    /// A chart could not be drawn (says why).
    #[error("chart: {0}")]
    Chart(String),
}

impl OutputError {
    /// A failure writing `file`.
    pub fn new(file: &Path, source: impl Into<OutputFailure>) -> Self {
        Self {
            file: file.to_owned(),
            source: source.into(),
        }
    }
}

/// One row of the per-step metrics CSV.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StepMetrics {
    /// Step index.
    pub step: usize,
    /// Target's arc length along the path from the start tip [mm].
    pub c: f64,
    /// Needle tip, world frame [mm].
    pub tip: Vector3<f64>,
    /// Target point on the deformed path [mm].
    pub target: Vector3<f64>,
    /// Tracking error |tip − target| [mm].
    pub error: f64,
    /// Insertion depth: tip distance past the entry point, 0 before puncture [mm].
    pub depth: f64,
    /// Smallest distance from the inserted needle to each deformed obstacle surface [mm].
    pub clearance: Vec<f64>,
    /// Norm of the base constraint forces [N].
    pub lambda_base: f64,
    /// Norm of the tip contact forces [N].
    pub lambda_contact: f64,
    /// Norm of the sliding constraint forces [N].
    pub lambda_sliding: f64,
    /// Gauss-Seidel iterations of the final solve.
    pub gs_iterations: u32,
    /// The core's status flags (`needle_core::payload::StatusFlags`, bits OR-ed).
    pub flags: u32,
    /// Gauss-Seidel residual of the final solve.
    pub gs_residual: f64,
    /// Constraint rows this step.
    pub rows: usize,
    /// Stage times: free motion, proximity, compliance, constraint solves (all), correction [ms].
    pub time_ms: [f64; 5],
    /// Joint vector after the step [rad], one per joint of the robot.
    pub q: Joints,
    /// The smallest distance of any joint to a position limit, as a fraction of its half range
    /// (1: mid-range, 0: at a limit; see [`crate::step::StepReport::limit_margin`]).
    pub limit_margin: f64,
    /// The needle's largest bending strain at its surface after the step [-]
    /// (`crate::free_motion::NeedleModel::max_bending_strain`).
    pub needle_strain: f64,
    /// What held the step, when a clearance row did ([`crate::step::StepReport::holding`]):
    /// `obstacle:K` (the obstacle of the `clearance_K_mm` column), `entry_shift`, `bend:N`
    /// (the needle's yield strain at node N from the clamp); empty otherwise.
    pub held_by: String,
}

/// Writes [`StepMetrics`] rows to a CSV file.
pub struct MetricsWriter {
    out: csv::Writer<File>,
    file: PathBuf,
    obstacles: usize,
    joints: usize,
}

impl MetricsWriter {
    /// Creates the file and writes the header; `obstacles` fixes the number of clearance columns,
    /// `joints` the number of joint columns.
    ///
    /// # Errors
    /// [`OutputError`] naming the file.
    pub fn create(path: &Path, obstacles: usize, joints: usize) -> Result<Self, OutputError> {
        let err = |e: csv::Error| OutputError::new(path, e);
        let mut out = csv::Writer::from_path(path).map_err(err)?;
        let mut header = vec![
            "step", "c_mm", "tip_x", "tip_y", "tip_z", "target_x", "target_y", "target_z",
            "error_mm", "depth_mm",
        ]
        .into_iter()
        .map(String::from)
        .collect::<Vec<_>>();
        header.extend((0..obstacles).map(|k| format!("clearance_{k}_mm")));
        header.extend(
            [
                "lambda_base_N",
                "lambda_contact_N",
                "lambda_sliding_N",
                "gs_iterations",
                "gs_residual",
                "flags",
                "rows",
                "fm_ms",
                "cd_ms",
                "cc_ms",
                "sc_ms",
                "corr_ms",
            ]
            .map(String::from),
        );
        header.extend((1..=joints).map(|j| format!("q{j}_rad")));
        header.push("limit_margin".into());
        header.push("needle_strain".into());
        header.push("held_by".into());
        out.write_record(&header).map_err(err)?;
        Ok(Self {
            out,
            file: path.to_owned(),
            obstacles,
            joints,
        })
    }

    /// Appends one row.
    ///
    /// # Errors
    /// [`OutputError`] naming the file.
    pub fn write(&mut self, m: &StepMetrics) -> Result<(), OutputError> {
        let mut row: Vec<String> = vec![m.step.to_string(), m.c.to_string()];
        row.extend(m.tip.iter().chain(m.target.iter()).map(|v| v.to_string()));
        row.push(m.error.to_string());
        row.push(m.depth.to_string());
        row.extend(
            (0..self.obstacles)
                .map(|k| m.clearance.get(k).copied().unwrap_or(f64::NAN).to_string()),
        );
        row.extend([m.lambda_base, m.lambda_contact, m.lambda_sliding].map(|v| v.to_string()));
        row.push(m.gs_iterations.to_string());
        row.push(m.gs_residual.to_string());
        row.push(m.flags.to_string());
        row.push(m.rows.to_string());
        row.extend(m.time_ms.iter().map(|v| v.to_string()));
        row.extend((0..self.joints).map(|j| m.q.get(j).copied().unwrap_or(f64::NAN).to_string()));
        row.push(m.limit_margin.to_string());
        row.push(m.needle_strain.to_string());
        row.push(m.held_by.clone());
        self.out
            .write_record(&row)
            .map_err(|e| OutputError::new(&self.file, e))
    }

    /// Flushes the file.
    ///
    /// # Errors
    /// [`OutputError`] naming the file.
    pub fn flush(&mut self) -> Result<(), OutputError> {
        self.out
            .flush()
            .map_err(|e| OutputError::new(&self.file, e))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A fresh folder of this test, removed when dropped, and `name` in it.
    fn tmp(name: &str) -> (tempfile::TempDir, PathBuf) {
        let dir = (tempfile::Builder::new()
            .prefix("needle-output-test-")
            .tempdir())
        .unwrap();
        let path = dir.path().join(name);
        (dir, path)
    }

    #[test]
    fn csv_has_one_column_per_header_field() {
        let (_dir, path) = tmp("metrics.csv");
        let mut w = MetricsWriter::create(&path, 3, 6).unwrap();
        w.write(&StepMetrics {
            step: 1,
            clearance: vec![1.0, 2.0, 3.0],
            ..Default::default()
        })
        .unwrap();
        w.write(&StepMetrics {
            step: 2,
            needle_strain: 0.0125,
            held_by: "obstacle:2".into(),
            ..Default::default()
        })
        .unwrap();
        w.flush().unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        let lines: Vec<_> = text.lines().collect();
        assert_eq!(lines.len(), 3);
        assert_eq!(lines[0].split(',').count(), lines[1].split(',').count());
        assert_eq!(lines[0].split(',').count(), lines[2].split(',').count());
        assert!(lines[0].contains("clearance_2_mm"));
        assert!(lines[0].ends_with(",needle_strain,held_by"), "{}", lines[0]);
        assert!(
            lines[1].ends_with(",0,"),
            "nothing held step 1: {}",
            lines[1]
        );
        assert!(lines[2].ends_with(",0.0125,obstacle:2"), "{}", lines[2]);
    }

    #[test]
    fn unwritable_file_names_the_path() {
        let grid = vtu::Grid {
            points: vec![Vector3::zeros()],
            cells: vec![(vtu::CellKind::Vertex, vec![0])],
            ..vtu::Grid::default()
        };
        let e = grid.write(Path::new("/nonexistent-dir/x.vtu")).unwrap_err();
        assert!(e.to_string().contains("/nonexistent-dir/x.vtu"), "{e}");
        assert!(matches!(e.source, OutputFailure::Io(_)), "{e:?}");
    }
}

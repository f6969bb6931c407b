//! Outputs of a run: VTK files that ParaView opens, and the per-step metrics CSV.
//!
//! VTK (legacy, ASCII, through `vtkio`): one file per object and frame —
//! `gel_NNNNN.vtk` (tetrahedra with the displacement field), `needle_NNNNN.vtk` (polyline),
//! `path_NNNNN.vtk` (the embedded path, deformed), `obstacles_NNNNN.vtk` (centres with a `radius`
//! scalar: glyph them with spheres), `constraints_NNNNN.vtk` (sliding/contact points with a
//! `kind` scalar). The CSV holds one row per step (see [`StepMetrics`]).

// Units are written in brackets ([mm], [N]) as in the workspace style: not intra-doc links.
#![allow(rustdoc::broken_intra_doc_links)]

use nalgebra::Vector3;
use std::fs::File;
use std::path::{Path, PathBuf};
use vtkio::model::{
    Attribute, Attributes, ByteOrder, CellType, Cells, DataSet, UnstructuredGridPiece, Version,
    VertexNumbers, Vtk,
};

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
    /// The VTK writer failed.
    #[error(transparent)]
    Vtk(#[from] vtkio::Error),
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

fn flat(points: &[Vector3<f64>]) -> Vec<f64> {
    points.iter().flat_map(|p| [p.x, p.y, p.z]).collect()
}

/// A point-data array written with a VTK file.
pub enum PointData<'a> {
    /// One scalar per point.
    Scalars(&'a str, &'a [f64]),
    /// One 3-vector per point.
    Vectors(&'a str, &'a [Vector3<f64>]),
}

/// Writes an unstructured grid: `points`, cells of one `kind` (each a list of point indices), point data.
///
/// # Errors
/// [`OutputError`] naming the file when it cannot be written.
pub fn write_vtk(
    path: &Path,
    title: &str,
    points: &[Vector3<f64>],
    kind: CellType,
    cells: &[&[usize]],
    data: &[PointData<'_>],
) -> Result<(), OutputError> {
    let mut vertices = Vec::with_capacity(cells.iter().map(|c| c.len() + 1).sum());
    for c in cells {
        vertices.push(c.len() as u32);
        vertices.extend(c.iter().map(|&i| i as u32));
    }
    let point = data
        .iter()
        .map(|d| match d {
            PointData::Scalars(name, v) => Attribute::scalars(*name, 1).with_data(v.to_vec()),
            PointData::Vectors(name, v) => Attribute::vectors(*name).with_data(flat(v)),
        })
        .collect();
    let vtk = Vtk {
        version: Version::new((4, 2)),
        title: title.to_owned(),
        byte_order: ByteOrder::BigEndian,
        file_path: None,
        data: DataSet::inline(UnstructuredGridPiece {
            points: flat(points).into(),
            cells: Cells {
                cell_verts: VertexNumbers::Legacy {
                    num_cells: cells.len() as u32,
                    vertices,
                },
                types: vec![kind; cells.len()],
            },
            data: Attributes {
                point,
                cell: Vec::new(),
            },
        }),
    };
    vtk.export_ascii(path)
        .map_err(|e| OutputError::new(path, e))
}

/// Writes a tetrahedral mesh with its displacement from `rest`.
///
/// # Errors
/// [`OutputError`] naming the file.
pub fn write_tet_mesh(
    path: &Path,
    nodes: &[Vector3<f64>],
    rest: &[Vector3<f64>],
    tets: &[[usize; 4]],
) -> Result<(), OutputError> {
    let cells: Vec<&[usize]> = tets.iter().map(|t| &t[..]).collect();
    let disp: Vec<Vector3<f64>> = nodes.iter().zip(rest).map(|(x, x0)| x - x0).collect();
    write_vtk(
        path,
        "gel",
        nodes,
        CellType::Tetra,
        &cells,
        &[PointData::Vectors("displacement", &disp)],
    )
}

/// Writes a polyline through `points` (the needle, the path).
///
/// # Errors
/// [`OutputError`] naming the file.
pub fn write_polyline(
    path: &Path,
    title: &str,
    points: &[Vector3<f64>],
) -> Result<(), OutputError> {
    let idx: Vec<usize> = (0..points.len()).collect();
    write_vtk(path, title, points, CellType::PolyLine, &[&idx], &[])
}

/// Writes isolated points with one scalar each (obstacle centres with their radius, constraint
/// points with their kind).
///
/// # Errors
/// [`OutputError`] naming the file.
pub fn write_points(
    path: &Path,
    title: &str,
    points: &[Vector3<f64>],
    name: &str,
    values: &[f64],
) -> Result<(), OutputError> {
    let idx: Vec<[usize; 1]> = (0..points.len()).map(|i| [i]).collect();
    let cells: Vec<&[usize]> = idx.iter().map(|c| &c[..]).collect();
    write_vtk(
        path,
        title,
        points,
        CellType::Vertex,
        &cells,
        &[PointData::Scalars(name, values)],
    )
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
    /// Gauss-Seidel residual of the final solve.
    pub gs_residual: f64,
    /// Constraint rows this step.
    pub rows: usize,
    /// Stage times: free motion, proximity, compliance, constraint solves (all), correction [ms].
    pub time_ms: [f64; 5],
    /// Joint vector after the step [rad].
    pub q: [f64; 6],
}

/// Writes [`StepMetrics`] rows to a CSV file.
pub struct MetricsWriter {
    out: csv::Writer<File>,
    file: PathBuf,
    obstacles: usize,
}

impl MetricsWriter {
    /// Creates the file and writes the header; `obstacles` fixes the number of clearance columns.
    ///
    /// # Errors
    /// [`OutputError`] naming the file.
    pub fn create(path: &Path, obstacles: usize) -> Result<Self, OutputError> {
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
                "rows",
                "fm_ms",
                "cd_ms",
                "cc_ms",
                "sc_ms",
                "corr_ms",
            ]
            .map(String::from),
        );
        header.extend((1..=6).map(|j| format!("q{j}_rad")));
        out.write_record(&header).map_err(err)?;
        Ok(Self {
            out,
            file: path.to_owned(),
            obstacles,
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
        row.push(m.rows.to_string());
        row.extend(m.time_ms.iter().map(|v| v.to_string()));
        row.extend(m.q.iter().map(|v| v.to_string()));
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

    fn tmp(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("needle-output-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir.join(name)
    }

    #[test]
    fn vtk_files_read_back_with_their_cells_and_data() {
        let nodes = vec![Vector3::zeros(), Vector3::x(), Vector3::y(), Vector3::z()];
        let moved: Vec<_> = nodes
            .iter()
            .map(|p| p + Vector3::new(0.5, 0.0, 0.0))
            .collect();
        let path = tmp("gel.vtk");
        write_tet_mesh(&path, &moved, &nodes, &[[0, 1, 2, 3]]).unwrap();
        let back = Vtk::import(&path).expect("vtkio reads what it wrote");
        let DataSet::UnstructuredGrid { pieces, .. } = back.data else {
            panic!("not a grid")
        };
        let vtkio::model::Piece::Inline(piece) = &pieces[0] else {
            panic!("not inline")
        };
        assert_eq!(piece.num_points(), 4);
        assert_eq!(piece.cells.types, vec![CellType::Tetra]);
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text.contains("displacement"), "{text}");

        let line = tmp("needle.vtk");
        write_polyline(&line, "needle", &nodes).unwrap();
        assert!(
            std::fs::read_to_string(&line)
                .unwrap()
                .contains("CELL_TYPES 1")
        );
        let pts = tmp("obstacles.vtk");
        write_points(&pts, "obstacles", &nodes[..2], "radius", &[2.0, 3.0]).unwrap();
        assert!(std::fs::read_to_string(&pts).unwrap().contains("radius"));
    }

    #[test]
    fn csv_has_one_column_per_header_field() {
        let path = tmp("metrics.csv");
        let mut w = MetricsWriter::create(&path, 3).unwrap();
        w.write(&StepMetrics {
            step: 1,
            clearance: vec![1.0, 2.0, 3.0],
            ..Default::default()
        })
        .unwrap();
        w.flush().unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        let lines: Vec<_> = text.lines().collect();
        assert_eq!(lines.len(), 2);
        assert_eq!(lines[0].split(',').count(), lines[1].split(',').count());
        assert!(lines[0].contains("clearance_2_mm"));
    }

    #[test]
    fn unwritable_file_names_the_path() {
        let e = write_polyline(
            Path::new("/nonexistent-dir/x.vtk"),
            "x",
            &[Vector3::zeros()],
        )
        .unwrap_err();
        assert!(e.to_string().contains("/nonexistent-dir/x.vtk"), "{e}");
        assert!(matches!(e.source, OutputFailure::Vtk(_)), "{e:?}");
    }
}

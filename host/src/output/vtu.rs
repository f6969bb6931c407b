//! VTK XML unstructured grids (`.vtu`, binary, zlib-compressed) and `.pvd` time collections,
//! the files ParaView (and VTK's readers, meshio, PyVista) open.
//!
//! Every data array is written inline, `format="binary"`, with VTK's compressed layout: the
//! raw little-endian bytes cut into blocks of [`BLOCK`] bytes, each compressed with zlib; the
//! header `[blocks, block size, last block size, compressed size of each block]` (UInt64) is
//! base64-encoded on its own, followed by the base64 of the concatenated compressed blocks.
//! (`vtkio` 0.6.3's XML writer puts a single size before the compressed stream instead, which
//! VTK cannot read: hence this small writer.)

use base64::Engine as _;
use base64::engine::general_purpose::STANDARD;
use flate2::Compression;
use flate2::write::ZlibEncoder;
use nalgebra::Vector3;
use std::fmt::Write as _;
use std::io::Write as _;
use std::path::Path;

use super::OutputError;

/// Uncompressed bytes per compressed block (VTK's default).
pub const BLOCK: usize = 1 << 15;

/// VTK cell types used by the outputs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum CellKind {
    /// One point.
    Vertex = 1,
    /// A segment.
    Line = 3,
    /// A chain of segments through its points.
    PolyLine = 4,
    /// A triangle.
    Triangle = 5,
    /// A linear tetrahedron.
    Tetra = 10,
}

/// The values of one data array.
#[derive(Clone, Debug, PartialEq)]
pub enum Values {
    /// Doubles, `components` per tuple (1 scalar, 3 vector, 9 tensor).
    F64 {
        /// Components per tuple.
        components: usize,
        /// The tuples, flattened.
        data: Vec<f64>,
    },
    /// 32-bit integers, one per tuple.
    I32(Vec<i32>),
}

impl Values {
    /// Scalars.
    pub fn scalars(v: impl IntoIterator<Item = f64>) -> Self {
        Self::F64 {
            components: 1,
            data: v.into_iter().collect(),
        }
    }

    /// 3-vectors.
    pub fn vectors<'a>(v: impl IntoIterator<Item = &'a Vector3<f64>>) -> Self {
        Self::F64 {
            components: 3,
            data: v.into_iter().flat_map(|p| [p.x, p.y, p.z]).collect(),
        }
    }

    fn components(&self) -> usize {
        match self {
            Self::F64 { components, .. } => *components,
            Self::I32(_) => 1,
        }
    }

    fn tuples(&self) -> usize {
        match self {
            Self::F64 { components, data } => data.len() / (*components).max(1),
            Self::I32(v) => v.len(),
        }
    }

    fn type_name(&self) -> &'static str {
        match self {
            Self::F64 { .. } => "Float64",
            Self::I32(_) => "Int32",
        }
    }

    fn bytes(&self) -> Vec<u8> {
        match self {
            Self::F64 { data, .. } => data.iter().flat_map(|v| v.to_le_bytes()).collect(),
            Self::I32(v) => v.iter().flat_map(|v| v.to_le_bytes()).collect(),
        }
    }
}

/// A named data array of a grid's points or cells.
#[derive(Clone, Debug, PartialEq)]
pub struct Array {
    /// Its name in ParaView.
    pub name: String,
    /// Its values (one tuple per point or per cell).
    pub values: Values,
}

impl Array {
    /// A named array.
    pub fn new(name: &str, values: Values) -> Self {
        Self {
            name: name.to_owned(),
            values,
        }
    }
}

/// An unstructured grid: points, cells, point data and cell data.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Grid {
    /// Points [mm].
    pub points: Vec<Vector3<f64>>,
    /// Cells: kind and point indices.
    pub cells: Vec<(CellKind, Vec<usize>)>,
    /// One tuple per point.
    pub point_data: Vec<Array>,
    /// One tuple per cell.
    pub cell_data: Vec<Array>,
    /// The time of the frame [s], written as the `TimeValue` field.
    pub time: Option<f64>,
}

impl Grid {
    /// The grid as `.vtu` text, or why its arrays do not fit its points and cells.
    ///
    /// # Errors
    /// An array whose tuple count differs from the points' or cells' count, or a cell that
    /// names a point the grid does not have (the message names the array or cell).
    pub fn to_vtu(&self) -> Result<String, String> {
        let (n, m) = (self.points.len(), self.cells.len());
        for (data, count, what) in [(&self.point_data, n, "point"), (&self.cell_data, m, "cell")] {
            if let Some(a) = data.iter().find(|a| a.values.tuples() != count) {
                return Err(format!(
                    "{what} array `{}` has {} tuples for {count} {what}s",
                    a.name,
                    a.values.tuples()
                ));
            }
        }
        if let Some(k) = self
            .cells
            .iter()
            .position(|(_, c)| c.iter().any(|&i| i >= n))
        {
            return Err(format!("cell {k} names a point beyond the grid's {n}"));
        }
        let mut connectivity = Vec::new();
        let mut offsets = Vec::with_capacity(m);
        for (_, c) in &self.cells {
            connectivity.extend(c.iter().map(|&i| i as i64));
            offsets.push(connectivity.len() as i64);
        }
        let types: Vec<u8> = self.cells.iter().map(|(k, _)| *k as u8).collect();

        let mut s = String::with_capacity(1024);
        s.push_str("<?xml version=\"1.0\"?>\n");
        s.push_str(
            "<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" \
             header_type=\"UInt64\" compressor=\"vtkZLibDataCompressor\">\n<UnstructuredGrid>\n",
        );
        if let Some(t) = self.time {
            s.push_str("<FieldData>\n");
            let bytes = t.to_le_bytes();
            write_array(&mut s, "Float64", Some("TimeValue"), 1, Some(1), &bytes);
            s.push_str("</FieldData>\n");
        }
        let _ = writeln!(s, "<Piece NumberOfPoints=\"{n}\" NumberOfCells=\"{m}\">");
        for (tag, data) in [
            ("PointData", &self.point_data),
            ("CellData", &self.cell_data),
        ] {
            let _ = writeln!(s, "<{tag}>");
            for a in data {
                let v = &a.values;
                write_array(
                    &mut s,
                    v.type_name(),
                    Some(&a.name),
                    v.components(),
                    None,
                    &v.bytes(),
                );
            }
            let _ = writeln!(s, "</{tag}>");
        }
        s.push_str("<Points>\n");
        write_array(
            &mut s,
            "Float64",
            Some("Points"),
            3,
            None,
            &Values::vectors(&self.points).bytes(),
        );
        s.push_str("</Points>\n<Cells>\n");
        let ints = |v: &[i64]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
        write_array(
            &mut s,
            "Int64",
            Some("connectivity"),
            1,
            None,
            &ints(&connectivity),
        );
        write_array(&mut s, "Int64", Some("offsets"), 1, None, &ints(&offsets));
        write_array(&mut s, "UInt8", Some("types"), 1, None, &types);
        s.push_str("</Cells>\n</Piece>\n</UnstructuredGrid>\n</VTKFile>\n");
        Ok(s)
    }

    /// Writes the grid to `path` (`.vtu`).
    ///
    /// # Errors
    /// [`OutputError`] naming the file: it cannot be written, or the grid is inconsistent.
    pub fn write(&self, path: &Path) -> Result<(), OutputError> {
        let text = self
            .to_vtu()
            .map_err(|why| OutputError::new(path, super::OutputFailure::Vtk(why)))?;
        std::fs::write(path, text).map_err(|e| OutputError::new(path, e))
    }
}

/// One `<DataArray>` element, binary, zlib-compressed in [`BLOCK`]-byte blocks.
fn write_array(
    s: &mut String,
    ty: &str,
    name: Option<&str>,
    components: usize,
    tuples: Option<usize>,
    raw: &[u8],
) {
    let _ = write!(s, "<DataArray type=\"{ty}\"");
    if let Some(name) = name {
        let _ = write!(s, " Name=\"{name}\"");
    }
    if components != 1 {
        let _ = write!(s, " NumberOfComponents=\"{components}\"");
    }
    if let Some(t) = tuples {
        let _ = write!(s, " NumberOfTuples=\"{t}\"");
    }
    s.push_str(" format=\"binary\">");
    let (header, body) = compress(raw);
    STANDARD.encode_string(header, s);
    STANDARD.encode_string(body, s);
    s.push_str("</DataArray>\n");
}

/// VTK's compressed layout of `raw`: the header bytes and the concatenated zlib blocks.
fn compress(raw: &[u8]) -> (Vec<u8>, Vec<u8>) {
    let chunks: Vec<&[u8]> = raw.chunks(BLOCK).collect();
    let last = chunks.last().map_or(0, |c| c.len());
    let mut header: Vec<u64> = vec![chunks.len() as u64, BLOCK as u64, last as u64];
    let mut body = Vec::new();
    for c in &chunks {
        let mut z = ZlibEncoder::new(Vec::new(), Compression::new(6));
        // Writing into a Vec cannot fail.
        let _ = z.write_all(c);
        let out = z.finish().unwrap_or_default();
        header.push(out.len() as u64);
        body.extend_from_slice(&out);
    }
    (header.iter().flat_map(|v| v.to_le_bytes()).collect(), body)
}

/// A `.pvd` collection: for each frame, its time [s] and one file per part (names relative to
/// the collection's folder).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Collection {
    /// `(time, files)` per frame, in time order.
    pub frames: Vec<(f64, Vec<String>)>,
}

impl Collection {
    /// The `.pvd` text: one `<DataSet>` per frame and part (`part` numbers the files of a frame).
    pub fn to_pvd(&self) -> String {
        let mut s = String::from(
            "<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"0.1\" \
             byte_order=\"LittleEndian\">\n<Collection>\n",
        );
        for (t, files) in &self.frames {
            for (part, f) in files.iter().enumerate() {
                let _ = writeln!(
                    s,
                    "<DataSet timestep=\"{t:e}\" group=\"\" part=\"{part}\" file=\"{f}\"/>"
                );
            }
        }
        s.push_str("</Collection>\n</VTKFile>\n");
        s
    }

    /// Writes the collection to `path` (`.pvd`).
    ///
    /// # Errors
    /// [`OutputError`] naming the file.
    pub fn write(&self, path: &Path) -> Result<(), OutputError> {
        std::fs::write(path, self.to_pvd()).map_err(|e| OutputError::new(path, e))
    }
}

/// A triangulated unit sphere: an icosahedron subdivided `levels` times (12, 42, 162, 642
/// vertices …), vertices on the unit sphere, triangles outward.
pub fn unit_sphere(levels: usize) -> (Vec<Vector3<f64>>, Vec<[usize; 3]>) {
    let t = (1.0 + 5f64.sqrt()) / 2.0;
    let mut v: Vec<Vector3<f64>> = [
        [-1.0, t, 0.0],
        [1.0, t, 0.0],
        [-1.0, -t, 0.0],
        [1.0, -t, 0.0],
        [0.0, -1.0, t],
        [0.0, 1.0, t],
        [0.0, -1.0, -t],
        [0.0, 1.0, -t],
        [t, 0.0, -1.0],
        [t, 0.0, 1.0],
        [-t, 0.0, -1.0],
        [-t, 0.0, 1.0],
    ]
    .iter()
    .map(|p| Vector3::from(*p).normalize())
    .collect();
    let mut f: Vec<[usize; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..levels {
        let mut mid = std::collections::HashMap::new();
        let mut split = |a: usize, b: usize, v: &mut Vec<Vector3<f64>>| {
            *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                v.push(((v[a] + v[b]) / 2.0).normalize());
                v.len() - 1
            })
        };
        f = f
            .iter()
            .flat_map(|&[a, b, c]| {
                let (ab, bc, ca) = (
                    split(a, b, &mut v),
                    split(b, c, &mut v),
                    split(c, a, &mut v),
                );
                [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
            })
            .collect();
    }
    (v, f)
}

#[cfg(test)]
mod tests;

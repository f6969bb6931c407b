//! VTK unstructured grids: XML `.vtu` (ASCII, binary inline, appended raw or base64; zlib
//! compressed or not; 32- or 64-bit block headers; either byte order) and legacy `.vtk`
//! (`DATASET UNSTRUCTURED_GRID`, ASCII or binary, file formats 4.x and 5.x).
//!
//! Points are taken as mm. Cells of dimension below 3 (vertices, lines, triangles, quads, …)
//! are skipped; linear tetrahedra (VTK type 10) are kept; any other volume cell (a voxel, a
//! hexahedron, a wedge, a pyramid, a quadratic tetrahedron, …) is refused, naming the cell. The
//! cell array `region` (any numeric type, integer values) gives each tetrahedron's region; 0
//! when there is none. Nodes no tetrahedron uses are dropped and elements reoriented, as for
//! Gmsh files; an invalid element is named by its cell index (0-based, in file order).

use super::{MeshError, TetMesh};
use base64::Engine as _;
use nalgebra::Vector3;
use std::fmt;
use std::io::Read as _;
use std::path::Path;

/// Why a VTK file could not be read.
#[derive(Debug)]
#[non_exhaustive]
pub enum VtkError {
    /// Reading the file failed.
    Io(std::io::Error),
    /// The file is not a readable unstructured grid (what is wrong, in words).
    Format(String),
    /// A cell cannot be a gel element.
    Cell {
        /// Index of the cell in the file (0-based).
        cell: usize,
        /// Why.
        reason: String,
    },
    /// The mesh read is invalid (not tied to one cell).
    Mesh(MeshError),
}

impl fmt::Display for VtkError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Io(e) => write!(f, "vtk file I/O: {e}"),
            Self::Format(m) => write!(f, "vtk file could not be read: {m}"),
            Self::Cell { cell, reason } => write!(f, "vtk cell {cell}: {reason}"),
            Self::Mesh(e) => write!(f, "vtk mesh is invalid: {e}"),
        }
    }
}

impl std::error::Error for VtkError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Self::Io(e) => Some(e),
            Self::Mesh(e) => Some(e),
            _ => None,
        }
    }
}

fn format_error(m: impl Into<String>) -> VtkError {
    VtkError::Format(m.into())
}

/// Reads a `.vtu` (XML) or legacy `.vtk` file, by its extension.
///
/// # Errors
/// [`VtkError`] on I/O, an unreadable file, a cell that cannot be read or an invalid mesh.
pub fn read_vtk(path: impl AsRef<Path>) -> Result<TetMesh, VtkError> {
    let path = path.as_ref();
    let bytes = crate::bounded_read::read_bounded(path, super::gmsh::MAX_FILE_BYTES)
        .map_err(VtkError::Io)?;
    match path.extension().and_then(|e| e.to_str()) {
        Some(e) if e.eq_ignore_ascii_case("vtu") => read_vtu_bytes(&bytes),
        _ => read_legacy_vtk_bytes(&bytes),
    }
}

/// What a file holds: points, cells (VTK type, point indices) and the `region` cell values.
struct Grid {
    points: Vec<Vector3<f64>>,
    cells: Vec<(u8, Vec<i64>)>,
    region: Option<Vec<f64>>,
}

/// Dimension of a VTK cell type (`None`: unknown).
fn cell_dimension(kind: u8) -> Option<u8> {
    Some(match kind {
        1 | 2 => 0,
        3 | 4 | 21 | 35 | 68 => 1,
        5..=9 | 22 | 23 | 28 | 30 | 34 | 36 | 37 | 69 | 70 => 2,
        10..=16 | 24..=27 | 29 | 31..=33 | 42 | 71 | 72 => 3,
        _ => return None,
    })
}

fn cell_name(kind: u8) -> &'static str {
    match kind {
        11 => "voxel",
        12 | 25 | 29 | 33 | 72 => "hexahedron",
        13 | 26 | 32 | 73 => "wedge",
        14 | 27 | 31 => "pyramid",
        24 | 71 => "quadratic tetrahedron",
        15 => "pentagonal prism",
        16 => "hexagonal prism",
        42 => "polyhedron",
        _ => "volume cell",
    }
}

impl Grid {
    fn into_mesh(self) -> Result<TetMesh, VtkError> {
        let n = self.points.len();
        if let Some(r) = &self.region
            && r.len() != self.cells.len()
        {
            return Err(format_error(format!(
                "the cell array `region` has {} values for {} cells",
                r.len(),
                self.cells.len()
            )));
        }
        let mut tets = Vec::new();
        let mut regions = Vec::new();
        let mut cell_of = Vec::new();
        for (cell, (kind, ids)) in self.cells.iter().enumerate() {
            let dim = cell_dimension(*kind).ok_or_else(|| VtkError::Cell {
                cell,
                reason: format!("unknown VTK cell type {kind}"),
            })?;
            if dim < 3 {
                continue;
            }
            if *kind != 10 {
                return Err(VtkError::Cell {
                    cell,
                    reason: format!(
                        "a {} (VTK type {kind}), not a linear tetrahedron (only those are read)",
                        cell_name(*kind)
                    ),
                });
            }
            if ids.len() != 4 {
                return Err(VtkError::Cell {
                    cell,
                    reason: format!("a tetrahedron with {} points", ids.len()),
                });
            }
            let mut t = [0usize; 4];
            for (k, &v) in ids.iter().enumerate() {
                t[k] =
                    usize::try_from(v)
                        .ok()
                        .filter(|&v| v < n)
                        .ok_or_else(|| VtkError::Cell {
                            cell,
                            reason: format!("point index {v} out of range ({n} points)"),
                        })?;
            }
            let region = match &self.region {
                None => 0,
                Some(r) => {
                    let v = r[cell];
                    if !(v.fract() == 0.0 && v.abs() <= f64::from(i32::MAX)) {
                        return Err(VtkError::Cell {
                            cell,
                            reason: format!("region {v} is not an integer tag"),
                        });
                    }
                    v as i32
                }
            };
            tets.push(t);
            regions.push(region);
            cell_of.push(cell);
        }
        if tets.is_empty() {
            return Err(format_error("the grid has no tetrahedron (VTK type 10)"));
        }
        super::compact_oriented(self.points, tets, regions).map_err(|e| match e.element() {
            Some(i) => VtkError::Cell {
                cell: cell_of[i],
                reason: e.to_string(),
            },
            None => VtkError::Mesh(e),
        })
    }
}

/// Size in bytes of a VTK scalar type (XML or legacy name) and whether it is a float.
fn scalar_type(name: &str) -> Option<(usize, Kind)> {
    Some(match name {
        "Int8" | "char" | "signed_char" => (1, Kind::Int),
        "UInt8" | "unsigned_char" | "bit" => (1, Kind::UInt),
        "Int16" | "short" => (2, Kind::Int),
        "UInt16" | "unsigned_short" => (2, Kind::UInt),
        "Int32" | "int" | "vtktypeint32" => (4, Kind::Int),
        "UInt32" | "unsigned_int" | "vtktypeuint32" => (4, Kind::UInt),
        "Int64" | "long" | "vtktypeint64" | "vtkIdType" => (8, Kind::Int),
        "UInt64" | "unsigned_long" | "vtktypeuint64" => (8, Kind::UInt),
        "Float32" | "float" => (4, Kind::Float),
        "Float64" | "double" => (8, Kind::Float),
        _ => return None,
    })
}

#[derive(Clone, Copy, PartialEq)]
enum Kind {
    Int,
    UInt,
    Float,
}

/// Decodes `count` binary values of `size` bytes each.
fn decode_values(
    bytes: &[u8],
    size: usize,
    kind: Kind,
    big_endian: bool,
    count: usize,
    what: &str,
) -> Result<Vec<f64>, VtkError> {
    let need = count
        .checked_mul(size)
        .ok_or_else(|| format_error(format!("{what}: too many values")))?;
    if bytes.len() < need {
        return Err(format_error(format!(
            "{what}: {} bytes of data for {count} values of {size} bytes",
            bytes.len()
        )));
    }
    Ok(bytes[..need]
        .chunks_exact(size)
        .map(|c| {
            let mut b = [0u8; 8];
            if big_endian {
                for (i, v) in c.iter().rev().enumerate() {
                    b[i] = *v;
                }
            } else {
                b[..size].copy_from_slice(c);
            }
            // Sign-extend signed integers.
            let negative = kind == Kind::Int && size < 8 && b[size - 1] & 0x80 != 0;
            if negative {
                for v in b.iter_mut().skip(size) {
                    *v = 0xff;
                }
            }
            match (kind, size) {
                (Kind::Float, 4) => f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
                (Kind::Float, _) => f64::from_le_bytes(b),
                (Kind::Int, _) => i64::from_le_bytes(b) as f64,
                (Kind::UInt, _) => u64::from_le_bytes(b) as f64,
            }
        })
        .collect())
}

// ---------------------------------------------------------------------------------------------
// XML `.vtu`.

/// The attributes of the first tag `<name …>` in `text` from `from`, and where its body starts
/// (after `>`; `None` for a self-closing tag).
fn find_tag<'a>(
    text: &'a str,
    name: &str,
    from: usize,
) -> Option<(usize, Attrs<'a>, Option<usize>)> {
    let pat = format!("<{name}");
    let mut at = from;
    loop {
        let start = at + text.get(at..)?.find(&pat)?;
        let after = start + pat.len();
        let next = text[after..].chars().next()?;
        if !(next.is_whitespace() || next == '>' || next == '/') {
            at = after;
            continue;
        }
        let end = after + text[after..].find('>')?;
        let inner = &text[after..end];
        let (inner, closed) = match inner.strip_suffix('/') {
            Some(s) => (s, true),
            None => (inner, false),
        };
        return Some((start, Attrs(inner), (!closed).then_some(end + 1)));
    }
}

/// The attributes of a tag (`key="value"` pairs).
#[derive(Clone, Copy)]
struct Attrs<'a>(&'a str);

impl<'a> Attrs<'a> {
    fn get(&self, key: &str) -> Option<&'a str> {
        let mut rest = self.0;
        while let Some(eq) = rest.find('=') {
            let k = rest[..eq].trim();
            let after = rest[eq + 1..].trim_start();
            let quote = after.chars().next()?;
            if quote != '"' && quote != '\'' {
                return None;
            }
            let close = after[1..].find(quote)?;
            let v = &after[1..1 + close];
            if k == key {
                return Some(v);
            }
            rest = &after[close + 2..];
        }
        None
    }
}

/// How the binary data of a `.vtu` file is laid out.
struct Layout {
    big_endian: bool,
    header: usize,
    zlib: bool,
}

/// Base64 text made of independently padded pieces (VTK encodes a compressed array's header
/// and its blocks separately), decoded piece by piece.
fn decode_base64(text: &str, what: &str) -> Result<Vec<u8>, VtkError> {
    let clean: Vec<u8> = text.bytes().filter(|b| !b.is_ascii_whitespace()).collect();
    let mut out = Vec::with_capacity(clean.len() / 4 * 3);
    let mut start = 0;
    while start < clean.len() {
        let mut end = start;
        while end < clean.len() && clean[end] != b'=' {
            end += 1;
        }
        while end < clean.len() && clean[end] == b'=' {
            end += 1;
        }
        base64::engine::general_purpose::STANDARD
            .decode_vec(&clean[start..end], &mut out)
            .map_err(|e| format_error(format!("{what}: bad base64 ({e})")))?;
        start = end;
    }
    Ok(out)
}

impl Layout {
    fn uint(&self, b: &[u8], what: &str) -> Result<usize, VtkError> {
        let v = decode_values(b, self.header, Kind::UInt, self.big_endian, 1, what)?;
        let v = v[0];
        if !(v >= 0.0 && v <= (1u64 << 40) as f64) {
            return Err(format_error(format!(
                "{what}: header value {v} out of range"
            )));
        }
        Ok(v as usize)
    }

    /// The payload of one array from its binary form (header + data), and the bytes used.
    fn payload(&self, b: &[u8], what: &str) -> Result<(Vec<u8>, usize), VtkError> {
        let h = self.header;
        if !self.zlib {
            let n = self.uint(b, what)?;
            let data = b.get(h..h + n).ok_or_else(|| {
                format_error(format!("{what}: {n} bytes announced, fewer present"))
            })?;
            return Ok((data.to_vec(), h + n));
        }
        let blocks = self.uint(b, what)?;
        let block = self.uint(b.get(h..).unwrap_or(&[]), what)?;
        let last = self.uint(b.get(2 * h..).unwrap_or(&[]), what)?;
        if blocks > b.len() / h {
            return Err(format_error(format!(
                "{what}: {blocks} compressed blocks announced"
            )));
        }
        let mut sizes = Vec::with_capacity(blocks);
        for k in 0..blocks {
            sizes.push(self.uint(b.get((3 + k) * h..).unwrap_or(&[]), what)?);
        }
        let mut at = (3 + blocks) * h;
        let mut out = Vec::new();
        for (k, &c) in sizes.iter().enumerate() {
            let chunk = b.get(at..at + c).ok_or_else(|| {
                format_error(format!("{what}: compressed block {k} is cut short"))
            })?;
            let expect = if k + 1 == blocks && last != 0 {
                last
            } else {
                block
            };
            let mut d = flate2::read::ZlibDecoder::new(chunk).take(expect as u64 + 1);
            let before = out.len();
            d.read_to_end(&mut out)
                .map_err(|e| format_error(format!("{what}: block {k} does not inflate ({e})")))?;
            if out.len() - before != expect {
                return Err(format_error(format!(
                    "{what}: block {k} inflates to {} bytes, its header says {expect}",
                    out.len() - before
                )));
            }
            at += c;
        }
        Ok((out, at))
    }
}

/// Reads a `.vtu` (VTK XML unstructured grid) from memory; see [`read_vtk`].
///
/// # Errors
/// As [`read_vtk`].
pub fn read_vtu_bytes(bytes: &[u8]) -> Result<TetMesh, VtkError> {
    // The XML part ends where raw appended data may begin.
    let split = bytes
        .windows(13)
        .position(|w| w == b"<AppendedData")
        .unwrap_or(bytes.len());
    let head = std::str::from_utf8(&bytes[..split])
        .map_err(|_| format_error("the XML part is not UTF-8 text"))?;
    let (_, file, _) =
        find_tag(head, "VTKFile", 0).ok_or_else(|| format_error("no <VTKFile> tag"))?;
    if file.get("type") != Some("UnstructuredGrid") {
        return Err(format_error(format!(
            "VTKFile type {:?} is not UnstructuredGrid",
            file.get("type").unwrap_or("")
        )));
    }
    let layout = Layout {
        big_endian: file.get("byte_order") == Some("BigEndian"),
        header: match file.get("header_type").unwrap_or("UInt32") {
            "UInt32" => 4,
            "UInt64" => 8,
            h => {
                return Err(format_error(format!(
                    "header_type {h} (UInt32 or UInt64 are read)"
                )));
            }
        },
        zlib: match file.get("compressor") {
            None | Some("") => false,
            Some("vtkZLibDataCompressor") => true,
            Some(c) => {
                return Err(format_error(format!(
                    "compressor {c} (only vtkZLibDataCompressor is read)"
                )));
            }
        },
    };
    let (piece_at, piece, _) =
        find_tag(head, "Piece", 0).ok_or_else(|| format_error("no <Piece> tag"))?;
    if find_tag(head, "Piece", piece_at + 6).is_some() {
        return Err(format_error("more than one <Piece> (one is read)"));
    }
    let count = |key: &str| -> Result<usize, VtkError> {
        piece
            .get(key)
            .and_then(|v| v.trim().parse().ok())
            .filter(|&n: &usize| n <= bytes.len())
            .ok_or_else(|| format_error(format!("<Piece> has no valid {key}")))
    };
    let (n_points, n_cells) = (count("NumberOfPoints")?, count("NumberOfCells")?);
    // The appended data, after its `_` marker.
    let appended = if split < bytes.len() {
        let tail = &bytes[split..];
        let gt = tail
            .iter()
            .position(|&b| b == b'>')
            .ok_or_else(|| format_error("bad <AppendedData>"))?;
        let tag =
            std::str::from_utf8(&tail[..gt]).map_err(|_| format_error("bad <AppendedData>"))?;
        let encoding = Attrs(&tag[13..])
            .get("encoding")
            .unwrap_or("raw")
            .to_owned();
        let underscore = tail[gt..]
            .iter()
            .position(|&b| b == b'_')
            .ok_or_else(|| format_error("<AppendedData> has no `_` marker"))?;
        Some((encoding, &tail[gt + underscore + 1..]))
    } else {
        None
    };
    let section = |name: &str| -> Option<(usize, usize)> {
        let (_, _, body) = find_tag(head, name, 0)?;
        let body = body?;
        let end = body + head[body..].find(&format!("</{name}>"))?;
        Some((body, end))
    };
    let array = |sect: &str,
                 name: Option<&str>,
                 expect: usize,
                 what: &str|
     -> Result<Option<Vec<f64>>, VtkError> {
        let Some((lo, hi)) = section(sect) else {
            return Ok(None);
        };
        let mut at = lo;
        while let Some((start, attrs, body)) = find_tag(&head[..hi], "DataArray", at) {
            at = start + 10;
            if let Some(n) = name
                && attrs.get("Name") != Some(n)
            {
                continue;
            }
            let ty = attrs.get("type").unwrap_or("");
            let (size, kind) = scalar_type(ty)
                .ok_or_else(|| format_error(format!("{what}: unknown data type `{ty}`")))?;
            let comps: usize = attrs
                .get("NumberOfComponents")
                .map_or(Some(1), |c| c.trim().parse().ok())
                .filter(|&c| (1..=16).contains(&c))
                .ok_or_else(|| format_error(format!("{what}: bad NumberOfComponents")))?;
            let values = expect
                .checked_mul(comps)
                .ok_or_else(|| format_error(format!("{what}: too many values")))?;
            let text = match body {
                // The data, up to `</DataArray>` or a nested `<InformationKey>` after it.
                Some(b) => {
                    let end = b + head[b..]
                        .find('<')
                        .ok_or_else(|| format_error(format!("{what}: no </DataArray>")))?;
                    &head[b..end]
                }
                None => "",
            };
            let format = attrs.get("format").unwrap_or("ascii");
            let v = match format {
                "ascii" => {
                    let v: Vec<f64> = text
                        .split_ascii_whitespace()
                        .map(|t| t.parse::<f64>())
                        .collect::<Result<_, _>>()
                        .map_err(|_| format_error(format!("{what}: a value is not a number")))?;
                    if v.len() != values {
                        return Err(format_error(format!(
                            "{what}: {} values, {values} expected",
                            v.len()
                        )));
                    }
                    v
                }
                "binary" => {
                    let raw = decode_base64(text, what)?;
                    let (data, _) = layout.payload(&raw, what)?;
                    decode_values(&data, size, kind, layout.big_endian, values, what)?
                }
                "appended" => {
                    let (encoding, data) = appended
                        .as_ref()
                        .ok_or_else(|| format_error(format!("{what}: no <AppendedData>")))?;
                    let offset: usize = attrs
                        .get("offset")
                        .and_then(|o| o.trim().parse().ok())
                        .filter(|&o: &usize| o <= data.len())
                        .ok_or_else(|| format_error(format!("{what}: bad offset")))?;
                    let rest = &data[offset..];
                    let payload = if encoding == "base64" {
                        let end = rest.iter().position(|&b| b == b'<').unwrap_or(rest.len());
                        // The array's base64 runs to the next array's offset: decode the
                        // header first, then just its data.
                        let text = std::str::from_utf8(&rest[..end])
                            .map_err(|_| format_error(format!("{what}: bad base64")))?;
                        payload_from_base64(&layout, text, what)?
                    } else {
                        layout.payload(rest, what)?.0
                    };
                    decode_values(&payload, size, kind, layout.big_endian, values, what)?
                }
                f => return Err(format_error(format!("{what}: format `{f}`"))),
            };
            return Ok(Some(v));
        }
        Ok(None)
    };
    let coords = array("Points", None, n_points, "the points")?
        .ok_or_else(|| format_error("no <Points> data array"))?;
    if coords.len() != 3 * n_points {
        return Err(format_error("the points do not have 3 components"));
    }
    let offsets = array("Cells", Some("offsets"), n_cells, "the cell offsets")?
        .ok_or_else(|| format_error("no cell `offsets` array"))?;
    let types = array("Cells", Some("types"), n_cells, "the cell types")?
        .ok_or_else(|| format_error("no cell `types` array"))?;
    let total = offsets.last().copied().unwrap_or(0.0);
    if !(total >= 0.0 && total <= bytes.len() as f64) {
        return Err(format_error("the cell offsets are out of range"));
    }
    let conn = array(
        "Cells",
        Some("connectivity"),
        total as usize,
        "the cell connectivity",
    )?
    .ok_or_else(|| format_error("no cell `connectivity` array"))?;
    let region = array(
        "CellData",
        Some("region"),
        n_cells,
        "the cell array `region`",
    )?;
    let points = coords
        .chunks_exact(3)
        .map(|c| Vector3::new(c[0], c[1], c[2]))
        .collect();
    let mut cells = Vec::with_capacity(n_cells);
    let mut prev = 0usize;
    for (cell, (&end, &kind)) in offsets.iter().zip(&types).enumerate() {
        let end = end as usize;
        if end < prev || end > conn.len() {
            return Err(VtkError::Cell {
                cell,
                reason: format!("offset {end} out of order or past the connectivity"),
            });
        }
        let kind = u8::try_from(kind as i64).map_err(|_| VtkError::Cell {
            cell,
            reason: format!("unknown VTK cell type {kind}"),
        })?;
        cells.push((kind, conn[prev..end].iter().map(|&v| v as i64).collect()));
        prev = end;
    }
    Grid {
        points,
        cells,
        region,
    }
    .into_mesh()
}

/// An appended base64 array: its header (one base64 piece), then as much of the following
/// text as the header says.
fn payload_from_base64(layout: &Layout, text: &str, what: &str) -> Result<Vec<u8>, VtkError> {
    let text: String = text.chars().filter(|c| !c.is_ascii_whitespace()).collect();
    let b64 = |bytes: usize| bytes.div_ceil(3) * 4;
    let h = layout.header;
    let piece = |from: usize, bytes: usize| -> Result<Vec<u8>, VtkError> {
        let to = from + b64(bytes);
        let s = text
            .get(from..to)
            .ok_or_else(|| format_error(format!("{what}: the base64 data is cut short")))?;
        decode_base64(s, what)
    };
    if !layout.zlib {
        // The header and the data in one base64 stream (VTK), or each padded on its own.
        let first = piece(0, h)?;
        let n = layout.uint(&first, what)?;
        let separate = text.get(..b64(h)).is_some_and(|t| t.ends_with('='));
        let all = if separate {
            let mut all = first[..h.min(first.len())].to_vec();
            all.extend_from_slice(&piece(b64(h), n)?);
            all
        } else {
            piece(0, h + n)?
        };
        return Ok(layout.payload(&all, what)?.0);
    }
    let first = piece(0, 3 * h)?;
    let blocks = layout.uint(&first, what)?;
    if blocks > text.len() {
        return Err(format_error(format!("{what}: {blocks} blocks announced")));
    }
    let header = piece(0, (3 + blocks) * h)?;
    let mut total = 0usize;
    for k in 0..blocks {
        total += layout.uint(header.get((3 + k) * h..).unwrap_or(&[]), what)?;
    }
    let data = piece(b64((3 + blocks) * h), total)?;
    let mut all = header[..((3 + blocks) * h).min(header.len())].to_vec();
    all.extend_from_slice(&data);
    Ok(layout.payload(&all, what)?.0)
}

// ---------------------------------------------------------------------------------------------
// Legacy `.vtk`.

/// A cursor over a legacy file: text lines and words, or big-endian binary values.
struct Legacy<'a> {
    bytes: &'a [u8],
    at: usize,
    binary: bool,
}

impl<'a> Legacy<'a> {
    fn line(&mut self) -> Option<&'a str> {
        if self.at >= self.bytes.len() {
            return None;
        }
        let end = self.bytes[self.at..]
            .iter()
            .position(|&b| b == b'\n')
            .map_or(self.bytes.len(), |p| self.at + p);
        let l = std::str::from_utf8(&self.bytes[self.at..end]).ok();
        self.at = end + 1;
        l.map(|l| l.trim_end_matches('\r'))
    }

    /// The next non-empty line.
    fn keyword_line(&mut self) -> Option<&'a str> {
        loop {
            let l = self.line()?;
            if !l.trim().is_empty() {
                return Some(l.trim());
            }
        }
    }

    fn word(&mut self) -> Option<&'a str> {
        while self.at < self.bytes.len() && self.bytes[self.at].is_ascii_whitespace() {
            self.at += 1;
        }
        let start = self.at;
        while self.at < self.bytes.len() && !self.bytes[self.at].is_ascii_whitespace() {
            self.at += 1;
        }
        (start < self.at)
            .then(|| std::str::from_utf8(&self.bytes[start..self.at]).ok())
            .flatten()
    }

    /// `count` values of type `ty`, ASCII words or big-endian binary.
    fn values(&mut self, ty: &str, count: usize, what: &str) -> Result<Vec<f64>, VtkError> {
        let (size, kind) = scalar_type(ty)
            .ok_or_else(|| format_error(format!("{what}: unknown data type `{ty}`")))?;
        if count > self.bytes.len() {
            return Err(format_error(format!("{what}: {count} values announced")));
        }
        if self.binary {
            let v = decode_values(
                &self.bytes[self.at.min(self.bytes.len())..],
                size,
                kind,
                true,
                count,
                what,
            )?;
            self.at += count * size;
            // The newline that ends the binary data.
            if self.bytes.get(self.at) == Some(&b'\n') {
                self.at += 1;
            }
            Ok(v)
        } else {
            let mut v = Vec::with_capacity(count);
            for _ in 0..count {
                let w = self
                    .word()
                    .ok_or_else(|| format_error(format!("{what}: the file ends")))?;
                v.push(w.parse().map_err(|_| {
                    format_error(format!(
                        "{what}: `{}` is not a number",
                        w.chars().take(20).collect::<String>()
                    ))
                })?);
            }
            Ok(v)
        }
    }
}

fn number<T: std::str::FromStr>(w: Option<&str>, what: &str) -> Result<T, VtkError> {
    w.and_then(|w| w.parse().ok())
        .ok_or_else(|| format_error(format!("{what} is missing or not a number")))
}

/// Reads a legacy `.vtk` unstructured grid from memory; see [`read_vtk`].
///
/// # Errors
/// As [`read_vtk`].
pub fn read_legacy_vtk_bytes(bytes: &[u8]) -> Result<TetMesh, VtkError> {
    let mut c = Legacy {
        bytes,
        at: 0,
        binary: false,
    };
    let version = c.line().unwrap_or("");
    if !version.starts_with("# vtk DataFile Version") {
        return Err(format_error(
            "the first line is not `# vtk DataFile Version …`",
        ));
    }
    let _title = c.line();
    c.binary = match c.keyword_line() {
        Some(l) if l.eq_ignore_ascii_case("ASCII") => false,
        Some(l) if l.eq_ignore_ascii_case("BINARY") => true,
        _ => return Err(format_error("the third line is neither ASCII nor BINARY")),
    };
    match c.keyword_line() {
        Some(l) if l.split_whitespace().eq(["DATASET", "UNSTRUCTURED_GRID"]) => {}
        l => {
            return Err(format_error(format!(
                "`{}` is not DATASET UNSTRUCTURED_GRID",
                l.unwrap_or("").chars().take(40).collect::<String>()
            )));
        }
    }
    let mut points = None;
    let mut cells: Option<Vec<Vec<i64>>> = None;
    let mut types: Option<Vec<f64>> = None;
    let mut region = None;
    let mut in_cell_data = false;
    let mut cell_count = 0usize;
    while let Some(l) = c.keyword_line() {
        let mut w = l.split_whitespace();
        let key = w.next().unwrap_or("");
        match key {
            "POINTS" => {
                let n: usize = number(w.next(), "the POINTS count")?;
                let ty = w.next().unwrap_or("float");
                let v = c.values(ty, n.saturating_mul(3), "the points")?;
                points = Some(
                    v.chunks_exact(3)
                        .map(|p| Vector3::new(p[0], p[1], p[2]))
                        .collect::<Vec<_>>(),
                );
            }
            "CELLS" => {
                let a: usize = number(w.next(), "the CELLS count")?;
                let b: usize = number(w.next(), "the CELLS size")?;
                // Format 5: OFFSETS and CONNECTIVITY follow; format 4: counts and indices.
                let save = c.at;
                let next = c.keyword_line().unwrap_or("");
                if let Some(ty) = next.strip_prefix("OFFSETS") {
                    let offsets = c.values(ty.trim(), a, "the cell offsets")?;
                    let conn_line = c.keyword_line().unwrap_or("");
                    let ty = conn_line
                        .strip_prefix("CONNECTIVITY")
                        .ok_or_else(|| format_error("OFFSETS are not followed by CONNECTIVITY"))?;
                    let conn = c.values(ty.trim(), b, "the cell connectivity")?;
                    let mut out = Vec::with_capacity(a.saturating_sub(1));
                    for (cell, pair) in offsets.windows(2).enumerate() {
                        let (lo, hi) = (pair[0] as usize, pair[1] as usize);
                        if lo > hi || hi > conn.len() {
                            return Err(VtkError::Cell {
                                cell,
                                reason: "offsets out of order or past the connectivity".into(),
                            });
                        }
                        out.push(conn[lo..hi].iter().map(|&v| v as i64).collect());
                    }
                    cells = Some(out);
                } else {
                    c.at = save;
                    let flat = c.values("int", b, "the cells")?;
                    let mut out = Vec::with_capacity(a);
                    let mut at = 0usize;
                    for cell in 0..a {
                        let k = flat.get(at).copied().unwrap_or(-1.0);
                        let k = if k >= 0.0 { k as usize } else { usize::MAX };
                        let ids = flat
                            .get(at + 1..at.saturating_add(1).saturating_add(k))
                            .ok_or_else(|| VtkError::Cell {
                                cell,
                                reason: "its point list runs past the CELLS size".into(),
                            })?;
                        out.push(ids.iter().map(|&v| v as i64).collect());
                        at += 1 + k;
                    }
                    cells = Some(out);
                }
            }
            "CELL_TYPES" => {
                let n: usize = number(w.next(), "the CELL_TYPES count")?;
                types = Some(c.values("int", n, "the cell types")?);
            }
            "CELL_DATA" | "POINT_DATA" => {
                in_cell_data = key == "CELL_DATA";
                cell_count = number(w.next(), "the data count")?;
            }
            "SCALARS" => {
                let name = w.next().unwrap_or("");
                let ty = w.next().unwrap_or("float");
                let comps: usize = w
                    .next()
                    .map_or(Ok(1), |x| number(Some(x), "the components"))?;
                let save = c.at;
                if !c.keyword_line().unwrap_or("").starts_with("LOOKUP_TABLE") {
                    c.at = save;
                }
                let v = c.values(ty, cell_count.saturating_mul(comps), "a SCALARS array")?;
                if in_cell_data && name == "region" && comps == 1 {
                    region = Some(v);
                }
            }
            "FIELD" => {
                let arrays: usize = number(w.nth(1), "the FIELD array count")?;
                for _ in 0..arrays {
                    let head = c.keyword_line().unwrap_or("");
                    let mut h = head.split_whitespace();
                    let name = h.next().unwrap_or("");
                    let comps: usize = number(h.next(), "a FIELD array's components")?;
                    let tuples: usize = number(h.next(), "a FIELD array's tuples")?;
                    let ty = h.next().unwrap_or("float");
                    let v = c.values(ty, comps.saturating_mul(tuples), "a FIELD array")?;
                    if in_cell_data && name == "region" && comps == 1 {
                        region = Some(v);
                    }
                    skip_metadata(&mut c);
                }
            }
            "METADATA" => skip_metadata_body(&mut c),
            "VECTORS" | "NORMALS" => {
                let ty = w.nth(1).unwrap_or("float");
                c.values(ty, cell_count.saturating_mul(3), "a VECTORS array")?;
            }
            _ => {
                return Err(format_error(format!(
                    "unknown keyword `{}`",
                    key.chars().take(40).collect::<String>()
                )));
            }
        }
    }
    let points = points.ok_or_else(|| format_error("no POINTS"))?;
    let cells = cells.ok_or_else(|| format_error("no CELLS"))?;
    let types = types.ok_or_else(|| format_error("no CELL_TYPES"))?;
    if types.len() != cells.len() {
        return Err(format_error(format!(
            "{} CELL_TYPES for {} CELLS",
            types.len(),
            cells.len()
        )));
    }
    let cells = types
        .iter()
        .zip(cells)
        .map(|(&t, ids)| (u8::try_from(t as i64).unwrap_or(u8::MAX), ids))
        .collect();
    Grid {
        points,
        cells,
        region,
    }
    .into_mesh()
}

/// Skips a `METADATA` block that may follow an array (up to its blank line).
fn skip_metadata(c: &mut Legacy<'_>) {
    let save = c.at;
    match c.keyword_line() {
        Some("METADATA") => skip_metadata_body(c),
        _ => c.at = save,
    }
}

/// Skips the body of a `METADATA` block: lines up to the first blank one.
fn skip_metadata_body(c: &mut Legacy<'_>) {
    while let Some(l) = c.line() {
        if l.trim().is_empty() {
            break;
        }
    }
}

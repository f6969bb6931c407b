//! Gmsh `.msh` version 4.1 import (ASCII and binary, through `mshio`) and export.
//!
//! Only 4-node tetrahedra (element type 4) are read; every other element block (points, lines,
//! triangles, …) is ignored — the surface is extracted from the tetrahedra
//! ([`TetMesh::surface_triangles`]). Nodes that no tetrahedron uses are dropped and the rest
//! renumbered 0-based in file order. Elements of negative orientation are reordered (Gmsh does
//! not guarantee an orientation); the result is then validated.
//!
//! Node tags: when the file's tags are dense (`max − min + 1 == count`), `mshio` does not keep
//! them and they are taken as `min_tag, min_tag + 1, …` in file order (what Gmsh writes).

use super::{MeshError, TetMesh, signed_volume};
use nalgebra::Vector3;
use std::fmt;
use std::io::Write;
use std::path::Path;

/// Why a Gmsh file could not be read or written.
#[derive(Debug)]
#[non_exhaustive]
pub enum GmshError {
    /// Reading or writing the file failed.
    Io(std::io::Error),
    /// `mshio` could not parse the file (message from the parser).
    Parse(String),
    /// The file has no node section.
    NoNodes,
    /// The file has no 4-node tetrahedron.
    NoTetrahedra,
    /// A tetrahedron references a node tag that no node block defines.
    UnknownNodeTag {
        /// Tag of the element in the file.
        element_tag: u64,
        /// The missing node tag.
        node_tag: u64,
    },
    /// The mesh read is invalid.
    Mesh(MeshError),
    /// A section's header count differs from what the section holds.
    CountMismatch {
        /// `$Nodes` or `$Elements`.
        section: &'static str,
        /// The header's count.
        header: u64,
        /// What the blocks hold.
        found: u64,
    },
}

/// Largest Gmsh file read [bytes] (1 GiB: about 20 million nodes in ASCII).
pub const MAX_FILE_BYTES: u64 = 1 << 30;

impl fmt::Display for GmshError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Io(e) => write!(f, "gmsh file I/O: {e}"),
            Self::Parse(m) => write!(f, "gmsh file could not be parsed: {m}"),
            Self::NoNodes => write!(f, "gmsh file has no $Nodes section"),
            Self::NoTetrahedra => write!(f, "gmsh file has no 4-node tetrahedron (element type 4)"),
            Self::UnknownNodeTag {
                element_tag,
                node_tag,
            } => {
                write!(
                    f,
                    "gmsh element {element_tag} references unknown node tag {node_tag}"
                )
            }
            Self::Mesh(e) => write!(f, "gmsh mesh is invalid: {e}"),
            Self::CountMismatch {
                section,
                header,
                found,
            } => write!(
                f,
                "gmsh {section} header counts {header} entries but its blocks hold {found}"
            ),
        }
    }
}

impl std::error::Error for GmshError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Self::Io(e) => Some(e),
            Self::Mesh(e) => Some(e),
            _ => None,
        }
    }
}

impl From<std::io::Error> for GmshError {
    fn from(e: std::io::Error) -> Self {
        Self::Io(e)
    }
}

/// Reads a Gmsh 4.1 tetrahedral mesh (ASCII or binary) from a file; coordinates are taken as mm.
///
/// # Errors
/// [`GmshError`] on I/O, parse, missing data or an invalid mesh.
pub fn read_gmsh(path: impl AsRef<Path>) -> Result<TetMesh, GmshError> {
    let bytes = crate::bounded_read::read_bounded(path.as_ref(), MAX_FILE_BYTES)?;
    read_gmsh_bytes(&bytes)
}

/// The header counts of the node and element sections against what their blocks hold.
fn check_counts(file: &mshio::MshFile<u64, i32, f64>) -> Result<(), GmshError> {
    let check = |section, header: u64, found: u64| {
        if header == found {
            Ok(())
        } else {
            Err(GmshError::CountMismatch {
                section,
                header,
                found,
            })
        }
    };
    if let Some(n) = &file.data.nodes {
        let found = n.node_blocks.iter().map(|b| b.nodes.len() as u64).sum();
        check("$Nodes", n.num_nodes, found)?;
    }
    if let Some(e) = &file.data.elements {
        let found = e
            .element_blocks
            .iter()
            .map(|b| b.elements.len() as u64)
            .sum();
        check("$Elements", e.num_elements, found)?;
    }
    Ok(())
}

/// Reads a Gmsh 4.1 tetrahedral mesh (ASCII or binary) from memory; see [`read_gmsh`].
///
/// # Errors
/// [`GmshError`] on parse, missing data or an invalid mesh.
pub fn read_gmsh_bytes(bytes: &[u8]) -> Result<TetMesh, GmshError> {
    let file = parse(bytes)?;
    check_counts(&file)?;
    let nodes = file.data.nodes.as_ref().ok_or(GmshError::NoNodes)?;
    // Node tags and positions in file order.
    let mut file_nodes: Vec<(u64, Vector3<f64>)> = Vec::new();
    let mut next_dense = nodes.min_node_tag;
    for block in &nodes.node_blocks {
        match &block.node_tags {
            Some(map) => {
                let mut by_index: Vec<(usize, u64)> =
                    map.iter().map(|(&tag, &i)| (i, tag)).collect();
                by_index.sort_unstable();
                for (i, tag) in by_index {
                    let n = &block.nodes[i];
                    file_nodes.push((tag, Vector3::new(n.x, n.y, n.z)));
                }
            }
            None => {
                for n in &block.nodes {
                    file_nodes.push((next_dense, Vector3::new(n.x, n.y, n.z)));
                    next_dense += 1;
                }
            }
        }
    }
    let slot: std::collections::HashMap<u64, usize> = file_nodes
        .iter()
        .enumerate()
        .map(|(i, (tag, _))| (*tag, i))
        .collect();
    let mut tets_file = Vec::new();
    if let Some(elements) = &file.data.elements {
        for block in &elements.element_blocks {
            if block.element_type != mshio::mshfile::ElementType::Tet4 {
                continue;
            }
            for el in &block.elements {
                let mut t = [0usize; 4];
                for (k, &tag) in el.nodes.iter().take(4).enumerate() {
                    t[k] = *slot.get(&tag).ok_or(GmshError::UnknownNodeTag {
                        element_tag: el.element_tag,
                        node_tag: tag,
                    })?;
                }
                tets_file.push(t);
            }
        }
    }
    // Keep the nodes the tetrahedra use, in file order.
    let mut new_index = vec![usize::MAX; file_nodes.len()];
    for t in &tets_file {
        for &v in t {
            new_index[v] = 0;
        }
    }
    let mut out_nodes = Vec::new();
    for (i, (_, p)) in file_nodes.iter().enumerate() {
        if new_index[i] == 0 {
            new_index[i] = out_nodes.len();
            out_nodes.push(*p);
        }
    }
    let mut tets = Vec::with_capacity(tets_file.len());
    for t in tets_file {
        let mut t = t.map(|v| new_index[v]);
        if signed_volume(
            &out_nodes[t[0]],
            &out_nodes[t[1]],
            &out_nodes[t[2]],
            &out_nodes[t[3]],
        ) < 0.0
        {
            t.swap(2, 3);
        }
        tets.push(t);
    }
    if tets.is_empty() {
        return Err(GmshError::NoTetrahedra);
    }
    TetMesh::try_new(out_nodes, tets).map_err(GmshError::Mesh)
}

/// The data size a `$MeshFormat` header declares (the size of `size_t` in a binary file), when
/// it can be read.
fn declared_data_size(bytes: &[u8]) -> Option<u64> {
    let head = &bytes[..bytes.len().min(256)];
    let text = String::from_utf8_lossy(head);
    let mut lines = text.lines().map(str::trim).skip_while(|l| l.is_empty());
    if lines.next()? != "$MeshFormat" {
        return None;
    }
    lines.next()?.split_whitespace().nth(2)?.parse().ok()
}

/// The file parsed by mshio. A data size other than 4 or 8 bytes is refused first (mshio 0.4.2
/// panics on it), and a panic of the parser on other hostile input is turned into an error.
fn parse(bytes: &[u8]) -> Result<mshio::MshFile<u64, i32, f64>, GmshError> {
    if let Some(n) = declared_data_size(bytes)
        && n != 4
        && n != 8
    {
        return Err(GmshError::Parse(format!(
            "$MeshFormat declares a data size of {n} bytes (4 or 8 are read)"
        )));
    }
    std::panic::catch_unwind(|| mshio::parse_msh_bytes(bytes))
        .map_err(|_| GmshError::Parse("the Gmsh parser failed on this file".to_owned()))?
        .map_err(|e| GmshError::Parse(parse_message(&e)))
}

/// The first line of a parser error (its trace and the hex dump of the input are dropped).
fn parse_message(e: &impl fmt::Display) -> String {
    let text = e.to_string();
    let line = text
        .lines()
        .map(str::trim)
        .find(|l| !l.is_empty())
        .unwrap_or("");
    line.chars().take(200).collect()
}

/// Writes `mesh` as a Gmsh 4.1 ASCII file (one volume entity, node tags `1..=n`, element tags
/// `1..=m`, coordinates with 17 significant digits so they read back exactly).
///
/// # Errors
/// I/O errors of `out`.
pub fn write_gmsh_ascii(mesh: &TetMesh, mut out: impl Write) -> Result<(), GmshError> {
    let n = mesh.nodes.len();
    let m = mesh.tets.len();
    let mut s = String::with_capacity(64 * (n + m) + 256);
    use std::fmt::Write as _;
    let _ = writeln!(s, "$MeshFormat\n4.1 0 8\n$EndMeshFormat");
    let _ = writeln!(s, "$Nodes\n1 {n} 1 {n}\n3 1 0 {n}");
    for i in 1..=n {
        let _ = writeln!(s, "{i}");
    }
    for p in &mesh.nodes {
        let _ = writeln!(s, "{:.17e} {:.17e} {:.17e}", p.x, p.y, p.z);
    }
    let _ = writeln!(s, "$EndNodes\n$Elements\n1 {m} 1 {m}\n3 1 4 {m}");
    for (e, t) in mesh.tets.iter().enumerate() {
        let _ = writeln!(
            s,
            "{} {} {} {} {}",
            e + 1,
            t[0] + 1,
            t[1] + 1,
            t[2] + 1,
            t[3] + 1
        );
    }
    let _ = writeln!(s, "$EndElements");
    out.write_all(s.as_bytes())?;
    Ok(())
}

/// Writes `mesh` as a Gmsh 4.1 binary file (little endian, 8-byte `size_t`); same content as
/// [`write_gmsh_ascii`].
///
/// # Errors
/// I/O errors of `out`.
pub fn write_gmsh_binary(mesh: &TetMesh, mut out: impl Write) -> Result<(), GmshError> {
    let n = mesh.nodes.len() as u64;
    let m = mesh.tets.len() as u64;
    let mut b: Vec<u8> = Vec::with_capacity(32 * (n + m) as usize + 256);
    let sz = |b: &mut Vec<u8>, v: u64| b.extend_from_slice(&v.to_le_bytes());
    let int = |b: &mut Vec<u8>, v: i32| b.extend_from_slice(&v.to_le_bytes());
    b.extend_from_slice(b"$MeshFormat\n4.1 1 8\n");
    int(&mut b, 1);
    b.extend_from_slice(b"\n$EndMeshFormat\n$Nodes\n");
    for v in [1, n, 1, n] {
        sz(&mut b, v);
    }
    int(&mut b, 3);
    int(&mut b, 1);
    int(&mut b, 0);
    sz(&mut b, n);
    for i in 1..=n {
        sz(&mut b, i);
    }
    for p in &mesh.nodes {
        for c in [p.x, p.y, p.z] {
            b.extend_from_slice(&c.to_le_bytes());
        }
    }
    b.extend_from_slice(b"\n$EndNodes\n$Elements\n");
    for v in [1, m, 1, m] {
        sz(&mut b, v);
    }
    int(&mut b, 3);
    int(&mut b, 1);
    int(&mut b, 4);
    sz(&mut b, m);
    for (e, t) in mesh.tets.iter().enumerate() {
        sz(&mut b, e as u64 + 1);
        for &v in t {
            sz(&mut b, v as u64 + 1);
        }
    }
    b.extend_from_slice(b"\n$EndElements\n");
    out.write_all(&b)?;
    Ok(())
}

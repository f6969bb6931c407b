//! Gmsh `.msh` import, versions 4.1 (through `mshio`) and 2.2 ([`super::gmsh2`]), ASCII and
//! binary, and export (4.1).
//!
//! Only 4-node tetrahedra (element type 4) are read; elements of lower dimension (points, lines,
//! triangles, …) are ignored — the surface is extracted from the tetrahedra
//! ([`TetMesh::surface_triangles`]) — and any other volume element (a hexahedron, a 10-node
//! tetrahedron, …) is refused, naming it. Nodes that no tetrahedron uses are dropped and the
//! rest renumbered 0-based in file order. Elements of negative orientation are reordered (Gmsh
//! does not guarantee an orientation); the result is then validated, and an invalid element is
//! named by its tag in the file.
//!
//! Regions: each tetrahedron's region ([`TetMesh::regions`]) is the physical tag of its volume
//! entity (4.1: from `$Entities`; 2.2: the element's first tag), 0 when it has none. A volume
//! entity in more than one physical group is refused (its material would be ambiguous).
//!
//! Node tags: when the file's tags are dense (`max − min + 1 == count`), `mshio` does not keep
//! them and they are taken as `min_tag, min_tag + 1, …` in file order (what Gmsh writes).

use super::{MeshError, TetMesh};
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
    /// An element of the file is invalid (degenerate, a node out of range, tangled, …).
    Element {
        /// Tag of the element in the file.
        element_tag: u64,
        /// What is wrong with it.
        error: MeshError,
    },
    /// A volume element that is not a 4-node tetrahedron.
    NotTetrahedral {
        /// Tag of the (first such) element in the file.
        element_tag: u64,
        /// Its type.
        kind: String,
    },
    /// A volume entity belongs to more than one physical group: its region is ambiguous.
    AmbiguousRegion {
        /// Tag of the volume entity.
        entity: i32,
        /// Its physical tags.
        tags: Vec<i32>,
    },
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
            Self::Element { element_tag, error } => {
                write!(f, "gmsh element {element_tag} is invalid: {error}")
            }
            Self::NotTetrahedral { element_tag, kind } => write!(
                f,
                "gmsh element {element_tag} is a {kind}, not a 4-node tetrahedron (only linear tetrahedra are read)"
            ),
            Self::AmbiguousRegion { entity, tags } => write!(
                f,
                "gmsh volume {entity} is in {} physical groups {tags:?}: its region is ambiguous (put it in one)",
                tags.len()
            ),
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
            Self::Mesh(e) | Self::Element { error: e, .. } => Some(e),
            _ => None,
        }
    }
}

impl From<std::io::Error> for GmshError {
    fn from(e: std::io::Error) -> Self {
        Self::Io(e)
    }
}

/// Reads a Gmsh 2.2 or 4.1 tetrahedral mesh (ASCII or binary) from a file; coordinates are
/// taken as mm.
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

/// Reads a Gmsh tetrahedral mesh (format 2.2 or 4.1, ASCII or binary) from memory; see
/// [`read_gmsh`].
///
/// # Errors
/// [`GmshError`] on parse, missing data or an invalid mesh.
pub fn read_gmsh_bytes(bytes: &[u8]) -> Result<TetMesh, GmshError> {
    let raw = if declared_version(bytes).is_some_and(|v| v.starts_with('2')) {
        super::gmsh2::parse(bytes)?
    } else {
        parse_v4(bytes)?
    };
    raw.into_mesh()
}

/// What a Gmsh file holds, in file order, before renumbering: nodes by tag, tetrahedra by the
/// node tags they use, with their element tag and region.
#[derive(Default)]
pub(super) struct RawGmsh {
    /// Node tags and positions [mm].
    pub nodes: Vec<(u64, Vector3<f64>)>,
    /// Element tag, node tags and physical tag (0: none) of each 4-node tetrahedron.
    pub tets: Vec<(u64, [u64; 4], i32)>,
}

impl RawGmsh {
    /// The mesh: nodes that no tetrahedron uses dropped, the rest renumbered in file order,
    /// elements oriented positively, then validated (an invalid element named by its tag).
    fn into_mesh(self) -> Result<TetMesh, GmshError> {
        let slot: std::collections::HashMap<u64, usize> = self
            .nodes
            .iter()
            .enumerate()
            .map(|(i, (tag, _))| (*tag, i))
            .collect();
        let mut tets = Vec::with_capacity(self.tets.len());
        let mut regions = Vec::with_capacity(self.tets.len());
        let mut element_tags = Vec::with_capacity(self.tets.len());
        for (element_tag, nodes, region) in &self.tets {
            let mut t = [0usize; 4];
            for (k, tag) in nodes.iter().enumerate() {
                t[k] = *slot.get(tag).ok_or(GmshError::UnknownNodeTag {
                    element_tag: *element_tag,
                    node_tag: *tag,
                })?;
            }
            tets.push(t);
            regions.push(*region);
            element_tags.push(*element_tag);
        }
        if tets.is_empty() {
            return Err(GmshError::NoTetrahedra);
        }
        let positions = self.nodes.into_iter().map(|(_, p)| p).collect();
        super::compact_oriented(positions, tets, regions).map_err(|e| match e.element() {
            Some(i) => GmshError::Element {
                element_tag: element_tags[i],
                error: e,
            },
            None => GmshError::Mesh(e),
        })
    }
}

/// A Gmsh 4.1 file (through mshio): nodes, and the tetrahedra with the physical tag of their
/// volume entity.
fn parse_v4(bytes: &[u8]) -> Result<RawGmsh, GmshError> {
    let file = parse(bytes)?;
    check_counts(&file)?;
    let nodes = file.data.nodes.as_ref().ok_or(GmshError::NoNodes)?;
    let mut raw = RawGmsh::default();
    let mut next_dense = nodes.min_node_tag;
    for block in &nodes.node_blocks {
        match &block.node_tags {
            Some(map) => {
                let mut by_index: Vec<(usize, u64)> =
                    map.iter().map(|(&tag, &i)| (i, tag)).collect();
                by_index.sort_unstable();
                for (i, tag) in by_index {
                    let n = &block.nodes[i];
                    raw.nodes.push((tag, Vector3::new(n.x, n.y, n.z)));
                }
            }
            None => {
                for n in &block.nodes {
                    raw.nodes.push((next_dense, Vector3::new(n.x, n.y, n.z)));
                    next_dense += 1;
                }
            }
        }
    }
    let volumes: &[mshio::mshfile::Volume<i32, f64>] = file
        .data
        .entities
        .as_ref()
        .map_or(&[], |e| e.volumes.as_slice());
    if let Some(elements) = &file.data.elements {
        for block in &elements.element_blocks {
            if block.element_type != mshio::mshfile::ElementType::Tet4 {
                if block.entity_dim == 3
                    && let Some(el) = block.elements.first()
                {
                    return Err(GmshError::NotTetrahedral {
                        element_tag: el.element_tag,
                        kind: volume_name(&format!("{:?}", block.element_type)),
                    });
                }
                continue;
            }
            let region = match volumes.iter().find(|v| v.tag == block.entity_tag) {
                None => 0,
                Some(v) => match v.physical_tags.as_slice() {
                    [] => 0,
                    [t] => *t,
                    more => {
                        return Err(GmshError::AmbiguousRegion {
                            entity: block.entity_tag,
                            tags: more.to_vec(),
                        });
                    }
                },
            };
            for el in &block.elements {
                if el.nodes.len() < 4 {
                    return Err(GmshError::Parse(format!(
                        "element {} has {} nodes (a tetrahedron has 4)",
                        el.element_tag,
                        el.nodes.len()
                    )));
                }
                let t = [el.nodes[0], el.nodes[1], el.nodes[2], el.nodes[3]];
                raw.tets.push((el.element_tag, t, region));
            }
        }
    }
    Ok(raw)
}

/// A readable name of a volume element type from mshio's name (`Hex8`, `Prism6`, `Tet10`, …).
fn volume_name(kind: &str) -> String {
    if kind.starts_with("Hex") {
        "hexahedron".to_owned()
    } else if kind.starts_with("Prism") {
        "prism".to_owned()
    } else if kind.starts_with("Pyr") {
        "pyramid".to_owned()
    } else if let Some(n) = kind.strip_prefix("Tet") {
        format!("{n}-node tetrahedron")
    } else {
        format!("volume element of type {kind}")
    }
}

/// The version a `$MeshFormat` header declares (e.g. `"2.2"`, `"4.1"`), when it can be read.
fn declared_version(bytes: &[u8]) -> Option<String> {
    header_field(bytes, 0).map(str::to_owned)
}

/// The data size a `$MeshFormat` header declares (the size of `size_t` in a binary file), when
/// it can be read.
fn declared_data_size(bytes: &[u8]) -> Option<u64> {
    header_field(bytes, 2)?.parse().ok()
}

/// Field `index` of the line after `$MeshFormat` (version, file type, data size).
fn header_field(bytes: &[u8], index: usize) -> Option<&str> {
    let head = &bytes[..bytes.len().min(256)];
    let text = std::str::from_utf8(head)
        .or_else(|e| std::str::from_utf8(&head[..e.valid_up_to()]))
        .ok()?;
    let mut lines = text.lines().map(str::trim).skip_while(|l| l.is_empty());
    if lines.next()? != "$MeshFormat" {
        return None;
    }
    lines.next()?.split_whitespace().nth(index)
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

/// The mesh's region tags in order of first appearance (volume entity `k + 1` holds region
/// `k`), and the runs of consecutive elements of one region: `(entity, first, end)`.
fn region_blocks(mesh: &TetMesh) -> (Vec<i32>, Vec<(usize, usize, usize)>) {
    let mut tags: Vec<i32> = Vec::new();
    let mut runs: Vec<(usize, usize, usize)> = Vec::new();
    for (e, r) in mesh.regions.iter().enumerate() {
        let entity = match tags.iter().position(|t| t == r) {
            Some(k) => k + 1,
            None => {
                tags.push(*r);
                tags.len()
            }
        };
        match runs.last_mut() {
            Some(run) if run.0 == entity => run.2 = e + 1,
            _ => runs.push((entity, e, e + 1)),
        }
    }
    (tags, runs)
}

/// Writes `mesh` as a Gmsh 4.1 ASCII file: one volume entity per region, in the physical group
/// of its tag (none for region 0), node tags `1..=n` (one block), element tags `1..=m` in the
/// mesh's order (a block per run of one region), coordinates with 17 significant digits so they
/// read back exactly.
///
/// # Errors
/// I/O errors of `out`.
pub fn write_gmsh_ascii(mesh: &TetMesh, mut out: impl Write) -> Result<(), GmshError> {
    let n = mesh.nodes.len();
    let m = mesh.tets.len();
    let (tags, runs) = region_blocks(mesh);
    let (lo, hi) = mesh.bounds();
    let mut s = String::with_capacity(64 * (n + m) + 256);
    use std::fmt::Write as _;
    let _ = writeln!(s, "$MeshFormat\n4.1 0 8\n$EndMeshFormat");
    let _ = writeln!(s, "$Entities\n0 0 0 {}", tags.len());
    for (k, r) in tags.iter().enumerate() {
        let physical = if *r == 0 {
            "0".to_owned()
        } else {
            format!("1 {r}")
        };
        let _ = writeln!(
            s,
            "{} {:.17e} {:.17e} {:.17e} {:.17e} {:.17e} {:.17e} {physical} 0",
            k + 1,
            lo.x,
            lo.y,
            lo.z,
            hi.x,
            hi.y,
            hi.z
        );
    }
    let _ = writeln!(s, "$EndEntities");
    let _ = writeln!(s, "$Nodes\n1 {n} 1 {n}\n3 1 0 {n}");
    for i in 1..=n {
        let _ = writeln!(s, "{i}");
    }
    for p in &mesh.nodes {
        let _ = writeln!(s, "{:.17e} {:.17e} {:.17e}", p.x, p.y, p.z);
    }
    let _ = writeln!(s, "$EndNodes\n$Elements\n{} {m} 1 {m}", runs.len());
    for (entity, first, end) in runs {
        let _ = writeln!(s, "3 {entity} 4 {}", end - first);
        for (e, t) in mesh.tets.iter().enumerate().take(end).skip(first) {
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
    let (tags, runs) = region_blocks(mesh);
    let (lo, hi) = mesh.bounds();
    let mut b: Vec<u8> = Vec::with_capacity(32 * (n + m) as usize + 256);
    let sz = |b: &mut Vec<u8>, v: u64| b.extend_from_slice(&v.to_le_bytes());
    let int = |b: &mut Vec<u8>, v: i32| b.extend_from_slice(&v.to_le_bytes());
    let real = |b: &mut Vec<u8>, v: f64| b.extend_from_slice(&v.to_le_bytes());
    b.extend_from_slice(b"$MeshFormat\n4.1 1 8\n");
    int(&mut b, 1);
    b.extend_from_slice(b"\n$EndMeshFormat\n$Entities\n");
    for v in [0, 0, 0, tags.len() as u64] {
        sz(&mut b, v);
    }
    for (k, r) in tags.iter().enumerate() {
        int(&mut b, k as i32 + 1);
        for c in [lo.x, lo.y, lo.z, hi.x, hi.y, hi.z] {
            real(&mut b, c);
        }
        if *r == 0 {
            sz(&mut b, 0);
        } else {
            sz(&mut b, 1);
            int(&mut b, *r);
        }
        sz(&mut b, 0);
    }
    b.extend_from_slice(b"\n$EndEntities\n$Nodes\n");
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
            real(&mut b, c);
        }
    }
    b.extend_from_slice(b"\n$EndNodes\n$Elements\n");
    for v in [runs.len() as u64, m, 1, m] {
        sz(&mut b, v);
    }
    for (entity, first, end) in runs {
        int(&mut b, 3);
        int(&mut b, entity as i32);
        int(&mut b, 4);
        sz(&mut b, (end - first) as u64);
        for (e, t) in mesh.tets.iter().enumerate().take(end).skip(first) {
            sz(&mut b, e as u64 + 1);
            for &v in t {
                sz(&mut b, v as u64 + 1);
            }
        }
    }
    b.extend_from_slice(b"\n$EndElements\n");
    out.write_all(&b)?;
    Ok(())
}

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
    /// A surface element that is not a 3-node triangle (reading a surface).
    NotTriangle {
        /// Tag of the element in the file.
        element_tag: u64,
        /// Its type, in words.
        kind: String,
    },
    /// The file (or the physical group chosen) has no surface element.
    NoSurface {
        /// The physical group chosen, if any.
        group: Option<PhysicalGroup>,
    },
    /// The physical group chosen is not a physical surface group of the file.
    UnknownGroup {
        /// The group chosen.
        group: PhysicalGroup,
        /// The file's physical surface groups.
        available: Vec<(i32, Option<String>)>,
    },
    /// The file's surface elements lie in several physical groups and none was chosen.
    SeveralSurfaces {
        /// The file's physical surface groups.
        available: Vec<(i32, Option<String>)>,
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
            Self::NotTriangle { element_tag, kind } => write!(
                f,
                "gmsh element {element_tag} is a {kind}, not a 3-node triangle (a surface is read from linear triangles only)"
            ),
            Self::NoSurface { group: None } => write!(
                f,
                "gmsh file has no surface element (a 3-node triangle, element type 2)"
            ),
            Self::NoSurface { group: Some(g) } => {
                write!(f, "gmsh {g} has no surface element")
            }
            Self::UnknownGroup { group, available } => write!(
                f,
                "gmsh file has no {group} of surface elements; its physical surface groups: {}",
                group_list(available)
            ),
            Self::SeveralSurfaces { available } => write!(
                f,
                "gmsh file holds {} physical surface groups ({}): choose one with the obstacle's `physical_group` (its tag or name)",
                available.len(),
                group_list(available)
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

/// `1 (`lesion`), 2` — the groups of a message, or `none`.
fn group_list(groups: &[(i32, Option<String>)]) -> String {
    if groups.is_empty() {
        return "none".to_owned();
    }
    groups
        .iter()
        .map(|(t, n)| match n {
            Some(n) => format!("{t} (`{n}`)"),
            None => t.to_string(),
        })
        .collect::<Vec<_>>()
        .join(", ")
}

/// A physical group of a Gmsh file, by its tag or its name (`$PhysicalNames`); in a scene, an
/// integer or a string.
#[derive(Clone, Debug, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(untagged)]
pub enum PhysicalGroup {
    /// The group's tag.
    Tag(i32),
    /// The group's name.
    Name(String),
}

impl fmt::Display for PhysicalGroup {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Tag(t) => write!(f, "physical group {t}"),
            Self::Name(n) => write!(f, "physical group `{n}`"),
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

/// A triangulated surface read from a Gmsh file: the nodes its triangles use (in file order)
/// and the triangles (in file order), each with its tag in the file.
#[derive(Clone, Debug, PartialEq)]
pub struct GmshSurface {
    /// Node positions [mm].
    pub nodes: Vec<Vector3<f64>>,
    /// The Gmsh tag of each node.
    pub node_tags: Vec<u64>,
    /// Triangles as indices into `nodes`, in the file's node order.
    pub triangles: Vec<[usize; 3]>,
    /// The Gmsh tag of each triangle.
    pub element_tags: Vec<u64>,
}

/// Reads the triangles of a Gmsh 2.2 or 4.1 file (ASCII or binary), all of them or those of
/// one physical surface group; see [`read_gmsh_surface_bytes`].
///
/// # Errors
/// [`GmshError`] naming the element at fault and the reason.
pub fn read_gmsh_surface(
    path: impl AsRef<Path>,
    group: Option<&PhysicalGroup>,
) -> Result<GmshSurface, GmshError> {
    let bytes = crate::bounded_read::read_bounded(path.as_ref(), MAX_FILE_BYTES)?;
    read_gmsh_surface_bytes(&bytes, group)
}

/// Reads the surface (2-D) elements of a Gmsh file from memory, through the same parsers as
/// the tetrahedral meshes. Points, lines and volume elements are ignored. With `group`, the
/// elements of that physical surface group (by tag, or by name through `$PhysicalNames`);
/// without it, every surface element, unless they lie in more than one physical group (then
/// the choice is the caller's: [`GmshError::SeveralSurfaces`]). Every element read must be a
/// 3-node triangle.
///
/// # Errors
/// [`GmshError`]: parse errors, [`GmshError::NotTriangle`], [`GmshError::NoSurface`],
/// [`GmshError::UnknownGroup`], [`GmshError::SeveralSurfaces`],
/// [`GmshError::UnknownNodeTag`].
pub fn read_gmsh_surface_bytes(
    bytes: &[u8],
    group: Option<&PhysicalGroup>,
) -> Result<GmshSurface, GmshError> {
    let raw = if declared_version(bytes).is_some_and(|v| v.starts_with('2')) {
        super::gmsh2::parse(bytes)?
    } else {
        parse_v4(bytes)?
    };
    let names = physical_names(bytes)?;
    let name_of = |tag: i32| {
        names
            .iter()
            .find(|(d, t, _)| *d == 2 && *t == tag)
            .map(|(_, _, n)| n.clone())
    };
    let mut tags: Vec<i32> = raw.faces.iter().flat_map(|f| f.groups.clone()).collect();
    tags.extend(names.iter().filter(|(d, _, _)| *d == 2).map(|(_, t, _)| *t));
    tags.sort_unstable();
    tags.dedup();
    let available: Vec<(i32, Option<String>)> = tags.iter().map(|&t| (t, name_of(t))).collect();
    let chosen = match group {
        None => {
            let used = raw
                .faces
                .iter()
                .flat_map(|f| f.groups.iter().copied())
                .collect::<std::collections::BTreeSet<_>>();
            if used.len() > 1 {
                return Err(GmshError::SeveralSurfaces {
                    available: used.iter().map(|&t| (t, name_of(t))).collect(),
                });
            }
            None
        }
        Some(g) => {
            let tag = match g {
                PhysicalGroup::Tag(t) => Some(*t),
                PhysicalGroup::Name(n) => names
                    .iter()
                    .find(|(d, _, m)| *d == 2 && m == n)
                    .map(|(_, t, _)| *t),
            };
            match tag {
                Some(t) if tags.contains(&t) => Some(t),
                _ => {
                    return Err(GmshError::UnknownGroup {
                        group: g.clone(),
                        available,
                    });
                }
            }
        }
    };
    let faces: Vec<&RawFace> = raw
        .faces
        .iter()
        .filter(|f| chosen.is_none_or(|t| f.groups.contains(&t)))
        .collect();
    if faces.is_empty() {
        return Err(GmshError::NoSurface {
            group: group.cloned(),
        });
    }
    if let Some(f) = faces.iter().find(|f| f.kind != 2 || f.nodes.len() != 3) {
        return Err(GmshError::NotTriangle {
            element_tag: f.element_tag,
            kind: face_name(f.kind),
        });
    }
    let slot: std::collections::HashMap<u64, usize> = raw
        .nodes
        .iter()
        .enumerate()
        .map(|(i, (tag, _))| (*tag, i))
        .collect();
    // The nodes the triangles use, in the file's node order.
    let mut used = vec![usize::MAX; raw.nodes.len()];
    let mut file_triangles = Vec::with_capacity(faces.len());
    for f in &faces {
        let mut t = [0usize; 3];
        for (k, tag) in f.nodes.iter().enumerate() {
            t[k] = *slot.get(tag).ok_or(GmshError::UnknownNodeTag {
                element_tag: f.element_tag,
                node_tag: *tag,
            })?;
            used[t[k]] = 0;
        }
        file_triangles.push(t);
    }
    let (mut nodes, mut node_tags) = (Vec::new(), Vec::new());
    for (i, (tag, p)) in raw.nodes.iter().enumerate() {
        if used[i] == 0 {
            used[i] = nodes.len();
            nodes.push(*p);
            node_tags.push(*tag);
        }
    }
    Ok(GmshSurface {
        nodes,
        node_tags,
        triangles: file_triangles.iter().map(|t| t.map(|i| used[i])).collect(),
        element_tags: faces.iter().map(|f| f.element_tag).collect(),
    })
}

/// A readable name of a surface element type (Gmsh type numbers).
fn face_name(kind: i32) -> String {
    match kind {
        2 => "3-node triangle".to_owned(),
        3 => "4-node quadrangle".to_owned(),
        9 => "6-node triangle".to_owned(),
        10 => "9-node quadrangle".to_owned(),
        16 => "8-node quadrangle".to_owned(),
        20 => "9-node triangle".to_owned(),
        21 => "10-node triangle".to_owned(),
        k => format!("surface element of type {k}"),
    }
}

/// The `$PhysicalNames` section, `(dimension, tag, name)` per entry (empty without one). The
/// section is text in ASCII and binary files alike, written before the node and element data;
/// it is looked for at the start of a line before `$Nodes`.
fn physical_names(bytes: &[u8]) -> Result<Vec<(i32, i32, String)>, GmshError> {
    let find = |what: &[u8]| {
        bytes
            .windows(what.len())
            .position(|w| w == what)
            .map(|i| i + 1)
    };
    let Some(start) = find(b"\n$PhysicalNames") else {
        return Ok(Vec::new());
    };
    if find(b"\n$Nodes").is_some_and(|n| n < start) {
        return Ok(Vec::new());
    }
    let end = bytes[start..]
        .windows(b"$EndPhysicalNames".len())
        .position(|w| w == b"$EndPhysicalNames")
        .ok_or_else(|| GmshError::Parse("$PhysicalNames has no $EndPhysicalNames".into()))?;
    let text = std::str::from_utf8(&bytes[start..start + end])
        .map_err(|_| GmshError::Parse("$PhysicalNames is not text".into()))?;
    let mut lines = text
        .lines()
        .skip(1)
        .map(str::trim)
        .filter(|l| !l.is_empty());
    let bad = |l: &str| {
        GmshError::Parse(format!(
            "$PhysicalNames: `{}` is not `dimension tag \"name\"`",
            l.chars().take(60).collect::<String>()
        ))
    };
    let n: usize = match lines.next() {
        Some(l) => l.parse().map_err(|_| bad(l))?,
        None => 0,
    };
    let mut out = Vec::new();
    for l in lines {
        let mut it = l.splitn(3, char::is_whitespace);
        let (Some(d), Some(t), Some(name)) = (it.next(), it.next(), it.next()) else {
            return Err(bad(l));
        };
        let (Ok(d), Ok(t)) = (d.parse(), t.parse()) else {
            return Err(bad(l));
        };
        let name = name.trim();
        let name = name
            .strip_prefix('"')
            .and_then(|s| s.strip_suffix('"'))
            .unwrap_or(name);
        out.push((d, t, name.to_owned()));
    }
    if out.len() != n {
        return Err(GmshError::CountMismatch {
            section: "$PhysicalNames",
            header: n as u64,
            found: out.len() as u64,
        });
    }
    Ok(out)
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
    /// Why the file's volume elements cannot make a tetrahedral mesh (the first volume element
    /// that is not a 4-node tetrahedron, or a volume in two physical groups), kept for
    /// [`RawGmsh::into_mesh`]: a surface read from the same file does not need the volumes.
    pub volume_error: Option<GmshError>,
    /// The surface (2-D) elements, in file order.
    pub faces: Vec<RawFace>,
}

/// A surface (2-D) element as the file gives it.
pub(super) struct RawFace {
    /// Tag of the element in the file.
    pub element_tag: u64,
    /// Gmsh element type (2: the 3-node triangle).
    pub kind: i32,
    /// Node tags.
    pub nodes: Vec<u64>,
    /// Physical groups it belongs to (4.1: those of its surface entity; 2.2: its first tag,
    /// unless 0).
    pub groups: Vec<i32>,
}

impl RawGmsh {
    /// The mesh: nodes that no tetrahedron uses dropped, the rest renumbered in file order,
    /// elements oriented positively, then validated (an invalid element named by its tag).
    fn into_mesh(self) -> Result<TetMesh, GmshError> {
        if let Some(e) = self.volume_error {
            return Err(e);
        }
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
    let surfaces: &[mshio::mshfile::Surface<i32, f64>] = file
        .data
        .entities
        .as_ref()
        .map_or(&[], |e| e.surfaces.as_slice());
    if let Some(elements) = &file.data.elements {
        for block in &elements.element_blocks {
            if block.entity_dim == 2 {
                let groups = surfaces
                    .iter()
                    .find(|s| s.tag == block.entity_tag)
                    .map_or_else(Vec::new, |s| s.physical_tags.clone());
                for el in &block.elements {
                    raw.faces.push(RawFace {
                        element_tag: el.element_tag,
                        kind: block.element_type as i32,
                        nodes: el.nodes.clone(),
                        groups: groups.clone(),
                    });
                }
                continue;
            }
            if block.element_type != mshio::mshfile::ElementType::Tet4 {
                if block.entity_dim == 3
                    && let Some(el) = block.elements.first()
                    && raw.volume_error.is_none()
                {
                    raw.volume_error = Some(GmshError::NotTetrahedral {
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
                        if raw.volume_error.is_none() {
                            raw.volume_error = Some(GmshError::AmbiguousRegion {
                                entity: block.entity_tag,
                                tags: more.to_vec(),
                            });
                        }
                        0
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

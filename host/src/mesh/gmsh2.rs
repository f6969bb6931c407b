//! Gmsh `.msh` version 2.2 (ASCII and binary), the legacy format many tools still write
//! (meshio, older Gmsh, `-format msh22`).
//!
//! ```text
//! $MeshFormat / 2.2 file-type data-size [binary: int 1] / $EndMeshFormat
//! $Nodes / n / n × (id x y z)                                   binary: n × (int, 3 doubles)
//! $Elements / m / m × (id type ntags tag… node…)                binary: blocks of
//!     (int type, int count, int ntags), then count × (int id, ntags ints, node ints)
//! ```
//!
//! The first tag of an element is its physical group (0: none), taken as its region. Other
//! sections (`$PhysicalNames`, `$NodeData`, …) are skipped. Binary files must be little endian
//! with 8-byte reals.

use super::gmsh::{GmshError, RawFace, RawGmsh};
use nalgebra::Vector3;

/// Dimension and node count of a Gmsh element type (`None`: a type this reader does not know).
fn element_shape(kind: i32) -> Option<(u8, usize)> {
    Some(match kind {
        15 => (0, 1),
        1 => (1, 2),
        8 => (1, 3),
        2 => (2, 3),
        3 => (2, 4),
        9 => (2, 6),
        10 => (2, 9),
        16 => (2, 8),
        4 => (3, 4),
        5 => (3, 8),
        6 => (3, 6),
        7 => (3, 5),
        11 => (3, 10),
        12 => (3, 27),
        13 => (3, 18),
        14 => (3, 14),
        17 => (3, 20),
        18 => (3, 15),
        19 => (3, 13),
        _ => return None,
    })
}

/// A readable name of a volume element type.
fn element_name(kind: i32) -> String {
    match kind {
        5 | 12 | 17 => "hexahedron".to_owned(),
        6 | 13 | 18 => "prism".to_owned(),
        7 | 14 | 19 => "pyramid".to_owned(),
        11 => "10-node tetrahedron".to_owned(),
        k => format!("element of type {k}"),
    }
}

/// A cursor over the file's bytes: whitespace-separated tokens, or raw little-endian values.
struct Cursor<'a> {
    bytes: &'a [u8],
    at: usize,
}

fn parse_error(what: impl Into<String>) -> GmshError {
    GmshError::Parse(what.into())
}

impl<'a> Cursor<'a> {
    fn token(&mut self) -> Option<&'a str> {
        while self.at < self.bytes.len() && self.bytes[self.at].is_ascii_whitespace() {
            self.at += 1;
        }
        let start = self.at;
        while self.at < self.bytes.len() && !self.bytes[self.at].is_ascii_whitespace() {
            self.at += 1;
        }
        if start == self.at {
            return None;
        }
        std::str::from_utf8(&self.bytes[start..self.at]).ok()
    }

    fn number<T: std::str::FromStr>(&mut self, what: &str) -> Result<T, GmshError> {
        let t = self
            .token()
            .ok_or_else(|| parse_error(format!("the file ends before {what}")))?;
        t.parse()
            .map_err(|_| parse_error(format!("{what}: `{}` is not a number", short(t))))
    }

    fn expect(&mut self, word: &str) -> Result<(), GmshError> {
        match self.token() {
            Some(t) if t == word => Ok(()),
            Some(t) => Err(parse_error(format!(
                "expected {word}, found `{}`",
                short(t)
            ))),
            None => Err(parse_error(format!("the file ends before {word}"))),
        }
    }

    /// Skips the one newline that follows a count line before binary data.
    fn end_of_line(&mut self) {
        while self.at < self.bytes.len() && self.bytes[self.at] != b'\n' {
            self.at += 1;
        }
        self.at += 1;
    }

    fn raw<const N: usize>(&mut self, what: &str) -> Result<[u8; N], GmshError> {
        let end = self.at.checked_add(N).filter(|&e| e <= self.bytes.len());
        let end = end.ok_or_else(|| parse_error(format!("the file ends inside {what}")))?;
        let mut out = [0u8; N];
        out.copy_from_slice(&self.bytes[self.at..end]);
        self.at = end;
        Ok(out)
    }

    fn int(&mut self, what: &str) -> Result<i32, GmshError> {
        self.raw::<4>(what).map(i32::from_le_bytes)
    }

    fn real(&mut self, what: &str) -> Result<f64, GmshError> {
        self.raw::<8>(what).map(f64::from_le_bytes)
    }

    /// Moves past the line `$End<name>`.
    fn skip_section(&mut self, name: &str) -> Result<(), GmshError> {
        let end = format!("$End{name}");
        let found = self.bytes[self.at..]
            .windows(end.len())
            .position(|w| w == end.as_bytes())
            .ok_or_else(|| parse_error(format!("${name} has no {end}")))?;
        self.at += found + end.len();
        Ok(())
    }

    fn remaining(&self) -> usize {
        self.bytes.len().saturating_sub(self.at)
    }
}

fn short(t: &str) -> String {
    t.chars().take(40).collect()
}

/// A count from the file, refused when the rest of the file cannot hold that many entries of
/// at least `min_bytes` each (a forged count must not allocate gigabytes).
fn count(c: &mut Cursor<'_>, what: &str, min_bytes: usize) -> Result<usize, GmshError> {
    let n: usize = c.number(what)?;
    if n > c.remaining() / min_bytes.max(1) {
        return Err(parse_error(format!(
            "{what} is {n}, more than the rest of the file can hold"
        )));
    }
    Ok(n)
}

/// Parses a Gmsh 2.2 file (ASCII or binary).
pub(super) fn parse(bytes: &[u8]) -> Result<RawGmsh, GmshError> {
    let mut c = Cursor { bytes, at: 0 };
    c.expect("$MeshFormat")?;
    let version: String = c.number("the format version")?;
    if !version.starts_with("2.") {
        return Err(parse_error(format!("format version {version} is not 2.x")));
    }
    let binary = match c.number::<i32>("the file type")? {
        0 => false,
        1 => true,
        t => {
            return Err(parse_error(format!(
                "file type {t} is neither 0 (ASCII) nor 1 (binary)"
            )));
        }
    };
    let data_size: i32 = c.number("the data size")?;
    if binary {
        if data_size != 8 {
            return Err(parse_error(format!(
                "a binary file with {data_size}-byte reals (8 are read)"
            )));
        }
        c.end_of_line();
        if c.int("the endianness mark")? != 1 {
            return Err(parse_error(
                "the binary file is big endian (little endian is read)",
            ));
        }
    }
    c.expect("$EndMeshFormat")?;
    let mut raw = RawGmsh::default();
    let mut seen_nodes = false;
    while let Some(section) = c.token() {
        match section {
            "$Nodes" => {
                nodes(&mut c, binary, &mut raw)?;
                c.expect("$EndNodes")?;
                seen_nodes = true;
            }
            "$Elements" => {
                elements(&mut c, binary, &mut raw)?;
                c.expect("$EndElements")?;
            }
            s if s.starts_with('$') && !s.starts_with("$End") => c.skip_section(&s[1..])?,
            s => {
                return Err(parse_error(format!(
                    "unexpected `{}` between sections",
                    short(s)
                )));
            }
        }
    }
    if !seen_nodes {
        return Err(GmshError::NoNodes);
    }
    Ok(raw)
}

fn nodes(c: &mut Cursor<'_>, binary: bool, raw: &mut RawGmsh) -> Result<(), GmshError> {
    let n = count(c, "the node count", if binary { 28 } else { 8 })?;
    raw.nodes.reserve(n);
    if binary {
        c.end_of_line();
    }
    for _ in 0..n {
        let (tag, p) = if binary {
            let tag = c.int("a node tag")?;
            let p = Vector3::new(c.real("a node")?, c.real("a node")?, c.real("a node")?);
            (i64::from(tag), p)
        } else {
            let tag: i64 = c.number("a node tag")?;
            let p = Vector3::new(
                c.number("a node coordinate")?,
                c.number("a node coordinate")?,
                c.number("a node coordinate")?,
            );
            (tag, p)
        };
        let tag =
            u64::try_from(tag).map_err(|_| parse_error(format!("node tag {tag} is negative")))?;
        raw.nodes.push((tag, p));
    }
    Ok(())
}

/// One element: keeps 4-node tetrahedra, ignores lower dimensions, refuses other volumes.
fn element(
    raw: &mut RawGmsh,
    tag: i64,
    kind: i32,
    tags: &[i64],
    nodes: &[i64],
) -> Result<(), GmshError> {
    let element_tag =
        u64::try_from(tag).map_err(|_| parse_error(format!("element tag {tag} is negative")))?;
    let (dim, _) = element_shape(kind).ok_or_else(|| {
        parse_error(format!(
            "element {element_tag} has type {kind}, which is not a Gmsh 2.2 element type read here"
        ))
    })?;
    if dim == 2 {
        let nodes = nodes
            .iter()
            .map(|&v| {
                u64::try_from(v).map_err(|_| GmshError::UnknownNodeTag {
                    element_tag,
                    node_tag: v as u64,
                })
            })
            .collect::<Result<Vec<_>, _>>()?;
        let group = tags.first().copied().unwrap_or(0);
        let group = i32::try_from(group).map_err(|_| {
            parse_error(format!(
                "element {element_tag}: physical tag {group} is out of range"
            ))
        })?;
        raw.faces.push(RawFace {
            element_tag,
            kind,
            nodes,
            groups: if group == 0 { Vec::new() } else { vec![group] },
        });
        return Ok(());
    }
    if dim < 3 {
        return Ok(());
    }
    if kind != 4 {
        if raw.volume_error.is_none() {
            raw.volume_error = Some(GmshError::NotTetrahedral {
                element_tag,
                kind: element_name(kind),
            });
        }
        return Ok(());
    }
    let mut t = [0u64; 4];
    for (k, &v) in nodes.iter().take(4).enumerate() {
        t[k] = u64::try_from(v).map_err(|_| GmshError::UnknownNodeTag {
            element_tag,
            node_tag: v as u64,
        })?;
    }
    let region = tags.first().copied().unwrap_or(0);
    let region = i32::try_from(region).map_err(|_| {
        parse_error(format!(
            "element {element_tag}: physical tag {region} is out of range"
        ))
    })?;
    raw.tets.push((element_tag, t, region));
    Ok(())
}

fn elements(c: &mut Cursor<'_>, binary: bool, raw: &mut RawGmsh) -> Result<(), GmshError> {
    let m = count(c, "the element count", if binary { 8 } else { 4 })?;
    let mut tags = Vec::new();
    let mut nodes = Vec::new();
    if binary {
        c.end_of_line();
        let mut read = 0usize;
        while read < m {
            let kind = c.int("an element block header")?;
            let follow = c.int("an element block header")?;
            let ntags = c.int("an element block header")?;
            let (_, nn) = element_shape(kind)
                .ok_or_else(|| parse_error(format!("an element block has unknown type {kind}")))?;
            let follow = usize::try_from(follow)
                .ok()
                .filter(|&f| f >= 1 && f <= m - read)
                .ok_or_else(|| parse_error(format!("an element block holds {follow} elements")))?;
            let ntags = usize::try_from(ntags)
                .ok()
                .filter(|&t| t <= 64)
                .ok_or_else(|| parse_error(format!("an element block has {ntags} tags")))?;
            for _ in 0..follow {
                let tag = c.int("an element")?;
                tags.clear();
                for _ in 0..ntags {
                    tags.push(i64::from(c.int("an element's tags")?));
                }
                nodes.clear();
                for _ in 0..nn {
                    nodes.push(i64::from(c.int("an element's nodes")?));
                }
                element(raw, i64::from(tag), kind, &tags, &nodes)?;
            }
            read += follow;
        }
    } else {
        for _ in 0..m {
            let tag: i64 = c.number("an element tag")?;
            let kind: i32 = c.number("an element type")?;
            let ntags: usize = c.number("an element's tag count")?;
            if ntags > 64 {
                return Err(parse_error(format!("element {tag} has {ntags} tags")));
            }
            let (_, nn) = element_shape(kind)
                .ok_or_else(|| parse_error(format!("element {tag} has unknown type {kind}")))?;
            let what = format!("the tags and nodes of element {tag}");
            tags.clear();
            for _ in 0..ntags {
                tags.push(c.number(&what)?);
            }
            nodes.clear();
            for _ in 0..nn {
                nodes.push(c.number(&what)?);
            }
            element(raw, tag, kind, &tags, &nodes)?;
        }
    }
    Ok(())
}

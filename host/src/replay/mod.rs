//! A replay of a run that any browser opens offline: one self-contained HTML file
//! (`replay.html`) with the data embedded, showing the gel surface, the needle, the path, the
//! target and the obstacles in 3D over time, the tracking error and the run's summary.
//!
//! The types here are plain data, independent of the simulation's state: whoever records a run
//! fills a [`ReplayData`] (static data) and pushes one [`ReplayFrame`] per recorded step, then
//! calls [`write_replay`]. [`SurfaceMap`] turns the gel's boundary triangles (global node
//! indices) into the compact surface the replay stores (only the surface nodes, every frame).
//!
//! The page is the template `host/assets/replay.html` with its one placeholder ([`PLACEHOLDER`],
//! inside `<script id="replay-data" type="application/json">`) replaced by the JSON document
//! [`replay_json`] builds. Its schema, `needle.replay.v1`, is described in `docs/replay.md` and at
//! the top of the template. Float arrays are little-endian `Float32` in base64 (positions in mm:
//! a resolution of about 3e-5 mm at 300 mm); index arrays are little-endian `Uint32` in base64.
//! Non-finite positions are kept (a diverged run can be replayed); the page leaves them out.

// Units are written in brackets ([mm], [s]) as in the workspace style: not intra-doc links.
#![allow(rustdoc::broken_intra_doc_links)]

use nalgebra::Vector3;
use serde_json::{Value, json};
use std::path::Path;

/// The HTML template of the replay, with exactly one [`PLACEHOLDER`].
pub const TEMPLATE: &str = include_str!("../assets/replay.html");

/// The text of the template that [`replay_html`] replaces by the JSON document.
pub const PLACEHOLDER: &str = "/*__REPLAY_DATA__*/";

/// Name and version of the JSON schema (the document's `schema` field).
pub const SCHEMA: &str = "needle.replay.v1";

/// A sphere obstacle: its name and radius; its centre is given in every frame.
#[derive(Clone, Debug, PartialEq)]
pub struct SphereObstacle {
    /// Name shown in the page.
    pub name: String,
    /// Radius [mm].
    pub radius: f64,
}

/// An obstacle given as a triangle surface: its name and triangles; its nodes are given in every
/// frame ([`ReplayFrame::mesh_nodes`]).
#[derive(Clone, Debug, PartialEq)]
pub struct MeshObstacle {
    /// Name shown in the page.
    pub name: String,
    /// Triangles as indices into the obstacle's nodes, counter-clockwise seen from outside.
    pub triangles: Vec<[u32; 3]>,
}

/// A horizontal reference line of the error plot (e.g. the paper's bound).
#[derive(Clone, Debug, PartialEq)]
pub struct ReferenceLine {
    /// Label drawn with the line.
    pub label: String,
    /// Tracking error [mm].
    pub value: f64,
}

/// The tracking error of every step of the run (not only the recorded frames), for the plot.
/// A non-finite error (e.g. before the tip enters the gel) leaves a gap.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ErrorSeries {
    /// Step index of each sample.
    pub steps: Vec<u32>,
    /// Insertion depth of the tip below the gel surface at each sample [mm].
    pub depth: Vec<f64>,
    /// Tracking error `|tip − target|` at each sample [mm].
    pub error: Vec<f64>,
}

/// One recorded instant of the run. Every frame of a replay has the same number of surface
/// nodes, sphere centres and obstacle meshes (with the same node counts); the needle and the path
/// may change their number of points.
#[derive(Clone, Debug, PartialEq)]
pub struct ReplayFrame {
    /// Simulated time [s].
    pub time: f64,
    /// Step index.
    pub step: u32,
    /// Gel surface node positions, indexed by [`ReplayData::surface_triangles`] [mm].
    pub surface: Vec<Vector3<f64>>,
    /// Needle nodes from its base to its tip [mm].
    pub needle: Vec<Vector3<f64>>,
    /// The planned path in its current (deformed) configuration [mm].
    pub path: Vec<Vector3<f64>>,
    /// The target point the controller follows at this step [mm].
    pub target: Vector3<f64>,
    /// Centre of each sphere of [`ReplayData::spheres`], in order [mm].
    pub sphere_centres: Vec<Vector3<f64>>,
    /// Node positions of each obstacle of [`ReplayData::meshes`], in order [mm].
    pub mesh_nodes: Vec<Vec<Vector3<f64>>>,
}

/// Everything a replay shows: static data and the frames.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ReplayData {
    /// Title of the page (e.g. `"complex · inverse · 1485 gel nodes"`).
    pub title: String,
    /// The run's summary as key/value rows, in display order.
    pub summary: Vec<(String, String)>,
    /// Gel surface triangles as indices into each frame's [`ReplayFrame::surface`],
    /// counter-clockwise seen from outside.
    pub surface_triangles: Vec<[u32; 3]>,
    /// Sphere obstacles.
    pub spheres: Vec<SphereObstacle>,
    /// Obstacles given as triangle surfaces.
    pub meshes: Vec<MeshObstacle>,
    /// Tracking error of every step.
    pub error: ErrorSeries,
    /// Reference lines of the error plot.
    pub error_references: Vec<ReferenceLine>,
    /// The recorded frames, in time order.
    pub frames: Vec<ReplayFrame>,
}

/// Why replay data cannot be written: what is inconsistent, or the file that failed.
#[derive(Debug)]
pub enum ReplayError {
    /// The data is inconsistent (a count that differs between frames, an index out of range, a
    /// non-finite time, …); says what.
    Invalid(String),
    /// The file could not be written.
    Io {
        /// The file being written.
        file: std::path::PathBuf,
        /// Why it failed.
        reason: String,
    },
}

impl std::fmt::Display for ReplayError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Invalid(what) => write!(f, "invalid replay data: {what}"),
            Self::Io { file, reason } => write!(f, "{}: {reason}", file.display()),
        }
    }
}

impl std::error::Error for ReplayError {}

fn invalid<T>(what: String) -> Result<T, ReplayError> {
    Err(ReplayError::Invalid(what))
}

/// The gel's boundary surface in the replay's compact form: the surface nodes (global indices,
/// sorted) and the triangles as indices into that list.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SurfaceMap {
    /// Global index of each surface node, sorted.
    pub nodes: Vec<usize>,
    /// Triangles as indices into [`SurfaceMap::nodes`], with the input's orientation.
    pub triangles: Vec<[u32; 3]>,
}

impl SurfaceMap {
    /// Builds the map from triangles given by global node indices (e.g.
    /// [`crate::mesh::TetMesh::surface_triangles`]).
    ///
    /// # Errors
    /// [`ReplayError::Invalid`] when there are more than `u32::MAX` surface nodes.
    pub fn from_triangles(triangles: &[[usize; 3]]) -> Result<Self, ReplayError> {
        let mut nodes: Vec<usize> = triangles.iter().flatten().copied().collect();
        nodes.sort_unstable();
        nodes.dedup();
        if nodes.len() > u32::MAX as usize {
            return invalid(format!("{} surface nodes exceed u32", nodes.len()));
        }
        let local = |g: usize| nodes.binary_search(&g).map_or(0, |i| i as u32);
        let triangles = triangles
            .iter()
            .map(|t| [local(t[0]), local(t[1]), local(t[2])])
            .collect();
        Ok(Self { nodes, triangles })
    }

    /// The positions of the surface nodes, taken from the positions of every node.
    ///
    /// # Errors
    /// [`ReplayError::Invalid`] when `positions` has fewer nodes than the map refers to.
    pub fn gather(&self, positions: &[Vector3<f64>]) -> Result<Vec<Vector3<f64>>, ReplayError> {
        self.nodes
            .iter()
            .map(|&g| {
                positions.get(g).copied().ok_or_else(|| {
                    ReplayError::Invalid(format!(
                        "surface node {g} out of range of {} positions",
                        positions.len()
                    ))
                })
            })
            .collect()
    }
}

/// The stride between recorded steps that keeps a run of `planned_steps` steps within about
/// `max_frames` frames (at least 1). Record step `k` when `k % stride == 0`, and always the last.
pub fn frame_stride(planned_steps: usize, max_frames: usize) -> usize {
    planned_steps.div_ceil(max_frames.max(1)).max(1)
}

impl ReplayData {
    /// Checks the counts and indices the page relies on.
    ///
    /// # Errors
    /// [`ReplayError::Invalid`] saying what is inconsistent: no frame; a frame whose surface,
    /// sphere or obstacle counts differ from the first frame's; a triangle index out of range; a
    /// non-finite or negative radius, a non-finite time or reference value; error series of
    /// different lengths.
    pub fn validate(&self) -> Result<(), ReplayError> {
        let Some(first) = self.frames.first() else {
            return invalid("no frame".into());
        };
        let surface_nodes = first.surface.len();
        check_triangles("gel surface", &self.surface_triangles, surface_nodes)?;
        for s in &self.spheres {
            if !(s.radius.is_finite() && s.radius >= 0.0) {
                return invalid(format!("sphere {:?} has radius {}", s.name, s.radius));
            }
        }
        if first.mesh_nodes.len() != self.meshes.len() {
            return invalid(format!(
                "frame 0 has {} obstacle meshes, the replay {}",
                first.mesh_nodes.len(),
                self.meshes.len()
            ));
        }
        for (m, nodes) in self.meshes.iter().zip(&first.mesh_nodes) {
            check_triangles(&format!("obstacle {:?}", m.name), &m.triangles, nodes.len())?;
        }
        for (i, f) in self.frames.iter().enumerate() {
            if !f.time.is_finite() {
                return invalid(format!("frame {i} has time {}", f.time));
            }
            if f.surface.len() != surface_nodes {
                return invalid(format!(
                    "frame {i} has {} surface nodes, frame 0 {surface_nodes}",
                    f.surface.len()
                ));
            }
            if f.sphere_centres.len() != self.spheres.len() {
                return invalid(format!(
                    "frame {i} has {} sphere centres for {} spheres",
                    f.sphere_centres.len(),
                    self.spheres.len()
                ));
            }
            let counts = |fr: &ReplayFrame| fr.mesh_nodes.iter().map(Vec::len).collect::<Vec<_>>();
            if counts(f) != counts(first) {
                return invalid(format!(
                    "frame {i} has obstacle node counts {:?}, frame 0 {:?}",
                    counts(f),
                    counts(first)
                ));
            }
        }
        let e = &self.error;
        if e.depth.len() != e.steps.len() || e.error.len() != e.steps.len() {
            return invalid(format!(
                "error series of {} steps, {} depths, {} errors",
                e.steps.len(),
                e.depth.len(),
                e.error.len()
            ));
        }
        for r in &self.error_references {
            if !r.value.is_finite() {
                return invalid(format!("reference line {:?} is {}", r.label, r.value));
            }
        }
        Ok(())
    }
}

fn check_triangles(what: &str, triangles: &[[u32; 3]], nodes: usize) -> Result<(), ReplayError> {
    match triangles.iter().flatten().find(|&&i| i as usize >= nodes) {
        Some(i) => invalid(format!("{what}: triangle index {i} out of {nodes} nodes")),
        None => Ok(()),
    }
}

/// Standard base64 (RFC 4648 §4, with padding).
pub fn base64(bytes: &[u8]) -> String {
    const ALPHABET: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for chunk in bytes.chunks(3) {
        let byte = |i: usize| u32::from(chunk.get(i).copied().unwrap_or(0));
        let n = (byte(0) << 16) | (byte(1) << 8) | byte(2);
        let sextet = |shift: u32| char::from(ALPHABET[((n >> shift) & 63) as usize]);
        out.push(sextet(18));
        out.push(sextet(12));
        out.push(if chunk.len() > 1 { sextet(6) } else { '=' });
        out.push(if chunk.len() > 2 { sextet(0) } else { '=' });
    }
    out
}

/// Base64 of the values as little-endian `Float32`.
fn f32_base64(values: impl Iterator<Item = f64>) -> String {
    let bytes: Vec<u8> = values.flat_map(|v| (v as f32).to_le_bytes()).collect();
    base64(&bytes)
}

/// Base64 of the points' coordinates (x, y, z of each point) as little-endian `Float32`.
fn points_base64(points: &[Vector3<f64>]) -> String {
    f32_base64(points.iter().flat_map(|p| [p.x, p.y, p.z]))
}

/// Base64 of the indices as little-endian `Uint32`.
fn u32_base64(values: impl Iterator<Item = u32>) -> String {
    let bytes: Vec<u8> = values.flat_map(u32::to_le_bytes).collect();
    base64(&bytes)
}

fn triangles_base64(triangles: &[[u32; 3]]) -> String {
    u32_base64(triangles.iter().flatten().copied())
}

/// The JSON document of schema [`SCHEMA`] (see `docs/replay.md`).
///
/// # Errors
/// [`ReplayError::Invalid`] from [`ReplayData::validate`].
pub fn replay_json(data: &ReplayData) -> Result<Value, ReplayError> {
    data.validate()?;
    let frames: Vec<Value> = data
        .frames
        .iter()
        .map(|f| {
            json!({
                "t": f.time,
                "step": f.step,
                "surface": points_base64(&f.surface),
                "needle": points_base64(&f.needle),
                "path": points_base64(&f.path),
                "target": points_base64(&[f.target]),
                "spheres": points_base64(&f.sphere_centres),
                "meshes": f.mesh_nodes.iter().map(|m| points_base64(m)).collect::<Vec<_>>(),
            })
        })
        .collect();
    Ok(json!({
        "schema": SCHEMA,
        "title": data.title,
        "units": { "length": "mm", "time": "s", "error": "mm" },
        "summary": data.summary.iter().map(|(k, v)| json!([k, v])).collect::<Vec<_>>(),
        "surface": {
            "nodes": data.frames[0].surface.len(),
            "triangles": triangles_base64(&data.surface_triangles),
        },
        "spheres": data.spheres.iter().map(|s| json!({ "name": s.name, "radius": s.radius })).collect::<Vec<_>>(),
        "meshes": data.meshes.iter().zip(&data.frames[0].mesh_nodes).map(|(m, nodes)| json!({
            "name": m.name,
            "nodes": nodes.len(),
            "triangles": triangles_base64(&m.triangles),
        })).collect::<Vec<_>>(),
        "error": {
            "steps": u32_base64(data.error.steps.iter().copied()),
            "depth": f32_base64(data.error.depth.iter().copied()),
            "error": f32_base64(data.error.error.iter().copied()),
        },
        "error_references": data.error_references.iter().map(|r| json!({ "label": r.label, "value": r.value })).collect::<Vec<_>>(),
        "frames": frames,
    }))
}

/// The replay page: [`TEMPLATE`] with its [`PLACEHOLDER`] replaced by the JSON document.
/// Every `<` of the JSON is written `\u003c`, so no string of the data can close the script
/// element that holds it.
///
/// # Errors
/// [`ReplayError::Invalid`] from [`ReplayData::validate`].
pub fn replay_html(data: &ReplayData) -> Result<String, ReplayError> {
    let json = replay_json(data)?.to_string().replace('<', "\\u003c");
    let (before, after) = TEMPLATE
        .split_once(PLACEHOLDER)
        .ok_or_else(|| ReplayError::Invalid("the template has no placeholder".into()))?;
    let mut html = String::with_capacity(TEMPLATE.len() + json.len());
    html.push_str(before);
    html.push_str(&json);
    html.push_str(after);
    Ok(html)
}

/// Writes the replay page to `path` (conventionally `DIR/replay.html`).
///
/// # Errors
/// [`ReplayError::Invalid`] from [`ReplayData::validate`]; [`ReplayError::Io`] naming the file
/// when it cannot be written.
pub fn write_replay(path: &Path, data: &ReplayData) -> Result<(), ReplayError> {
    let html = replay_html(data)?;
    std::fs::write(path, html).map_err(|e| ReplayError::Io {
        file: path.to_owned(),
        reason: e.to_string(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::box_mesh;

    /// Decodes standard base64 (test side: an independent, table-free decoder).
    fn decode_base64(text: &str) -> Vec<u8> {
        let value = |c: u8| match c {
            b'A'..=b'Z' => u32::from(c - b'A'),
            b'a'..=b'z' => u32::from(c - b'a') + 26,
            b'0'..=b'9' => u32::from(c - b'0') + 52,
            b'+' => 62,
            b'/' => 63,
            _ => panic!("not base64: {c}"),
        };
        let mut out = Vec::new();
        for quad in text.as_bytes().chunks(4) {
            assert_eq!(quad.len(), 4, "base64 length is a multiple of 4");
            let pad = quad.iter().filter(|&&c| c == b'=').count();
            let n = quad
                .iter()
                .map(|&c| if c == b'=' { 0 } else { value(c) })
                .fold(0u32, |acc, v| (acc << 6) | v);
            out.extend_from_slice(&n.to_be_bytes()[1..4 - pad]);
        }
        out
    }

    fn decode_f32(text: &str) -> Vec<f32> {
        decode_base64(text)
            .chunks(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect()
    }

    fn decode_u32(text: &str) -> Vec<u32> {
        decode_base64(text)
            .chunks(4)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect()
    }

    fn flat32(points: &[Vector3<f64>]) -> Vec<f32> {
        points
            .iter()
            .flat_map(|p| [p.x as f32, p.y as f32, p.z as f32])
            .collect()
    }

    fn v(x: f64, y: f64, z: f64) -> Vector3<f64> {
        Vector3::new(x, y, z)
    }

    /// A tetrahedron's surface, a needle, a path, one sphere and one triangle obstacle, two
    /// frames that differ everywhere.
    fn small_replay() -> ReplayData {
        let frame = |k: f64| ReplayFrame {
            time: 0.04 * k,
            step: 5 * k as u32,
            surface: vec![
                v(260.0, -30.0, 0.0),
                v(340.0 + k, -30.0, 0.0),
                v(260.0, 30.0, 0.0),
                v(300.0, 0.0, 60.0 - 1.5 * k),
            ],
            needle: vec![
                v(300.0, 0.0, 180.0 - k),
                v(300.1, 0.0, 120.0 - k),
                v(300.25, 1e-3, 60.0 - k),
            ],
            path: vec![
                v(300.0, 0.0, 70.0),
                v(300.0 + 0.3 * k, 0.0, 60.0),
                v(308.0, 0.0, 10.0),
            ],
            target: v(300.0, 0.125 * k, 60.0 - k),
            sphere_centres: vec![v(300.0, 0.0, 20.0 - 0.1 * k)],
            mesh_nodes: vec![vec![
                v(290.0, -5.0, 10.0),
                v(295.0, 5.0, 10.0 + k),
                v(292.0, 0.0, 15.0),
            ]],
        };
        ReplayData {
            title: "small".into(),
            summary: vec![
                ("scene".into(), "tetra".into()),
                ("e_mean".into(), "0.5 mm".into()),
            ],
            surface_triangles: vec![[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]],
            spheres: vec![SphereObstacle {
                name: "sphere".into(),
                radius: 3.0,
            }],
            meshes: vec![MeshObstacle {
                name: "plate".into(),
                triangles: vec![[0, 1, 2]],
            }],
            error: ErrorSeries {
                steps: vec![0, 1, 2],
                depth: vec![0.0, 0.1, 0.2],
                error: vec![f64::NAN, 0.25, 1.5],
            },
            error_references: vec![ReferenceLine {
                label: "paper e_max".into(),
                value: 1.8,
            }],
            frames: vec![frame(0.0), frame(1.0)],
        }
    }

    fn tmp(name: &str) -> std::path::PathBuf {
        let dir = std::env::temp_dir().join(format!("needle-replay-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir.join(name)
    }

    const DATA_OPEN: &str = r#"<script id="replay-data" type="application/json">"#;

    /// The JSON text embedded in a page.
    fn embedded_json(html: &str) -> &str {
        let start = html.find(DATA_OPEN).expect("data element") + DATA_OPEN.len();
        let len = html[start..]
            .find("</script>")
            .expect("data element closed");
        &html[start..start + len]
    }

    #[test]
    fn base64_matches_the_rfc_4648_test_vectors() {
        let cases = [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ];
        for (plain, encoded) in cases {
            assert_eq!(base64(plain.as_bytes()), encoded, "{plain:?}");
            assert_eq!(decode_base64(encoded), plain.as_bytes(), "{encoded:?}");
        }
        let all: Vec<u8> = (0..=255).collect();
        assert_eq!(decode_base64(&base64(&all)), all);
    }

    #[test]
    fn template_has_the_placeholder_exactly_once_and_the_data_element_around_it() {
        assert_eq!(TEMPLATE.matches(PLACEHOLDER).count(), 1);
        assert_eq!(TEMPLATE.matches(DATA_OPEN).count(), 1);
        assert!(TEMPLATE.contains(&format!("{DATA_OPEN}{PLACEHOLDER}</script>")));
    }

    #[test]
    fn written_replay_holds_the_data_in_place_of_the_placeholder_and_decodes_to_the_same_floats() {
        let data = small_replay();
        let path = tmp("replay.html");
        write_replay(&path, &data).unwrap();
        let html = std::fs::read_to_string(&path).unwrap();

        // The placeholder is replaced exactly once: the page is the template's two halves
        // around the JSON, and no placeholder is left.
        let (before, after) = TEMPLATE.split_once(PLACEHOLDER).unwrap();
        assert!(html.starts_with(before) && html.ends_with(after));
        assert_eq!(
            html.len(),
            before.len() + embedded_json(&html).len() + after.len()
        );
        assert!(!html.contains(PLACEHOLDER));

        let doc: Value = serde_json::from_str(embedded_json(&html)).unwrap();
        assert_eq!(doc["schema"], SCHEMA);
        assert_eq!(doc["title"], "small");
        assert_eq!(doc["summary"][1], json!(["e_mean", "0.5 mm"]));
        assert_eq!(doc["surface"]["nodes"], 4);
        let tris = decode_u32(doc["surface"]["triangles"].as_str().unwrap());
        assert_eq!(
            tris,
            data.surface_triangles
                .iter()
                .flatten()
                .copied()
                .collect::<Vec<_>>()
        );
        assert_eq!(
            doc["spheres"][0],
            json!({ "name": "sphere", "radius": 3.0 })
        );
        assert_eq!(doc["meshes"][0]["nodes"], 3);
        assert_eq!(
            decode_u32(doc["meshes"][0]["triangles"].as_str().unwrap()),
            vec![0, 1, 2]
        );
        assert_eq!(
            decode_u32(doc["error"]["steps"].as_str().unwrap()),
            vec![0, 1, 2]
        );
        assert_eq!(
            decode_f32(doc["error"]["depth"].as_str().unwrap()),
            vec![0.0, 0.1f32, 0.2f32]
        );
        let err = decode_f32(doc["error"]["error"].as_str().unwrap());
        assert!(err[0].is_nan() && err[1] == 0.25 && err[2] == 1.5);
        assert_eq!(
            doc["error_references"][0],
            json!({ "label": "paper e_max", "value": 1.8 })
        );

        let frames = doc["frames"].as_array().unwrap();
        assert_eq!(frames.len(), 2);
        for (f, j) in data.frames.iter().zip(frames) {
            assert_eq!(j["t"].as_f64().unwrap(), f.time);
            assert_eq!(j["step"].as_u64().unwrap(), u64::from(f.step));
            let field = |name: &str| decode_f32(j[name].as_str().unwrap());
            assert_eq!(field("surface"), flat32(&f.surface));
            assert_eq!(field("needle"), flat32(&f.needle));
            assert_eq!(field("path"), flat32(&f.path));
            assert_eq!(field("target"), flat32(&[f.target]));
            assert_eq!(field("spheres"), flat32(&f.sphere_centres));
            assert_eq!(
                decode_f32(j["meshes"][0].as_str().unwrap()),
                flat32(&f.mesh_nodes[0])
            );
        }
        std::fs::remove_file(&path).unwrap();
    }

    #[test]
    fn a_summary_holding_a_closing_script_tag_stays_inside_the_data_element() {
        let mut data = small_replay();
        let nasty = "</script><script>throw 1</script><!-- /*__REPLAY_DATA__*/";
        data.summary.push(("note".into(), nasty.into()));
        let html = replay_html(&data).unwrap();
        let doc: Value = serde_json::from_str(embedded_json(&html)).unwrap();
        assert_eq!(doc["summary"][2], json!(["note", nasty]));
        assert_eq!(
            html.matches("</script>").count(),
            TEMPLATE.matches("</script>").count()
        );
    }

    #[test]
    fn inconsistent_data_is_refused_and_says_what() {
        let refused = |data: &ReplayData, what: &str| match replay_html(data) {
            Err(ReplayError::Invalid(msg)) => assert!(msg.contains(what), "{msg:?} lacks {what:?}"),
            other => panic!("expected Invalid({what}), got {other:?}"),
        };
        let mut d = small_replay();
        d.frames.clear();
        refused(&d, "no frame");
        let mut d = small_replay();
        d.frames[1].surface.pop();
        refused(&d, "frame 1 has 3 surface nodes");
        let mut d = small_replay();
        d.surface_triangles.push([0, 1, 4]);
        refused(&d, "triangle index 4 out of 4 nodes");
        let mut d = small_replay();
        d.frames[0].sphere_centres.clear();
        refused(&d, "0 sphere centres for 1 spheres");
        let mut d = small_replay();
        d.frames[1].mesh_nodes[0].pop();
        refused(&d, "obstacle node counts");
        let mut d = small_replay();
        d.meshes[0].triangles.push([0, 3, 1]);
        refused(&d, "triangle index 3 out of 3 nodes");
        let mut d = small_replay();
        d.frames[1].time = f64::INFINITY;
        refused(&d, "frame 1 has time inf");
        let mut d = small_replay();
        d.error.depth.pop();
        refused(&d, "3 steps, 2 depths");
        let mut d = small_replay();
        d.spheres[0].radius = -1.0;
        refused(&d, "radius -1");
    }

    #[test]
    fn non_finite_positions_are_kept_for_the_page_to_leave_out() {
        let mut d = small_replay();
        d.frames[1].needle[2] = v(f64::NAN, 0.0, f64::INFINITY);
        let doc = replay_json(&d).unwrap();
        let needle = decode_f32(doc["frames"][1]["needle"].as_str().unwrap());
        assert!(needle[6].is_nan() && needle[7] == 0.0 && needle[8] == f32::INFINITY);
    }

    #[test]
    fn surface_map_of_a_box_mesh_indexes_its_surface_nodes() {
        let mesh = box_mesh(v(260.0, -30.0, 0.0), v(340.0, 30.0, 60.0), 200);
        let global = mesh.surface_triangles();
        let map = SurfaceMap::from_triangles(&global).unwrap();
        assert_eq!(map.nodes, mesh.surface_nodes());
        assert_eq!(map.triangles.len(), global.len());
        for (local, g) in map.triangles.iter().zip(&global) {
            for k in 0..3 {
                assert_eq!(map.nodes[local[k] as usize], g[k]);
            }
        }
        let positions = map.gather(&mesh.nodes).unwrap();
        assert_eq!(positions.len(), map.nodes.len());
        assert_eq!(positions[7], mesh.nodes[map.nodes[7]]);
        assert!(matches!(
            map.gather(&mesh.nodes[..3]),
            Err(ReplayError::Invalid(_))
        ));
    }

    #[test]
    fn frame_stride_keeps_about_the_requested_number_of_frames() {
        assert_eq!(frame_stride(609, 120), 6); // 102 frames + the last
        assert_eq!(frame_stride(120, 120), 1);
        assert_eq!(frame_stride(0, 120), 1);
        assert_eq!(frame_stride(50, 0), 50);
    }
}

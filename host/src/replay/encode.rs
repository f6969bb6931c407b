//! The replay's JSON document (schema [`SCHEMA`]: base64 little-endian `Float32` / `Uint32`
//! arrays) and the page: the template with the document in place of its placeholder.

// Units are written in brackets ([mm], [s]) as in the workspace style: not intra-doc links.
#![allow(rustdoc::broken_intra_doc_links)]

use super::{PLACEHOLDER, ReplayData, ReplayError, SCHEMA, TEMPLATE};
use nalgebra::Vector3;
use serde_json::{Value, json};
use std::path::Path;

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

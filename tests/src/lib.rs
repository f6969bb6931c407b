//! Shared helpers for the integration tests.

use std::path::PathBuf;

/// Path of a reference file copied from `shared/ref/` into `tests/data/ref/`.
///
/// # Panics
/// Panics when the file is missing: a reference test must fail, not pass silently.
pub fn ref_path(name: &str) -> PathBuf {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("data/ref")
        .join(name);
    assert!(
        p.is_file(),
        "reference file {} is missing (copy it from shared/ref/)",
        p.display()
    );
    p
}

/// Parses a reference JSON file.
pub fn load_ref(name: &str) -> serde_json::Value {
    let p = ref_path(name);
    let text =
        std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("reading {}: {e}", p.display()));
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("parsing {}: {e}", p.display()))
}

/// A JSON array of numbers (reference files).
///
/// # Panics
/// When `v` is not an array of numbers: a malformed reference must fail the test.
pub fn arr(v: &serde_json::Value) -> Vec<f64> {
    v.as_array()
        .expect("array")
        .iter()
        .map(|x| x.as_f64().expect("number"))
        .collect()
}

/// A JSON array of arrays of numbers, row by row (reference files).
///
/// # Panics
/// As [`arr`].
pub fn mat(v: &serde_json::Value) -> Vec<Vec<f64>> {
    v.as_array().expect("array").iter().map(arr).collect()
}

/// The largest entry-wise difference of `a` from the reference `b`, relative to the largest
/// entry of `b` (the displacement error of the FE reference tests).
pub fn max_rel_err(a: &[f64], b: &[f64]) -> f64 {
    let num = a
        .iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max);
    let den = b.iter().map(|y| y.abs()).fold(0.0, f64::max);
    num / den
}

/// The 40 × 20 × 20 mm box `[0, 40] × [0, 20] × [0, 20]` meshed with `divisions`, and its
/// bottom nodes (z = 0), to clamp.
pub fn clamped_box(
    divisions: needle_host::mesh::BoxDivisions,
) -> (needle_host::mesh::TetMesh, Vec<usize>) {
    let mesh = needle_host::mesh::box_mesh_with_divisions(
        nalgebra::Vector3::zeros(),
        nalgebra::Vector3::new(40.0, 20.0, 20.0),
        divisions,
    );
    let bottom = mesh.nodes_on_plane(2, 0.0, 1e-9);
    (mesh, bottom)
}

/// The embedded scene `name` with `overrides` (`field`, TOML value) applied.
///
/// # Panics
/// Panics on an unknown scene or an invalid override (a test's own input).
pub fn builtin_scene(name: &str, overrides: &[(&str, &str)]) -> needle_host::scene::Scene {
    let overrides: Vec<(String, String)> = overrides
        .iter()
        .map(|(f, v)| (f.to_string(), v.to_string()))
        .collect();
    needle_host::scene::Scene::builtin(name)
        .unwrap()
        .with_overrides(&overrides)
        .unwrap()
}

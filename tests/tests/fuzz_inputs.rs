//! Fuzzing of the host's inputs (issue "trust"): generated scenes (field overrides with hostile
//! values, and byte-level corruptions of a scene file) and corrupted Gmsh meshes (2.2 and 4.1,
//! ASCII and binary). Every input is answered by a value or an error, never by a panic; a scene that is
//! accepted also sets up or is refused with an error. Bounded: seeded proptest, a fixed number
//! of cases.

use needle_host::mesh::{TetMesh, box_mesh, read_gmsh_bytes, write_gmsh_ascii, write_gmsh_binary};
use needle_host::scene::{SIMPLE_TOML, Scene};
use needle_host::setup::Setup;
use proptest::prelude::*;
use proptest::test_runner::{Config, RngSeed};

/// Scene fields a user sets, numbers and strings alike.
const FIELDS: &[&str] = &[
    "gel.young_modulus",
    "gel.poisson_ratio",
    "gel.density",
    "gel.box.nodes",
    "gel.box.min",
    "gel.box.max",
    "gel.fixed.below_z",
    "needle.length",
    "needle.diameter",
    "needle.young_modulus",
    "needle.poisson_ratio",
    "needle.beams",
    "interaction.puncture_force",
    "interaction.surface_friction",
    "interaction.shaft_friction",
    "interaction.shaft_resistance",
    "interaction.constraint_spacing",
    "inverse.delta_q",
    "inverse.blend_distance",
    "inverse.jacobian",
    "inverse.max_base_step",
    "insertion.advance_per_step",
    "insertion.steps",
    "insertion.mode",
    "solver.time_step",
    "solver.refactor_every",
    "robot.dt",
    "robot.start_joints_deg",
    "robot.tool.translation",
    "path.samples",
    "path.approach",
    "path.formula.x",
    "obstacles",
    "name",
];

/// Hostile TOML values: extremes, signs, wrong types, odd strings, arrays.
fn value() -> impl Strategy<Value = String> {
    prop_oneof![
        prop::sample::select(vec![
            "0",
            "-1",
            "1e300",
            "-1e300",
            "1e-300",
            "nan",
            "inf",
            "-inf",
            "0.4999999",
            "0.5",
            "18446744073709551615",
            "-9223372036854775808",
            "1e17",
            "true",
            "\"\"",
            "\"solve\"",
            "\"back-and-forth\"",
            "[]",
            "[1, 2]",
            "[0, 0, 0, 0, 0, 0]",
            "[[0, 0, 0], [0, 0, 0]]",
            "[[1e300, 0, 0], [0, 0, 1]]",
            "{}",
            "[{ center = [0, 0, 0], radius = 1e300 }]",
            "\"s^s^s^s\"",
            "\"1/s\"",
            "\"300 + 1e300*s\"",
            "[300, 0, 1e300]",
            "[-1e300, 0, 0]",
        ])
        .prop_map(str::to_owned),
        any::<f64>().prop_map(|v| format!("{v:e}")),
        any::<i64>().prop_map(|v| v.to_string()),
    ]
}

/// A fixed seed, so that CI runs the same cases every time (a random seed made CI flaky the
/// day it found the mshio panic below); another seed: change it here and run the test.
fn config(cases: u32) -> Config {
    Config {
        cases,
        rng_seed: RngSeed::Fixed(2026),
        ..Config::default()
    }
}

proptest! {
    #![proptest_config(config(1000))]

    /// 1000 generated scenes: one to three hostile overrides of the simple scene (on a 300-node
    /// gel) are accepted or refused with an error; an accepted one sets up or is refused.
    #[test]
    fn generated_scenes_are_accepted_or_refused_never_a_panic(
        edits in proptest::collection::vec((prop::sample::select(FIELDS), value()), 1..4),
        set_up in 0u8..8,
    ) {
        let base = Scene::builtin("simple").expect("simple");
        let mut overrides: Vec<(String, String)> =
            vec![("gel.box.nodes".to_owned(), "300".to_owned())];
        overrides.extend(edits.iter().map(|(f, v)| ((*f).to_owned(), v.clone())));
        if let Ok(scene) = base.with_overrides(&overrides) {
            // Set-up costs a mesh and a factorisation: one accepted scene in eight.
            if set_up == 0 {
                let _ = Setup::build(&scene);
            }
        }
    }

    /// 1000 corruptions of the scene file's text (bytes replaced, removed or inserted).
    #[test]
    fn corrupted_scene_files_are_refused_never_a_panic(
        cuts in proptest::collection::vec((any::<prop::sample::Index>(), any::<u8>(), 0u8..3), 1..6),
    ) {
        let mut bytes = SIMPLE_TOML.as_bytes().to_vec();
        for (at, b, how) in cuts {
            let i = at.index(bytes.len());
            match how {
                0 => bytes[i] = b,
                1 => { bytes.remove(i); }
                _ => bytes.insert(i, b),
            }
        }
        let text = String::from_utf8_lossy(&bytes);
        let _ = Scene::from_toml_str(&text, "fuzzed.toml");
    }
}

fn small_box() -> TetMesh {
    box_mesh(
        nalgebra::Vector3::new(0.0, 0.0, 0.0),
        nalgebra::Vector3::new(10.0, 10.0, 10.0),
        64,
    )
}

/// A corruption of a mesh file's bytes.
fn corrupt(mut bytes: Vec<u8>, cuts: &[(prop::sample::Index, u8, u8)]) -> Vec<u8> {
    for (at, b, how) in cuts {
        if bytes.is_empty() {
            break;
        }
        let i = at.index(bytes.len());
        match how {
            0 => bytes[i] = *b,
            1 => {
                bytes.remove(i);
            }
            2 => bytes.insert(i, *b),
            // A digit changed: counts, tags and indices go wrong while the file still parses.
            _ => {
                if let Some(j) = bytes[i..].iter().position(u8::is_ascii_digit) {
                    bytes[i + j] = b'0' + b % 10;
                }
            }
        }
    }
    bytes
}

proptest! {
    #![proptest_config(config(300))]

    /// 300 corrupted Gmsh meshes (ASCII and binary): read, or refused with an error.
    #[test]
    fn corrupted_gmsh_meshes_are_refused_never_a_panic(
        binary in any::<bool>(),
        cuts in proptest::collection::vec((any::<prop::sample::Index>(), any::<u8>(), 0u8..4), 1..5),
    ) {
        let mesh = small_box();
        let mut bytes = Vec::new();
        if binary {
            write_gmsh_binary(&mesh, &mut bytes).expect("write");
        } else {
            write_gmsh_ascii(&mesh, &mut bytes).expect("write");
        }
        let bytes = corrupt(bytes, &cuts);
        if let Ok(m) = read_gmsh_bytes(&bytes) {
            // What is read back is a valid mesh.
            prop_assert!(m.validate().is_ok());
        }
    }
}

/// A mesh file committed under `tests/data/mesh/` (written by Gmsh itself).
fn fixture(name: &str) -> Vec<u8> {
    let p = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("data/mesh")
        .join(name);
    std::fs::read(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

proptest! {
    #![proptest_config(config(300))]

    /// 300 corrupted Gmsh 2.2 and 4.1 files as Gmsh writes them (ASCII and binary, two
    /// regions, boundary triangles): read, or refused with an error.
    #[test]
    fn corrupted_gmsh_files_of_every_format_are_refused_never_a_panic(
        file in 0usize..4,
        cuts in proptest::collection::vec((any::<prop::sample::Index>(), any::<u8>(), 0u8..4), 1..5),
    ) {
        let name = [
            "two_regions_v22_ascii.msh",
            "two_regions_v22_binary.msh",
            "two_regions_v41_ascii.msh",
            "two_regions_v41_binary.msh",
        ][file];
        let bytes = corrupt(fixture(name), &cuts);
        if let Ok(m) = read_gmsh_bytes(&bytes) {
            prop_assert!(m.validate().is_ok());
        }
    }
}

proptest! {
    #![proptest_config(config(400))]

    /// 400 corrupted VTK files as VTK and meshio write them (`.vtu` ASCII, inline binary,
    /// appended raw and base64, zlib; legacy `.vtk` ASCII and binary): read, or refused with an
    /// error.
    #[test]
    fn corrupted_vtk_files_are_refused_never_a_panic(
        file in 0usize..8,
        cuts in proptest::collection::vec((any::<prop::sample::Index>(), any::<u8>(), 0u8..4), 1..5),
    ) {
        let name = [
            "vtk_ascii.vtu",
            "vtk_binary_zlib.vtu",
            "vtk_appended_raw_zlib.vtu",
            "vtk_appended_base64.vtu",
            "meshio_zlib.vtu",
            "vtk_legacy_ascii.vtk",
            "vtk_legacy_binary.vtk",
            "vtk_legacy42_binary.vtk",
        ][file];
        let bytes = corrupt(fixture(name), &cuts);
        let read = if name.ends_with(".vtu") {
            needle_host::mesh::read_vtu_bytes(&bytes)
        } else {
            needle_host::mesh::read_legacy_vtk_bytes(&bytes)
        };
        if let Ok(m) = read {
            prop_assert!(m.validate().is_ok());
        }
    }
}

/// Regression (found by the fuzz test above with a random seed): a binary file whose
/// `$MeshFormat` declares a data size of 3 bytes made mshio 0.4.2 panic (`unimplemented!`).
#[test]
fn gmsh_binary_with_a_data_size_of_3_bytes_is_refused_not_a_panic() {
    let mut bytes = Vec::new();
    write_gmsh_binary(&small_box(), &mut bytes).expect("write");
    let text = String::from_utf8_lossy(&bytes[..30]).into_owned();
    assert!(text.starts_with("$MeshFormat\n4.1 1 8\n"), "{text}");
    // "$MeshFormat\n4.1 1 8\n": the data size is byte 18.
    bytes[18] = b'3';
    let e = read_gmsh_bytes(&bytes).expect_err("refused");
    assert!(e.to_string().contains("data size of 3 bytes"), "{e}");
}

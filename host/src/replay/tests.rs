use super::*;
use crate::mesh::box_mesh;
use serde_json::{Value, json};

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

/// A fresh folder of this test, removed when dropped, and `name` in it.
fn tmp(name: &str) -> (tempfile::TempDir, std::path::PathBuf) {
    let dir = (tempfile::Builder::new().prefix("needle-replay-").tempdir()).unwrap();
    let path = dir.path().join(name);
    (dir, path)
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
    let (_dir, path) = tmp("replay.html");
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

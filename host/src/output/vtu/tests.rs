use super::*;

/// Reads every `<DataArray>` of a `.vtu` text back: name (or the `Points` array), type, and
/// the raw bytes, decoding VTK's compressed layout independently of the writer.
fn arrays(text: &str) -> Vec<(String, String, Vec<u8>)> {
    use flate2::read::ZlibDecoder;
    use std::io::Read;
    let mut out = Vec::new();
    for part in text.split("<DataArray ").skip(1) {
        let (attrs, rest) = part.split_once('>').unwrap();
        let body = rest.split_once("</DataArray>").unwrap().0;
        let attr = |key: &str| {
            attrs
                .split(&format!("{key}=\""))
                .nth(1)
                .map(|s| s.split('"').next().unwrap().to_owned())
        };
        assert_eq!(attr("format").as_deref(), Some("binary"), "{attrs}");
        let first = STANDARD.decode(&body[..16]).unwrap();
        let blocks = u64::from_le_bytes(first[..8].try_into().unwrap()) as usize;
        let header_len = 8 * (3 + blocks);
        let header_chars = 4 * header_len.div_ceil(3);
        let header = STANDARD.decode(&body[..header_chars]).unwrap();
        let word = |i: usize| u64::from_le_bytes(header[8 * i..8 * i + 8].try_into().unwrap());
        let (block, last) = (word(1) as usize, word(2) as usize);
        let data = STANDARD.decode(&body[header_chars..]).unwrap();
        let mut raw = Vec::new();
        let mut at = 0;
        for b in 0..blocks {
            let size = word(3 + b) as usize;
            let mut chunk = Vec::new();
            ZlibDecoder::new(&data[at..at + size])
                .read_to_end(&mut chunk)
                .unwrap();
            let expected = if b + 1 == blocks { last } else { block };
            assert_eq!(chunk.len(), expected, "block {b} of {attrs}");
            raw.extend(chunk);
            at += size;
        }
        assert_eq!(at, data.len(), "trailing bytes in {attrs}");
        out.push((attr("Name").unwrap_or_default(), attr("type").unwrap(), raw));
    }
    out
}

fn f64s(raw: &[u8]) -> Vec<f64> {
    raw.chunks(8)
        .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
        .collect()
}

#[test]
fn vtu_arrays_read_back_through_vtks_compressed_layout() {
    // 5000 points: 120 000 bytes of coordinates, four blocks with a short last one.
    let points: Vec<Vector3<f64>> = (0..5000)
        .map(|i| Vector3::new(i as f64, 0.5 * i as f64, -1.0 / (i as f64 + 1.0)))
        .collect();
    let grid = Grid {
        points: points.clone(),
        cells: vec![
            (CellKind::Tetra, vec![0, 1, 2, 3]),
            (CellKind::PolyLine, (0..5000).collect()),
        ],
        point_data: vec![Array::new(
            "displacement",
            Values::vectors(points.iter().rev()),
        )],
        cell_data: vec![
            Array::new("region", Values::I32(vec![7, -2])),
            Array::new("von_mises_kPa", Values::scalars([1.5, f64::MAX])),
        ],
        time: Some(0.25),
    };
    let text = grid.to_vtu().unwrap();
    assert!(text.contains("NumberOfPoints=\"5000\" NumberOfCells=\"2\""));
    let a = arrays(&text);
    let names: Vec<&str> = a.iter().map(|(n, _, _)| n.as_str()).collect();
    assert_eq!(
        names,
        [
            "TimeValue",
            "displacement",
            "region",
            "von_mises_kPa",
            "Points",
            "connectivity",
            "offsets",
            "types"
        ]
    );
    assert_eq!(f64s(&a[0].2), [0.25]);
    let disp: Vec<f64> = points.iter().rev().flat_map(|p| [p.x, p.y, p.z]).collect();
    assert_eq!(f64s(&a[1].2), disp);
    assert_eq!(a[2].1, "Int32");
    assert_eq!(
        a[2].2,
        [7i32, -2]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect::<Vec<_>>()
    );
    assert_eq!(f64s(&a[3].2), [1.5, f64::MAX]);
    let pts: Vec<f64> = points.iter().flat_map(|p| [p.x, p.y, p.z]).collect();
    assert_eq!(a[4].2.len(), 120_000, "more than three blocks");
    assert_eq!(f64s(&a[4].2), pts);
    let ints = |raw: &[u8]| -> Vec<i64> {
        raw.chunks(8)
            .map(|c| i64::from_le_bytes(c.try_into().unwrap()))
            .collect()
    };
    let conn = ints(&a[5].2);
    assert_eq!(conn.len(), 5004);
    assert_eq!(&conn[..6], [0, 1, 2, 3, 0, 1]);
    assert_eq!(ints(&a[6].2), [4, 5004]);
    assert_eq!(a[7].2, [10u8, 4]);
}

#[test]
fn a_grid_whose_arrays_do_not_fit_is_refused_naming_the_array() {
    let mut grid = Grid {
        points: vec![Vector3::zeros(); 2],
        cells: vec![(CellKind::Vertex, vec![0]), (CellKind::Vertex, vec![1])],
        point_data: vec![Array::new("force_N", Values::scalars([1.0]))],
        ..Grid::default()
    };
    let e = grid.to_vtu().unwrap_err();
    assert!(
        e.contains("point array `force_N` has 1 tuples for 2 points"),
        "{e}"
    );
    grid.point_data.clear();
    grid.cells.push((CellKind::Vertex, vec![2]));
    let e = grid.to_vtu().unwrap_err();
    assert!(e.contains("cell 2 names a point beyond"), "{e}");
    let file = std::env::temp_dir().join(format!("needle-vtu-{}.vtu", std::process::id()));
    let e = grid.write(&file).unwrap_err();
    assert!(e.to_string().contains(&*file.to_string_lossy()), "{e}");
    assert!(!file.exists());
}

#[test]
fn the_unit_sphere_is_closed_outward_and_on_the_sphere() {
    let (v, f) = unit_sphere(2);
    assert_eq!((v.len(), f.len()), (162, 320));
    assert!(v.iter().all(|p| (p.norm() - 1.0).abs() < 1e-12));
    let mut edges = std::collections::HashMap::new();
    for t in &f {
        let n = (v[t[1]] - v[t[0]]).cross(&(v[t[2]] - v[t[0]]));
        assert!(n.dot(&(v[t[0]] + v[t[1]] + v[t[2]])) > 0.0, "inward {t:?}");
        for k in 0..3 {
            *edges.entry((t[k], t[(k + 1) % 3])).or_insert(0) += 1;
        }
    }
    // Closed and consistently oriented: every directed edge once, its reverse once.
    assert!(edges.keys().all(|&(a, b)| edges.get(&(b, a)) == Some(&1)));
    assert!(edges.values().all(|&c| c == 1));
}

#[test]
fn the_collection_lists_every_part_of_every_frame_with_its_time() {
    let c = Collection {
        frames: vec![
            (0.0, vec!["gel_00000.vtu".into(), "needle_00000.vtu".into()]),
            (0.5, vec!["gel_00050.vtu".into(), "needle_00050.vtu".into()]),
        ],
    };
    let text = c.to_pvd();
    assert_eq!(text.matches("<DataSet ").count(), 4);
    assert!(text.contains("timestep=\"5e-1\" group=\"\" part=\"1\" file=\"needle_00050.vtu\""));
    assert!(text.contains("type=\"Collection\""));
}

//! Writes `DIR/replay.html`, a browser replay of a synthetic insertion: the benchmark's gel box
//! (box mesher, its boundary surface), the complex benchmark path, a needle that approaches, indents
//! the surface, punctures and follows the path with a tracking error, two spheres and a vessel (a
//! triangle surface) embedded in the gel.
//!
//! The motion is prescribed, not simulated: a smooth displacement field (a dimple under the tip
//! that grows until puncture and then relaxes, and a drag of the gel along the inserted shaft)
//! moves the surface, the embedded path, the target and the obstacles; the tracking error is a
//! smooth function of the depth. It exercises the replay page (`needle_host::replay`) with data of
//! a real run's shape and size until the run loop records real runs.
//!
//! ```sh
//! cargo run --release -p needle-host --example replay_demo -- DIR [--nodes 1500] [--frames 120]
//! ```

use nalgebra::Vector3;
use needle_host::mesh::box_mesh;
use needle_host::replay::{
    ErrorSeries, MeshObstacle, ReferenceLine, ReplayData, ReplayFrame, SCHEMA, SphereObstacle,
    SurfaceMap, write_replay,
};
use std::f64::consts::PI;
use std::path::PathBuf;

/// Control period [s].
const DT: f64 = 0.04;
/// Path length the target advances per step [mm].
const ADVANCE: f64 = 0.1;
/// Approach segment in the air before the entry point [mm].
const APPROACH: f64 = 10.0;
/// Indentation of the surface under the tip at puncture [mm].
const PUNCTURE_DEPTH: f64 = 3.0;
/// Needle length [mm] and number of beams.
const NEEDLE_LENGTH: f64 = 120.0;
const NEEDLE_BEAMS: usize = 40;

fn v(x: f64, y: f64, z: f64) -> Vector3<f64> {
    Vector3::new(x, y, z)
}

/// The complex benchmark path in the rest configuration, s ∈ [0, 1] [mm].
fn path_at(s: f64) -> Vector3<f64> {
    v(
        300.0 + 3.0 * (2.0 * PI * s).sin(),
        5.0 * s * s,
        60.0 - 50.0 * s,
    )
}

/// A polyline with its cumulative arc length, evaluated by arc length.
struct Polyline {
    points: Vec<Vector3<f64>>,
    length: Vec<f64>,
}

impl Polyline {
    fn new(points: Vec<Vector3<f64>>) -> Self {
        let mut length = vec![0.0];
        for w in points.windows(2) {
            length.push(length.last().copied().unwrap_or(0.0) + (w[1] - w[0]).norm());
        }
        Self { points, length }
    }

    fn total(&self) -> f64 {
        self.length.last().copied().unwrap_or(0.0)
    }

    fn at(&self, c: f64) -> Vector3<f64> {
        let c = c.clamp(0.0, self.total());
        let i = self
            .length
            .partition_point(|&l| l <= c)
            .clamp(1, self.points.len() - 1);
        let (l0, l1) = (self.length[i - 1], self.length[i]);
        let t = if l1 > l0 { (c - l0) / (l1 - l0) } else { 0.0 };
        self.points[i - 1].lerp(&self.points[i], t)
    }

    /// The points up to arc length `c`, ending exactly at `c`.
    fn up_to(&self, c: f64) -> Vec<Vector3<f64>> {
        let mut out: Vec<Vector3<f64>> = self
            .points
            .iter()
            .zip(&self.length)
            .take_while(|(_, l)| **l < c)
            .map(|(p, _)| *p)
            .collect();
        out.push(self.at(c));
        out
    }
}

/// Distance from `p` to the polyline through `points` [mm].
fn distance_to_polyline(p: &Vector3<f64>, points: &[Vector3<f64>]) -> f64 {
    if points.len() == 1 {
        return (p - points[0]).norm();
    }
    points
        .windows(2)
        .map(|w| {
            let d = w[1] - w[0];
            let t = ((p - w[0]).dot(&d) / d.norm_squared().max(1e-300)).clamp(0.0, 1.0);
            (p - (w[0] + t * d)).norm()
        })
        .fold(f64::INFINITY, f64::min)
}

/// The prescribed displacement field of one step, as a function of the rest position.
struct Field {
    /// Entry point (rest) and insertion direction (unit).
    entry: Vector3<f64>,
    dir: Vector3<f64>,
    /// Dimple amplitude along `dir` [mm].
    dimple: f64,
    /// Drag amplitude along the shaft [mm] and the inserted shaft (rest positions).
    drag: f64,
    shaft: Vec<Vector3<f64>>,
}

impl Field {
    fn displacement(&self, x: &Vector3<f64>) -> Vector3<f64> {
        // The bottom face is fixed: the field vanishes linearly towards z = 0.
        let fixed = (x.z / 60.0).clamp(0.0, 1.0);
        let r2 = (x - self.entry).norm_squared();
        let mut amp = self.dimple * (-r2 / (2.0 * 7.0 * 7.0)).exp();
        if self.drag > 0.0 && self.shaft.len() > 1 {
            let d = distance_to_polyline(x, &self.shaft);
            amp += self.drag * (-d * d / (2.0 * 5.0 * 5.0)).exp();
        }
        self.dir * (amp * fixed)
    }

    fn apply(&self, x: &Vector3<f64>) -> Vector3<f64> {
        x + self.displacement(x)
    }
}

/// A closed cylinder along y (a vessel): nodes and outward triangles.
fn cylinder(
    centre: Vector3<f64>,
    radius: f64,
    half_length: f64,
    around: usize,
    along: usize,
) -> (Vec<Vector3<f64>>, Vec<[u32; 3]>) {
    let mut nodes = Vec::new();
    for j in 0..=along {
        let y = -half_length + 2.0 * half_length * j as f64 / along as f64;
        for i in 0..around {
            let a = 2.0 * PI * i as f64 / around as f64;
            nodes.push(centre + v(radius * a.cos(), y, radius * a.sin()));
        }
    }
    let id = |i: usize, j: usize| (j * around + i % around) as u32;
    let mut tris = Vec::new();
    for j in 0..along {
        for i in 0..around {
            // Outward: the ring's angle runs from +x towards +z, y grows with j.
            tris.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            tris.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    let start = nodes.len() as u32;
    nodes.push(centre - v(0.0, half_length, 0.0));
    nodes.push(centre + v(0.0, half_length, 0.0));
    for i in 0..around {
        tris.push([start, id(i + 1, 0), id(i, 0)]);
        tris.push([start + 1, id(i, along), id(i + 1, along)]);
    }
    (nodes, tris)
}

fn main() {
    let mut args = std::env::args().skip(1);
    let mut dir: Option<PathBuf> = None;
    let (mut nodes, mut frame_count) = (1500usize, 120usize);
    while let Some(a) = args.next() {
        let mut number = |name: &str| -> usize {
            args.next()
                .and_then(|s| s.parse().ok())
                .unwrap_or_else(|| panic!("{name} needs a positive integer"))
        };
        match a.as_str() {
            "--nodes" => nodes = number("--nodes"),
            "--frames" => frame_count = number("--frames").max(2),
            _ if dir.is_none() => dir = Some(PathBuf::from(a)),
            _ => panic!("usage: replay_demo DIR [--nodes N] [--frames F]"),
        }
    }
    let dir = dir.expect("usage: replay_demo DIR [--nodes N] [--frames F]");
    std::fs::create_dir_all(&dir).expect("create the output folder");

    // Gel: the benchmark box and its boundary surface.
    let mesh = box_mesh(v(260.0, -30.0, 0.0), v(340.0, 30.0, 60.0), nodes);
    let surface = SurfaceMap::from_triangles(&mesh.surface_triangles()).expect("surface");
    let rest_surface = surface.gather(&mesh.nodes).expect("surface nodes");

    // Path: the approach in the air, then the complex path through the gel.
    let entry = path_at(0.0);
    let dir_in = (path_at(1e-6) - entry).normalize();
    let start = entry - APPROACH * dir_in;
    let mut rest_path = vec![start];
    rest_path.extend((0..=200).map(|i| path_at(i as f64 / 200.0)));
    let path = Polyline::new(rest_path);
    let puncture_c = APPROACH + PUNCTURE_DEPTH;
    let end_c = path.total() + PUNCTURE_DEPTH;
    let steps = (end_c / ADVANCE).ceil() as u32;

    let spheres = [
        ("upper", v(298.0, 0.3125, 47.5)),
        ("middle", v(305.0, 1.25, 35.0)),
    ];
    let (vessel_nodes, vessel_tris) = cylinder(v(285.0, 0.0, 28.0), 2.5, 22.0, 16, 8);

    // One step of the prescribed motion: the field, the target, the tip, the needle, the depth.
    struct Step {
        field: Field,
        target: Vector3<f64>,
        needle: Vec<Vector3<f64>>,
        depth: f64,
        inside: bool,
    }
    let step_state = |k: u32| -> Step {
        let c = ADVANCE * f64::from(k + 1);
        let punctured = c >= puncture_c;
        // Path length inserted past the entry point.
        let inserted = if punctured { c - puncture_c } else { 0.0 };
        let since = (c - puncture_c) / ADVANCE; // steps since puncture
        let dimple = if c < APPROACH {
            0.0
        } else if !punctured {
            c - APPROACH
        } else {
            0.8 + (PUNCTURE_DEPTH - 0.8) * (-since / 15.0).exp()
        };
        let shaft = path.up_to(APPROACH + inserted);
        let field = Field {
            entry,
            dir: dir_in,
            dimple,
            drag: if punctured { 0.6 } else { 0.0 },
            shaft: shaft.iter().skip(1).copied().collect(),
        };
        let (target, tip, depth) = if c < APPROACH {
            (path.at(c), path.at(c), 0.0)
        } else if !punctured {
            let tip = field.apply(&entry);
            (tip, tip, 0.0)
        } else {
            let target = field.apply(&path.at(APPROACH + inserted));
            // Tracking error: grows on the first bend, a bump in the middle, small at the end.
            let e = 0.35
                + 0.5 * (2.0 * PI * inserted / 17.0).sin().abs()
                + 2.2 * (-((inserted - 24.0) / 5.0).powi(2)).exp();
            let t = (path.at(APPROACH + inserted + 0.5) - path.at(APPROACH + inserted - 0.5))
                .normalize();
            let l1 = t.cross(&Vector3::y()).normalize();
            let l2 = t.cross(&l1);
            let phi = inserted / 9.0;
            (
                target,
                target + e * (phi.cos() * l1 + phi.sin() * l2),
                inserted,
            )
        };
        // The needle: inside, along the deformed path bent towards the tip; outside, straight
        // along the entry direction up to its length; sampled at its beam nodes.
        let mut centre_line: Vec<Vector3<f64>> = if punctured {
            let inside: Vec<Vector3<f64>> = shaft[1..].iter().map(|x| field.apply(x)).collect();
            let n = inside.len().max(2) as f64 - 1.0;
            let offset = tip - inside.last().copied().unwrap_or(tip);
            inside
                .iter()
                .enumerate()
                .map(|(i, p)| p + offset * (i as f64 / n).powi(2))
                .collect()
        } else {
            vec![tip]
        };
        let entry_now = centre_line[0];
        let used = Polyline::new(centre_line.clone()).total();
        centre_line.insert(0, entry_now - (NEEDLE_LENGTH - used) * dir_in);
        let line = Polyline::new(centre_line);
        let needle = (0..=NEEDLE_BEAMS)
            .map(|i| line.at(line.total() * i as f64 / NEEDLE_BEAMS as f64))
            .collect();
        Step {
            field,
            target,
            needle,
            depth,
            inside: punctured,
        }
    };

    // The error of every step, and the frames at evenly spaced steps (the first and the last).
    let mut error = ErrorSeries::default();
    let (mut e_sum, mut e_max, mut e_count) = (0.0, 0.0f64, 0usize);
    for k in 0..steps {
        let s = step_state(k);
        let tip = *s.needle.last().expect("needle nodes");
        let e = if s.inside {
            (tip - s.target).norm()
        } else {
            f64::NAN
        };
        if e.is_finite() {
            e_sum += e;
            e_max = e_max.max(e);
            e_count += 1;
        }
        error.steps.push(k);
        error.depth.push(s.depth);
        error.error.push(e);
    }
    let frames: Vec<ReplayFrame> = (0..frame_count)
        .map(|i| {
            let k = ((i as f64) * f64::from(steps - 1) / (frame_count - 1) as f64).round() as u32;
            let s = step_state(k);
            ReplayFrame {
                time: DT * f64::from(k + 1),
                step: k,
                surface: rest_surface.iter().map(|x| s.field.apply(x)).collect(),
                needle: s.needle,
                path: path.points.iter().map(|x| s.field.apply(x)).collect(),
                target: s.target,
                sphere_centres: spheres.iter().map(|(_, c)| s.field.apply(c)).collect(),
                mesh_nodes: vec![vessel_nodes.iter().map(|x| s.field.apply(x)).collect()],
            }
        })
        .collect();

    let puncture_step = (puncture_c / ADVANCE).ceil() as u32 - 1;
    let data = ReplayData {
        title: format!(
            "Replay demo · complex path · {} gel nodes (synthetic)",
            mesh.node_count()
        ),
        summary: vec![
            (
                "scene".into(),
                "synthetic demo: prescribed motion, not a simulation".into(),
            ),
            (
                "gel".into(),
                format!(
                    "{} nodes, {} on the surface, {} surface triangles",
                    mesh.node_count(),
                    surface.nodes.len(),
                    surface.triangles.len()
                ),
            ),
            (
                "path".into(),
                "x = 300 + 3 sin(2πs), y = 5 s², z = 60 − 50 s [mm]".into(),
            ),
            (
                "steps".into(),
                format!("{steps} (dt {DT} s, {ADVANCE} mm per step)"),
            ),
            ("frames".into(), frame_count.to_string()),
            (
                "puncture".into(),
                format!("step {puncture_step}, {PUNCTURE_DEPTH} mm indentation"),
            ),
            (
                "tracking error".into(),
                format!(
                    "mean {:.3} mm, max {:.3} mm",
                    e_sum / e_count.max(1) as f64,
                    e_max
                ),
            ),
            (
                "obstacles".into(),
                "spheres upper, middle (r 2 mm); vessel (surface)".into(),
            ),
        ],
        surface_triangles: surface.triangles.clone(),
        spheres: spheres
            .iter()
            .map(|(name, _)| SphereObstacle {
                name: (*name).into(),
                radius: 2.0,
            })
            .collect(),
        meshes: vec![MeshObstacle {
            name: "vessel".into(),
            triangles: vessel_tris,
        }],
        error,
        error_references: vec![
            ReferenceLine {
                label: "paper, complex: e_mean 2.6 mm".into(),
                value: 2.6,
            },
            ReferenceLine {
                label: "paper, complex: e_max 6.0 mm".into(),
                value: 6.0,
            },
        ],
        frames,
    };
    let file = dir.join("replay.html");
    write_replay(&file, &data).unwrap_or_else(|e| panic!("{e}"));

    let html = std::fs::read_to_string(&file).expect("read the replay back");
    assert!(html.contains(SCHEMA), "the replay holds its data");
    println!(
        "wrote {} ({} bytes): {} frames of {} steps, {} surface nodes, {} triangles",
        file.display(),
        html.len(),
        data.frames.len(),
        steps,
        surface.nodes.len(),
        surface.triangles.len()
    );
}

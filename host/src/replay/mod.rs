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

mod encode;
mod surface;

pub use encode::{base64, replay_html, replay_json, write_replay};
pub use surface::SurfaceMap;

use nalgebra::Vector3;

/// The HTML template of the replay, with exactly one [`PLACEHOLDER`].
pub const TEMPLATE: &str = include_str!("../../assets/replay.html");

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

#[cfg(test)]
mod tests;

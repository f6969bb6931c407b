//! Why a set-up or a step failed: one enum per layer, each variant naming what failed and
//! carrying the error underneath as its `source()` (the FE layer's [`FemError`], the mesh's,
//! the transport's). [`chain`] writes an error with its sources, as the CLI prints it.

// Units are written in brackets ([mm], [N]) as in the workspace style: not intra-doc links.
#![allow(rustdoc::broken_intra_doc_links)]

use crate::fem::FemError;
use crate::mesh::{MeshError, MeshFileError};
use crate::scene::PathError;
use nalgebra::Vector3;
use needle_bridge::TransportError;
use needle_core::ik::IkError;
use needle_core::payload::ValidationError;
use std::path::PathBuf;

/// One of the two FE bodies.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Body {
    /// The gel (corotational tetrahedra).
    Gel,
    /// The needle (corotational beams).
    Needle,
}

impl std::fmt::Display for Body {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Gel => "gel",
            Self::Needle => "needle",
        })
    }
}

/// Why a scene could not be turned into a world (see [`crate::setup`]).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SetupError {
    /// The scene's robot cannot be built (its URDF).
    #[error("robot: field `{field}`: {reason}")]
    Robot {
        /// The scene field.
        field: String,
        /// Why (naming the URDF file).
        reason: String,
    },
    /// The planned path could not be sampled.
    #[error("the path cannot be sampled")]
    Path(#[source] PathError),
    /// The scene names no gel mesh.
    #[error("the scene has no gel mesh")]
    NoMesh,
    /// The mesh file of the gel (Gmsh, `.vtu` or `.vtk`) could not be read.
    #[error("gel mesh {}", file.display())]
    MeshFile {
        /// The file.
        file: PathBuf,
        /// Why.
        #[source]
        source: MeshFileError,
    },
    /// The gel mesh is invalid.
    #[error("gel mesh")]
    Mesh(#[source] MeshError),
    /// A node listed in `gel.fixed.nodes` does not exist.
    #[error("gel.fixed.nodes: node {node} does not exist ({nodes} nodes)")]
    FixedNodeMissing {
        /// The listed node.
        node: usize,
        /// Nodes of the mesh.
        nodes: usize,
    },
    /// No node of the gel is fixed: its stiffness would be singular.
    #[error("gel.fixed: no node of the mesh is fixed")]
    NothingFixed,
    /// The inverse kinematics of the start pose failed.
    #[error("start pose")]
    StartPose(#[source] IkError),
    /// The start pose is out of the robot's reach.
    #[error(
        "start pose out of reach: needle base ({:.3}, {:.3}, {:.3}) mm along ({:.4}, {:.4}, {:.4}): \
         IK stopped {position_error:.3} mm / {angle_error:.2e} rad away",
        base.x, base.y, base.z, axis.x, axis.y, axis.z
    )]
    StartOutOfReach {
        /// Needle base the IK aimed at [mm].
        base: Vector3<f64>,
        /// Needle axis it aimed at.
        axis: Vector3<f64>,
        /// Where the IK stopped: position error [mm].
        position_error: f64,
        /// Angle error [rad].
        angle_error: f64,
    },
    /// The path's entry point is not on the gel.
    #[error("the path's entry point {} is not on the gel", mm(.0))]
    EntryOffGel(Vector3<f64>),
    /// An obstacle's centre is not inside the gel.
    #[error("obstacles[{index}]: centre {} is not inside the gel", mm(center))]
    ObstacleOutside {
        /// Index in the scene's list.
        index: usize,
        /// Its centre [mm].
        center: Vector3<f64>,
    },
    /// A vertex of an obstacle's surface mesh is not inside the gel.
    #[error(
        "obstacles[{index}].mesh: vertex {vertex}{} at {} (after `scale` and `translation`) is not inside the gel: a mesh obstacle must lie wholly in the gel, each vertex embedded in an element",
        node_tag.map(|t| format!(" (gmsh node {t})")).unwrap_or_default(),
        mm(point)
    )]
    ObstacleVertexOutside {
        /// Index in the scene's list.
        index: usize,
        /// Vertex of the surface (duplicates merged).
        vertex: usize,
        /// Its node tag in a Gmsh file.
        node_tag: Option<u64>,
        /// Its rest position [mm].
        point: Vector3<f64>,
    },
    /// An obstacle's surface mesh file cannot be used.
    #[error("obstacles[{index}].mesh: {}: {reason}", file.display())]
    ObstacleMesh {
        /// Index in the scene's list.
        index: usize,
        /// The file.
        file: PathBuf,
        /// Why.
        reason: String,
    },
    /// The scene's plan cannot work: a path outside the gel or into its fixed part, an
    /// obstacle on the path, a needle too short for the insertion, a mesh in the wrong unit.
    #[error("{field}: {reason}")]
    Plan {
        /// The scene field at fault.
        field: String,
        /// Why, in plain units.
        reason: String,
    },
    /// An FE model could not be built.
    #[error("the {body} model cannot be built")]
    Model {
        /// Which.
        body: Body,
        /// Why.
        #[source]
        source: FemError,
    },
}

/// A point on one line in millimetres (nalgebra's `Display` draws a matrix over several lines).
pub fn mm(v: &Vector3<f64>) -> String {
    format!("({:.2}, {:.2}, {:.2}) mm", v.x, v.y, v.z)
}

/// Which stage of a step found a non-finite value.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NonFiniteAt {
    /// The free motion `Δx_free`.
    FreeMotion,
    /// The positions after the corrective motion.
    Correction,
}

/// What in a command does not answer the frame it was received for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CommandMismatch {
    /// Another payload version.
    Version,
    /// It answers another frame.
    Sequence,
    /// Another row count.
    RowCount,
    /// A joint or a constraint force is NaN or infinite.
    NonFinite,
}

impl std::fmt::Display for CommandMismatch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Version => "version",
            Self::Sequence => "sequence",
            Self::RowCount => "row count",
            Self::NonFinite => "non-finite value",
        })
    }
}

/// Why a step failed (see [`crate::step::Pipeline::step`]); the world may then be half-way
/// through the step and should not be stepped again.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SimError {
    /// A body's free motion failed: its matrix is not positive definite
    /// ([`FemError::NotPositiveDefinite`]), or its factorisation thread stopped
    /// ([`FemError::WorkerStopped`]).
    #[error("free motion of the {body}")]
    FreeMotion {
        /// Which body.
        body: Body,
        /// Why.
        #[source]
        source: FemError,
    },
    /// A compliance solve (`K⁻¹ Pᵀ` of a constrained point) failed.
    #[error("compliance of the {body}")]
    Compliance {
        /// Which body.
        body: Body,
        /// Why.
        #[source]
        source: FemError,
    },
    /// The state became non-finite.
    #[error("the simulation became non-finite ({})", match .0 {
        NonFiniteAt::FreeMotion => "free motion",
        NonFiniteAt::Correction => "positions after correction",
    })]
    NonFinite(NonFiniteAt),
    /// More constraint rows than the frame holds.
    #[error("{rows} constraint rows exceed the capacity of {capacity}")]
    Capacity {
        /// Rows needed.
        rows: usize,
        /// Capacity.
        capacity: usize,
    },
    /// The frame built for the core is invalid (e.g. its `W` is not positive definite on the
    /// base rows).
    #[error("invalid frame")]
    InvalidFrame(#[source] ValidationError),
    /// The transport did not bring a command back (the in-process core rejected the frame, a
    /// remote one did not answer in time, shared memory failed).
    #[error("constraint solve")]
    Transport(#[source] TransportError),
    /// The command received does not answer the frame; the state is unchanged.
    #[error("the command does not answer the frame: {0}")]
    Command(CommandMismatch),
    /// The tip punctured the surface at a point that is not on the gel.
    #[error("punctured at {}, which is not on the gel", mm(.0))]
    PunctureOffGel(Vector3<f64>),
}

impl SimError {
    /// For `map_err`: the free motion of `body` failed.
    pub(crate) fn in_free_motion(body: Body) -> impl FnOnce(FemError) -> Self {
        move |source| Self::FreeMotion { body, source }
    }

    /// For `map_err`: a compliance solve of `body` failed.
    pub(crate) fn in_compliance(body: Body) -> impl FnOnce(FemError) -> Self {
        move |source| Self::Compliance { body, source }
    }
}

/// An error and its sources on one line, `outer: inner: …` (as the CLI prints errors). A
/// source whose message its outer error already ends with (errors that both print and return
/// their source, as the bridge's `TransportError` does) is not repeated.
///
/// # Example
/// ```
/// use needle_host::error::{Body, SimError, chain};
/// use needle_host::fem::FemError;
///
/// let e = SimError::FreeMotion { body: Body::Gel, source: FemError::NotPositiveDefinite { pivot: 3 } };
/// assert_eq!(
///     chain(&e),
///     "free motion of the gel: the system matrix is not positive definite (non-positive pivot at permuted column 3)"
/// );
/// ```
pub fn chain(e: &dyn std::error::Error) -> String {
    let mut s = e.to_string();
    let mut next = e.source();
    while let Some(c) = next {
        let m = c.to_string();
        if !s.ends_with(&m) {
            s.push_str(": ");
            s.push_str(&m);
        }
        next = c.source();
    }
    s
}

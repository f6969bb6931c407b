//! Mesh validation: every element must reference existing nodes, be positively oriented and
//! non-degenerate, and appear once; every node must be used.

// Negated comparisons are deliberate: NaN must fail every validity check.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::nonminimal_bool)]

use super::TetMesh;
use std::fmt;

/// Elements whose normalised volume `6√2 · V / ℓ_max³` (1 for a regular tetrahedron) is below
/// this threshold are rejected as degenerate.
pub const fn degenerate_ratio_threshold() -> f64 {
    1e-6
}

/// What is wrong with a mesh; each variant names the element or node at fault.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub enum MeshError {
    /// The mesh has no element.
    Empty,
    /// A node coordinate is NaN or infinite.
    NonFiniteNode {
        /// Index of the node.
        node: usize,
    },
    /// An element references a node that does not exist.
    NodeIndexOutOfRange {
        /// Index of the element.
        element: usize,
        /// The offending node index.
        node: usize,
        /// Number of nodes in the mesh.
        node_count: usize,
    },
    /// An element uses the same node twice, or has (near-)zero volume relative to its longest
    /// edge cubed.
    DegenerateElement {
        /// Index of the element.
        element: usize,
        /// Signed volume [mm³].
        volume: f64,
        /// Normalised volume `6√2 · V / ℓ_max³` (1 for a regular tetrahedron).
        quality: f64,
    },
    /// An element has negative volume (wrong node order or inverted).
    InvertedElement {
        /// Index of the element.
        element: usize,
        /// Signed volume [mm³].
        volume: f64,
    },
    /// Two elements share the same four nodes.
    DuplicateElement {
        /// Index of the later element.
        element: usize,
        /// Index of the earlier element with the same node set.
        first: usize,
    },
    /// A node is used by no element.
    UnreferencedNode {
        /// Index of the node.
        node: usize,
    },
    /// Two elements sharing a face lie on the same side of it: the mesh folds over itself there
    /// (a node moved through its neighbours).
    TangledElement {
        /// Index of the later element.
        element: usize,
        /// The element on the same side of their shared face.
        neighbour: usize,
    },
    /// A face is shared by more than two elements (the mesh is not a manifold volume there).
    OvershareFace {
        /// Index of the third element on the face.
        element: usize,
    },
    /// The region list does not give one tag per element.
    RegionCount {
        /// Region tags given.
        regions: usize,
        /// Elements of the mesh.
        elements: usize,
    },
}

impl fmt::Display for MeshError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Self::Empty => write!(f, "mesh has no tetrahedron"),
            Self::NonFiniteNode { node } => write!(f, "node {node} has a non-finite coordinate"),
            Self::NodeIndexOutOfRange {
                element,
                node,
                node_count,
            } => {
                write!(
                    f,
                    "element {element} references node {node}, but the mesh has {node_count} nodes"
                )
            }
            Self::DegenerateElement {
                element,
                volume,
                quality,
            } => write!(
                f,
                "element {element} is degenerate (volume {volume:e} mm³, normalised quality {quality:e})"
            ),
            Self::InvertedElement { element, volume } => {
                write!(
                    f,
                    "element {element} is inverted (volume {volume:e} mm³ < 0)"
                )
            }
            Self::DuplicateElement { element, first } => {
                write!(
                    f,
                    "element {element} duplicates element {first} (same node set)"
                )
            }
            Self::UnreferencedNode { node } => write!(f, "node {node} is used by no element"),
            Self::TangledElement { element, neighbour } => write!(
                f,
                "element {element} overlaps element {neighbour} (both on the same side of their shared face: the mesh is tangled)"
            ),
            Self::OvershareFace { element } => write!(
                f,
                "element {element} shares a face already shared by two other elements"
            ),
            Self::RegionCount { regions, elements } => write!(
                f,
                "{regions} region tags for {elements} elements (one per element is needed)"
            ),
        }
    }
}

impl std::error::Error for MeshError {}

impl MeshError {
    /// The element at fault, when the error names one.
    pub fn element(&self) -> Option<usize> {
        match *self {
            Self::NodeIndexOutOfRange { element, .. }
            | Self::DegenerateElement { element, .. }
            | Self::InvertedElement { element, .. }
            | Self::DuplicateElement { element, .. }
            | Self::TangledElement { element, .. }
            | Self::OvershareFace { element } => Some(element),
            Self::Empty
            | Self::NonFiniteNode { .. }
            | Self::UnreferencedNode { .. }
            | Self::RegionCount { .. } => None,
        }
    }
}

impl TetMesh {
    /// Checks the mesh invariants (see [`MeshError`]) in this order: non-empty, one region tag
    /// per element, finite nodes, node indices in range, degenerate, inverted, duplicate
    /// elements, unreferenced nodes.
    ///
    /// # Errors
    /// The first problem found.
    pub fn validate(&self) -> Result<(), MeshError> {
        if self.tets.is_empty() {
            return Err(MeshError::Empty);
        }
        if self.regions.len() != self.tets.len() {
            return Err(MeshError::RegionCount {
                regions: self.regions.len(),
                elements: self.tets.len(),
            });
        }
        let n = self.nodes.len();
        if let Some(node) = self
            .nodes
            .iter()
            .position(|p| !p.iter().all(|c| c.is_finite()))
        {
            return Err(MeshError::NonFiniteNode { node });
        }
        for (element, t) in self.tets.iter().enumerate() {
            if let Some(&node) = t.iter().find(|&&v| v >= n) {
                return Err(MeshError::NodeIndexOutOfRange {
                    element,
                    node,
                    node_count: n,
                });
            }
        }
        for (element, t) in self.tets.iter().enumerate() {
            let volume = self.tet_volume(element);
            let mut lmax2: f64 = 0.0;
            for i in 0..4 {
                for j in i + 1..4 {
                    lmax2 = lmax2.max((self.nodes[t[i]] - self.nodes[t[j]]).norm_squared());
                }
            }
            let quality = if lmax2 > 0.0 {
                6.0 * std::f64::consts::SQRT_2 * volume / (lmax2 * lmax2.sqrt())
            } else {
                0.0
            };
            let repeated = (0..4).any(|i| (i + 1..4).any(|j| t[i] == t[j]));
            if repeated || !(quality.abs() >= degenerate_ratio_threshold()) {
                return Err(MeshError::DegenerateElement {
                    element,
                    volume,
                    quality,
                });
            }
            if volume < 0.0 {
                return Err(MeshError::InvertedElement { element, volume });
            }
        }
        let mut seen = std::collections::HashMap::with_capacity(self.tets.len());
        for (element, t) in self.tets.iter().enumerate() {
            let mut key = *t;
            key.sort_unstable();
            if let Some(&first) = seen.get(&key) {
                return Err(MeshError::DuplicateElement { element, first });
            }
            seen.insert(key, element);
        }
        let mut used = vec![false; n];
        for t in &self.tets {
            for &v in t {
                used[v] = true;
            }
        }
        if let Some(node) = used.iter().position(|u| !u) {
            return Err(MeshError::UnreferencedNode { node });
        }
        self.check_folds()
    }

    /// Every interior face has its two elements on opposite sides (a positively oriented mesh
    /// can still fold over itself: each element positive, their union overlapping).
    fn check_folds(&self) -> Result<(), MeshError> {
        const FACES: [[usize; 3]; 4] = [[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]];
        let mut faces: std::collections::HashMap<[usize; 3], usize> =
            std::collections::HashMap::with_capacity(2 * self.tets.len());
        for (element, t) in self.tets.iter().enumerate() {
            for (opposite, f) in FACES.iter().enumerate() {
                let mut key = f.map(|i| t[i]);
                key.sort_unstable();
                let Some(&neighbour) = faces.get(&key) else {
                    faces.insert(key, element);
                    continue;
                };
                if neighbour == usize::MAX {
                    return Err(MeshError::OvershareFace { element });
                }
                faces.insert(key, usize::MAX);
                let p = key.map(|v| self.nodes[v]);
                let side = |apex: usize| {
                    super::signed_volume(&p[0], &p[1], &p[2], &self.nodes[apex]).signum()
                };
                let other = self.tets[neighbour]
                    .iter()
                    .copied()
                    .find(|v| !key.contains(v))
                    .unwrap_or(key[0]);
                if side(t[opposite]) == side(other) {
                    return Err(MeshError::TangledElement { element, neighbour });
                }
            }
        }
        Ok(())
    }
}

//! The gel's boundary surface in the replay's compact form.

use super::{ReplayError, invalid};
use nalgebra::Vector3;

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

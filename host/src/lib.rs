//! `needle-host`: the FE half of the simulation.

pub mod scene;
pub mod fem;
pub mod free_motion;
pub mod linalg;
pub mod mesh;

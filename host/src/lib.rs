//! `needle-host`: the FE half of the simulation.

pub mod bodies;
pub mod compliance;
pub mod constraints;
pub mod fem;
pub mod free_motion;
pub mod linalg;
pub mod mesh;
pub mod output;
pub mod proximity;
pub mod replay;
pub mod report;
pub mod run;
pub mod scene;
pub mod world;

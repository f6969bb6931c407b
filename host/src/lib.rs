//! `needle-host`: the FE half of the simulation.

pub mod scene;

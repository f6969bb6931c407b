//! `needle-host`: the FE half of the simulation.
//!
//! A run goes one way, down: a [`scene::Scene`] file is read by [`setup`] into a [`world::World`]
//! (state) and typed parameters ([`step::StepParams`], the FE models', the core's); a
//! [`step::Pipeline`] steps the world through a transport to the core ([`step`]: the paper's
//! Algorithm 1); [`run`] loops over the steps with its observers (metrics, VTK, summary).

pub mod accuracy;
mod bounded_read;
pub mod compliance;
pub mod constraints;
pub mod cpu;
pub mod error;
pub mod fem;
pub mod free_motion;
pub mod joints;
pub mod linalg;
pub mod logs;
pub mod mesh;
pub mod obstacle_mesh;
pub mod open_loop;
pub mod output;
pub mod plan_check;
pub mod provenance;
pub mod proximity;
pub mod replay;
pub mod report;
pub mod robot;
pub mod run;
pub mod scene;
pub mod setup;
pub mod step;
pub mod straighten;
pub mod suite;
pub mod support_motion;
pub mod world;

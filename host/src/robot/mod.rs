//! Robots described by files: [`urdf`] reads a URDF into a core [`needle_core::SerialChain`].

pub mod urdf;

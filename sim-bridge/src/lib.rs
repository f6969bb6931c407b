//! `needle-bridge`: frames and commands between the FE host and the core, in one process or
//! over iceoryx2 shared memory between two.
//!
//! - [`Transport`]: the host's one interface to the core — [`InProcess`] (a
//!   [`needle_core::inverse::Controller`] called directly) or [`SharedMemoryHost`] (publish the
//!   frame, wait lock-step for the command answering it);
//! - [`payload`]: the core's payloads as iceoryx2 zero-copy payloads (transparent newtypes,
//!   versioned type names `needle.ComplianceFrame.v2`, `needle.Command.v2`) and their headers;
//! - [`shm`]: the two publish-subscribe services, dead-node cleanup, the host's end;
//! - [`controller`]: the core's end — the fixed-rate controller loop with its faults (hold on a
//!   missing frame, rejected frames counted, restarted hosts picked up).
//!
//! `needle-bridge` depends on `needle-core` and iceoryx2 only. The controller *binary*
//! (`needle-controller`) lives in `needle-host`'s bin folder because it reads the same scene file
//! as `needle serve` to build the robot chain and the inverse tuning; at run time it uses only
//! this crate and the core. The frames carry a fingerprint of that set-up
//! ([`payload::setup_fingerprint`]), so a controller started with another scene refuses them.

/// The iceoryx2 this crate is built with (to open its services with matching types).
pub use iceoryx2;

pub mod controller;
pub mod payload;
pub mod plausible;
pub mod shm;
pub mod transport;

pub use controller::{
    ControllerNode, ControllerOptions, ControllerStats, Rejection, run_controller,
};
pub use payload::{
    CommandHeader, CommandKind, CommandPayload, FrameHeader, FramePayload, setup_fingerprint,
};
pub use shm::{BridgeConfig, HostStats, SharedMemoryHost, Wait};
pub use transport::{ExchangeReport, InProcess, Transport, TransportError};

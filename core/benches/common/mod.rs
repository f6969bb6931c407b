//! Shared bench setup: seeded synthetic frames in boxes (never on the stack).

#![allow(dead_code)]

use needle_core::synthetic::random_frame;
use needle_core::{Command, ComplianceFrame, Controller, DhChain, InverseParams};

/// Capacity used by the benches: the host's (`needle_host::step::ROWS`), so that strides and
/// cache footprint are production's.
pub const M: usize = 192;

/// Benchmark pose (wrist away from the J5 = 0 singularity).
pub const Q: [f64; 6] = [0.1, 0.3, 2.0, 0.0, 0.5, 0.0];

/// A boxed frame of `m` rows with the production layout, seeded.
pub fn frame(m: usize, seed: u64) -> Box<ComplianceFrame<M>> {
    let mut f = ComplianceFrame::new_boxed();
    random_frame(&mut f, &DhChain::rv1a(), &Q, m, seed, false);
    f
}

/// A boxed zero command.
pub fn command() -> Box<Command<M>> {
    Command::new_boxed()
}

/// A boxed RV-1A controller with default tuning.
pub fn controller() -> Box<Controller<M>> {
    Controller::new_boxed(DhChain::rv1a(), InverseParams::default())
}

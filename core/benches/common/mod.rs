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

/// Two boxed frames of `m` rows a control period apart: the seeded frame, and the same frame
/// with the free violations of the constraint rows moved by up to 1 % and the joints by
/// 0.002 rad, as consecutive frames of an insertion differ. Stepping them in turn keeps every
/// warm start one frame old, where stepping one frame again and again hands each solve its own
/// last answer.
pub fn drifting_frames(m: usize, seed: u64) -> [Box<ComplianceFrame<M>>; 2] {
    let a = frame(m, seed);
    let mut b = frame(m, seed);
    let mut state = seed ^ 0x9e37_79b9_7f4a_7c15;
    let rows = b.rows();
    for d in &mut b.delta_free[6..rows] {
        state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1);
        let u = (state >> 11) as f64 / (1u64 << 53) as f64;
        *d *= 1.0 + 0.02 * (u - 0.5);
    }
    // The base rows' violation follows the joints within the step.
    b.q = core::array::from_fn(|i| Q[i] + 0.002);
    [a, b]
}

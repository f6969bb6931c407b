//! Shared bench setup: seeded synthetic frames in boxes (never on the stack).

#![allow(dead_code)]

use needle_core::synthetic::random_frame;
use needle_core::{Command, ComplianceFrame, Controller, DhChain, InverseParams};
use std::mem::MaybeUninit;

/// Capacity used by the benches.
pub const M: usize = 128;

/// Benchmark pose (wrist away from the J5 = 0 singularity).
pub const Q: [f64; 6] = [0.1, 0.3, 2.0, 0.0, 0.5, 0.0];

/// A boxed frame of `m` rows with the production layout, seeded.
pub fn frame(m: usize, seed: u64) -> Box<ComplianceFrame<M>> {
    let mut b = Box::new(MaybeUninit::<ComplianceFrame<M>>::uninit());
    let f = ComplianceFrame::init_in_place(&mut b);
    random_frame(f, &DhChain::rv1a(), &Q, m, seed, false);
    // SAFETY: initialised by `init_in_place`.
    unsafe { b.assume_init() }
}

/// A boxed zero command.
pub fn command() -> Box<Command<M>> {
    let mut b = Box::new(MaybeUninit::<Command<M>>::uninit());
    Command::init_in_place(&mut b);
    // SAFETY: initialised by `init_in_place`.
    unsafe { b.assume_init() }
}

/// A boxed RV-1A controller with default tuning.
pub fn controller() -> Box<Controller<M>> {
    let mut b = Box::new(MaybeUninit::<Controller<M>>::uninit());
    Controller::init_in_place(&mut b, DhChain::rv1a(), InverseParams::default());
    // SAFETY: initialised by `init_in_place`.
    unsafe { b.assume_init() }
}

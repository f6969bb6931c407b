//! The core's large payloads and controller, built in place on the heap (≈ 300 KiB each at
//! [`ROWS`]: never on the stack). The one place of the host that does it.

use crate::step::ROWS;
use needle_core::inverse::{Controller, InverseParams};
use needle_core::kinematics::DhChain;
use needle_core::payload::{Command, ComplianceFrame, JOINTS};

/// An all-zero frame.
pub fn frame() -> Box<ComplianceFrame<ROWS>> {
    let mut b = Box::<ComplianceFrame<ROWS>>::new_uninit();
    ComplianceFrame::init_in_place(&mut b);
    // SAFETY: `init_in_place` initialised every field.
    unsafe { b.assume_init() }
}

/// An all-zero command.
pub fn command() -> Box<Command<ROWS>> {
    let mut b = Box::<Command<ROWS>>::new_uninit();
    Command::init_in_place(&mut b);
    // SAFETY: `init_in_place` initialised every field.
    unsafe { b.assume_init() }
}

/// A controller for `chain` with tuning `params`, no warm start.
pub fn controller(chain: DhChain<JOINTS>, params: InverseParams) -> Box<Controller<ROWS>> {
    let mut b = Box::<Controller<ROWS>>::new_uninit();
    Controller::init_in_place(&mut b, chain, params);
    // SAFETY: `init_in_place` initialised every field.
    unsafe { b.assume_init() }
}

//! The whole inverse step allocates nothing: a counting global allocator (thread-local counter,
//! so other test threads do not interfere) around `Controller::step`, after a warm-up.

use needle_core::synthetic::{random_frame, rv1a_on_turntable};
use needle_core::{
    Command, ComplianceFrame, Controller, DhChain, InverseParams, Kinematics, Robot, SerialChain,
};
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

struct Counting;

thread_local! {
    static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
}

// SAFETY: forwards to `System`, only counting calls.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let _ = ALLOCATIONS.try_with(|c| c.set(c.get() + 1));
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let _ = ALLOCATIONS.try_with(|c| c.set(c.get() + 1));
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocations() -> u64 {
    ALLOCATIONS.with(Cell::get)
}

const M: usize = 120;

/// Allocations counted over five `Controller::step`s on seeded random frames, after a warm-up.
fn step_allocations<const N: usize, K>(chain: K, q: [f64; N]) -> u64
where
    K: Kinematics<N> + Into<Robot<N>> + Copy,
{
    let mut frame = ComplianceFrame::<M, N>::new_boxed();
    let mut cmd = Command::<M, N>::new_boxed();
    let mut ctrl = Controller::<M, N>::new_boxed(chain, InverseParams::default());
    random_frame(&mut frame, &chain, &q, M, 42, false);
    // Warm up (lazy statics, first-touch of anything).
    ctrl.step(&frame, &mut cmd).expect("valid frame");
    let mut total = 0;
    for seed in 0..5 {
        random_frame(&mut frame, &chain, &q, M, seed, seed % 2 == 0);
        let before = allocations();
        let rep = ctrl.step(&frame, &mut cmd).expect("valid frame");
        total += allocations() - before;
        assert_eq!(rep.solves, N as u32 + 2);
    }
    total
}

#[test]
fn inverse_step_allocates_nothing() {
    let total = step_allocations(DhChain::rv1a(), [0.1, 0.3, 2.0, 0.0, 0.5, 0.0]);
    // Sanity check that the counter counts.
    let before = allocations();
    let v = std::hint::black_box(vec![1u8; 16]);
    drop(v);
    assert_eq!(
        allocations() - before,
        1,
        "the counting allocator must see allocations"
    );
    assert_eq!(total, 0, "Controller::step allocated");
}

/// The same for a 7-joint arm (`Controller<M, 7>`: J is 4×7, the step 7 joints).
#[test]
fn seven_joint_step_allocates_nothing() {
    let total = step_allocations(rv1a_on_turntable(), [0.1, 0.1, 0.3, 2.0, 0.0, 0.5, 0.0]);
    assert_eq!(total, 0, "Controller<M, 7>::step allocated");
}

/// A 7-joint general serial chain (origins and axes, as read from a URDF), whose step runs the
/// third, joint-limit stage of the QP update: nothing allocated either.
#[test]
fn seven_joint_serial_chain_step_allocates_nothing() {
    let chain = SerialChain::from_dh(&rv1a_on_turntable());
    let total = step_allocations(chain, [2.8, 0.1, 0.3, 2.0, 0.0, 0.5, 0.0]);
    assert_eq!(
        total, 0,
        "Controller<M, 7>::step over a SerialChain allocated"
    );
}

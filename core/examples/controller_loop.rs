//! A tiny controller loop: each period the "host" builds a compliance frame at the robot's
//! current joints (here `needle_core::synthetic::rigid_needle_frame`: a rigid needle hanging
//! on a spring at its base, the target being the needle tip at other joints), the core runs one
//! inverse step, and the robot moves to the commanded joints. The objective `|T|` (tip error
//! and weighted angle, mm) must fall to the target.
//!
//! ```sh
//! cargo run -p needle-core --example controller_loop --features alloc
//! ```

use needle_core::synthetic::rigid_needle_frame;
use needle_core::{Command, ComplianceFrame, Controller, DhChain, InverseParams, StatusFlags};

/// Row capacity: the rigid-needle frame uses the 6 base rows only.
const M: usize = 12;

fn main() {
    let chain = DhChain::rv1a();
    let q_target = [0.2, 0.35, 2.0, 0.1, 0.6, -0.2];
    let mut q = [0.3, 0.25, 2.1, 0.0, 0.5, -0.3];
    // Large values are built where they live, never on the stack.
    let mut frame = ComplianceFrame::<M>::new_boxed();
    let mut cmd = Command::<M>::new_boxed();
    let mut ctrl = Controller::<M>::new_boxed(chain, InverseParams::default());
    let mut history = Vec::new();
    for sequence in 0..12 {
        // Host: free motion at the current joints, 25 Hz control period.
        rigid_needle_frame(&mut frame, &chain, &q, &q_target, 120.0);
        frame.sequence = sequence;
        frame.dt = 0.04;
        // Core: one inverse step into the command.
        let report = ctrl.step(&frame, &mut cmd).expect("a valid frame");
        assert_eq!(cmd.frame_sequence, sequence);
        let t = report.objective;
        let norm = (t[0] * t[0] + t[1] * t[1] + t[2] * t[2] + t[3] * t[3]).sqrt();
        let note = if report.flags & StatusFlags::WITHIN_TOLERANCE != 0 {
            ", within tolerance: hold"
        } else if report.flags & StatusFlags::SATURATED_SPEED != 0 {
            ", speed-limited"
        } else {
            ""
        };
        println!(
            "step {sequence:2}: |T| = {norm:9.5} mm, {} solves{note}",
            report.solves
        );
        history.push(norm);
        // Robot: move to the commanded joints.
        q = cmd.q;
    }
    let (first, last) = (history[0], history[history.len() - 1]);
    assert!(first > 10.0, "the loop starts away from the target");
    assert!(last < 1e-3 * first, "|T| fell from {first} to only {last}");
    assert!(history.windows(2).all(|w| w[1] <= w[0]), "{history:?}");
    println!("|T| fell from {first:.3} mm to {last:.2e} mm");
}

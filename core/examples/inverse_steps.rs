//! Repeats the inverse step of the criterion bench (`benches/inverse.rs`: seeded frame, capacity
//! 192, warm from the previous step) `reps` times at `m` rows and prints the last report, a
//! checksum of the last λ (its sum, shortest round-trip digits: equal before and after a change
//! that keeps the results bitwise) and the wall time per step. For comparisons on a busy
//! machine, time the process's CPU time rather than the wall time:
//!
//! ```sh
//! cargo build --release -p needle-core --example inverse_steps
//! /usr/bin/time -f "%U s user" target/release/examples/inverse_steps 3000 120
//! ```

use needle_core::synthetic::random_frame;
use needle_core::{Command, ComplianceFrame, Controller, DhChain, InverseParams};

/// Row capacity of the benches and the host.
const M: usize = 192;

fn main() {
    let mut args = std::env::args().skip(1);
    let reps: usize = args
        .next()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1000)
        .max(1);
    let m: usize = args.next().and_then(|s| s.parse().ok()).unwrap_or(120);
    let q = [0.1, 0.3, 2.0, 0.0, 0.5, 0.0];
    let mut frame = ComplianceFrame::<M>::new_boxed();
    random_frame(&mut frame, &DhChain::rv1a(), &q, m, 11, false);
    let mut cmd = Command::<M>::new_boxed();
    let mut ctrl = Controller::<M>::new_boxed(DhChain::rv1a(), InverseParams::default());
    let start = std::time::Instant::now();
    let mut report = None;
    for _ in 0..reps {
        report = ctrl.step(&frame, &mut cmd).ok();
    }
    let per_step = start.elapsed().as_secs_f64() / reps as f64;
    let rows = frame.rows();
    let sum: f64 = cmd.lambda[..rows].iter().sum();
    match report {
        Some(r) => println!(
            "m = {rows}: {} solves, {} sweeps (final solve {}), λ sum {sum:e}, {:.1} µs per step (wall)",
            r.solves,
            r.iterations,
            r.final_iterations,
            per_step * 1e6
        ),
        None => println!("m = {rows}: the step failed"),
    }
}

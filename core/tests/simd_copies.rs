//! Every copy of the core's hot loops gives the same step, bit for bit.
//!
//! On x86-64 the sweeps, the products by `W`, the base rows' Schur complement, the active-set
//! factor and the frame's validation are compiled for the baseline, AVX2 and AVX-512F, and the
//! widest copy the machine has runs. A machine tests only the copy it runs, so a CI machine
//! with AVX-512 would never run the AVX2 copies that a controller PC without AVX-512 does.
//! Here every copy the machine has runs the same closed-loop sequence of steps — seeded frames
//! of 30, 120 and 192 rows, with and without a tip contact, the hybrid and the linearised
//! Jacobian, each frame at the joints the previous command sent and its violations drifting —
//! and every command (joints, `λ`, report) must equal the widest copy's to the bit.
//!
//! One test in its own binary: [`simd::set_limit`] is process-wide.
#![allow(clippy::expect_used, clippy::unwrap_used, clippy::panic)]

use needle_core::simd::{self, SimdLevel};
use needle_core::synthetic::random_frame;
use needle_core::{Command, ComplianceFrame, Controller, DhChain, InverseParams, JacobianMode};

const M: usize = 192;
const Q: [f64; 6] = [0.1, 0.3, 2.0, 0.0, 0.5, 0.0];
const STEPS: usize = 6;

/// Everything a step returns, as bits.
fn bits(cmd: &Command<M>, m: usize) -> Vec<u64> {
    let r = &cmd.report;
    let mut v: Vec<u64> = cmd.q.iter().map(|x| x.to_bits()).collect();
    v.extend(cmd.lambda[..m].iter().map(|x| x.to_bits()));
    v.extend([
        u64::from(r.iterations),
        u64::from(r.solves),
        u64::from(r.flags),
        u64::from(r.final_iterations),
        r.final_residual.to_bits(),
    ]);
    v.extend(
        r.objective
            .iter()
            .chain(&r.objective_after)
            .map(|x| x.to_bits()),
    );
    v.extend(r.delta_q.iter().map(|x| x.to_bits()));
    v
}

/// A closed loop of [`STEPS`] steps on the seeded frame: each next frame at the commanded
/// joints, its free violations scaled by up to ±1 %. The bits of every command.
fn run(m: usize, seed: u64, contact: bool, jacobian: JacobianMode) -> Vec<Vec<u64>> {
    let chain = DhChain::rv1a();
    let mut frame = ComplianceFrame::<M>::new_boxed();
    random_frame(&mut frame, &chain, &Q, m, seed, contact);
    let params = InverseParams {
        jacobian,
        ..InverseParams::default()
    };
    let mut ctrl = Controller::<M>::new_boxed(chain, params);
    let mut cmd = Command::<M>::new_boxed();
    let rows = frame.rows();
    let mut state = seed ^ 0x9e37_79b9_7f4a_7c15;
    let mut out = Vec::new();
    for _ in 0..STEPS {
        ctrl.step(&frame, &mut cmd)
            .expect("a valid synthetic frame");
        out.push(bits(&cmd, rows));
        frame.q = cmd.q;
        for d in &mut frame.delta_free[6..rows] {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1);
            let u = (state >> 11) as f64 / (1u64 << 53) as f64;
            *d *= 1.0 + 0.02 * (u - 0.5);
        }
    }
    out
}

#[test]
fn every_simd_copy_gives_the_widest_copys_steps_bit_for_bit() {
    let widest = simd::detected();
    let levels: Vec<SimdLevel> = SimdLevel::ALL
        .into_iter()
        .filter(|l| *l <= widest)
        .collect();
    println!(
        "copies on this machine: {:?}",
        levels.iter().map(|l| l.name()).collect::<Vec<_>>()
    );
    let cases: Vec<(usize, u64, bool, JacobianMode)> = [30usize, 120, 192]
        .into_iter()
        .flat_map(|m| {
            [
                (m, 11, false, JacobianMode::Hybrid),
                (m, 5, true, JacobianMode::Hybrid),
                (m, 7, true, JacobianMode::Linearized),
            ]
        })
        .collect();
    for &(m, seed, contact, jac) in &cases {
        assert_eq!(simd::set_limit(widest), widest);
        let reference = run(m, seed, contact, jac);
        assert!(
            reference.iter().any(|b| b != &reference[0]),
            "m = {m}, seed {seed}: the loop must move (the joints or λ change from step to step)"
        );
        for &level in &levels[..levels.len() - 1] {
            assert_eq!(simd::set_limit(level), level);
            let got = run(m, seed, contact, jac);
            for (k, (a, b)) in reference.iter().zip(&got).enumerate() {
                assert!(
                    a == b,
                    "m = {m}, seed {seed}, contact {contact}, {jac:?}: step {k} differs between \
                     {} and {}",
                    widest.name(),
                    level.name()
                );
            }
        }
    }
    simd::set_limit(SimdLevel::Avx512);
    assert_eq!(simd::active(), widest);
}

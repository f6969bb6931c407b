//! Terminal 1 of the synthetic pair: a host without FE model. Each step it writes a rigid-needle
//! frame ([`needle_core::synthetic::rigid_needle_frame`]) straight into a loaned shared-memory
//! sample, waits for the command, and moves the "robot" to the commanded joints; the target is
//! the tip at fixed joints, so the tip error must fall.
//!
//! ```sh
//! cargo run --release -p needle-bridge --example synthetic_host         # terminal 1
//! cargo run --release -p needle-bridge --example synthetic_controller   # terminal 2
//! ```

use needle_bridge::{BridgeConfig, SharedMemoryHost, TransportError, setup_fingerprint};
use needle_core::inverse::InverseParams;
use needle_core::kinematics::DhChain;
use needle_core::payload::{Command, ObsIndex};
use needle_core::synthetic::rigid_needle_frame;

fn main() {
    needle_bridge::shm::quiet_logs();
    let chain = DhChain::rv1a();
    let cfg = BridgeConfig {
        instance: "needle-synthetic".into(),
        handle_signals: true,
        ..BridgeConfig::default()
    };
    let mut host =
        SharedMemoryHost::<16>::connect(&cfg, setup_fingerprint(&chain, &InverseParams::default()))
            .expect("host");
    let mut q = [0.1, 0.4, 2.0, 0.05, -0.6, 0.1];
    let target = [0.15, 0.45, 1.95, 0.0, -0.55, 0.1];
    let mut cmd = Command::<16>::new_boxed();
    let (mut first, mut last) = (None, 0.0);
    let mut waited = 0;
    let mut k = 0u64;
    while k < 100 {
        let mut err = 0.0;
        let seq = host
            .publish_with(|f| {
                rigid_needle_frame(f, &chain, &q, &target, 100.0);
                f.sequence = k;
                f.dt = 0.01;
                err = (0..3)
                    .map(|i| {
                        let d = f.o_free[ObsIndex::TARGET_POINT + i]
                            - f.o_free[ObsIndex::TIP_POSITION + i];
                        d * d
                    })
                    .sum::<f64>()
                    .sqrt();
            })
            .expect("publish");
        match host.wait_command(seq, &mut cmd) {
            Ok(_) => {
                q = cmd.q;
                first.get_or_insert(err);
                last = err;
                k += 1;
            }
            Err(TransportError::Timeout { .. }) => {
                waited += 1;
                if waited % 20 == 1 {
                    eprintln!("synthetic_host: waiting for synthetic_controller …");
                }
                assert!(waited < 1200, "no controller within a minute");
            }
            Err(e) => panic!("{e}"),
        }
    }
    let first = first.unwrap_or(f64::NAN);
    println!(
        "tip error {first:.3} mm → {last:.3} mm over 100 steps; {:?}",
        host.stats()
    );
    assert!(last < 0.1 * first, "the error did not fall");
}

//! Terminal 2 of the synthetic pair: a controller for the RV-1A with the core's default tuning,
//! at 1 kHz, answering the frames of `synthetic_host` over shared memory.
//!
//! ```sh
//! cargo run --release -p needle-bridge --example synthetic_host         # terminal 1
//! cargo run --release -p needle-bridge --example synthetic_controller   # terminal 2
//! ```
//!
//! It stops after 100 frames (or 30 s) and asserts that it solved frames and rejected none.

use needle_bridge::{BridgeConfig, ControllerOptions, run_controller};
use needle_core::inverse::InverseParams;
use needle_core::kinematics::DhChain;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

fn main() {
    needle_bridge::shm::quiet_logs();
    let opts = ControllerOptions {
        bridge: BridgeConfig {
            instance: "needle-synthetic".into(),
            handle_signals: true,
            ..BridgeConfig::default()
        },
        run_for: Some(Duration::from_secs(30)),
        max_frames: Some(100),
        ..ControllerOptions::default()
    };
    let stats = run_controller::<16, 6>(
        DhChain::rv1a(),
        InverseParams::default(),
        &opts,
        &AtomicBool::new(false),
    )
    .expect("controller");
    println!("{stats}");
    assert!(
        stats.frames_solved > 0,
        "no frame arrived: is synthetic_host running?"
    );
    assert_eq!(stats.frames_rejected, 0);
}

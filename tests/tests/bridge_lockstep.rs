//! Two processes in lock-step give the one-process result bit for bit.
//!
//! The complex scene's first 40 steps (the approach in the air) run once with the core in
//! process (`needle_host::run::run`, [`needle_bridge::InProcess`]) and once with the core in a
//! child process — this test binary re-run as a `needle-controller` at 1 kHz — over iceoryx2
//! shared memory (`run_with` + [`needle_bridge::SharedMemoryHost`]). Every step's tip, joints,
//! error and λ norms must be equal exactly — in lock-step (the host waits for each answer) and
//! free-running (the host starts a step every 40 ms, the controller ticks at 1 kHz: as long as
//! the host applies only the command answering its frame, and holds otherwise, the trajectory is
//! the same).

#[path = "bridge_util/mod.rs"]
mod util;

use needle_bridge::{ControllerOptions, SharedMemoryHost, run_controller, setup_fingerprint};
use needle_host::run::{RunOptions, run, run_with};
use needle_host::scene::Scene;
use needle_host::step::ROWS;
use std::sync::atomic::AtomicBool;
use std::time::Duration;
use util::*;

const TEST: &str = "two_process_lockstep_equals_one_process_bit_for_bit";
const STEPS: usize = 40;

fn scene() -> Scene {
    Scene::builtin("complex").expect("the embedded complex scene")
}

/// The child's role: a controller that exits after answering `STEPS` frames (or after 120 s).
fn controller_role() {
    quiet_logs_once();
    let instance = std::env::var(INSTANCE).expect("instance");
    let s = scene();
    let opts = ControllerOptions {
        bridge: config(&instance),
        rate_hz: 1000.0,
        run_for: Some(Duration::from_secs(120)),
        max_frames: Some(STEPS as u64),
        verbose: true,
    };
    let stats = run_controller::<ROWS, 6>(
        s.robot().expect("robot"),
        s.inverse_params(),
        &opts,
        &AtomicBool::new(false),
    )
    .expect("controller run");
    println!("CONTROLLER {stats}");
}

fn quiet_logs_once() {
    quiet_iceoryx();
}

#[test]
fn two_process_lockstep_equals_one_process_bit_for_bit() {
    two_processes_equal_one(TEST, None);
}

#[test]
fn two_process_free_running_equals_one_process_bit_for_bit() {
    two_processes_equal_one(
        "two_process_free_running_equals_one_process_bit_for_bit",
        Some(Duration::from_millis(40)),
    );
}

fn two_processes_equal_one(test: &str, period: Option<Duration>) {
    if let Ok(role) = std::env::var(ROLE) {
        assert_eq!(role, "controller");
        controller_role();
        return;
    }
    quiet_iceoryx();
    let scene = scene();
    let opts = RunOptions {
        steps: Some(STEPS),
        give_up_after: Some(Duration::from_secs(60)),
        ..RunOptions::default()
    };
    let one = run(&scene, &opts, |_| {}).expect("one-process run");
    assert_eq!(
        one.reports.len(),
        STEPS,
        "one-process run: {:?}",
        one.summary.stopped
    );

    let instance = unique_instance("lockstep");
    let setup = setup_fingerprint(&scene.robot().expect("robot"), &scene.inverse_params());
    let mut host = SharedMemoryHost::<ROWS>::connect(&config(&instance), setup).expect("host");
    let mut child = spawn_role(test, "controller", &[(INSTANCE, instance.clone())]);
    let two = run_with(&scene, &RunOptions { period, ..opts }, &mut host, |_| {});
    let (status, out) = wait_child(&mut child, Duration::from_secs(60));
    let two = two.expect("two-process run");
    println!("{out}");
    assert!(
        status.is_some_and(|s| s.success()),
        "controller: {status:?}\n{out}"
    );
    assert_eq!(
        two.reports.len(),
        STEPS,
        "two-process run: {:?}",
        two.summary.stopped
    );
    assert_same_steps(&one.reports, &two.reports, 6);
    let st = host.stats();
    assert_eq!(st.commands_accepted, STEPS as u64);
    assert_eq!(st.commands_rejected, 0);
}

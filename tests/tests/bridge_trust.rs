//! Issue 13, two processes: one publisher per service, forged frames rejected without locking
//! out the real host, and a pause (SIGSTOP 2 s, SIGCONT) of either side survived — iceoryx2's
//! `NodeWaitFailure::Interrupt` is not a termination request.

#[path = "bridge_util/mod.rs"]
mod util;

use needle_bridge::controller::run_controller;
use needle_bridge::plausible::Implausible;
use needle_bridge::{ControllerOptions, Rejection, SharedMemoryHost, setup_fingerprint};
use needle_core::inverse::InverseParams;
use needle_core::kinematics::DhChain;
use needle_core::payload::{Command, ComplianceFrame};
use needle_core::synthetic::rigid_needle_frame;
use needle_host::run::{RunOptions, run_with};
use needle_host::scene::Scene;
use needle_host::step::ROWS;
use std::sync::atomic::AtomicBool;
use std::time::Duration;
use util::*;

const M: usize = 24;

fn valid(f: &mut ComplianceFrame<M>, sequence: u64) {
    let chain = DhChain::rv1a();
    let q0 = [0.1, 0.4, 2.0, 0.05, -0.6, 0.1];
    let mut qt = q0;
    qt[0] += 0.01;
    rigid_needle_frame(f, &chain, &q0, &qt, 100.0);
    f.sequence = sequence;
}

#[test]
fn a_second_publisher_on_the_frame_service_is_refused() {
    quiet_iceoryx();
    let instance = unique_instance("twohosts");
    let cfg = config(&instance);
    let _first = SharedMemoryHost::<M>::connect(&cfg, 1).expect("first host");
    assert!(
        SharedMemoryHost::<M>::connect(&cfg, 1).is_err(),
        "a second host (publisher) was allowed on the frame service"
    );
}

#[test]
fn forged_sequence_jump_and_scaled_w_are_rejected_without_locking_out_the_host() {
    quiet_iceoryx();
    let instance = unique_instance("forged");
    let chain = DhChain::rv1a();
    let params = InverseParams::default();
    let ctl =
        ControllerThread::start::<M>(chain, params, &instance, 1000.0, Duration::from_secs(60));
    let cfg = needle_bridge::BridgeConfig {
        deadline: Duration::from_secs(2),
        ..config(&instance)
    };
    let mut host =
        SharedMemoryHost::<M>::connect(&cfg, setup_fingerprint(&chain, &params)).expect("host");
    std::thread::sleep(Duration::from_millis(20));
    let mut cmd = Command::<M>::new_boxed();
    let seq = host.publish_with(|f| valid(f, 0)).expect("publish");
    host.wait_command(seq, &mut cmd).expect("answer to frame 0");

    // Sequence + 1 000 000: rejected, and the real next frame is still answered.
    host.publish_with(|f| valid(f, 1_000_000)).expect("publish");
    assert!(wait_until(Duration::from_secs(10), || ctl
        .now()
        .0
        .rejected_sequence
        == 1));
    let seq = host.publish_with(|f| valid(f, 1)).expect("publish");
    host.wait_command(seq, &mut cmd)
        .expect("the real host is not locked out after a jump");

    // The current sequence with W × 1e6: implausible, never used.
    host.publish_with(|f| {
        valid(f, 2);
        for row in f.w.iter_mut() {
            for x in row.iter_mut() {
                *x *= 1e6;
            }
        }
    })
    .expect("publish");
    assert!(wait_until(Duration::from_secs(10), || ctl
        .now()
        .0
        .rejected_implausible
        == 1));
    assert!(matches!(
        ctl.now().0.last_rejection,
        Some(Rejection::Implausible(Implausible::BaseScale { .. }))
    ));
    // δ = 1e300 with the next sequence: implausible.
    host.publish_with(|f| {
        valid(f, 2);
        f.delta_free[0] = 1e300;
    })
    .expect("publish");
    assert!(wait_until(Duration::from_secs(10), || ctl
        .now()
        .0
        .rejected_implausible
        == 2));
    let seq = host.publish_with(|f| valid(f, 2)).expect("publish");
    host.wait_command(seq, &mut cmd).expect("answer to frame 2");
    let st = ctl.finish().expect("controller");
    println!("controller: {st}");
    assert_eq!(st.frames_solved, 3, "{st}");
    assert_eq!(st.frames_rejected, 3, "{st}");
}

const PAUSED_CONTROLLER: &str = "sigstop_of_the_controller_for_2_s_is_survived";
const PAUSED_HOST: &str = "sigstop_of_the_host_for_2_s_is_survived";
const TRIALS: usize = 2;

fn scene() -> Scene {
    Scene::builtin("simple")
        .expect("simple")
        .with_overrides(&[("gel.box.nodes".into(), "300".into())])
        .expect("scene")
}

/// SIGSTOP, 2 s, SIGCONT of process `pid`, `TRIALS` times, starting after `first`.
fn pause_process(pid: u32, first: Duration) {
    std::thread::sleep(first);
    for _ in 0..TRIALS {
        let signal = |s: &str| {
            std::process::Command::new("kill")
                .args([s, &pid.to_string()])
                .status()
                .expect("kill")
        };
        assert!(signal("-STOP").success());
        std::thread::sleep(Duration::from_secs(2));
        assert!(signal("-CONT").success());
        std::thread::sleep(Duration::from_millis(500));
    }
}

/// The host side of the pause tests: runs `steps` steps of the scene.
fn host_run(instance: &str, steps: usize) -> needle_host::run::RunSummary {
    let s = scene();
    let setup = setup_fingerprint(&s.robot().expect("robot"), &s.inverse_params());
    let cfg = needle_bridge::BridgeConfig {
        handle_signals: true,
        ..config(instance)
    };
    let mut host = SharedMemoryHost::<ROWS>::connect(&cfg, setup).expect("host");
    // Paced (a step every 40 ms): the run lasts through the pauses.
    let opts = RunOptions {
        steps: Some(steps),
        period: Some(Duration::from_millis(40)),
        give_up_after: Some(Duration::from_secs(30)),
        ..RunOptions::default()
    };
    run_with(&s, &opts, &mut host, |_| {})
        .expect("host run")
        .summary
}

#[test]
fn sigstop_of_the_controller_for_2_s_is_survived() {
    quiet_iceoryx();
    if std::env::var(ROLE).is_ok() {
        // The controller process, with the signal handling of `needle-controller`.
        let instance = std::env::var(INSTANCE).expect("instance");
        let s = scene();
        let opts = ControllerOptions {
            bridge: needle_bridge::BridgeConfig {
                handle_signals: true,
                ..config(&instance)
            },
            run_for: Some(Duration::from_secs(60)),
            verbose: false,
            ..ControllerOptions::default()
        };
        let st = run_controller::<ROWS, 6>(
            s.robot().expect("robot"),
            s.inverse_params(),
            &opts,
            &AtomicBool::new(false),
        )
        .expect("controller");
        println!("CONTROLLER solved={}", st.frames_solved);
        return;
    }
    let instance = unique_instance("stopctl");
    let mut child = spawn_role(
        PAUSED_CONTROLLER,
        "controller",
        &[(INSTANCE, instance.clone())],
    );
    let pid = child.id();
    let pauser = std::thread::spawn(move || pause_process(pid, Duration::from_secs(3)));
    let s = host_run(&instance, 250);
    pauser.join().expect("pauser");
    let alive = matches!(child.try_wait(), Ok(None));
    let _ = child.kill();
    let _ = child.wait();
    assert!(
        s.completed,
        "the host run did not complete: {:?}",
        s.stopped
    );
    assert!(alive, "the controller quit after SIGSTOP/SIGCONT");
    assert!(s.holds >= 1, "the pauses were not seen: {} holds", s.holds);
}

#[test]
fn sigstop_of_the_host_for_2_s_is_survived() {
    quiet_iceoryx();
    if std::env::var(ROLE).is_ok() {
        let instance = std::env::var(INSTANCE).expect("instance");
        let s = host_run(&instance, 250);
        println!("HOST completed={} steps={}", s.completed, s.steps);
        return;
    }
    let instance = unique_instance("stophost");
    let s = scene();
    let ctl = ControllerThread::start::<ROWS>(
        s.robot().expect("robot"),
        s.inverse_params(),
        &instance,
        1000.0,
        Duration::from_secs(120),
    );
    let mut child = spawn_role(PAUSED_HOST, "host", &[(INSTANCE, instance)]);
    let pid = child.id();
    let pauser = std::thread::spawn(move || pause_process(pid, Duration::from_secs(3)));
    let (status, out) = wait_child(&mut child, Duration::from_secs(110));
    pauser.join().expect("pauser");
    drop(ctl);
    assert!(
        status.is_some_and(|s| s.success()),
        "host child: {status:?}\n{out}"
    );
    assert!(out.contains("HOST completed=true"), "{out}");
}

//! Issue 15, two processes with a 7-joint arm, and a joint count the two sides disagree on.
//!
//! - The LBR iiwa 14 R820 scene (`scenes/robots/iiwa_complex.toml`, 7 joints) runs its first
//!   steps once with the core in process and once with the core in a child process — this test
//!   binary re-run as a 7-joint `needle-controller` — over iceoryx2 shared memory; every step's
//!   tip, joints (all 7), error, λ norms and solver report must be equal bit for bit, as
//!   `bridge_lockstep.rs` asks of the 6-joint RV-1A.
//! - A 6-joint controller and a 7-joint host are refused at connect, whichever starts first,
//!   with [`TransportError::JointCount`] naming both counts (their payloads differ, so iceoryx2
//!   would not let them share the services anyway; the error says why).
//! - A frame whose header claims another joint count than the controller's is rejected,
//!   counted, and never solved; the same frame with the right count is solved.

#[path = "bridge_util/mod.rs"]
mod util;

use needle_bridge::shm::{create_node, frame_service, loan_initialised};
use needle_bridge::{
    ControllerNode, ControllerOptions, FrameHeader, Rejection, SharedMemoryHost, TransportError,
    run_controller, setup_fingerprint,
};
use needle_core::inverse::InverseParams;
use needle_core::kinematics::DhChain;
use needle_core::payload::ComplianceFrame;
use needle_core::synthetic::rigid_needle_frame;
use needle_host::run::{RunOptions, run, run_with};
use needle_host::scene::Scene;
use needle_host::setup;
use needle_host::step::ROWS;
use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::time::Duration;
use util::*;

const TEST: &str = "a_7_joint_arm_in_two_processes_equals_one_process_bit_for_bit";
/// Steps of the iiwa run: the approach, the contact and the puncture (step 114 of the scene)
/// and some steps inside the gel.
const STEPS: usize = 160;

fn iiwa() -> Scene {
    Scene::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/robots/iiwa_complex.toml"))
        .expect("scenes/robots/iiwa_complex.toml")
}

/// The child's role: a 7-joint controller that exits after answering `STEPS` frames (or after
/// 120 s).
fn controller_role() {
    quiet_iceoryx();
    let instance = std::env::var(INSTANCE).expect("instance");
    let (robot, inverse) = setup::core::<7>(&iiwa()).expect("the iiwa's 7-joint chain");
    let opts = ControllerOptions {
        bridge: config(&instance),
        rate_hz: 1000.0,
        run_for: Some(Duration::from_secs(120)),
        max_frames: Some(STEPS as u64),
        verbose: true,
    };
    let stats = run_controller::<ROWS, 7>(robot, inverse, &opts, &AtomicBool::new(false))
        .expect("controller run");
    println!("CONTROLLER {stats}");
}

#[test]
fn a_7_joint_arm_in_two_processes_equals_one_process_bit_for_bit() {
    if let Ok(role) = std::env::var(ROLE) {
        assert_eq!(role, "controller");
        controller_role();
        return;
    }
    quiet_iceoryx();
    let scene = iiwa();
    assert_eq!(scene.joint_count(), Ok(7));
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
    assert_eq!(one.summary.joints, 7);
    assert!(
        one.reports.iter().any(|r| r.inserted),
        "the run should puncture the gel within {STEPS} steps"
    );

    let instance = unique_instance("iiwa");
    let (robot, inverse) = setup::core::<7>(&scene).expect("robot");
    let mut host = SharedMemoryHost::<ROWS, 7>::connect(
        &config(&instance),
        setup_fingerprint(&robot, &inverse),
    )
    .expect("host");
    let mut child = spawn_role(TEST, "controller", &[(INSTANCE, instance.clone())]);
    let two = run_with::<7>(&scene, &opts, &mut host, |_| {});
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
    assert_same_steps(&one.reports, &two.reports, 7);
    assert_eq!(
        one.summary.e_mean_mm.to_bits(),
        two.summary.e_mean_mm.to_bits()
    );
    let st = host.stats();
    assert_eq!(st.commands_accepted, STEPS as u64);
    assert_eq!(st.commands_rejected, 0);
}

fn quiet_controller(instance: &str) -> ControllerOptions {
    ControllerOptions {
        bridge: config(instance),
        rate_hz: 0.0,
        verbose: false,
        ..ControllerOptions::default()
    }
}

/// The error of a connect that must be refused for the joint count.
fn refused<T>(what: &str, r: Result<T, TransportError>) -> TransportError {
    match r {
        Ok(_) => panic!("{what}: connected, the joint counts differ"),
        Err(e) => e,
    }
}

#[test]
fn a_6_joint_controller_and_a_7_joint_host_are_refused_naming_both_counts() {
    quiet_iceoryx();
    let (r7, p7) = setup::core::<7>(&iiwa()).expect("the iiwa's chain");
    let complex = Scene::builtin("complex").expect("the complex scene");
    let (r6, p6) = setup::core::<6>(&complex).expect("the RV-1A");

    // The 7-joint host first: the 6-joint controller is refused.
    let instance = unique_instance("joints-host-first");
    let _host =
        SharedMemoryHost::<ROWS, 7>::connect(&config(&instance), setup_fingerprint(&r7, &p7))
            .expect("the 7-joint host");
    let e = refused(
        "a 6-joint controller on a 7-joint host",
        ControllerNode::<ROWS, 6>::connect(r6, p6, &quiet_controller(&instance)),
    );
    let TransportError::JointCount {
        service,
        found,
        expected,
    } = &e
    else {
        panic!("refused, but not for the joint count: {e}");
    };
    assert_eq!((*found, *expected), (7, 6), "{e}");
    assert_eq!(service, &config(&instance).frame_service_name());
    let text = e.to_string();
    assert!(
        text.contains("a robot of 7 joints") && text.contains("runs 6 joints"),
        "{text}"
    );

    // The 6-joint controller first: the 7-joint host is refused.
    let instance = unique_instance("joints-controller-first");
    let _ctl = ControllerNode::<ROWS, 6>::connect(r6, p6, &quiet_controller(&instance))
        .map_err(|e| e.to_string())
        .expect("the 6-joint controller");
    let e = refused(
        "a 7-joint host beside a 6-joint controller",
        SharedMemoryHost::<ROWS, 7>::connect(&config(&instance), setup_fingerprint(&r7, &p7)),
    );
    assert!(
        matches!(
            e,
            TransportError::JointCount {
                found: 6,
                expected: 7,
                ..
            }
        ),
        "{e}"
    );
}

#[test]
fn a_frame_whose_header_claims_another_joint_count_is_rejected_and_counted() {
    const M: usize = 24;
    quiet_iceoryx();
    let instance = unique_instance("joints-frame");
    let cfg = config(&instance);
    let chain = DhChain::rv1a();
    let params = InverseParams::default();
    let setup = setup_fingerprint(&chain, &params);
    let mut ctl = ControllerNode::<M>::connect(chain, params, &quiet_controller(&instance))
        .map_err(|e| e.to_string())
        .expect("controller");
    // A publisher of 6-joint frames that writes its own headers.
    let node = create_node("needle-test-forger", &cfg).expect("node");
    let publisher = frame_service::<M, 6>(&node, &cfg)
        .expect("frame service")
        .publisher_builder()
        .create()
        .expect("publisher");
    std::thread::sleep(Duration::from_millis(20));
    let send = |joints: u32| {
        let header = FrameHeader {
            session: 0x5eed,
            setup,
            joints,
            reserved: 0,
        };
        let mut s = loan_initialised(&publisher, header, "loan frame").expect("loan");
        valid(&mut s.payload_mut().0);
        s.send().expect("send");
    };
    let mut tick_until = |what: &str, done: &dyn Fn(&needle_bridge::ControllerStats) -> bool| {
        assert!(
            wait_until(Duration::from_secs(10), || {
                ctl.tick().expect("tick");
                done(&ctl.stats())
            }),
            "{what}: {:?}",
            ctl.stats()
        );
        ctl.stats()
    };

    send(7);
    let st = tick_until("the frame claiming 7 joints", &|s| s.frames_received == 1);
    assert_eq!(st.frames_rejected, 1, "{st:?}");
    assert_eq!(st.rejected_setup, 1, "{st:?}");
    assert_eq!(st.frames_solved, 0, "{st:?}");
    let r = st.last_rejection.expect("a rejection");
    assert_eq!(
        r,
        Rejection::JointCount {
            found: 7,
            expected: 6
        }
    );
    assert!(
        r.to_string().contains("7 joints") && r.to_string().contains("runs 6 joints"),
        "{r}"
    );

    // The same frame with the controller's joint count is solved: only the count was wrong.
    send(6);
    let st = tick_until("the frame saying 6 joints", &|s| s.frames_solved == 1);
    assert_eq!(st.frames_rejected, 1, "{st:?}");
}

/// A valid frame of the RV-1A (a rigid needle: the base rows only).
fn valid<const M: usize>(f: &mut ComplianceFrame<M>) {
    let chain = DhChain::rv1a();
    let q0 = [0.1, 0.4, 2.0, 0.05, -0.6, 0.1];
    let mut qt = q0;
    qt[0] += 0.01;
    rigid_needle_frame(f, &chain, &q0, &qt, 100.0);
    f.sequence = 0;
}

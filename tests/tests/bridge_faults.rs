//! Faults of the two-process bridge: corrupted frames are rejected and counted, never used; a
//! host without a controller holds its insertion; the stale resources of a killed process are
//! removed when the next one starts.

#[path = "bridge_util/mod.rs"]
mod util;

use needle_bridge::iceoryx2::node::NodeView;
use needle_bridge::iceoryx2::prelude::{
    CallbackProgression, Config, Node, NodeState, PortFactory as _, ipc,
};
use needle_bridge::shm::{cleanup_dead_nodes, create_node};
use needle_bridge::{BridgeConfig, ControllerNode, ControllerOptions, Rejection, SharedMemoryHost};
use needle_bridge::{Transport, TransportError, setup_fingerprint};
use needle_core::inverse::InverseParams;
use needle_core::kinematics::DhChain;
use needle_core::payload::{Command, ComplianceFrame, ValidationError};
use needle_core::synthetic::rigid_needle_frame;
use needle_host::run::{RunOptions, run_with};
use needle_host::scene::Scene;
use needle_host::world::ROWS;
use std::time::Duration;
use util::*;

/// Small capacity: the synthetic rigid-needle frames use 6 rows.
const M: usize = 24;

fn q0() -> [f64; 6] {
    [0.1, 0.4, 2.0, 0.05, -0.6, 0.1]
}

fn valid(f: &mut ComplianceFrame<M>, sequence: u64) {
    let chain = DhChain::rv1a();
    let mut qt = q0();
    qt[0] += 0.01;
    rigid_needle_frame(f, &chain, &q0(), &qt, 100.0);
    f.sequence = sequence;
}

fn boxed_command() -> Box<Command<M>> {
    let mut b = Box::<Command<M>>::new_uninit();
    Command::init_in_place(&mut b);
    // SAFETY: initialised just above.
    unsafe { b.assume_init() }
}

/// Publishes through `publish` then waits until the controller has received `received` frames.
fn settle(ctl: &ControllerThread, received: u64) {
    assert!(
        wait_until(Duration::from_secs(10), || ctl.now().0.frames_received
            >= received),
        "the controller did not receive frame {received}: {:?}",
        ctl.now().0
    );
}

#[test]
fn corrupted_frames_are_rejected_and_counted_never_used() {
    quiet_iceoryx();
    let instance = unique_instance("corrupt");
    let chain = DhChain::rv1a();
    let params = InverseParams::default();
    let ctl =
        ControllerThread::start::<M>(chain, params, &instance, 1000.0, Duration::from_secs(60));
    let setup = setup_fingerprint(&chain, &params);
    // A generous host deadline: the answers must come, however loaded the machine.
    let cfg = BridgeConfig {
        deadline: Duration::from_secs(2),
        ..config(&instance)
    };
    let mut host = SharedMemoryHost::<M>::connect(&cfg, setup).expect("host");
    // The controller's subscriber must be connected before the first frame (no history).
    std::thread::sleep(Duration::from_millis(20));
    let mut cmd = boxed_command();
    let mut received = 0;

    // 1. A valid frame: answered.
    let seq = host.publish_with(|f| valid(f, 0)).expect("publish");
    received += 1;
    host.wait_command(seq, &mut cmd)
        .expect("answer to a valid frame");
    assert_eq!(cmd.frame_sequence, 0);
    assert_eq!(ctl.now().0.frames_solved, 1);

    // 2. Corrupted frames, each rejected for its own reason.
    type Corruption = fn(&mut ComplianceFrame<M>);
    let corruptions: [(&str, Corruption); 5] = [
        ("version", |f| f.version = 99),
        ("m above capacity", |f| f.m = M as u32 + 1),
        ("NaN in W", |f| f.w[1][1] = f64::NAN),
        ("infinite in C", |f| f.c[0][2] = f64::INFINITY),
        ("non-rotation", |f| f.r_free[0][0] = 2.0),
    ];
    for (k, (what, corrupt)) in corruptions.iter().enumerate() {
        host.publish_with(|f| {
            valid(f, 1 + k as u64);
            corrupt(f);
        })
        .expect("publish");
        received += 1;
        settle(&ctl, received);
        let (st, _) = ctl.now();
        assert_eq!(st.rejected_invalid, 1 + k as u64, "{what}: {st:?}");
        assert!(
            matches!(st.last_rejection, Some(Rejection::Invalid(_))),
            "{what}"
        );
        assert_eq!(st.frames_solved, 1, "{what}: a corrupted frame was used");
    }
    assert!(matches!(
        ctl.now().0.last_rejection,
        Some(Rejection::Invalid(ValidationError::NotRotation))
    ));
    // The host got no answer to any of them.
    assert!(matches!(
        host.wait_command(5, &mut cmd),
        Err(TransportError::Timeout { .. })
    ));

    // 3. Sequence going backwards within the session: rejected.
    let seq = host.publish_with(|f| valid(f, 10)).expect("publish");
    received += 1;
    host.wait_command(seq, &mut cmd)
        .expect("answer to frame 10");
    host.publish_with(|f| valid(f, 7)).expect("publish");
    received += 1;
    settle(&ctl, received);
    let (st, _) = ctl.now();
    assert_eq!(st.rejected_sequence, 1, "{st:?}");
    assert_eq!(st.frames_solved, 2);

    // 4. A host built for another robot set-up: rejected.
    drop(host);
    let other = InverseParams {
        damping: 3.0,
        ..params
    };
    let mut stranger = SharedMemoryHost::<M>::connect(&cfg, setup_fingerprint(&chain, &other))
        .expect("other host");
    std::thread::sleep(Duration::from_millis(20));
    stranger.publish_with(|f| valid(f, 0)).expect("publish");
    received += 1;
    settle(&ctl, received);

    let st = ctl.finish().expect("controller");
    println!("controller: {st}");
    assert_eq!(st.rejected_invalid, 5);
    assert_eq!(st.rejected_sequence, 1);
    assert_eq!(st.rejected_setup, 1);
    assert_eq!(st.frames_rejected, 7);
    assert_eq!(st.frames_solved, 2);
    assert_eq!(st.step_errors, 0);
}

#[test]
fn a_host_without_controller_holds_the_insertion() {
    quiet_iceoryx();
    let scene = Scene::builtin("complex").expect("scene");
    let instance = unique_instance("nocore");
    let setup = setup_fingerprint(&scene.robot(), &scene.inverse_params());
    let mut host = SharedMemoryHost::<ROWS>::connect(&config(&instance), setup).expect("host");
    let opts = RunOptions {
        steps: Some(3),
        give_up_after: Some(Duration::from_millis(300)),
        ..RunOptions::default()
    };
    let r = run_with(&scene, &opts, &mut host, |_| {}).expect("run");
    assert_eq!(r.summary.steps, 0, "no step may complete without a command");
    assert_eq!(r.summary.holds, 1);
    assert!(r.summary.held_ms >= 300.0);
    assert!(
        r.summary
            .stopped
            .as_deref()
            .is_some_and(|s| s.contains("no command")),
        "{:?}",
        r.summary.stopped
    );
    let st = host.stats();
    assert!(st.timeouts >= 5, "{st:?}");
    // Every timeout republished the same frame.
    assert_eq!(st.frames_published, st.timeouts);
    assert_eq!(st.commands_accepted, 0);
}

const KILLED: &str = "stale_resources_of_a_killed_process_are_removed_at_start";

#[test]
fn stale_resources_of_a_killed_process_are_removed_at_start() {
    if std::env::var(ROLE).is_ok() {
        // Child: open the services as a host would, then wait to be killed.
        quiet_iceoryx();
        let instance = std::env::var(INSTANCE).expect("instance");
        let _host = SharedMemoryHost::<M>::connect(&config(&instance), 1).expect("host");
        println!("READY");
        std::thread::sleep(Duration::from_secs(30));
        return;
    }
    quiet_iceoryx();
    let instance = unique_instance("stale");
    let mut child = spawn_role(KILLED, "host", &[(INSTANCE, instance.clone())]);
    // Wait until the child's node exists: its services can then be opened.
    let node = create_node("needle-test-observer", &config(&instance)).expect("node");
    let opened = wait_until(Duration::from_secs(20), || {
        needle_bridge::shm::frame_service::<M>(&node, &config(&instance))
            .is_ok_and(|s| s.dynamic_config().number_of_publishers() == 1)
    });
    assert!(opened, "the child never published its service");
    let pid = child.id() as i32;
    assert_eq!(node_state(pid), Some("alive"));
    child.kill().expect("kill the child");
    let _ = child.wait();
    // The next process to start removes the dead node's resources. (Another test's controller
    // may get there first when it holds: whoever does, the dead node must go.)
    let mut cleaned = 0;
    assert!(
        wait_until(Duration::from_secs(5), || {
            cleaned += cleanup_dead_nodes(&node);
            node_state(pid).is_none()
        }),
        "the killed process's node is still listed: {:?}",
        node_state(pid)
    );
    println!("dead nodes removed here: {cleaned}");
    // And a new host can take the service over.
    let mut ctl = ControllerNode::<M>::connect(
        DhChain::rv1a(),
        InverseParams::default(),
        &ControllerOptions {
            bridge: config(&instance),
            ..ControllerOptions::default()
        },
    )
    .expect("controller after the crash");
    let mut host = SharedMemoryHost::<M>::connect(
        &config(&instance),
        setup_fingerprint(&DhChain::rv1a(), &InverseParams::default()),
    )
    .expect("host after the crash");
    let mut f = Box::<ComplianceFrame<M>>::new_uninit();
    let frame = ComplianceFrame::init_in_place(&mut f);
    valid(frame, 0);
    let mut cmd = boxed_command();
    let mut answered = false;
    for _ in 0..200 {
        host.publish(frame).expect("publish");
        for _ in 0..5 {
            ctl.tick().expect("tick");
        }
        if host.wait_command(0, &mut cmd).is_ok() {
            answered = true;
            break;
        }
    }
    assert!(answered, "no answer after the crash: {:?}", ctl.stats());
    let _ = host.exchange(frame, &mut cmd);
}

/// The state of the iceoryx2 node of process `pid` in the node list: `alive`, `dead`, or none.
fn node_state(pid: i32) -> Option<&'static str> {
    let mut found = None;
    let _ = Node::<ipc::Service>::list(Config::global_config(), |state| {
        let (view_pid, what) = match &state {
            NodeState::Alive(v) => (
                v.details().as_ref().map(|d| d.process_id().value()),
                "alive",
            ),
            NodeState::Dead(v) => (v.details().as_ref().map(|d| d.process_id().value()), "dead"),
            _ => (None, ""),
        };
        if view_pid == Some(pid) {
            found = Some(what);
            CallbackProgression::Stop
        } else {
            CallbackProgression::Continue
        }
    });
    found
}

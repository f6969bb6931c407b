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
use needle_bridge::{
    BridgeConfig, ControllerNode, ControllerOptions, ControllerStats, Rejection, SharedMemoryHost,
};
use needle_bridge::{Transport, TransportError, setup_fingerprint};
use needle_core::inverse::InverseParams;
use needle_core::kinematics::DhChain;
use needle_core::payload::{Command, ComplianceFrame, ValidationError};
use needle_core::synthetic::rigid_needle_frame;
use needle_host::run::{RunOptions, run_with};
use needle_host::scene::Scene;
use needle_host::step::ROWS;
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
    Command::new_boxed()
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
    // The answer reaches the host inside the controller's tick, before its thread copies the
    // counters out: wait for the copy rather than read it at once.
    settle(&ctl, received);
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
        // Each the next sequence (a rejected frame does not move the expected one).
        host.publish_with(|f| {
            valid(f, 1);
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
        host.wait_command(1, &mut cmd),
        Err(TransportError::Timeout { .. })
    ));

    // 3. Sequence going backwards within the session: rejected.
    let seq = host.publish_with(|f| valid(f, 1)).expect("publish");
    received += 1;
    host.wait_command(seq, &mut cmd).expect("answer to frame 1");
    host.publish_with(|f| valid(f, 0)).expect("publish");
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
    let setup = setup_fingerprint(&scene.robot().expect("robot"), &scene.inverse_params());
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
const HALF_CREATED: &str = "a_service_left_half_created_by_a_killed_process_is_created_again";

/// Child role of the kill tests: opens the services as a host would, says `READY`, and waits to
/// be killed. Returns whether this process is the child.
fn host_child_waiting_to_be_killed() -> bool {
    if std::env::var(ROLE).is_err() {
        return false;
    }
    quiet_iceoryx();
    let instance = std::env::var(INSTANCE).expect("instance");
    let _host = SharedMemoryHost::<M>::connect(&config(&instance), 1).expect("host");
    println!("READY");
    std::thread::sleep(Duration::from_secs(30));
    true
}

/// Starts a child host (re-running `test`), waits until it has opened both services, kills it,
/// and checks that the dead node is removed. Returns the instance and an observer node.
fn kill_a_connected_host(test: &str, tag: &str) -> (String, Node<ipc::Service>) {
    let instance = unique_instance(tag);
    let mut child = spawn_role(test, "host", &[(INSTANCE, instance.clone())]);
    // READY comes after both services and ports exist: killing earlier could interrupt their
    // creation, which is the other test's case.
    assert!(
        wait_for_line(&mut child, "READY", Duration::from_secs(20)),
        "the child never connected"
    );
    let node = create_node("needle-test-observer", &config(&instance)).expect("node");
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
    (instance, node)
}

/// A controller and a host connect on `instance` and one frame is answered.
fn new_pair_answers(instance: &str) -> (ControllerStats, needle_bridge::HostStats) {
    let mut ctl = ControllerNode::<M>::connect(
        DhChain::rv1a(),
        InverseParams::default(),
        &ControllerOptions {
            bridge: config(instance),
            ..ControllerOptions::default()
        },
    )
    .expect("controller after the crash");
    let mut host = SharedMemoryHost::<M>::connect(
        &config(instance),
        setup_fingerprint(&DhChain::rv1a(), &InverseParams::default()),
    )
    .expect("host after the crash");
    let mut frame = ComplianceFrame::<M>::new_boxed();
    valid(&mut frame, 0);
    let mut cmd = boxed_command();
    let mut answered = false;
    for _ in 0..200 {
        host.publish(&frame).expect("publish");
        for _ in 0..5 {
            ctl.tick().expect("tick");
        }
        if host.wait_command(0, &mut cmd).is_ok() {
            answered = true;
            break;
        }
    }
    assert!(answered, "no answer after the crash: {:?}", ctl.stats());
    let _ = host.exchange(&frame, &mut cmd);
    (ctl.stats(), host.stats())
}

#[test]
fn stale_resources_of_a_killed_process_are_removed_at_start() {
    if host_child_waiting_to_be_killed() {
        return;
    }
    quiet_iceoryx();
    let (instance, node) = kill_a_connected_host(KILLED, "stale");
    // The killed host's frame publisher is gone from the service.
    let frames =
        needle_bridge::shm::frame_service::<M, 6>(&node, &config(&instance)).expect("open");
    assert_eq!(frames.dynamic_config().number_of_publishers(), 0);
    drop(frames);
    // And a new host can take the service over.
    let (ctl, host) = new_pair_answers(&instance);
    assert_eq!(ctl.hung_services_removed + host.hung_services_removed, 0);
}

#[test]
fn a_service_left_half_created_by_a_killed_process_is_created_again() {
    if host_child_waiting_to_be_killed() {
        return;
    }
    quiet_iceoryx();
    // A process killed between writing a service's static config and finalising it leaves the
    // file behind with its initial permissions (owner read-write instead of read-only), and
    // nothing else of the service: every later open waits for the creation timeout and fails
    // with `HangsInCreation`. (It happened for real in CI.) That state is reproduced here: the
    // command service's static config, as the child wrote it, put back unfinalised after the
    // child was killed and its services removed.
    let instance = unique_instance("half");
    let name = config(&instance).command_service_name();
    let mut child = spawn_role(HALF_CREATED, "host", &[(INSTANCE, instance.clone())]);
    assert!(
        wait_for_line(&mut child, "READY", Duration::from_secs(20)),
        "the child never connected"
    );
    let file = static_config_file(&name).expect("the command service's static config file");
    let text = std::fs::read(&file).expect("read it");
    child.kill().expect("kill the child");
    let _ = child.wait();
    let node = create_node("needle-test-observer", &config(&instance)).expect("node");
    assert!(
        wait_until(Duration::from_secs(5), || {
            cleanup_dead_nodes(&node);
            static_config_file(&name).is_none()
        }),
        "the killed host's services were not removed"
    );
    std::fs::write(&file, text).expect("write the static config back");
    std::fs::set_permissions(&file, std::os::unix::fs::PermissionsExt::from_mode(0o600))
        .expect("chmod");
    let (ctl, host) = new_pair_answers(&instance);
    assert_eq!(
        ctl.hung_services_removed, 1,
        "the controller, first to open, removes the half-created service: {ctl:?}"
    );
    assert_eq!(host.hung_services_removed, 0, "{host:?}");
}

/// The static config file of the service named `name` (iceoryx2 0.10 keeps one TOML file per
/// service under `<root>/services`, with the name in it).
fn static_config_file(name: &str) -> Option<std::path::PathBuf> {
    let dir = format!("{}", Config::global_config().global.service_dir());
    let needle = format!("service_name = \"{name}\"");
    std::fs::read_dir(&dir).ok()?.flatten().find_map(|e| {
        let p = e.path();
        let text = std::fs::read_to_string(&p).ok()?;
        text.contains(&needle).then_some(p)
    })
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

//! The host dies mid-run: the controller holds the robot within its deadline, removes the dead
//! host's resources, and resumes when a restarted host publishes again.
//!
//! The controller runs on a thread of this test (its counters visible live); each host is this
//! test binary re-run as a child process (`needle serve` through the library: `run_with` +
//! `SharedMemoryHost`) on the complex scene's approach. The first host is killed (SIGKILL) after
//! the controller has answered a few of its frames.

#[path = "bridge_util/mod.rs"]
mod util;

use needle_bridge::{SharedMemoryHost, setup_fingerprint};
use needle_host::run::{RunOptions, run_with};
use needle_host::scene::Scene;
use needle_host::step::ROWS;
use std::time::Duration;
use util::*;

const TEST: &str = "controller_holds_when_the_host_dies_and_resumes_with_a_restarted_host";
const STEPS_ENV: &str = "NEEDLE_BRIDGE_TEST_STEPS";

fn scene() -> Scene {
    Scene::builtin("complex").expect("the embedded complex scene")
}

/// The child's role: a host running `STEPS_ENV` steps.
fn host_role() {
    quiet_iceoryx();
    let instance = std::env::var(INSTANCE).expect("instance");
    let steps: usize = std::env::var(STEPS_ENV)
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(10);
    let s = scene();
    let setup = setup_fingerprint(&s.robot().expect("robot"), &s.inverse_params());
    let mut host = SharedMemoryHost::<ROWS>::connect(&config(&instance), setup).expect("host");
    let opts = RunOptions {
        steps: Some(steps),
        give_up_after: Some(Duration::from_secs(30)),
        ..RunOptions::default()
    };
    let r = run_with(&s, &opts, &mut host, |_| {}).expect("host run");
    println!(
        "HOST steps={} completed={} holds={} dead_nodes_cleaned={}",
        r.summary.steps,
        r.summary.completed,
        r.summary.holds,
        host.stats().dead_nodes_cleaned
    );
}

fn field(out: &str, key: &str) -> Option<u64> {
    out.split_whitespace()
        .find_map(|w| w.strip_prefix(key)?.strip_prefix('=')?.parse().ok())
}

#[test]
fn controller_holds_when_the_host_dies_and_resumes_with_a_restarted_host() {
    if let Ok(role) = std::env::var(ROLE) {
        assert_eq!(role, "host");
        host_role();
        return;
    }
    quiet_iceoryx();
    let s = scene();
    let instance = unique_instance("restart");
    let ctl = ControllerThread::start::<ROWS>(
        s.robot().expect("robot"),
        s.inverse_params(),
        &instance,
        1000.0,
        Duration::from_secs(180),
    );

    // Host A: killed after 5 answered frames.
    let env = |steps: usize| [(INSTANCE, instance.clone()), (STEPS_ENV, steps.to_string())];
    let mut a = spawn_role(TEST, "host", &env(40));
    let got_frames = wait_until(Duration::from_secs(90), || ctl.now().0.frames_solved >= 5);
    if !got_frames {
        let _ = wait_child(&mut a, Duration::ZERO);
        panic!("the controller never answered host A: {:?}", ctl.now());
    }
    a.kill().expect("kill host A");
    let _ = a.wait();
    let solved_a = ctl.now().0.frames_solved;

    // The controller holds.
    assert!(
        wait_until(Duration::from_secs(10), || {
            let (st, holding) = ctl.now();
            holding && st.hold_events >= 1 && st.hold_commands >= 1
        }),
        "the controller did not hold after the host died: {:?}",
        ctl.now()
    );
    assert_eq!(ctl.now().0.sessions, 1);

    // Host B: a restart; the controller picks it up and answers all its frames.
    let mut b = spawn_role(TEST, "host", &env(10));
    let (status, out) = wait_child(&mut b, Duration::from_secs(120));
    println!("{out}");
    assert!(status.is_some_and(|s| s.success()), "host B: {status:?}");
    assert_eq!(field(&out, "steps"), Some(10), "host B: {out}");
    assert!(
        wait_until(Duration::from_secs(5), || ctl.now().0.frames_solved
            >= solved_a + 10),
        "{:?}",
        ctl.now()
    );
    let st = ctl.finish().expect("controller");
    println!("controller: {st}");
    assert_eq!(st.sessions, 2, "{st}");
    assert!(st.hold_events >= 1, "{st}");
    assert_eq!(st.frames_rejected, 0, "{st}");
    assert_eq!(st.step_errors, 0, "{st}");
    // Host A's node was dead: whoever came first (the holding controller or host B) removed it.
    let cleaned = st.dead_nodes_cleaned + field(&out, "dead_nodes_cleaned").unwrap_or(0);
    assert!(
        cleaned >= 1,
        "nobody removed the dead host's resources: {st} / {out}"
    );
}

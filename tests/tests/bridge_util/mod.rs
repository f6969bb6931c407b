//! Shared helpers of the two-process tests (`bridge_*.rs`): unique service names, child
//! processes that re-run the test binary in a role, a controller on a thread with live counters,
//! bounded waits. Nothing here waits without a limit.

#![allow(dead_code)]

use needle_bridge::{BridgeConfig, ControllerNode, ControllerOptions, ControllerStats, Wait};
use needle_core::inverse::InverseParams;
use std::io::Read;
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Environment variable naming the role of a re-invoked test binary.
pub const ROLE: &str = "NEEDLE_BRIDGE_TEST_ROLE";
/// Environment variable carrying the bridge instance (service-name prefix).
pub const INSTANCE: &str = "NEEDLE_BRIDGE_TEST_INSTANCE";

/// A service-name prefix no other test (or test run) uses.
pub fn unique_instance(tag: &str) -> String {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.subsec_nanos());
    format!("needle-test-{tag}-{}-{nanos}", std::process::id())
}

/// Silences iceoryx2's "no config file" warning.
pub fn quiet_iceoryx() {
    needle_bridge::shm::quiet_logs();
}

/// A bridge configuration for tests: the given instance, 50 ms deadline, short sleeps.
pub fn config(instance: &str) -> BridgeConfig {
    BridgeConfig {
        instance: instance.to_string(),
        wait: Wait::Sleep(Duration::from_micros(20)),
        ..BridgeConfig::default()
    }
}

/// Re-runs this test binary as a child process executing only `test` (which must dispatch on
/// [`ROLE`] first), with the given role and extra environment. Stdout is piped.
pub fn spawn_role(test: &str, role: &str, env: &[(&str, String)]) -> Child {
    let exe = std::env::current_exe().expect("the test binary's path");
    let mut cmd = Command::new(exe);
    cmd.args([
        test,
        "--exact",
        "--nocapture",
        "--include-ignored",
        "--test-threads",
        "1",
    ])
    .env(ROLE, role)
    .stdout(Stdio::piped())
    .stderr(Stdio::inherit());
    for (k, v) in env {
        cmd.env(k, v);
    }
    cmd.spawn().expect("spawn the test binary in a child role")
}

/// Waits for `child` at most `limit`; kills it past the limit. Returns its status (None: killed)
/// and its stdout.
pub fn wait_child(child: &mut Child, limit: Duration) -> (Option<ExitStatus>, String) {
    let start = Instant::now();
    let status = loop {
        match child.try_wait() {
            Ok(Some(s)) => break Some(s),
            Ok(None) if start.elapsed() < limit => std::thread::sleep(Duration::from_millis(10)),
            _ => {
                let _ = child.kill();
                let _ = child.wait();
                break None;
            }
        }
    };
    let mut out = String::new();
    if let Some(mut s) = child.stdout.take() {
        let _ = s.read_to_string(&mut out);
    }
    (status, out)
}

/// Reads `child`'s stdout until a line ending in `line` arrives (the test harness prints the
/// test's name first on the same line) (true) or `limit` passes (false).
/// Takes the child's stdout.
pub fn wait_for_line(child: &mut Child, line: &str, limit: Duration) -> bool {
    use std::io::BufRead;
    let Some(out) = child.stdout.take() else {
        return false;
    };
    let (tx, rx) = std::sync::mpsc::channel();
    let want = line.to_string();
    std::thread::spawn(move || {
        for l in std::io::BufReader::new(out).lines() {
            match l {
                Ok(l) if l.trim_end().ends_with(want.as_str()) => {
                    let _ = tx.send(());
                }
                Ok(_) => {}
                Err(_) => return,
            }
        }
    });
    rx.recv_timeout(limit).is_ok()
}

/// Polls `cond` every millisecond until it holds or `limit` passes.
pub fn wait_until(limit: Duration, mut cond: impl FnMut() -> bool) -> bool {
    let start = Instant::now();
    while start.elapsed() < limit {
        if cond() {
            return true;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    cond()
}

/// A controller running on a thread of the test process, its counters visible while it runs.
pub struct ControllerThread {
    /// Latest counters (updated every tick).
    pub stats: Arc<Mutex<(ControllerStats, bool)>>,
    stop: Arc<AtomicBool>,
    handle: Option<JoinHandle<Result<ControllerStats, String>>>,
}

impl ControllerThread {
    /// Starts a controller of capacity `M` on `instance` at `rate_hz`, for at most `limit`.
    pub fn start<const M: usize>(
        chain: impl Into<needle_core::Robot<6>> + Send + 'static,
        params: InverseParams,
        instance: &str,
        rate_hz: f64,
        limit: Duration,
    ) -> Self {
        let stats = Arc::new(Mutex::new((ControllerStats::default(), false)));
        let stop = Arc::new(AtomicBool::new(false));
        let opts = ControllerOptions {
            bridge: config(instance),
            rate_hz,
            run_for: Some(limit),
            max_frames: None,
            verbose: true,
        };
        let (s, st) = (stats.clone(), stop.clone());
        let ready = Arc::new(AtomicBool::new(false));
        let r = ready.clone();
        let handle = std::thread::spawn(move || {
            let node = ControllerNode::<M>::connect(chain, params, &opts);
            r.store(true, Ordering::SeqCst);
            let mut node = node.map_err(|e| e.to_string())?;
            let start = Instant::now();
            let period = Duration::from_secs_f64(1.0 / rate_hz);
            while !st.load(Ordering::Relaxed) && start.elapsed() < limit {
                node.tick().map_err(|e| e.to_string())?;
                if let Ok(mut g) = s.lock() {
                    *g = (node.stats(), node.holding());
                }
                std::thread::sleep(period);
            }
            Ok(node.stats())
        });
        wait_until(Duration::from_secs(10), || ready.load(Ordering::SeqCst));
        Self {
            stats,
            stop,
            handle: Some(handle),
        }
    }

    /// The counters and the holding flag now.
    pub fn now(&self) -> (ControllerStats, bool) {
        self.stats.lock().map(|g| *g).unwrap_or_default()
    }

    /// Stops the thread and returns its final counters.
    pub fn finish(mut self) -> Result<ControllerStats, String> {
        self.stop.store(true, Ordering::Relaxed);
        match self.handle.take() {
            Some(h) => h
                .join()
                .map_err(|_| "controller thread panicked".to_string())?,
            None => Err("already finished".into()),
        }
    }
}

impl Drop for ControllerThread {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

/// Two runs of the same scene (one process, two) step for step, bit for bit: target, tip, the
/// `joints` joints, error, λ norms and the solver's report.
pub fn assert_same_steps(
    one: &[needle_host::step::StepReport],
    two: &[needle_host::step::StepReport],
    joints: usize,
) {
    assert_eq!(one.len(), two.len(), "steps");
    for (a, b) in one.iter().zip(two) {
        assert_eq!(a.step, b.step);
        assert_eq!(a.c.to_bits(), b.c.to_bits(), "step {}: c", a.step);
        for k in 0..3 {
            assert_eq!(
                a.tip[k].to_bits(),
                b.tip[k].to_bits(),
                "step {}: tip {k}",
                a.step
            );
        }
        assert_eq!(
            (a.q.len(), b.q.len()),
            (joints, joints),
            "step {}: joints",
            a.step
        );
        for k in 0..joints {
            assert_eq!(a.q[k].to_bits(), b.q[k].to_bits(), "step {}: q {k}", a.step);
        }
        assert_eq!(
            a.error.to_bits(),
            b.error.to_bits(),
            "step {}: error",
            a.step
        );
        for k in 0..3 {
            assert_eq!(
                a.lambda_norms[k].to_bits(),
                b.lambda_norms[k].to_bits(),
                "step {}: λ norm {k}",
                a.step
            );
        }
        assert_eq!(a.solver, b.solver, "step {}: solver report", a.step);
    }
}

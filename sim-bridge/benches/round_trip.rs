//! Frame → command round trip over iceoryx2 shared memory at m = 120 rows (capacity 192, the
//! host's), host and responder on two threads of this process, both polling with
//! `Wait::Spin`:
//!
//! - `shm_round_trip_m120_echo`: the responder answers without solving (transport only: the
//!   host's copy of the used block into the loaned sample, the publish, the responder's receive
//!   and in-place command, the way back);
//! - `shm_round_trip_m120_solve`: the responder is the real controller loop
//!   ([`ControllerNode`], inverse step on the shared-memory sample);
//! - `inprocess_m120_solve`: the same inverse step through [`InProcess`], for comparison.
//!
//! The same frame content goes round with increasing sequences, so every inverse step after the
//! first is warm-started from the previous one's λ. Criterion reports the mean; before each
//! group the bench prints the median and p99 of 2000 timed round trips.

use criterion::{Criterion, criterion_group, criterion_main};
use needle_bridge::shm::{command_service, create_node, frame_service, loan_initialised};
use needle_bridge::{
    BridgeConfig, CommandHeader, CommandKind, ControllerNode, ControllerOptions, InProcess,
    SharedMemoryHost, Transport, Wait, setup_fingerprint,
};
use needle_core::inverse::InverseParams;
use needle_core::kinematics::DhChain;
use needle_core::payload::{Command, ComplianceFrame};
use needle_core::synthetic::random_frame;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

const M: usize = 192;
const ROWS_USED: usize = 120;
const Q: [f64; 6] = [0.1, 0.3, 2.0, 0.0, 0.5, 0.0];

fn frame() -> Box<ComplianceFrame<M>> {
    let mut f = ComplianceFrame::new_boxed();
    random_frame(&mut f, &DhChain::rv1a(), &Q, ROWS_USED, 7, false);
    f
}

fn command() -> Box<Command<M>> {
    Command::new_boxed()
}

fn config(tag: &str) -> BridgeConfig {
    BridgeConfig {
        instance: format!("needle-bench-{tag}-{}", std::process::id()),
        deadline: Duration::from_secs(5),
        wait: Wait::Spin,
        handle_signals: false,
    }
}

/// Echo responder: answers each frame with a zero command carrying its sequence.
fn echo(cfg: BridgeConfig, stop: Arc<AtomicBool>, ready: Arc<AtomicBool>) {
    let node = create_node("needle-bench-echo", &cfg).expect("node");
    let sub = frame_service::<M, 6>(&node, &cfg)
        .expect("frames")
        .subscriber_builder()
        .create()
        .expect("subscriber");
    let publ = command_service::<M, 6>(&node, &cfg)
        .expect("commands")
        .publisher_builder()
        .create()
        .expect("publisher");
    ready.store(true, Ordering::SeqCst);
    while !stop.load(Ordering::Relaxed) {
        match sub.receive() {
            Ok(Some(s)) => {
                let f = &s.payload().0;
                let header = CommandHeader {
                    session: s.user_header().session,
                    kind: CommandKind::Answer as u32,
                    reserved: 0,
                };
                let mut out = loan_initialised(&publ, header, "loan").expect("loan");
                let c = &mut out.payload_mut().0;
                c.m = f.m;
                c.frame_sequence = f.sequence;
                c.q = f.q;
                out.send().expect("send");
            }
            _ => std::thread::yield_now(),
        }
    }
}

/// The real controller loop, polling.
fn solver(cfg: BridgeConfig, stop: Arc<AtomicBool>, ready: Arc<AtomicBool>) {
    let opts = ControllerOptions {
        bridge: cfg,
        rate_hz: 0.0,
        verbose: false,
        ..ControllerOptions::default()
    };
    let mut node = ControllerNode::<M>::connect(DhChain::rv1a(), InverseParams::default(), &opts)
        .expect("controller");
    ready.store(true, Ordering::SeqCst);
    node.run(&stop).expect("controller loop");
}

fn percentiles(mut v: Vec<f64>) -> (f64, f64) {
    v.sort_by(f64::total_cmp);
    let at = |p: f64| v[((p * (v.len() - 1) as f64).round() as usize).min(v.len() - 1)];
    (at(0.5), at(0.99))
}

fn shm_group(
    c: &mut Criterion,
    name: &str,
    responder: fn(BridgeConfig, Arc<AtomicBool>, Arc<AtomicBool>),
) {
    let cfg = config(name);
    let stop = Arc::new(AtomicBool::new(false));
    let ready = Arc::new(AtomicBool::new(false));
    let (c2, s2, r2) = (cfg.clone(), stop.clone(), ready.clone());
    let th = std::thread::spawn(move || responder(c2, s2, r2));
    while !ready.load(Ordering::SeqCst) {
        std::thread::sleep(Duration::from_millis(1));
    }
    let mut host = SharedMemoryHost::<M>::connect(
        &cfg,
        setup_fingerprint(&DhChain::rv1a(), &InverseParams::default()),
    )
    .expect("host");
    let mut f = frame();
    let mut cmd = command();
    let mut seq = 0u64;
    let mut once = |host: &mut SharedMemoryHost<M>, f: &mut ComplianceFrame<M>| {
        f.sequence = seq;
        seq += 1;
        host.exchange(f, &mut cmd).expect("round trip");
    };
    // Connect and warm up.
    std::thread::sleep(Duration::from_millis(50));
    for _ in 0..100 {
        once(&mut host, &mut f);
    }
    let samples: Vec<f64> = (0..2000)
        .map(|_| {
            let t = Instant::now();
            once(&mut host, &mut f);
            t.elapsed().as_secs_f64() * 1e6
        })
        .collect();
    let (median, p99) = percentiles(samples);
    println!("{name}: median {median:.1} µs, p99 {p99:.1} µs (2000 round trips)");
    c.bench_function(name, |b| b.iter(|| once(&mut host, &mut f)));
    stop.store(true, Ordering::Relaxed);
    let _ = th.join();
}

fn bench(c: &mut Criterion) {
    needle_bridge::shm::quiet_logs();
    shm_group(c, "shm_round_trip_m120_echo", echo);
    shm_group(c, "shm_round_trip_m120_solve", solver);
    let mut t = InProcess::<M>::new(DhChain::rv1a(), InverseParams::default());
    let mut f = frame();
    let mut cmd = command();
    let mut seq = 0u64;
    let mut samples = Vec::with_capacity(2000);
    for k in 0..2100 {
        f.sequence = seq;
        seq += 1;
        let s = Instant::now();
        t.exchange(&f, &mut cmd).expect("step");
        if k >= 100 {
            samples.push(s.elapsed().as_secs_f64() * 1e6);
        }
    }
    let (median, p99) = percentiles(samples);
    println!("inprocess_m120_solve: median {median:.1} µs, p99 {p99:.1} µs (2000 steps)");
    c.bench_function("inprocess_m120_solve", |b| {
        b.iter(|| {
            f.sequence = seq;
            seq += 1;
            t.exchange(&f, &mut cmd).expect("step")
        })
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);

//! The core's inverse step on frames the host produced, where `needle-core`'s own `inverse`
//! bench steps seeded synthetic frames ([`needle_core::synthetic::random_frame`]): the complex
//! benchmark insertion is run closed loop (the core in this process) and the 500 frames of
//! steps 120–619 of its 621 (at 1500 nodes from just after the puncture at step 114 to the
//! end; the bench prints the depths) are recorded, not timed. A fresh controller with the scene's tuning then
//! steps them in order, once to warm up, then again and again in the timed loop: every warm
//! start is the previous frame's, as in the product (one step in 500, the wrap-around, starts
//! from the last frame).
//!
//! - `core_step_complex_<n>_nodes_m<m>`: the scene's tuning (`solver.gs_relaxation` 1, plain
//!   Gauss-Seidel), a gel of about `n` nodes, `m` the mean number of rows of the recorded frames.
//! - `…_sor12`: the same frames with over-relaxation ω = 1.2, which takes ~20 % fewer sweeps on
//!   the synthetic frames and 1–4 % fewer here (measured 2026-12-02).
//!
//! After each variant the bench prints the mean rows and Gauss-Seidel sweeps per step.
//!
//! Run: `cargo bench -p needle-host --bench core_on_host_frames`.

use criterion::{Criterion, criterion_group, criterion_main};
use needle_bridge::{ExchangeReport, InProcess, Transport, TransportError};
use needle_core::inverse::{Controller, InverseParams};
use needle_core::kinematics::Robot;
use needle_core::payload::{Command, ComplianceFrame};
use needle_host::scene::Scene;
use needle_host::setup::Setup;
use needle_host::step::{Pipeline, ROWS};
use std::hint::black_box;

/// First recorded step.
const FIRST: usize = 120;
/// Recorded steps.
const WINDOW: usize = 500;

/// The core in this process, copying the frames of steps `FIRST..FIRST + WINDOW`.
struct Recorder {
    core: InProcess<ROWS>,
    step: usize,
    frames: Vec<Box<ComplianceFrame<ROWS>>>,
}

impl Transport<ROWS> for Recorder {
    fn exchange(
        &mut self,
        frame: &ComplianceFrame<ROWS>,
        cmd: &mut Command<ROWS>,
    ) -> Result<ExchangeReport, TransportError> {
        if (FIRST..FIRST + WINDOW).contains(&self.step) {
            let mut copy = ComplianceFrame::new_boxed();
            (*copy).clone_from(frame);
            self.frames.push(copy);
        }
        self.step += 1;
        self.core.exchange(frame, cmd)
    }
}

/// The recorded frames of the complex insertion at about `nodes` gel nodes, the robot and
/// the core's tuning of that scene.
fn record(nodes: usize) -> (Vec<Box<ComplianceFrame<ROWS>>>, Robot<6>, InverseParams) {
    let scene = Scene::builtin("complex")
        .expect("embedded scene")
        .with_overrides(&[("gel.box.nodes".to_string(), nodes.to_string())])
        .expect("valid override");
    let setup = Setup::build(&scene).expect("the benchmark scene builds");
    let (mut world, params, planned) = (setup.world, setup.params, setup.plan.steps);
    let mut rec = Recorder {
        core: InProcess::new(setup.robot, setup.inverse),
        step: 0,
        frames: Vec::with_capacity(WINDOW),
    };
    let mut pipeline = Pipeline::new(&world);
    let mut depth0 = 0.0;
    while rec.frames.len() < WINDOW {
        if rec.frames.is_empty() {
            depth0 = world.depth();
        }
        assert!(
            world.steps < planned,
            "the insertion ended before step {}",
            FIRST + WINDOW
        );
        pipeline
            .step(&mut world, &params, &mut rec)
            .expect("a step of the benchmark insertion");
    }
    eprintln!(
        "complex, {} gel nodes: steps {FIRST}..{} recorded, tip depth {depth0:.1} → {:.1} mm",
        world.gel.node_count(),
        FIRST + WINDOW,
        world.depth()
    );
    (rec.frames, setup.robot, setup.inverse)
}

fn bench(c: &mut Criterion) {
    for nodes in [1500usize, 5000] {
        let (frames, robot, inverse) = record(nodes);
        let rows = frames.iter().map(|f| f.rows()).sum::<usize>() as f64 / WINDOW as f64;
        let sor = InverseParams {
            gs: needle_core::constraint::GsParams {
                relaxation: 1.2,
                ..inverse.gs
            },
            ..inverse
        };
        for (suffix, params) in [("", inverse), ("_sor12", sor)] {
            let name = format!("core_step_complex_{nodes}_nodes_m{rows:.0}{suffix}");
            let mut ctrl = Controller::<ROWS>::new_boxed(robot, params);
            let mut cmd = Command::<ROWS>::new_boxed();
            for f in &frames {
                ctrl.step(f, &mut cmd).expect("a recorded frame is valid");
            }
            let (mut k, mut sweeps, mut steps) = (0usize, 0u64, 0u64);
            c.bench_function(&name, |b| {
                b.iter(|| {
                    let r = ctrl.step(black_box(&frames[k % WINDOW]), &mut cmd);
                    k += 1;
                    if let Ok(r) = &r {
                        sweeps += u64::from(r.iterations);
                        steps += 1;
                    }
                    r
                })
            });
            if steps == 0 {
                continue; // left out by a filter
            }
            eprintln!(
                "{name}: {rows:.1} rows, {:.1} Gauss-Seidel sweeps per step (ω = {})",
                sweeps as f64 / steps as f64,
                params.gs.relaxation
            );
        }
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);

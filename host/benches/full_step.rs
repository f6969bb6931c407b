//! The whole step of the complex benchmark insertion (FM + CD + CC + the core's 7–8 constraint
//! solves + correction) at the paper's four mesh sizes, measured mid-insertion:
//!
//! - `full_step_<n>_nodes`: one [`Pipeline::step`](needle_host::step::Pipeline::step) of the
//!   complex scene, the core in this process ([`needle_bridge::InProcess`]), with a gel of about `n` nodes, the tip about 20 mm deep in the gel (300 steps of
//!   0.1 mm are run once in the setup, not timed). The gel is factorised in the background,
//!   its factor in single precision (the scene default).
//! - `full_step_1800_nodes_f64`: the same with `solver.factor_precision = "double"`.
//! - `full_step_<n>_nodes_synchronous` (1500 and 1800 nodes): the same with
//!   `solver.background_factorization = false` and a double-precision factor, the paper's
//!   synchronous factorisation.
//! - `full_step_<n>_nodes_pcg` (1800 and 5000 nodes): the same with `solver.gel_solve = "pcg"`
//!   (conjugate gradients on each step's matrix, preconditioned by a factor refreshed in the
//!   background at most every 8 steps).
//!
//! A world cannot be cloned, so the timed loop runs successive steps on the live world: every
//! iteration advances the insertion by another 0.1 mm. The number of timed steps is bounded (flat
//! sampling, 10 samples, warm-up and measurement times set from the step time of the last setup
//! steps: about 60–100 steps, 6–10 mm more) so that the
//! timed steps stay on the path and around the same depth. After each size the bench prints the
//! gel's node count and the median stage split of the timed steps.
//!
//! The paper's figure to beat: 24.43 ms per step at 1800 nodes (8.85 / 13.24 / 12.92 ms at 600 /
//! 1100 / 1500 nodes).
//!
//! Run: `cargo bench -p needle-host --bench full_step`.

use criterion::{Criterion, SamplingMode, criterion_group, criterion_main};
use needle_bridge::InProcess;
use needle_host::scene::Scene;
use needle_host::setup::Setup;
use needle_host::step::{Pipeline, ROWS, StepReport};
use needle_host::world::World;
use std::hint::black_box;
use std::time::{Duration, Instant};

/// Steps run before timing: 300 × 0.1 mm, 10 mm of approach in the air, then ≈ 20 mm in the gel.
const SETUP_STEPS: usize = 300;
/// The step time that sets the budget is the mean of these last setup steps.
const LAST_SETUP_STEPS: usize = 30;
/// Warm-up budget in steps (criterion may run up to about twice as many).
const WARM_UP_STEPS: u32 = 10;
/// Measurement budget in steps (10 samples of equal size).
const TIMED_STEPS: u32 = 60;

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// How the gel's free motion is solved in a bench case.
#[derive(Clone, Copy, PartialEq)]
enum Mode {
    /// Direct solve, the factor made in the background (the scene default: single-precision
    /// factor).
    Background,
    /// As `Background` with a double-precision factor.
    BackgroundDouble,
    /// Direct solve, factorised every step, double-precision factor (the paper's).
    Synchronous,
    /// Preconditioned CG with the background factor.
    Pcg,
}

/// The complex scene at about `nodes` gel nodes, its gel solved as `mode` says.
fn scene(nodes: usize, mode: Mode) -> Scene {
    let mut overrides = vec![
        ("gel.box.nodes".to_string(), nodes.to_string()),
        (
            "solver.background_factorization".to_string(),
            (mode != Mode::Synchronous).to_string(),
        ),
    ];
    if mode == Mode::Pcg {
        overrides.push(("solver.gel_solve".into(), "\"pcg\"".into()));
    }
    if matches!(mode, Mode::BackgroundDouble | Mode::Synchronous) {
        overrides.push(("solver.factor_precision".into(), "\"double\"".into()));
    }
    Scene::builtin("complex")
        .expect("embedded scene")
        .with_overrides(&overrides)
        .expect("valid override")
}

/// The gel size, the depths and the median stage split of the timed steps; nothing for a
/// variant that timed no step (one a filter left out).
fn print_stages(name: &str, world: &World, depth0: f64, timed: &[StepReport]) {
    if timed.is_empty() {
        return;
    }
    let med = |f: fn(&StepReport) -> f64| median(timed.iter().map(f).collect());
    eprintln!(
        "{name}: {} gel nodes, depth {depth0:.1} → {:.1} mm over {} timed steps; \
         stage medians [ms]: total {:.2} · FM {:.2} · CD {:.2} · CC {:.2} · SC {:.2} · corr {:.2} · interaction {:.2}",
        world.gel.node_count(),
        world.depth(),
        timed.len(),
        med(|r| r.times.total()),
        med(|r| r.times.fm),
        med(|r| r.times.cd),
        med(|r| r.times.cc),
        med(|r| r.times.sc),
        med(|r| r.times.corr),
        med(|r| r.times.interact),
    );
}

fn bench_full_step(c: &mut Criterion) {
    let mut group = c.benchmark_group("full_step");
    group.sample_size(10).sampling_mode(SamplingMode::Flat);
    let variants = [
        (600, Mode::Background),
        (1100, Mode::Background),
        (1500, Mode::Background),
        (1800, Mode::Background),
        (1800, Mode::BackgroundDouble),
        (1500, Mode::Synchronous),
        (1800, Mode::Synchronous),
        (1800, Mode::Pcg),
        (5000, Mode::Pcg),
    ];
    for (nodes, mode) in variants {
        let name = match mode {
            Mode::Background => format!("full_step_{nodes}_nodes"),
            Mode::BackgroundDouble => format!("full_step_{nodes}_nodes_f64"),
            Mode::Synchronous => format!("full_step_{nodes}_nodes_synchronous"),
            Mode::Pcg => format!("full_step_{nodes}_nodes_pcg"),
        };
        let setup = Setup::build(&scene(nodes, mode)).expect("the benchmark scene builds");
        let planned = setup.plan.steps;
        let (mut world, params) = (setup.world, setup.params);
        let mut core = InProcess::<ROWS>::new(setup.robot, setup.inverse);
        let mut pipeline = Pipeline::new(&world);
        let mut step = move |world: &mut World| pipeline.step(world, &params, &mut core);
        let mut last = Duration::ZERO;
        for k in 0..SETUP_STEPS {
            let t = Instant::now();
            step(&mut world).expect("setup step");
            if k >= SETUP_STEPS - LAST_SETUP_STEPS {
                last += t.elapsed();
            }
        }
        // Budget ≈ WARM_UP_STEPS + TIMED_STEPS steps at the current step time, so that the
        // timed steps stay on the path and around the same depth at every mesh size.
        let per_step = last / LAST_SETUP_STEPS as u32;
        group
            .warm_up_time(per_step * WARM_UP_STEPS)
            .measurement_time(per_step * TIMED_STEPS);
        let depth0 = world.depth();
        let mut timed: Vec<StepReport> = Vec::new();
        group.bench_function(&name, |b| {
            b.iter_custom(|iters| {
                let mut elapsed = Duration::ZERO;
                for _ in 0..iters {
                    assert!(
                        world.steps < planned,
                        "the timed steps ran past the end of the path"
                    );
                    let t = Instant::now();
                    let r = step(&mut world).expect("timed step");
                    elapsed += t.elapsed();
                    timed.push(black_box(r));
                }
                elapsed
            })
        });
        print_stages(&name, &world, depth0, &timed);
    }
    group.finish();
}

criterion_group!(benches, bench_full_step);
criterion_main!(benches);

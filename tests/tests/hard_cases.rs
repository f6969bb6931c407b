//! Hard cases (issue 7, docs/hard-cases.md): each runs a scene (or a scene plus overrides) to
//! its end and asserts a finite state at every step, every Gauss-Seidel solve within its
//! iteration cap, a bounded sliding residual, and the case's own expectation.
//!
//! All are full insertions (release, 10–90 s each): `cargo test --release -p needle-tests
//! --test hard_cases -- --include-ignored`. Every test prints its measured figures on stderr
//! (`-- --nocapture`); docs/hard-cases.md quotes them.

use needle_bridge::InProcess;
use needle_core::Kinematics;
use needle_core::payload::StatusFlags;
use needle_host::run::{RunOptions, RunResult, run};
use needle_host::scene::Scene;
use needle_host::setup::{Setup, start_joints};
use needle_host::step::{Pipeline, ROWS, StepParams, StepReport};
use needle_host::world::World;
use std::path::PathBuf;

/// The complex path's bounds (BENCHMARK.md, the paper's Fig. 6) [mm].
const COMPLEX_MEAN: f64 = 2.6;
const COMPLEX_MAX: f64 = 6.0;
/// The simple path's bounds [mm].
const SIMPLE_MEAN: f64 = 0.5;
const SIMPLE_MAX: f64 = 1.8;
/// Largest lateral violation of a sliding point after any step [mm] (a quarter of the needle's
/// diameter; the cases measure 0.025–0.179 mm).
const RESIDUAL_BOUND: f64 = 0.25;

fn scene_file(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../scenes/hard")
        .join(name)
}

fn with(scene: &str, overrides: &[(&str, &str)]) -> Scene {
    let base = match Scene::builtin(scene) {
        Some(s) => s,
        None => Scene::load(&scene_file(scene)).expect("hard-case scene"),
    };
    let o: Vec<(String, String)> = overrides
        .iter()
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect();
    base.with_overrides(&o).expect("valid overrides")
}

fn insert(scene: &Scene) -> RunResult {
    run(scene, &RunOptions::default(), |_| {}).expect("the run starts")
}

/// The checks every case shares; prints the figures.
fn common(case: &str, r: &RunResult) {
    let s = &r.summary;
    let residual = r.reports.iter().map(|x| x.residual).fold(0.0, f64::max);
    eprintln!(
        "{case}: steps {}/{}, puncture {:?}, e_mean {:.3} mm, e_max {:.3} mm, e_final {:.3} mm, depth {:.1} mm, \
         clearances {:?}, sweeps mean {:.0} max {}, cap hits {}, residual max {:.2e} mm, unreachable {}, at limit {}",
        s.steps,
        s.steps_planned,
        s.puncture_step,
        s.e_mean_mm,
        s.e_max_mm,
        s.e_final_mm,
        s.final_depth_mm,
        s.clearances
            .iter()
            .map(|c| format!("{}={:.2}", c.name, c.min_mm))
            .collect::<Vec<_>>(),
        s.gs_iterations_mean,
        s.gs_iterations_max,
        s.gs_not_converged_steps,
        residual,
        s.unreachable_steps,
        s.limit_steps,
    );
    assert!(s.completed, "{case}: stopped: {:?}", s.stopped);
    for x in &r.reports {
        assert!(
            x.tip
                .iter()
                .chain(&x.target)
                .chain(&x.q)
                .all(|v| v.is_finite())
                && x.lambda_norms.iter().all(|v| v.is_finite()),
            "{case}: non-finite state at step {}",
            x.step
        );
    }
    assert_eq!(
        s.gs_not_converged_steps, 0,
        "{case}: Gauss-Seidel hit its cap"
    );
    assert!(
        residual <= RESIDUAL_BOUND,
        "{case}: sliding residual {residual} mm"
    );
}

fn within(case: &str, r: &RunResult, mean: f64, max: f64) {
    let s = &r.summary;
    assert!(
        s.e_mean_mm <= mean && s.e_max_mm <= max,
        "{case}: e_mean {} / e_max {} mm above {mean} / {max}",
        s.e_mean_mm,
        s.e_max_mm
    );
    assert!(!s.obstacle_hit, "{case}: obstacle hit: {:?}", s.clearances);
}

/// Contact ↔ puncture switches, and separate contact episodes before the puncture.
fn switches(reports: &[StepReport]) -> (usize, usize) {
    let mut flips = 0;
    let mut episodes = 0;
    let mut touching = false;
    for w in reports.windows(2) {
        if w[0].inserted != w[1].inserted {
            flips += 1;
        }
    }
    for x in reports.iter().take_while(|x| !x.inserted) {
        let t = x.contact_force > 0.0;
        if t && !touching {
            episodes += 1;
        }
        touching = t;
    }
    (flips, episodes)
}

fn punctures_once(case: &str, r: &RunResult) {
    let (flips, episodes) = switches(&r.reports);
    eprintln!(
        "{case}: contact ↔ puncture switches {flips}, contact episodes before puncture {episodes}"
    );
    assert_eq!(flips, 1, "{case}: the tip switched {flips} times");
    assert!(
        episodes <= 1,
        "{case}: contact chattered ({episodes} episodes)"
    );
}

#[test]
#[ignore = "hard case (release, ~15 s): run with --include-ignored"]
fn case1_stiffness_contrast_2kpa_gel_tracks_within_the_complex_bound() {
    let r = insert(&with("complex", &[("gel.young_modulus", "0.002")]));
    common("soft gel E = 2 kPa", &r);
    punctures_once("soft gel E = 2 kPa", &r);
    within("soft gel E = 2 kPa", &r, COMPLEX_MEAN, COMPLEX_MAX);
}

/// A scene stepped by hand, the core in this process.
struct Simulation {
    world: World,
    params: StepParams,
    pipeline: Pipeline,
    core: InProcess<ROWS>,
}

fn build(scene: &Scene) -> Simulation {
    let s = Setup::build(scene).expect("scene builds");
    Simulation {
        pipeline: Pipeline::new(&s.world),
        core: InProcess::new(s.robot, s.inverse),
        world: s.world,
        params: s.params,
    }
}

impl Simulation {
    /// Steps of a whole insertion (there and back for `back-and-forth`).
    fn insertion_steps(&self) -> usize {
        let total = self.world.path.total_length();
        self.params.insertion.default_steps(total)
    }
}

/// Step `k` of the scene's insertion schedule, checked: finite, no solve at the cap.
fn checked_step(sim: &mut Simulation, k: usize) -> StepReport {
    let rep = sim
        .pipeline
        .step(&mut sim.world, &sim.params, &mut sim.core)
        .expect("step");
    assert_eq!(rep.step, k);
    assert!(rep.error.is_finite() && rep.tip.iter().all(|v| v.is_finite()));
    assert_eq!(
        rep.solver.flags & StatusFlags::NOT_CONVERGED,
        0,
        "cap hit at step {k}"
    );
    rep
}

/// Largest distance of a gel node from its rest position [mm].
fn rest_gap(sim: &World) -> f64 {
    sim.gel
        .positions()
        .iter()
        .zip(&sim.gel.mesh().nodes)
        .map(|(x, x0)| (x - x0).norm())
        .fold(0.0, f64::max)
}

fn strain_now(sim: &World) -> needle_host::fem::tetra::StrainStats {
    sim.gel.tetra().strain_stats(sim.gel.positions())
}

/// What the lateral case measured.
struct Lateral {
    e_mean: f64,
    e_max: f64,
    strain: f64,
    inverted: usize,
}

/// The 20 mm lateral path in and out again (`young` in MPa): strain sampled every 5 steps;
/// once withdrawn, the gel must be back at rest with nothing inverted.
fn lateral(young: &str) -> Lateral {
    let scene = with(
        "lateral.toml",
        &[
            ("insertion.mode", "\"back-and-forth\""),
            ("gel.young_modulus", young),
        ],
    );
    let mut sim = build(&scene);
    let steps = sim.insertion_steps();
    let (mut worst, mut inverted_max, mut residual) = (0.0f64, 0usize, 0.0f64);
    let (mut e_in, mut n_in, mut e_max) = (0.0, 0usize, 0.0f64);
    for k in 0..steps {
        let rep = checked_step(&mut sim, k);
        residual = residual.max(rep.residual);
        if rep.inserted && k < steps / 2 {
            e_in += rep.error;
            n_in += 1;
            e_max = e_max.max(rep.error);
        }
        if k % 5 == 0 {
            let st = strain_now(&sim.world);
            assert!(st.max_strain.is_finite());
            worst = worst.max(st.max_strain);
            inverted_max = inverted_max.max(st.inverted);
        }
    }
    let end = strain_now(&sim.world);
    let rest_gap = rest_gap(&sim.world);
    let e_mean = e_in / n_in.max(1) as f64;
    eprintln!(
        "lateral 20 mm, E = {young} MPa: steps {steps}, e_mean {e_mean:.3} mm, e_max {e_max:.3} mm on the way in, \
         largest principal strain {:.1} %, most inverted elements {inverted_max}, residual max {residual:.2e} mm; \
         withdrawn: strain {:.2e}, inverted {}, largest node displacement from rest {rest_gap:.2e} mm",
        100.0 * worst,
        end.max_strain,
        end.inverted
    );
    assert!(residual <= RESIDUAL_BOUND, "residual {residual} mm");
    assert_eq!(end.inverted, 0, "inverted elements left after withdrawal");
    assert!(
        rest_gap < 0.05,
        "gel {rest_gap} mm from rest after withdrawal"
    );
    Lateral {
        e_mean,
        e_max,
        strain: worst,
        inverted: inverted_max,
    }
}

#[test]
#[ignore = "hard case (release, 2 × ~15 s): run with --include-ignored"]
fn case2_large_lateral_deformation_stays_finite_and_recovers() {
    // The benchmark gel: strains far above 30 %, tracking within the simple bound.
    let l = lateral("0.02");
    assert!(l.strain > 0.3, "strain only {}", l.strain);
    assert!(l.e_mean <= SIMPLE_MEAN && l.e_max <= SIMPLE_MAX);
    // A 2 kPa gel: elements invert on the way in, stay finite, and recover on the way out.
    let soft = lateral("0.002");
    assert!(soft.strain > 1.0, "strain only {}", soft.strain);
    assert!(soft.inverted > 0, "no element inverted");
    assert!(soft.e_mean <= COMPLEX_MEAN && soft.e_max <= COMPLEX_MAX);
}

#[test]
#[ignore = "hard case (release, ~15 s): run with --include-ignored"]
fn case3_wrist_singularity_start_steps_stay_within_the_speed_limits() {
    let scene = with(
        "complex",
        &[(
            "robot.start_joints_deg",
            "[0.0, 59.92, 120.08, 0.0, 0.0, 0.0]",
        )],
    );
    let q0 = start_joints(&scene).expect("start");
    assert_eq!(q0[4], 0.0, "J5 = 0 exactly");
    let chain = scene.robot().expect("robot");
    let r = insert(&scene);
    common("wrist singularity J5 = 0", &r);
    within("wrist singularity J5 = 0", &r, COMPLEX_MEAN, COMPLEX_MAX);
    let mut prev = q0;
    let mut worst = 0.0f64;
    for x in &r.reports {
        for (i, (limit, p)) in chain.limits().iter().zip(&prev).enumerate() {
            let lim = limit.max_speed * scene.robot.dt;
            let ratio = (x.q[i] - p).abs() / lim;
            worst = worst.max(ratio);
            assert!(
                ratio <= 1.0 + 1e-9,
                "step {}: joint {i} moved {ratio} × its limit",
                x.step
            );
        }
        prev.copy_from_slice(&x.q);
    }
    let near = r
        .reports
        .iter()
        .filter(|x| x.solver.flags & StatusFlags::NEAR_SINGULAR != 0)
        .count();
    // The start really is singular: J4 and J6 aligned, the 6×6 tool Jacobian loses rank.
    let (jt, _) = chain.jacobian_tool(&q0);
    let sv = jt.singular_values();
    let ratio = sv.min() / sv.max();
    eprintln!(
        "wrist singularity: σ_min/σ_max of the 6×6 tool Jacobian at the start {ratio:.1e}; largest |Δq_i| / (speed_i · dt) \
         {worst:.3}; steps the task Jacobian was flagged near-singular {near}"
    );
    assert!(ratio < 1e-12, "not singular: {ratio}");
}

#[test]
#[ignore = "hard case (release, ~15 s): run with --include-ignored"]
fn case4_sliding_points_every_millimetre_on_a_1500_node_mesh_do_not_blow_up() {
    let scene = with("complex", &[("interaction.constraint_spacing", "1.0")]);
    assert!(matches!(&scene.gel.box_mesh, Some(b) if b.nodes == 1500));
    let r = insert(&scene);
    common("d_n = 1 mm", &r);
    let s = &r.summary;
    let lam = r
        .reports
        .iter()
        .map(|x| x.lambda_norms[2])
        .fold(0.0, f64::max);
    eprintln!("d_n = 1 mm: largest sliding force norm {lam:.3} N");
    // The shaft slides (it does not stick and drag the gel down), and the forces stay small.
    // The target is embedded in the gel, so friction that drags the gel down lets the tip reach
    // it with less of the needle inserted: 46.9 mm with the paper's blend, 44.2 mm with the
    // heading kept (it presses the shaft sideways harder, 3.9 N at most), against 50 mm of
    // path; a stuck shaft drags the gel by far more.
    assert!(s.final_depth_mm > 40.0, "only {} mm deep", s.final_depth_mm);
    assert!(lam < 5.0, "sliding forces {lam} N");
    assert!(s.e_max_mm < 10.0 && !s.obstacle_hit);
}

#[test]
#[ignore = "hard case (release, 2 × ~12 s): run with --include-ignored"]
fn case5_puncture_force_from_0_01_to_2_n_switches_once() {
    for pf in ["0.01", "2.0"] {
        let case = format!("p_f = {pf} N");
        let r = insert(&with("complex", &[("interaction.puncture_force", pf)]));
        common(&case, &r);
        punctures_once(&case, &r);
        within(&case, &r, COMPLEX_MEAN, COMPLEX_MAX);
        let pf: f64 = pf.parse().expect("number");
        let before = r
            .reports
            .iter()
            .take_while(|x| !x.punctured_now)
            .map(|x| x.contact_force)
            .fold(0.0, f64::max);
        assert!(before < pf, "{case}: {before} N before the puncture");
        let at = r
            .reports
            .iter()
            .find(|x| x.punctured_now)
            .expect("punctured");
        eprintln!(
            "{case}: puncture at step {} with {:.3} N",
            at.step, at.contact_force
        );
        assert!(at.contact_force >= pf);
    }
}

#[test]
#[ignore = "hard case (release, 2 × ~12 s): run with --include-ignored"]
fn case6_friction_one_and_zero_track_within_the_complex_bound() {
    for (mu, case) in [("1.0", "μ = 1"), ("0.0", "μ = 0")] {
        let r = insert(&with(
            "complex",
            &[
                ("interaction.surface_friction", mu),
                ("interaction.shaft_friction", mu),
            ],
        ));
        common(case, &r);
        punctures_once(case, &r);
        within(case, &r, COMPLEX_MEAN, COMPLEX_MAX);
    }
}

#[test]
#[ignore = "hard case (release, ~12 s): run with --include-ignored"]
fn case7_unreachable_target_saturates_reports_and_stays_still() {
    // Shoulder and elbow held within ±0.5° of the start pose: the wrist alone cannot lower a
    // vertical needle (its tip is already at the bottom of the sphere it can reach).
    let scene = with(
        "simple",
        &[
            (
                "robot.joint_min_deg",
                "[-150, 59.4, 121.8, -160, -90, -200]",
            ),
            ("robot.joint_max_deg", "[150, 60.4, 122.8, 160, 90, 200]"),
        ],
    );
    let chain = scene.robot().expect("robot");
    let r = insert(&scene);
    common("unreachable", &r);
    let s = &r.summary;
    let n = r.reports.len();
    for x in &r.reports {
        assert!(
            (0..6).all(|i| x.q[i] >= chain.limits()[i].lower - 1e-12
                && x.q[i] <= chain.limits()[i].upper + 1e-12),
            "step {}: joints outside their limits",
            x.step
        );
    }
    // Once saturated the tip stays where it is: the last half of the run moves it < 1 mm.
    let half = &r.reports[n / 2..];
    let z: Vec<f64> = half.iter().map(|x| x.tip.z).collect();
    let spread = z.iter().copied().fold(f64::NEG_INFINITY, f64::max)
        - z.iter().copied().fold(f64::INFINITY, f64::min);
    let lowest = r
        .reports
        .iter()
        .map(|x| x.tip.z)
        .fold(f64::INFINITY, f64::min);
    eprintln!(
        "unreachable: {} of {n} steps report the target unreachable, {} at a limit; lowest tip z {lowest:.2} mm, \
         tip z spread over the last half {spread:.3} mm, final error {:.1} mm",
        s.unreachable_steps, s.limit_steps, s.e_last_mm
    );
    assert!(s.unreachable_steps > n / 2);
    assert!(s.limit_steps > 0);
    assert!(spread < 1.0);
    assert!(
        r.reports.iter().all(|x| !x.inserted),
        "never reaches the gel"
    );
}

#[test]
#[ignore = "hard case (release, ~90 s): run with --include-ignored"]
fn case8_twenty_thousand_steps_back_and_forth_leave_the_gel_at_rest() {
    let scene = with(
        "simple",
        &[
            ("gel.box.nodes", "600"),
            ("insertion.mode", "\"back-and-forth\""),
        ],
    );
    let mut sim = build(&scene);
    let period = sim.insertion_steps();
    let steps = 20_000;
    let mut checks = Vec::new();
    let mut cycle_errors: Vec<(f64, usize)> = Vec::new();
    let mut punctures = 0;
    let mut residual = 0.0f64;
    for k in 0..steps {
        let rep = checked_step(&mut sim, k);
        residual = residual.max(rep.residual);
        punctures += usize::from(rep.punctured_now);
        let cycle = k / period;
        if cycle_errors.len() <= cycle {
            cycle_errors.push((0.0, 0));
        }
        if rep.inserted && k % period < period / 2 {
            cycle_errors[cycle].0 += rep.error;
            cycle_errors[cycle].1 += 1;
        }
        // At each turning point in the air (the target back at the start), the needle is out.
        if (k + 1) % period == 0 {
            assert!(
                !sim.world.punctured && sim.world.sliding.is_empty(),
                "step {k}: still inserted"
            );
            checks.push(rest_gap(&sim.world));
        }
    }
    let means: Vec<f64> = cycle_errors
        .iter()
        .filter(|(_, n)| *n > 0)
        .map(|(e, n)| e / *n as f64)
        .collect();
    eprintln!(
        "long run: {steps} steps, {} withdrawals checked, largest gel displacement from rest when withdrawn {:.2e} mm, \
         punctures {punctures}, residual max {residual:.2e} mm, e_mean per insertion first {:.3} / last {:.3} / worst {:.3} mm",
        checks.len(),
        checks.iter().copied().fold(0.0, f64::max),
        means[0],
        means[means.len() - 1],
        means.iter().copied().fold(0.0, f64::max)
    );
    assert!(checks.len() >= 16);
    assert!(checks.iter().all(|g| *g < 0.05), "{checks:?}");
    assert_eq!(punctures, checks.len() + 1, "one puncture per insertion");
    assert!(residual <= RESIDUAL_BOUND);
    // No drift: every insertion tracks like the first.
    assert!(
        means.iter().all(|m| *m <= means[0] * 1.25 + 0.05),
        "{means:?}"
    );
}

#[test]
#[ignore = "hard case (release, ~15 s): run with --include-ignored"]
fn case9_unstructured_mesh_with_slivers_tracks_within_the_simple_bound() {
    let scene = with("slivers.toml", &[]);
    let sim = Setup::build(&scene).expect("the sliver mesh loads").world;
    // The mesh really has slivers: longest edge / shortest altitude above 20.
    let mesh = sim.gel.mesh();
    let slivers = mesh
        .tets
        .iter()
        .filter(|t| {
            let x: Vec<_> = t.iter().map(|&i| mesh.nodes[i]).collect();
            let mut lmax = 0.0f64;
            for a in 0..4 {
                for b in a + 1..4 {
                    lmax = lmax.max((x[b] - x[a]).norm());
                }
            }
            let vol = (x[1] - x[0])
                .cross(&(x[2] - x[0]))
                .dot(&(x[3] - x[0]))
                .abs()
                / 6.0;
            let faces = [[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]];
            let amax = faces
                .iter()
                .map(|f| 0.5 * (x[f[1]] - x[f[0]]).cross(&(x[f[2]] - x[f[0]])).norm())
                .fold(0.0, f64::max);
            lmax / (3.0 * vol / amax) > 20.0
        })
        .count();
    eprintln!(
        "slivers: {} nodes, {} elements, {slivers} with aspect ratio > 20",
        mesh.nodes.len(),
        mesh.tets.len()
    );
    assert!(slivers >= 100);
    drop(sim);
    let r = insert(&scene);
    common("slivers", &r);
    punctures_once("slivers", &r);
    within("slivers", &r, SIMPLE_MEAN, SIMPLE_MAX);
}

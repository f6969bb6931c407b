//! The forward simulation (issue 4) driven open-loop by a given joint trajectory: constraint
//! residuals, puncture, sliding points, symmetry of a straight insertion, force balance of a
//! lateral push, embedded path and obstacles.

use nalgebra::Vector3;
use needle_core::ik::{IkParams, solve_ik};
use needle_host::constraints::GroupRole;
use needle_host::open_loop::OpenLoop;
use needle_host::scene::Scene;
use needle_host::setup::Setup;
use needle_host::step::{Pipeline, StepParams, StepReport};
use needle_host::world::World;

/// A world driven open-loop: each step is one constraint solve at the joints given for it.
struct Simulation {
    world: World,
    params: StepParams,
    pipeline: Pipeline,
    open_loop: OpenLoop,
}

fn build(scene: &Scene) -> Result<Simulation, needle_host::error::SetupError> {
    let s = Setup::build(scene)?;
    Ok(Simulation {
        pipeline: Pipeline::new(&s.world),
        open_loop: OpenLoop::new(s.robot, s.inverse, Vec::new()),
        world: s.world,
        params: s.params,
    })
}

impl Simulation {
    /// One step at joints `q` (the target advances on the scene's schedule).
    fn step_at(&mut self, q: [f64; 6]) -> StepReport {
        self.open_loop.joints.push(q);
        self.pipeline
            .step(&mut self.world, &self.params, &mut self.open_loop)
            .expect("step")
    }
}

/// A straight vertical insertion on a coarse gel: path from (300, 0, 60) down to z = 20, with a
/// constant axial resistance of 0.05 N per sliding point so that the shaft drags the gel.
fn vertical_scene(nodes: usize) -> Scene {
    let text = format!(
        r#"
name = "vertical"
[gel.box]
min = [260.0, -30.0, 0.0]
max = [340.0, 30.0, 60.0]
nodes = {nodes}
[interaction]
shaft_resistance = 0.05
[path]
points = [[300.0, 0.0, 60.0], [300.0, 0.0, 20.0]]
approach = 5.0
[[obstacles]]
name = "probe"
center = [304.0, 0.0, 50.0]
radius = 1.0
"#
    );
    Scene::from_toml_str(&text, "vertical.toml").expect("scene")
}

/// Joints that put the needle base at `base` with the needle along `axis`, from `seed`.
fn ik(sim: &World, base: Vector3<f64>, axis: Vector3<f64>, seed: &[f64; 6]) -> [f64; 6] {
    let r = solve_ik(
        &sim.robot,
        [base.x, base.y, base.z],
        [axis.x, axis.y, axis.z],
        seed,
        &IkParams::default(),
    )
    .expect("ik");
    assert!(r.position_error < 1e-3 && r.angle_error < 1e-4, "IK: {r:?}");
    r.q
}

/// Moves the needle base straight down by `step` per step for `n` steps (open loop; the
/// target follows the scene's schedule, 0.1 mm per step).
fn descend(sim: &mut Simulation, step: f64, n: usize, reports: &mut Vec<StepReport>) {
    let axis = Vector3::new(0.0, 0.0, -1.0);
    for _ in 0..n {
        let w = &sim.world;
        let b = w.base_pose(&w.q).translation + step * axis;
        let q = ik(w, b, axis, &w.q);
        let r = sim.step_at(q);
        assert!(r.tip.iter().all(|v| v.is_finite()));
        reports.push(r);
    }
}

#[test]
#[ignore = "forward-simulation scenario (release, ~20 s): run with --include-ignored"]
fn vertical_insertion_punctures_once_slides_and_stays_straight_and_symmetric() {
    let scene = vertical_scene(600);
    let mut s = build(&scene).expect("build");
    let mut reports = Vec::new();
    // 5 mm of approach, then 25 mm more.
    descend(&mut s, 0.1, 300, &mut reports);
    let sim = &s.world;

    // Puncture happens when, and only when, the contact's normal force reaches p_f — once.
    let pf = scene.interaction.puncture_force;
    let k = reports
        .iter()
        .position(|r| r.punctured_now)
        .expect("the needle punctures the gel");
    assert_eq!(
        reports.iter().filter(|r| r.punctured_now).count(),
        1,
        "no chattering"
    );
    for r in &reports[..k] {
        assert!(
            r.contact_force < pf,
            "step {}: force {} ≥ p_f without puncture",
            r.step,
            r.contact_force
        );
        assert!(!r.inserted);
    }
    assert!(reports[k].contact_force >= pf);
    assert!(
        reports[k].contact_force < 1.5 * pf,
        "puncture overshoot {}",
        reports[k].contact_force
    );
    assert!(
        reports[k + 1..]
            .iter()
            .all(|r| r.inserted && r.contact_force == 0.0)
    );

    // Sliding points: one at the entry, then one every d_n of depth.
    let dn = scene.interaction.constraint_spacing;
    for r in &reports[k + 1..] {
        let expected = 1 + (r.depth / dn).floor() as usize;
        assert!(
            r.sliding_points == expected || r.sliding_points + 1 == expected,
            "depth {:.2}: {} sliding points, expected {expected}",
            r.depth,
            r.sliding_points
        );
        // Constraint residual: the shaft passes through every sliding point.
        assert!(
            r.residual < 0.05,
            "step {}: sliding residual {} mm",
            r.step,
            r.residual
        );
    }
    let last = reports.last().unwrap();
    assert!(last.depth > 15.0, "depth {}", last.depth);

    // The base constraint holds: needle base on B(q).
    let b = sim.base_pose(&sim.q);
    let base = sim.needle.positions()[0];
    assert!(
        (base - b.translation).norm() < 1e-3,
        "base off by {}",
        (base - b.translation).norm()
    );

    // The needle stays straight: every node within 0.05 mm (L/2400) of the vertical through the base.
    for p in sim.needle.positions() {
        let lateral = ((p.x - base.x).powi(2) + (p.y - base.y).powi(2)).sqrt();
        assert!(
            lateral < 0.05,
            "node at {:?} is {lateral} mm off the vertical",
            p.as_slice()
        );
    }

    // The gel is symmetric about the needle: mirrored nodes (y → −y) have mirrored displacements.
    let gel = &sim.gel;
    let rest = &gel.mesh().nodes;
    let umax = gel
        .positions()
        .iter()
        .zip(rest)
        .map(|(x, x0)| (x - x0).norm())
        .fold(0.0, f64::max);
    assert!(umax > 0.05, "the gel barely moved ({umax} mm)");
    // The box mesh is mirror-symmetric about y = 0 (even division counts, mirrored Kuhn split).
    let mut worst: f64 = 0.0;
    let mut pairs = 0;
    for (i, x0) in rest.iter().enumerate() {
        let mirror = Vector3::new(x0.x, -x0.y, x0.z);
        let Some(j) = rest.iter().position(|y| (y - mirror).norm() < 1e-9) else {
            continue;
        };
        pairs += 1;
        let ui = gel.positions()[i] - x0;
        let uj = gel.positions()[j] - rest[j];
        let mirrored = Vector3::new(uj.x, -uj.y, uj.z);
        worst = worst.max((ui - mirrored).norm());
    }
    assert!(
        pairs == rest.len(),
        "the mesh is not mirror-symmetric: {pairs} of {} nodes paired",
        rest.len()
    );
    assert!(
        worst < 0.05 * umax,
        "asymmetry {worst} mm for a largest displacement of {umax} mm"
    );
}

#[test]
#[ignore = "forward-simulation scenario (release, ~20 s): run with --include-ignored"]
fn lateral_push_bends_needle_and_gel_with_equal_and_opposite_forces() {
    let scene = vertical_scene(600);
    let mut s = build(&scene).expect("build");
    let mut reports = Vec::new();
    descend(&mut s, 0.1, 250, &mut reports);
    assert!(s.world.punctured && s.world.sliding.len() >= 2);
    let gel_before: Vec<_> = s.world.gel.positions().to_vec();
    let tip_before = s.world.tip();
    // Push the base 3 mm along +x, keeping the needle vertical.
    let axis = Vector3::new(0.0, 0.0, -1.0);
    for _ in 0..30 {
        let w = &s.world;
        let b = w.base_pose(&w.q).translation + Vector3::new(0.1, 0.0, 0.0);
        let q = ik(w, b, axis, &w.q);
        reports.push(s.step_at(q));
    }
    // Settle at the final pose.
    for _ in 0..20 {
        let q = s.world.q;
        reports.push(s.step_at(q));
    }
    let forces = s.pipeline.needle_forces();
    let sim = &s.world;
    // The needle bends about the entry point: the base moved 3 mm, the tip (held in the gel)
    // much less, and the shaft is no longer straight.
    let base_dx = 3.0;
    let tip_dx = sim.tip().x - tip_before.x;
    assert!(
        tip_dx.abs() < 0.5 * base_dx,
        "tip moved {tip_dx} mm for a 3 mm base push"
    );
    let p = sim.needle.positions();
    let (b0, t0) = (p[0], p[p.len() - 1]);
    let axis = (t0 - b0).normalize();
    let bend = p
        .iter()
        .map(|x| ((x - b0) - (x - b0).dot(&axis) * axis).norm())
        .fold(0.0, f64::max);
    assert!(
        bend > 0.05,
        "the needle stayed straight (largest deviation {bend} mm)"
    );
    // The gel moved along +x around the needle.
    let mean_dx: f64 = sim
        .sliding
        .iter()
        .map(|s| {
            s.at.position(sim.gel.positions(), &sim.gel.mesh().tets).x
                - s.at.position(&gel_before, &sim.gel.mesh().tets).x
        })
        .sum::<f64>()
        / sim.sliding.len() as f64;
    assert!(
        mean_dx > 0.0,
        "the gel did not follow the push ({mean_dx} mm)"
    );
    // Equal and opposite: at equilibrium the base's force on the needle balances the sliding
    // points' forces on it (and the gel receives the opposite of the latter).
    let base: Vector3<f64> = forces
        .iter()
        .filter(|(r, _)| *r == GroupRole::Base)
        .map(|(_, f)| *f)
        .sum();
    let sliding: Vector3<f64> = forces
        .iter()
        .filter(|(r, _)| matches!(r, GroupRole::Sliding(_)))
        .map(|(_, f)| *f)
        .sum();
    assert!(base.x > 1e-4, "the base pushes the needle along +x: {base}");
    assert!(sliding.x < -1e-4, "the gel resists the push: {sliding}");
    let imbalance = (base + sliding).norm();
    assert!(
        imbalance < 0.02 * base.norm(),
        "base {base} + sliding {sliding} = {imbalance} N"
    );
    // The step's report carries the same forces, where they act, and their nodal sum (what the
    // VTK frames write).
    let last = reports.last().expect("a report");
    let roles: Vec<_> = forces.iter().map(|(r, _)| *r).collect();
    assert_eq!(
        last.forces.iter().map(|f| f.role).collect::<Vec<_>>(),
        roles
    );
    for (f, (_, g)) in last.forces.iter().zip(&forces) {
        assert!((f.force - g).norm() < 1e-12, "{} vs {g}", f.force);
    }
    let p = sim.needle.positions();
    assert!(
        (last.forces[0].at - p[0]).norm() < 1e-12,
        "the base acts at node 0"
    );
    for f in &last.forces {
        if let GroupRole::Sliding(id) = f.role {
            let gel_point = sim.sliding.iter().find(|s| s.id == id).expect("its point");
            let x = gel_point
                .at
                .position(sim.gel.positions(), &sim.gel.mesh().tets);
            assert!(
                (f.at - x).norm() < 0.05,
                "sliding point {id}: needle {} vs gel {x}",
                f.at
            );
        }
    }
    let nodal: Vector3<f64> = last.needle_node_forces.iter().sum();
    let total: Vector3<f64> = last.forces.iter().map(|f| f.force).sum();
    assert_eq!(last.needle_node_forces.len(), p.len());
    assert!(
        (nodal - total).norm() < 1e-12,
        "nodal {nodal} vs groups {total}"
    );
}

#[test]
#[ignore = "forward-simulation scenario (release): run with --include-ignored"]
fn embedded_path_and_obstacles_move_with_the_gel() {
    let scene = vertical_scene(600);
    let mut s = build(&scene).expect("build");
    let mut reports = Vec::new();
    descend(&mut s, 0.1, 200, &mut reports);
    let sim = &s.world;
    let gel = &sim.gel;
    let tets = &gel.mesh().tets;
    // The obstacle centre is the barycentric interpolation of its element's current nodes.
    let needle_host::world::Obstacle::Sphere { centre: e, .. } = sim.obstacles[0] else {
        panic!("the scene's obstacle is a sphere");
    };
    let t = tets[e.tet];
    let expect: Vector3<f64> = (0..4).map(|k| e.weights[k] * gel.positions()[t[k]]).sum();
    let rest_centre: Vector3<f64> = (0..4).map(|k| e.weights[k] * gel.mesh().nodes[t[k]]).sum();
    assert!((rest_centre - Vector3::new(304.0, 0.0, 50.0)).norm() < 1e-9);
    assert!((e.position(gel.positions(), tets) - expect).norm() < 1e-12);
    assert!(
        (expect - rest_centre).norm() > 1e-4,
        "the gel did not move at the obstacle"
    );
    // The target moves with the gel: it is no longer at its rest position.
    let c = sim.c;
    let rest_target = sim.path.at(c).0;
    let target = sim.target(c);
    assert!((target - rest_target).norm() > 1e-4);
    assert!((target - rest_target).norm() < 5.0);
}

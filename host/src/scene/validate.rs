//! Physical validation of a parsed scene: every rejected value names its field and the reason.
//! One check per topic (robot, gel, needle, contact and inverse tuning, solver, path and
//! insertion), each value against its physical meaning and a range where a number far outside
//! it can only be a typo or an attack (a needle of 10³⁰⁰ MPa, a time step of 10⁻³⁰⁰ s).

use super::{
    EntryTilt, FAR_RESIDUAL_MAX, HorizonSpec, NearRadiusSpec, PoseSpec, SampledPath, Scene,
    StraightenFromSpec, StraightenSpec,
};
use crate::free_motion::LAG_ROTATION_LIMIT;
use needle_core::kinematics::{Kinematics, Robot};

type Check = Result<(), (String, String)>;

fn fail<T>(field: &str, reason: impl Into<String>) -> Result<T, (String, String)> {
    Err((field.to_owned(), reason.into()))
}

fn finite(field: &str, v: f64) -> Check {
    if v.is_finite() {
        Ok(())
    } else {
        fail(field, format!("must be finite (got {v})"))
    }
}

fn positive(field: &str, v: f64, unit: &str) -> Check {
    finite(field, v)?;
    if v > 0.0 {
        Ok(())
    } else {
        fail(field, format!("must be > 0 {unit} (got {v})"))
    }
}

fn non_negative(field: &str, v: f64, unit: &str) -> Check {
    finite(field, v)?;
    if v >= 0.0 {
        Ok(())
    } else {
        fail(field, format!("must be ≥ 0 {unit} (got {v})"))
    }
}

/// `lo ≤ v ≤ hi` (and finite).
fn within(field: &str, v: f64, lo: f64, hi: f64, unit: &str) -> Check {
    finite(field, v)?;
    if v >= lo && v <= hi {
        Ok(())
    } else if lo > 0.0 && v <= 0.0 {
        fail(field, format!("must be > 0 {unit} (got {v})"))
    } else {
        fail(
            field,
            format!("must lie in [{lo:e}, {hi:e}] {unit} (got {v:e})"),
        )
    }
}

/// Most steps of a run (10⁷: a kilometre of path at 0.1 mm per step).
pub const MAX_STEPS: usize = 10_000_000;

/// Most obstacles of a scene.
pub const MAX_OBSTACLES: usize = 1000;

fn pose(field: &str, p: &PoseSpec) -> Check {
    for (i, v) in p.translation.iter().enumerate() {
        finite(&format!("{field}.translation[{i}]"), *v)?;
    }
    for (i, v) in p.rpy.iter().enumerate() {
        finite(&format!("{field}.rpy[{i}]"), *v)?;
    }
    Ok(())
}

fn poisson(field: &str, v: f64) -> Check {
    finite(field, v)?;
    if v > -1.0 && v < 0.5 {
        Ok(())
    } else {
        fail(field, format!("must lie in (-1, 0.5) (got {v})"))
    }
}

/// From a foam to ten times osmium [t/mm³].
fn density(field: &str, v: f64) -> Check {
    within(field, v, 1e-12, 2e-7, "[t/mm³]")
}

/// A per-joint list: one finite value per joint, 6 (or 7 for a URDF arm of 7 joints; the exact
/// count is checked against the robot, `Scene::robot`).
fn per_joint(field: &str, v: &Option<Vec<f64>>, urdf: bool) -> Check {
    if let Some(v) = v {
        if !(v.len() == 6 || (urdf && v.len() == 7)) {
            let counts = if urdf { "6 or 7" } else { "6" };
            return fail(
                field,
                format!("needs {counts} values, one per joint (got {})", v.len()),
            );
        }
        for (i, x) in v.iter().enumerate() {
            finite(&format!("{field}[{i}]"), *x)?;
        }
    }
    Ok(())
}

impl Scene {
    /// Checks every value against its physical meaning.
    ///
    /// # Errors
    /// `(field, reason)` for the first value that makes no sense.
    pub fn validate(&self) -> Check {
        if self.name.trim().is_empty() {
            return fail("name", "must not be empty");
        }
        self.validate_robot()?;
        self.validate_gel()?;
        self.validate_needle()?;
        self.validate_interaction()?;
        self.validate_inverse()?;
        self.validate_solver()?;
        self.validate_path_and_insertion()
    }

    fn validate_robot(&self) -> Check {
        let r = &self.robot;
        if r.urdf.is_some() {
            if r.dh.is_some() {
                return fail("robot.dh", "give either `urdf` or `dh`, not both");
            }
            for (field, v) in [
                ("robot.base_link", &r.base_link),
                ("robot.tip_link", &r.tip_link),
            ] {
                if v.as_deref().is_none_or(|s| s.trim().is_empty()) {
                    return fail(
                        field,
                        "needed with `robot.urdf`: the name of a link of the file",
                    );
                }
            }
        } else if let Some(field) = [
            ("robot.base_link", &r.base_link),
            ("robot.tip_link", &r.tip_link),
        ]
        .iter()
        .find_map(|(f, v)| v.is_some().then_some(*f))
        {
            return fail(field, "only with `robot.urdf`");
        }
        match &r.dh {
            Some(rows) if rows.len() != 6 => {
                return fail(
                    "robot.dh",
                    format!("needs 6 rows, one per joint (got {})", rows.len()),
                );
            }
            Some(rows) => {
                for (i, row) in rows.iter().enumerate() {
                    for (name, v) in [
                        ("theta", row.theta),
                        ("d", row.d),
                        ("a", row.a),
                        ("alpha", row.alpha),
                    ] {
                        finite(&format!("robot.dh[{i}].{name}"), v)?;
                    }
                }
            }
            None if r.preset != "rv1a" && r.urdf.is_none() => {
                return fail(
                    "robot.preset",
                    format!(
                        "unknown robot `{}` (known: rv1a); or give a `dh` table",
                        r.preset
                    ),
                );
            }
            None => {}
        }
        pose("robot.base", &r.base)?;
        pose("robot.tool", &r.tool)?;
        self.validate_joints()?;
        within("robot.dt", r.dt, 1e-6, 10.0, "[s]")
    }

    fn validate_joints(&self) -> Check {
        let r = &self.robot;
        let urdf = r.urdf.is_some();
        per_joint("robot.joint_min_deg", &r.joint_min_deg, urdf)?;
        per_joint("robot.joint_max_deg", &r.joint_max_deg, urdf)?;
        per_joint("robot.speed_limit_deg_s", &r.speed_limit_deg_s, urdf)?;
        if let (Some(lo), Some(hi)) = (&r.joint_min_deg, &r.joint_max_deg)
            && let Some(i) = (0..lo.len().min(hi.len())).find(|&i| lo[i] >= hi[i])
        {
            return fail(
                &format!("robot.joint_max_deg[{i}]"),
                format!("must exceed joint_min_deg[{i}] = {}", lo[i]),
            );
        }
        if let Some(v) = &r.speed_limit_deg_s
            && let Some(i) = v.iter().position(|s| *s <= 0.0)
        {
            return fail(
                &format!("robot.speed_limit_deg_s[{i}]"),
                "must be > 0 [deg/s]",
            );
        }
        per_joint("robot.start_joints_deg", &r.start_joints_deg, urdf)?;
        per_joint("robot.ik_seed_deg", &r.ik_seed_deg, urdf)?;
        // A URDF's limits are checked when the file is read (`Scene::load`).
        if !urdf {
            self.check_start_joints(&self.robot_n::<6>()?)?;
        }
        Ok(())
    }

    /// The start joints and the IK seed, when given, within the limits of `robot`.
    pub(crate) fn check_start_joints<const N: usize>(&self, robot: &Robot<N>) -> Check {
        let r = &self.robot;
        for (field, q) in [
            ("robot.start_joints_deg", &r.start_joints_deg),
            ("robot.ik_seed_deg", &r.ik_seed_deg),
        ] {
            let Some(q) = q else { continue };
            for (i, (v, l)) in q.iter().zip(robot.limits()).enumerate() {
                let (lo, hi) = (l.lower.to_degrees(), l.upper.to_degrees());
                if !(*v >= lo && *v <= hi) {
                    return fail(
                        &format!("{field}[{i}]"),
                        format!("{v} is outside the joint limits [{lo}, {hi}] [deg]"),
                    );
                }
            }
        }
        Ok(())
    }

    fn validate_gel(&self) -> Check {
        let g = &self.gel;
        match (&g.box_mesh, &g.mesh) {
            (Some(_), Some(_)) => return fail("gel", "give either `box` or `mesh`, not both"),
            (None, None) => return fail("gel", "give a `box` or a `mesh`"),
            (Some(b), None) => {
                for i in 0..3 {
                    finite(&format!("gel.box.min[{i}]"), b.min[i])?;
                    finite(&format!("gel.box.max[{i}]"), b.max[i])?;
                    if b.max[i] <= b.min[i] {
                        return fail(
                            &format!("gel.box.max[{i}]"),
                            format!("must exceed min[{i}] = {}", b.min[i]),
                        );
                    }
                }
                if !(27..=2_000_000).contains(&b.nodes) {
                    return fail(
                        "gel.box.nodes",
                        format!("must be between 27 and 2000000 (got {})", b.nodes),
                    );
                }
            }
            (None, Some(_)) => {}
        }
        // 1 Pa to 10 GPa: from the softest gel to bone.
        within("gel.young_modulus", g.young_modulus, 1e-6, 1e4, "[MPa]")?;
        poisson("gel.poisson_ratio", g.poisson_ratio)?;
        density("gel.density", g.density)?;
        if let Some(z) = g.fixed.below_z {
            finite("gel.fixed.below_z", z)?;
        }
        if g.fixed.below_z.is_none() && g.fixed.nodes.is_empty() {
            return fail(
                "gel.fixed",
                "no node is fixed: the gel would float away (give `below_z` or `nodes`)",
            );
        }
        if let Some(m) = &g.support_motion {
            match (&m.breathing, &m.csv) {
                (Some(_), Some(_)) => {
                    return fail(
                        "gel.support_motion",
                        "give either `breathing` or `csv`, not both",
                    );
                }
                (None, None) => {
                    return fail("gel.support_motion", "give `breathing` or `csv`");
                }
                (Some(b), None) => {
                    // Up to a metre of travel, periods from 10 ms to a day.
                    within(
                        "gel.support_motion.breathing.amplitude",
                        b.amplitude,
                        0.0,
                        1000.0,
                        "[mm]",
                    )?;
                    within(
                        "gel.support_motion.breathing.period",
                        b.period,
                        1e-2,
                        86400.0,
                        "[s]",
                    )?;
                    finite("gel.support_motion.breathing.phase", b.phase)?;
                    for (i, v) in b.direction.iter().enumerate() {
                        finite(&format!("gel.support_motion.breathing.direction[{i}]"), *v)?;
                    }
                    if b.direction.iter().all(|v| *v == 0.0) {
                        return fail(
                            "gel.support_motion.breathing.direction",
                            "must be a non-zero vector",
                        );
                    }
                }
                (None, Some(_)) => {}
            }
        }
        for (i, r) in g.regions.iter().enumerate() {
            let field = |name: &str| format!("gel.regions[{i}].{name}");
            if let Some(j) = g.regions[..i].iter().position(|o| o.tag == r.tag) {
                return fail(
                    &field("tag"),
                    format!("region {} is already listed as gel.regions[{j}]", r.tag),
                );
            }
            within(&field("young_modulus"), r.young_modulus, 1e-6, 1e4, "[MPa]")?;
            if let Some(nu) = r.poisson_ratio {
                poisson(&field("poisson_ratio"), nu)?;
            }
            if let Some(rho) = r.density {
                density(&field("density"), rho)?;
            }
        }
        Ok(())
    }

    fn validate_needle(&self) -> Check {
        let n = &self.needle;
        within("needle.length", n.length, 1e-3, 1e4, "[mm]")?;
        positive("needle.diameter", n.diameter, "[mm]")?;
        if n.diameter >= n.length {
            return fail(
                "needle.diameter",
                "must be smaller than the length (a needle is slender)",
            );
        }
        // Up to 10 TPa (ten times diamond).
        within("needle.young_modulus", n.young_modulus, 1e-6, 1e7, "[MPa]")?;
        // Against the stiffest material of the gel.
        let gel_e = (self.gel.regions.iter())
            .map(|r| r.young_modulus)
            .fold(self.gel.young_modulus, f64::max);
        let ratio = n.young_modulus / gel_e;
        if !(1.0..=1e12).contains(&ratio) {
            return fail(
                "needle.young_modulus",
                format!(
                    "{:e} MPa is {ratio:.1e} times the gel's {:e} MPa: a needle must be stiffer than the gel, by at most 10¹²",
                    n.young_modulus, gel_e
                ),
            );
        }
        poisson("needle.poisson_ratio", n.poisson_ratio)?;
        density("needle.density", n.density)?;
        if !(1..=1000).contains(&n.beams) {
            return fail(
                "needle.beams",
                format!("must be between 1 and 1000 (got {})", n.beams),
            );
        }
        if let Some(y) = n.yield_strain {
            within(
                "needle.yield_strain",
                y,
                1e-6,
                1.0,
                "[-] (σ_y / E, a fraction)",
            )?;
        }
        Ok(())
    }

    fn validate_interaction(&self) -> Check {
        let i = &self.interaction;
        within(
            "interaction.puncture_force",
            i.puncture_force,
            1e-9,
            1e4,
            "[N]",
        )?;
        within(
            "interaction.surface_friction",
            i.surface_friction,
            0.0,
            10.0,
            "",
        )?;
        within(
            "interaction.shaft_friction",
            i.shaft_friction,
            0.0,
            10.0,
            "",
        )?;
        within(
            "interaction.shaft_resistance",
            i.shaft_resistance,
            0.0,
            1e4,
            "[N]",
        )?;
        positive(
            "interaction.constraint_spacing",
            i.constraint_spacing,
            "[mm]",
        )
    }

    fn validate_inverse(&self) -> Check {
        let v = &self.inverse;
        positive("inverse.delta_q", v.delta_q, "[rad]")?;
        if v.delta_q > 0.5 {
            return fail(
                "inverse.delta_q",
                format!(
                    "must be ≤ 0.5 rad for a meaningful finite difference (got {})",
                    v.delta_q
                ),
            );
        }
        positive("inverse.blend_distance", v.blend_distance, "[mm]")?;
        non_negative("inverse.damping", v.damping, "[mm]")?;
        non_negative("inverse.angle_weight", v.angle_weight, "[mm/rad]")?;
        non_negative("inverse.tolerance", v.tolerance, "[mm²]")?;
        positive("inverse.max_base_step", v.max_base_step, "[mm]")?;
        if let Some(s) = v.max_entry_shift {
            positive("inverse.max_entry_shift", s, "[mm]")?;
        }
        non_negative("inverse.clearance_margin", v.clearance_margin, "[mm]")?;
        non_negative("inverse.qp_angle_weight", v.qp_angle_weight, "[mm/rad]")?;
        if let HorizonSpec::Mm(h) = v.qp_horizon {
            non_negative("inverse.qp_horizon", h, "[mm]")?;
        }
        if let StraightenSpec::Fraction(b) = v.straighten {
            within("inverse.straighten", b, 0.0, 1.0, "[-]")?;
        }
        if let EntryTilt::Angle(a) = v.entry_tilt {
            non_negative("inverse.entry_tilt", a, "[rad]")?;
        }
        if let StraightenFromSpec::Mm(d) = v.straighten_from {
            non_negative("inverse.straighten_from", d, "[mm]")?;
        }
        let (offset, tolerance) = (
            v.straighten_max_offset,
            crate::run::metrics::PATH_TOLERANCE_MM,
        );
        positive("inverse.straighten_max_offset", offset, "[mm]")?;
        non_negative("inverse.target_standoff", v.target_standoff, "[mm]")?;
        if offset > tolerance {
            fail::<()>(
                "inverse.straighten_max_offset",
                format!(
                    "must be ≤ {tolerance} mm, the path's tolerance: a target shown farther \
                     from the path leads the tip off it (got {offset})"
                ),
            )?;
        }
        non_negative(
            "inverse.qp_angle_damping_max",
            v.qp_angle_damping_max,
            "[mm/rad]",
        )?;
        non_negative("inverse.qp_spin_weight", v.qp_spin_weight, "[mm/rad]")?;
        within(
            "inverse.limit_avoidance",
            v.limit_avoidance,
            0.0,
            10.0,
            "[-]",
        )
    }

    fn validate_solver(&self) -> Check {
        let s = &self.solver;
        within("solver.gs_tolerance", s.gs_tolerance, 1e-300, 1.0, "")?;
        if !(1..=1_000_000).contains(&s.gs_max_iterations) {
            return fail(
                "solver.gs_max_iterations",
                format!(
                    "must be between 1 and 1000000 (got {})",
                    s.gs_max_iterations
                ),
            );
        }
        within("solver.gs_relaxation", s.gs_relaxation, 0.1, 1.9, "[-]")?;
        within("solver.time_step", s.time_step, 1e-6, 10.0, "[s]")?;
        if s.refactor_every == Some(0) {
            return fail("solver.refactor_every", "must be ≥ 1");
        }
        within("solver.pcg_tolerance", s.pcg_tolerance, 1e-14, 0.5, "")?;
        if !(1..=10_000).contains(&s.pcg_max_iterations) {
            return fail(
                "solver.pcg_max_iterations",
                format!("must be between 1 and 10000 (got {})", s.pcg_max_iterations),
            );
        }
        if !(0.0..=LAG_ROTATION_LIMIT).contains(&s.refresh_rotation) {
            return fail(
                "solver.refresh_rotation",
                format!(
                    "must lie in [0, {LAG_ROTATION_LIMIT}] [rad] (got {})",
                    s.refresh_rotation
                ),
            );
        }
        if let Some(c) = s.refresh_ceiling
            && !(1..=10_000).contains(&c)
        {
            return fail(
                "solver.refresh_ceiling",
                format!("must be between 1 and 10000 when given (got {c})"),
            );
        }
        if let Some(r) = s.far_refresh_rotation
            && !(r > 0.0 && r <= LAG_ROTATION_LIMIT)
        {
            return fail(
                "solver.far_refresh_rotation",
                format!(
                    "must be above 0 and at most {LAG_ROTATION_LIMIT} rad (the rotation that \
                     factorises at once) when given (got {r})"
                ),
            );
        }
        if let NearRadiusSpec::Radius(r) = s.near_radius
            && !(r > 0.0 && r.is_finite())
        {
            return fail(
                "solver.near_radius",
                format!("must be a positive distance [mm], \"auto\" or \"off\" (got {r})"),
            );
        }
        if let NearRadiusSpec::Radius(r) = s.entry_radius
            && !(r > 0.0 && r.is_finite())
        {
            return fail(
                "solver.entry_radius",
                format!("must be a positive distance [mm], \"auto\" or \"off\" (got {r})"),
            );
        }
        let tol = s.far_residual_tolerance;
        if !(0.0..=FAR_RESIDUAL_MAX).contains(&tol) {
            return fail(
                "solver.far_residual_tolerance",
                format!("must be between 0 (every solve exact) and {FAR_RESIDUAL_MAX} (got {tol})"),
            );
        }
        Ok(())
    }

    fn validate_path_and_insertion(&self) -> Check {
        let path = SampledPath::from_spec(&self.path).map_err(|e| (e.field, e.reason))?;
        if self.obstacles.len() > MAX_OBSTACLES {
            return fail(
                "obstacles",
                format!(
                    "{} obstacles, more than the limit of {MAX_OBSTACLES}",
                    self.obstacles.len()
                ),
            );
        }
        for (k, o) in self.obstacles.iter().enumerate() {
            let field = |f: &str| format!("obstacles[{k}].{f}");
            match (&o.mesh, o.center, o.radius) {
                (None, Some(center), Some(radius)) => {
                    for (c, v) in center.iter().enumerate() {
                        finite(&format!("obstacles[{k}].center[{c}]"), *v)?;
                    }
                    positive(&field("radius"), radius, "[mm]")?;
                    let placed = [
                        ("scale", o.scale.is_some()),
                        ("translation", o.translation.is_some()),
                        ("physical_group", o.physical_group.is_some()),
                    ];
                    if let Some((f, _)) = placed.iter().find(|(_, given)| *given) {
                        return fail(
                            &field(f),
                            "only a mesh obstacle (`mesh`) is placed by `scale` and `translation` (and chosen in a Gmsh file by `physical_group`); a sphere by `center`",
                        );
                    }
                }
                (None, c, _) => {
                    return fail(
                        &field(if c.is_none() { "center" } else { "radius" }),
                        "missing: an obstacle is a sphere (`center` and `radius`) or a surface mesh (`mesh`)",
                    );
                }
                (Some(_), c, r) => {
                    if c.is_some() || r.is_some() {
                        return fail(
                            &field(if c.is_some() { "center" } else { "radius" }),
                            "a mesh obstacle (`mesh`) has no `center` or `radius`: place it by `scale` and `translation`",
                        );
                    }
                    if let Some(sc) = o.scale {
                        positive(&field("scale"), sc, "[–]")?;
                    }
                    for (c, v) in o.translation.unwrap_or_default().iter().enumerate() {
                        finite(&format!("obstacles[{k}].translation[{c}]"), *v)?;
                    }
                }
            }
        }
        positive(
            "insertion.advance_per_step",
            self.insertion.advance_per_step,
            "[mm]",
        )?;
        if self.insertion.advance_per_step > path.total_length() {
            return fail(
                "insertion.advance_per_step",
                "exceeds the whole path length",
            );
        }
        let lead = self.insertion.max_lead;
        if lead.is_nan() || lead < self.insertion.advance_per_step {
            return fail(
                "insertion.max_lead",
                format!(
                    "must be at least `advance_per_step` ({} mm), or `inf` (got {lead})",
                    self.insertion.advance_per_step
                ),
            );
        }
        match self.insertion.steps {
            Some(0) => fail(
                "insertion.steps",
                "must be ≥ 1 (or omitted: until the end of the path)",
            ),
            Some(n) if n > MAX_STEPS => fail(
                "insertion.steps",
                format!("must be at most {MAX_STEPS} (got {n})"),
            ),
            _ => Ok(()),
        }
    }
}

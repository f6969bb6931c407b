//! Physical validation of a parsed scene: every rejected value names its field and the reason.

use super::{PoseSpec, SampledPath, Scene};

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

fn pose(field: &str, p: &PoseSpec) -> Check {
    for (i, v) in p.translation.iter().enumerate() {
        finite(&format!("{field}.translation[{i}]"), *v)?;
    }
    for (i, v) in p.rpy.iter().enumerate() {
        finite(&format!("{field}.rpy[{i}]"), *v)?;
    }
    Ok(())
}

fn six(field: &str, v: &Option<Vec<f64>>) -> Check {
    if let Some(v) = v {
        if v.len() != 6 {
            return fail(
                field,
                format!("needs 6 values, one per joint (got {})", v.len()),
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
        // Robot.
        let r = &self.robot;
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
            None if r.preset != "rv1a" => {
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
        six("robot.joint_min_deg", &r.joint_min_deg)?;
        six("robot.joint_max_deg", &r.joint_max_deg)?;
        six("robot.speed_limit_deg_s", &r.speed_limit_deg_s)?;
        if let (Some(lo), Some(hi)) = (&r.joint_min_deg, &r.joint_max_deg)
            && let Some(i) = (0..6).find(|&i| lo[i] >= hi[i])
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
        positive("robot.dt", r.dt, "[s]")?;
        six("robot.start_joints_deg", &r.start_joints_deg)?;
        if let Some(q) = &r.start_joints_deg {
            let chain = self.robot();
            for (i, (v, l)) in q.iter().zip(&chain.limits).enumerate() {
                let (lo, hi) = (l.lower.to_degrees(), l.upper.to_degrees());
                if !(*v >= lo && *v <= hi) {
                    return fail(
                        &format!("robot.start_joints_deg[{i}]"),
                        format!("{v} is outside the joint limits [{lo}, {hi}] [deg]"),
                    );
                }
            }
        }

        // Gel.
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
        positive("gel.young_modulus", g.young_modulus, "[MPa]")?;
        finite("gel.poisson_ratio", g.poisson_ratio)?;
        if !(g.poisson_ratio > -1.0 && g.poisson_ratio < 0.5) {
            return fail(
                "gel.poisson_ratio",
                format!("must lie in (-1, 0.5) (got {})", g.poisson_ratio),
            );
        }
        positive("gel.density", g.density, "[t/mm³]")?;
        if let Some(z) = g.fixed.below_z {
            finite("gel.fixed.below_z", z)?;
        }
        if g.fixed.below_z.is_none() && g.fixed.nodes.is_empty() {
            return fail(
                "gel.fixed",
                "no node is fixed: the gel would float away (give `below_z` or `nodes`)",
            );
        }

        // Needle.
        let n = &self.needle;
        positive("needle.length", n.length, "[mm]")?;
        positive("needle.diameter", n.diameter, "[mm]")?;
        if n.diameter >= n.length {
            return fail(
                "needle.diameter",
                "must be smaller than the length (a needle is slender)",
            );
        }
        positive("needle.young_modulus", n.young_modulus, "[MPa]")?;
        finite("needle.poisson_ratio", n.poisson_ratio)?;
        if !(n.poisson_ratio > -1.0 && n.poisson_ratio < 0.5) {
            return fail(
                "needle.poisson_ratio",
                format!("must lie in (-1, 0.5) (got {})", n.poisson_ratio),
            );
        }
        positive("needle.density", n.density, "[t/mm³]")?;
        if !(1..=1000).contains(&n.beams) {
            return fail(
                "needle.beams",
                format!("must be between 1 and 1000 (got {})", n.beams),
            );
        }

        // Interaction.
        let i = &self.interaction;
        positive("interaction.puncture_force", i.puncture_force, "[N]")?;
        non_negative("interaction.surface_friction", i.surface_friction, "")?;
        non_negative("interaction.shaft_friction", i.shaft_friction, "")?;
        non_negative("interaction.shaft_resistance", i.shaft_resistance, "[N]")?;
        positive(
            "interaction.constraint_spacing",
            i.constraint_spacing,
            "[mm]",
        )?;

        // Inverse.
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

        // Solver.
        let s = &self.solver;
        positive("solver.gs_tolerance", s.gs_tolerance, "")?;
        if s.gs_max_iterations == 0 {
            return fail("solver.gs_max_iterations", "must be ≥ 1");
        }
        positive("solver.time_step", s.time_step, "[s]")?;
        if s.refactor_every == Some(0) {
            return fail("solver.refactor_every", "must be ≥ 1");
        }

        // Path and obstacles.
        let path = SampledPath::from_spec(&self.path).map_err(|e| (e.field, e.reason))?;
        for (k, o) in self.obstacles.iter().enumerate() {
            for c in 0..3 {
                finite(&format!("obstacles[{k}].center[{c}]"), o.center[c])?;
            }
            positive(&format!("obstacles[{k}].radius"), o.radius, "[mm]")?;
        }

        // Insertion.
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
        if self.insertion.steps == Some(0) {
            return fail(
                "insertion.steps",
                "must be ≥ 1 (or omitted: until the end of the path)",
            );
        }
        Ok(())
    }
}

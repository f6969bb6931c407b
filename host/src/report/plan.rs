//! The plan of the report: which scenes, controllers and overrides run, in which group, and the
//! merge of the planned runs that are the same simulation.

use super::{Group, Membership, ReportError, ReportRun, controller_name};
use crate::run::ControllerKind;
use crate::scene::Scene;
use std::collections::HashMap;

/// One planned run before de-duplication.
pub(super) struct Spec {
    scene: &'static str,
    controller: ControllerKind,
    overrides: Vec<(String, String)>,
    group: Group,
    parameter: String,
}

/// Scene overrides shared by every run (the quick set: the 600-node mesh).
pub(super) fn base(quick: bool) -> Vec<(String, String)> {
    if quick {
        vec![("gel.box.nodes".into(), "600".into())]
    } else {
        Vec::new()
    }
}

/// The base overrides with `field = value` (replacing the base's value of `field`).
fn with(base: &[(String, String)], field: &str, value: String) -> Vec<(String, String)> {
    let mut o = base.to_vec();
    o.retain(|(f, _)| f != field);
    o.push((field.to_owned(), value));
    o
}

/// Both scenes under both controllers.
fn controllers(quick: bool, specs: &mut Vec<Spec>) {
    for scene in ["simple", "complex"] {
        for controller in [ControllerKind::Inverse, ControllerKind::Naive] {
            specs.push(Spec {
                scene,
                controller,
                overrides: base(quick),
                group: Group::Controllers,
                parameter: if quick {
                    "600 nodes".into()
                } else {
                    "scene defaults (1500 nodes)".into()
                },
            });
        }
    }
}

/// The gel mesh sizes of the paper's Fig. 8.
fn meshes(quick: bool, specs: &mut Vec<Spec>) {
    let meshes: &[usize] = if quick {
        &[600]
    } else {
        &[600, 1100, 1500, 1800]
    };
    for scene in ["simple", "complex"] {
        for &n in meshes {
            specs.push(Spec {
                scene,
                controller: ControllerKind::Inverse,
                overrides: with(&base(quick), "gel.box.nodes", n.to_string()),
                group: Group::Mesh,
                parameter: format!("{n} nodes"),
            });
        }
    }
}

/// The parameter sweeps on the complex scene: δq, blend distance, constraint spacing.
fn sweeps(quick: bool, specs: &mut Vec<Spec>) {
    // (group, scene field, parameter text, full set, quick set)
    type Sweep<'a> = (Group, &'a str, &'a str, &'a [f64], &'a [f64]);
    let sweeps: [Sweep; 3] = [
        (
            Group::DeltaQ,
            "inverse.delta_q",
            "δq = {} rad",
            &[0.001, 0.01, 0.1],
            &[0.001],
        ),
        (
            Group::BlendDistance,
            "inverse.blend_distance",
            "d = {} mm",
            &[6.0, 12.0, 18.0, 30.0],
            &[6.0],
        ),
        (
            Group::ConstraintSpacing,
            "interaction.constraint_spacing",
            "d_n = {} mm",
            &[5.0, 10.0, 20.0],
            &[5.0],
        ),
    ];
    for (group, field, fmt, full, short) in sweeps {
        for &v in if quick { short } else { full } {
            specs.push(Spec {
                scene: "complex",
                controller: ControllerKind::Inverse,
                overrides: with(&base(quick), field, format!("{v:?}")),
                group,
                parameter: fmt.replace("{}", &format!("{v}")),
            });
        }
    }
}

/// The gel's factorisation: background pipelines of 1–3 steps, the default with a double
/// factor, and the preconditioned CG (asynchronous factor) against the synchronous double step
/// (the paper's exact Newton step).
fn factorization(quick: bool, specs: &mut Vec<Spec>) {
    let scenes: &[&'static str] = if quick {
        &["complex"]
    } else {
        &["simple", "complex"]
    };
    // (overrides beyond the base, parameter text)
    let variants: [(&[(&str, &str)], &str); 8] = [
        (
            &[
                ("solver.refactor_every", "1"),
                ("solver.refresh_rotation", "0"),
            ],
            "background, a factor 1 step old",
        ),
        (
            &[],
            "background, adaptive refresh: a factor when an element turned 0.05 rad, single-precision factor (default)",
        ),
        (
            &[("solver.far_elements", "\"linear\"")],
            "background, adaptive refresh, the elements outside the near block linear",
        ),
        (
            &[("solver.factor_precision", "\"double\"")],
            "background, adaptive refresh, double-precision factor",
        ),
        (
            &[("solver.refresh_rotation", "0")],
            "background, pipeline of 2 steps",
        ),
        (
            &[
                ("solver.refactor_every", "3"),
                ("solver.refresh_rotation", "0"),
            ],
            "background, pipeline of 3 steps",
        ),
        (
            &[("solver.gel_solve", "\"pcg\"")],
            "preconditioned CG, background factor at most every 8 steps",
        ),
        (
            &[
                ("solver.background_factorization", "false"),
                ("solver.factor_precision", "\"double\""),
            ],
            "synchronous, every step, double-precision factor (the paper's)",
        ),
    ];
    for &scene in scenes {
        for (extra, text) in variants {
            // The quick set's gels (616 nodes) have no near block: no far elements either.
            let skipped = ["solver.refactor_every", "solver.far_elements"];
            if quick && extra.iter().any(|(f, _)| skipped.contains(f)) {
                continue;
            }
            let mut overrides = base(quick);
            overrides.extend(extra.iter().map(|(f, v)| (f.to_string(), v.to_string())));
            specs.push(Spec {
                scene,
                controller: ControllerKind::Inverse,
                overrides,
                group: Group::Factorization,
                parameter: text.into(),
            });
        }
    }
}

/// Every planned run, group by group, in report order.
pub(super) fn plan(quick: bool) -> Vec<Spec> {
    let mut specs = Vec::new();
    controllers(quick, &mut specs);
    meshes(quick, &mut specs);
    sweeps(quick, &mut specs);
    factorization(quick, &mut specs);
    specs
}

/// The runs of the plan, the specs that are the same simulation merged into one run (which then
/// belongs to several groups), each with its scene.
///
/// # Errors
/// [`ReportError`] when a planned scene or override does not exist or is invalid.
pub(super) fn planned_runs(quick: bool) -> Result<Vec<(ReportRun, Scene)>, ReportError> {
    let mut runs: Vec<(ReportRun, Scene)> = Vec::new();
    let mut index: HashMap<(String, &'static str), usize> = HashMap::new();
    for (order, spec) in plan(quick).into_iter().enumerate() {
        let base = Scene::builtin(spec.scene)
            .ok_or_else(|| ReportError::NoScene(spec.scene.to_owned()))?;
        let scene = base
            .with_overrides(&spec.overrides)
            .map_err(|source| ReportError::Scene {
                scene: spec.scene.to_owned(),
                source,
            })?;
        // The same simulation: the same scene (every field) under the same controller.
        let key = (format!("{scene:?}"), controller_name(spec.controller));
        let membership = Membership {
            group: spec.group,
            parameter: spec.parameter,
            order,
        };
        if let Some(&i) = index.get(&key) {
            runs[i].0.memberships.push(membership);
            continue;
        }
        index.insert(key, runs.len());
        let run = ReportRun {
            id: runs.len(),
            scene: scene.name.clone(),
            controller: spec.controller,
            nodes_target: scene.gel.box_mesh.as_ref().map_or(0, |b| b.nodes),
            delta_q: scene.inverse.delta_q,
            blend_distance_mm: scene.inverse.blend_distance,
            constraint_spacing_mm: scene.interaction.constraint_spacing,
            overrides: spec.overrides,
            memberships: vec![membership],
            summary: None,
            failure: None,
            wall_s: 0.0,
            error_by_depth: Vec::new(),
        };
        runs.push((run, scene));
    }
    Ok(runs)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_group_is_planned_and_shared_runs_merge() {
        for quick in [true, false] {
            let runs = planned_runs(quick).expect("the plan's scenes and overrides are valid");
            for g in Group::ALL {
                assert!(
                    runs.iter().any(|(r, _)| r.parameter(g).is_some()),
                    "quick = {quick}: no run in {g:?}"
                );
            }
            // Fewer runs than specs: the complex scene at its defaults is in several groups.
            assert!(runs.len() < plan(quick).len());
            println!("quick {quick}: {} runs", runs.len());
            assert!(runs.iter().any(|(r, _)| r.memberships.len() > 1));
        }
    }
}

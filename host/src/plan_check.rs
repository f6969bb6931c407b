//! Checks of a scene's plan against its gel, made at set-up before any step: the path stays in
//! the gel and out of its fixed part, no obstacle lies on the path, and the needle is long enough
//! for the insertion. Each refusal names the field and says why in millimetres, on one line.

// Units are written in brackets ([mm], [N]) as in the workspace style: not intra-doc links.
#![allow(rustdoc::broken_intra_doc_links)]

use crate::error::{SetupError, mm};
use crate::proximity::ClosedSurface;
use crate::scene::Scene;
use crate::world::{Obstacle, World};
use nalgebra::Vector3;

fn refuse(field: &str, reason: String) -> SetupError {
    SetupError::Plan {
        field: field.to_owned(),
        reason,
    }
}

/// Every check of the plan of `scene` in its `world` at rest.
///
/// # Errors
/// [`SetupError::Plan`] naming the first problem.
pub fn check<const N: usize>(scene: &Scene, world: &World<N>) -> Result<(), SetupError> {
    fixed_bottom(scene, world)?;
    inside_gel(world)?;
    obstacles(scene, world)?;
    needle_length(scene, world)
}

/// No vertex of the path at or below the gel's fixed bottom (`gel.fixed.below_z`).
fn fixed_bottom<const N: usize>(scene: &Scene, world: &World<N>) -> Result<(), SetupError> {
    let Some(z) = scene.gel.fixed.below_z else {
        return Ok(());
    };
    let path = &world.path;
    match path.points.iter().position(|p| p.z <= z) {
        Some(i) => Err(refuse(
            "path",
            format!(
                "reaches z = {:.1} mm at {:.1} mm along the path, into the gel's fixed bottom (gel.fixed.below_z = {z} mm)",
                path.points[i].z, path.arc[i]
            ),
        )),
        None => Ok(()),
    }
}

/// Every vertex of the path lies in the rest gel.
fn inside_gel<const N: usize>(world: &World<N>) -> Result<(), SetupError> {
    let path = &world.path;
    match path.points.iter().position(|p| !world.in_rest_gel(p)) {
        Some(i) => Err(refuse(
            "path",
            format!(
                "the point {} at {:.1} mm along the path is outside the gel",
                mm(&path.points[i]),
                path.arc[i]
            ),
        )),
        None => Ok(()),
    }
}

/// Distance from `c` to the polyline `points` [mm].
fn distance_to_polyline(points: &[Vector3<f64>], c: &Vector3<f64>) -> f64 {
    points
        .windows(2)
        .map(|s| {
            let d = s[1] - s[0];
            let f = ((c - s[0]).dot(&d) / d.norm_squared()).clamp(0.0, 1.0);
            (s[0] + f * d - c).norm()
        })
        .fold(f64::INFINITY, f64::min)
}

/// No obstacle on the path: the path's centre line must pass outside every sphere and every
/// mesh obstacle's closed surface (the controller keeps the needle on the path, so a path
/// through an obstacle plans a hit).
fn obstacles<const N: usize>(scene: &Scene, world: &World<N>) -> Result<(), SetupError> {
    for (k, (o, w)) in scene.obstacles.iter().zip(&world.obstacles).enumerate() {
        let name = if o.name.is_empty() {
            String::new()
        } else {
            format!(" `{}`", o.name)
        };
        match w {
            Obstacle::Sphere { .. } => {
                let (Some(center), Some(radius)) = (o.center, o.radius) else {
                    continue;
                };
                let c = Vector3::from(center);
                let d = distance_to_polyline(&world.path.points, &c);
                if d < radius {
                    return Err(refuse(
                        &format!("obstacles[{k}]"),
                        format!(
                            "obstacle{name} lies on the path: the path passes {d:.2} mm from its centre, inside its radius of {radius} mm"
                        ),
                    ));
                }
            }
            Obstacle::Mesh {
                vertices,
                triangles,
                ..
            } => {
                let rest = &world.gel.mesh().nodes;
                let tets = &world.gel.mesh().tets;
                let v: Vec<_> = vertices.iter().map(|e| e.position(rest, tets)).collect();
                let segments: Vec<_> = world.path.points.windows(2).map(|s| (s[0], s[1])).collect();
                let c = ClosedSurface::new(&v, triangles).and_then(|s| s.clearance(&segments));
                if let Some(c) = c.filter(|c| c.value < 0.0) {
                    return Err(refuse(
                        &format!("obstacles[{k}]"),
                        format!(
                            "obstacle{name} lies on the path: the path passes inside its surface, {:.2} mm deep at {}",
                            -c.value,
                            mm(&c.point)
                        ),
                    ));
                }
            }
        }
    }
    Ok(())
}

/// The needle is longer than the deepest planned insertion (else its base, the flange, would
/// enter the gel).
fn needle_length<const N: usize>(scene: &Scene, world: &World<N>) -> Result<(), SetupError> {
    let path = &world.path;
    let reach = match scene.insertion.steps {
        Some(n) => (scene.insertion.advance_per_step * n as f64 - path.approach).min(path.length()),
        None => path.length(),
    };
    if scene.needle.length > reach {
        return Ok(());
    }
    Err(refuse(
        "needle.length",
        format!(
            "a {} mm needle cannot be inserted {reach:.1} mm (its base would enter the gel)",
            scene.needle.length
        ),
    ))
}

/// Steering length under which a bending path is flagged by [`advisories`] [mm]. Measured on
/// the public suite and fourteen held-out sets (367 runs, `docs/benchmark.md`, "Reach against
/// the steering length"): under 18 mm 14 of 43 runs reach their target, from 18 mm 319 of 324.
pub const SHORT_STEERING_MM: f64 = 18.0;

/// Largest offset of the path from its entry line under which a path counts as straight for
/// [`advisories`] [mm] (a straight entry reaches its target at any steering length).
pub const STRAIGHT_PATH_MM: f64 = 1.0;

/// The path's largest distance from its entry line (the line through its entry point along its
/// entry tangent) [mm].
pub fn path_bend(path: &crate::scene::SampledPath) -> f64 {
    let (p0, t0) = (path.entry(), path.entry_tangent());
    path.points
        .iter()
        .map(|p| {
            let d = p - p0;
            (d - t0 * d.dot(&t0)).norm()
        })
        .fold(0.0, f64::max)
}

/// Whether a needle of steering length `ell` [mm] lags a path that bends `bend` [mm] from its
/// entry line ([`path_bend`]): `ell` under [`SHORT_STEERING_MM`] and `bend` over
/// [`STRAIGHT_PATH_MM`]. Such a run gets an advisory ([`advisories`]) and, under
/// `inverse.straighten = "auto"`, a straightened target ([`crate::scene::StraightenSpec`]).
pub fn lags_its_bend(ell: f64, bend: f64) -> bool {
    ell < SHORT_STEERING_MM && bend > STRAIGHT_PATH_MM
}

/// What the plan allows but makes unlikely to succeed, one sentence each, for the run's
/// summary and the start of `needle run` (a scene that is refused fails [`check`] instead).
/// Today one: a path that bends ([`path_bend`] above [`STRAIGHT_PATH_MM`]) for a needle whose
/// steering length in this gel ([`crate::setup::steering_length`]) is under
/// [`SHORT_STEERING_MM`]: deep in the gel the joints then barely turn the tip, and the tip may
/// lag the bend.
pub fn advisories<const N: usize>(scene: &Scene, world: &World<N>) -> Vec<String> {
    let mut out = Vec::new();
    let ell = scene.steering_length();
    let bend = path_bend(&world.path);
    if lags_its_bend(ell, bend) {
        out.push(format!(
            "the needle's steering length in this gel is {ell:.1} mm (under {SHORT_STEERING_MM:.0} mm: \
             Ø {} mm, E {} MPa in a {} MPa gel) and the path bends {bend:.1} mm away from its entry \
             line: deep in the gel the joints barely turn the tip, which may lag the bend and miss \
             the target (docs/benchmark.md, \"Reach against the steering length\")",
            scene.needle.diameter, scene.needle.young_modulus, scene.gel.young_modulus
        ));
    }
    out
}

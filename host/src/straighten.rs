//! The target shown to the controller, straightened towards the path's chord
//! (`inverse.straighten`, [`SampledPath::straightened`]) and kept from coming nearer an
//! obstacle than the planned path does.
//!
//! A needle whose gel holds its shaft (a short steering length) turns its tip while it is
//! shallow and hardly at all deep in the gel, so it is asked for the heading of the path's chord
//! early rather than for a bend it cannot make late. The chord of a bending path lies inside
//! the bend, where an obstacle placed beside the path may lie too: a target shown inside an
//! obstacle holds the tip at the obstacle's margin, unable to advance. So along the path the
//! fraction is the largest one (up to the one asked for) at which the shown point is no nearer
//! to any obstacle than the path's own point, or at least [`OBSTACLE_REACH_MM`] from it, and
//! it ramps back over [`RAMP_MM`] of path on either side of where an obstacle lowers it, so the
//! shown target moves smoothly.

use crate::proximity::ClosedSurface;
use crate::scene::SampledPath;
use crate::world::ObstacleShape;
use nalgebra::Vector3;

/// Spacing of the fraction's table along the path [mm].
pub const SPACING_MM: f64 = 0.5;
/// A straightened point at least this far from an obstacle's surface is not limited by it,
/// whatever the path's own distance [mm].
pub const OBSTACLE_REACH_MM: f64 = 2.0;
/// Length of path over which the fraction returns to the one asked for, on either side of where
/// an obstacle lowers it [mm].
pub const RAMP_MM: f64 = 5.0;
/// Fractions tried at each table point: the one asked for times `j / LEVELS`, `j` = `LEVELS` … 0.
const LEVELS: u32 = 16;

/// The fraction of the way towards the path's chord at each arc length.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Straightening {
    /// The fraction asked for (`inverse.straighten` resolved) [-]; 0: the planned path.
    pub fraction: f64,
    /// The fraction at arc length `k · SPACING_MM` from the start tip (empty: none).
    table: Vec<f64>,
}

impl Straightening {
    /// The fractions along `path` for `fraction` asked for, kept clear of `obstacles` (their
    /// rest shapes: the path and the obstacles are embedded in the gel together).
    pub fn new(path: &SampledPath, fraction: f64, obstacles: &[ObstacleShape]) -> Self {
        if fraction <= 0.0 {
            return Self::default();
        }
        let surfaces: Vec<Option<ClosedSurface>> = obstacles
            .iter()
            .map(|o| match o {
                ObstacleShape::Mesh(m) => ClosedSurface::new(&m.vertices, &m.triangles),
                ObstacleShape::Sphere { .. } => None,
            })
            .collect();
        let distance = |k: usize, q: &Vector3<f64>| match &obstacles[k] {
            ObstacleShape::Sphere { center, radius } => (q - center).norm() - radius,
            ObstacleShape::Mesh(_) => {
                (surfaces[k].as_ref()).map_or(f64::INFINITY, |s| s.signed_distance(q).0)
            }
        };
        let n = (path.total_length() / SPACING_MM).ceil() as usize + 1;
        let free: Vec<f64> = (0..n)
            .map(|i| {
                let c = i as f64 * SPACING_MM;
                let p = path.at(c).0;
                let clear = |q: &Vector3<f64>| {
                    (0..obstacles.len())
                        .all(|k| distance(k, q) >= distance(k, &p).min(OBSTACLE_REACH_MM))
                };
                (0..=LEVELS)
                    .rev()
                    .map(|j| fraction * f64::from(j) / f64::from(LEVELS))
                    .find(|&b| clear(&path.straightened(c, b)))
                    .unwrap_or(0.0)
            })
            .collect();
        // Each point at most the lowest fraction of its neighbours (so that the table's linear
        // interpolation stays within what both ends allow) plus a rise of `fraction` per
        // RAMP_MM of path between.
        let table = (0..n)
            .map(|i| {
                (0..n)
                    .map(|j| {
                        let near = free[j.saturating_sub(1)..=(j + 1).min(n - 1)]
                            .iter()
                            .copied()
                            .fold(fraction, f64::min);
                        near + fraction * (i.abs_diff(j) as f64 * SPACING_MM) / RAMP_MM
                    })
                    .fold(fraction, f64::min)
            })
            .collect();
        Self { fraction, table }
    }

    /// The fraction at arc length `c` from the start tip (linear between table points).
    pub fn at(&self, c: f64) -> f64 {
        let Some(last) = self.table.len().checked_sub(1) else {
            return 0.0;
        };
        let x = (c / SPACING_MM).clamp(0.0, last as f64);
        let i = (x.floor() as usize).min(last);
        let j = (i + 1).min(last);
        let f = x - i as f64;
        self.table[i] * (1.0 - f) + self.table[j] * f
    }

    /// The lowest fraction along the path (the asked one without obstacles in the way).
    pub fn lowest(&self) -> f64 {
        self.table.iter().copied().fold(self.fraction, f64::min)
    }

    /// The point shown to the controller at arc length `c` ([`SampledPath::straightened`] by
    /// [`Straightening::at`]).
    pub fn point(&self, path: &SampledPath, c: f64) -> Vector3<f64> {
        path.straightened(c, self.at(c))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Scene;

    /// The simple benchmark's path bends towards +x, so its chord lies on the +x side. With no
    /// obstacle the whole fraction applies everywhere; a sphere put on the chord's side at
    /// mid-depth, 0.6 mm from the path, lowers it there (to 0 where the chord would pass nearer
    /// the sphere) and nowhere farther than the ramp from it; the shown points are never nearer
    /// the sphere than the path's, or at least the reach from it (the obstacle's safety is the
    /// update's clearance rows; this keeps the target from being shown inside it).
    #[test]
    fn straightened_target_keeps_its_distance_from_an_obstacle_on_the_chord_side() {
        let path = Scene::builtin("simple").unwrap().sampled_path().unwrap();
        let free = Straightening::new(&path, 0.4, &[]);
        for c in [0.0, 10.0, 30.0, 59.0, 100.0] {
            assert_eq!(free.at(c), 0.4);
        }
        assert_eq!(Straightening::new(&path, 0.0, &[]).at(30.0), 0.0);
        // At mid-path, on the chord's side (+x) of the path point.
        let mid = path.approach + 0.5 * path.length();
        let (p, chord) = (path.at(mid).0, path.straightened(mid, 1.0));
        let side = (chord - p).normalize();
        let (center, radius) = (p + side * 3.6, 3.0);
        let sphere = [ObstacleShape::Sphere { center, radius }];
        let s = Straightening::new(&path, 0.4, &sphere);
        assert!(s.at(mid) < 0.1, "{}", s.at(mid));
        assert!(s.lowest() < 0.1);
        assert_eq!(
            s.at(path.approach + 0.05 * path.length()),
            0.4,
            "far before it"
        );
        assert_eq!(s.at(path.total_length()), 0.4, "far after it");
        let mut c = path.approach;
        while c <= path.total_length() {
            let d = |q: Vector3<f64>| (q - center).norm() - radius;
            let (dp, dq) = (d(path.at(c).0), d(s.point(&path, c)));
            // (Checked at the table's points; between them, within the interpolation's error.)
            assert!(
                dq >= dp.min(OBSTACLE_REACH_MM) - 0.02,
                "c {c}: {dq} against {dp}"
            );
            // The fraction changes by at most the ramp's slope.
            let step = (s.at(c + 0.1) - s.at(c)).abs();
            assert!(step <= 0.4 * 0.1 / RAMP_MM + 1e-12, "c {c}: {step}");
            c += 0.1;
        }
    }
}

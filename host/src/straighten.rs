//! The target shown to the controller, straightened towards a chord of the path
//! (`inverse.straighten`, `inverse.straighten_from`, [`SampledPath::straightened`]), never
//! more than `inverse.straighten_max_offset` (default [`MAX_OFFSET_MM`]) off the path and kept
//! from coming nearer an obstacle than the planned path does.
//!
//! A needle whose gel holds its shaft (a short steering length) turns its tip while it is
//! shallow and hardly at all deep in the gel. Under `"auto"`, where it lags its path's bend, it
//! is shown the path down to one steering length past the entry point and the straight line
//! from there to the path's end after ([`Straightening::for_scene`]). The chord of a bending
//! path lies inside the bend, where an obstacle placed beside the path may lie too: a target
//! shown inside an obstacle holds the tip at the obstacle's margin, unable to advance. So along
//! the path the fraction is the largest one (up to the one asked for) at which the shown point
//! is no nearer to any obstacle than the path's own point, or at least [`OBSTACLE_REACH_MM`]
//! from it, and it ramps back over [`RAMP_MM`] of path on either side of where an obstacle
//! lowers it, so the shown target moves smoothly.

use crate::proximity::ClosedSurface;
use crate::scene::{MethodSpec, SampledPath, StraightenFromSpec, StraightenSpec};
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
/// The shown point is never farther than this from the path's own point by default
/// (`inverse.straighten_max_offset`) [mm]: half the
/// deviation from the path that makes a run that reaches its target
/// [`crate::run::Outcome::LeftPath`] ([`crate::run::metrics::PATH_TOLERANCE_MM`]), so a tip
/// that lags the shown point by as much again still keeps to the path's tolerance.
pub const MAX_OFFSET_MM: f64 = crate::run::metrics::PATH_TOLERANCE_MM / 2.0;
/// The distance the shown point keeps from an obstacle's surface where the path passes nearer,
/// by default (`inverse.target_standoff`) [mm]; 0: none.
pub const TARGET_STANDOFF_MM: f64 = 0.0;
/// `inverse.straighten = "auto"` where the needle lags its path's bend: the whole way to the
/// chord from one steering length deep (within [`MAX_OFFSET_MM`]).
pub const AUTO_FRACTION: f64 = 1.0;
/// ... unless an obstacle lies nearer that chord than the path: then this fraction of the
/// way towards the chord from the entry point, which leaves the path less deep in the gel.
pub const AUTO_FRACTION_NEAR_OBSTACLE: f64 = 0.4;
/// Fractions tried at each table point: the one asked for times `j / LEVELS`, `j` = `LEVELS` … 0.
const LEVELS: u32 = 16;

/// The fraction of the way towards the path's chord at each arc length.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Straightening {
    /// The fraction asked for (`inverse.straighten` resolved) [-]; 0: the planned path.
    pub fraction: f64,
    /// Where the chord starts: path length past the entry point [mm] (0: the entry point).
    pub from: f64,
    /// The largest distance of a shown point from the path's own point [mm]
    /// (`inverse.straighten_max_offset`).
    pub max_offset: f64,
    /// Whether an obstacle lowers the fraction somewhere (below what [`MAX_OFFSET_MM`] alone
    /// allows).
    pub obstacle_limited: bool,
    /// The fraction at arc length `k · SPACING_MM` from the start tip (empty: none).
    table: Vec<f64>,
    /// The distance the shown point keeps from every obstacle's surface where the path allows
    /// (`inverse.target_standoff`) [mm]; 0: none.
    pub standoff: f64,
    /// The shift of the shown point away from the obstacles at arc length `k · SPACING_MM`
    /// [mm] (empty: none).
    push: Vec<Vector3<f64>>,
}

/// The obstacles' rest shapes, for their distance to a point.
struct Nearness<'a> {
    obstacles: &'a [ObstacleShape],
    surfaces: Vec<Option<ClosedSurface>>,
}

impl<'a> Nearness<'a> {
    fn new(obstacles: &'a [ObstacleShape]) -> Self {
        let surfaces = obstacles
            .iter()
            .map(|o| match o {
                ObstacleShape::Mesh(m) => ClosedSurface::new(&m.vertices, &m.triangles),
                ObstacleShape::Sphere { .. } => None,
            })
            .collect();
        Self {
            obstacles,
            surfaces,
        }
    }

    /// The signed distance of `q` from obstacle `k`'s surface [mm] and the unit normal pointing
    /// away from it (zero where it has none: at a sphere's centre, or a surface that could not
    /// be built, whose distance is infinite).
    fn distance(&self, k: usize, q: &Vector3<f64>) -> (f64, Vector3<f64>) {
        match &self.obstacles[k] {
            ObstacleShape::Sphere { center, radius } => {
                let r = q - center;
                let n = r.norm();
                (n - radius, if n > 0.0 { r / n } else { Vector3::zeros() })
            }
            ObstacleShape::Mesh(_) => match &self.surfaces[k] {
                Some(s) => {
                    let (d, _, _, closest) = s.signed_distance(q);
                    (
                        d,
                        if d != 0.0 {
                            (q - closest) / d
                        } else {
                            Vector3::zeros()
                        },
                    )
                }
                None => (f64::INFINITY, Vector3::zeros()),
            },
        }
    }
}

impl Straightening {
    /// The straightening of a scene's path: `spec` and `from` resolved for the update `method`,
    /// where the needle does or does not lag its path's bend (`lags_its_bend`:
    /// [`crate::plan_check::lags_its_bend`]) with its `steering_length` [mm]. The paper's update
    /// is shown the planned path; a fraction is taken as given, from where `from` says.
    /// `"auto"`: none where the needle keeps up with its path; where it lags,
    /// [`AUTO_FRACTION`] of the way towards the chord from `from` (`"auto"`: one steering
    /// length deep), unless an obstacle lies nearer that chord than the path: then
    /// [`AUTO_FRACTION_NEAR_OBSTACLE`] towards the chord from the entry point
    /// (`docs/benchmark.md`, "The path from one steering length deep").
    /// Every shown point lies within `max_offset` [mm] of the path's own point.
    pub fn for_scene(
        path: &SampledPath,
        (spec, from, max_offset): (StraightenSpec, StraightenFromSpec, f64),
        method: MethodSpec,
        (lags_its_bend, steering_length): (bool, f64),
        obstacles: &[ObstacleShape],
    ) -> Self {
        let from_mm = from.from(steering_length);
        match (spec, method) {
            (_, MethodSpec::Paper) => Self::none(max_offset),
            (StraightenSpec::Fraction(b), _) => {
                Self::new(path, (b, from_mm, max_offset), obstacles)
            }
            (StraightenSpec::Auto, _) if !lags_its_bend => Self::none(max_offset),
            (StraightenSpec::Auto, _) => {
                let deep = Self::new(path, (AUTO_FRACTION, from_mm, max_offset), obstacles);
                if deep.obstacle_limited {
                    Self::new(
                        path,
                        (AUTO_FRACTION_NEAR_OBSTACLE, 0.0, max_offset),
                        obstacles,
                    )
                } else {
                    deep
                }
            }
        }
    }

    /// The fractions along `path` for `fraction` asked for towards the chord from `from` [mm]
    /// past the entry point, at most `max_offset` [mm] off the path and kept clear of
    /// `obstacles` (their rest shapes: the path and the obstacles are embedded in the gel
    /// together).
    pub fn new(
        path: &SampledPath,
        (fraction, from, max_offset): (f64, f64, f64),
        obstacles: &[ObstacleShape],
    ) -> Self {
        if fraction <= 0.0 {
            return Self::none(max_offset);
        }
        let near_obstacles = Nearness::new(obstacles);
        let distance = |k: usize, q: &Vector3<f64>| near_obstacles.distance(k, q).0;
        let n = (path.total_length() / SPACING_MM).ceil() as usize + 1;
        let levels = || {
            (0..=LEVELS)
                .rev()
                .map(|j| fraction * f64::from(j) / f64::from(LEVELS))
        };
        let mut obstacle_limited = false;
        let free: Vec<f64> = (0..n)
            .map(|i| {
                let c = i as f64 * SPACING_MM;
                let p = path.at(c).0;
                let near = |q: &Vector3<f64>| (q - p).norm() <= max_offset;
                let clear = |q: &Vector3<f64>| {
                    (0..obstacles.len())
                        .all(|k| distance(k, q) >= distance(k, &p).min(OBSTACLE_REACH_MM))
                };
                let shown = |b: f64| path.straightened(c, b, from);
                let offset = levels().find(|&b| near(&shown(b))).unwrap_or(0.0);
                // Below `offset` every level is near enough: only the obstacles are left.
                let b = levels()
                    .filter(|&b| b <= offset)
                    .find(|&b| clear(&shown(b)))
                    .unwrap_or(0.0);
                obstacle_limited |= b < offset;
                b
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
        Self {
            fraction,
            from,
            max_offset,
            obstacle_limited,
            table,
            ..Self::default()
        }
    }

    /// The planned path itself, shown points bounded by `max_offset` [mm] (for
    /// [`Straightening::with_standoff`]).
    pub fn none(max_offset: f64) -> Self {
        Self {
            max_offset,
            ..Self::default()
        }
    }

    /// The same, with each shown point moved away from the obstacles it is nearer than
    /// `standoff` [mm] to (along their normals, by what it lacks), at most as far as keeps it
    /// within [`Straightening::max_offset`] of the path's own point. The clearance rows of the
    /// update keep the needle `clearance_margin` from an obstacle; a target shown at that
    /// margin leaves the tip no room to lag towards the obstacle, and a shaft held at the
    /// margin cannot advance.
    pub fn with_standoff(
        mut self,
        path: &SampledPath,
        standoff: f64,
        obstacles: &[ObstacleShape],
    ) -> Self {
        if standoff.is_nan() || standoff <= 0.0 || obstacles.is_empty() {
            return self;
        }
        let nearness = Nearness::new(obstacles);
        let n = (path.total_length() / SPACING_MM).ceil() as usize + 1;
        self.push = (0..n)
            .map(|i| {
                let c = i as f64 * SPACING_MM;
                let (p, shown) = (path.at(c).0, self.point(path, c));
                let mut q = shown;
                // A few sweeps: a move away from one obstacle may bring the point nearer another.
                for _ in 0..4 {
                    for k in 0..obstacles.len() {
                        let (d, normal) = nearness.distance(k, &q);
                        if d < standoff {
                            q += normal * (standoff - d);
                        }
                    }
                }
                let off = q - p;
                if off.norm() > self.max_offset {
                    q = p + off * (self.max_offset / off.norm());
                }
                q - shown
            })
            .collect();
        self.standoff = standoff;
        self
    }

    /// The fraction at arc length `c` from the start tip (linear between table points).
    pub fn at(&self, c: f64) -> f64 {
        interpolate(&self.table, c).unwrap_or(0.0)
    }

    /// The lowest fraction along the path (the asked one without obstacles in the way).
    pub fn lowest(&self) -> f64 {
        self.table.iter().copied().fold(self.fraction, f64::min)
    }

    /// The distance over which the target tangent shown to the controller is the difference
    /// quotient of the shown points at arc lengths `c` and `c + h` [mm]. Where the path is
    /// straightened, their rest distance, at least `h / 10`: a unit vector at rest. A chord is
    /// shorter than the bend it replaces and the fraction varies along the path, so a quotient
    /// over `h` would weigh the tangent against the tip's error differently from one part of
    /// the path to the next; past the path's end the second point stops, and the quotient over
    /// the shorter distance keeps unit length down to the last `h / 10`. On the planned path
    /// `h` itself, as before the straightening (the quotient over 1 mm of the sampled path is a
    /// unit vector to within 10⁻³ up to the last millimetre).
    pub fn span(&self, path: &SampledPath, c: f64, h: f64) -> f64 {
        if self.table.is_empty() && self.push.is_empty() {
            return h;
        }
        (self.point(path, c + h) - self.point(path, c))
            .norm()
            .max(0.1 * h)
    }

    /// The point shown to the controller at arc length `c` ([`SampledPath::straightened`] by
    /// [`Straightening::at`], moved away from the obstacles by [`Straightening::with_standoff`]).
    pub fn point(&self, path: &SampledPath, c: f64) -> Vector3<f64> {
        path.straightened(c, self.at(c), self.from) + self.push_at(c)
    }

    /// The shift away from the obstacles at arc length `c` (linear between table points) [mm].
    fn push_at(&self, c: f64) -> Vector3<f64> {
        interpolate(&self.push, c).unwrap_or_else(Vector3::zeros)
    }
}

/// A table of values at arc lengths `k · SPACING_MM`, at `c` (linear between table points,
/// the end values beyond them); `None` for an empty table.
fn interpolate<T>(table: &[T], c: f64) -> Option<T>
where
    T: Copy + core::ops::Mul<f64, Output = T> + core::ops::Add<Output = T>,
{
    let last = table.len().checked_sub(1)?;
    let x = (c / SPACING_MM).clamp(0.0, last as f64);
    let i = (x.floor() as usize).min(last);
    let j = (i + 1).min(last);
    let f = x - i as f64;
    Some(table[i] * (1.0 - f) + table[j] * f)
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
        let free = Straightening::new(&path, (0.4, 0.0, MAX_OFFSET_MM), &[]);
        for c in [0.0, 10.0, 30.0, 59.0, 100.0] {
            assert_eq!(free.at(c), 0.4);
        }
        assert_eq!(
            Straightening::new(&path, (0.0, 0.0, MAX_OFFSET_MM), &[]).at(30.0),
            0.0
        );
        // At mid-path, on the chord's side (+x) of the path point.
        let mid = path.approach + 0.5 * path.length();
        let (p, chord) = (path.at(mid).0, path.straightened(mid, 1.0, 0.0));
        let side = (chord - p).normalize();
        let (center, radius) = (p + side * 3.6, 3.0);
        let sphere = [ObstacleShape::Sphere { center, radius }];
        let s = Straightening::new(&path, (0.4, 0.0, MAX_OFFSET_MM), &sphere);
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

    /// `"auto"` where the needle lags its bend: the whole way to the chord from one steering
    /// length deep, never more than [`MAX_OFFSET_MM`] off the path; nothing where it
    /// keeps up, nor for the paper's update; a fraction as given. An obstacle nearer that chord
    /// than the path sends it back to 40 % of the way to the chord from the entry point.
    #[test]
    fn auto_straightens_from_one_steering_length_deep_unless_an_obstacle_is_in_the_way() {
        let path = Scene::builtin("simple").unwrap().sampled_path().unwrap();
        let auto = (
            StraightenSpec::Auto,
            StraightenFromSpec::Auto,
            MAX_OFFSET_MM,
        );
        let qp = MethodSpec::Qp;
        let s = Straightening::for_scene(&path, auto, qp, (true, 13.0), &[]);
        assert_eq!((s.fraction, s.from, s.obstacle_limited), (1.0, 13.0, false));
        let end = path.total_length();
        // The largest offset of the shown point from the path, checking the bound on the way.
        let largest = |s: &Straightening, shallow: f64| {
            let mut c: f64 = 0.0;
            let mut largest: f64 = 0.0;
            while c <= end {
                let offset = (s.point(&path, c) - path.at(c).0).norm();
                assert!(offset <= MAX_OFFSET_MM + 0.01, "c {c}: {offset}");
                if c <= path.approach + shallow {
                    assert_eq!(offset, 0.0, "c {c}: the path itself while shallow");
                }
                largest = largest.max(offset);
                c += 0.1;
            }
            largest
        };
        // The chord from 13 mm deep runs within 1.07 mm of the path: the whole way to it.
        assert!((1.0..MAX_OFFSET_MM).contains(&largest(&s, 13.0)));
        assert_eq!(s.lowest(), 1.0);
        // The chord from the entry point runs 2 mm from it: held to the bound mid-way.
        let whole = Straightening::new(&path, (1.0, 0.0, MAX_OFFSET_MM), &[]);
        assert!(largest(&whole, 0.0) > 1.45);
        assert!(whole.lowest() < 0.8 && !whole.obstacle_limited);
        // A wider bound (`inverse.straighten_max_offset`) lets the chord from the entry point
        // whole: the same points where it held them nearer, nowhere farther than the bound.
        let wide = Straightening::new(&path, (1.0, 0.0, 2.5), &[]);
        assert_eq!(wide.max_offset, 2.5);
        assert_eq!(wide.lowest(), 1.0);
        let mut c: f64 = 0.0;
        while c <= end {
            let offset = (wide.point(&path, c) - path.at(c).0).norm();
            assert!(offset <= 2.5 + 0.01, "c {c}: {offset}");
            assert!(offset >= (whole.point(&path, c) - path.at(c).0).norm() - 1e-9);
            c += 0.1;
        }
        assert_eq!(s.point(&path, end), path.at(end).0);
        for none in [
            Straightening::for_scene(&path, auto, qp, (false, 13.0), &[]),
            Straightening::for_scene(&path, auto, MethodSpec::Paper, (true, 13.0), &[]),
        ] {
            assert_eq!(none.fraction, 0.0);
            assert_eq!(none.point(&path, 40.0), path.at(40.0).0);
        }
        let given = (
            StraightenSpec::Fraction(0.25),
            StraightenFromSpec::Mm(5.0),
            MAX_OFFSET_MM,
        );
        let g = Straightening::for_scene(&path, given, qp, (false, 13.0), &[]);
        assert_eq!((g.fraction, g.from), (0.25, 5.0));
        // A sphere beside the deep chord, on its side of the path, 3/4 of the way down.
        let l = path.approach + 13.0 + 0.75 * (path.length() - 13.0);
        let (p, chord) = (path.at(l).0, path.straightened(l, 1.0, 13.0));
        let side = (chord - p).normalize();
        let sphere = [ObstacleShape::Sphere {
            center: p + side * 3.6,
            radius: 3.0,
        }];
        let near = Straightening::for_scene(&path, auto, qp, (true, 13.0), &sphere);
        assert_eq!(
            (near.fraction, near.from),
            (AUTO_FRACTION_NEAR_OBSTACLE, 0.0)
        );
        assert!(Straightening::new(&path, (1.0, 13.0, MAX_OFFSET_MM), &sphere).obstacle_limited);
    }

    /// `inverse.target_standoff`: a sphere 0.6 mm from the simple path at mid-depth; the shown
    /// points are kept 1 mm from its surface (to the table's interpolation) where the path
    /// passes nearer, moved along its normal by what they lack, nowhere more than the offset
    /// bound from the path; the path's own points elsewhere; nothing for no standoff.
    #[test]
    fn shown_target_keeps_its_standoff_from_an_obstacle_the_path_passes_near() {
        let path = Scene::builtin("simple").unwrap().sampled_path().unwrap();
        let mid = path.approach + 0.5 * path.length();
        let (p, chord) = (path.at(mid).0, path.straightened(mid, 1.0, 0.0));
        let side = (chord - p).normalize();
        let (center, radius) = (p + side * 3.6, 3.0);
        let sphere = [ObstacleShape::Sphere { center, radius }];
        let d = |q: Vector3<f64>| (q - center).norm() - radius;
        let none = Straightening::none(MAX_OFFSET_MM);
        let kept = none.clone().with_standoff(&path, 1.0, &sphere);
        assert_eq!(kept.standoff, 1.0);
        assert_eq!(none.clone().with_standoff(&path, 0.0, &sphere), none);
        assert_eq!(none.clone().with_standoff(&path, 1.0, &[]), none);
        let (mut c, mut moved) = (0.0, 0.0_f64);
        while c <= path.total_length() {
            let (own, shown) = (path.at(c).0, kept.point(&path, c));
            let offset = (shown - own).norm();
            assert!(offset <= MAX_OFFSET_MM + 1e-9, "c {c}: {offset}");
            // (Between the table's points the push is interpolated: 1 mm of slack there.)
            if d(own) >= 1.0 + 2.0 * SPACING_MM {
                assert!(offset < 1e-9, "c {c}: moved {offset} though 1 mm clear");
            }
            assert!(d(shown) >= d(own).min(1.0) - 0.05, "c {c}: {}", d(shown));
            moved = moved.max(offset);
            c += 0.1;
        }
        // At the table's points, 1 mm from the sphere wherever the path passes nearer.
        for k in 0..=(path.total_length() / SPACING_MM) as usize {
            let c = k as f64 * SPACING_MM;
            let shown = kept.point(&path, c);
            assert!(
                d(shown) >= 1.0 - 1e-9,
                "c {c}: {} from the sphere",
                d(shown)
            );
        }
        // The path's nearest point is 0.6 mm from the sphere: moved 0.4 mm off it.
        assert!((moved - 0.4).abs() < 0.01, "{moved}");
        // A bound tighter than what is lacking holds the point to it.
        let held = Straightening::none(0.25).with_standoff(&path, 1.0, &sphere);
        assert!((held.point(&path, mid) - p).norm() <= 0.25 + 1e-9);
    }

    /// The target tangent shown to the controller is the shown points' difference quotient over
    /// [`Straightening::span`]: of unit length on the chord from the entry point held to the
    /// offset bound (where the shown point does not move 1 mm per mm of path) up to the path's
    /// end, where a quotient over the 1 mm of path alone is off unit length by more than 5 %; on
    /// the planned path the quotient over 1 mm, as before, within 10⁻³ of unit length.
    #[test]
    fn shown_tangent_has_unit_length_where_the_path_is_straightened() {
        let path = Scene::builtin("simple").unwrap().sampled_path().unwrap();
        let whole = Straightening::new(&path, (1.0, 0.0, MAX_OFFSET_MM), &[]);
        let none = Straightening::default();
        let (h, end) = (1.0, path.total_length());
        let mut off_unit: f64 = 0.0;
        let mut c = path.approach;
        while c < end - 0.1 * h {
            let d = whole.point(&path, c + h) - whole.point(&path, c);
            let t = d / whole.span(&path, c, h);
            assert!((t.norm() - 1.0).abs() < 1e-12, "c {c}: |t| {}", t.norm());
            assert_eq!(none.span(&path, c, h), h);
            if c + h <= end {
                let t = (none.point(&path, c + h) - none.point(&path, c)) / h;
                assert!((t.norm() - 1.0).abs() < 1e-3, "c {c}: |t| {}", t.norm());
            }
            let d = whole.point(&path, c + h) - whole.point(&path, c);
            off_unit = off_unit.max((d.norm() / h - 1.0).abs());
            c += 0.1;
        }
        assert!(off_unit > 0.05, "{off_unit}");
        // At the end the two points meet: the span stops at a tenth of the step.
        assert_eq!(whole.span(&path, end, h), 0.1 * h);
    }
}

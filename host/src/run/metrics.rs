//! Whether a run did its job: the distance from the tip to the path's end point when the run
//! ends (`e_final`), the tip's deviation from the deformed path, the steps it took to reach the
//! end, and the [`Outcome`] with its exit code.
//!
//! **Reached** is strict: the run was not stopped, no obstacle was hit, the tip came within
//! [`REACH_TOLERANCE_MM`] of the path's end point (deformed with the gel) within
//! [`STEP_ALLOWANCE`] × the nominal steps (path length / `advance_per_step`), it is still
//! within that tolerance at the run's last step, and, on an insertion (not a back-and-forth
//! schedule), the needle never left the gel after puncturing it: a needle pulled out and
//! pushed in again entered the tissue twice, the second time off the planned entry. A run
//! that meets all of that but whose tip strayed more than [`PATH_TOLERANCE_MM`] from the
//! (deformed) path on the way is [`Outcome::LeftPath`]: the target was reached off the planned
//! route, which is what the path was planned to avoid.

// Units are written in brackets ([mm], [N]) as in the workspace style: not intra-doc links.
#![allow(rustdoc::broken_intra_doc_links)]

use crate::proximity::Embedded;
use crate::step::StepReport;
use crate::world::World;
use nalgebra::Vector3;
use serde::Serialize;

/// The tip must end within this distance of the path's end point [mm].
pub const REACH_TOLERANCE_MM: f64 = 1.0;

/// ... within this many times the nominal steps.
pub const STEP_ALLOWANCE: f64 = 1.2;

/// ... and the tip never further than this from the deformed path inside the gel [mm] (issue
/// "controller"'s bound on the largest tracking error).
pub const PATH_TOLERANCE_MM: f64 = 3.0;

/// How a run ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Outcome {
    /// The tip ended at the path's end point (see the module docs).
    Reached,
    /// The run went to its end without an obstacle hit or a stop, but the tip did not end within
    /// the tolerance of the path's end point in time.
    MissedTarget,
    /// The tip ended at the path's end point, but on the way it went further than
    /// [`PATH_TOLERANCE_MM`] from the deformed path: the target reached off the planned route
    /// (typically by dragging the tissue onto the needle).
    LeftPath,
    /// The needle went into an obstacle (clearance below 0).
    ObstacleHit,
    /// The run stopped early (a breakdown, a non-finite state, a divergence or a transport
    /// failure: `RunSummary::stopped` says which).
    Diverged,
}

impl Outcome {
    /// The process exit code of a run that ended so (`needle run`, `needle serve`): 0 reached,
    /// 3 diverged / stopped, 4 missed the target, 5 hit an obstacle, 6 reached the target off
    /// the path.
    pub fn exit_code(self) -> u8 {
        match self {
            Self::Reached => 0,
            Self::Diverged => 3,
            Self::MissedTarget => 4,
            Self::ObstacleHit => 5,
            Self::LeftPath => 6,
        }
    }

    /// The name used in the summaries and tables.
    pub fn name(self) -> &'static str {
        match self {
            Self::Reached => "reached",
            Self::MissedTarget => "missed_target",
            Self::ObstacleHit => "obstacle_hit",
            Self::Diverged => "diverged",
            Self::LeftPath => "left_path",
        }
    }

    /// The outcome of a run that ended as `end` says: stopped → diverged, else hit → obstacle
    /// hit, else reached when the tip ends within the tolerance, got there within the allowance
    /// and the needle was not withdrawn from the gel on the way — left the path when its
    /// largest deviation from the path is over [`PATH_TOLERANCE_MM`] — else missed.
    pub fn of(end: &RunEnd) -> Self {
        let allowed = (STEP_ALLOWANCE * end.steps_nominal as f64).floor() as usize;
        if end.stopped {
            Self::Diverged
        } else if end.obstacle_hit {
            Self::ObstacleHit
        } else if end.e_final_mm <= REACH_TOLERANCE_MM
            && end.steps_to_target.is_some_and(|k| k <= allowed)
            && !end.withdrawn
        {
            if end.path_deviation_max_mm > PATH_TOLERANCE_MM {
                Self::LeftPath
            } else {
                Self::Reached
            }
        } else {
            Self::MissedTarget
        }
    }
}

/// What a run's [`Outcome`] is judged on.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RunEnd {
    /// The run stopped early, not on purpose (a breakdown, a divergence, no step at all).
    pub stopped: bool,
    /// The needle went into an obstacle (a clearance below 0).
    pub obstacle_hit: bool,
    /// The tip's distance to the path's end point when the run ended [mm].
    pub e_final_mm: f64,
    /// The first step after which the tip was within [`REACH_TOLERANCE_MM`] of the path's end.
    pub steps_to_target: Option<usize>,
    /// The path's length over the advance per step.
    pub steps_nominal: usize,
    /// The needle was pulled out of the gel and pushed in again on the way (insert-only runs).
    pub withdrawn: bool,
    /// The tip's largest distance to the deformed path [mm] (NaN: never inside).
    pub path_deviation_max_mm: f64,
}

/// Distance from `p` to the polyline through `points` [mm] (∞ for fewer than 2 points).
pub fn distance_to_polyline(points: &[Vector3<f64>], p: &Vector3<f64>) -> f64 {
    points
        .windows(2)
        .map(|s| {
            let d = s[1] - s[0];
            let l2 = d.norm_squared();
            let t = if l2 > 0.0 {
                ((p - s[0]).dot(&d) / l2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            (s[0] + t * d - p).norm()
        })
        .fold(f64::INFINITY, f64::min)
}

/// How far the tissue has moved under the needle, the support's motion taken out [mm]: the
/// path's end point (the target, embedded in the gel at rest) and the entry point (the
/// material point the needle punctured) against their rest positions; 0 for a target outside
/// the gel. Both 0 in a gel at rest.
pub fn tissue_shift<const N: usize>(world: &World<N>, target: Option<&Embedded>) -> (f64, f64) {
    (
        target.map_or(0.0, |e| world.shift_from_rest(e).norm()),
        world.entry_shift().norm(),
    )
}

/// Path metrics gathered step by step.
#[derive(Clone, Debug)]
pub struct PathMetrics {
    /// The path's vertices in the gel, embedded at their rest positions once the tip is in.
    embedded: Option<Vec<Embedded>>,
    /// Scratch: the deformed vertices.
    deformed: Vec<Vector3<f64>>,
    deviation_sum: f64,
    deviation_count: usize,
    deviation_max: f64,
    /// Steps until the tip first came within the tolerance of the path's end point.
    pub steps_to_target: Option<usize>,
    /// Distance from the tip to the path's end point after the last step [mm].
    pub e_end: f64,
    /// Largest displacement of the path's end point from its rest position, the support's
    /// motion taken out, over the steps after the puncture [mm]: how far the insertion pushed
    /// the target through the tissue.
    pub target_shift_max: f64,
    /// Largest displacement of the entry point (the material point the needle punctured) from
    /// its rest position, the support's motion taken out, after the puncture [mm]: how far
    /// the needle dragged the tissue at the surface.
    pub entry_shift_max: f64,
}

impl Default for PathMetrics {
    fn default() -> Self {
        Self {
            embedded: None,
            deformed: Vec::new(),
            deviation_sum: 0.0,
            deviation_count: 0,
            deviation_max: 0.0,
            steps_to_target: None,
            e_end: f64::INFINITY,
            target_shift_max: 0.0,
            entry_shift_max: 0.0,
        }
    }
}

impl PathMetrics {
    /// After step `r` of `world`.
    pub fn step<const N: usize>(&mut self, world: &World<N>, r: &StepReport) {
        let length = world.path.total_length();
        let target = world.target_embedding(length);
        let end = target.as_ref().map_or_else(
            || world.path.at(length).0 + world.support_offset,
            |e| world.gel_point(e),
        );
        self.e_end = (r.tip - end).norm();
        if self.e_end <= REACH_TOLERANCE_MM && self.steps_to_target.is_none() {
            self.steps_to_target = Some(r.step + 1);
        }
        if world.punctured {
            let (target, entry) = tissue_shift(world, target.as_ref());
            self.target_shift_max = self.target_shift_max.max(target);
            self.entry_shift_max = self.entry_shift_max.max(entry);
        }
        if !r.tip_inside() {
            return;
        }
        if self.embedded.is_none() {
            let a = world.path.approach;
            let e: Option<Vec<Embedded>> = world
                .path
                .arc
                .iter()
                .map(|s| world.target_embedding(a + s))
                .collect();
            // A vertex outside the mesh (should not happen: the path lies in the gel): no
            // deviation for this run rather than a wrong one.
            self.embedded = Some(e.unwrap_or_default());
        }
        let Some(e) = &self.embedded else { return };
        if e.len() < 2 {
            return;
        }
        self.deformed.clear();
        self.deformed.extend(e.iter().map(|p| world.gel_point(p)));
        let d = distance_to_polyline(&self.deformed, &r.tip);
        self.deviation_sum += d;
        self.deviation_count += 1;
        self.deviation_max = self.deviation_max.max(d);
    }

    /// Mean and largest distance from the tip to the deformed path over the steps inside the
    /// gel [mm] (NaN when the tip never went in).
    pub fn deviation(&self) -> (f64, f64) {
        if self.deviation_count == 0 {
            (f64::NAN, f64::NAN)
        } else {
            (
                self.deviation_sum / self.deviation_count as f64,
                self.deviation_max,
            )
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn polyline_distance_is_to_the_nearest_segment() {
        let pts = [
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(10.0, 0.0, 0.0),
            Vector3::new(10.0, 10.0, 0.0),
        ];
        assert!((distance_to_polyline(&pts, &Vector3::new(5.0, 2.0, 0.0)) - 2.0).abs() < 1e-12);
        assert!((distance_to_polyline(&pts, &Vector3::new(12.0, 5.0, 0.0)) - 2.0).abs() < 1e-12);
        // Beyond the end: the distance to the end point.
        assert!((distance_to_polyline(&pts, &Vector3::new(10.0, 13.0, 4.0)) - 5.0).abs() < 1e-12);
        assert!(distance_to_polyline(&pts[..1], &Vector3::zeros()).is_infinite());
    }

    /// A run that ended 0.001 mm from the path's end, there at step 608 of 620 nominal, at most
    /// 0.5 mm from the path.
    const ON_TARGET: RunEnd = RunEnd {
        stopped: false,
        obstacle_hit: false,
        e_final_mm: 0.001,
        steps_to_target: Some(608),
        steps_nominal: 620,
        withdrawn: false,
        path_deviation_max_mm: 0.5,
    };

    /// Seed 404's `scurve_x` (`tools/gen_suite.py --seed 404`): the tip ended 0.001 mm from the
    /// path's end after straying 14.7 mm from the path (the entry dragged 42.9 mm), and the run
    /// counted as reached.
    #[test]
    fn target_reached_14_7_mm_off_the_path_is_not_reached() {
        use Outcome::*;
        let off = |d| RunEnd {
            path_deviation_max_mm: d,
            ..ON_TARGET
        };
        assert_eq!(Outcome::of(&off(14.68)), LeftPath);
        assert_eq!(Outcome::of(&off(3.0)), Reached);
        assert_eq!(Outcome::of(&off(3.01)), LeftPath);
        // No deviation measured (never inside): judged by the target alone.
        assert_eq!(Outcome::of(&off(f64::NAN)), Reached);
        // The other outcomes come first.
        let hit = RunEnd {
            obstacle_hit: true,
            ..off(14.68)
        };
        assert_eq!(Outcome::of(&hit), ObstacleHit);
        let missed = RunEnd {
            e_final_mm: 1.5,
            ..off(14.68)
        };
        assert_eq!(Outcome::of(&missed), MissedTarget);
        let stopped = RunEnd {
            stopped: true,
            ..off(14.68)
        };
        assert_eq!(Outcome::of(&stopped), Diverged);
    }

    #[test]
    fn reached_needs_tolerance_time_and_no_hit_or_stop() {
        use Outcome::*;
        // 1.2 × 100 nominal steps allowed.
        let run = |e_final_mm, steps_to_target| RunEnd {
            e_final_mm,
            steps_to_target,
            steps_nominal: 100,
            ..ON_TARGET
        };
        assert_eq!(Outcome::of(&run(0.9, Some(120))), Reached);
        assert_eq!(Outcome::of(&run(1.1, Some(120))), MissedTarget);
        assert_eq!(Outcome::of(&run(0.9, Some(121))), MissedTarget);
        assert_eq!(Outcome::of(&run(0.9, None)), MissedTarget);
        let hit = RunEnd {
            obstacle_hit: true,
            ..run(0.1, Some(90))
        };
        assert_eq!(Outcome::of(&hit), ObstacleHit);
        let stopped_and_hit = RunEnd {
            stopped: true,
            ..hit
        };
        assert_eq!(Outcome::of(&stopped_and_hit), Diverged);
        // Pulled out of the gel and pushed in again on the way: not reached, however close.
        let withdrawn = RunEnd {
            withdrawn: true,
            ..run(0.0, Some(90))
        };
        assert_eq!(Outcome::of(&withdrawn), MissedTarget);
        let codes: Vec<u8> = [Reached, Diverged, MissedTarget, ObstacleHit, LeftPath]
            .iter()
            .map(|o| o.exit_code())
            .collect();
        assert_eq!(codes, [0, 3, 4, 5, 6]);
    }
}

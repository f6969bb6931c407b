//! Divergence detection: after every step, the run is checked for a state no physical insertion
//! reaches — a non-finite value, the tip far outside the gel's neighbourhood, the gel displaced by
//! more than its own size, a needle folded onto itself — and, at every strain sample, gel
//! elements inverted or stretched beyond any soft tissue's range. The first such finding stops
//! the run with a [`StopReason`] (a diverged simulation is never reported as completed).

// Units are written in brackets ([mm], [N]) as in the workspace style: not intra-doc links.
#![allow(rustdoc::broken_intra_doc_links)]

use crate::constraints::ClearanceKind;
use crate::fem::tetra::StrainStats;
use crate::step::StepReport;
use crate::world::World;
use nalgebra::Vector3;
use needle_core::payload::StatusFlags;
use serde::Serialize;
use std::fmt;

/// Largest principal strain `|σ(F) − 1|` of a gel element a run may reach [-]: 300 % (the
/// benchmark scenes stay below 60 %; a gel that blew up reaches thousands of %).
pub const MAX_STRAIN: f64 = 3.0;

/// Share of the gel's elements that may be inverted at once before the run is declared
/// diverged (a few elements pinched by the needle tip are normal).
pub const MAX_INVERTED_SHARE: f64 = 0.01;

/// Shortest chord (base to tip) of the needle, as a share of its length, before it is
/// declared folded: an elastic needle bent into a half circle keeps 64 %.
pub const MIN_CHORD_SHARE: f64 = 0.5;

/// Why a run stopped before its last step.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
#[non_exhaustive]
pub enum StopReason {
    /// A value of the state or of the step's report is NaN or infinite.
    NonFinite,
    /// The tip left the gel's neighbourhood (the gel's bounding box grown by the needle's
    /// length on every side).
    TipLeftGel {
        /// Distance of the tip from the gel's rest bounding box [mm].
        distance_mm: f64,
        /// Largest distance allowed [mm].
        limit_mm: f64,
    },
    /// A gel node moved further than the gel's rest diagonal.
    GelBlowUp {
        /// Largest node displacement [mm].
        displacement_mm: f64,
        /// The gel's rest diagonal [mm].
        limit_mm: f64,
    },
    /// The needle folded: its base and tip came closer than [`MIN_CHORD_SHARE`] of its length.
    NeedleFolded {
        /// Base-to-tip distance [mm].
        chord_mm: f64,
        /// Needle length [mm].
        length_mm: f64,
    },
    /// More than [`MAX_INVERTED_SHARE`] of the gel's elements are inverted.
    InvertedElements {
        /// Inverted elements.
        inverted: usize,
        /// Elements of the gel.
        elements: usize,
    },
    /// A gel element is strained beyond [`MAX_STRAIN`].
    Strain {
        /// Largest principal strain [-].
        strain: f64,
        /// The element.
        element: usize,
    },
    /// The step failed (factorisation, solve, transport, command): the message says which.
    StepFailed {
        /// The error chain.
        message: String,
    },
    /// No command answered the frame within the give-up time.
    NoCommand {
        /// Seconds waited.
        waited_s: f64,
    },
    /// The naive baseline's rigid IK could not follow the path further.
    IkFailed {
        /// The error chain.
        message: String,
    },
    /// For [`BLOCKED_AFTER_S`] the controller could not bring the tip toward its target
    /// without entering an obstacle's clearance margin (flags `CLEARANCE_ACTIVE` and
    /// `TARGET_UNREACHABLE` in every step) and the tip's depth moved by less than
    /// [`BLOCKED_MOVE_SHARE`] of the insertion scheduled over that time: the run stops rather
    /// than push into the obstacle.
    Blocked {
        /// Steps in a row.
        steps: usize,
        /// Their duration [s].
        seconds: f64,
        /// What held the last of them, e.g. "o1's margin" (empty: not known).
        by: String,
    },
    /// The caller's observer asked the run to stop ([`super::run_until`]; e.g. a Python
    /// callback that raised).
    Interrupted,
}

impl StopReason {
    /// Whether the run ended on purpose (blocked, or stopped by its caller) rather than by a
    /// failure: its outcome is then judged from where the tip is, not `diverged`.
    pub fn is_deliberate(&self) -> bool {
        matches!(self, Self::Blocked { .. } | Self::Interrupted)
    }

    /// Whether the simulation diverged (as opposed to a failure of a solve, the transport or the
    /// baseline's IK).
    pub fn is_divergence(&self) -> bool {
        matches!(
            self,
            Self::NonFinite
                | Self::TipLeftGel { .. }
                | Self::GelBlowUp { .. }
                | Self::NeedleFolded { .. }
                | Self::InvertedElements { .. }
                | Self::Strain { .. }
        )
    }
}

impl fmt::Display for StopReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::NonFinite => write!(f, "diverged: the state became non-finite"),
            Self::TipLeftGel {
                distance_mm,
                limit_mm,
            } => write!(
                f,
                "diverged: the tip is {distance_mm:.0} mm from the gel (limit {limit_mm:.0} mm)"
            ),
            Self::GelBlowUp {
                displacement_mm,
                limit_mm,
            } => write!(
                f,
                "diverged: a gel node moved {displacement_mm:.0} mm, more than the gel's size ({limit_mm:.0} mm)"
            ),
            Self::NeedleFolded {
                chord_mm,
                length_mm,
            } => write!(
                f,
                "diverged: the needle folded (base to tip {chord_mm:.1} mm for a {length_mm:.1} mm needle)"
            ),
            Self::InvertedElements { inverted, elements } => write!(
                f,
                "diverged: {inverted} of {elements} gel elements inverted"
            ),
            Self::Strain { strain, element } => write!(
                f,
                "diverged: gel element {element} strained {:.0} % (limit {:.0} %)",
                strain * 100.0,
                MAX_STRAIN * 100.0
            ),
            Self::StepFailed { message } => write!(f, "{message}"),
            Self::NoCommand { waited_s } => write!(f, "no command for {waited_s:.1} s"),
            Self::IkFailed { message } => write!(f, "{message}"),
            Self::Blocked { steps, seconds, by } => {
                let by = if by.is_empty() {
                    "a clearance row (an obstacle's margin, the bound on the entry point's \
                     shift, or the needle's yield strain)"
                } else {
                    by
                };
                write!(
                    f,
                    "blocked: for {seconds:.1} s ({steps} steps) {by} held the needle, the \
                     target stayed out of reach and the tip did not advance; stopped rather than \
                     push past it"
                )
            }
            Self::Interrupted => write!(f, "stopped by the caller"),
        }
    }
}

/// How long the controller may be held by a clearance margin with its target out of reach
/// before the run stops ([`StopReason::Blocked`]) [s].
pub const BLOCKED_AFTER_S: f64 = 1.0;

/// Share of the scheduled insertion (`advance_per_step` per step) by which the tip's depth must
/// move over [`BLOCKED_AFTER_S`] of held steps for the controller not to count as blocked [-].
/// A tip that slides along an obstacle's margin and keeps advancing (the flags of a held step
/// set at every step, the depth growing at the scheduled rate) is steered, not blocked; a tip
/// held at the margin moves by a few hundredths of a millimetre per step at most.
pub const BLOCKED_MOVE_SHARE: f64 = 0.25;

/// Counts the steps in a row in which a clearance row held the controller and the target was
/// out of reach, and stops the run ([`StopReason::Blocked`]) once they last
/// [`BLOCKED_AFTER_S`] with the tip's depth moved by less than [`BLOCKED_MOVE_SHARE`] of the
/// insertion scheduled over them.
#[derive(Clone, Debug)]
pub struct Blocked {
    run: usize,
    limit: usize,
    dt: f64,
    /// The least depth change over `limit` held steps that counts as moving [mm] (0: the
    /// flags alone decide, for a schedule without a finite positive advance).
    min_move: f64,
    /// The depths after the last `limit + 1` steps, oldest first [mm].
    depths: std::collections::VecDeque<f64>,
    /// What held the last held step ([`StepReport::holding`]).
    holding: Option<ClearanceKind>,
    /// The obstacles' names, in the scene's order.
    names: Vec<String>,
}

impl Blocked {
    /// For a control period `dt` [s] and a target that advances `advance_per_step` [mm] per
    /// step: stops after [`BLOCKED_AFTER_S`] of held steps in which the tip's depth moved by
    /// less than [`BLOCKED_MOVE_SHARE`] of the scheduled insertion.
    pub fn new(dt: f64, advance_per_step: f64) -> Self {
        let limit = (BLOCKED_AFTER_S / dt).ceil();
        let limit = if limit.is_finite() && limit >= 1.0 {
            limit as usize
        } else {
            1
        };
        let min_move = BLOCKED_MOVE_SHARE * advance_per_step * limit as f64;
        Self {
            run: 0,
            limit,
            dt,
            min_move: if min_move.is_finite() && min_move > 0.0 {
                min_move
            } else {
                0.0
            },
            depths: std::collections::VecDeque::with_capacity(limit + 1),
            holding: None,
            names: Vec::new(),
        }
    }

    /// Names the obstacles (in the scene's order) in the reason to stop.
    #[must_use]
    pub fn naming(mut self, obstacles: &[String]) -> Self {
        self.names = obstacles.to_vec();
        self
    }

    /// What a row of `kind` bounds, in words.
    fn describe(&self, kind: ClearanceKind) -> String {
        match kind {
            ClearanceKind::Obstacle(i) => match self.names.get(i) {
                Some(name) => format!("the margin of obstacle `{name}`"),
                None => format!("the margin of obstacle {}", i + 1),
            },
            ClearanceKind::EntryShift => {
                "the bound on the entry point's shift (inverse.max_entry_shift)".to_owned()
            }
            ClearanceKind::Bending(0) => {
                "the needle's yield strain (needle.yield_strain) at the clamp".to_owned()
            }
            ClearanceKind::Bending(node) => format!(
                "the needle's yield strain (needle.yield_strain) at its node {node} from the \
                 clamp"
            ),
        }
    }

    /// After a recorded step: the reason to stop once the run of held steps reaches the limit
    /// with the tip's depth (0 before the puncture) moved by less than the least move over it.
    pub fn after_step(&mut self, r: &StepReport) -> Option<StopReason> {
        if self.depths.len() > self.limit {
            self.depths.pop_front();
        }
        self.depths
            .push_back(if r.inserted { r.depth } else { 0.0 });
        let held = StatusFlags::CLEARANCE_ACTIVE | StatusFlags::TARGET_UNREACHABLE;
        if r.solver.flags & held == held {
            self.run += 1;
            self.holding = r.holding.or(self.holding);
        } else {
            self.run = 0;
            self.holding = None;
        }
        if self.run < self.limit {
            return None;
        }
        // Since the depth before the last `limit` steps, all of them held (since the first
        // step when the run began with the run's first step).
        let moved = match (self.depths.front(), self.depths.back()) {
            (Some(a), Some(b)) => (b - a).abs(),
            _ => 0.0,
        };
        // NaN depths count as not moving: a held run with no usable depth stops as before.
        let moving = self.min_move > 0.0 && moved >= self.min_move;
        (!moving).then(|| StopReason::Blocked {
            steps: self.run,
            seconds: self.run as f64 * self.dt,
            by: self.holding.map(|k| self.describe(k)).unwrap_or_default(),
        })
    }
}

/// The divergence checks of a run of one world (bounds taken from the rest gel and needle).
pub struct Watchdog {
    lo: Vector3<f64>,
    hi: Vector3<f64>,
    reach: f64,
    diagonal: f64,
    needle_length: f64,
    elements: usize,
}

impl Watchdog {
    /// The checks for `world` at rest.
    pub fn new<const N: usize>(world: &World<N>) -> Self {
        let (lo, hi) = world.gel.mesh().bounds();
        let diagonal = (hi - lo).norm();
        Self {
            lo,
            hi,
            reach: world.needle_length.max(diagonal),
            diagonal,
            needle_length: world.needle_length,
            elements: world.gel.tetra().len(),
        }
    }

    /// Distance from `p` to the gel's rest bounding box [mm] (0 inside).
    fn box_distance(&self, p: &Vector3<f64>) -> f64 {
        let out = (self.lo - p).sup(&(p - self.hi)).sup(&Vector3::zeros());
        out.norm()
    }

    /// The cheap checks after every step: finite report, tip near the gel, gel displacement,
    /// needle chord.
    pub fn after_step<const N: usize>(
        &self,
        world: &World<N>,
        r: &StepReport,
    ) -> Option<StopReason> {
        let finite = r.error.is_finite()
            && r.depth.is_finite()
            && r.tip.iter().chain(r.target.iter()).all(|v| v.is_finite())
            && r.q.iter().all(|v| v.is_finite());
        if !finite {
            return Some(StopReason::NonFinite);
        }
        let distance = self.box_distance(&r.tip);
        if distance > self.reach {
            return Some(StopReason::TipLeftGel {
                distance_mm: distance,
                limit_mm: self.reach,
            });
        }
        let rest = &world.gel.mesh().nodes;
        let mut largest = 0.0_f64;
        for (x, x0) in world.gel.positions().iter().zip(rest) {
            let d = (x - x0).norm();
            if !d.is_finite() {
                return Some(StopReason::NonFinite);
            }
            largest = largest.max(d);
        }
        if largest > self.diagonal {
            return Some(StopReason::GelBlowUp {
                displacement_mm: largest,
                limit_mm: self.diagonal,
            });
        }
        let needle = world.needle.positions();
        let chord = (needle[needle.len() - 1] - needle[0]).norm();
        if !chord.is_finite() {
            return Some(StopReason::NonFinite);
        }
        (chord < MIN_CHORD_SHARE * self.needle_length).then_some(StopReason::NeedleFolded {
            chord_mm: chord,
            length_mm: self.needle_length,
        })
    }

    /// The checks of a strain sample: inverted elements and largest strain.
    pub fn strain(&self, st: &StrainStats) -> Option<StopReason> {
        if st.inverted as f64 > MAX_INVERTED_SHARE * self.elements as f64 {
            return Some(StopReason::InvertedElements {
                inverted: st.inverted,
                elements: self.elements,
            });
        }
        (st.max_strain.is_nan() || st.max_strain > MAX_STRAIN).then_some(StopReason::Strain {
            strain: st.max_strain,
            element: st.element,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn report(flags: u32) -> StepReport {
        let mut r = StepReport::default();
        r.solver.flags = flags;
        r
    }

    #[test]
    fn blocked_counts_steps_held_by_a_clearance_with_the_target_out_of_reach() {
        let held = StatusFlags::CLEARANCE_ACTIVE | StatusFlags::TARGET_UNREACHABLE;
        // dt = 0.04 s: 25 steps make the second.
        let mut b = Blocked::new(0.04, 0.1);
        assert!((0..24).all(|_| b.after_step(&report(held)).is_none()));
        // One free step starts the count again.
        assert!(
            b.after_step(&report(StatusFlags::CLEARANCE_ACTIVE))
                .is_none()
        );
        assert!(
            b.after_step(&report(StatusFlags::TARGET_UNREACHABLE))
                .is_none()
        );
        assert!((0..24).all(|_| {
            b.after_step(&report(held | StatusFlags::NEAR_SINGULAR))
                .is_none()
        }));
        let why = b.after_step(&report(held)).expect("blocked");
        assert!(
            matches!(why, StopReason::Blocked { steps: 25, .. }),
            "{why:?}"
        );
        assert!(!why.is_divergence());
        assert!(
            why.to_string().starts_with("blocked: for 1.0 s (25 steps)"),
            "{why}"
        );
        // A nonsensical period still gives a limit of at least one step.
        let mut b = Blocked::new(f64::NAN, 0.1);
        assert!(b.after_step(&report(held)).is_some());
    }

    /// A blocked run says what held it: the row nearest its bound at its held steps
    /// (`StepReport::holding`), an obstacle by its name; the generic words when no step said.
    #[test]
    fn a_blocked_run_names_what_held_it() {
        let held = StatusFlags::CLEARANCE_ACTIVE | StatusFlags::TARGET_UNREACHABLE;
        let names = ["o1".to_owned(), "vessel".to_owned()];
        let stop = |holding: Option<ClearanceKind>| {
            let mut b = Blocked::new(0.04, 0.1).naming(&names);
            let mut r = report(held);
            r.holding = holding;
            (0..25)
                .find_map(|_| b.after_step(&r))
                .expect("blocked")
                .to_string()
        };
        let by = |s: String| s.split(" held the needle").next().unwrap_or("").to_owned();
        assert_eq!(
            by(stop(Some(ClearanceKind::Obstacle(1)))),
            "blocked: for 1.0 s (25 steps) the margin of obstacle `vessel`"
        );
        assert!(
            by(stop(Some(ClearanceKind::Bending(0))))
                .ends_with("(needle.yield_strain) at the clamp")
        );
        assert!(
            by(stop(Some(ClearanceKind::Bending(3)))).ends_with("at its node 3 from the clamp")
        );
        assert!(by(stop(Some(ClearanceKind::EntryShift))).ends_with("(inverse.max_entry_shift)"));
        assert!(by(stop(Some(ClearanceKind::Obstacle(7)))).ends_with("obstacle 8"));
        assert!(by(stop(None)).ends_with("or the needle's yield strain)"));
        // What held the steps of an earlier run of held steps is forgotten with it.
        let mut b = Blocked::new(0.04, 0.1).naming(&names);
        let mut r = report(held);
        r.holding = Some(ClearanceKind::Obstacle(0));
        assert!(b.after_step(&r).is_none());
        assert!(b.after_step(&report(0)).is_none());
        let why = (0..25)
            .find_map(|_| b.after_step(&report(held)))
            .expect("blocked");
        assert!(!why.to_string().contains("o1"), "{why}");
    }

    fn inserted(flags: u32, depth: f64) -> StepReport {
        let mut r = report(flags);
        r.inserted = true;
        r.depth = depth;
        r
    }

    /// `gmsh_box` with `--set inverse.delta_q=0.003` was stopped as blocked at step 460: the
    /// flags of a held step were set for 25 steps while the tip slid along an obstacle's margin
    /// from 27.0 to 30.5 mm deep, 0.05–0.29 mm from its target.
    #[test]
    fn a_tip_advancing_along_an_obstacle_margin_is_not_blocked() {
        let held = StatusFlags::CLEARANCE_ACTIVE | StatusFlags::TARGET_UNREACHABLE;
        // dt = 0.04 s, 0.1 mm per step: 25 held steps, and the least move 0.25 · 2.5 mm.
        let mut b = Blocked::new(0.04, 0.1);
        assert!(b.after_step(&inserted(0, 27.0)).is_none());
        // Advancing at the scheduled rate: never blocked, however long the flags stay set.
        assert!((1..=100).all(|k| {
            b.after_step(&inserted(held, 27.0 + 0.1 * f64::from(k)))
                .is_none()
        }));
        // At a quarter of the rate and more: still moving.
        let mut b = Blocked::new(0.04, 0.1);
        assert!(b.after_step(&inserted(0, 27.0)).is_none());
        assert!((1..=100).all(|k| {
            b.after_step(&inserted(held, 27.0 + 0.0251 * f64::from(k)))
                .is_none()
        }));
        // Then held in place: blocked at once, the last 25 steps having moved 24 · 0.0251 mm
        // (less than 0.625 mm).
        let at = 27.0 + 0.0251 * 100.0;
        let stop = (1..=50)
            .find(|_| b.after_step(&inserted(held, at)).is_some())
            .expect("blocked");
        assert_eq!(stop, 1);
        // A tip creeping at a tenth of the rate is blocked after the 25 steps.
        let mut b = Blocked::new(0.04, 0.1);
        assert!((0..24).all(|k| {
            b.after_step(&inserted(held, 30.0 + 0.01 * f64::from(k)))
                .is_none()
        }));
        let why = b.after_step(&inserted(held, 30.24)).expect("blocked");
        assert!(
            matches!(why, StopReason::Blocked { steps: 25, .. }),
            "{why:?}"
        );
        // Moving back out (a retraction) counts as moving too.
        let mut b = Blocked::new(0.04, 0.1);
        assert!(b.after_step(&inserted(0, 30.0)).is_none());
        assert!((1..=60).all(|k| {
            b.after_step(&inserted(held, 30.0 - 0.1 * f64::from(k)))
                .is_none()
        }));
        // No finite advance: the flags alone decide, as before.
        let mut b = Blocked::new(0.04, 0.0);
        assert!((0..24).all(|k| { b.after_step(&inserted(held, f64::from(k))).is_none() }));
        assert!(b.after_step(&inserted(held, 30.0)).is_some());
    }
}

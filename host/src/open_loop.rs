//! Open loop: a [`Transport`] that answers each frame with a single constraint solve at given
//! joints ([`Controller::solve_open_loop`]) instead of the inverse update — the naive baseline's
//! replay of a precomputed trajectory, and forward simulations driven by hand.

// Units are written in brackets ([mm], [N]) as in the workspace style: not intra-doc links.
#![allow(rustdoc::broken_intra_doc_links)]

use crate::step::ROWS;
use needle_bridge::{ExchangeReport, Transport, TransportError};
use needle_core::inverse::{Controller, InverseParams, StepError};
use needle_core::kinematics::Robot;
use needle_core::payload::{Command, ComplianceFrame};
use std::time::Instant;

/// Answers frame `k` (its `sequence`) with the constraint solve at `joints[k]`.
///
/// # Example
/// ```
/// use needle_host::{open_loop::OpenLoop, scene::Scene, setup::Setup, step::Pipeline};
///
/// let scene = Scene::builtin("simple").unwrap()
///     .with_overrides(&[("gel.box.nodes".into(), "300".into())]).unwrap();
/// let s = Setup::build(&scene).unwrap();
/// let (mut world, params) = (s.world, s.params);
/// // Hold the robot still for two steps: the needle stays where it is.
/// let mut hold = OpenLoop::new(s.robot, s.inverse, vec![world.q; 2]);
/// let mut pipeline = Pipeline::new(&world);
/// let tip = world.tip();
/// for _ in 0..2 {
///     pipeline.step(&mut world, &params, &mut hold).unwrap();
/// }
/// assert!((world.tip() - tip).norm() < 1e-6);
/// // No joints for a third frame: the step fails, it does not guess.
/// assert!(pipeline.step(&mut world, &params, &mut hold).is_err());
/// ```
pub struct OpenLoop<const N: usize = 6> {
    controller: Box<Controller<ROWS, N>>,
    /// The joints of each frame, by sequence [rad].
    pub joints: Vec<[f64; N]>,
}

impl<const N: usize> OpenLoop<N> {
    /// An open loop for `chain` with the solver tuning of `params`, replaying `joints`.
    pub fn new(chain: Robot<N>, params: InverseParams, joints: Vec<[f64; N]>) -> Self {
        Self {
            controller: Controller::new_boxed(chain, params),
            joints,
        }
    }
}

impl<const N: usize> Transport<ROWS, N> for OpenLoop<N> {
    /// # Errors
    /// [`TransportError::Core`]: no joints for the frame's sequence
    /// ([`StepError::InvalidParameter`] `joints`), or the core's rejection of the frame.
    fn exchange(
        &mut self,
        frame: &ComplianceFrame<ROWS, N>,
        cmd: &mut Command<ROWS, N>,
    ) -> Result<ExchangeReport, TransportError> {
        let q = usize::try_from(frame.sequence)
            .ok()
            .and_then(|k| self.joints.get(k))
            .ok_or(StepError::InvalidParameter { name: "joints" })?;
        let t = Instant::now();
        self.controller.solve_open_loop(frame, q, cmd)?;
        Ok(ExchangeReport {
            round_trip: t.elapsed(),
            ..ExchangeReport::default()
        })
    }
}

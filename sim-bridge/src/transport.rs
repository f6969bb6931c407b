//! The one interface between the host's step and the core: hand a frame over, get the command
//! that answers it. The host loop (`needle_host::run`) is the same code whichever way the frame
//! travels:
//!
//! - [`InProcess`]: the core's [`Controller::step`] called directly (tests, reports,
//!   deterministic benches; bit-identical results run to run);
//! - [`crate::shm::SharedMemoryHost`]: the frame is published through iceoryx2 shared memory and
//!   the host waits, lock-step, for the command answering that frame's sequence from a controller
//!   in another process.

use core::fmt;
use core::time::Duration;
use needle_core::inverse::{Controller, InverseParams, StepError};
use needle_core::kinematics::Robot;
use needle_core::payload::{Command, ComplianceFrame, ValidationError};
use std::time::Instant;

/// How one exchange went.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ExchangeReport {
    /// Time from handing the frame over to holding the answer.
    pub round_trip: Duration,
    /// Commands received during this exchange that failed validation (discarded).
    pub rejected_commands: u32,
    /// Commands received that answer another frame or another host session, or hold commands
    /// (discarded).
    pub stale_commands: u32,
}

/// Why an exchange failed.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub enum TransportError {
    /// No command answering the frame arrived within the deadline. The frame stays published;
    /// calling `exchange` again with the same frame publishes it again and keeps waiting.
    Timeout {
        /// How long the exchange waited.
        waited: Duration,
    },
    /// The in-process core rejected the frame or failed.
    Core(StepError),
    /// A payload failed validation before it was sent.
    Invalid(ValidationError),
    /// The other side of the bridge runs a robot of another joint count: the service exists
    /// with the payload of `found` joints, this side's robot has `expected` (refused at connect;
    /// a host and a controller must be started with the same scene).
    JointCount {
        /// The service's name.
        service: String,
        /// Joints of the other side's payload.
        found: usize,
        /// Joints of this side's robot.
        expected: usize,
    },
    /// The shared-memory middleware failed (creating a node, a service or a port, loaning,
    /// sending, receiving).
    Ipc {
        /// What was being done.
        what: &'static str,
        /// iceoryx2's error.
        detail: String,
    },
}

impl fmt::Display for TransportError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Timeout { waited } => write!(
                f,
                "no command answering the frame within {:.1} ms",
                waited.as_secs_f64() * 1e3
            ),
            Self::Core(e) => write!(f, "core: {e}"),
            Self::Invalid(e) => write!(f, "invalid payload: {e}"),
            Self::JointCount {
                service,
                found,
                expected,
            } => write!(
                f,
                "shared memory: the service \"{service}\" carries a robot of {found} joints, this side runs {expected} joints: start `needle serve` and `needle-controller` with the same scene (or another `--instance`)"
            ),
            Self::Ipc { what, detail } => write!(f, "shared memory: {what}: {detail}"),
        }
    }
}

impl std::error::Error for TransportError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Self::Core(e) => Some(e),
            Self::Invalid(e) => Some(e),
            _ => None,
        }
    }
}

impl From<StepError> for TransportError {
    fn from(e: StepError) -> Self {
        Self::Core(e)
    }
}

/// Carries one frame to the core and its command back; frames and commands of `M` rows and `N`
/// joints (6 by default).
///
/// # Example
/// ```
/// use needle_bridge::{InProcess, Transport};
/// use needle_core::inverse::InverseParams;
/// use needle_core::kinematics::DhChain;
/// use needle_core::payload::{Command, ComplianceFrame};
///
/// let mut t = InProcess::<24>::new(DhChain::rv1a(), InverseParams::default());
/// let frame = ComplianceFrame::<24>::new_boxed(); // all zero: fails validation
/// let mut cmd = Command::<24>::new_boxed();
/// assert!(t.exchange(&frame, &mut cmd).is_err());
/// ```
pub trait Transport<const M: usize, const N: usize = 6> {
    /// Hands `frame` to the core and writes the command answering it (same `sequence`, checked
    /// with [`Command::validate`]) into `cmd`.
    ///
    /// # Errors
    /// [`TransportError`]; `cmd` is then unspecified (the host must not apply it).
    fn exchange(
        &mut self,
        frame: &ComplianceFrame<M, N>,
        cmd: &mut Command<M, N>,
    ) -> Result<ExchangeReport, TransportError>;
}

/// The core in the same process: [`Controller::step`] on the caller's frame, no copy; a robot
/// of `N` joints (6 by default).
pub struct InProcess<const M: usize, const N: usize = 6> {
    controller: Box<Controller<M, N>>,
}

impl<const M: usize, const N: usize> InProcess<M, N> {
    /// A core for `chain` with tuning `params` (the controller, ≈ 300 KiB at `M = 192`, is built
    /// in place on the heap).
    pub fn new(robot: impl Into<Robot<N>>, params: InverseParams) -> Self {
        Self {
            controller: Controller::new_boxed(robot, params),
        }
    }

    /// The core's controller (tuning, warm-start state).
    pub fn controller(&mut self) -> &mut Controller<M, N> {
        &mut self.controller
    }
}

impl<const M: usize, const N: usize> Transport<M, N> for InProcess<M, N> {
    fn exchange(
        &mut self,
        frame: &ComplianceFrame<M, N>,
        cmd: &mut Command<M, N>,
    ) -> Result<ExchangeReport, TransportError> {
        let t = Instant::now();
        self.controller.step(frame, cmd)?;
        Ok(ExchangeReport {
            round_trip: t.elapsed(),
            ..ExchangeReport::default()
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use needle_core::kinematics::DhChain;
    use needle_core::synthetic::random_frame;

    /// The in-process transport is exactly the core's step.
    #[test]
    fn in_process_equals_the_core_step() {
        const M: usize = 48;
        let chain = DhChain::rv1a();
        let q = [0.1, 0.3, 2.0, 0.0, 0.5, 0.0];
        let mut f = ComplianceFrame::<M>::new_boxed();
        let mut c1 = Command::<M>::new_boxed();
        let mut c2 = Command::<M>::new_boxed();
        let mut t = InProcess::<M>::new(chain, InverseParams::default());
        let mut core = Controller::<M>::new_boxed(chain, InverseParams::default());
        for seed in 0..3 {
            random_frame(&mut f, &chain, &q, 30, seed, seed == 1);
            f.sequence = seed;
            t.exchange(&f, &mut c1).expect("in process");
            core.step(&f, &mut c2).expect("core");
            assert_eq!(c1.frame_sequence, seed);
            assert_eq!(c1.q.map(f64::to_bits), c2.q.map(f64::to_bits));
            assert_eq!(c1.lambda.map(f64::to_bits), c2.lambda.map(f64::to_bits));
        }
        f.version = 0;
        assert!(matches!(
            t.exchange(&f, &mut c1),
            Err(TransportError::Core(StepError::InvalidFrame(_)))
        ));
    }
}

//! The core's end of the bridge, as a robot controller runs it: a fixed-rate loop (default
//! 1 kHz) that takes the newest frame, checks it, runs the inverse step directly on the
//! shared-memory sample and publishes the command, written in place into a loaned sample.
//!
//! Faults:
//! - **no fresh frame within the deadline** (default 50 ms): the controller *holds* — it
//!   re-commands the last joints every tick (zero joint velocity, [`CommandKind::Hold`]), says
//!   so on stderr, removes the resources of dead nodes (a killed host), and resumes as soon as a
//!   host (the same one, or a restarted one with a new session) publishes again;
//! - **a frame failing validation** (version, `m` above the capacity, non-finite values, group
//!   table, …), **a sequence going backwards within a session**, **another joint count** (the
//!   frame header's) or **another robot set-up** (fingerprint): the frame is rejected, counted
//!   in [`ControllerStats`], never used;
//! - **the same frame again** (a host that timed out republishes it): the cached answer is sent
//!   again, the core does not step twice.
//!
//! Pacing: with `rate_hz > 0` the loop ticks at that rate and each tick solves over the newest
//! frame (free-running: frames published faster than the rate are skipped, counted); with
//! `rate_hz = 0` it polls ([`crate::shm::Wait`]) and answers every frame as soon as it arrives
//! (lock-step with a host that waits).

use crate::payload::{CommandHeader, CommandKind, FrameHeader, setup_fingerprint};
use crate::plausible::{Implausible, Plausibility};
use crate::shm::{
    BridgeConfig, CommandPublisher, FrameSubscriber, Ipc, cleanup_dead_nodes,
    command_service_counting, create_node_cleaning, frame_service_counting, ipc_err,
    loan_initialised, pause,
};
use crate::transport::TransportError;
use core::fmt;
use core::time::Duration;
use iceoryx2::node::NodeWaitFailure;
use iceoryx2::prelude::*;
use needle_core::inverse::{Controller, InverseParams};
use needle_core::kinematics::Robot;
use needle_core::payload::{Command, ComplianceFrame, ValidationError};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

/// Options of the controller loop.
#[derive(Clone, Debug, PartialEq)]
pub struct ControllerOptions {
    /// Services, deadline (no fresh frame for this long ⇒ hold), polling.
    pub bridge: BridgeConfig,
    /// Loop rate in Hz (default 1000); 0: poll and answer every frame at once.
    pub rate_hz: f64,
    /// Stop after this long (none: until stopped or interrupted).
    pub run_for: Option<Duration>,
    /// Stop once this many frames have been solved (none: no limit).
    pub max_frames: Option<u64>,
    /// Print events (hold, resume, new session, rejections) on stderr.
    pub verbose: bool,
}

impl Default for ControllerOptions {
    fn default() -> Self {
        Self {
            bridge: BridgeConfig::default(),
            rate_hz: 1000.0,
            run_for: None,
            max_frames: None,
            verbose: true,
        }
    }
}

/// Why a frame was rejected.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub enum Rejection {
    /// The frame failed [`ComplianceFrame::validate`].
    Invalid(ValidationError),
    /// Its sequence is below the last one accepted from the same host session.
    SequenceBackwards {
        /// Sequence received.
        found: u64,
        /// Last sequence accepted.
        last: u64,
    },
    /// Its sequence jumps ahead of the next one expected from the host session (a host steps
    /// one at a time): a forged frame, never allowed to move the expected sequence.
    SequenceJump {
        /// Sequence received.
        found: u64,
        /// Last sequence accepted.
        last: u64,
    },
    /// It comes from another host session while the one followed is alive (a stale or forged
    /// host); the controller follows a new session only once the old one fell silent.
    OtherSession {
        /// The frame's session.
        found: u64,
        /// The session followed.
        followed: u64,
    },
    /// Its numbers are physically implausible for this set-up ([`Implausible`]).
    Implausible(Implausible),
    /// It was built for a robot of another joint count (the frame header's `joints`).
    JointCount {
        /// The frame's joint count.
        found: u32,
        /// This controller's.
        expected: u32,
    },
    /// It was built for another robot or tuning (setup fingerprint).
    SetupMismatch {
        /// The frame's fingerprint.
        found: u64,
        /// This controller's.
        expected: u64,
    },
}

impl fmt::Display for Rejection {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Invalid(e) => write!(f, "invalid frame: {e}"),
            Self::SequenceBackwards { found, last } => {
                write!(f, "sequence {found} after {last}: going backwards")
            }
            Self::SequenceJump { found, last } => {
                write!(f, "sequence {found} after {last}: jumping ahead")
            }
            Self::OtherSession { found, followed } => write!(
                f,
                "frame of host session {found:016x} while following {followed:016x}"
            ),
            Self::Implausible(why) => write!(f, "implausible frame: {why}"),
            Self::JointCount { found, expected } => write!(
                f,
                "frame built for a robot of {found} joints; this controller runs {expected} joints (start it with the host's scene)"
            ),
            Self::SetupMismatch { found, expected } => write!(
                f,
                "frame built for another robot set-up (fingerprint {found:016x}, expected {expected:016x})"
            ),
        }
    }
}

/// Counters of a controller run (printed at the end by `needle-controller`).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ControllerStats {
    /// Frame samples received.
    pub frames_received: u64,
    /// Frames the core stepped on (one command each).
    pub frames_solved: u64,
    /// Frames rejected (invalid, sequence backwards, set-up mismatch): never used.
    pub frames_rejected: u64,
    /// Of which failed validation.
    pub rejected_invalid: u64,
    /// Of which had a sequence going backwards.
    pub rejected_sequence: u64,
    /// Of which came from another set-up (another robot, joint count or tuning).
    pub rejected_setup: u64,
    /// Of which came from another host session while the followed one was alive.
    pub rejected_session: u64,
    /// Of which were physically implausible.
    pub rejected_implausible: u64,
    /// Valid frames superseded by a newer one before a tick could solve them.
    pub frames_skipped: u64,
    /// Repeated frames answered again from the cache.
    pub answers_repeated: u64,
    /// Inverse steps that failed (no command sent).
    pub step_errors: u64,
    /// Commands sent (answers, repeats and holds).
    pub commands_sent: u64,
    /// Times the controller started holding (deadline missed).
    pub hold_events: u64,
    /// Hold commands sent.
    pub hold_commands: u64,
    /// Host sessions seen (1 + restarts).
    pub sessions: u64,
    /// Dead nodes whose resources were removed.
    pub dead_nodes_cleaned: u64,
    /// Services left half-created by a killed process, removed and created again at start.
    pub hung_services_removed: u64,
    /// The last rejection.
    pub last_rejection: Option<Rejection>,
}

impl fmt::Display for ControllerStats {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "frames received {}, solved {}, rejected {} (invalid {}, sequence {}, set-up {}, other session {}, implausible {}), skipped {}, repeated answers {}, step errors {}; commands sent {} (holds {} in {} hold events); host sessions {}; dead nodes cleaned {}, hung services removed {}",
            self.frames_received,
            self.frames_solved,
            self.frames_rejected,
            self.rejected_invalid,
            self.rejected_sequence,
            self.rejected_setup,
            self.rejected_session,
            self.rejected_implausible,
            self.frames_skipped,
            self.answers_repeated,
            self.step_errors,
            self.commands_sent,
            self.hold_commands,
            self.hold_events,
            self.sessions,
            self.dead_nodes_cleaned,
            self.hung_services_removed
        )
    }
}

/// A frame that passed every check, with what the loop needs to know about it.
enum Verdict {
    /// With the frame's base compliance scale ([`Plausibility::check`]).
    Fresh(f64),
    Repeat,
    Reject(Rejection),
}

/// The controller process's state (ports, core, counters); a robot of `N` joints (6 by
/// default, or 7).
pub struct ControllerNode<const M: usize, const N: usize = 6> {
    node: Node<Ipc>,
    frames: FrameSubscriber<M, N>,
    commands: CommandPublisher<M, N>,
    core: Box<Controller<M, N>>,
    setup: u64,
    opts: ControllerOptions,
    session: Option<u64>,
    plausibility: Plausibility,
    last_sequence: u64,
    last_answer: Box<Command<M, N>>,
    have_answer: bool,
    last_q: Option<[f64; N]>,
    last_frame_at: Instant,
    holding: bool,
    last_cleanup: Instant,
    stats: ControllerStats,
}

fn dbg<E: fmt::Debug>(e: E) -> String {
    format!("{e:?}")
}

impl<const M: usize, const N: usize> ControllerNode<M, N> {
    /// Connects a controller for `chain` and `params` (the same the host uses: the frames carry
    /// their [`setup_fingerprint`] and joint count), cleaning the resources of dead nodes first.
    ///
    /// # Errors
    /// [`TransportError::JointCount`] when a host of another joint count holds the services;
    /// [`TransportError::Ipc`] when a node, service or port cannot be created.
    pub fn connect(
        chain: impl Into<Robot<N>>,
        params: InverseParams,
        opts: &ControllerOptions,
    ) -> Result<Self, TransportError> {
        let chain: Robot<N> = chain.into();
        let (node, dead) = create_node_cleaning("needle-controller", &opts.bridge)?;
        let mut hung = 0;
        let frames = frame_service_counting::<M, N>(&node, &opts.bridge, &mut hung)?
            .subscriber_builder()
            .create()
            .map_err(dbg)
            .map_err(ipc_err("create frame subscriber"))?;
        let commands = command_service_counting::<M, N>(&node, &opts.bridge, &mut hung)?
            .publisher_builder()
            .create()
            .map_err(dbg)
            .map_err(ipc_err("create command publisher"))?;
        let core = Controller::new_boxed(chain, params);
        let last_answer = Command::new_boxed();
        Ok(Self {
            node,
            frames,
            commands,
            core,
            setup: setup_fingerprint(&chain, &params),
            opts: opts.clone(),
            session: None,
            plausibility: Plausibility::default(),
            last_sequence: 0,
            last_answer,
            have_answer: false,
            last_q: None,
            last_frame_at: Instant::now(),
            holding: false,
            last_cleanup: Instant::now(),
            stats: ControllerStats {
                dead_nodes_cleaned: dead,
                hung_services_removed: hung,
                ..ControllerStats::default()
            },
        })
    }

    /// The counters so far.
    pub fn stats(&self) -> ControllerStats {
        self.stats
    }

    /// Whether the controller is holding the robot (no fresh frame within the deadline).
    pub fn holding(&self) -> bool {
        self.holding
    }

    /// A line of the controller's log (`tracing`, level info; nothing unless `verbose`).
    fn log(&self, msg: core::fmt::Arguments<'_>) {
        if self.opts.verbose {
            tracing::info!(target: "needle_controller", "{msg}");
        }
    }

    /// The verdict on a received frame: joint count, set-up, session, sequence, validity,
    /// plausibility.
    fn judge(&self, h: &FrameHeader, f: &ComplianceFrame<M, N>) -> Verdict {
        if h.joints as usize != N {
            return Verdict::Reject(Rejection::JointCount {
                found: h.joints,
                expected: N as u32,
            });
        }
        if h.setup != self.setup {
            return Verdict::Reject(Rejection::SetupMismatch {
                found: h.setup,
                expected: self.setup,
            });
        }
        let same = self.session == Some(h.session);
        match self.session {
            Some(_) if same => {
                let last = self.last_sequence;
                if f.sequence < last {
                    return Verdict::Reject(Rejection::SequenceBackwards {
                        found: f.sequence,
                        last,
                    });
                }
                if f.sequence == last && self.have_answer {
                    return Verdict::Repeat;
                }
                // A host steps one at a time (and repeats a frame it got no answer to).
                if f.sequence > last.saturating_add(1) {
                    return Verdict::Reject(Rejection::SequenceJump {
                        found: f.sequence,
                        last,
                    });
                }
            }
            // Another session while the followed host is alive: not followed.
            Some(followed) if !self.holding => {
                return Verdict::Reject(Rejection::OtherSession {
                    found: h.session,
                    followed,
                });
            }
            _ => {}
        }
        if let Err(e) = f.validate() {
            return Verdict::Reject(Rejection::Invalid(e));
        }
        let checks = if same {
            self.plausibility
        } else {
            Plausibility::default()
        };
        match checks.check(f) {
            Ok(scale) => Verdict::Fresh(scale),
            Err(e) => Verdict::Reject(Rejection::Implausible(e)),
        }
    }

    /// Counts a rejected frame and drops the warm start (the next solve must not start from
    /// anything a bad frame may have touched).
    fn reject(&mut self, r: Rejection) {
        self.stats.frames_rejected += 1;
        match r {
            Rejection::Invalid(_) => self.stats.rejected_invalid += 1,
            Rejection::SequenceBackwards { .. } | Rejection::SequenceJump { .. } => {
                self.stats.rejected_sequence += 1;
            }
            Rejection::SetupMismatch { .. } | Rejection::JointCount { .. } => {
                self.stats.rejected_setup += 1;
            }
            Rejection::OtherSession { .. } => self.stats.rejected_session += 1,
            Rejection::Implausible(_) => self.stats.rejected_implausible += 1,
        }
        self.stats.last_rejection = Some(r);
        self.core.reset_warm_start();
        self.log(format_args!(
            "frame rejected ({} so far): {r}",
            self.stats.frames_rejected
        ));
    }

    /// Sends a command written in place by `fill`.
    fn send(
        &mut self,
        kind: CommandKind,
        session: u64,
        fill: impl FnOnce(&mut Command<M, N>),
    ) -> Result<(), TransportError> {
        let header = CommandHeader {
            session,
            kind: kind as u32,
            reserved: 0,
        };
        let mut sample = loan_initialised(&self.commands, header, "loan command")?;
        fill(&mut sample.payload_mut().0);
        sample
            .send()
            .map_err(dbg)
            .map_err(ipc_err("send command"))?;
        self.stats.commands_sent += 1;
        Ok(())
    }

    /// One tick: takes every frame received since the last tick, answers the newest fresh one
    /// (or repeats an answer), or holds when the deadline has passed. Returns whether a frame
    /// was solved.
    ///
    /// # Errors
    /// [`TransportError::Ipc`] when receiving or sending fails.
    pub fn tick(&mut self) -> Result<bool, TransportError> {
        let mut newest = None;
        while let Some(sample) = self
            .frames
            .receive()
            .map_err(dbg)
            .map_err(ipc_err("receive frame"))?
        {
            self.stats.frames_received += 1;
            let h = *sample.user_header();
            match self.judge(&h, &sample.payload().0) {
                Verdict::Reject(r) => self.reject(r),
                Verdict::Repeat => {
                    self.last_frame_at = Instant::now();
                    let answer = *self.last_answer;
                    self.send(CommandKind::Answer, h.session, |c| *c = answer)?;
                    self.stats.answers_repeated += 1;
                }
                Verdict::Fresh(scale) => {
                    if newest.is_some() {
                        self.stats.frames_skipped += 1;
                    }
                    newest = Some((sample, scale));
                }
            }
        }
        let Some((sample, scale)) = newest else {
            self.check_deadline()?;
            return Ok(false);
        };
        let h = *sample.user_header();
        let frame = &sample.payload().0;
        if self.session != Some(h.session) {
            self.session = Some(h.session);
            self.stats.sessions += 1;
            self.plausibility.reset();
            self.core.reset_warm_start();
            self.log(format_args!(
                "host session {:016x}: first frame (sequence {})",
                h.session, frame.sequence
            ));
        }
        self.plausibility.accept(scale);
        self.last_sequence = frame.sequence;
        self.have_answer = false;
        self.last_frame_at = Instant::now();
        if self.holding {
            self.holding = false;
            self.log(format_args!("fresh frame {}: resuming", frame.sequence));
        }
        let header = CommandHeader {
            session: h.session,
            kind: CommandKind::Answer as u32,
            reserved: 0,
        };
        let mut sample_out = loan_initialised(&self.commands, header, "loan command")?;
        let cmd = &mut sample_out.payload_mut().0;
        match self.core.step(frame, cmd) {
            Ok(_) => {
                *self.last_answer = *cmd;
                sample_out
                    .send()
                    .map_err(dbg)
                    .map_err(ipc_err("send command"))?;
                self.stats.commands_sent += 1;
                self.have_answer = true;
                self.last_q = Some(self.last_answer.q);
                self.stats.frames_solved += 1;
                Ok(true)
            }
            Err(e) => {
                // Nothing is sent (the loaned sample returns to the pool): the host times out
                // and holds, which is what it must do without a valid answer.
                self.stats.step_errors += 1;
                self.core.reset_warm_start();
                self.log(format_args!(
                    "inverse step failed on frame {}: {e}",
                    frame.sequence
                ));
                Ok(false)
            }
        }
    }

    fn check_deadline(&mut self) -> Result<(), TransportError> {
        let Some(session) = self.session else {
            return Ok(());
        };
        let silent = self.last_frame_at.elapsed();
        if silent < self.opts.bridge.deadline {
            return Ok(());
        }
        if !self.holding {
            self.holding = true;
            self.stats.hold_events += 1;
            self.log(format_args!(
                "no fresh frame for {:.0} ms (deadline {:.0} ms): holding the robot at q = {} rad",
                silent.as_secs_f64() * 1e3,
                self.opts.bridge.deadline.as_secs_f64() * 1e3,
                match self.last_q {
                    Some(q) => format!("{q:.5?}"),
                    None => "(no command yet)".into(),
                }
            ));
            self.cleanup();
        } else if self.last_cleanup.elapsed() > Duration::from_secs(1) {
            self.cleanup();
        }
        if let Some(q) = self.last_q {
            let seq = self.last_sequence;
            self.send(CommandKind::Hold, session, |c| {
                c.q = q;
                c.frame_sequence = seq;
            })?;
            self.stats.hold_commands += 1;
        }
        Ok(())
    }

    fn cleanup(&mut self) {
        self.last_cleanup = Instant::now();
        let n = cleanup_dead_nodes(&self.node);
        if n > 0 {
            self.stats.dead_nodes_cleaned += n;
            self.log(format_args!(
                "removed the stale resources of {n} dead node(s)"
            ));
        }
    }

    /// Runs the loop until `stop` is set, a termination signal arrives (with
    /// `handle_signals`), `run_for` has passed or `max_frames` frames were solved.
    ///
    /// # Errors
    /// [`TransportError::Ipc`] when receiving or sending fails.
    pub fn run(&mut self, stop: &AtomicBool) -> Result<ControllerStats, TransportError> {
        let start = Instant::now();
        let period =
            (self.opts.rate_hz > 0.0).then(|| Duration::from_secs_f64(1.0 / self.opts.rate_hz));
        let mut next = Instant::now();
        loop {
            if stop.load(Ordering::Relaxed)
                || self.opts.run_for.is_some_and(|d| start.elapsed() >= d)
                || self
                    .opts
                    .max_frames
                    .is_some_and(|n| self.stats.frames_solved >= n)
            {
                return Ok(self.stats);
            }
            self.tick()?;
            let waited = match period {
                Some(p) => {
                    next += p;
                    let now = Instant::now();
                    if next > now {
                        // `Interrupt` (SIGCONT after a SIGSTOP, …) is not a termination request.
                        match self.node.wait(next - now) {
                            Ok(()) | Err(NodeWaitFailure::Interrupt) => Ok(()),
                            Err(e) => Err(dbg(e)),
                        }
                    } else {
                        // Overran the tick: restart the schedule from now.
                        next = now;
                        Ok(())
                    }
                }
                None => pause(&self.node, self.opts.bridge.wait).map_err(|e| e.to_string()),
            };
            if waited.is_err() {
                self.log(format_args!("termination requested"));
                return Ok(self.stats);
            }
        }
    }
}

/// Connects and runs a controller (see [`ControllerNode::run`]).
///
/// # Errors
/// As [`ControllerNode::connect`] and [`ControllerNode::run`].
pub fn run_controller<const M: usize, const N: usize>(
    chain: impl Into<Robot<N>>,
    params: InverseParams,
    opts: &ControllerOptions,
    stop: &AtomicBool,
) -> Result<ControllerStats, TransportError> {
    let mut node = ControllerNode::<M, N>::connect(chain, params, opts)?;
    node.run(stop)
}

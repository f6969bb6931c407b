//! Pacing and holding for a core reached through a transport that can be late (another
//! process): a free-running host starts a step at most every period; when no command arrives
//! within the transport's deadline the host *holds the insertion* — applies nothing, does not
//! advance the target, says so on stderr, and hands the same frame over again until an answer
//! arrives or the give-up time has passed.

use super::StopReason;
use crate::error::{SimError, chain};
use crate::step::ROWS;
use needle_bridge::{ExchangeReport, Transport, TransportError};
use needle_core::payload::{Command, ComplianceFrame};
use std::time::{Duration, Instant};

/// A transport wrapped with pacing and holding.
pub struct Remote<'a, const N: usize = 6> {
    inner: &'a mut dyn Transport<ROWS, N>,
    period: Option<Duration>,
    next_start: Instant,
    give_up_after: Option<Duration>,
    /// The target of the last applied step, for the messages [mm].
    c: f64,
    /// Times the host held the insertion.
    pub holds: usize,
    /// Total time held.
    pub held: Duration,
    /// How long the last exchange waited before giving up (it returned a timeout).
    pub gave_up: Option<Duration>,
    /// Free-running: steps that started after their slot because the step before them took
    /// longer than the period, and the largest such delay.
    pub overruns: (usize, Duration),
    /// Whether a step was paced already (the first one has no slot to miss).
    paced: bool,
}

impl<'a, const N: usize> Remote<'a, N> {
    /// Wraps `inner`: a step at most every `period` (none: lock-step), give up after
    /// `give_up_after` without a command (none: hold for ever).
    pub fn new(
        inner: &'a mut dyn Transport<ROWS, N>,
        period: Option<Duration>,
        give_up_after: Option<Duration>,
    ) -> Self {
        Self {
            inner,
            period,
            next_start: Instant::now(),
            give_up_after,
            c: 0.0,
            holds: 0,
            held: Duration::ZERO,
            gave_up: None,
            overruns: (0, Duration::ZERO),
            paced: false,
        }
    }

    /// Before a step from target `c` [mm]: waits until the step may start; a step that can
    /// only start after its slot (the one before it overran the period) is counted.
    pub fn pace(&mut self, c: f64) {
        self.c = c;
        if let Some(p) = self.period {
            let now = Instant::now();
            if self.next_start > now {
                std::thread::sleep(self.next_start - now);
            } else if self.paced {
                let late = now - self.next_start;
                self.overruns = (self.overruns.0 + 1, self.overruns.1.max(late));
            }
            self.paced = true;
            self.next_start = self.next_start.max(now) + p;
        }
    }
}

impl<const N: usize> Remote<'_, N> {
    /// Why a step failed with `e`, as the run's summary says it.
    pub fn why_stopped(&self, e: &SimError) -> StopReason {
        match self.gave_up {
            Some(w) => StopReason::NoCommand {
                waited_s: w.as_secs_f64(),
            },
            None => StopReason::StepFailed { message: chain(e) },
        }
    }
}

impl<const N: usize> Transport<ROWS, N> for Remote<'_, N> {
    fn exchange(
        &mut self,
        frame: &ComplianceFrame<ROWS, N>,
        cmd: &mut Command<ROWS, N>,
    ) -> Result<ExchangeReport, TransportError> {
        let (start, k) = (Instant::now(), frame.sequence);
        let mut holding = false;
        loop {
            match self.inner.exchange(frame, cmd) {
                Ok(r) => {
                    if holding {
                        let h = start.elapsed();
                        self.held += h;
                        tracing::warn!(
                            "command received after {:.0} ms: resuming at step {k}",
                            h.as_secs_f64() * 1e3
                        );
                    }
                    return Ok(r);
                }
                Err(TransportError::Timeout { waited }) => {
                    if !holding {
                        holding = true;
                        self.holds += 1;
                        tracing::warn!(
                            "no command within {:.0} ms: holding the insertion at step {k} (c = {:.2} mm)",
                            waited.as_secs_f64() * 1e3,
                            self.c
                        );
                    }
                    if let Some(limit) = self.give_up_after
                        && start.elapsed() >= limit
                    {
                        let waited = start.elapsed();
                        self.held += waited;
                        self.gave_up = Some(waited);
                        return Err(TransportError::Timeout { waited });
                    }
                }
                Err(e) => return Err(e),
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A transport never reached by pacing.
    struct Unused;

    impl Transport<ROWS, 6> for Unused {
        fn exchange(
            &mut self,
            _: &ComplianceFrame<ROWS, 6>,
            _: &mut Command<ROWS, 6>,
        ) -> Result<ExchangeReport, TransportError> {
            Err(TransportError::Timeout {
                waited: Duration::ZERO,
            })
        }
    }

    /// A step that takes longer than the period makes the next one start late: counted, with
    /// how late. The first step has no slot to miss; a step within its period is not counted.
    #[test]
    fn a_step_longer_than_the_period_is_counted_as_an_overrun() {
        let mut inner = Unused;
        let period = Duration::from_millis(200);
        let mut remote = Remote::<6>::new(&mut inner, Some(period), None);
        std::thread::sleep(Duration::from_millis(30));
        remote.pace(0.0);
        assert_eq!(remote.overruns.0, 0, "the first step");
        remote.pace(0.1);
        assert_eq!(
            remote.overruns.0, 0,
            "a step within its period waits for its slot"
        );
        // This step takes 400 ms: the next starts about 200 ms after its slot.
        std::thread::sleep(Duration::from_millis(400));
        remote.pace(0.2);
        assert_eq!(remote.overruns.0, 1);
        assert!(
            remote.overruns.1 >= Duration::from_millis(150),
            "{:?}",
            remote.overruns.1
        );
        // Lock-step (no period): nothing to overrun.
        let mut inner = Unused;
        let mut lock_step = Remote::<6>::new(&mut inner, None, None);
        lock_step.pace(0.0);
        std::thread::sleep(Duration::from_millis(5));
        lock_step.pace(0.1);
        assert_eq!(lock_step.overruns.0, 0);
    }
}

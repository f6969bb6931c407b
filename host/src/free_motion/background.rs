//! Background factorisation: the gel's numeric Cholesky on a second thread, one job in flight at
//! most, and the guard that factorises at once when the elements rotated too far since the
//! matrix in use (see the module docs of [`crate::free_motion`]).

use crate::fem::FemError;
use crate::fem::tetra::{largest_rotation_between, largest_rotation_where};
use crate::linalg::{Cholesky, LinalgError, Precision, SymmetricMatrix, SymmetricPattern};
use nalgebra::Matrix3;
use std::sync::mpsc::{Receiver, SyncSender, TryRecvError, sync_channel};

/// Background factorisation: the largest rotation of an element [rad] between the matrix of the
/// factor in use and the current positions for which that factor is used; above it the step
/// factorises its own matrix at once. The tangent `R K0 Rᵀ` changes only through the rotations,
/// by about `2θ` relative, and a Newton step with a matrix off by ε contracts by about ε.
pub const LAG_ROTATION_LIMIT: f64 = 0.2;

/// Adaptive refresh of the background pipeline: a step sends its matrix to the idle worker
/// only when the factor in use has gone stale — an element rotated by `rotation` or more since
/// the factor's matrix was assembled, or that matrix is `ceiling` steps old. Without it, a
/// step sends its matrix whenever the worker is idle (every `refactor_every` steps).
///
/// The tangent `R K0 Rᵀ` changes only through the element rotations, so a factor whose
/// elements have not rotated is still the Newton matrix: no factorisation is spent on it.
/// Consecutive factors' matrices are between `refactor_every` (the pipeline's depth, the floor)
/// and `ceiling` steps apart; a job in flight is still waited for `refactor_every` steps after
/// its matrix, so runs repeat bit for bit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RefreshParams {
    /// Refresh when an element has rotated by this much or more since the matrix in use [rad].
    pub rotation: f64,
    /// With a near block ([`super::GelParams::near_nodes`]): `rotation` for the elements not
    /// all of whose nodes are near (the near ones refresh the block at `rotation`); without
    /// one, unused.
    pub far_rotation: f64,
    /// Refresh at the latest when the matrix in use is this many steps old.
    pub ceiling: usize,
}

/// What the start of a step found of the background factorisation.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(super) enum Adopted {
    /// A new factor is in use.
    Yes,
    /// No job was due.
    #[default]
    Idle,
    /// The job failed (not positive definite); its result was dropped.
    Failed,
}

/// What a step's free motion did with the factors (background mode).
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct FactorEvent {
    /// What the start of the step found of the job in flight.
    pub adopted: Adopted,
    /// The step factorised its own matrix at once.
    pub immediate: bool,
    /// The step's matrix was sent to the worker.
    pub submitted: bool,
}

/// A matrix to factorise and the factor buffer to do it in, passed to the worker and back.
pub(super) struct Job {
    pub chol: Cholesky,
    pub matrix: SymmetricMatrix,
    result: Result<(), LinalgError>,
}

impl Job {
    /// Whether the worker's factorisation succeeded.
    pub fn succeeded(&self) -> bool {
        self.result.is_ok()
    }
}

/// The background factorisation thread of a reduced system: one job in flight at most.
pub(super) struct Background {
    jobs: SyncSender<Box<Job>>,
    done: Receiver<Box<Job>>,
    /// The job buffer while no job is in flight.
    pub spare: Option<Box<Job>>,
    /// This step's matrix, written while the previous one is being factorised.
    pub staged: SymmetricMatrix,
    /// Factorisations finished in the background and used.
    pub adopted: u64,
    /// Factorisations made at once instead.
    pub immediate: u64,
    /// Steps since the job in flight was sent.
    pub in_flight_steps: usize,
    /// The precision fallbacks of the job in flight's factor when it was sent.
    sent_fallbacks: u64,
    /// The job in flight, received finished by [`Self::is_finished`] and not yet taken.
    finished: Option<Box<Job>>,
}

impl std::fmt::Debug for Background {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Background")
            .field("in_flight", &self.spare.is_none())
            .field("adopted", &self.adopted)
            .finish()
    }
}

impl Background {
    /// Starts the worker with a second factor buffer for `pattern` (same ordering and
    /// precision).
    ///
    /// # Errors
    /// The symbolic factorisation of the second buffer, or [`FemError::WorkerSpawn`].
    pub fn start(
        pattern: &SymmetricPattern,
        order: Option<&[usize]>,
        precision: Precision,
    ) -> Result<Self, FemError> {
        let chol = Cholesky::try_new_with_precision(pattern, order, 1, precision)?;
        let (jobs, inbox) = sync_channel::<Box<Job>>(1);
        let (outbox, done) = sync_channel::<Box<Job>>(1);
        std::thread::Builder::new()
            .name("needle-factor".into())
            .spawn(move || {
                // Ends when the system (the sender) is dropped.
                while let Ok(mut job) = inbox.recv() {
                    let Job { chol, matrix, .. } = &mut *job;
                    job.result = chol.factorize(matrix);
                    if outbox.send(job).is_err() {
                        return;
                    }
                }
            })
            .map_err(FemError::WorkerSpawn)?;
        Ok(Self {
            jobs,
            done,
            spare: Some(Box::new(Job {
                chol,
                matrix: SymmetricMatrix::zeros(pattern.clone()),
                result: Ok(()),
            })),
            staged: SymmetricMatrix::zeros(pattern.clone()),
            adopted: 0,
            immediate: 0,
            in_flight_steps: 0,
            sent_fallbacks: 0,
            finished: None,
        })
    }

    /// Precision fallbacks of the worker's factor buffer (as of its last return, while a job
    /// is in flight).
    pub fn precision_fallbacks(&self) -> u64 {
        match &self.spare {
            Some(job) => job.chol.precision_fallbacks(),
            None => self.sent_fallbacks,
        }
    }

    /// Waits for the job in flight, if any, and returns it.
    ///
    /// # Errors
    /// [`FemError::WorkerStopped`] if the worker is gone.
    pub fn finish(&mut self) -> Result<Option<Box<Job>>, FemError> {
        if self.spare.is_some() {
            return Ok(None);
        }
        if let Some(job) = self.finished.take() {
            return Ok(Some(job));
        }
        self.done
            .recv()
            .map(Some)
            .map_err(|_| FemError::WorkerStopped)
    }

    /// The job in flight if it is finished, without waiting.
    ///
    /// # Errors
    /// [`FemError::WorkerStopped`] if the worker is gone.
    pub fn poll(&mut self) -> Result<Option<Box<Job>>, FemError> {
        if self.spare.is_some() {
            return Ok(None);
        }
        if let Some(job) = self.finished.take() {
            return Ok(Some(job));
        }
        match self.done.try_recv() {
            Ok(job) => Ok(Some(job)),
            Err(TryRecvError::Empty) => Ok(None),
            Err(TryRecvError::Disconnected) => Err(FemError::WorkerStopped),
        }
    }

    /// Whether the job in flight has finished, without waiting (it is kept for
    /// [`Self::finish`] or [`Self::poll`]); `false` when no job is in flight.
    ///
    /// # Errors
    /// [`FemError::WorkerStopped`] if the worker is gone.
    pub fn is_finished(&mut self) -> Result<bool, FemError> {
        if self.finished.is_none() {
            self.finished = self.poll()?;
        }
        Ok(self.finished.is_some())
    }

    /// Sends `job` to the worker.
    ///
    /// # Errors
    /// [`FemError::WorkerStopped`] if the worker is gone.
    pub fn send(&mut self, job: Box<Job>) -> Result<(), FemError> {
        self.in_flight_steps = 0;
        self.sent_fallbacks = job.chol.precision_fallbacks();
        self.jobs.send(job).map_err(|_| FemError::WorkerStopped)
    }
}

/// The rotation guard of the background factorisation: the element rotations of the matrix of
/// the factor in use and of the matrix being factorised, and the last measured lag.
#[derive(Debug)]
pub(super) struct LagGuard {
    in_use: Vec<Matrix3<f64>>,
    sent: Vec<Matrix3<f64>>,
    /// Largest rotation of an element between the matrix of the factor in use and the current
    /// positions [rad] (0 after a factorisation at once); with a near block, of the elements
    /// not all of whose nodes are near.
    pub lag: f64,
    /// The elements whose nodes are all in the factor's near block (empty: no block). Their
    /// rotations are measured apart ([`LagGuard::near_lag`]): the block is refactorised on its
    /// own.
    near: Vec<bool>,
    /// The indices of those elements.
    near_list: Vec<usize>,
    /// With a near block: the element rotations of the matrix of the last full factorisation
    /// in use (`in_use` but for the near block's refreshes); empty without a block.
    full: Vec<Matrix3<f64>>,
    /// The near elements all of whose nodes are in the entry block (empty: none), measured
    /// apart from the other near ones ([`LagGuard::entry_lag`]).
    entry: Vec<bool>,
    /// The indices of those elements.
    entry_list: Vec<usize>,
}

impl LagGuard {
    /// A guard for `elements` elements at rest; `near` marks the elements of the near block
    /// (empty: none), `entry` those of the entry block inside it (empty: none; ignored
    /// without `near`).
    pub fn new(elements: usize, near: Vec<bool>, entry: Vec<bool>) -> Self {
        let near_list = (0..near.len()).filter(|&e| near[e]).collect();
        let full = if near.is_empty() {
            Vec::new()
        } else {
            vec![Matrix3::identity(); elements]
        };
        let entry = if near.is_empty() || entry.len() != near.len() {
            Vec::new()
        } else {
            entry
        };
        let entry_list: Vec<usize> = (0..entry.len()).filter(|&e| entry[e]).collect();
        Self {
            in_use: vec![Matrix3::identity(); elements],
            sent: vec![Matrix3::identity(); elements],
            lag: 0.0,
            near,
            near_list,
            full,
            entry,
            entry_list,
        }
    }

    /// Whether element `e` is in the entry block.
    fn is_entry(&self, e: usize) -> bool {
        self.entry.get(e).copied().unwrap_or(false)
    }

    /// The entry block's elements and the rotations of the factor's matrix: an entry refresh
    /// changes that matrix by those elements' turns since.
    pub fn entry_elements_and_in_use(&self) -> (&[usize], &[Matrix3<f64>]) {
        (&self.entry_list, &self.in_use)
    }

    /// The largest rotation of an entry-block element since the matrix of the factor in use
    /// [rad] (0 without an entry block).
    pub fn entry_lag(&self, rotations: &[Matrix3<f64>]) -> f64 {
        if self.entry_list.is_empty() {
            return 0.0;
        }
        largest_rotation_where(rotations, &self.in_use, |e| self.entry[e])
    }

    /// The entry block of the factor in use was refactorised for `rotations`.
    pub fn record_entry(&mut self, rotations: &[Matrix3<f64>]) {
        for &e in &self.entry_list {
            self.in_use[e] = rotations[e];
        }
    }

    /// The whole factor was made at once from the factor's matrix with the entry block's
    /// elements turned to `rotations` (an entry refresh that fell back): that matrix is the new
    /// full one.
    pub fn record_entry_full(&mut self, rotations: &[Matrix3<f64>]) {
        for &e in &self.entry_list {
            self.in_use[e] = rotations[e];
        }
        for &e in &self.near_list {
            self.full[e] = self.in_use[e];
        }
        self.lag = largest_rotation_where(rotations, &self.in_use, |e| !self.near[e]);
    }

    /// The near block's elements and the rotations of the last full factor's matrix: a near
    /// refresh assembles that matrix changed by those elements' turns since.
    pub fn near_elements_and_full(&self) -> (&[usize], &[Matrix3<f64>]) {
        (&self.near_list, &self.full)
    }

    /// Measures the lag of this step, whose elements have `rotations`, against the matrix of
    /// the factor it will use: the one in flight when `adopting` (it is due this step), else
    /// the one in use; over the elements outside the near block. Returns it (also kept in
    /// [`LagGuard::lag`]).
    pub fn measure(&mut self, adopting: bool, rotations: &[Matrix3<f64>]) -> f64 {
        let reference = if adopting { &self.sent } else { &self.in_use };
        self.lag = if self.near.is_empty() {
            largest_rotation_between(rotations, reference)
        } else {
            largest_rotation_where(rotations, reference, |e| !self.near[e])
        };
        self.lag
    }

    /// The largest rotation of a near-block element outside the entry block since the matrix
    /// of the factor in use [rad] (0 without a block).
    pub fn near_lag(&self, rotations: &[Matrix3<f64>]) -> f64 {
        if self.near.is_empty() {
            return 0.0;
        }
        largest_rotation_where(rotations, &self.in_use, |e| {
            self.near[e] && !self.is_entry(e)
        })
    }

    /// The near block of the factor in use was refactorised for `rotations`.
    pub fn record_near(&mut self, rotations: &[Matrix3<f64>]) {
        for &e in &self.near_list {
            self.in_use[e] = rotations[e];
        }
    }

    /// The whole factor was made at once from the last full matrix with the near block's
    /// elements turned to `rotations` (a near refresh that fell back): that matrix is the new
    /// full one.
    pub fn record_near_full(&mut self, rotations: &[Matrix3<f64>]) {
        for &e in &self.near_list {
            self.in_use[e] = rotations[e];
            self.full[e] = rotations[e];
        }
        self.lag = largest_rotation_where(rotations, &self.in_use, |e| !self.near[e]);
    }

    /// Records which matrix is in use (adopted) and which the step factorised or sent.
    pub fn record(&mut self, event: FactorEvent, rotations: &[Matrix3<f64>]) {
        if event.adopted == Adopted::Yes {
            std::mem::swap(&mut self.in_use, &mut self.sent);
            if !self.full.is_empty() {
                self.full.copy_from_slice(&self.in_use);
            }
        }
        if event.immediate {
            self.in_use.copy_from_slice(rotations);
            if !self.full.is_empty() {
                self.full.copy_from_slice(rotations);
            }
            self.lag = 0.0;
        } else if event.submitted {
            self.sent.copy_from_slice(rotations);
        }
    }
}

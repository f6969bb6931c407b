//! The reduced (Dirichlet-eliminated) sparse system shared by the gel and the needle: the fixed
//! pattern and its slots, the regularisation `M/h²`, the factor (made at once, or in the
//! background), and the solves over global dofs.

use super::background::{Adopted, Background, FactorEvent, Job, LAG_ROTATION_LIMIT, RefreshParams};
use crate::fem::FemError;
use crate::linalg::LinalgError;
use crate::linalg::{
    Cholesky, PcgOutcome, PcgWork, Precision, SymmetricMatrix, SymmetricPattern, TrailingBlock,
    nested_dissection_order, nested_dissection_order_with_last,
    nested_dissection_order_with_last_two, pcg_solve, pcg_solve_from,
};

/// Marks a fixed (eliminated) dof in the global → reduced map.
pub(super) const SKIP: u32 = u32::MAX;

/// The reduced sparse system `K + M/h²` over the free dofs of one model.
#[derive(Debug)]
pub(super) struct ReducedSystem {
    /// Global dof → reduced index, `SKIP` for fixed dofs.
    pub dof_map: Vec<u32>,
    /// Reduced index → global dof.
    pub free: Vec<usize>,
    pub matrix: SymmetricMatrix,
    diag_slots: Vec<usize>,
    /// Added to the diagonal after assembly (M/h² per reduced dof).
    regularization: Vec<f64>,
    chol: Cholesky,
    work: Vec<f64>,
    work_many: Vec<f64>,
    /// Steps since the factor in use was made (`None`: never factorised).
    pub factor_age: Option<usize>,
    /// Background mode: steps since the matrix of the factor in use was assembled (`None`:
    /// never factorised).
    matrix_age: Option<usize>,
    refactor_every: usize,
    /// Background mode: a due factor is put in use once finished, never waited for.
    asynchronous: bool,
    /// Background mode: the adaptive refresh (`None`: a matrix is sent whenever the worker is
    /// idle).
    refresh: Option<RefreshParams>,
    pub refactor_requested: bool,
    /// The factorisation thread (background mode).
    pub background: Option<Background>,
    /// Preconditioned-CG mode: each step solves its own matrix with the factor in use as
    /// preconditioner.
    pub pcg: Option<PcgState>,
    /// Refined-step mode: the step's own matrix and the CG scratch.
    pub refine: Option<RefineState>,
    /// The near block: the dofs eliminated last, refactorised on their own
    /// ([`ReducedSystem::refresh_near`]).
    near: Option<NearBlock>,
}

/// What [`ReducedSystem::refresh_near`] did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum NearRefresh {
    /// Nothing: no block, or none captured from the factor in use.
    None,
    /// The near block was refactorised.
    Block,
    /// The block was not positive definite: the whole matrix was factorised at once.
    Full,
}

/// The near block of the factor ([`TrailingBlock`]) and the scratch matrix its refreshes are
/// assembled into.
#[derive(Debug)]
struct NearBlock {
    block: TrailingBlock,
    /// The matrix of the factor in use (the last full factorisation's, changed by the last
    /// near refresh and the entry refreshes since).
    matrix: SymmetricMatrix,
    /// Refactorisations of the block so far.
    refreshes: u64,
    /// The entry block inside it, eliminated last of all (`None`: none).
    entry: Option<EntryBlock>,
    /// Whether each reduced dof lies outside the block (is eliminated before it).
    far: Vec<bool>,
    /// The free motion's far-residual tolerance (0: none) and the solves that dropped it.
    far_residual_tolerance: f64,
    far_drops: u64,
    /// Where the deferred solves stop ([`Cholesky::deferral_split`]; `None`: no deferral).
    split: Option<(usize, usize)>,
}

/// The entry block: the trailing part of the near block, around the path's entry point,
/// refactorised on its own ([`ReducedSystem::refresh_entry`]).
#[derive(Debug)]
struct EntryBlock {
    block: TrailingBlock,
    /// Refactorisations of the entry block so far.
    refreshes: u64,
}

/// Settings of the preconditioned-CG free motion (see the module docs of
/// [`crate::free_motion`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PcgParams {
    /// Stop when `‖b − A Δx‖ ≤ tolerance ‖b‖` [-].
    pub tolerance: f64,
    /// Iteration cap; a step that reaches it without converging factorises its own matrix at
    /// once and solves directly.
    pub max_iterations: usize,
}

/// Counts of the preconditioned-CG free motion over a model's life.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PcgStats {
    /// Steps solved by CG (not counting the steps that factorised at once).
    pub steps: u64,
    /// CG iterations over those steps.
    pub iterations: u64,
    /// Most iterations of one step.
    pub max_iterations: usize,
    /// Steps that did not converge within the cap (or broke down) and factorised at once.
    pub fallbacks: u64,
    /// The last step's CG outcome.
    pub last: PcgOutcome,
}

/// The state of the preconditioned-CG mode: this step's matrix, the CG scratch and counts.
#[derive(Debug)]
pub(super) struct PcgState {
    params: PcgParams,
    /// This step's matrix `K(x) + M/h²`, assembled every step; sent to the worker (swapped with
    /// its buffer) when a refresh is due.
    current: SymmetricMatrix,
    work: PcgWork,
    rhs: Vec<f64>,
    pub stats: PcgStats,
}

/// Refined-step mode ([`ReducedSystem::refine_step`]): the step's own matrix `A`, written at
/// every free motion, the CG scratch and the counts.
#[derive(Debug)]
pub(super) struct RefineState {
    params: PcgParams,
    current: SymmetricMatrix,
    work: PcgWork,
    b: Vec<f64>,
    x: Vec<f64>,
    pub stats: PcgStats,
}

/// How a reduced system is built: which global dofs are fixed, the element entries, the
/// regularisation per global dof, the refactorisation period, the dof coordinates for a
/// nested-dissection ordering, and whether to factorise in the background.
pub(super) struct SystemLayout<'a, I: Iterator<Item = (usize, usize)>, F: Fn() -> I> {
    pub fixed: &'a [bool],
    pub entries: F,
    pub regularization: &'a [f64],
    pub refactor_every: usize,
    pub dof_coords: Option<&'a [[f64; 3]]>,
    pub background: bool,
    /// Background mode: adopt a due factor once it is finished, never waiting for it
    /// ([`super::GelParams::asynchronous_factor`]).
    pub asynchronous: bool,
    pub pcg: Option<PcgParams>,
    pub refine: Option<PcgParams>,
    pub refresh: Option<RefreshParams>,
    /// The precision of the factors (see [`Precision`]).
    pub precision: Precision,
    /// Global dofs eliminated last, whose block of the factor is refactorised on its own
    /// ([`ReducedSystem::refresh_near`]); needs `dof_coords` and the direct solve.
    pub near_dofs: Option<&'a [bool]>,
    /// Global dofs among `near_dofs` eliminated last of all, whose block is refactorised on
    /// its own again ([`ReducedSystem::refresh_entry`]); ignored without `near_dofs`.
    pub entry_dofs: Option<&'a [bool]>,
    /// With `near_dofs`: the free motion's far-residual tolerance
    /// ([`super::GelParams::far_residual_tolerance`]; 0: none).
    pub far_residual_tolerance: f64,
    /// With `near_dofs` and the direct solve: defer the far rows of the free motion
    /// ([`ReducedSystem::deferral`]).
    pub defer_far: bool,
}

impl ReducedSystem {
    /// Builds the pattern over the free dofs, its symbolic factorisation, and the slot of every
    /// element entry (`SKIP` for entries on fixed dofs).
    ///
    /// # Errors
    /// [`FemError::NoFreeDof`], a failed symbolic factorisation, or a background thread that
    /// cannot start.
    pub fn try_new<I: Iterator<Item = (usize, usize)>, F: Fn() -> I>(
        layout: SystemLayout<'_, I, F>,
    ) -> Result<(Self, Vec<u32>), FemError> {
        let ndof = layout.fixed.len();
        let mut dof_map = vec![SKIP; ndof];
        let mut free = Vec::new();
        for (g, _) in layout.fixed.iter().enumerate().filter(|(_, f)| !**f) {
            dof_map[g] = free.len() as u32;
            free.push(g);
        }
        if free.is_empty() {
            return Err(FemError::NoFreeDof);
        }
        let reduce = |(r, c): (usize, usize)| {
            let (a, b) = (dof_map[r], dof_map[c]);
            (a != SKIP && b != SKIP).then_some((a as usize, b as usize))
        };
        let entries = &layout.entries;
        let pattern = SymmetricPattern::from_entries(free.len(), entries().filter_map(reduce));
        let slots: Vec<u32> = entries()
            .map(|e| {
                reduce(e)
                    .and_then(|(a, b)| pattern.slot(a, b))
                    .map_or(SKIP, |s| s as u32)
            })
            .collect();
        let diag_slots = (0..free.len())
            .map(|k| pattern.slot(k, k).unwrap_or(0))
            .collect();
        let regularization = free.iter().map(|&g| layout.regularization[g]).collect();
        // The near dofs (free ones), eliminated last; only with the direct solve.
        let near_free: Option<Vec<bool>> = layout
            .near_dofs
            .filter(|_| layout.pcg.is_none() && layout.refine.is_none())
            .filter(|_| layout.background && layout.refresh.is_some())
            .map(|m| {
                free.iter()
                    .map(|&g| m.get(g).copied().unwrap_or(false))
                    .collect()
            });
        // The entry dofs: near ones eliminated last of all (empty: none).
        let entry_free: Vec<bool> = match (&near_free, layout.entry_dofs) {
            (Some(near), Some(m)) => (free.iter().zip(near))
                .map(|(&g, &n)| n && m.get(g).copied().unwrap_or(false))
                .collect(),
            _ => Vec::new(),
        };
        let order = layout.dof_coords.map(|c| {
            let reduced: Vec<[f64; 3]> = free.iter().map(|&g| c[g]).collect();
            match &near_free {
                Some(last) if entry_free.contains(&true) => {
                    nested_dissection_order_with_last_two(&pattern, &reduced, last, &entry_free)
                }
                Some(last) => nested_dissection_order_with_last(&pattern, &reduced, last),
                None => nested_dissection_order(&pattern, &reduced),
            }
        });
        let chol =
            Cholesky::try_new_with_precision(&pattern, order.as_deref(), 1, layout.precision)?;
        let near_count = near_free
            .as_ref()
            .map_or(0, |m| m.iter().filter(|x| **x).count());
        let entry_count = entry_free.iter().filter(|x| **x).count();
        // A factor too small for supernodes (or no near dof, or no ordering) keeps no block.
        let near = (order.is_some() && near_count > 0)
            .then(|| TrailingBlock::new(&chol, &pattern, free.len() - near_count).ok())
            .flatten()
            .map(|block| NearBlock {
                far: far_dofs(&chol, block.first()),
                split: (layout.defer_far && layout.pcg.is_none() && layout.refine.is_none())
                    .then(|| chol.deferral_split(block.first()))
                    .flatten(),
                far_residual_tolerance: layout.far_residual_tolerance.max(0.0),
                far_drops: 0,
                block,
                matrix: SymmetricMatrix::zeros(pattern.clone()),
                refreshes: 0,
                entry: (entry_count > 0 && entry_count < near_count)
                    .then(|| TrailingBlock::new(&chol, &pattern, free.len() - entry_count).ok())
                    .flatten()
                    .map(|block| EntryBlock {
                        block,
                        refreshes: 0,
                    }),
            });
        let background = if layout.background {
            Some(Background::start(
                &pattern,
                order.as_deref(),
                layout.precision,
            )?)
        } else {
            None
        };
        let n = free.len();
        let pcg = layout.pcg.map(|params| PcgState {
            params,
            current: SymmetricMatrix::zeros(pattern.clone()),
            work: PcgWork::new(n),
            rhs: vec![0.0; n],
            stats: PcgStats::default(),
        });
        let refine = layout.refine.map(|params| RefineState {
            params,
            current: SymmetricMatrix::zeros(pattern.clone()),
            work: PcgWork::new(n),
            b: vec![0.0; n],
            x: vec![0.0; n],
            stats: PcgStats::default(),
        });
        Ok((
            Self {
                dof_map,
                free,
                matrix: SymmetricMatrix::zeros(pattern),
                diag_slots,
                regularization,
                chol,
                work: vec![0.0; n],
                work_many: Vec::new(),
                factor_age: None,
                matrix_age: None,
                refactor_every: layout.refactor_every.max(1),
                asynchronous: layout.asynchronous,
                refresh: layout.refresh,
                refactor_requested: false,
                background,
                pcg,
                refine,
                near,
            },
            slots,
        ))
    }

    /// The precision of the factor in use (`Double` after a fallback) and the precision
    /// fallbacks of both factor buffers (see [`Cholesky::precision_fallbacks`]).
    pub fn factor_precision(&self) -> (Precision, u64) {
        let worker = self
            .background
            .as_ref()
            .map_or(0, Background::precision_fallbacks);
        (
            self.chol.precision(),
            self.chol.precision_fallbacks() + worker,
        )
    }

    /// Whether global dof `g` is free.
    pub fn is_free(&self, g: usize) -> bool {
        self.dof_map[g] != SKIP
    }

    fn needs_refactor(&self) -> bool {
        match self.factor_age {
            None => true,
            Some(age) => self.refactor_requested || age + 1 >= self.refactor_every,
        }
    }

    /// Writes `matrix`'s values: zero, the elements' contributions through `write`, then the
    /// regularisation `M/h²` on the diagonal.
    fn write_into(
        matrix: &mut SymmetricMatrix,
        diag_slots: &[usize],
        regularization: &[f64],
        write: impl FnOnce(&mut [f64]),
    ) {
        matrix.fill_zero();
        write(&mut matrix.values);
        for (&s, &r) in diag_slots.iter().zip(regularization) {
            matrix.values[s] += r;
        }
    }

    /// Writes the matrix values: zero, the elements' contributions through `write`, `M/h²`.
    pub fn write_values(&mut self, write: impl FnOnce(&mut [f64])) {
        Self::write_into(
            &mut self.matrix,
            &self.diag_slots,
            &self.regularization,
            write,
        );
    }

    /// Background mode, start of a step: counts the steps of the job in flight and, once it is
    /// due (`refactor_every` steps after its matrix), waits for it and puts it in use (a failed
    /// one is dropped: the step then factorises at once).
    fn adopt_background(&mut self) -> Result<Adopted, FemError> {
        let every = self.refactor_every;
        let Some(bg) = self.background.as_mut() else {
            return Ok(Adopted::Idle);
        };
        if bg.spare.is_some() {
            return Ok(Adopted::Idle);
        }
        bg.in_flight_steps += 1;
        if bg.in_flight_steps < every {
            return Ok(Adopted::Idle);
        }
        // Asynchronous: a job not finished yet stays in flight; the step goes on without it.
        if self.asynchronous && !bg.is_finished()? {
            return Ok(Adopted::Idle);
        }
        let Some(job) = bg.finish()? else {
            return Ok(Adopted::Idle);
        };
        Ok(Self::adopt(&mut self.chol, &mut self.matrix, bg, job))
    }

    /// Puts a finished job's factor and matrix in use (their buffers go back to the worker's
    /// spare job), or drops a failed one.
    fn adopt(
        chol: &mut Cholesky,
        matrix: &mut SymmetricMatrix,
        bg: &mut Background,
        mut job: Box<Job>,
    ) -> Adopted {
        let ok = job.succeeded();
        if ok {
            std::mem::swap(chol, &mut job.chol);
            std::mem::swap(matrix, &mut job.matrix);
            bg.adopted += 1;
        }
        bg.spare = Some(job);
        if ok { Adopted::Yes } else { Adopted::Failed }
    }

    /// Background mode: writes this step's matrix into the staging buffer.
    fn stage_background(&mut self, write: &impl Fn(&mut [f64])) {
        let Some(bg) = self.background.as_mut() else {
            return;
        };
        Self::write_into(
            &mut bg.staged,
            &self.diag_slots,
            &self.regularization,
            write,
        );
    }

    /// Background mode: makes the staged matrix the one to factorise at once.
    fn unstage_background(&mut self) {
        if let Some(bg) = self.background.as_mut() {
            std::mem::swap(&mut self.matrix, &mut bg.staged);
        }
    }

    /// Background mode: sends the staged matrix to the worker.
    fn submit_background(&mut self) -> Result<(), FemError> {
        let Some(bg) = self.background.as_mut() else {
            return Ok(());
        };
        let Some(mut job) = bg.spare.take() else {
            return Ok(());
        };
        std::mem::swap(&mut job.matrix, &mut bg.staged);
        bg.send(job)
    }

    /// Background mode: waits for a job in flight and drops its result (a synchronous
    /// factorisation supersedes it).
    fn discard_background(&mut self) -> Result<(), FemError> {
        if let Some(bg) = self.background.as_mut()
            && let Some(job) = bg.finish()?
        {
            bg.spare = Some(job);
        }
        Ok(())
    }

    /// The factor of a step: refactorises if due (`write` fills the elements' values). In
    /// background mode `lag` measures the largest element rotation between this step and the
    /// matrix of the factor it would use (the one due this step when its argument is true);
    /// `None`: no guard. Above [`LAG_ROTATION_LIMIT`] the step factorises at once; with the
    /// adaptive refresh, it decides whether the step's matrix is sent.
    ///
    /// # Errors
    /// A failed factorisation, or a stopped background thread.
    pub fn update_factor(
        &mut self,
        lag: impl FnOnce(bool) -> Option<f64>,
        write: impl Fn(&mut [f64]),
    ) -> Result<FactorEvent, FemError> {
        if self.background.is_some() {
            return self.update_factor_background(lag, write);
        }
        if self.needs_refactor() {
            self.write_values(write);
            self.factorize()?;
        } else if let Some(age) = self.factor_age.as_mut() {
            *age += 1;
        }
        Ok(FactorEvent::default())
    }

    fn update_factor_background(
        &mut self,
        lag: impl FnOnce(bool) -> Option<f64>,
        write: impl Fn(&mut [f64]),
    ) -> Result<FactorEvent, FemError> {
        let mut event = FactorEvent::default();
        let Some(bg) = self.background.as_mut() else {
            return Ok(event);
        };
        // A job in flight is due after `refactor_every` steps (1: the step after its
        // matrix); asynchronous, once it is also finished. Assemble this step's matrix first
        // when it will be sent (no job in flight after this step's adoption): that overlaps
        // the tail of the running factorisation.
        let mut due = bg.spare.is_none() && bg.in_flight_steps + 1 >= self.refactor_every;
        if due && self.asynchronous {
            due = bg.is_finished()?;
        }
        let (idle, in_flight_steps) = (bg.spare.is_some(), bg.in_flight_steps);
        let lag = lag(due);
        // The age of the matrix in use once the due job (if any) is in use.
        let matrix_age = if due {
            Some(in_flight_steps + 1)
        } else {
            self.matrix_age.map(|a| a + 1)
        };
        let wanted = self.refresh_wanted(lag, matrix_age);
        let idle_after = idle || due;
        let will_submit = idle_after && wanted;
        if will_submit {
            self.stage_background(&write);
        }
        let adopted = self.adopt_background()?;
        if adopted == Adopted::Yes {
            self.capture_near();
        }
        event.adopted = adopted;
        match adopted {
            Adopted::Yes => self.factor_age = Some(0),
            Adopted::Idle => {
                if let Some(age) = self.factor_age.as_mut() {
                    *age += 1;
                }
            }
            Adopted::Failed => self.factor_age = None,
        }
        self.matrix_age = match adopted {
            Adopted::Failed => None,
            _ => self.factor_age.and(matrix_age),
        };
        let lag_ok = lag.is_none_or(|l| l <= LAG_ROTATION_LIMIT);
        let in_use_ok = self.factor_age.is_some() && lag_ok;
        if !in_use_ok || self.refactor_requested {
            // No factor yet, a request, a failed background factorisation, or elements
            // that rotated too far since the matrix in use: factorise now.
            if !will_submit {
                self.stage_background(&write);
            }
            self.unstage_background();
            // A job still in flight holds an older matrix than this one: drop it.
            self.discard_background()?;
            self.factorize_now()?;
            event.immediate = true;
            if let Some(bg) = self.background.as_mut() {
                bg.immediate += 1;
            }
        } else if will_submit {
            self.submit_background()?;
            event.submitted = true;
        }
        Ok(event)
    }

    /// Background mode: whether a step should send its matrix to the worker when it is idle,
    /// given the lag of the factor it uses and the age of that factor's matrix. Always without
    /// the adaptive refresh; with it, when the lag reaches its rotation or the matrix its
    /// ceiling (or the lag or the age is unknown).
    fn refresh_wanted(&self, lag: Option<f64>, matrix_age: Option<usize>) -> bool {
        let Some(p) = self.refresh else {
            return true;
        };
        // With a near block, `lag` is the far elements' (the near ones refresh the block).
        let rotation = if self.has_near() {
            p.far_rotation
        } else {
            p.rotation
        };
        lag.is_none_or(|l| !(l < rotation)) || matrix_age.is_none_or(|a| a >= p.ceiling)
    }

    /// Preconditioned-CG mode: the free-motion solve of a step. Writes this step's matrix
    /// (`write` fills the elements' values), puts a finished background factor in use (never
    /// waits for one), and solves `A Δx = rhs` (global dofs, replaced by `Δx`, zero at fixed
    /// dofs) by CG with the factor in use as preconditioner. The first step, a requested
    /// refactorisation and a step whose CG does not converge within the cap factorise this
    /// step's matrix at once and solve directly. After a CG step, the matrix is sent to be
    /// factorised when the worker is idle and the factor in use is `refactor_every` steps old
    /// (without background thread: factorised at once, for the next step).
    ///
    /// # Errors
    /// A failed factorisation at once, or a stopped background thread.
    pub fn solve_step_pcg(
        &mut self,
        write: impl FnOnce(&mut [f64]),
        rhs: &mut [f64],
    ) -> Result<(), FemError> {
        let Some(pcg) = self.pcg.as_mut() else {
            return self.solve_global(rhs);
        };
        Self::write_into(
            &mut pcg.current,
            &self.diag_slots,
            &self.regularization,
            write,
        );
        for (k, &g) in self.free.iter().enumerate() {
            pcg.rhs[k] = rhs[g];
        }
        match self.poll_background()? {
            Adopted::Yes => self.factor_age = Some(0),
            Adopted::Idle | Adopted::Failed => {
                if let Some(age) = self.factor_age.as_mut() {
                    *age += 1;
                }
            }
        }
        let Self {
            chol, work, pcg, ..
        } = self;
        let Some(pcg) = pcg.as_mut() else {
            return Ok(());
        };
        let mut solved = false;
        if self.factor_age.is_some() && !self.refactor_requested {
            let out = pcg_solve(
                &pcg.current,
                chol,
                &pcg.rhs,
                work,
                &mut pcg.work,
                pcg.params.tolerance,
                pcg.params.max_iterations,
            )?;
            pcg.stats.last = out;
            if out.converged {
                pcg.stats.steps += 1;
                pcg.stats.iterations += out.iterations as u64;
                pcg.stats.max_iterations = pcg.stats.max_iterations.max(out.iterations);
                solved = true;
            } else {
                pcg.stats.fallbacks += 1;
            }
        }
        if solved {
            self.refresh_pcg()?;
        } else {
            // No factor yet, a request, or CG did not converge: this step's own factor.
            self.discard_background()?;
            if let Some(pcg) = self.pcg.as_mut() {
                std::mem::swap(&mut self.matrix, &mut pcg.current);
                self.work.copy_from_slice(&pcg.rhs);
            }
            self.factorize_now()?;
            if let Some(bg) = self.background.as_mut() {
                bg.immediate += 1;
            }
            self.chol.solve_in_place(&mut self.work)?;
        }
        rhs.iter_mut().for_each(|v| *v = 0.0);
        for (k, &g) in self.free.iter().enumerate() {
            rhs[g] = self.work[k];
        }
        Ok(())
    }

    /// Preconditioned-CG mode: puts a finished background factor in use, without waiting.
    fn poll_background(&mut self) -> Result<Adopted, FemError> {
        let Some(bg) = self.background.as_mut() else {
            return Ok(Adopted::Idle);
        };
        let Some(job) = bg.poll()? else {
            return Ok(Adopted::Idle);
        };
        Ok(Self::adopt(&mut self.chol, &mut self.matrix, bg, job))
    }

    /// Preconditioned-CG mode, after a CG step: refreshes the factor from this step's matrix
    /// when due (sent to the idle worker, or factorised at once without one).
    fn refresh_pcg(&mut self) -> Result<(), FemError> {
        let due = self
            .factor_age
            .is_none_or(|age| age + 1 >= self.refactor_every);
        let Some(pcg) = self.pcg.as_mut() else {
            return Ok(());
        };
        if !due {
            return Ok(());
        }
        match self.background.as_mut() {
            Some(bg) => {
                if let Some(mut job) = bg.spare.take() {
                    std::mem::swap(&mut job.matrix, &mut pcg.current);
                    bg.send(job)?;
                }
                Ok(())
            }
            None => {
                std::mem::swap(&mut self.matrix, &mut pcg.current);
                self.factorize_now()
            }
        }
    }

    /// Refined-step mode: writes this step's own matrix `A` (`write` fills the elements'
    /// values); a no-op in the other modes.
    pub fn stage_refine(&mut self, write: impl FnOnce(&mut [f64])) {
        if let Some(rf) = self.refine.as_mut() {
            Self::write_into(
                &mut rf.current,
                &self.diag_slots,
                &self.regularization,
                write,
            );
        }
    }

    /// Refined-step mode: `dx` (global dofs) is a step made with the factor in use `F`, free
    /// motion and correction alike, `dx = F⁻¹ g` with `g = f_ext − f_int(x) + Hᵀλ` the net force
    /// of the step. Replaces it by `A⁻¹ g`, the step with this step's own matrix `A` (written
    /// by [`Self::stage_refine`]): `g = F dx` by a product with the factor's matrix, then CG on
    /// `A` from `dx`, preconditioned by `F`, to `‖g − A dx‖ ≤ tolerance ‖g‖`. A step whose CG
    /// does not converge within the cap keeps the factor's step (counted as a fallback).
    /// Returns the CG outcome (`None` in the other modes: `dx` unchanged).
    ///
    /// # Errors
    /// Wrong length, or no factorisation yet.
    pub fn refine_step(&mut self, dx: &mut [f64]) -> Result<Option<PcgOutcome>, FemError> {
        if dx.len() != self.dof_map.len() {
            return Err(FemError::DimensionMismatch {
                what: "step",
                expected: self.dof_map.len(),
                got: dx.len(),
            });
        }
        let Self {
            chol,
            matrix,
            refine,
            free,
            ..
        } = self;
        let Some(rf) = refine.as_mut() else {
            return Ok(None);
        };
        for (k, &g) in free.iter().enumerate() {
            rf.x[k] = dx[g];
        }
        matrix.mul_vec(&rf.x, &mut rf.b)?;
        let out = pcg_solve_from(
            &rf.current,
            chol,
            &rf.b,
            &mut rf.x,
            &mut rf.work,
            rf.params.tolerance,
            rf.params.max_iterations,
        )?;
        rf.stats.last = out;
        if out.converged {
            rf.stats.steps += 1;
            rf.stats.iterations += out.iterations as u64;
            rf.stats.max_iterations = rf.stats.max_iterations.max(out.iterations);
            for (k, &g) in free.iter().enumerate() {
                dx[g] = rf.x[k];
            }
        } else {
            rf.stats.fallbacks += 1;
        }
        Ok(Some(out))
    }

    /// [`Self::solve_global`] after checking the length (one value per global dof).
    pub fn solve_checked(&mut self, rhs: &mut [f64]) -> Result<(), FemError> {
        if rhs.len() != self.dof_map.len() {
            return Err(FemError::DimensionMismatch {
                what: "right-hand side",
                expected: self.dof_map.len(),
                got: rhs.len(),
            });
        }
        self.solve_global(rhs)
    }

    /// Numeric factorisation of the assembled values (a background job in flight is dropped).
    pub fn factorize(&mut self) -> Result<(), FemError> {
        self.discard_background()?;
        self.factorize_now()
    }

    fn factorize_now(&mut self) -> Result<(), FemError> {
        self.factor_age = None;
        self.matrix_age = None;
        self.chol.factorize(&self.matrix)?;
        self.factor_age = Some(0);
        self.matrix_age = Some(0);
        self.refactor_requested = false;
        self.capture_near();
        Ok(())
    }

    /// After a full factorisation of `matrix` (at once or adopted): the near block's far
    /// contribution from it. A block that cannot be captured is dropped (full refreshes only).
    fn capture_near(&mut self) {
        let Some(near) = self.near.as_mut() else {
            return;
        };
        if near.block.capture(&self.chol, &self.matrix).is_err() {
            self.near = None;
            return;
        }
        near.matrix.values.copy_from_slice(&self.matrix.values);
        Self::capture_entry(near, &self.chol);
    }

    /// After the near block's columns were computed for `near.matrix` (a full factorisation
    /// or a near refresh): the entry block's contribution from the columns before it. An entry
    /// block that cannot be captured is dropped (near refreshes only).
    fn capture_entry(near: &mut NearBlock, chol: &Cholesky) {
        if let Some(entry) = near.entry.as_mut()
            && entry.block.capture(chol, &near.matrix).is_err()
        {
            near.entry = None;
        }
    }

    /// Whether the factor in use has an entry block ready for [`Self::refresh_entry`].
    pub fn has_entry(&self) -> bool {
        (self.near.as_ref())
            .and_then(|n| n.entry.as_ref())
            .is_some_and(|e| e.block.captured() == self.chol.stamp() && self.chol.is_factorized())
    }

    /// Refactorisations of the entry block so far.
    pub fn entry_refreshes(&self) -> u64 {
        (self.near.as_ref())
            .and_then(|n| n.entry.as_ref())
            .map_or(0, |e| e.refreshes)
    }

    /// Refactorises the entry block of the factor in use, the rest kept, for the factor's
    /// matrix changed by `change`: the elements all of whose nodes are in the entry block,
    /// turned from their rotations in that matrix to their current ones (only they change the
    /// entry block alone). The near block's capture holds for the new factor (its far columns
    /// are unchanged). Returns what it did, as [`Self::refresh_near`]: nothing (no entry block
    /// ready), the block, or a full factorisation at once of the matrix so changed when the
    /// block is not positive definite.
    ///
    /// # Errors
    /// A failed full factorisation, or a stopped background thread.
    pub fn refresh_entry(
        &mut self,
        change: impl FnOnce(&mut [f64]),
    ) -> Result<NearRefresh, FemError> {
        if !self.has_entry() {
            return Ok(NearRefresh::None);
        }
        let Some(near) = self.near.as_mut() else {
            return Ok(NearRefresh::None);
        };
        let Some(entry) = near.entry.as_mut() else {
            return Ok(NearRefresh::None);
        };
        // The matrix of the factor in use, changed in the entry block alone: it stays that of
        // the factor whatever follows.
        change(&mut near.matrix.values);
        let before = self.chol.stamp();
        if entry.block.refactor(&mut self.chol, &near.matrix).is_ok() {
            entry.refreshes += 1;
            near.block.carry_capture(before, &self.chol);
            self.factor_age = Some(0);
            return Ok(NearRefresh::Block);
        }
        self.factorize_near_matrix_now()
    }

    /// A block refresh that was not positive definite: the near block's matrix so changed,
    /// whole, factorised at once (the matrix in use from now on).
    fn factorize_near_matrix_now(&mut self) -> Result<NearRefresh, FemError> {
        if let Some(near) = self.near.as_mut() {
            std::mem::swap(&mut self.matrix, &mut near.matrix);
        }
        self.discard_background()?;
        self.factorize_now()?;
        if let Some(bg) = self.background.as_mut() {
            bg.immediate += 1;
        }
        Ok(NearRefresh::Full)
    }

    /// Whether the factor has a near block ([`Self::refresh_near`]).
    pub fn has_near(&self) -> bool {
        self.near.is_some()
    }

    /// The near block is refactorised when one of its elements has rotated by this much since
    /// the matrix of the factor in use [rad]: the adaptive refresh's angle.
    pub fn near_rotation(&self) -> f64 {
        self.refresh.map_or(LAG_ROTATION_LIMIT, |r| r.rotation)
    }

    /// Refactorisations of the near block so far.
    pub fn near_refreshes(&self) -> u64 {
        self.near.as_ref().map_or(0, |n| n.refreshes)
    }

    /// Refactorises the near block of the factor in use, the rest of the factor kept, for the
    /// matrix of the last full factorisation changed by `change`: the elements all of whose
    /// nodes are near, turned from their rotations in that matrix to their current ones (only
    /// such elements change the block alone; every element keeps one rotation, so the matrix
    /// is an assembled stiffness, positive definite). The other elements keep the full
    /// factor's rotations: the caller refreshes the whole factor when they have rotated.
    /// Returns what it did: nothing (no block, or no far contribution captured from the factor
    /// in use), the block, or, for a block that is not positive definite nonetheless, a full
    /// factorisation at once of the matrix so changed.
    ///
    /// # Errors
    /// A failed full factorisation, or a stopped background thread.
    pub fn refresh_near(
        &mut self,
        change: impl FnOnce(&mut [f64]),
    ) -> Result<NearRefresh, FemError> {
        let Some(near) = self.near.as_mut() else {
            return Ok(NearRefresh::None);
        };
        if near.block.captured() != self.chol.stamp() || !self.chol.is_factorized() {
            return Ok(NearRefresh::None);
        }
        near.matrix.values.copy_from_slice(&self.matrix.values);
        change(&mut near.matrix.values);
        if near.block.refactor(&mut self.chol, &near.matrix).is_ok() {
            near.refreshes += 1;
            Self::capture_entry(near, &self.chol);
            self.factor_age = Some(0);
            return Ok(NearRefresh::Block);
        }
        // Not positive definite as mixed: this step's whole matrix, at once.
        self.factorize_near_matrix_now()
    }

    /// The stamp of the factor in use ([`crate::linalg::Cholesky::stamp`]).
    pub fn factor_stamp(&self) -> u64 {
        self.chol.stamp()
    }

    /// The free motion's solve ([`Self::solve_global`]), but with a near block and a far-residual
    /// tolerance `τ > 0`, a right-hand side whose entries outside the block have a norm of at
    /// most `τ` times the whole one is solved with those entries set to zero: the forward
    /// substitution skips every supernode before the block's (their rows stay zero), and the
    /// backward one is whole. Counted in [`Self::far_residual_drops`].
    pub fn solve_free_motion(&mut self, rhs: &mut [f64]) -> Result<(), FemError> {
        self.drop_far_residual(rhs);
        self.solve_global(rhs)
    }

    /// With a near block and a far-residual tolerance: zeroes the far entries of `rhs` when
    /// their norm is at most the tolerance's share of the whole (counted).
    fn drop_far_residual(&mut self, rhs: &mut [f64]) {
        let Some(near) = self
            .near
            .as_mut()
            .filter(|n| n.far_residual_tolerance > 0.0)
        else {
            return;
        };
        let (mut far2, mut all2) = (0.0, 0.0);
        for (&g, &far) in self.free.iter().zip(&near.far) {
            let v2 = rhs[g] * rhs[g];
            all2 += v2;
            if far {
                far2 += v2;
            }
        }
        let tol = near.far_residual_tolerance;
        // A NaN or infinite norm fails this test: such a right-hand side is solved whole.
        if far2 > 0.0 && far2 <= tol * tol * all2 {
            for (&g, &far) in self.free.iter().zip(&near.far) {
                if far {
                    rhs[g] = 0.0;
                }
            }
            near.far_drops += 1;
        }
    }

    /// Where the deferred solves stop (see [`Cholesky::deferral_split`]): with a near block,
    /// `GelParams::defer_far` and the direct solve; `None` otherwise.
    pub fn deferral(&self) -> Option<(usize, usize)> {
        self.near.as_ref().and_then(|n| n.split)
    }

    /// Whether global dof `g` is solved exactly by the deferred solves: a fixed dof, or a free
    /// one eliminated from the split on. `false` without deferral.
    pub fn is_deferral_exact(&self, g: usize) -> bool {
        let Some(split) = self.deferral() else {
            return false;
        };
        match self.dof_map.get(g) {
            Some(&r) if r == SKIP => true,
            Some(&r) => self.chol.is_after_split(r as usize, split),
            None => false,
        }
    }

    /// [`Self::solve_free_motion`] with its far rows deferred: `rhs` returns the solution on
    /// the dofs solved from the split on and zero on the others, which
    /// [`Self::complete_far`] finishes.
    ///
    /// # Errors
    /// No deferral ([`Self::deferral`]), or the solve's.
    pub fn solve_free_motion_deferring_far(&mut self, rhs: &mut [f64]) -> Result<(), FemError> {
        let split = self
            .deferral()
            .ok_or(LinalgError::Deferred("no near block to defer to"))?;
        self.drop_far_residual(rhs);
        for (k, &g) in self.free.iter().enumerate() {
            self.work[k] = rhs[g];
        }
        self.chol.solve_deferring_far(&mut self.work, split)?;
        rhs.iter_mut().for_each(|v| *v = 0.0);
        for (k, &g) in self.free.iter().enumerate() {
            rhs[g] = self.work[k];
        }
        Ok(())
    }

    /// Finishes the last deferred free motion into `dx` (global dofs), whose exactly solved
    /// dofs hold that free motion plus any response to loads on them alone (a corrective
    /// motion): its other free dofs are written, the rest left as they are.
    ///
    /// # Errors
    /// No deferral, a changed factor, or a wrong length.
    pub fn complete_far(&mut self, dx: &mut [f64]) -> Result<(), FemError> {
        let split = self
            .deferral()
            .ok_or(LinalgError::Deferred("no near block to defer to"))?;
        if dx.len() != self.dof_map.len() {
            return Err(FemError::DimensionMismatch {
                what: "step",
                expected: self.dof_map.len(),
                got: dx.len(),
            });
        }
        for (k, &g) in self.free.iter().enumerate() {
            self.work[k] = dx[g];
        }
        self.chol.complete_far(&mut self.work, split)?;
        for (k, &g) in self.free.iter().enumerate() {
            dx[g] = self.work[k];
        }
        Ok(())
    }

    /// [`Self::solve_global_many`] on the dofs solved exactly from the split on (zero on the
    /// others): exact there for loads there, at the cost of the factor's trailing part.
    ///
    /// # Errors
    /// No deferral, or the solve's.
    pub fn solve_global_many_near(
        &mut self,
        rhs: &mut [f64],
        ncols: usize,
    ) -> Result<(), FemError> {
        let split = self
            .deferral()
            .ok_or(LinalgError::Deferred("no near block to defer to"))?;
        self.solve_global_many_with(rhs, ncols, Some(split))
    }

    /// Free motions solved with their far residual dropped ([`Self::solve_free_motion`]).
    pub fn far_residual_drops(&self) -> u64 {
        self.near.as_ref().map_or(0, |n| n.far_drops)
    }

    /// Solves in place over global dofs (fixed entries set to zero).
    pub fn solve_global(&mut self, rhs: &mut [f64]) -> Result<(), FemError> {
        for (k, &g) in self.free.iter().enumerate() {
            self.work[k] = rhs[g];
        }
        self.chol.solve_in_place(&mut self.work)?;
        rhs.iter_mut().for_each(|v| *v = 0.0);
        for (k, &g) in self.free.iter().enumerate() {
            rhs[g] = self.work[k];
        }
        Ok(())
    }

    /// Solves `ncols` column-major global right-hand sides in place.
    pub fn solve_global_many(&mut self, rhs: &mut [f64], ncols: usize) -> Result<(), FemError> {
        self.solve_global_many_with(rhs, ncols, None)
    }

    fn solve_global_many_with(
        &mut self,
        rhs: &mut [f64],
        ncols: usize,
        split: Option<(usize, usize)>,
    ) -> Result<(), FemError> {
        let ndof = self.dof_map.len();
        if rhs.len() != ndof * ncols {
            return Err(FemError::DimensionMismatch {
                what: "right-hand sides",
                expected: ndof * ncols,
                got: rhs.len(),
            });
        }
        let n = self.free.len();
        // Grows once to the largest column count used, then reused.
        if self.work_many.len() < n * ncols {
            self.work_many.resize(n * ncols, 0.0);
        }
        let buf = &mut self.work_many[..n * ncols];
        for c in 0..ncols {
            for (k, &g) in self.free.iter().enumerate() {
                buf[c * n + k] = rhs[c * ndof + g];
            }
        }
        match split {
            Some(split) => self.chol.solve_near_many(buf, ncols, split)?,
            None => self.chol.solve_many_in_place(buf, ncols)?,
        }
        rhs.iter_mut().for_each(|v| *v = 0.0);
        for c in 0..ncols {
            for (k, &g) in self.free.iter().enumerate() {
                rhs[c * ndof + g] = buf[c * n + k];
            }
        }
        Ok(())
    }
}

/// Whether each reduced dof is eliminated before the permuted column `first` (outside a
/// trailing block that starts there).
fn far_dofs(chol: &Cholesky, first: usize) -> Vec<bool> {
    let inv = chol.inverse_permutation();
    (0..chol.dim())
        .map(|k| inv.map_or(k, |p| p[k]) < first)
        .collect()
}

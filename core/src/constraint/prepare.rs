//! Block factors of a frame, computed once and reused by every solve of the step.

use super::project::Sym2;
use super::{Block, BlockGs};
use crate::math::spd_inverse_in_place;
use crate::payload::{
    ComplianceFrame, GroupKind, RowGroup, ValidationError, validate_compliance, validate_entries,
    validate_groups,
};

impl<const M: usize> BlockGs<M> {
    /// Validates a frame ([`ComplianceFrame::validate`]) and prepares its block factors.
    ///
    /// # Errors
    /// The frame's validation error.
    pub fn prepare_frame<const N: usize>(
        &mut self,
        frame: &ComplianceFrame<M, N>,
    ) -> Result<(), ValidationError> {
        frame.validate()?;
        self.prepare_unchecked(&frame.w, frame.rows(), frame.used_groups());
        Ok(())
    }

    /// Validates a group table and the used block of `w`, then factors every diagonal block.
    /// Unlike a frame, the table need not start with the 6 base rows.
    ///
    /// # Errors
    /// A [`ValidationError`] for an inconsistent table or a bad `w`.
    pub fn prepare(
        &mut self,
        w: &[[f64; M]; M],
        m: usize,
        groups: &[RowGroup],
    ) -> Result<(), ValidationError> {
        self.m = 0;
        self.n_blocks = 0;
        validate_groups(groups, m, M, false)?;
        validate_compliance(w, m)?;
        self.prepare_unchecked(w, m, groups);
        Ok(())
    }

    /// [`Self::prepare`] for a `w` symmetric by construction (the base rows' Schur complement,
    /// [`crate::reduce`]): the same checks but symmetry.
    ///
    /// # Errors
    /// A [`ValidationError`] for an inconsistent table, a non-finite entry or a non-positive
    /// diagonal.
    pub(crate) fn prepare_symmetric(
        &mut self,
        w: &[[f64; M]; M],
        m: usize,
        groups: &[RowGroup],
    ) -> Result<(), ValidationError> {
        self.m = 0;
        self.n_blocks = 0;
        validate_groups(groups, m, M, false)?;
        validate_entries(w, m)?;
        self.prepare_unchecked(w, m, groups);
        Ok(())
    }

    fn prepare_unchecked(&mut self, w: &[[f64; M]; M], m: usize, groups: &[RowGroup]) {
        self.m = m.min(M);
        self.n_blocks = groups.len().min(M);
        self.frictional = false;
        for i in 0..self.m {
            self.diag[i] = w[i][i];
        }
        for (b, g) in self.blocks.iter_mut().zip(groups) {
            *b = Block {
                kind: g.kind as u8,
                len: g.len as u8,
                start: g.start,
                mu: g.mu,
                r0: g.r0,
            };
            let s = g.start as usize;
            let f = self.factors[s..].as_flattened_mut();
            match GroupKind::from_raw(g.kind) {
                Some(GroupKind::Bilateral) => {
                    let n = g.len as usize;
                    for i in 0..n {
                        for j in 0..n {
                            f[i * n + j] = w[s + i][s + j];
                        }
                    }
                    spd_inverse_in_place(&mut f[..n * n], n);
                }
                Some(GroupKind::Unilateral) => f[0] = 1.0 / w[s][s],
                Some(GroupKind::Contact) => {
                    self.frictional = true;
                    f[0] = 1.0 / w[s][s];
                    let (a, bb, c) = (w[s + 1][s + 1], w[s + 1][s + 2], w[s + 2][s + 2]);
                    let e = Sym2::new(a, bb, c);
                    f[1..11].copy_from_slice(&e.pack());
                }
                Some(GroupKind::Sliding) => {
                    // The axial row is bounded by `μ_n |λ_lat| + r_0`: not an equality, so not
                    // for the equality polish either.
                    self.frictional = true;
                    let e = Sym2::new(w[s][s], w[s][s + 1], w[s + 1][s + 1]);
                    f[0..10].copy_from_slice(&e.pack());
                    f[10] = 1.0 / w[s + 2][s + 2];
                }
                None => {}
            }
        }
    }
}

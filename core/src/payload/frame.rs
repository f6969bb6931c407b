//! The compliance frame: everything the core needs for one inverse step (host → core).

use super::{NCLEAR, NOBS, Payload, RowGroup, VERSION};
use core::mem::MaybeUninit;

/// One compliance frame: everything the core needs for one inverse step (host → core).
///
/// `N` is the robot's joint count (default 6, the RV-1A); with `N = 6` the layout is the v2
/// layout of `needle.ComplianceFrame.v2` (the transports carry only that one).
///
/// `M` is the row capacity; only the first `m` rows/columns of the arrays are used. At `M = 192`
/// a frame is about 320 KiB: never build one on the stack, use [`Self::init_in_place`] on storage
/// you own (a `static`, a shared-memory sample) or `new_boxed` (feature `alloc`).
#[derive(Clone, Copy, Debug)]
#[repr(C)]
pub struct ComplianceFrame<const M: usize, const N: usize = 6> {
    /// Layout version, [`VERSION`].
    pub version: u32,
    /// Number of rows used, `6 ≤ m ≤ M`.
    pub m: u32,
    /// Sequence number of the frame, increasing by one per host step.
    pub sequence: u64,
    /// Number of row groups used in `groups`.
    pub group_count: u32,
    /// 1 once the needle tip has punctured the gel surface, else 0.
    pub inserted: u32,
    /// Row groups, contiguous from row 0; group 0 is the 6 base rows (bilateral).
    pub groups: [RowGroup; M],
    /// Compliance `W = H K⁻¹ Hᵀ`, row-major, only `m × m` used [mm/N, rad/(N·mm) for rotation rows].
    pub w: [[f64; M]; M],
    /// Constraint violation after free motion `δ_free` [mm or rad]. Rows 0..6 are recomputed by
    /// the core from `q` (host: write `δ_base(q)` there for diagnostics).
    pub delta_free: [f64; M],
    /// Needle base node position after free motion, world frame [mm].
    pub p_free: [f64; 3],
    /// Needle base node orientation after free motion, row-major rotation matrix, world frame.
    pub r_free: [[f64; 3]; 3],
    /// Observations after free motion, laid out by [`ObsIndex`](super::ObsIndex) (world frame,
    /// mm or unit vectors).
    pub o_free: [f64; NOBS],
    /// Observation sensitivity `C = O K⁻¹ Hᵀ`: `o = o_free + C λ`, row-major, `m` columns used.
    pub c: [[f64; M]; NOBS],
    /// Insertion depth of the tip past the entry point [mm] (0 before puncture).
    pub insertion_depth: f64,
    /// Robot joints at which the frame was built [rad].
    pub q: [f64; N],
    /// Robot control period [s].
    pub dt: f64,
    /// Number of obstacle clearances used in `clearance_free` and `clearance_c`
    /// (`≤ NCLEAR`; 0 before puncture or without obstacles).
    pub clearance_count: u32,
    /// Reserved, 0.
    pub reserved: u32,
    /// Clearance of the needle to each obstacle after free motion: distance from the obstacle's
    /// centre to the nearest point of the inserted needle's centre line, minus the obstacle's
    /// radius [mm] (negative: inside).
    pub clearance_free: [f64; NCLEAR],
    /// Clearance sensitivity to first order, `clearance = clearance_free + clearance_c λ`
    /// (row-major, `m` columns used) [mm/N or mm/(N·mm)].
    pub clearance_c: [[f64; M]; NCLEAR],
}

crate::zeroed::impl_zeroable!(ComplianceFrame<const M, const N> {
    version,
    m,
    sequence,
    group_count,
    inserted,
    groups,
    w,
    delta_free,
    p_free,
    r_free,
    o_free,
    c,
    insertion_depth,
    q,
    dt,
    clearance_count,
    reserved,
    clearance_free,
    clearance_c,
});

impl<const M: usize, const N: usize> Payload for ComplianceFrame<M, N> {
    fn stamp(&mut self) {
        self.version = VERSION;
    }
}

impl<const M: usize, const N: usize> ComplianceFrame<M, N> {
    /// Initialises a frame in place: all zero, `version = VERSION`. Returns the initialised frame.
    ///
    /// Use it on storage you own so that the (large) frame never transits the stack (a
    /// `static`, a shared-memory sample); on the heap, [`Self::new_boxed`] does it for you.
    ///
    /// # Example
    /// ```
    /// use core::mem::MaybeUninit;
    /// use needle_core::{ComplianceFrame, VERSION};
    ///
    /// static mut FRAME: MaybeUninit<ComplianceFrame<16>> = MaybeUninit::uninit();
    /// // SAFETY (of this example): the only borrow of the static.
    /// let frame = ComplianceFrame::init_in_place(unsafe { &mut *(&raw mut FRAME) });
    /// assert_eq!((frame.version, frame.m), (VERSION, 0));
    /// ```
    pub fn init_in_place(this: &mut MaybeUninit<Self>) -> &mut Self {
        super::init_in_place(this)
    }

    /// A frame on the heap in the state of [`Self::init_in_place`], built there (no stack copy).
    ///
    /// # Example
    /// ```
    /// use needle_core::{ComplianceFrame, ValidationError, VERSION};
    ///
    /// let frame = ComplianceFrame::<192>::new_boxed(); // ≈ 320 KiB
    /// assert_eq!(frame.version, VERSION);
    /// // All zero: too few rows to be a frame.
    /// assert_eq!(frame.validate(), Err(ValidationError::TooFewRows { m: 0, min: 6 }));
    /// ```
    #[cfg(feature = "alloc")]
    pub fn new_boxed() -> alloc::boxed::Box<Self> {
        super::new_boxed()
    }

    /// Resets an existing frame to the state of [`Self::init_in_place`], without a stack copy.
    pub fn reset(&mut self) {
        super::reset(self);
    }

    /// Number of rows used, as `usize`.
    pub fn rows(&self) -> usize {
        self.m as usize
    }

    /// The used row groups (clamped to the capacity; call [`Self::validate`] first).
    pub fn used_groups(&self) -> &[RowGroup] {
        &self.groups[..(self.group_count as usize).min(M)]
    }

    /// The used clearances: `clearance_count` clamped to [`NCLEAR`].
    pub fn clearances(&self) -> usize {
        (self.clearance_count as usize).min(NCLEAR)
    }

    /// Clearance `k` for `λ`: `clearance_free[k] + clearance_c[k] · λ` over the first `m`
    /// rows [mm].
    pub fn clearance(&self, k: usize, lambda: &[f64]) -> f64 {
        let m = self.rows().min(M).min(lambda.len());
        let row = &self.clearance_c[k.min(NCLEAR - 1)];
        self.clearance_free[k.min(NCLEAR - 1)]
            + row[..m]
                .iter()
                .zip(&lambda[..m])
                .map(|(a, b)| a * b)
                .sum::<f64>()
    }

    /// The observed 3-vector starting at `index` (one of the [`ObsIndex`](super::ObsIndex)
    /// constants) for `λ`: `o_free + C λ` over the first `m` rows.
    pub fn observe(&self, index: usize, lambda: &[f64]) -> [f64; 3] {
        let m = self.rows().min(M).min(lambda.len());
        let mut out = [0.0; 3];
        for (k, o) in out.iter_mut().enumerate() {
            let r = (index + k).min(NOBS - 1);
            *o = self.o_free[r] + crate::math::dot(&self.c[r][..m], &lambda[..m]);
        }
        out
    }
}

//! Which copy of the core's hot loops runs: the sweeps, the products by `W`, the Schur
//! complement of the base rows, the active-set factor and the frame's validation are compiled
//! three times on x86-64 — baseline (SSE2), AVX2 and AVX-512F — and the widest copy the CPU
//! and the OS support is picked at run time. The copies do the same operations in the same
//! order on wider vectors, so a step gives the same answer, bit for bit, whichever runs
//! (`tests/simd_copies.rs` checks it on every copy the machine has).
//!
//! [`set_limit`] caps the copy in use, process-wide: to test or time the narrower copies on a
//! machine that has the wider ones (the benches' `_avx2` and `_baseline` variants), or to run as a
//! machine without them would. It never enables a copy the CPU lacks. On other architectures
//! the baseline copy is the only one.
//!
//! ```
//! use needle_core::simd::{self, SimdLevel};
//! let before = simd::active();
//! assert!(simd::set_limit(SimdLevel::Baseline) == SimdLevel::Baseline);
//! assert!(simd::set_limit(SimdLevel::Avx512) == simd::detected());
//! # let _ = before;
//! ```

/// A set of vector instructions the core's loops can be compiled for, narrowest first.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum SimdLevel {
    /// The architecture's baseline (SSE2 on x86-64).
    Baseline,
    /// AVX2 (4 lanes of `f64`).
    Avx2,
    /// AVX-512F (8 lanes of `f64`), besides AVX2.
    Avx512,
}

impl SimdLevel {
    /// Every level, narrowest first.
    pub const ALL: [SimdLevel; 3] = [SimdLevel::Baseline, SimdLevel::Avx2, SimdLevel::Avx512];

    /// Its lower-case name (`baseline`, `avx2`, `avx512`).
    pub const fn name(self) -> &'static str {
        match self {
            SimdLevel::Baseline => "baseline",
            SimdLevel::Avx2 => "avx2",
            SimdLevel::Avx512 => "avx512",
        }
    }

    #[cfg(target_arch = "x86_64")]
    const fn code(self) -> u8 {
        use crate::math::simd::{AVX2, AVX512, BASELINE};
        match self {
            SimdLevel::Baseline => BASELINE,
            SimdLevel::Avx2 => AVX2,
            SimdLevel::Avx512 => AVX512,
        }
    }

    #[cfg(target_arch = "x86_64")]
    fn from_code(c: u8) -> Self {
        use crate::math::simd::{AVX2, AVX512};
        if c >= AVX512 {
            SimdLevel::Avx512
        } else if c >= AVX2 {
            SimdLevel::Avx2
        } else {
            SimdLevel::Baseline
        }
    }
}

/// The widest level the CPU and the OS support.
pub fn detected() -> SimdLevel {
    #[cfg(target_arch = "x86_64")]
    {
        SimdLevel::from_code(crate::math::simd::detected())
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        SimdLevel::Baseline
    }
}

/// The level the loops use now: [`detected`], at most the limit of [`set_limit`].
pub fn active() -> SimdLevel {
    #[cfg(target_arch = "x86_64")]
    {
        SimdLevel::from_code(crate::math::simd::level())
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        SimdLevel::Baseline
    }
}

/// Caps the level the loops use at `limit` for the whole process (`SimdLevel::Avx512`, the
/// default, lifts the cap) and returns the level now in use: `limit` or, on a machine without
/// it, the widest it has. Safe at any time; a step already running may finish on either copy.
pub fn set_limit(limit: SimdLevel) -> SimdLevel {
    #[cfg(target_arch = "x86_64")]
    crate::math::simd::set_limit(limit.code());
    #[cfg(not(target_arch = "x86_64"))]
    let _ = limit;
    active()
}

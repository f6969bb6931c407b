//! Small numerical kernels shared by the solver and the inverse update (crate-private).

use nalgebra::{Matrix3, Quaternion, UnitQuaternion, Vector3};

/// Dot product with four independent accumulators (lets the compiler vectorise without
/// reassociation).
#[inline(always)]
pub(crate) fn dot(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let mut acc = [0.0f64; 4];
    let mut ca = a.chunks_exact(4);
    let mut cb = b.chunks_exact(4);
    for (x, y) in (&mut ca).zip(&mut cb) {
        acc[0] += x[0] * y[0];
        acc[1] += x[1] * y[1];
        acc[2] += x[2] * y[2];
        acc[3] += x[3] * y[3];
    }
    let mut tail = 0.0;
    for (x, y) in ca.remainder().iter().zip(cb.remainder()) {
        tail += x * y;
    }
    (acc[0] + acc[2]) + (acc[1] + acc[3]) + tail
}

/// The correctly rounded square root (IEEE 754), as `libm::sqrt`: on x86-64 the `sqrtsd`
/// instruction through its intrinsic rather than `libm`'s inline assembly, so that the compiler
/// schedules it and encodes it as the surrounding code (VEX inside the AVX copies).
#[inline(always)]
pub(crate) fn sqrt(x: f64) -> f64 {
    #[cfg(target_arch = "x86_64")]
    {
        use core::arch::x86_64::{_mm_cvtsd_f64, _mm_set_sd, _mm_sqrt_sd};
        // SSE2 is part of the x86-64 baseline.
        #[allow(unused_unsafe)]
        let r = unsafe {
            let v = _mm_set_sd(x);
            _mm_cvtsd_f64(_mm_sqrt_sd(v, v))
        };
        r
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        libm::sqrt(x)
    }
}

/// `y += alpha · x`.
#[inline(always)]
pub(crate) fn axpy(alpha: f64, x: &[f64], y: &mut [f64]) {
    for (yi, xi) in y.iter_mut().zip(x) {
        *yi += alpha * xi;
    }
}

/// `y += d0 · x0 + d1 · x1 + d2 · x2` in one pass over `y`.
#[inline(always)]
pub(crate) fn axpy3(d: [f64; 3], x0: &[f64], x1: &[f64], x2: &[f64], y: &mut [f64]) {
    let n = y.len().min(x0.len()).min(x1.len()).min(x2.len());
    let (x0, x1, x2, y) = (&x0[..n], &x1[..n], &x2[..n], &mut y[..n]);
    for i in 0..n {
        y[i] += d[0] * x0[i] + d[1] * x1[i] + d[2] * x2[i];
    }
}

/// Largest absolute entry (0 for an empty slice; NaN-safe: NaN entries are ignored).
///
/// Eight running maxima, one per lane, so that the compiler can vectorise it and no chain of
/// dependent comparisons runs the slice's length (the result does not depend on the order:
/// it is one of the entries, or 0).
#[inline]
pub(crate) fn max_abs(v: &[f64]) -> f64 {
    #[inline(always)]
    fn keep(m: f64, x: f64) -> f64 {
        let a = libm::fabs(x);
        if a > m { a } else { m }
    }
    let mut lanes = [0.0f64; 8];
    let mut chunks = v.chunks_exact(8);
    for c in &mut chunks {
        for (m, x) in lanes.iter_mut().zip(c) {
            *m = keep(*m, *x);
        }
    }
    let tail = chunks.remainder().iter().fold(0.0, |m, x| keep(m, *x));
    lanes.iter().fold(tail, |m, x| keep(m, *x))
}

/// Rotation vector `log(R)` [rad], accurate for small angles (no `acos`) and finite for any
/// input. `r` is assumed orthonormal.
pub(crate) fn rotation_log(r: &Matrix3<f64>) -> Vector3<f64> {
    let rot = nalgebra::Rotation3::from_matrix_unchecked(*r);
    let q: UnitQuaternion<f64> = UnitQuaternion::from_rotation_matrix(&rot);
    quaternion_log(q.quaternion())
}

fn quaternion_log(q: &Quaternion<f64>) -> Vector3<f64> {
    let (mut w, mut v) = (q.w, q.imag());
    if w < 0.0 {
        w = -w;
        v = -v;
    }
    let s = v.norm();
    if !(s > 1e-300) {
        return Vector3::zeros();
    }
    let angle = 2.0 * libm::atan2(s, w);
    v * (angle / s)
}

/// Angle between two vectors [rad] in `[0, π]`, via `atan2(|a×b|, a·b)` (accurate near 0 and π);
/// 0 when either vector is zero.
pub(crate) fn angle_between(a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    let c = a.cross(b).norm();
    let d = a.dot(b);
    if c == 0.0 && d == 0.0 {
        return 0.0;
    }
    libm::atan2(c, d)
}

/// In-place inverse of a symmetric positive (semi-)definite `n × n` block (`n ≤ 6`) stored
/// row-major in `a[..n*n]`, through a Cholesky factorisation. A pivot below `1e-13 ·` the largest
/// diagonal is regularised so that the result is always finite for finite input; returns the
/// number of regularised pivots.
pub(crate) fn spd_inverse_in_place(a: &mut [f64], n: usize) -> usize {
    debug_assert!(n <= 6 && a.len() >= n * n);
    let mut l = [0.0f64; 36];
    let mut dmax = 0.0f64;
    for i in 0..n {
        dmax = dmax.max(libm::fabs(a[i * n + i]));
    }
    let floor = if dmax > 0.0 { 1e-13 * dmax } else { 1.0 };
    let mut fixed = 0;
    for j in 0..n {
        let mut d = a[j * n + j];
        for k in 0..j {
            d -= l[j * 6 + k] * l[j * 6 + k];
        }
        if !(d > floor) {
            d = floor;
            fixed += 1;
        }
        let djj = libm::sqrt(d);
        l[j * 6 + j] = djj;
        for i in (j + 1)..n {
            let mut s = a[i * n + j];
            for k in 0..j {
                s -= l[i * 6 + k] * l[j * 6 + k];
            }
            l[i * 6 + j] = s / djj;
        }
    }
    // inv = L⁻ᵀ L⁻¹, column by column.
    for c in 0..n {
        let mut y = [0.0f64; 6];
        for i in 0..n {
            let mut s = if i == c { 1.0 } else { 0.0 };
            for k in 0..i {
                s -= l[i * 6 + k] * y[k];
            }
            y[i] = s / l[i * 6 + i];
        }
        let mut x = [0.0f64; 6];
        for i in (0..n).rev() {
            let mut s = y[i];
            for k in (i + 1)..n {
                s -= l[k * 6 + i] * x[k];
            }
            x[i] = s / l[i * 6 + i];
        }
        for i in 0..n {
            a[i * n + c] = x[i];
        }
    }
    fixed
}

#[cfg(test)]
#[allow(clippy::expect_used, clippy::unwrap_used, clippy::panic)]
mod tests {
    use super::*;

    /// The eight-lane `max_abs` gives the serial fold's value bit for bit, NaN entries ignored,
    /// at every length around the lane count.
    #[test]
    fn max_abs_equals_the_serial_fold() {
        let serial = |v: &[f64]| {
            v.iter().fold(0.0f64, |m, x| {
                if libm::fabs(*x) > m {
                    libm::fabs(*x)
                } else {
                    m
                }
            })
        };
        let mut state = 7u64;
        let mut v = [0.0f64; 40];
        for n in 0..=40 {
            for trial in 0..20 {
                for x in &mut v[..n] {
                    state = state
                        .wrapping_mul(6_364_136_223_846_793_005)
                        .wrapping_add(1_442_695_040_888_963_407);
                    let u = (state >> 11) as f64 / (1u64 << 53) as f64;
                    *x = match (state >> 3) % 17 {
                        0 if trial % 3 == 0 => f64::NAN,
                        1 => -0.0,
                        _ => (u - 0.5) * 1e3,
                    };
                }
                let (a, b) = (max_abs(&v[..n]), serial(&v[..n]));
                assert_eq!(a.to_bits(), b.to_bits(), "n = {n}: {a} against {b}");
            }
        }
        assert_eq!(max_abs(&[f64::NAN; 9]), 0.0);
    }

    #[test]
    fn log_small_and_large_angles() {
        for &ang in &[1e-12, 1e-6, 0.3, 3.0] {
            let axis = Vector3::new(1.0, -2.0, 0.5).normalize();
            let r = nalgebra::Rotation3::from_scaled_axis(axis * ang);
            let v = rotation_log(r.matrix());
            assert!(
                (v - axis * ang).norm() <= 1e-15 + 1e-12 * ang,
                "{ang}: {v:?}"
            );
        }
    }

    #[test]
    fn spd_inverse_matches() {
        let mut a = [4.0, 1.0, 0.5, 1.0, 3.0, 0.2, 0.5, 0.2, 2.0];
        let orig = a;
        spd_inverse_in_place(&mut a, 3);
        for i in 0..3 {
            for j in 0..3 {
                let s: f64 = (0..3).map(|k| orig[i * 3 + k] * a[k * 3 + j]).sum();
                assert!((s - if i == j { 1.0 } else { 0.0 }).abs() < 1e-14);
            }
        }
    }
}

/// Runtime detection of AVX2 and AVX-512F on x86-64 (cached), so the hot loops can be compiled twice —
/// baseline x86-64 (SSE2) and AVX2 — and the right copy picked at run time without
/// `-C target-cpu`. Uses only `core` (cpuid, xgetbv): no std.
#[cfg(target_arch = "x86_64")]
pub(crate) mod simd {
    use core::sync::atomic::{AtomicU8, Ordering};

    static LEVEL: AtomicU8 = AtomicU8::new(0);
    /// The highest level the loops may use ([`crate::simd::set_limit`]); the detected one when
    /// higher is not taken.
    static LIMIT: AtomicU8 = AtomicU8::new(AVX512);

    /// No AVX2.
    pub(crate) const BASELINE: u8 = 1;
    /// AVX2 (YMM state enabled).
    pub(crate) const AVX2: u8 = 2;
    /// AVX2 and AVX-512F (ZMM and mask state enabled too).
    pub(crate) const AVX512: u8 = 3;

    /// The detected level (cached).
    #[inline]
    pub(crate) fn detected() -> u8 {
        match LEVEL.load(Ordering::Relaxed) {
            0 => {
                let v = detect();
                LEVEL.store(v, Ordering::Relaxed);
                v
            }
            v => v,
        }
    }

    /// The level the loops use: the detected one, at most the limit.
    #[inline]
    pub(crate) fn level() -> u8 {
        detected().min(LIMIT.load(Ordering::Relaxed))
    }

    /// Sets the limit (`BASELINE..=AVX512`).
    pub(crate) fn set_limit(limit: u8) {
        LIMIT.store(limit.clamp(BASELINE, AVX512), Ordering::Relaxed);
    }

    /// Whether the CPU and the OS support AVX2 (YMM state enabled) and the limit allows it.
    #[inline]
    pub(crate) fn has_avx2() -> bool {
        level() >= AVX2
    }

    /// Whether the CPU and the OS support AVX-512F besides AVX2 and the limit allows it.
    #[inline]
    pub(crate) fn has_avx512() -> bool {
        level() >= AVX512
    }

    fn detect() -> u8 {
        use core::arch::x86_64::{__cpuid, __cpuid_count};
        // `cpuid` exists on every x86-64 CPU.
        #[allow(unused_unsafe)]
        let l1 = unsafe { __cpuid(1) };
        let osxsave = l1.ecx & (1 << 27) != 0;
        let avx = l1.ecx & (1 << 28) != 0;
        if !(osxsave && avx) {
            return BASELINE;
        }
        // SAFETY: OSXSAVE is set, so `xgetbv` is enabled by the OS.
        let xcr0 = unsafe { xgetbv0() };
        if xcr0 & 0b110 != 0b110 {
            return BASELINE;
        }
        #[allow(unused_unsafe)]
        let l7 = unsafe { __cpuid_count(7, 0) };
        if l7.ebx & (1 << 5) == 0 {
            return BASELINE;
        }
        // AVX-512F, and the OS saves the opmask and both halves of the ZMM registers.
        if l7.ebx & (1 << 16) != 0 && xcr0 & 0b1110_0000 == 0b1110_0000 {
            AVX512
        } else {
            AVX2
        }
    }

    #[target_feature(enable = "xsave")]
    unsafe fn xgetbv0() -> u64 {
        // SAFETY: the caller checked OSXSAVE.
        unsafe { core::arch::x86_64::_xgetbv(0) }
    }
}

/// Whether the AVX-512 copy of the sweep may run.
#[inline]
pub(crate) fn use_avx512() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        simd::has_avx512()
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Whether the AVX2 copies of the hot loops may run.
#[inline]
pub(crate) fn use_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        simd::has_avx2()
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

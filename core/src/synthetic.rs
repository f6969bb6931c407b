//! Synthetic compliance frames with known structure, for tests, benches and examples (no
//! allocation: they write into a frame you own).
//!
//! * [`rigid_needle_frame`]: only the 6 base rows; a rigid needle of length `L` hangs on a
//!   linear spring at the base, so the tip follows the base through a known linear map and the
//!   target (taken from joints `q_target`) is exactly reachable.
//! * [`random_frame`]: a seeded random SPD compliance with the production layout (6 base rows, an
//!   optional tip contact, sliding points), random violations and observation rows.
//! * [`rv1a_on_turntable`]: a 7-joint arm for tests of `N ≠ 6`.
//!
//! Both frames work for any joint count `N` of the chain.

use crate::kinematics::{DhChain, Kinematics, Pose};
use crate::kinematics::{DhJoint, JointLimit};
use crate::payload::{BASE_ROWS, ComplianceFrame, NOBS, ObsIndex, RowGroup, VERSION};
use nalgebra::{Matrix3, Vector3};

/// A small counter-based random generator (SplitMix64); deterministic for a seed.
#[derive(Clone, Copy, Debug)]
pub struct Rng(pub u64);

impl Rng {
    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        mix(self.0)
    }

    /// Uniform in `[0, 1)`.
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Uniform in `[lo, hi)`.
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.uniform()
    }
}

fn mix(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Deterministic value in `[-1, 1)` for `(seed, i, k)`.
fn hash_unit(seed: u64, i: usize, k: usize) -> f64 {
    let z = mix(seed ^ mix((i as u64) << 32 ^ k as u64));
    (z >> 11) as f64 * (2.0 / (1u64 << 53) as f64) - 1.0
}

fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v[2], v[1], v[2], 0.0, -v[0], -v[1], v[0], 0.0)
}

fn write_rotation(dst: &mut [[f64; 3]; 3], r: &Matrix3<f64>) {
    for (i, row) in dst.iter_mut().enumerate() {
        for (j, x) in row.iter_mut().enumerate() {
            *x = r[(i, j)];
        }
    }
}

/// A 7-joint arm for tests of redundant robots: the RV-1A ([`DhChain::rv1a`]) mounted on a
/// turntable, a revolute joint about the world z axis whose link carries the robot 200 mm out
/// (`q_0` first, then the RV-1A's six joints; turntable ±170°, 90°/s).
pub fn rv1a_on_turntable() -> DhChain<7> {
    let arm = DhChain::rv1a();
    let mut joints = [DhJoint {
        theta_offset: 0.0,
        d: 0.0,
        a: 200.0,
        alpha: 0.0,
    }; 7];
    joints[1..].copy_from_slice(&arm.joints);
    let mut limits = [JointLimit::from_degrees(-170.0, 170.0, 90.0); 7];
    limits[1..].copy_from_slice(&arm.limits);
    DhChain {
        joints,
        limits,
        base: arm.base,
        tool: arm.tool,
    }
}

/// Model tip and tip direction of the rigid-needle frame for a base pose `b`.
fn rigid_tip(free: &Pose, b: &Pose, length: f64) -> (Vector3<f64>, Vector3<f64>) {
    let z = free.z_axis();
    let u_p = b.translation - free.translation;
    let u_r = crate::math::rotation_log(&(b.rotation * free.rotation.transpose()));
    (
        free.translation + u_p + z * length + u_r.cross(&(z * length)),
        z + u_r.cross(&z),
    )
}

/// Fills `frame` with the rigid-needle model: 6 bilateral base rows with compliance
/// `W = diag(c_t I, c_r I)` [mm/N, rad/(N·mm)], the needle base resting (free motion) at
/// `B(q_free)`, a rigid needle of `length` [mm] along the base z axis, so that
/// `tip = p_free + u_p + L z + u_r × L z` with `(u_p, u_r) = W λ` — linear in `λ`. The target is
/// this model's tip at `q_target` and the tangent its direction there; the entry point lies
/// `L/4` behind the target along that direction. `frame.q = q_free`, `dt` = 1 s, not inserted.
///
/// # Example
/// ```
/// use needle_core::synthetic::rigid_needle_frame;
/// use needle_core::{ComplianceFrame, Controller, DhChain, InverseParams};
///
/// let chain = DhChain::rv1a();
/// let (q_free, q_target) = ([0.25, 0.3, 2.05, 0.05, 0.55, -0.25], [0.2, 0.35, 2.0, 0.1, 0.6, -0.2]);
/// let mut frame = ComplianceFrame::<12>::new_boxed();
/// rigid_needle_frame(&mut frame, &chain, &q_free, &q_target, 120.0);
/// assert_eq!(frame.validate(), Ok(()));
/// // The target is exactly reachable: the objective vanishes at q_target, not at q_free.
/// let mut ctrl = Controller::<12>::new_boxed(chain, InverseParams::default());
/// let norm = |t: [f64; 4]| t.iter().map(|x| x * x).sum::<f64>().sqrt();
/// assert!(norm(ctrl.objective_at(&frame, &q_target)?.t) < 1e-6);
/// assert!(norm(ctrl.objective_at(&frame, &q_free)?.t) > 1.0);
/// # Ok::<(), needle_core::StepError>(())
/// ```
pub fn rigid_needle_frame<const M: usize, const N: usize>(
    frame: &mut ComplianceFrame<M, N>,
    chain: &impl Kinematics<N>,
    q_free: &[f64; N],
    q_target: &[f64; N],
    length: f64,
) {
    frame.reset();
    let (ct, cr) = (1e-3, 1e-5);
    frame.m = BASE_ROWS as u32;
    frame.group_count = 1;
    frame.groups[0] = RowGroup::bilateral(0, BASE_ROWS as u32);
    for i in 0..BASE_ROWS {
        frame.w[i][i] = if i < 3 { ct } else { cr };
    }
    let free = chain.tool_pose(q_free);
    frame.p_free = free.translation.into();
    write_rotation(&mut frame.r_free, &free.rotation);
    let d = crate::inverse::base_violation(&free, &frame.p_free, &frame.r_free);
    frame.delta_free[..BASE_ROWS].copy_from_slice(&d);
    let z = free.z_axis();
    // o_tip = p_free + L z + [I, −[L z]×] u,  o_dir = z + [0, −[z]×] u,  u = W λ.
    let a_tip = -skew(&(z * length));
    let a_dir = -skew(&z);
    for r in 0..3 {
        frame.o_free[ObsIndex::TIP_POSITION + r] = free.translation[r] + length * z[r];
        frame.o_free[ObsIndex::TIP_DIRECTION + r] = z[r];
        frame.c[ObsIndex::TIP_POSITION + r][r] = ct;
        for c in 0..3 {
            frame.c[ObsIndex::TIP_POSITION + r][3 + c] = a_tip[(r, c)] * cr;
            frame.c[ObsIndex::TIP_DIRECTION + r][3 + c] = a_dir[(r, c)] * cr;
        }
    }
    let (tip, dir) = rigid_tip(&free, &chain.tool_pose(q_target), length);
    let dir = dir.normalize();
    for r in 0..3 {
        frame.o_free[ObsIndex::TARGET_POINT + r] = tip[r];
        frame.o_free[ObsIndex::TARGET_TANGENT + r] = dir[r];
        // A quarter of the needle behind the tip, on the target direction: pivoting about the
        // tip then changes θ2, so (e, θ2) are independent objectives.
        frame.o_free[ObsIndex::ENTRY_POINT + r] = tip[r] - 0.25 * length * dir[r];
    }
    frame.q = *q_free;
    frame.dt = 1.0;
    frame.version = VERSION;
}

/// Fills `frame` with a seeded random problem of `m` rows (`m` clamped to `6..=M`, rounded down
/// to 6 + a multiple of 3) in the production layout: 6 bilateral base rows, then (when
/// `with_contact`) one tip contact `[n, t1, t2]`, then sliding points. `W = A Aᵀ / k + α I`
/// with random `A` (`k = m + 8` columns), scaled so that base rows are stiffer than gel rows;
/// random violations and observation rows; the needle base rests near `B(q)`.
pub fn random_frame<const M: usize, const N: usize>(
    frame: &mut ComplianceFrame<M, N>,
    chain: &impl Kinematics<N>,
    q: &[f64; N],
    m: usize,
    seed: u64,
    with_contact: bool,
) {
    frame.reset();
    let mut rng = Rng(seed);
    let m = m.clamp(BASE_ROWS, M.max(BASE_ROWS));
    let m = BASE_ROWS + (m - BASE_ROWS) / 3 * 3;
    let m = m.min(M);
    frame.m = m as u32;
    random_groups(frame, &mut rng, with_contact);
    random_compliance(frame, rng.next_u64());
    // Free motion: base rests near B(q).
    let b = chain.tool_pose(q);
    let off = Vector3::new(
        rng.range(-1.0, 1.0),
        rng.range(-1.0, 1.0),
        rng.range(-1.0, 1.0),
    );
    frame.p_free = (b.translation + off).into();
    let rot = nalgebra::Rotation3::from_scaled_axis(Vector3::new(
        rng.range(-0.02, 0.02),
        rng.range(-0.02, 0.02),
        rng.range(-0.02, 0.02),
    ));
    write_rotation(&mut frame.r_free, &(rot.matrix() * b.rotation));
    let d = crate::inverse::base_violation(&b, &frame.p_free, &frame.r_free);
    frame.delta_free[..BASE_ROWS].copy_from_slice(&d);
    for i in BASE_ROWS..m {
        frame.delta_free[i] = rng.range(-0.5, 0.5);
    }
    random_observations(frame, &b, &mut rng);
    frame.inserted = 1;
    frame.insertion_depth = rng.range(0.0, 30.0);
    frame.q = *q;
    frame.dt = 0.01;
    frame.sequence = seed;
    frame.version = VERSION;
}

/// Row groups of `random_frame` for `frame.m` rows: the 6 base rows, an optional tip contact,
/// then sliding points.
fn random_groups<const M: usize, const N: usize>(
    frame: &mut ComplianceFrame<M, N>,
    rng: &mut Rng,
    with_contact: bool,
) {
    let m = frame.rows();
    let mut g = 0;
    frame.groups[g] = RowGroup::bilateral(0, BASE_ROWS as u32);
    g += 1;
    let mut row = BASE_ROWS;
    if with_contact && row + 3 <= m {
        frame.groups[g] = RowGroup::contact(row as u32, rng.range(0.1, 0.5));
        g += 1;
        row += 3;
    }
    while row + 3 <= m {
        frame.groups[g] = RowGroup::sliding(row as u32, rng.range(0.05, 0.3), rng.range(0.0, 0.05));
        g += 1;
        row += 3;
    }
    frame.group_count = g as u32;
}

/// Row scale of `random_frame`: rotation base rows in rad/(N·mm), the others 1.
fn row_scale(i: usize) -> f64 {
    match i {
        0..3 => 1.0,
        3..BASE_ROWS => 0.01,
        _ => 1.0,
    }
}

/// `W = S (A Aᵀ / k + α I) S` of `random_frame` with row scales `S`: the base rows are as
/// compliant as the gel rows — the needle hangs on the base constraint alone (its own stiffness
/// only regularised), so moving the base is soft, not stiff; rotation rows scaled to rad/(N·mm).
fn random_compliance<const M: usize, const N: usize>(
    frame: &mut ComplianceFrame<M, N>,
    wseed: u64,
) {
    let m = frame.rows();
    let k = m + 8;
    for i in 0..m {
        for j in 0..=i {
            let mut s = 0.0;
            for c in 0..k {
                s += hash_unit(wseed, i, c) * hash_unit(wseed, j, c);
            }
            let mut v = s / k as f64;
            if i == j {
                v += 0.05;
            }
            v *= row_scale(i) * row_scale(j);
            frame.w[i][j] = v;
            frame.w[j][i] = v;
        }
    }
}

/// Observations of `random_frame`: tip 100 mm below the base pose `b`, target a few mm away,
/// and a random sensitivity `C`.
fn random_observations<const M: usize, const N: usize>(
    frame: &mut ComplianceFrame<M, N>,
    b: &Pose,
    rng: &mut Rng,
) {
    let z = b.z_axis();
    for r in 0..3 {
        let tip = b.translation[r] + 100.0 * z[r];
        frame.o_free[ObsIndex::TIP_POSITION + r] = tip;
        frame.o_free[ObsIndex::TIP_DIRECTION + r] = z[r];
        frame.o_free[ObsIndex::TARGET_POINT + r] = tip + rng.range(-3.0, 3.0);
        frame.o_free[ObsIndex::TARGET_TANGENT + r] = z[r] + rng.range(-0.1, 0.1);
        frame.o_free[ObsIndex::ENTRY_POINT + r] = tip - 20.0 * z[r];
    }
    let cseed = rng.next_u64();
    for r in 0..NOBS {
        for c in 0..frame.rows() {
            // Tip position moves ~1 mm per mm of base violation; directions ~0.01 rad.
            let base = match r {
                0..3 => 1.0,
                3..6 => 0.01,
                _ => 0.05,
            };
            frame.c[r][c] = base * 0.01 * hash_unit(cseed, r, c) * row_scale(c);
        }
    }
}

//! What travels through shared memory: the core's [`ComplianceFrame`] and [`Command`] wrapped in
//! `#[repr(transparent)]` newtypes that implement iceoryx2's [`ZeroCopySend`], and two small
//! `#[repr(C)]` user headers that say which host session and which robot set-up a sample
//! belongs to.
//!
//! The orphan rule forbids implementing iceoryx2's trait on `needle-core`'s types here, and the
//! core stays free of iceoryx2: the newtypes are the one place where the two meet. They add no
//! field, so the layout is exactly the core's (`#[repr(C)]`, integers, floats and fixed arrays
//! only — any bit pattern is a valid value, which is why every received frame is still checked
//! with [`ComplianceFrame::validate`]).
//!
//! The iceoryx2 type names are versioned and say the joint count `N` ([`frame_type_name`],
//! [`command_type_name`]: `needle.ComplianceFrame.v2` and `needle.Command.v2` for 6 joints,
//! `needle.ComplianceFrame.v2.j7` and `needle.Command.v2.j7` for 7); iceoryx2 compares the type
//! name, size and alignment when a service is opened, so two builds with different row
//! capacities `M`, or a host and a controller of different joint counts, refuse to talk to each
//! other instead of misreading each other ([`crate::shm`] says which joint count the service
//! carries). The frame header carries the joint count too ([`FrameHeader::joints`]), and the
//! set-up fingerprint hashes it ([`setup_fingerprint`]).

use core::fmt::Write as _;
use iceoryx2::prelude::ZeroCopySend;
use needle_core::Zeroable;
use needle_core::inverse::InverseParams;
use needle_core::kinematics::Robot;
use needle_core::payload::{COMMAND_TYPE_NAME, Command, ComplianceFrame, FRAME_TYPE_NAME, Payload};

/// The joint counts the bridge carries: 6 (the RV-1A, the KR 16-2, …) and 7 (the LBR iiwa, …).
pub const BRIDGE_JOINTS: [usize; 2] = [6, 7];

/// The iceoryx2 type name of a frame of `joints` joints: [`FRAME_TYPE_NAME`]
/// (`needle.ComplianceFrame.v2`) for 6, `needle.ComplianceFrame.v2.j7` for 7; `None` for a
/// count the bridge does not carry ([`BRIDGE_JOINTS`]).
pub const fn frame_type_name(joints: usize) -> Option<&'static str> {
    match joints {
        6 => Some(FRAME_TYPE_NAME),
        7 => Some("needle.ComplianceFrame.v2.j7"),
        _ => None,
    }
}

/// The iceoryx2 type name of a command of `joints` joints: [`COMMAND_TYPE_NAME`]
/// (`needle.Command.v2`) for 6, `needle.Command.v2.j7` for 7; `None` otherwise.
pub const fn command_type_name(joints: usize) -> Option<&'static str> {
    match joints {
        6 => Some(COMMAND_TYPE_NAME),
        7 => Some("needle.Command.v2.j7"),
        _ => None,
    }
}

/// The joint count a payload type name of [`frame_type_name`] or [`command_type_name`] stands
/// for (`None`: not one of the bridge's).
pub fn joints_of_type_name(name: &str) -> Option<usize> {
    BRIDGE_JOINTS
        .into_iter()
        .find(|&n| frame_type_name(n) == Some(name) || command_type_name(n) == Some(name))
}

/// The type name of `name(N)`, a compile-time error for a joint count the bridge does not
/// carry.
const fn known(name: Option<&'static str>) -> &'static str {
    match name {
        Some(n) => n,
        None => panic!("the bridge carries robots of 6 or 7 joints"),
    }
}

/// A compliance frame as an iceoryx2 payload (host → core), layout identical to
/// [`ComplianceFrame<M, N>`]; `N` joints, 6 (default) or 7.
#[derive(Debug)]
#[repr(transparent)]
pub struct FramePayload<const M: usize, const N: usize = 6>(pub ComplianceFrame<M, N>);

// SAFETY: `ComplianceFrame<M, N>` is `#[repr(C)]` and holds only `u32`, `u64`, `f64` and fixed
// arrays of those (`RowGroup` included, itself `#[repr(C)]` of the same): no pointer, no
// reference, no process-local handle, every bit pattern valid. The newtype is transparent.
unsafe impl<const M: usize, const N: usize> ZeroCopySend for FramePayload<M, N> {
    unsafe fn type_name() -> &'static str {
        const { known(frame_type_name(N)) }
    }
}

/// A command as an iceoryx2 payload (core → host), layout identical to [`Command<M, N>`].
#[derive(Debug)]
#[repr(transparent)]
pub struct CommandPayload<const M: usize, const N: usize = 6>(pub Command<M, N>);

// SAFETY: as for `FramePayload`: `Command<M, N>` and `SolverReport<N>` are `#[repr(C)]`
// integers, floats and fixed arrays only.
unsafe impl<const M: usize, const N: usize> ZeroCopySend for CommandPayload<M, N> {
    unsafe fn type_name() -> &'static str {
        const { known(command_type_name(N)) }
    }
}

// SAFETY: `#[repr(transparent)]` over `ComplianceFrame<M, N>`, which is `Zeroable`.
unsafe impl<const M: usize, const N: usize> Zeroable for FramePayload<M, N> {}
// SAFETY: `#[repr(transparent)]` over `Command<M, N>`, which is `Zeroable`.
unsafe impl<const M: usize, const N: usize> Zeroable for CommandPayload<M, N> {}

// The core's initial state (all zero, layout version written), so that a loaned sample is
// initialised in place as the core's `init_in_place` does ([`crate::shm::loan_initialised`]).
impl<const M: usize, const N: usize> Payload for FramePayload<M, N> {
    fn stamp(&mut self) {
        self.0.stamp();
    }
}

impl<const M: usize, const N: usize> Payload for CommandPayload<M, N> {
    fn stamp(&mut self) {
        self.0.stamp();
    }
}

/// User header of every frame sample.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, ZeroCopySend)]
#[type_name("needle.FrameHeader.v2")]
#[repr(C)]
pub struct FrameHeader {
    /// Identifier of the host run that published the frame (new at every host start). Frame
    /// sequences increase within a session; a new session is a restarted host.
    pub session: u64,
    /// [`setup_fingerprint`] of the robot chain and inverse tuning the host expects the core to
    /// use; a controller configured differently rejects the frame.
    pub setup: u64,
    /// The robot's joint count the frame was built for (the payload's `N`); a controller of
    /// another count rejects the frame.
    pub joints: u32,
    /// Reserved, 0.
    pub reserved: u32,
}

/// What a command sample is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u32)]
pub enum CommandKind {
    /// The answer to the frame `(session, frame_sequence)`: the host applies it.
    Answer = 1,
    /// Hold: no fresh frame within the deadline, the robot is held at `q` (zero joint
    /// velocity). For the robot; a host ignores it.
    Hold = 2,
}

impl CommandKind {
    /// Decodes a raw kind; `None` for an unknown value.
    pub const fn from_raw(raw: u32) -> Option<Self> {
        match raw {
            1 => Some(Self::Answer),
            2 => Some(Self::Hold),
            _ => None,
        }
    }
}

/// User header of every command sample.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, ZeroCopySend)]
#[type_name("needle.CommandHeader.v1")]
#[repr(C)]
pub struct CommandHeader {
    /// The host session of the frame this command answers (or of the last frame, for a hold).
    pub session: u64,
    /// Raw [`CommandKind`].
    pub kind: u32,
    /// Reserved, 0.
    pub reserved: u32,
}

/// A 64-bit fingerprint of a robot chain of `N` joints and inverse tuning (FNV-1a over the
/// joint count and their `Debug` text, which prints every `f64` exactly): both processes
/// compute it from their own set-up, and a controller refuses frames from a host that expects
/// another robot, another joint count or another tuning.
pub fn setup_fingerprint<const N: usize>(
    chain: &(impl Into<Robot<N>> + Copy),
    params: &InverseParams,
) -> u64 {
    let chain: Robot<N> = (*chain).into();
    let mut text = String::new();
    // Writing into a String cannot fail.
    let _ = write!(text, "joints {N}|{chain:?}|{params:?}");
    fnv1a(text.as_bytes())
}

fn fnv1a(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in bytes {
        h ^= u64::from(*b);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

/// A fresh, non-zero session identifier (process id, wall clock and a counter).
pub fn new_session_id() -> u64 {
    use std::sync::atomic::{AtomicU64, Ordering};
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64);
    let mut bytes = [0u8; 24];
    bytes[..8].copy_from_slice(&u64::from(std::process::id()).to_le_bytes());
    bytes[8..16].copy_from_slice(&now.to_le_bytes());
    bytes[16..].copy_from_slice(&COUNTER.fetch_add(1, Ordering::Relaxed).to_le_bytes());
    fnv1a(&bytes).max(1)
}

/// Copies the used part of `src` into `dst` (a frame in the state of
/// [`ComplianceFrame::init_in_place`]): the header, the used groups, the `m × m` block of `W`,
/// the `m` used columns of `C` and the used rows of `δ_free`. The unused entries of `dst` keep
/// their zeros. `m` is clamped to the capacity, so a corrupt `src` cannot make it read out of
/// bounds.
pub fn copy_used<const M: usize, const N: usize>(
    src: &ComplianceFrame<M, N>,
    dst: &mut ComplianceFrame<M, N>,
) {
    let m = src.rows().min(M);
    let g = (src.group_count as usize).min(M);
    dst.version = src.version;
    dst.m = src.m;
    dst.sequence = src.sequence;
    dst.group_count = src.group_count;
    dst.inserted = src.inserted;
    dst.groups[..g].copy_from_slice(&src.groups[..g]);
    for (d, s) in dst.w.iter_mut().zip(&src.w).take(m) {
        d[..m].copy_from_slice(&s[..m]);
    }
    dst.delta_free[..m].copy_from_slice(&src.delta_free[..m]);
    dst.p_free = src.p_free;
    dst.r_free = src.r_free;
    dst.o_free = src.o_free;
    for (d, s) in dst.c.iter_mut().zip(&src.c) {
        d[..m].copy_from_slice(&s[..m]);
    }
    dst.insertion_depth = src.insertion_depth;
    dst.q = src.q;
    dst.dt = src.dt;
    let k = src.clearances();
    dst.clearance_count = src.clearance_count;
    dst.reserved = src.reserved;
    dst.clearance_free[..k].copy_from_slice(&src.clearance_free[..k]);
    for (d, s) in dst.clearance_c.iter_mut().zip(&src.clearance_c).take(k) {
        d[..m].copy_from_slice(&s[..m]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use needle_core::kinematics::DhChain;
    use needle_core::synthetic::random_frame;

    fn boxed<const M: usize>() -> Box<ComplianceFrame<M>> {
        ComplianceFrame::new_boxed()
    }

    #[test]
    fn newtypes_keep_the_core_layout() {
        assert_eq!(
            core::mem::size_of::<FramePayload<192>>(),
            core::mem::size_of::<ComplianceFrame<192>>()
        );
        assert_eq!(
            core::mem::align_of::<CommandPayload<192>>(),
            core::mem::align_of::<Command<192>>()
        );
        // SAFETY: only reads the type names.
        unsafe {
            assert_eq!(
                <FramePayload<8> as ZeroCopySend>::type_name(),
                "needle.ComplianceFrame.v2"
            );
            assert_eq!(
                <CommandPayload<8> as ZeroCopySend>::type_name(),
                "needle.Command.v2"
            );
            assert_eq!(
                <FramePayload<8, 7> as ZeroCopySend>::type_name(),
                "needle.ComplianceFrame.v2.j7"
            );
            assert_eq!(
                <CommandPayload<8, 7> as ZeroCopySend>::type_name(),
                "needle.Command.v2.j7"
            );
        }
        assert_eq!(joints_of_type_name("needle.ComplianceFrame.v2"), Some(6));
        assert_eq!(joints_of_type_name("needle.Command.v2.j7"), Some(7));
        assert_eq!(joints_of_type_name("needle.Command.v1"), None);
        // A 7-joint frame is another layout (iceoryx2 compares sizes as well as names).
        assert_ne!(
            core::mem::size_of::<FramePayload<192, 7>>(),
            core::mem::size_of::<FramePayload<192, 6>>()
        );
    }

    #[test]
    fn copy_used_gives_a_frame_that_validates_and_observes_alike() {
        let chain = DhChain::rv1a();
        let q = [0.1, 0.3, 2.0, 0.0, 0.5, 0.0];
        let mut src = boxed::<64>();
        random_frame(&mut src, &chain, &q, 45, 3, true);
        src.sequence = 17;
        src.validate().expect("valid source");
        let mut dst = boxed::<64>();
        copy_used(&src, &mut dst);
        dst.validate().expect("valid copy");
        let m = src.rows();
        assert_eq!(dst.sequence, 17);
        for i in 0..m {
            assert_eq!(dst.w[i][..m], src.w[i][..m]);
        }
        let lambda: Vec<f64> = (0..m).map(|i| i as f64 * 0.01).collect();
        assert_eq!(dst.observe(0, &lambda), src.observe(0, &lambda));
    }

    #[test]
    fn copy_used_clamps_a_corrupt_row_count() {
        let mut src = boxed::<16>();
        src.m = u32::MAX;
        src.group_count = u32::MAX;
        let mut dst = boxed::<16>();
        copy_used(&src, &mut dst);
        assert!(dst.validate().is_err());
    }

    #[test]
    fn fingerprint_tells_setups_apart() {
        let chain = DhChain::rv1a();
        let p = InverseParams::default();
        assert_eq!(setup_fingerprint(&chain, &p), setup_fingerprint(&chain, &p));
        let p2 = InverseParams {
            damping: p.damping + 1e-12,
            ..p
        };
        assert_ne!(
            setup_fingerprint(&chain, &p),
            setup_fingerprint(&chain, &p2)
        );
        let mut c2 = chain;
        c2.joints[2].a += 1.0;
        assert_ne!(setup_fingerprint(&chain, &p), setup_fingerprint(&c2, &p));
        assert_ne!(new_session_id(), new_session_id());
        // The joint count is part of the fingerprint.
        let seven = DhChain::<7> {
            joints: [chain.joints[0]; 7],
            base: chain.base,
            tool: chain.tool,
            limits: [chain.limits[0]; 7],
        };
        assert_ne!(setup_fingerprint(&seven, &p), setup_fingerprint(&chain, &p));
        assert_eq!(CommandKind::from_raw(2), Some(CommandKind::Hold));
        assert_eq!(CommandKind::from_raw(0), None);
    }
}

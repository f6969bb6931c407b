//! no_std smoke binary: builds an RV-1A controller and a small synthetic frame in static
//! storage, runs one inverse step, prints one line through libc `write`, exits 0 when the
//! command is finite (1 otherwise, 2 on an error).
#![no_std]
#![no_main]

use core::fmt::Write;
use core::mem::MaybeUninit;
use needle_core::synthetic::random_frame;
use needle_core::{Command, ComplianceFrame, Controller, DhChain, InverseParams};

#[link(name = "c")]
unsafe extern "C" {
    fn write(fd: i32, buf: *const u8, count: usize) -> isize;
    fn abort() -> !;
}

const M: usize = 30;

static mut FRAME: MaybeUninit<ComplianceFrame<M>> = MaybeUninit::uninit();
static mut COMMAND: MaybeUninit<Command<M>> = MaybeUninit::uninit();
static mut CONTROLLER: MaybeUninit<Controller<M>> = MaybeUninit::uninit();

/// A fixed-size line buffer for `core::fmt`.
struct Line {
    buf: [u8; 256],
    len: usize,
}

impl Write for Line {
    fn write_str(&mut self, s: &str) -> core::fmt::Result {
        let b = s.as_bytes();
        let n = b.len().min(self.buf.len() - self.len);
        self.buf[self.len..self.len + n].copy_from_slice(&b[..n]);
        self.len += n;
        Ok(())
    }
}

fn print(line: &Line) {
    // SAFETY: the pointer and length describe initialised bytes of `line.buf`.
    unsafe {
        write(1, line.buf.as_ptr(), line.len);
    }
}

#[unsafe(no_mangle)]
pub extern "C" fn main(_argc: i32, _argv: *const *const u8) -> i32 {
    // SAFETY: single-threaded program; each static is borrowed exactly once, here.
    let (frame, cmd, ctrl) = unsafe {
        (
            ComplianceFrame::init_in_place(&mut *(&raw mut FRAME)),
            Command::init_in_place(&mut *(&raw mut COMMAND)),
            Controller::init_in_place(
                &mut *(&raw mut CONTROLLER),
                DhChain::rv1a(),
                InverseParams::default(),
            ),
        )
    };
    let q = [0.1, 0.3, 2.0, 0.0, 0.5, 0.0];
    random_frame(frame, &ctrl.robot, &q, M, 1, true);
    let mut line = Line {
        buf: [0; 256],
        len: 0,
    };
    match ctrl.step(frame, cmd) {
        Ok(rep) => {
            let finite = cmd.q.iter().all(|x| x.is_finite())
                && cmd.lambda[..cmd.m as usize].iter().all(|x| x.is_finite());
            let _ = writeln!(
                line,
                "needle-core no_std: m={} solves={} sweeps={} |T|={:.4} mm q=[{:.4}, {:.4}, {:.4}, {:.4}, {:.4}, {:.4}] finite={}",
                cmd.m,
                rep.solves,
                rep.iterations,
                libm_free_norm(&rep.objective),
                cmd.q[0],
                cmd.q[1],
                cmd.q[2],
                cmd.q[3],
                cmd.q[4],
                cmd.q[5],
                finite
            );
            print(&line);
            if finite { 0 } else { 1 }
        }
        Err(e) => {
            let _ = writeln!(line, "needle-core no_std: step failed: {e}");
            print(&line);
            2
        }
    }
}

/// Euclidean norm by Newton iterations (keeps this binary free of a libm dependency).
fn libm_free_norm(v: &[f64; 4]) -> f64 {
    let s: f64 = v.iter().map(|x| x * x).sum();
    if !(s > 0.0) {
        return 0.0;
    }
    let mut r = s;
    for _ in 0..64 {
        r = 0.5 * (r + s / r);
    }
    r
}

/// The precompiled `core` references the unwinding personality routine even though this binary
/// is built with `panic = "abort"` and never unwinds; on stable the lang item cannot be defined, so
/// an inert symbol satisfies the linker. It is never called.
#[unsafe(no_mangle)]
pub extern "C" fn rust_eh_personality() {}

#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    // SAFETY: libc `abort` never returns.
    unsafe { abort() }
}

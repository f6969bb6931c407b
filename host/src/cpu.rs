//! CPU clocks of this process: the time summed over all its threads (the gel's background
//! factorisation included), and the calling thread's own. A background thread is not free: the
//! run summary reports CPU time per step beside wall time.

/// One of the kernel's CPU clocks [s] (0 when it cannot be read).
fn clock(id: libc::clockid_t) -> f64 {
    let mut t = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `t` is a valid, writable timespec; the clock ids used are defined on every Unix.
    if unsafe { libc::clock_gettime(id, &raw mut t) } != 0 {
        return 0.0;
    }
    t.tv_sec as f64 + t.tv_nsec as f64 * 1e-9
}

/// CPU time of the whole process, all threads [s].
pub fn process_s() -> f64 {
    clock(libc::CLOCK_PROCESS_CPUTIME_ID)
}

/// CPU time of the calling thread [s].
pub fn thread_s() -> f64 {
    clock(libc::CLOCK_THREAD_CPUTIME_ID)
}

#[cfg(test)]
mod tests {
    #[test]
    fn process_clock_counts_a_second_threads_work() {
        let busy = |s: f64| {
            let t0 = super::thread_s();
            let mut x = 0.0_f64;
            while super::thread_s() - t0 < s {
                x = core::hint::black_box(x + 1.0);
            }
        };
        let p0 = super::process_s();
        let t0 = super::thread_s();
        std::thread::spawn(move || busy(0.05)).join().unwrap();
        busy(0.02);
        let process = super::process_s() - p0;
        let thread = super::thread_s() - t0;
        assert!((0.02..0.06).contains(&thread), "thread {thread}");
        assert!(
            process >= 0.07,
            "process {process} must include the other thread's 0.05 s"
        );
    }
}

//! Instruction counts (valgrind, through gungraun) of the inverse step at m = 30, 120 and the full
//! capacity 192, cold (fresh controller; `_plain_gs`: without the active-set prediction) and,
//! `_drifting`, one frame after another a control period apart (the counted step starts from the
//! previous step's λ and sensitivities, as in production) — deterministic, so regressions show as exact count changes. CI gates them against
//! `core/benches/instructions_baseline.json`: `python3 tools/check_instructions.py` (needs
//! valgrind and `gungraun-runner` 0.20.0; `--update` rewrites the baseline).

use gungraun::{library_benchmark, library_benchmark_group, main};
use needle_core::{Command, ComplianceFrame, Controller, SolverReport};
use std::hint::black_box;

mod common;

struct State {
    frame: Box<ComplianceFrame<{ common::M }>>,
    cmd: Box<Command<{ common::M }>>,
    ctrl: Box<Controller<{ common::M }>>,
}

fn setup(m: usize, active_set: bool) -> State {
    let mut ctrl = common::controller();
    ctrl.params.active_set = active_set;
    State {
        frame: common::frame(m, 11),
        cmd: common::command(),
        ctrl,
    }
}

/// A controller that has stepped the first of two frames a control period apart
/// (`common::drifting_frames`), and the second frame, to be stepped.
fn setup_drifting(m: usize) -> State {
    let [first, frame] = common::drifting_frames(m, 11);
    let (mut ctrl, mut cmd) = (common::controller(), common::command());
    let _ = ctrl.step(&first, &mut cmd);
    State { frame, cmd, ctrl }
}

#[library_benchmark]
#[bench::inverse_step_m30(args = (30, true), setup = setup)]
#[bench::inverse_step_m120(args = (120, true), setup = setup)]
#[bench::inverse_step_m120_plain_gs(args = (120, false), setup = setup)]
#[bench::inverse_step_m192(args = (192, true), setup = setup)]
#[bench::inverse_step_m120_drifting(args = (120,), setup = setup_drifting)]
#[bench::inverse_step_m192_drifting(args = (192,), setup = setup_drifting)]
fn inverse_step(mut s: State) -> SolverReport {
    let rep = s.ctrl.step(black_box(&s.frame), &mut s.cmd);
    black_box(rep.unwrap_or_default())
}

library_benchmark_group!(name = inverse; benchmarks = inverse_step);

main!(library_benchmark_groups = inverse);

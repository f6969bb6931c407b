//! Probes the constrained map from the joints to the tip at one step of a run: how the
//! controller's linear model (a forward difference of `joint_step`) compares with the map at
//! smaller steps and on both sides, and how far random joint steps of a few sizes can bring the
//! tip's error down. For understanding a step the controller cannot make (every planned step
//! rejected by its confirming solve, the joints held): a nonsmooth map, or a target out of reach.
//! Also prints the scene's steering length `(E_n I / E_gel)^(1/4)` and the singular values of the
//! tip's Jacobian by differences of 10⁻⁴ rad (how far the joints still move the tip sideways).
//!
//! ```sh
//! cargo run --release -p needle-host --example probe_step -- scenes/suite/helix_half.toml 390 \
//!     insertion.max_lead=0.5
//! ```
//!
//! Arguments: the scene file, the step to probe (0-based), then any `field=value` overrides as
//! `needle run --set` takes them. The 6-joint scenes only.

use needle_bridge::{ExchangeReport, Transport, TransportError};
use needle_core::payload::{Command, ComplianceFrame};
use needle_core::{Controller, InverseParams, Robot};
use needle_host::scene::Scene;
use needle_host::setup::Setup;
use needle_host::step::{Pipeline, ROWS};
use std::process::ExitCode;

/// The core in this process, with a second controller that probes the frame of step `at`.
struct Probe {
    controller: Box<Controller<ROWS, 6>>,
    probe: Box<Controller<ROWS, 6>>,
    at: usize,
    step: usize,
}

/// The tip's error `|T[0..3]|` [mm].
fn tip_error(t: &[f64; 4]) -> f64 {
    (t[0] * t[0] + t[1] * t[1] + t[2] * t[2]).sqrt()
}

impl Probe {
    fn new(robot: Robot<6>, params: InverseParams, at: usize) -> Self {
        Self {
            controller: Controller::new_boxed(robot, params),
            probe: Controller::new_boxed(robot, params),
            at,
            step: 0,
        }
    }

    fn objective(&mut self, frame: &ComplianceFrame<ROWS, 6>, q: &[f64; 6]) -> [f64; 4] {
        self.probe
            .objective_at(frame, q)
            .map_or([f64::NAN; 4], |o| o.t)
    }

    /// Prints the probes of `frame`.
    fn report(&mut self, frame: &ComplianceFrame<ROWS, 6>, joint_step: f64) {
        let q = frame.q;
        let t0 = self.objective(frame, &q);
        println!(
            "T(q) = [{:+.4} {:+.4} {:+.4}] mm, |e| {:.4} mm, {} rows",
            t0[0],
            t0[1],
            t0[2],
            tip_error(&t0),
            frame.rows()
        );
        println!("∂e/∂q_i by differences of h [mm/rad] (the controller's h = {joint_step}):");
        let mut local = nalgebra::Matrix3x6::<f64>::zeros();
        for h in [joint_step, 1e-3, 1e-4, -1e-4, -1e-3, -joint_step] {
            print!("  h {h:+.0e}:");
            for i in 0..6 {
                let mut qi = q;
                qi[i] += h;
                let t = self.objective(frame, &qi);
                let d = [0, 1, 2].map(|r| (t[r] - t0[r]) / h);
                if h == 1e-4 {
                    for (r, x) in d.iter().enumerate() {
                        local[(r, i)] = *x;
                    }
                }
                print!(" q{}[{:+7.2} {:+7.2} {:+7.2}]", i + 1, d[0], d[1], d[2]);
            }
            println!();
        }
        // How far the joints can move the tip in each direction: along the needle (σ₁) and
        // sideways (σ₂, σ₃), which the gel holding the shaft takes away.
        let mut sigma: Vec<f64> = local.singular_values().iter().copied().collect();
        sigma.sort_by(|a, b| b.total_cmp(a));
        println!(
            "singular values of the tip's Jacobian (h = 1e-4): {:.2} / {:.2} / {:.2} mm/rad",
            sigma[0], sigma[1], sigma[2]
        );
        // A fixed seed: the same probes on every run.
        let mut seed = 0x5eed_u64;
        let mut uniform = || {
            seed = seed
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            ((seed >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
        };
        println!("best of 300 random joint steps of each size:");
        for size in [3e-4, 1e-3, 3e-3, 1e-2, 3e-2] {
            let mut best = (f64::INFINITY, [0.0; 6]);
            for _ in 0..300 {
                let mut d: [f64; 6] = core::array::from_fn(|_| uniform());
                let n = d.iter().map(|x| x * x).sum::<f64>().sqrt();
                let mut qi = q;
                for i in 0..6 {
                    d[i] *= size / n;
                    qi[i] += d[i];
                }
                let e = tip_error(&self.objective(frame, &qi));
                if e < best.0 {
                    best = (e, d);
                }
            }
            println!(
                "  |Δq| {size:.0e} rad: |e| {:.4} mm at Δq {:?}",
                best.0,
                best.1.map(|x| (x * 1e5).round() / 1e5)
            );
        }
    }
}

impl Transport<ROWS, 6> for Probe {
    fn exchange(
        &mut self,
        frame: &ComplianceFrame<ROWS, 6>,
        cmd: &mut Command<ROWS, 6>,
    ) -> Result<ExchangeReport, TransportError> {
        let r = self
            .controller
            .step(frame, cmd)
            .map_err(TransportError::Core)?;
        if self.step == self.at {
            println!(
                "step {}: the controller's flags {:#b}, Δq {:?}",
                self.step,
                r.flags,
                r.delta_q.map(|x| (x * 1e6).round() / 1e6)
            );
            let h = self.controller.params.joint_step;
            self.report(frame, h);
        }
        self.step += 1;
        Ok(ExchangeReport::default())
    }
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (Some(file), Some(at)) = (args.first(), args.get(1).and_then(|a| a.parse().ok())) else {
        eprintln!("usage: probe_step <scene.toml> <step> [field=value …]");
        return ExitCode::from(2);
    };
    let overrides: Vec<(String, String)> = args[2..]
        .iter()
        .filter_map(|a| a.split_once('=').map(|(k, v)| (k.into(), v.into())))
        .collect();
    let scene =
        match Scene::load(std::path::Path::new(file)).and_then(|s| s.with_overrides(&overrides)) {
            Ok(s) => s,
            Err(e) => {
                eprintln!("error: {e}");
                return ExitCode::from(2);
            }
        };
    // The length over which the needle bends as a beam on an elastic foundation (the gel):
    // short, and the gel holds the shaft so that the base barely steers the tip deep inside.
    let (d, e_n, e_gel) = (
        scene.needle.diameter,
        scene.needle.young_modulus,
        scene.gel.young_modulus,
    );
    println!(
        "steering length (E_n I / E_gel)^(1/4) = {:.1} mm (needle Ø {d} mm, E_n {e_n} MPa, gel {e_gel} MPa)",
        needle_host::setup::steering_length(d, e_n, e_gel)
    );
    let setup = match Setup::build(&scene) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::from(2);
        }
    };
    let (mut world, params) = (setup.world, setup.params);
    let mut core = Probe::new(setup.robot, setup.inverse, at);
    let mut pipeline = Pipeline::new(&world);
    for _ in 0..=at {
        match pipeline.step(&mut world, &params, &mut core) {
            Ok(r) if r.step == at => println!(
                "after step {at}: error {:.4} mm, depth {:.3} mm",
                r.error, r.depth
            ),
            Ok(_) => {}
            Err(e) => {
                eprintln!("error: step {}: {e}", world.steps);
                return ExitCode::FAILURE;
            }
        }
    }
    ExitCode::SUCCESS
}

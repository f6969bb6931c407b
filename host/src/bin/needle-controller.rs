//! `needle-controller`: the core's process of a two-process run. It links `needle-core` the way
//! a robot controller would and talks to `needle serve` over iceoryx2 shared memory
//! (`needle-bridge`): a fixed-rate loop (default 1 kHz) that solves the inverse step over the
//! newest frame and publishes the command; without a fresh frame for the deadline (default
//! 50 ms) it holds the robot (re-commands the last joints) and resumes when a host publishes
//! again.
//!
//! It reads the same scene as `needle serve` only to build the robot chain (6 or 7 joints, the
//! scene's) and the inverse tuning (`needle_host::setup::core`); the frames carry a fingerprint
//! of that set-up and the joint count, and a controller started with another scene rejects them
//! (one of another joint count is refused at connect: the two sides' payloads differ). At run
//! time it uses `needle-core` and `needle-bridge` only.
//!
//! ```sh
//! needle serve complex            # terminal 1
//! needle-controller complex       # terminal 2
//! ```

use clap::Parser;
use needle_bridge::{BridgeConfig, ControllerOptions, run_controller};
use needle_host::error::{SetupError, chain};
use needle_host::joints::{WithJoints, with_joints};
use needle_host::scene::Scene;
use needle_host::setup;
use needle_host::step::ROWS;
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

#[derive(Parser)]
#[command(
    name = "needle-controller",
    version,
    about = "Inverse controller process: solves over the frames of `needle serve` (iceoryx2 shared memory)"
)]
struct Cli {
    /// The scene `needle serve` runs: a file, or an embedded name (`simple`, `complex`).
    #[arg(default_value = "complex")]
    scene: String,
    /// Service-name prefix shared with `needle serve --instance`.
    #[arg(long, default_value = "needle")]
    instance: String,
    /// Loop rate [Hz]; 0: answer every frame as soon as it arrives.
    #[arg(long, default_value_t = 1000.0)]
    rate: f64,
    /// Hold the robot when no fresh frame arrived for this long [ms].
    #[arg(long, default_value_t = 50.0)]
    deadline_ms: f64,
    /// Stop after this many seconds (default: until Ctrl-C).
    #[arg(long)]
    run_for: Option<f64>,
    /// Stop after solving this many frames.
    #[arg(long)]
    max_frames: Option<u64>,
    /// Do not print events.
    #[arg(long)]
    quiet: bool,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    // Its events (sessions, rejected frames, holds) at info level unless --quiet; `RUST_LOG`
    // overrides.
    needle_host::logs::init(if cli.quiet { "warn" } else { "info" });
    let scene = match Scene::open(&cli.scene) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::from(2);
        }
    };
    let valid = cli.deadline_ms.is_finite()
        && cli.deadline_ms > 0.0
        && cli.rate.is_finite()
        && cli.rate >= 0.0;
    if !valid {
        eprintln!("error: --deadline-ms must be positive and --rate non-negative");
        return ExitCode::from(2);
    }
    needle_bridge::shm::quiet_logs();
    let opts = ControllerOptions {
        bridge: BridgeConfig {
            instance: cli.instance,
            deadline: Duration::from_secs_f64(cli.deadline_ms * 1e-3),
            handle_signals: true,
            ..BridgeConfig::default()
        },
        rate_hz: cli.rate,
        run_for: cli.run_for.map(Duration::from_secs_f64),
        max_frames: cli.max_frames,
        verbose: !cli.quiet,
    };
    let n = match scene.joint_count() {
        Ok(n) => n,
        Err((field, reason)) => {
            eprintln!("error: {}", chain(&SetupError::Robot { field, reason }));
            return ExitCode::FAILURE;
        }
    };
    eprintln!(
        "needle-controller: scene {} · {n} joints · {} Hz · deadline {} ms · frames from {}",
        scene.name,
        opts.rate_hz,
        cli.deadline_ms,
        opts.bridge.frame_service_name()
    );
    with_joints(
        n,
        Controller {
            scene: &scene,
            opts: &opts,
        },
    )
    .unwrap_or_else(|| {
        eprintln!(
            "error: robot: a robot of {n} joints; the two-process mode runs arms of 6 or 7 joints"
        );
        ExitCode::FAILURE
    })
}

/// The controller loop for the scene's robot of `N` joints.
struct Controller<'a> {
    scene: &'a Scene,
    opts: &'a ControllerOptions,
}

impl WithJoints for Controller<'_> {
    type Output = ExitCode;
    fn with<const N: usize>(self) -> ExitCode {
        let (robot, inverse) = match setup::core::<N>(self.scene) {
            Ok(c) => c,
            Err(e) => {
                eprintln!("error: {}", chain(&e));
                return ExitCode::FAILURE;
            }
        };
        match run_controller::<ROWS, N>(robot, inverse, self.opts, &AtomicBool::new(false)) {
            Ok(stats) => {
                println!("needle-controller: {stats}");
                ExitCode::SUCCESS
            }
            Err(e) => {
                eprintln!("error: {}", chain(&e));
                ExitCode::FAILURE
            }
        }
    }
}

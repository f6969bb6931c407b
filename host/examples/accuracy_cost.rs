//! The default gel pipeline's accuracy cost, scene by scene, without the closed loop's
//! amplification: each scene runs closed loop with the exact step (the whole corotational gel
//! factorised at every step, in double precision: `solver.background_factorization = false`,
//! `solver.factor_precision = "double"`, `solver.far_elements = "corotational"`), then its
//! joints are replayed open loop (one constraint solve at each step's joints) with the
//! scene's own settings — the default pipeline. Both runs then take the same joints, so the
//! differences of e_mean, e_max and e_final are what the pipeline costs, not where a chaotic
//! closed loop happens to land.
//!
//! ```sh
//! cargo run --release -p needle-host --example accuracy_cost            # benchmarks + scenes/suite
//! cargo run --release -p needle-host --example accuracy_cost -- scenes/suite/arc_x.toml complex
//! cargo run --release -p needle-host --example accuracy_cost -- --set 'solver.far_elements="corotational"'
//! ```
//!
//! `--set FIELD=VALUE` (repeatable) changes the replayed pipeline, as `needle run --set` does.
//!
//! Prints one row per scene and the count of scenes within 0.05 mm on all three; exits 1 if a
//! scene cannot be set up or run.

use needle_host::run::{RunOptions, RunSummary, replay, run};
use needle_host::scene::Scene;
use needle_host::suite::{SuiteOptions, scene_list};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// The exact step's overrides.
const EXACT: [(&str, &str); 3] = [
    ("solver.background_factorization", "false"),
    ("solver.factor_precision", "\"double\""),
    ("solver.far_elements", "\"corotational\""),
];

/// The tolerance of issue "speed" on e_mean, e_max and e_final [mm].
const TOLERANCE_MM: f64 = 0.05;

/// A scene by embedded name or file.
fn load(name: &str, file: Option<&Path>) -> Result<Scene, String> {
    match file {
        Some(f) => Scene::load(f).map_err(|e| e.to_string()),
        None => Scene::builtin(name).ok_or_else(|| format!("no embedded scene `{name}`")),
    }
}

/// The scenes `needle suite` runs: the benchmarks, then `scenes/suite/` in name order.
fn default_scenes() -> Vec<(String, Option<PathBuf>)> {
    let opts = SuiteOptions {
        dir: PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../scenes/suite")),
        benchmarks: true,
        overrides: Vec::new(),
        nodes: None,
        steps: None,
        variants: Vec::new(),
    };
    scene_list(&opts).unwrap_or_default()
}

/// The exact closed loop's summary and the default pipeline's replay of its joints.
fn compare(scene: &Scene) -> Result<(RunSummary, RunSummary), String> {
    let exact_overrides: Vec<(String, String)> = (EXACT.iter())
        .map(|(f, v)| (f.to_string(), v.to_string()))
        .collect();
    let exact = scene
        .with_overrides(&exact_overrides)
        .map_err(|e| e.to_string())?;
    let closed = run(&exact, &RunOptions::default(), |_| {}).map_err(|e| e.to_string())?;
    let joints: Vec<[f64; 6]> = (closed.reports.iter())
        .map(|r| {
            r.q.to_array::<6>()
                .ok_or("only 6-joint arms are replayed here")
        })
        .collect::<Result<_, _>>()?;
    let replayed = replay(scene, joints).map_err(|e| e.to_string())?;
    Ok((closed.summary, replayed.summary))
}

fn main() -> ExitCode {
    let mut args: Vec<String> = Vec::new();
    let mut overrides: Vec<(String, String)> = Vec::new();
    let mut it = std::env::args().skip(1);
    while let Some(a) = it.next() {
        if a == "--set" {
            let Some((f, v)) = it.next().and_then(|kv| {
                kv.split_once('=')
                    .map(|(f, v)| (f.trim().to_owned(), v.trim().to_owned()))
            }) else {
                eprintln!("--set needs FIELD=VALUE");
                return ExitCode::from(2);
            };
            overrides.push((f, v));
        } else {
            args.push(a);
        }
    }
    let names: Vec<(String, Option<PathBuf>)> = if args.is_empty() {
        default_scenes()
    } else {
        // An embedded scene by name, else a file.
        (args.into_iter())
            .map(|a| match Scene::builtin(&a) {
                Some(_) => (a, None),
                None => (a.clone(), Some(PathBuf::from(a))),
            })
            .collect()
    };
    println!(
        "| scene | exact e_mean / e_max / e_final [mm] | default pipeline, same joints | largest difference |"
    );
    println!("|---|---|---|---|");
    let (mut within, mut total, mut failed) = (0, 0, 0);
    let mut worst = (0.0f64, String::new());
    for (name, file) in &names {
        let short = file
            .as_deref()
            .and_then(Path::file_stem)
            .map_or_else(|| name.clone(), |s| s.to_string_lossy().into_owned());
        let result = load(name, file.as_deref())
            .and_then(|scene| scene.with_overrides(&overrides).map_err(|e| e.to_string()))
            .and_then(|scene| compare(&scene));
        let (a, b) = match result {
            Ok(pair) => pair,
            Err(e) => {
                eprintln!("{name}: {e}");
                failed += 1;
                continue;
            }
        };
        let triple = |s: &RunSummary| [s.e_mean_mm, s.e_max_mm, s.e_final_mm];
        let (ta, tb) = (triple(&a), triple(&b));
        let diff = (0..3).map(|k| (ta[k] - tb[k]).abs()).fold(0.0, f64::max);
        total += 1;
        if diff <= TOLERANCE_MM {
            within += 1;
        }
        if !(diff <= worst.0) {
            worst = (diff, short.clone());
        }
        println!(
            "| `{short}` | {:.3} / {:.3} / {:.3} | {:.3} / {:.3} / {:.3} | {diff:.3} |",
            ta[0], ta[1], ta[2], tb[0], tb[1], tb[2]
        );
    }
    println!(
        "\n{within} of {total} scenes within {TOLERANCE_MM} mm of the exact step on e_mean, e_max \
         and e_final; the largest difference {:.3} mm (`{}`){}",
        worst.0,
        worst.1,
        if failed > 0 {
            format!("; {failed} scenes could not run")
        } else {
            String::new()
        }
    );
    if failed > 0 {
        ExitCode::FAILURE
    } else {
        ExitCode::SUCCESS
    }
}

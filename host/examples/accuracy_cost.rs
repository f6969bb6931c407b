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
//! Prints one row per scene and the count of scenes within 0.05 mm on all three. Each row also
//! gives how many steps, from the first, end with the two runs' tips within 0.05 mm of each
//! other, and the tips' largest distance: where a replay departs (a contact that slips in one
//! run and sticks in the other) shows as its first step out. Exits 1 if a
//! scene cannot be set up or run. `needle report` prints the same comparison for the default
//! pipeline and the linear far field side by side (`needle_host::accuracy` is the code of
//! both).

use needle_host::accuracy::{AccuracyCost, TOLERANCE_MM, exact_run, replayed};
use needle_host::scene::Scene;
use needle_host::suite::{SuiteOptions, load_scene, scene_list};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

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

/// The exact closed loop and the default pipeline's replay of its joints.
fn compare(scene: &Scene) -> Result<AccuracyCost, String> {
    let exact = exact_run(scene, None).map_err(|e| e.to_string())?;
    replayed(scene, &exact).map_err(|e| e.to_string())
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
        "| scene | exact e_mean / e_max / e_final [mm] | default pipeline, same joints | largest difference | tips within {TOLERANCE_MM} mm for | tips' largest distance |"
    );
    println!("|---|---|---|---|---|---|");
    let (mut within, mut total, mut failed) = (0, 0, 0);
    let mut worst = (0.0f64, String::new());
    for (name, file) in &names {
        let short = file
            .as_deref()
            .and_then(Path::file_stem)
            .map_or_else(|| name.clone(), |s| s.to_string_lossy().into_owned());
        let result = load_scene(name, file.as_deref())
            .and_then(|scene| scene.with_overrides(&overrides).map_err(|e| e.to_string()))
            .and_then(|scene| compare(&scene));
        let cost = match result {
            Ok(cost) => cost,
            Err(e) => {
                eprintln!("{name}: {e}");
                failed += 1;
                continue;
            }
        };
        let (a, b) = (cost.exact, cost.pipeline);
        let diff = cost.largest_difference_mm();
        total += 1;
        if cost.within(TOLERANCE_MM) {
            within += 1;
        }
        if diff.is_nan() || diff > worst.0 {
            worst = (diff, short.clone());
        }
        println!(
            "| `{short}` | {:.3} / {:.3} / {:.3} | {:.3} / {:.3} / {:.3} | {diff:.3} | {} of {} steps | {:.3} |",
            a.e_mean_mm,
            a.e_max_mm,
            a.e_final_mm,
            b.e_mean_mm,
            b.e_max_mm,
            b.e_final_mm,
            cost.agreeing_steps,
            cost.steps,
            cost.tip_difference_max_mm
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

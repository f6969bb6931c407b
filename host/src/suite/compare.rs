//! `needle compare BEFORE AFTER`: two runs of the suite (`suite.json`, from `needle suite`)
//! scene by scene, for one controller — which targets were gained or lost, which scenes moved
//! by more than a tolerance on e_mean, e_max, e_final or their smallest obstacle clearance, which
//! came closer to an obstacle by more than it, how many are equal in every compared field, and
//! each run's means and worst cases. The question every configuration change asks
//! of the suite ("one default configuration, every scene"), answered the same way each time.
//!
//! The files are read as JSON values, not as [`super::SuiteRow`]s: a `suite.json` written by an
//! older `needle` (fewer summary fields) still compares on the fields both have.

use crate::bounded_read::read_bounded;
use serde_json::Value;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Largest `suite.json` read [bytes] (a suite of 100 scenes under two controllers is ~1 MB).
const MAX_FILE_BYTES: u64 = 256 << 20;

/// The summary fields compared, in the order printed.
const ERRORS: [&str; 3] = ["e_mean_mm", "e_max_mm", "e_final_mm"];

/// Why a `suite.json` could not be compared; each names the file.
#[derive(Debug, thiserror::Error)]
pub enum CompareError {
    /// The file could not be read.
    #[error("{}: {source}", path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The file is not a suite's JSON.
    #[error("{}: {reason}", path.display())]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong, naming the row and field.
        reason: String,
    },
}

/// One scene's figures under the controller compared.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneFigures {
    /// `reached`, `missed_target`, `obstacle_hit`, `diverged`, …; `failed` when the scene
    /// could not run (the row's `failure`).
    pub outcome: String,
    /// e_mean, e_max, e_final [mm] (NaN where the run has none).
    pub errors: [f64; 3],
    /// Smallest clearance to an obstacle [mm]; `+∞` without obstacles.
    pub min_clearance_mm: f64,
    /// Steps run.
    pub steps: u64,
    /// CPU time per step [ms] (not compared: the machine's load moves it).
    pub cpu_ms_per_step: f64,
}

impl SceneFigures {
    fn reached(&self) -> bool {
        self.outcome == "reached"
    }
}

/// The scenes of one `suite.json` under `controller`, by name.
///
/// # Errors
/// [`CompareError`] naming the file, and for a malformed row its index and field.
pub fn load(path: &Path, controller: &str) -> Result<BTreeMap<String, SceneFigures>, CompareError> {
    let bytes = read_bounded(path, MAX_FILE_BYTES).map_err(|source| CompareError::Read {
        path: path.to_owned(),
        source,
    })?;
    let fail = |reason: String| CompareError::Format {
        path: path.to_owned(),
        reason,
    };
    let value: Value = serde_json::from_slice(&bytes).map_err(|e| {
        fail(format!(
            "not JSON ({e}); expected the suite.json of `needle suite`"
        ))
    })?;
    let rows = value.as_array().ok_or_else(|| {
        fail("expected a JSON array of rows (the suite.json of `needle suite`)".into())
    })?;
    let mut scenes = BTreeMap::new();
    for (i, row) in rows.iter().enumerate() {
        let text = |field: &str| {
            row.get(field)
                .and_then(Value::as_str)
                .ok_or_else(|| fail(format!("row {i}: field `{field}`: missing or not a string")))
        };
        let scene = text("scene")?;
        if text("controller")? != controller {
            continue;
        }
        let figures = match row.get("summary").filter(|s| !s.is_null()) {
            Some(s) => figures(s).map_err(|(field, why)| {
                fail(format!(
                    "row {i} (`{scene}`): field `summary.{field}`: {why}"
                ))
            })?,
            None => SceneFigures {
                outcome: "failed".into(),
                errors: [f64::NAN; 3],
                min_clearance_mm: f64::INFINITY,
                steps: 0,
                cpu_ms_per_step: f64::NAN,
            },
        };
        if scenes.insert(scene.to_owned(), figures).is_some() {
            return Err(fail(format!(
                "row {i}: scene `{scene}` twice under controller `{controller}`"
            )));
        }
    }
    if scenes.is_empty() {
        return Err(fail(format!("no row of controller `{controller}`")));
    }
    Ok(scenes)
}

/// The compared fields of a run's summary; `(field, reason)` for a missing or mistyped one.
fn figures(s: &Value) -> Result<SceneFigures, (&'static str, &'static str)> {
    let number = |field: &'static str| match s.get(field) {
        Some(Value::Null) => Ok(f64::NAN),
        Some(v) => v.as_f64().ok_or((field, "not a number")),
        None => Err((field, "missing")),
    };
    let outcome = s
        .get("outcome")
        .and_then(Value::as_str)
        .ok_or(("outcome", "missing or not a string"))?
        .to_owned();
    let mut errors = [0.0; 3];
    for (e, field) in errors.iter_mut().zip(ERRORS) {
        *e = number(field)?;
    }
    // `null` when the scene has no obstacle (JSON has no infinity).
    let min_clearance_mm = match s.get("min_clearance_mm") {
        None | Some(Value::Null) => f64::INFINITY,
        Some(v) => v.as_f64().ok_or(("min_clearance_mm", "not a number"))?,
    };
    let steps = s
        .get("steps")
        .and_then(Value::as_u64)
        .ok_or(("steps", "missing or not a count"))?;
    Ok(SceneFigures {
        outcome,
        errors,
        min_clearance_mm,
        steps,
        cpu_ms_per_step: number("cpu_ms_per_step")?,
    })
}

/// What the comparison found.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Comparison {
    /// Scenes in both files whose compared fields (outcome, e_mean, e_max, e_final, smallest
    /// clearance, steps) are all equal.
    pub equal: usize,
    /// Scenes in both files.
    pub common: usize,
    /// Reached before, not after.
    pub lost: Vec<String>,
    /// Reached after, not before.
    pub gained: Vec<String>,
    /// Scenes whose e_mean, e_max, e_final or smallest clearance moved by more than the
    /// tolerance, or whose outcome changed, one line each.
    pub moved: Vec<String>,
    /// Scenes whose smallest clearance fell by more than the tolerance (a scene without an
    /// obstacle before and with a finite clearance after counts), whatever their errors did.
    pub closer: Vec<String>,
    /// Scenes in one file only.
    pub unmatched: Vec<String>,
    /// The whole report, for the terminal (Markdown).
    pub text: String,
}

/// Compares `after` with `before` (scenes of one controller, from [`load`]); a scene moves
/// when an error or its smallest clearance changes by more than `tolerance` mm (NaN on one side
/// and not the other counts; so does a clearance finite on one side only).
pub fn compare(
    before: &BTreeMap<String, SceneFigures>,
    after: &BTreeMap<String, SceneFigures>,
    tolerance: f64,
) -> Comparison {
    let mut c = Comparison::default();
    let mut rows = String::new();
    for (name, b) in before {
        let Some(a) = after.get(name) else {
            c.unmatched.push(format!("{name} (before only)"));
            continue;
        };
        c.common += 1;
        let same = |x: f64, y: f64| x == y || (x.is_nan() && y.is_nan());
        if a.outcome == b.outcome
            && (0..3).all(|k| same(a.errors[k], b.errors[k]))
            && same(a.min_clearance_mm, b.min_clearance_mm)
            && a.steps == b.steps
        {
            c.equal += 1;
            continue;
        }
        let moved_by = |k: usize| {
            let d = (a.errors[k] - b.errors[k]).abs();
            d > tolerance || (d.is_nan() && !same(a.errors[k], b.errors[k]))
        };
        if b.reached() && !a.reached() {
            c.lost.push(name.clone());
        }
        if a.reached() && !b.reached() {
            c.gained.push(name.clone());
        }
        let (cb, ca) = (b.min_clearance_mm, a.min_clearance_mm);
        let clearance_moved = if cb.is_finite() && ca.is_finite() {
            (ca - cb).abs() > tolerance
        } else {
            !same(ca, cb)
        };
        if clearance_moved && ca.partial_cmp(&cb) != Some(std::cmp::Ordering::Greater) {
            c.closer.push(name.clone());
        }
        if a.outcome != b.outcome || (0..3).any(moved_by) || clearance_moved {
            let cell = |k: usize| format!("{} → {}", mm(b.errors[k]), mm(a.errors[k]));
            let _ = writeln!(
                rows,
                "| `{name}` | {} → {} | {} | {} | {} | {} → {} |",
                b.outcome,
                a.outcome,
                cell(0),
                cell(1),
                cell(2),
                mm(b.min_clearance_mm),
                mm(a.min_clearance_mm)
            );
            c.moved.push(name.clone());
        }
    }
    for name in after.keys().filter(|n| !before.contains_key(*n)) {
        c.unmatched.push(format!("{name} (after only)"));
    }
    let t = &mut c.text;
    let _ = writeln!(
        t,
        "{} of {} scenes equal in every compared field; {} moved by more than {tolerance} mm \
         on e_mean, e_max, e_final or smallest clearance, or changed outcome\n",
        c.equal,
        c.common,
        c.moved.len()
    );
    if !rows.is_empty() {
        t.push_str("| scene | outcome | e_mean [mm] | e_max [mm] | e_final [mm] | smallest clearance [mm] |\n");
        t.push_str("|---|---|---|---|---|---|\n");
        t.push_str(&rows);
        t.push('\n');
    }
    let list = |v: &[String]| {
        if v.is_empty() {
            "none".to_owned()
        } else {
            v.iter()
                .map(|s| format!("`{s}`"))
                .collect::<Vec<_>>()
                .join(", ")
        }
    };
    let _ = writeln!(t, "- targets lost: {}", list(&c.lost));
    let _ = writeln!(t, "- targets gained: {}", list(&c.gained));
    let _ = writeln!(
        t,
        "- closer to an obstacle by more than {tolerance} mm: {}",
        list(&c.closer)
    );
    if !c.unmatched.is_empty() {
        let _ = writeln!(t, "- in one file only: {}", c.unmatched.join(", "));
    }
    let common = |m: &BTreeMap<String, SceneFigures>| {
        m.iter()
            .filter(|(k, _)| before.contains_key(*k) && after.contains_key(*k))
            .map(|(_, v)| v.clone())
            .collect::<Vec<_>>()
    };
    let _ = writeln!(t, "- before: {}", aggregate(&common(before)));
    let _ = writeln!(t, "- after:  {}", aggregate(&common(after)));
    c
}

/// Reached; mean and worst e_mean / e_max / e_final; smallest clearance; mean CPU per step.
fn aggregate(scenes: &[SceneFigures]) -> String {
    let n = scenes.len();
    let reached = scenes.iter().filter(|s| s.reached()).count();
    let finite = |k: usize| {
        scenes
            .iter()
            .map(move |s| s.errors[k])
            .filter(|x| x.is_finite())
    };
    let mean = |k: usize| {
        let v: Vec<f64> = finite(k).collect();
        v.iter().sum::<f64>() / v.len().max(1) as f64
    };
    let worst = |k: usize| finite(k).fold(f64::NAN, f64::max);
    let clearance = scenes
        .iter()
        .map(|s| s.min_clearance_mm)
        .fold(f64::INFINITY, f64::min);
    let cpu: Vec<f64> = scenes
        .iter()
        .map(|s| s.cpu_ms_per_step)
        .filter(|x| x.is_finite())
        .collect();
    format!(
        "reached {reached} / {n}; mean e_mean / e_max / e_final {} / {} / {} mm; worst {} / {} / {} mm; \
         smallest clearance {} mm; mean CPU per step {:.2} ms",
        mm(mean(0)),
        mm(mean(1)),
        mm(mean(2)),
        mm(worst(0)),
        mm(worst(1)),
        mm(worst(2)),
        mm(clearance),
        cpu.iter().sum::<f64>() / cpu.len().max(1) as f64
    )
}

/// Millimetres to 3 decimals; `∞` and `—` for the infinite and the missing.
fn mm(x: f64) -> String {
    if x.is_nan() {
        "—".into()
    } else if x.is_infinite() {
        "∞".into()
    } else {
        format!("{x:.3}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(
        scene: &str,
        controller: &str,
        outcome: &str,
        e: [f64; 3],
        clearance: Option<f64>,
    ) -> Value {
        serde_json::json!({
            "scene": scene,
            "controller": controller,
            "summary": {
                "outcome": outcome,
                "e_mean_mm": e[0],
                "e_max_mm": e[1],
                "e_final_mm": e[2],
                "min_clearance_mm": clearance,
                "steps": 600,
                "cpu_ms_per_step": 1.5,
            },
            "failure": null,
            "wall_s": 1.0,
        })
    }

    /// A fresh folder under the system's temporary folder, removed when dropped.
    fn temp_dir(test: &str) -> tempfile::TempDir {
        let prefix = format!("needle-compare-{test}-");
        (tempfile::Builder::new().prefix(&prefix).tempdir()).unwrap()
    }

    fn write(dir: &Path, name: &str, rows: &[Value]) -> PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, serde_json::to_string(rows).unwrap()).unwrap();
        p
    }

    /// Equal scenes are counted, not listed; a target lost and one gained are named; a move
    /// within the tolerance is not one; rows of another controller are left out; the means
    /// are over the scenes both files have.
    #[test]
    fn compare_names_lost_gained_and_moved_scenes() {
        let tmp = temp_dir("names");
        let dir = tmp.path();
        let before = write(
            dir,
            "before.json",
            &[
                row("same", "default", "reached", [0.1, 0.2, 0.01], None),
                row("lost", "default", "reached", [0.1, 0.2, 0.3], Some(0.5)),
                row(
                    "gained",
                    "default",
                    "missed_target",
                    [1.0, 3.0, 2.0],
                    Some(0.3),
                ),
                row("small", "default", "reached", [0.1, 0.2, 0.3], None),
                row("same", "paper", "missed_target", [9.0, 9.0, 9.0], None),
                row("gone", "default", "reached", [0.1, 0.1, 0.1], None),
            ],
        );
        let after = write(
            dir,
            "after.json",
            &[
                row("same", "default", "reached", [0.1, 0.2, 0.01], None),
                row(
                    "lost",
                    "default",
                    "missed_target",
                    [0.2, 0.9, 1.3],
                    Some(0.2),
                ),
                row("gained", "default", "reached", [0.3, 0.8, 0.1], Some(0.25)),
                row("small", "default", "reached", [0.11, 0.2, 0.3], None),
                row("same", "paper", "reached", [0.0, 0.0, 0.0], None),
            ],
        );
        let b = load(&before, "default").unwrap();
        let a = load(&after, "default").unwrap();
        let c = compare(&b, &a, 0.05);
        assert_eq!(c.common, 4);
        assert_eq!(c.equal, 1, "{}", c.text);
        assert_eq!(c.lost, ["lost"]);
        assert_eq!(c.gained, ["gained"]);
        assert_eq!(c.moved, ["gained", "lost"], "{}", c.text);
        assert_eq!(c.unmatched, ["gone (before only)"]);
        assert!(c.text.contains("| `lost` | reached → missed_target | 0.100 → 0.200 | 0.200 → 0.900 | 0.300 → 1.300 | 0.500 → 0.200 |"), "{}", c.text);
        assert!(c.text.contains("before: reached 3 / 4; mean e_mean / e_max / e_final 0.325 / 0.900 / 0.652 mm; worst 1.000 / 3.000 / 2.000 mm; smallest clearance 0.300 mm"), "{}", c.text);
        assert!(c.text.contains("after:  reached 3 / 4"), "{}", c.text);
        // The paper's rows alone: one scene, moved and gained.
        let c = compare(
            &load(&before, "paper").unwrap(),
            &load(&after, "paper").unwrap(),
            0.05,
        );
        assert_eq!((c.common, c.gained.len()), (1, 1));
    }

    /// A scene whose errors held but which came closer to its obstacle is a moved scene and is
    /// named as closer; one that moved away is moved, not closer; a change within the tolerance
    /// is neither; an obstacle appearing (clearance finite after, none before) is closer.
    #[test]
    fn a_scene_closer_to_its_obstacle_is_named_though_its_errors_held() {
        let tmp = temp_dir("closer");
        let dir = tmp.path();
        let e = [0.1, 0.2, 0.01];
        let before = write(
            dir,
            "before.json",
            &[
                row("closer", "default", "reached", e, Some(0.5)),
                row("away", "default", "reached", e, Some(0.2)),
                row("within", "default", "reached", e, Some(0.5)),
                row("appears", "default", "reached", e, None),
            ],
        );
        let after = write(
            dir,
            "after.json",
            &[
                row("closer", "default", "reached", e, Some(0.2)),
                row("away", "default", "reached", e, Some(0.5)),
                row("within", "default", "reached", e, Some(0.46)),
                row("appears", "default", "reached", e, Some(1.0)),
            ],
        );
        let c = compare(
            &load(&before, "default").unwrap(),
            &load(&after, "default").unwrap(),
            0.05,
        );
        assert_eq!(c.moved, ["appears", "away", "closer"], "{}", c.text);
        assert_eq!(c.closer, ["appears", "closer"], "{}", c.text);
        assert_eq!(c.equal, 0);
        assert!(
            c.text.contains("| `closer` | reached → reached | 0.100 → 0.100 | 0.200 → 0.200 | 0.010 → 0.010 | 0.500 → 0.200 |"),
            "{}",
            c.text
        );
        assert!(
            c.text
                .contains("- closer to an obstacle by more than 0.05 mm: `appears`, `closer`"),
            "{}",
            c.text
        );
    }

    /// A file that is not a suite's JSON is refused naming the file, and a malformed row its
    /// index, scene and field.
    #[test]
    fn bad_suite_files_are_refused_naming_file_row_and_field() {
        let tmp = temp_dir("bad");
        let dir = tmp.path();
        let missing = dir.join("none.json");
        let e = load(&missing, "default").unwrap_err().to_string();
        assert!(e.starts_with(&missing.display().to_string()), "{e}");
        let text = &dir.join("text.json");
        std::fs::write(text, "scene,e_mean\n").unwrap();
        let e = load(text, "default").unwrap_err().to_string();
        assert!(e.contains("text.json") && e.contains("not JSON"), "{e}");
        let object = write(dir, "object.json", &[]);
        std::fs::write(&object, "{}").unwrap();
        let e = load(&object, "default").unwrap_err().to_string();
        assert!(e.contains("expected a JSON array"), "{e}");
        let mut bad = row("arc", "default", "reached", [0.1, 0.2, 0.3], None);
        bad["summary"]["e_max_mm"] = Value::from("big");
        let bad = write(
            dir,
            "bad.json",
            &[row("ok", "default", "reached", [0.0; 3], None), bad],
        );
        let e = load(&bad, "default").unwrap_err().to_string();
        assert!(
            e.contains("bad.json: row 1 (`arc`): field `summary.e_max_mm`: not a number"),
            "{e}"
        );
        let e = load(&bad, "nobody").unwrap_err().to_string();
        assert!(e.contains("no row of controller `nobody`"), "{e}");
        let twice = write(
            dir,
            "twice.json",
            &[
                row("a", "default", "reached", [0.0; 3], None),
                row("a", "default", "reached", [0.0; 3], None),
            ],
        );
        let e = load(&twice, "default").unwrap_err().to_string();
        assert!(e.contains("row 1: scene `a` twice"), "{e}");
    }
}

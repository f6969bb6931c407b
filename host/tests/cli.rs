//! The `needle` command line as a user meets it: traps found by trying it (issue "trust"), each
//! test named after what broke.

use std::process::{Command, Output, Stdio};

fn needle() -> Command {
    Command::new(env!("CARGO_BIN_EXE_needle"))
}

/// A fresh folder under the system's temporary folder, removed when dropped.
fn tmp(name: &str) -> tempfile::TempDir {
    let prefix = format!("needle-cli-{name}-");
    (tempfile::Builder::new().prefix(&prefix).tempdir()).expect("temp dir")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// A short run of the simple scene on a small gel (3 steps unless `extra` gives `--steps`).
fn short_run(extra: &[&str]) -> Command {
    let mut c = needle();
    c.args(["run", "simple", "--nodes", "300", "--quiet"]);
    if !extra.contains(&"--steps") {
        c.args(["--steps", "3"]);
    }
    c.args(extra);
    c
}

#[test]
fn steps_of_a_billion_are_refused_instead_of_allocating_368_gb() {
    let o = short_run(&["--steps", "1000000000"]).output().expect("run");
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("must be between 1 and 10000000"));
}

#[test]
fn steps_of_u64_max_are_refused_instead_of_panicking() {
    let o = short_run(&["--steps", "18446744073709551615"])
        .output()
        .expect("run");
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(!stderr(&o).contains("panicked"), "{}", stderr(&o));
}

#[test]
fn vtk_every_without_out_is_refused_instead_of_ignored() {
    let o = short_run(&["--vtk-every", "10"]).output().expect("run");
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("--out"), "{}", stderr(&o));
}

#[test]
fn embedded_scene_runs_beside_a_folder_of_the_same_name() {
    let guard = tmp("folder");
    let dir = guard.path();
    std::fs::create_dir_all(dir.join("simple")).expect("folder `simple`");
    let o = short_run(&[]).current_dir(dir).output().expect("run");
    let err = stderr(&o);
    assert!(!err.contains("Is a directory"), "{err}");
    assert!(!err.contains("cannot read"), "{err}");
    // Three steps end above the gel: stopped short of the target, a run's outcome, not an error.
    assert!(!matches!(o.status.code(), Some(1 | 2)), "{err}");
}

#[test]
fn json_into_a_closed_pipe_exits_quietly_without_a_panic() {
    let mut child = short_run(&["--json"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn");
    // The reader goes away before the summary is printed (`needle run --json | head -0`).
    drop(child.stdout.take());
    let o = child.wait_with_output().expect("wait");
    let err = stderr(&o);
    assert!(!err.contains("panicked"), "{err}");
    assert!(!err.contains("Broken pipe"), "{err}");
}

/// The embedded JSON document of a replay page.
fn replay_doc(html: &str) -> serde_json::Value {
    let open = r#"<script id="replay-data" type="application/json">"#;
    let start = html.find(open).expect("the data element") + open.len();
    let end = start + html[start..].find("</script>").expect("its end");
    serde_json::from_str(&html[start..end]).expect("JSON")
}

#[test]
fn run_with_out_writes_a_replay_with_its_first_and_last_frames() {
    let guard = tmp("replay");
    let dir = guard.path();
    let o = short_run(&["--steps", "47"])
        .arg("--out")
        .arg(dir)
        .output()
        .expect("run");
    assert!(!matches!(o.status.code(), Some(1 | 2)), "{}", stderr(&o));
    let html = std::fs::read_to_string(dir.join("replay.html")).expect("replay.html");
    let doc = replay_doc(&html);
    let frames = doc["frames"].as_array().expect("frames");
    // 47 planned steps → about one frame a step; the start and the last step always.
    assert_eq!(frames[0]["step"], 0);
    assert_eq!(frames.last().expect("a frame")["step"], 47);
    assert!(frames.len() >= 2);
    let summary = doc["summary"].as_array().expect("summary");
    assert_eq!(summary[0][0], "outcome");
}

#[test]
fn vtk_frames_include_the_last_step_and_a_pvd_with_their_times() {
    // 47 steps every 20: frames 0, 20, 40 and the last, 47 (step 600 of 609 was the last
    // frame written before).
    let guard = tmp("vtk");
    let dir = guard.path();
    let o = short_run(&["--steps", "47", "--vtk-every", "20"])
        .arg("--out")
        .arg(dir)
        .output()
        .expect("run");
    assert!(!matches!(o.status.code(), Some(1 | 2)), "{}", stderr(&o));
    let parts = ["gel", "needle", "path", "obstacles", "constraints"];
    for k in [0, 20, 40, 47] {
        for part in parts {
            let f = dir.join(format!("{part}_{k:05}.vtu"));
            let text = std::fs::read_to_string(&f).expect("frame file");
            assert!(
                text.contains("compressor=\"vtkZLibDataCompressor\""),
                "{f:?}"
            );
        }
    }
    assert!(!dir.join("gel_00060.vtu").exists());
    let gel = std::fs::read_to_string(dir.join("gel.pvd")).expect("gel.pvd");
    // dt = 0.04 s in the simple scene: frame 47 at 1.88 s.
    let times: Vec<f64> = gel
        .split("timestep=\"")
        .skip(1)
        .map(|t| t.split('"').next().unwrap().parse().unwrap())
        .collect();
    assert_eq!(times.len(), 4, "{gel}");
    assert!(
        (times[3] - 47.0 * times[1] / 20.0).abs() < 1e-12,
        "{times:?}"
    );
    let run = std::fs::read_to_string(dir.join("run.pvd")).expect("run.pvd");
    assert_eq!(run.matches("<DataSet ").count(), 4 * parts.len());
}

#[test]
fn suite_runs_every_scene_of_a_folder_and_records_one_that_cannot_run() {
    let guard = tmp("suite");
    let dir = guard.path();
    let scenes = dir.join("scenes");
    std::fs::create_dir_all(&scenes).expect("folder");
    let simple = concat!(env!("CARGO_MANIFEST_DIR"), "/../scenes/simple.toml");
    std::fs::copy(simple, scenes.join("a_simple.toml")).expect("copy");
    let thin = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../scenes/suite/needle_thin.toml"
    );
    std::fs::copy(thin, scenes.join("c_thin.toml")).expect("copy");
    std::fs::write(scenes.join("b_broken.toml"), "name = \"broken\"\n[gel\n").expect("write");
    std::fs::write(scenes.join("notes.txt"), "not a scene").expect("write");
    let o = needle()
        .args(["suite", "--no-benchmarks", "--quiet", "--steps", "20"])
        .args(["--set", "gel.box.nodes=300"])
        .arg("--dir")
        .arg(&scenes)
        .arg("--out")
        .arg(dir.join("out"))
        .output()
        .expect("suite");
    let out = String::from_utf8_lossy(&o.stdout);
    // A scene that cannot run: exit 1, and the others still ran.
    assert_eq!(o.status.code(), Some(1), "{out}\n{}", stderr(&o));
    // Each scene under both controllers, side by side.
    assert!(out.contains("default: scenes run: 2 of 3"), "{out}");
    assert!(out.contains("paper: scenes run: 2 of 3"), "{out}");
    let md = std::fs::read_to_string(dir.join("out/suite.md")).expect("suite.md");
    assert!(
        md.contains("| a_simple | default | missed_target |"),
        "{md}"
    );
    assert!(md.contains("| a_simple | paper | missed_target |"), "{md}");
    assert!(md.contains("`b_broken` (default) failed:"), "{md}");
    // The thin needle's plan advisory, under each controller; none for the benchmark's needle.
    assert!(
        md.contains(
            "`c_thin` (default) advisory: the needle's steering length in this gel is 13.0 mm"
        ),
        "{md}"
    );
    assert!(md.contains("`c_thin` (paper) advisory:"), "{md}");
    assert!(!md.contains("`a_simple` (default) advisory"), "{md}");
    let csv = std::fs::read_to_string(dir.join("out/suite.csv")).expect("suite.csv");
    assert_eq!(csv.lines().count(), 7, "{csv}");
    let json: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.join("out/suite.json")).expect("suite.json"),
    )
    .expect("JSON");
    assert_eq!(json[0]["summary"]["steps"], 20);
    assert_eq!(json[1]["controller"], "paper");
    assert_eq!(json[1]["summary"]["steps"], 20);
    // The chart, with the default `charts` feature: a PNG.
    let png = std::fs::read(dir.join("out/suite.png")).expect("suite.png");
    assert!(png.starts_with(b"\x89PNG"), "not a PNG");
}

#[test]
fn suite_with_an_unknown_controller_is_a_usage_error() {
    let o = needle()
        .args(["suite", "--quiet", "--controllers", "default,pid"])
        .output()
        .expect("suite");
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("`pid`"), "{}", stderr(&o));
}

#[test]
fn logs_are_leveled_by_v_and_q_and_rust_log() {
    let quiet = short_run(&[]).env_remove("RUST_LOG").output().expect("run");
    assert!(!stderr(&quiet).contains("INFO"), "{}", stderr(&quiet));
    let v = needle()
        .arg("-v")
        .args(["run", "simple", "--nodes", "300", "--quiet", "--steps", "3"])
        .env_remove("RUST_LOG")
        .output()
        .expect("run -v");
    let err = stderr(&v);
    assert!(err.contains("INFO") && err.contains("set up in"), "{err}");
    assert!(err.contains("ended after 3 of 3 steps"), "{err}");
    let debug = short_run(&[])
        .env("RUST_LOG", "debug")
        .output()
        .expect("run");
    assert!(
        stderr(&debug).contains("gel mesh ready"),
        "{}",
        stderr(&debug)
    );
}

/// `needle compare` on two runs of the same suite: every scene equal, exit 0; against a copy
/// whose scene lost its target, the scene is named and `--fail-on-loss` exits 4; a file that
/// is not a suite's JSON is refused naming it, exit 2.
#[test]
fn compare_reads_two_suite_runs_and_names_a_lost_target() {
    let guard = tmp("compare");
    let d = guard.path();
    let scenes = d.join("scenes");
    std::fs::create_dir_all(&scenes).expect("dir");
    let src = concat!(env!("CARGO_MANIFEST_DIR"), "/../scenes/suite/simple_y.toml");
    std::fs::copy(src, scenes.join("simple_y.toml")).expect("copy");
    let out = d.join("run");
    let o = needle()
        .args([
            "suite",
            "--no-benchmarks",
            "--controllers",
            "default",
            "--quiet",
        ])
        .args(["--nodes", "300", "--steps", "3", "--dir"])
        .arg(&scenes)
        .arg("--out")
        .arg(&out)
        .output()
        .expect("suite");
    assert!(out.join("suite.json").is_file(), "{}", stderr(&o));
    let o = needle()
        .arg("compare")
        .arg(&out)
        .arg(&out)
        .output()
        .expect("compare");
    let text = String::from_utf8_lossy(&o.stdout).into_owned();
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    assert!(text.starts_with("1 of 1 scenes equal"), "{text}");
    // The same run, its scene marked reached before and missed after.
    let json = std::fs::read_to_string(out.join("suite.json")).expect("read");
    let mut rows: serde_json::Value = serde_json::from_str(&json).expect("json");
    rows[0]["summary"]["outcome"] = "reached".into();
    let before = d.join("before.json");
    std::fs::write(&before, rows.to_string()).expect("write");
    rows[0]["summary"]["outcome"] = "missed_target".into();
    let after = d.join("after.json");
    std::fs::write(&after, rows.to_string()).expect("write");
    let o = needle()
        .arg("compare")
        .args([&before, &after])
        .arg("--fail-on-loss")
        .output()
        .expect("compare");
    let text = String::from_utf8_lossy(&o.stdout).into_owned();
    assert_eq!(o.status.code(), Some(4), "{text}{}", stderr(&o));
    assert!(text.contains("targets lost: `simple_y`"), "{text}");
    let o = needle()
        .arg("compare")
        .arg(src)
        .arg(&after)
        .output()
        .expect("compare");
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).contains("simple_y.toml: not JSON"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn report_with_a_missing_suite_folder_fails_before_any_run_naming_it() {
    let dir = tmp("report-suite");
    let missing = dir.path().join("no-such-suite");
    let o = needle()
        .args(["report", "--quiet", "--out"])
        .arg(dir.path().join("report"))
        .arg("--suite")
        .arg(&missing)
        .output()
        .expect("run");
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let err = stderr(&o);
    assert!(
        err.contains("suite folder") && err.contains("no-such-suite"),
        "{err}"
    );
    assert!(
        !dir.path().join("report/summary.md").exists(),
        "no report from a missing folder"
    );
}

//! The quick benchmark report (`needle report --quick`) end to end: every promised file exists
//! and is non-empty, `runs.csv` has one row per run, the charts are real SVG and PNG files.

use needle_host::report::{ACCURACY_SECTION_TITLE, Group, ReportOptions, accuracy_summary, report};
use std::path::{Path, PathBuf};

/// A fresh folder under the system's temporary folder, removed on drop.
struct TempDir(PathBuf);

impl TempDir {
    fn new(name: &str) -> Self {
        let p = std::env::temp_dir().join(format!("{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&p);
        Self(p)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn read(dir: &Path, name: &str) -> Vec<u8> {
    let p = dir.join(name);
    let bytes = std::fs::read(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
    assert!(!bytes.is_empty(), "{} is empty", p.display());
    bytes
}

#[test]
#[ignore = "runs 8 insertions (≈ 5 s in release); CI runs the ignored tests in release"]
fn quick_report_writes_every_promised_file() {
    let tmp = TempDir::new("needle-report-quick");
    let out = tmp.0.join("report");
    let summary = report(&ReportOptions {
        out_dir: out.clone(),
        quick: true,
        steps: None,
        progress: false,
        suite: None,
    })
    .expect("the quick report is written");

    // Every group has at least one run, and every run ran (a breakdown would still be reported).
    for g in Group::ALL {
        assert!(
            summary.runs.iter().any(|r| r.parameter(g).is_some()),
            "no run in group {g:?}"
        );
    }
    for r in &summary.runs {
        let s = r
            .summary
            .as_ref()
            .unwrap_or_else(|| panic!("run {} did not start: {:?}", r.id, r.failure));
        assert!(s.steps > 0, "run {} ran no step", r.id);
    }

    let promised = [
        "summary.md",
        "runs.csv",
        "error_vs_depth.csv",
        "accuracy_cost.csv",
        "report.json",
        "error_vs_depth.svg",
        "error_vs_depth.png",
        "stage_times.svg",
        "stage_times.png",
        "speed_vs_error.svg",
        "speed_vs_error.png",
    ];
    for f in promised {
        read(&out, f);
        assert!(
            summary.files.iter().any(|p| p.ends_with(f)),
            "{f} missing from ReportSummary::files"
        );
    }

    // runs.csv: a header and one row per run, each with as many fields as the header.
    let csv = String::from_utf8(read(&out, "runs.csv")).expect("UTF-8");
    let lines: Vec<&str> = csv.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(
        lines.len(),
        summary.runs.len() + 1,
        "runs.csv: expected a header and {} rows",
        summary.runs.len()
    );
    assert!(lines[0].starts_with("run,scene,controller"));
    // The figures a run's summary gives beyond its errors are in its row: how far the tissue
    // moved, the needle's steering length and the horizon it set.
    let header: Vec<&str> = lines[0].split(',').collect();
    let col = |name: &str| {
        header
            .iter()
            .position(|h| *h == name)
            .unwrap_or_else(|| panic!("runs.csv has no column {name}"))
    };
    let mut rows = ::csv::Reader::from_path(out.join("runs.csv")).expect("runs.csv opens");
    for (r, row) in summary.runs.iter().zip(rows.records()) {
        let row = row.expect("a row of runs.csv");
        assert_eq!(
            row.len(),
            header.len(),
            "run {}: fields against the header",
            r.id
        );
        let s = r.summary.as_ref().expect("every run ran");
        for (name, want) in [
            ("target_shift_max_mm", s.target_shift_max_mm),
            ("entry_shift_max_mm", s.entry_shift_max_mm),
            ("steering_length_mm", s.steering_length_mm),
            ("qp_horizon_mm", s.qp_horizon_mm),
            ("straighten", s.straighten),
            ("max_strain", s.max_strain),
            ("needle_strain_max", s.needle_strain_max),
        ] {
            let got: f64 = row[col(name)]
                .parse()
                .unwrap_or_else(|e| panic!("run {} {name} {:?}: {e}", r.id, &row[col(name)]));
            assert_eq!(got, want, "run {}: {name}", r.id);
        }
    }

    // error_vs_depth.csv: a header and at least one point per run that punctured the gel.
    let err = String::from_utf8(read(&out, "error_vs_depth.csv")).expect("UTF-8");
    assert!(err.lines().next().unwrap_or("").contains("depth_mm"));
    assert!(err.lines().count() > summary.runs.len());

    // summary.md: a table per group and the paper's figures, labelled as such.
    let md = String::from_utf8(read(&out, "summary.md")).expect("UTF-8");
    for g in Group::ALL {
        assert!(md.contains(g.title()), "summary.md lacks the table {g:?}");
    }
    assert!(md.contains("The paper's figures"));

    // The accuracy cost: both benchmarks, the default pipeline replaying the exact step's joints
    // within the tolerance of issue "speed" (the 600-node gel, 250 steps), in the summary and
    // in accuracy_cost.csv (a header and a row per scene and pipeline).
    assert!(
        md.contains(ACCURACY_SECTION_TITLE),
        "summary.md lacks the accuracy cost"
    );
    let scenes: Vec<&str> = summary.accuracy.iter().map(|r| r.scene.as_str()).collect();
    assert_eq!(scenes, ["simple", "complex"]);
    for r in &summary.accuracy {
        assert!(r.failure.is_none(), "{}: {:?}", r.scene, r.failure);
        assert_eq!(
            r.pipelines.len(),
            1,
            "the quick set compares the default only"
        );
        let cost = r.pipelines[0].cost.expect("the default pipeline replayed");
        assert_eq!(cost.steps, 250);
        assert!(
            cost.within(0.05),
            "{}: the default pipeline {:.4} mm off the exact step",
            r.scene,
            cost.largest_difference_mm()
        );
    }
    let lines = accuracy_summary(&summary.accuracy);
    assert_eq!(lines.len(), 1, "{lines:?}");
    assert!(
        lines[0].starts_with("default pipeline: 2 of 2 scenes within 0.05 mm"),
        "{}",
        lines[0]
    );
    assert!(
        md.contains(&lines[0]),
        "the summary's line is the section's"
    );
    let acc = String::from_utf8(read(&out, "accuracy_cost.csv")).expect("UTF-8");
    assert_eq!(acc.lines().count(), 1 + summary.accuracy.len());
    assert!(acc.starts_with("scene,pipeline,steps,"));

    for chart in ["error_vs_depth", "stage_times", "speed_vs_error"] {
        let svg = String::from_utf8(read(&out, &format!("{chart}.svg"))).expect("UTF-8 SVG");
        assert!(svg.contains("<svg"), "{chart}.svg has no <svg element");
        assert!(
            svg.trim_end().ends_with("</svg>"),
            "{chart}.svg is not closed"
        );
        let png = read(&out, &format!("{chart}.png"));
        assert!(
            png.starts_with(b"\x89PNG\r\n\x1a\n"),
            "{chart}.png lacks the PNG signature"
        );
    }
}

//! Prescribed motion of the gel's support (its fixed nodes): a periodic breathing motion or a
//! table of displacements over time read from a CSV file.
//!
//! Every fixed node follows the same displacement `d(t)` from its rest position — a rigid
//! translation of the support, as when the organ's bed moves with breathing. The displacement
//! is an inhomogeneous Dirichlet condition of the gel's free motion
//! ([`crate::world::World::move_support`]).
//!
//! - **Breathing**: `d(t) = A · (1 − cos(2π t / T + φ)) / 2 · u` with `A` the amplitude
//!   (peak to peak: the support travels from 0 to `A·u` and back), `T` the period, `u` the unit
//!   direction and `φ` the phase. With `φ = 0` the motion starts at rest with zero velocity:
//!   `d(0) = 0`, `d'(0) = 0`; the peak speed is `π A / T`.
//! - **Table** (CSV `t, dx, dy, dz` [s, mm]): linear interpolation between rows; before the first
//!   row the first displacement, after the last row the last one.

// Units are written in brackets ([mm], [s]) as in the workspace style: not intra-doc links.
#![allow(rustdoc::broken_intra_doc_links)]

use nalgebra::Vector3;
use serde::Serialize;
use std::fmt;
use std::path::{Path, PathBuf};

/// Largest motion CSV file read [bytes].
pub const MAX_CSV_BYTES: u64 = 64 << 20;

/// A prescribed displacement of the gel's support over time.
#[derive(Clone, Debug, PartialEq)]
pub enum SupportMotion {
    /// `d(t) = amplitude · (1 − cos(2π t / period + phase)) / 2 · direction`.
    Breathing {
        /// Peak-to-peak travel [mm].
        amplitude: f64,
        /// Period [s].
        period: f64,
        /// Unit direction.
        direction: Vector3<f64>,
        /// Phase [rad].
        phase: f64,
    },
    /// Displacements at increasing times, interpolated linearly.
    Table {
        /// Strictly increasing times [s].
        times: Vec<f64>,
        /// Displacement at each time [mm].
        displacements: Vec<Vector3<f64>>,
    },
}

impl SupportMotion {
    /// A breathing motion; `direction` is normalised.
    ///
    /// # Errors
    /// A reason when the amplitude is negative or not finite, the period not positive, the
    /// phase not finite, or the direction zero or not finite.
    pub fn breathing(
        amplitude: f64,
        period: f64,
        direction: [f64; 3],
        phase: f64,
    ) -> Result<Self, String> {
        if !(amplitude.is_finite() && amplitude >= 0.0) {
            return Err(format!("amplitude must be ≥ 0 [mm] (got {amplitude})"));
        }
        if !(period.is_finite() && period > 0.0) {
            return Err(format!("period must be > 0 [s] (got {period})"));
        }
        if !phase.is_finite() {
            return Err(format!("phase must be finite (got {phase})"));
        }
        let d = Vector3::from(direction);
        let n = d.norm();
        if !(n.is_finite() && n > 0.0) {
            return Err(format!(
                "direction must be a non-zero vector (got {direction:?})"
            ));
        }
        Ok(Self::Breathing {
            amplitude,
            period,
            direction: d / n,
            phase,
        })
    }

    /// The displacement of the support at time `t` [s] (from its rest position) [mm].
    pub fn displacement(&self, t: f64) -> Vector3<f64> {
        match self {
            Self::Breathing {
                amplitude,
                period,
                direction,
                phase,
            } => {
                let a = std::f64::consts::TAU * t / period + phase;
                direction * (amplitude * 0.5 * (1.0 - a.cos()))
            }
            Self::Table {
                times,
                displacements,
            } => {
                let (Some(&t0), Some(&t1)) = (times.first(), times.last()) else {
                    return Vector3::zeros();
                };
                if t <= t0 {
                    return displacements[0];
                }
                if t >= t1 {
                    return displacements[times.len() - 1];
                }
                // First row with time > t (≥ 1: t > t0).
                let k = times.partition_point(|&s| s <= t);
                let (ta, tb) = (times[k - 1], times[k]);
                let f = (t - ta) / (tb - ta);
                displacements[k - 1] * (1.0 - f) + displacements[k] * f
            }
        }
    }

    /// What a run's summary says of this motion ([`MotionSummary`]); `hidden`: the motion is
    /// hidden from the controller's model (`gel.support_motion.hidden`).
    pub fn summary(&self, hidden: bool) -> MotionSummary {
        match self {
            Self::Breathing {
                amplitude,
                period,
                direction,
                phase,
            } => MotionSummary {
                kind: MotionKind::Breathing,
                amplitude_mm: *amplitude,
                period_s: Some(*period),
                direction: Some([direction.x, direction.y, direction.z]),
                phase_rad: Some(*phase),
                table_rows: None,
                hidden,
            },
            Self::Table {
                times: _,
                displacements,
            } => {
                let largest = displacements
                    .iter()
                    .copied()
                    .max_by(|a, b| a.norm().total_cmp(&b.norm()))
                    .unwrap_or_else(Vector3::zeros);
                let n = largest.norm();
                MotionSummary {
                    kind: MotionKind::Table,
                    amplitude_mm: n,
                    period_s: None,
                    direction: (n > 0.0).then(|| {
                        let u = largest / n;
                        [u.x, u.y, u.z]
                    }),
                    phase_rad: None,
                    table_rows: Some(displacements.len()),
                    hidden,
                }
            }
        }
    }

    /// Reads a table from a CSV file (see [`SupportMotion::parse_csv`]).
    ///
    /// # Errors
    /// [`MotionCsvError`] naming the file (and the line) and the reason.
    pub fn from_csv(path: &Path) -> Result<Self, MotionCsvError> {
        let bytes =
            crate::bounded_read::read_bounded(path, MAX_CSV_BYTES).map_err(|e| MotionCsvError {
                file: path.to_path_buf(),
                line: None,
                reason: format!("cannot read: {e}"),
            })?;
        Self::parse_csv(&bytes, path)
    }

    /// Parses a table: rows `t, dx, dy, dz` [s, mm, mm, mm], times strictly increasing, at least
    /// one row. A first line whose first field is not a number is a header; lines starting
    /// with `#` are comments; spaces around fields are ignored.
    ///
    /// # Errors
    /// [`MotionCsvError`] naming `file`, the line and the reason: a row without exactly four
    /// fields, a field that is not a finite number (named by its column), a time not after the
    /// row before, no row.
    pub fn parse_csv(bytes: &[u8], file: &Path) -> Result<Self, MotionCsvError> {
        let err = |line: Option<u64>, reason: String| MotionCsvError {
            file: file.to_path_buf(),
            line,
            reason,
        };
        let mut reader = csv::ReaderBuilder::new()
            .has_headers(false)
            .flexible(true)
            .comment(Some(b'#'))
            .trim(csv::Trim::All)
            .from_reader(bytes);
        const COLUMNS: [&str; 4] = ["t", "dx", "dy", "dz"];
        let (mut times, mut displacements) = (Vec::new(), Vec::new());
        let mut first = true;
        for record in reader.records() {
            let record = record.map_err(|e| {
                let line = e.position().map(|p| p.line());
                err(line, format!("not a valid CSV row: {e}"))
            })?;
            let line = record.position().map(|p| p.line());
            let is_first = std::mem::replace(&mut first, false);
            if is_first && record.get(0).is_some_and(|f| f.parse::<f64>().is_err()) {
                // A header.
                continue;
            }
            if record.len() != 4 {
                return Err(err(
                    line,
                    format!(
                        "expected 4 fields `t, dx, dy, dz` [s, mm, mm, mm], found {}",
                        record.len()
                    ),
                ));
            }
            let mut v = [0.0; 4];
            for (i, (field, name)) in record.iter().zip(COLUMNS).enumerate() {
                v[i] = match field.parse::<f64>() {
                    Ok(x) if x.is_finite() => x,
                    Ok(x) => return Err(err(line, format!("`{name}` must be finite (got {x})"))),
                    Err(_) => {
                        return Err(err(line, format!("`{name}` is not a number: `{field}`")));
                    }
                };
            }
            if let Some(&prev) = times.last()
                && v[0] <= prev
            {
                return Err(err(
                    line,
                    format!(
                        "`t` must increase from row to row: {} s after {prev} s",
                        v[0]
                    ),
                ));
            }
            times.push(v[0]);
            displacements.push(Vector3::new(v[1], v[2], v[3]));
        }
        if times.is_empty() {
            return Err(err(
                None,
                "no row `t, dx, dy, dz`: the table is empty".into(),
            ));
        }
        Ok(Self::Table {
            times,
            displacements,
        })
    }
}

/// A motion CSV file that cannot be read or parsed.
#[derive(Clone, Debug, PartialEq)]
pub struct MotionCsvError {
    /// The file.
    pub file: PathBuf,
    /// The line (1-based), when the error is on one.
    pub line: Option<u64>,
    /// Why.
    pub reason: String,
}

impl fmt::Display for MotionCsvError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.line {
            Some(l) => write!(f, "{}: line {l}: {}", self.file.display(), self.reason),
            None => write!(f, "{}: {}", self.file.display(), self.reason),
        }
    }
}

impl std::error::Error for MotionCsvError {}

/// The kind of a support motion, as a run's summary names it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum MotionKind {
    /// `[gel.support_motion.breathing]`.
    Breathing,
    /// A table of displacements (`gel.support_motion.csv`).
    Table,
}

impl MotionKind {
    /// The name of the kind (`breathing`, `table`), as in `summary.json`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Breathing => "breathing",
            Self::Table => "table",
        }
    }
}

/// The support motion of a run, in its summary (`summary.json`'s `support_motion`, the
/// `support motion:` line of `needle run`).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MotionSummary {
    /// `breathing` or `table` (a CSV file).
    pub kind: MotionKind,
    /// The largest distance of the support from its rest position [mm]: a breathing motion's
    /// amplitude (its peak-to-peak travel, `d` goes from 0 to `amplitude · direction`), a
    /// table's largest displacement.
    pub amplitude_mm: f64,
    /// A breathing motion's period [s] (none for a table).
    pub period_s: Option<f64>,
    /// The unit direction of the motion: a breathing motion's, a table's largest displacement's
    /// (none for a table that never moves).
    pub direction: Option<[f64; 3]>,
    /// A breathing motion's phase [rad] (none for a table).
    pub phase_rad: Option<f64>,
    /// A table's rows (none for a breathing motion).
    pub table_rows: Option<usize>,
    /// Whether the motion is hidden from the controller's model (`hidden = true`: the
    /// controller steers a model whose support stays still) or modelled (the default).
    pub hidden: bool,
}

impl fmt::Display for MotionSummary {
    /// One line: `breathing, 5.000 mm every 4.000 s along [1.000, 0.000, 0.000], phase 0.000
    /// rad, modelled`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}, {:.3} mm", self.kind.name(), self.amplitude_mm)?;
        if let Some(t) = self.period_s {
            write!(f, " every {t:.3} s")?;
        }
        if let Some(rows) = self.table_rows {
            write!(f, " at most (a table of {rows} rows)")?;
        }
        if let Some([x, y, z]) = self.direction {
            write!(f, " along [{x:.3}, {y:.3}, {z:.3}]")?;
        }
        if let Some(p) = self.phase_rad {
            write!(f, ", phase {p:.3} rad")?;
        }
        f.write_str(if self.hidden {
            ", hidden from the controller's model"
        } else {
            ", modelled (the controller's model moves alike)"
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<SupportMotion, MotionCsvError> {
        SupportMotion::parse_csv(text.as_bytes(), Path::new("m.csv"))
    }

    #[test]
    fn breathing_starts_at_rest_and_peaks_at_half_period() {
        let m = SupportMotion::breathing(5.0, 4.0, [0.0, 0.0, 2.0], 0.0).unwrap();
        assert_eq!(m.displacement(0.0), Vector3::zeros());
        assert!((m.displacement(2.0) - Vector3::new(0.0, 0.0, 5.0)).norm() < 1e-12);
        assert!(m.displacement(4.0).norm() < 1e-12);
        assert!((m.displacement(1.0).z - 2.5).abs() < 1e-12);
        // Zero velocity at t = 0 (central difference).
        let h = 1e-4;
        assert!(((m.displacement(h) - m.displacement(-h)) / (2.0 * h)).norm() < 1e-9);
        // A phase of π starts at the peak.
        let p = SupportMotion::breathing(5.0, 4.0, [1.0, 0.0, 0.0], std::f64::consts::PI).unwrap();
        assert!((p.displacement(0.0).x - 5.0).abs() < 1e-12);
    }

    #[test]
    fn the_summary_names_kind_amplitude_period_direction_and_hiding() {
        let b = SupportMotion::breathing(5.0, 4.0, [2.0, 0.0, 0.0], 0.0).unwrap();
        let s = b.summary(true);
        assert_eq!(s.kind, MotionKind::Breathing);
        assert_eq!((s.amplitude_mm, s.period_s), (5.0, Some(4.0)));
        assert_eq!(s.direction, Some([1.0, 0.0, 0.0]));
        assert!(s.hidden);
        assert_eq!(
            s.to_string(),
            "breathing, 5.000 mm every 4.000 s along [1.000, 0.000, 0.000], phase 0.000 rad, \
             hidden from the controller's model"
        );
        let json = serde_json::to_value(&s).unwrap();
        assert_eq!(json["kind"], "breathing");
        assert_eq!(json["period_s"], 4.0);
        assert_eq!(json["table_rows"], serde_json::Value::Null);
        let t = parse("t,dx,dy,dz\n0,0,0,0\n1,0,3,4\n2,0,0,1\n")
            .unwrap()
            .summary(false);
        assert_eq!((t.kind, t.amplitude_mm), (MotionKind::Table, 5.0));
        assert_eq!(t.direction, Some([0.0, 0.6, 0.8]));
        assert_eq!((t.period_s, t.table_rows, t.hidden), (None, Some(3), false));
        assert!(
            t.to_string()
                .ends_with("modelled (the controller's model moves alike)")
        );
    }

    #[test]
    fn breathing_refuses_bad_parameters() {
        assert!(SupportMotion::breathing(-1.0, 4.0, [1.0, 0.0, 0.0], 0.0).is_err());
        assert!(SupportMotion::breathing(5.0, 0.0, [1.0, 0.0, 0.0], 0.0).is_err());
        assert!(SupportMotion::breathing(5.0, 4.0, [0.0, 0.0, 0.0], 0.0).is_err());
        assert!(SupportMotion::breathing(5.0, 4.0, [f64::NAN, 0.0, 1.0], 0.0).is_err());
    }

    #[test]
    fn table_interpolates_linearly_and_holds_its_ends() {
        let m =
            parse("t,dx,dy,dz\n# a comment\n0, 0, 0, 0\n1.0, 2, 0, -4\n3.0, 2, 6, 0\n").unwrap();
        assert_eq!(m.displacement(-1.0), Vector3::zeros());
        assert!((m.displacement(0.5) - Vector3::new(1.0, 0.0, -2.0)).norm() < 1e-12);
        assert!((m.displacement(2.0) - Vector3::new(2.0, 3.0, -2.0)).norm() < 1e-12);
        assert_eq!(m.displacement(9.0), Vector3::new(2.0, 6.0, 0.0));
        assert_eq!(m.displacement(1.0), Vector3::new(2.0, 0.0, -4.0));
    }

    #[test]
    fn table_errors_name_file_line_and_reason() {
        let e = parse("t,dx,dy,dz\n0,0,0,0\n1,0,0\n").unwrap_err();
        assert_eq!(e.line, Some(3));
        assert!(
            e.to_string()
                .starts_with("m.csv: line 3: expected 4 fields"),
            "{e}"
        );
        let e = parse("0,0,0,0\n1,0,abc,0\n").unwrap_err();
        assert_eq!(e.to_string(), "m.csv: line 2: `dy` is not a number: `abc`");
        let e = parse("0,0,0,0\n1,0,0,0\n1,1,1,1\n").unwrap_err();
        assert_eq!(
            e.to_string(),
            "m.csv: line 3: `t` must increase from row to row: 1 s after 1 s"
        );
        let e = parse("0,0,0,inf\n").unwrap_err();
        assert_eq!(
            e.to_string(),
            "m.csv: line 1: `dz` must be finite (got inf)"
        );
        let e = parse("t,dx,dy,dz\n").unwrap_err();
        assert!(e.to_string().contains("empty"), "{e}");
        let e = SupportMotion::from_csv(Path::new("/nonexistent/motion.csv")).unwrap_err();
        assert!(
            e.to_string()
                .starts_with("/nonexistent/motion.csv: cannot read"),
            "{e}"
        );
    }
}

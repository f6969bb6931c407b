//! The planned path as a polyline parametrised by arc length (rest configuration).

use super::PathSpec;
use exmex::Express;
use nalgebra::Vector3;
use std::fmt;

/// Why a path could not be built.
#[derive(Debug, Clone, PartialEq)]
pub struct PathError {
    /// Dotted field path, e.g. `path.formula.x`.
    pub field: String,
    /// Why.
    pub reason: String,
}

impl fmt::Display for PathError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "field `{}`: {}", self.field, self.reason)
    }
}

impl std::error::Error for PathError {}

impl PathError {
    fn new(field: impl Into<String>, reason: impl Into<String>) -> Self {
        Self {
            field: field.into(),
            reason: reason.into(),
        }
    }
}

/// The path's vertices: the scene's points, or its formulas sampled at `samples` values of `s`.
fn spec_points(spec: &PathSpec) -> Result<Vec<Vector3<f64>>, PathError> {
    match (&spec.points, &spec.formula) {
        (Some(_), Some(_)) => Err(PathError::new(
            "path",
            "give either `points` or `formula`, not both",
        )),
        (None, None) => Err(PathError::new("path", "give `points` or `formula`")),
        (Some(p), None) if p.len() > MAX_PATH_POINTS => Err(PathError::new(
            "path.points",
            format!(
                "{} points, more than the limit of {MAX_PATH_POINTS}",
                p.len()
            ),
        )),
        (Some(p), None) => Ok(p.iter().map(|p| Vector3::from(*p)).collect()),
        (None, Some(f)) => {
            if !(2..=MAX_PATH_POINTS).contains(&spec.samples) {
                return Err(PathError::new(
                    "path.samples",
                    format!(
                        "must be between 2 and {MAX_PATH_POINTS} (got {})",
                        spec.samples
                    ),
                ));
            }
            let x = eval_formula("path.formula.x", &f.x, spec.samples)?;
            let y = eval_formula("path.formula.y", &f.y, spec.samples)?;
            let z = eval_formula("path.formula.z", &f.z, spec.samples)?;
            Ok((0..spec.samples)
                .map(|i| Vector3::new(x[i], y[i], z[i]))
                .collect())
        }
    }
}

/// Cumulative arc length at each vertex; an error at a zero-length segment.
fn arc_lengths(points: &[Vector3<f64>]) -> Result<Vec<f64>, PathError> {
    let mut arc = Vec::with_capacity(points.len());
    let mut acc = 0.0;
    for (i, p) in points.iter().enumerate() {
        if i > 0 {
            let l = (p - points[i - 1]).norm();
            if l <= 1e-9 {
                return Err(PathError::new(
                    format!("path.points[{i}]"),
                    "repeats the previous point (zero-length segment)",
                ));
            }
            acc += l;
        }
        arc.push(acc);
    }
    Ok(arc)
}

/// A polyline with cumulative arc length: the path in the gel, from the entry point on.
#[derive(Clone, Debug, PartialEq)]
pub struct SampledPath {
    /// Vertices in the rest configuration [mm]; the first is the entry point.
    pub points: Vec<Vector3<f64>>,
    /// Arc length from the entry point to each vertex [mm].
    pub arc: Vec<f64>,
    /// Length of the straight approach in the air before the entry point [mm].
    pub approach: f64,
    /// Unit tangent at the entry point: second-order one-sided difference for a sampled formula
    /// (exact for quadratics), the first chord for a polyline.
    pub entry_tangent: Vector3<f64>,
}

/// Most vertices of a path (`path.samples`, or the length of `path.points`).
pub const MAX_PATH_POINTS: usize = 100_000;

/// Longest formula of a path coordinate [characters].
pub const MAX_FORMULA_CHARS: usize = 1000;

/// The start of a long text, for a message.
fn excerpt(text: &str) -> String {
    if text.chars().count() <= 60 {
        text.to_owned()
    } else {
        format!("{}…", text.chars().take(60).collect::<String>())
    }
}

/// The first line of a parser's message, shortened.
fn first_line(e: &impl fmt::Display) -> String {
    let text = e.to_string();
    excerpt(text.lines().next().unwrap_or(""))
}

fn eval_formula(field: &str, text: &str, samples: usize) -> Result<Vec<f64>, PathError> {
    let err = |reason: String| PathError::new(field, reason);
    let n = text.chars().count();
    if n > MAX_FORMULA_CHARS {
        return Err(err(format!(
            "{n} characters, more than the limit of {MAX_FORMULA_CHARS}"
        )));
    }
    let shown = excerpt(text);
    let expr = exmex::parse::<f64>(text)
        .map_err(|e| err(format!("cannot parse `{shown}`: {}", first_line(&e))))?;
    let vars = expr.var_names().to_vec();
    if vars.iter().any(|v| v != "s") {
        return Err(err(format!(
            "`{shown}` uses variables {vars:?}; only `s` (0 at the entry, 1 at the end) is defined"
        )));
    }
    (0..samples)
        .map(|i| {
            let s = i as f64 / (samples - 1) as f64;
            let v = if vars.is_empty() {
                expr.eval(&[])
            } else {
                expr.eval(&[s])
            }
            .map_err(|e| {
                err(format!(
                    "cannot evaluate `{shown}` at s = {s}: {}",
                    first_line(&e)
                ))
            })?;
            if v.is_finite() {
                Ok(v)
            } else {
                Err(err(format!("`{shown}` is not finite at s = {s}")))
            }
        })
        .collect()
}

impl SampledPath {
    /// Builds the polyline from the scene's points or formulas.
    ///
    /// # Errors
    /// [`PathError`] when neither or both of `points` and `formula` are given, a formula does not
    /// parse, uses a variable other than `s`, is not finite, or the path has fewer than two distinct points.
    pub fn from_spec(spec: &PathSpec) -> Result<Self, PathError> {
        let points = spec_points(spec)?;
        if let Some(i) = points.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
            return Err(PathError::new(format!("path.points[{i}]"), "not finite"));
        }
        let arc = arc_lengths(&points)?;
        if points.len() < 2 {
            return Err(PathError::new("path.points", "needs at least two points"));
        }
        if !(spec.approach.is_finite() && spec.approach >= 0.0) {
            return Err(PathError::new(
                "path.approach",
                "must be finite and ≥ 0 [mm]",
            ));
        }
        let entry_tangent = if spec.formula.is_some() && points.len() >= 3 {
            (4.0 * points[1] - 3.0 * points[0] - points[2]).normalize()
        } else {
            (points[1] - points[0]).normalize()
        };
        if !entry_tangent.iter().all(|c| c.is_finite()) {
            return Err(PathError::new("path", "the entry tangent is undefined"));
        }
        Ok(Self {
            points,
            arc,
            approach: spec.approach,
            entry_tangent,
        })
    }

    /// Length of the path inside the gel, from the entry point [mm].
    pub fn length(&self) -> f64 {
        self.arc.last().copied().unwrap_or(0.0)
    }

    /// The entry point (first vertex) [mm].
    pub fn entry(&self) -> Vector3<f64> {
        self.points[0]
    }

    /// Unit tangent at the entry point.
    pub fn entry_tangent(&self) -> Vector3<f64> {
        self.entry_tangent
    }

    /// The needle tip's start: `approach` before the entry point along the entry tangent [mm].
    pub fn start_tip(&self) -> Vector3<f64> {
        self.entry() - self.approach * self.entry_tangent()
    }

    /// Total length from the start tip through the approach to the path's end [mm].
    pub fn total_length(&self) -> f64 {
        self.approach + self.length()
    }

    /// Index of the segment holding arc length `l` (clamped to the path) and the local fraction.
    pub fn locate(&self, l: f64) -> (usize, f64) {
        let l = l.clamp(0.0, self.length());
        let seg = match self.arc.binary_search_by(|a| a.total_cmp(&l)) {
            Ok(i) => i.min(self.points.len() - 2),
            Err(i) => i.saturating_sub(1).min(self.points.len() - 2),
        };
        let len = self.arc[seg + 1] - self.arc[seg];
        (seg, ((l - self.arc[seg]) / len).clamp(0.0, 1.0))
    }

    /// The point at arc length `l` (from the start tip) of the path straightened by `beta` ∈
    /// [0, 1] towards its chord from `from` [mm] of path past the entry point: the straight
    /// line from the path's point there to the path's end. `P(l) + beta (C(u) − P(l))`, `C(u)`
    /// the chord's point at the same fraction `u` of the path's length past `from`. The
    /// approach, the path up to `from` and the end are the path's own; `beta` = 0 is the path,
    /// 1 the chord; `from` = 0 the chord from the entry point (at or past the path's length:
    /// the path itself).
    ///
    /// A needle whose gel holds its shaft (a short steering length) can turn its tip while it is
    /// shallow and hardly at all deep in the gel: it can follow the path while shallow and a
    /// straight line after, not a bend that goes on deep. The controller is shown the
    /// straightened path (`inverse.straighten`, `inverse.straighten_from`); the errors are
    /// still measured against the planned one.
    pub fn straightened(&self, l: f64, beta: f64, from: f64) -> Vector3<f64> {
        let p = self.at(l).0;
        let len = self.length();
        let from = from.max(0.0);
        let start = self.approach + from;
        if l <= start || beta == 0.0 || from >= len {
            return p;
        }
        let u = ((l - start) / (len - from)).min(1.0);
        let a = self.at(start).0;
        let end = self.points[self.points.len() - 1];
        let chord = a + u * (end - a);
        p + beta * (chord - p)
    }

    /// Point and unit tangent at arc length `l` from the start tip (the approach counts, so
    /// `l < approach` lies in the air on the straight approach segment) [mm].
    pub fn at(&self, l: f64) -> (Vector3<f64>, Vector3<f64>) {
        if l < self.approach {
            let t = self.entry_tangent();
            return (self.start_tip() + l.max(0.0) * t, t);
        }
        let (seg, f) = self.locate(l - self.approach);
        let a = self.points[seg];
        let b = self.points[seg + 1];
        (a + f * (b - a), (b - a).normalize())
    }
}

//! Where a result comes from: the build (commit, compiler), the machine (CPU model, logical
//! cores) and the date, recorded in every run summary and in the report.

use serde::Serialize;

/// Provenance of a result.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct Provenance {
    /// The package version.
    pub version: String,
    /// The commit the binary was built from (`-dirty`: with uncommitted changes; `unknown`
    /// outside a git checkout).
    pub commit: String,
    /// The compiler (`rustc --version`).
    pub rustc: String,
    /// The CPU model (`/proc/cpuinfo`), or `unknown`.
    pub cpu: String,
    /// Logical cores available.
    pub cores: usize,
    /// When the result was made, UTC (`YYYY-MM-DDTHH:MM:SSZ`).
    pub date: String,
}

impl Provenance {
    /// The provenance of a result made now by this binary on this machine.
    pub fn now() -> Self {
        let secs = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_secs());
        Self {
            version: env!("CARGO_PKG_VERSION").to_owned(),
            commit: env!("NEEDLE_COMMIT").to_owned(),
            rustc: env!("NEEDLE_RUSTC").to_owned(),
            cpu: cpu_model().unwrap_or_else(|| "unknown".to_owned()),
            cores: std::thread::available_parallelism().map_or(1, |n| n.get()),
            date: utc_date(secs),
        }
    }
}

impl Provenance {
    /// One sentence for a report: "Made on DATE by needle VERSION at commit `C` (RUSTC), on CPU
    /// (N logical cores)."
    pub fn sentence(&self) -> String {
        format!(
            "Made on {} by needle {} at commit `{}` ({}), on {} ({} logical cores).",
            self.date, self.version, self.commit, self.rustc, self.cpu, self.cores
        )
    }
}

/// The CPU's model name from `/proc/cpuinfo`.
fn cpu_model() -> Option<String> {
    let text = std::fs::read_to_string("/proc/cpuinfo").ok()?;
    text.lines()
        .find(|l| l.starts_with("model name"))
        .and_then(|l| l.split_once(':'))
        .map(|(_, v)| v.trim().to_owned())
}

/// `secs` since the Unix epoch as an ISO 8601 UTC date and time (proleptic Gregorian calendar,
/// H. Hinnant's days-to-civil algorithm).
pub fn utc_date(secs: u64) -> String {
    let days = (secs / 86_400) as i64;
    let rem = secs % 86_400;
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!(
        "{year:04}-{month:02}-{day:02}T{:02}:{:02}:{:02}Z",
        rem / 3600,
        rem % 3600 / 60,
        rem % 60
    )
}

#[cfg(test)]
mod tests {
    use super::utc_date;

    #[test]
    fn utc_dates_match_known_instants() {
        assert_eq!(utc_date(0), "1970-01-01T00:00:00Z");
        // `date -u -d @951782400`: a leap day.
        assert_eq!(utc_date(951_782_400), "2000-02-29T00:00:00Z");
        // `date -u -d @1795865400`.
        assert_eq!(utc_date(1_795_865_400), "2026-11-28T11:30:00Z");
    }

    #[test]
    fn provenance_names_the_build_and_the_machine() {
        let p = super::Provenance::now();
        assert!(!p.commit.is_empty() && !p.rustc.is_empty());
        assert!(
            p.rustc.starts_with("rustc ") || p.rustc == "unknown",
            "{}",
            p.rustc
        );
        assert!(p.cores >= 1);
        assert_eq!(p.date.len(), 20);
    }
}

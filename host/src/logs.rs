//! The binaries' log on stderr through `tracing`: one subscriber set-up for `needle` and
//! `needle-controller`.

/// Installs the log: events at `level` and above (`"warn"`, `"info"`, …), unless `RUST_LOG`
/// says otherwise; colours only on a terminal. A second call does nothing.
pub fn init(level: &str) {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(level));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_target(false)
        .try_init();
}

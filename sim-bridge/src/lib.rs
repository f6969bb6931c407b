//! `needle-bridge`: frames and commands between host and core.

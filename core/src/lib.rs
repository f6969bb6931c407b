//! `needle-core`: the fixed-capacity, allocation-free step core.
#![cfg_attr(not(test), no_std)]

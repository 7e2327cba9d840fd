//! Helpers shared by the benchmarks: peak-memory measurement and the shared data folder.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

#[allow(unused_imports)]
pub use scanstation::pipeline::memory::reset_peak;

/// Peak RSS (VmHWM) in MiB; NaN where unavailable.
pub fn peak_mib() -> f64 {
    scanstation::pipeline::memory::status_mib("VmHWM:").unwrap_or(f64::NAN)
}

/// The shared scan data folder (`SCANSTATION_SHARED_DATA`, default `../shared/data`).
pub fn data_dir() -> PathBuf {
    std::env::var_os("SCANSTATION_SHARED_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data"))
}

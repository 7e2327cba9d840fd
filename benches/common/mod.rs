//! Helpers shared by the benchmarks: peak-memory measurement and the shared data folder.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

/// Reset the kernel's peak-RSS counter (VmHWM) to the current RSS; false when not permitted.
pub fn reset_peak() -> bool {
    std::fs::write("/proc/self/clear_refs", "5").is_ok()
}

/// Peak RSS (VmHWM) in MiB.
pub fn peak_mib() -> f64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status
        .lines()
        .find(|l| l.starts_with("VmHWM:"))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|kb| kb.parse::<f64>().ok())
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

/// The shared scan data folder (`SCANSTATION_SHARED_DATA`, default `../shared/data`).
pub fn data_dir() -> PathBuf {
    std::env::var_os("SCANSTATION_SHARED_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data"))
}

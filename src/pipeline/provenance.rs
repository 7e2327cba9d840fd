//! Provenance of the files a conversion writes: content hashes, and the artifacts beside a STEP file
//! (`NAME.solid.ply`, the solid's tessellation whose header names the STEP's hash, and `NAME.error-map.ply`).

use std::io::Read;
use std::path::{Path, PathBuf};

use sha2::{Digest, Sha256};

use crate::error::{Error, ErrorCode, Result};

/// Comment key of the solid artifact's PLY header.
pub const SOLID_OF: &str = "scanstation-solid-of sha256=";

/// Hex SHA-256 of a file's bytes.
pub fn sha256_file(path: &Path) -> Result<String> {
    let mut f = std::fs::File::open(path).map_err(|e| Error::new(ErrorCode::InputIo, e.to_string()).in_file(path))?;
    let mut h = Sha256::new();
    let mut buf = vec![0u8; 1 << 16];
    loop {
        let n = f.read(&mut buf).map_err(|e| Error::new(ErrorCode::InputIo, e.to_string()).in_file(path))?;
        if n == 0 {
            break;
        }
        h.update(&buf[..n]);
    }
    Ok(h.finalize().iter().map(|b| format!("{b:02x}")).collect())
}

/// The solid artifact path beside a STEP file: `NAME.step` → `NAME.solid.ply`.
pub fn solid_artifact_path(step: &Path) -> PathBuf {
    step.with_extension("solid.ply")
}

/// The error map beside a STEP file: `NAME.step` → `NAME.error-map.ply` (the solid's tessellation coloured by
/// its distance to the scan).
pub fn error_map_path(step: &Path) -> PathBuf {
    step.with_extension("error-map.ply")
}

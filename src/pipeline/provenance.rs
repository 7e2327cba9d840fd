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

/// Most files a directory input (a scan set) may hold, and how deep it may nest.
pub const MAX_TREE_FILES: usize = 10_000;
/// See [`MAX_TREE_FILES`].
pub const MAX_TREE_DEPTH: usize = 4;

/// The regular files under `dir` (symbolic links followed to files), relative, sorted.
fn tree_files(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    let mut stack = vec![(PathBuf::new(), 0usize)];
    while let Some((rel, depth)) = stack.pop() {
        let here = dir.join(&rel);
        let rd = std::fs::read_dir(&here).map_err(|e| Error::new(ErrorCode::InputIo, e.to_string()).in_file(&here))?;
        for e in rd.flatten() {
            let r = rel.join(e.file_name());
            let Ok(m) = std::fs::metadata(e.path()) else { continue };
            if m.is_dir() && depth < MAX_TREE_DEPTH {
                stack.push((r, depth + 1));
            } else if m.is_file() {
                out.push(r);
            }
            if out.len() > MAX_TREE_FILES {
                return Err(
                    Error::new(ErrorCode::InputTooLarge, format!("more than {MAX_TREE_FILES} files")).in_file(dir)
                );
            }
        }
    }
    out.sort();
    Ok(out)
}

/// The sha256 of an input: a file's content, or for a directory (a scan set) the sha256 of its listing,
/// one line `relative/path NUL sha256-of-the-file` per file in sorted order, so equal trees hash equal
/// wherever they lie.
///
/// # Errors
/// `input.io` when it cannot be read; `input.too-large` for a directory of more than [`MAX_TREE_FILES`].
pub fn sha256_input(path: &Path) -> Result<String> {
    if !path.is_dir() {
        return sha256_file(path);
    }
    let mut h = Sha256::new();
    for rel in tree_files(path)? {
        h.update(rel.to_string_lossy().as_bytes());
        h.update([0u8]);
        h.update(sha256_file(&path.join(&rel))?.as_bytes());
        h.update(b"\n");
    }
    Ok(h.finalize().iter().map(|b| format!("{b:02x}")).collect())
}

/// The bytes of an input: a file's size, or the sum over a directory's files (0 when unreadable).
pub fn input_size(path: &Path) -> u64 {
    if !path.is_dir() {
        return std::fs::metadata(path).map_or(0, |m| m.len());
    }
    tree_files(path).map_or(0, |fs| fs.iter().map(|r| std::fs::metadata(path.join(r)).map_or(0, |m| m.len())).sum())
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

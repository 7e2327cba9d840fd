//! Durable writes: a file replaced atomically and its directory fsynced, so a rename survives a power loss.
//! Every record the daemon keeps (journal, reports, manifests, capture logs) is written this way.

use std::io::Write;
use std::path::Path;

/// Write `bytes` to `path` atomically and durably: [`crate::geometry::io::write_atomic`] (temp file, fsync,
/// rename), then an fsync of the directory so the rename itself survives a power loss. Returns the file's
/// size and SHA-256, taken while writing.
///
/// # Errors
/// The I/O error.
pub fn write_durable(path: &Path, bytes: &[u8]) -> std::io::Result<crate::geometry::io::FileDigest> {
    let digest = crate::geometry::io::write_atomic(path, |w| w.write_all(bytes)).map_err(std::io::Error::other)?;
    sync_dir(path.parent().unwrap_or(Path::new(".")))?;
    Ok(digest)
}

/// fsync a directory (makes renames and creations in it durable).
///
/// # Errors
/// The I/O error.
pub fn sync_dir(dir: &Path) -> std::io::Result<()> {
    std::fs::File::open(dir)?.sync_all()
}

//! The watch-folder spool on disk: `inbox/`, `work/<id>/`, `outbox/<stem>-<id>/`, `quarantine/<stem>-<id>/`,
//! all on one filesystem so that every move is a `rename(2)`: claiming, publishing and quarantining are
//! atomic, and a crash leaves each file in exactly one place.

use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};

use super::config::Config;
use super::durable::sync_dir;
use super::journal::JobId;

/// Sidecar suffix for per-job options (`scan.ply` + `scan.ply.job.toml` or `scan.job.toml`).
pub const SIDECAR_SUFFIX: &str = ".job.toml";
/// Largest sidecar (`NAME.job.toml`), bytes: a handful of options is a few hundred bytes.
pub const MAX_SIDECAR_BYTES: u64 = 64 << 10;

/// Paths of the spool.
#[derive(Clone, Debug)]
pub struct Spool {
    /// The spool root.
    pub root: PathBuf,
    /// Where files are dropped.
    pub inbox: PathBuf,
    /// Claimed inputs, one directory per job.
    pub work: PathBuf,
    /// Published results, one directory per job.
    pub outbox: PathBuf,
    /// Failed and cancelled jobs, one directory per job.
    pub quarantine: PathBuf,
}

/// A start-up error of the spool: the path and the reason.
#[derive(Debug, thiserror::Error)]
#[error("spool {path}: {reason}")]
pub struct SpoolError {
    /// The directory at fault.
    pub path: String,
    /// What is wrong with it.
    pub reason: String,
}

impl Spool {
    /// Create the four directories where missing and check that they are writable and on one filesystem.
    ///
    /// # Errors
    /// [`SpoolError`] naming the directory (cannot create, not writable, another filesystem).
    pub fn open(root: &Path) -> Result<Spool, SpoolError> {
        let s = Spool {
            root: root.to_path_buf(),
            inbox: root.join("inbox"),
            work: root.join("work"),
            outbox: root.join("outbox"),
            quarantine: root.join("quarantine"),
        };
        let mut dev = None;
        for d in [&s.inbox, &s.work, &s.outbox, &s.quarantine] {
            let e = |reason: String| SpoolError { path: d.display().to_string(), reason };
            std::fs::create_dir_all(d).map_err(|x| e(format!("cannot create: {x}")))?;
            let probe = d.join(format!(".scanstation-probe-{}", std::process::id()));
            std::fs::write(&probe, b"").map_err(|x| e(format!("not writable: {x}")))?;
            let _ = std::fs::remove_file(&probe);
            let m = std::fs::metadata(d).map_err(|x| e(x.to_string()))?;
            match dev {
                None => dev = Some(m.dev()),
                Some(v) if v != m.dev() => {
                    return Err(e("is on another filesystem than inbox/ (every move must be a rename)".into()));
                }
                _ => {}
            }
        }
        Ok(s)
    }

    /// The job's private directory.
    pub fn work_dir(&self, id: &JobId) -> PathBuf {
        self.work.join(id.as_str())
    }

    /// The published output directory of a job.
    pub fn outbox_dir(&self, stem: &str, id: &JobId) -> PathBuf {
        self.outbox.join(format!("{stem}-{id}"))
    }

    /// The output directory while it is written (hidden, renamed on publication).
    pub fn outbox_part(&self, stem: &str, id: &JobId) -> PathBuf {
        self.outbox.join(format!(".{stem}-{id}.part"))
    }

    /// `quarantine/<stem>-<id>/`.
    pub fn quarantine_dir(&self, stem: &str, id: &JobId) -> PathBuf {
        self.quarantine.join(format!("{stem}-{id}"))
    }

    /// `quarantine/.<stem>-<id>.part/`, where a quarantine is built before its rename.
    pub fn quarantine_part(&self, stem: &str, id: &JobId) -> PathBuf {
        self.quarantine.join(format!(".{stem}-{id}.part"))
    }
}

/// Whether an inbox name is a candidate input (not hidden, not a temp suffix, not a sidecar).
pub fn is_candidate(name: &str, cfg: &Config) -> bool {
    !name.starts_with('.')
        && !name.ends_with(SIDECAR_SUFFIX)
        && !cfg.ignore_suffixes.iter().any(|s| !s.is_empty() && name.ends_with(s.as_str()))
}

/// Whether the extension is one the pipeline accepts (`.gz` of an accepted one too), case-insensitive.
pub fn is_accepted(name: &str, cfg: &Config) -> bool {
    let lower = name.to_ascii_lowercase();
    let base = lower.strip_suffix(".gz").unwrap_or(&lower);
    Path::new(base).extension().and_then(|e| e.to_str()).is_some_and(|e| cfg.accept.iter().any(|a| a == e))
}

/// The sidecar of an inbox file, if one exists: `NAME.job.toml` or `STEM.job.toml`.
pub fn sidecar_of(inbox_file: &Path) -> Option<PathBuf> {
    let name = inbox_file.file_name()?.to_string_lossy().into_owned();
    let dir = inbox_file.parent()?;
    let a = dir.join(format!("{name}{SIDECAR_SUFFIX}"));
    if a.is_file() {
        return Some(a);
    }
    let stem = Path::new(&name).file_stem()?.to_string_lossy().into_owned();
    let b = dir.join(format!("{stem}{SIDECAR_SUFFIX}"));
    b.is_file().then_some(b)
}

/// Move a finished directory from its `.part` name to its public name, durably.
///
/// # Errors
/// The I/O error.
pub fn publish_dir(part: &Path, public: &Path) -> std::io::Result<()> {
    sync_dir(part)?;
    std::fs::rename(part, public)?;
    sync_dir(public.parent().unwrap_or(Path::new(".")))
}

/// Size and modification time of a file, or of a directory itself (its mtime changes as entries come and
/// go); None when gone or anything else.
pub fn stat(path: &Path) -> Option<(u64, i64, i64)> {
    let m = std::fs::symlink_metadata(path).ok()?;
    (m.is_file() || m.is_dir()).then(|| (if m.is_dir() { 0 } else { m.len() }, m.mtime(), m.mtime_nsec()))
}

//! The crash-safe job journal: one JSON record per job in `STATE/jobs/<id>.json`, each write atomic (temp
//! file in the same directory, fsync, rename, fsync of the directory). The journal plus the spool layout is
//! the whole truth after a restart; see [`super::station`] for the recovery rules.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{SystemTime, UNIX_EPOCH};

use sha2::{Digest, Sha256};

use super::config::JobOptions;
use super::durable::write_durable;

/// Schema of a record; bumped on incompatible change.
pub const SCHEMA: u32 = 1;

/// Microseconds since the Unix epoch (0 never occurs for a real time).
pub fn now_usec() -> u64 {
    SystemTime::now().duration_since(UNIX_EPOCH).map(|d| d.as_micros() as u64).unwrap_or(0)
}

/// A job id: 26 characters of Crockford base32, sortable by creation time (48-bit milliseconds, then 80
/// bits from a hash of time, pid and a counter). Valid as a D-Bus object-path element and a file name.
#[derive(Clone, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize, serde::Deserialize)]
#[serde(transparent)]
pub struct JobId(pub String);

const CROCKFORD: &[u8; 32] = b"0123456789ABCDEFGHJKMNPQRSTVWXYZ";

impl JobId {
    /// A new id.
    pub fn new() -> JobId {
        static COUNTER: AtomicU64 = AtomicU64::new(0);
        let ns = SystemTime::now().duration_since(UNIX_EPOCH).map(|d| d.as_nanos()).unwrap_or(0);
        let ms = (ns / 1_000_000) as u64 & ((1 << 48) - 1);
        let mut h = Sha256::new();
        h.update(ns.to_le_bytes());
        h.update(std::process::id().to_le_bytes());
        h.update(COUNTER.fetch_add(1, Ordering::Relaxed).to_le_bytes());
        let r = h.finalize();
        let mut bits: u128 = (ms as u128) << 80;
        for (i, b) in r.iter().take(10).enumerate() {
            bits |= (*b as u128) << (8 * (9 - i));
        }
        let s: String = (0..26).rev().map(|k| CROCKFORD[((bits >> (5 * k)) & 31) as usize] as char).collect();
        JobId(s)
    }

    /// Accept an id string only if it has the form of one of ours (so it can name paths safely).
    pub fn parse(s: &str) -> Option<JobId> {
        (s.len() == 26 && s.bytes().all(|b| CROCKFORD.contains(&b))).then(|| JobId(s.to_string()))
    }

    /// The id as text.
    pub fn as_str(&self) -> &str {
        &self.0
    }
}

impl Default for JobId {
    fn default() -> Self {
        Self::new()
    }
}

impl std::fmt::Display for JobId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

/// Lifecycle of a job. Terminal states never change again.
#[derive(Copy, Clone, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum JobState {
    /// Waiting for a worker.
    Queued,
    /// On a worker.
    Running,
    /// Published to the outbox.
    Succeeded,
    /// Quarantined with an error.
    Failed,
    /// Stopped on request and quarantined.
    Cancelled,
}

impl JobState {
    /// The state as D-Bus and the journal write it.
    pub fn as_str(self) -> &'static str {
        match self {
            JobState::Queued => "queued",
            JobState::Running => "running",
            JobState::Succeeded => "succeeded",
            JobState::Failed => "failed",
            JobState::Cancelled => "cancelled",
        }
    }

    /// Succeeded, failed or cancelled: never changes again.
    pub fn is_terminal(self) -> bool {
        matches!(self, JobState::Succeeded | JobState::Failed | JobState::Cancelled)
    }
}

/// One job as the journal keeps it.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct JobRecord {
    /// Record schema ([`SCHEMA`]).
    pub schema: u32,
    /// The job's id.
    pub id: JobId,
    /// The input's file name as it arrived.
    pub input: String,
    /// Where it came from: `inbox` or `dbus:<unique name>`.
    pub source: String,
    /// Hex SHA-256 of the input.
    pub input_sha256: String,
    /// Input size, bytes.
    pub input_size: u64,
    /// Options from the sidecar or `SubmitFile`.
    pub options: JobOptions,
    /// Where it is in its lifecycle.
    pub state: JobState,
    /// The stage it is in (or ended in).
    pub stage: String,
    /// When it was queued, µs since the epoch.
    pub submitted_usec: u64,
    /// When it last started, µs since the epoch (0: never).
    pub start_usec: u64,
    /// When it ended, µs since the epoch (0: not yet).
    pub finish_usec: u64,
    /// Times this job was started (more than one after a resume).
    pub runs: u32,
    /// Stable error code when it failed or was cancelled.
    pub error_code: String,
    /// Human-readable message of that error.
    pub message: String,
    /// Files it published (kind → path).
    pub outputs: BTreeMap<String, String>,
    /// Peak memory of its last run, bytes.
    pub peak_memory: u64,
    /// Whether `Completed` was emitted (a terminal record without it is announced after a restart).
    pub announced: bool,
    /// A scan session (`StartScan`): what to capture. Its input is then the scan directory in `work/<id>/`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scan: Option<super::scan::ScanRequest>,
    /// Its conversion on a Slurm cluster (`[executor] kind = "slurm"`): the cluster's job id, journaled as
    /// soon as `sbatch` returns it, so a restarted daemon follows that job instead of submitting again.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cluster: Option<ClusterRun>,
}

/// A job's conversion on a Slurm cluster.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct ClusterRun {
    /// Slurm's job id of the current submission.
    pub slurm_id: u64,
    /// Submissions so far (2 after a node failure was resubmitted once).
    pub submissions: u32,
}

impl JobRecord {
    /// A record for a job just queued (not started, default options, no scan), in its first `stage`.
    pub fn queued(
        id: JobId,
        input: String,
        source: String,
        input_sha256: String,
        input_size: u64,
        stage: &str,
    ) -> JobRecord {
        JobRecord {
            schema: SCHEMA,
            id,
            input,
            source,
            input_sha256,
            input_size,
            options: JobOptions::default(),
            state: JobState::Queued,
            stage: stage.into(),
            submitted_usec: now_usec(),
            start_usec: 0,
            finish_usec: 0,
            runs: 0,
            error_code: String::new(),
            message: String::new(),
            outputs: BTreeMap::new(),
            peak_memory: 0,
            announced: false,
            scan: None,
            cluster: None,
        }
    }

    /// The stem used in outbox and quarantine names: the input name without its extension(s), reduced to
    /// safe characters.
    pub fn stem(&self) -> String {
        let mut s = self.input.as_str();
        for ext in [".gz"] {
            if s.to_ascii_lowercase().ends_with(ext) {
                s = &s[..s.len() - ext.len()];
            }
        }
        let s = Path::new(s).file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        let clean: String =
            s.chars().map(|c| if c.is_ascii_alphanumeric() || "-_.".contains(c) { c } else { '_' }).take(80).collect();
        if clean.is_empty() || clean.starts_with('.') { format!("scan{clean}") } else { clean }
    }

    /// `result` for `Completed`: "" until terminal.
    pub fn result(&self) -> &'static str {
        if self.state.is_terminal() { self.state.as_str() } else { "" }
    }
}

/// The journal directory.
pub struct Journal {
    dir: PathBuf,
}

impl Journal {
    /// Open (creating) `STATE/jobs`.
    ///
    /// # Errors
    /// The I/O error.
    pub fn open(state: &Path) -> std::io::Result<Journal> {
        let dir = state.join("jobs");
        std::fs::create_dir_all(&dir)?;
        Ok(Journal { dir })
    }

    /// Persist a record (atomically).
    ///
    /// # Errors
    /// The I/O error.
    pub fn save(&self, r: &JobRecord) -> std::io::Result<()> {
        let bytes = serde_json::to_vec_pretty(r).map_err(std::io::Error::other)?;
        write_durable(&self.dir.join(format!("{}.json", r.id)), &bytes).map(|_| ())
    }

    /// Every readable record, oldest id first; unreadable ones are logged and skipped (left in place).
    pub fn load_all(&self) -> Vec<JobRecord> {
        let mut out = Vec::new();
        let Ok(rd) = std::fs::read_dir(&self.dir) else { return out };
        for e in rd.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            if name.starts_with('.') {
                // A temp file from an interrupted write: the rename never happened, the old record stands.
                let _ = std::fs::remove_file(e.path());
                continue;
            }
            if !name.ends_with(".json") {
                continue;
            }
            match std::fs::read(e.path())
                .map_err(|e| e.to_string())
                .and_then(|b| serde_json::from_slice::<JobRecord>(&b).map_err(|e| e.to_string()))
            {
                Ok(r) => out.push(r),
                Err(err) => tracing::error!(file = %e.path().display(), %err, "unreadable job record skipped"),
            }
        }
        out.sort_by(|a, b| a.id.cmp(&b.id));
        out
    }
}

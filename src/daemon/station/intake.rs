//! Intake: the inbox scan, files settling, the claim (rename into `work/<id>/`, hash, admit) and
//! `SubmitFile`.

use std::path::{Path, PathBuf};
use std::time::Instant;

use super::*;
use crate::daemon::config::JobOptions;
use crate::daemon::dbus::StationError;
use crate::daemon::durable::sync_dir;
use crate::daemon::journal::{JobId, JobRecord};
use crate::daemon::spool;
use crate::daemon::watch::WatchEvent;
use crate::daemon::worker::STAGES;
use crate::error::{Error, ErrorCode};

/// A claimed inbox file's hash, computed off the actor's task ([`Station::claim`]).
pub struct Hashed {
    pub id: JobId,
    pub sha256: Result<String, Error>,
}

/// A claimed file waiting for its hash (and, for a file submitted from outside the inbox, its copy); claims
/// are admitted in the order they were made.
pub(super) struct Hashing {
    id: JobId,
    dest: PathBuf,
    /// `inbox`, or `dbus:<sender>` for `SubmitFile`.
    source: String,
    /// `SubmitFile`'s options (they override a sidecar's) and its pending answer; `None` for an inbox claim.
    submitted: Option<(JobOptions, tokio::sync::oneshot::Sender<Result<JobId, StationError>>)>,
    sha256: Option<Result<String, Error>>,
}

impl Station {
    /// A new record for the claimed `input`, hashing it here. Cost: reads the whole input.
    pub(super) fn new_record(&self, id: JobId, input: &Path, source: String) -> std::io::Result<JobRecord> {
        let sha = crate::pipeline::provenance::sha256_input(input).map_err(std::io::Error::other)?;
        Ok(Self::record(id, input, source, sha))
    }

    /// A new queued record for the claimed `input` whose hash is `sha`.
    fn record(id: JobId, input: &Path, source: String, sha: String) -> JobRecord {
        let name = input.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let size = crate::pipeline::provenance::input_size(input);
        JobRecord::queued(id, name, source, sha, size, STAGES[0])
    }

    /// Read the sidecar, check size and duplicates: the record with its options, and an error that sends
    /// the job straight to quarantine.
    pub(super) fn admit(&mut self, mut rec: JobRecord, input: &Path) -> (JobRecord, Option<Error>) {
        let mut preset = None;
        let work = input.parent().unwrap_or(Path::new("."));
        let sidecar = std::fs::read_dir(work)
            .ok()
            .and_then(|r| r.flatten().map(|f| f.path()).find(|p| p.to_string_lossy().ends_with(spool::SIDECAR_SUFFIX)));
        if let Some(sc) = sidecar {
            let text = crate::geometry::io::read_small_text(&sc, spool::MAX_SIDECAR_BYTES, "the sidecar");
            match text.map_err(|e| e.message).and_then(|t| JobOptions::parse_toml(&t)) {
                Ok(o) => rec.options = o,
                Err(m) => {
                    preset = Some(Error::new(
                        ErrorCode::InputBadArgument,
                        format!("sidecar {}: {m}", sc.file_name().unwrap_or_default().to_string_lossy()),
                    ))
                }
            }
        }
        if rec.input_size > self.cfg.max_input_size {
            preset = Some(Error::new(
                ErrorCode::InputTooLarge,
                format!("{} bytes exceed limits.max_input_size ({} bytes)", rec.input_size, self.cfg.max_input_size),
            ));
        }
        if preset.is_none()
            && !self.cfg.dedupe_window.is_zero()
            && let Some((other, at)) = self.seen.get(&rec.input_sha256)
            && *other != rec.id
            && rec.submitted_usec.saturating_sub(*at) <= self.cfg.dedupe_window.as_micros() as u64
        {
            tracing::warn!(job_id = %rec.id, duplicate_of = %other, sha256 = %rec.input_sha256, "same content processed recently; skipped");
            preset = Some(Error::new(
                ErrorCode::InputDuplicate,
                format!("the same content (sha256 {}) was submitted as job {other}", rec.input_sha256),
            ));
        }
        if preset.is_none() {
            self.seen.insert(rec.input_sha256.clone(), (rec.id.clone(), rec.submitted_usec));
        }
        (rec, preset)
    }

    /// `SubmitFile`: claim `path` as a job and answer `reply` with its id once it is hashed and queued. A file
    /// in the inbox is renamed into `work/<id>/` here; one from elsewhere is copied, and the copy and the hash
    /// (each reading the whole file) run off the actor's task, so D-Bus calls are answered meanwhile. A claim
    /// interrupted before it is queued is left in `work/<id>/` and recovered as an orphan at the next start.
    pub(super) fn submit(
        &mut self,
        path: &Path,
        options: JobOptions,
        source: String,
        reply: tokio::sync::oneshot::Sender<Result<JobId, StationError>>,
    ) {
        if self.paused {
            let _ = reply.send(Err(StationError::IntakePaused("intake is paused (ResumeIntake to continue)".into())));
            return;
        }
        if !path.is_file() {
            let _ = reply.send(Err(StationError::NotFound(format!("{} is not a readable file", path.display()))));
            return;
        }
        let in_inbox = path.parent().is_some_and(|p| same_dir(p, &self.spool.inbox));
        let id = JobId::new();
        let work = self.spool.work_dir(&id);
        let name = path.file_name().map(|n| n.to_os_string()).unwrap_or_default();
        let dest = work.join(&name);
        let what = format!("cannot claim {}", path.display());
        if let Err(e) = std::fs::create_dir_all(&work) {
            let _ = reply.send(Err(StationError::Internal(format!("{what}: {e}"))));
            return;
        }
        if in_inbox && let Err(e) = std::fs::rename(path, &dest).and_then(|()| sync_dir(&work)) {
            let _ = std::fs::remove_dir(&work);
            let _ = reply.send(Err(StationError::Internal(format!("{what}: {e}"))));
            return;
        }
        self.hashing.push_back(Hashing {
            id: id.clone(),
            dest: dest.clone(),
            source,
            submitted: Some((options, reply)),
            sha256: None,
        });
        let (tx, src) = (self.intake_tx.clone(), path.to_path_buf());
        tokio::task::spawn_blocking(move || {
            let copied = if in_inbox { Ok(()) } else { copy_durably(&src, &dest, &work) };
            let sha256 = copied
                .map_err(|e| Error::new(ErrorCode::InputIo, format!("{what}: {e}")))
                .and_then(|()| crate::pipeline::provenance::sha256_input(&dest));
            let _ = tx.send(Hashed { id, sha256 });
        });
    }

    pub(super) async fn enqueue(&mut self, rec: JobRecord, preset: Option<Error>) -> std::io::Result<()> {
        self.journal.save(&rec)?;
        let id = rec.id.clone();
        tracing::info!(job_id = %id, input = %rec.input, sha256 = %rec.input_sha256, source = %rec.source, "job queued");
        self.insert(rec, preset);
        self.export(&id).await.map_err(std::io::Error::other)?;
        self.queue.push_back(id);
        Ok(())
    }

    /// Claim an inbox file: rename into `work/<id>/` (the rename is the lock), then queue it.
    pub(super) async fn claim(&mut self, name: &str) {
        if self.paused || !self.degraded.is_empty() {
            return;
        }
        let src = self.spool.inbox.join(name);
        // A file, or a directory renamed in whole (a scan set; README, "Watch folders").
        let kind = std::fs::symlink_metadata(&src).map(|m| m.file_type());
        if !kind.is_ok_and(|k| k.is_file() || k.is_dir()) {
            return;
        }
        let id = JobId::new();
        let work = self.spool.work_dir(&id);
        if let Err(e) = std::fs::create_dir_all(&work) {
            tracing::error!(error = %e, "cannot create work dir");
            return;
        }
        let sidecar = spool::sidecar_of(&src);
        let dest = work.join(name);
        if let Err(e) = std::fs::rename(&src, &dest) {
            let _ = std::fs::remove_dir(&work);
            tracing::warn!(file = name, error = %e, "could not claim");
            return;
        }
        if let Some(sc) = sidecar {
            let _ = std::fs::rename(&sc, work.join(sc.file_name().unwrap_or_default()));
        }
        let _ = sync_dir(&work);
        let _ = sync_dir(&self.spool.inbox);
        // Hashing reads the whole file: off the actor's task, so D-Bus calls are answered meanwhile. A claim
        // interrupted here is left in work/<id>/ and recovered as an orphan at the next start.
        self.hashing.push_back(Hashing {
            id: id.clone(),
            dest: dest.clone(),
            source: "inbox".into(),
            submitted: None,
            sha256: None,
        });
        let tx = self.intake_tx.clone();
        tokio::task::spawn_blocking(move || {
            let sha256 = crate::pipeline::provenance::sha256_input(&dest);
            let _ = tx.send(Hashed { id, sha256 });
        });
    }

    /// A claim's hash arrived: admit and queue the claims whose hashes are in, in the order of the claims,
    /// answering `SubmitFile` for those it made.
    pub(super) async fn hashed(&mut self, h: Hashed) {
        if let Some(p) = self.hashing.iter_mut().find(|p| p.id == h.id) {
            p.sha256 = Some(h.sha256);
        }
        while self.hashing.front().is_some_and(|p| p.sha256.is_some()) {
            let Some(Hashing { id, dest, source, submitted, sha256: Some(sha256) }) = self.hashing.pop_front() else {
                break;
            };
            let (options, reply) = submitted.map_or((None, None), |(o, r)| (Some(o), Some(r)));
            let answer = |r: Result<JobId, StationError>| {
                if let Some(reply) = reply {
                    let _ = reply.send(r);
                }
            };
            let sha = match sha256 {
                Ok(s) => s,
                Err(e) => {
                    tracing::error!(job_id = %id, error = %e, "cannot hash the claimed input");
                    if options.is_some() {
                        // Nothing was taken from the submitter's directory: drop the partial copy.
                        let _ = std::fs::remove_dir_all(self.spool.work_dir(&id));
                    }
                    answer(Err(StationError::Internal(e.to_string())));
                    continue;
                }
            };
            let rec = Self::record(id.clone(), &dest, source, sha);
            let (mut rec, preset) = self.admit(rec, &dest);
            if let Some(o) = options
                && o != JobOptions::default()
            {
                rec.options = o;
            }
            match self.enqueue(rec, preset).await {
                Ok(()) => answer(Ok(id)),
                Err(e) => {
                    tracing::error!(job_id = %id, error = %e, "cannot record the job");
                    answer(Err(StationError::Internal(e.to_string())));
                }
            }
        }
    }

    pub(super) fn scan_inbox(&mut self) {
        let Ok(rd) = std::fs::read_dir(&self.spool.inbox) else {
            return;
        };
        let now = Instant::now();
        for e in rd.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            if !spool::is_candidate(&name, &self.cfg) {
                continue;
            }
            let Some(st) = spool::stat(&e.path()) else { continue };
            self.candidates
                .entry(name)
                .and_modify(|c| {
                    if c.stat != st {
                        *c = Candidate { stat: st, since: now };
                    }
                })
                .or_insert(Candidate { stat: st, since: now });
        }
    }

    pub(super) async fn check_candidates(&mut self) {
        let now = Instant::now();
        let mut ready = Vec::new();
        let names: Vec<String> = self.candidates.keys().cloned().collect();
        for name in names {
            match spool::stat(&self.spool.inbox.join(&name)) {
                None => {
                    self.candidates.remove(&name);
                }
                Some(st) => {
                    let c = self.candidates.get_mut(&name).expect("listed");
                    if c.stat != st {
                        *c = Candidate { stat: st, since: now };
                    } else if now.duration_since(c.since) >= self.cfg.settle {
                        ready.push(name);
                    }
                }
            }
        }
        ready.sort();
        for name in ready {
            if self.paused || !self.degraded.is_empty() {
                break;
            }
            self.candidates.remove(&name);
            self.claim(&name).await;
        }
    }

    pub(super) async fn watch_event(&mut self, ev: WatchEvent) {
        match ev {
            WatchEvent::MovedIn(name) => {
                if spool::is_candidate(&name, &self.cfg) && !self.paused {
                    self.candidates.remove(&name);
                    self.claim(&name).await;
                }
            }
            WatchEvent::ClosedWrite(name) => {
                if spool::is_candidate(&name, &self.cfg)
                    && let Some(st) = spool::stat(&self.spool.inbox.join(&name))
                {
                    let now = Instant::now();
                    self.candidates
                        .entry(name)
                        .and_modify(|c| {
                            if c.stat != st {
                                *c = Candidate { stat: st, since: now }
                            }
                        })
                        .or_insert(Candidate { stat: st, since: now });
                }
            }
            WatchEvent::Overflow => {
                tracing::warn!("inotify queue overflow: rescanning the inbox");
                self.scan_inbox();
            }
            WatchEvent::Lost(why) => {
                tracing::error!(reason = %why, "inbox watch lost; state degraded");
                if !self.degraded.iter().any(|d| d == "watch-lost") {
                    self.degraded.push("watch-lost".into());
                }
            }
        }
    }
}

/// Copy `src` to `dest` through a temporary name in `work`, synced, so `dest` is whole or absent.
fn copy_durably(src: &Path, dest: &Path, work: &Path) -> std::io::Result<()> {
    let tmp = work.join(".copy.part");
    std::fs::copy(src, &tmp)?;
    std::fs::File::open(&tmp).and_then(|f| f.sync_all())?;
    std::fs::rename(&tmp, dest)?;
    sync_dir(work)
}

fn same_dir(a: &Path, b: &Path) -> bool {
    match (std::fs::canonicalize(a), std::fs::canonicalize(b)) {
        (Ok(x), Ok(y)) => x == y,
        _ => false,
    }
}

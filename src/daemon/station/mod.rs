//! The station actor: the one task that owns the job table, the queue, the spool and the journal. D-Bus
//! handlers, the inbox watch and the workers talk to it through channels.
//!
//! Claiming an inbox file: `mkdir work/<id>`, rename the file (and its sidecar) into it, hash it, write the
//! journal record, export the job object. Recovery after a restart (also after `kill -9`):
//! - a `work/<id>/` without a record (crash right after the rename) becomes a queued job again;
//! - a record `queued` is queued again;
//! - a record `running`: if `outbox/<stem>-<id>/` exists the job had published and is `succeeded`; if
//!   `quarantine/<stem>-<id>/` exists it had failed; otherwise its half-built `.part` directories are
//!   removed and it is re-queued (`pipeline.resume = true`, the default) or quarantined as `interrupted`;
//! - a terminal record whose `Completed` was not yet emitted is announced once the bus name is ours.
//!
//! So every claimed input ends in exactly one outbox or one quarantine directory.

use std::collections::{BTreeMap, HashMap, VecDeque};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tokio::sync::mpsc;
use zbus::Connection;
use zbus::object_server::{InterfaceRef, SignalEmitter};
use zbus::zvariant::{OwnedValue, Value};

use super::config::{Config, JobOptions};
use super::dbus::{
    Access, Command, JobIface, JobIfaceSignals, JobView, MANAGER_PATH, ManagerIface, ManagerView, StationError,
    job_path, lock,
};
use super::journal::{JobId, JobRecord, JobState, Journal, SCHEMA, now_usec, sync_dir};
use super::spool::{self, Spool};
use super::watch::WatchEvent;
use super::worker::{self, JobRun, Outcome, STAGES, WorkerEvent};
use crate::error::{Error, ErrorCode};

/// Delay between taking the bus name and announcing jobs that ended while the daemon was down.
pub const ANNOUNCE_DELAY: Duration = Duration::from_millis(750);

struct Job {
    rec: JobRecord,
    view: Arc<Mutex<JobView>>,
    iface: Option<InterfaceRef<JobIface>>,
    cancel: Arc<AtomicBool>,
    preset_error: Option<Error>,
    last_emit: Option<Instant>,
    emitted_progress: f64,
    finished_at: Option<Instant>,
}

/// A file seen in the inbox, waiting to settle.
struct Candidate {
    stat: (u64, i64, i64),
    since: Instant,
}

/// The actor's state.
pub struct Station {
    cfg: Arc<Config>,
    digest: String,
    spool: Spool,
    journal: Journal,
    conn: Connection,
    access: Access,
    cmd_tx: mpsc::Sender<Command>,
    worker_tx: mpsc::UnboundedSender<WorkerEvent>,
    pool: Arc<rayon::ThreadPool>,
    jobs: BTreeMap<JobId, Job>,
    queue: VecDeque<JobId>,
    running: Vec<JobId>,
    paused: bool,
    degraded: Vec<String>,
    succeeded: u64,
    failed: u64,
    candidates: HashMap<String, Candidate>,
    manager_view: Arc<Mutex<ManagerView>>,
    /// sha256 → (job, submitted µs) of jobs that count for de-duplication.
    seen: HashMap<String, (JobId, u64)>,
    pub heartbeat: Arc<AtomicU64>,
}

/// Channels the actor listens on.
pub struct Inputs {
    pub commands: mpsc::Receiver<Command>,
    pub watch: mpsc::UnboundedReceiver<WatchEvent>,
    pub worker: mpsc::UnboundedReceiver<WorkerEvent>,
}

impl Station {
    /// Build the station and recover from the journal and the spool (no D-Bus traffic yet).
    #[allow(clippy::too_many_arguments)]
    pub fn recover(
        cfg: Arc<Config>,
        spool: Spool,
        journal: Journal,
        conn: Connection,
        access: Access,
        cmd_tx: mpsc::Sender<Command>,
        worker_tx: mpsc::UnboundedSender<WorkerEvent>,
        manager_view: Arc<Mutex<ManagerView>>,
    ) -> std::io::Result<Station> {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(cfg.worker_threads)
            .thread_name(|i| format!("stage-{i}"))
            .build()
            .map_err(std::io::Error::other)?;
        let digest = cfg.digest();
        let mut st = Station {
            cfg,
            digest,
            spool,
            journal,
            conn,
            access,
            cmd_tx,
            worker_tx,
            pool: Arc::new(pool),
            jobs: BTreeMap::new(),
            queue: VecDeque::new(),
            running: Vec::new(),
            paused: false,
            degraded: Vec::new(),
            succeeded: 0,
            failed: 0,
            candidates: HashMap::new(),
            manager_view,
            seen: HashMap::new(),
            heartbeat: Arc::new(AtomicU64::new(now_usec())),
        };
        let records = st.journal.load_all();
        let mut known: std::collections::HashSet<JobId> = std::collections::HashSet::new();
        for mut rec in records {
            known.insert(rec.id.clone());
            let counts = match rec.state {
                JobState::Cancelled => false,
                JobState::Failed => rec.error_code != ErrorCode::Interrupted.as_str(),
                _ => true,
            };
            if counts && !rec.input_sha256.is_empty() {
                st.seen.entry(rec.input_sha256.clone()).or_insert((rec.id.clone(), rec.submitted_usec));
            }
            let stem = rec.stem();
            match rec.state {
                s if s.is_terminal() => {
                    let _ = std::fs::remove_dir_all(st.spool.work_dir(&rec.id));
                    if !rec.announced {
                        st.insert(rec, None);
                    }
                }
                _ => {
                    for p in [st.spool.outbox_part(&stem, &rec.id), st.spool.quarantine_part(&stem, &rec.id)] {
                        if p.exists() {
                            tracing::info!(job_id = %rec.id, dir = %p.display(), "removing a half-built directory");
                            let _ = std::fs::remove_dir_all(&p);
                        }
                    }
                    let published = st.spool.outbox_dir(&stem, &rec.id);
                    let quarantined = st.spool.quarantine_dir(&stem, &rec.id);
                    if published.join("manifest.json").exists() {
                        rec.state = JobState::Succeeded;
                        rec.finish_usec = now_usec();
                        rec.outputs.insert("manifest".into(), published.join("manifest.json").display().to_string());
                        let _ = std::fs::remove_dir_all(st.spool.work_dir(&rec.id));
                        st.journal.save(&rec)?;
                        st.insert(rec, None);
                    } else if quarantined.exists() {
                        let code = std::fs::read(quarantined.join("error.json"))
                            .ok()
                            .and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok())
                            .and_then(|v| v["error_code"].as_str().map(String::from))
                            .unwrap_or_else(|| ErrorCode::Interrupted.as_str().into());
                        rec.state = if code == "cancelled" { JobState::Cancelled } else { JobState::Failed };
                        rec.error_code = code;
                        rec.finish_usec = now_usec();
                        rec.outputs.insert("quarantine".into(), quarantined.display().to_string());
                        let _ = std::fs::remove_dir_all(st.spool.work_dir(&rec.id));
                        st.journal.save(&rec)?;
                        st.insert(rec, None);
                    } else if !worker::input_path(&st.spool, &rec).exists() {
                        tracing::error!(job_id = %rec.id, "the claimed input is missing from work/; marking the job failed");
                        rec.state = JobState::Failed;
                        rec.error_code = ErrorCode::InternalBug.as_str().into();
                        rec.message = "the claimed input vanished from work/".into();
                        rec.finish_usec = now_usec();
                        st.journal.save(&rec)?;
                        st.insert(rec, None);
                    } else if rec.state == JobState::Running && !st.cfg.resume {
                        let e = Error::new(ErrorCode::Interrupted, "the daemon stopped while this job ran");
                        let outputs = worker::quarantine_record(&st.spool, &rec, &st.digest, &e, &rec.stage.clone())
                            .map_err(std::io::Error::other)?;
                        rec.state = JobState::Failed;
                        rec.error_code = e.code.as_str().into();
                        rec.message = e.message;
                        rec.outputs = outputs;
                        rec.finish_usec = now_usec();
                        st.journal.save(&rec)?;
                        st.insert(rec, None);
                    } else {
                        if rec.state == JobState::Running {
                            tracing::info!(job_id = %rec.id, "resuming a job interrupted by a restart");
                        }
                        rec.state = JobState::Queued;
                        rec.stage = STAGES[0].into();
                        st.journal.save(&rec)?;
                        let id = rec.id.clone();
                        st.insert(rec, None);
                        st.queue.push_back(id);
                    }
                }
            }
        }
        // Claimed files without a record: the crash came between the rename and the journal write.
        if let Ok(rd) = std::fs::read_dir(&st.spool.work) {
            let mut orphans: Vec<(JobId, PathBuf)> = Vec::new();
            for d in rd.flatten() {
                let Some(id) = JobId::parse(&d.file_name().to_string_lossy()) else { continue };
                if known.contains(&id) {
                    continue;
                }
                let files: Vec<PathBuf> =
                    std::fs::read_dir(d.path()).map(|r| r.flatten().map(|f| f.path()).collect()).unwrap_or_default();
                match files.iter().find(|f| !f.to_string_lossy().ends_with(spool::SIDECAR_SUFFIX)) {
                    Some(input) => orphans.push((id, input.clone())),
                    None => {
                        // Only a sidecar or nothing: the input was never moved; put a sidecar back.
                        for f in files {
                            let _ = std::fs::rename(&f, st.spool.inbox.join(f.file_name().unwrap_or_default()));
                        }
                        let _ = std::fs::remove_dir(d.path());
                    }
                }
            }
            orphans.sort();
            for (id, input) in orphans {
                tracing::info!(job_id = %id, "re-queueing a claimed input that had no journal record");
                let rec = st.new_record(id, &input, "inbox".into())?;
                let (rec, preset) = st.admit(rec, &input);
                st.journal.save(&rec)?;
                let id = rec.id.clone();
                st.insert(rec, preset);
                st.queue.push_back(id);
            }
        }
        st.refresh_manager_view();
        Ok(st)
    }

    fn new_record(&self, id: JobId, input: &Path, source: String) -> std::io::Result<JobRecord> {
        let name = input.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let size = std::fs::metadata(input).map(|m| m.len()).unwrap_or(0);
        let sha = crate::pipeline::fea::sha256_file(input).map_err(std::io::Error::other)?;
        Ok(JobRecord {
            schema: SCHEMA,
            id,
            input: name,
            source,
            input_sha256: sha,
            input_size: size,
            options: JobOptions::default(),
            state: JobState::Queued,
            stage: STAGES[0].into(),
            submitted_usec: now_usec(),
            start_usec: 0,
            finish_usec: 0,
            runs: 0,
            error_code: String::new(),
            message: String::new(),
            outputs: BTreeMap::new(),
            peak_memory: 0,
            announced: false,
        })
    }

    /// Read the sidecar, check size and duplicates: the record with its options, and an error that sends
    /// the job straight to quarantine.
    fn admit(&mut self, mut rec: JobRecord, input: &Path) -> (JobRecord, Option<Error>) {
        let mut preset = None;
        let work = input.parent().unwrap_or(Path::new("."));
        let sidecar = std::fs::read_dir(work)
            .ok()
            .and_then(|r| r.flatten().map(|f| f.path()).find(|p| p.to_string_lossy().ends_with(spool::SIDECAR_SUFFIX)));
        if let Some(sc) = sidecar {
            match std::fs::read_to_string(&sc).map_err(|e| e.to_string()).and_then(|t| JobOptions::parse_toml(&t)) {
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

    fn insert(&mut self, rec: JobRecord, preset_error: Option<Error>) {
        let view = JobView {
            id: rec.id.to_string(),
            input: rec.input.clone(),
            input_sha256: rec.input_sha256.clone(),
            state: rec.state.as_str().into(),
            stage: rec.stage.clone(),
            stage_index: STAGES.iter().position(|s| *s == rec.stage).unwrap_or(0) as u32,
            stage_count: STAGES.len() as u32,
            progress: if rec.state.is_terminal() { 1.0 } else { 0.0 },
            message: rec.message.clone(),
            submitted_time: rec.submitted_usec,
            start_time: rec.start_usec,
            finish_time: rec.finish_usec,
            peak_memory: rec.peak_memory,
            cancelable: !rec.state.is_terminal(),
            result: rec.result().into(),
            error_code: rec.error_code.clone(),
            outputs: rec.outputs.clone(),
        };
        let id = rec.id.clone();
        self.jobs.insert(
            id,
            Job {
                rec,
                view: Arc::new(Mutex::new(view)),
                iface: None,
                cancel: Arc::new(AtomicBool::new(false)),
                preset_error,
                last_emit: None,
                emitted_progress: 0.0,
                finished_at: None,
            },
        );
    }

    /// Export the object of every job not yet on the bus.
    pub async fn export_all(&mut self) -> zbus::Result<()> {
        let ids: Vec<JobId> = self.jobs.iter().filter(|(_, j)| j.iface.is_none()).map(|(k, _)| k.clone()).collect();
        for id in ids {
            self.export(&id).await?;
        }
        Ok(())
    }

    async fn export(&mut self, id: &JobId) -> zbus::Result<()> {
        let Some(job) = self.jobs.get(id) else { return Ok(()) };
        let path = job_path(id);
        let iface = JobIface { tx: self.cmd_tx.clone(), view: job.view.clone(), access: self.access.clone() };
        self.conn.object_server().at(&path, iface).await?;
        let r = self.conn.object_server().interface::<_, JobIface>(&path).await?;
        if let Some(job) = self.jobs.get_mut(id) {
            job.iface = Some(r);
        }
        Ok(())
    }

    /// Emit `Completed` (and the manager's `JobFinished`) for terminal jobs not yet announced.
    pub async fn announce_pending(&mut self) {
        let ids: Vec<JobId> = self
            .jobs
            .iter()
            .filter(|(_, j)| j.rec.state.is_terminal() && !j.rec.announced)
            .map(|(k, _)| k.clone())
            .collect();
        for id in ids {
            self.announce(&id).await;
        }
    }

    /// The one place `Completed` is emitted: only for a terminal, not yet announced job, and the record
    /// is marked announced right after.
    async fn announce(&mut self, id: &JobId) {
        let Some(job) = self.jobs.get_mut(id) else { return };
        if !job.rec.state.is_terminal() || job.rec.announced {
            return;
        }
        job.rec.announced = true;
        job.finished_at = Some(Instant::now());
        let (result, code, message) =
            (job.rec.result().to_string(), job.rec.error_code.clone(), job.rec.message.clone());
        if let Some(iface) = &job.iface
            && let Err(e) = iface.completed(&result, &code, &message).await
        {
            tracing::error!(job_id = %id, error = %e, "cannot emit Completed");
        }
        if let Ok(em) = SignalEmitter::new(&self.conn, MANAGER_PATH) {
            let _ = ManagerIface::job_finished(&em, job_path(id).as_ref(), &result, &code).await;
        }
        if let Err(e) = self.journal.save(&job.rec) {
            tracing::error!(job_id = %id, error = %e, "cannot persist the job record");
        }
        tracing::info!(job_id = %id, result, error_code = code, "job finished");
    }

    fn manager_state(&self) -> &'static str {
        if !self.degraded.is_empty() {
            "degraded"
        } else if self.paused {
            "paused"
        } else if !self.running.is_empty() || !self.queue.is_empty() {
            "busy"
        } else {
            "idle"
        }
    }

    fn refresh_manager_view(&self) -> [bool; 5] {
        let mut v = lock(&self.manager_view);
        let state = self.manager_state().to_string();
        let active: Vec<_> = self.running.iter().map(job_path).collect();
        let queued: Vec<_> = self.queue.iter().map(job_path).collect();
        let changed = [
            v.state != state,
            v.active != active,
            v.queued != queued,
            v.succeeded != self.succeeded,
            v.failed != self.failed,
        ];
        *v = ManagerView { state, active, queued, succeeded: self.succeeded, failed: self.failed };
        changed
    }

    async fn emit_manager(&self) {
        let changed = self.refresh_manager_view();
        if !changed.iter().any(|c| *c) {
            return;
        }
        let Ok(r) = self.conn.object_server().interface::<_, ManagerIface>(MANAGER_PATH).await else { return };
        let em = r.signal_emitter();
        let g = r.get().await;
        if changed[0] {
            let _ = g.state_changed(em).await;
        }
        if changed[1] {
            let _ = g.active_jobs_changed(em).await;
        }
        if changed[2] {
            let _ = g.queued_jobs_changed(em).await;
        }
        if changed[3] {
            let _ = g.jobs_succeeded_changed(em).await;
        }
        if changed[4] {
            let _ = g.jobs_failed_changed(em).await;
        }
    }

    /// The main loop; returns when `shutdown` fires.
    pub async fn run(mut self, mut inputs: Inputs, shutdown: impl std::future::Future<Output = ()>) {
        tokio::pin!(shutdown);
        let mut reconcile = tokio::time::interval(self.cfg.reconcile_interval);
        let settle_step = (self.cfg.settle / 4).max(Duration::from_millis(50));
        let mut settle = tokio::time::interval(settle_step);
        let mut prune = tokio::time::interval(Duration::from_secs(30));
        // Jobs that ended while the daemon was down are announced a moment after the name is ours, so that
        // monitors following NameOwnerChanged (gdbus monitor, busctl monitor) have re-subscribed.
        let announce = tokio::time::sleep(ANNOUNCE_DELAY);
        tokio::pin!(announce);
        let mut announced = false;
        self.scan_inbox();
        self.start_jobs().await;
        self.emit_manager().await;
        loop {
            tokio::select! {
                _ = &mut shutdown => break,
                Some(cmd) = inputs.commands.recv() => self.command(cmd).await,
                Some(ev) = inputs.worker.recv() => self.worker_event(ev).await,
                Some(ev) = inputs.watch.recv() => self.watch_event(ev).await,
                _ = reconcile.tick() => self.scan_inbox(),
                _ = settle.tick(), if !self.candidates.is_empty() => self.check_candidates().await,
                _ = prune.tick() => self.prune().await,
                _ = &mut announce, if !announced => {
                    announced = true;
                    self.announce_pending().await;
                }
            }
            self.start_jobs().await;
            self.emit_manager().await;
        }
        tracing::info!("station stopping");
    }

    async fn command(&mut self, cmd: Command) {
        match cmd {
            Command::Submit { path, options, source, reply } => {
                let r = self.submit(&path, options, source).await;
                let _ = reply.send(r);
            }
            Command::Cancel { id, reply } => {
                let _ = reply.send(self.cancel(&id).await);
            }
            Command::SetPaused { paused, reply } => {
                self.paused = paused;
                tracing::info!(paused, "intake");
                if !paused {
                    self.scan_inbox();
                }
                let _ = reply.send(());
            }
            Command::History { since_usec, limit, reply } => {
                let _ = reply.send(self.history(since_usec, limit));
            }
            Command::Ping { reply } => {
                let _ = reply.send(());
            }
        }
    }

    fn history(&self, since: u64, limit: u32) -> Vec<HashMap<String, OwnedValue>> {
        let limit = if limit == 0 { 100 } else { limit as usize };
        let mut recs: Vec<JobRecord> =
            self.journal.load_all().into_iter().filter(|r| r.state.is_terminal() && r.finish_usec >= since).collect();
        recs.sort_by(|a, b| b.finish_usec.cmp(&a.finish_usec).then(b.id.cmp(&a.id)));
        recs.into_iter()
            .take(limit)
            .map(|r| {
                let mut m: HashMap<String, OwnedValue> = HashMap::new();
                let mut put = |k: &str, v: Value<'_>| {
                    if let Ok(o) = v.try_to_owned() {
                        m.insert(k.to_string(), o);
                    }
                };
                put("Id", Value::from(r.id.to_string()));
                put("Input", Value::from(r.input.clone()));
                put("InputSha256", Value::from(r.input_sha256.clone()));
                put("State", Value::from(r.state.as_str()));
                put("Stage", Value::from(r.stage.clone()));
                put("Result", Value::from(r.result()));
                put("ErrorCode", Value::from(r.error_code.clone()));
                put("Message", Value::from(r.message.clone()));
                put("Source", Value::from(r.source.clone()));
                put("SubmittedTime", Value::from(r.submitted_usec));
                put("StartTime", Value::from(r.start_usec));
                put("FinishTime", Value::from(r.finish_usec));
                put("PeakMemory", Value::from(r.peak_memory));
                put("Outputs", Value::from(r.outputs.clone().into_iter().collect::<HashMap<String, String>>()));
                m
            })
            .collect()
    }

    async fn submit(&mut self, path: &Path, options: JobOptions, source: String) -> Result<JobId, StationError> {
        if self.paused {
            return Err(StationError::IntakePaused("intake is paused (ResumeIntake to continue)".into()));
        }
        if !path.is_file() {
            return Err(StationError::NotFound(format!("{} is not a readable file", path.display())));
        }
        let in_inbox = path.parent().is_some_and(|p| same_dir(p, &self.spool.inbox));
        let id = JobId::new();
        let work = self.spool.work_dir(&id);
        let name = path.file_name().map(|n| n.to_os_string()).unwrap_or_default();
        let dest = work.join(&name);
        let io = |e: std::io::Error| StationError::Internal(format!("cannot claim {}: {e}", path.display()));
        std::fs::create_dir_all(&work).map_err(io)?;
        if in_inbox {
            std::fs::rename(path, &dest).map_err(io)?;
        } else {
            let tmp = work.join(".copy.part");
            std::fs::copy(path, &tmp).map_err(io)?;
            std::fs::File::open(&tmp).and_then(|f| f.sync_all()).map_err(io)?;
            std::fs::rename(&tmp, &dest).map_err(io)?;
        }
        sync_dir(&work).map_err(io)?;
        let rec = self.new_record(id.clone(), &dest, source).map_err(io)?;
        let (mut rec, preset) = self.admit(rec, &dest);
        if options != JobOptions::default() {
            rec.options = options;
        }
        self.enqueue(rec, preset).await.map_err(|e| StationError::Internal(e.to_string()))?;
        Ok(id)
    }

    async fn enqueue(&mut self, rec: JobRecord, preset: Option<Error>) -> std::io::Result<()> {
        self.journal.save(&rec)?;
        let id = rec.id.clone();
        tracing::info!(job_id = %id, input = %rec.input, sha256 = %rec.input_sha256, source = %rec.source, "job queued");
        self.insert(rec, preset);
        self.export(&id).await.map_err(std::io::Error::other)?;
        self.queue.push_back(id);
        Ok(())
    }

    /// Claim an inbox file: rename into `work/<id>/` (the rename is the lock), then queue it.
    async fn claim(&mut self, name: &str) {
        if self.paused || !self.degraded.is_empty() {
            return;
        }
        let src = self.spool.inbox.join(name);
        if !src.is_file() {
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
        let rec = match self.new_record(id.clone(), &dest, "inbox".into()) {
            Ok(r) => r,
            Err(e) => {
                // Left in work/<id>/: recovered as an orphan at the next start.
                tracing::error!(job_id = %id, error = %e, "cannot hash the claimed input");
                return;
            }
        };
        let (rec, preset) = self.admit(rec, &dest);
        if let Err(e) = self.enqueue(rec, preset).await {
            tracing::error!(job_id = %id, error = %e, "cannot record the job");
        }
    }

    fn scan_inbox(&mut self) {
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

    async fn check_candidates(&mut self) {
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

    async fn watch_event(&mut self, ev: WatchEvent) {
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

    async fn start_jobs(&mut self) {
        while self.running.len() < self.cfg.max_parallel_jobs {
            let Some(id) = self.queue.pop_front() else { break };
            let Some(job) = self.jobs.get_mut(&id) else { continue };
            job.rec.state = JobState::Running;
            job.rec.start_usec = now_usec();
            job.rec.runs += 1;
            if let Err(e) = self.journal.save(&job.rec) {
                tracing::error!(job_id = %id, error = %e, "cannot persist the job record");
            }
            {
                let mut v = lock(&job.view);
                v.state = "running".into();
                v.start_time = job.rec.start_usec;
            }
            if let Some(r) = &job.iface {
                let g = r.get().await;
                let _ = g.state_changed(r.signal_emitter()).await;
                let _ = g.start_time_changed(r.signal_emitter()).await;
            }
            let run = JobRun {
                record: job.rec.clone(),
                cfg: self.cfg.clone(),
                config_digest: self.digest.clone(),
                spool: self.spool.clone(),
                preset_error: job.preset_error.clone(),
                cancel: job.cancel.clone(),
                heartbeat: self.heartbeat.clone(),
                events: self.worker_tx.clone(),
            };
            self.heartbeat.store(now_usec(), Ordering::Relaxed);
            let span = tracing::info_span!("job", job_id = %id);
            tracing::info!(parent: &span, input = %job.rec.input, run = job.rec.runs, "job started");
            self.pool.spawn(move || span.in_scope(|| worker::run(run)));
            self.running.push(id);
        }
    }

    async fn worker_event(&mut self, ev: WorkerEvent) {
        match ev {
            WorkerEvent::Progress { id, fraction, stage, message } => {
                let max_rate = self.cfg.progress_max_rate_hz;
                let Some(job) = self.jobs.get_mut(&id) else { return };
                if job.rec.state.is_terminal() {
                    return;
                }
                let stage_changed = job.rec.stage != stage;
                let index = STAGES.iter().position(|s| *s == stage).unwrap_or(0) as u32;
                {
                    let mut v = lock(&job.view);
                    v.progress = v.progress.max(fraction).min(0.999);
                    v.stage = stage.into();
                    v.stage_index = index;
                    v.message = message;
                }
                if stage_changed {
                    job.rec.stage = stage.into();
                    if let Err(e) = self.journal.save(&job.rec) {
                        tracing::error!(job_id = %id, error = %e, "cannot persist the job record");
                    }
                }
                let due = job.last_emit.is_none_or(|t| t.elapsed().as_secs_f64() >= 1.0 / max_rate);
                let progress = lock(&job.view).progress;
                let emit_progress = stage_changed || (due && progress >= job.emitted_progress + 0.005);
                if let Some(r) = &job.iface {
                    let g = r.get().await;
                    let em = r.signal_emitter();
                    if stage_changed {
                        let _ = g.stage_changed(em).await;
                        let _ = g.stage_index_changed(em).await;
                    }
                    if emit_progress {
                        let _ = g.progress_changed(em).await;
                        let _ = g.message_changed(em).await;
                    }
                }
                if emit_progress {
                    job.last_emit = Some(Instant::now());
                    job.emitted_progress = progress;
                }
            }
            WorkerEvent::Done { id, outcome } => self.finish(&id, outcome).await,
        }
    }

    async fn finish(&mut self, id: &JobId, outcome: Outcome) {
        self.running.retain(|r| r != id);
        let Some(job) = self.jobs.get_mut(id) else { return };
        let Outcome { error, stage, outputs, peak_memory } = outcome;
        job.rec.state = match &error {
            None => JobState::Succeeded,
            Some(e) if e.code == ErrorCode::Cancelled => JobState::Cancelled,
            Some(_) => JobState::Failed,
        };
        job.rec.stage = stage;
        job.rec.finish_usec = now_usec();
        job.rec.error_code = error.as_ref().map(|e| e.code.as_str().to_string()).unwrap_or_default();
        job.rec.message = error.as_ref().map(|e| e.to_string()).unwrap_or_else(|| "done".into());
        job.rec.outputs = outputs;
        job.rec.peak_memory = peak_memory;
        if job.rec.state == JobState::Succeeded {
            self.succeeded += 1;
        } else {
            self.failed += 1;
        }
        // Persist the terminal state before the work directory goes (a crash in between re-derives it).
        if let Err(e) = self.journal.save(&job.rec) {
            tracing::error!(job_id = %id, error = %e, "cannot persist the job record");
        }
        let _ = std::fs::remove_dir_all(self.spool.work_dir(id));
        {
            let mut v = lock(&job.view);
            v.state = job.rec.state.as_str().into();
            v.stage = job.rec.stage.clone();
            v.stage_index = STAGES.iter().position(|s| *s == job.rec.stage).unwrap_or(0) as u32;
            v.progress = 1.0;
            v.message = job.rec.message.clone();
            v.finish_time = job.rec.finish_usec;
            v.peak_memory = peak_memory;
            v.cancelable = false;
            v.result = job.rec.result().into();
            v.error_code = job.rec.error_code.clone();
            v.outputs = job.rec.outputs.clone();
        }
        if let Some(r) = &job.iface {
            let g = r.get().await;
            let em = r.signal_emitter();
            let _ = g.progress_changed(em).await;
            let _ = g.state_changed(em).await;
            let _ = g.stage_changed(em).await;
            let _ = g.stage_index_changed(em).await;
            let _ = g.message_changed(em).await;
            let _ = g.finish_time_changed(em).await;
            let _ = g.peak_memory_changed(em).await;
            let _ = g.cancelable_changed(em).await;
            let _ = g.result_changed(em).await;
            let _ = g.error_code_changed(em).await;
            let _ = g.outputs_changed(em).await;
        }
        self.announce(id).await;
    }

    async fn cancel(&mut self, id: &str) -> Result<(), StationError> {
        let jid = JobId::parse(id).ok_or_else(|| StationError::NotFound(format!("no job {id}")))?;
        let Some(job) = self.jobs.get(&jid) else { return Err(StationError::NotFound(format!("no job {id}"))) };
        if job.rec.state.is_terminal() {
            return Err(StationError::NotCancelable(format!("job {id} has finished ({})", job.rec.state.as_str())));
        }
        job.cancel.store(true, Ordering::Relaxed);
        tracing::info!(job_id = %jid, "cancel requested");
        if job.rec.state == JobState::Queued {
            // Not started: quarantine the input now (through the worker path, so the same rules apply).
            self.queue.retain(|q| *q != jid);
            let e = Error::new(ErrorCode::Cancelled, "cancelled before it started");
            let rec = job.rec.clone();
            let outputs = worker::quarantine_record(&self.spool, &rec, &self.digest, &e, "read")
                .map_err(|x| StationError::Internal(x.to_string()))?;
            self.running.push(jid.clone());
            self.finish(&jid, Outcome { error: Some(e), stage: "read".into(), outputs, peak_memory: 0 }).await;
        }
        Ok(())
    }

    /// Remove finished job objects beyond `keep_finished_jobs` or older than the linger time.
    async fn prune(&mut self) {
        let mut finished: Vec<(Instant, JobId)> =
            self.jobs.iter().filter_map(|(k, j)| j.finished_at.map(|t| (t, k.clone()))).collect();
        finished.sort();
        let excess = finished.len().saturating_sub(self.cfg.keep_finished_jobs);
        for (i, (t, id)) in finished.into_iter().enumerate() {
            if i < excess || t.elapsed() >= self.cfg.finished_job_linger {
                let path = job_path(&id);
                let _ = self.conn.object_server().remove::<JobIface, _>(&path).await;
                self.jobs.remove(&id);
            }
        }
    }
}

fn same_dir(a: &Path, b: &Path) -> bool {
    match (std::fs::canonicalize(a), std::fs::canonicalize(b)) {
        (Ok(x), Ok(y)) => x == y,
        _ => false,
    }
}

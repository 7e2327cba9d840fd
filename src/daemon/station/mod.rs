//! The station actor: the one task that owns the job table, the queue, the spool and the journal. D-Bus
//! handlers, the inbox watch and the workers talk to it through channels.
//!
//! Claiming an inbox file: `mkdir work/<id>`, rename the file (and its sidecar) into it, hash it, write the
//! journal record, export the job object ([`intake`]). Recovery after a restart is a pure plan carried out
//! in order ([`recovery`]). The job table's lifecycle is in [`lifecycle`], the D-Bus mirror in [`mirror`].

mod intake;
mod lifecycle;
mod mirror;
pub mod recovery;
mod scans;

use std::collections::{BTreeMap, HashMap, VecDeque};
use std::sync::atomic::{AtomicBool, AtomicU64};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tokio::sync::mpsc;
use zbus::Connection;
use zbus::object_server::{InterfaceRef, SignalEmitter};

use super::config::Config;
use super::dbus::{Access, Command, JobIface, JobIfaceSignals, JobView, MANAGER_PATH, ManagerIface, ManagerView};
use super::journal::{JobId, JobRecord, JobState, Journal, now_usec};
use super::spool::Spool;
use super::watch::WatchEvent;
use super::worker::{self, WorkerEvent};
use crate::error::{Error, ErrorCode};
use recovery::Action;

/// Delay between taking the bus name and announcing jobs that ended while the daemon was down.
pub const ANNOUNCE_DELAY: Duration = Duration::from_millis(750);

struct Job {
    rec: JobRecord,
    view: Arc<Mutex<JobView>>,
    iface: Option<InterfaceRef<JobIface>>,
    cancel: Arc<AtomicBool>,
    proceed: Arc<tokio::sync::Notify>,
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
    /// Configured devices that are lost, and why (they make the state degraded; intake goes on).
    device_faults: BTreeMap<&'static str, Vec<String>>,
    succeeded: u64,
    failed: u64,
    candidates: HashMap<String, Candidate>,
    manager_view: Arc<Mutex<ManagerView>>,
    /// sha256 → (job, submitted µs) of jobs that count for de-duplication.
    seen: HashMap<String, (JobId, u64)>,
    /// Time of the last progress, µs since the epoch (the watchdog reads it).
    pub heartbeat: Arc<AtomicU64>,
    /// Claims waiting for their hash, in claim order, and the channel their hashes come back on.
    hashing: VecDeque<intake::Hashing>,
    intake_tx: mpsc::UnboundedSender<intake::Hashed>,
    intake_rx: Option<mpsc::UnboundedReceiver<intake::Hashed>>,
    /// The rig's devices (set by [`Station::set_rig`] once they are started).
    rig: crate::daemon::scan::Rig,
    /// Held by the scan that is capturing.
    rig_lock: Arc<tokio::sync::Mutex<()>>,
}

/// Channels the actor listens on.
pub struct Inputs {
    /// D-Bus commands.
    pub commands: mpsc::Receiver<Command>,
    /// Inbox events.
    pub watch: mpsc::UnboundedReceiver<WatchEvent>,
    /// Worker events.
    pub worker: mpsc::UnboundedReceiver<WorkerEvent>,
}

/// What the station is built from: its settings, the spool and journal, the bus, the access rules, the
/// channels back to itself and the Manager's shared view.
pub struct Parts {
    /// The settings.
    pub cfg: Arc<Config>,
    /// The spool.
    pub spool: Spool,
    /// The job journal.
    pub journal: Journal,
    /// The bus connection.
    pub conn: Connection,
    /// Who may call what.
    pub access: Access,
    /// The command channel (for the job objects).
    pub cmd_tx: mpsc::Sender<Command>,
    /// The worker event channel (for the workers).
    pub worker_tx: mpsc::UnboundedSender<WorkerEvent>,
    /// The Manager's properties, shared with its interface.
    pub manager_view: Arc<Mutex<ManagerView>>,
}

impl Station {
    /// The station with no job yet. Cost: starts the stage thread pool.
    fn new(parts: Parts) -> std::io::Result<Station> {
        let Parts { cfg, spool, journal, conn, access, cmd_tx, worker_tx, manager_view } = parts;
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(cfg.worker_threads)
            .thread_name(|i| format!("stage-{i}"))
            .build()
            .map_err(std::io::Error::other)?;
        let digest = cfg.digest();
        let (intake_tx, intake_rx) = mpsc::unbounded_channel();
        Ok(Station {
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
            device_faults: BTreeMap::new(),
            succeeded: 0,
            failed: 0,
            candidates: HashMap::new(),
            manager_view,
            seen: HashMap::new(),
            heartbeat: Arc::new(AtomicU64::new(now_usec())),
            hashing: VecDeque::new(),
            intake_tx,
            intake_rx: Some(intake_rx),
            rig: Default::default(),
            rig_lock: Arc::new(tokio::sync::Mutex::new(())),
        })
    }

    /// Build the station and recover from the journal and the spool (no D-Bus traffic yet): the facts are
    /// gathered, the pure [`recovery::plan`] made from them, and its actions carried out in order.
    ///
    /// # Errors
    /// A journal record or a quarantine that cannot be written.
    pub fn recover(parts: Parts) -> std::io::Result<Station> {
        let mut st = Station::new(parts)?;
        let records = st.journal.load_all();
        let (facts, orphans) = recovery::gather(&st.spool, &records);
        let spool = st.spool.clone();
        let actions = recovery::plan(records, facts, orphans, st.cfg.resume, now_usec(), &|id| spool.work_dir(id));
        st.seen = recovery::seen_table(&actions);
        for action in actions {
            st.apply(action)?;
        }
        st.refresh_manager_view();
        Ok(st)
    }

    /// The rig's devices, for scans.
    pub fn set_rig(&mut self, rig: crate::daemon::scan::Rig) {
        self.rig = rig;
    }

    /// Carries out one step of the recovery plan.
    fn apply(&mut self, action: Action) -> std::io::Result<()> {
        match action {
            Action::Seen { .. } => {}
            Action::RemoveDir(dir) => {
                if dir.exists() && !dir.starts_with(&self.spool.work) {
                    tracing::info!(dir = %dir.display(), "removing a half-built directory");
                }
                let _ = std::fs::remove_dir_all(&dir);
            }
            Action::Restore { rec, save, queue } => {
                if queue && rec.runs > 0 {
                    tracing::info!(job_id = %rec.id, "resuming a job interrupted by a restart");
                }
                if rec.error_code == ErrorCode::InternalBug.as_str() && save {
                    tracing::error!(job_id = %rec.id, "the claimed input is missing from work/; marking the job failed");
                }
                if save {
                    self.journal.save(&rec)?;
                }
                let id = rec.id.clone();
                self.insert(rec, None);
                if queue {
                    self.queue.push_back(id);
                }
            }
            Action::Quarantine(mut rec) => {
                let e = Error::new(ErrorCode::Interrupted, "the daemon stopped while this job ran");
                let outputs = worker::quarantine_record(&self.spool, &rec, &self.digest, &e, &rec.stage.clone())
                    .map_err(std::io::Error::other)?;
                rec.state = JobState::Failed;
                rec.error_code = e.code.as_str().into();
                rec.message = e.message;
                rec.outputs = outputs;
                rec.finish_usec = now_usec();
                self.journal.save(&rec)?;
                self.insert(rec, None);
            }
            Action::ReturnToInbox { files, dir } => {
                for f in files {
                    let _ = std::fs::rename(&f, self.spool.inbox.join(f.file_name().unwrap_or_default()));
                }
                let _ = std::fs::remove_dir(dir);
            }
            Action::Adopt { id, input } => {
                tracing::info!(job_id = %id, "re-queueing a claimed input that had no journal record");
                let rec = self.new_record(id, &input, "inbox".into())?;
                let (rec, preset) = self.admit(rec, &input);
                self.journal.save(&rec)?;
                let id = rec.id.clone();
                self.insert(rec, preset);
                self.queue.push_back(id);
            }
        }
        Ok(())
    }

    /// Serve until `shutdown`: commands, worker and inbox events, rescans, settling, pruning and the delayed announcement.
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
        let (_, spare) = mpsc::unbounded_channel();
        let mut hashes = self.intake_rx.take().unwrap_or(spare);
        self.scan_inbox();
        self.start_jobs().await;
        self.emit_manager().await;
        loop {
            tokio::select! {
                _ = &mut shutdown => break,
                Some(cmd) = inputs.commands.recv() => self.command(cmd).await,
                Some(ev) = inputs.worker.recv() => self.worker_event(ev).await,
                Some(ev) = inputs.watch.recv() => self.watch_event(ev).await,
                Some(h) = hashes.recv() => self.hashed(h).await,
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
            Command::Submit { path, options, source, reply } => self.submit(&path, options, source, reply),
            Command::StartScan { request, name, options, source, reply } => {
                let _ = reply.send(self.start_scan(request, name, options, source).await);
            }
            Command::Cancel { id, reply } => {
                let _ = reply.send(self.cancel(&id).await);
            }
            Command::Continue { id, reply } => {
                let _ = reply.send(self.proceed(&id).await);
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
            Command::DeviceHealth { device, reasons } => {
                if reasons.is_empty() {
                    if self.device_faults.remove(device).is_some() {
                        tracing::info!(device, "device back: no longer degraded by it");
                    }
                } else {
                    tracing::warn!(device, ?reasons, "device lost: state degraded");
                    self.device_faults.insert(device, reasons);
                }
            }
        }
    }
}

//! The D-Bus face of the station (zbus 5): `org.scanstation.Station1.Manager` and one
//! `org.scanstation.Station1.Job` object per job, under an `org.freedesktop.DBus.ObjectManager`.
//!
//! The interface structs are thin (after InputPlumber): properties are read from a snapshot ([`JobView`],
//! [`ManagerView`]) that the station actor owns and updates, and methods send a [`Command`] to the actor and
//! wait for its reply. No handler holds domain state or registers objects itself. Mutating methods re-check
//! the caller's credentials (root, the daemon's own user, or a member of the ops group) besides the bus
//! policy file.

use std::collections::{BTreeMap, HashMap};
use std::path::PathBuf;
use std::sync::{Arc, Mutex};

use tokio::sync::{mpsc, oneshot};
use zbus::message::Header;
use zbus::object_server::SignalEmitter;
use zbus::zvariant::{ObjectPath, OwnedObjectPath, OwnedValue, Value};
use zbus::{Connection, interface};

use super::config::{JobOptions, option_keys};
use super::journal::JobId;

/// The bus name.
pub const BUS_NAME: &str = "org.scanstation.Station1";
/// The manager's object path (also the ObjectManager's).
pub const MANAGER_PATH: &str = "/org/scanstation/Station1";
/// Interface names.
pub const MANAGER_IFACE: &str = "org.scanstation.Station1.Manager";
/// The job objects' interface name.
pub const JOB_IFACE: &str = "org.scanstation.Station1.Job";

/// Object path of a job.
pub fn job_path(id: &JobId) -> OwnedObjectPath {
    OwnedObjectPath::try_from(format!("{MANAGER_PATH}/jobs/{id}")).expect("job ids are path-safe")
}

/// Errors returned to D-Bus callers as `org.scanstation.Station1.Error.*`.
#[derive(Debug, zbus::DBusError)]
#[zbus(prefix = "org.scanstation.Station1.Error")]
pub enum StationError {
    #[zbus(error)]
    /// A D-Bus error of zbus itself.
    ZBus(zbus::Error),
    /// A malformed argument (relative path, unknown option, value out of range).
    InvalidArgument(String),
    /// No such job, or the file does not exist.
    NotFound(String),
    /// The job is already finished.
    NotCancelable(String),
    /// `Continue()` on a job that is not waiting for a person.
    NotWaiting(String),
    /// Intake is paused.
    IntakePaused(String),
    /// The caller may read but not change anything.
    AccessDenied(String),
    /// The station could not do it (disk, journal, shutting down).
    Internal(String),
    /// A device of the rig failed; the message starts with its stable code in brackets (`[device.timeout] …`).
    Device(String),
}

/// A request to the station actor.
pub enum Command {
    /// `SubmitFile`: claim the file at `path` (moved from the inbox, copied from elsewhere) as a job.
    Submit {
        /// The file (absolute).
        path: PathBuf,
        /// The job's options.
        options: JobOptions,
        /// Who submitted it (`dbus:<sender>`).
        source: String,
        /// The new job's id, or why not.
        reply: oneshot::Sender<Result<JobId, StationError>>,
    },
    /// `Continue()`: a scan waiting for a person goes on.
    Continue {
        /// The job.
        id: String,
        /// Done, or why not.
        reply: oneshot::Sender<Result<(), StationError>>,
    },
    /// `StartScan`: a scan session on the rig.
    StartScan {
        /// The views.
        request: crate::daemon::scan::ScanRequest,
        /// The scan's name (its outbox directory's stem).
        name: String,
        /// The conversion's options.
        options: JobOptions,
        /// Who started it (`dbus:<sender>`).
        source: String,
        /// The new job's id, or why not.
        reply: oneshot::Sender<Result<JobId, StationError>>,
    },
    /// `Cancel` on a job.
    Cancel {
        /// The job's id.
        id: String,
        /// Done, or why not.
        reply: oneshot::Sender<Result<(), StationError>>,
    },
    /// `PauseIntake` / `ResumeIntake`.
    SetPaused {
        /// Pause (true) or resume.
        paused: bool,
        /// Done.
        reply: oneshot::Sender<()>,
    },
    /// `GetHistory`.
    History {
        /// Jobs finished since this time, µs since the epoch.
        since_usec: u64,
        /// At most this many (0: 100).
        limit: u32,
        /// The finished jobs, newest first.
        reply: oneshot::Sender<Vec<HashMap<String, OwnedValue>>>,
    },
    /// A configured device's health changed: why it makes the station degraded (empty: it is fine).
    DeviceHealth {
        /// `turntable` or `trigger`.
        device: &'static str,
        /// Reasons (`turntable-disconnected`, `scanner-lost`, `can-bus-off`, `can-down`).
        reasons: Vec<String>,
    },
    /// Liveness probe of the actor loop (the watchdog).
    Ping {
        /// Answered by the loop.
        reply: oneshot::Sender<()>,
    },
}

/// Who may change things.
#[derive(Clone, Debug)]
pub struct Access {
    /// The daemon's own uid (allowed like root).
    pub own_uid: u32,
    /// The name of the operators' group.
    pub ops_group: String,
    /// Its gid, when the group exists.
    pub ops_gid: Option<u32>,
}

impl Access {
    /// The daemon's effective uid and the ops group's gid from `/etc/group` (None when it does not exist).
    pub fn new(ops_group: &str) -> Access {
        let own_uid = proc_status_id("Uid:").unwrap_or(u32::MAX);
        let ops_gid = etc_entries("/etc/group").into_iter().find(|f| f[0] == ops_group).and_then(|f| f[2].parse().ok());
        Access { own_uid, ops_group: ops_group.into(), ops_gid }
    }

    /// Whether a caller with this uid and these groups may change things.
    pub fn allows(&self, uid: u32, gids: &[u32]) -> bool {
        uid == 0 || uid == self.own_uid || self.ops_gid.is_some_and(|g| gids.contains(&g))
    }
}

fn proc_status_id(key: &str) -> Option<u32> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    s.lines().find(|l| l.starts_with(key))?.split_whitespace().nth(2)?.parse().ok()
}

fn etc_entries(path: &str) -> Vec<Vec<String>> {
    std::fs::read_to_string(path)
        .unwrap_or_default()
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| l.split(':').map(String::from).collect::<Vec<_>>())
        .filter(|f| f.len() >= 4)
        .collect()
}

/// Groups of a user from the user databases (used when the bus does not report `UnixGroupIDs`).
fn groups_of(uid: u32) -> Vec<u32> {
    let passwd = etc_entries("/etc/passwd");
    let Some(user) = passwd.iter().find(|f| f[2].parse() == Ok(uid)) else { return vec![] };
    let mut g: Vec<u32> = user[3].parse().into_iter().collect();
    for f in etc_entries("/etc/group") {
        if f[3].split(',').any(|m| m == user[0])
            && let Ok(x) = f[2].parse()
        {
            g.push(x);
        }
    }
    g
}

/// Check the caller of a mutating method.
pub(crate) async fn authorize(
    conn: &Connection,
    hdr: &Header<'_>,
    access: &Access,
    what: &str,
) -> Result<(), StationError> {
    let Some(sender) = hdr.sender() else {
        // A peer-to-peer connection has no bus to ask; only the daemon's own process can open one.
        return Ok(());
    };
    let dbus = zbus::fdo::DBusProxy::new(conn).await?;
    let creds = dbus
        .get_connection_credentials(sender.clone().into())
        .await
        .map_err(|e| StationError::Internal(format!("cannot read the caller's credentials: {e}")))?;
    let uid = creds.unix_user_id().ok_or_else(|| StationError::AccessDenied("the caller's uid is unknown".into()))?;
    let gids = creds.unix_group_ids().cloned().unwrap_or_else(|| groups_of(uid));
    if access.allows(uid, &gids) {
        Ok(())
    } else {
        tracing::warn!(uid, sender = %sender, what, "refused: caller is not root, the daemon's user or in the ops group");
        Err(StationError::AccessDenied(format!(
            "{what} needs root or membership in group {:?} (uid {uid} is neither)",
            access.ops_group
        )))
    }
}

async fn ask<T>(
    tx: &mpsc::Sender<Command>,
    make: impl FnOnce(oneshot::Sender<T>) -> Command,
) -> Result<T, StationError> {
    let (reply, rx) = oneshot::channel();
    tx.send(make(reply)).await.map_err(|_| StationError::Internal("the station is shutting down".into()))?;
    rx.await.map_err(|_| StationError::Internal("the station is shutting down".into()))
}

/// What the Manager's properties show.
#[derive(Clone, Debug, Default)]
pub struct ManagerView {
    /// `idle`, `busy`, `paused` or `degraded`.
    pub state: String,
    /// Why it is degraded (`watch-lost`, `turntable-disconnected`, `scanner-lost`, `can-bus-off`, `can-down`).
    pub degraded: Vec<String>,
    /// Jobs running.
    pub active: Vec<OwnedObjectPath>,
    /// Jobs waiting.
    pub queued: Vec<OwnedObjectPath>,
    /// Jobs that succeeded since the start.
    pub succeeded: u64,
    /// Jobs that failed since the start.
    pub failed: u64,
}

/// `org.scanstation.Station1.Manager`.
pub struct ManagerIface {
    /// The actor's command channel.
    pub tx: mpsc::Sender<Command>,
    /// The properties as the actor last set them.
    pub view: Arc<Mutex<ManagerView>>,
    /// The daemon's memory budget (property `MemoryBudget`).
    pub memory_budget: u64,
    /// Who may call what.
    pub access: Access,
    /// Views of a scan that names none (`[scan] views`).
    pub default_views: u32,
    /// Tilted rings of a scan that names none (`[scan] tilts`).
    pub default_tilts: Vec<crate::daemon::scan::plan::Ring>,
    /// The coverage target of a scan that names none (`[scan] coverage`).
    pub default_coverage: Option<f64>,
}

/// Lock a view, also after a panic elsewhere (views hold plain values; a poisoned one is still consistent).
pub(crate) fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// A non-negative integer of any D-Bus integer type.
fn int(v: &Value<'_>) -> Option<u64> {
    match v {
        Value::U8(x) => Some(*x as u64),
        Value::U16(x) => Some(*x as u64),
        Value::U32(x) => Some(*x as u64),
        Value::U64(x) => Some(*x),
        Value::I16(x) => u64::try_from(*x).ok(),
        Value::I32(x) => u64::try_from(*x).ok(),
        Value::I64(x) => u64::try_from(*x).ok(),
        Value::Value(b) => int(b),
        _ => None,
    }
}

/// Parse the `a{sv}` of `SubmitFile` ([`option_keys::JOB`]): `vertices` (integer), `tolerance` (double),
/// `seed` (integer), `accept_degraded` (boolean). An unknown key is refused, naming `known`.
fn parse_options(options: &HashMap<String, OwnedValue>, known: &[&str]) -> Result<JobOptions, StationError> {
    let mut o = JobOptions::default();
    for (k, v) in options {
        let bad =
            || StationError::InvalidArgument(format!("option {k:?} has the wrong type ({})", v.value_signature()));
        match k.as_str() {
            option_keys::VERTICES => o.vertices = Some(int(v).ok_or_else(bad)? as usize),
            option_keys::SEED => o.seed = Some(int(v).ok_or_else(bad)?),
            option_keys::TOLERANCE => match &**v {
                Value::F64(x) => o.tolerance = Some(*x),
                _ => return Err(bad()),
            },
            option_keys::ACCEPT_DEGRADED => match &**v {
                Value::Bool(b) => o.accept_degraded = Some(*b),
                _ => return Err(bad()),
            },
            _ => {
                return Err(StationError::InvalidArgument(format!(
                    "unknown option {k:?} (known: {})",
                    known.join(", ")
                )));
            }
        }
    }
    o.validate().map_err(StationError::InvalidArgument)?;
    Ok(o)
}

/// Parse the `a{sv}` of `StartScan`: `views` (integer), `step_deg` (double), `tilts` (string, `TILT:VIEWS,…`),
/// `name` (string), `fea` (string, an absolute path), and the options of `SubmitFile`. `default_views` when
/// neither views nor step is given, `default_tilts` when `tilts` is not.
fn parse_scan_options(
    options: &HashMap<String, OwnedValue>,
    (default_views, default_tilts, default_coverage): (u32, &[crate::daemon::scan::plan::Ring], Option<f64>),
) -> Result<(crate::daemon::scan::ScanRequest, String, JobOptions), StationError> {
    let mut rest = HashMap::new();
    let (mut views, mut step, mut name, mut fea) = (None, None, "scan".to_string(), None);
    use crate::daemon::scan::plan::{check_coverage, check_max_views, check_passes};
    let invalid = |key: &str, m: String| StationError::InvalidArgument(format!("{key}: {m}"));
    let mut rings = None;
    let (mut coverage, mut max_views, mut passes) = (default_coverage, None, 1);
    for (k, v) in options {
        let bad =
            || StationError::InvalidArgument(format!("option {k:?} has the wrong type ({})", v.value_signature()));
        let text = || match &**v {
            Value::Str(s) => Ok(s.to_string()),
            _ => Err(bad()),
        };
        match k.as_str() {
            // Beyond u32: refused by the range check below.
            option_keys::VIEWS => views = Some(u32::try_from(int(v).ok_or_else(bad)?).unwrap_or(u32::MAX)),
            option_keys::STEP_DEG => match &**v {
                Value::F64(x) => step = Some(*x),
                _ => return Err(bad()),
            },
            option_keys::NAME => name = text()?,
            option_keys::TILTS => {
                rings =
                    Some(crate::daemon::scan::plan::Ring::parse_list(&text()?).map_err(StationError::InvalidArgument)?);
            }
            option_keys::COVERAGE => match &**v {
                Value::F64(c) => coverage = Some(check_coverage(*c).map_err(|m| invalid("coverage", m))?),
                _ => return Err(bad()),
            },
            option_keys::MAX_VIEWS => {
                max_views = Some(check_max_views(int(v).ok_or_else(bad)?).map_err(|m| invalid("max_views", m))?);
            }
            option_keys::PASSES => passes = check_passes(int(v).ok_or_else(bad)?).map_err(|m| invalid("passes", m))?,
            option_keys::FEA => {
                let p = PathBuf::from(text()?);
                if !p.is_absolute() {
                    return Err(StationError::InvalidArgument(format!("fea: {} is not an absolute path", p.display())));
                }
                fea = Some(p);
            }
            _ => {
                rest.insert(k.clone(), v.try_clone().map_err(|e| StationError::InvalidArgument(e.to_string()))?);
            }
        }
    }
    let mut request =
        crate::daemon::scan::ScanRequest::new(views, step, default_views).map_err(StationError::InvalidArgument)?;
    request.fea = fea;
    // None named: the station's (`[scan] tilts`); an empty text: the level ring only.
    request.rings = rings.unwrap_or_else(|| default_tilts.to_vec());
    (request.coverage, request.max_views, request.passes) = (coverage, max_views, passes);
    let known: Vec<&str> = option_keys::SCAN.into_iter().chain(option_keys::JOB).collect();
    let options = parse_options(&rest, &known)?;
    Ok((request, name, options))
}

/// `ManagerIface`'s D-Bus methods, properties and signals (a module of its own so that the undocumented helpers
/// zbus's interface macro adds are allowed, and nothing else).
pub mod manager_iface {
    #![allow(missing_docs)]
    use super::*;

    #[interface(name = "org.scanstation.Station1.Manager")]
    impl ManagerIface {
        /// Queue a file as a job. `path` must be absolute; a file in the spool's inbox is moved into the job
        /// (as the watch folder would), any other file is copied. Options: `vertices` (u), `tolerance` (d),
        /// `seed` (t), `accept_degraded` (b). The job object exists when this returns.
        async fn submit_file(
            &self,
            path: String,
            options: HashMap<String, OwnedValue>,
            #[zbus(header)] hdr: Header<'_>,
            #[zbus(connection)] conn: &Connection,
        ) -> Result<OwnedObjectPath, StationError> {
            authorize(conn, &hdr, &self.access, "SubmitFile").await?;
            let path = PathBuf::from(path);
            if !path.is_absolute() {
                return Err(StationError::InvalidArgument(format!("{} is not an absolute path", path.display())));
            }
            let options = parse_options(&options, &option_keys::JOB)?;
            let source = format!("dbus:{}", hdr.sender().map(|s| s.to_string()).unwrap_or_default());
            let id = ask(&self.tx, |reply| Command::Submit { path, options, source, reply }).await??;
            Ok(job_path(&id))
        }

        /// Scan the object on the turntable: home, then at each of `views` stops (or every `step_deg`) move,
        /// settle and trigger the scanner, keep the view; then fuse the views and convert them as a submitted
        /// file. Options: `views` (u), `step_deg` (d), `tilts` (s: a tilting table's rings after the level one,
        /// `TILT:VIEWS,…`, e.g. `-25:8,-45:8,50:6`; "" for none), `coverage` (d: then views chosen where the
        /// surface is unseen until this share is seen), `max_views` (u: the most views, chosen ones included),
        /// `passes` (u, 1–4: the plan taken once per pass; before each pass after the first the job asks a
        /// person to turn the object over, `OperatorActionRequired` on the job, and waits for its
        /// `Continue()`; the passes are aligned by their geometry), `name` (s: the bundle's stem), `fea` (s: an FEA spec
        /// on the station, in table coordinates), and `vertices` (u), `tolerance` (d), `seed` (t),
        /// `accept_degraded` (b) as `SubmitFile`. The job object exists when this returns.
        async fn start_scan(
            &self,
            options: HashMap<String, OwnedValue>,
            #[zbus(header)] hdr: Header<'_>,
            #[zbus(connection)] conn: &Connection,
        ) -> Result<OwnedObjectPath, StationError> {
            authorize(conn, &hdr, &self.access, "StartScan").await?;
            let (request, name, options) =
                parse_scan_options(&options, (self.default_views, &self.default_tilts, self.default_coverage))?;
            let source = format!("dbus:{}", hdr.sender().map(|s| s.to_string()).unwrap_or_default());
            let id = ask(&self.tx, |reply| Command::StartScan { request, name, options, source, reply }).await??;
            Ok(job_path(&id))
        }

        /// Finished jobs (from the journal) since a time (µs since the epoch), newest first, at most `limit`
        /// (0 = 100). Each entry holds the Job properties by name.
        async fn get_history(
            &self,
            since_usec: u64,
            limit: u32,
        ) -> Result<Vec<HashMap<String, OwnedValue>>, StationError> {
            ask(&self.tx, |reply| Command::History { since_usec, limit, reply }).await
        }

        /// Stop claiming new inbox files and refuse `SubmitFile`; running and queued jobs go on.
        async fn pause_intake(
            &self,
            #[zbus(header)] hdr: Header<'_>,
            #[zbus(connection)] conn: &Connection,
        ) -> Result<(), StationError> {
            authorize(conn, &hdr, &self.access, "PauseIntake").await?;
            ask(&self.tx, |reply| Command::SetPaused { paused: true, reply }).await
        }

        /// Claim inbox files again (and rescan the inbox).
        async fn resume_intake(
            &self,
            #[zbus(header)] hdr: Header<'_>,
            #[zbus(connection)] conn: &Connection,
        ) -> Result<(), StationError> {
            authorize(conn, &hdr, &self.access, "ResumeIntake").await?;
            ask(&self.tx, |reply| Command::SetPaused { paused: false, reply }).await
        }

        #[zbus(property(emits_changed_signal = "const"))]
        fn version(&self) -> String {
            env!("CARGO_PKG_VERSION").to_string()
        }

        /// idle, busy, paused or degraded.
        #[zbus(property)]
        fn state(&self) -> String {
            lock(&self.view).state.clone()
        }

        /// Why the state is degraded (empty otherwise): `watch-lost`, `turntable-disconnected`, `scanner-lost`,
        /// `can-bus-off`, `can-down`.
        #[zbus(property)]
        fn degraded(&self) -> Vec<String> {
            lock(&self.view).degraded.clone()
        }

        #[zbus(property)]
        fn active_jobs(&self) -> Vec<OwnedObjectPath> {
            lock(&self.view).active.clone()
        }

        #[zbus(property)]
        fn queued_jobs(&self) -> Vec<OwnedObjectPath> {
            lock(&self.view).queued.clone()
        }

        /// Jobs that succeeded since the daemon started.
        #[zbus(property)]
        fn jobs_succeeded(&self) -> u64 {
            lock(&self.view).succeeded
        }

        /// Jobs that failed (or were cancelled) since the daemon started.
        #[zbus(property)]
        fn jobs_failed(&self) -> u64 {
            lock(&self.view).failed
        }

        /// Bytes a job may use (`limits.memory_budget`).
        #[zbus(property(emits_changed_signal = "const"))]
        fn memory_budget(&self) -> u64 {
            self.memory_budget
        }

        /// A job reached a terminal state (emitted once per job, like its `Completed`).
        #[zbus(signal)]
        pub async fn job_finished(
            emitter: &SignalEmitter<'_>,
            job: ObjectPath<'_>,
            result: &str,
            error_code: &str,
        ) -> zbus::Result<()>;
    }
}

/// What a Job object's properties show.
#[derive(Clone, Debug, Default)]
pub struct JobView {
    /// Property `Id`.
    pub id: String,
    /// Property `Input`: the input's file name.
    pub input: String,
    /// Property `InputSha256`.
    pub input_sha256: String,
    /// Property `State`.
    pub state: String,
    /// Property `Stage`.
    pub stage: String,
    /// Property `StageIndex`.
    pub stage_index: u32,
    /// Property `StageCount`.
    pub stage_count: u32,
    /// Property `Progress` (0–1).
    pub progress: f64,
    /// Property `Message`.
    pub message: String,
    /// Property `SubmittedTime` (µs since the epoch).
    pub submitted_time: u64,
    /// Property `StartTime` (µs since the epoch).
    pub start_time: u64,
    /// Property `FinishTime` (µs since the epoch).
    pub finish_time: u64,
    /// Property `PeakMemory` (bytes).
    pub peak_memory: u64,
    /// Property `Cancelable`.
    pub cancelable: bool,
    /// Property `Result`.
    pub result: String,
    /// Property `ErrorCode`.
    pub error_code: String,
    /// Property `Outputs` (kind → path).
    pub outputs: BTreeMap<String, String>,
    /// Property `OperatorAction`: what a person is asked to do now ("" when nothing).
    pub operator_action: String,
}

/// The `Outputs` kind of a job's HTML report (property `ReportFile`).
pub const REPORT_HTML: &str = "report-html";

/// The `Outputs` kind of a job's thumbnail (property `Thumbnail`).
pub const THUMBNAIL: &str = "thumbnail";

/// `org.scanstation.Station1.Job`.
pub struct JobIface {
    /// The actor's command channel.
    pub tx: mpsc::Sender<Command>,
    /// The properties as the actor last set them.
    pub view: Arc<Mutex<JobView>>,
    /// Who may call what.
    pub access: Access,
}

/// `JobIface`'s D-Bus methods, properties and signals (a module of its own so that the undocumented helpers
/// zbus's interface macro adds are allowed, and nothing else).
pub use job_iface::JobIfaceSignals;
pub use manager_iface::ManagerIfaceSignals;

pub mod job_iface {
    #![allow(missing_docs)]
    use super::*;

    #[interface(name = "org.scanstation.Station1.Job")]
    impl JobIface {
        /// Stop the job: a queued job ends at once, a running one at its next checkpoint between stages;
        /// `Completed("cancelled", "cancelled", …)` follows once the work has really stopped. The input moves
        /// to quarantine. Fails with `NotCancelable` once the job has finished.
        async fn cancel(
            &self,
            #[zbus(header)] hdr: Header<'_>,
            #[zbus(connection)] conn: &Connection,
        ) -> Result<(), StationError> {
            authorize(conn, &hdr, &self.access, "Cancel").await?;
            let id = lock(&self.view).id.clone();
            ask(&self.tx, |reply| Command::Cancel { id, reply }).await?
        }

        /// Tell a scan waiting for a person (`OperatorAction` not empty: the object to be turned over between
        /// two passes) that it is done: the scan goes on with the next pass. Fails with `NotWaiting` when
        /// the job is not waiting.
        async fn r#continue(
            &self,
            #[zbus(header)] hdr: Header<'_>,
            #[zbus(connection)] conn: &Connection,
        ) -> Result<(), StationError> {
            authorize(conn, &hdr, &self.access, "Continue").await?;
            let id = lock(&self.view).id.clone();
            ask(&self.tx, |reply| Command::Continue { id, reply }).await?
        }

        /// What a person is asked to do before the scan goes on (turn the object over for the next pass,
        /// then call `Continue()`); "" when nothing.
        #[zbus(property)]
        fn operator_action(&self) -> String {
            lock(&self.view).operator_action.clone()
        }

        /// A scan waits for a person: `what` says what to do (turn the object over for the next pass); call
        /// `Continue()` once it is done. Also in the property `OperatorAction` until then.
        #[zbus(signal)]
        pub async fn operator_action_required(emitter: &SignalEmitter<'_>, what: &str) -> zbus::Result<()>;

        #[zbus(property(emits_changed_signal = "const"))]
        fn id(&self) -> String {
            lock(&self.view).id.clone()
        }

        /// The input's file name.
        #[zbus(property(emits_changed_signal = "const"))]
        fn input(&self) -> String {
            lock(&self.view).input.clone()
        }

        #[zbus(property(emits_changed_signal = "const"), name = "InputSha256")]
        fn input_sha256(&self) -> String {
            lock(&self.view).input_sha256.clone()
        }

        /// queued, running, succeeded, failed or cancelled.
        #[zbus(property)]
        fn state(&self) -> String {
            lock(&self.view).state.clone()
        }

        /// The stage running now: read, repair, remesh, surface, brep, step, quality, publish.
        #[zbus(property)]
        fn stage(&self) -> String {
            lock(&self.view).stage.clone()
        }

        #[zbus(property)]
        fn stage_index(&self) -> u32 {
            lock(&self.view).stage_index
        }

        #[zbus(property(emits_changed_signal = "const"))]
        fn stage_count(&self) -> u32 {
            lock(&self.view).stage_count
        }

        /// 0–1 over all stages, weighted; never decreases; 1 only when the job has finished.
        #[zbus(property)]
        fn progress(&self) -> f64 {
            lock(&self.view).progress
        }

        #[zbus(property)]
        fn message(&self) -> String {
            lock(&self.view).message.clone()
        }

        /// µs since the epoch.
        #[zbus(property)]
        fn submitted_time(&self) -> u64 {
            lock(&self.view).submitted_time
        }

        #[zbus(property)]
        fn start_time(&self) -> u64 {
            lock(&self.view).start_time
        }

        #[zbus(property)]
        fn finish_time(&self) -> u64 {
            lock(&self.view).finish_time
        }

        /// Peak resident memory of the daemon while the job ran, bytes.
        #[zbus(property)]
        fn peak_memory(&self) -> u64 {
            lock(&self.view).peak_memory
        }

        #[zbus(property)]
        fn cancelable(&self) -> bool {
            lock(&self.view).cancelable
        }

        /// "" until finished; then succeeded, failed or cancelled.
        #[zbus(property)]
        fn result(&self) -> String {
            lock(&self.view).result.clone()
        }

        #[zbus(property)]
        fn error_code(&self) -> String {
            lock(&self.view).error_code.clone()
        }

        /// Kind → path: step, solid-mesh, report, error-map, manifest, quarantine, error, report-html,
        /// thumbnail and the pictures (deviation, histogram, net, faces, convergence, coverage, stress).
        #[zbus(property)]
        fn outputs(&self) -> HashMap<String, String> {
            lock(&self.view).outputs.clone().into_iter().collect()
        }

        /// The job's HTML report (`NAME.report.html` in its bundle, or in quarantine: why it stopped); ""
        /// until the bundle is published or quarantined.
        #[zbus(property)]
        fn report_file(&self) -> String {
            lock(&self.view).outputs.get(REPORT_HTML).cloned().unwrap_or_default()
        }

        /// The job's 256 × 256 PNG thumbnail (the deviation map, isometric); "" until published, and for a
        /// job quarantined before it had a solid.
        #[zbus(property)]
        fn thumbnail(&self) -> String {
            lock(&self.view).outputs.get(THUMBNAIL).cloned().unwrap_or_default()
        }

        /// Emitted exactly once per job, after its work has stopped (also, after a restart, for a job that a
        /// crash interrupted: `failed`, `interrupted`).
        #[zbus(signal)]
        pub async fn completed(
            emitter: &SignalEmitter<'_>,
            result: &str,
            error_code: &str,
            message: &str,
        ) -> zbus::Result<()>;
    }
}

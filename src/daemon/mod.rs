//! **Daemon** — the unattended station: watch folders, a crash-safe job queue, progress on D-Bus, systemd
//! integration, scan sessions on the rig. The top layer: it runs the pipeline (and reaches the stages only
//! through it) and uses tokio and zbus; nothing below imports it.
//!
//! - [`config`]: `config/scanstation.toml`, strict, validated, with a digest;
//! - [`spool`]: the watch-folder layout (`inbox/`, `work/`, `outbox/`, `quarantine/`) and its atomic moves;
//! - [`watch`]: inotify on the inbox;
//! - [`journal`]: one durable JSON record per job;
//! - [`station`]: the actor that owns jobs, queue and recovery;
//! - [`worker`]: a job's work on the CPU pool, publication and quarantine;
//! - [`scan`]: scan sessions (the plan, the fault policy, the capture) and [`scan_bundle`] (what a scan's
//!   bundle adds); [`durable`]: atomic, fsynced writes;
//! - [`dbus`]: the `org.scanstation.Station1` interfaces (thin, actor-backed);
//! - [`rig`]: the configured devices (turntable, trigger) on D-Bus and in the Manager's state;
//! - [`client`]: proxies for the `scanstation` CLI;
//! - [`notify`]: sd_notify and the watchdog.

pub mod client;
pub mod cluster;
pub mod config;
pub mod dbus;
pub mod durable;
pub mod executor;
pub mod journal;
pub mod notify;
pub mod rig;
pub mod scan;
pub mod scan_bundle;
pub mod spool;
pub mod station;
pub mod watch;
pub mod worker;

use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use tokio::sync::{mpsc, oneshot};

use config::{Bus, Config};
use dbus::{Access, BUS_NAME, Command, MANAGER_PATH, ManagerIface, ManagerView};

/// A start-up failure: what could not be set up, for the operator.
#[derive(Debug, thiserror::Error)]
pub enum StartError {
    /// A bad configuration file.
    #[error(transparent)]
    Config(#[from] config::ConfigError),
    /// A spool directory that cannot be used.
    #[error(transparent)]
    Spool(#[from] spool::SpoolError),
    /// `[executor] kind = "slurm"`, but the cluster cannot run the station's jobs (no Slurm commands, or a
    /// spool the nodes do not see).
    #[error("executor.kind = \"slurm\": {0}")]
    Cluster(String),
    /// The state directory (journal) cannot be used.
    #[error("state directory {path}: {reason}")]
    State {
        /// The directory.
        path: String,
        /// Why.
        reason: String,
    },
    /// The bus cannot be reached.
    #[error("cannot connect to the {bus} bus: {reason}")]
    Bus {
        /// `system` or `session`.
        bus: &'static str,
        /// Why.
        reason: String,
    },
    #[error(
        "cannot take the bus name {BUS_NAME}: {0} (is another scanstationd running, or does the policy forbid it?)"
    )]
    /// The bus name is taken or forbidden.
    Name(String),
    /// The objects cannot be exported.
    #[error("cannot export the D-Bus objects: {0}")]
    Export(String),
    /// The inbox cannot be watched.
    #[error("cannot watch the inbox {path}: {reason}")]
    Watch {
        /// The inbox.
        path: String,
        /// Why.
        reason: String,
    },
}

/// Run the daemon until SIGTERM or SIGINT.
///
/// Order (so that clients never see a half-ready station): spool and journal are opened and recovered,
/// the ObjectManager, Manager, job and device objects are exported, the inbox watch is added and the inbox
/// scanned, then the bus name is requested, interrupted jobs are announced, and systemd is told READY.
///
/// # Errors
/// [`StartError`] for anything that prevents start-up (bad spool, state directory, bus, name).
pub async fn run(cfg: Config) -> Result<(), StartError> {
    let cfg = Arc::new(cfg);
    let spool = spool::Spool::open(&cfg.spool)?;
    if cfg.executor.kind == executor::ExecutorKind::Slurm {
        let found = cluster::check_shared_spool(&cfg.spool, &cfg.executor).map_err(StartError::Cluster)?;
        tracing::info!(%found, "conversions run on the Slurm cluster");
    }
    let journal = journal::Journal::open(&cfg.state)
        .map_err(|e| StartError::State { path: cfg.state.display().to_string(), reason: e.to_string() })?;
    let (bus_name, builder) = match cfg.bus {
        Bus::System => ("system", zbus::connection::Builder::system()),
        Bus::Session => ("session", zbus::connection::Builder::session()),
    };
    let bus_err = |e: zbus::Error| StartError::Bus { bus: bus_name, reason: e.to_string() };
    let conn = builder.map_err(bus_err)?.build().await.map_err(bus_err)?;

    let (cmd_tx, cmd_rx) = mpsc::channel::<Command>(64);
    let (worker_tx, worker_rx) = mpsc::unbounded_channel();
    let (watch_tx, watch_rx) = mpsc::unbounded_channel();
    let manager_view = Arc::new(Mutex::new(ManagerView::default()));
    let access = Access::new(&cfg.ops_group);
    if access.ops_gid.is_none() {
        tracing::warn!(group = %cfg.ops_group, "the ops group does not exist: only root and the daemon's user may submit");
    }
    let export_err = |e: zbus::Error| StartError::Export(e.to_string());
    let server = conn.object_server();
    server.at(MANAGER_PATH, zbus::fdo::ObjectManager).await.map_err(export_err)?;
    server
        .at(
            MANAGER_PATH,
            ManagerIface {
                tx: cmd_tx.clone(),
                view: manager_view.clone(),
                memory_budget: cfg.memory_budget,
                access: access.clone(),
                default_views: cfg.scan.as_ref().map_or(12, |s| s.views),
                default_tilts: cfg.scan.as_ref().map_or(Vec::new(), |s| s.tilts.clone()),
                default_coverage: cfg.scan.as_ref().and_then(|s| s.coverage),
            },
        )
        .await
        .map_err(export_err)?;
    let access_for_rig = access.clone();
    let mut station = station::Station::recover(station::Parts {
        cfg: cfg.clone(),
        spool: spool.clone(),
        journal,
        conn: conn.clone(),
        access,
        cmd_tx: cmd_tx.clone(),
        worker_tx,
        manager_view: manager_view.clone(),
    })
    .map_err(|e| StartError::State { path: cfg.state.display().to_string(), reason: e.to_string() })?;
    station.export_all().await.map_err(export_err)?;
    let rig = rig::start(&conn, cfg.turntable.as_ref(), cfg.trigger.as_ref(), &access_for_rig, cmd_tx.clone())
        .await
        .map_err(export_err)?;
    station.set_rig(rig);
    watch::start(&spool.inbox, watch_tx)
        .map_err(|e| StartError::Watch { path: spool.inbox.display().to_string(), reason: e.to_string() })?;
    conn.request_name(BUS_NAME).await.map_err(|e| StartError::Name(e.to_string()))?;
    tracing::info!(bus = bus_name, spool = %cfg.spool.display(), state = %cfg.state.display(), digest = %cfg.digest(), "scanstationd ready");
    notify::notify("READY=1\nSTATUS=ready");

    if cfg.watchdog
        && let Some(period) = notify::watchdog_period()
    {
        let heartbeat = station.heartbeat.clone();
        let tx = cmd_tx.clone();
        let view = manager_view.clone();
        let stall = cfg.stall_timeout;
        tokio::spawn(async move {
            let mut tick = tokio::time::interval(period / 2);
            loop {
                tick.tick().await;
                let (reply, rx) = oneshot::channel();
                let alive = tx.send(Command::Ping { reply }).await.is_ok()
                    && tokio::time::timeout(Duration::from_secs(2), rx).await.is_ok_and(|r| r.is_ok());
                let busy = !view.lock().map(|v| v.active.is_empty()).unwrap_or(true);
                let last = heartbeat.load(Ordering::Relaxed);
                let moving = journal::now_usec().saturating_sub(last) < stall.as_micros() as u64;
                if alive && (!busy || moving) {
                    notify::notify("WATCHDOG=1");
                } else {
                    tracing::error!(alive, busy, "watchdog not fed: the station is stuck");
                }
            }
        });
    }

    let shutdown = async {
        let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()).ok();
        tokio::select! {
            _ = tokio::signal::ctrl_c() => {},
            _ = async { match term.as_mut() { Some(t) => { t.recv().await; } None => std::future::pending::<()>().await } } => {},
        }
    };
    let inputs = station::Inputs { commands: cmd_rx, watch: watch_rx, worker: worker_rx };
    station.run(inputs, shutdown).await;
    notify::notify("STOPPING=1");
    // A running job is left `running` in the journal: the next start resumes (or fails) it.
    Ok(())
}

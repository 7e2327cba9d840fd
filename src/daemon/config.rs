//! The daemon's configuration: `config/scanstation.toml` parsed strictly (unknown keys are refused) into a
//! raw form, then validated into [`Config`] with human-readable durations ("2s", "7d") and sizes ("6GiB").
//! Every error names the key and the reason.

use std::path::{Path, PathBuf};
use std::time::Duration;

use serde::Deserialize;

use sha2::{Digest, Sha256};

use crate::daemon::scan::plan;
use crate::devices::turntable::Homing;

/// A configuration error: the key (dotted, e.g. `limits.memory_budget`) and why it was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("config {file}: {key}: {reason}")]
pub struct ConfigError {
    /// The configuration file.
    pub file: String,
    /// The key at fault (`section.key`).
    pub key: String,
    /// What is wrong with it.
    pub reason: String,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct Raw {
    #[serde(default)]
    daemon: RawDaemon,
    paths: Option<RawPaths>,
    #[serde(default)]
    watch: RawWatch,
    #[serde(default)]
    limits: RawLimits,
    #[serde(default)]
    pipeline: RawPipeline,
    #[serde(default)]
    dbus: RawDbus,
    #[serde(default)]
    devices: RawDevices,
    scan: Option<RawScan>,
    #[serde(default)]
    executor: super::executor::RawExecutor,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawScan {
    capture_dir: Option<PathBuf>,
    axis_point: Option<[f64; 3]>,
    axis_direction: Option<[f64; 3]>,
    tilt_axis_point: Option<[f64; 3]>,
    tilt_axis_direction: Option<[f64; 3]>,
    tilts: Option<String>,
    plate_radius: Option<f64>,
    coverage: Option<f64>,
    max_views: Option<u32>,
    views: Option<u32>,
    settle: Option<String>,
    view_file_timeout: Option<String>,
    view_retries: Option<u32>,
    on_lost_view: Option<String>,
    on_empty_view: Option<String>,
    on_unplug: Option<String>,
    replug_timeout: Option<String>,
    trigger_channel: Option<u8>,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct RawDevices {
    turntable: Option<RawTurntable>,
    trigger: Option<RawTrigger>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawTurntable {
    port: Option<PathBuf>,
    baud: Option<u32>,
    steps_per_revolution: Option<u32>,
    speed: Option<f64>,
    accel: Option<f64>,
    homing: Option<String>,
    reply_timeout: Option<String>,
    banner_timeout: Option<String>,
    home_timeout: Option<String>,
    reconnect_max: Option<String>,
    tilt_min: Option<f64>,
    tilt_max: Option<f64>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawTrigger {
    interface: Option<String>,
    node: Option<u8>,
    heartbeat: Option<String>,
    lost_after: Option<u32>,
    ack_timeout: Option<String>,
    view_timeout: Option<String>,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct RawDaemon {
    bus: Option<String>,
    log_format: Option<String>,
    worker_threads: Option<usize>,
    max_parallel_jobs: Option<usize>,
    watchdog: Option<bool>,
    stall_timeout: Option<String>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawPaths {
    spool: Option<PathBuf>,
    state: Option<PathBuf>,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct RawWatch {
    settle: Option<String>,
    reconcile_interval: Option<String>,
    accept: Option<Vec<String>>,
    ignore_suffixes: Option<Vec<String>>,
    dedupe_window: Option<String>,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct RawLimits {
    memory_budget: Option<String>,
    max_input_size: Option<String>,
    keep_finished_jobs: Option<usize>,
    finished_job_linger: Option<String>,
}

/// `[pipeline] vertices` (an exact count, or none: the deviation goal) and `max_vertices` (the goal's cap),
/// each within 8 ..= 10⁷; the key and the reason otherwise.
fn vertex_counts(p: &RawPipeline) -> Result<(Option<usize>, usize), (&'static str, String)> {
    let range = 8..=10_000_000;
    if let Some(v) = p.vertices
        && !range.contains(&v)
    {
        return Err(("pipeline.vertices", format!("{v} is outside 8..=10000000")));
    }
    let max_vertices = p.max_vertices.unwrap_or(crate::pipeline::goal::GOAL_CAP);
    if !range.contains(&max_vertices) {
        return Err(("pipeline.max_vertices", format!("{max_vertices} is outside 8..=10000000")));
    }
    Ok((p.vertices, max_vertices))
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct RawPipeline {
    vertices: Option<usize>,
    max_vertices: Option<usize>,
    tolerance: Option<f64>,
    seed: Option<u64>,
    compare_samples: Option<usize>,
    resume: Option<bool>,
    max_rms_pct: Option<f64>,
    max_volume_error_pct: Option<f64>,
    max_distance_pct: Option<f64>,
    accept_degraded: Option<bool>,
    pictures_up: Option<String>,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct RawDbus {
    progress_max_rate_hz: Option<f64>,
    ops_group: Option<String>,
}

/// Which message bus the daemon serves on.
#[derive(Copy, Clone, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Bus {
    /// The system bus (the service's normal place).
    System,
    /// The session bus (tests, a desk).
    Session,
}

/// How log lines are written.
#[derive(Copy, Clone, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum LogFormat {
    /// journald when its socket exists, else `pretty` on stderr.
    Auto,
    /// To the systemd journal, with structured fields.
    Journald,
    /// Human-readable lines on stderr.
    Pretty,
    /// One JSON object per line on stderr.
    Json,
}

/// The validated configuration (see `config/scanstation.toml` for every key's meaning).
#[derive(Clone, Debug, serde::Serialize)]
pub struct Config {
    /// The bus the daemon serves on.
    pub bus: Bus,
    /// Where and how it logs.
    pub log_format: LogFormat,
    /// Threads of the CPU pool that runs stages (0 in the file = cores − 1, at least 1).
    pub worker_threads: usize,
    /// Jobs that run at once.
    pub max_parallel_jobs: usize,
    /// Feed systemd's watchdog.
    pub watchdog: bool,
    #[serde(with = "secs")]
    /// A running job with no progress for this long counts as stuck (the watchdog is then not fed).
    pub stall_timeout: Duration,
    /// The spool root (inbox, work, outbox, quarantine).
    pub spool: PathBuf,
    /// The state directory (the job journal).
    pub state: PathBuf,
    #[serde(with = "secs")]
    /// How long an inbox file must stay unchanged before it is claimed.
    pub settle: Duration,
    #[serde(with = "secs")]
    /// How often the inbox is rescanned besides inotify.
    pub reconcile_interval: Duration,
    /// Accepted extensions, lower case, without the dot (".gz" variants are accepted too).
    pub accept: Vec<String>,
    /// File name suffixes the inbox ignores (partial uploads).
    pub ignore_suffixes: Vec<String>,
    #[serde(with = "secs")]
    /// Content submitted again within this window is refused as a duplicate (0: never).
    pub dedupe_window: Duration,
    /// Most bytes a job may allocate.
    pub memory_budget: u64,
    /// Largest input file accepted, bytes.
    pub max_input_size: u64,
    /// Finished job objects kept on the bus at most.
    pub keep_finished_jobs: usize,
    #[serde(with = "secs")]
    /// How long a finished job object stays on the bus.
    pub finished_job_linger: Duration,
    /// Control vertices of the quad net, exactly (ignored when `tolerance` is set); unset: the deviation
    /// goal (`max_rms_pct`) from 10,000 vertices up to `max_vertices` ([`crate::pipeline::goal`]).
    pub vertices: Option<usize>,
    /// The deviation goal's cap on control vertices.
    pub max_vertices: usize,
    /// Default RMS tolerance (length) instead of a vertex count.
    pub tolerance: Option<f64>,
    /// Default seed of remeshing and sampling.
    pub seed: u64,
    /// The up axis of a dropped file's pictures (a scan's is the turntable's axis, z of the table frame).
    pub pictures_up: crate::pipeline::pictures::Up,
    /// Samples per side of every quality measurement.
    pub compare_samples: usize,
    /// Re-queue jobs a restart interrupted (otherwise quarantine them as `interrupted`).
    pub resume: bool,
    /// The quality gates' bounds, and whether a job whose solid misses one is published (as `degraded`)
    /// instead of quarantined.
    pub gates: crate::pipeline::GateOptions,
    /// Most `Progress` change signals per second per job.
    pub progress_max_rate_hz: f64,
    /// The group whose members may submit, cancel and pause.
    pub ops_group: String,
    /// The turntable (`[devices.turntable]`; none by default).
    pub turntable: Option<TurntableConfig>,
    /// The scanner's trigger (`[devices.trigger]`; none by default).
    pub trigger: Option<TriggerConfig>,
    /// Scan sessions (`[scan]`; none by default: `StartScan` is then refused).
    pub scan: Option<ScanConfig>,
    /// Where conversions run (`[executor]`; local by default).
    pub executor: super::executor::ExecutorConfig,
    /// The text this configuration was parsed from, and the file it names in errors (a cluster job's node
    /// parses the same text: the same configuration and digest).
    #[serde(skip)]
    pub source: (String, String),
}

/// What a scan does when a view never arrives ([`ScanConfig::on_lost_view`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum OnLostView {
    /// The scan fails with the device's code (`device.timeout`), its views quarantined.
    Fail,
    /// The view is left out (named in the fusion report) and the scan goes on.
    Skip,
}

/// What a scan does when the turntable is lost mid-scan ([`ScanConfig::on_unplug`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum OnUnplug {
    /// Wait up to `replug_timeout` for it to come back, home it, and go on from the view that was interrupted.
    Wait,
    /// Fail at once with the device's code, the views captured so far quarantined.
    Fail,
}

/// `[scan]`: how the station scans an object on its rig (`StartScan`).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct ScanConfig {
    /// Where the scanner writes each view (`view-SSSSS.ply`, SSSSS the trigger's sequence number).
    pub capture_dir: PathBuf,
    /// A point on the turntable's axis in the scanner's frame: the table top's centre (calibration).
    pub axis_point: [f64; 3],
    /// The axis direction in the scanner's frame, pointing up from the table (calibration; normalised).
    pub axis_direction: [f64; 3],
    /// A tilting table's cradle axis in the scanner's frame, the table at 0° and level: a point on it and
    /// its direction (calibration; normalised); `None` without one.
    pub tilt_axis: Option<([f64; 3], [f64; 3])>,
    /// A tilting table's rings after the level one when `StartScan` names none (`TILT:VIEWS,…`).
    pub tilts: Vec<crate::daemon::scan::plan::Ring>,
    /// The table's plate radius, in the scanner's units (calibration): what lies beyond it is hidden from
    /// below; `None`: the whole table plane hides (views from below the plane are never chosen).
    pub plate_radius: Option<f64>,
    /// Choose views where the surface is unseen until this share is seen, when `StartScan` names no
    /// `coverage`; `None`: the plan only.
    pub coverage: Option<f64>,
    /// Most views of a scan, chosen ones included, when `StartScan` names no `max_views`.
    pub max_views: u32,
    /// Views per scan when `StartScan` names none.
    pub views: u32,
    #[serde(with = "secs")]
    /// Wait after a move before the trigger (the object stops swinging).
    pub settle: Duration,
    #[serde(with = "secs")]
    /// Longest wait for a view's file after the scanner reported it ready.
    pub view_file_timeout: Duration,
    /// Triggers tried again for a view that never arrives.
    pub view_retries: u32,
    /// After the retries: fail the scan, or skip the view.
    pub on_lost_view: OnLostView,
    /// A view with no points (`device.empty-view`, not retried: the scanner would see the same): fail the
    /// scan, or skip the view.
    pub on_empty_view: OnLostView,
    /// The turntable lost mid-scan: wait for it, or fail.
    pub on_unplug: OnUnplug,
    #[serde(with = "secs")]
    /// How long `on_unplug = "wait"` waits.
    pub replug_timeout: Duration,
    /// The trigger channel fired for each view.
    pub trigger_channel: u8,
}

/// `[devices.turntable]`: a Grbl 1.1 board on a serial port.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct TurntableConfig {
    /// The port (a stable name: `/dev/serial/by-id/…` or a udev symlink).
    pub port: PathBuf,
    /// Baud rate.
    pub baud: u32,
    /// Motor steps per table revolution, as configured on the board (shown on D-Bus; 0: not given).
    pub steps_per_revolution: u32,
    /// Top speed, degrees per second; `None`: the board's (`$110`). More than the board allows is
    /// `device.config` at connect.
    pub speed: Option<f64>,
    /// The acceleration expected, degrees per second²; `None`: the board's (`$120`). The deadlines use the
    /// board's.
    pub accel: Option<f64>,
    /// After a reset: `auto` (as the board is set up), `home` (`$H`) or `unlock` (`$X`).
    pub homing: Homing,
    #[serde(with = "secs")]
    /// Deadline of one reply.
    pub reply_timeout: Duration,
    #[serde(with = "secs")]
    /// Deadline of the banner after a reset.
    pub banner_timeout: Duration,
    #[serde(with = "secs")]
    /// Deadline of a homing cycle.
    pub home_timeout: Duration,
    #[serde(with = "secs")]
    /// Longest wait between reconnecting tries.
    pub reconnect_max: Duration,
    /// A tilting table: its cradle on Grbl's Y, in degrees, may move from the first to the second
    /// (`tilt_min`, `tilt_max`); `None`: a single-axis table.
    pub tilt: Option<(f64, f64)>,
}

/// `[devices.trigger]`: the scanner's node on CAN.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct TriggerConfig {
    /// The CAN interface, or `unix:PATH` (a simulator's socket).
    pub interface: String,
    /// The scanner's node id.
    pub node: u8,
    #[serde(with = "secs")]
    /// Its heartbeat period.
    pub heartbeat: Duration,
    /// Heartbeat periods without one before it is lost.
    pub lost_after: u32,
    #[serde(with = "secs")]
    /// Longest wait for a trigger's acknowledgement.
    pub ack_timeout: Duration,
    #[serde(with = "secs")]
    /// Longest wait for a view after the acknowledgement.
    pub view_timeout: Duration,
}

pub(crate) mod secs {
    pub fn serialize<S: serde::Serializer>(d: &std::time::Duration, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_f64(d.as_secs_f64())
    }
}

/// Parse "250ms", "2s", "5m", "4h", "7d" (a bare number is seconds).
pub fn parse_duration(s: &str) -> Result<Duration, String> {
    let t = s.trim();
    let split = t.find(|c: char| !(c.is_ascii_digit() || c == '.')).unwrap_or(t.len());
    let (num, unit) = t.split_at(split);
    let v: f64 = num.parse().map_err(|_| format!("{s:?} is not a duration like \"2s\", \"500ms\", \"7d\""))?;
    let mult = match unit.trim() {
        "ms" => 1e-3,
        "" | "s" => 1.0,
        "m" | "min" => 60.0,
        "h" => 3600.0,
        "d" => 86400.0,
        u => return Err(format!("unknown duration unit {u:?} (ms, s, m, h, d)")),
    };
    let secs = v * mult;
    if !(secs.is_finite() && (0.0..=1e9).contains(&secs)) {
        return Err(format!("{s:?} is out of range"));
    }
    Ok(Duration::from_secs_f64(secs))
}

/// Parse "512MiB", "6GiB", "4G", "100M", "1024" (bytes); K/M/G/T are powers of 1024, as are KiB…TiB.
pub fn parse_size(s: &str) -> Result<u64, String> {
    let t = s.trim();
    let split = t.find(|c: char| !(c.is_ascii_digit() || c == '.')).unwrap_or(t.len());
    let (num, unit) = t.split_at(split);
    let v: f64 = num.parse().map_err(|_| format!("{s:?} is not a size like \"512MiB\" or \"6GiB\""))?;
    let mult = match unit.trim().trim_end_matches("iB").trim_end_matches('B') {
        "" => 1.0,
        "K" | "k" => 1024.0,
        "M" => 1024.0 * 1024.0,
        "G" => 1024.0 * 1024.0 * 1024.0,
        "T" => 1024.0 * 1024.0 * 1024.0 * 1024.0,
        u => return Err(format!("unknown size unit {u:?} (K, M, G, T, optionally with iB)")),
    };
    let b = v * mult;
    if !(b.is_finite() && (0.0..1.8e19).contains(&b)) {
        return Err(format!("{s:?} is out of range"));
    }
    Ok(b as u64)
}

/// Largest config file, bytes (the shipped one is about 4 KiB).
pub const MAX_CONFIG_BYTES: u64 = 1 << 20;

impl Config {
    /// Read and validate `path` (at most [`MAX_CONFIG_BYTES`]).
    ///
    /// # Errors
    /// [`ConfigError`] naming the key and the reason (unreadable file, TOML syntax, unknown key, bad value).
    pub fn load(path: &Path) -> Result<Config, ConfigError> {
        let text =
            crate::geometry::io::read_small_text(path, MAX_CONFIG_BYTES, "the config").map_err(|e| ConfigError {
                file: path.display().to_string(),
                key: "(file)".into(),
                reason: format!("cannot read: {}", e.message),
            })?;
        Self::parse(&text, &path.display().to_string())
    }

    /// Validate the text of a config file; `file` names it in errors.
    ///
    /// # Errors
    /// As [`Config::load`].
    pub fn parse(text: &str, file: &str) -> Result<Config, ConfigError> {
        let err = |key: &str, reason: String| ConfigError { file: file.to_string(), key: key.into(), reason };
        let raw: Raw = toml::from_str(text).map_err(|e| {
            let msg = e.message().to_string();
            // serde names unknown fields in the message; toml gives the span.
            let key = e
                .span()
                .and_then(|s| text.get(s))
                .map(|s| s.trim().split('=').next().unwrap_or("").trim().to_string())
                .filter(|s| !s.is_empty() && s.len() < 80)
                .unwrap_or_else(|| "(syntax)".into());
            err(&key, msg)
        })?;
        let dur = |key: &str, v: &Option<String>, default: &str| -> Result<Duration, ConfigError> {
            parse_duration(v.as_deref().unwrap_or(default)).map_err(|r| err(key, r))
        };
        let size = |key: &str, v: &Option<String>, default: &str| -> Result<u64, ConfigError> {
            parse_size(v.as_deref().unwrap_or(default)).map_err(|r| err(key, r))
        };
        let bus = match raw.daemon.bus.as_deref().unwrap_or("system") {
            "system" => Bus::System,
            "session" => Bus::Session,
            o => return Err(err("daemon.bus", format!("{o:?} is neither \"system\" nor \"session\""))),
        };
        let log_format = match raw.daemon.log_format.as_deref().unwrap_or("auto") {
            "auto" => LogFormat::Auto,
            "journald" => LogFormat::Journald,
            "pretty" => LogFormat::Pretty,
            "json" => LogFormat::Json,
            o => return Err(err("daemon.log_format", format!("{o:?}: use auto, journald, pretty or json"))),
        };
        let cores = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(2);
        let worker_threads = match raw.daemon.worker_threads.unwrap_or(0) {
            0 => cores.saturating_sub(1).max(1),
            n if n <= 1024 => n,
            n => return Err(err("daemon.worker_threads", format!("{n} threads is absurd"))),
        };
        let max_parallel_jobs = raw.daemon.max_parallel_jobs.unwrap_or(1);
        if !(1..=64).contains(&max_parallel_jobs) {
            return Err(err("daemon.max_parallel_jobs", "must be between 1 and 64".into()));
        }
        let paths = raw.paths.ok_or_else(|| err("paths", "the [paths] table (spool, state) is required".into()))?;
        let spool = paths.spool.ok_or_else(|| err("paths.spool", "required".into()))?;
        let state = paths.state.ok_or_else(|| err("paths.state", "required".into()))?;
        for (k, p) in [("paths.spool", &spool), ("paths.state", &state)] {
            if !p.is_absolute() {
                return Err(err(k, format!("{} is not an absolute path", p.display())));
            }
        }
        let accept: Vec<String> = raw
            .watch
            .accept
            .unwrap_or_else(|| ["ply", "obj", "stl", "off", "xyz", "pts", "e57", "conf"].map(String::from).to_vec())
            .into_iter()
            .map(|a| a.trim_start_matches('.').to_ascii_lowercase())
            .collect();
        if accept.is_empty() || accept.iter().any(|a| a.is_empty() || a.contains('/')) {
            return Err(err("watch.accept", "a non-empty list of extensions such as \"ply\"".into()));
        }
        let ignore_suffixes = raw
            .watch
            .ignore_suffixes
            .unwrap_or_else(|| [".part", ".tmp", ".partial", ".crdownload", "~"].map(String::from).to_vec());
        let memory_budget = size("limits.memory_budget", &raw.limits.memory_budget, "6GiB")?;
        if memory_budget < 16 << 20 {
            return Err(err("limits.memory_budget", "below 16 MiB nothing can run".into()));
        }
        let max_input_size = size("limits.max_input_size", &raw.limits.max_input_size, "4GiB")?;
        let (vertices, max_vertices) = vertex_counts(&raw.pipeline).map_err(|(key, why)| err(key, why))?;
        if let Some(t) = raw.pipeline.tolerance
            && !(t.is_finite() && t > 0.0)
        {
            return Err(err("pipeline.tolerance", "must be a positive length".into()));
        }
        let compare_samples = raw.pipeline.compare_samples.unwrap_or(200_000);
        if !(1_000..=100_000_000).contains(&compare_samples) {
            return Err(err("pipeline.compare_samples", "must be between 1000 and 100000000".into()));
        }
        let gates = crate::pipeline::GateOptions {
            max_rms_pct: raw.pipeline.max_rms_pct.unwrap_or(crate::pipeline::gates::DEFAULT_MAX_RMS_PCT),
            max_volume_error_pct: raw
                .pipeline
                .max_volume_error_pct
                .unwrap_or(crate::pipeline::gates::DEFAULT_MAX_VOLUME_ERROR_PCT),
            max_distance_pct: raw.pipeline.max_distance_pct.unwrap_or(crate::pipeline::gates::DEFAULT_MAX_DISTANCE_PCT),
            accept_degraded: raw.pipeline.accept_degraded.unwrap_or(false),
        };
        if let Err(e) = gates.validated() {
            return Err(err("pipeline.max_rms_pct / max_volume_error_pct / max_distance_pct", e.message));
        }
        let progress_max_rate_hz = raw.dbus.progress_max_rate_hz.unwrap_or(4.0);
        if !(progress_max_rate_hz.is_finite() && (0.1..=100.0).contains(&progress_max_rate_hz)) {
            return Err(err("dbus.progress_max_rate_hz", "must be between 0.1 and 100".into()));
        }
        let settle = dur("watch.settle", &raw.watch.settle, "2s")?;
        let reconcile_interval = dur("watch.reconcile_interval", &raw.watch.reconcile_interval, "60s")?;
        if reconcile_interval < Duration::from_millis(100) {
            return Err(err("watch.reconcile_interval", "must be at least 100ms".into()));
        }
        let turntable = raw.devices.turntable.map(|t| turntable_config(t, &dur, &err)).transpose()?;
        let trigger = raw.devices.trigger.map(|t| trigger_config(t, &dur, &err)).transpose()?;
        let scan = raw.scan.map(|t| scan_config(t, &dur, &err)).transpose()?;
        let keep_finished_jobs = raw.limits.keep_finished_jobs.unwrap_or(100);
        if keep_finished_jobs > 100_000 {
            return Err(err("limits.keep_finished_jobs", "at most 100000".into()));
        }
        Ok(Config {
            bus,
            log_format,
            worker_threads,
            max_parallel_jobs,
            watchdog: raw.daemon.watchdog.unwrap_or(true),
            stall_timeout: dur("daemon.stall_timeout", &raw.daemon.stall_timeout, "10m")?,
            spool,
            state,
            settle,
            reconcile_interval,
            accept,
            ignore_suffixes,
            dedupe_window: dur("watch.dedupe_window", &raw.watch.dedupe_window, "7d")?,
            memory_budget,
            max_input_size,
            keep_finished_jobs,
            finished_job_linger: dur("limits.finished_job_linger", &raw.limits.finished_job_linger, "24h")?,
            vertices,
            max_vertices,
            tolerance: raw.pipeline.tolerance,
            seed: raw.pipeline.seed.unwrap_or(0),
            pictures_up: match raw.pipeline.pictures_up.as_deref() {
                None => crate::pipeline::pictures::Up::Y,
                Some(s) => crate::pipeline::pictures::Up::parse(s)
                    .ok_or_else(|| err("pipeline.pictures_up", format!("{s:?} is not an axis: use x, y or z")))?,
            },
            compare_samples,
            resume: raw.pipeline.resume.unwrap_or(true),
            gates,
            progress_max_rate_hz,
            ops_group: raw.dbus.ops_group.unwrap_or_else(|| "scanstation".into()),
            turntable,
            trigger,
            scan,
            executor: super::executor::parse(raw.executor, &|key, v, default| {
                parse_duration(v.as_deref().unwrap_or(default)).map_err(|r| (key.to_string(), r))
            })
            .map_err(|(key, reason)| err(&key, reason))?,
            source: (text.to_string(), file.to_string()),
        })
    }

    /// The effective configuration as pretty JSON (what `--check-config` prints).
    pub fn effective_json(&self) -> String {
        serde_json::to_string_pretty(self).unwrap_or_default()
    }

    /// sha256 (hex) of the effective configuration's canonical JSON; written into every report.
    pub fn digest(&self) -> String {
        let s = serde_json::to_string(self).unwrap_or_default();
        Sha256::digest(s.as_bytes()).iter().map(|x| format!("{x:02x}")).collect()
    }
}

type DurOf<'a> = dyn Fn(&str, &Option<String>, &str) -> Result<Duration, ConfigError> + 'a;
type ErrOf<'a> = dyn Fn(&str, String) -> ConfigError + 'a;

fn turntable_config(t: RawTurntable, dur: &DurOf, err: &ErrOf) -> Result<TurntableConfig, ConfigError> {
    let k = |key: &str| format!("devices.turntable.{key}");
    let port = t.port.ok_or_else(|| err(&k("port"), "required (e.g. /dev/serial/by-id/usb-…)".into()))?;
    if !port.is_absolute() {
        return Err(err(&k("port"), format!("{} is not an absolute path", port.display())));
    }
    let baud = t.baud.unwrap_or(115_200);
    if !(1_200..=4_000_000).contains(&baud) {
        return Err(err(&k("baud"), format!("{baud} is outside 1200..=4000000")));
    }
    for (key, v) in [("speed", t.speed), ("accel", t.accel)] {
        if let Some(v) = v
            && !(v.is_finite() && v > 0.0 && v <= 1e5)
        {
            return Err(err(&k(key), format!("{v} is not a positive rate up to 100000")));
        }
    }
    let homing = match t.homing.as_deref().unwrap_or("auto") {
        "auto" => Homing::Auto,
        "home" => Homing::Home,
        "unlock" => Homing::Unlock,
        o => {
            return Err(err(
                &k("homing"),
                format!("{o:?}: use \"auto\" (as the board is set up), \"home\" ($H) or \"unlock\" ($X)"),
            ));
        }
    };
    let tilt = match (t.tilt_min, t.tilt_max) {
        (None, None) => None,
        (Some(lo), Some(hi)) if lo.is_finite() && hi.is_finite() && lo < hi && lo >= -180.0 && hi <= 180.0 => {
            Some((lo, hi))
        }
        (Some(lo), Some(hi)) => {
            return Err(err(&k("tilt_min"), format!("{lo} to {hi}: a range of degrees, lowest first, within ±180")));
        }
        (Some(_), None) => return Err(err(&k("tilt_max"), "required with tilt_min (the cradle's range)".into())),
        (None, Some(_)) => return Err(err(&k("tilt_min"), "required with tilt_max (the cradle's range)".into())),
    };
    Ok(TurntableConfig {
        tilt,
        port,
        baud,
        steps_per_revolution: t.steps_per_revolution.unwrap_or(0),
        speed: t.speed,
        accel: t.accel,
        homing,
        reply_timeout: dur(&k("reply_timeout"), &t.reply_timeout, "2s")?,
        banner_timeout: dur(&k("banner_timeout"), &t.banner_timeout, "5s")?,
        home_timeout: dur(&k("home_timeout"), &t.home_timeout, "60s")?,
        reconnect_max: dur(&k("reconnect_max"), &t.reconnect_max, "5s")?,
    })
}

fn trigger_config(t: RawTrigger, dur: &DurOf, err: &ErrOf) -> Result<TriggerConfig, ConfigError> {
    let k = |key: &str| format!("devices.trigger.{key}");
    let interface = t.interface.ok_or_else(|| err(&k("interface"), "required (e.g. \"can0\")".into()))?;
    let ok_name = match interface.strip_prefix("unix:") {
        Some(p) => Path::new(p).is_absolute(),
        None => !interface.is_empty() && interface.len() < 16 && !interface.contains(['/', ' ']),
    };
    if !ok_name {
        return Err(err(&k("interface"), format!("{interface:?}: a CAN interface name or unix:/absolute/path")));
    }
    let node = t.node.unwrap_or(0x10);
    if !(1..=127).contains(&node) {
        return Err(err(&k("node"), format!("{node} is outside 1..=127")));
    }
    let heartbeat = dur(&k("heartbeat"), &t.heartbeat, "100ms")?;
    if heartbeat < Duration::from_millis(10) {
        return Err(err(&k("heartbeat"), "at least 10ms".into()));
    }
    let lost_after = t.lost_after.unwrap_or(3);
    if !(1..=100).contains(&lost_after) {
        return Err(err(&k("lost_after"), format!("{lost_after} is outside 1..=100")));
    }
    Ok(TriggerConfig {
        interface,
        node,
        heartbeat,
        lost_after,
        ack_timeout: dur(&k("ack_timeout"), &t.ack_timeout, "250ms")?,
        view_timeout: dur(&k("view_timeout"), &t.view_timeout, "10s")?,
    })
}

/// A calibrated axis (`[scan] KEY_point`, `KEY_direction`): a finite point and a non-zero finite direction,
/// returned normalised; the error names the key.
fn calibrated_axis(
    (point, d): ([f64; 3], [f64; 3]),
    (point_key, direction_key): (&str, &str),
    err: &ErrOf,
) -> Result<([f64; 3], [f64; 3]), ConfigError> {
    if point.iter().any(|v| !v.is_finite()) {
        return Err(err(&format!("scan.{point_key}"), "three finite numbers".into()));
    }
    let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    if !(len.is_finite() && len > 1e-9) {
        return Err(err(&format!("scan.{direction_key}"), "a non-zero vector of finite numbers".into()));
    }
    Ok((point, d.map(|v| v / len)))
}

fn scan_config(t: RawScan, dur: &DurOf, err: &ErrOf) -> Result<ScanConfig, ConfigError> {
    let k = |key: &str| format!("scan.{key}");
    let capture_dir =
        t.capture_dir.ok_or_else(|| err(&k("capture_dir"), "required (where the scanner writes views)".into()))?;
    if !capture_dir.is_absolute() {
        return Err(err(&k("capture_dir"), format!("{} is not an absolute path", capture_dir.display())));
    }
    let axis_point =
        t.axis_point.ok_or_else(|| err(&k("axis_point"), "required (the calibrated table centre)".into()))?;
    let d = t.axis_direction.ok_or_else(|| err(&k("axis_direction"), "required (the calibrated axis)".into()))?;
    let (axis_point, axis_direction) = calibrated_axis((axis_point, d), ("axis_point", "axis_direction"), err)?;
    let views = t.views.unwrap_or(12);
    if !(1..=360).contains(&views) {
        return Err(err(&k("views"), format!("{views} is outside 1..=360")));
    }
    let tilt_axis = match (t.tilt_axis_point, t.tilt_axis_direction) {
        (None, None) => None,
        (Some(p), Some(d)) => Some(calibrated_axis((p, d), ("tilt_axis_point", "tilt_axis_direction"), err)?),
        (Some(_), None) => return Err(err(&k("tilt_axis_direction"), "required with tilt_axis_point".into())),
        (None, Some(_)) => return Err(err(&k("tilt_axis_point"), "required with tilt_axis_direction".into())),
    };
    let tilts = plan::Ring::parse_list(t.tilts.as_deref().unwrap_or("")).map_err(|m| err(&k("tilts"), m))?;
    if let Some(r) = t.plate_radius
        && !(r.is_finite() && r > 0.0)
    {
        return Err(err(&k("plate_radius"), format!("{r} is not a positive length")));
    }
    let coverage = t.coverage.map(plan::check_coverage).transpose().map_err(|m| err(&k("coverage"), m))?;
    let max_views = plan::check_max_views(u64::from(t.max_views.unwrap_or(60))).map_err(|m| err(&k("max_views"), m))?;
    if !tilts.is_empty() && tilt_axis.is_none() {
        return Err(err(
            &k("tilts"),
            "tilted rings need the cradle's calibration: tilt_axis_point and tilt_axis_direction".into(),
        ));
    }
    let view_retries = t.view_retries.unwrap_or(2);
    if view_retries > 20 {
        return Err(err(&k("view_retries"), format!("{view_retries} is more than 20")));
    }
    let on_lost_view = match t.on_lost_view.as_deref().unwrap_or("fail") {
        "fail" => OnLostView::Fail,
        "skip" => OnLostView::Skip,
        o => return Err(err(&k("on_lost_view"), format!("{o:?}: use \"fail\" or \"skip\""))),
    };
    let on_empty_view = match t.on_empty_view.as_deref().unwrap_or("fail") {
        "fail" => OnLostView::Fail,
        "skip" => OnLostView::Skip,
        o => return Err(err(&k("on_empty_view"), format!("{o:?}: use \"fail\" or \"skip\""))),
    };
    let on_unplug = match t.on_unplug.as_deref().unwrap_or("wait") {
        "wait" => OnUnplug::Wait,
        "fail" => OnUnplug::Fail,
        o => return Err(err(&k("on_unplug"), format!("{o:?}: use \"wait\" or \"fail\""))),
    };
    Ok(ScanConfig {
        capture_dir,
        axis_point,
        axis_direction,
        tilt_axis,
        tilts,
        plate_radius: t.plate_radius,
        coverage,
        max_views,
        views,
        settle: dur(&k("settle"), &t.settle, "300ms")?,
        view_file_timeout: dur(&k("view_file_timeout"), &t.view_file_timeout, "5s")?,
        view_retries,
        on_lost_view,
        on_empty_view,
        on_unplug,
        replug_timeout: dur(&k("replug_timeout"), &t.replug_timeout, "60s")?,
        trigger_channel: t.trigger_channel.unwrap_or(0),
    })
}

/// The option keys a job takes: in a sidecar file, in `SubmitFile`'s and `StartScan`'s `a{sv}` and from the
/// CLI, spelled here once.
pub mod option_keys {
    /// Control vertices of the quad net (integer).
    pub const VERTICES: &str = "vertices";
    /// RMS tolerance, a length (double).
    pub const TOLERANCE: &str = "tolerance";
    /// Seed of the randomised steps (integer).
    pub const SEED: &str = "seed";
    /// Publish a solid that misses a gate as `degraded` (boolean).
    pub const ACCEPT_DEGRADED: &str = "accept_degraded";
    /// A scan's views (integer).
    pub const VIEWS: &str = "views";
    /// Degrees between a scan's views (double).
    pub const STEP_DEG: &str = "step_deg";
    /// A tilting table's rings after the level one, `TILT:VIEWS,…` (string).
    pub const TILTS: &str = "tilts";
    /// Choose views where the surface is unseen until this share is seen (double, 0–1).
    pub const COVERAGE: &str = "coverage";
    /// Most views of a scan, chosen ones included (integer).
    pub const MAX_VIEWS: &str = "max_views";
    /// A scan's passes, the object turned over between two (integer, 1–4).
    pub const PASSES: &str = "passes";
    /// A scan's name (string).
    pub const NAME: &str = "name";
    /// An FEA spec for a scan's solid, an absolute path (string).
    pub const FEA: &str = "fea";
    /// Every job's options ([`super::JobOptions`]).
    pub const JOB: [&str; 4] = [VERTICES, TOLERANCE, SEED, ACCEPT_DEGRADED];
    /// A scan's own options, beside [`JOB`].
    pub const SCAN: [&str; 8] = [VIEWS, STEP_DEG, TILTS, COVERAGE, MAX_VIEWS, PASSES, NAME, FEA];
}

/// Per-job options: from a sidecar `NAME.job.toml` or the `a{sv}` of `SubmitFile`.
#[derive(Clone, Debug, Default, PartialEq, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct JobOptions {
    /// Control vertices of the quad net.
    pub vertices: Option<usize>,
    /// Raise the resolution until the solid's RMS distance to the input is at most this length.
    pub tolerance: Option<f64>,
    /// Seed of the randomised steps.
    pub seed: Option<u64>,
    /// Publish a solid that misses a quality gate anyway, as `degraded` (otherwise the job is quarantined).
    pub accept_degraded: Option<bool>,
}

impl JobOptions {
    /// Parse and check a sidecar file's text.
    ///
    /// # Errors
    /// A message naming the key and the reason.
    pub fn parse_toml(text: &str) -> Result<JobOptions, String> {
        let o: JobOptions = toml::from_str(text).map_err(|e| e.message().to_string())?;
        o.validate()?;
        Ok(o)
    }

    /// Check ranges.
    ///
    /// # Errors
    /// A message naming the key.
    pub fn validate(&self) -> Result<(), String> {
        if let Some(v) = self.vertices
            && !(8..=10_000_000).contains(&v)
        {
            return Err(format!("vertices: {v} is outside 8..=10000000"));
        }
        if let Some(t) = self.tolerance
            && !(t.is_finite() && t > 0.0)
        {
            return Err("tolerance: must be a positive length".into());
        }
        Ok(())
    }
}

//! Scan sessions: the station turns the object on its table, fires the scanner at every stop and keeps each
//! view, then hands the views to the conversion chain as a scan set ([`super::worker`]).
//!
//! A scan job's input is a directory `work/<id>/<name>.scan/` that grows view by view:
//! - `view-NNN.ply`: view NNN of the plan (its points in the scanner's frame, as the scanner wrote them);
//! - `capture.json` ([`CaptureLog`]): every view taken (angle asked and reached, trigger sequence number,
//!   points, tries) and every view skipped, with the calibration used;
//! - `scanset.toml`: the views as a scan set, each posed by a matrix from the scanner's frame to the
//!   **table frame** (origin at the table top's centre, z up the axis, x along the scanner's right turned
//!   flat), so the solid stands on the table as the object did: view at table angle θ → turn back by −θ
//!   about the calibrated axis ([`crate::geometry::pose::Pose::turntable`]) → table frame.
//!
//! A view is persisted before the next move (its file moved in and synced, then `capture.json` and the
//! manifest rewritten atomically), so a crash loses at most the view in flight; a restarted job
//! ([`capture`]) re-homes and goes on from the first view `capture.json` does not hold. No view is taken
//! twice into the set, and none that was kept is lost.
//!
//! Faults ([`ScanConfig`]): a turntable lost mid-scan is waited for (`on_unplug = "wait"`, up to
//! `replug_timeout`; then it is homed and the interrupted view taken again) or fails the scan with its code;
//! a view that never arrives is triggered again `view_retries` times, then fails the scan (`device.timeout`)
//! or is skipped and named; a cancel stops the scan before its next move.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use super::config::{OnLostView, OnUnplug, ScanConfig};
use super::journal::{sync_dir, write_durable};
use crate::devices::link::TurntableHandle;
use crate::devices::trigger::TriggerHandle;
use crate::error::{Error, ErrorCode};
use crate::geometry::pose::Pose;
use crate::geometry::vec3::{V3, cross, dot, norm, scale, sub};

/// The capture log's file name in a scan directory.
pub const CAPTURE_LOG: &str = "capture.json";

/// What `StartScan` asked for.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ScanRequest {
    /// Views (stops of the table).
    pub views: u32,
    /// Degrees between stops.
    pub step_deg: f64,
    /// An FEA spec to solve on the solid (a TOML file on the station; coordinates in the table frame).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fea: Option<PathBuf>,
}

impl ScanRequest {
    /// The table angles of the plan's views, degrees.
    pub fn angles(&self) -> Vec<f64> {
        (0..self.views).map(|i| f64::from(i) * self.step_deg).collect()
    }

    /// From `views` and/or `step_deg` (one is enough; neither: the configured number of views, evenly
    /// around).
    ///
    /// # Errors
    /// A message naming the option when they are out of range or the views would go round more than once.
    pub fn new(views: Option<u32>, step_deg: Option<f64>, default_views: u32) -> Result<ScanRequest, String> {
        let (views, step_deg) = match (views, step_deg) {
            (Some(v), Some(s)) => (v, s),
            (Some(v), None) => (v, 360.0 / f64::from(v.max(1))),
            (None, Some(s)) if s.is_finite() && s > 0.0 => (((360.0 / s) - 1e-9).floor() as u32 + 1, s),
            (None, Some(s)) => return Err(format!("step_deg: {s} is not a positive angle")),
            (None, None) => (default_views, 360.0 / f64::from(default_views.max(1))),
        };
        if !(1..=360).contains(&views) {
            return Err(format!("views: {views} is outside 1..=360"));
        }
        if !(step_deg.is_finite() && step_deg > 0.0 && step_deg <= 360.0) {
            return Err(format!("step_deg: {step_deg} is outside (0, 360]"));
        }
        if f64::from(views - 1) * step_deg >= 360.0 - 1e-9 {
            return Err(format!("{views} views {step_deg}° apart go round more than once"));
        }
        Ok(ScanRequest { views, step_deg, fea: None })
    }
}

/// The rig's devices the daemon drives (those configured).
#[derive(Clone, Default)]
pub struct Rig {
    /// The turntable.
    pub turntable: Option<TurntableHandle>,
    /// The scanner's trigger.
    pub trigger: Option<TriggerHandle>,
}

/// One view taken.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TakenView {
    /// Its index in the plan.
    pub index: u32,
    /// Its file in the scan directory.
    pub file: String,
    /// The table angle asked, degrees.
    pub angle_deg: f64,
    /// The angle the table reported reaching, degrees.
    pub reached_deg: f64,
    /// The trigger's sequence number.
    pub seq: u16,
    /// Points in the view.
    pub points: u32,
    /// Triggers it took (1 when the first view arrived).
    pub tries: u32,
    /// From the trigger to "view ready", milliseconds.
    pub view_ms: f64,
}

/// One view left out (`on_lost_view = "skip"`).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SkippedView {
    /// Its index in the plan.
    pub index: u32,
    /// The table angle, degrees.
    pub angle_deg: f64,
    /// Why (the last error, with its code).
    pub reason: String,
}

/// `capture.json`: what the capture did so far (the truth a resumed scan goes on from).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CaptureLog {
    /// The calibrated axis: a point (the table top's centre) in the scanner's frame.
    pub axis_point: V3,
    /// The axis direction in the scanner's frame.
    pub axis_direction: V3,
    /// Views planned.
    pub planned: u32,
    /// Views taken, in plan order.
    pub views: Vec<TakenView>,
    /// Views skipped.
    pub skipped: Vec<SkippedView>,
    /// Times the scan was (re)started: 1, more after a restart.
    pub runs: u32,
    /// Homing cycles run (one per run, one after each replug).
    pub homings: u32,
    /// Times the turntable was lost and came back.
    pub replugs: u32,
    /// Triggers sent again for views that did not arrive.
    pub retries: u32,
}

impl CaptureLog {
    /// Read `capture.json` in `dir`; `None` when there is none (or it is unreadable: it is rewritten whole).
    pub fn load(dir: &Path) -> Option<CaptureLog> {
        let bytes = std::fs::read(dir.join(CAPTURE_LOG)).ok()?;
        serde_json::from_slice(&bytes).ok()
    }

    fn has(&self, index: u32) -> bool {
        self.views.iter().any(|v| v.index == index) || self.skipped.iter().any(|v| v.index == index)
    }
}

/// The table frame from the calibration: scanner frame → table frame (origin at `point`, z along
/// `direction`, x the scanner's x made perpendicular to the axis).
pub fn table_frame(point: V3, direction: V3) -> Pose {
    let z = scale(direction, 1.0 / norm(direction));
    let seed = if dot([1.0, 0.0, 0.0], z).abs() < 0.9 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
    let x = sub(seed, scale(z, dot(seed, z)));
    let x = scale(x, 1.0 / norm(x));
    let y = cross(z, x);
    let rotation = [x, y, z];
    let t = [-dot(x, point), -dot(y, point), -dot(z, point)];
    Pose { rotation, translation: t }
}

/// The pose of a view taken at table angle `angle_deg`: scanner frame → table frame.
pub fn view_pose(point: V3, direction: V3, angle_deg: f64) -> Pose {
    let back = Pose::turntable(point, direction, angle_deg).unwrap_or(Pose::IDENTITY);
    table_frame(point, direction).then_after(&back)
}

/// Write `capture.json` and `scanset.toml` for `log` into `dir` (each atomically and durably).
///
/// # Errors
/// `resource.output` with the file.
pub fn persist(dir: &Path, log: &CaptureLog) -> Result<(), Error> {
    let io = |p: &Path, e: std::io::Error| {
        Error::new(ErrorCode::ResourceOutput, format!("cannot write {}: {e}", p.display()))
    };
    let log_path = dir.join(CAPTURE_LOG);
    let json = serde_json::to_vec_pretty(log).unwrap_or_default();
    write_durable(&log_path, &json).map_err(|e| io(&log_path, e))?;
    if !log.views.is_empty() {
        let listed: Vec<(String, Pose)> = log
            .views
            .iter()
            .map(|v| (v.file.clone(), view_pose(log.axis_point, log.axis_direction, v.angle_deg)))
            .collect();
        crate::geometry::io::scanset::write_manifest(&dir.join(crate::geometry::io::scanset::MANIFEST), &listed)?;
        sync_dir(dir).map_err(|e| io(dir, e))?;
    }
    Ok(())
}

/// What the capture needs.
pub struct CaptureJob<'a> {
    /// The scan directory (`work/<id>/<name>.scan/`).
    pub dir: &'a Path,
    /// The plan.
    pub request: &'a ScanRequest,
    /// `[scan]`.
    pub cfg: &'a ScanConfig,
    /// The devices.
    pub rig: &'a Rig,
    /// Set when the job is cancelled.
    pub cancel: &'a AtomicBool,
    /// Progress: (share of the capture done 0–1, stage `home` or `capture`, message).
    pub progress: &'a (dyn Fn(f64, &'static str, String) + Send + Sync),
}

fn cancelled() -> Error {
    Error::new(ErrorCode::Cancelled, "cancelled during the capture; the views taken are kept in quarantine")
}

fn is_unplug(e: &Error, table: &TurntableHandle) -> bool {
    matches!(e.code, ErrorCode::DeviceUnplugged | ErrorCode::DeviceLost) || !table.state().connected
}

/// Run `fut`, giving up with [`cancelled`] as soon as the job is cancelled (checked every 20 ms).
async fn or_cancel<T>(cancel: &AtomicBool, fut: impl std::future::Future<Output = T>) -> Result<T, Error> {
    tokio::pin!(fut);
    let mut tick = tokio::time::interval(Duration::from_millis(20));
    loop {
        tokio::select! {
            r = &mut fut => return Ok(r),
            _ = tick.tick() => if cancel.load(Ordering::Relaxed) { return Err(cancelled()) },
        }
    }
}

/// Capture the plan's missing views into `job.dir` (resuming from its `capture.json`): home, then for each
/// view move, settle, trigger, take the view's file. Returns the log.
///
/// # Errors
/// `cancelled`; `device.*` from the rig (per the fault settings); `resource.output`.
pub async fn capture(job: &CaptureJob<'_>) -> Result<CaptureLog, Error> {
    let cfg = job.cfg;
    let (Some(table), Some(trigger)) = (&job.rig.turntable, &job.rig.trigger) else {
        return Err(Error::new(
            ErrorCode::DeviceUnplugged,
            "a scan needs a turntable and a trigger ([devices.turntable], [devices.trigger])",
        ));
    };
    std::fs::create_dir_all(job.dir)
        .map_err(|e| Error::new(ErrorCode::ResourceOutput, format!("cannot create {}: {e}", job.dir.display())))?;
    let mut log = CaptureLog::load(job.dir).unwrap_or(CaptureLog {
        axis_point: cfg.axis_point,
        axis_direction: cfg.axis_direction,
        planned: job.request.views,
        ..Default::default()
    });
    log.runs += 1;
    persist(job.dir, &log)?;
    let angles = job.request.angles();
    let total = angles.len().max(1) as f64;
    let share = |log: &CaptureLog| (log.views.len() + log.skipped.len()) as f64 / total;

    // 1. Home (again after a restart: the table may have been turned by hand meanwhile), unless every view
    //    is in already.
    if (0..job.request.views).any(|i| !log.has(i)) {
        (job.progress)(0.0, "home", "home/homing the turntable".into());
        home(job, table, &mut log).await?;
    }

    // 2. Every missing view, in plan order.
    for (i, &angle) in angles.iter().enumerate() {
        let index = i as u32;
        if log.has(index) {
            continue;
        }
        if job.cancel.load(Ordering::Relaxed) {
            return Err(cancelled());
        }
        (job.progress)(share(&log), "capture", format!("capture/view {} of {} at {angle:.1}°", i + 1, angles.len()));
        let reached = move_to(job, table, &mut log, angle).await?;
        tokio::time::sleep(cfg.settle).await;
        match trigger_view(job, trigger, &mut log, index, (angle, reached)).await? {
            Ok(v) => log.views.push(v),
            Err(e) => {
                let reason = format!("[{}] {}", e.code.as_str(), e.message);
                if cfg.on_lost_view == OnLostView::Fail {
                    persist(job.dir, &log)?;
                    return Err(Error::new(
                        e.code,
                        format!(
                            "view {} at {angle:.1}° never arrived after {} triggers: {}",
                            i + 1,
                            cfg.view_retries + 1,
                            e.message
                        ),
                    ));
                }
                tracing::warn!(view = index, %reason, "view skipped");
                log.skipped.push(SkippedView { index, angle_deg: angle, reason });
            }
        }
        log.views.sort_by_key(|v| v.index);
        persist(job.dir, &log)?;
        (job.progress)(share(&log), "capture", format!("capture/{} of {} views", log.views.len(), angles.len()));
    }
    if log.views.len() < 2 {
        return Err(Error::new(
            ErrorCode::ReconstructViewsDisagree,
            format!("only {} view(s) captured of {}: too few to fuse", log.views.len(), angles.len()),
        ));
    }
    Ok(log)
}

/// Trigger view `index` (the table asked to `angle`, at `reached`) until it arrives: `Ok(Ok(view))`, or `Ok(Err(last error))` when `view_retries` more triggers were lost too. A lost scanner
/// is waited for (`on_unplug = "wait"`) and does not count as a lost view.
async fn trigger_view(
    job: &CaptureJob<'_>,
    trigger: &TriggerHandle,
    log: &mut CaptureLog,
    index: u32,
    (angle, reached): (f64, f64),
) -> Result<Result<TakenView, Error>, Error> {
    // Triggers lost for this view so far.
    let mut lost = 0;
    loop {
        if job.cancel.load(Ordering::Relaxed) {
            return Err(cancelled());
        }
        match take_view(job, trigger, index).await {
            Ok((file, report)) => {
                return Ok(Ok(TakenView {
                    index,
                    file,
                    angle_deg: angle,
                    reached_deg: reached,
                    seq: report.seq,
                    points: report.points,
                    tries: lost + 1,
                    view_ms: report.view_ms,
                }));
            }
            Err(e) if matches!(e.code, ErrorCode::DeviceTimeout | ErrorCode::DeviceRefused | ErrorCode::InputIo) => {
                lost += 1;
                if lost > job.cfg.view_retries {
                    return Ok(Err(e));
                }
                log.retries += 1;
                tracing::warn!(view = index, lost, "view lost; triggering again");
            }
            // The scanner (or its bus) gone: waited for as the table is, then the view is tried again.
            Err(e) if trigger_gone(&e) && job.cfg.on_unplug == OnUnplug::Wait => {
                wait_trigger(job, trigger, &e).await?;
                log.replugs += 1;
            }
            Err(e) => return Err(e),
        }
    }
}

/// Home, waiting for a replug when the table is gone and the settings say so.
async fn home(job: &CaptureJob<'_>, table: &TurntableHandle, log: &mut CaptureLog) -> Result<(), Error> {
    loop {
        match or_cancel(job.cancel, table.home()).await? {
            Ok(()) => {
                log.homings += 1;
                return Ok(());
            }
            Err(e) if is_unplug(&e, table) && job.cfg.on_unplug == OnUnplug::Wait => {
                wait_replug(job, table, &e).await?;
                log.replugs += 1;
            }
            Err(e) => return Err(e),
        }
    }
}

/// Move to `angle`; after a lost table, wait for it, home it and move again. The angle reached.
async fn move_to(
    job: &CaptureJob<'_>,
    table: &TurntableHandle,
    log: &mut CaptureLog,
    angle: f64,
) -> Result<f64, Error> {
    loop {
        // A move under way is finished before a cancel takes effect: the table stops within one move.
        match table.move_to(angle).await {
            Ok(r) => return Ok(r.reached),
            Err(e) if is_unplug(&e, table) && job.cfg.on_unplug == OnUnplug::Wait => {
                wait_replug(job, table, &e).await?;
                log.replugs += 1;
                home(job, table, log).await?;
            }
            Err(e) => return Err(e),
        }
    }
}

/// Wait up to `replug_timeout` for the table to be connected again.
async fn wait_replug(job: &CaptureJob<'_>, table: &TurntableHandle, why: &Error) -> Result<(), Error> {
    wait_back(job, table.watch(), |s| s.connected, "turntable", why).await
}

/// Wait up to `replug_timeout` until `back` holds for the device `what` watched through `w` (checking the
/// cancel flag); `why` is the error that sent us waiting, returned with the timeout named when it does not.
async fn wait_back<T>(
    job: &CaptureJob<'_>,
    mut w: tokio::sync::watch::Receiver<T>,
    back: impl Fn(&T) -> bool,
    what: &str,
    why: &Error,
) -> Result<(), Error> {
    let limit = job.cfg.replug_timeout;
    tracing::warn!(error = %why, timeout_s = limit.as_secs_f64(), "{what} lost mid-scan; waiting for it");
    (job.progress)(f64::NAN, "capture", format!("capture/waiting for the {what} to come back"));
    let is_back = async {
        loop {
            if back(&w.borrow_and_update()) {
                return true;
            }
            if w.changed().await.is_err() {
                return false;
            }
        }
    };
    match tokio::time::timeout(limit, or_cancel(job.cancel, is_back)).await {
        Ok(r) => match r? {
            true => Ok(()),
            false => Err(why.clone()),
        },
        Err(_) => Err(Error::new(
            why.code,
            format!(
                "the {what} did not come back within {:.0} s ({}); the views taken are kept in quarantine",
                limit.as_secs_f64(),
                why.message
            ),
        )),
    }
}

fn trigger_gone(e: &Error) -> bool {
    matches!(e.code, ErrorCode::DeviceUnplugged | ErrorCode::DeviceLost | ErrorCode::DeviceBusOff)
}

/// Wait up to `replug_timeout` for the scanner to be ready again.
async fn wait_trigger(job: &CaptureJob<'_>, trigger: &TriggerHandle, why: &Error) -> Result<(), Error> {
    wait_back(job, trigger.watch(), |s| s.ready(), "scanner", why).await
}

/// Trigger one view and take its file into the scan directory as `view-NNN.ply`.
async fn take_view(
    job: &CaptureJob<'_>,
    trigger: &TriggerHandle,
    index: u32,
) -> Result<(String, crate::devices::trigger::FireReport), Error> {
    let report = or_cancel(job.cancel, trigger.fire(job.cfg.trigger_channel)).await??;
    let from = job.cfg.capture_dir.join(format!("view-{:05}.ply", report.seq));
    let name = format!("view-{index:03}.ply");
    let to = job.dir.join(&name);
    // The scanner reported the view ready; its file may still be on its way (a network share).
    let fresh_since = report.sent_usec.saturating_sub(2_000_000);
    let deadline = Instant::now() + job.cfg.view_file_timeout;
    loop {
        let fresh = std::fs::metadata(&from)
            .and_then(|m| m.modified())
            .ok()
            .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
            .is_some_and(|t| t.as_micros() as u64 >= fresh_since);
        if fresh {
            break;
        }
        if Instant::now() >= deadline {
            return Err(Error::new(
                ErrorCode::DeviceTimeout,
                format!(
                    "the scanner reported view {} ready but {} did not appear within {:.1} s",
                    report.seq,
                    from.display(),
                    job.cfg.view_file_timeout.as_secs_f64()
                ),
            ));
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let (from2, to2, expect) = (from.clone(), to.clone(), report.points);
    let dir = job.dir.to_path_buf();
    tokio::task::spawn_blocking(move || take_file(&from2, &to2, &dir, expect))
        .await
        .map_err(|e| Error::internal(format!("the view's mover failed: {e}")))??;
    Ok((name, report))
}

/// Check the view file holds the points the scanner announced, then move it into the scan directory
/// (renamed; copied and removed across file systems) and make it durable.
fn take_file(from: &Path, to: &Path, dir: &Path, expect: u32) -> Result<(), Error> {
    let read = crate::geometry::io::ReadOptions::default();
    let count = match crate::geometry::io::read_geometry(from, &read) {
        Ok(crate::geometry::mesh::Geometry::Cloud(c)) => c.positions.len(),
        Ok(crate::geometry::mesh::Geometry::Mesh(m)) => m.positions.len(),
        Err(e) => {
            return Err(Error::new(ErrorCode::InputIo, format!("the view {} is unreadable: {e}", from.display())));
        }
    };
    if count != expect as usize {
        return Err(Error::new(
            ErrorCode::InputIo,
            format!("the view {} holds {count} points, the scanner announced {expect}", from.display()),
        ));
    }
    let io = |e: std::io::Error| Error::new(ErrorCode::ResourceOutput, format!("cannot take {}: {e}", from.display()));
    if std::fs::rename(from, to).is_err() {
        let part = to.with_extension("ply.part");
        std::fs::copy(from, &part).map_err(io)?;
        std::fs::File::open(&part).and_then(|f| f.sync_all()).map_err(io)?;
        std::fs::rename(&part, to).map_err(io)?;
        let _ = std::fs::remove_file(from);
    }
    sync_dir(dir).map_err(io)
}

//! The capture: the I/O loop that carries a scan's plan out on the rig (home, then per view move, settle,
//! trigger, take the file), asking [`super::policy::next`] what each fault leads to. Files are written and
//! synced on blocking threads, off the async workers.

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use super::super::config::ScanConfig;
use super::super::durable::{sync_dir, write_durable};
use super::Rig;
use super::next::{self, Chooser};
use super::plan::{CAPTURE_LOG, CaptureLog, ScanRequest, SkippedView, Stop, TakenView};
use super::policy::{Action, Device, Fault, Rules, Step, classify, next};
use crate::devices::trigger::TriggerHandle;
use crate::devices::turntable::actor::TurntableHandle;
use crate::error::{Error, ErrorCode};
use crate::geometry::io::{FileDigest, ReadOptions};
use crate::geometry::pose::Pose;

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
        // Each view posed within its pass's table frame; the passes' frames are found by fusion.
        let listed: Vec<(String, Pose, u32)> =
            log.views.iter().map(|v| (v.file.clone(), log.pose_of(v), v.pass)).collect();
        let manifest = dir.join(crate::geometry::io::scanset::MANIFEST);
        crate::geometry::io::scanset::write_manifest_passes(&manifest, &listed, true)?;
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
    /// A tilting table's range (`[devices.turntable] tilt_min`, `tilt_max`); `None`: single-axis.
    pub tilt_range: Option<(f64, f64)>,
    /// Bytes the coverage estimates may use.
    pub memory_budget: u64,
    /// The devices.
    pub rig: &'a Rig,
    /// Set when the job is cancelled.
    pub cancel: &'a AtomicBool,
    /// Progress: (share of the capture done 0–1, stage `home` or `capture`, message).
    pub progress: &'a (dyn Fn(f64, &'static str, String) + Send + Sync),
    /// A person is asked to act (`Some(what)`: turn the object over), or no longer (`None`).
    pub operator: &'a (dyn Fn(Option<String>) + Send + Sync),
    /// Notified when the person has acted (`Continue()`).
    pub proceed: &'a tokio::sync::Notify,
}

fn cancelled() -> Error {
    Error::new(ErrorCode::Cancelled, "cancelled during the capture; the views taken are kept in quarantine")
}

/// [`persist`] on a blocking thread (it writes and fsyncs), off the async workers.
async fn save(dir: &Path, log: &CaptureLog) -> Result<(), Error> {
    let (dir, log) = (dir.to_path_buf(), log.clone());
    tokio::task::spawn_blocking(move || persist(&dir, &log))
        .await
        .map_err(|e| Error::internal(format!("the capture log's writer failed: {e}")))?
}

/// What came of one view's triggers.
enum ViewOutcome {
    /// It arrived.
    Taken(TakenView),
    /// It was lost `view_retries + 1` times and is left out (`on_lost_view = "skip"`): the last error.
    Skipped(Error),
    /// It was lost `view_retries + 1` times and fails the scan (`on_lost_view = "fail"`): the last error.
    GaveUp(Error),
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
        // The cradle's calibration for a tilted plan, and for views chosen on a tilting table.
        tilt_axis: cfg
            .tilt_axis
            .filter(|_| job.request.tilts() || (job.request.coverage.is_some() && job.tilt_range.is_some())),
        planned: job.request.stops().len() as u32,
        ..Default::default()
    });
    log.runs += 1;
    save(job.dir, &log).await?;
    let stops = job.request.stops();

    // 1. Home (again after a restart: the table may have been turned by hand meanwhile), unless every view
    //    is in already.
    if (0..stops.len() as u32).any(|i| !log.has(i)) {
        (job.progress)(0.0, "home", "home/homing the turntable".into());
        home(job, table, &mut log).await?;
    }

    // 2. Every missing view, in plan order, pass by pass; before each pass after the first, a person turns
    //    the object over (asked once: a restart after the confirmation does not ask again), and the table
    //    is homed again (it may have been turned by hand meanwhile).
    let passes = job.request.passes.max(1) as usize;
    let per_pass = stops.len() / passes;
    for pass in 1..=passes {
        let first = (pass - 1) * per_pass;
        let missing = (first..first + per_pass).any(|i| !log.has(i as u32));
        if pass > 1 && missing && !log.turned_over.iter().any(|t| t.0 == pass as u32) {
            turn_over(job, &mut log, pass as u32).await?;
            home(job, table, &mut log).await?;
        }
        take_stops(job, (table, trigger), &mut log, &stops[first..first + per_pass], first as u32).await?;
    }

    // 3. Views chosen where the surface is unseen (chosen before a restart first), round by round.
    let chooser = Chooser {
        dir: job.dir,
        request: job.request,
        cfg,
        tilt_range: job.tilt_range,
        memory_budget: job.memory_budget,
    };
    loop {
        for (index, stop) in next::pending(&log) {
            take_stops(job, (table, trigger), &mut log, &[stop], index).await?;
        }
        if !log.next_views_end.is_empty() || job.request.coverage.is_none() {
            break;
        }
        (job.progress)(
            1.0,
            "capture",
            format!("capture/estimating the unseen surface after {} views", log.views.len()),
        );
        let more = next::round(&chooser, &mut log).await?;
        save(job.dir, &log).await?;
        if !more {
            break;
        }
    }
    if log.views.len() < 2 {
        return Err(Error::new(
            ErrorCode::ReconstructViewsDisagree,
            format!("only {} view(s) captured of {}: too few to fuse", log.views.len(), stops.len()),
        ));
    }
    Ok(log)
}

/// Ask a person to turn the object over before `pass` (`OperatorActionRequired`; the wait journaled in
/// `capture.json`), and wait for `Continue()` or a cancel, keeping the heartbeat.
async fn turn_over(job: &CaptureJob<'_>, log: &mut CaptureLog, pass: u32) -> Result<(), Error> {
    let what = format!(
        "turn the object over for pass {pass} of {}: rest it on another face, anywhere on the table top, then call Continue() on this job",
        job.request.passes
    );
    log.waiting_for_pass = Some(pass);
    save(job.dir, log).await?;
    tracing::info!(pass, "waiting for a person to turn the object over");
    let share = ((log.views.len() + log.skipped.len()) as f64 / f64::from(log.planned.max(1))).min(1.0);
    (job.operator)(Some(what.clone()));
    let mut tick = tokio::time::interval(Duration::from_millis(250));
    loop {
        tokio::select! {
            () = job.proceed.notified() => break,
            _ = tick.tick() => {
                if job.cancel.load(Ordering::Relaxed) {
                    (job.operator)(None);
                    return Err(cancelled());
                }
                (job.progress)(share, "capture", format!("capture/waiting: {what}"));
            }
        }
    }
    (job.operator)(None);
    log.waiting_for_pass = None;
    log.turned_over.push((pass, crate::daemon::journal::now_usec()));
    save(job.dir, log).await?;
    tracing::info!(pass, "the object is turned over; the capture goes on");
    Ok(())
}

/// Take the views of `stops` (plan indices from `first`) that `log` does not hold, in order: move, settle,
/// trigger, keep; the log saved after each.
async fn take_stops(
    job: &CaptureJob<'_>,
    (table, trigger): (&TurntableHandle, &TriggerHandle),
    log: &mut CaptureLog,
    stops: &[Stop],
    first: u32,
) -> Result<(), Error> {
    let total = (log.planned as usize).max(1) as f64;
    let share = |log: &CaptureLog| ((log.views.len() + log.skipped.len()) as f64 / total).min(1.0);
    for (i, stop) in stops.iter().enumerate() {
        let index = first + i as u32;
        if log.has(index) {
            continue;
        }
        if job.cancel.load(Ordering::Relaxed) {
            return Err(cancelled());
        }
        let n = index + 1;
        let at = where_text(stop);
        (job.progress)(share(log), "capture", format!("capture/view {n} of {} at {at}", log.planned));
        let reached = move_to(job, table, log, stop).await?;
        tokio::time::sleep(job.cfg.settle).await;
        let outcome = match trigger_view(job, trigger, log, index, (stop, reached)).await? {
            // A chosen view predicted surface where the scanner saw none (the prediction does not know the
            // projector, nor the plate's exact edge): a miss of the choice, not of the rig. Named, skipped.
            ViewOutcome::GaveUp(e) if e.code == ErrorCode::DeviceEmptyView && index >= first_chosen(log) => {
                ViewOutcome::Skipped(Error::new(e.code, format!("{} (a chosen view: skipped)", e.message)))
            }
            o => o,
        };
        match outcome {
            ViewOutcome::Taken(v) => log.views.push(v),
            ViewOutcome::GaveUp(e) => {
                save(job.dir, log).await?;
                let what = if e.code == ErrorCode::DeviceEmptyView {
                    format!("view {n} at {at}: {}", e.message)
                } else {
                    format!("view {n} at {at} never arrived after {} triggers: {}", job.cfg.view_retries + 1, e.message)
                };
                return Err(Error::new(e.code, what));
            }
            ViewOutcome::Skipped(e) => {
                let reason = format!("[{}] {}", e.code.as_str(), e.message);
                tracing::warn!(view = index, %reason, "view skipped");
                let (angle_deg, tilt_deg, pass) = (stop.angle_deg, stop.tilt_deg, stop.pass);
                log.skipped.push(SkippedView { index, angle_deg, tilt_deg, pass, reason });
            }
        }
        log.views.sort_by_key(|v| v.index);
        save(job.dir, log).await?;
        (job.progress)(share(log), "capture", format!("capture/{} of {} views", log.views.len(), log.planned));
    }
    Ok(())
}

/// The plan index of the first view chosen where the surface was unseen (`u32::MAX` when none was).
fn first_chosen(log: &CaptureLog) -> u32 {
    log.next_views.first().map_or(u32::MAX, |v| v.index)
}

/// A stop in words: `30.0°`, or `30.0° tilted -25.0°`.
fn where_text(stop: &Stop) -> String {
    let pass = if stop.pass > 1 { format!(" (pass {})", stop.pass) } else { String::new() };
    if stop.tilt_deg == 0.0 {
        format!("{:.1}°{pass}", stop.angle_deg)
    } else {
        format!("{:.1}° tilted {:.1}°{pass}", stop.angle_deg, stop.tilt_deg)
    }
}

/// Trigger view `index` (the table asked to `angle`, at `reached`) until it arrives, or until the policy
/// gives it up ([`next`]: a lost view is triggered again `view_retries` times; a lost scanner is waited for
/// and does not count as a lost view).
async fn trigger_view(
    job: &CaptureJob<'_>,
    trigger: &TriggerHandle,
    log: &mut CaptureLog,
    index: u32,
    (stop, reached): (&Stop, f64),
) -> Result<ViewOutcome, Error> {
    let rules = Rules::of(job.cfg);
    // Triggers lost for this view so far.
    let mut lost = 0;
    loop {
        if job.cancel.load(Ordering::Relaxed) {
            return Err(cancelled());
        }
        let e = match take_view(job, trigger, index).await {
            Ok((file, report, digest)) => {
                return Ok(ViewOutcome::Taken(TakenView {
                    index,
                    file,
                    bytes: digest.bytes,
                    sha256: digest.sha256,
                    angle_deg: stop.angle_deg,
                    reached_deg: reached,
                    tilt_deg: stop.tilt_deg,
                    pass: stop.pass,
                    seq: report.seq,
                    points: report.points,
                    tries: lost + 1,
                    view_ms: report.view_ms,
                }));
            }
            Err(e) => e,
        };
        let fault = classify(Device::Trigger, &e, true);
        // The view's own trouble (lost, or seen empty), as against the scanner's.
        let view_lost = matches!(fault, Fault::ViewLost | Fault::ViewEmpty);
        if fault == Fault::ViewLost {
            lost += 1;
        }
        match next(Device::Trigger, Action::View, &e, true, &rules, lost) {
            Step::Retry => {
                log.retries += 1;
                tracing::warn!(view = index, lost, "view lost; triggering again");
            }
            Step::WaitFor(_) | Step::WaitAndReHome => {
                wait_trigger(job, trigger, &e).await?;
                log.replugs += 1;
            }
            Step::Skip => return Ok(ViewOutcome::Skipped(e)),
            Step::Fail if view_lost => return Ok(ViewOutcome::GaveUp(e)),
            Step::Fail => return Err(e),
        }
    }
}

/// Home; a lost table is waited for and homed again, when the policy says so.
async fn home(job: &CaptureJob<'_>, table: &TurntableHandle, log: &mut CaptureLog) -> Result<(), Error> {
    let rules = Rules::of(job.cfg);
    loop {
        let e = match or_cancel(job.cancel, table.home()).await? {
            Ok(()) => {
                log.homings += 1;
                return Ok(());
            }
            Err(e) => e,
        };
        match next(Device::Turntable, Action::Home, &e, table.state().connected, &rules, 0) {
            Step::WaitFor(_) | Step::WaitAndReHome => {
                wait_replug(job, table, &e).await?;
                log.replugs += 1;
            }
            _ => return Err(e),
        }
    }
}

/// Move to `stop` (a tilting plan sends the tilt with every move, 0 for the level ring); after a lost table,
/// as the policy says: wait for it, home it and move again. The angle reached.
async fn move_to(
    job: &CaptureJob<'_>,
    table: &TurntableHandle,
    log: &mut CaptureLog,
    stop: &Stop,
) -> Result<f64, Error> {
    let rules = Rules::of(job.cfg);
    loop {
        // A move under way is finished before a cancel takes effect: the table stops within one move.
        let moved = match log.tilt_axis {
            Some(_) => table.move_to_tilted(stop.angle_deg, stop.tilt_deg).await,
            None => table.move_to(stop.angle_deg).await,
        };
        let e = match moved {
            Ok(r) => return Ok(r.reached),
            Err(e) => e,
        };
        match next(Device::Turntable, Action::Move, &e, table.state().connected, &rules, 0) {
            Step::WaitAndReHome | Step::WaitFor(_) => {
                wait_replug(job, table, &e).await?;
                log.replugs += 1;
                home(job, table, log).await?;
            }
            _ => return Err(e),
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

/// Wait up to `replug_timeout` for the scanner to be ready again.
async fn wait_trigger(job: &CaptureJob<'_>, trigger: &TriggerHandle, why: &Error) -> Result<(), Error> {
    wait_back(job, trigger.watch(), |s| s.ready(), "scanner", why).await
}

/// Trigger one view and take its file into the scan directory as `view-NNN.ply`.
async fn take_view(
    job: &CaptureJob<'_>,
    trigger: &TriggerHandle,
    index: u32,
) -> Result<(String, crate::devices::trigger::FireReport, FileDigest), Error> {
    let report = or_cancel(job.cancel, trigger.fire(job.cfg.trigger_channel)).await??;
    if report.points == 0 {
        return Err(Error::new(
            ErrorCode::DeviceEmptyView,
            format!(
                "the scanner saw nothing (trigger {}: no points; nothing in its field of view, or a black, shiny or inside-out surface)",
                report.seq
            ),
        ));
    }
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
    let digest = tokio::task::spawn_blocking(move || take_file(&from2, &to2, &dir, expect))
        .await
        .map_err(|e| Error::internal(format!("the view's mover failed: {e}")))??;
    Ok((name, report, digest))
}

/// Check the view file holds the points the scanner announced, then move it into the scan directory
/// (renamed; copied and removed across file systems) and make it durable. Its size and hash, from the one
/// read that checked it.
fn take_file(from: &Path, to: &Path, dir: &Path, expect: u32) -> Result<FileDigest, Error> {
    let digest = crate::pipeline::reconstruct::check_view(from, expect, &ReadOptions::default())?;
    let io = |e: std::io::Error| Error::new(ErrorCode::ResourceOutput, format!("cannot take {}: {e}", from.display()));
    if std::fs::rename(from, to).is_err() {
        let part = to.with_extension("ply.part");
        std::fs::copy(from, &part).map_err(io)?;
        std::fs::File::open(&part).and_then(|f| f.sync_all()).map_err(io)?;
        std::fs::rename(&part, to).map_err(io)?;
        let _ = std::fs::remove_file(from);
    }
    sync_dir(dir).map_err(io)?;
    Ok(digest)
}

//! Views chosen where the surface is unseen (`StartScan`'s `coverage`): after the plan, and after each round
//! of chosen views, estimate what the views taken so far saw ([`crate::pipeline::next_view::estimate`]) and
//! choose the stops that would see most of the rest ([`crate::pipeline::next_view::choose`]), under the
//! view budget. The choice is kept in the capture log before any of its views is taken, so a restarted scan
//! takes the same views. In a scan of several passes the views are chosen after the last pass, in its frame
//! (the estimate's surface is moved there by the motion fusion found for that pass).

use std::path::Path;
use std::time::Instant;

use super::plan::{CaptureLog, ChosenView, CoverageEstimate, ScanRequest, Stop, stop_pose};
use crate::daemon::config::ScanConfig;
use crate::error::Error;
use crate::pipeline::next_view::{NextViewOptions, candidates, choose, estimate};

/// Rounds of choosing at most (each needs an estimate: a fusion and a coarse reconstruction).
pub const MAX_ROUNDS: u32 = 3;

/// Candidate stops every this many degrees around.
pub const ANGLE_STEP_DEG: f64 = 15.0;

/// Candidate tilts every this many degrees across the cradle's range.
pub const TILT_STEP_DEG: f64 = 10.0;

/// What a scan's choosing needs beyond its log.
pub struct Chooser<'a> {
    /// The scan directory (its `scanset.toml` is read).
    pub dir: &'a Path,
    /// The request (`coverage`, `max_views`).
    pub request: &'a ScanRequest,
    /// `[scan]` (the view budget's default, the plate).
    pub cfg: &'a ScanConfig,
    /// A tilting table's range, when the log has the cradle's calibration.
    pub tilt_range: Option<(f64, f64)>,
    /// Bytes the estimate may use.
    pub memory_budget: u64,
}

/// The chosen views the log holds that are not taken yet, as stops with their plan indices.
pub fn pending(log: &CaptureLog) -> Vec<(u32, Stop)> {
    log.next_views
        .iter()
        .filter(|v| !log.has(v.index))
        .map(|v| (v.index, Stop { angle_deg: v.angle_deg, tilt_deg: v.tilt_deg, pass: v.pass }))
        .collect()
}

/// One round: estimate, and unless the target is reached, the budget spent or no stop adds enough, choose
/// views and add them to `log` (and to its `planned`). `Ok(false)`: no more rounds (`log.next_views_end` says
/// why).
///
/// # Errors
/// The estimate's (the scan set's reading and fusion; `reconstruct.failed`).
pub async fn round(c: &Chooser<'_>, log: &mut CaptureLog) -> Result<bool, Error> {
    let Some(target) = c.request.coverage else { return Ok(false) };
    let max_views = c.request.max_views.unwrap_or(c.cfg.max_views);
    let rounds = log.next_views.iter().map(|v| v.round).max().unwrap_or(0);
    let end = |log: &mut CaptureLog, why: &str| {
        log.next_views_end = why.to_string();
        Ok(false)
    };
    if rounds >= MAX_ROUNDS {
        return end(log, "the rounds of choosing");
    }
    if log.planned >= max_views {
        return end(log, "the view budget");
    }
    let t = Instant::now();
    let (dir, budget) = (c.dir.to_path_buf(), c.memory_budget);
    let est = tokio::task::spawn_blocking(move || estimate(&dir, budget))
        .await
        .map_err(|e| Error::internal(format!("the coverage estimate failed: {e}")))??;
    let opts = NextViewOptions {
        target,
        budget: (max_views - log.planned) as usize,
        plate_radius: c.cfg.plate_radius,
        ..Default::default()
    };
    let views = log.views.len() as u32;
    let (coverage, seen_twice) = (est.coverage, est.seen_share(opts.need));
    let seconds = t.elapsed().as_secs_f64();
    log.estimates.push(CoverageEstimate { views, coverage, seen_twice, seconds, choose_seconds: 0.0 });
    tracing::info!(views, coverage, seen_twice, "coverage estimated");
    if seen_twice >= target {
        return end(log, "coverage reached");
    }
    // Stops not taken yet in this pass (the last): a stop taken again sees what it saw.
    let pass = c.request.passes.max(1);
    let taken = |&(a, t): &(f64, f64)| {
        log.views.iter().filter(|v| v.pass == pass).any(|v| {
            let d = (v.angle_deg - a).rem_euclid(360.0);
            d.min(360.0 - d) < 1e-6 && (v.tilt_deg - t).abs() < 1e-6
        })
    };
    let cands: Vec<(f64, f64)> =
        candidates(ANGLE_STEP_DEG, c.tilt_range.filter(|_| log.tilt_axis.is_some()), TILT_STEP_DEG)
            .into_iter()
            .filter(|s| !taken(s))
            .collect();
    let (axis, tilt) = ((log.axis_point, log.axis_direction), log.tilt_axis);
    let pose_of = move |angle_deg: f64, tilt_deg: f64| stop_pose(axis, tilt, Stop { angle_deg, tilt_deg, pass });
    let t = Instant::now();
    let picked = tokio::task::spawn_blocking(move || choose(&est, &cands, &pose_of, &opts))
        .await
        .map_err(|e| Error::internal(format!("choosing the next views failed: {e}")))?;
    if let Some(e) = log.estimates.last_mut() {
        e.choose_seconds = t.elapsed().as_secs_f64();
    }
    if picked.is_empty() {
        return end(log, "no view adds enough");
    }
    for v in picked {
        let (angle_deg, tilt_deg, predicted_gain) = (v.angle_deg, v.tilt_deg, v.predicted_gain);
        let index = log.planned;
        log.next_views.push(ChosenView { index, angle_deg, tilt_deg, predicted_gain, round: rounds + 1, pass });
        log.planned += 1;
    }
    Ok(true)
}

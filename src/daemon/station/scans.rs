//! Scan sessions on the actor: `StartScan` makes a job whose input is a scan directory that its capture
//! fills ([`crate::daemon::scan`]); starting it runs the capture on the runtime (the rig is async), one scan at
//! a time on the rig, then the conversion on the CPU pool as any job's.

use std::sync::atomic::Ordering;

use super::*;
use crate::daemon::config::JobOptions;
use crate::daemon::dbus::StationError;
use crate::daemon::durable::sync_dir;
use crate::daemon::journal::{JobId, JobRecord, now_usec};
use crate::daemon::scan::{self, CaptureJob, ScanRequest};
use crate::daemon::worker::{CAPTURE_END, HOME_END, JobRun, SCAN_STAGES};

/// A scan's name: 1 to 64 of `[A-Za-z0-9_.-]`, not starting with a dot.
pub fn valid_scan_name(name: &str) -> bool {
    (1..=64).contains(&name.len())
        && !name.starts_with('.')
        && name.chars().all(|c| c.is_ascii_alphanumeric() || "_.-".contains(c))
}

impl Station {
    /// `StartScan`: a queued scan job whose scan directory exists, its record saved and its object exported.
    pub(super) async fn start_scan(
        &mut self,
        request: ScanRequest,
        name: String,
        options: JobOptions,
        source: String,
    ) -> Result<JobId, StationError> {
        if self.cfg.scan.is_none() {
            return Err(StationError::Device(
                "[device.unplugged] this station has no [scan] section (capture_dir and the calibrated axis)".into(),
            ));
        }
        if self.rig.turntable.is_none() || self.rig.trigger.is_none() {
            return Err(StationError::Device(
                "[device.unplugged] a scan needs both [devices.turntable] and [devices.trigger]".into(),
            ));
        }
        if !request.rings.is_empty() {
            let calibrated = self.cfg.scan.as_ref().is_some_and(|s| s.tilt_axis.is_some());
            let tilting = self.cfg.turntable.as_ref().and_then(|t| t.tilt);
            let Some((lo, hi)) = tilting.filter(|_| calibrated) else {
                return Err(StationError::Device(
                    "[device.config] tilted rings need a tilting table: tilt_min and tilt_max in [devices.turntable], and its calibration (tilt_axis_point, tilt_axis_direction) in [scan]".into(),
                ));
            };
            if let Some(r) = request.rings.iter().find(|r| !(lo..=hi).contains(&r.tilt_deg)) {
                return Err(StationError::InvalidArgument(format!(
                    "tilts: {}° is outside the cradle's range {lo}° to {hi}°",
                    r.tilt_deg
                )));
            }
        }
        if !valid_scan_name(&name) {
            return Err(StationError::InvalidArgument(format!(
                "name {name:?}: 1 to 64 letters, digits, '_', '-' or '.', not starting with '.'"
            )));
        }
        if let Some(spec) = &request.fea
            && !spec.is_file()
        {
            return Err(StationError::NotFound(format!("fea: {} is not a readable file", spec.display())));
        }
        let id = JobId::new();
        let input = format!("{name}.scan");
        let dir = self.spool.work_dir(&id).join(&input);
        std::fs::create_dir_all(&dir)
            .and_then(|()| sync_dir(self.spool.work_dir(&id).as_path()))
            .map_err(|e| StationError::Internal(format!("cannot create {}: {e}", dir.display())))?;
        let rec = JobRecord {
            options,
            scan: Some(request),
            ..JobRecord::queued(id.clone(), input, source, String::new(), 0, SCAN_STAGES[0])
        };
        tracing::info!(job_id = %id, views = rec.scan.as_ref().map(|s| s.views), "scan queued");
        self.enqueue(rec, None).await.map_err(|e| StationError::Internal(e.to_string()))?;
        Ok(id)
    }

    /// Start a scan job: capture on the runtime (holding the rig), then convert on the pool.
    pub(super) fn spawn_scan(&self, mut run: JobRun) {
        let Some(cfg) = self.cfg.scan.clone() else {
            run.preset_error = Some(crate::error::Error::new(
                crate::error::ErrorCode::DeviceUnplugged,
                "the station's [scan] section is gone (config reloaded without it)",
            ));
            let span = tracing::info_span!("job", job_id = %run.record.id);
            worker::start(&self.pool, run, span);
            return;
        };
        let rig = self.rig.clone();
        let lock = self.rig_lock.clone();
        let pool = self.pool.clone();
        let dir = worker::input_path(&self.spool, &run.record);
        let tilt_range = self.cfg.turntable.as_ref().and_then(|t| t.tilt);
        let memory_budget = self.cfg.memory_budget;
        tokio::spawn(async move {
            let id = run.record.id.clone();
            let events = run.events.clone();
            let heartbeat = run.heartbeat.clone();
            let stage = std::sync::Mutex::new("home");
            let progress = |share: f64, s: &'static str, message: String| {
                heartbeat.store(now_usec(), Ordering::Relaxed);
                *stage.lock().unwrap_or_else(|p| p.into_inner()) = s;
                let share = if share.is_finite() { share.clamp(0.0, 1.0) } else { 0.0 };
                let fraction = if s == "home" { 0.0 } else { HOME_END + share * (CAPTURE_END - HOME_END) };
                let _ = events.send(WorkerEvent::Progress { id: id.clone(), fraction, stage: s, message });
            };
            let operator = |what: Option<String>| {
                let _ = events.send(WorkerEvent::Operator { id: id.clone(), what });
            };
            let proceed = run.proceed.clone();
            let request = run.record.scan.clone().unwrap_or(ScanRequest {
                views: 0,
                step_deg: 0.0,
                rings: Vec::new(),
                coverage: None,
                max_views: None,
                fea: None,
                passes: 1,
            });
            let result = {
                // One scan at a time on the rig.
                if lock.try_lock().is_err() {
                    progress(0.0, "home", "home/waiting for the rig (another scan is capturing)".into());
                }
                let _rig = lock.lock().await;
                let job = CaptureJob {
                    dir: &dir,
                    request: &request,
                    cfg: &cfg,
                    tilt_range,
                    memory_budget,
                    rig: &rig,
                    cancel: &run.cancel,
                    progress: &progress,
                    operator: &operator,
                    proceed: &proceed,
                };
                scan::capture(&job).await
            };
            let stage_now = *stage.lock().unwrap_or_else(|p| p.into_inner());
            match result {
                Ok(log) => {
                    tracing::info!(views = log.views.len(), skipped = log.skipped.len(), "capture done");
                    run.stage = "fuse";
                    run.capture = Some(log);
                }
                Err(e) => {
                    tracing::warn!(error = %e, "capture ended");
                    run.preset_error = Some(e);
                    run.stage = stage_now;
                }
            }
            let span = tracing::info_span!("job", job_id = %run.record.id);
            worker::start(&pool, run, span);
        });
    }
}

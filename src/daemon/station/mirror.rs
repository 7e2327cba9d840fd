//! The D-Bus mirror of the actor's state: exporting job objects, announcing finished jobs, the Manager's
//! properties and signals.

use std::time::Instant;

use super::*;
use crate::daemon::dbus::{job_path, lock};
use crate::daemon::journal::JobId;

impl Station {
    /// Export the object of every job not yet on the bus.
    pub async fn export_all(&mut self) -> zbus::Result<()> {
        let ids: Vec<JobId> = self.jobs.iter().filter(|(_, j)| j.iface.is_none()).map(|(k, _)| k.clone()).collect();
        for id in ids {
            self.export(&id).await?;
        }
        Ok(())
    }

    pub(super) async fn export(&mut self, id: &JobId) -> zbus::Result<()> {
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
    pub(super) async fn announce(&mut self, id: &JobId) {
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

    /// Why the station is degraded: its own reasons, then its devices'.
    pub(super) fn degraded_reasons(&self) -> Vec<String> {
        self.degraded.iter().chain(self.device_faults.values().flatten()).cloned().collect()
    }

    pub(super) fn manager_state(&self) -> &'static str {
        if !self.degraded.is_empty() || !self.device_faults.is_empty() {
            "degraded"
        } else if self.paused {
            "paused"
        } else if !self.running.is_empty() || !self.queue.is_empty() {
            "busy"
        } else {
            "idle"
        }
    }

    pub(super) fn refresh_manager_view(&self) -> [bool; 6] {
        let mut v = lock(&self.manager_view);
        let state = self.manager_state().to_string();
        let active: Vec<_> = self.running.iter().map(job_path).collect();
        let queued: Vec<_> = self.queue.iter().map(job_path).collect();
        let degraded = self.degraded_reasons();
        let changed = [
            v.state != state,
            v.active != active,
            v.queued != queued,
            v.succeeded != self.succeeded,
            v.failed != self.failed,
            v.degraded != degraded,
        ];
        *v = ManagerView { state, degraded, active, queued, succeeded: self.succeeded, failed: self.failed };
        changed
    }

    pub(super) async fn emit_manager(&self) {
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
        if changed[5] {
            let _ = g.degraded_changed(em).await;
        }
    }
}

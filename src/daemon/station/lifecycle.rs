//! The job lifecycle: the job table, starting jobs on the workers, their events, finishing, cancelling,
//! pruning and the history.

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use zbus::zvariant::{OwnedValue, Value};

use super::*;
use crate::daemon::dbus::{JobView, StationError, job_path, lock};
use crate::daemon::journal::{JobId, JobRecord, JobState, now_usec};
use crate::daemon::worker::{self, JobRun, Outcome, WorkerEvent, stages_of};
use crate::error::{Error, ErrorCode};

impl Station {
    pub(super) fn insert(&mut self, rec: JobRecord, preset_error: Option<Error>) {
        let view = JobView {
            id: rec.id.to_string(),
            input: rec.input.clone(),
            input_sha256: rec.input_sha256.clone(),
            state: rec.state.as_str().into(),
            stage: rec.stage.clone(),
            stage_index: stages_of(&rec).iter().position(|s| *s == rec.stage).unwrap_or(0) as u32,
            stage_count: stages_of(&rec).len() as u32,
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
            operator_action: String::new(),
        };
        let id = rec.id.clone();
        self.jobs.insert(
            id,
            Job {
                rec,
                view: Arc::new(Mutex::new(view)),
                iface: None,
                cancel: Arc::new(AtomicBool::new(false)),
                proceed: Arc::new(tokio::sync::Notify::new()),
                preset_error,
                last_emit: None,
                emitted_progress: 0.0,
                finished_at: None,
            },
        );
    }

    pub(super) async fn start_jobs(&mut self) {
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
                proceed: job.proceed.clone(),
                heartbeat: self.heartbeat.clone(),
                events: self.worker_tx.clone(),
                stage: stages_of(&job.rec)[0],
                capture: None,
            };
            self.heartbeat.store(now_usec(), Ordering::Relaxed);
            let span = tracing::info_span!("job", job_id = %id);
            tracing::info!(parent: &span, input = %job.rec.input, run = job.rec.runs, "job started");
            if job.rec.scan.is_some() && job.preset_error.is_none() {
                self.spawn_scan(run);
            } else {
                worker::start(&self.pool, run, span);
            }
            self.running.push(id);
        }
    }

    pub(super) async fn worker_event(&mut self, ev: WorkerEvent) {
        match ev {
            WorkerEvent::Progress { id, fraction, stage, message } => {
                let max_rate = self.cfg.progress_max_rate_hz;
                let Some(job) = self.jobs.get_mut(&id) else { return };
                if job.rec.state.is_terminal() {
                    return;
                }
                let stage_changed = job.rec.stage != stage;
                let index = stages_of(&job.rec).iter().position(|s| *s == stage).unwrap_or(0) as u32;
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
            WorkerEvent::Operator { id, what } => self.operator(&id, what).await,
            WorkerEvent::Cluster { id, run } => {
                let Some(job) = self.jobs.get_mut(&id) else { return };
                tracing::info!(job_id = %id, slurm_id = run.slurm_id, submissions = run.submissions, "on the cluster");
                job.rec.cluster = Some(run);
                if let Err(e) = self.journal.save(&job.rec) {
                    tracing::error!(job_id = %id, error = %e, "cannot persist the job record");
                }
            }
            WorkerEvent::Done { id, outcome } => self.finish(&id, outcome).await,
        }
    }

    pub(super) async fn finish(&mut self, id: &JobId, outcome: Outcome) {
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
            v.stage_index = stages_of(&job.rec).iter().position(|s| *s == job.rec.stage).unwrap_or(0) as u32;
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
            let _ = g.report_file_changed(em).await;
            let _ = g.thumbnail_changed(em).await;
        }
        self.announce(id).await;
    }

    /// A scan's request to a person (`Some(what)`), or its end: property `OperatorAction`, and the signal
    /// `OperatorActionRequired` when asked.
    async fn operator(&mut self, id: &JobId, what: Option<String>) {
        let Some(job) = self.jobs.get_mut(id) else { return };
        if job.rec.state.is_terminal() {
            return;
        }
        lock(&job.view).operator_action = what.clone().unwrap_or_default();
        if let Some(r) = &job.iface {
            let g = r.get().await;
            let em = r.signal_emitter();
            let _ = g.operator_action_changed(em).await;
            if let Some(what) = &what {
                let _ = JobIface::operator_action_required(em, what).await;
            }
        }
    }

    /// `Continue()`: the person asked to act has done it.
    pub(super) async fn proceed(&mut self, id: &str) -> Result<(), StationError> {
        let jid = JobId::parse(id).ok_or_else(|| StationError::NotFound(format!("no job {id}")))?;
        let Some(job) = self.jobs.get(&jid) else { return Err(StationError::NotFound(format!("no job {id}"))) };
        if job.rec.state.is_terminal() || lock(&job.view).operator_action.is_empty() {
            return Err(StationError::NotWaiting(format!("job {id} is not waiting for a person")));
        }
        job.proceed.notify_one();
        tracing::info!(job_id = %jid, "continue: the person has acted");
        self.operator(&jid, None).await;
        Ok(())
    }

    pub(super) async fn cancel(&mut self, id: &str) -> Result<(), StationError> {
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
    pub(super) async fn prune(&mut self) {
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

    pub(super) fn history(&self, since: u64, limit: u32) -> Vec<HashMap<String, OwnedValue>> {
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
}

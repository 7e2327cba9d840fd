//! One job's work, run on the CPU pool (never on the async runtime): the conversion chain on the claimed
//! input, the quality artifacts, then publication of `outbox/<stem>-<id>/` (manifest last, one rename) — or,
//! on any error, the input moved to `quarantine/<stem>-<id>/` with `error.json` (and, when the solid failed a
//! quality gate, its artifacts and report beside it). Progress goes back to the
//! station as one monotonic, weighted fraction.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use tokio::sync::mpsc;

use super::config::Config;
use super::durable::{sync_dir, write_durable};
use super::journal::{JobId, JobRecord, now_usec};
use super::spool::{Spool, publish_dir};
use crate::error::{Error, ErrorCode};
use crate::geometry::io::ReadOptions;
use crate::pipeline::GateOptions;
use crate::pipeline::convert::{ConvertOptions, Resolution, convert_held};
use crate::pipeline::memory::StageMeter;
use crate::pipeline::{Progress, check_cancelled};

/// The stages a file's job goes through, in order (`StageIndex` indexes this).
pub const STAGES: [&str; 8] = ["read", "repair", "remesh", "surface", "brep", "step", "quality", "publish"];

/// The stages of a scan session ([`super::scan`]): the capture, then the chain from the fused views on.
pub const SCAN_STAGES: [&str; 12] = [
    "home",
    "capture",
    "fuse",
    "reconstruct",
    "repair",
    "remesh",
    "surface",
    "brep",
    "step",
    "quality",
    "fea",
    "publish",
];

/// The stages of `rec`'s job.
pub fn stages_of(rec: &JobRecord) -> &'static [&'static str] {
    if rec.scan.is_some() { &SCAN_STAGES } else { &STAGES }
}

/// Overall progress at the end of the conversion chain (its stages, `quality` last, map to 0 – this, or from
/// [`CAPTURE_END`] for a scan) and the start of `publish`.
const PUBLISH_AT: f64 = 0.97;

/// A scan's overall progress at the end of homing.
pub const HOME_END: f64 = 0.02;

/// A scan's overall progress at the end of the capture (the views, evenly) and the start of fusion.
pub const CAPTURE_END: f64 = 0.30;

/// A scan's overall progress at the start of the FEA (after the quality check).
const FEA_AT: f64 = 0.95;
/// Highest value reported before the job has finished.
const BEFORE_DONE: f64 = 0.999;

/// What the worker tells the station.
#[derive(Debug)]
pub enum WorkerEvent {
    /// Progress of a running job.
    Progress {
        /// The job.
        id: JobId,
        /// Overall fraction, 0–1.
        fraction: f64,
        /// Its stage ([`STAGES`]).
        stage: &'static str,
        /// The phase, `stage/phase`.
        message: String,
    },
    /// A scan asks a person to act (`Some(what)`: turn the object over), or no longer (`None`).
    Operator {
        /// The job.
        id: JobId,
        /// What to do.
        what: Option<String>,
    },
    /// A job's conversion was submitted to the cluster (journal its Slurm id).
    Cluster {
        /// The job.
        id: JobId,
        /// The submission.
        run: super::journal::ClusterRun,
    },
    /// The job ended.
    Done {
        /// The job.
        id: JobId,
        /// How.
        outcome: Outcome,
    },
}

/// How a job ended.
#[derive(Debug)]
pub struct Outcome {
    /// None on success.
    pub error: Option<Error>,
    /// The stage that was running when it ended.
    pub stage: String,
    /// Files published (kind → path).
    pub outputs: BTreeMap<String, String>,
    /// Peak memory of the run, bytes.
    pub peak_memory: u64,
}

/// Everything a job's run needs.
pub struct JobRun {
    /// The job's record as it starts.
    pub record: JobRecord,
    /// The settings.
    pub cfg: Arc<Config>,
    /// Digest of the settings (written into reports).
    pub config_digest: String,
    /// The spool.
    pub spool: Spool,
    /// An error decided before the work (duplicate, too large, bad sidecar): quarantine at once.
    pub preset_error: Option<Error>,
    /// Set to stop the job at its next checkpoint.
    pub cancel: Arc<AtomicBool>,
    /// Notified by `Continue()`: the person asked to act has done it.
    pub proceed: Arc<tokio::sync::Notify>,
    /// µs of the last progress report (the watchdog only pets while this moves).
    pub heartbeat: Arc<AtomicU64>,
    /// Where progress and the outcome go.
    pub events: mpsc::UnboundedSender<WorkerEvent>,
    /// The stage the run starts in (the one a preset error is reported in): `read` for a file, `fuse` for a
    /// scan after its capture, the capture's stage when it failed there.
    pub stage: &'static str,
    /// A scan's capture log as the capture handed it over (`None` for a file, and for a scan resumed after a
    /// restart: its `capture.json` is read then).
    pub capture: Option<super::scan::CaptureLog>,
}

/// A job's progress and cancel flag as the conversion chain sees them.
pub struct Reporter<'a> {
    run: &'a JobRun,
    state: Mutex<(f64, &'static str)>,
    /// The overall range the conversion chain's 0–1 maps to.
    span: (f64, f64),
}

impl Reporter<'_> {
    fn send(&self, fraction: f64, stage: &'static str, message: String) {
        self.run.heartbeat.store(now_usec(), Ordering::Relaxed);
        let mut s = self.state.lock().unwrap_or_else(|p| p.into_inner());
        let f = fraction.clamp(0.0, BEFORE_DONE).max(s.0);
        if stage != s.1 || f >= s.0 + 0.002 {
            *s = (f, stage);
            let _ = self.run.events.send(WorkerEvent::Progress {
                id: self.run.record.id.clone(),
                fraction: f,
                stage,
                message,
            });
        }
    }
}

impl Progress for Reporter<'_> {
    fn report(&self, fraction: f64, phase: &str) {
        let mut stage_name = phase.split('/').next().unwrap_or("");
        let scan = self.run.record.scan.is_some();
        if scan && stage_name == "read" {
            // A scan's views are read and fused in one step.
            stage_name = "fuse";
        }
        let stage = stages_of(&self.run.record)
            .iter()
            .copied()
            .find(|s| *s == stage_name)
            .unwrap_or(self.state.lock().map(|s| s.1).ok().filter(|s| !s.is_empty()).unwrap_or(self.run.stage));
        let (a, b) = self.span;
        self.send(a + fraction * (b - a), stage, phase.to_string());
    }

    fn cancelled(&self) -> bool {
        self.run.cancel.load(Ordering::Relaxed)
    }
}

/// Start [`run`] in `span`: on the CPU `pool`, or, when conversions run on a cluster (where a job mostly
/// waits), on a thread of its own, so the pool's size does not bound the jobs on the cluster.
pub fn start(pool: &rayon::ThreadPool, job: JobRun, span: tracing::Span) {
    if job.cfg.executor.kind == super::executor::ExecutorKind::Slurm {
        let spawned = std::thread::Builder::new().name("cluster-job".into()).spawn(move || span.in_scope(|| run(job)));
        if let Err(e) = spawned {
            tracing::error!(error = %e, "cannot start a thread for a cluster job");
        }
    } else {
        pool.spawn(move || span.in_scope(|| run(job)));
    }
}

/// Run the job to its end (success, error, or cancellation) and report [`WorkerEvent::Done`].
pub fn run(job: JobRun) {
    let meter = StageMeter::start();
    let span = if job.record.scan.is_some() { (CAPTURE_END, FEA_AT) } else { (0.0, PUBLISH_AT) };
    // No stage yet: the first report names one (and is sent).
    let reporter = Reporter { run: &job, state: Mutex::new((span.0, "")), span };
    let result = match &job.preset_error {
        Some(e) => Err(e.clone()),
        None => convert_and_publish(&job, &reporter),
    };
    let stage = reporter.state.lock().map(|s| s.1).ok().filter(|s| !s.is_empty()).unwrap_or(job.stage).to_string();
    let (_, peak_mib) = meter.finish();
    let peak_memory = peak_mib.map(|m| (m * 1024.0 * 1024.0) as u64).unwrap_or(0);
    let outcome = match result {
        Ok(outputs) => Outcome { error: None, stage, outputs, peak_memory },
        Err(error) => {
            let outputs = match quarantine(&job, &error, &stage) {
                Ok(o) => o,
                Err(q) => {
                    tracing::error!(job_id = %job.record.id, error = %q, "quarantine failed; the input stays in work/");
                    BTreeMap::new()
                }
            };
            Outcome { error: Some(error), stage, outputs, peak_memory }
        }
    };
    let _ = job.events.send(WorkerEvent::Done { id: job.record.id.clone(), outcome });
}

/// The claimed input in `work/<id>/`.
pub fn input_path(spool: &Spool, rec: &JobRecord) -> PathBuf {
    spool.work_dir(&rec.id).join(&rec.input)
}

fn io_err(what: &str, path: &Path, e: std::io::Error) -> Error {
    Error::new(ErrorCode::ResourceOutput, format!("{what} {}: {e}", path.display()))
}

/// What a conversion left in the outbox's part directory, before its manifest: the bundle's files and their
/// digests, taken as they were written. What a cluster node hands back in its `result.json`.
#[derive(Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct Produced {
    /// (kind, path) of every file of the bundle, in the manifest's order.
    pub files: Vec<(String, PathBuf)>,
    /// Size and SHA-256 of the files whose digest was taken as they were written.
    pub digests: BTreeMap<PathBuf, (u64, String)>,
    /// A scan's views in its manifest.
    pub views_manifest: Option<serde_json::Value>,
}

/// Convert the job's input and publish its bundle: here ([`produce`]) or on the cluster
/// ([`produce_on_cluster`]), then [`publish`] on the station.
fn convert_and_publish(job: &JobRun, rep: &Reporter<'_>) -> Result<BTreeMap<String, String>, Error> {
    let produced = match job.cfg.executor.kind {
        super::executor::ExecutorKind::Local => produce(job, rep)?,
        super::executor::ExecutorKind::Slurm => produce_on_cluster(job, rep)?,
    };
    publish(job, &produced)
}

/// The conversion and every file of the bundle but its manifest, in `outbox/.<stem>-<id>.part/`.
///
/// # Errors
/// The chain's; a quality gate's (the report written beside the artifacts).
pub fn produce(job: &JobRun, rep: &Reporter<'_>) -> Result<Produced, Error> {
    let rec = &job.record;
    let stem = rec.stem();
    let input = input_path(&job.spool, rec);
    let part = job.spool.outbox_part(&stem, &rec.id);
    if part.exists() {
        std::fs::remove_dir_all(&part).map_err(|e| io_err("cannot clear", &part, e))?;
    }
    std::fs::create_dir_all(&part).map_err(|e| io_err("cannot create", &part, e))?;
    let cfg = &job.cfg;
    let tolerance = rec.options.tolerance.or(cfg.tolerance).map(Resolution::Tolerance);
    let default = cfg.vertices.map_or(Resolution::goal(cfg.max_vertices), Resolution::Vertices);
    let resolution = Resolution::choose(rec.options.vertices, tolerance, default);
    let opts = ConvertOptions {
        resolution,
        seed: rec.options.seed.unwrap_or(cfg.seed),
        compare_samples: cfg.compare_samples,
        memory_budget: cfg.memory_budget,
        gates: GateOptions {
            accept_degraded: rec.options.accept_degraded.unwrap_or(cfg.gates.accept_degraded),
            ..cfg.gates
        },
        // A scan's views stay in memory for its coverage.
        keep_views: rec.scan.is_some(),
        // A scan's solid stands on the turntable: z of the table frame is up.
        pictures: Some(if rec.scan.is_some() { crate::pipeline::pictures::Up::Z } else { cfg.pictures_up }),
        ..Default::default()
    };
    let read = ReadOptions { memory_budget: cfg.memory_budget, max_input_size: cfg.max_input_size };
    let step = part.join(format!("{stem}.step"));
    // The STEP file, the solid mesh, the error map (its last phase is `quality`) and the report.
    let converted = convert_held(&input, &step, &read, &opts, rep)?;
    let report = &converted.report;

    let report_path = part.join(format!("{stem}.report.json"));
    let report_json = serde_json::json!({
        "job_id": rec.id,
        "input": rec.input,
        "input_sha256": rec.input_sha256,
        "config_digest": job.config_digest,
        "daemon_version": env!("CARGO_PKG_VERSION"),
        "status": report.status,
        "convert": report,
    });
    // A solid that failed a quality gate is not published: the job goes to quarantine, and its artifacts and
    // report with it ([`quarantine_record`] moves them).
    if let Err(e) = report.verdict() {
        write_durable(&report_path, serde_json::to_string_pretty(&report_json).unwrap_or_default().as_bytes())
            .map_err(|e| io_err("cannot write", &report_path, e))?;
        return Err(e);
    }
    check_cancelled(rep)?;
    // A scan's bundle also holds its views, the fusion report and, when asked, the FEA: from what the
    // conversion held and the capture's log (handed over, or read after a restart).
    let mut extra = super::scan_bundle::Extras::default();
    if let Some(scan) = &rec.scan {
        let fea_span = (FEA_AT, PUBLISH_AT);
        let progress = |f: f64, phase: &str| rep.send(fea_span.0 + f * (fea_span.1 - fea_span.0), "fea", phase.into());
        let log = match &job.capture {
            Some(log) => log.clone(),
            None => super::scan::CaptureLog::read(&input)?,
        };
        let bundle = super::scan_bundle::ScanBundle { scan_dir: &input, part: &part, stem: &stem, scan, cfg };
        extra = super::scan_bundle::add(&bundle, &converted, &log, &progress)?;
        check_cancelled(rep)?;
    }
    rep.send(PUBLISH_AT, "publish", "publish/report and manifest".into());
    let report_digest =
        write_durable(&report_path, serde_json::to_string_pretty(&report_json).unwrap_or_default().as_bytes())
            .map_err(|e| io_err("cannot write", &report_path, e))?;
    let mut written = std::mem::take(&mut extra.digests);
    written.insert(report_path.clone(), report_digest);
    let mut files = vec![
        ("step", step.clone()),
        ("solid-mesh", report.solid_mesh_file.clone()),
        ("error-map", report.error_map_file.clone()),
        ("report", report_path),
    ];
    files.extend(extra.files.iter().cloned());
    for p in &report.pictures {
        written.insert(p.file.clone(), p.digest());
        files.push((p.kind, p.file.clone()));
    }
    // The page last before the manifest: it lists every other file of the bundle with its hash.
    let (page, page_digest) = crate::pipeline::report_html::write_report_html(&part)?;
    written.insert(page.clone(), page_digest);
    files.push((super::dbus::REPORT_HTML, page));
    let mut digests: BTreeMap<PathBuf, (u64, String)> =
        written.into_iter().map(|(p, d)| (p, (d.bytes, d.sha256))).collect();
    for (p, d) in [
        (&step, &converted.digests.step),
        (&report.solid_mesh_file, &converted.digests.solid_mesh),
        (&report.error_map_file, &converted.digests.error_map),
    ] {
        digests.insert(p.clone(), (d.bytes, d.sha256.clone()));
    }
    let files = files.into_iter().map(|(k, p)| (k.to_string(), p)).collect();
    Ok(Produced { files, digests, views_manifest: extra.views_manifest })
}

/// Publish what [`produce`] left: each file synced, the manifest (every file's size and hash), then one
/// rename of the part directory into the outbox. The outputs, kind → path.
///
/// # Errors
/// `resource.output`.
fn publish(job: &JobRun, produced: &Produced) -> Result<BTreeMap<String, String>, Error> {
    let rec = &job.record;
    let stem = rec.stem();
    let part = job.spool.outbox_part(&stem, &rec.id);
    let files = &produced.files;
    let mut manifest_files = serde_json::Map::new();
    for (kind, p) in files {
        let f = std::fs::File::open(p).map_err(|e| io_err("cannot reopen", p, e))?;
        f.sync_all().map_err(|e| io_err("cannot fsync", p, e))?;
        // The digests of the files the conversion and this job wrote were taken as they were written.
        let (bytes, sha256) = match produced.digests.get(p) {
            Some(d) => d.clone(),
            None => (f.metadata().map(|m| m.len()).unwrap_or(0), crate::pipeline::provenance::sha256_file(p)?),
        };
        manifest_files.insert(
            kind.to_string(),
            serde_json::json!({
                "file": p.file_name().map(|n| n.to_string_lossy().into_owned()),
                "bytes": bytes,
                "sha256": sha256,
            }),
        );
    }
    if let Some(views) = &produced.views_manifest {
        manifest_files.insert("views".into(), views.clone());
    }
    let manifest = serde_json::json!({
        "schema": 1,
        "job_id": rec.id,
        "input": rec.input,
        "input_sha256": rec.input_sha256,
        "config_digest": job.config_digest,
        "daemon_version": env!("CARGO_PKG_VERSION"),
        "finished_usec": now_usec(),
        "files": manifest_files,
    });
    let manifest_path = part.join("manifest.json");
    write_durable(&manifest_path, serde_json::to_string_pretty(&manifest).unwrap_or_default().as_bytes())
        .map_err(|e| io_err("cannot write", &manifest_path, e))?;
    let public = job.spool.outbox_dir(&stem, &rec.id);
    publish_dir(&part, &public).map_err(|e| io_err("cannot publish", &public, e))?;
    let mut outputs = BTreeMap::new();
    for (kind, p) in files.iter().map(|(k, p)| (k.clone(), p)).chain([("manifest".to_string(), &manifest_path)]) {
        outputs.insert(kind, public.join(p.file_name().unwrap_or_default()).display().to_string());
    }
    if produced.views_manifest.is_some() {
        outputs.insert("views".into(), public.join(super::scan_bundle::VIEWS_DIR).display().to_string());
    }
    Ok(outputs)
}

/// The `error.json` of a quarantined input.
pub fn error_json(rec: &JobRecord, digest: &str, stage: &str, e: &Error) -> serde_json::Value {
    serde_json::json!({
        "schema": 1,
        "job_id": rec.id,
        "input": rec.input,
        "sha256": rec.input_sha256,
        "stage": stage,
        "error_code": e.code.as_str(),
        "error_class": e.class(),
        "message": e.message,
        "hint": e.hint.clone().unwrap_or_else(|| default_hint(e.code).to_string()),
        "location": e.location,
        "daemon_version": env!("CARGO_PKG_VERSION"),
        "config_digest": digest,
        "submitted_usec": rec.submitted_usec,
        "started_usec": rec.start_usec,
        "finished_usec": now_usec(),
    })
}

fn default_hint(code: ErrorCode) -> &'static str {
    use ErrorCode::*;
    match code {
        InputUnknownFormat => "use PLY, OBJ, STL, OFF or XYZ (optionally .gz), E57, or a scan-set directory",
        InputDuplicate => "the same content was processed recently; see the earlier job named in the message",
        InputTooLarge => "raise limits.max_input_size or decimate the scan",
        ResourceMemoryBudget => "raise limits.memory_budget or lower the resolution (vertices)",
        Cancelled => "cancelled on request; drop the file into the inbox again to retry",
        Interrupted => "the daemon stopped while the job ran; drop the file into the inbox again to retry",
        InputBadArgument => "check the job options (sidecar NAME.job.toml or SubmitFile options)",
        _ => "check the input with `scanstation inspect`, or `scanstation repair` it first",
    }
}

/// Move the job's input (and sidecar) from `work/<id>/` to `quarantine/<stem>-<id>/` with `error.json`,
/// built under a hidden `.part` name and renamed.
///
/// # Errors
/// The I/O error as `resource.output`.
pub fn quarantine(job: &JobRun, e: &Error, stage: &str) -> Result<BTreeMap<String, String>, Error> {
    quarantine_record(&job.spool, &job.record, &job.config_digest, e, stage)
}

/// As [`quarantine`], from the record alone (also used at start-up for interrupted jobs).
///
/// # Errors
/// The I/O error as `resource.output`.
pub fn quarantine_record(
    spool: &Spool,
    rec: &JobRecord,
    digest: &str,
    e: &Error,
    stage: &str,
) -> Result<BTreeMap<String, String>, Error> {
    let stem = rec.stem();
    let part = spool.quarantine_part(&stem, &rec.id);
    let public = spool.quarantine_dir(&stem, &rec.id);
    // A solid that failed a quality gate keeps its artifacts (STEP, solid mesh, error map, report) beside
    // the input; any other half-built outbox directory of this job is removed.
    let out_part = spool.outbox_part(&stem, &rec.id);
    std::fs::create_dir_all(&part).map_err(|x| io_err("cannot create", &part, x))?;
    if out_part.exists() {
        if e.class() == crate::error::ErrorClass::Quality
            && let Ok(rd) = std::fs::read_dir(&out_part)
        {
            for f in rd.flatten().filter(|f| f.path().is_file()) {
                let to = part.join(f.file_name());
                std::fs::rename(f.path(), &to).map_err(|x| io_err("cannot move", &f.path(), x))?;
            }
        }
        let _ = std::fs::remove_dir_all(&out_part);
    }
    let work = spool.work_dir(&rec.id);
    if let Ok(rd) = std::fs::read_dir(&work) {
        for f in rd.flatten() {
            let to = part.join(f.file_name());
            std::fs::rename(f.path(), &to).map_err(|x| io_err("cannot move", &f.path(), x))?;
        }
    }
    let _ = std::fs::remove_dir(&work);
    let ej = part.join("error.json");
    write_durable(&ej, serde_json::to_string_pretty(&error_json(rec, digest, stage, e)).unwrap_or_default().as_bytes())
        .map_err(|x| io_err("cannot write", &ej, x))?;
    // The page that says why, with the pictures of a solid that missed a gate. An input is never held back
    // for want of its page: a failure is logged and the quarantine goes on.
    let page = match crate::pipeline::report_html::write_report_html(&part) {
        Ok((p, _)) => p.file_name().map(|n| public.join(n)),
        Err(x) => {
            tracing::warn!(job_id = %rec.id, error = %x, "the quarantine's report page was not written");
            None
        }
    };
    let thumbnail = std::fs::read_dir(&part)
        .ok()
        .and_then(|rd| rd.flatten().map(|f| f.file_name()).find(|n| n.to_string_lossy().ends_with(".thumbnail.png")));
    sync_dir(&part).map_err(|x| io_err("cannot fsync", &part, x))?;
    std::fs::rename(&part, &public).map_err(|x| io_err("cannot publish", &public, x))?;
    sync_dir(&spool.quarantine).map_err(|x| io_err("cannot fsync", &spool.quarantine, x))?;
    let mut o = BTreeMap::new();
    o.insert("quarantine".to_string(), public.display().to_string());
    o.insert("error".to_string(), public.join("error.json").display().to_string());
    if let Some(p) = page {
        o.insert(super::dbus::REPORT_HTML.to_string(), p.display().to_string());
    }
    if let Some(t) = thumbnail {
        o.insert(super::dbus::THUMBNAIL.to_string(), public.join(t).display().to_string());
    }
    Ok(o)
}

/// What a cluster node needs to convert a job exactly as the station would: its record and the station's
/// configuration text (`job.json` in the job's [`super::cluster::DIR`]).
#[derive(serde::Serialize, serde::Deserialize)]
pub struct NodeJob {
    /// The job's record.
    pub record: JobRecord,
    /// The station's configuration file's text, and its name.
    pub config: (String, String),
}

/// What a cluster node hands back (`result.json`).
#[derive(serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NodeResult {
    /// The bundle's files, before the manifest.
    Produced(Produced),
    /// The conversion's error, and the stage it ended in.
    Failed {
        /// Its stable code.
        code: String,
        /// Its message.
        message: String,
        /// Its hint.
        hint: Option<String>,
        /// The stage.
        stage: String,
    },
}

/// [`produce`] on the Slurm cluster (`[executor] kind = "slurm"`, [`super::cluster`]): the job submitted
/// (or followed, after a restart) and its progress handed on; the node's [`Produced`].
fn produce_on_cluster(job: &JobRun, rep: &Reporter<'_>) -> Result<Produced, Error> {
    let rec = &job.record;
    let work = job.spool.work_dir(&rec.id);
    let dir = work.join(super::cluster::DIR);
    let spec = NodeJob { record: rec.clone(), config: job.cfg.source.clone() };
    // The node names stages as text; ours are the static names.
    let stage_of = |name: &str| stages_of(rec).iter().copied().find(|s| *s == name).unwrap_or(job.stage);
    let progress = |fraction: f64, stage: &str, message: &str| rep.send(fraction, stage_of(stage), message.to_string());
    let journal = |run: &super::journal::ClusterRun| {
        let _ = job.events.send(WorkerEvent::Cluster { id: rec.id.clone(), run: run.clone() });
    };
    let follow = super::cluster::Follow {
        dir: &dir,
        work: &work,
        name: format!("scanstation-{}", rec.id),
        exec: &job.cfg.executor,
        mem_bytes: job.cfg.memory_budget,
        known: rec.cluster.clone(),
        cancel: &job.cancel,
        progress: &progress,
        journal: &journal,
    };
    let value = super::cluster::run(&follow, &serde_json::to_value(&spec).unwrap_or_default())?;
    let result: NodeResult = serde_json::from_value(value).map_err(|e| {
        Error::new(ErrorCode::ClusterFailed, format!("the cluster node's result is not one this station reads: {e}"))
    })?;
    match result {
        NodeResult::Produced(p) => Ok(p),
        NodeResult::Failed { code, message, hint, stage } => {
            let stage = stage_of(&stage);
            rep.send(0.0, stage, format!("{stage}/failed on the cluster"));
            let code = ErrorCode::parse(&code).unwrap_or(ErrorCode::ClusterFailed);
            let e = Error::new(code, message);
            Err(match hint {
                Some(h) => e.with_hint(h),
                None => e,
            })
        }
    }
}

/// The node's side of a cluster job (`scanstation cluster-run DIR`, DIR the job's [`super::cluster::DIR`]):
/// read `job.json`, convert as the station would ([`produce`], into the same part directory of the shared
/// spool), append progress to `progress.log`, write `result.json`.
///
/// # Errors
/// Only when `job.json` cannot be read or `result.json` not written; the conversion's own errors go into
/// `result.json`.
pub fn cluster_run(dir: &Path) -> Result<(), Error> {
    use std::io::Write;
    let job_file = dir.join("job.json");
    let bytes = std::fs::read(&job_file)
        .map_err(|e| Error::new(ErrorCode::InputNotFound, format!("{}: {e}", job_file.display())))?;
    let spec: NodeJob = serde_json::from_slice(&bytes)
        .map_err(|e| Error::new(ErrorCode::InputBadRecord, format!("{}: {e}", job_file.display())))?;
    let cfg = Config::parse(&spec.config.0, &spec.config.1)
        .map_err(|e| Error::new(ErrorCode::InputBadArgument, format!("the station's configuration: {e}")))?;
    let spool = Spool::open(&cfg.spool).map_err(|e| {
        Error::new(ErrorCode::ResourceOutput, format!("the spool on this node: {} ({})", e.path, e.reason))
    })?;
    let (tx, mut rx) = mpsc::unbounded_channel();
    let log_path = dir.join("progress.log");
    let mut log = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&log_path)
        .map_err(|e| io_err("cannot open", &log_path, e))?;
    let writer = std::thread::spawn(move || {
        while let Some(ev) = rx.blocking_recv() {
            if let WorkerEvent::Progress { fraction, stage, message, .. } = ev {
                let _ = writeln!(log, "{fraction}\t{stage}\t{}", message.replace(['\t', '\n'], " "));
            }
        }
    });
    let stage0 = stages_of(&spec.record)[0];
    let run = JobRun {
        config_digest: cfg.digest(),
        cfg: Arc::new(cfg),
        record: spec.record,
        spool,
        preset_error: None,
        cancel: Arc::new(AtomicBool::new(false)),
        proceed: Arc::new(tokio::sync::Notify::new()),
        heartbeat: Arc::new(AtomicU64::new(0)),
        events: tx,
        stage: if stage0 == "home" { "fuse" } else { stage0 },
        capture: None,
    };
    let span = if run.record.scan.is_some() { (CAPTURE_END, FEA_AT) } else { (0.0, PUBLISH_AT) };
    let reporter = Reporter { run: &run, state: Mutex::new((span.0, "")), span };
    let result = match produce(&run, &reporter) {
        Ok(p) => NodeResult::Produced(p),
        Err(e) => NodeResult::Failed {
            code: e.code.as_str().to_string(),
            message: e.message.clone(),
            hint: e.hint.clone(),
            stage: reporter.state.lock().map(|s| s.1).ok().filter(|s| !s.is_empty()).unwrap_or(run.stage).to_string(),
        },
    };
    // The progress channel closes with the run: the writer drains it and ends.
    drop(run);
    let _ = writer.join();
    let out = dir.join("result.json");
    write_durable(&out, serde_json::to_string_pretty(&result).unwrap_or_default().as_bytes())
        .map_err(|e| io_err("cannot write", &out, e))?;
    Ok(())
}

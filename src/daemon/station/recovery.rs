//! Recovery after a restart (also after `kill -9`), as a pure plan: from the journal's records and what the
//! spool holds ([`SpoolFacts`], gathered by [`gather`]) to a list of [`Action`]s the station carries out in
//! order ([`super::Station::recover`]).
//!
//! - a terminal record: its `work/<id>/` is removed; it is shown (and announced) only when its `Completed`
//!   was not yet emitted;
//! - a record `queued` or `running`: half-built `.part` directories are removed; then, if
//!   `outbox/<stem>-<id>/manifest.json` exists the job had published and is `succeeded`; if
//!   `quarantine/<stem>-<id>/` exists it had failed (with the code of its `error.json`, `interrupted` when
//!   unreadable; `cancelled` gives the state cancelled); if the claimed input is gone from `work/` it failed
//!   (`internal.bug`); a `running` one is quarantined as `interrupted` when `pipeline.resume` is off;
//!   otherwise it is queued again;
//! - a `work/<id>/` without a record (the crash came between the rename and the journal write) becomes a
//!   queued job again; one holding only a sidecar (or nothing) goes back to the inbox.
//!
//! So every claimed input ends in exactly one outbox or one quarantine directory.

use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};

use super::super::journal::{JobId, JobRecord, JobState};
use super::super::spool::{self, Spool};
use super::super::worker::{self, stages_of};
use crate::error::ErrorCode;

/// Whether `p` is an outbox part directory (`outbox/.<stem>-<id>.part`), not a quarantine's.
fn is_outbox_part(p: &Path) -> bool {
    p.parent().and_then(|d| d.file_name()).is_some_and(|n| n == "outbox")
}

/// What the spool holds for one job with a record.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SpoolFacts {
    /// Half-built `outbox/…part` and `quarantine/…part` directories of the job that exist.
    pub half_built: Vec<PathBuf>,
    /// `outbox/<stem>-<id>/manifest.json`, when it exists (the job had published).
    pub manifest: Option<PathBuf>,
    /// `quarantine/<stem>-<id>/` and the error code its `error.json` names (`None`: unreadable), when the
    /// directory exists.
    pub quarantine: Option<(PathBuf, Option<String>)>,
    /// The claimed input is still in `work/<id>/`.
    pub input_present: bool,
    /// What the published or quarantined bundle holds, kind → path: every file its manifest lists; a
    /// quarantine's page and thumbnail (so `ReportFile` and `Thumbnail` survive a crash after publication).
    pub outputs: std::collections::BTreeMap<String, String>,
}

/// A `work/<id>/` directory no record names, with the files in it.
#[derive(Clone, Debug, PartialEq)]
pub struct Orphan {
    /// The id its name carries.
    pub id: JobId,
    /// The directory.
    pub dir: PathBuf,
    /// The files in it.
    pub files: Vec<PathBuf>,
}

/// One step of the recovery, in the order of the plan.
#[derive(Clone, Debug, PartialEq)]
pub enum Action {
    /// Remove a directory tree (a terminal job's `work/<id>/`, a half-built directory).
    RemoveDir(PathBuf),
    /// Count this input's hash for de-duplication (first record of a hash wins).
    Seen {
        /// The input's hash.
        sha256: String,
        /// The job.
        id: JobId,
        /// When it was submitted, µs since the epoch.
        submitted_usec: u64,
    },
    /// Show the job (the record as planned); save it to the journal first when `save`; queue it when `queue`.
    Restore {
        /// The record as planned.
        rec: JobRecord,
        /// Save it to the journal first.
        save: bool,
        /// Queue it.
        queue: bool,
    },
    /// Quarantine the running job as `interrupted` (resume is off), then save and show it.
    Quarantine(JobRecord),
    /// Put these files back into the inbox and remove the empty `dir`.
    ReturnToInbox {
        /// The files (a sidecar at most).
        files: Vec<PathBuf>,
        /// The work directory to remove.
        dir: PathBuf,
    },
    /// Make a queued job of this claimed input that had no record (hash it, admit it, save, queue).
    Adopt {
        /// The id its directory carries.
        id: JobId,
        /// The claimed input.
        input: PathBuf,
    },
}

/// The facts for every record that is not terminal, and the orphan work directories, read from the spool.
/// Cost: a few `stat`s per record, one directory listing of `work/`.
pub fn gather(spool: &Spool, records: &[JobRecord]) -> (Vec<SpoolFacts>, Vec<Orphan>) {
    let facts = records
        .iter()
        .map(|rec| {
            if rec.state.is_terminal() {
                return SpoolFacts::default();
            }
            let stem = rec.stem();
            let half_built = [spool.outbox_part(&stem, &rec.id), spool.quarantine_part(&stem, &rec.id)]
                .into_iter()
                .filter(|p| p.exists())
                .collect();
            let manifest = Some(spool.outbox_dir(&stem, &rec.id).join("manifest.json")).filter(|m| m.exists());
            let q = spool.quarantine_dir(&stem, &rec.id);
            let quarantine = q.exists().then(|| {
                let code = std::fs::read(q.join("error.json"))
                    .ok()
                    .and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok())
                    .and_then(|v| v["error_code"].as_str().map(String::from));
                (q, code)
            });
            let outputs = bundle_outputs(manifest.as_deref(), quarantine.as_ref().map(|q| q.0.as_path()));
            let input_present = worker::input_path(spool, rec).exists();
            SpoolFacts { half_built, manifest, quarantine, input_present, outputs }
        })
        .collect();
    let known: HashSet<&JobId> = records.iter().map(|r| &r.id).collect();
    let mut orphans = Vec::new();
    if let Ok(rd) = std::fs::read_dir(&spool.work) {
        for d in rd.flatten() {
            let Some(id) = JobId::parse(&d.file_name().to_string_lossy()) else { continue };
            if known.contains(&id) {
                continue;
            }
            let files: Vec<PathBuf> =
                std::fs::read_dir(d.path()).map(|r| r.flatten().map(|f| f.path()).collect()).unwrap_or_default();
            orphans.push(Orphan { id, dir: d.path(), files });
        }
    }
    (facts, orphans)
}

/// The recovery plan for `records` (in journal order) with their `facts` (same order), then the `orphans`
/// (in id order). `resume` is `pipeline.resume`; `now_usec` stamps the jobs it ends; `work_dir` names a
/// job's `work/<id>/`.
pub fn plan(
    records: Vec<JobRecord>,
    facts: Vec<SpoolFacts>,
    mut orphans: Vec<Orphan>,
    resume: bool,
    now_usec: u64,
    work_dir: &dyn Fn(&JobId) -> PathBuf,
) -> Vec<Action> {
    let mut actions = Vec::new();
    for (mut rec, f) in records.into_iter().zip(facts) {
        let counts = match rec.state {
            JobState::Cancelled => false,
            JobState::Failed => rec.error_code != ErrorCode::Interrupted.as_str(),
            _ => true,
        };
        if counts && !rec.input_sha256.is_empty() {
            let (sha256, id, submitted_usec) = (rec.input_sha256.clone(), rec.id.clone(), rec.submitted_usec);
            actions.push(Action::Seen { sha256, id, submitted_usec });
        }
        if rec.state.is_terminal() {
            actions.push(Action::RemoveDir(work_dir(&rec.id)));
            if !rec.announced {
                actions.push(Action::Restore { rec, save: false, queue: false });
            }
            continue;
        }
        // A conversion on the cluster goes on while the station is down: its bundle's part directory is the
        // node's to finish (the job is followed again below).
        let on_cluster = rec.cluster.is_some();
        actions.extend(f.half_built.into_iter().filter(|p| !(on_cluster && is_outbox_part(p))).map(Action::RemoveDir));
        if let Some(manifest) = f.manifest {
            rec.state = JobState::Succeeded;
            rec.finish_usec = now_usec;
            rec.outputs.extend(f.outputs);
            rec.outputs.insert("manifest".into(), manifest.display().to_string());
            actions.push(Action::RemoveDir(work_dir(&rec.id)));
            actions.push(Action::Restore { rec, save: true, queue: false });
        } else if let Some((dir, code)) = f.quarantine {
            let code = code.unwrap_or_else(|| ErrorCode::Interrupted.as_str().into());
            rec.state = if code == "cancelled" { JobState::Cancelled } else { JobState::Failed };
            rec.error_code = code;
            rec.finish_usec = now_usec;
            rec.outputs.extend(f.outputs);
            rec.outputs.insert("quarantine".into(), dir.display().to_string());
            actions.push(Action::RemoveDir(work_dir(&rec.id)));
            actions.push(Action::Restore { rec, save: true, queue: false });
        } else if !f.input_present {
            rec.state = JobState::Failed;
            rec.error_code = ErrorCode::InternalBug.as_str().into();
            rec.message = "the claimed input vanished from work/".into();
            rec.finish_usec = now_usec;
            actions.push(Action::Restore { rec, save: true, queue: false });
        } else if rec.state == JobState::Running && !resume && !on_cluster {
            actions.push(Action::Quarantine(rec));
        } else {
            rec.state = JobState::Queued;
            rec.stage = stages_of(&rec)[0].into();
            actions.push(Action::Restore { rec, save: true, queue: true });
        }
    }
    orphans.sort_by(|a, b| a.id.cmp(&b.id));
    for o in orphans {
        match o.files.iter().find(|f| !f.to_string_lossy().ends_with(spool::SIDECAR_SUFFIX)) {
            Some(input) => actions.push(Action::Adopt { id: o.id, input: input.clone() }),
            // Only a sidecar or nothing: the input was never moved; put a sidecar back.
            None => actions.push(Action::ReturnToInbox { files: o.files, dir: o.dir }),
        }
    }
    // Orphans are adopted after every record's action (as the journal records come first).
    let (adopt, rest): (Vec<Action>, Vec<Action>) =
        actions.into_iter().partition(|a| matches!(a, Action::Adopt { .. }));
    rest.into_iter().chain(adopt).collect()
}

/// The de-duplication table the plan's [`Action::Seen`] entries build: sha256 → (first job, submitted µs).
pub fn seen_table(actions: &[Action]) -> HashMap<String, (JobId, u64)> {
    let mut seen = HashMap::new();
    for a in actions {
        if let Action::Seen { sha256, id, submitted_usec } = a {
            seen.entry(sha256.clone()).or_insert((id.clone(), *submitted_usec));
        }
    }
    seen
}

/// The outputs a finished bundle names: a published one's manifest files (kind → path), a quarantine's page
/// (`report-html`) and thumbnail.
fn bundle_outputs(manifest: Option<&Path>, quarantine: Option<&Path>) -> std::collections::BTreeMap<String, String> {
    let mut out = std::collections::BTreeMap::new();
    if let Some(m) = manifest {
        let dir = m.parent().unwrap_or(Path::new("."));
        let v = std::fs::read(m).ok().and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok());
        for (kind, f) in v.as_ref().and_then(|v| v["files"].as_object()).into_iter().flatten() {
            if let Some(name) = f["file"].as_str() {
                out.insert(kind.clone(), dir.join(name).display().to_string());
            }
        }
    }
    if let Some(q) = quarantine
        && let Ok(rd) = std::fs::read_dir(q)
    {
        for name in rd.flatten().map(|e| e.file_name().to_string_lossy().into_owned()) {
            let kind = if name.ends_with(".report.html") {
                super::super::dbus::REPORT_HTML
            } else if name.ends_with(".thumbnail.png") {
                super::super::dbus::THUMBNAIL
            } else {
                continue;
            };
            out.insert(kind.to_string(), q.join(name).display().to_string());
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::daemon::config::JobOptions;
    use crate::daemon::journal::SCHEMA;
    use std::collections::BTreeMap;

    fn rec(id: &str, state: JobState) -> JobRecord {
        JobRecord {
            schema: SCHEMA,
            id: JobId(id.into()),
            input: "scan.ply".into(),
            source: "inbox".into(),
            input_sha256: format!("sha-{id}"),
            input_size: 10,
            options: JobOptions::default(),
            state,
            stage: "remesh".into(),
            submitted_usec: 5,
            start_usec: 0,
            finish_usec: 0,
            runs: 1,
            error_code: String::new(),
            message: String::new(),
            outputs: BTreeMap::new(),
            peak_memory: 0,
            announced: false,
            scan: None,
            cluster: None,
        }
    }

    fn work(id: &JobId) -> PathBuf {
        PathBuf::from(format!("/spool/work/{id}"))
    }

    fn present() -> SpoolFacts {
        SpoolFacts { input_present: true, ..Default::default() }
    }

    /// The plan for one record with its facts, without the `Seen` entries.
    fn one(r: JobRecord, f: SpoolFacts, resume: bool) -> Vec<Action> {
        plan(vec![r], vec![f], Vec::new(), resume, 99, &work)
            .into_iter()
            .filter(|a| !matches!(a, Action::Seen { .. }))
            .collect()
    }

    fn restored(actions: &[Action]) -> (&JobRecord, bool, bool) {
        match actions.iter().find_map(|a| match a {
            Action::Restore { rec, save, queue } => Some((rec, *save, *queue)),
            _ => None,
        }) {
            Some(r) => r,
            None => panic!("no Restore in {actions:#?}"),
        }
    }

    #[test]
    fn a_terminal_record_loses_its_work_dir_and_is_shown_only_until_announced() {
        let mut r = rec("A", JobState::Succeeded);
        let a = one(r.clone(), SpoolFacts::default(), true);
        assert_eq!(a[0], Action::RemoveDir(work(&r.id)));
        let (shown, save, queue) = restored(&a);
        assert_eq!((shown.state, save, queue), (JobState::Succeeded, false, false));
        r.announced = true;
        assert_eq!(one(r.clone(), SpoolFacts::default(), true), vec![Action::RemoveDir(work(&r.id))]);
    }

    /// A job converting on the cluster when the station died keeps its outbox part directory (the node is
    /// writing it) and is followed again, even with `resume` off; its quarantine part is removed.
    #[test]
    fn a_job_on_the_cluster_keeps_its_part_directory_and_is_followed_again() {
        let mut r = rec("A", JobState::Running);
        r.cluster = Some(crate::daemon::journal::ClusterRun { slurm_id: 7, submissions: 1 });
        let parts = vec![PathBuf::from("/spool/outbox/.scan-A.part"), PathBuf::from("/spool/quarantine/.scan-A.part")];
        let f = SpoolFacts { half_built: parts.clone(), ..present() };
        let a = one(r.clone(), f.clone(), false);
        assert!(!a.contains(&Action::RemoveDir(parts[0].clone())), "{a:#?}");
        assert!(a.contains(&Action::RemoveDir(parts[1].clone())), "{a:#?}");
        let (back, _, queue) = restored(&a);
        assert!(queue && back.cluster.is_some(), "{a:#?}");
        // Not on the cluster: both go, and with resume off it is quarantined.
        r.cluster = None;
        let a = one(r, f, false);
        assert!(a.contains(&Action::RemoveDir(parts[0].clone())), "{a:#?}");
        assert!(a.iter().any(|x| matches!(x, Action::Quarantine(_))), "{a:#?}");
    }

    #[test]
    fn a_published_job_is_succeeded_with_its_manifest() {
        let f = SpoolFacts { manifest: Some("/spool/outbox/scan-A/manifest.json".into()), ..present() };
        let a = one(rec("A", JobState::Running), f, true);
        let (r, save, queue) = restored(&a);
        assert_eq!((r.state, r.finish_usec, save, queue), (JobState::Succeeded, 99, true, false));
        assert_eq!(r.outputs["manifest"], "/spool/outbox/scan-A/manifest.json");
        assert!(a.contains(&Action::RemoveDir(work(&r.id))), "{a:#?}");
    }

    #[test]
    fn a_quarantined_job_takes_the_code_of_its_error_file() {
        for (code, state, want) in [
            (Some("remesh.failed"), JobState::Failed, "remesh.failed"),
            (Some("cancelled"), JobState::Cancelled, "cancelled"),
            (None, JobState::Failed, "interrupted"),
        ] {
            let f = SpoolFacts {
                quarantine: Some(("/spool/quarantine/scan-A".into(), code.map(String::from))),
                ..present()
            };
            let a = one(rec("A", JobState::Running), f, true);
            let (r, save, _) = restored(&a);
            assert_eq!((r.state, r.error_code.as_str(), save), (state, want, true), "code {code:?}");
            assert_eq!(r.outputs["quarantine"], "/spool/quarantine/scan-A");
        }
    }

    #[test]
    fn a_job_whose_input_vanished_fails_as_a_bug() {
        let a = one(rec("A", JobState::Queued), SpoolFacts::default(), true);
        let (r, save, queue) = restored(&a);
        assert_eq!((r.state, r.error_code.as_str(), save, queue), (JobState::Failed, "internal.bug", true, false));
    }

    #[test]
    fn a_running_job_is_requeued_with_resume_and_quarantined_without() {
        let a = one(rec("A", JobState::Running), present(), true);
        let (r, save, queue) = restored(&a);
        assert_eq!(
            (r.state, r.stage.as_str(), save, queue),
            (JobState::Queued, crate::daemon::worker::STAGES[0], true, true)
        );
        let a = one(rec("A", JobState::Running), present(), false);
        assert!(matches!(&a[..], [Action::Quarantine(r)] if r.id.0 == "A"), "{a:#?}");
        // A queued job is queued again either way.
        let a = one(rec("B", JobState::Queued), present(), false);
        assert!(restored(&a).2);
    }

    #[test]
    fn half_built_directories_go_first() {
        let f = SpoolFacts { half_built: vec!["/spool/outbox/.scan-A.part".into()], ..present() };
        let a = one(rec("A", JobState::Running), f, true);
        assert_eq!(a[0], Action::RemoveDir("/spool/outbox/.scan-A.part".into()));
        assert!(restored(&a).2);
    }

    #[test]
    fn orphans_are_adopted_in_id_order_after_the_records_or_go_back_to_the_inbox() {
        let orphans = vec![
            Orphan { id: JobId("C".into()), dir: "/w/C".into(), files: vec!["/w/C/b.ply".into()] },
            Orphan { id: JobId("B".into()), dir: "/w/B".into(), files: vec!["/w/B/a.ply.job.toml".into()] },
            Orphan {
                id: JobId("A".into()),
                dir: "/w/A".into(),
                files: vec!["/w/A/a.job.toml".into(), "/w/A/a.ply".into()],
            },
        ];
        let a = plan(vec![rec("Z", JobState::Queued)], vec![present()], orphans, true, 99, &work);
        let kinds: Vec<String> = a
            .iter()
            .map(|x| match x {
                Action::Seen { id, .. } => format!("seen {id}"),
                Action::Restore { rec, .. } => format!("restore {}", rec.id),
                Action::Adopt { id, input } => format!("adopt {id} {}", input.display()),
                Action::ReturnToInbox { dir, .. } => format!("return {}", dir.display()),
                other => format!("{other:?}"),
            })
            .collect();
        assert_eq!(kinds, ["seen Z", "restore Z", "return /w/B", "adopt A /w/A/a.ply", "adopt C /w/C/b.ply"]);
    }

    #[test]
    fn only_counting_records_enter_the_dedupe_table_first_one_winning() {
        let mut failed = rec("B", JobState::Failed);
        failed.error_code = "interrupted".into();
        let mut cancelled = rec("C", JobState::Cancelled);
        cancelled.input_sha256 = "sha-A".into();
        let mut again = rec("D", JobState::Succeeded);
        again.input_sha256 = "sha-A".into();
        let records = vec![rec("A", JobState::Succeeded), failed, cancelled, again];
        let facts = vec![SpoolFacts::default(); 4];
        let seen = seen_table(&plan(records, facts, Vec::new(), true, 1, &work));
        assert_eq!(seen.len(), 1, "{seen:?}");
        assert_eq!(seen["sha-A"].0, JobId("A".into()));
    }
}

//! A job's conversion on a Slurm cluster, the station's side (`[executor] kind = "slurm"`): submit, follow,
//! cancel, and read the outcome; the node's side is `scanstation cluster-run` (the worker's `cluster_run`).
//!
//! The job's work directory (on the spool, which every node mounts at the same path) holds [`DIR`]:
//! `job.json` (the job's record and the station's configuration text: the node converts exactly as the
//! station would), `progress.log` (one line per progress report, `fraction⇥stage⇥message`, appended by the
//! node and followed here), `result.json` (what the node produced, or its error with code and stage) and
//! Slurm's `slurm-<id>.out`.
//!
//! 1. **Find or submit.** A journaled Slurm id is followed; without one, a job named `scanstation-<job id>`
//!    in the queue or in the completion log (`sacct --completion`) is adopted (the daemon died between
//!    `sbatch` and its journal); only then is one submitted: `sbatch --parsable --no-requeue --job-name
//!    --chdir --output --mem (the job's memory budget) --time --cpus-per-task [--partition] [--account]
//!    [sbatch_args] --wrap "exec BINARY cluster-run DIR"`. The id is journaled at once (`journal`).
//! 2. **Follow** every `poll`: new progress lines are handed on; a cancel is `scancel`; the state is read with
//!    `squeue`, and once the job has left the queue, with `scontrol show job` (or `sacct --completion`).
//! 3. **The outcome** ([`outcome_of`]): `COMPLETED` → the node's `result.json`; `OUT_OF_MEMORY` →
//!    `resource.memory`; `TIMEOUT` → `resource.time`; `CANCELLED` not by the station →
//!    `cluster.cancelled`; `NODE_FAIL` → submitted once more, then `cluster.node-failed`; anything else, or
//!    a node program that died without a result → `cluster.failed` with Slurm's words and the output's tail.

use std::io::{BufRead, Seek};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::{AtomicBool, Ordering};

use super::executor::ExecutorConfig;
use super::journal::ClusterRun;
use crate::error::{Error, ErrorCode};

/// The cluster files' directory inside a job's `work/<id>/`.
pub const DIR: &str = ".slurm";

/// What following a cluster job needs.
pub struct Follow<'a> {
    /// `work/<id>/.slurm`.
    pub dir: &'a Path,
    /// `work/<id>` (the job's `--chdir`).
    pub work: &'a Path,
    /// The Slurm job name: `scanstation-<job id>`.
    pub name: String,
    /// `[executor]`.
    pub exec: &'a ExecutorConfig,
    /// The job's memory budget, bytes (`--mem`).
    pub mem_bytes: u64,
    /// The run the journal holds, if any.
    pub known: Option<ClusterRun>,
    /// Set when the job is cancelled.
    pub cancel: &'a AtomicBool,
    /// Progress from the node: (fraction 0–1 overall, stage, message).
    pub progress: &'a (dyn Fn(f64, &str, &str) + Sync),
    /// Journal a (new) submission.
    pub journal: &'a (dyn Fn(&ClusterRun) + Sync),
}

/// Run a Slurm command with `args`; its stdout.
///
/// # Errors
/// `cluster.failed` naming the command and its stderr (or that it is missing).
fn slurm(cmd: &str, args: &[&str]) -> Result<String, Error> {
    let out = Command::new(cmd).args(args).output().map_err(|e| {
        Error::new(ErrorCode::ClusterFailed, format!("cannot run {cmd}: {e}"))
            .with_hint("install Slurm's client commands (Debian: slurm-client) and set SLURM_CONF for the daemon")
    })?;
    if !out.status.success() {
        return Err(Error::new(
            ErrorCode::ClusterFailed,
            format!("{cmd} {} failed: {}", args.join(" "), String::from_utf8_lossy(&out.stderr).trim()),
        ));
    }
    Ok(String::from_utf8_lossy(&out.stdout).into_owned())
}

/// `s` quoted for a POSIX shell.
fn shell_quote(s: &str) -> String {
    format!("'{}'", s.replace('\'', "'\\''"))
}

/// The `sbatch` arguments for a submission.
pub fn sbatch_args(f: &Follow<'_>) -> Vec<String> {
    let e = f.exec;
    let mut a = vec![
        "--parsable".to_string(),
        "--no-requeue".into(),
        format!("--job-name={}", f.name),
        format!("--chdir={}", f.work.display()),
        format!("--output={}", f.dir.join("slurm-%j.out").display()),
        format!("--mem={}M", f.mem_bytes.div_ceil(1 << 20).max(1)),
        format!("--time={}", e.time_limit_min),
        format!("--cpus-per-task={}", e.cpus),
    ];
    if !e.partition.is_empty() {
        a.push(format!("--partition={}", e.partition));
    }
    if !e.account.is_empty() {
        a.push(format!("--account={}", e.account));
    }
    a.extend(e.sbatch_args.iter().cloned());
    let run = format!(
        "exec {} cluster-run {}",
        shell_quote(&e.binary.display().to_string()),
        shell_quote(&f.dir.display().to_string())
    );
    a.push(format!("--wrap={run}"));
    a
}

/// Submit: clear the last run's progress and result, `sbatch`; the Slurm id.
fn submit(f: &Follow<'_>) -> Result<u64, Error> {
    for old in ["progress.log", "result.json"] {
        let _ = std::fs::remove_file(f.dir.join(old));
    }
    let args = sbatch_args(f);
    let refs: Vec<&str> = args.iter().map(String::as_str).collect();
    let out = slurm("sbatch", &refs)?;
    let id =
        out.trim().split(';').next().unwrap_or("").parse::<u64>().map_err(|_| {
            Error::new(ErrorCode::ClusterFailed, format!("sbatch answered {:?}, not a job id", out.trim()))
        })?;
    tracing::info!(slurm_id = id, name = %f.name, "submitted to the cluster");
    Ok(id)
}

/// A job of this name the cluster knows (queued, running, or in its completion log): its id, the newest.
fn find_by_name(name: &str) -> Option<u64> {
    let queued = slurm("squeue", &["-h", "--name", name, "-o", "%i|%j"]).ok();
    // The completion log does not filter by name (`--name` is ignored with `--completion`): filtered here.
    let done = || slurm("sacct", &["--completion", "-n", "-P", "-o", "jobid,jobname"]).ok();
    let ids = |s: String| {
        s.lines()
            .filter_map(|l| l.trim().split_once('|'))
            .filter(|(_, n)| *n == name)
            .filter_map(|(id, _)| id.parse::<u64>().ok())
            .max()
    };
    queued.and_then(ids).or_else(|| done().and_then(ids))
}

/// The job's state while Slurm's queue lists it (`None` once it has left).
fn queue_state(id: u64) -> Option<String> {
    let s = slurm("squeue", &["-h", "-j", &id.to_string(), "-o", "%T"]).ok()?;
    let s = s.trim().to_string();
    (!s.is_empty()).then_some(s)
}

/// A finished job's state and reason: `scontrol show job` while the controller remembers it, else the
/// completion log.
fn final_state(id: u64) -> Option<(String, String)> {
    if let Ok(s) = slurm("scontrol", &["show", "job", "-o", &id.to_string()]) {
        let field =
            |k: &str| s.split_whitespace().find_map(|w| w.strip_prefix(k)).map(str::to_string).unwrap_or_default();
        let state = field("JobState=");
        if !state.is_empty() {
            return Some((state, field("Reason=")));
        }
    }
    let s = slurm("sacct", &["--completion", "-n", "-P", "-j", &id.to_string(), "-o", "state"]).ok()?;
    s.lines().last().map(|l| (l.split_whitespace().next().unwrap_or("").to_string(), String::new()))
}

/// States after which a job runs no more.
const ENDED: [&str; 10] = [
    "COMPLETED",
    "FAILED",
    "CANCELLED",
    "TIMEOUT",
    "OUT_OF_MEMORY",
    "NODE_FAIL",
    "BOOT_FAIL",
    "DEADLINE",
    "PREEMPTED",
    "SPECIAL_EXIT",
];

/// What a finished job's state means.
#[derive(Debug, PartialEq)]
pub enum Outcome {
    /// The node program ran to its end: read its result.
    Result,
    /// The node failed: submit again (once).
    NodeFailed,
    /// An error.
    Failed(ErrorCode, String),
}

/// The outcome of a job that ended in `state` (Slurm's words, with `reason`).
pub fn outcome_of(state: &str, reason: &str) -> Outcome {
    let words = if reason.is_empty() || reason == "None" { state.to_string() } else { format!("{state} ({reason})") };
    match state.split_whitespace().next().unwrap_or("") {
        "COMPLETED" => Outcome::Result,
        "NODE_FAIL" => Outcome::NodeFailed,
        "OUT_OF_MEMORY" => Outcome::Failed(
            ErrorCode::ResourceMemoryBudget,
            format!("the cluster stopped the job at its memory limit (the job's budget): {words}"),
        ),
        "TIMEOUT" | "DEADLINE" => {
            Outcome::Failed(ErrorCode::ResourceTime, format!("the cluster stopped the job at its time limit: {words}"))
        }
        "CANCELLED" => Outcome::Failed(
            ErrorCode::ClusterCancelled,
            format!("the cluster job was cancelled outside the station: {words}"),
        ),
        // A node program that exits non-zero died without writing its result (a crash, a kill).
        "FAILED" => Outcome::Result,
        _ => Outcome::Failed(ErrorCode::ClusterFailed, format!("the cluster job ended {words}")),
    }
}

/// Hand on the progress lines the node appended since `offset`; the new offset.
fn forward_progress(f: &Follow<'_>, offset: u64) -> u64 {
    let Ok(mut file) = std::fs::File::open(f.dir.join("progress.log")) else { return offset };
    if file.seek(std::io::SeekFrom::Start(offset)).is_err() {
        return offset;
    }
    let mut reader = std::io::BufReader::new(file);
    let mut at = offset;
    let mut line = String::new();
    while reader.read_line(&mut line).unwrap_or(0) > 0 {
        if !line.ends_with('\n') {
            break; // a line still being written: read it next time
        }
        at += line.len() as u64;
        let mut parts = line.trim_end().splitn(3, '\t');
        if let (Some(fr), Some(stage), Some(msg)) = (parts.next(), parts.next(), parts.next())
            && let Ok(fr) = fr.parse::<f64>()
        {
            (f.progress)(fr, stage, msg);
        }
        line.clear();
    }
    at
}

/// The last lines of the job's Slurm output, for an error message.
fn output_tail(dir: &Path, id: u64) -> String {
    let text = std::fs::read_to_string(dir.join(format!("slurm-{id}.out"))).unwrap_or_default();
    let lines: Vec<&str> = text.lines().rev().take(5).collect();
    lines.into_iter().rev().collect::<Vec<_>>().join(" | ")
}

/// Run the job on the cluster to its end (see the module docs): the node's `result.json`.
///
/// # Errors
/// `cancelled` (after `scancel`), the codes of [`outcome_of`], `cluster.failed` when `sbatch` refuses or the
/// node left no result.
pub fn run(f: &Follow<'_>, spec: &serde_json::Value) -> Result<serde_json::Value, Error> {
    std::fs::create_dir_all(f.dir)
        .map_err(|e| Error::new(ErrorCode::ResourceOutput, format!("cannot create {}: {e}", f.dir.display())))?;
    let job_file = f.dir.join("job.json");
    // 1. The journaled job, one of this name, or a new submission.
    let mut run = match f
        .known
        .clone()
        .or_else(|| find_by_name(&f.name).map(|id| ClusterRun { slurm_id: id, submissions: 1 }))
    {
        Some(r) => {
            tracing::info!(slurm_id = r.slurm_id, "following the cluster job submitted before");
            r
        }
        None => {
            super::durable::write_durable(&job_file, serde_json::to_string_pretty(spec).unwrap_or_default().as_bytes())
                .map_err(|e| {
                    Error::new(ErrorCode::ResourceOutput, format!("cannot write {}: {e}", job_file.display()))
                })?;
            ClusterRun { slurm_id: submit(f)?, submissions: 1 }
        }
    };
    (f.journal)(&run);
    let mut offset = 0;
    let mut cancelled = false;
    loop {
        // 2. Progress, a cancel, the state.
        offset = forward_progress(f, offset);
        if f.cancel.load(Ordering::Relaxed) && !cancelled {
            cancelled = true;
            tracing::info!(slurm_id = run.slurm_id, "cancel: scancel");
            slurm("scancel", &[&run.slurm_id.to_string()])?;
        }
        let queued = queue_state(run.slurm_id);
        if queued.as_deref().is_some_and(|s| !ENDED.contains(&s)) {
            std::thread::sleep(f.exec.poll);
            continue;
        }
        // 3. It has ended: the last progress lines, then the outcome.
        forward_progress(f, offset);
        let (state, reason) = final_state(run.slurm_id).unwrap_or_else(|| (queued.unwrap_or_default(), String::new()));
        if cancelled {
            return Err(Error::new(
                ErrorCode::Cancelled,
                format!("cancelled on the cluster (job {}: {state})", run.slurm_id),
            ));
        }
        match outcome_of(&state, &reason) {
            Outcome::Result => return read_result(f.dir, run.slurm_id, &state),
            Outcome::NodeFailed if run.submissions < 2 => {
                tracing::warn!(slurm_id = run.slurm_id, "the node failed; submitting once more");
                run = ClusterRun { slurm_id: submit(f)?, submissions: run.submissions + 1 };
                (f.journal)(&run);
                offset = 0;
            }
            Outcome::NodeFailed => {
                return Err(Error::new(
                    ErrorCode::ClusterNodeFailed,
                    format!("the cluster node failed twice (jobs … {}): {state} {reason}", run.slurm_id),
                ));
            }
            Outcome::Failed(code, words) => {
                return Err(Error::new(code, format!("{words} (Slurm job {})", run.slurm_id)));
            }
        }
    }
}

/// The node's `result.json`.
fn read_result(dir: &Path, id: u64, state: &str) -> Result<serde_json::Value, Error> {
    let path: PathBuf = dir.join("result.json");
    let bytes = std::fs::read(&path).map_err(|_| {
        Error::new(
            ErrorCode::ClusterFailed,
            format!("the cluster job {id} ended {state} without a result: {}", output_tail(dir, id)),
        )
    })?;
    serde_json::from_slice(&bytes)
        .map_err(|e| Error::new(ErrorCode::ClusterFailed, format!("the result of cluster job {id} is unreadable: {e}")))
}

/// Check, at start-up, that the cluster can reach the spool: Slurm's commands answer, and the spool is on a
/// network file system (NFS, SMB, Ceph, Lustre, GPFS, BeeGFS, 9p, FUSE) or every node of the partition is
/// this host. Returns what was found, for the log.
///
/// # Errors
/// A message saying what is missing: the commands, or a spool only this host sees.
pub fn check_shared_spool(spool: &Path, exec: &ExecutorConfig) -> Result<String, String> {
    let version = slurm("sbatch", &["--version"]).map_err(|e| e.message)?;
    let fs = filesystem_of(spool).unwrap_or_else(|| "unknown".into());
    const NETWORK: [&str; 12] =
        ["nfs", "nfs4", "cifs", "smb3", "ceph", "lustre", "gpfs", "beegfs", "9p", "fuse", "fuse.sshfs", "glusterfs"];
    if NETWORK.iter().any(|n| fs == *n || fs.starts_with("fuse.")) {
        return Ok(format!("{}; spool on {fs}", version.trim()));
    }
    let mut args = vec!["-h", "-N", "-o", "%N"];
    if !exec.partition.is_empty() {
        args.extend(["-p", exec.partition.as_str()]);
    }
    let nodes = slurm("sinfo", &args).map_err(|e| e.message)?;
    let host = std::fs::read_to_string("/proc/sys/kernel/hostname").unwrap_or_default().trim().to_string();
    let short = host.split('.').next().unwrap_or("").to_string();
    let mut names: Vec<&str> = nodes.lines().map(str::trim).filter(|l| !l.is_empty()).collect();
    names.dedup();
    if !names.is_empty() && names.iter().all(|n| *n == short || *n == host || *n == "localhost") {
        return Ok(format!("{}; spool on {fs}, and the cluster's one node is this host", version.trim()));
    }
    Err(format!(
        "the spool {} is on a local file system ({fs}), but the cluster's nodes are {}: mount the spool at the same path on every node (NFS, Lustre, …)",
        spool.display(),
        names.join(", ")
    ))
}

/// The file system type of the mount holding `path` (`/proc/self/mountinfo`, the longest mount point that
/// prefixes it).
fn filesystem_of(path: &Path) -> Option<String> {
    let path = std::fs::canonicalize(path).ok()?;
    let info = std::fs::read_to_string("/proc/self/mountinfo").ok()?;
    let mut best: Option<(usize, String)> = None;
    for line in info.lines() {
        let fields: Vec<&str> = line.split_whitespace().collect();
        let (Some(mount), Some(sep)) = (fields.get(4), fields.iter().position(|f| *f == "-")) else { continue };
        let Some(fstype) = fields.get(sep + 1) else { continue };
        if path.starts_with(mount) && best.as_ref().is_none_or(|(len, _)| mount.len() > *len) {
            best = Some((mount.len(), fstype.to_string()));
        }
    }
    best.map(|b| b.1)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The file system of a path is its longest mount point's (the root's for a path nothing else holds).
    #[test]
    fn the_spools_file_system_is_read_from_mountinfo() {
        let root = filesystem_of(Path::new("/")).expect("/ is mounted");
        assert!(!root.is_empty());
        let proc_fs = filesystem_of(Path::new("/proc/self")).expect("/proc is mounted");
        assert_eq!(proc_fs, "proc");
    }

    #[test]
    fn slurm_states_map_to_codes() {
        assert_eq!(outcome_of("COMPLETED", "None"), Outcome::Result);
        assert_eq!(outcome_of("NODE_FAIL", "NodeDown"), Outcome::NodeFailed);
        let code = |s: &str| match outcome_of(s, "") {
            Outcome::Failed(c, _) => Some(c),
            _ => None,
        };
        assert_eq!(code("OUT_OF_MEMORY"), Some(ErrorCode::ResourceMemoryBudget));
        assert_eq!(code("TIMEOUT"), Some(ErrorCode::ResourceTime));
        assert_eq!(code("CANCELLED by 0"), Some(ErrorCode::ClusterCancelled));
        assert_eq!(code("BOOT_FAIL"), Some(ErrorCode::ClusterFailed));
    }

    #[test]
    fn the_submission_names_the_job_and_its_budget() {
        let exec =
            ExecutorConfig { partition: "scan".into(), sbatch_args: vec!["--qos=low".into()], ..Default::default() };
        let cancel = AtomicBool::new(false);
        let f = Follow {
            dir: Path::new("/spool/work/J1/.slurm"),
            work: Path::new("/spool/work/J1"),
            name: "scanstation-J1".into(),
            exec: &exec,
            mem_bytes: 3 << 30,
            known: None,
            cancel: &cancel,
            progress: &|_, _, _| {},
            journal: &|_| {},
        };
        let a = sbatch_args(&f);
        for want in
            ["--job-name=scanstation-J1", "--mem=3072M", "--time=60", "--partition=scan", "--qos=low", "--no-requeue"]
        {
            assert!(a.iter().any(|x| x == want), "{want} in {a:?}");
        }
        assert_eq!(a.last().unwrap(), "--wrap=exec '/usr/bin/scanstation' cluster-run '/spool/work/J1/.slurm'");
        assert_eq!(shell_quote("it's"), "'it'\\''s'");
    }
}

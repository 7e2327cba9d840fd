//! Conversions on a real Slurm cluster (`[executor] kind = "slurm"`): Debian's munge, slurmctld and slurmd
//! started as a one-node cluster on this machine by `scripts/slurm-cluster.sh` (no systemd), the real
//! `scanstationd` on a private bus, jobs submitted with `sbatch` as `scanstation cluster-run`.
//!
//! Needs Debian's munge, slurmctld, slurmd and slurm-client (`bash scripts/slurm-cluster.sh install`), plus
//! what the daemon tests need; a missing tool fails the test with the package to install. Needs root (slurmd
//! runs the jobs). The tests share the machine's one node, so they take turns.

mod common;
mod harness;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use harness::*;

/// One cluster at a time on this machine.
static TURN: Mutex<()> = Mutex::new(());

/// A one-node cluster under `dir`, stopped when dropped.
struct Cluster {
    dir: PathBuf,
}

impl Cluster {
    fn start(dir: &Path) -> Cluster {
        for (tool, package) in
            [("munged", "munge"), ("slurmctld", "slurmctld"), ("slurmd", "slurmd"), ("sbatch", "slurm-client")]
        {
            need(tool, package);
        }
        let dir = dir.join("slurm");
        let out = Command::new("bash").arg(script()).args(["start", dir.to_str().unwrap()]).output().unwrap();
        assert!(
            out.status.success(),
            "the one-node cluster did not start: {}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        Cluster { dir }
    }

    fn conf(&self) -> String {
        self.dir.join("slurm.conf").display().to_string()
    }

    /// A Slurm command's output, with this cluster's configuration.
    fn slurm(&self, cmd: &str, args: &[&str]) -> String {
        let out = Command::new(cmd).args(args).env("SLURM_CONF", self.conf()).output().unwrap();
        String::from_utf8_lossy(&out.stdout).into_owned()
    }

    fn script(&self, what: &str) {
        let out = Command::new("bash").arg(script()).args([what, self.dir.to_str().unwrap()]).output().unwrap();
        assert!(out.status.success(), "{what}: {}", String::from_utf8_lossy(&out.stderr));
    }

    /// The Slurm ids of the jobs named for station job `id`, from the completion log and the queue.
    fn submissions(&self, id: &str) -> (Vec<String>, Vec<String>) {
        let name = format!("scanstation-{id}");
        // `--name` is ignored with `--completion`: the job name is filtered here.
        let done = self.slurm("sacct", &["--completion", "-n", "-P", "-o", "jobid,jobname,state"]);
        let done = done
            .lines()
            .filter_map(|l| {
                let f: Vec<&str> = l.trim().split('|').collect();
                (f.len() == 3 && f[1] == name).then(|| format!("{}|{}", f[0], f[2]))
            })
            .collect();
        let queued = self.slurm("squeue", &["-h", "--name", &name, "-o", "%i %T"]);
        let queued = queued.lines().map(str::trim).filter(|l| !l.is_empty()).map(String::from).collect();
        (done, queued)
    }

    /// Wait until station job `id`'s cluster job is RUNNING; its Slurm id.
    fn wait_running(&self, id: &str, limit: Duration) -> String {
        let t = Instant::now();
        loop {
            let q = self.slurm("squeue", &["-h", "--name", &format!("scanstation-{id}"), "-o", "%i %T"]);
            if let Some(l) = q.lines().find(|l| l.ends_with("RUNNING")) {
                return l.split_whitespace().next().unwrap().to_string();
            }
            assert!(t.elapsed() < limit, "job {id} not running on the cluster within {limit:?}: {q}");
            std::thread::sleep(Duration::from_millis(50));
        }
    }
}

impl Drop for Cluster {
    fn drop(&mut self) {
        let _ = Command::new("bash").arg(script()).args(["stop", self.dir.to_str().unwrap()]).output();
    }
}

fn script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/slurm-cluster.sh")
}

/// What every test here starts with: its turn on the machine, a scratch directory, a one-node cluster and a
/// private bus (dropped in reverse: the bus, the cluster, then the turn).
struct Scene {
    dir: PathBuf,
    bus: Bus,
    cluster: Cluster,
    _turn: std::sync::MutexGuard<'static, ()>,
}

fn scene(name: &str) -> Scene {
    let turn = TURN.lock().unwrap_or_else(|p| p.into_inner());
    need("busctl", "systemd");
    let dir = common::scratch(name);
    let cluster = Cluster::start(&dir);
    let bus = start_bus(&dir, OPEN_POLICY);
    Scene { dir, bus, cluster, _turn: turn }
}

/// `[executor]` for the test cluster (`scanstation cluster-run` from this build).
fn executor_toml() -> String {
    format!(
        "[executor]\nkind = \"slurm\"\npartition = \"scan\"\ncpus = 1\nbinary = \"{CLI}\"\npoll = \"200ms\"\ntime_limit = \"10\"\n"
    )
}

/// A station in `dir` whose conversions run on `cluster`, with `extra` config lines before its `[executor]`.
fn cluster_station(dir: &Path, bus: &Bus, cluster: &Cluster, extra: &str) -> Station {
    let mut st = Station::new(dir, bus, false, &format!("{extra}{}", executor_toml()));
    st.env.push(("SLURM_CONF".into(), cluster.conf()));
    st
}

/// A sample from `examples/`.
fn example(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("examples").join(name)
}

fn job_id(path: &str) -> String {
    path.rsplit('/').next().unwrap().to_string()
}

/// `SubmitFile` of `file` with `vertices`; the job's path.
fn submit(st: &Station, file: &Path, vertices: u32) -> String {
    let out = st.busctl(&[
        "call",
        NAME,
        ROOT,
        "org.scanstation.Station1.Manager",
        "SubmitFile",
        "sa{sv}",
        file.to_str().unwrap(),
        "1",
        "vertices",
        "u",
        &vertices.to_string(),
    ]);
    assert!(out.status.success(), "SubmitFile: {}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8_lossy(&out.stdout).trim().trim_start_matches("o ").trim_matches('"').to_string()
}

fn error_code(st: &Station) -> String {
    error_code_of(&only_entry(&st.spool("quarantine")))
}

/// Three files dropped into the inbox are converted on the cluster and published; their STEP files equal
/// those of a station converting locally, byte for byte.
#[test]
fn three_files_converted_on_the_cluster_equal_a_local_run() {
    let Scene { dir, bus, cluster, .. } = &scene("cluster-three");
    let t = Instant::now();
    std::fs::create_dir_all(dir.join("cluster")).unwrap();
    std::fs::create_dir_all(dir.join("local")).unwrap();
    let mut st = cluster_station(&dir.join("cluster"), bus, cluster, "");
    st.start();
    for (name, r) in [("a.ply", 1.0), ("b.ply", 2.0), ("c.ply", 0.5)] {
        drop_renamed(&st.inbox(), name, &sphere_bytes(dir, r));
    }
    st.wait_done(3, Duration::from_secs(300));
    let on_cluster = t.elapsed();
    let published = visible(&st.spool("outbox"));
    assert_eq!(
        published.len(),
        3,
        "outbox {published:?}, quarantine {:?}\n{}",
        visible(&st.spool("quarantine")),
        st.log()
    );
    // The same three files on a station that converts locally.
    let t = Instant::now();
    let mut local = Station::new(&dir.join("local"), bus, false, "");
    // One station owns the bus name at a time.
    drop(st);
    local.start();
    for (name, r) in [("a.ply", 1.0), ("b.ply", 2.0), ("c.ply", 0.5)] {
        drop_renamed(&local.inbox(), name, &sphere_bytes(dir, r));
    }
    local.wait_done(3, Duration::from_secs(300));
    let here = t.elapsed();
    let step = |root: &Path, stem: &str| {
        let b = visible(root).into_iter().find(|b| b.starts_with(&format!("{stem}-"))).unwrap();
        std::fs::read(root.join(&b).join(format!("{stem}.step"))).unwrap()
    };
    for stem in ["a", "b", "c"] {
        let (c, l) = (step(&dir.join("cluster/spool/outbox"), stem), step(&local.spool("outbox"), stem));
        assert!(
            c == l,
            "{stem}.step: the cluster's ({} bytes) and the local run's ({} bytes) differ",
            c.len(),
            l.len()
        );
    }
    let jobs = cluster.slurm("sacct", &["--completion", "-n", "-P", "-o", "jobname,state"]);
    let jobs: Vec<&str> = jobs.lines().filter(|l| l.starts_with("scanstation-")).collect();
    assert_eq!(jobs.len(), 3, "one cluster job per file: {jobs:?}");
    assert!(jobs.iter().all(|l| l.ends_with("|COMPLETED")), "{jobs:?}");
    eprintln!("three files: on the cluster {on_cluster:?}, locally {here:?}; cluster jobs {jobs:?}; STEP files equal");
}

/// `kill -9` of the daemon while its job runs on the cluster: after the restart the job is followed to its
/// end, the cluster ran it once, and the outbox holds one bundle.
#[test]
fn kill_9_while_the_cluster_converts_follows_the_same_job() {
    let Scene { dir, bus, cluster, .. } = &scene("cluster-kill9");
    let mut st = cluster_station(dir, bus, cluster, "");
    st.start();
    let spot = example("spot.ply");
    let job = submit(&st, &spot, 3000);
    let id = job_id(&job);
    let slurm_id = cluster.wait_running(&id, Duration::from_secs(60));
    // Progress on D-Bus comes from the node's progress file, as a local job's from its worker.
    let t = Instant::now();
    let progress = loop {
        let p = st.property("Job", &job, "Progress").unwrap_or_default();
        let v: f64 = p.trim_start_matches("d ").parse().unwrap_or(0.0);
        if v > 0.05 {
            break v;
        }
        assert!(t.elapsed() < Duration::from_secs(60), "no progress from the cluster: {p}\n{}", st.log());
        std::thread::sleep(Duration::from_millis(50));
    };
    let stage = st.property("Job", &job, "Stage").unwrap_or_default();
    st.kill9();
    st.start();
    st.wait_done(1, Duration::from_secs(300));
    let out = visible(&st.spool("outbox"));
    assert_eq!(out.len(), 1, "outbox {out:?}, quarantine {:?}\n{}", visible(&st.spool("quarantine")), st.log());
    let (done, queued) = cluster.submissions(&id);
    assert!(queued.is_empty(), "{queued:?}");
    assert_eq!(done.len(), 1, "one submission: {done:?}");
    assert!(done[0].starts_with(&format!("{slurm_id}|COMPLETED")), "{done:?}");
    assert!(st.log().contains("following the cluster job submitted before"), "{}", st.log());
    eprintln!(
        "kill -9 during cluster job {slurm_id} (Progress {progress:.3}, Stage {stage}): followed after the restart; sacct: {done:?}"
    );
}

/// A job cancelled outside the station (`scancel`) fails with `cluster.cancelled`, its input in quarantine;
/// `Cancel()` over D-Bus is a `scancel` of the job, and the job ends `cancelled`.
#[test]
fn scancel_from_outside_and_cancel_over_dbus() {
    let Scene { dir, bus, cluster, .. } = &scene("cluster-cancel");
    let mut st = cluster_station(dir, bus, cluster, "");
    st.start();
    let spot = example("spot.ply");
    // 1. scancel from outside.
    let job = submit(&st, &spot, 3000);
    let slurm_id = cluster.wait_running(&job_id(&job), Duration::from_secs(60));
    cluster.slurm("scancel", &[&slurm_id]);
    st.wait_done(1, Duration::from_secs(120));
    assert_eq!(error_code(&st), "cluster.cancelled", "{}", st.log());
    let q = only_entry(&st.spool("quarantine"));
    assert!(visible(&q).iter().any(|f| f == "spot.ply"), "the input is in quarantine: {:?}", visible(&q));
    // 2. Cancel() over D-Bus (another input: the same one again would be refused as a duplicate).
    let rod = example("rod.ply");
    let job = submit(&st, &rod, 3000);
    let id = job_id(&job);
    let slurm_id = cluster.wait_running(&id, Duration::from_secs(60));
    let t = Instant::now();
    let out = st.busctl(&["call", NAME, &job, "org.scanstation.Station1.Job", "Cancel"]);
    assert!(out.status.success(), "Cancel: {}", String::from_utf8_lossy(&out.stderr));
    st.wait_property("Job", &job, "State", "s \"cancelled\"", Duration::from_secs(60));
    let (done, _) = cluster.submissions(&id);
    assert!(done.iter().any(|l| l.starts_with(&format!("{slurm_id}|CANCELLED"))), "scancel'd: {done:?}");
    eprintln!("scancel from outside: cluster.cancelled; Cancel() over D-Bus: cancelled in {:?}", t.elapsed());
}

/// The node dies mid-job (`slurmd` and the job's steps killed): the job is submitted once more; when the
/// node dies again, the job fails with `cluster.node-failed`.
#[test]
fn a_node_that_dies_is_retried_once_then_the_job_fails() {
    let Scene { dir, bus, cluster, .. } = &scene("cluster-node");
    let mut st = cluster_station(dir, bus, cluster, "");
    st.start();
    let spot = example("spot.ply");
    let job = submit(&st, &spot, 3000);
    let id = job_id(&job);
    let first = cluster.wait_running(&id, Duration::from_secs(60));
    let t = Instant::now();
    cluster.script("kill-node");
    // The controller marks the node down (SlurmdTimeout), the job NODE_FAIL; the station submits again.
    let second = loop {
        let (_, queued) = cluster.submissions(&id);
        if let Some(l) = queued.iter().find(|l| !l.starts_with(&first)) {
            break l.split_whitespace().next().unwrap().to_string();
        }
        assert!(t.elapsed() < Duration::from_secs(90), "no second submission: {queued:?}\n{}", st.log());
        std::thread::sleep(Duration::from_millis(200));
    };
    let resubmitted = t.elapsed();
    cluster.script("start-node");
    assert_eq!(cluster.wait_running(&id, Duration::from_secs(60)), second);
    cluster.script("kill-node");
    st.wait_done(1, Duration::from_secs(120));
    let failed = t.elapsed();
    cluster.script("start-node");
    assert_eq!(error_code(&st), "cluster.node-failed", "{}", st.log());
    let (done, _) = cluster.submissions(&id);
    assert_eq!(done.len(), 2, "two submissions, both NODE_FAIL: {done:?}");
    assert!(done.iter().all(|l| l.ends_with("NODE_FAIL")), "{done:?}");
    eprintln!("node killed twice: resubmitted after {resubmitted:?}, failed after {failed:?}; sacct {done:?}");
}

/// A scan session captures on the station (the simulated rig as its own process) and converts on the
/// cluster: the bundle holds the views, the fusion report and the solid, as a local scan's does.
#[test]
fn a_scan_captures_here_and_converts_on_the_cluster() {
    let Scene { dir, bus, cluster, .. } = &scene("cluster-scan");
    let _rig = start_rig(dir, 7);
    let mut st = cluster_station(dir, bus, cluster, &scan_config(dir, ""));
    st.start();
    let job = start_scan(&st, &["3", "views", "u", "8", "name", "s", "spot", "vertices", "u", "3000"]);
    let id = job_id(&job);
    st.wait_done(1, Duration::from_secs(300));
    let out = only_entry(&st.spool("outbox"));
    let files = visible(&out);
    for f in ["spot.step", "spot.fusion.json", "spot.report.html", "views"] {
        assert!(files.iter().any(|x| x == f), "{f} in {files:?}\n{}", st.log());
    }
    let (done, _) = cluster.submissions(&id);
    assert_eq!(done.len(), 1, "converted on the cluster once: {done:?}");
    eprintln!("a scan converted on the cluster: {done:?}; bundle {files:?}");
}

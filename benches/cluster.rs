//! The cluster path's overhead against the local one, and the CPU time per object the sizing table in the
//! README is built from.
//!
//! 1. **Overhead**: the same small jobs (a 1,280-triangle sphere, 100 control vertices, one at a time) through
//!    a station converting locally and one converting on a one-node Slurm cluster on this machine
//!    (`scripts/slurm-cluster.sh`), each timed from the drop into the inbox to its bundle in the outbox; the
//!    mean per job, and the cluster's extra seconds per job.
//! 2. **CPU time per object**: `scanstation convert` of spot (`examples/`) and of the shared bust and figurine
//!    at 10,000 control vertices, user + system seconds (`/usr/bin/time`).
//!
//! Needs what `tests/cluster.rs` needs (Slurm, D-Bus tools, root). Run: `cargo bench --bench cluster`
//! (`SCANSTATION_CLUSTER_JOBS` small jobs each way, 5 by default).

#[path = "../tests/harness/mod.rs"]
mod harness;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use harness::*;

fn script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/slurm-cluster.sh")
}

/// Seconds per job, one job at a time: drop, wait for its bundle.
fn per_job(st: &Station, dir: &Path, jobs: usize) -> Vec<f64> {
    (0..jobs)
        .map(|k| {
            let t = Instant::now();
            drop_renamed(&st.inbox(), &format!("s{k}.ply"), &sphere_bytes(dir, 1.0 + k as f64 * 0.01));
            st.wait_done(k + 1, Duration::from_secs(300));
            t.elapsed().as_secs_f64()
        })
        .collect()
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

fn main() {
    let jobs: usize = std::env::var("SCANSTATION_CLUSTER_JOBS").ok().and_then(|v| v.parse().ok()).unwrap_or(5);
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("bench-cluster");
    let _ = std::fs::remove_dir_all(&dir);
    for d in ["local", "cluster"] {
        std::fs::create_dir_all(dir.join(d)).unwrap();
    }
    let slurm = dir.join("slurm");
    let up = Command::new("bash").arg(script()).args(["start", slurm.to_str().unwrap()]).output().unwrap();
    assert!(up.status.success(), "the cluster did not start: {}", String::from_utf8_lossy(&up.stderr));
    let bus = start_bus(&dir, OPEN_POLICY);
    // 1. Overhead, local first.
    let mut local = Station::new(&dir.join("local"), &bus, false, "");
    local.start();
    let here = per_job(&local, &dir, jobs);
    drop(local);
    let extra =
        format!("[executor]\nkind = \"slurm\"\npartition = \"scan\"\ncpus = 1\nbinary = \"{CLI}\"\npoll = \"200ms\"\n");
    let mut st = Station::new(&dir.join("cluster"), &bus, false, &extra);
    st.env.push(("SLURM_CONF".into(), slurm.join("slurm.conf").display().to_string()));
    st.start();
    let there = per_job(&st, &dir, jobs);
    drop(st);
    let _ = Command::new("bash").arg(script()).args(["stop", slurm.to_str().unwrap()]).output();
    println!("# a small job (sphere, 1,280 triangles, 100 control vertices), {jobs} one at a time, drop → bundle");
    println!("| path | mean s per job | jobs (s) |");
    println!("|---|---:|---|");
    let fmt = |v: &[f64]| v.iter().map(|x| format!("{x:.2}")).collect::<Vec<_>>().join(", ");
    println!("| local | {:.2} | {} |", mean(&here), fmt(&here));
    println!("| Slurm (one node, this machine) | {:.2} | {} |", mean(&there), fmt(&there));
    println!(
        "| **cluster overhead** | **+{:.2} s a job** ({:.2}×) | |",
        mean(&there) - mean(&here),
        mean(&there) / mean(&here)
    );
    // 2. CPU time per object.
    let shared = std::env::var("SCANSTATION_SHARED_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|_| Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data"));
    let objects = [
        ("spot", Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/spot.ply")),
        ("igea (bust)", shared.join("meshes/igea.ply")),
        ("armadillo_50k (figurine)", shared.join("meshes/armadillo_50k.ply")),
    ];
    println!();
    println!("# CPU time per object: scanstation convert --vertices 10000 --pictures (release, 2 cores)");
    println!("| object | wall s | user + system s |");
    println!("|---|---:|---:|");
    for (name, path) in objects {
        if !path.is_file() {
            println!("| {name} | missing: {} | |", path.display());
            continue;
        }
        let out = dir.join(format!("{}.step", name.split(' ').next().unwrap()));
        let run = Command::new("/usr/bin/time")
            .args(["-f", "%e %U %S", CLI, "convert"])
            .arg(&path)
            .args(["-o", out.to_str().unwrap(), "--vertices", "10000", "--pictures"])
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&run.stderr);
        let t: Vec<f64> = err.lines().last().unwrap_or("").split_whitespace().filter_map(|x| x.parse().ok()).collect();
        if t.len() == 3 {
            println!("| {name} | {:.1} | {:.1} |", t[0], t[1] + t[2]);
        } else {
            println!("| {name} | failed: {} | |", err.lines().last().unwrap_or(""));
        }
    }
}

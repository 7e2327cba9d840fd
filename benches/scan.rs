//! A scan session's time: the real `scanstationd` on a private bus, the simulated rig as its own process
//! (`scanstation sim rig` holding spot from `examples/`; the turntable at 1000 × real speed and no exposure,
//! so motion and exposure are as good as zero), `StartScan` with 12 views at the station's default of
//! 10,000 control vertices, from the call to the published bundle. Reports the time in every stage (from
//! the job's `Stage` property, polled every 10 ms), the conversion's own per-stage time and peak memory (its
//! report), the job's `PeakMemory` and the daemon's peak RSS, and the solid's RMS to the true object.
//!
//! Needs `dbus-daemon`, `busctl` and `gdbus` (as the daemon tests). Run: `cargo bench --bench scan`
//! (`SCANSTATION_SCAN_VIEWS` overrides the 12 views, `SCANSTATION_SCAN_VERTICES` the vertex count;
//! `SCANSTATION_SCAN_TILTS=-25:8,-45:8,50:6` adds tilted rings, `SCANSTATION_SCAN_COVERAGE=0.99` views chosen
//! where the surface is unseen, up to `SCANSTATION_SCAN_MAX_VIEWS`, 48 by default; `SCANSTATION_SCAN_PASSES=2`
//! takes the plan twice, the simulated rig turning the object over when the job asks (`turn-over`, then
//! `Continue()`); `SCANSTATION_SCAN_OBJECT` and `SCANSTATION_SCAN_UP` scan another closed mesh;
//! `SCANSTATION_SCAN_SEED` the rig's noise seed, 7 by default; `SCANSTATION_SCAN_KEEP=DIR` copies the
//! published bundle there).

#[path = "../tests/harness/mod.rs"]
mod harness;

use std::path::Path;
use std::time::{Duration, Instant};

use harness::*;

fn main() {
    let views: u32 = std::env::var("SCANSTATION_SCAN_VIEWS").ok().and_then(|v| v.parse().ok()).unwrap_or(12);
    let vertices: u32 = std::env::var("SCANSTATION_SCAN_VERTICES").ok().and_then(|v| v.parse().ok()).unwrap_or(10_000);
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("bench-scan");
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let bus = start_bus(&dir, OPEN_POLICY);
    // Another object than spot: `SCANSTATION_SCAN_OBJECT` (a closed mesh) and its up axis `SCANSTATION_SCAN_UP`.
    let object = std::env::var("SCANSTATION_SCAN_OBJECT")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|_| Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/spot.ply"));
    let up = std::env::var("SCANSTATION_SCAN_UP").unwrap_or("y".into());
    let seed: u64 = std::env::var("SCANSTATION_SCAN_SEED").ok().and_then(|v| v.parse().ok()).unwrap_or(7);
    let rig = start_rig_holding(&dir, seed, ("1000", "0"), (&object, &up));
    let mut st = Station::new(&dir, &bus, false, &scan_config(&dir, "settle = \"0ms\""));
    st.start();
    // The rig connected before the clock starts.
    st.wait_property(
        "Turntable",
        "/org/scanstation/Station1/devices/turntable",
        "Connected",
        "b true",
        Duration::from_secs(10),
    );
    st.wait_property(
        "Trigger",
        "/org/scanstation/Station1/devices/trigger",
        "NodeAlive",
        "b true",
        Duration::from_secs(10),
    );
    let rss_idle = st.peak_rss_kib();
    let (v, n) = (views.to_string(), vertices.to_string());
    let t0 = Instant::now();
    let env = |k: &str| std::env::var(k).ok().filter(|v| !v.is_empty());
    let (tilts, coverage) = (env("SCANSTATION_SCAN_TILTS"), env("SCANSTATION_SCAN_COVERAGE"));
    let max_views = env("SCANSTATION_SCAN_MAX_VIEWS").unwrap_or("48".into());
    let mut args: Vec<&str> = vec!["views", "u", &v, "name", "s", "spot", "vertices", "u", &n];
    if let Some(t) = &tilts {
        args.extend(["tilts", "s", t]);
    }
    if let Some(c) = &coverage {
        args.extend(["coverage", "d", c, "max_views", "u", &max_views]);
    }
    let passes = env("SCANSTATION_SCAN_PASSES");
    if let Some(p) = &passes {
        args.extend(["passes", "u", p]);
    }
    let mut turned = 0;
    let count = (args.len() / 3).to_string();
    let job = start_scan(&st, &[&[count.as_str()][..], &args].concat());
    // Stage transitions, as a client sees them.
    let mut stages: Vec<(String, Duration)> = Vec::new();
    let done = loop {
        let stage = st.property("Job", &job, "Stage").unwrap_or_default();
        let state = st.property("Job", &job, "State").unwrap_or_default();
        let name = stage.trim_start_matches("s ").trim_matches('"').to_string();
        if stages.last().is_none_or(|(s, _)| *s != name) && !name.is_empty() {
            stages.push((name, t0.elapsed()));
        }
        // Asked to turn the object over: the rig does it, then Continue().
        let asked = st.property("Job", &job, "OperatorAction").unwrap_or_default();
        if asked.len() > 4 {
            turned += 1;
            rig.send(&format!("turn-over {turned}"));
            std::thread::sleep(Duration::from_millis(50));
            let out = st.busctl(&["call", NAME, &job, "org.scanstation.Station1.Job", "Continue"]);
            assert!(out.status.success(), "Continue: {}", String::from_utf8_lossy(&out.stderr));
            stages.push((format!("capture (pass {})", turned + 1), t0.elapsed()));
        }
        if state.contains("succeeded") || state.contains("failed") || state.contains("cancelled") {
            break (state, t0.elapsed());
        }
        assert!(t0.elapsed() < Duration::from_secs(1800), "the scan did not finish: {}", st.log());
        std::thread::sleep(Duration::from_millis(10));
    };
    let (state, total) = done;
    if !state.contains("succeeded") {
        // Another object may miss a quality gate (thin parts: issue 42): say so with its code, and what the
        // capture saw.
        let q = only_entry(&st.spool("quarantine"));
        let err: serde_json::Value =
            serde_json::from_slice(&std::fs::read(q.join("error.json")).unwrap_or_default()).unwrap_or_default();
        println!(
            "# scan of {}: {state} in {:.1} s: [{}] {}",
            object.display(),
            total.as_secs_f64(),
            err["error_code"],
            err["message"]
        );
        return;
    }
    let peak_memory = st.property("Job", &job, "PeakMemory").unwrap_or_default();
    let rss_peak = st.peak_rss_kib();
    let out = only_entry(&st.spool("outbox"));
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("spot.report.json")).unwrap()).unwrap();
    let fusion: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("spot.fusion.json")).unwrap()).unwrap();

    let taken = fusion["views"].as_array().map_or(0, |v| v.len());
    println!(
        "# scan of {}: {views} level views, tilts {:?}, coverage target {:?}, passes {}: {taken} views taken, {vertices} control vertices (turntable ×1000, no exposure)",
        object.display(),
        tilts.as_deref().unwrap_or(""),
        coverage.as_deref().unwrap_or(""),
        passes.as_deref().unwrap_or("1")
    );
    println!("| stage (Job.Stage) | from s | seconds |");
    println!("|---|---:|---:|");
    for (i, (name, at)) in stages.iter().enumerate() {
        let end = stages.get(i + 1).map_or(total, |n| n.1);
        println!("| {name} | {:.2} | {:.2} |", at.as_secs_f64(), (end - *at).as_secs_f64());
    }
    println!("| **StartScan → published** | | **{:.2}** |", total.as_secs_f64());
    println!();
    println!("| conversion stage (report) | seconds | peak MiB |");
    println!("|---|---:|---:|");
    for s in report["convert"]["stages"].as_array().into_iter().flatten() {
        println!(
            "| {} | {:.2} | {} |",
            s["stage"].as_str().unwrap_or("?"),
            s["seconds"].as_f64().unwrap_or(0.0),
            s["peak_rss_mib"].as_f64().map_or("-".into(), |m| format!("{m:.0}"))
        );
    }
    println!();
    println!(
        "job PeakMemory {peak_memory}; daemon peak RSS {:.0} MiB (idle {:.0} MiB)",
        rss_peak as f64 / 1024.0,
        rss_idle as f64 / 1024.0
    );
    println!(
        "fusion: {} points, coverage {:.4}; solid {} faces; estimates {}",
        fusion["fused_points"],
        fusion["coverage"]["share"],
        report["convert"]["brep"]["faces"],
        fusion["next_views"]["estimates"]
    );
    if let Some(p) = fusion["passes"]["aligned"].as_array().filter(|p| !p.is_empty()) {
        println!("passes aligned: {}", serde_json::Value::Array(p.clone()));
    }
    let out_cmp = std::process::Command::new(CLI)
        .args([
            "compare",
            out.join("spot.solid.ply").to_str().unwrap(),
            dir.join("truth.ply").to_str().unwrap(),
            "--json",
        ])
        .output()
        .unwrap();
    let cmp: serde_json::Value = serde_json::from_slice(&out_cmp.stdout).unwrap_or_default();
    println!("solid ↔ true object: RMS {} % of the diagonal", cmp["symmetric"]["rms"]["pct_of_diagonal"]);
    if let Ok(keep) = std::env::var("SCANSTATION_SCAN_KEEP") {
        let keep = Path::new(&keep);
        std::fs::create_dir_all(keep).unwrap();
        for f in ["spot.step", "spot.solid.ply", "spot.fusion.json"] {
            std::fs::copy(out.join(f), keep.join(f)).unwrap();
        }
    }
}

//! Scan sessions end to end: the real `scanstationd` on a private `dbus-daemon`, the simulated rig as its own
//! process (`scanstation sim rig`: turntable on a pty, scanner node on a socket, a range camera ray-casting
//! spot from `examples/` at the table's angle), `StartScan` through `busctl` and the CLI, faults injected into
//! the rig while it scans.
//!
//! Needs Debian's `dbus-daemon`, `busctl` (dbus-daemon, systemd) and `gdbus` (libglib2.0-bin); a test fails
//! with the package to install when one is missing.

mod common;
mod harness;

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use harness::*;

/// The simulated rig (`scanstation sim rig`) holding spot, and its control socket.
struct Rig {
    _sim: Sim,
    control: PathBuf,
}

impl Rig {
    /// Send a fault command line (`unplug`, `replug`, `drop-view 3`, …).
    fn send(&self, line: &str) {
        let mut s = std::os::unix::net::UnixStream::connect(&self.control).expect("the rig's control socket");
        writeln!(s, "{line}").unwrap();
    }
}

/// Start the rig for `dir` with noise seed `seed`; returns it once its line, socket and calibration exist.
fn start_rig(dir: &Path, seed: u64) -> Rig {
    let link = dir.join("ttyTurntable");
    let sock = dir.join("can.sock");
    let control = dir.join("rig.ctl");
    let calib = dir.join("calibration.toml");
    for p in [&link, &sock, &control, &calib] {
        let _ = std::fs::remove_file(p);
    }
    let object = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/spot.ply");
    let seed = seed.to_string();
    let s = sim(
        dir,
        "rig",
        &[
            "rig",
            "--object",
            object.to_str().unwrap(),
            "--link",
            link.to_str().unwrap(),
            "--bus",
            &format!("unix:{}", sock.display()),
            "--capture",
            dir.join("capture").to_str().unwrap(),
            "--calibration",
            calib.to_str().unwrap(),
            "--truth",
            dir.join("truth.ply").to_str().unwrap(),
            "--seed",
            &seed,
            "--time-scale",
            "20",
            "--heartbeat-ms",
            "50",
            "--exposure-ms",
            "20",
            "--control",
            control.to_str().unwrap(),
        ],
    );
    let t = Instant::now();
    while !(link.exists() && sock.exists() && control.exists() && calib.exists()) {
        assert!(
            t.elapsed() < Duration::from_secs(10),
            "the simulated rig did not come up: {}",
            std::fs::read_to_string(dir.join("rig.log")).unwrap_or_default()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    Rig { _sim: s, control }
}

/// The station's config for a scan rig in `dir`: the devices, and `[scan]` with the rig's calibration plus
/// `scan_extra` lines.
fn scan_config(dir: &Path, scan_extra: &str) -> String {
    let calib = std::fs::read_to_string(dir.join("calibration.toml")).unwrap();
    format!(
        "{}{calib}capture_dir = \"{}\"\nsettle = \"50ms\"\nview_file_timeout = \"2s\"\n{scan_extra}\n",
        rig_config(dir),
        dir.join("capture").display()
    )
}

/// `StartScan` through busctl with `args` (`a{sv}` count and entries); the job's path.
fn start_scan(st: &Station, args: &[&str]) -> String {
    let mut a = vec!["call", NAME, ROOT, "org.scanstation.Station1.Manager", "StartScan", "a{sv}"];
    a.extend_from_slice(args);
    let out = st.busctl(&a);
    assert!(out.status.success(), "StartScan failed: {}\n{}", String::from_utf8_lossy(&out.stderr), st.log());
    let text = String::from_utf8_lossy(&out.stdout);
    text.trim().trim_start_matches("o ").trim_matches('"').to_string()
}

/// The one outbox (or quarantine) entry of the finished scan.
fn only_entry(dir: &Path) -> PathBuf {
    let v = visible(dir);
    assert_eq!(v.len(), 1, "{}: {v:?}", dir.display());
    dir.join(&v[0])
}

/// `scanstation compare TEST REFERENCE --json`: the symmetric RMS as % of the reference's diagonal.
fn rms_pct(test: &Path, reference: &Path) -> f64 {
    let out = Command::new(CLI)
        .args(["compare", test.to_str().unwrap(), reference.to_str().unwrap(), "--json"])
        .stderr(Stdio::inherit())
        .output()
        .unwrap();
    assert!(out.status.success(), "compare {} {}", test.display(), reference.display());
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    v["symmetric"]["rms"]["pct_of_diagonal"].as_f64().unwrap_or_else(|| panic!("no symmetric rms in {v}"))
}

fn json(p: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))).unwrap()
}

#[test]
fn a_twelve_view_scan_of_spot_becomes_a_solid_close_to_the_object() {
    need("busctl", "systemd");
    let dir = common::scratch("scan-e2e");
    let bus = start_bus(&dir, OPEN_POLICY);
    let _rig = start_rig(&dir, 7);
    let mut st = Station::new(&dir, &bus, false, &scan_config(&dir, ""));
    st.start();
    let monitor = Monitor::start(&st.bus, dir.join("monitor.txt"));
    let t = Instant::now();
    let job = start_scan(&st, &["3", "views", "u", "12", "name", "s", "spot", "vertices", "u", "3000"]);
    st.wait_done(1, Duration::from_secs(600));
    let took = t.elapsed();
    let signals = monitor.finish();
    let out = only_entry(&st.spool("outbox"));
    eprintln!("scan took {took:?}; bundle {}", out.display());
    let sig = signals.get(&job).unwrap_or_else(|| panic!("no signals for {job}"));
    assert_eq!(sig.completed, vec![("succeeded".to_string(), String::new())], "{}", st.log());
    let progress: Vec<f64> = sig.events.iter().flatten().copied().collect();
    assert!(progress.windows(2).all(|w| w[1] >= w[0]), "progress not monotonic: {progress:?}");
    assert!(progress.len() >= 10, "too few progress signals: {progress:?}");
    let views: Vec<String> = visible(&out.join("views")).into_iter().filter(|f| f.starts_with("view-")).collect();
    assert_eq!(views.len(), 12, "views/: {views:?}");
    let fusion = json(&out.join("spot.fusion.json"));
    let coverage = fusion["coverage"]["share"].as_f64().unwrap();
    eprintln!(
        "fusion: coverage {coverage:.4}, pooled residual {} -> {}, decision {}",
        fusion["pooled_residual_before"], fusion["pooled_residual_after"], fusion["decision"]
    );
    assert!((0.8..1.0).contains(&coverage), "coverage {coverage}");
    let rms = rms_pct(&out.join("spot.solid.ply"), &dir.join("truth.ply"));
    eprintln!("solid vs the true object: RMS {rms:.4} % of the diagonal");
    assert!(rms < 0.5, "RMS {rms} % of the diagonal");
}

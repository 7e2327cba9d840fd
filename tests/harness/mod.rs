//! The harness of the daemon's integration tests (`tests/daemon.rs`, `tests/scan.rs`): a private
//! `dbus-daemon`, the real `scanstationd` binary with a config of the test's, `gdbus monitor` parsed into
//! per-job signals, and the rig's simulators as processes.
#![allow(dead_code)]

use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use scanstation::PolyMesh;
use scanstation::geometry::io::write_ply;
use scanstation::geometry::shapes::icosphere;

pub const DAEMON: &str = env!("CARGO_BIN_EXE_scanstationd");
pub const CLI: &str = env!("CARGO_BIN_EXE_scanstation");
pub const NAME: &str = "org.scanstation.Station1";
pub const ROOT: &str = "/org/scanstation/Station1";

pub fn need(tool: &str, package: &str) {
    let ok = Command::new("sh").arg("-c").arg(format!("command -v {tool}")).stdout(Stdio::null()).status();
    assert!(ok.is_ok_and(|s| s.success()), "{tool} is missing: install it with `apt-get install {package}`");
}

/// A private bus: `dbus-daemon` with a config of ours, listening on a socket in `dir`.
pub struct Bus {
    pub child: Child,
    pub address: String,
}

impl Drop for Bus {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// `policy` is inserted into the bus config: the station's policy file (system-bus rules), or a permissive
/// default (session-bus rules).
pub fn start_bus(dir: &Path, policy: &str) -> Bus {
    need("dbus-daemon", "dbus-daemon");
    let sock = dir.join("bus");
    let conf = dir.join("bus.conf");
    std::fs::write(
        &conf,
        format!(
            r#"<!DOCTYPE busconfig PUBLIC "-//freedesktop//DTD D-BUS Bus Configuration 1.0//EN"
 "http://www.freedesktop.org/standards/dbus/1.0/busconfig.dtd">
<busconfig>
  <type>system</type>
  <listen>unix:path={}</listen>
  <auth>EXTERNAL</auth>
  {policy}
</busconfig>"#,
            sock.display()
        ),
    )
    .unwrap();
    let child = Command::new("dbus-daemon")
        .arg(format!("--config-file={}", conf.display()))
        .arg("--nofork")
        .stdout(Stdio::null())
        .spawn()
        .expect("start dbus-daemon");
    let t = Instant::now();
    while !sock.exists() {
        assert!(t.elapsed() < Duration::from_secs(10), "dbus-daemon did not create {}", sock.display());
        std::thread::sleep(Duration::from_millis(20));
    }
    Bus { child, address: format!("unix:path={}", sock.display()) }
}

/// Session-bus rules: anyone may connect, own and send (so only the daemon's own check guards changes).
pub const OPEN_POLICY: &str = r#"<policy context="default">
    <allow user="*"/>
    <allow own="*"/>
    <allow send_destination="*" eavesdrop="true"/>
    <allow eavesdrop="true"/>
  </policy>"#;

/// System-bus defaults (as Debian's system.conf) plus the station's policy file.
pub fn system_policy() -> String {
    let ours = Path::new(env!("CARGO_MANIFEST_DIR")).join("systemd/org.scanstation.Station1.conf");
    format!(
        r#"<policy context="default">
    <allow user="*"/>
    <deny own="*"/>
    <deny send_type="method_call"/>
    <allow send_type="signal"/>
    <allow send_requested_reply="true" send_type="method_return"/>
    <allow send_requested_reply="true" send_type="error"/>
    <allow receive_type="method_call"/>
    <allow receive_type="method_return"/>
    <allow receive_type="error"/>
    <allow receive_type="signal"/>
    <allow send_destination="org.freedesktop.DBus" send_interface="org.freedesktop.DBus"/>
    <allow send_destination="org.freedesktop.DBus" send_interface="org.freedesktop.DBus.Introspectable"/>
    <allow send_destination="org.freedesktop.DBus" send_interface="org.freedesktop.DBus.Properties"/>
  </policy>
  <include>{}</include>"#,
        ours.display()
    )
}

/// The daemon under test.
pub struct Station {
    pub child: Option<Child>,
    pub dir: PathBuf,
    pub config: PathBuf,
    pub bus: String,
    pub system: bool,
    /// Extra environment for the daemon (`SLURM_CONF` for the cluster tests).
    pub env: Vec<(String, String)>,
}

impl Drop for Station {
    fn drop(&mut self) {
        if let Some(c) = &mut self.child {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

impl Station {
    pub fn new(dir: &Path, bus: &Bus, system: bool, extra: &str) -> Station {
        let config = dir.join("scanstation.toml");
        std::fs::write(
            &config,
            format!(
                r#"[daemon]
bus = "{}"
log_format = "pretty"
worker_threads = 1
[paths]
spool = "{}"
state = "{}"
[watch]
settle = "500ms"
reconcile_interval = "1s"
[pipeline]
vertices = 100
compare_samples = 5000
{gate}
{extra}
"#,
                if system { "system" } else { "session" },
                dir.join("spool").display(),
                dir.join("state").display(),
                // 100-vertex nets keep these tests fast; they are coarse by design (RMS about 0.1 % of the
                // sphere's diagonal), so the accuracy gate is loosened unless a test sets its own.
                gate = if extra.contains("max_rms_pct") { "" } else { "max_rms_pct = 1.0" },
            ),
        )
        .unwrap();
        Station { child: None, dir: dir.to_path_buf(), config, bus: bus.address.clone(), system, env: Vec::new() }
    }

    /// A station whose config sets `limits.memory_budget` to `mib` MiB.
    pub fn with_memory_budget(dir: &Path, bus: &Bus, mib: u64) -> Station {
        let st = Station::new(dir, bus, false, "");
        let cfg = std::fs::read_to_string(&st.config)
            .unwrap()
            .replace("[pipeline]", &format!("[limits]\nmemory_budget = \"{mib}MiB\"\n[pipeline]"));
        std::fs::write(&st.config, cfg).unwrap();
        st
    }

    /// The daemon's peak resident memory so far (VmHWM), KiB.
    pub fn peak_rss_kib(&self) -> u64 {
        let status = std::fs::read_to_string(format!("/proc/{}/status", self.pid())).unwrap();
        let line = status.lines().find(|l| l.starts_with("VmHWM:")).expect("VmHWM in /proc/PID/status");
        line.split_whitespace().nth(1).unwrap().parse().unwrap()
    }

    pub fn inbox(&self) -> PathBuf {
        self.dir.join("spool/inbox")
    }

    pub fn spool(&self, sub: &str) -> PathBuf {
        self.dir.join("spool").join(sub)
    }

    /// Start the binary and wait until the bus name is taken.
    pub fn start(&mut self) {
        let var = if self.system { "DBUS_SYSTEM_BUS_ADDRESS" } else { "DBUS_SESSION_BUS_ADDRESS" };
        let log = std::fs::OpenOptions::new().create(true).append(true).open(self.dir.join("daemon.log")).unwrap();
        let child = Command::new(DAEMON)
            .arg("--config")
            .arg(&self.config)
            .env(var, &self.bus)
            .envs(self.env.iter().map(|(k, v)| (k.as_str(), v.as_str())))
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .expect("start scanstationd");
        self.child = Some(child);
        let t = Instant::now();
        loop {
            if self.property("Manager", ROOT, "Version").is_some() {
                return;
            }
            if let Some(Ok(Some(st))) = self.child.as_mut().map(|c| c.try_wait()) {
                panic!("scanstationd exited with {st}: {}", self.log());
            }
            assert!(t.elapsed() < Duration::from_secs(30), "scanstationd did not take its name: {}", self.log());
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    pub fn kill9(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill(); // SIGKILL
            let _ = c.wait();
        }
    }

    pub fn pid(&self) -> u32 {
        self.child.as_ref().expect("running").id()
    }

    pub fn log(&self) -> String {
        std::fs::read_to_string(self.dir.join("daemon.log")).unwrap_or_default()
    }

    /// `busctl get-property` as the current user; None when it fails.
    pub fn property(&self, iface: &str, path: &str, prop: &str) -> Option<String> {
        let out = Command::new("busctl")
            .args(["--address", &self.bus, "get-property", NAME, path, &format!("{NAME}.{iface}"), prop])
            .output()
            .ok()?;
        out.status.success().then(|| String::from_utf8_lossy(&out.stdout).trim().to_string())
    }

    pub fn cli(&self, args: &[&str]) -> std::process::Output {
        Command::new(CLI).args(args).arg("--session").env("DBUS_SESSION_BUS_ADDRESS", &self.bus).output().unwrap()
    }

    /// Wait until outbox + quarantine hold `n` entries and work/ is empty.
    pub fn wait_done(&self, n: usize, limit: Duration) {
        let t = Instant::now();
        loop {
            let done = visible(&self.spool("outbox")).len() + visible(&self.spool("quarantine")).len();
            let working = std::fs::read_dir(self.spool("work")).map(|r| r.count()).unwrap_or(0);
            if done >= n && working == 0 {
                return;
            }
            assert!(
                t.elapsed() < limit,
                "after {:?}: {done} of {n} finished, {working} in work/\n{}",
                limit,
                self.log()
            );
            std::thread::sleep(Duration::from_millis(100));
        }
    }
}

/// Entries of a directory that are not hidden, sorted.
pub fn visible(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .map(|r| {
            r.flatten().map(|e| e.file_name().to_string_lossy().into_owned()).filter(|n| !n.starts_with('.')).collect()
        })
        .unwrap_or_default();
    v.sort();
    v
}

/// A small closed sphere scan as binary PLY; `r` makes its content (and sha256) distinct.
pub fn sphere_bytes(dir: &Path, r: f64) -> Vec<u8> {
    let p = dir.join(format!(".sphere-{r}.ply"));
    write_ply(&p, &PolyMesh::from(icosphere(r, 3, [0.0; 3])), &Default::default(), &[]).unwrap();
    let b = std::fs::read(&p).unwrap();
    std::fs::remove_file(&p).unwrap();
    b
}

/// Producer protocol 1: write NAME.part, then rename.
pub fn drop_renamed(inbox: &Path, name: &str, bytes: &[u8]) {
    let part = inbox.join(format!("{name}.part"));
    std::fs::write(&part, bytes).unwrap();
    std::fs::rename(&part, inbox.join(name)).unwrap();
}

/// Producer protocol 2: written in place, slowly, in chunks (closed and reopened between chunks).
pub fn drop_in_place_slowly(inbox: &Path, name: &str, bytes: &[u8], chunks: usize, pause: Duration) {
    let p = inbox.join(name);
    for c in bytes.chunks(bytes.len().div_ceil(chunks)) {
        let mut f = std::fs::OpenOptions::new().create(true).append(true).open(&p).unwrap();
        f.write_all(c).unwrap();
        drop(f);
        std::thread::sleep(pause);
    }
}

/// `gdbus monitor` on the station's name: every signal as text, until dropped.
pub struct Monitor {
    pub child: Child,
    pub out: PathBuf,
}

impl Monitor {
    pub fn start(bus: &str, out: PathBuf) -> Monitor {
        need("gdbus", "libglib2.0-bin");
        let f = std::fs::File::create(&out).unwrap();
        let child = Command::new("gdbus")
            .args(["monitor", "--address", bus, "--dest", NAME])
            .stdout(f)
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        std::thread::sleep(Duration::from_millis(300));
        Monitor { child, out }
    }

    /// Wait until the output holds `n` lines containing `needle`.
    pub fn wait_for(&self, needle: &str, n: usize, limit: Duration) {
        let t = Instant::now();
        while std::fs::read_to_string(&self.out).unwrap_or_default().matches(needle).count() < n {
            assert!(t.elapsed() < limit, "no {needle} within {limit:?}");
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// Stop and parse: per job path, its Progress values and Completed results in order.
    pub fn finish(mut self) -> BTreeMap<String, JobSignals> {
        std::thread::sleep(Duration::from_millis(500));
        let _ = self.child.kill();
        let _ = self.child.wait();
        parse_monitor(&std::fs::read_to_string(&self.out).unwrap())
    }
}

#[derive(Default, Debug)]
pub struct JobSignals {
    /// Progress values, and `Completed` as a marker (None) in order.
    pub events: Vec<Option<f64>>,
    pub completed: Vec<(String, String)>,
}

pub fn parse_monitor(text: &str) -> BTreeMap<String, JobSignals> {
    let mut m: BTreeMap<String, JobSignals> = BTreeMap::new();
    for line in text.lines() {
        let Some((path, rest)) = line.split_once(": ") else { continue };
        if !path.starts_with(&format!("{ROOT}/jobs/")) {
            continue;
        }
        let j = m.entry(path.to_string()).or_default();
        if rest.starts_with("org.freedesktop.DBus.Properties.PropertiesChanged") {
            if let Some(i) = rest.find("'Progress': <") {
                let v: f64 = rest[i + 13..].split('>').next().unwrap().parse().unwrap();
                j.events.push(Some(v));
            }
        } else if let Some(args) = rest.strip_prefix(&format!("{NAME}.Job.Completed (")) {
            let parts: Vec<String> =
                args.split(", ").map(|s| s.trim_matches(|c| c == '\'' || c == ')').to_string()).collect();
            j.events.push(None);
            j.completed.push((parts[0].clone(), parts.get(1).cloned().unwrap_or_default()));
        }
    }
    m
}

pub fn error_code_of(quarantine_entry: &Path) -> String {
    let v: serde_json::Value =
        serde_json::from_slice(&std::fs::read(quarantine_entry.join("error.json")).unwrap()).unwrap();
    v["error_code"].as_str().unwrap().to_string()
}

/// A simulator of the rig as its own process (`scanstation sim …`), killed when dropped.
pub struct Sim(pub Child);

impl Drop for Sim {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// `scanstation sim ARGS…`, stdin held open (the simulators quit at its end), its log in `dir/NAME.log`.
pub fn sim(dir: &Path, name: &str, args: &[&str]) -> Sim {
    let log = std::fs::File::create(dir.join(format!("{name}.log"))).unwrap();
    let child = Command::new(CLI)
        .arg("sim")
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::null())
        .stderr(log)
        .spawn()
        .expect("start the simulator");
    Sim(child)
}

pub fn sim_turntable(dir: &Path) -> Sim {
    let link = dir.join("ttyTurntable");
    let s = sim(dir, "turntable", &["turntable", "--link", link.to_str().unwrap(), "--time-scale", "10"]);
    let t = Instant::now();
    while !link.exists() {
        assert!(t.elapsed() < Duration::from_secs(5), "the simulated turntable did not appear");
        std::thread::sleep(Duration::from_millis(20));
    }
    s
}

pub fn sim_trigger(dir: &Path) -> Sim {
    let sock = dir.join("can.sock");
    let _ = std::fs::remove_file(&sock);
    let bus = format!("unix:{}", sock.display());
    let s = sim(dir, "trigger", &["trigger", "--bus", &bus, "--heartbeat-ms", "50", "--exposure-ms", "20"]);
    let t = Instant::now();
    while !sock.exists() {
        assert!(t.elapsed() < Duration::from_secs(5), "the simulated scanner node did not appear");
        std::thread::sleep(Duration::from_millis(20));
    }
    s
}

/// The `[devices.*]` sections for the simulators in `dir` (fast deadlines: the turntable runs ten times faster
/// than real time, the scanner beats every 50 ms).
pub fn rig_config(dir: &Path) -> String {
    format!(
        r#"[devices.turntable]
port = "{}"
steps_per_revolution = 3200
reply_timeout = "500ms"
banner_timeout = "2s"
home_timeout = "5s"
reconnect_max = "400ms"
tilt_min = -60
tilt_max = 60
[devices.trigger]
interface = "unix:{}"
heartbeat = "50ms"
ack_timeout = "500ms"
view_timeout = "2s"
"#,
        dir.join("ttyTurntable").display(),
        dir.join("can.sock").display()
    )
}

impl Station {
    /// Wait until `busctl get-property` of `prop` prints `want`.
    pub fn wait_property(&self, iface: &str, path: &str, prop: &str, want: &str, limit: Duration) -> Duration {
        let t = Instant::now();
        loop {
            let got = self.property(iface, path, prop);
            if got.as_deref() == Some(want) {
                return t.elapsed();
            }
            assert!(t.elapsed() < limit, "{iface}.{prop}: {got:?}, not {want:?} within {limit:?}\n{}", self.log());
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    pub fn busctl(&self, args: &[&str]) -> std::process::Output {
        Command::new("busctl").args(["--address", &self.bus]).args(args).output().unwrap()
    }
}

/// The simulated rig (`scanstation sim rig`) holding spot, and its control socket.
pub struct Rig {
    pub sim: Sim,
    pub control: PathBuf,
}

impl Rig {
    /// Send a fault command line (`unplug`, `replug`, `drop-view 3`, …).
    pub fn send(&self, line: &str) {
        let mut s = std::os::unix::net::UnixStream::connect(&self.control).expect("the rig's control socket");
        writeln!(s, "{line}").unwrap();
    }
}

/// Start the rig for `dir` with noise seed `seed`; returns it once its line, socket and calibration exist.
pub fn start_rig(dir: &Path, seed: u64) -> Rig {
    start_rig_at(dir, seed, "20", "20")
}

/// [`start_rig`] with the turntable's time scale and the scanner's exposure (ms) given.
pub fn start_rig_at(dir: &Path, seed: u64, time_scale: &str, exposure_ms: &str) -> Rig {
    let spot = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/spot.ply");
    start_rig_holding(dir, seed, (time_scale, exposure_ms), (&spot, "y"))
}

/// [`start_rig_at`] holding `object` (a closed mesh; its up axis `y` or `z`).
pub fn start_rig_holding(
    dir: &Path,
    seed: u64,
    (time_scale, exposure_ms): (&str, &str),
    (object, up): (&Path, &str),
) -> Rig {
    let link = dir.join("ttyTurntable");
    let sock = dir.join("can.sock");
    let control = dir.join("rig.ctl");
    let calib = dir.join("calibration.toml");
    for p in [&link, &sock, &control, &calib] {
        let _ = std::fs::remove_file(p);
    }
    let seed = seed.to_string();
    let s = sim(
        dir,
        "rig",
        &[
            "rig",
            "--object",
            object.to_str().unwrap(),
            "--up",
            up,
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
            time_scale,
            "--heartbeat-ms",
            "50",
            "--exposure-ms",
            exposure_ms,
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
    Rig { sim: s, control }
}

/// The station's config for a scan rig in `dir`: the devices, and `[scan]` with the rig's calibration plus
/// `scan_extra` lines.
pub fn scan_config(dir: &Path, scan_extra: &str) -> String {
    let calib = std::fs::read_to_string(dir.join("calibration.toml")).unwrap();
    format!(
        "{}{calib}capture_dir = \"{}\"\n{}view_file_timeout = \"2s\"\n{scan_extra}\n",
        rig_config(dir),
        dir.join("capture").display(),
        if scan_extra.contains("settle") { "" } else { "settle = \"50ms\"\n" }
    )
}

/// `StartScan` through busctl with `args` (`a{sv}` count and entries); the job's path.
pub fn start_scan(st: &Station, args: &[&str]) -> String {
    // `--`: a negative number among the arguments (a tilt) is not an option.
    let mut a = vec!["--", "call", NAME, ROOT, "org.scanstation.Station1.Manager", "StartScan", "a{sv}"];
    a.extend_from_slice(args);
    let out = st.busctl(&a);
    assert!(out.status.success(), "StartScan failed: {}\n{}", String::from_utf8_lossy(&out.stderr), st.log());
    let text = String::from_utf8_lossy(&out.stdout);
    text.trim().trim_start_matches("o ").trim_matches('"').to_string()
}

/// The one outbox (or quarantine) entry of the finished scan.
pub fn only_entry(dir: &Path) -> PathBuf {
    let v = visible(dir);
    assert_eq!(v.len(), 1, "{}: {v:?}", dir.display());
    dir.join(&v[0])
}

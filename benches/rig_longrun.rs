//! The rig's long run: the real `scanstationd` on a private bus with both simulators as their own processes
//! (the Grbl turntable on a pty at ten times real speed, the scanner node behind a Unix socket), a seeded
//! random fault every 2–4 s for `SCANSTATION_LONGRUN_SECS` (default 600), and after each one a move and a
//! fire. A fault counts as recovered when, within 15 s, the station is back to idle and a move and a fire
//! succeed. Reports the faults injected and recovered, the `Fault` signals seen, the daemon's RSS at the
//! start and the end, and its CPU while idle (30 s without calls, at the start and the end).
//!
//! Needs `dbus-daemon`, `busctl` and `gdbus` (as the daemon tests). Run: `cargo bench --bench rig_longrun`.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use scanstation::geometry::sampling::Rng;

const DAEMON: &str = env!("CARGO_BIN_EXE_scanstationd");
const CLI: &str = env!("CARGO_BIN_EXE_scanstation");
const NAME: &str = "org.scanstation.Station1";
const ROOT: &str = "/org/scanstation/Station1";

struct Proc(Child);

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn spawn(cmd: &mut Command, log: &Path) -> Proc {
    let log = std::fs::File::create(log).unwrap();
    Proc(cmd.stdin(Stdio::piped()).stdout(Stdio::null()).stderr(log).spawn().expect("spawn"))
}

fn wait_for(what: &str, limit: Duration, mut f: impl FnMut() -> bool) -> bool {
    let t = Instant::now();
    while !f() {
        if t.elapsed() > limit {
            eprintln!("{what}: not within {limit:?}");
            return false;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    true
}

struct Rig {
    dir: PathBuf,
    bus: String,
    table: Option<Proc>,
    trigger: Option<Proc>,
}

impl Rig {
    fn start_table(&mut self) {
        let link = self.dir.join("ttyTurntable");
        let ctl = self.dir.join("tt.ctl");
        self.table = Some(spawn(
            Command::new(CLI)
                .args(["sim", "turntable", "--link"])
                .arg(&link)
                .args(["--time-scale", "10", "--control"])
                .arg(&ctl),
            &self.dir.join("sim-turntable.log"),
        ));
        wait_for("turntable sim", Duration::from_secs(5), || link.exists() && ctl.exists());
    }

    fn start_trigger(&mut self) {
        let sock = self.dir.join("can.sock");
        let ctl = self.dir.join("trig.ctl");
        let _ = std::fs::remove_file(&sock);
        self.trigger = Some(spawn(
            Command::new(CLI)
                .args(["sim", "trigger", "--bus"])
                .arg(format!("unix:{}", sock.display()))
                .args(["--heartbeat-ms", "50", "--exposure-ms", "20", "--control"])
                .arg(&ctl),
            &self.dir.join("sim-trigger.log"),
        ));
        wait_for("trigger sim", Duration::from_secs(5), || sock.exists() && ctl.exists());
    }

    fn control(&self, which: &str, line: &str) {
        if let Ok(mut s) = std::os::unix::net::UnixStream::connect(self.dir.join(which)) {
            let _ = writeln!(s, "{line}");
        }
    }

    fn property(&self, path: &str, iface: &str, prop: &str) -> String {
        let out = Command::new("busctl")
            .args(["--address", &self.bus, "get-property", NAME, path, &format!("{NAME}.{iface}"), prop])
            .output()
            .unwrap();
        String::from_utf8_lossy(&out.stdout).trim().to_string()
    }

    fn cli(&self, args: &[&str]) -> bool {
        Command::new(CLI)
            .args(["--json", "rig"])
            .args(args)
            .arg("--session")
            .env("DBUS_SESSION_BUS_ADDRESS", &self.bus)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|s| s.success())
    }

    fn idle(&self) -> bool {
        self.property(ROOT, "Manager", "State") == "s \"idle\""
    }
}

fn proc_stat(pid: u32) -> (f64, f64) {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    let fields: Vec<&str> = stat.rsplit(')').next().unwrap_or("").split_whitespace().collect();
    let ticks = 100.0; // USER_HZ
    let cpu = (fields.get(11).and_then(|s| s.parse::<f64>().ok()).unwrap_or(0.0)
        + fields.get(12).and_then(|s| s.parse::<f64>().ok()).unwrap_or(0.0))
        / ticks;
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    let rss = status
        .lines()
        .find(|l| l.starts_with("VmRSS:"))
        .and_then(|l| l.split_whitespace().nth(1)?.parse::<f64>().ok())
        .unwrap_or(f64::NAN)
        / 1024.0;
    (cpu, rss)
}

/// The daemon's CPU over `secs` seconds without calls, % of one core.
fn idle_cpu(pid: u32, secs: u64) -> f64 {
    let (c0, _) = proc_stat(pid);
    std::thread::sleep(Duration::from_secs(secs));
    let (c1, _) = proc_stat(pid);
    100.0 * (c1 - c0) / secs as f64
}

fn main() {
    let secs: u64 = std::env::var("SCANSTATION_LONGRUN_SECS").ok().and_then(|s| s.parse().ok()).unwrap_or(600);
    let dir = std::env::temp_dir().join(format!("scanstation-rig-longrun-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    // 1. A private bus (session rules), the simulators, the daemon.
    let sock = dir.join("bus");
    std::fs::write(
        dir.join("bus.conf"),
        format!(
            "<busconfig><type>session</type><listen>unix:path={}</listen><auth>EXTERNAL</auth>\
             <policy context=\"default\"><allow user=\"*\"/><allow own=\"*\"/><allow send_destination=\"*\" eavesdrop=\"true\"/><allow eavesdrop=\"true\"/></policy></busconfig>",
            sock.display()
        ),
    )
    .unwrap();
    let _bus = spawn(
        Command::new("dbus-daemon").arg(format!("--config-file={}", dir.join("bus.conf").display())).arg("--nofork"),
        &dir.join("bus.log"),
    );
    assert!(
        wait_for("dbus-daemon", Duration::from_secs(10), || sock.exists()),
        "dbus-daemon (apt-get install dbus-daemon)"
    );
    let bus = format!("unix:path={}", sock.display());
    let mut rig = Rig { dir: dir.clone(), bus: bus.clone(), table: None, trigger: None };
    rig.start_table();
    rig.start_trigger();
    std::fs::write(
        dir.join("scanstation.toml"),
        format!(
            "[daemon]\nbus = \"session\"\nlog_format = \"pretty\"\nwatchdog = false\n[paths]\nspool = \"{}\"\nstate = \"{}\"\n\
             [devices.turntable]\nport = \"{}\"\nreply_timeout = \"500ms\"\nbanner_timeout = \"2s\"\nhome_timeout = \"5s\"\nreconnect_max = \"400ms\"\n\
             [devices.trigger]\ninterface = \"unix:{}\"\nheartbeat = \"50ms\"\nack_timeout = \"500ms\"\nview_timeout = \"2s\"\n",
            dir.join("spool").display(),
            dir.join("state").display(),
            dir.join("ttyTurntable").display(),
            dir.join("can.sock").display()
        ),
    )
    .unwrap();
    let daemon = spawn(
        Command::new(DAEMON).arg("--config").arg(dir.join("scanstation.toml")).env("DBUS_SESSION_BUS_ADDRESS", &bus),
        &dir.join("daemon.log"),
    );
    let pid = daemon.0.id();
    assert!(wait_for("the station idle", Duration::from_secs(20), || rig.idle()), "the daemon did not come up");
    let monitor_log = dir.join("monitor.log");
    let monitor = Proc(
        Command::new("gdbus")
            .args(["monitor", "--address", &bus, "--dest", NAME])
            .stdout(std::fs::File::create(&monitor_log).unwrap())
            .stderr(Stdio::null())
            .spawn()
            .expect("gdbus (apt-get install libglib2.0-bin)"),
    );
    assert!(rig.cli(&["move", "10"]) && rig.cli(&["fire"]), "the first move and fire");
    let (_, rss_start) = proc_stat(pid);
    let cpu_idle_start = idle_cpu(pid, 30);
    eprintln!("start: RSS {rss_start:.1} MiB, idle CPU {cpu_idle_start:.2} %");

    // 2. Faults.
    let mut rng = Rng::new(0x0051_ca11);
    let kinds = [
        "unplug",
        "drop-reply",
        "error 15",
        "alarm 1",
        "stall",
        "silence 500",
        "emcy 0x5000",
        "drop-view",
        "busy",
        "garbage 5",
        "bus-off 300",
        "kill-trigger",
    ];
    let mut injected = std::collections::BTreeMap::<&str, (u32, u32)>::new();
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_secs(secs) {
        std::thread::sleep(Duration::from_millis(2000 + (rng.next_f64() * 2000.0) as u64));
        let kind = kinds[(rng.next_f64() * kinds.len() as f64) as usize % kinds.len()];
        match kind {
            "unplug" => {
                rig.control("tt.ctl", "unplug");
                std::thread::sleep(Duration::from_secs(1));
                rig.control("tt.ctl", "replug");
            }
            "kill-trigger" => {
                rig.trigger = None;
                std::thread::sleep(Duration::from_millis(500));
                rig.start_trigger();
            }
            k if ["drop-reply", "error 15", "alarm 1", "stall"].contains(&k) => {
                rig.control("tt.ctl", k);
                let _ = rig.cli(&["move", &format!("{:.1}", rng.next_f64() * 360.0)]);
            }
            k => {
                rig.control("trig.ctl", k);
                let _ = rig.cli(&["fire"]);
            }
        }
        let e = injected.entry(kind).or_default();
        e.0 += 1;
        // Recovered: idle again, then a move and a fire that succeed.
        let ok = wait_for(kind, Duration::from_secs(15), || {
            rig.idle() && rig.cli(&["move", &format!("{:.1}", rng.next_f64() * 360.0)]) && rig.cli(&["fire"])
        });
        if ok {
            e.1 += 1;
        } else {
            eprintln!("not recovered from {kind}: {}", rig.property(ROOT, "Manager", "Degraded"));
        }
    }
    let cpu_idle_end = idle_cpu(pid, 30);
    let (cpu_total, rss_end) = proc_stat(pid);
    drop(monitor);
    std::thread::sleep(Duration::from_millis(200));
    let faults =
        std::fs::read_to_string(&monitor_log).unwrap_or_default().lines().filter(|l| l.contains(".Fault (")).count();
    let total: (u32, u32) = injected.values().fold((0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
    println!("| fault | injected | recovered |");
    println!("|---|---:|---:|");
    for (k, (i, r)) in &injected {
        println!("| {k} | {i} | {r} |");
    }
    println!("| **all** | **{}** | **{}** |", total.0, total.1);
    println!();
    println!(
        "{secs} s; Fault signals seen: {faults}; daemon RSS {rss_start:.1} MiB at the start, {rss_end:.1} MiB at the end; \
         idle CPU {cpu_idle_start:.2} % of a core at the start, {cpu_idle_end:.2} % at the end; CPU over the whole run {cpu_total:.1} s"
    );
    drop(daemon);
    std::fs::remove_dir_all(&dir).ok();
}

//! The daemon driven only from outside: a private `dbus-daemon`, the real `scanstationd` binary, files
//! dropped into its inbox, `gdbus monitor` / `busctl` as D-Bus clients and the `scanstation` CLI.
//!
//! Needs Debian's `dbus-daemon`, `busctl` and `systemd-analyze` (packages dbus-daemon, systemd), `gdbus`
//! (libglib2.0-bin) and `setpriv` (util-linux); a test fails with the package to install when one is missing.
//! The access test switches to uid 65534 (nobody) and so needs root.

mod common;
mod harness;

use harness::*;

use std::collections::{BTreeMap, BTreeSet};
use std::io::Write;
use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use scanstation::PolyMesh;
use scanstation::geometry::io::write_ply;
use scanstation::geometry::shapes::icosphere;

#[test]
fn inbox_files_become_solids_with_monotonic_progress_and_one_completed_each() {
    need("busctl", "systemd");
    let dir = common::scratch("daemon-inbox");
    let bus = start_bus(&dir, OPEN_POLICY);
    let mut st = Station::new(&dir, &bus, false, "");
    // A file already in the inbox before the daemon starts is picked up too.
    std::fs::create_dir_all(st.inbox()).unwrap();
    std::fs::write(st.inbox().join("early.ply"), sphere_bytes(&dir, 0.9)).unwrap();
    st.start();
    let mon = Monitor::start(&st.bus, dir.join("monitor.txt"));

    drop_renamed(&st.inbox(), "renamed.ply", &sphere_bytes(&dir, 1.0));
    drop_in_place_slowly(&st.inbox(), "slow.ply", &sphere_bytes(&dir, 1.1), 8, Duration::from_millis(150));
    drop_renamed(
        &st.inbox(),
        "broken.ply",
        b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n1 0",
    );
    drop_renamed(&st.inbox(), "notes.txt", b"not a scan");
    st.wait_done(5, Duration::from_secs(180));
    let signals = mon.finish();

    // Outputs: three solids, each a complete bundle with the manifest naming existing files.
    let outbox = visible(&st.spool("outbox"));
    assert_eq!(outbox.len(), 3, "outbox: {outbox:?}\n{}", st.log());
    for stem in ["early", "renamed", "slow"] {
        let d =
            outbox.iter().find(|d| d.starts_with(&format!("{stem}-"))).unwrap_or_else(|| panic!("{stem}: {outbox:?}"));
        let d = st.spool("outbox").join(d);
        let m: serde_json::Value = serde_json::from_slice(&std::fs::read(d.join("manifest.json")).unwrap()).unwrap();
        for kind in ["step", "solid-mesh", "error-map", "report"] {
            let f = m["files"][kind]["file"].as_str().unwrap_or_else(|| panic!("{stem}: manifest lacks {kind}"));
            let len = std::fs::metadata(d.join(f)).unwrap_or_else(|e| panic!("{stem}: {f}: {e}")).len();
            assert_eq!(len, m["files"][kind]["bytes"].as_u64().unwrap(), "{stem}: {f} size");
        }
        let step = std::fs::read_to_string(d.join(format!("{stem}.step"))).unwrap();
        assert!(step.contains("MANIFOLD_SOLID_BREP"), "{stem}: not a solid");
    }
    // Bad files: quarantined with their code, the original kept byte for byte.
    let q = visible(&st.spool("quarantine"));
    assert_eq!(q.len(), 2, "quarantine: {q:?}");
    let broken = st.spool("quarantine").join(q.iter().find(|d| d.starts_with("broken-")).unwrap());
    assert_eq!(error_code_of(&broken), "input.bad-record");
    assert!(std::fs::read(broken.join("broken.ply")).unwrap().ends_with(b"1 0"));
    let notes = st.spool("quarantine").join(q.iter().find(|d| d.starts_with("notes-")).unwrap());
    assert_eq!(error_code_of(&notes), "input.unknown-format");
    assert!(visible(&st.inbox()).is_empty(), "inbox not emptied: {:?}", visible(&st.inbox()));

    // Signals: every job completed exactly once; progress never decreased and reached 1.0 exactly at the end.
    assert_eq!(signals.len(), 5, "jobs seen on the bus: {:?}", signals.keys());
    let mut results = BTreeMap::new();
    for (path, s) in &signals {
        assert_eq!(s.completed.len(), 1, "{path}: Completed {} times", s.completed.len());
        let marker = s.events.iter().position(|e| e.is_none()).unwrap();
        assert_eq!(marker, s.events.len() - 1, "{path}: a Progress change after Completed: {:?}", s.events);
        let values: Vec<f64> = s.events.iter().flatten().copied().collect();
        assert_eq!(values.last(), Some(&1.0), "{path}: the last Progress before Completed is not 1.0: {values:?}");
        assert!(values[..values.len() - 1].iter().all(|v| *v < 1.0), "{path}: 1.0 before the end: {values:?}");
        assert!(values.windows(2).all(|w| w[1] >= w[0]), "{path}: progress went back: {values:?}");
        *results.entry(s.completed[0].clone()).or_insert(0) += 1;
    }
    assert_eq!(results.get(&("succeeded".into(), "".into())), Some(&3), "{results:?}");
    // The successful jobs reported progress along the way, not just the final jump.
    let steps = signals.values().filter(|s| s.completed[0].0 == "succeeded").map(|s| s.events.len()).min().unwrap();
    assert!(steps >= 4, "too few progress updates: {steps}");

    // The CLI and busctl see the same.
    let out = st.cli(&["jobs", "--json"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let states: BTreeSet<String> =
        v["jobs"].as_array().unwrap().iter().map(|j| j["State"].as_str().unwrap().to_string()).collect();
    assert_eq!(states, ["failed", "succeeded"].map(String::from).into());
    assert_eq!(st.property("Manager", ROOT, "JobsSucceeded").as_deref(), Some("t 3"));
    assert_eq!(st.property("Manager", ROOT, "JobsFailed").as_deref(), Some("t 2"));
    assert_eq!(st.property("Manager", ROOT, "State").as_deref(), Some("s \"idle\""));

    // The same content again is skipped as a duplicate, naming the first job.
    drop_renamed(&st.inbox(), "again.ply", &sphere_bytes(&dir, 1.0));
    st.wait_done(6, Duration::from_secs(60));
    let again =
        visible(&st.spool("quarantine")).into_iter().find(|d| d.starts_with("again-")).expect("again quarantined");
    assert_eq!(error_code_of(&st.spool("quarantine").join(again)), "input.duplicate");
}

#[test]
fn submit_wait_and_cancel_through_the_cli() {
    need("busctl", "systemd");
    let dir = common::scratch("daemon-cli");
    let bus = start_bus(&dir, OPEN_POLICY);
    let mut st = Station::new(&dir, &bus, false, "");
    st.start();
    let input = dir.join("part.ply");
    std::fs::write(&input, sphere_bytes(&dir, 2.0)).unwrap();
    let out = st.cli(&["submit", input.to_str().unwrap(), "--vertices", "120", "--wait", "--json"]);
    assert!(out.status.success(), "{}\n{}", String::from_utf8_lossy(&out.stderr), st.log());
    let text = String::from_utf8_lossy(&out.stdout);
    let last: serde_json::Value = serde_json::from_str(text.lines().last().unwrap()).unwrap();
    assert_eq!(last["event"], "completed", "{text}");
    assert_eq!(last["result"], "succeeded");
    assert!(input.exists(), "a submitted file outside the inbox is copied, never moved");

    // Pause: SubmitFile is refused with a named error; resume: accepted again.
    let status = st.cli(&["status", "--json"]);
    assert!(status.status.success());
    Command::new("busctl")
        .args(["--address", &st.bus, "call", NAME, ROOT, &format!("{NAME}.Manager"), "PauseIntake"])
        .status()
        .unwrap();
    let out = st.cli(&["submit", input.to_str().unwrap(), "--json"]);
    assert!(!out.status.success());
    assert!(
        String::from_utf8_lossy(&out.stdout).contains("org.scanstation.Station1.Error.IntakePaused"),
        "{}",
        String::from_utf8_lossy(&out.stdout)
    );
    Command::new("busctl")
        .args(["--address", &st.bus, "call", NAME, ROOT, &format!("{NAME}.Manager"), "ResumeIntake"])
        .status()
        .unwrap();

    // Cancel a running job: it ends `cancelled`, its input in quarantine with code `cancelled`.
    let big = dir.join("big.ply");
    std::fs::write(&big, sphere_bytes(&dir, 3.0)).unwrap();
    let out = st.cli(&["submit", big.to_str().unwrap(), "--vertices", "3000"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let path = String::from_utf8_lossy(&out.stdout).trim().to_string();
    let t = Instant::now();
    while st.property("Job", &path, "State").as_deref() != Some("s \"running\"") {
        assert!(t.elapsed() < Duration::from_secs(30));
        std::thread::sleep(Duration::from_millis(20));
    }
    assert_eq!(st.property("Job", &path, "Cancelable").as_deref(), Some("b true"));
    let out = st.cli(&["cancel", &path]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stdout));
    let done = st.cli(&["watch", &path, "--json"]);
    let text = String::from_utf8_lossy(&done.stdout);
    assert!(text.lines().last().unwrap().contains("\"cancelled\""), "{text}");
    assert_eq!(st.property("Job", &path, "ErrorCode").as_deref(), Some("s \"cancelled\""));
    assert_eq!(st.property("Job", &path, "Progress").as_deref(), Some("d 1"));
    // Cancel after the end is refused with a named error.
    let out = st.cli(&["cancel", &path, "--json"]);
    assert!(String::from_utf8_lossy(&out.stdout).contains("NotCancelable"));
    let hist = Command::new("busctl")
        .args([
            "--address",
            &st.bus,
            "--json=short",
            "call",
            NAME,
            ROOT,
            &format!("{NAME}.Manager"),
            "GetHistory",
            "tu",
            "0",
            "10",
        ])
        .output()
        .unwrap();
    let h: serde_json::Value = serde_json::from_slice(&hist.stdout).unwrap();
    assert_eq!(h["data"][0].as_array().unwrap().len(), 2, "{h}");
}

#[test]
fn kill_9_twenty_times_loses_and_duplicates_nothing() {
    need("busctl", "systemd");
    let dir = common::scratch("daemon-crash");
    let bus = start_bus(&dir, OPEN_POLICY);
    let mut st = Station::new(&dir, &bus, false, "");
    std::fs::create_dir_all(st.inbox()).unwrap();
    let mon = Monitor::start(&bus.address, dir.join("monitor.txt"));
    let n = 8;
    for k in 0..n / 2 {
        drop_renamed(&st.inbox(), &format!("scan{k}.ply"), &sphere_bytes(&dir, 1.0 + 0.1 * k as f64));
    }
    drop_renamed(&st.inbox(), "junk.ply", b"ply\nformat binary_little_endian 1.0\nelement vertex 99\n");
    // A seeded sequence of kill moments between 0.2 s and 4 s after each start (a job takes about 1.5 s, so
    // kills land in claiming, in every stage, in publication and between jobs); the other half of the
    // inputs arrives while the rounds go on.
    let mut seed: u64 = 0x5ca9_57a7;
    for round in 0..20 {
        st.start();
        if round % 3 == 1 && round / 3 < n / 2 {
            let k = n / 2 + round / 3;
            drop_renamed(&st.inbox(), &format!("scan{k}.ply"), &sphere_bytes(&dir, 1.0 + 0.1 * k as f64));
        }
        seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        let ms = 200 + (seed >> 33) % 3800;
        std::thread::sleep(Duration::from_millis(ms));
        st.kill9();
        eprintln!("round {round}: killed after {ms} ms");
    }
    st.start();
    st.wait_done(n + 1, Duration::from_secs(240));
    mon.wait_for(".Job.Completed", n + 1, Duration::from_secs(10));
    let signals = mon.finish();

    let entries: Vec<String> =
        visible(&st.spool("outbox")).into_iter().chain(visible(&st.spool("quarantine"))).collect();
    for k in 0..n {
        let hits = entries.iter().filter(|e| e.starts_with(&format!("scan{k}-"))).count();
        assert_eq!(hits, 1, "scan{k}: {hits} outputs/quarantine entries in {entries:?}");
    }
    assert_eq!(entries.iter().filter(|e| e.starts_with("junk-")).count(), 1, "{entries:?}");
    assert_eq!(entries.len(), n + 1, "{entries:?}");
    for d in ["outbox", "quarantine"] {
        let hidden: Vec<_> = std::fs::read_dir(st.spool(d))
            .unwrap()
            .flatten()
            .filter(|e| e.file_name().to_string_lossy().starts_with('.'))
            .collect();
        assert!(hidden.is_empty(), "{d}: half-built directories left: {hidden:?}");
    }
    assert!(visible(&st.inbox()).is_empty());
    // Every job that finished said so exactly once (resumed jobs finish under their first id).
    let completed: usize = signals.values().map(|s| s.completed.len()).sum();
    assert_eq!(completed, n + 1, "Completed signals: {signals:?}");
    assert!(signals.values().all(|s| s.completed.len() <= 1), "{signals:?}");
}

#[test]
fn without_resume_an_interrupted_job_fails_as_interrupted_after_restart() {
    need("busctl", "systemd");
    let dir = common::scratch("daemon-interrupted");
    let bus = start_bus(&dir, OPEN_POLICY);
    let mut st = Station::new(&dir, &bus, false, "resume = false");
    st.start();
    let mon = Monitor::start(&bus.address, dir.join("monitor.txt"));
    let input = dir.join("long.ply");
    std::fs::write(&input, sphere_bytes(&dir, 5.0)).unwrap();
    let out = st.cli(&["submit", input.to_str().unwrap(), "--vertices", "3000"]);
    let path = String::from_utf8_lossy(&out.stdout).trim().to_string();
    let t = Instant::now();
    while st.property("Job", &path, "State").as_deref() != Some("s \"running\"") {
        assert!(t.elapsed() < Duration::from_secs(30));
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_millis(200));
    st.kill9();
    st.start();
    st.wait_done(1, Duration::from_secs(30));
    mon.wait_for(".Job.Completed", 1, Duration::from_secs(10));
    let signals = mon.finish();
    let s = &signals[&path];
    assert_eq!(s.completed, vec![("failed".to_string(), "interrupted".to_string())], "{s:?}");
    let q = visible(&st.spool("quarantine"));
    assert_eq!(error_code_of(&st.spool("quarantine").join(&q[0])), "interrupted");
    assert!(st.spool("quarantine").join(&q[0]).join("long.ply").exists());
}

#[test]
fn unprivileged_callers_read_but_cannot_change_anything() {
    need("busctl", "systemd");
    need("setpriv", "util-linux");
    assert_eq!(
        Command::new("id")
            .arg("-u")
            .output()
            .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
            .ok()
            .as_deref(),
        Some("0"),
        "this test switches to uid 65534 and must run as root"
    );
    for (label, policy, refusal) in [
        ("policy", system_policy(), "org.freedesktop.DBus.Error.AccessDenied"),
        ("daemon check", OPEN_POLICY.to_string(), "org.scanstation.Station1.Error.AccessDenied"),
    ] {
        let dir = common::scratch(&format!("daemon-access-{}", label.replace(' ', "-")));
        std::fs::set_permissions(&dir, std::os::unix::fs::PermissionsExt::from_mode(0o755)).unwrap();
        let bus = start_bus(&dir, &policy);
        let mut st = Station::new(&dir, &bus, true, "");
        st.start();
        let input = dir.join("x.ply");
        std::fs::write(&input, sphere_bytes(&dir, 1.0)).unwrap();
        let as_nobody = |args: &[&str]| {
            Command::new("setpriv")
                .args(["--reuid=65534", "--regid=65534", "--clear-groups", "busctl", "--address", &st.bus])
                .args(args)
                .output()
                .unwrap()
        };
        let read = as_nobody(&["get-property", NAME, ROOT, &format!("{NAME}.Manager"), "State"]);
        assert!(read.status.success(), "{label}: nobody cannot read: {}", String::from_utf8_lossy(&read.stderr));
        let intro = as_nobody(&["introspect", NAME, ROOT]);
        assert!(intro.status.success(), "{label}: nobody cannot introspect");
        let hist = as_nobody(&["call", NAME, ROOT, &format!("{NAME}.Manager"), "GetHistory", "tu", "0", "5"]);
        assert!(
            hist.status.success(),
            "{label}: nobody cannot read the history: {}",
            String::from_utf8_lossy(&hist.stderr)
        );
        for call in [
            vec![
                "call",
                NAME,
                ROOT,
                &format!("{NAME}.Manager") as &str,
                "SubmitFile",
                "sa{sv}",
                input.to_str().unwrap(),
                "0",
            ],
            vec!["call", NAME, ROOT, &format!("{NAME}.Manager"), "PauseIntake"],
        ] {
            let out = as_nobody(&call);
            assert!(!out.status.success(), "{label}: nobody may {}", call[4]);
        }
        // The error's name (gdbus prints it; busctl only the message).
        let out = Command::new("setpriv")
            .args([
                "--reuid=65534",
                "--regid=65534",
                "--clear-groups",
                "gdbus",
                "call",
                "--address",
                &st.bus,
                "--dest",
                NAME,
                "--object-path",
                ROOT,
                "--method",
                &format!("{NAME}.Manager.PauseIntake"),
            ])
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(refusal), "{label}: expected {refusal}, got {err}");
        // Root may.
        let ok = Command::new("busctl")
            .args([
                "--address",
                &st.bus,
                "call",
                NAME,
                ROOT,
                &format!("{NAME}.Manager"),
                "SubmitFile",
                "sa{sv}",
                input.to_str().unwrap(),
                "0",
            ])
            .output()
            .unwrap();
        assert!(ok.status.success(), "{label}: root cannot submit: {}", String::from_utf8_lossy(&ok.stderr));
        assert_eq!(st.property("Manager", ROOT, "State").as_deref().map(|s| s != "s \"paused\""), Some(true));
    }
}

/// `<interface name="org.scanstation…">…</interface>` blocks of an introspection XML, by name.
fn our_interfaces(xml: &str) -> BTreeMap<String, String> {
    let mut out = BTreeMap::new();
    let mut rest = xml;
    while let Some(i) = rest.find("<interface name=\"org.scanstation.") {
        let end = rest[i..].find("</interface>").unwrap() + i + "</interface>".len();
        let block = &rest[i..end];
        let name = block[17..].split('"').next().unwrap().to_string();
        let lines: Vec<&str> = block.lines().map(str::trim).filter(|l| !l.is_empty()).collect();
        out.insert(name, lines.join("\n"));
        rest = &rest[end..];
    }
    out
}

#[test]
fn packaging_matches_the_code() {
    need("busctl", "systemd");
    need("systemd-analyze", "systemd");
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = common::scratch("daemon-packaging");
    let bus = start_bus(&dir, OPEN_POLICY);
    // Devices configured (their simulators need not run: the objects are exported either way).
    let mut st = Station::new(&dir, &bus, false, &rig_config(&dir));
    st.start();
    let input = dir.join("x.ply");
    std::fs::write(&input, sphere_bytes(&dir, 1.0)).unwrap();
    let job = String::from_utf8_lossy(&st.cli(&["submit", input.to_str().unwrap()]).stdout).trim().to_string();
    let mut live = String::new();
    for path in [ROOT, job.as_str(), TURNTABLE, TRIGGER] {
        let out = Command::new("busctl")
            .args(["--address", &st.bus, "introspect", "--xml-interface", NAME, path])
            .output()
            .unwrap();
        assert!(out.status.success(), "introspect {path}");
        live.push_str(&String::from_utf8_lossy(&out.stdout));
    }
    let live = our_interfaces(&live);
    assert_eq!(
        live.keys().collect::<Vec<_>>(),
        [
            "org.scanstation.Station1.Job",
            "org.scanstation.Station1.Manager",
            "org.scanstation.Station1.Trigger",
            "org.scanstation.Station1.Turntable"
        ]
    );
    let committed_path = root.join("systemd/org.scanstation.Station1.xml");
    if std::env::var_os("SCANSTATION_REGENERATE").is_some() {
        let mut s = String::from(
            "<!-- The station's D-Bus API as the daemon introspects it (tests/daemon.rs checks it is current;\n     SCANSTATION_REGENERATE=1 cargo test --test daemon packaging rewrites it). -->\n<node>\n",
        );
        for block in live.values() {
            s.push_str(block);
            s.push('\n');
        }
        s.push_str("</node>\n");
        std::fs::write(&committed_path, s).unwrap();
    }
    let committed = our_interfaces(&std::fs::read_to_string(&committed_path).unwrap());
    assert_eq!(
        committed, live,
        "systemd/org.scanstation.Station1.xml differs from the live API (SCANSTATION_REGENERATE=1 rewrites it)"
    );

    // Every interface and member the policy names exists.
    let policy = std::fs::read_to_string(root.join("systemd/org.scanstation.Station1.conf")).unwrap();
    let all_xml: String = committed.values().cloned().collect();
    let standard = [
        "org.freedesktop.DBus.Introspectable",
        "org.freedesktop.DBus.Peer",
        "org.freedesktop.DBus.Properties",
        "org.freedesktop.DBus.ObjectManager",
    ];
    let mut checked = 0;
    for rule in policy.split("<allow ").skip(1) {
        let attr = |k: &str| rule.split(&format!("{k}=\"")).nth(1).map(|s| s.split('"').next().unwrap().to_string());
        if let Some(iface) = attr("send_interface") {
            if iface.starts_with("org.scanstation.") {
                assert!(committed.contains_key(&iface), "policy names unknown interface {iface}");
                if let Some(m) = attr("send_member") {
                    assert!(
                        committed[&iface].contains(&format!("<method name=\"{m}\"")),
                        "policy names {iface}.{m}, which does not exist"
                    );
                    checked += 1;
                }
            } else {
                assert!(standard.contains(&iface.as_str()), "policy names {iface}");
            }
        }
        if let Some(own) = attr("own") {
            assert_eq!(own, NAME);
        }
    }
    assert!(checked >= 1 && all_xml.contains("SubmitFile"));

    // The unit: verified by systemd-analyze (with ExecStart pointing at the built binary, since
    // /usr/bin/scanstationd is not installed here), and its paths agree with the shipped config.
    let unit = std::fs::read_to_string(root.join("systemd/scanstation.service")).unwrap();
    assert!(unit.contains("Type=notify") && unit.contains("WatchdogSec="));
    // The rig: CAN sockets, USB serial ports, and the group that owns them.
    let families = unit.lines().find_map(|l| l.strip_prefix("RestrictAddressFamilies=")).unwrap_or("");
    assert!(families.split_whitespace().any(|f| f == "AF_CAN"), "the unit must allow AF_CAN: {families}");
    for dev in ["DeviceAllow=char-ttyUSB rw", "DeviceAllow=char-ttyACM rw", "SupplementaryGroups=dialout"] {
        assert!(unit.lines().any(|l| l == dev), "the unit must keep {dev}");
    }
    let udev = std::fs::read_to_string(root.join("systemd/70-scanstation-turntable.rules")).unwrap();
    assert!(udev.contains("SYMLINK+=\"turntable\"") && udev.contains("GROUP=\"dialout\""));
    let udir = dir.join("unit");
    std::fs::create_dir_all(&udir).unwrap();
    std::fs::write(udir.join("scanstation.service"), unit.replace("/usr/bin/scanstationd", DAEMON)).unwrap();
    let out = Command::new("systemd-analyze").arg("verify").arg(udir.join("scanstation.service")).output().unwrap();
    assert!(
        out.status.success() && out.stderr.is_empty(),
        "systemd-analyze verify: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let cfg = scanstation::daemon::config::Config::load(&root.join("config/scanstation.toml")).unwrap();
    assert!(unit.contains(&format!("ReadWritePaths={}", cfg.spool.display())), "ReadWritePaths is not the spool");
    assert_eq!(
        Some(cfg.state.file_name().unwrap().to_str().unwrap()),
        unit.lines().find_map(|l| l.strip_prefix("StateDirectory="))
    );
    assert!(
        unit.contains("--config /etc/scanstation/scanstation.toml")
            && unit.contains("ConfigurationDirectory=scanstation")
    );
    let mem_high = unit.lines().find_map(|l| l.strip_prefix("MemoryHigh=")).unwrap();
    let high = scanstation::daemon::config::parse_size(mem_high).unwrap();
    assert!(cfg.memory_budget < high, "the memory budget must stay below MemoryHigh");
}

/// The trust issue's gate: a solid that misses its accuracy bound is never published as a success. The job
/// fails with `quality.rms`, and its quarantine entry holds the input, every artifact (STEP, solid mesh,
/// error map, report with `"status": "failed"`) and `error.json`; the same scan with `accept_degraded = true`
/// in its sidecar is published, its report saying `degraded`.
#[test]
fn a_solid_that_misses_a_quality_gate_is_quarantined_with_its_artifacts() {
    need("busctl", "systemd");
    let dir = common::scratch("daemon-quality");
    let bus = start_bus(&dir, OPEN_POLICY);
    // No 100-vertex solid of a sphere is within 0.0001 % of its diagonal.
    let mut st = Station::new(&dir, &bus, false, "max_rms_pct = 0.0001");
    st.start();
    drop_renamed(&st.inbox(), "coarse.ply", &sphere_bytes(&dir, 1.0));
    std::fs::write(st.inbox().join("kept.job.toml"), "accept_degraded = true\n").unwrap();
    drop_renamed(&st.inbox(), "kept.ply", &sphere_bytes(&dir, 1.2));
    st.wait_done(2, Duration::from_secs(120));

    let q = visible(&st.spool("quarantine"));
    assert_eq!(q.len(), 1, "quarantine: {q:?}\n{}", st.log());
    let entry = st.spool("quarantine").join(&q[0]);
    assert!(q[0].starts_with("coarse-"), "{q:?}");
    assert_eq!(error_code_of(&entry), "quality.rms");
    let files = visible(&entry);
    for f in
        ["coarse.ply", "coarse.step", "coarse.solid.ply", "coarse.error-map.ply", "coarse.report.json", "error.json"]
    {
        assert!(files.iter().any(|x| x == f), "quarantine lacks {f}: {files:?}");
    }
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(entry.join("coarse.report.json")).unwrap()).unwrap();
    assert_eq!(report["status"], "failed");
    let rms = report["convert"]["gates"].as_array().unwrap().iter().find(|g| g["name"] == "rms").unwrap().clone();
    assert_eq!(rms["passed"], false, "{rms}");
    assert!(rms["value"].as_f64().unwrap() > 0.0001, "{rms}");
    let error: serde_json::Value = serde_json::from_slice(&std::fs::read(entry.join("error.json")).unwrap()).unwrap();
    assert!(error["message"].as_str().unwrap().contains("bound 0.0001 %"), "{error}");
    // Its page shows why, with the pictures of the solid that missed the gate, and the gates as measured.
    let page = entry.join("coarse.report.html");
    let seen = common::browser_check(&page, "daemon-quality-quarantine", 1280);
    common::assert_safe_page(&page, &seen, 5);
    common::assert_gates_match(&page, &seen, &report["convert"]["gates"]);

    let out = visible(&st.spool("outbox"));
    assert_eq!(out.len(), 1, "outbox: {out:?}");
    assert!(out[0].starts_with("kept-"), "{out:?}");
    let published = st.spool("outbox").join(&out[0]);
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(published.join("kept.report.json")).unwrap()).unwrap();
    assert_eq!(report["status"], "degraded", "{}", report["convert"]["gates"]);
    assert_eq!(st.property("Manager", ROOT, "JobsFailed").as_deref(), Some("t 1"));
    assert_eq!(st.property("Manager", ROOT, "JobsSucceeded").as_deref(), Some("t 1"));
}

/// The SHA-256 (hex) of a file.
fn sha256_hex(p: &Path) -> String {
    use sha2::Digest;
    sha2::Sha256::digest(std::fs::read(p).unwrap_or_else(|e| panic!("{}: {e}", p.display())))
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// A string property as busctl prints it (`s "…"`), unquoted.
fn string_property(st: &Station, path: &str, prop: &str) -> String {
    let v = st.property("Job", path, prop).unwrap_or_else(|| panic!("{path}: no {prop}"));
    v.strip_prefix("s \"").and_then(|v| v.strip_suffix('"')).unwrap_or_else(|| panic!("{prop}: {v}")).to_string()
}

/// Every job has its page: a published job's bundle lists the page, the thumbnail and the pictures in its
/// manifest, with their hashes, and the Job's `ReportFile` and `Thumbnail` name them; a quarantined job's
/// page says why. A file named like markup shows its name as text in a real browser, runs nothing and
/// fetches nothing; `scanstation report` makes the same page again.
#[test]
fn every_job_has_its_page_and_a_name_of_markup_stays_text() {
    need("busctl", "systemd");
    let dir = common::scratch("daemon-pages");
    let bus = start_bus(&dir, OPEN_POLICY);
    let mut st = Station::new(&dir, &bus, false, "");
    st.start();
    let hostile = "<img src=x onerror=alert(1)>.ply";
    drop_renamed(&st.inbox(), hostile, &sphere_bytes(&dir, 1.0));
    drop_renamed(
        &st.inbox(),
        "broken.ply",
        b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n0\n1",
    );
    st.wait_done(2, Duration::from_secs(180));
    let out = st.cli(&["jobs", "--json"]);
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let job = |input: &str| {
        let j = v["jobs"]
            .as_array()
            .unwrap()
            .iter()
            .find(|j| j["Input"] == input)
            .unwrap_or_else(|| panic!("{input}: {v}"));
        format!("{ROOT}/jobs/{}", j["Id"].as_str().unwrap())
    };

    // The published job: the page, the thumbnail and the pictures, in the manifest with their hashes.
    let path = job(hostile);
    let page = std::path::PathBuf::from(string_property(&st, &path, "ReportFile"));
    let thumb = std::path::PathBuf::from(string_property(&st, &path, "Thumbnail"));
    let bundle = page.parent().unwrap().to_path_buf();
    assert!(bundle.starts_with(st.spool("outbox")), "{}", page.display());
    let m: serde_json::Value = serde_json::from_slice(&std::fs::read(bundle.join("manifest.json")).unwrap()).unwrap();
    for kind in ["report-html", "thumbnail", "deviation", "histogram", "net", "faces"] {
        let f = m["files"][kind]["file"].as_str().unwrap_or_else(|| panic!("the manifest lacks {kind}: {m}"));
        assert_eq!(m["files"][kind]["sha256"], sha256_hex(&bundle.join(f)), "{kind}: {f}");
    }
    assert_eq!(bundle.join(m["files"]["report-html"]["file"].as_str().unwrap()), page);
    assert_eq!(bundle.join(m["files"]["thumbnail"]["file"].as_str().unwrap()), thumb);
    let outputs = st.property("Job", &path, "Outputs").unwrap();
    assert!(outputs.contains("\"report-html\"") && outputs.contains("\"thumbnail\""), "{outputs}");
    let seen = common::browser_check(&page, "daemon-markup-name", 1280);
    common::assert_safe_page(&page, &seen, 5);
    assert_eq!(seen["title"], hostile, "the name is shown as text");
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(bundle.join(m["files"]["report"]["file"].as_str().unwrap())).unwrap())
            .unwrap();
    common::assert_gates_match(&page, &seen, &report["convert"]["gates"]);
    let html = std::fs::read_to_string(&page).unwrap();
    assert!(!html.contains("<img src=x"), "the name reached the page as markup");
    // Made again from the bundle: the bytes the manifest hashed.
    let again = Command::new(CLI).arg("report").arg(&bundle).output().unwrap();
    assert!(again.status.success(), "{}", String::from_utf8_lossy(&again.stderr));
    assert_eq!(sha256_hex(&page), m["files"]["report-html"]["sha256"], "the page made again differs");

    // The quarantined job: its page says why; no solid, so no thumbnail.
    let path = job("broken.ply");
    let page = std::path::PathBuf::from(string_property(&st, &path, "ReportFile"));
    assert!(page.starts_with(st.spool("quarantine")), "{}", page.display());
    assert_eq!(string_property(&st, &path, "Thumbnail"), "");
    let seen = common::browser_check(&page, "daemon-quarantined", 1280);
    common::assert_safe_page(&page, &seen, 0);
    assert_eq!(error_code_of(page.parent().unwrap()), "input.bad-header");
    let html = std::fs::read_to_string(&page).unwrap();
    assert!(html.contains("id=\"why\"") && html.contains("input.bad-header"), "the page says why");
}

#[test]
fn a_job_that_cannot_fit_the_memory_budget_fails_without_exceeding_it() {
    need("busctl", "systemd");
    let dir = common::scratch("daemon-memory");
    let bus = start_bus(&dir, OPEN_POLICY);
    let budget_mib = 48;
    let mut st = Station::with_memory_budget(&dir, &bus, budget_mib);
    st.start();
    let big = dir.join("big.ply");
    write_ply(&big, &PolyMesh::from(icosphere(1.0, 8, [0.0; 3])), &Default::default(), &[]).unwrap();
    let out = st.cli(&["submit", big.to_str().unwrap(), "--wait", "--json"]);
    let text = String::from_utf8_lossy(&out.stdout);
    let last: serde_json::Value = serde_json::from_str(text.lines().last().unwrap()).unwrap();
    assert_eq!(last["error_code"], "resource.memory", "{text}\n{}", st.log());
    let hwm_kib = st.peak_rss_kib();
    eprintln!("daemon peak RSS {:.1} MiB with a budget of {budget_mib} MiB", hwm_kib as f64 / 1024.0);
    assert!(hwm_kib < budget_mib * 1024, "peak RSS {hwm_kib} KiB exceeds the {budget_mib} MiB budget");
    let q = visible(&st.spool("quarantine"));
    assert_eq!(error_code_of(&st.spool("quarantine").join(&q[0])), "resource.memory");
}

#[test]
fn config_errors_name_the_key_and_stop_start_up() {
    let dir = common::scratch("daemon-config");
    let bad = common::file(
        &dir,
        "bad.toml",
        "[paths]\nspool = \"/tmp/x\"\nstate = \"/tmp/y\"\n[limits]\nmemory_budget = \"lots\"\n",
    );
    let out = Command::new(DAEMON).arg("--config").arg(&bad).output().unwrap();
    assert_eq!(out.status.code(), Some(78));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("limits.memory_budget") && err.contains("lots"), "{err}");
    let unknown = common::file(
        &dir,
        "unknown.toml",
        "[paths]\nspool = \"/tmp/x\"\nstate = \"/tmp/y\"\n[watch]\nsettel = \"2s\"\n",
    );
    let err = String::from_utf8_lossy(&Command::new(DAEMON).arg("--config").arg(&unknown).output().unwrap().stderr)
        .to_string();
    assert!(err.contains("settel"), "{err}");
    // The rig's sections: each bad value names its key.
    for (body, key) in [
        ("[devices.turntable]\nbaud = 115200\n", "devices.turntable.port"),
        ("[devices.turntable]\nport = \"ttyUSB0\"\n", "devices.turntable.port"),
        ("[devices.turntable]\nport = \"/dev/turntable\"\nhoming = \"maybe\"\n", "devices.turntable.homing"),
        ("[devices.turntable]\nport = \"/dev/turntable\"\nspeed = -1\n", "devices.turntable.speed"),
        ("[devices.trigger]\ninterface = \"can0\"\nnode = 200\n", "devices.trigger.node"),
        ("[devices.trigger]\ninterface = \"unix:relative.sock\"\n", "devices.trigger.interface"),
        ("[devices.trigger]\ninterface = \"can0\"\nheartbeat = \"1ms\"\n", "devices.trigger.heartbeat"),
        ("[devices.trigger]\ninterface = \"can0\"\nbitrate = 500000\n", "bitrate"),
        ("[pipeline]\nmax_vertices = 4\n", "pipeline.max_vertices"),
        ("[pipeline]\nvertices = 4\n", "pipeline.vertices"),
    ] {
        let f = common::file(&dir, "rig.toml", format!("[paths]\nspool = \"/tmp/x\"\nstate = \"/tmp/y\"\n{body}"));
        let out = Command::new(DAEMON).arg("--config").arg(&f).arg("--check-config").output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(78), "{body}: {err}");
        assert!(err.contains(key), "{body}: expected {key} in {err}");
    }
    let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/scanstation.toml");
    let out = Command::new(DAEMON).arg("--config").arg(&shipped).arg("--check-config").output().unwrap();
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("\"memory_budget\": 6442450944") && text.contains("digest "), "{text}");
    // The shipped station converts to the deviation goal (no exact count) under its cap.
    assert!(text.contains("\"vertices\": null") && text.contains("\"max_vertices\": 22500"), "{text}");
    // No device by default: a watch-folder-only station.
    assert!(text.contains("\"turntable\": null") && text.contains("\"trigger\": null"), "{text}");
    // A spool that cannot be created is a clear start-up error.
    let cfg = common::file(
        &dir,
        "ro.toml",
        "[daemon]\nbus = \"session\"\n[paths]\nspool = \"/proc/scanstation-spool\"\nstate = \"/tmp/y\"\n",
    );
    let out = Command::new(DAEMON).arg("--config").arg(&cfg).output().unwrap();
    assert!(!out.status.success());
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("/proc/scanstation-spool"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// The hostile-input issue: a gzip bomb and a file whose one line runs 2 GB are quarantined with their
/// codes, the daemon's peak RSS stays under its memory budget, and the next good file is converted.
#[test]
fn a_gzip_bomb_and_an_endless_line_are_quarantined_within_the_budget() {
    need("busctl", "systemd");
    let dir = common::scratch("daemon-hostile");
    let bus = start_bus(&dir, OPEN_POLICY);
    let budget_mib = 96;
    let mut st = Station::with_memory_budget(&dir, &bus, budget_mib);
    st.start();
    // 2.3 GB of valid-looking records in 1 MiB gzip members (about 3 MB on disk).
    let block: Vec<u8> = b"0 0 0\n".iter().copied().cycle().take((1 << 20) / 6 * 6).collect();
    let member = common::gz(&block);
    let bomb: Vec<u8> = std::iter::repeat_n(&member[..], 2300).flatten().copied().collect();
    drop_renamed(&st.inbox(), "bomb.xyz.gz", &bomb);
    // One line of 2 GB: a sparse file, renamed into the inbox.
    let part = st.inbox().join("endless.obj.part");
    let mut f = std::fs::File::create(&part).unwrap();
    f.write_all(b"v ").unwrap();
    f.set_len(2_000_000_000).unwrap();
    drop(f);
    std::fs::rename(&part, st.inbox().join("endless.obj")).unwrap();
    st.wait_done(2, Duration::from_secs(120));
    drop_renamed(&st.inbox(), "good.ply", &sphere_bytes(&dir, 1.0));
    st.wait_done(3, Duration::from_secs(120));

    let q = visible(&st.spool("quarantine"));
    assert_eq!(q.len(), 2, "quarantine: {q:?}\n{}", st.log());
    for entry in &q {
        let code = error_code_of(&st.spool("quarantine").join(entry));
        if entry.starts_with("bomb-") {
            assert!(["input.decompression-bomb", "resource.memory"].contains(&code.as_str()), "{entry}: {code}");
            let kept = std::fs::metadata(st.spool("quarantine").join(entry).join("bomb.xyz.gz")).unwrap().len();
            assert_eq!(kept, bomb.len() as u64, "the bomb is kept whole in quarantine");
        } else {
            assert!(entry.starts_with("endless-"), "{q:?}");
            assert_eq!(code, "input.bad-record", "{entry}");
        }
    }
    let out = visible(&st.spool("outbox"));
    assert!(out.len() == 1 && out[0].starts_with("good-"), "outbox: {out:?}\n{}", st.log());
    let hwm_kib = st.peak_rss_kib();
    eprintln!("daemon peak RSS {:.1} MiB with a budget of {budget_mib} MiB", hwm_kib as f64 / 1024.0);
    assert!(hwm_kib < budget_mib * 1024, "peak RSS {hwm_kib} KiB exceeds the {budget_mib} MiB budget");
}

/// A point cloud dropped into the inbox (an XYZ file without normals) is reconstructed and converted like a
/// mesh: its bundle lands in the outbox, and its report carries the reconstruction.
#[test]
fn a_point_cloud_in_the_inbox_becomes_a_solid() {
    need("busctl", "systemd");
    let dir = common::scratch("daemon-cloud");
    let bus = start_bus(&dir, OPEN_POLICY);
    let mut st = Station::new(&dir, &bus, false, "");
    st.start();
    let sphere = icosphere(1.0, 4, [0.0; 3]);
    let xyz: String = sphere.positions.iter().map(|p| format!("{} {} {}\n", p[0], p[1], p[2])).collect();
    drop_renamed(&st.inbox(), "ball.xyz", xyz.as_bytes());
    st.wait_done(1, Duration::from_secs(120));
    let out = visible(&st.spool("outbox"));
    assert!(out.len() == 1 && out[0].starts_with("ball-"), "outbox: {out:?}\n{}", st.log());
    let bundle = st.spool("outbox").join(&out[0]);
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(bundle.join("ball.report.json")).unwrap()).unwrap();
    assert_eq!(report["convert"]["reconstruct"]["report"]["points"], 2562, "{}", report["convert"]["reconstruct"]);
    assert!(bundle.join("ball.step").is_file(), "{:?}", visible(&bundle));
}

/// A scan set renamed into the inbox as a directory (four views of a sphere on a turntable, their table
/// angles in `scanset.toml`) becomes one job: fused, reconstructed and converted, its bundle in the outbox
/// with the fusion in the report; the same views as an E57 file too. A directory holding no scan set goes to quarantine whole, with
/// `input.no-geometry`, its files kept.
#[test]
fn a_scan_set_directory_in_the_inbox_becomes_one_solid() {
    need("busctl", "systemd");
    let dir = common::scratch("daemon-scanset");
    let bus = start_bus(&dir, OPEN_POLICY);
    let mut st = Station::new(&dir, &bus, false, "");
    st.start();
    let sphere = icosphere(1.0, 5, [0.0; 3]);
    let set = dir.join("ball-set");
    std::fs::create_dir_all(&set).unwrap();
    let mut manifest = String::from("[axis]\npoint = [0.0, 0.0, -3.0]\ndirection = [0.0, 1.0, 0.0]\n");
    for k in 0..4 {
        // The table turned by θ about its vertical axis 3 units in front of the scanner, which sits at the
        // origin looking down −z and sees what faces it.
        let t = (90.0 * k as f64).to_radians();
        let xyz: String = sphere
            .positions
            .iter()
            .map(|p| p.map(f64::from))
            .map(|p| [t.cos() * p[0] + t.sin() * p[2], p[1], -t.sin() * p[0] + t.cos() * p[2]])
            .filter(|q| q[2] > 0.4)
            .map(|q| [q[0], q[1], q[2] - 3.0])
            .map(|q| format!("{} {} {}\n", q[0], q[1], q[2]))
            .collect();
        std::fs::write(set.join(format!("v{k}.xyz")), xyz).unwrap();
        manifest += &format!("\n[[view]]\nfile = \"v{k}.xyz\"\nangle_deg = {}\n", 90 * k);
    }
    std::fs::write(set.join("scanset.toml"), manifest).unwrap();
    // The same views as an E57 file (one point cloud per view, its pose as the cloud's transform).
    let views = scanstation::geometry::io::scanset::read_scan_set(&set, &Default::default()).unwrap();
    let listed: Vec<_> = views.iter().map(|v| (v.name.clone(), v.pose, v.points.clone())).collect();
    scanstation::geometry::io::e57::write_e57(&dir.join("ball.e57.part"), &listed).unwrap();
    std::fs::rename(dir.join("ball.e57.part"), st.inbox().join("ball.e57")).unwrap();
    std::fs::rename(&set, st.inbox().join("ball-set")).unwrap();
    let junk = dir.join("holiday-photos");
    std::fs::create_dir_all(&junk).unwrap();
    std::fs::write(junk.join("a.txt"), "not a scan").unwrap();
    std::fs::rename(&junk, st.inbox().join("holiday-photos")).unwrap();
    st.wait_done(3, Duration::from_secs(240));
    let mut out = visible(&st.spool("outbox"));
    out.sort();
    assert!(
        out.len() == 2 && out[0].starts_with("ball-") && out[1].starts_with("ball-set-"),
        "outbox: {out:?}\n{}",
        st.log()
    );
    let e57: serde_json::Value =
        serde_json::from_slice(&std::fs::read(st.spool("outbox").join(&out[0]).join("ball.report.json")).unwrap())
            .unwrap();
    assert_eq!(e57["convert"]["reconstruct"]["fusion"]["views"].as_array().map(Vec::len), Some(4), "ball.e57");
    let bundle = st.spool("outbox").join(&out[1]);
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(bundle.join("ball-set.report.json")).unwrap()).unwrap();
    let fusion = &report["convert"]["reconstruct"]["fusion"];
    assert_eq!(fusion["views"].as_array().map(Vec::len), Some(4), "{fusion}");
    assert!(bundle.join("ball-set.step").is_file(), "{:?}", visible(&bundle));
    let q = visible(&st.spool("quarantine"));
    assert!(q.len() == 1 && q[0].starts_with("holiday-photos-"), "quarantine: {q:?}\n{}", st.log());
    let qdir = st.spool("quarantine").join(&q[0]);
    assert!(qdir.join("holiday-photos/a.txt").is_file(), "the directory is kept whole: {:?}", visible(&qdir));
    let err: serde_json::Value = serde_json::from_slice(&std::fs::read(qdir.join("error.json")).unwrap()).unwrap();
    assert_eq!(err["error_code"], "input.no-geometry", "{err}");
    assert!(visible(&st.inbox()).is_empty(), "inbox: {:?}", visible(&st.inbox()));
}

/// The reconstruction issue's acceptance on real data (corpus suite, `.ci/run`): the Stanford bunny's ten
/// range scans with `bun.conf`, renamed into the inbox as one directory, come out as one outbox bundle whose
/// solid passes every quality gate, the fusion's ten views in its report.
#[cfg(feature = "corpus")]
#[test]
fn corpus_the_bunny_scan_set_in_the_inbox_becomes_a_solid() {
    need("busctl", "systemd");
    let scans = common::shared_data().join("bunny/scans");
    assert!(
        scans.join("bun.conf").is_file(),
        "{}: the shared data is missing (SCANSTATION_SHARED_DATA)",
        scans.display()
    );
    let dir = common::scratch("daemon-bunny");
    let bus = start_bus(&dir, OPEN_POLICY);
    let mut st = Station::new(&dir, &bus, false, "");
    // The defaults' resolution and gates (10,000 control vertices, 0.05 %), not the fast tests' 100.
    let cfg = std::fs::read_to_string(&st.config).unwrap();
    let cfg = cfg.replace("vertices = 100\n", "vertices = 10000\n").replace("max_rms_pct = 1.0\n", "");
    std::fs::write(&st.config, cfg).unwrap();
    st.start();
    // Staged beside the inbox (the shared data is never moved), then renamed in as one directory.
    let set = dir.join("bunny-scans");
    std::fs::create_dir_all(&set).unwrap();
    for e in std::fs::read_dir(&scans).unwrap().flatten() {
        std::fs::copy(e.path(), set.join(e.file_name())).unwrap();
    }
    std::fs::rename(&set, st.inbox().join("bunny-scans")).unwrap();
    st.wait_done(1, Duration::from_secs(900));
    let out = visible(&st.spool("outbox"));
    assert!(out.len() == 1 && out[0].starts_with("bunny-scans-"), "bun.conf: outbox {out:?}\n{}", st.log());
    let bundle = st.spool("outbox").join(&out[0]);
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(bundle.join("bunny-scans.report.json")).unwrap()).unwrap();
    let convert = &report["convert"];
    assert_eq!(convert["status"], "ok", "bun.conf: gates {}", convert["gates"]);
    assert_eq!(convert["reconstruct"]["fusion"]["views"].as_array().map(Vec::len), Some(10), "bun.conf: fusion");
    assert!(bundle.join("bunny-scans.step").is_file(), "bun.conf: {:?}", visible(&bundle));
    eprintln!("bun.conf through the daemon: gates {}", convert["gates"]);
}

const TURNTABLE: &str = "/org/scanstation/Station1/devices/turntable";
const TRIGGER: &str = "/org/scanstation/Station1/devices/trigger";

#[test]
fn the_rig_on_dbus_moves_fires_degrades_and_recovers_with_its_simulators() {
    need("busctl", "systemd");
    need("gdbus", "libglib2.0-bin");
    need("setpriv", "util-linux");
    let dir = common::scratch("daemon-rig");
    std::fs::set_permissions(&dir, std::os::unix::fs::PermissionsExt::from_mode(0o755)).unwrap();
    let bus = start_bus(&dir, &system_policy());
    let table = sim_turntable(&dir);
    let trigger = sim_trigger(&dir);
    let mut st = Station::new(&dir, &bus, true, &rig_config(&dir));
    st.start();
    let t = st.wait_property("Turntable", TURNTABLE, "Connected", "b true", Duration::from_secs(10));
    st.wait_property("Trigger", TRIGGER, "NodeAlive", "b true", Duration::from_secs(5));
    st.wait_property("Manager", ROOT, "State", "s \"idle\"", Duration::from_secs(5));
    println!("rig connected {t:?} after the name was taken");
    assert_eq!(st.property("Turntable", TURNTABLE, "StepsPerRevolution").as_deref(), Some("u 3200"));
    assert_eq!(st.property("Turntable", TURNTABLE, "Firmware").as_deref(), Some("s \"Grbl 1.1h\""));
    // The board's own settings, read at connect: a factory-fresh Grbl 1.1h ten times faster ($110 = 500 °/min,
    // $120 = 10 °/s² in simulated time), homing off, so the table is unlocked, not homed.
    for (prop, want) in [
        ("BoardHoming", "b false"),
        ("BoardMaxRate", "d 5000"),
        ("BoardAcceleration", "d 1000"),
        ("BoardStepsPerDegree", "d 250"),
        ("Homing", "s \"unlock\""),
    ] {
        assert_eq!(st.property("Turntable", TURNTABLE, prop).as_deref(), Some(want), "{prop}");
    }

    // MoveTo moves, and Angle follows.
    let monitor_log = dir.join("monitor.log");
    let mut monitor = Command::new("gdbus")
        .args(["monitor", "--address", &st.bus, "--dest", NAME])
        .stdout(std::fs::File::create(&monitor_log).unwrap())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_millis(300));
    for deg in ["90", "45", "360"] {
        let out = st.busctl(&["call", NAME, TURNTABLE, &format!("{NAME}.Turntable"), "MoveTo", "da{sv}", deg, "0"]);
        let reply = String::from_utf8_lossy(&out.stdout).trim().to_string();
        assert!(out.status.success(), "MoveTo {deg}: {}", String::from_utf8_lossy(&out.stderr));
        let reached: f64 = reply.trim_start_matches("d ").parse().unwrap();
        let target: f64 = deg.parse().unwrap();
        assert!((reached - target).abs() < 0.01, "MoveTo {deg} reached {reached}");
        let angle = st.property("Turntable", TURNTABLE, "Angle").unwrap();
        let angle: f64 = angle.trim_start_matches("d ").parse().unwrap();
        assert!((angle - target).abs() < 0.01, "Angle {angle} after MoveTo {deg}");
    }
    // Issue 46: a tilting table (the rig config names tilt_min = -60, tilt_max = 60). MoveTo's `tilt` option
    // moves Grbl's Y too, Tilt follows; out of range or of the wrong type: refused, naming why.
    assert_eq!(st.property("Turntable", TURNTABLE, "TiltRange").as_deref(), Some("ad 2 -60 60"));
    let tt = format!("{NAME}.Turntable");
    let out = st.busctl(&["--", "call", NAME, TURNTABLE, &tt, "MoveTo", "da{sv}", "30", "1", "tilt", "d", "-20"]);
    assert!(out.status.success(), "MoveTo tilted: {}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(st.property("Turntable", TURNTABLE, "Tilt").as_deref(), Some("d -20"));
    for (value, why) in [("d 75", "outside the cradle's range -60° to 60°"), ("s x", "must be a finite double")] {
        let (ty, v) = value.split_once(' ').unwrap();
        let out = st.busctl(&["--", "call", NAME, TURNTABLE, &tt, "MoveTo", "da{sv}", "30", "1", "tilt", ty, v]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && err.contains(why), "tilt {value}: {err}");
    }
    assert_eq!(st.property("Turntable", TURNTABLE, "Tilt").as_deref(), Some("d -20"), "a refused move moves nothing");
    let out = st.busctl(&["--", "call", NAME, TURNTABLE, &tt, "MoveTo", "da{sv}", "90", "1", "tilt", "d", "0"]);
    assert!(out.status.success(), "MoveTo level: {}", String::from_utf8_lossy(&out.stderr));
    let sent = st.busctl(&["call", NAME, TRIGGER, &format!("{NAME}.Trigger"), "Fire", "ua{sv}", "0", "0"]);
    assert!(sent.status.success(), "Fire: {}", String::from_utf8_lossy(&sent.stderr));
    assert!(String::from_utf8_lossy(&sent.stdout).starts_with("t "));
    assert_eq!(st.property("Trigger", TRIGGER, "FramesSent").as_deref(), Some("t 1"));

    // The same through the CLI (`scanstation rig`), on the system bus.
    let rig_cli =
        |args: &[&str]| Command::new(CLI).args(args).env("DBUS_SYSTEM_BUS_ADDRESS", &st.bus).output().unwrap();
    let out = rig_cli(&["--json", "rig", "move", "120", "--tilt", "-10"]);
    assert!(out.status.success(), "rig move: {}", String::from_utf8_lossy(&out.stderr));
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!((j["reached"].as_f64().unwrap() - 120.0).abs() < 0.01 && j["tilt"] == -10.0, "{j}");
    assert_eq!(st.property("Turntable", TURNTABLE, "Tilt").as_deref(), Some("d -10"));
    let out = rig_cli(&["--json", "rig", "fire", "--channel", "2"]);
    assert!(out.status.success(), "rig fire: {}", String::from_utf8_lossy(&out.stderr));
    let out = rig_cli(&["--json", "rig", "status"]);
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(j["turntable"]["Connected"], true, "{j}");
    assert!((j["turntable"]["Angle"].as_f64().unwrap() - 120.0).abs() < 0.01, "{j}");
    assert_eq!(
        (j["trigger"]["BusState"].as_str(), j["trigger"]["FramesSent"].as_u64()),
        (Some("error-active"), Some(2)),
        "{j}"
    );

    // An unprivileged caller may read but not move or fire.
    for call in [
        vec!["call", NAME, TURNTABLE, "org.scanstation.Station1.Turntable", "MoveTo", "da{sv}", "10", "0"],
        vec!["call", NAME, TRIGGER, "org.scanstation.Station1.Trigger", "Fire", "ua{sv}", "0", "0"],
        vec!["call", NAME, TURNTABLE, "org.scanstation.Station1.Turntable", "Home"],
    ] {
        let out = Command::new("setpriv")
            .args(["--reuid=65534", "--regid=65534", "--clear-groups", "busctl", "--address", &st.bus])
            .args(&call)
            .output()
            .unwrap();
        assert!(!out.status.success(), "nobody may call {}", call[4]);
        assert!(
            String::from_utf8_lossy(&out.stderr).contains("ccess denied"),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    let read = Command::new("setpriv")
        .args(["--reuid=65534", "--regid=65534", "--clear-groups", "busctl", "--address", &st.bus])
        .args(["get-property", NAME, TURNTABLE, "org.scanstation.Station1.Turntable", "Angle"])
        .output()
        .unwrap();
    assert!(read.status.success(), "nobody may read the angle");

    // Killing the turntable's simulator: a Fault, Connected=false, the station degraded; a new one: back.
    let t = Instant::now();
    drop(table);
    let lost = st.wait_property("Turntable", TURNTABLE, "Connected", "b false", Duration::from_secs(3));
    st.wait_property("Manager", ROOT, "State", "s \"degraded\"", Duration::from_secs(2));
    assert_eq!(
        st.property("Manager", ROOT, "Degraded").as_deref(),
        Some("as 1 \"turntable-disconnected\""),
        "{}",
        st.log()
    );
    println!("turntable simulator killed: Connected=false after {lost:?}, degraded after {:?}", t.elapsed());
    let refused = st.busctl(&["call", NAME, TURNTABLE, &format!("{NAME}.Turntable"), "MoveTo", "da{sv}", "10", "0"]);
    assert!(String::from_utf8_lossy(&refused.stderr).contains("device.unplugged"), "{refused:?}");
    let out = rig_cli(&["--json", "rig", "move", "10"]);
    assert_eq!(out.status.code(), Some(5), "a device error exits 5: {out:?}");
    assert!(String::from_utf8_lossy(&out.stdout).contains("\"device.unplugged\""), "{out:?}");
    let table = sim_turntable(&dir);
    let back = st.wait_property("Turntable", TURNTABLE, "Connected", "b true", Duration::from_secs(5));
    st.wait_property("Manager", ROOT, "State", "s \"idle\"", Duration::from_secs(2));
    println!("turntable simulator restarted: connected again after {back:?}");
    let out = st.busctl(&["call", NAME, TURNTABLE, &format!("{NAME}.Turntable"), "MoveTo", "da{sv}", "30", "0"]);
    assert!(out.status.success(), "MoveTo after the reconnect: {}", String::from_utf8_lossy(&out.stderr));

    // The same for the scanner node.
    let t = Instant::now();
    drop(trigger);
    st.wait_property("Trigger", TRIGGER, "NodeAlive", "b false", Duration::from_secs(2));
    st.wait_property("Manager", ROOT, "State", "s \"degraded\"", Duration::from_secs(2));
    println!("scanner simulator killed: degraded after {:?}", t.elapsed());
    let _trigger = sim_trigger(&dir);
    st.wait_property("Trigger", TRIGGER, "NodeAlive", "b true", Duration::from_secs(5));
    st.wait_property("Manager", ROOT, "State", "s \"idle\"", Duration::from_secs(2));
    let fired = st.busctl(&["call", NAME, TRIGGER, &format!("{NAME}.Trigger"), "Fire", "ua{sv}", "1", "0"]);
    assert!(fired.status.success(), "Fire after the restart: {}", String::from_utf8_lossy(&fired.stderr));

    // The Fault signals, as a monitor saw them.
    std::thread::sleep(Duration::from_millis(300));
    let _ = monitor.kill();
    let _ = monitor.wait();
    let seen = std::fs::read_to_string(&monitor_log).unwrap();
    let faults: Vec<&str> = seen.lines().filter(|l| l.contains(".Fault (")).collect();
    println!("Fault signals: {faults:#?}");
    assert!(faults.iter().any(|l| l.contains("Turntable.Fault") && l.contains("device.unplugged")), "{seen}");
    assert!(
        faults
            .iter()
            .any(|l| l.contains("Trigger.Fault") && (l.contains("device.unplugged") || l.contains("device.lost"))),
        "{seen}"
    );
    drop(table);
}

//! The rig's turntable driver against the simulated Grbl 1.1 firmware on a real pseudo-terminal (termios,
//! exclusive open, EIO on unplug), through the same actor the daemon runs: banner, homing, timed moves,
//! dropped replies, `error:n`, `ALARM:n`, unplug mid-move and replug, a wrong firmware.

mod common;

use std::path::Path;
use std::time::{Duration, Instant};

use scanstation::ErrorCode;
use scanstation::devices::turntable::TurntableSettings;
use scanstation::devices::turntable::actor::{DeviceFault, LinkSettings, TurntableHandle, spawn_turntable};
use scanstation::devices::turntable::sim::{Fault, SimSettings};
use scanstation::devices::turntable::transport::{SimCommand, SimTurntable};

/// Simulated time runs this much faster than the wall clock.
const TIME_SCALE: f64 = 10.0;

fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().unwrap()
}

fn link_settings(port: &Path) -> LinkSettings {
    // Speed and acceleration are the board's (read with `$$`: 90 °/s, 180 °/s² simulated, ten times that in
    // wall time, as the simulator reports them); the deadlines stay short.
    let driver = TurntableSettings {
        reply_timeout: Duration::from_millis(500),
        banner_timeout: Duration::from_secs(2),
        home_timeout: Duration::from_secs(5),
        poll_interval: Duration::from_millis(20),
        ..Default::default()
    };
    LinkSettings {
        driver,
        reconnect_min: Duration::from_millis(100),
        reconnect_max: Duration::from_millis(400),
        idle_poll: Duration::from_millis(200),
        ..LinkSettings::new(port)
    }
}

/// A simulated board with homing (`$22=1`): 90 °/s top speed and 180 °/s² in simulated time.
fn sim(dir: &Path, banner: &str) -> SimTurntable {
    let settings =
        SimSettings { banner: banner.into(), homing: true, max_speed: 90.0, accel: 180.0, ..Default::default() };
    SimTurntable::spawn(settings, &dir.join("ttyTurntable"), TIME_SCALE).expect("a pty")
}

async fn until(
    h: &TurntableHandle,
    what: &str,
    limit: Duration,
    f: impl Fn(&scanstation::devices::turntable::actor::TurntableState) -> bool,
) {
    let t = Instant::now();
    let mut w = h.watch();
    while !f(&w.borrow_and_update()) {
        assert!(t.elapsed() < limit, "{what}: not within {limit:?}: {:?}", h.state());
        let _ = tokio::time::timeout(Duration::from_millis(50), w.changed()).await;
    }
}

/// Send `c` to the simulator and give its thread time to take it (it polls its commands every 5 ms).
async fn inject(board: &SimTurntable, c: SimCommand) {
    board.send(c);
    tokio::time::sleep(Duration::from_millis(50)).await;
}

async fn next_fault(rx: &mut tokio::sync::broadcast::Receiver<DeviceFault>, limit: Duration) -> DeviceFault {
    tokio::time::timeout(limit, rx.recv()).await.expect("a fault in time").expect("the fault channel")
}

const BANNER: &str = "Grbl 1.1h ['$' for help]";

#[test]
fn banner_home_and_moves_land_within_a_hundredth_of_a_degree() {
    let dir = common::scratch("rig-moves");
    let board = sim(&dir, BANNER);
    runtime().block_on(async {
        let tt = spawn_turntable(link_settings(board.link()));
        until(&tt, "connected and homed", Duration::from_secs(5), |s| s.connected && s.homed).await;
        let s = tt.state();
        assert_eq!(s.firmware, "Grbl 1.1h");
        assert_eq!(s.angle, 0.0, "homed at 0");
        for target in [45.0, 90.0, 360.0, 12.345] {
            let r = tt.move_to(target).await.unwrap_or_else(|e| panic!("move to {target}: {e}"));
            println!("move to {target}°: reached {:.4}° in {:.3} s", r.reached, r.seconds);
            assert!((r.reached - target).abs() <= 0.01, "{target}: reached {}", r.reached);
            assert!((tt.state().angle - target).abs() <= 0.01, "the published angle follows: {:?}", tt.state());
        }
        assert_eq!(tt.state().faults, 0);
    });
}

#[test]
fn dropped_replies_errors_and_alarms_are_mapped_and_recovered() {
    let dir = common::scratch("rig-faults");
    let board = sim(&dir, BANNER);
    runtime().block_on(async {
        let settings = link_settings(board.link());
        let reply_timeout = settings.driver.reply_timeout;
        let tt = spawn_turntable(settings);
        let mut faults = tt.faults();
        until(&tt, "connected", Duration::from_secs(5), |s| s.connected && s.homed).await;
        // A dropped `ok`: device.timeout after the reply's deadline (not before), then the board is stopped
        // and re-homed before the next move.
        inject(&board, SimCommand::Fault(Fault::DropReply)).await;
        let t = Instant::now();
        let e = tt.move_to(30.0).await.unwrap_err();
        let waited = t.elapsed();
        assert_eq!(e.code, ErrorCode::DeviceTimeout, "{e}");
        assert!(waited >= reply_timeout && waited < reply_timeout + Duration::from_secs(2), "{waited:?}: {e}");
        assert_eq!(next_fault(&mut faults, Duration::from_secs(1)).await.code, ErrorCode::DeviceTimeout);
        let r = tt.move_to(30.0).await.expect("the next move after a timeout");
        assert!((r.reached - 30.0).abs() <= 0.01);
        // error:15 is device.refused, naming the code.
        inject(&board, SimCommand::Fault(Fault::Error(15))).await;
        let e = tt.move_to(60.0).await.unwrap_err();
        assert!(e.code == ErrorCode::DeviceRefused && e.message.contains("error:15"), "{e}");
        assert_eq!(next_fault(&mut faults, Duration::from_secs(1)).await.code, ErrorCode::DeviceRefused);
        // ALARM:1 while idle: the idle poll raises device.alarm; the next move homes first, then moves.
        board.send(SimCommand::Fault(Fault::Alarm(1)));
        let f = next_fault(&mut faults, Duration::from_secs(2)).await;
        assert!(f.code == ErrorCode::DeviceAlarm && f.message.contains("ALARM:1"), "{f:?}");
        until(&tt, "not homed after the alarm", Duration::from_secs(1), |s| !s.homed).await;
        let r = tt.move_to(60.0).await.expect("a move after the alarm re-homes first");
        assert!((r.reached - 60.0).abs() <= 0.01 && tt.state().homed);
        // A stalled table: device.timeout within the move's derived deadline.
        inject(&board, SimCommand::Fault(Fault::Stall)).await;
        let e = tt.move_to(300.0).await.unwrap_err();
        assert_eq!(e.code, ErrorCode::DeviceTimeout, "{e}");
        assert!(tt.state().connected, "a stall is not an unplug");
    });
}

/// CPU seconds (user + system) of this process so far.
fn cpu_seconds() -> f64 {
    let mut u: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: getrusage fills the struct we own.
    unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut u) };
    let tv = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    tv(u.ru_utime) + tv(u.ru_stime)
}

#[test]
fn an_unplug_mid_move_is_a_fault_within_a_second_and_a_replug_re_homes() {
    let dir = common::scratch("rig-unplug");
    let board = sim(&dir, BANNER);
    runtime().block_on(async {
        let tt = spawn_turntable(link_settings(board.link()));
        let mut faults = tt.faults();
        until(&tt, "connected", Duration::from_secs(5), |s| s.connected && s.homed).await;
        // A long move (3600° at the board's 90 °/s: 4 s of wall time), unplugged 0.1 s in.
        let mover = {
            let tt = tt.clone();
            tokio::spawn(async move { tt.move_to(3600.0).await })
        };
        tokio::time::sleep(Duration::from_millis(100)).await;
        let t = Instant::now();
        board.send(SimCommand::Unplug);
        let f = next_fault(&mut faults, Duration::from_secs(1)).await;
        let noticed = t.elapsed();
        assert_eq!(f.code, ErrorCode::DeviceUnplugged, "{f:?}");
        until(&tt, "disconnected", Duration::from_secs(1), |s| !s.connected && !s.homed).await;
        let e = mover.await.unwrap().unwrap_err();
        assert_eq!(e.code, ErrorCode::DeviceUnplugged, "the move in flight fails: {e}");
        println!("unplug noticed after {noticed:?}");
        // Unplugged: commands are refused at once, and the reconnect loop sleeps (no busy loop).
        let c0 = cpu_seconds();
        let w = Instant::now();
        assert_eq!(tt.move_to(10.0).await.unwrap_err().code, ErrorCode::DeviceUnplugged);
        tokio::time::sleep(Duration::from_secs(1)).await;
        let cpu = (cpu_seconds() - c0) / w.elapsed().as_secs_f64();
        println!("CPU while unplugged: {:.1} % of a core", 100.0 * cpu);
        // The whole test process (the other rig tests run beside this one): a busy loop would be a full core.
        assert!(cpu < 0.25, "{:.1} % of a core while unplugged", 100.0 * cpu);
        // Replugged: reconnected and re-homed before the next move.
        board.send(SimCommand::Replug);
        until(&tt, "reconnected and homed", Duration::from_secs(3), |s| s.connected && s.homed).await;
        assert_eq!(tt.state().connections, 2);
        assert_eq!(tt.state().angle, 0.0, "re-homed");
        let r = tt.move_to(45.0).await.expect("a move after the replug");
        assert!((r.reached - 45.0).abs() <= 0.01);
    });
}

#[test]
fn a_wrong_firmware_and_a_missing_port_are_faults_not_crashes() {
    let dir = common::scratch("rig-firmware");
    let board = sim(&dir, "Grbl 0.9j ['$' for help]");
    runtime().block_on(async {
        let tt = spawn_turntable(link_settings(board.link()));
        until(&tt, "a fault", Duration::from_secs(3), |s| s.last_fault.is_some()).await;
        let f = tt.state().last_fault.unwrap();
        assert!(f.code == ErrorCode::DeviceWrongFirmware && f.message.contains("0.9j"), "{f:?}");
        assert!(!tt.state().connected);
        let missing = spawn_turntable(link_settings(&dir.join("no-such-port")));
        until(&missing, "a fault", Duration::from_secs(3), |s| s.last_fault.is_some()).await;
        let f = missing.state().last_fault.unwrap();
        assert_eq!(f.code, ErrorCode::DeviceUnplugged, "{f:?}");
        assert_eq!(missing.home().await.unwrap_err().code, ErrorCode::DeviceUnplugged);
        // Still one fault per outage, however often it retries.
        tokio::time::sleep(Duration::from_millis(900)).await;
        assert_eq!(missing.state().faults, 1, "{:?}", missing.state());
    });
}

/// A factory-fresh Grbl 1.1h (homing off, `$110=500`, `$120=10`, real time) driven with the default settings
/// only: the driver reads the board, does not send `$H` (the board would refuse it, `error:5`), times the
/// move by the board's 8.3 °/s and 10 °/s², and reaches 90°. A config asking for more than the board allows is
/// `device.config`, never a move; one asking for less is used, with a warning.
#[test]
fn a_factory_fresh_board_is_read_and_driven_with_the_default_settings() {
    let dir = common::scratch("rig-factory");
    let board = SimTurntable::spawn(SimSettings::default(), &dir.join("ttyTurntable"), 1.0).expect("a pty");
    runtime().block_on(async {
        let defaults = LinkSettings { reconnect_min: Duration::from_millis(100), ..LinkSettings::new(board.link()) };
        let tt = spawn_turntable(defaults);
        until(&tt, "connected", Duration::from_secs(8), |s| s.connected).await;
        let s = tt.state();
        let b = s.board.expect("the board's settings");
        assert_eq!((b.homing, b.max_rate, b.accel, b.steps_per_degree), (false, 500.0, 10.0, 250.0), "{s:?}");
        assert_eq!((s.homing.as_str(), s.homed), ("unlock", true), "no $H on a board without homing: {s:?}");
        assert!((s.speed - 500.0 / 60.0).abs() < 1e-9, "the board's top rate: {s:?}");
        let r = tt.move_to(90.0).await.unwrap_or_else(|e| panic!("move to 90 on a factory board: {e}"));
        let want = scanstation::devices::turntable::protocol::move_seconds(90.0, 500.0 / 60.0, 10.0);
        println!("factory board: 90° in {:.2} s (the trapezoid at 8.3 °/s, 10 °/s²: {want:.2} s)", r.seconds);
        assert!((r.reached - 90.0).abs() <= 0.01, "reached {}", r.reached);
        assert!(r.seconds >= want - 0.1, "the move took {:.2} s, the board needs {want:.2} s", r.seconds);
        assert_eq!(tt.state().faults, 0, "{:?}", tt.state().last_fault);
        // Unplugged and plugged in again (the board powers up at 0): reconnected, and it moves.
        inject(&board, SimCommand::Unplug).await;
        until(&tt, "the unplug seen", Duration::from_secs(3), |s| !s.connected).await;
        inject(&board, SimCommand::Replug).await;
        until(&tt, "reconnected", Duration::from_secs(8), |s| s.connected && s.homed).await;
        let r = tt.move_to(10.0).await.unwrap_or_else(|e| panic!("a move after the replug: {e}"));
        assert!((r.reached - 10.0).abs() <= 0.01, "reached {} after the replug", r.reached);
    });
    drop(board);
    // Asking for more than the board allows: a fault with the board's value, and moves refused with it.
    let board = SimTurntable::spawn(SimSettings::default(), &dir.join("ttyTurntable"), 1.0).expect("a pty");
    runtime().block_on(async {
        let driver = TurntableSettings { speed: Some(60.0), ..Default::default() };
        let tt = spawn_turntable(LinkSettings { driver, ..LinkSettings::new(board.link()) });
        let mut faults = tt.faults();
        let f = next_fault(&mut faults, Duration::from_secs(8)).await;
        assert_eq!(f.code, ErrorCode::DeviceConfig, "{f:?}");
        assert!(f.message.contains("speed = 60") && f.message.contains("$110 = 500"), "{}", f.message);
        let e = tt.move_to(10.0).await.unwrap_err();
        assert_eq!(e.code, ErrorCode::DeviceConfig, "{e}");
        assert_eq!(board.angle(), 0.0, "the table never moved");
    });
    drop(board);
    // Less than the board allows: used.
    let board = SimTurntable::spawn(SimSettings::default(), &dir.join("ttyTurntable"), 1.0).expect("a pty");
    runtime().block_on(async {
        let driver = TurntableSettings { speed: Some(5.0), accel: Some(5.0), ..Default::default() };
        let tt = spawn_turntable(LinkSettings { driver, ..LinkSettings::new(board.link()) });
        until(&tt, "connected", Duration::from_secs(8), |s| s.connected).await;
        assert_eq!(tt.state().speed, 5.0);
        let r = tt.move_to(5.0).await.expect("a slower move");
        assert!((r.reached - 5.0).abs() <= 0.01, "reached {}", r.reached);
    });
}

/// Resident memory of process `pid`, KiB (`VmRSS` in /proc).
fn rss_kib(pid: u32) -> u64 {
    let s = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    let line = s.lines().find(|l| l.starts_with("VmRSS:")).expect("VmRSS");
    line.split_whitespace().nth(1).unwrap().parse().unwrap()
}

/// Regression: `scanstation sim turntable < /dev/zero` grew by about 750 MB/s until the kernel killed it (4.4 GB
/// after 6 s), and a control-socket line without a newline the same. Both readers are bounded now: after
/// 3 s of NULs on stdin and 64 MB without a newline on the socket the simulator holds under 64 MiB and still
/// takes `quit`.
#[test]
fn the_simulators_command_readers_are_bounded() {
    use std::io::Write;
    let dir = common::scratch("rig-bounded");
    let (link, control) = (dir.join("ttyTurntable"), dir.join("control.sock"));
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_scanstation"))
        .args(["sim", "turntable", "--link", link.to_str().unwrap(), "--control", control.to_str().unwrap()])
        .stdin(std::fs::File::open("/dev/zero").unwrap())
        .stderr(std::fs::File::create(dir.join("sim.log")).unwrap())
        .spawn()
        .unwrap();
    let t = Instant::now();
    while !control.exists() {
        assert!(t.elapsed() < Duration::from_secs(5), "no control socket");
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_secs(3));
    let after_stdin = rss_kib(child.id());
    let mut sock = std::os::unix::net::UnixStream::connect(&control).unwrap();
    let chunk = vec![b'x'; 1 << 20];
    for _ in 0..64 {
        sock.write_all(&chunk).unwrap();
    }
    std::thread::sleep(Duration::from_millis(300));
    let after_socket = rss_kib(child.id());
    println!("simulator resident: {after_stdin} KiB after 3 s of /dev/zero, {after_socket} KiB after 64 MB unbroken");
    assert!(after_stdin < 64 * 1024 && after_socket < 64 * 1024, "{after_stdin} KiB, {after_socket} KiB");
    sock.write_all(b"\nquit\n").unwrap();
    let t = Instant::now();
    while child.try_wait().unwrap().is_none() {
        assert!(t.elapsed() < Duration::from_secs(10), "quit after the overlong line was not taken");
        std::thread::sleep(Duration::from_millis(50));
    }
    let log = std::fs::read_to_string(dir.join("sim.log")).unwrap();
    assert!(log.contains("was dropped"), "{log}");
}

/// Issue 46: a tilting table over a real pty. On a factory-fresh board (no homing: X and Y are zero where they
/// stand) a tilted move drives X and Y along one straight path, its deadline from the path's length, and
/// both axes are checked; the simulated firmware's cradle (what its camera sees) stands where the board
/// reports it. A tilt outside the configured range, or any tilt on a table configured without a tilt axis,
/// is refused before anything moves.
#[test]
fn a_tilting_table_moves_both_axes_within_its_range() {
    let dir = common::scratch("rig-tilt");
    let board = SimTurntable::spawn(SimSettings::default(), &dir.join("ttyTurntable"), TIME_SCALE).expect("a pty");
    let tilt_of = board.tilt_source();
    runtime().block_on(async {
        let mut settings = link_settings(board.link());
        settings.driver.tilt = Some((-60.0, 60.0));
        let tt = spawn_turntable(settings);
        until(&tt, "connected", Duration::from_secs(8), |s| s.connected && s.homed).await;
        assert_eq!(tt.state().tilt_range, Some((-60.0, 60.0)));
        for (angle, tilt) in [(90.0, -45.0), (135.0, 50.0), (135.0, 0.0), (200.0, -25.0)] {
            let r = tt.move_to_tilted(angle, tilt).await.unwrap_or_else(|e| panic!("move to {angle}°/{tilt}°: {e}"));
            println!(
                "tilted move to {angle}°, {tilt}°: reached {:.4}°, {:.4}° in {:.3} s",
                r.reached, r.tilt, r.seconds
            );
            assert!((r.reached - angle).abs() <= 0.01 && (r.tilt - tilt).abs() <= 0.01, "{r:?}");
            assert!((tt.state().tilt - tilt).abs() <= 0.01, "the published tilt follows: {:?}", tt.state());
            assert!((tilt_of() - tilt).abs() <= 0.01, "the firmware's cradle: {}", tilt_of());
        }
        // A plain move leaves the cradle where it is.
        let r = tt.move_to(10.0).await.unwrap();
        assert!((r.tilt + 25.0).abs() <= 0.01, "{r:?}");
        let e = tt.move_to_tilted(10.0, 61.0).await.unwrap_err();
        assert_eq!(e.code, ErrorCode::InputBadArgument, "{e}");
        assert!(e.message.contains("outside the cradle's range -60° to 60°"), "{e}");
        assert!((tilt_of() + 25.0).abs() <= 0.01, "a refused tilt moves nothing");
        tokio::time::sleep(Duration::from_millis(100)).await;
        assert_eq!(tt.state().faults, 0, "a caller's bad argument is no device fault: {:?}", tt.state().last_fault);
    });
    drop(board);
    let board = SimTurntable::spawn(SimSettings::default(), &dir.join("ttyTurntable"), TIME_SCALE).expect("a pty");
    runtime().block_on(async {
        let tt = spawn_turntable(link_settings(board.link()));
        until(&tt, "connected", Duration::from_secs(8), |s| s.connected && s.homed).await;
        let e = tt.move_to_tilted(10.0, 20.0).await.unwrap_err();
        assert_eq!(e.code, ErrorCode::DeviceConfig, "{e}");
        assert!(e.message.contains("no tilt axis"), "{e}");
        assert_eq!(board.angle(), 0.0, "the table never moved");
    });
}

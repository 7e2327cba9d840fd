//! The rig's turntable driver against the simulated Grbl 1.1 firmware on a real pseudo-terminal (termios,
//! exclusive open, EIO on unplug), through the same actor the daemon runs: banner, homing, timed moves,
//! dropped replies, `error:n`, `ALARM:n`, unplug mid-move and replug, a wrong firmware.

mod common;

use std::path::Path;
use std::time::{Duration, Instant};

use scanstation::ErrorCode;
use scanstation::devices::grbl_sim::{Fault, SimSettings};
use scanstation::devices::link::{DeviceFault, LinkSettings, TurntableHandle, spawn_turntable};
use scanstation::devices::sim_pty::{SimCommand, SimTurntable};
use scanstation::devices::turntable::TurntableSettings;

/// Simulated time runs this much faster than the wall clock.
const TIME_SCALE: f64 = 10.0;

fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().unwrap()
}

fn link_settings(port: &Path) -> LinkSettings {
    // The driver's speed and acceleration are above the board's (90 °/s, 180 °/s² simulated, ten times that
    // in wall time): the board limits the moves, and the driver's deadlines stay short.
    let driver = TurntableSettings {
        speed: 600.0,
        accel: 1200.0,
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

/// A simulated board: 90 °/s top speed and 180 °/s² in simulated time.
fn sim(dir: &Path, banner: &str) -> SimTurntable {
    let settings = SimSettings { banner: banner.into(), ..Default::default() };
    SimTurntable::spawn(settings, &dir.join("ttyTurntable"), TIME_SCALE).expect("a pty")
}

async fn until(
    h: &TurntableHandle,
    what: &str,
    limit: Duration,
    f: impl Fn(&scanstation::devices::link::TurntableState) -> bool,
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

//! `scanstation sim turntable`: the simulated Grbl 1.1 turntable on a pty; `scanstation sim trigger`: the
//! simulated scanner node on CAN (an interface or a Unix socket). For a person at a desk with no hardware and
//! for tests in other processes. Faults are typed on stdin, or sent as lines to `--control` (a Unix socket):
//! for the turntable `unplug`, `replug`, `drop-reply`, `error N`, `alarm N`, `stall`, `quit`; for the trigger
//! `silence MS`, `emcy CODE`, `drop-view [N]`, `busy [N]`, `garbage N`, `bus-off MS`, `quit`.

use std::io::BufRead;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use clap::Args;
use scanstation::devices::grbl_sim::{Fault, SimSettings};
use scanstation::devices::sim_pty::{SimCommand, SimTurntable};
use scanstation::devices::socketcan_bus::SocketCanBus;
use scanstation::devices::trigger_sim::{ScannerFault, ScannerSettings, SimScanner};

/// Arguments of `scanstation sim turntable`.
#[derive(Args)]
pub struct SimTurntableArgs {
    /// Where the serial line appears (a symbolic link to the pty, as /dev/serial/by-id/… names a board).
    #[arg(long)]
    pub link: PathBuf,
    /// Simulated time runs this many times faster than the wall clock (0.01 to 1000).
    #[arg(long, default_value_t = 1.0, value_parser = time_scale)]
    pub time_scale: f64,
    /// The banner after a reset (a wrong one exercises the driver's firmware check).
    #[arg(long, default_value = "Grbl 1.1h ['$' for help]")]
    pub banner: String,
    /// Homing disabled: the board starts unlocked (Grbl's $22=0).
    #[arg(long)]
    pub no_homing: bool,
    /// Top speed, degrees per second (simulated time).
    #[arg(long, default_value_t = 90.0)]
    pub max_speed: f64,
    /// Acceleration, degrees per second² (simulated time).
    #[arg(long, default_value_t = 180.0)]
    pub accel: f64,
    /// A Unix socket taking fault commands, one per line (as on stdin).
    #[arg(long)]
    pub control: Option<PathBuf>,
}

fn time_scale(s: &str) -> Result<f64, String> {
    let v: f64 = s.parse().map_err(|e| format!("{e}"))?;
    if (0.01..=1000.0).contains(&v) { Ok(v) } else { Err("between 0.01 and 1000".into()) }
}

/// Feed `send` the command lines typed on stdin and, with `control`, those sent to that Unix socket (one
/// connection after another), each on a thread of its own. Without a control socket the end of stdin is
/// `quit`. `Err` (exit status 3, reported) when the socket cannot be bound.
fn command_lines(
    control: Option<&std::path::Path>,
    send: impl Fn(String) -> bool + Send + Sync + Clone + 'static,
) -> Result<(), ExitCode> {
    if let Some(path) = control {
        let _ = std::fs::remove_file(path);
        let l = std::os::unix::net::UnixListener::bind(path).map_err(|e| {
            eprintln!("scanstation: error: cannot listen on {}: {e}", path.display());
            ExitCode::from(3)
        })?;
        let send = send.clone();
        std::thread::spawn(move || {
            for conn in l.incoming().flatten() {
                for line in std::io::BufReader::new(conn).lines().map_while(Result::ok) {
                    send(line);
                }
            }
        });
    }
    let stdin_ends = control.is_none();
    std::thread::spawn(move || {
        for line in std::io::stdin().lock().lines().map_while(Result::ok) {
            send(line);
        }
        if stdin_ends {
            send("quit".into());
        }
    });
    Ok(())
}

/// A command line: `unplug`, `replug`, `drop-reply`, `error N`, `alarm N`, `stall`, `quit`.
fn parse_command(line: &str) -> Result<SimCommand, String> {
    let mut words = line.split_whitespace();
    let word = words.next().unwrap_or("");
    let code =
        |w: Option<&str>| w.and_then(|n| n.parse::<u32>().ok()).ok_or_else(|| format!("{word}: a number is needed"));
    Ok(match word {
        "unplug" => SimCommand::Unplug,
        "replug" => SimCommand::Replug,
        "drop-reply" => SimCommand::Fault(Fault::DropReply),
        "error" => SimCommand::Fault(Fault::Error(code(words.next())?)),
        "alarm" => SimCommand::Fault(Fault::Alarm(code(words.next())?)),
        "stall" => SimCommand::Fault(Fault::Stall),
        "quit" => SimCommand::Stop,
        _ => {
            return Err(format!(
                "unknown command {word:?} (unplug, replug, drop-reply, error N, alarm N, stall, quit)"
            ));
        }
    })
}

/// Run the simulator until `quit`, end of stdin with no control socket, or a signal.
pub fn run(a: &SimTurntableArgs) -> ExitCode {
    let settings = SimSettings {
        banner: a.banner.clone(),
        homing: !a.no_homing,
        max_speed: a.max_speed,
        accel: a.accel,
        ..Default::default()
    };
    let sim = match SimTurntable::spawn(settings, &a.link, a.time_scale) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("scanstation: error: cannot start the simulated turntable at {}: {e}", a.link.display());
            return ExitCode::from(3);
        }
    };
    eprintln!("simulated Grbl turntable at {} (time ×{})", a.link.display(), a.time_scale);
    let (tx, rx) = std::sync::mpsc::channel::<String>();
    if let Err(code) = command_lines(a.control.as_deref(), move |l| tx.send(l).is_ok()) {
        return code;
    }
    for line in rx {
        if line.trim().is_empty() {
            continue;
        }
        match parse_command(&line) {
            Ok(SimCommand::Stop) => break,
            Ok(c) => {
                eprintln!("sim: {}", line.trim());
                sim.send(c);
            }
            Err(e) => eprintln!("sim: {e}"),
        }
    }
    ExitCode::SUCCESS
}

/// Arguments of `scanstation sim trigger`.
#[derive(Args)]
pub struct SimTriggerArgs {
    /// Where the node sits: a CAN interface (`vcan0`, `can0`) or `unix:PATH`, a socket the station connects to
    /// (the kernel's CAN frame records; no privileges needed).
    #[arg(long)]
    pub bus: String,
    /// The node id (1 to 127).
    #[arg(long, default_value_t = 0x10, value_parser = clap::value_parser!(u8).range(1..=127))]
    pub node: u8,
    /// Heartbeat period, milliseconds (10 to 10000).
    #[arg(long, default_value_t = 100, value_parser = clap::value_parser!(u64).range(10..=10_000))]
    pub heartbeat_ms: u64,
    /// From a trigger's acknowledgement to its view, milliseconds (0 to 60000).
    #[arg(long, default_value_t = 50, value_parser = clap::value_parser!(u64).range(0..=60_000))]
    pub exposure_ms: u64,
    /// Points reported per view.
    #[arg(long, default_value_t = 100_000)]
    pub points: u32,
    /// A Unix socket taking fault commands, one per line (as on stdin).
    #[arg(long)]
    pub control: Option<PathBuf>,
}

/// A trigger-node command line: `silence MS`, `emcy CODE`, `drop-view [N]`, `busy [N]`, `garbage N`,
/// `bus-off MS`, `quit`.
fn parse_trigger_command(line: &str) -> Result<ScannerFault, String> {
    let mut words = line.split_whitespace();
    let word = words.next().unwrap_or("");
    let arg = words.next();
    let number = |default: Option<u64>| -> Result<u64, String> {
        match arg {
            Some(w) => {
                let w = w.trim_start_matches("0x");
                let radix = if arg.is_some_and(|a| a.starts_with("0x")) { 16 } else { 10 };
                u64::from_str_radix(w, radix).map_err(|_| format!("{word}: {:?} is not a number", arg.unwrap_or("")))
            }
            None => default.ok_or_else(|| format!("{word}: a number is needed")),
        }
    };
    let ms = |n: u64| Duration::from_millis(n);
    Ok(match word {
        "silence" => ScannerFault::Silence(ms(number(None)?)),
        "emcy" => ScannerFault::Emergency(number(None)?.min(0xFFFF) as u16),
        "drop-view" => ScannerFault::DropViews(number(Some(1))?.min(u64::from(u32::MAX)) as u32),
        "busy" => ScannerFault::Busy(number(Some(1))?.min(u64::from(u32::MAX)) as u32),
        "garbage" => ScannerFault::Garbage(number(None)?.min(10_000) as u32),
        "bus-off" => ScannerFault::BusOff(ms(number(None)?)),
        "quit" => ScannerFault::Quit,
        _ => {
            return Err(format!(
                "unknown command {word:?} (silence MS, emcy CODE, drop-view [N], busy [N], garbage N, bus-off MS, quit)"
            ));
        }
    })
}

/// Run the simulated scanner node until `quit`, end of stdin with no control socket, or a signal.
pub fn run_trigger(a: &SimTriggerArgs) -> ExitCode {
    let settings = ScannerSettings {
        node: a.node,
        heartbeat: Duration::from_millis(a.heartbeat_ms),
        exposure: Duration::from_millis(a.exposure_ms),
        points: a.points,
    };
    let rt = match tokio::runtime::Builder::new_current_thread().enable_all().build() {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("scanstation: error: no async runtime: {e}");
            return ExitCode::from(70);
        }
    };
    rt.block_on(async {
        let node = match a.bus.strip_prefix("unix:") {
            Some(path) => SimScanner::listen_unix(std::path::Path::new(path), settings),
            None => SocketCanBus::open(&a.bus).map(|bus| SimScanner::spawn(bus, settings)),
        };
        let node = match node {
            Ok(n) => n,
            Err(e) => {
                eprintln!("scanstation: error: cannot start the simulated scanner node on {}: {e}", a.bus);
                return ExitCode::from(3);
            }
        };
        eprintln!("simulated scanner node {:#04x} on {} (heartbeat {} ms)", a.node, a.bus, a.heartbeat_ms);
        let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel::<String>();
        if let Err(code) = command_lines(a.control.as_deref(), move |l| tx.send(l).is_ok()) {
            return code;
        }
        while let Some(line) = rx.recv().await {
            if line.trim().is_empty() {
                continue;
            }
            match parse_trigger_command(&line) {
                Ok(ScannerFault::Quit) => break,
                Ok(f) => {
                    eprintln!("sim: {}", line.trim());
                    node.inject(f).await;
                }
                Err(e) => eprintln!("sim: {e}"),
            }
        }
        node.inject(ScannerFault::Quit).await;
        ExitCode::SUCCESS
    })
}

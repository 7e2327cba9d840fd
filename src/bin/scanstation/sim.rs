//! `scanstation sim turntable`: the simulated Grbl 1.1 turntable on a pty; `scanstation sim rig`: both and the
//! range camera in one process (a whole station with no hardware); `scanstation sim trigger`: the
//! simulated scanner node on CAN (an interface or a Unix socket). For a person at a desk with no hardware and
//! for tests in other processes. Faults are typed on stdin, or sent as lines to `--control` (a Unix socket):
//! for the turntable `unplug`, `replug`, `drop-reply`, `error N`, `alarm N`, `stall`, `quit`; for the trigger
//! `silence MS`, `emcy CODE`, `drop-view [N]`, `busy [N]`, `garbage N`, `bus-off MS`, `quit`.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use clap::Args;
use scanstation::devices::commands::{CommandLine, MAX_COMMAND_BYTES, for_each_line};
use scanstation::devices::rig_sim;
use scanstation::devices::trigger::sim::{ScannerFault, ScannerSettings, SimScanner};
use scanstation::devices::turntable::sim::SimSettings;
use scanstation::devices::turntable::transport::{SimCommand, SimTurntable};

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
    /// Homing enabled (Grbl's `$22=1`): the board starts locked until `$H` or `$X`. Off by default, as on a
    /// factory-fresh board.
    #[arg(long)]
    pub homing: bool,
    /// Top rate, degrees per minute (Grbl's `$110`, simulated time); Grbl 1.1's factory default is 500.
    #[arg(long, default_value_t = 500.0, value_parser = positive)]
    pub max_rate: f64,
    /// Acceleration, degrees per second² (Grbl's `$120`, simulated time); the factory default is 10.
    #[arg(long, default_value_t = 10.0, value_parser = positive)]
    pub accel: f64,
    /// A Unix socket taking fault commands, one per line (as on stdin).
    #[arg(long)]
    pub control: Option<PathBuf>,
}

fn positive(s: &str) -> Result<f64, String> {
    let v: f64 = s.parse().map_err(|e| format!("{e}"))?;
    if v.is_finite() && v > 0.0 && v <= 1e6 { Ok(v) } else { Err("a positive number up to 1e6".into()) }
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
                for_each_line(conn, |l| forward(l, &send));
            }
        });
    }
    let stdin_ends = control.is_none();
    std::thread::spawn(move || {
        for_each_line(std::io::stdin().lock(), |l| forward(l, &send));
        if stdin_ends {
            send("quit".into());
        }
    });
    Ok(())
}

/// Pass a command line on (`false` once the receiver is gone); an overlong one is reported and dropped.
fn forward(line: CommandLine, send: &impl Fn(String) -> bool) -> bool {
    match line {
        CommandLine::Line(l) => send(l),
        CommandLine::TooLong(n) => {
            eprintln!("sim: a command line of {n} bytes or more was dropped (at most {MAX_COMMAND_BYTES})");
            true
        }
    }
}

/// Run the simulator until `quit`, end of stdin with no control socket, or a signal.
pub fn run(a: &SimTurntableArgs) -> ExitCode {
    let settings = SimSettings {
        banner: a.banner.clone(),
        homing: a.homing,
        max_speed: a.max_rate / 60.0,
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
        match rig_sim::turntable_command(&line) {
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

/// Start the simulated scanner node on `bus` (`unix:PATH` or a CAN interface), on the current runtime;
/// `Err` (exit status 3, reported) when it cannot.
fn start_node(bus: &str, settings: ScannerSettings) -> Result<SimScanner, ExitCode> {
    rig_sim::start_node(bus, settings).map_err(|e| {
        eprintln!("scanstation: error: cannot start the simulated scanner node on {bus}: {e}");
        ExitCode::from(3)
    })
}

/// Run the simulated scanner node until `quit`, end of stdin with no control socket, or a signal.
pub fn run_trigger(a: &SimTriggerArgs) -> ExitCode {
    let settings = ScannerSettings {
        node: a.node,
        heartbeat: Duration::from_millis(a.heartbeat_ms),
        exposure: Duration::from_millis(a.exposure_ms),
        points: a.points,
        views: None,
    };
    let rt = match tokio::runtime::Builder::new_current_thread().enable_all().build() {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("scanstation: error: no async runtime: {e}");
            return ExitCode::from(70);
        }
    };
    rt.block_on(async {
        let node = match start_node(&a.bus, settings) {
            Ok(n) => n,
            Err(code) => return code,
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
            match rig_sim::scanner_command(&line) {
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

/// Arguments of `scanstation sim rig`: the whole simulated station in one process.
#[derive(Args)]
pub struct SimRigArgs {
    /// The object on the table: a closed mesh (PLY, OBJ, STL, OFF).
    #[arg(long)]
    pub object: PathBuf,
    /// The mesh axis that points up on the table.
    #[arg(long, default_value = "y", value_parser = ["y", "z"])]
    pub up: String,
    /// Where the turntable's serial line appears (as `sim turntable --link`).
    #[arg(long)]
    pub link: PathBuf,
    /// Where the scanner node sits (as `sim trigger --bus`).
    #[arg(long)]
    pub bus: String,
    /// The directory the scanner writes each view into (`view-SSSSS.ply`, SSSSS the trigger's sequence
    /// number; binary PLY, points in the scanner's frame), as the station's `[scan] capture_dir` names it.
    #[arg(long)]
    pub capture: PathBuf,
    /// Write the station's calibration here: a TOML `[scan]` fragment with `axis_point` and `axis_direction`.
    #[arg(long)]
    pub calibration: Option<PathBuf>,
    /// Write the object as the scan should find it (the table frame: origin at the table top's centre, z up the axis) here, as PLY.
    #[arg(long)]
    pub truth: Option<PathBuf>,
    /// Seed of the scanner's noise, dropouts and outliers.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Range image width and height, pixels (8 to 4096 each).
    #[arg(long, default_value = "320x240", value_parser = resolution)]
    pub resolution: (u32, u32),
    /// Depth noise σ at the working distance, as a share of the object's bounding-box diagonal.
    #[arg(long, default_value_t = 0.0002)]
    pub noise: f64,
    /// Share of points that are outliers (0 to 0.5).
    #[arg(long, default_value_t = 0.0)]
    pub outliers: f64,
    /// Points whose surface turns away from the camera or projector by more than this are lost, degrees.
    #[arg(long, default_value_t = 80.0)]
    pub grazing_deg: f64,
    /// The camera's height above the table plane, seen from the object's middle, degrees.
    #[arg(long, default_value_t = 20.0)]
    pub elevation_deg: f64,
    /// Simulated time of the turntable runs this many times faster than the wall clock (0.01 to 1000).
    #[arg(long, default_value_t = 1.0, value_parser = time_scale)]
    pub time_scale: f64,
    /// The scanner node's heartbeat period, milliseconds (10 to 10000).
    #[arg(long, default_value_t = 100, value_parser = clap::value_parser!(u64).range(10..=10_000))]
    pub heartbeat_ms: u64,
    /// From a trigger's acknowledgement to its view, milliseconds (0 to 60000).
    #[arg(long, default_value_t = 50, value_parser = clap::value_parser!(u64).range(0..=60_000))]
    pub exposure_ms: u64,
    /// The scanner's node id (1 to 127).
    #[arg(long, default_value_t = 0x10, value_parser = clap::value_parser!(u8).range(1..=127))]
    pub node: u8,
    /// A Unix socket taking fault commands, one per line (as on stdin): the turntable's and the trigger's.
    #[arg(long)]
    pub control: Option<PathBuf>,
}

fn resolution(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s.split_once('x').ok_or("WIDTHxHEIGHT, e.g. 320x240")?;
    let p = |v: &str| v.parse::<u32>().map_err(|e| format!("{v:?}: {e}"));
    Ok((p(w)?, p(h)?))
}

/// Run the simulated rig (turntable, scanner node, range camera; assembled by [`rig_sim::RigSim`]) until
/// `quit`, end of stdin with no control socket, or a signal.
pub fn run_rig(a: &SimRigArgs) -> ExitCode {
    use scanstation::devices::rangecam::{CameraSettings, Up};
    use scanstation::geometry::io::{ReadOptions, read_mesh, write_ply};
    let fail = |what: String| {
        eprintln!("scanstation: error: {what}");
        ExitCode::from(3)
    };
    let mesh = match read_mesh(&a.object, &ReadOptions::default()) {
        Ok(m) => m.triangulate().0,
        Err(e) => return fail(format!("cannot read the object: {e}")),
    };
    let camera = CameraSettings {
        width: a.resolution.0,
        height: a.resolution.1,
        noise_rel: a.noise,
        outliers: a.outliers,
        grazing_deg: a.grazing_deg,
        elevation_deg: a.elevation_deg,
        seed: a.seed,
        ..Default::default()
    };
    let node = ScannerSettings {
        node: a.node,
        heartbeat: Duration::from_millis(a.heartbeat_ms),
        exposure: Duration::from_millis(a.exposure_ms),
        points: 0,
        views: None,
    };
    let settings = rig_sim::RigSimSettings {
        object: (mesh, if a.up == "z" { Up::Z } else { Up::Y }),
        camera,
        table: (a.link.clone(), a.time_scale),
        node: (a.bus.clone(), node),
        capture: a.capture.clone(),
    };
    let rt = match tokio::runtime::Builder::new_multi_thread().worker_threads(1).enable_all().build() {
        Ok(rt) => rt,
        Err(e) => return fail(format!("no async runtime: {e}")),
    };
    rt.block_on(async {
        let rig = match rig_sim::RigSim::start(settings) {
            Ok(r) => r,
            Err(e) => return fail(e),
        };
        if let Some(path) = &a.calibration
            && let Err(e) = std::fs::write(path, rig.calibration_toml())
        {
            return fail(format!("cannot write {}: {e}", path.display()));
        }
        if let Some(path) = &a.truth {
            let truth = scanstation::geometry::mesh::PolyMesh::from(rig.camera.truth());
            let note = ["the simulated rig's object in the table frame"];
            if let Err(e) = write_ply(path, &truth, &Default::default(), &note) {
                return fail(format!("cannot write {}: {e}", path.display()));
            }
        }
        let (point, direction) = rig.camera.axis();
        eprintln!(
            "simulated rig: turntable at {}, scanner node {:#04x} on {}, views into {}; axis point {:?} direction {:?}",
            a.link.display(),
            a.node,
            a.bus,
            a.capture.display(),
            point,
            direction
        );
        let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel::<String>();
        if let Err(code) = command_lines(a.control.as_deref(), move |l| tx.send(l).is_ok()) {
            return code;
        }
        while let Some(line) = rx.recv().await {
            if line.trim().is_empty() {
                continue;
            }
            match rig.command(&line).await {
                Ok(false) => break,
                Ok(true) => eprintln!("sim: {}", line.trim()),
                Err(e) => eprintln!("sim: {e}"),
            }
        }
        rig.quit().await;
        ExitCode::SUCCESS
    })
}

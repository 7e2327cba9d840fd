//! `scanstation sim turntable`: the simulated Grbl 1.1 turntable on a pty; `scanstation sim rig`: both and the
//! range camera in one process (a whole station with no hardware); `scanstation sim trigger`: the
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

/// Start the simulated scanner node on `bus` (`unix:PATH` or a CAN interface), on the current runtime;
/// `Err` (exit status 3, reported) when it cannot.
fn start_node(bus: &str, settings: ScannerSettings) -> Result<SimScanner, ExitCode> {
    let node = match bus.strip_prefix("unix:") {
        Some(path) => SimScanner::listen_unix(std::path::Path::new(path), settings),
        None => SocketCanBus::open(bus).map(|b| SimScanner::spawn(b, settings)),
    };
    node.map_err(|e| {
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

/// Run the simulated rig (turntable, scanner node, range camera) until `quit`, end of stdin with no control
/// socket, or a signal.
pub fn run_rig(a: &SimRigArgs) -> ExitCode {
    use scanstation::devices::rangecam::{CameraSettings, RangeCamera, Up};
    use scanstation::devices::trigger_sim::ViewSource;
    use scanstation::geometry::io::{ReadOptions, read_mesh, write_ply, write_ply_cloud};
    let fail = |what: String| {
        eprintln!("scanstation: error: {what}");
        ExitCode::from(3)
    };
    let mesh = match read_mesh(&a.object, &ReadOptions::default()) {
        Ok(m) => m.triangulate().0,
        Err(e) => return fail(format!("cannot read the object: {e}")),
    };
    let settings = CameraSettings {
        width: a.resolution.0,
        height: a.resolution.1,
        noise_rel: a.noise,
        outliers: a.outliers,
        grazing_deg: a.grazing_deg,
        elevation_deg: a.elevation_deg,
        seed: a.seed,
        ..Default::default()
    };
    let up = if a.up == "z" { Up::Z } else { Up::Y };
    let camera = match RangeCamera::new(&mesh, up, settings) {
        Ok(c) => std::sync::Arc::new(c),
        Err(e) => return fail(format!("the range camera: {e}")),
    };
    if let Err(e) = std::fs::create_dir_all(&a.capture) {
        return fail(format!("cannot create {}: {e}", a.capture.display()));
    }
    let (point, direction) = camera.axis();
    if let Some(path) = &a.calibration {
        let text = format!(
            "# The simulated rig's turntable axis in the scanner's frame (scanstation sim rig).\n[scan]\naxis_point = [{}, {}, {}]\naxis_direction = [{}, {}, {}]\n",
            point[0], point[1], point[2], direction[0], direction[1], direction[2]
        );
        if let Err(e) = std::fs::write(path, text) {
            return fail(format!("cannot write {}: {e}", path.display()));
        }
    }
    if let Some(path) = &a.truth {
        let truth = scanstation::geometry::mesh::PolyMesh::from(camera.truth());
        if let Err(e) = write_ply(path, &truth, &Default::default(), &["the simulated rig's object in the table frame"])
        {
            return fail(format!("cannot write {}: {e}", path.display()));
        }
    }
    let table = match SimTurntable::spawn(SimSettings::default(), &a.link, a.time_scale) {
        Ok(s) => s,
        Err(e) => return fail(format!("cannot start the simulated turntable at {}: {e}", a.link.display())),
    };
    let angle = table.angle_source();
    let (cam, dir) = (camera.clone(), a.capture.clone());
    let views = ViewSource(std::sync::Arc::new(move |seq: u16| {
        let at = angle();
        let points = cam.capture(at);
        let cloud = scanstation::geometry::mesh::PointCloud { positions: points, normals: None, colors: None };
        let path = dir.join(format!("view-{seq:05}.ply"));
        let note = format!("simulated range image at table angle {at:.4} deg");
        match write_ply_cloud(&path, &cloud, &Default::default(), &[&note]) {
            Ok(()) => Some(cloud.positions.len() as u32),
            Err(e) => {
                eprintln!("sim: cannot write {}: {e}", path.display());
                None
            }
        }
    }));
    let settings = ScannerSettings {
        node: a.node,
        heartbeat: Duration::from_millis(a.heartbeat_ms),
        exposure: Duration::from_millis(a.exposure_ms),
        points: 0,
        views: Some(views),
    };
    let rt = match tokio::runtime::Builder::new_multi_thread().worker_threads(1).enable_all().build() {
        Ok(rt) => rt,
        Err(e) => return fail(format!("no async runtime: {e}")),
    };
    rt.block_on(async {
        let node = match start_node(&a.bus, settings) {
            Ok(n) => n,
            Err(code) => return code,
        };
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
            match (parse_command(&line), parse_trigger_command(&line)) {
                (Ok(SimCommand::Stop), _) | (_, Ok(ScannerFault::Quit)) => break,
                (Ok(c), _) => {
                    eprintln!("sim: {}", line.trim());
                    table.send(c);
                }
                (_, Ok(f)) => {
                    eprintln!("sim: {}", line.trim());
                    node.inject(f).await;
                }
                (Err(_), Err(_)) => eprintln!(
                    "sim: unknown command {:?} (turntable: unplug, replug, drop-reply, error N, alarm N, stall; scanner: silence MS, emcy CODE, drop-view [N], busy [N], garbage N, bus-off MS; quit)",
                    line.trim()
                ),
            }
        }
        node.inject(ScannerFault::Quit).await;
        ExitCode::SUCCESS
    })
}

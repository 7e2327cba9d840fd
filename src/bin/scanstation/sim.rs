//! `scanstation sim turntable`: the simulated Grbl 1.1 turntable on a pty, for a person at a desk with no
//! hardware and for tests in other processes. Faults are typed on stdin, or sent as lines to `--control`
//! (a Unix socket): `unplug`, `replug`, `drop-reply`, `error N`, `alarm N`, `stall`, `quit`.

use std::io::BufRead;
use std::path::PathBuf;
use std::process::ExitCode;

use clap::Args;
use scanstation::devices::grbl_sim::{Fault, SimSettings};
use scanstation::devices::sim_pty::{SimCommand, SimTurntable};

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
    if let Some(path) = &a.control {
        let _ = std::fs::remove_file(path);
        match std::os::unix::net::UnixListener::bind(path) {
            Ok(l) => {
                let tx = tx.clone();
                std::thread::spawn(move || {
                    for conn in l.incoming().flatten() {
                        for line in std::io::BufReader::new(conn).lines().map_while(Result::ok) {
                            let _ = tx.send(line);
                        }
                    }
                });
            }
            Err(e) => {
                eprintln!("scanstation: error: cannot listen on {}: {e}", path.display());
                return ExitCode::from(3);
            }
        }
    }
    let stdin_ends = a.control.is_none();
    std::thread::spawn(move || {
        for line in std::io::stdin().lock().lines().map_while(Result::ok) {
            let _ = tx.send(line);
        }
        if stdin_ends {
            let _ = tx.send("quit".into());
        }
    });
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

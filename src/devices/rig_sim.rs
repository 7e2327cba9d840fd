//! The whole simulated rig in one place: the turntable's firmware on a pty, the scanner node on a bus, and the
//! range camera that ray-casts the object on the table at the angle the simulated table stands at, writing
//! each view where the station's `[scan] capture_dir` expects it. `scanstation sim rig` is this behind a
//! command line; tests and benchmarks can assemble it the same way.
//!
//! The simulators' command language lives here too ([`turntable_command`], [`scanner_command`]): the lines
//! typed on a simulator's stdin or sent to its control socket (read bounded, [`super::commands`]).

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use super::rangecam::{CameraSettings, RangeCamera, Up};
use super::trigger::sim::{ScannerFault, ScannerSettings, SimScanner, ViewSource};
use super::trigger::socketcan::SocketCanBus;
use super::turntable::sim::{Fault, SimSettings};
use super::turntable::transport::{SimCommand, SimTurntable};
use crate::geometry::mesh::{PointCloud, TriMesh};
use crate::geometry::pose::Pose;

/// A turntable command line: `unplug`, `replug`, `drop-reply`, `error N`, `alarm N`, `stall`, `quit`.
///
/// # Errors
/// A message naming the word and the commands there are.
pub fn turntable_command(line: &str) -> Result<SimCommand, String> {
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

/// A scanner-node command line: `silence MS`, `emcy CODE`, `drop-view [N]`, `busy [N]`, `garbage N`,
/// `bus-off MS`, `quit`.
///
/// # Errors
/// A message naming the word and the commands there are.
pub fn scanner_command(line: &str) -> Result<ScannerFault, String> {
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
        "blind" => ScannerFault::Blind(number(Some(1))?.min(u64::from(u32::MAX)) as u32),
        "garbage" => ScannerFault::Garbage(number(None)?.min(10_000) as u32),
        "bus-off" => ScannerFault::BusOff(ms(number(None)?)),
        "quit" => ScannerFault::Quit,
        _ => {
            return Err(format!(
                "unknown command {word:?} (silence MS, emcy CODE, drop-view [N], busy [N], blind [N], garbage N, bus-off MS, quit)"
            ));
        }
    })
}

/// Start the simulated scanner node on `bus` (`unix:PATH`, or a CAN interface) on the current tokio runtime.
///
/// # Errors
/// The operating system's, when the socket or the interface cannot be opened.
pub fn start_node(bus: &str, settings: ScannerSettings) -> std::io::Result<SimScanner> {
    match bus.strip_prefix("unix:") {
        Some(path) => SimScanner::listen_unix(Path::new(path), settings),
        None => SocketCanBus::open(bus).map(|b| SimScanner::spawn(b, settings)),
    }
}

/// Where the simulated rig's parts appear and how they behave.
pub struct RigSimSettings {
    /// The object on the table, and the mesh axis that points up.
    pub object: (TriMesh, Up),
    /// The range camera's optics and noise.
    pub camera: CameraSettings,
    /// The turntable's link (a symbolic link to its pty) and how much faster than the wall clock it runs.
    pub table: (PathBuf, f64),
    /// The scanner node's bus (`unix:PATH` or a CAN interface) and its settings (its views come from the
    /// camera).
    pub node: (String, ScannerSettings),
    /// The directory the scanner writes each view into (`view-SSSSS.ply`).
    pub capture: PathBuf,
}

/// The running simulated rig; dropping it stops the turntable (call [`RigSim::quit`] for the node).
pub struct RigSim {
    /// The simulated turntable.
    pub table: SimTurntable,
    /// The simulated scanner node.
    pub node: SimScanner,
    /// The range camera as the rig started (the object as first placed, its axis, its truth: the frame a
    /// scan's first pass is fused in).
    pub camera: Arc<RangeCamera>,
    /// The camera over the object as it lies now (after `turn-over`s).
    current: Arc<std::sync::RwLock<Arc<RangeCamera>>>,
    /// Turn-overs so far, and the motion from the first placing's table frame to the object's now.
    placing: std::sync::Mutex<(u64, Pose)>,
}

impl RigSim {
    /// Assemble and start the rig (on the current tokio runtime, for the node): the camera over the object,
    /// the capture directory, the turntable (a factory-fresh Grbl 1.1h), and the node whose views the camera
    /// ray-casts at the table's angle when it is triggered.
    ///
    /// # Errors
    /// A message naming the part that cannot start.
    pub fn start(s: RigSimSettings) -> Result<RigSim, String> {
        let (mesh, up) = &s.object;
        let camera = Arc::new(RangeCamera::new(mesh, *up, s.camera).map_err(|e| format!("the range camera: {e}"))?);
        std::fs::create_dir_all(&s.capture).map_err(|e| format!("cannot create {}: {e}", s.capture.display()))?;
        let (link, time_scale) = &s.table;
        let table = SimTurntable::spawn(SimSettings::default(), link, *time_scale)
            .map_err(|e| format!("cannot start the simulated turntable at {}: {e}", link.display()))?;
        let (angle, tilt) = (table.angle_source(), table.tilt_source());
        let current = Arc::new(std::sync::RwLock::new(camera.clone()));
        let (now, dir) = (current.clone(), s.capture.clone());
        let views = ViewSource(Arc::new(move |seq: u16| {
            let (at, tilted) = (angle(), tilt());
            let cam = now.read().unwrap_or_else(|p| p.into_inner()).clone();
            let cloud = PointCloud { positions: cam.capture_tilted(at, tilted), normals: None, colors: None };
            let path = dir.join(format!("view-{seq:05}.ply"));
            let note = format!("simulated range image at table angle {at:.4} deg, tilt {tilted:.4} deg");
            match crate::geometry::io::write_ply_cloud(&path, &cloud, &Default::default(), &[&note]) {
                Ok(_) => Some(cloud.positions.len() as u32),
                Err(e) => {
                    tracing::warn!(file = %path.display(), error = %e, "the simulated scanner cannot write a view");
                    None
                }
            }
        }));
        let (bus, settings) = s.node;
        let node = start_node(&bus, ScannerSettings { views: Some(views), ..settings })
            .map_err(|e| format!("cannot start the simulated scanner node on {bus}: {e}"))?;
        Ok(RigSim { table, node, camera, current, placing: std::sync::Mutex::new((0, Pose::IDENTITY)) })
    }

    /// The station's calibration for this rig: a TOML `[scan]` fragment with the table's axis and the
    /// cradle's tilt axis (Grbl's Y; the table at 0°, level) in the scanner's frame, and the plate's radius.
    pub fn calibration_toml(&self) -> String {
        let (p, d) = self.camera.axis();
        let (tp, td) = self.camera.tilt_axis();
        format!(
            "# The simulated rig's turntable axis and cradle (tilt) axis in the scanner's frame (scanstation sim rig).\n[scan]\naxis_point = [{}, {}, {}]\naxis_direction = [{}, {}, {}]\ntilt_axis_point = [{}, {}, {}]\ntilt_axis_direction = [{}, {}, {}]\nplate_radius = {}\n",
            p[0],
            p[1],
            p[2],
            d[0],
            d[1],
            d[2],
            tp[0],
            tp[1],
            tp[2],
            td[0],
            td[1],
            td[2],
            self.camera.plate_radius()
        )
    }

    /// Turn the object over, as an operator does between two passes ([`RangeCamera::turned_over`]): it
    /// rests on another stable face, turned and shifted by `seed`'s draws. Returns the motion from the first
    /// placing's table frame to the new one (what the station is not told; tests compare it).
    ///
    /// # Errors
    /// A message when the object has no other face to rest on.
    pub fn turn_over(&self, seed: u64) -> Result<Pose, String> {
        let mut now = self.current.write().unwrap_or_else(|p| p.into_inner());
        let (turned, motion) = now.turned_over(seed)?;
        *now = Arc::new(turned);
        let mut placing = self.placing.lock().unwrap_or_else(|p| p.into_inner());
        // From the first placing: the motion so far, then this one.
        *placing = (placing.0 + 1, motion.then_after(&placing.1));
        Ok(placing.1)
    }

    /// Turn-overs so far, and the motion from the first placing's table frame to the object's now.
    pub fn placing(&self) -> (u64, Pose) {
        *self.placing.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Carry out one command line, the rig's (`turn-over [SEED]`), the turntable's or the scanner's;
    /// `Ok(false)` for `quit`.
    ///
    /// # Errors
    /// A message naming both command sets when the line is neither's.
    pub async fn command(&self, line: &str) -> Result<bool, String> {
        let mut words = line.split_whitespace();
        if words.next() == Some("turn-over") {
            let seed = match words.next() {
                Some(w) => w.parse::<u64>().map_err(|_| format!("turn-over: {w:?} is not a seed (a whole number)"))?,
                None => self.placing().0 + 1,
            };
            let motion = self.turn_over(seed)?;
            let (deg, dist) = motion.difference(&Pose::IDENTITY);
            tracing::info!(seed, turned_deg = deg, moved = dist, "the object is turned over");
            return Ok(true);
        }
        match (turntable_command(line), scanner_command(line)) {
            (Ok(SimCommand::Stop), _) | (_, Ok(ScannerFault::Quit)) => Ok(false),
            (Ok(c), _) => {
                self.table.send(c);
                Ok(true)
            }
            (_, Ok(f)) => {
                self.node.inject(f).await;
                Ok(true)
            }
            (Err(_), Err(_)) => Err(format!(
                "unknown command {:?} (rig: turn-over [SEED]; turntable: unplug, replug, drop-reply, error N, alarm N, stall; scanner: silence MS, emcy CODE, drop-view [N], busy [N], garbage N, bus-off MS; quit)",
                line.trim()
            )),
        }
    }

    /// Stop the scanner node.
    pub async fn quit(&self) {
        self.node.inject(ScannerFault::Quit).await;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn command_lines_parse_or_name_what_there_is() {
        assert_eq!(turntable_command("error 9"), Ok(SimCommand::Fault(Fault::Error(9))));
        assert!(turntable_command("error").unwrap_err().contains("a number is needed"));
        assert_eq!(scanner_command("emcy 0x5000"), Ok(ScannerFault::Emergency(0x5000)));
        assert_eq!(scanner_command("drop-view"), Ok(ScannerFault::DropViews(1)));
        assert_eq!(scanner_command("blind 2"), Ok(ScannerFault::Blind(2)));
        assert!(scanner_command("fly").unwrap_err().contains("silence MS"));
    }
}

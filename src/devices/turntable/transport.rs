//! The lines a turntable is reached over: a serial port ([`open_serial`]: a board, or a pty), and the
//! simulated turntable on a real pseudo-terminal.
//!
//! The pty: [`GrblSim`] behind the master side of a pty, its slave
//! side reached through a stable symbolic link (as `/dev/serial/by-id/…` names a real board), so the driver
//! opens it exactly as it opens hardware (termios, exclusive open, EOF and EIO on unplug).
//!
//! [`SimTurntable::spawn`] runs the firmware in its own thread; its handle injects faults, unplugs (the pty is
//! closed: the driver's reads fail with EIO, and the link disappears) and replugs (a new pty behind the same
//! link, the board freshly powered on, its EEPROM kept). Time runs `time_scale` times faster than the wall
//! clock, so tests can make a 90° move take milliseconds: the board is that much faster ([`SimSettings::faster`])
//! and its `$$` says so, as a real board's would.

use std::io;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use super::sim::{Fault, GrblSim, SimSettings};
use crate::error::{Error, ErrorCode, Result};

/// Open a serial port (a board, or a pty) for the driver: exclusive (TIOCEXCL), 8N1, no flow control.
///
/// # Errors
/// `device.unplugged` when the port does not exist or cannot be opened.
pub fn open_serial(path: &Path, baud: u32) -> Result<tokio_serial::SerialStream> {
    use tokio_serial::SerialPortBuilderExt;
    let name = path.to_string_lossy();
    let mut port = tokio_serial::new(name.as_ref(), baud)
        .open_native_async()
        .map_err(|e| Error::new(ErrorCode::DeviceUnplugged, format!("cannot open the turntable's port {name}: {e}")))?;
    port.set_exclusive(true).map_err(|e| {
        Error::new(ErrorCode::DeviceUnplugged, format!("cannot take the turntable's port {name} exclusively: {e}"))
    })?;
    Ok(port)
}

/// A command to the running simulator.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SimCommand {
    /// Inject a firmware fault.
    Fault(Fault),
    /// Close the pty and remove the link (the cable pulled).
    Unplug,
    /// A new pty behind the link, the board powered on again.
    Replug,
    /// End the simulator.
    Stop,
}

/// A running simulated turntable.
pub struct SimTurntable {
    link: PathBuf,
    /// The table's angle, degrees (`f64` bits), as the firmware last computed it.
    angle: std::sync::Arc<std::sync::atomic::AtomicU64>,
    /// The cradle's tilt (Grbl's Y), degrees (`f64` bits), likewise.
    tilt: std::sync::Arc<std::sync::atomic::AtomicU64>,
    commands: mpsc::Sender<SimCommand>,
    thread: Option<std::thread::JoinHandle<()>>,
}

/// One pty: the master (ours) and an open slave descriptor that keeps the line up while no driver has it
/// open (without one, the master sees a hang-up).
struct Pty {
    master: OwnedFd,
    _slave: OwnedFd,
}

/// A raw-mode pty, its slave linked at `link` (replaced atomically).
fn open_pty(link: &Path) -> io::Result<Pty> {
    // SAFETY: plain libc calls on descriptors we own; every result is checked.
    unsafe {
        let m = libc::posix_openpt(libc::O_RDWR | libc::O_NOCTTY | libc::O_NONBLOCK | libc::O_CLOEXEC);
        if m < 0 {
            return Err(io::Error::last_os_error());
        }
        let master = OwnedFd::from_raw_fd(m);
        if libc::grantpt(m) != 0 || libc::unlockpt(m) != 0 {
            return Err(io::Error::last_os_error());
        }
        let mut name = [0 as libc::c_char; 128];
        if libc::ptsname_r(m, name.as_mut_ptr(), name.len()) != 0 {
            return Err(io::Error::last_os_error());
        }
        let path = std::ffi::CStr::from_ptr(name.as_ptr()).to_owned();
        let s = libc::open(path.as_ptr(), libc::O_RDWR | libc::O_NOCTTY | libc::O_CLOEXEC);
        if s < 0 {
            return Err(io::Error::last_os_error());
        }
        let slave = OwnedFd::from_raw_fd(s);
        let mut t: libc::termios = std::mem::zeroed();
        if libc::tcgetattr(s, &mut t) == 0 {
            libc::cfmakeraw(&mut t);
            libc::tcsetattr(s, libc::TCSANOW, &t);
        }
        let target = PathBuf::from(path.to_string_lossy().into_owned());
        let tmp = link.with_extension("new-link");
        let _ = std::fs::remove_file(&tmp);
        std::os::unix::fs::symlink(&target, &tmp)?;
        std::fs::rename(&tmp, link)?;
        Ok(Pty { master, _slave: slave })
    }
}

/// Read what is there (non-blocking); `None` when nothing is.
fn read_some(fd: &OwnedFd) -> Option<Vec<u8>> {
    let mut buf = [0u8; 512];
    // SAFETY: reading into a buffer we own, of its length.
    let n = unsafe { libc::read(fd.as_raw_fd(), buf.as_mut_ptr().cast(), buf.len()) };
    (n > 0).then(|| buf[..n as usize].to_vec())
}

/// Write all of `bytes` (the pty's buffer is far larger than any reply); what does not fit is dropped, as
/// a real board's transmit overruns are.
fn write_all(fd: &OwnedFd, mut bytes: &[u8]) {
    while !bytes.is_empty() {
        // SAFETY: writing from a buffer we own, of its length.
        let n = unsafe { libc::write(fd.as_raw_fd(), bytes.as_ptr().cast(), bytes.len()) };
        if n <= 0 {
            return;
        }
        bytes = &bytes[n as usize..];
    }
}

/// Wait until `fd` is readable or `timeout` passes.
fn wait_readable(fd: &OwnedFd, timeout: Duration) {
    let mut p = libc::pollfd { fd: fd.as_raw_fd(), events: libc::POLLIN, revents: 0 };
    // SAFETY: one pollfd of ours.
    unsafe { libc::poll(&mut p, 1, timeout.as_millis().min(1000) as libc::c_int) };
}

impl SimTurntable {
    /// Start a simulated turntable whose serial line is reached at `link`; simulated time runs
    /// `time_scale` times faster than the wall clock.
    ///
    /// # Errors
    /// The operating system's, when no pty can be made or the link cannot be written.
    pub fn spawn(settings: SimSettings, link: &Path, time_scale: f64) -> io::Result<SimTurntable> {
        let mut pty = Some(open_pty(link)?);
        let (tx, rx) = mpsc::channel();
        let link_owned = link.to_path_buf();
        let scale = if time_scale > 0.0 { time_scale } else { 1.0 };
        let angle = std::sync::Arc::new(std::sync::atomic::AtomicU64::new(0f64.to_bits()));
        let angle_out = angle.clone();
        let tilt = std::sync::Arc::new(std::sync::atomic::AtomicU64::new(0f64.to_bits()));
        let tilt_out = tilt.clone();
        // The board as the wall clock sees it: `scale` times faster, so that its `$$` holds in wall time.
        let settings = settings.faster(scale);
        let thread = std::thread::Builder::new().name("sim-turntable".into()).spawn(move || {
            let start = Instant::now();
            let now = || start.elapsed().as_secs_f64();
            let mut sim = GrblSim::new(settings);
            if let Some(p) = &pty {
                write_all(&p.master, &sim.power_on());
            }
            loop {
                match rx.try_recv() {
                    Ok(SimCommand::Stop) | Err(mpsc::TryRecvError::Disconnected) => break,
                    Ok(SimCommand::Unplug) => {
                        pty = None;
                        let _ = std::fs::remove_file(&link_owned);
                    }
                    Ok(SimCommand::Replug) => {
                        if pty.is_none() {
                            pty = open_pty(&link_owned).ok();
                            sim = GrblSim::new(sim.eeprom().clone());
                            if let Some(p) = &pty {
                                write_all(&p.master, &sim.power_on());
                            }
                        }
                    }
                    Ok(SimCommand::Fault(f)) => {
                        let out = sim.inject(f, now());
                        if let Some(p) = &pty {
                            write_all(&p.master, &out);
                        }
                    }
                    Err(mpsc::TryRecvError::Empty) => {}
                }
                let Some(p) = &pty else {
                    std::thread::sleep(Duration::from_millis(10));
                    continue;
                };
                wait_readable(&p.master, Duration::from_millis(5));
                let out = match read_some(&p.master) {
                    Some(bytes) => sim.input(&bytes, now()),
                    None => sim.tick(now()),
                };
                write_all(&p.master, &out);
                angle_out.store(sim.position(now()).to_bits(), std::sync::atomic::Ordering::Relaxed);
                tilt_out.store(sim.tilt(now()).to_bits(), std::sync::atomic::Ordering::Relaxed);
            }
            let _ = std::fs::remove_file(&link_owned);
        })?;
        Ok(SimTurntable { link: link.to_path_buf(), angle, tilt, commands: tx, thread: Some(thread) })
    }

    /// The link the driver opens.
    pub fn link(&self) -> &Path {
        &self.link
    }

    /// The table's angle now, degrees (where the firmware has it; a simulated scanner sees the object turned
    /// by this).
    pub fn angle(&self) -> f64 {
        f64::from_bits(self.angle.load(std::sync::atomic::Ordering::Relaxed))
    }

    /// A reader of [`angle`](Self::angle) that other threads can keep.
    pub fn angle_source(&self) -> impl Fn() -> f64 + Send + Sync + 'static {
        let a = self.angle.clone();
        move || f64::from_bits(a.load(std::sync::atomic::Ordering::Relaxed))
    }

    /// A reader of the cradle's tilt (Grbl's Y, degrees) that other threads can keep.
    pub fn tilt_source(&self) -> impl Fn() -> f64 + Send + Sync + 'static {
        let a = self.tilt.clone();
        move || f64::from_bits(a.load(std::sync::atomic::Ordering::Relaxed))
    }

    /// Send a command (ignored once the simulator has stopped).
    pub fn send(&self, command: SimCommand) {
        let _ = self.commands.send(command);
    }
}

impl Drop for SimTurntable {
    fn drop(&mut self) {
        let _ = self.commands.send(SimCommand::Stop);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

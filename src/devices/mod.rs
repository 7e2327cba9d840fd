//! **devices** — the rig: the turntable (Grbl 1.1 over a serial port) and the scanner's trigger on CAN, with
//! simulators that behave like the real devices, faults included.
//!
//! Beside the pipeline and under the daemon: nothing here imports the stages, the pipeline or the daemon.
//! Each device is a folder of the same five parts: `protocol` (its messages, parsed without I/O), `driver`
//! (talking to one connected device), `actor` (the task that owns the connection: commands, published state,
//! faults), `sim` (the simulated device, pure) and `transport` (the lines it is reached over). The actors'
//! supervision — reconnecting with backoff, refusing commands while away, one fault per outage — is written
//! once, in [`supervise`]. [`turntable`]: Grbl 1.1 over a serial port (tokio-serial; a pty for the simulator);
//! [`trigger`]: the scanner's node on CAN (SocketCAN, or a Unix socket for the simulator). [`rangecam`] is the
//! simulated scanner's optics, [`rig_sim`] the whole simulated rig, and [`commands`] reads the simulators'
//! command lines, bounded.

pub mod commands;
pub mod rangecam;
pub mod rig_sim;
pub mod supervise;
pub mod trigger;
pub mod turntable;

/// A device fault, as the `Fault` signal carries it.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct DeviceFault {
    /// The device (`turntable`, `trigger`).
    pub device: &'static str,
    /// Stable code (`device.unplugged`, …).
    pub code: crate::error::ErrorCode,
    /// For people.
    pub message: String,
}

//! **devices** — the rig: the turntable (Grbl 1.1 over a serial port) and the scanner's trigger on CAN, with
//! simulators that behave like the real devices, faults included.
//!
//! Beside the pipeline and under the daemon: nothing here imports the stages, the pipeline or the daemon.
//! The protocol modules ([`grbl`], [`grbl_sim`]) are plain functions over bytes and time; the driver
//! ([`turntable`]) is async (tokio, tokio-serial) over any byte stream; [`sim_pty`] puts the simulated
//! firmware behind a real pseudo-terminal so the driver meets termios, exclusive opens and unplugs as on
//! hardware. On CAN, [`can`] holds the frames (SocketCAN's layout), the bus state and the transports,
//! [`trigger_proto`] the protocol, [`trigger`] the driver, [`trigger_sim`] the simulated scanner node and
//! [`socketcan_bus`] the SocketCAN backend.

pub mod can;
pub mod grbl;
pub mod grbl_sim;
pub mod link;
pub mod rangecam;
pub mod sim_pty;
pub mod socketcan_bus;
pub mod trigger;
pub mod trigger_proto;
pub mod trigger_sim;
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

//! The turntable: a Grbl 1.1 board turning the table as its axis X, in degrees.
//!
//! - [`protocol`]: Grbl's lines and settings, parsed without I/O; move timing;
//! - [`driver`]: one connected board (reset, banner, its settings reconciled with the config, homing, moves
//!   with deadlines);
//! - [`actor`]: the task that owns the port (commands, published state, faults), supervised by
//!   [`super::supervise`];
//! - [`sim`]: the simulated firmware, pure (bytes and simulated time in, bytes out);
//! - [`transport`]: the serial port, and the simulator on a real pty behind a stable link.

pub mod actor;
pub mod driver;
pub mod protocol;
pub mod sim;
pub mod transport;

pub use driver::{Homing, Motion, MoveReport, Turntable, TurntableSettings};

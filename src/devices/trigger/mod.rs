//! The trigger: the scanner's node on CAN, fired one view at a time.
//!
//! - [`protocol`]: the trigger protocol's messages (trigger, acknowledgement, view ready, heartbeat, EMCY),
//!   encoded and decoded without I/O;
//! - [`actor`]: the task that owns the bus connection: the node's heartbeat, the controller's error frames,
//!   one trigger in flight (the driver's part lives here: the node has no session to keep beyond the bus),
//!   supervised by [`super::supervise`];
//! - [`sim`]: the simulated scanner node;
//! - [`transport`]: CAN frames in SocketCAN's layout, the bus state, and the in-process and Unix-socket buses;
//!   [`socketcan`]: the SocketCAN backend.

pub mod actor;
pub mod protocol;
pub mod sim;
pub mod socketcan;
pub mod transport;

pub use actor::{FireReport, TriggerHandle, TriggerSettings, TriggerState, spawn_trigger};

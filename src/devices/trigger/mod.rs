//! The trigger: the scanner's node on CAN, fired one view at a time.
//!
//! - [`protocol`]: the trigger protocol's messages (trigger, acknowledgement, view ready, heartbeat, EMCY),
//!   encoded and decoded without I/O;
//! - [`driver`]: the session with the node: a trigger checked, sent and made pending, every frame answered;
//!   the settings, state and report types;
//! - [`actor`]: the task that owns the bus connection and its timers (the node's heartbeat, the pending
//!   trigger's deadline), supervised by [`super::supervise`];
//! - [`sim`]: the simulated scanner node;
//! - [`transport`]: CAN frames in SocketCAN's layout, the bus state, and the in-process and Unix-socket buses;
//!   [`socketcan`]: the SocketCAN backend.

pub mod actor;
pub mod driver;
pub mod protocol;
pub mod sim;
pub mod socketcan;
pub mod transport;

pub use actor::{TriggerHandle, spawn_trigger};
pub use driver::{FireReport, TriggerSettings, TriggerState};

/// The trigger's actor: its settings, its ends of the handles' channels, and the last sequence number sent.
/// Its loop is [`actor`]'s, its session with the node [`driver`]'s.
struct Actor {
    settings: TriggerSettings,
    /// Its ends of the handles' channels: commands in, state and faults out.
    ends: crate::devices::supervise::Ends<actor::Command, TriggerState>,
    seq: u16,
}

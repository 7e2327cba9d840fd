//! The session with the scanner node on a connected bus: a trigger checked, sent (with `ENOBUFS` retries) and
//! made pending, and every frame from the bus answered (error frames move the bus state; heartbeats, the
//! acknowledgement, "view ready" and EMCY settle the pending trigger). The actor ([`super::actor`]) owns the
//! connection and its timers and calls these; the settings, state and report types it publishes are here.

use std::time::Duration;

use tokio::sync::oneshot;
use tokio::time::Instant;

use super::Actor;
use super::protocol::{AckStatus, Decoded, Message, NmtState, decode};
use super::transport::{BusState, CanBus, Frame, is_enobufs};
use crate::devices::DeviceFault;
use crate::devices::supervise::Ended;
use crate::error::{Error, ErrorCode, Result};

/// How the trigger is reached and timed (`[devices.trigger]`).
#[derive(Clone, Debug, PartialEq)]
pub struct TriggerSettings {
    /// The CAN interface (`can0`, `vcan0`) or a simulator's socket (`unix:/path`).
    pub interface: String,
    /// The scanner's node id (1–127).
    pub node: u8,
    /// The node's heartbeat period.
    pub heartbeat: Duration,
    /// Heartbeat periods without one before the node is lost.
    pub lost_after: u32,
    /// Longest wait for a trigger's acknowledgement.
    pub ack_timeout: Duration,
    /// Longest wait for "view ready" after the acknowledgement.
    pub view_timeout: Duration,
    /// Longest a send is retried while the transmit queue is full (`ENOBUFS`).
    pub send_patience: Duration,
    /// First wait before reconnecting a lost interface.
    pub reconnect_min: Duration,
    /// Longest wait between reconnecting tries.
    pub reconnect_max: Duration,
}

impl TriggerSettings {
    /// Settings for `interface` and node `node` with the defaults: a 100 ms heartbeat lost after 3 periods,
    /// 250 ms for the acknowledgement, 10 s for the view, 250 ms of `ENOBUFS` retries, reconnecting every
    /// 0.25 s up to every 5 s.
    pub fn new(interface: impl Into<String>, node: u8) -> TriggerSettings {
        TriggerSettings {
            interface: interface.into(),
            node,
            heartbeat: Duration::from_millis(100),
            lost_after: 3,
            ack_timeout: Duration::from_millis(250),
            view_timeout: Duration::from_secs(10),
            send_patience: Duration::from_millis(250),
            reconnect_min: Duration::from_millis(250),
            reconnect_max: Duration::from_secs(5),
        }
    }
}

/// What the trigger is doing, as published.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct TriggerState {
    /// The interface.
    pub interface: String,
    /// The controller's state (`down` while the interface is away).
    pub bus_state: BusState,
    /// The scanner's node id.
    pub node: u8,
    /// The node's heartbeat is current.
    pub node_alive: bool,
    /// The node's NMT state from its last heartbeat.
    pub node_state: Option<NmtState>,
    /// Frames sent.
    pub frames_sent: u64,
    /// Frames received (all nodes, error frames included).
    pub frames_received: u64,
    /// Error frames received and sends that failed.
    pub errors: u64,
    /// Sends retried after `ENOBUFS`.
    pub send_retries: u64,
    /// Frames on the node's identifiers that were malformed.
    pub garbage_frames: u64,
    /// Views reported ready.
    pub views: u64,
    /// Faults so far.
    pub faults: u64,
    /// The last fault.
    pub last_fault: Option<DeviceFault>,
    /// Connections made so far.
    pub connections: u64,
}

impl TriggerState {
    /// Whether a trigger would be sent now: the node is alive and operational, the bus neither off nor down.
    pub fn ready(&self) -> bool {
        self.node_alive
            && self.node_state == Some(NmtState::Operational)
            && !matches!(self.bus_state, BusState::BusOff | BusState::Down)
    }
}

/// One trigger's course.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct FireReport {
    /// Its sequence number.
    pub seq: u16,
    /// The channel fired.
    pub channel: u8,
    /// When the trigger frame was queued, µs since the Unix epoch.
    pub sent_usec: u64,
    /// Milliseconds from sending to the acknowledgement.
    pub ack_ms: f64,
    /// Milliseconds from sending to "view ready".
    pub view_ms: f64,
    /// Points in the view, as the scanner reports.
    pub points: u32,
}

/// The trigger in flight.
pub(super) struct Pending {
    pub(super) seq: u16,
    pub(super) channel: u8,
    pub(super) reply: oneshot::Sender<Result<FireReport>>,
    pub(super) sent: Instant,
    pub(super) sent_usec: u64,
    pub(super) acked: Option<Instant>,
    pub(super) deadline: Instant,
}

/// What the connected loop tracks besides the state.
pub(super) struct Watch {
    /// Last heartbeat (or the connection's start, before the first).
    pub(super) since: Instant,
    /// The loss was reported (no deadline until the node is back).
    pub(super) lost_reported: bool,
    pub(super) pending: Option<Pending>,
}

pub(super) fn usec_now() -> u64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_micros() as u64)
}

impl Actor {
    /// Check, send the trigger and make it pending; `Err` ends the connected phase (the interface is gone).
    pub(super) async fn start_fire<B: CanBus>(
        &mut self,
        bus: &mut B,
        w: &mut Watch,
        channel: u8,
        reply: oneshot::Sender<Result<FireReport>>,
    ) -> std::result::Result<(), Ended> {
        let s = self.ends.state.borrow().clone();
        let refuse = |code, msg: String| Err(Error::new(code, msg));
        let check: Result<()> = if s.bus_state == BusState::BusOff {
            refuse(ErrorCode::DeviceBusOff, format!("{} is bus-off", self.settings.interface))
        } else if !s.node_alive {
            refuse(ErrorCode::DeviceLost, format!("node {} sends no heartbeat", self.settings.node))
        } else if s.node_state != Some(NmtState::Operational) {
            refuse(
                ErrorCode::DeviceRefused,
                format!("node {} is not operational ({:?})", self.settings.node, s.node_state),
            )
        } else {
            Ok(())
        };
        if let Err(e) = check {
            let _ = reply.send(Err(e));
            return Ok(());
        }
        self.seq = self.seq.wrapping_add(1);
        let seq = self.seq;
        let frame = Message::Trigger { node: self.settings.node, seq, channel }.encode();
        let (sent, sent_usec) = (Instant::now(), usec_now());
        match self.send(bus, &frame).await {
            Ok(()) => {
                let deadline = sent + self.settings.ack_timeout;
                w.pending = Some(Pending { seq, channel, reply, sent, sent_usec, acked: None, deadline });
                Ok(())
            }
            Err(e) if e.code == ErrorCode::DeviceUnplugged => {
                self.fault(e.code, e.message.clone());
                let _ = reply.send(Err(e));
                Err(Ended::Lost)
            }
            Err(e) => {
                self.fault(e.code, e.message.clone());
                let _ = reply.send(Err(e));
                Ok(())
            }
        }
    }

    /// Send with `ENOBUFS` retries (1 ms doubling, for up to `send_patience`).
    async fn send<B: CanBus>(&mut self, bus: &mut B, frame: &Frame) -> Result<()> {
        let give_up = Instant::now() + self.settings.send_patience;
        let mut pause = Duration::from_millis(1);
        loop {
            match bus.send(frame).await {
                Ok(()) => {
                    self.ends.state.send_modify(|s| s.frames_sent += 1);
                    return Ok(());
                }
                Err(e) if is_enobufs(&e) => {
                    self.ends.state.send_modify(|s| s.send_retries += 1);
                    if Instant::now() + pause > give_up {
                        self.ends.state.send_modify(|s| s.errors += 1);
                        let st = self.ends.state.borrow().bus_state;
                        let (code, why) = match st {
                            BusState::BusOff | BusState::ErrorPassive => (ErrorCode::DeviceBusOff, st.as_str()),
                            _ => (ErrorCode::DeviceTimeout, "the transmit queue stayed full"),
                        };
                        return Err(Error::new(
                            code,
                            format!(
                                "{}: a frame could not be sent for {} ms ({why})",
                                self.settings.interface,
                                self.settings.send_patience.as_millis()
                            ),
                        ));
                    }
                    tokio::time::sleep(pause).await;
                    pause = (pause * 2).min(Duration::from_millis(64));
                }
                Err(e) => {
                    self.ends.state.send_modify(|s| s.errors += 1);
                    return Err(Error::new(ErrorCode::DeviceUnplugged, format!("{}: {e}", self.settings.interface)));
                }
            }
        }
    }

    pub(super) fn on_frame(&mut self, f: &Frame, w: &mut Watch) {
        self.ends.state.send_modify(|s| s.frames_received += 1);
        let before = self.ends.state.borrow().bus_state;
        if let Some(after) = before.after(f) {
            self.ends.state.send_modify(|s| {
                s.errors += 1;
                s.bus_state = after;
            });
            if after != before {
                tracing::info!(device = "trigger", from = before.as_str(), to = after.as_str(), "bus state");
                if after == BusState::BusOff {
                    let msg = format!("{} went bus-off", self.settings.interface);
                    self.fail_pending(w, ErrorCode::DeviceBusOff, &msg);
                    self.fault(ErrorCode::DeviceBusOff, msg);
                }
            }
            return;
        }
        let node = self.settings.node;
        match decode(f, node) {
            Decoded::Other => {}
            Decoded::Garbage(why) => {
                let n = {
                    self.ends.state.send_modify(|s| s.garbage_frames += 1);
                    self.ends.state.borrow().garbage_frames
                };
                // The first few in full, then one line per 100.
                if n <= 5 || n % 100 == 0 {
                    tracing::warn!(device = "trigger", id = format!("{:#x}", f.id), count = n, "garbage frame: {why}");
                }
            }
            Decoded::Message(Message::Heartbeat { state, .. }) => {
                w.since = Instant::now();
                let was_alive = self.ends.state.borrow().node_alive;
                if !was_alive {
                    tracing::info!(device = "trigger", node, ?state, "node heard");
                }
                w.lost_reported = false;
                self.ends.state.send_modify(|s| {
                    s.node_alive = true;
                    s.node_state = Some(state);
                });
                if state == NmtState::BootUp {
                    self.fail_pending(w, ErrorCode::DeviceLost, &format!("node {node} restarted"));
                }
            }
            Decoded::Message(Message::Ack { seq, status, .. }) => match &mut w.pending {
                Some(p) if p.seq == seq => {
                    if status == AckStatus::Accepted {
                        let now = Instant::now();
                        p.acked = Some(now);
                        p.deadline = now + self.settings.view_timeout;
                    } else {
                        let msg = format!("node {node} refused trigger {seq}: {status:?}");
                        self.fail_pending(w, ErrorCode::DeviceRefused, &msg);
                    }
                }
                _ => tracing::debug!(device = "trigger", seq, "acknowledgement of no pending trigger"),
            },
            Decoded::Message(Message::ViewReady { seq, points, .. }) => match w.pending.take() {
                Some(p) if p.seq == seq => {
                    let now = Instant::now();
                    let ms = |t: Instant| (t - p.sent).as_secs_f64() * 1e3;
                    let report = FireReport {
                        seq,
                        channel: p.channel,
                        sent_usec: p.sent_usec,
                        ack_ms: ms(p.acked.unwrap_or(now)),
                        view_ms: ms(now),
                        points,
                    };
                    self.ends.state.send_modify(|s| s.views += 1);
                    let _ = p.reply.send(Ok(report));
                }
                other => {
                    w.pending = other;
                    tracing::debug!(device = "trigger", seq, "view of no pending trigger");
                }
            },
            Decoded::Message(Message::Emergency { code, register, .. }) => {
                if code == 0 {
                    tracing::info!(device = "trigger", node, "emergency cleared");
                } else {
                    let msg = format!("node {node} emergency {code:#06x} (error register {register:#04x})");
                    self.fail_pending(w, ErrorCode::DeviceEmergency, &msg);
                    self.fault(ErrorCode::DeviceEmergency, msg);
                }
            }
            Decoded::Message(Message::Trigger { .. }) => {}
        }
    }

    pub(super) fn fail_pending(&self, w: &mut Watch, code: ErrorCode, msg: &str) {
        if let Some(p) = w.pending.take() {
            let _ = p.reply.send(Err(Error::new(code, msg.to_string())));
        }
    }
}

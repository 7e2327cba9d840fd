//! The scanner's trigger on CAN as a long-lived device: an actor task that owns the bus connection, watches
//! the scanner node's heartbeat and the controller's error frames, fires triggers one at a time and waits for
//! their acknowledgement and "view ready" (protocol: [`super::protocol`]).
//!
//! - **Heartbeat:** the node is *lost* when [`TriggerSettings::lost_after`] periods pass without one (or
//!   it never appears after connecting): `device.lost`, once per loss. It is back with its next heartbeat.
//! - **Bus state** from error frames ([`BusState::after`]): bus-off is a `device.bus-off` fault and refuses
//!   triggers until the controller restarts (configure the interface with `restart-ms`); a restarted or
//!   error-active frame brings it back.
//! - **Sending:** `ENOBUFS` (a full transmit queue) is retried with a doubling wait from 1 ms for up to
//!   [`TriggerSettings::send_patience`]; then `device.bus-off` (when the state says so) or `device.timeout`.
//! - **A fire** fails with `device.timeout` when no acknowledgement comes within
//!   [`TriggerSettings::ack_timeout`] or no view within [`TriggerSettings::view_timeout`] after it,
//!   `device.refused` when the node answers busy or not ready, `device.lost`/`device.bus-off`/
//!   `device.emergency` when that happens while it waits.
//! - **EMCY** frames become `device.emergency` faults (code 0, "fault cleared", is logged only).
//! - **Garbage** (our identifiers with malformed bodies) is counted and logged, never trusted.
//! - **The interface gone** (the transport fails or closes): `device.unplugged`, reconnect with backoff.
//!
//! No fault ends the actor; it ends when every handle is dropped. Nothing spins: every wait is a timer or a
//! read.

use std::future::Future;
use std::io;
use std::time::Duration;

use tokio::sync::oneshot;
use tokio::time::Instant;

use super::protocol::{AckStatus, Decoded, Message, NmtState, decode};
use super::transport::{BusState, CanBus, Frame, is_enobufs};
use crate::devices::DeviceFault;
use crate::devices::supervise::{self, Backoff, Ended, Ends, Handle, Outage};
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

/// A command to the trigger's actor.
pub enum Command {
    /// Fire the channel and wait for the view.
    Fire(u8, oneshot::Sender<Result<FireReport>>),
}

/// A handle on the trigger actor; dropping every handle ends it. Its state, watch and faults are the shared
/// [`Handle`]'s.
#[derive(Clone)]
pub struct TriggerHandle(Handle<Command, TriggerState>);

impl std::ops::Deref for TriggerHandle {
    type Target = Handle<Command, TriggerState>;
    fn deref(&self) -> &Self::Target {
        &self.0
    }
}

impl TriggerHandle {
    /// Fire `channel` and wait for the view.
    ///
    /// # Errors
    /// `device.unplugged` (no interface), `device.lost` (no heartbeat), `device.bus-off`, `device.refused`
    /// (busy, not ready or not operational), `device.timeout` (no acknowledgement or no view in time),
    /// `device.emergency` (an EMCY while waiting).
    pub async fn fire(&self, channel: u8) -> Result<FireReport> {
        self.0.ask(|tx| Command::Fire(channel, tx)).await
    }
}

/// Start the trigger actor on the current tokio runtime; `connect` opens the transport (again after a loss).
pub fn spawn_trigger<B, F, Fut>(settings: TriggerSettings, connect: F) -> TriggerHandle
where
    B: CanBus,
    F: FnMut() -> Fut + Send + 'static,
    Fut: Future<Output = io::Result<B>> + Send + 'static,
{
    let state = TriggerState {
        interface: settings.interface.clone(),
        node: settings.node,
        bus_state: BusState::Down,
        ..Default::default()
    };
    let (handle, ends) = Handle::new("trigger", state);
    let actor = Actor { settings, ends, seq: 0 };
    tokio::spawn(actor.run(connect));
    TriggerHandle(handle)
}

struct Actor {
    settings: TriggerSettings,
    /// Its ends of the handles' channels: commands in, state and faults out.
    ends: Ends<Command, TriggerState>,
    seq: u16,
}

/// The trigger in flight.
struct Pending {
    seq: u16,
    channel: u8,
    reply: oneshot::Sender<Result<FireReport>>,
    sent: Instant,
    sent_usec: u64,
    acked: Option<Instant>,
    deadline: Instant,
}

/// What the connected loop tracks besides the state.
struct Watch {
    /// Last heartbeat (or the connection's start, before the first).
    since: Instant,
    /// The loss was reported (no deadline until the node is back).
    lost_reported: bool,
    pending: Option<Pending>,
}

fn usec_now() -> u64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_micros() as u64)
}

impl Actor {
    async fn run<B, F, Fut>(mut self, mut connect: F)
    where
        B: CanBus,
        F: FnMut() -> Fut,
        Fut: Future<Output = io::Result<B>>,
    {
        let mut backoff = Backoff::new(self.settings.reconnect_min, self.settings.reconnect_max);
        let mut outage = Outage::default();
        loop {
            let bus = match connect().await {
                Ok(b) => b,
                Err(e) => {
                    let e = Error::new(ErrorCode::DeviceUnplugged, format!("{}: {e}", self.settings.interface));
                    if outage.report(&e) {
                        self.fault(e.code, e.message);
                    } else {
                        tracing::debug!(device = "trigger", error = %e, "still unreachable");
                    }
                    let interface = self.settings.interface.clone();
                    let refuse = |Command::Fire(_, reply): Command| {
                        let e = Error::new(
                            ErrorCode::DeviceUnplugged,
                            format!("the trigger's interface ({interface}) is not there"),
                        );
                        let _ = reply.send(Err(e));
                    };
                    if supervise::idle(&mut self.ends.commands, backoff.next_wait(), refuse).await {
                        return;
                    }
                    continue;
                }
            };
            backoff.reset();
            outage.connected();
            tracing::info!(device = "trigger", interface = %self.settings.interface, node = self.settings.node, "connected");
            self.ends.state.send_modify(|s| {
                s.bus_state = BusState::ErrorActive;
                s.connections += 1;
            });
            let ended = self.serve(bus).await;
            self.ends.state.send_modify(|s| {
                s.bus_state = BusState::Down;
                s.node_alive = false;
            });
            if let Ended::Closed = ended {
                return;
            }
            // The loss was the outage's fault; failed reopening tries are not faults of their own.
            outage.lost();
        }
    }

    async fn serve<B: CanBus>(&mut self, mut bus: B) -> Ended {
        let lost_span = self.settings.heartbeat * self.settings.lost_after.max(1);
        let mut w = Watch { since: Instant::now(), lost_reported: false, pending: None };
        loop {
            let heartbeat_due = w.since + lost_span;
            let pending_due = w.pending.as_ref().map_or(heartbeat_due, |p| p.deadline);
            tokio::select! {
                c = self.ends.commands.recv(), if w.pending.is_none() => match c {
                    None => return Ended::Closed,
                    Some(Command::Fire(channel, reply)) => {
                        if let Err(lost) = self.start_fire(&mut bus, &mut w, channel, reply).await {
                            return lost;
                        }
                    }
                },
                r = bus.recv() => match r {
                    Ok(f) => self.on_frame(&f, &mut w),
                    Err(e) => {
                        let msg = format!("{}: {e}", self.settings.interface);
                        self.fail_pending(&mut w, ErrorCode::DeviceUnplugged, &msg);
                        self.fault(ErrorCode::DeviceUnplugged, msg);
                        return Ended::Lost;
                    }
                },
                _ = tokio::time::sleep_until(heartbeat_due), if !w.lost_reported => {
                    w.lost_reported = true;
                    let seen = self.ends.state.borrow().node_state.is_some();
                    let msg = if seen {
                        format!("node {} sent no heartbeat for {} ms", self.settings.node, lost_span.as_millis())
                    } else {
                        format!("node {} sent no heartbeat within {} ms of connecting", self.settings.node, lost_span.as_millis())
                    };
                    self.ends.state.send_modify(|s| s.node_alive = false);
                    self.fail_pending(&mut w, ErrorCode::DeviceLost, &msg);
                    self.fault(ErrorCode::DeviceLost, msg);
                },
                _ = tokio::time::sleep_until(pending_due), if w.pending.is_some() => {
                    let p = w.pending.as_ref().expect("pending");
                    let msg = match p.acked {
                        None => format!("no acknowledgement of trigger {} within {} ms", p.seq, self.settings.ack_timeout.as_millis()),
                        Some(_) => format!("no view for trigger {} within {} ms of its acknowledgement", p.seq, self.settings.view_timeout.as_millis()),
                    };
                    self.fail_pending(&mut w, ErrorCode::DeviceTimeout, &msg);
                    self.fault(ErrorCode::DeviceTimeout, msg);
                },
            }
        }
    }

    /// Check, send the trigger and make it pending; `Err` ends the connected phase (the interface is gone).
    async fn start_fire<B: CanBus>(
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

    fn on_frame(&mut self, f: &Frame, w: &mut Watch) {
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

    fn fail_pending(&self, w: &mut Watch, code: ErrorCode, msg: &str) {
        if let Some(p) = w.pending.take() {
            let _ = p.reply.send(Err(Error::new(code, msg.to_string())));
        }
    }

    fn fault(&self, code: ErrorCode, message: String) {
        tracing::warn!(device = "trigger", code = %code, error = %message, "device fault");
        let fault = DeviceFault { device: "trigger", code, message };
        self.ends.state.send_modify(|s| {
            s.faults += 1;
            s.last_fault = Some(fault.clone());
        });
        let _ = self.ends.faults.send(fault);
    }
}

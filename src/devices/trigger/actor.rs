//! The scanner's trigger on CAN as a long-lived device: an actor task that owns the bus connection, watches
//! the scanner node's heartbeat and the controller's error frames, fires triggers one at a time and waits for
//! their acknowledgement and "view ready" (protocol: [`super::protocol`]; the session with the node — a
//! trigger sent, its frames answered — is [`super::driver`]).
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

use tokio::sync::oneshot;
use tokio::time::Instant;

use super::Actor;
use super::driver::{FireReport, TriggerSettings, TriggerState, Watch};
use super::transport::{BusState, CanBus};
use crate::devices::DeviceFault;
use crate::devices::supervise::{self, Backoff, Ended, Handle, Outage};
use crate::error::{Error, ErrorCode, Result};

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

    pub(super) fn fault(&self, code: ErrorCode, message: String) {
        tracing::warn!(device = "trigger", code = %code, error = %message, "device fault");
        let fault = DeviceFault { device: "trigger", code, message };
        self.ends.state.send_modify(|s| {
            s.faults += 1;
            s.last_fault = Some(fault.clone());
        });
        let _ = self.ends.faults.send(fault);
    }
}

//! The turntable as a long-lived device: an actor task that owns the port, connects, reconnects with backoff
//! after an unplug, re-homes before the first move after a reconnect, watches an idle board with a status
//! poll, and publishes its state and its faults.
//!
//! Callers hold a [`TurntableHandle`]: commands go in over a channel (one at a time, in order), the state is a
//! `watch` value ([`TurntableState`]: `connected`, `homed`, `moving`, `angle`, …), faults a `broadcast`
//! ([`DeviceFault`]). A fault never ends the actor: an unplugged or silent port is closed and reopened every
//! [`LinkSettings::reconnect_min`] doubling to [`LinkSettings::reconnect_max`] (sleeping between tries, never
//! spinning); a timed-out or refused move leaves the board stopped and re-homed before the next one.

use std::path::PathBuf;
use std::time::Duration;

use tokio::sync::oneshot;

use super::driver::{MoveReport, Turntable, TurntableSettings};
use super::transport::open_serial;
use crate::devices::supervise::{self, Backoff, Ended, Ends, Handle, Outage};
use crate::error::{Error, ErrorCode, Result};

/// Where the turntable is and how to reach it (`[devices.turntable]`).
#[derive(Clone, Debug, PartialEq)]
pub struct LinkSettings {
    /// The serial port (a stable name: `/dev/serial/by-id/…` or a udev symlink).
    pub port: PathBuf,
    /// Baud rate (Grbl: 115200).
    pub baud: u32,
    /// The driver's settings.
    pub driver: TurntableSettings,
    /// First wait before reopening a lost port.
    pub reconnect_min: Duration,
    /// Longest wait between reopening tries.
    pub reconnect_max: Duration,
    /// Status poll of an idle board (notices an unplug or an alarm between moves).
    pub idle_poll: Duration,
}

impl LinkSettings {
    /// Settings for `port` with the defaults: 115200 baud, reconnecting every 0.25 s up to every 5 s, an idle
    /// poll every second.
    pub fn new(port: impl Into<PathBuf>) -> LinkSettings {
        LinkSettings {
            port: port.into(),
            baud: 115_200,
            driver: TurntableSettings::default(),
            reconnect_min: Duration::from_millis(250),
            reconnect_max: Duration::from_secs(5),
            idle_poll: Duration::from_secs(1),
        }
    }
}

/// What the turntable is doing, as published.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct TurntableState {
    /// The port is open and the board answered.
    pub connected: bool,
    /// The port.
    pub port: String,
    /// Firmware name and version (`Grbl 1.1h`), empty before the first connection.
    pub firmware: String,
    /// The table's zero is established.
    pub homed: bool,
    /// A move is in progress.
    pub moving: bool,
    /// The table's angle as last reported, degrees.
    pub angle: f64,
    /// The cradle's tilt as last reported, degrees (0 on a single-axis table).
    pub tilt: f64,
    /// A tilting table's range (lowest, highest tilt), degrees, as configured; `None`: single-axis.
    pub tilt_range: Option<(f64, f64)>,
    /// Lines from the board that parsed as nothing, over all connections.
    pub garbage_lines: u64,
    /// Faults so far.
    pub faults: u64,
    /// The last fault (also sent on the fault channel, which only those subscribed at the time see).
    pub last_fault: Option<DeviceFault>,
    /// Connections made so far.
    pub connections: u64,
    /// The board's settings as read at the last connect (`$$`), `None` before the first.
    pub board: Option<super::protocol::BoardSettings>,
    /// The top speed moves run at, degrees per second (the config's, else the board's), 0 before the first
    /// connect.
    pub speed: f64,
    /// How the zero is established on this board (`home` or `unlock`), empty before the first connect.
    pub homing: String,
}

pub use crate::devices::DeviceFault;

/// A command to the turntable's actor.
pub enum Command {
    /// Home (or unlock).
    Home(oneshot::Sender<Result<()>>),
    /// Turn to the angle, and tilt to the second when given, degrees.
    MoveTo(f64, Option<f64>, oneshot::Sender<Result<MoveReport>>),
    /// Stop where the table is.
    Stop(oneshot::Sender<Result<()>>),
}

/// A handle on the turntable actor; dropping every handle ends it. Its state, watch and faults are the
/// shared [`Handle`]'s.
#[derive(Clone)]
pub struct TurntableHandle(Handle<Command, TurntableState>);

impl std::ops::Deref for TurntableHandle {
    type Target = Handle<Command, TurntableState>;
    fn deref(&self) -> &Self::Target {
        &self.0
    }
}

impl TurntableHandle {
    /// Home (or unlock, as configured).
    ///
    /// # Errors
    /// `device.*` as [`Turntable::unlock_or_home`]; `device.unplugged` while disconnected.
    pub async fn home(&self) -> Result<()> {
        self.0.ask(Command::Home).await
    }

    /// Turn to `degrees`.
    ///
    /// # Errors
    /// As [`Turntable::move_to`]; `device.unplugged` while disconnected.
    pub async fn move_to(&self, degrees: f64) -> Result<MoveReport> {
        self.0.ask(|tx| Command::MoveTo(degrees, None, tx)).await
    }

    /// Turn to `degrees` and tilt the cradle to `tilt`.
    ///
    /// # Errors
    /// As [`Turntable::move_to_tilted`]; `device.unplugged` while disconnected.
    pub async fn move_to_tilted(&self, degrees: f64, tilt: f64) -> Result<MoveReport> {
        self.0.ask(|tx| Command::MoveTo(degrees, Some(tilt), tx)).await
    }

    /// Stop where the table is (after the command before it).
    ///
    /// # Errors
    /// `device.unplugged` while disconnected.
    pub async fn stop(&self) -> Result<()> {
        self.0.ask(Command::Stop).await
    }
}

/// Start the turntable actor on the current tokio runtime.
pub fn spawn_turntable(settings: LinkSettings) -> TurntableHandle {
    let state = TurntableState {
        port: settings.port.display().to_string(),
        tilt_range: settings.driver.tilt,
        ..Default::default()
    };
    let (handle, ends) = Handle::new("turntable", state);
    let actor = Actor { settings, ends, garbage_base: 0 };
    tokio::spawn(actor.run());
    TurntableHandle(handle)
}

struct Actor {
    settings: LinkSettings,
    /// Its ends of the handles' channels: commands in, state and faults out.
    ends: Ends<Command, TurntableState>,
    /// Garbage lines of the connections before this one.
    garbage_base: u64,
}

impl Actor {
    async fn run(mut self) {
        let mut backoff = Backoff::new(self.settings.reconnect_min, self.settings.reconnect_max);
        let mut outage = Outage::default();
        loop {
            // 1. Connect, answering commands with `device.unplugged` (or the board's refusal) while away.
            let name = self.settings.port.display().to_string();
            let opened = match open_serial(&self.settings.port, self.settings.baud) {
                Ok(io) => Turntable::connect(io, self.settings.driver.clone(), &name).await,
                Err(e) => Err(e),
            };
            let tt = match opened {
                Ok(tt) => tt,
                Err(e) => {
                    if outage.report(&e) {
                        self.fault(&e);
                    } else {
                        tracing::debug!(device = "turntable", error = %e, "still unreachable");
                    }
                    let blocked = (e.code == ErrorCode::DeviceConfig).then_some(e);
                    let port = self.settings.port.clone();
                    if supervise::idle(&mut self.ends.commands, backoff.next_wait(), |c| {
                        refuse(c, &port, blocked.as_ref())
                    })
                    .await
                    {
                        return;
                    }
                    continue;
                }
            };
            backoff.reset();
            outage.connected();
            self.garbage_base = self.ends.state.borrow().garbage_lines;
            tracing::info!(device = "turntable", port = %name, firmware = tt.firmware(), "connected");
            self.ends.state.send_modify(|s| {
                s.connected = true;
                s.firmware = tt.firmware().to_string();
                s.board = Some(*tt.board());
                s.speed = tt.motion().speed;
                s.homing = tt.motion().homing.as_str().to_string();
                s.homed = tt.homed();
                s.angle = tt.angle();
                s.tilt = tt.tilt();
                s.connections += 1;
            });
            // 2. Serve commands until the line fails.
            let ended = self.serve(tt).await;
            self.ends.state.send_modify(|s| {
                s.connected = false;
                s.homed = false;
                s.moving = false;
            });
            if let Ended::Closed = ended {
                return;
            }
            // The loss was the outage's fault; failed reopening tries are not faults of their own.
            outage.lost();
        }
    }

    async fn serve<S>(&mut self, mut tt: Turntable<S>) -> Ended
    where
        S: tokio::io::AsyncRead + tokio::io::AsyncWrite + Unpin,
    {
        loop {
            let command = tokio::select! {
                c = self.ends.commands.recv() => c,
                _ = tokio::time::sleep(self.settings.idle_poll) => {
                    let r = tt.status().await.map(|_| ());
                    if let Some(ended) = self.after(&mut tt, r.as_ref().err()).await {
                        return ended;
                    }
                    continue;
                }
            };
            let Some(command) = command else { return Ended::Closed };
            let failure = match command {
                // The state is published before the reply, so a caller sees the angle it was answered.
                Command::Home(reply) => {
                    let r = tt.unlock_or_home().await;
                    self.publish(&tt);
                    let e = r.as_ref().err().cloned();
                    let _ = reply.send(r);
                    e
                }
                Command::MoveTo(deg, tilt, reply) => {
                    self.ends.state.send_modify(|s| s.moving = true);
                    let r = match tilt {
                        Some(t) => tt.move_to_tilted(deg, t).await,
                        None => tt.move_to(deg).await,
                    };
                    self.ends.state.send_modify(|s| s.moving = false);
                    self.publish(&tt);
                    let e = r.as_ref().err().cloned();
                    let _ = reply.send(r);
                    e
                }
                Command::Stop(reply) => {
                    let r = tt.stop().await;
                    self.publish(&tt);
                    let e = r.as_ref().err().cloned();
                    let _ = reply.send(r);
                    e
                }
            };
            if let Some(ended) = self.after(&mut tt, failure.as_ref()).await {
                return ended;
            }
        }
    }

    /// After a command or a poll: publish the state; on a failure, the fault and the recovery. `Some` ends
    /// the connected phase.
    async fn after<S>(&mut self, tt: &mut Turntable<S>, failure: Option<&Error>) -> Option<Ended>
    where
        S: tokio::io::AsyncRead + tokio::io::AsyncWrite + Unpin,
    {
        let mut lost = false;
        // A caller's bad argument (a target out of range) is refused before anything moves: not a fault.
        if let Some(e) = failure.filter(|e| e.code != ErrorCode::InputBadArgument) {
            self.fault(e);
            match e.code {
                ErrorCode::DeviceUnplugged => lost = true,
                // The board may still be moving, or may have lost a line: hold and reset it; the next
                // move re-homes. A board that does not answer that is lost.
                ErrorCode::DeviceTimeout | ErrorCode::DevicePosition => {
                    if let Err(e2) = tt.stop().await {
                        self.fault(&e2);
                        lost = true;
                    }
                }
                _ => {}
            }
        }
        self.publish(tt);
        lost.then_some(Ended::Lost)
    }

    /// The driver's homed flag, angle and garbage count into the published state.
    fn publish<S: tokio::io::AsyncRead + tokio::io::AsyncWrite + Unpin>(&self, tt: &Turntable<S>) {
        self.ends.state.send_modify(|s| {
            s.homed = tt.homed();
            s.angle = tt.angle();
            s.tilt = tt.tilt();
            s.garbage_lines = self.garbage_base + tt.garbage_lines();
        });
    }

    fn fault(&self, e: &Error) {
        tracing::warn!(device = "turntable", code = %e.code, error = %e.message, "device fault");
        let fault = DeviceFault { device: "turntable", code: e.code, message: e.message.clone() };
        self.ends.state.send_modify(|s| {
            s.faults += 1;
            s.last_fault = Some(fault.clone());
        });
        let _ = self.ends.faults.send(fault);
    }
}

/// Answer `c` while disconnected: `device.unplugged`, or the reason the board cannot be used (`why`: a
/// `device.config` mismatch found at connect).
fn refuse(c: Command, port: &std::path::Path, why: Option<&Error>) {
    let e = || match why {
        Some(w) => w.clone(),
        None => Error::new(ErrorCode::DeviceUnplugged, format!("the turntable ({}) is not connected", port.display())),
    };
    match c {
        Command::Home(r) | Command::Stop(r) => {
            let _ = r.send(Err(e()));
        }
        Command::MoveTo(_, _, r) => {
            let _ = r.send(Err(e()));
        }
    }
}

//! The rig on D-Bus: `org.scanstation.Station1.Turntable` at [`TURNTABLE_PATH`] and
//! `org.scanstation.Station1.Trigger` at [`TRIGGER_PATH`], exported only for the devices the config names.
//!
//! Thin, as the Manager and the jobs (after InputPlumber): the device actors ([`crate::devices::turntable::actor`],
//! [`crate::devices::trigger`]) own the ports and the state; an interface reads the actor's published state
//! and sends it commands through its handle. A mirror task per device turns state changes into
//! `PropertiesChanged`, faults into the `Fault` signal, and the device's health into the Manager's `State`
//! (`degraded` while a configured device is lost; back when it returns). Moving and firing need the
//! submitting privilege (root, the daemon's user, the ops group); reading is open to all.

use std::collections::HashMap;

use tokio::sync::mpsc;
use zbus::message::Header;
use zbus::object_server::SignalEmitter;
use zbus::zvariant::{OwnedValue, Value};
use zbus::{Connection, interface};

use super::config::{TriggerConfig, TurntableConfig};
use super::dbus::{Access, Command, StationError, authorize};
use crate::devices::trigger::socketcan::SocketCanBus;
use crate::devices::trigger::transport::{BusState, StreamBus};
use crate::devices::trigger::{TriggerHandle, TriggerSettings, TriggerState, spawn_trigger};
use crate::devices::turntable::TurntableSettings;
use crate::devices::turntable::actor::{DeviceFault, LinkSettings, TurntableHandle, TurntableState, spawn_turntable};
use crate::error::Error;

/// The turntable's object path.
pub const TURNTABLE_PATH: &str = "/org/scanstation/Station1/devices/turntable";
/// The trigger's object path.
pub const TRIGGER_PATH: &str = "/org/scanstation/Station1/devices/trigger";

/// A device error for a D-Bus caller: `org.scanstation.Station1.Error.Device`, the message led by the code.
fn device_err(e: Error) -> StationError {
    StationError::Device(format!("[{}] {}", e.code, e.message))
}

fn no_options(options: &HashMap<String, OwnedValue>) -> Result<(), StationError> {
    match options.keys().next() {
        Some(k) => Err(StationError::InvalidArgument(format!("unknown option {k:?} (none are defined yet)"))),
        None => Ok(()),
    }
}

/// `MoveTo`'s options: `tilt` (a double), nothing else.
fn tilt_option(options: &HashMap<String, OwnedValue>) -> Result<Option<f64>, StationError> {
    let mut tilt = None;
    for (k, v) in options {
        match (k.as_str(), &**v) {
            ("tilt", Value::F64(t)) if t.is_finite() => tilt = Some(*t),
            ("tilt", other) => {
                return Err(StationError::InvalidArgument(format!(
                    "option \"tilt\" must be a finite double (degrees), not {} {other:?}",
                    other.value_signature()
                )));
            }
            _ => return Err(StationError::InvalidArgument(format!("unknown option {k:?} (MoveTo takes: tilt)"))),
        }
    }
    Ok(tilt)
}

/// `org.scanstation.Station1.Turntable`.
pub struct TurntableIface {
    handle: TurntableHandle,
    access: Access,
    steps_per_revolution: u32,
}

/// `org.scanstation.Station1.Trigger`.
pub struct TriggerIface {
    handle: TriggerHandle,
    access: Access,
}

/// The devices' D-Bus interfaces (a module of their own so that the undocumented helpers zbus's interface
/// macro adds are allowed, and nothing else).
pub mod ifaces {
    #![allow(missing_docs)]
    use super::*;

    #[interface(name = "org.scanstation.Station1.Turntable")]
    impl TurntableIface {
        /// Home the table (or unlock it, as configured).
        async fn home(
            &self,
            #[zbus(header)] hdr: Header<'_>,
            #[zbus(connection)] conn: &Connection,
        ) -> Result<(), StationError> {
            authorize(conn, &hdr, &self.access, "Turntable.Home").await?;
            self.handle.home().await.map_err(device_err)
        }

        /// Turn to `degrees` (absolute); returns the angle the board reports when it stops. Options: `tilt`
        /// (double, degrees): a tilting table's cradle moves there too, along the same path (within
        /// `TiltRange`; a table with none refuses it, `device.config`).
        async fn move_to(
            &self,
            degrees: f64,
            options: HashMap<String, OwnedValue>,
            #[zbus(header)] hdr: Header<'_>,
            #[zbus(connection)] conn: &Connection,
        ) -> Result<f64, StationError> {
            authorize(conn, &hdr, &self.access, "Turntable.MoveTo").await?;
            let tilt = tilt_option(&options)?;
            if !(degrees.is_finite() && degrees.abs() <= 1e6) {
                return Err(StationError::InvalidArgument(format!("{degrees} is not an angle (|a| ≤ 1e6)")));
            }
            let moved = match tilt {
                Some(t) => self.handle.move_to_tilted(degrees, t).await,
                None => self.handle.move_to(degrees).await,
            };
            moved.map(|r| r.reached).map_err(device_err)
        }

        /// Stop where the table is.
        async fn stop(
            &self,
            #[zbus(header)] hdr: Header<'_>,
            #[zbus(connection)] conn: &Connection,
        ) -> Result<(), StationError> {
            authorize(conn, &hdr, &self.access, "Turntable.Stop").await?;
            self.handle.stop().await.map_err(device_err)
        }

        #[zbus(property)]
        fn connected(&self) -> bool {
            self.handle.state().connected
        }

        #[zbus(property(emits_changed_signal = "const"))]
        fn port(&self) -> String {
            self.handle.state().port
        }

        #[zbus(property)]
        fn firmware(&self) -> String {
            self.handle.state().firmware
        }

        #[zbus(property)]
        fn homed(&self) -> bool {
            self.handle.state().homed
        }

        #[zbus(property)]
        fn moving(&self) -> bool {
            self.handle.state().moving
        }

        /// Degrees, as the board last reported.
        #[zbus(property)]
        fn angle(&self) -> f64 {
            self.handle.state().angle
        }

        /// The cradle's tilt, degrees, as the board last reported (Grbl's Y; 0 on a single-axis table).
        #[zbus(property)]
        fn tilt(&self) -> f64 {
            self.handle.state().tilt
        }

        /// A tilting table's range (lowest, highest tilt), degrees, as configured; empty on a single-axis
        /// table.
        #[zbus(property(emits_changed_signal = "const"))]
        fn tilt_range(&self) -> Vec<f64> {
            self.handle.state().tilt_range.map_or(Vec::new(), |(lo, hi)| vec![lo, hi])
        }

        /// As configured (0: not given).
        #[zbus(property(emits_changed_signal = "const"))]
        fn steps_per_revolution(&self) -> u32 {
            self.steps_per_revolution
        }

        /// The board's homing (`$22`), as read at the last connect.
        #[zbus(property)]
        fn board_homing(&self) -> bool {
            self.handle.state().board.is_some_and(|b| b.homing)
        }

        /// The board's top rate (`$110`), degrees per minute, as read at the last connect (0 before it).
        #[zbus(property)]
        fn board_max_rate(&self) -> f64 {
            self.handle.state().board.map_or(0.0, |b| b.max_rate)
        }

        /// The board's acceleration (`$120`), degrees per second², as read at the last connect (0 before it).
        #[zbus(property)]
        fn board_acceleration(&self) -> f64 {
            self.handle.state().board.map_or(0.0, |b| b.accel)
        }

        /// The board's steps per degree (`$100`), as read at the last connect (0 before it).
        #[zbus(property)]
        fn board_steps_per_degree(&self) -> f64 {
            self.handle.state().board.map_or(0.0, |b| b.steps_per_degree)
        }

        /// The top speed moves run at, degrees per second: the config's, else the board's.
        #[zbus(property)]
        fn speed(&self) -> f64 {
            self.handle.state().speed
        }

        /// How the zero is established on this board: `home` (`$H`) or `unlock` (`$X`, or nothing when not
        /// locked); empty before the first connect.
        #[zbus(property)]
        fn homing(&self) -> String {
            self.handle.state().homing
        }

        /// A device fault: its stable code (`device.*`), a message, details (`device`).
        #[zbus(signal)]
        pub async fn fault(
            emitter: &SignalEmitter<'_>,
            code: &str,
            message: &str,
            details: HashMap<&str, Value<'_>>,
        ) -> zbus::Result<()>;
    }

    #[interface(name = "org.scanstation.Station1.Trigger")]
    impl TriggerIface {
        /// Fire `channel` and wait for the view; returns when the trigger was sent, µs since the epoch.
        async fn fire(
            &self,
            channel: u32,
            options: HashMap<String, OwnedValue>,
            #[zbus(header)] hdr: Header<'_>,
            #[zbus(connection)] conn: &Connection,
        ) -> Result<u64, StationError> {
            authorize(conn, &hdr, &self.access, "Trigger.Fire").await?;
            no_options(&options)?;
            let channel = u8::try_from(channel)
                .map_err(|_| StationError::InvalidArgument(format!("channel {channel} is outside 0..=255")))?;
            self.handle.fire(channel).await.map(|r| r.sent_usec).map_err(device_err)
        }

        #[zbus(property(emits_changed_signal = "const"))]
        fn interface(&self) -> String {
            self.handle.state().interface
        }

        /// error-active, error-warning, error-passive, bus-off or down.
        #[zbus(property)]
        fn bus_state(&self) -> String {
            self.handle.state().bus_state.as_str().to_string()
        }

        /// Whether the scanner's heartbeat is current.
        #[zbus(property)]
        fn node_alive(&self) -> bool {
            self.handle.state().node_alive
        }

        #[zbus(property)]
        fn frames_sent(&self) -> u64 {
            self.handle.state().frames_sent
        }

        /// Error frames received and sends that failed.
        #[zbus(property)]
        fn errors(&self) -> u64 {
            self.handle.state().errors
        }

        /// A device fault: its stable code (`device.*`), a message, details (`device`).
        #[zbus(signal)]
        pub async fn fault(
            emitter: &SignalEmitter<'_>,
            code: &str,
            message: &str,
            details: HashMap<&str, Value<'_>>,
        ) -> zbus::Result<()>;
    }
}

/// The turntable's driver settings from its config section.
pub fn link_settings(c: &TurntableConfig) -> LinkSettings {
    LinkSettings {
        baud: c.baud,
        driver: TurntableSettings {
            speed: c.speed,
            accel: c.accel,
            homing: c.homing,
            reply_timeout: c.reply_timeout,
            banner_timeout: c.banner_timeout,
            home_timeout: c.home_timeout,
            tilt: c.tilt,
            ..Default::default()
        },
        reconnect_max: c.reconnect_max,
        ..LinkSettings::new(&c.port)
    }
}

/// The trigger's driver settings from its config section.
pub fn trigger_settings(c: &TriggerConfig) -> TriggerSettings {
    TriggerSettings {
        heartbeat: c.heartbeat,
        lost_after: c.lost_after,
        ack_timeout: c.ack_timeout,
        view_timeout: c.view_timeout,
        ..TriggerSettings::new(c.interface.clone(), c.node)
    }
}

/// Start the trigger's actor on the transport its interface names (`unix:PATH` or a CAN interface).
pub fn start_trigger(c: &TriggerConfig) -> TriggerHandle {
    let settings = trigger_settings(c);
    match c.interface.strip_prefix("unix:") {
        Some(path) => {
            let path = std::path::PathBuf::from(path);
            spawn_trigger(settings, move || {
                let p = path.clone();
                async move { StreamBus::connect(&p).await }
            })
        }
        None => {
            let name = c.interface.clone();
            spawn_trigger(settings, move || std::future::ready(SocketCanBus::open(&name)))
        }
    }
}

/// Why a turntable makes the station degraded (none while it is connected).
fn turntable_health(s: &TurntableState) -> Vec<String> {
    if s.connected { vec![] } else { vec!["turntable-disconnected".into()] }
}

/// Why a trigger makes the station degraded.
fn trigger_health(s: &TriggerState) -> Vec<String> {
    match s.bus_state {
        BusState::Down => vec!["can-down".into()],
        BusState::BusOff => vec!["can-bus-off".into()],
        _ if !s.node_alive => vec!["scanner-lost".into()],
        _ => vec![],
    }
}

fn details(f: &DeviceFault) -> HashMap<&'static str, Value<'static>> {
    HashMap::from([("device", Value::from(f.device.to_string()))])
}

/// Export the configured devices and start their mirror tasks. `station` takes their health; the handles
/// come back for the scans.
///
/// # Errors
/// Exporting an object.
pub async fn start(
    conn: &Connection,
    turntable: Option<&TurntableConfig>,
    trigger: Option<&TriggerConfig>,
    access: &Access,
    station: mpsc::Sender<Command>,
) -> zbus::Result<crate::daemon::scan::Rig> {
    let server = conn.object_server();
    let mut rig = crate::daemon::scan::Rig::default();
    if let Some(c) = turntable {
        let handle = spawn_turntable(link_settings(c));
        let iface = TurntableIface {
            handle: handle.clone(),
            access: access.clone(),
            steps_per_revolution: c.steps_per_revolution,
        };
        server.at(TURNTABLE_PATH, iface).await?;
        let r = server.interface::<_, TurntableIface>(TURNTABLE_PATH).await?;
        tokio::spawn(mirror(handle.watch(), handle.faults(), r, station.clone()));
        rig.turntable = Some(handle);
    }
    if let Some(c) = trigger {
        let handle = start_trigger(c);
        server.at(TRIGGER_PATH, TriggerIface { handle: handle.clone(), access: access.clone() }).await?;
        let r = server.interface::<_, TriggerIface>(TRIGGER_PATH).await?;
        tokio::spawn(mirror(handle.watch(), handle.faults(), r, station));
        rig.trigger = Some(handle);
    }
    Ok(rig)
}

async fn health(station: &mpsc::Sender<Command>, device: &'static str, reasons: Vec<String>) {
    let _ = station.send(Command::DeviceHealth { device, reasons }).await;
}

/// What a device's mirror task needs of its interface: the state it mirrors, why that state degrades the
/// station, and the signals for a change and a fault.
trait Mirrored: zbus::object_server::Interface + Sized {
    type State: Clone + Send + Sync + 'static;
    const DEVICE: &'static str;
    fn health(s: &Self::State) -> Vec<String>;
    /// `PropertiesChanged` for each property that differs between `old` and `new`.
    fn emit_changes(
        &self,
        em: &SignalEmitter<'_>,
        old: &Self::State,
        new: &Self::State,
    ) -> impl std::future::Future<Output = ()> + Send;
    fn emit_fault(em: &SignalEmitter<'_>, f: &DeviceFault) -> impl std::future::Future<Output = ()> + Send;
}

impl Mirrored for TurntableIface {
    type State = TurntableState;
    const DEVICE: &'static str = "turntable";
    fn health(s: &TurntableState) -> Vec<String> {
        turntable_health(s)
    }
    async fn emit_changes(&self, em: &SignalEmitter<'_>, old: &TurntableState, new: &TurntableState) {
        if new.connected != old.connected {
            let _ = self.connected_changed(em).await;
        }
        if new.firmware != old.firmware {
            let _ = self.firmware_changed(em).await;
        }
        if new.homed != old.homed {
            let _ = self.homed_changed(em).await;
        }
        if new.moving != old.moving {
            let _ = self.moving_changed(em).await;
        }
        if new.angle != old.angle {
            let _ = self.angle_changed(em).await;
        }
        if new.tilt != old.tilt {
            let _ = self.tilt_changed(em).await;
        }
        if new.board != old.board {
            let _ = self.board_homing_changed(em).await;
            let _ = self.board_max_rate_changed(em).await;
            let _ = self.board_acceleration_changed(em).await;
            let _ = self.board_steps_per_degree_changed(em).await;
        }
        if new.speed != old.speed {
            let _ = self.speed_changed(em).await;
        }
        if new.homing != old.homing {
            let _ = self.homing_changed(em).await;
        }
    }
    async fn emit_fault(em: &SignalEmitter<'_>, f: &DeviceFault) {
        let _ = TurntableIface::fault(em, f.code.as_str(), &f.message, details(f)).await;
    }
}

impl Mirrored for TriggerIface {
    type State = TriggerState;
    const DEVICE: &'static str = "trigger";
    fn health(s: &TriggerState) -> Vec<String> {
        trigger_health(s)
    }
    async fn emit_changes(&self, em: &SignalEmitter<'_>, old: &TriggerState, new: &TriggerState) {
        if new.bus_state != old.bus_state {
            let _ = self.bus_state_changed(em).await;
        }
        if new.node_alive != old.node_alive {
            let _ = self.node_alive_changed(em).await;
        }
        if new.frames_sent != old.frames_sent {
            let _ = self.frames_sent_changed(em).await;
        }
        if new.errors != old.errors {
            let _ = self.errors_changed(em).await;
        }
    }
    async fn emit_fault(em: &SignalEmitter<'_>, f: &DeviceFault) {
        let _ = TriggerIface::fault(em, f.code.as_str(), &f.message, details(f)).await;
    }
}

/// A device's mirror task: state changes become `PropertiesChanged`, faults the `Fault` signal, and health
/// changes a [`Command::DeviceHealth`] to the station. Ends when the device's actor does.
async fn mirror<I: Mirrored>(
    mut w: tokio::sync::watch::Receiver<I::State>,
    mut faults: tokio::sync::broadcast::Receiver<DeviceFault>,
    r: zbus::object_server::InterfaceRef<I>,
    station: mpsc::Sender<Command>,
) {
    let mut last = w.borrow_and_update().clone();
    let mut last_health = I::health(&last);
    health(&station, I::DEVICE, last_health.clone()).await;
    loop {
        tokio::select! {
            c = w.changed() => {
                if c.is_err() {
                    return;
                }
                let s = w.borrow_and_update().clone();
                r.get().await.emit_changes(r.signal_emitter(), &last, &s).await;
                let h = I::health(&s);
                if h != last_health {
                    health(&station, I::DEVICE, h.clone()).await;
                    last_health = h;
                }
                last = s;
            }
            f = faults.recv() => match f {
                Ok(f) => I::emit_fault(r.signal_emitter(), &f).await,
                Err(tokio::sync::broadcast::error::RecvError::Lagged(n)) => tracing::warn!(device = I::DEVICE, n, "fault signals dropped"),
                Err(_) => return,
            },
        }
    }
}

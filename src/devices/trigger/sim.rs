//! A simulated structured-light scanner node on CAN: it sends its heartbeat, acknowledges triggers at once and
//! reports "view ready" after the exposure, as [`super::protocol`] says, over any [`CanBus`]. Faults are
//! injected through a channel ([`ScannerFault`]): silence (a lost heartbeat, then a reboot), an emergency, a
//! lost view, garbage frames, busy answers, a bus-off report.

use std::time::Duration;

use tokio::sync::{mpsc, watch};
use tokio::time::Instant;

use super::protocol::{AckStatus, Decoded, Message, NmtState, decode};
use super::transport::{CanBus, ERR_BUSOFF, ERR_RESTARTED, Frame, is_enobufs};

/// The simulated node's settings.
#[derive(Clone, Debug, PartialEq)]
pub struct ScannerSettings {
    /// Node id (1–127).
    pub node: u8,
    /// Heartbeat period.
    pub heartbeat: Duration,
    /// From the acknowledgement to "view ready".
    pub exposure: Duration,
    /// Points reported per view (when no `views` source makes the views).
    pub points: u32,
    /// What makes each view (the simulated rig's range camera): called with the trigger's sequence number when
    /// the exposure ends, it delivers the view (writes it where the station reads it) and returns its point
    /// count, or `None` when the view could not be made (it is then never reported, as a lost view).
    pub views: Option<ViewSource>,
}

/// A view maker for [`ScannerSettings::views`].
#[derive(Clone)]
pub struct ViewSource(pub std::sync::Arc<dyn Fn(u16) -> Option<u32> + Send + Sync>);

impl std::fmt::Debug for ViewSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("ViewSource")
    }
}

impl PartialEq for ViewSource {
    fn eq(&self, other: &Self) -> bool {
        std::sync::Arc::ptr_eq(&self.0, &other.0)
    }
}

impl Default for ScannerSettings {
    /// Node 0x10, a 100 ms heartbeat, 50 ms exposure, 100,000 points.
    fn default() -> Self {
        ScannerSettings {
            node: 0x10,
            heartbeat: Duration::from_millis(100),
            exposure: Duration::from_millis(50),
            points: 100_000,
            views: None,
        }
    }
}

/// A fault to inject.
#[derive(Clone, Debug, PartialEq)]
pub enum ScannerFault {
    /// Go silent (no heartbeat, no answers) for this long, then boot up again (a boot-up heartbeat).
    Silence(Duration),
    /// Send an emergency with this code (0 clears).
    Emergency(u16),
    /// Acknowledge the next n triggers but never report their views.
    DropViews(u32),
    /// Answer the next n triggers `busy`.
    Busy(u32),
    /// Report the next n views ready with no points: the scanner saw nothing (a black or shiny object).
    Blind(u32),
    /// Send n malformed frames on the node's identifiers.
    Garbage(u32),
    /// Report bus-off (an error frame), stay silent this long, then report the restart. On a bus whose
    /// controller reports its own state (SocketCAN), use the bus's own fault instead.
    BusOff(Duration),
    /// Stop the node.
    Quit,
}

/// A fault and, optionally, who to tell once the node has taken it.
pub type Control = (ScannerFault, Option<tokio::sync::oneshot::Sender<()>>);

/// What the node has done, for tests and the simulator's log.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ScannerStats {
    /// Heartbeats sent.
    pub heartbeats: u64,
    /// Triggers received for this node.
    pub triggers: u64,
    /// Views reported.
    pub views: u64,
    /// Sends refused with `ENOBUFS`, each retry counted (a frame is dropped after 200 ms of refusals).
    pub refused_sends: u64,
}

/// Why [`run_scanner`] returned.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ScannerEnd {
    /// [`ScannerFault::Quit`], or the control channel closed.
    Quit,
    /// The bus failed or closed (the station went away): a listener takes the next connection.
    BusGone,
}

/// Run the node on `bus` until [`ScannerFault::Quit`], the control channel closes, or the bus fails.
pub async fn run_scanner<B: CanBus>(
    mut bus: B,
    settings: &ScannerSettings,
    control: &mut mpsc::Receiver<Control>,
    stats: &watch::Sender<ScannerStats>,
) -> ScannerEnd {
    let node = settings.node;
    let mut next_beat = Instant::now();
    let mut silent_until: Option<Instant> = None;
    let mut off_until: Option<Instant> = None;
    let mut drop_views = 0u32;
    let mut busy = 0u32;
    let mut blind = 0u32;
    // Views in exposure: (due, seq), in order.
    let mut exposing: std::collections::VecDeque<(Instant, u16)> = Default::default();
    let mut booted = false;
    loop {
        let now = Instant::now();
        if let Some(t) = silent_until
            && now >= t
        {
            silent_until = None;
            booted = false;
        }
        if let Some(t) = off_until
            && now >= t
        {
            off_until = None;
            let _ = bus.send(&Frame::error(ERR_RESTARTED, 0)).await;
        }
        let quiet = silent_until.is_some() || off_until.is_some();
        let view_due = exposing.front().map(|v| v.0);
        // Quiet: wake only to end the silence (nothing is sent, so nothing else is due).
        let wake = if quiet { [silent_until, off_until] } else { [Some(next_beat), view_due] };
        let wake = wake.into_iter().flatten().min().unwrap_or(next_beat);
        tokio::select! {
            c = control.recv() => {
                let Some((fault, done)) = c else { return ScannerEnd::Quit };
                match fault {
                ScannerFault::Quit => return ScannerEnd::Quit,
                ScannerFault::Silence(d) => silent_until = Some(Instant::now() + d),
                ScannerFault::Emergency(code) => {
                    let m = Message::Emergency { node, code, register: u8::from(code != 0), vendor: [0; 5] };
                    send(&mut bus, &m.encode(), stats).await;
                }
                ScannerFault::DropViews(n) => drop_views = n,
                ScannerFault::Busy(n) => busy = n,
                ScannerFault::Blind(n) => blind = n,
                ScannerFault::Garbage(n) => {
                    for i in 0..n {
                        // A heartbeat of three bytes, an acknowledgement of one: our identifiers, wrong bodies.
                        let f = if i % 2 == 0 {
                            Frame::standard(0x700 + u16::from(node), &[5, 0, 0])
                        } else {
                            Frame::standard(0x180 + u16::from(node), &[1])
                        };
                        send(&mut bus, &f.expect("short frame"), stats).await;
                    }
                }
                ScannerFault::BusOff(d) => {
                    let _ = bus.send(&Frame::error(ERR_BUSOFF, 0)).await;
                    off_until = Some(Instant::now() + d);
                }
                }
                // Taken: the frames it called for are sent.
                if let Some(d) = done {
                    let _ = d.send(());
                }
            },
            r = bus.recv() => match r {
                Err(_) => return ScannerEnd::BusGone,
                Ok(f) => {
                    if quiet {
                        continue;
                    }
                    if let Decoded::Message(Message::Trigger { seq, .. }) = decode(&f, node) {
                        stats.send_modify(|s| s.triggers += 1);
                        let status = if busy > 0 {
                            busy -= 1;
                            AckStatus::Busy
                        } else {
                            AckStatus::Accepted
                        };
                        send(&mut bus, &Message::Ack { node, seq, status }.encode(), stats).await;
                        if status == AckStatus::Accepted {
                            if drop_views > 0 {
                                drop_views -= 1;
                            } else {
                                exposing.push_back((Instant::now() + settings.exposure, seq));
                            }
                        }
                    }
                }
            },
            _ = tokio::time::sleep_until(wake) => {
                let now = Instant::now();
                if quiet {
                    exposing.clear();
                    continue;
                }
                while let Some(&(due, seq)) = exposing.front() {
                    if due > now {
                        break;
                    }
                    exposing.pop_front();
                    let points = match &settings.views {
                        _ if blind > 0 => {
                            blind -= 1;
                            Some(0)
                        }
                        None => Some(settings.points),
                        // Making a view takes milliseconds of ray casting: off the async thread (the node's
                        // heartbeat waits for it, well within a period).
                        Some(v) => {
                            let v = v.clone();
                            tokio::task::spawn_blocking(move || (v.0)(seq)).await.ok().flatten()
                        }
                    };
                    if let Some(points) = points {
                        send(&mut bus, &Message::ViewReady { node, seq, points }.encode(), stats).await;
                        stats.send_modify(|s| s.views += 1);
                    }
                }
                if now >= next_beat {
                    let state = if booted { NmtState::Operational } else { NmtState::BootUp };
                    send(&mut bus, &Message::Heartbeat { node, state }.encode(), stats).await;
                    stats.send_modify(|s| s.heartbeats += 1);
                    // After the boot-up message, operational from the next heartbeat on (a real node sends
                    // boot-up once, then its state).
                    if !booted {
                        booted = true;
                        next_beat = now;
                        continue;
                    }
                    next_beat += settings.heartbeat;
                    if next_beat < now {
                        next_beat = now + settings.heartbeat;
                    }
                }
            },
        }
    }
}

/// Longest the node keeps retrying one frame while its transmit queue is full. A real node's controller holds
/// the frame in its mailbox and sends it when the bus frees; 200 ms covers a queue of four frames behind the
/// 1 kB/s token bucket of the vcan tests many times over (the ack test lost its acknowledgement to a single
/// refusal under CI load).
const SEND_PATIENCE: std::time::Duration = std::time::Duration::from_millis(200);

/// Send `f`, retrying `ENOBUFS` with a doubling wait from 1 ms for up to [`SEND_PATIENCE`], then dropping it.
async fn send<B: CanBus>(bus: &mut B, f: &Frame, stats: &watch::Sender<ScannerStats>) {
    let start = tokio::time::Instant::now();
    let mut wait = std::time::Duration::from_millis(1);
    loop {
        match bus.send(f).await {
            Err(e) if is_enobufs(&e) => {
                stats.send_modify(|s| s.refused_sends += 1);
                if start.elapsed() + wait > SEND_PATIENCE {
                    return;
                }
                tokio::time::sleep(wait).await;
                wait = (wait * 2).min(std::time::Duration::from_millis(32));
            }
            _ => return,
        }
    }
}

/// A running simulated node: its fault channel and its statistics.
pub struct SimScanner {
    /// Faults in.
    pub control: mpsc::Sender<Control>,
    /// What it has done.
    pub stats: watch::Receiver<ScannerStats>,
}

impl SimScanner {
    /// Start the node on `bus` on the current tokio runtime.
    pub fn spawn<B: CanBus>(bus: B, settings: ScannerSettings) -> SimScanner {
        let (tx, mut rx) = mpsc::channel(16);
        let (stx, srx) = watch::channel(ScannerStats::default());
        tokio::spawn(async move { run_scanner(bus, &settings, &mut rx, &stx).await });
        SimScanner { control: tx, stats: srx }
    }

    /// Start the node behind a Unix socket at `path` (the transport of `unix:PATH` in the station's config):
    /// it serves one station connection at a time, the next after one closes, until [`ScannerFault::Quit`].
    ///
    /// # Errors
    /// Binding the socket (a stale socket file at `path` is replaced).
    pub fn listen_unix(path: &std::path::Path, settings: ScannerSettings) -> std::io::Result<SimScanner> {
        let _ = std::fs::remove_file(path);
        let listener = tokio::net::UnixListener::bind(path)?;
        let (tx, mut rx) = mpsc::channel(16);
        let (stx, srx) = watch::channel(ScannerStats::default());
        tokio::spawn(async move {
            loop {
                let conn = tokio::select! {
                    c = listener.accept() => c,
                    f = rx.recv() => match f {
                        None | Some((ScannerFault::Quit, _)) => return,
                        // Faults between connections have no bus to act on.
                        Some(_) => continue,
                    },
                };
                let Ok((stream, _)) = conn else { continue };
                let bus = super::transport::StreamBus::new(stream);
                if run_scanner(bus, &settings, &mut rx, &stx).await == ScannerEnd::Quit {
                    return;
                }
            }
        });
        Ok(SimScanner { control: tx, stats: srx })
    }

    /// Inject a fault; returns once the node has taken it (frames it sends for it are on the bus).
    pub async fn inject(&self, f: ScannerFault) {
        let (tx, rx) = tokio::sync::oneshot::channel();
        if self.control.send((f, Some(tx))).await.is_ok() {
            let _ = rx.await;
        }
    }
}

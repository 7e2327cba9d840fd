//! CAN frames as SocketCAN has them, the bus state their error frames tell, and the transports the trigger
//! driver runs over.
//!
//! A [`Frame`] is a classic CAN frame with SocketCAN's `can_id` flags (extended, remote, error); [`Frame::to_wire`]
//! and [`Frame::from_wire`] are the kernel's 16-byte `struct can_frame` (id in host byte order, length, padding,
//! data), so every transport carries exactly what a `CAN_RAW` socket reads and writes.
//!
//! Transports implement [`CanBus`]:
//! - [`MemBus`]: an in-process bus (every port sees every other port's frames) with injectable faults: a full
//!   transmit queue (`ENOBUFS`), bus-off (every send fails with `ENOBUFS`, as in SocketCAN, and an error
//!   frame tells the ports), and raw frames (error frames, garbage). For unit tests.
//! - [`StreamBus`]: the 16-byte frames over a Unix stream socket, for a simulated node in another process
//!   without privileges (`unix:/path` in the config; the simulator listens).
//! - `socketcan_bus::SocketCanBus` (the `socketcan` crate, `CAN_RAW` with error frames on): real interfaces
//!   (`can0`) and `vcan0`.

use std::future::Future;
use std::io;
use std::sync::{Arc, Mutex};

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::sync::mpsc;

/// `can_id` flag: extended (29-bit) identifier.
pub const EFF_FLAG: u32 = 0x8000_0000;
/// `can_id` flag: remote transmission request.
pub const RTR_FLAG: u32 = 0x4000_0000;
/// `can_id` flag: error frame (the class bits follow in the id, details in the data).
pub const ERR_FLAG: u32 = 0x2000_0000;
/// Error class: controller problems (details in data byte 1).
pub const ERR_CRTL: u32 = 0x0000_0004;
/// Error class: bus-off.
pub const ERR_BUSOFF: u32 = 0x0000_0040;
/// Error class: the controller restarted (after bus-off).
pub const ERR_RESTARTED: u32 = 0x0000_0100;
/// Every error class (the error filter that enables them all).
pub const ERR_MASK: u32 = 0x1FFF_FFFF;
/// Controller detail (data byte 1): receive error counter reached the warning level.
pub const CRTL_RX_WARNING: u8 = 0x04;
/// Controller detail: transmit error counter reached the warning level.
pub const CRTL_TX_WARNING: u8 = 0x08;
/// Controller detail: receive error-passive.
pub const CRTL_RX_PASSIVE: u8 = 0x10;
/// Controller detail: transmit error-passive.
pub const CRTL_TX_PASSIVE: u8 = 0x20;
/// Controller detail: back to error-active.
pub const CRTL_ACTIVE: u8 = 0x40;
/// Bytes of a `struct can_frame`.
pub const WIRE_BYTES: usize = 16;
/// Linux's `ENOBUFS`: the interface's transmit queue is full (or the controller is bus-off).
pub const ENOBUFS: i32 = 105;

/// A classic CAN frame: SocketCAN's `can_id` (identifier and flags), 0–8 data bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Frame {
    /// Identifier with the [`EFF_FLAG`], [`RTR_FLAG`] and [`ERR_FLAG`] bits.
    pub id: u32,
    /// Data length, 0 to 8.
    pub len: u8,
    /// Data (bytes past `len` are 0).
    pub data: [u8; 8],
}

impl Frame {
    /// A data frame with a standard (11-bit) identifier; `None` when `id` > 0x7FF or `data` is longer than 8.
    pub fn standard(id: u16, data: &[u8]) -> Option<Frame> {
        if id > 0x7FF || data.len() > 8 {
            return None;
        }
        let mut d = [0u8; 8];
        d[..data.len()].copy_from_slice(data);
        Some(Frame { id: u32::from(id), len: data.len() as u8, data: d })
    }

    /// An error frame of classes `class` with controller detail `crtl` (data byte 1).
    pub fn error(class: u32, crtl: u8) -> Frame {
        let mut data = [0u8; 8];
        data[1] = crtl;
        Frame { id: ERR_FLAG | (class & ERR_MASK), len: 8, data }
    }

    /// The data bytes.
    pub fn payload(&self) -> &[u8] {
        &self.data[..usize::from(self.len.min(8))]
    }

    /// Whether this is an error frame.
    pub fn is_error(&self) -> bool {
        self.id & ERR_FLAG != 0
    }

    /// The standard identifier of a plain data frame (`None` for extended, remote and error frames).
    pub fn standard_id(&self) -> Option<u16> {
        (self.id & (EFF_FLAG | RTR_FLAG | ERR_FLAG) == 0 && self.id <= 0x7FF).then_some(self.id as u16)
    }

    /// The kernel's `struct can_frame`: `can_id` (host order), `len`, two pad bytes, `len8_dlc`, 8 data bytes.
    pub fn to_wire(&self) -> [u8; WIRE_BYTES] {
        let mut w = [0u8; WIRE_BYTES];
        w[..4].copy_from_slice(&self.id.to_ne_bytes());
        w[4] = self.len;
        w[8..].copy_from_slice(&self.data);
        w
    }

    /// A frame from the kernel's layout; `None` when the length exceeds 8 (malformed).
    pub fn from_wire(w: &[u8; WIRE_BYTES]) -> Option<Frame> {
        let id = u32::from_ne_bytes([w[0], w[1], w[2], w[3]]);
        let len = w[4];
        if len > 8 {
            return None;
        }
        let mut data = [0u8; 8];
        data[..usize::from(len)].copy_from_slice(&w[8..8 + usize::from(len)]);
        Some(Frame { id, len, data })
    }
}

/// The controller's state as error frames tell it (SocketCAN's names; `down`: the interface or transport is
/// gone).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum BusState {
    /// Normal operation.
    #[default]
    ErrorActive,
    /// An error counter passed 96.
    ErrorWarning,
    /// An error counter passed 127: the controller no longer signals errors actively.
    ErrorPassive,
    /// The transmit error counter passed 255: the controller is off the bus until it restarts.
    BusOff,
    /// The interface or the transport is not there.
    Down,
}

impl BusState {
    /// The D-Bus `BusState` string.
    pub fn as_str(self) -> &'static str {
        match self {
            BusState::ErrorActive => "error-active",
            BusState::ErrorWarning => "error-warning",
            BusState::ErrorPassive => "error-passive",
            BusState::BusOff => "bus-off",
            BusState::Down => "down",
        }
    }

    /// The state after error frame `f` (unchanged by classes that do not change it: lost arbitration,
    /// protocol violations, …). `None` when `f` is not an error frame.
    pub fn after(self, f: &Frame) -> Option<BusState> {
        if !f.is_error() {
            return None;
        }
        let class = f.id & ERR_MASK;
        if class & ERR_BUSOFF != 0 {
            return Some(BusState::BusOff);
        }
        if class & ERR_RESTARTED != 0 {
            return Some(BusState::ErrorActive);
        }
        if class & ERR_CRTL != 0 {
            let d = f.data[1];
            return Some(if d & (CRTL_RX_PASSIVE | CRTL_TX_PASSIVE) != 0 {
                BusState::ErrorPassive
            } else if d & (CRTL_RX_WARNING | CRTL_TX_WARNING) != 0 {
                BusState::ErrorWarning
            } else if d & CRTL_ACTIVE != 0 {
                BusState::ErrorActive
            } else {
                self
            });
        }
        Some(self)
    }
}

/// A CAN transport: send a frame, receive the next one (data or error frames). `recv` must be
/// cancellation-safe (it is raced against timers and commands).
pub trait CanBus: Send + 'static {
    /// Queue `frame` for sending. `Err` with raw OS error [`ENOBUFS`] when the transmit queue is full or the
    /// controller is bus-off (retry later); other errors mean the interface is gone.
    fn send(&mut self, frame: &Frame) -> impl Future<Output = io::Result<()>> + Send;
    /// The next frame another node sent, or an error frame. `Err` when the interface is gone (`UnexpectedEof`
    /// for a closed transport).
    fn recv(&mut self) -> impl Future<Output = io::Result<Frame>> + Send;
}

/// Whether `e` is a full transmit queue (retry) rather than a lost interface.
pub fn is_enobufs(e: &io::Error) -> bool {
    e.raw_os_error() == Some(ENOBUFS)
}

// ---------------------------------------------------------------------------------------------------------
// In-process bus.

#[derive(Default)]
struct Hub {
    ports: Vec<Option<mpsc::UnboundedSender<Frame>>>,
    /// Sends still to refuse with ENOBUFS.
    refuse: u32,
    bus_off: bool,
}

impl Hub {
    fn deliver(&mut self, from: Option<usize>, f: Frame) {
        for (i, p) in self.ports.iter_mut().enumerate() {
            if Some(i) == from {
                continue;
            }
            if let Some(tx) = p
                && tx.send(f).is_err()
            {
                *p = None;
            }
        }
    }
}

/// An in-process CAN bus: [`MemBus::port`] adds a node; each sees the others' frames (not its own), in the
/// order they were sent. Faults come through the [`MemBus`] itself.
#[derive(Clone, Default)]
pub struct MemBus {
    hub: Arc<Mutex<Hub>>,
}

/// One node's connection to a [`MemBus`].
pub struct MemPort {
    hub: Arc<Mutex<Hub>>,
    index: usize,
    rx: mpsc::UnboundedReceiver<Frame>,
}

impl MemBus {
    /// An empty bus.
    pub fn new() -> MemBus {
        MemBus::default()
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Hub> {
        self.hub.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// A new node on the bus.
    pub fn port(&self) -> MemPort {
        let (tx, rx) = mpsc::unbounded_channel();
        let mut hub = self.lock();
        hub.ports.push(Some(tx));
        MemPort { hub: self.hub.clone(), index: hub.ports.len() - 1, rx }
    }

    /// Refuse the next `n` sends with `ENOBUFS` (a full transmit queue).
    pub fn refuse_sends(&self, n: u32) {
        self.lock().refuse = n;
    }

    /// Put the bus off (every send fails with `ENOBUFS`; the ports get a bus-off error frame) or restart it
    /// (a restarted error frame).
    pub fn set_bus_off(&self, off: bool) {
        let mut hub = self.lock();
        hub.bus_off = off;
        let f = if off { Frame::error(ERR_BUSOFF, 0) } else { Frame::error(ERR_RESTARTED, 0) };
        hub.deliver(None, f);
    }

    /// Deliver `f` to every port, as if the controller or another node had put it on the bus.
    pub fn inject(&self, f: Frame) {
        self.lock().deliver(None, f);
    }
}

impl CanBus for MemPort {
    fn send(&mut self, frame: &Frame) -> impl Future<Output = io::Result<()>> + Send {
        let r = {
            let mut hub = self.hub.lock().unwrap_or_else(|p| p.into_inner());
            if hub.bus_off {
                Err(io::Error::from_raw_os_error(ENOBUFS))
            } else if hub.refuse > 0 {
                hub.refuse -= 1;
                Err(io::Error::from_raw_os_error(ENOBUFS))
            } else {
                hub.deliver(Some(self.index), *frame);
                Ok(())
            }
        };
        std::future::ready(r)
    }

    async fn recv(&mut self) -> io::Result<Frame> {
        self.rx.recv().await.ok_or_else(|| io::Error::new(io::ErrorKind::UnexpectedEof, "the bus is gone"))
    }
}

// ---------------------------------------------------------------------------------------------------------
// Frames over a Unix stream socket.

/// The kernel's 16-byte frames over a byte stream (a Unix socket to a simulated node in another process).
/// A record whose length byte exceeds 8 is malformed: it is counted in [`StreamBus::malformed`] and skipped.
pub struct StreamBus<S> {
    io: S,
    buf: [u8; WIRE_BYTES],
    have: usize,
    /// Malformed records skipped.
    pub malformed: u64,
}

impl<S> StreamBus<S> {
    /// Frames over `io`.
    pub fn new(io: S) -> StreamBus<S> {
        StreamBus { io, buf: [0; WIRE_BYTES], have: 0, malformed: 0 }
    }
}

impl StreamBus<tokio::net::UnixStream> {
    /// Connect to a node listening at `path`.
    ///
    /// # Errors
    /// The socket's (no such file, refused, …).
    pub async fn connect(path: &std::path::Path) -> io::Result<Self> {
        Ok(StreamBus::new(tokio::net::UnixStream::connect(path).await?))
    }
}

impl<S> CanBus for StreamBus<S>
where
    S: tokio::io::AsyncRead + tokio::io::AsyncWrite + Unpin + Send + 'static,
{
    async fn send(&mut self, frame: &Frame) -> io::Result<()> {
        self.io.write_all(&frame.to_wire()).await
    }

    async fn recv(&mut self) -> io::Result<Frame> {
        loop {
            // Partial records stay in `buf` across cancelled calls: `read` is cancellation-safe.
            while self.have < WIRE_BYTES {
                let n = self.io.read(&mut self.buf[self.have..]).await?;
                if n == 0 {
                    return Err(io::Error::new(io::ErrorKind::UnexpectedEof, "the node closed the connection"));
                }
                self.have += n;
            }
            self.have = 0;
            match Frame::from_wire(&self.buf) {
                Some(f) => return Ok(f),
                None => self.malformed += 1,
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn frames_round_trip_through_the_kernel_layout(id in any::<u32>(), len in 0u8..=8, bytes in any::<[u8; 8]>()) {
            let mut data = [0u8; 8];
            data[..usize::from(len)].copy_from_slice(&bytes[..usize::from(len)]);
            let f = Frame { id, len, data };
            let w = f.to_wire();
            prop_assert_eq!(Frame::from_wire(&w), Some(f));
            prop_assert_eq!(w[4], len);
            prop_assert_eq!(&w[5..8], &[0u8, 0, 0]);
        }

        #[test]
        fn a_length_over_eight_is_malformed(len in 9u8..=255) {
            let mut w = Frame::standard(0x123, &[1, 2]).unwrap().to_wire();
            w[4] = len;
            prop_assert_eq!(Frame::from_wire(&w), None);
        }
    }

    #[test]
    fn error_frames_move_the_bus_state() {
        use BusState::*;
        let s = ErrorActive;
        assert_eq!(s.after(&Frame::error(ERR_CRTL, CRTL_TX_WARNING)), Some(ErrorWarning));
        assert_eq!(s.after(&Frame::error(ERR_CRTL, CRTL_RX_PASSIVE)), Some(ErrorPassive));
        assert_eq!(ErrorPassive.after(&Frame::error(ERR_BUSOFF, 0)), Some(BusOff));
        assert_eq!(BusOff.after(&Frame::error(ERR_RESTARTED, 0)), Some(ErrorActive));
        assert_eq!(ErrorWarning.after(&Frame::error(ERR_CRTL, CRTL_ACTIVE)), Some(ErrorActive));
        // A protocol violation (class 0x08) leaves the state.
        assert_eq!(ErrorWarning.after(&Frame::error(0x08, 0)), Some(ErrorWarning));
        assert_eq!(s.after(&Frame::standard(0x701, &[5]).unwrap()), None);
    }

    #[tokio::test]
    async fn the_memory_bus_delivers_to_the_others_and_refuses_when_full_or_off() {
        let bus = MemBus::new();
        let (mut a, mut b, mut c) = (bus.port(), bus.port(), bus.port());
        let f = Frame::standard(0x181, &[1, 0, 0]).unwrap();
        a.send(&f).await.unwrap();
        assert_eq!(b.recv().await.unwrap(), f);
        assert_eq!(c.recv().await.unwrap(), f);
        bus.refuse_sends(2);
        assert!(is_enobufs(&a.send(&f).await.unwrap_err()));
        assert!(is_enobufs(&a.send(&f).await.unwrap_err()));
        a.send(&f).await.unwrap();
        assert_eq!(b.recv().await.unwrap(), f);
        bus.set_bus_off(true);
        assert_eq!(b.recv().await.unwrap().id & ERR_BUSOFF, ERR_BUSOFF);
        assert!(is_enobufs(&b.send(&f).await.unwrap_err()));
        bus.set_bus_off(false);
        assert_eq!(b.recv().await.unwrap().id & ERR_RESTARTED, ERR_RESTARTED);
        b.send(&f).await.unwrap();
        // Every port saw the controller's error frames, then the frame.
        assert_eq!(a.recv().await.unwrap().id & ERR_BUSOFF, ERR_BUSOFF);
        assert_eq!(a.recv().await.unwrap().id & ERR_RESTARTED, ERR_RESTARTED);
        assert_eq!(a.recv().await.unwrap(), f);
    }

    #[tokio::test]
    async fn the_stream_bus_carries_frames_and_skips_malformed_records() {
        let (x, y) = tokio::io::duplex(256);
        let (mut a, mut b) = (StreamBus::new(x), StreamBus::new(y));
        let f = Frame::standard(0x701, &[5]).unwrap();
        a.send(&f).await.unwrap();
        let mut bad = f.to_wire();
        bad[4] = 12;
        a.io.write_all(&bad).await.unwrap();
        a.send(&Frame::error(ERR_BUSOFF, 0)).await.unwrap();
        assert_eq!(b.recv().await.unwrap(), f);
        assert!(b.recv().await.unwrap().is_error());
        assert_eq!(b.malformed, 1);
        drop(a);
        assert_eq!(b.recv().await.unwrap_err().kind(), io::ErrorKind::UnexpectedEof);
    }
}

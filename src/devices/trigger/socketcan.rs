//! The SocketCAN transport: a `CAN_RAW` socket on an interface (`can0`, `vcan0`) through the `socketcan`
//! crate's tokio socket, every error class enabled so the bus state follows the controller. Frames go in and
//! out as the kernel's `struct can_frame` ([`Frame`]'s layout).
//!
//! `ENOBUFS` from a full transmit queue or a bus-off controller comes back as the error it is, for the
//! driver's backoff ([`super::actor`]); a vanished interface (a USB adapter pulled) fails reads with
//! `ENETDOWN`/`ENODEV`, and the driver reconnects.

use std::io;

use socketcan::SocketOptions;

use super::transport::{CanBus, Frame};

/// A `CAN_RAW` socket bound to one interface.
pub struct SocketCanBus {
    socket: socketcan::tokio::CanSocket,
}

impl SocketCanBus {
    /// Open `interface` with every error class reported.
    ///
    /// # Errors
    /// The socket's: no such interface (`ENODEV`), no CAN support in the kernel (`EAFNOSUPPORT`).
    pub fn open(interface: &str) -> io::Result<SocketCanBus> {
        let socket = socketcan::tokio::CanSocket::open(interface)?;
        socket.set_error_filter_accept_all()?;
        Ok(SocketCanBus { socket })
    }
}

fn to_socketcan(f: &Frame) -> socketcan::CanFrame {
    let mut c = socketcan::frame::can_frame_default();
    c.can_id = f.id;
    c.can_dlc = f.len.min(8);
    c.data = f.data;
    socketcan::CanFrame::from(c)
}

fn from_socketcan(f: &socketcan::CanFrame) -> Frame {
    let c: &libc::can_frame = f.as_ref();
    Frame { id: c.can_id, len: c.can_dlc.min(8), data: c.data }
}

impl CanBus for SocketCanBus {
    async fn send(&mut self, frame: &Frame) -> io::Result<()> {
        self.socket.write_frame(to_socketcan(frame)).await
    }

    async fn recv(&mut self) -> io::Result<Frame> {
        self.socket.read_frame().await.map(|f| from_socketcan(&f))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_convert_both_ways_with_their_flags() {
        for f in [
            Frame::standard(0x710, &[5]).unwrap(),
            Frame::standard(0x290, &[1, 0, 0x40, 0xE2, 1, 0]).unwrap(),
            Frame::error(super::super::transport::ERR_BUSOFF, 0),
            Frame { id: super::super::transport::EFF_FLAG | 0x1234_5678, len: 2, data: [9, 8, 0, 0, 0, 0, 0, 0] },
        ] {
            assert_eq!(from_socketcan(&to_socketcan(&f)), f);
        }
    }
}

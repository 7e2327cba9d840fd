//! The trigger protocol on CAN, after CANopen's conventions (CiA 301): a node id per device (1–127), the
//! function code in the identifier's top bits, little-endian fields.
//!
//! | message | identifier | data | from |
//! |---|---|---|---|
//! | heartbeat | `0x700 + node` | 1 byte: NMT state (`0x00` boot-up, `0x04` stopped, `0x05` operational, `0x7F` pre-operational) | scanner, every period |
//! | trigger | `0x200 + node` (RPDO1) | `seq` u16, `channel` u8 | station |
//! | acknowledgement | `0x180 + node` (TPDO1) | `seq` u16, `status` u8 (0 accepted, 1 busy, 2 not ready) | scanner, at once |
//! | view ready | `0x280 + node` (TPDO2) | `seq` u16, `points` u32 | scanner, when the view is written |
//! | emergency (EMCY) | `0x080 + node` | `code` u16, `register` u8, 5 bytes vendor data | scanner, on a fault (`code` 0: fault cleared) |
//!
//! Frames with other identifiers belong to other nodes and are ignored; a frame with one of these identifiers
//! for our node but the wrong length, an extended or remote identifier is **garbage**: counted, never trusted.

use super::transport::Frame;

/// Function code of the heartbeat (NMT error control).
pub const HEARTBEAT: u16 = 0x700;
/// Function code of the trigger (the scanner's RPDO1).
pub const TRIGGER: u16 = 0x200;
/// Function code of the acknowledgement (TPDO1).
pub const ACK: u16 = 0x180;
/// Function code of "view ready" (TPDO2).
pub const VIEW_READY: u16 = 0x280;
/// Function code of the emergency message.
pub const EMCY: u16 = 0x080;

/// A node's NMT state as its heartbeat gives it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum NmtState {
    /// Just (re)started: anything in flight is lost.
    BootUp,
    /// Stopped: answers nothing but NMT.
    Stopped,
    /// Operational: takes triggers.
    Operational,
    /// Pre-operational: configuring, takes no triggers yet.
    PreOperational,
}

impl NmtState {
    /// The heartbeat byte.
    pub fn byte(self) -> u8 {
        match self {
            NmtState::BootUp => 0x00,
            NmtState::Stopped => 0x04,
            NmtState::Operational => 0x05,
            NmtState::PreOperational => 0x7F,
        }
    }

    fn from_byte(b: u8) -> Option<NmtState> {
        Some(match b & 0x7F {
            0x00 => NmtState::BootUp,
            0x04 => NmtState::Stopped,
            0x05 => NmtState::Operational,
            0x7F => NmtState::PreOperational,
            _ => return None,
        })
    }
}

/// The scanner's answer to a trigger.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum AckStatus {
    /// Exposing: a view-ready follows.
    Accepted,
    /// Still busy with the previous view.
    Busy,
    /// Not ready (warming up, no calibration).
    NotReady,
}

impl AckStatus {
    fn byte(self) -> u8 {
        match self {
            AckStatus::Accepted => 0,
            AckStatus::Busy => 1,
            AckStatus::NotReady => 2,
        }
    }

    fn from_byte(b: u8) -> Option<AckStatus> {
        Some(match b {
            0 => AckStatus::Accepted,
            1 => AckStatus::Busy,
            2 => AckStatus::NotReady,
            _ => return None,
        })
    }
}

/// One message of the protocol.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Message {
    /// A node's heartbeat.
    Heartbeat {
        /// Node id.
        node: u8,
        /// Its NMT state.
        state: NmtState,
    },
    /// Fire: expose a view.
    Trigger {
        /// The scanner's node id.
        node: u8,
        /// Sequence number (wraps).
        seq: u16,
        /// Channel (pattern set, camera).
        channel: u8,
    },
    /// The scanner took (or refused) trigger `seq`.
    Ack {
        /// Node id.
        node: u8,
        /// The trigger's sequence number.
        seq: u16,
        /// Accepted or why not.
        status: AckStatus,
    },
    /// The view of trigger `seq` is written.
    ViewReady {
        /// Node id.
        node: u8,
        /// The trigger's sequence number.
        seq: u16,
        /// Points in the view.
        points: u32,
    },
    /// A device fault (`code` 0: cleared).
    Emergency {
        /// Node id.
        node: u8,
        /// CANopen emergency error code.
        code: u16,
        /// Error register (object 0x1001).
        register: u8,
        /// Vendor-specific bytes.
        vendor: [u8; 5],
    },
}

/// What a frame is, for a station listening to node `node`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Decoded {
    /// One of ours.
    Message(Message),
    /// Another node's traffic, or a function we do not use: ignored.
    Other,
    /// One of our identifiers with a malformed body: counted and logged, never trusted.
    Garbage(&'static str),
}

impl Message {
    /// The frame carrying this message.
    pub fn encode(&self) -> Frame {
        let f = |base: u16, node: u8, data: &[u8]| {
            Frame::standard(base + u16::from(node & 0x7F), data).expect("≤ 8 bytes, id ≤ 0x7FF")
        };
        match *self {
            Message::Heartbeat { node, state } => f(HEARTBEAT, node, &[state.byte()]),
            Message::Trigger { node, seq, channel } => {
                let s = seq.to_le_bytes();
                f(TRIGGER, node, &[s[0], s[1], channel])
            }
            Message::Ack { node, seq, status } => {
                let s = seq.to_le_bytes();
                f(ACK, node, &[s[0], s[1], status.byte()])
            }
            Message::ViewReady { node, seq, points } => {
                let (s, p) = (seq.to_le_bytes(), points.to_le_bytes());
                f(VIEW_READY, node, &[s[0], s[1], p[0], p[1], p[2], p[3]])
            }
            Message::Emergency { node, code, register, vendor } => {
                let c = code.to_le_bytes();
                let mut d = [c[0], c[1], register, 0, 0, 0, 0, 0];
                d[3..].copy_from_slice(&vendor);
                f(EMCY, node, &d)
            }
        }
    }

    /// The node the message is from or for.
    pub fn node(&self) -> u8 {
        match *self {
            Message::Heartbeat { node, .. }
            | Message::Trigger { node, .. }
            | Message::Ack { node, .. }
            | Message::ViewReady { node, .. }
            | Message::Emergency { node, .. } => node,
        }
    }
}

/// Decode `f` as traffic of node `node` (1–127). Error frames are `Other` (the bus state reads them).
pub fn decode(f: &Frame, node: u8) -> Decoded {
    if f.is_error() {
        return Decoded::Other;
    }
    let raw = (f.id & 0x7FF) as u16;
    let (function, from) = (raw & 0x780, (raw & 0x7F) as u8);
    if from != node || !matches!(function, HEARTBEAT | TRIGGER | ACK | VIEW_READY | EMCY) {
        return Decoded::Other;
    }
    if f.standard_id().is_none() {
        return Decoded::Garbage("an extended or remote frame on one of the node's identifiers");
    }
    let d = f.payload();
    let seq = |d: &[u8]| u16::from_le_bytes([d[0], d[1]]);
    let m = match (function, d.len()) {
        (HEARTBEAT, 1) => match NmtState::from_byte(d[0]) {
            Some(state) => Message::Heartbeat { node, state },
            None => return Decoded::Garbage("a heartbeat with an unknown NMT state"),
        },
        (TRIGGER, 3) => Message::Trigger { node, seq: seq(d), channel: d[2] },
        (ACK, 3) => match AckStatus::from_byte(d[2]) {
            Some(status) => Message::Ack { node, seq: seq(d), status },
            None => return Decoded::Garbage("an acknowledgement with an unknown status"),
        },
        (VIEW_READY, 6) => {
            Message::ViewReady { node, seq: seq(d), points: u32::from_le_bytes([d[2], d[3], d[4], d[5]]) }
        }
        (EMCY, 8) => {
            let mut vendor = [0u8; 5];
            vendor.copy_from_slice(&d[3..8]);
            Message::Emergency { node, code: u16::from_le_bytes([d[0], d[1]]), register: d[2], vendor }
        }
        _ => return Decoded::Garbage("a frame of the wrong length for its identifier"),
    };
    Decoded::Message(m)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn message() -> impl Strategy<Value = Message> {
        let node = 1u8..=127;
        let state = prop_oneof![
            Just(NmtState::BootUp),
            Just(NmtState::Stopped),
            Just(NmtState::Operational),
            Just(NmtState::PreOperational)
        ];
        let status = prop_oneof![Just(AckStatus::Accepted), Just(AckStatus::Busy), Just(AckStatus::NotReady)];
        prop_oneof![
            (node.clone(), state).prop_map(|(node, state)| Message::Heartbeat { node, state }),
            (node.clone(), any::<u16>(), any::<u8>()).prop_map(|(node, seq, channel)| Message::Trigger {
                node,
                seq,
                channel
            }),
            (node.clone(), any::<u16>(), status).prop_map(|(node, seq, status)| Message::Ack { node, seq, status }),
            (node.clone(), any::<u16>(), any::<u32>()).prop_map(|(node, seq, points)| Message::ViewReady {
                node,
                seq,
                points
            }),
            (node, any::<u16>(), any::<u8>(), any::<[u8; 5]>())
                .prop_map(|(node, code, register, vendor)| Message::Emergency { node, code, register, vendor }),
        ]
    }

    proptest! {
        #[test]
        fn messages_round_trip_through_frames_and_the_wire(m in message()) {
            let f = m.encode();
            prop_assert!(f.id <= 0x7FF);
            let back = crate::devices::trigger::transport::Frame::from_wire(&f.to_wire()).unwrap();
            prop_assert_eq!(decode(&back, m.node()), Decoded::Message(m));
            // Another node's listener ignores it.
            let other = if m.node() == 127 { 1 } else { m.node() + 1 };
            prop_assert_eq!(decode(&f, other), Decoded::Other);
        }

        #[test]
        fn a_truncated_or_padded_frame_is_garbage(m in message(), cut in 0usize..9) {
            let f = m.encode();
            prop_assume!(cut != usize::from(f.len));
            let mut g = f;
            g.len = cut as u8;
            prop_assert!(matches!(decode(&g, m.node()), Decoded::Garbage(_)));
        }
    }

    #[test]
    fn the_identifiers_follow_canopen() {
        let n = 0x10;
        assert_eq!(Message::Heartbeat { node: n, state: NmtState::Operational }.encode().id, 0x710);
        assert_eq!(Message::Trigger { node: n, seq: 7, channel: 0 }.encode().id, 0x210);
        assert_eq!(Message::Ack { node: n, seq: 7, status: AckStatus::Accepted }.encode().id, 0x190);
        assert_eq!(Message::ViewReady { node: n, seq: 7, points: 1 }.encode().id, 0x290);
        assert_eq!(Message::Emergency { node: n, code: 0x5000, register: 1, vendor: [0; 5] }.encode().id, 0x090);
        let v = Message::ViewReady { node: n, seq: 0x0102, points: 0x0A0B0C0D }.encode();
        assert_eq!(v.payload(), &[0x02, 0x01, 0x0D, 0x0C, 0x0B, 0x0A]);
        // An extended frame on our identifier, and an error frame.
        let mut e = v;
        e.id |= crate::devices::trigger::transport::EFF_FLAG;
        assert!(matches!(decode(&e, n), Decoded::Garbage(_)));
        assert_eq!(decode(&crate::devices::trigger::transport::Frame::error(0x40, 0), n), Decoded::Other);
    }
}

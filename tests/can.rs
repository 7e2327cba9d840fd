//! The scanner's trigger on CAN, driver against the simulated scanner node, on the in-process bus (faults the
//! bus itself injects: a full transmit queue, bus-off) and on the Unix-socket transport a simulator in another
//! process uses (the interface going away and coming back): triggers, acknowledgements and views, a lost
//! heartbeat, bus-off and recovery, `ENOBUFS` backoff, EMCY, garbage frames, a lost view, busy answers.
//! The same driver on a real `vcan0` runs inside user-mode Linux (`tests/vcan.rs`, `scripts/uml-vcan.sh`).

mod common;

use std::time::{Duration, Instant};

use scanstation::ErrorCode;
use scanstation::devices::DeviceFault;
use scanstation::devices::trigger::sim::{ScannerFault, ScannerSettings, SimScanner};
use scanstation::devices::trigger::transport::{BusState, MemBus, StreamBus};
use scanstation::devices::trigger::{TriggerHandle, TriggerSettings, TriggerState, spawn_trigger};

/// Heartbeat period of these tests (the default is 100 ms; shorter keeps the tests quick).
const BEAT: Duration = Duration::from_millis(20);

fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().unwrap()
}

fn settings(interface: &str) -> TriggerSettings {
    TriggerSettings {
        heartbeat: BEAT,
        lost_after: 3,
        ack_timeout: Duration::from_millis(100),
        view_timeout: Duration::from_millis(300),
        send_patience: Duration::from_millis(100),
        reconnect_min: Duration::from_millis(50),
        reconnect_max: Duration::from_millis(200),
        ..TriggerSettings::new(interface, 0x10)
    }
}

fn scanner() -> ScannerSettings {
    ScannerSettings { heartbeat: BEAT, exposure: Duration::from_millis(15), points: 123_456, ..Default::default() }
}

/// A driver and a simulated node on one in-process bus.
fn mem_rig() -> (MemBus, TriggerHandle, SimScanner) {
    let bus = MemBus::new();
    let node = SimScanner::spawn(bus.port(), scanner());
    let b = bus.clone();
    let h = spawn_trigger(settings("mem0"), move || std::future::ready(Ok(b.port())));
    (bus, h, node)
}

async fn until(h: &TriggerHandle, what: &str, limit: Duration, f: impl Fn(&TriggerState) -> bool) -> Duration {
    let t = Instant::now();
    let mut w = h.watch();
    while !f(&w.borrow_and_update()) {
        assert!(t.elapsed() < limit, "{what}: not within {limit:?}: {:?}", h.state());
        let _ = tokio::time::timeout(Duration::from_millis(20), w.changed()).await;
    }
    t.elapsed()
}

async fn next_fault(rx: &mut tokio::sync::broadcast::Receiver<DeviceFault>, limit: Duration) -> DeviceFault {
    tokio::time::timeout(limit, rx.recv()).await.expect("a fault in time").expect("fault channel")
}

#[test]
fn triggers_are_acknowledged_and_views_reported_in_order() {
    runtime().block_on(async {
        let (_bus, h, node) = mem_rig();
        until(&h, "node ready", Duration::from_secs(2), |s| s.ready()).await;
        let mut last = 0;
        for i in 0..5u8 {
            let r = h.fire(i).await.expect("fire");
            println!("fire {i}: {r:?}");
            assert!(r.seq > last, "sequence numbers rise: {r:?}");
            last = r.seq;
            assert_eq!((r.channel, r.points), (i, 123_456));
            assert!(r.ack_ms <= r.view_ms && r.view_ms >= 15.0, "exposure of 15 ms: {r:?}");
            assert!(r.view_ms < 300.0, "{r:?}");
        }
        let s = h.state();
        assert_eq!((s.frames_sent, s.views, s.garbage_frames, s.faults), (5, 5, 0, 0), "{s:?}");
        assert_eq!(node.stats.borrow().triggers, 5);
        assert_eq!(s.bus_state, BusState::ErrorActive);
    });
}

#[test]
fn a_lost_heartbeat_is_a_fault_within_the_periods_and_the_node_comes_back() {
    runtime().block_on(async {
        let (_bus, h, node) = mem_rig();
        until(&h, "node ready", Duration::from_secs(2), |s| s.ready()).await;
        let mut faults = h.faults();
        let t = Instant::now();
        node.inject(ScannerFault::Silence(Duration::from_millis(400))).await;
        let f = next_fault(&mut faults, Duration::from_secs(1)).await;
        let took = t.elapsed();
        println!("heartbeat lost after {took:?}: {f:?}");
        assert_eq!(f.code, ErrorCode::DeviceLost, "{f:?}");
        // Three periods without a heartbeat, counted from the last one (up to a period before the silence).
        assert!(took <= BEAT * 4 + Duration::from_millis(40), "lost after {took:?}");
        assert!(!h.state().node_alive);
        let e = h.fire(0).await.unwrap_err();
        assert_eq!(e.code, ErrorCode::DeviceLost, "{e}");
        // After the silence the node boots up again and takes triggers.
        until(&h, "node back", Duration::from_secs(2), |s| s.ready()).await;
        let r = h.fire(1).await.expect("fire after the node came back");
        assert_eq!(r.points, 123_456);
        assert_eq!(h.state().faults, 1, "one fault per loss: {:?}", h.state());
    });
}

#[test]
fn bus_off_refuses_triggers_until_the_controller_restarts() {
    runtime().block_on(async {
        let (bus, h, _node) = mem_rig();
        until(&h, "node ready", Duration::from_secs(2), |s| s.ready()).await;
        let mut faults = h.faults();
        bus.set_bus_off(true);
        let f = next_fault(&mut faults, Duration::from_secs(1)).await;
        assert_eq!(f.code, ErrorCode::DeviceBusOff, "{f:?}");
        assert_eq!(h.state().bus_state, BusState::BusOff);
        let t = Instant::now();
        let e = h.fire(0).await.unwrap_err();
        assert_eq!(e.code, ErrorCode::DeviceBusOff, "{e}");
        assert!(t.elapsed() < Duration::from_millis(50), "refused at once, not after retries: {:?}", t.elapsed());
        bus.set_bus_off(false);
        until(&h, "error-active again", Duration::from_secs(1), |s| s.bus_state == BusState::ErrorActive).await;
        // The node's heartbeats were refused meanwhile: it may be reported lost; wait for it.
        until(&h, "node ready", Duration::from_secs(2), |s| s.ready()).await;
        h.fire(1).await.expect("fire after the restart");
    });
}

#[test]
fn a_full_transmit_queue_is_retried_with_backoff_then_refused() {
    runtime().block_on(async {
        let (bus, h, node) = mem_rig();
        until(&h, "node ready", Duration::from_secs(2), |s| s.ready()).await;
        // Three refusals: retried (1 + 2 + 4 ms), then sent.
        bus.refuse_sends(3);
        let r = h.fire(0).await.expect("fire after three ENOBUFS");
        let s = h.state();
        assert_eq!((s.send_retries, s.errors), (3, 0), "{s:?}");
        assert!(r.ack_ms >= 0.0);
        // A queue that stays full: given up after the patience (100 ms), with a handful of tries.
        bus.refuse_sends(u32::MAX);
        let t = Instant::now();
        let e = h.fire(1).await.unwrap_err();
        let took = t.elapsed();
        let retries = h.state().send_retries - 3;
        println!("gave up after {took:?} and {retries} retries: {e}");
        assert_eq!(e.code, ErrorCode::DeviceTimeout, "{e}");
        assert!(took >= Duration::from_millis(60) && took < Duration::from_millis(400), "{took:?}");
        assert!((5..=12).contains(&retries), "doubling waits, not a spin: {retries} retries");
        // The node's heartbeats were refused too, for longer than the driver waits for one: it is (or is about
        // to be) lost, and back with its next heartbeats once the queue drains.
        bus.refuse_sends(0);
        let beats = node.stats.borrow().heartbeats;
        while node.stats.borrow().heartbeats < beats + 3 {
            tokio::time::sleep(BEAT / 4).await;
        }
        until(&h, "node ready", Duration::from_secs(2), |s| s.ready()).await;
        h.fire(2).await.expect("fire once the queue drains");
    });
}

#[test]
fn emergencies_garbage_lost_views_and_busy_answers_are_mapped() {
    runtime().block_on(async {
        let (_bus, h, node) = mem_rig();
        until(&h, "node ready", Duration::from_secs(2), |s| s.ready()).await;
        let mut faults = h.faults();
        node.inject(ScannerFault::Emergency(0x5000)).await;
        let f = next_fault(&mut faults, Duration::from_secs(1)).await;
        assert_eq!(f.code, ErrorCode::DeviceEmergency, "{f:?}");
        assert!(f.message.contains("0x5000"), "{f:?}");
        node.inject(ScannerFault::Garbage(10)).await;
        until(&h, "garbage counted", Duration::from_secs(1), |s| s.garbage_frames == 10).await;
        h.fire(0).await.expect("garbage is not trusted, and does not stop the trigger");
        // A view that never comes: device.timeout after the view timeout (300 ms).
        node.inject(ScannerFault::DropViews(1)).await;
        let t = Instant::now();
        let e = h.fire(1).await.unwrap_err();
        assert_eq!(e.code, ErrorCode::DeviceTimeout, "{e}");
        let took = t.elapsed();
        assert!(took >= Duration::from_millis(300) && took < Duration::from_millis(600), "{took:?}");
        // Busy.
        node.inject(ScannerFault::Busy(1)).await;
        let e = h.fire(2).await.unwrap_err();
        assert_eq!(e.code, ErrorCode::DeviceRefused, "{e}");
        h.fire(3).await.expect("the next one goes through");
        let s = h.state();
        assert_eq!(s.views, 2, "{s:?}");
    });
}

#[test]
fn the_socket_transport_notices_a_vanished_simulator_and_reconnects() {
    runtime().block_on(async {
        let dir = common::scratch(&format!("can-socket-{}", std::process::id()));
        let path = dir.join("can.sock");
        let node = SimScanner::listen_unix(&path, scanner()).expect("listen");
        let p = path.clone();
        let h = spawn_trigger(settings(&format!("unix:{}", path.display())), move || {
            let p = p.clone();
            async move { StreamBus::connect(&p).await }
        });
        until(&h, "node ready", Duration::from_secs(2), |s| s.ready()).await;
        let r = h.fire(7).await.expect("fire over the socket");
        assert_eq!((r.channel, r.points), (7, 123_456));
        // The simulator goes away: the driver sees the socket close.
        let mut faults = h.faults();
        let t = Instant::now();
        node.inject(ScannerFault::Quit).await;
        let f = next_fault(&mut faults, Duration::from_secs(1)).await;
        println!("simulator gone: {f:?} after {:?}", t.elapsed());
        assert!(matches!(f.code, ErrorCode::DeviceUnplugged | ErrorCode::DeviceLost), "{f:?}");
        until(&h, "down", Duration::from_secs(1), |s| s.bus_state == BusState::Down || !s.node_alive).await;
        assert_eq!(h.fire(0).await.unwrap_err().code.as_str().split('.').next(), Some("device"));
        // A new simulator at the same path: reconnected, the node heard again.
        let _node2 = SimScanner::listen_unix(&path, scanner()).expect("listen again");
        until(&h, "reconnected", Duration::from_secs(3), |s| s.ready() && s.connections >= 2).await;
        h.fire(1).await.expect("fire after reconnecting");
    });
}

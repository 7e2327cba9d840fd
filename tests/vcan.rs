//! The trigger driver and the simulated scanner node on real SocketCAN interfaces: `vcan0`, and `vcan1` behind
//! a token-bucket qdisc that fills (`ENOBUFS`). This machine's kernel has no CAN, so these run inside
//! user-mode Linux: `scripts/uml-vcan.sh` boots it, loads can, can-raw, can-dev, vcan and sch_tbf, creates the
//! interfaces and runs this binary (`--test-threads 1`: the tests share the interfaces). `.ci/run` calls it.
//! Run by hand: `bash scripts/uml-vcan.sh`.

use std::time::{Duration, Instant};

use scanstation::ErrorCode;
use scanstation::devices::trigger::sim::{ScannerFault, ScannerSettings, SimScanner};
use scanstation::devices::trigger::socketcan::SocketCanBus;
use scanstation::devices::trigger::transport::{BusState, CanBus, Frame, is_enobufs};
use scanstation::devices::trigger::{TriggerHandle, TriggerSettings, TriggerState, spawn_trigger};

fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().unwrap()
}

fn rig(interface: &str, beat: Duration) -> (TriggerHandle, SimScanner) {
    let bus = SocketCanBus::open(interface)
        .unwrap_or_else(|e| panic!("open {interface} (run inside scripts/uml-vcan.sh): {e}"));
    let node = SimScanner::spawn(
        bus,
        ScannerSettings { heartbeat: beat, exposure: Duration::from_millis(10), points: 4242, ..Default::default() },
    );
    let settings = TriggerSettings {
        heartbeat: beat,
        ack_timeout: Duration::from_secs(1),
        view_timeout: Duration::from_secs(1),
        send_patience: Duration::from_millis(500),
        reconnect_min: Duration::from_millis(50),
        ..TriggerSettings::new(interface, 0x10)
    };
    let name = interface.to_string();
    let h = spawn_trigger(settings, move || std::future::ready(SocketCanBus::open(&name)));
    (h, node)
}

async fn until(h: &TriggerHandle, what: &str, limit: Duration, f: impl Fn(&TriggerState) -> bool) {
    let t = Instant::now();
    let mut w = h.watch();
    while !f(&w.borrow_and_update()) {
        assert!(t.elapsed() < limit, "{what}: not within {limit:?}: {:?}", h.state());
        let _ = tokio::time::timeout(Duration::from_millis(20), w.changed()).await;
    }
}

#[test]
fn triggers_acknowledgements_views_and_garbage_on_vcan0() {
    runtime().block_on(async {
        let (h, node) = rig("vcan0", Duration::from_millis(20));
        until(&h, "node ready", Duration::from_secs(2), |s| s.ready()).await;
        for ch in 0..3 {
            let r = h.fire(ch).await.expect("fire on vcan0");
            println!("vcan0 fire {ch}: {r:?}");
            assert_eq!((r.channel, r.points), (ch, 4242));
        }
        node.inject(ScannerFault::Garbage(6)).await;
        until(&h, "garbage counted", Duration::from_secs(1), |s| s.garbage_frames == 6).await;
        h.fire(3).await.expect("fire after garbage");
        let s = h.state();
        println!("vcan0 state: {s:?}");
        assert_eq!((s.views, s.faults, s.bus_state), (4, 0, BusState::ErrorActive), "{s:?}");
        node.inject(ScannerFault::Quit).await;
    });
}

#[test]
fn a_lost_heartbeat_on_vcan0_is_a_fault_and_the_node_comes_back() {
    runtime().block_on(async {
        let beat = Duration::from_millis(20);
        let (h, node) = rig("vcan0", beat);
        until(&h, "node ready", Duration::from_secs(2), |s| s.ready()).await;
        let mut faults = h.faults();
        let t = Instant::now();
        node.inject(ScannerFault::Silence(Duration::from_millis(300))).await;
        let f = tokio::time::timeout(Duration::from_secs(1), faults.recv()).await.expect("in time").unwrap();
        let took = t.elapsed();
        println!("vcan0 heartbeat lost after {took:?}: {f:?}");
        assert_eq!(f.code, ErrorCode::DeviceLost);
        assert!(took <= beat * 4 + Duration::from_millis(40), "{took:?}");
        until(&h, "node back", Duration::from_secs(2), |s| s.ready()).await;
        h.fire(0).await.expect("fire after the node came back");
        node.inject(ScannerFault::Quit).await;
    });
}

#[test]
fn error_frames_on_vcan0_move_the_bus_state_to_bus_off_and_back() {
    runtime().block_on(async {
        let (h, node) = rig("vcan0", Duration::from_millis(20));
        until(&h, "node ready", Duration::from_secs(2), |s| s.ready()).await;
        let mut faults = h.faults();
        // vcan has no controller: the node writes the error frames a controller would raise.
        node.inject(ScannerFault::BusOff(Duration::from_millis(300))).await;
        let f = tokio::time::timeout(Duration::from_secs(1), faults.recv()).await.expect("in time").unwrap();
        assert_eq!(f.code, ErrorCode::DeviceBusOff, "{f:?}");
        assert_eq!(h.state().bus_state, BusState::BusOff);
        assert_eq!(h.fire(0).await.unwrap_err().code, ErrorCode::DeviceBusOff);
        until(&h, "restarted", Duration::from_secs(2), |s| s.bus_state == BusState::ErrorActive).await;
        until(&h, "node ready", Duration::from_secs(2), |s| s.ready()).await;
        h.fire(1).await.expect("fire after the restart");
        println!("vcan0 bus-off and back: {:?}", h.state());
        node.inject(ScannerFault::Quit).await;
    });
}

#[test]
fn a_full_queue_on_vcan1_gives_enobufs_and_the_driver_retries_through_it() {
    runtime().block_on(async {
        // vcan1 sends through a token bucket of 1 kB/s with room for four frames: a burst overflows it.
        let mut blaster = SocketCanBus::open("vcan1").expect("vcan1");
        let filler = Frame::standard(0x555, &[0; 8]).unwrap();
        let fill = async |b: &mut SocketCanBus| {
            for i in 0..200 {
                if let Err(e) = b.send(&filler).await {
                    assert!(is_enobufs(&e), "{e}");
                    return i;
                }
            }
            panic!("no ENOBUFS after 200 frames on the rate-limited vcan1");
        };
        let accepted = fill(&mut blaster).await;
        println!("vcan1: ENOBUFS after {accepted} frames");
        tokio::time::sleep(Duration::from_millis(300)).await;
        let (h, node) = rig("vcan1", Duration::from_millis(100));
        until(&h, "node ready", Duration::from_secs(3), |s| s.ready()).await;
        fill(&mut blaster).await;
        let r = h.fire(0).await.expect("fire through a full queue");
        let s = h.state();
        println!("vcan1 fire through a full queue: {r:?}, {} retries", s.send_retries);
        assert!(s.send_retries >= 1, "{s:?}");
        node.inject(ScannerFault::Quit).await;
    });
}

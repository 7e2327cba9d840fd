//! systemd's notification protocol (`sd_notify(3)`), written directly: one datagram to `$NOTIFY_SOCKET`
//! (a path, or `@name` in the abstract namespace). `READY=1` once the bus name is ours, `STATUS=…`,
//! `STOPPING=1`, and `WATCHDOG=1` from a loop that pets only while the station answers and a running
//! job's progress moves.

use std::os::unix::net::UnixDatagram;
use std::time::Duration;

/// Send `state` (e.g. "READY=1\nSTATUS=idle") to systemd; false when not under systemd or on error.
pub fn notify(state: &str) -> bool {
    let Some(path) = std::env::var_os("NOTIFY_SOCKET") else { return false };
    let Ok(sock) = UnixDatagram::unbound() else { return false };
    let p = path.to_string_lossy().into_owned();
    let sent = if let Some(name) = p.strip_prefix('@') {
        use std::os::linux::net::SocketAddrExt;
        std::os::unix::net::SocketAddr::from_abstract_name(name.as_bytes())
            .and_then(|a| sock.send_to_addr(state.as_bytes(), &a))
    } else {
        sock.send_to(state.as_bytes(), &p)
    };
    sent.is_ok()
}

/// The watchdog period systemd asks for (`WATCHDOG_USEC`, for this process), if any.
pub fn watchdog_period() -> Option<Duration> {
    let usec: u64 = std::env::var("WATCHDOG_USEC").ok()?.parse().ok()?;
    if let Ok(pid) = std::env::var("WATCHDOG_PID")
        && pid.parse::<u32>().ok() != Some(std::process::id())
    {
        return None;
    }
    (usec > 0).then(|| Duration::from_micros(usec))
}

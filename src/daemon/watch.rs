//! inotify on the inbox, read on a plain thread and forwarded to the station as [`WatchEvent`]s. A rename
//! into the inbox (`IN_MOVED_TO`) is a finished file; a close after writing (`IN_CLOSE_WRITE`) is only a hint
//! (the station waits for a settle window of unchanged size and mtime); a queue overflow asks for a full
//! rescan; the inbox itself vanishing or moving makes the station degraded.

use std::path::Path;

use inotify::{EventMask, Inotify, WatchMask};
use tokio::sync::mpsc;

/// What the inbox watch saw.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum WatchEvent {
    /// A name was renamed into the inbox: complete now.
    MovedIn(String),
    /// A file open for writing was closed: complete once it settles.
    ClosedWrite(String),
    /// The kernel dropped events: rescan the whole inbox.
    Overflow,
    /// The inbox was deleted, moved or unmounted: the watch is gone.
    Lost(String),
}

/// Start watching `inbox`; events go to `tx` until the receiver is dropped.
///
/// # Errors
/// The I/O error of `inotify_init` or `inotify_add_watch`.
pub fn start(inbox: &Path, tx: mpsc::UnboundedSender<WatchEvent>) -> std::io::Result<()> {
    let mut ino = Inotify::init()?;
    ino.watches().add(
        inbox,
        WatchMask::CLOSE_WRITE
            | WatchMask::MOVED_TO
            | WatchMask::DELETE_SELF
            | WatchMask::MOVE_SELF
            | WatchMask::ONLYDIR,
    )?;
    std::thread::Builder::new().name("inbox-watch".into()).spawn(move || {
        let mut buf = vec![0u8; 64 * 1024];
        loop {
            let events = match ino.read_events_blocking(&mut buf) {
                Ok(ev) => ev,
                Err(e) => {
                    let _ = tx.send(WatchEvent::Lost(format!("inotify read failed: {e}")));
                    return;
                }
            };
            for ev in events {
                let name = ev.name.map(|n| n.to_string_lossy().into_owned());
                let we = if ev.mask.contains(EventMask::Q_OVERFLOW) {
                    WatchEvent::Overflow
                } else if ev.mask.intersects(EventMask::DELETE_SELF | EventMask::MOVE_SELF | EventMask::UNMOUNT)
                    || ev.mask.contains(EventMask::IGNORED)
                {
                    WatchEvent::Lost("the inbox was deleted, moved or unmounted".into())
                } else if let Some(n) = name {
                    if ev.mask.contains(EventMask::MOVED_TO) {
                        WatchEvent::MovedIn(n)
                    } else {
                        WatchEvent::ClosedWrite(n)
                    }
                } else {
                    continue;
                };
                let lost = matches!(we, WatchEvent::Lost(_));
                if tx.send(we).is_err() || lost {
                    return;
                }
            }
        }
    })?;
    Ok(())
}

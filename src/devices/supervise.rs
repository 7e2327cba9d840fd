//! The supervision every device actor shares, written once: reconnecting with a doubling backoff, refusing
//! commands while the device is away, and reporting one fault per outage.
//!
//! An actor ([`super::turntable::actor`], [`super::trigger::actor`]) loops: connect; on failure report it
//! when [`Outage::report`] says so, then [`idle`] for [`Backoff::next_wait`] (answering commands with its
//! refusal) and try again; once connected, [`Backoff::reset`] and [`Outage::connected`], serve until the line
//! is lost ([`Ended::Lost`]: [`Outage::lost`], the loss being that outage's fault) or every handle is gone
//! ([`Ended::Closed`]).

use std::time::Duration;

use tokio::sync::{broadcast, mpsc, oneshot, watch};

use super::DeviceFault;
use crate::error::{Error, ErrorCode, Result};

/// A handle on a device actor: its commands (`C`), its published state (`S`) and its faults. Cloned freely;
/// dropping every handle ends the actor. The devices' own handles wrap one and add their commands.
pub struct Handle<C, S> {
    commands: mpsc::Sender<C>,
    state: watch::Receiver<S>,
    faults: broadcast::Sender<DeviceFault>,
    device: &'static str,
}

impl<C, S> Clone for Handle<C, S> {
    fn clone(&self) -> Self {
        Handle {
            commands: self.commands.clone(),
            state: self.state.clone(),
            faults: self.faults.clone(),
            device: self.device,
        }
    }
}

/// The actor's ends of a [`Handle`]: where its commands arrive, where it publishes its state and faults.
pub struct Ends<C, S> {
    /// Commands from the handles.
    pub commands: mpsc::Receiver<C>,
    /// The published state.
    pub state: watch::Sender<S>,
    /// The fault channel.
    pub faults: broadcast::Sender<DeviceFault>,
}

impl<C, S: Clone> Handle<C, S> {
    /// A handle and the actor's ends for `device` (`turntable`, `trigger`), starting from `state`.
    pub fn new(device: &'static str, state: S) -> (Handle<C, S>, Ends<C, S>) {
        let (ctx, crx) = mpsc::channel(16);
        let (stx, srx) = watch::channel(state);
        let (ftx, _) = broadcast::channel(64);
        let handle = Handle { commands: ctx, state: srx, faults: ftx.clone(), device };
        (handle, Ends { commands: crx, state: stx, faults: ftx })
    }

    /// The state now.
    pub fn state(&self) -> S {
        self.state.borrow().clone()
    }

    /// A receiver of every state change.
    pub fn watch(&self) -> watch::Receiver<S> {
        self.state.clone()
    }

    /// A receiver of the faults from now on.
    pub fn faults(&self) -> broadcast::Receiver<DeviceFault> {
        self.faults.subscribe()
    }

    /// Send the command `make` builds around its reply channel, and wait for the reply.
    ///
    /// # Errors
    /// The command's; `device.unplugged` when the actor has ended.
    pub async fn ask<T>(&self, make: impl FnOnce(oneshot::Sender<Result<T>>) -> C) -> Result<T> {
        let gone = || Error::new(ErrorCode::DeviceUnplugged, format!("the {}'s task has ended", self.device));
        let (tx, rx) = oneshot::channel();
        self.commands.send(make(tx)).await.map_err(|_| gone())?;
        rx.await.unwrap_or_else(|_| Err(gone()))
    }
}

/// Why a connected phase ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Ended {
    /// Every handle was dropped: the actor ends.
    Closed,
    /// The line failed: reconnect.
    Lost,
}

/// The waits between reconnecting tries: from `min`, doubling up to `max`, back to `min` once connected.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Backoff {
    min: Duration,
    max: Duration,
    next: Duration,
}

impl Backoff {
    /// Waits from `min` doubling to `max` (`max` below `min` is taken as `min`).
    pub fn new(min: Duration, max: Duration) -> Backoff {
        Backoff { min, max: max.max(min), next: min }
    }

    /// The wait before the next try; the one after it doubles (up to the longest).
    pub fn next_wait(&mut self) -> Duration {
        let w = self.next;
        self.next = (self.next * 2).min(self.max);
        w
    }

    /// Connected: the next outage starts from the shortest wait again.
    pub fn reset(&mut self) {
        self.next = self.min;
    }
}

/// One fault per outage: the first failure to connect is reported and the retries are quiet — except a
/// failure that is not the device's absence (`device.unplugged`) and says something new (a wrong firmware, a
/// config the board refuses). A lost connection is itself the outage's fault ([`Outage::lost`]).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Outage {
    reported: bool,
    last: Option<String>,
}

impl Outage {
    /// Whether the failure `e` to connect is to be reported (and, if so, it counts as reported).
    pub fn report(&mut self, e: &Error) -> bool {
        let new = !self.reported || (e.code != ErrorCode::DeviceUnplugged && self.last.as_deref() != Some(&e.message));
        if new {
            self.reported = true;
            self.last = Some(e.message.clone());
        }
        new
    }

    /// Connected: the next failure starts a new outage.
    pub fn connected(&mut self) {
        *self = Outage::default();
    }

    /// The connection was lost (and reported as such by the actor): this outage's fault is reported.
    pub fn lost(&mut self) {
        *self = Outage { reported: true, last: None };
    }
}

/// While the device is away: answer every command with `refuse` for `wait` (sleeping, never spinning).
/// `true` when every handle is gone, so the actor ends.
pub async fn idle<C>(commands: &mut mpsc::Receiver<C>, wait: Duration, mut refuse: impl FnMut(C)) -> bool {
    let until = tokio::time::Instant::now() + wait;
    loop {
        tokio::select! {
            c = commands.recv() => match c {
                None => return true,
                Some(c) => refuse(c),
            },
            _ = tokio::time::sleep_until(until) => return false,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_backoff_doubles_to_its_longest_and_starts_again_when_connected() {
        let ms = Duration::from_millis;
        let mut b = Backoff::new(ms(250), ms(5000));
        let waits: Vec<u128> = (0..7).map(|_| b.next_wait().as_millis()).collect();
        assert_eq!(waits, [250, 500, 1000, 2000, 4000, 5000, 5000]);
        b.reset();
        assert_eq!(b.next_wait(), ms(250));
    }

    #[test]
    fn one_fault_per_outage_unless_the_reason_is_new() {
        let unplugged = Error::new(ErrorCode::DeviceUnplugged, "cannot open /dev/ttyUSB0");
        let config = Error::new(ErrorCode::DeviceConfig, "speed = 60 °/s is more than the board allows");
        let mut o = Outage::default();
        assert!(o.report(&unplugged), "the first failure of an outage");
        assert!(!o.report(&unplugged), "its retries are quiet");
        assert!(o.report(&config), "a new reason");
        assert!(!o.report(&config), "said once");
        o.connected();
        assert!(o.report(&unplugged), "a new outage");
        o.lost();
        assert!(!o.report(&unplugged), "after a loss, the loss was the fault");
    }

    #[test]
    fn idle_refuses_commands_until_the_wait_is_over() {
        let rt = tokio::runtime::Builder::new_current_thread().enable_time().build().unwrap();
        rt.block_on(async {
            let (tx, mut rx) = mpsc::channel(4);
            tx.send(1).await.unwrap();
            tx.send(2).await.unwrap();
            let mut refused = Vec::new();
            let t = std::time::Instant::now();
            assert!(!idle(&mut rx, Duration::from_millis(50), |c| refused.push(c)).await);
            assert!(t.elapsed() >= Duration::from_millis(50), "it waited");
            assert_eq!(refused, [1, 2]);
            drop(tx);
            assert!(idle(&mut rx, Duration::from_secs(5), |_: i32| {}).await, "every handle gone");
        });
    }
}

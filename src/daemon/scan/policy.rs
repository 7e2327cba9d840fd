//! What a fault during a scan leads to: one pure function, [`next`], over the device, what it was doing, the
//! error, whether the device is still connected, the `[scan]` fault settings and the tries so far. The
//! capture loop ([`super::capture`]) only carries the answer out; every rule is here and unit-tested.
//!
//! The rules:
//! - **a device gone** (the table's `device.unplugged` or `device.lost`, or any error while it reports
//!   itself disconnected; the scanner's `device.unplugged`, `device.lost` or `device.bus-off`): with
//!   `on_unplug = "wait"` it is waited for (up to `replug_timeout`) and the action tried again — after a lost
//!   table in a move, the table is homed first (its position is lost); with `on_unplug = "fail"` the scan
//!   fails with the device's code;
//! - **a view lost** (the scanner's `device.timeout` or `device.refused`, or a view file that is unreadable
//!   or short, `input.io`): the trigger is sent again, `view_retries` times; then the view is skipped and
//!   named (`on_lost_view = "skip"`) or the scan fails (`"fail"`);
//! - **anything else** (an alarm, a table stopped off its target, a timeout of the table, a config the
//!   board refuses, a cancel, a disk that is full): the scan fails with that error.

use super::super::config::{OnLostView, OnUnplug, ScanConfig};
use crate::error::{Error, ErrorCode};

/// The device an error came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Device {
    /// The turntable.
    Turntable,
    /// The scanner's trigger (and its view files).
    Trigger,
}

/// What the capture was doing when the error came.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Action {
    /// Homing (or unlocking) the table.
    Home,
    /// Moving the table to a view's angle.
    Move,
    /// Triggering a view and taking its file.
    View,
}

/// What an error is, for the policy.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Fault {
    /// The device is gone (unplugged, silent, bus-off): it may come back.
    Gone,
    /// A view did not arrive (or arrived broken): another trigger may bring it.
    ViewLost,
    /// A view arrived with no points: the scanner saw nothing, and would see the same again.
    ViewEmpty,
    /// Anything else: retrying will not help.
    Fatal,
}

/// What to do next.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Step {
    /// Trigger the view again.
    Retry,
    /// Wait for the device to come back, then do the same again.
    WaitFor(Device),
    /// Wait for the table to come back, home it, then move again.
    WaitAndReHome,
    /// Leave the view out, named in the capture log.
    Skip,
    /// Give up: the scan fails with the error.
    Fail,
}

/// The one classifier: what `e` from `device` is (`connected`: whether the device reports itself connected
/// now; an error from a table that is not is its loss, whatever its code).
pub fn classify(device: Device, e: &Error, connected: bool) -> Fault {
    use ErrorCode as C;
    match device {
        Device::Turntable if matches!(e.code, C::DeviceUnplugged | C::DeviceLost) || !connected => Fault::Gone,
        Device::Trigger if matches!(e.code, C::DeviceUnplugged | C::DeviceLost | C::DeviceBusOff) => Fault::Gone,
        Device::Trigger if matches!(e.code, C::DeviceTimeout | C::DeviceRefused | C::InputIo) => Fault::ViewLost,
        Device::Trigger if e.code == C::DeviceEmptyView => Fault::ViewEmpty,
        _ => Fault::Fatal,
    }
}

/// The `[scan]` settings the policy reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Rules {
    /// A device gone mid-scan: wait for it or fail.
    pub on_unplug: OnUnplug,
    /// A view lost after its retries: skip it or fail.
    pub on_lost_view: OnLostView,
    /// A view with no points: skip it or fail (never retried).
    pub on_empty_view: OnLostView,
    /// Triggers sent again for a view that did not arrive.
    pub view_retries: u32,
}

impl Rules {
    /// From `[scan]`.
    pub fn of(cfg: &ScanConfig) -> Rules {
        Rules {
            on_unplug: cfg.on_unplug,
            on_lost_view: cfg.on_lost_view,
            on_empty_view: cfg.on_empty_view,
            view_retries: cfg.view_retries,
        }
    }
}

/// What follows `e` from `device` while doing `action`; `lost` counts the triggers of this view lost so far,
/// this one included. Pure; cost O(1).
pub fn next(device: Device, action: Action, e: &Error, connected: bool, rules: &Rules, lost: u32) -> Step {
    match (classify(device, e, connected), action) {
        (Fault::Gone, _) if rules.on_unplug == OnUnplug::Fail => Step::Fail,
        (Fault::Gone, Action::Move) if device == Device::Turntable => Step::WaitAndReHome,
        (Fault::Gone, _) => Step::WaitFor(device),
        (Fault::ViewLost, Action::View) if lost <= rules.view_retries => Step::Retry,
        (Fault::ViewLost, Action::View) if rules.on_lost_view == OnLostView::Skip => Step::Skip,
        (Fault::ViewEmpty, Action::View) if rules.on_empty_view == OnLostView::Skip => Step::Skip,
        _ => Step::Fail,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn e(code: ErrorCode) -> Error {
        Error::new(code, "test")
    }

    const WAIT: Rules = Rules {
        on_unplug: OnUnplug::Wait,
        on_lost_view: OnLostView::Fail,
        on_empty_view: OnLostView::Fail,
        view_retries: 2,
    };
    const FAIL: Rules = Rules {
        on_unplug: OnUnplug::Fail,
        on_lost_view: OnLostView::Skip,
        on_empty_view: OnLostView::Skip,
        view_retries: 0,
    };

    /// A view with no points is its own fault, never retried: skipped or failing the scan as
    /// `on_empty_view` says, whatever `view_retries` allows.
    #[test]
    fn an_empty_view_is_not_a_lost_one_and_is_never_retried() {
        use {Action::View, Device::Trigger};
        let empty = e(ErrorCode::DeviceEmptyView);
        assert_eq!(classify(Trigger, &empty, true), Fault::ViewEmpty);
        assert_eq!(next(Trigger, View, &empty, true, &WAIT, 0), Step::Fail, "retries left, still not retried");
        assert_eq!(next(Trigger, View, &empty, true, &FAIL, 0), Step::Skip);
        assert_eq!(classify(Trigger, &e(ErrorCode::DeviceTimeout), true), Fault::ViewLost);
    }

    /// The table unplugged (or silent) is waited for; in a move it is homed again after it is back; with
    /// `on_unplug = "fail"` the scan fails.
    #[test]
    fn a_lost_table_is_waited_for_and_re_homed_after_a_move() {
        use {Action::*, Device::Turntable};
        for code in [ErrorCode::DeviceUnplugged, ErrorCode::DeviceLost] {
            assert_eq!(next(Turntable, Home, &e(code), false, &WAIT, 0), Step::WaitFor(Turntable), "{code:?}");
            assert_eq!(next(Turntable, Move, &e(code), false, &WAIT, 0), Step::WaitAndReHome, "{code:?}");
            assert_eq!(next(Turntable, Move, &e(code), false, &FAIL, 0), Step::Fail, "{code:?}");
        }
        // Any error from a table that reports itself disconnected is its loss (a timeout as the line died).
        assert_eq!(next(Turntable, Move, &e(ErrorCode::DeviceTimeout), false, &WAIT, 0), Step::WaitAndReHome);
        assert_eq!(next(Turntable, Move, &e(ErrorCode::DeviceTimeout), true, &WAIT, 0), Step::Fail);
    }

    /// The scanner gone (unplugged, heartbeat lost, its bus off) is waited for, then the view is triggered
    /// again without counting as a lost view.
    #[test]
    fn a_lost_scanner_is_waited_for() {
        use {Action::View, Device::Trigger};
        for code in [ErrorCode::DeviceUnplugged, ErrorCode::DeviceLost, ErrorCode::DeviceBusOff] {
            assert_eq!(next(Trigger, View, &e(code), true, &WAIT, 0), Step::WaitFor(Trigger), "{code:?}");
            assert_eq!(next(Trigger, View, &e(code), true, &FAIL, 0), Step::Fail, "{code:?}");
        }
    }

    /// A view that does not arrive (timeout, busy, a broken or short file) is triggered again `view_retries`
    /// times, then skipped or the scan fails, as configured.
    #[test]
    fn a_lost_view_is_retried_then_skipped_or_failed() {
        use {Action::View, Device::Trigger};
        for code in [ErrorCode::DeviceTimeout, ErrorCode::DeviceRefused, ErrorCode::InputIo] {
            assert_eq!(next(Trigger, View, &e(code), true, &WAIT, 1), Step::Retry, "{code:?}");
            assert_eq!(next(Trigger, View, &e(code), true, &WAIT, 2), Step::Retry, "{code:?}");
            assert_eq!(next(Trigger, View, &e(code), true, &WAIT, 3), Step::Fail, "{code:?}");
            assert_eq!(next(Trigger, View, &e(code), true, &FAIL, 1), Step::Skip, "{code:?}");
        }
    }

    /// Alarms, a table off its target or timing out while connected, a config the board refuses, an
    /// emergency, a cancel and a full disk end the scan: waiting or retrying would not help.
    #[test]
    fn everything_else_fails_the_scan() {
        use {Action::*, Device::*};
        for code in [
            ErrorCode::DeviceAlarm,
            ErrorCode::DevicePosition,
            ErrorCode::DeviceTimeout,
            ErrorCode::DeviceRefused,
            ErrorCode::DeviceConfig,
            ErrorCode::DeviceWrongFirmware,
            ErrorCode::Cancelled,
            ErrorCode::ResourceOutput,
        ] {
            for action in [Home, Move] {
                assert_eq!(next(Turntable, action, &e(code), true, &WAIT, 0), Step::Fail, "{code:?} {action:?}");
            }
        }
        for code in [ErrorCode::DeviceEmergency, ErrorCode::Cancelled, ErrorCode::ResourceOutput] {
            assert_eq!(next(Trigger, View, &e(code), true, &WAIT, 0), Step::Fail, "{code:?}");
        }
    }

    #[test]
    fn the_classifier_names_each_fault_once() {
        assert_eq!(classify(Device::Trigger, &e(ErrorCode::InputIo), true), Fault::ViewLost);
        assert_eq!(classify(Device::Turntable, &e(ErrorCode::InputIo), true), Fault::Fatal);
        assert_eq!(classify(Device::Turntable, &e(ErrorCode::DeviceBusOff), true), Fault::Fatal);
        assert_eq!(classify(Device::Trigger, &e(ErrorCode::DeviceBusOff), false), Fault::Gone);
    }
}

//! Scan sessions: the station turns the object on its table, fires the scanner at every stop and keeps each
//! view, then hands the views to the conversion chain as a scan set ([`super::worker`]).
//!
//! A scan job's input is a directory `work/<id>/<name>.scan/` that grows view by view:
//! - `view-NNN.ply`: view NNN of the plan (its points in the scanner's frame, as the scanner wrote them);
//! - `capture.json` ([`CaptureLog`]): every view taken (angle asked and reached, trigger sequence number,
//!   points, tries) and every view skipped, with the calibration used;
//! - `scanset.toml`: the views as a scan set, each posed by a matrix from the scanner's frame to the
//!   **table frame** (origin at the table top's centre, z up the axis, x along the scanner's right turned
//!   flat), so the solid stands on the table as the object did: view at table angle θ → turn back by −θ
//!   about the calibrated axis ([`crate::geometry::pose::Pose::turntable`]) → table frame.
//!
//! A view is persisted before the next move (its file moved in and synced, then `capture.json` and the
//! manifest rewritten atomically), so a crash loses at most the view in flight; a restarted job
//! ([`capture`]) re-homes and goes on from the first view `capture.json` does not hold. No view is taken
//! twice into the set, and none that was kept is lost.
//!
//! Faults ([`super::config::ScanConfig`]): a turntable lost mid-scan is waited for (`on_unplug = "wait"`, up to
//! `replug_timeout`; then it is homed and the interrupted view taken again) or fails the scan with its code;
//! a view that never arrives is triggered again `view_retries` times, then fails the scan (`device.timeout`)
//! or is skipped and named; a cancel stops the scan before its next move.

//!
//! The parts: [`plan`] (the request, the capture log, the poses), [`policy`] (what a fault leads to: one pure
//! function with its unit tests), [`next`] (after the plan, views chosen where the surface is unseen, through
//! [`crate::pipeline::next_view`]), [`capture`] (the I/O loop that carries the steps out; blocking file work
//! off the async workers).

pub mod capture;
pub mod next;
pub mod plan;
pub mod policy;

pub use capture::{CaptureJob, capture, persist};
pub use plan::{CAPTURE_LOG, CaptureLog, ScanRequest, SkippedView, TakenView, table_frame, view_pose};

use crate::devices::trigger::TriggerHandle;
use crate::devices::turntable::actor::TurntableHandle;

/// The rig's devices the daemon drives (those configured).
#[derive(Clone, Default)]
pub struct Rig {
    /// The turntable.
    pub turntable: Option<TurntableHandle>,
    /// The scanner's trigger.
    pub trigger: Option<TriggerHandle>,
}

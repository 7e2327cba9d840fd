//! A scan's plan and its record: what `StartScan` asked for ([`ScanRequest`]), what the capture did so far
//! ([`CaptureLog`], `capture.json`), and the poses of its views in the table frame ([`view_pose`]). Plain
//! data and geometry; the only I/O is reading the log ([`CaptureLog::load`], [`CaptureLog::read`]).

use std::path::{Path, PathBuf};

use crate::error::{Error, ErrorCode};
use crate::geometry::pose::Pose;
use crate::geometry::vec3::{V3, cross, dot, norm, scale, sub};

/// The capture log's file name in a scan directory.
pub const CAPTURE_LOG: &str = "capture.json";

/// What `StartScan` asked for.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ScanRequest {
    /// Views (stops of the table).
    pub views: u32,
    /// Degrees between stops.
    pub step_deg: f64,
    /// An FEA spec to solve on the solid (a TOML file on the station; coordinates in the table frame).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fea: Option<PathBuf>,
}

impl ScanRequest {
    /// The table angles of the plan's views, degrees.
    pub fn angles(&self) -> Vec<f64> {
        (0..self.views).map(|i| f64::from(i) * self.step_deg).collect()
    }

    /// From `views` and/or `step_deg` (one is enough; neither: the configured number of views, evenly
    /// around).
    ///
    /// # Errors
    /// A message naming the option when they are out of range or the views would go round more than once.
    pub fn new(views: Option<u32>, step_deg: Option<f64>, default_views: u32) -> Result<ScanRequest, String> {
        let (views, step_deg) = match (views, step_deg) {
            (Some(v), Some(s)) => (v, s),
            (Some(v), None) => (v, 360.0 / f64::from(v.max(1))),
            (None, Some(s)) if s.is_finite() && s > 0.0 => (((360.0 / s) - 1e-9).floor() as u32 + 1, s),
            (None, Some(s)) => return Err(format!("step_deg: {s} is not a positive angle")),
            (None, None) => (default_views, 360.0 / f64::from(default_views.max(1))),
        };
        if !(1..=360).contains(&views) {
            return Err(format!("views: {views} is outside 1..=360"));
        }
        if !(step_deg.is_finite() && step_deg > 0.0 && step_deg <= 360.0) {
            return Err(format!("step_deg: {step_deg} is outside (0, 360]"));
        }
        if f64::from(views - 1) * step_deg >= 360.0 - 1e-9 {
            return Err(format!("{views} views {step_deg}° apart go round more than once"));
        }
        Ok(ScanRequest { views, step_deg, fea: None })
    }
}

/// One view taken.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TakenView {
    /// Its index in the plan.
    pub index: u32,
    /// Its file in the scan directory.
    pub file: String,
    /// The file's size, bytes (0 in a log written before sizes were kept).
    #[serde(default)]
    pub bytes: u64,
    /// The file's SHA-256 from the read that checked it (empty in a log written before hashes were kept).
    #[serde(default)]
    pub sha256: String,
    /// The table angle asked, degrees.
    pub angle_deg: f64,
    /// The angle the table reported reaching, degrees.
    pub reached_deg: f64,
    /// The trigger's sequence number.
    pub seq: u16,
    /// Points in the view.
    pub points: u32,
    /// Triggers it took (1 when the first view arrived).
    pub tries: u32,
    /// From the trigger to "view ready", milliseconds.
    pub view_ms: f64,
}

/// One view left out (`on_lost_view = "skip"`).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SkippedView {
    /// Its index in the plan.
    pub index: u32,
    /// The table angle, degrees.
    pub angle_deg: f64,
    /// Why (the last error, with its code).
    pub reason: String,
}

/// `capture.json`: what the capture did so far (the truth a resumed scan goes on from).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CaptureLog {
    /// The calibrated axis: a point (the table top's centre) in the scanner's frame.
    pub axis_point: V3,
    /// The axis direction in the scanner's frame.
    pub axis_direction: V3,
    /// Views planned.
    pub planned: u32,
    /// Views taken, in plan order.
    pub views: Vec<TakenView>,
    /// Views skipped.
    pub skipped: Vec<SkippedView>,
    /// Times the scan was (re)started: 1, more after a restart.
    pub runs: u32,
    /// Homing cycles run (one per run, one after each replug).
    pub homings: u32,
    /// Times the turntable was lost and came back.
    pub replugs: u32,
    /// Triggers sent again for views that did not arrive.
    pub retries: u32,
}

impl CaptureLog {
    /// Read `capture.json` in `dir`; `None` when there is none (or it is unreadable: it is rewritten whole).
    pub fn load(dir: &Path) -> Option<CaptureLog> {
        Self::read(dir).ok()
    }

    /// Read `capture.json` in `dir`.
    ///
    /// # Errors
    /// `input.io` naming the file, when it is missing or not a capture log.
    pub fn read(dir: &Path) -> Result<CaptureLog, Error> {
        let path = dir.join(CAPTURE_LOG);
        let bad = |m: String| Error::new(ErrorCode::InputIo, format!("the capture log {}: {m}", path.display()));
        let bytes = std::fs::read(&path).map_err(|e| bad(e.to_string()))?;
        serde_json::from_slice(&bytes).map_err(|e| bad(e.to_string()))
    }

    /// Whether view `index` of the plan is in (taken or skipped).
    pub fn has(&self, index: u32) -> bool {
        self.views.iter().any(|v| v.index == index) || self.skipped.iter().any(|v| v.index == index)
    }
}

/// The table frame from the calibration: scanner frame → table frame (origin at `point`, z along
/// `direction`, x the scanner's x made perpendicular to the axis).
pub fn table_frame(point: V3, direction: V3) -> Pose {
    let z = scale(direction, 1.0 / norm(direction));
    let seed = if dot([1.0, 0.0, 0.0], z).abs() < 0.9 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
    let x = sub(seed, scale(z, dot(seed, z)));
    let x = scale(x, 1.0 / norm(x));
    let y = cross(z, x);
    let rotation = [x, y, z];
    let t = [-dot(x, point), -dot(y, point), -dot(z, point)];
    Pose { rotation, translation: t }
}

/// The pose of a view taken at table angle `angle_deg`: scanner frame → table frame.
pub fn view_pose(point: V3, direction: V3, angle_deg: f64) -> Pose {
    let back = Pose::turntable(point, direction, angle_deg).unwrap_or(Pose::IDENTITY);
    table_frame(point, direction).then_after(&back)
}

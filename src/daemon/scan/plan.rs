//! A scan's plan and its record: what `StartScan` asked for ([`ScanRequest`]), what the capture did so far
//! ([`CaptureLog`], `capture.json`), and the poses of its views in the table frame ([`view_pose`]). Plain
//! data and geometry; the only I/O is reading the log ([`CaptureLog::load`], [`CaptureLog::read`]).

use std::path::{Path, PathBuf};

use crate::error::{Error, ErrorCode};
use crate::geometry::pose::Pose;
use crate::geometry::vec3::{V3, cross, dot, norm, scale, sub};

/// The capture log's file name in a scan directory.
pub const CAPTURE_LOG: &str = "capture.json";

/// One ring of a tilting table's plan: `views` stops evenly around with the cradle at `tilt_deg`, the first
/// half a step from 0 (so a ring's views fall between the level ring's).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Ring {
    /// The cradle's tilt, degrees (positive turns the table's top toward the scanner).
    pub tilt_deg: f64,
    /// Stops around.
    pub views: u32,
}

impl Ring {
    /// Rings from `TILT:VIEWS,TILT:VIEWS…` (`-25:8,-45:8,50:6`); an empty text is no ring.
    ///
    /// # Errors
    /// A message naming the item that is not `TILT:VIEWS`, a tilt that is not a finite angle within ±180, a
    /// ring with 0 or more than 360 views, or a ring at tilt 0 (the level ring is `views`).
    pub fn parse_list(text: &str) -> Result<Vec<Ring>, String> {
        let mut out = Vec::new();
        for item in text.split(',').map(str::trim).filter(|i| !i.is_empty()) {
            let bad = || format!("tilts: {item:?} is not TILT:VIEWS (degrees:count, e.g. -25:8)");
            let (t, n) = item.split_once(':').ok_or_else(bad)?;
            let tilt_deg: f64 = t.trim().parse().map_err(|_| bad())?;
            let views: u32 = n.trim().parse().map_err(|_| bad())?;
            if !(tilt_deg.is_finite() && tilt_deg.abs() <= 180.0) || tilt_deg == 0.0 {
                return Err(format!(
                    "tilts: {item:?}: the tilt must be a non-zero angle within ±180° (the level ring is `views`)"
                ));
            }
            if !(1..=360).contains(&views) {
                return Err(format!("tilts: {item:?}: {views} views is outside 1..=360"));
            }
            out.push(Ring { tilt_deg, views });
        }
        Ok(out)
    }

    /// The ring as `TILT:VIEWS`.
    pub fn text(rings: &[Ring]) -> String {
        rings.iter().map(|r| format!("{}:{}", r.tilt_deg, r.views)).collect::<Vec<_>>().join(",")
    }
}

/// A coverage target (`coverage`): a share in (0, 1].
///
/// # Errors
/// A message naming the value.
pub fn check_coverage(c: f64) -> Result<f64, String> {
    if c > 0.0 && c <= 1.0 { Ok(c) } else { Err(format!("{c} is not a share in (0, 1]")) }
}

/// A view budget (`max_views`): 2 to 720 views.
///
/// # Errors
/// A message naming the value.
pub fn check_max_views(n: u64) -> Result<u32, String> {
    if (2..=720).contains(&n) { Ok(n as u32) } else { Err(format!("{n} is outside 2..=720")) }
}

/// One stop of a plan: where the table turns and tilts to, in which pass.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Stop {
    /// The table angle, degrees.
    pub angle_deg: f64,
    /// The cradle's tilt, degrees (0: level).
    pub tilt_deg: f64,
    /// The pass (1, 2, …: the object turned over before each after the first).
    pub pass: u32,
}

/// A scan's passes: 1 to [`MAX_PASSES`].
pub const MAX_PASSES: u32 = 4;

/// A number of passes (`passes`): 1 to [`MAX_PASSES`].
///
/// # Errors
/// A message naming the value.
pub fn check_passes(n: u64) -> Result<u32, String> {
    if (1..=u64::from(MAX_PASSES)).contains(&n) {
        Ok(n as u32)
    } else {
        Err(format!("{n} is outside 1..={MAX_PASSES}"))
    }
}

fn one() -> u32 {
    1
}

fn is_one(n: &u32) -> bool {
    *n == 1
}

/// What `StartScan` asked for.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ScanRequest {
    /// Views (stops of the table) of the level ring.
    pub views: u32,
    /// Degrees between stops.
    pub step_deg: f64,
    /// A tilting table's further rings, after the level one (`tilts`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub rings: Vec<Ring>,
    /// After the planned views, views chosen where the surface is unseen until this share is seen (0–1);
    /// `None`: the plan only.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub coverage: Option<f64>,
    /// Most views in all, the chosen ones included (`None`: the station's `[scan] max_views`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_views: Option<u32>,
    /// An FEA spec to solve on the solid (a TOML file on the station; coordinates in the table frame).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fea: Option<PathBuf>,
    /// Passes: the plan's stops are taken once per pass, the object turned over by a person (or the
    /// simulated rig) between two (`OperatorActionRequired`, then `Continue()`).
    #[serde(default = "one", skip_serializing_if = "is_one")]
    pub passes: u32,
}

impl ScanRequest {
    /// The plan's stops, in order, pass by pass: the level ring's, then each tilted ring's.
    pub fn stops(&self) -> Vec<Stop> {
        (1..=self.passes.max(1)).flat_map(|pass| self.stops_of(pass)).collect()
    }

    /// The stops of one pass: the level ring's, then each tilted ring's.
    fn stops_of(&self, pass: u32) -> Vec<Stop> {
        let level = (0..self.views).map(|i| Stop { angle_deg: f64::from(i) * self.step_deg, tilt_deg: 0.0, pass });
        let tilted = self.rings.iter().flat_map(|r| {
            let step = 360.0 / f64::from(r.views);
            (0..r.views).map(move |i| Stop { angle_deg: (f64::from(i) + 0.5) * step, tilt_deg: r.tilt_deg, pass })
        });
        level.chain(tilted).collect()
    }

    /// Whether the plan tilts the cradle (every move then sends the tilt, 0 for the level ring).
    pub fn tilts(&self) -> bool {
        !self.rings.is_empty()
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
        Ok(ScanRequest { views, step_deg, rings: Vec::new(), coverage: None, max_views: None, fea: None, passes: 1 })
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
    /// The cradle's tilt asked, degrees (0: level, and in logs of single-axis scans).
    #[serde(default)]
    pub tilt_deg: f64,
    /// Its pass (1 in logs written before passes).
    #[serde(default = "one", skip_serializing_if = "is_one")]
    pub pass: u32,
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
    /// The cradle's tilt, degrees.
    #[serde(default)]
    pub tilt_deg: f64,
    /// Its pass.
    #[serde(default = "one", skip_serializing_if = "is_one")]
    pub pass: u32,
    /// Why (the last error, with its code).
    pub reason: String,
}

/// A view chosen where the surface was unseen.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ChosenView {
    /// Its index in the plan.
    pub index: u32,
    /// Table angle, degrees.
    pub angle_deg: f64,
    /// Cradle tilt, degrees.
    pub tilt_deg: f64,
    /// The share of the surface it was predicted to see first.
    pub predicted_gain: f64,
    /// The round of choosing (1: after the plan).
    pub round: u32,
    /// The pass it is taken in (the scan's last).
    #[serde(default = "one", skip_serializing_if = "is_one")]
    pub pass: u32,
}

/// One estimate of what the views taken so far saw.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CoverageEstimate {
    /// Views taken when it was made.
    pub views: u32,
    /// The share of a coarse surface from them that they saw.
    pub coverage: f64,
    /// The same, each vertex counting half for one view and whole for two
    /// ([`crate::pipeline::next_view::Estimate::seen_share`]): what the choosing raises to the target.
    #[serde(default)]
    pub seen_twice: f64,
    /// Seconds it took.
    pub seconds: f64,
    /// Seconds choosing the next views took after it (0 when none were chosen).
    #[serde(default)]
    pub choose_seconds: f64,
}

/// `capture.json`: what the capture did so far (the truth a resumed scan goes on from).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CaptureLog {
    /// The calibrated axis: a point (the table top's centre) in the scanner's frame.
    pub axis_point: V3,
    /// The axis direction in the scanner's frame.
    pub axis_direction: V3,
    /// A tilting table's calibrated cradle axis in the scanner's frame (table at 0°, level): a point and a
    /// direction; `None` for a single-axis scan.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tilt_axis: Option<(V3, V3)>,
    /// Views planned (the plan's, then those chosen where the surface is unseen).
    pub planned: u32,
    /// Views chosen where the surface was unseen, in order (their plan indices follow the plan's).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub next_views: Vec<ChosenView>,
    /// Each estimate of the unseen surface: after the plan, then after each round of chosen views.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub estimates: Vec<CoverageEstimate>,
    /// Why the station chose no more views (`coverage reached`, `no view adds enough`, `the view budget`).
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub next_views_end: String,
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
    /// The pass whose turn-over a person is asked for now (`OperatorActionRequired`), until `Continue()`;
    /// a restarted scan asks again.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub waiting_for_pass: Option<u32>,
    /// Passes whose turn-over was confirmed (`Continue()`), with when (µs since the epoch).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub turned_over: Vec<(u32, u64)>,
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

/// The pose of a view taken at table angle `angle_deg` with the cradle tilted by `tilt_deg` about `tilt`
/// (its calibrated axis: a point and a direction in the scanner's frame): untilt, unturn, then the table
/// frame ([`Pose::tilted_turntable`]). Level (`tilt_deg` 0) it is [`view_pose`].
pub fn tilted_view_pose(point: V3, direction: V3, tilt: (V3, V3), angle_deg: f64, tilt_deg: f64) -> Pose {
    let back = Pose::tilted_turntable((point, direction), tilt, angle_deg, tilt_deg).unwrap_or(Pose::IDENTITY);
    table_frame(point, direction).then_after(&back)
}

/// The pose of a stop (scanner frame → table frame) on a table calibrated with `axis` (a point and a
/// direction) and, when it tilts, `tilt_axis`: [`tilted_view_pose`] for a tilted stop, [`view_pose`] for a
/// level one.
pub fn stop_pose((point, direction): (V3, V3), tilt_axis: Option<(V3, V3)>, stop: Stop) -> Pose {
    match tilt_axis {
        Some(tilt) if stop.tilt_deg != 0.0 => tilted_view_pose(point, direction, tilt, stop.angle_deg, stop.tilt_deg),
        _ => view_pose(point, direction, stop.angle_deg),
    }
}

impl CaptureLog {
    /// The pose of a view of this log (its angle and tilt, the log's calibration): scanner frame → table
    /// frame ([`stop_pose`]).
    pub fn pose_of(&self, v: &TakenView) -> Pose {
        let stop = Stop { angle_deg: v.angle_deg, tilt_deg: v.tilt_deg, pass: v.pass };
        stop_pose((self.axis_point, self.axis_direction), self.tilt_axis, stop)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rings_parse_and_stops_interleave() {
        let rings = Ring::parse_list(" -25:8, 50:2 ").unwrap();
        assert_eq!(rings, vec![Ring { tilt_deg: -25.0, views: 8 }, Ring { tilt_deg: 50.0, views: 2 }]);
        assert_eq!(Ring::text(&rings), "-25:8,50:2");
        assert!(Ring::parse_list("").unwrap().is_empty());
        for (bad, why) in [("-25", "TILT:VIEWS"), ("0:4", "non-zero"), ("200:4", "±180"), ("10:0", "1..=360")] {
            assert!(Ring::parse_list(bad).unwrap_err().contains(why), "{bad}");
        }
        let mut r = ScanRequest::new(Some(4), None, 12).unwrap();
        assert!(!r.tilts());
        r.rings = rings;
        let stops = r.stops();
        assert_eq!(stops.len(), 14);
        assert_eq!(stops[3], Stop { angle_deg: 270.0, tilt_deg: 0.0, pass: 1 });
        assert_eq!(stops[4], Stop { angle_deg: 22.5, tilt_deg: -25.0, pass: 1 });
        assert_eq!(stops[13], Stop { angle_deg: 270.0, tilt_deg: 50.0, pass: 1 });
        r.passes = 2;
        let stops = r.stops();
        assert_eq!(stops.len(), 28, "each pass takes the plan");
        assert_eq!(stops[14], Stop { angle_deg: 0.0, tilt_deg: 0.0, pass: 2 });
        assert_eq!(stops[27], Stop { angle_deg: 270.0, tilt_deg: 50.0, pass: 2 });
        assert_eq!(check_passes(0).unwrap_err(), "0 is outside 1..=4");
    }

    /// A point on the object, seen from a tilted stop and placed by the log's pose, lands where the level
    /// view at 0° places it; a level view's pose is the single-axis one.
    #[test]
    fn a_tilted_view_is_placed_by_turn_and_tilt() {
        let (p, d) = ([0.1, -0.4, -2.0], [0.0, 0.94, 0.34]);
        let tilt = (p, [1.0, 0.0, 0.0]);
        let log = CaptureLog { axis_point: p, axis_direction: d, tilt_axis: Some(tilt), ..Default::default() };
        let view = |angle_deg: f64, tilt_deg: f64| TakenView {
            index: 0,
            file: String::new(),
            bytes: 0,
            sha256: String::new(),
            angle_deg,
            reached_deg: angle_deg,
            tilt_deg,
            pass: 1,
            seq: 0,
            points: 0,
            tries: 1,
            view_ms: 0.0,
        };
        let q = [0.3, -0.1, -1.8];
        // Where the object's point q (scanner frame, table at 0°, level) is seen from the stop (30°, -40°).
        let seen = Pose::tilted_turntable((p, d), tilt, 30.0, -40.0).unwrap().inverse_apply(q);
        let placed = log.pose_of(&view(30.0, -40.0)).apply(seen);
        let level = log.pose_of(&view(0.0, 0.0)).apply(q);
        assert!(norm(sub(placed, level)) < 1e-12, "{placed:?} vs {level:?}");
        let single = view_pose(p, d, 30.0);
        assert_eq!(log.pose_of(&view(30.0, 0.0)), single);
    }
}

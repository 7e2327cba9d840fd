//! Scan sets: several range scans (views), each with its pose, listed in a Stanford `.conf` file:
//!
//! ```text
//! camera tx ty tz qx qy qz qw      (ignored)
//! bmesh FILE tx ty tz qx qy qz qw  (one view: its file, relative to the .conf, and its pose)
//! ```
//!
//! A view's points go to the common frame as `R(q)ᵀ·p + t` (unit quaternion, scalar last): scanalyze stores
//! the quaternion of the inverse rotation (checked on the Stanford bunny: with `R(q)ᵀ·p + t` 91 % of bun045's
//! points lie within 1 mm of bun000's, with `R(q)·p + t` 0.3 %). Errors name the line: a malformed pose or a duplicate view is `input.bad-record`, a missing view file `input.not-found`.

use std::path::{Path, PathBuf};

use crate::error::{Error, ErrorCode, Location, Result};
use crate::geometry::io::{ReadOptions, read_geometry};
use crate::geometry::vec3::V3;

/// One view of a scan set.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct View {
    /// The view's name (its file name as listed).
    pub name: String,
    /// Its file.
    pub file: PathBuf,
    /// Translation of its pose.
    pub translation: V3,
    /// Rotation of its pose as a unit quaternion (x, y, z, w).
    pub rotation: [f64; 4],
    /// Its points in its own frame.
    #[serde(skip)]
    pub points: Vec<[f32; 3]>,
    /// Its points' count.
    pub point_count: usize,
}

impl View {
    /// The pose's rotation matrix, view frame to common frame: R(q)ᵀ (see the module docs).
    pub fn rotation_matrix(&self) -> [[f64; 3]; 3] {
        let [x, y, z, w] = self.rotation;
        let w = -w; // the conjugate quaternion gives the transpose
        [
            [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - z * w), 2.0 * (x * z + y * w)],
            [2.0 * (x * y + z * w), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - x * w)],
            [2.0 * (x * z - y * w), 2.0 * (y * z + x * w), 1.0 - 2.0 * (x * x + y * y)],
        ]
    }

    /// The view's points in the common frame (the rotation computed once).
    pub fn placed(&self) -> Vec<[f32; 3]> {
        let (r, t) = (self.rotation_matrix(), self.translation);
        self.points
            .iter()
            .map(|p| {
                let p = p.map(f64::from);
                std::array::from_fn(|i| (r[i][0] * p[0] + r[i][1] * p[1] + r[i][2] * p[2] + t[i]) as f32)
            })
            .collect()
    }

    /// Direction `d` (in the view's frame) in the common frame.
    pub fn dir_to_world(&self, d: V3) -> V3 {
        let r = self.rotation_matrix();
        std::array::from_fn(|i| r[i][0] * d[0] + r[i][1] * d[1] + r[i][2] * d[2])
    }
}

/// Largest `.conf` file, bytes.
pub const MAX_CONF_BYTES: u64 = 1 << 20;

/// Whether `path` names a scan set (a `.conf` file).
pub fn is_scan_set(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("conf"))
}

/// Read a `.conf` scan set and every view it lists (each within `options`).
///
/// # Errors
/// `input.bad-record` for a malformed line, a pose that is not finite or whose quaternion is not of unit
/// length (within 1 %), or a view listed twice; `input.not-found` for a missing view file (named); the
/// readers' errors for a view; `input.no-geometry` for a set without views.
pub fn read_conf(path: &Path, options: &ReadOptions) -> Result<Vec<View>> {
    let text = super::read_small_text(path, MAX_CONF_BYTES, "the scan set")?;
    let dir = path.parent().unwrap_or(Path::new("."));
    let mut views: Vec<View> = Vec::new();
    for (k, line) in text.lines().enumerate() {
        let loc = Location::Line(k as u64 + 1);
        let bad = |m: String| Error::new(ErrorCode::InputBadRecord, m).in_file(path).at(loc);
        let toks: Vec<&str> = line.split_whitespace().collect();
        match toks.first() {
            None | Some(&"camera") => continue,
            Some(t) if t.starts_with('#') => continue,
            Some(&"bmesh") => {}
            Some(other) => {
                return Err(bad(format!("unknown entry {other:?}; expected `bmesh FILE tx ty tz qx qy qz qw`")));
            }
        }
        if toks.len() != 9 {
            return Err(bad(format!(
                "{} values; `bmesh FILE tx ty tz qx qy qz qw` has 8 after the keyword",
                toks.len() - 1
            )));
        }
        let nums: Vec<f64> = toks[2..]
            .iter()
            .map(|t| t.parse::<f64>().ok().filter(|v| v.is_finite()))
            .collect::<Option<Vec<f64>>>()
            .ok_or_else(|| bad("the pose has a value that is not a finite number".into()))?;
        let q = [nums[3], nums[4], nums[5], nums[6]];
        let len = q.iter().map(|v| v * v).sum::<f64>().sqrt();
        if (len - 1.0).abs() > 0.01 {
            return Err(bad(format!("the rotation quaternion has length {len:.4}, not 1")));
        }
        let name = toks[1].to_string();
        if views.iter().any(|v| v.name == name) {
            return Err(bad(format!("view {name} is listed twice")));
        }
        let file = dir.join(&name);
        if !file.is_file() {
            return Err(Error::new(ErrorCode::InputNotFound, format!("view {name} is missing: {}", file.display()))
                .in_file(path)
                .at(loc));
        }
        let points = read_geometry(&file, options)?.positions().to_vec();
        views.push(View {
            name,
            file,
            translation: [nums[0], nums[1], nums[2]],
            rotation: q.map(|v| v / len),
            point_count: points.len(),
            points,
        });
    }
    if views.is_empty() {
        return Err(Error::new(ErrorCode::InputNoGeometry, "the scan set lists no views (`bmesh` lines)").in_file(path));
    }
    Ok(views)
}

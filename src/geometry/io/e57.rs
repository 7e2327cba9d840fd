//! E57 (ASTM E2807), the scanner exchange format, read as a scan set: each point cloud of the file is a view,
//! its points in the scanner's own frame (the scanner at the origin), its pose the cloud's `pose` (rotation
//! quaternion and translation, local → file frame). Read through the `e57` crate, which checks every page's
//! CRC-32C as it reads; cartesian or spherical coordinates (converted), invalid points skipped and counted.
//!
//! Checked before reading points: the file size against `max_input_size`, each cloud's declared point count
//! against the file's size (`input.absurd-count`) and the total against the memory budget
//! (`resource.memory`, 12 bytes per point). A truncated file, a bad checksum page or malformed XML is
//! `input.bad-record` with the crate's message.

use std::path::Path;

use super::view::{MAX_VIEWS, View};
use crate::error::{Error, ErrorCode, Result};
use crate::geometry::io::ReadOptions;
use crate::geometry::pose::Pose;

/// Bytes per point held: position as 3 × f32.
pub const BYTES_PER_POINT: u64 = 12;

/// Most points a cloud may declare per byte of the file: the smallest useful record (three scaled
/// integers bit-packed) still takes more than a byte per point, so 8 per byte is absurd by far.
pub const MAX_POINTS_PER_BYTE: u64 = 8;

/// Whether `path` names an E57 file (by extension).
pub fn is_e57(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("e57"))
}

fn bad(e: impl std::fmt::Display) -> Error {
    Error::new(ErrorCode::InputBadRecord, format!("E57: {e}"))
}

/// Read every point cloud of an E57 file as a view with its pose.
///
/// # Errors
/// `input.not-found`/`input.io` when it cannot be opened; `input.too-large` over `max_input_size`;
/// `input.bad-record` for a damaged file (truncated, bad checksum, malformed XML or binary section);
/// `input.absurd-count` for a point count the file cannot hold; `resource.memory` when the points do not
/// fit the budget; `input.no-geometry` for a file without points (or only invalid ones).
pub fn read_e57(path: &Path, options: &ReadOptions) -> Result<Vec<View>> {
    let inner = || -> Result<Vec<View>> {
        let meta = std::fs::metadata(path).map_err(|e| {
            let code =
                if e.kind() == std::io::ErrorKind::NotFound { ErrorCode::InputNotFound } else { ErrorCode::InputIo };
            Error::new(code, e.to_string())
        })?;
        if meta.len() > options.max_input_size {
            return Err(Error::new(
                ErrorCode::InputTooLarge,
                format!("{} bytes exceed the input limit of {} bytes", meta.len(), options.max_input_size),
            ));
        }
        // 1. The XML section: the clouds, their counts and poses.
        let mut reader = e57::E57Reader::from_file(path).map_err(bad)?;
        let clouds = reader.pointclouds();
        if clouds.len() > MAX_VIEWS {
            return Err(bad(format!("{} point clouds; at most {MAX_VIEWS}", clouds.len())));
        }
        let mut total: u64 = 0;
        for (k, pc) in clouds.iter().enumerate() {
            if pc.records > MAX_POINTS_PER_BYTE.saturating_mul(meta.len()) {
                return Err(Error::new(
                    ErrorCode::InputAbsurdCount,
                    format!("point cloud {k} declares {} points in a file of {} bytes", pc.records, meta.len()),
                ));
            }
            total = total.saturating_add(pc.records);
        }
        let need = total.saturating_mul(BYTES_PER_POINT);
        if need > options.memory_budget {
            return Err(Error::new(
                ErrorCode::ResourceMemoryBudget,
                format!("{total} points need {} MiB; the budget is {} MiB", need >> 20, options.memory_budget >> 20),
            ));
        }
        // 2. Each cloud's points in its own frame, and its pose.
        let mut views: Vec<View> = Vec::with_capacity(clouds.len());
        for (k, pc) in clouds.iter().enumerate() {
            let pose = match &pc.transform {
                None => Pose::IDENTITY,
                Some(t) => {
                    let (q, tr) = (&t.rotation, &t.translation);
                    Pose::from_quaternion([tr.x, tr.y, tr.z], [q.x, q.y, q.z, q.w])
                        .map_err(|m| bad(format!("point cloud {k}: {m}")))?
                }
            };
            let mut it = reader.pointcloud_simple(pc).map_err(bad)?;
            it.apply_pose(false);
            it.spherical_to_cartesian(true);
            let mut points = Vec::with_capacity(pc.records as usize);
            for p in it {
                let p = p.map_err(|e| bad(format!("point cloud {k}: {e}")))?;
                if let e57::CartesianCoordinate::Valid { x, y, z } = p.cartesian {
                    let q = [x as f32, y as f32, z as f32];
                    if q.iter().all(|c| c.is_finite()) {
                        points.push(q);
                    }
                }
            }
            let base = pc.name.clone().or_else(|| pc.guid.clone()).unwrap_or_else(|| format!("scan{k}"));
            let name = if views.iter().any(|v| v.name == base) { format!("{base}#{k}") } else { base };
            views.push(View {
                name,
                file: path.to_path_buf(),
                pose,
                point_count: points.len(),
                points,
                scanner: Some([0.0; 3]),
                pass: 1,
                table_frame: false,
            });
        }
        if views.iter().all(|v| v.points.is_empty()) {
            return Err(Error::new(ErrorCode::InputNoGeometry, "the E57 file holds no valid points"));
        }
        views.retain(|v| !v.points.is_empty());
        Ok(views)
    };
    // The crate is pure safe Rust, but a damaged file must not take the daemon down should it panic.
    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(inner))
        .unwrap_or_else(|_| Err(bad("the reader failed on this file (damaged)")));
    result.map_err(|e| e.in_file(path))
}

/// Write `views` (points in their own frames, with their poses) as an E57 file, one point cloud per view
/// (single-precision cartesian coordinates). For tests and for exchanging the station's scans.
///
/// # Errors
/// `resource.output` when the file cannot be written.
pub fn write_e57(path: &Path, views: &[(String, Pose, Vec<[f32; 3]>)]) -> Result<()> {
    let out = |e: e57::Error| Error::new(ErrorCode::ResourceOutput, format!("E57: {e}")).in_file(path);
    let mut w = e57::E57Writer::from_file(path, "scanstation").map_err(out)?;
    for (k, (name, pose, points)) in views.iter().enumerate() {
        let proto = vec![e57::Record::CARTESIAN_X_F32, e57::Record::CARTESIAN_Y_F32, e57::Record::CARTESIAN_Z_F32];
        let mut pc = w.add_pointcloud(&format!("scanstation-view-{k}"), proto).map_err(out)?;
        pc.set_name(Some(name.clone()));
        let q = pose.quaternion();
        pc.set_transform(Some(e57::Transform {
            rotation: e57::Quaternion { w: q[3], x: q[0], y: q[1], z: q[2] },
            translation: e57::Translation { x: pose.translation[0], y: pose.translation[1], z: pose.translation[2] },
        }));
        for p in points {
            pc.add_point(p.iter().map(|&c| e57::RecordValue::Single(c)).collect()).map_err(out)?;
        }
        pc.finalize().map_err(out)?;
    }
    w.finalize().map_err(out)
}

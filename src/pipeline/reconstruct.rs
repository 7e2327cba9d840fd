//! `scanstation reconstruct`: a point cloud (or a mesh's vertices) to a closed mesh, measured against the
//! points both ways.

use std::path::{Path, PathBuf};

use crate::error::{Error, ErrorCode, Result};
use crate::geometry::io::{ReadOptions, ensure_not_input, ensure_replaceable, read_geometry};
use crate::geometry::mesh::{Geometry, PointCloud, PolyMesh, TriMesh};
use crate::stages::Progress;
use crate::stages::quality::{CompareOptions, DistanceReport, compare};
use crate::stages::reconstruct::fusion::{FuseOptions, FusionReport};
use crate::stages::reconstruct::{ReconstructOptions, ReconstructReport, reconstruct};

/// What `scanstation reconstruct` reports.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ReconstructFileReport {
    /// Input path.
    pub input_file: PathBuf,
    /// Output path.
    pub output_file: PathBuf,
    /// For a scan set: how its views were fused.
    pub fusion: Option<FusionReport>,
    /// The stage's report.
    pub reconstruct: ReconstructReport,
    /// Distance of the result (TEST) to the input points (REFERENCE): `reference_to_test` is the accuracy
    /// (points to surface), `test_to_reference` the invented surface (surface to points).
    pub distance: DistanceReport,
}

/// Read a mesh, a cloud, or a scan set (`.conf`: its views fused by their poses, normals toward each
/// scanner; [`crate::stages::reconstruct::fusion`]).
///
/// # Errors
/// The readers' errors; those of [`read_scan_set`](crate::geometry::io::scanset::read_scan_set) and
/// [`fuse`](crate::stages::reconstruct::fusion::fuse).
pub fn read_input(path: &Path, read: &ReadOptions, fuse: &FuseOptions) -> Result<(Geometry, Option<FusionReport>)> {
    // A directory is read as a scan set (one without a manifest is refused by name).
    if crate::geometry::io::scanset::is_scan_set(path) || path.is_dir() {
        let views = crate::geometry::io::scanset::read_scan_set(path, read)?;
        let (cloud, report) = crate::stages::reconstruct::fusion::fuse(&views, fuse).map_err(|e| e.in_file(path))?;
        return Ok((Geometry::Cloud(cloud), Some(report)));
    }
    Ok((read_geometry(path, read)?, None))
}

/// Reference points a result is measured against at most: a larger cloud is measured against every k-th point
/// (in file order), which leaves the RMS within sampling noise and keeps the measurement's index small (a
/// 10-million-point cloud would need 600 MB for it). Fewer where a quarter of the budget the input leaves
/// cannot hold them at [`MEASURE_BYTES_PER_POINT`].
pub const MEASURE_POINTS: usize = 1_000_000;

/// Bytes per reference point of the measurement: its copy and its share of the comparison's index.
pub const MEASURE_BYTES_PER_POINT: u64 = 12 + 60;

/// Reconstruct the points of `input` (a cloud, or a mesh's vertices without normals) and measure the result
/// against them: `reference_to_test` is the accuracy, `test_to_reference` the invented surface. A cloud of more
/// than [`MEASURE_POINTS`] points is measured against every k-th point.
///
/// # Errors
/// As [`reconstruct`] and [`compare`].
pub fn reconstruct_measured(
    input: &Geometry,
    opts: &ReconstructOptions,
    cmp: &CompareOptions,
    progress: &dyn Progress,
) -> Result<(TriMesh, ReconstructReport, DistanceReport)> {
    let vertices;
    let cloud = match input {
        Geometry::Cloud(c) => c,
        Geometry::Mesh(m) => {
            vertices = PointCloud::new(m.positions.clone(), None, None)?;
            &vertices
        }
    };
    let (mesh, report) = reconstruct(cloud, opts, progress)?;
    let room = opts.memory_budget.saturating_sub(cloud.heap_bytes()) / 4 / MEASURE_BYTES_PER_POINT;
    let most = (room.min(MEASURE_POINTS as u64) as usize).max(1);
    let stride = cloud.positions.len().div_ceil(most).max(1);
    let reference = PointCloud {
        positions: cloud.positions.iter().step_by(stride).copied().collect(),
        normals: None,
        colors: None,
    };
    let distance = compare(
        &Geometry::Mesh(PolyMesh::from(mesh.clone())),
        &Geometry::Cloud(reference),
        cmp,
        &crate::stages::NoProgress,
    )?;
    Ok((mesh, report, distance))
}

/// Read a cloud (PLY, XYZ/PTS, OBJ/OFF without faces; a mesh's vertices too), reconstruct a closed mesh,
/// write it as binary PLY (or OBJ by extension), measured against the points.
///
/// # Errors
/// Reader errors; those of [`reconstruct`]; `resource.output` when the output names the input or cannot be
/// written (checked before any work).
pub fn reconstruct_file(
    input: &Path,
    output: &Path,
    read: &ReadOptions,
    opts: &ReconstructOptions,
    progress: &dyn Progress,
) -> Result<ReconstructFileReport> {
    ensure_not_input(output, &[input])?;
    ensure_replaceable(output)?;
    let (geometry, fusion) = read_input(input, read, &opts.fusion)?;
    let cmp = CompareOptions { memory_budget: opts.memory_budget, ..Default::default() };
    let (mesh, report, distance) =
        reconstruct_measured(&geometry, opts, &cmp, progress).map_err(|e| e.in_file(input))?;
    if mesh.triangles.is_empty() {
        return Err(Error::new(ErrorCode::ReconstructFailed, "the result is empty").in_file(input));
    }
    super::write_mesh(output, &PolyMesh::from(mesh), "reconstructed by scanstation")?;
    Ok(ReconstructFileReport {
        input_file: input.to_path_buf(),
        output_file: output.to_path_buf(),
        fusion,
        reconstruct: report,
        distance,
    })
}

//! `scanstation reconstruct`: a point cloud (or a mesh's vertices) to a closed mesh, measured against the
//! points both ways.

use std::path::{Path, PathBuf};

use crate::error::{Error, ErrorCode, Result};
use crate::geometry::io::{ReadOptions, ensure_not_input, ensure_replaceable, read_geometry};
use crate::geometry::mesh::{Geometry, PointCloud, PolyMesh, TriMesh};
use crate::stages::Progress;
use crate::stages::quality::{CompareOptions, DistanceReport, compare};
use crate::stages::reconstruct::{ReconstructOptions, ReconstructReport, reconstruct};

/// What `scanstation reconstruct` reports.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ReconstructFileReport {
    /// Input path.
    pub input_file: PathBuf,
    /// Output path.
    pub output_file: PathBuf,
    /// The stage's report.
    pub reconstruct: ReconstructReport,
    /// Distance of the result (TEST) to the input points (REFERENCE): `reference_to_test` is the accuracy
    /// (points to surface), `test_to_reference` the invented surface (surface to points).
    pub distance: DistanceReport,
}

/// The points of `g`: a cloud as it is, a mesh's vertices without normals.
pub fn cloud_of(g: &Geometry) -> Result<PointCloud> {
    match g {
        Geometry::Cloud(c) => Ok(c.clone()),
        Geometry::Mesh(m) => PointCloud::new(m.positions.clone(), None, None),
    }
}

/// Reconstruct `cloud` and measure the result against it (`samples` per side).
///
/// # Errors
/// As [`reconstruct`] and [`compare`].
pub fn reconstruct_measured(
    cloud: &PointCloud,
    opts: &ReconstructOptions,
    cmp: &CompareOptions,
    progress: &dyn Progress,
) -> Result<(TriMesh, ReconstructReport, DistanceReport)> {
    let (mesh, report) = reconstruct(cloud, opts, progress)?;
    let distance = compare(
        &Geometry::Mesh(PolyMesh::from(mesh.clone())),
        &Geometry::Cloud(cloud.clone()),
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
    let cloud = cloud_of(&read_geometry(input, read)?)?;
    let cmp = CompareOptions { memory_budget: opts.memory_budget, ..Default::default() };
    let (mesh, report, distance) = reconstruct_measured(&cloud, opts, &cmp, progress).map_err(|e| e.in_file(input))?;
    if mesh.triangles.is_empty() {
        return Err(Error::new(ErrorCode::ReconstructFailed, "the result is empty").in_file(input));
    }
    super::write_mesh(output, &PolyMesh::from(mesh), "reconstructed by scanstation")?;
    Ok(ReconstructFileReport {
        input_file: input.to_path_buf(),
        output_file: output.to_path_buf(),
        reconstruct: report,
        distance,
    })
}

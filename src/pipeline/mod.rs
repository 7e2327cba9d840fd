//! **Pipeline** — runs stages on files and assembles their reports and artifacts. This is the layer the
//! CLI and the daemon call (the daemon reaches the stages only through it); it owns file handling, timing
//! and the shape of the reports.
//!
//! Inspection ([`inspect_file`]), the quality comparison of two files ([`compare_files`]), single stages on
//! files ([`repair_file`], [`remesh_file`]), reconstruction of clouds and scan sets ([`reconstruct_file`]),
//! the whole chain to a STEP solid ([`convert_file`], and [`convert_held`] handing back what it held), and
//! the FEA on a solid ([`fea`]).

mod checks;
pub mod convert;
pub mod far_tail;
pub mod fea;
pub mod gates;
pub mod goal;
pub mod memory;
pub mod next_view;
pub mod open_input;
pub mod pictures;
pub mod provenance;
pub mod reconstruct;
pub mod refine;
pub mod render;
pub mod report_html;
pub mod resolution;
mod solid_mesh;

/// What the daemon needs of the stages, through the pipeline: the progress sink every long step reports to,
/// its cancellation check, and the FEA's settings.
pub use crate::stages::{Progress, check_cancelled, fea::FeaOptions};
pub use convert::{
    ConvertOptions, ConvertReport, Converted, Resolution, convert_file, convert_held, small_handle_loop,
};
pub use gates::{Gate, GateOptions, Status};
pub use reconstruct::{ReconstructFileReport, reconstruct_file};

use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::error::Result;
use crate::geometry::io::{ReadOptions, ensure_not_input, read_geometry};
use crate::geometry::mesh::Geometry;
use crate::geometry::topology::TopologyReport;
use crate::geometry::vec3::Aabb;
use crate::stages::quality::{CompareOptions, DistanceReport, compare, write_error_map};

/// Summary of a point cloud (the mesh counterpart is [`TopologyReport`]).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct CloudSummary {
    /// Points.
    pub vertices: usize,
    /// Always 0.
    pub faces: usize,
    /// The file carries normals.
    pub has_normals: bool,
    /// The file carries colours.
    pub has_colors: bool,
    /// Bounding box.
    pub bbox: Aabb,
    /// Its diagonal.
    pub bbox_diagonal: f64,
}

/// What `scanstation inspect` reports: the file, its kind, and the mesh topology or cloud summary (their
/// keys appear at the top level of the JSON).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct InspectReport {
    /// The file read.
    pub file: PathBuf,
    /// `mesh` or `point_cloud`.
    pub kind: &'static str,
    /// Mesh figures.
    #[serde(flatten)]
    pub mesh: Option<TopologyReport>,
    /// Cloud figures.
    #[serde(flatten)]
    pub cloud: Option<CloudSummary>,
    /// For a scan set (`.conf`): its views with their points and poses (the cloud figures are then the
    /// views placed in the common frame).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub views: Option<Vec<crate::geometry::io::scanset::View>>,
    /// Seconds to read the file.
    pub read_seconds: f64,
    /// Seconds to analyse it.
    pub analyse_seconds: f64,
}

/// Describe a geometry.
pub fn inspect(geometry: &Geometry) -> (Option<TopologyReport>, Option<CloudSummary>) {
    match geometry {
        Geometry::Mesh(m) => (Some(TopologyReport::compute(m)), None),
        Geometry::Cloud(c) => {
            let bbox = c.bbox();
            (
                None,
                Some(CloudSummary {
                    vertices: c.positions.len(),
                    faces: 0,
                    has_normals: c.normals.is_some(),
                    has_colors: c.colors.is_some(),
                    bbox,
                    bbox_diagonal: bbox.diagonal(),
                }),
            )
        }
    }
}

/// Read `path` and inspect it.
///
/// # Errors
/// Any reader error (`input.*`, `resource.memory`).
pub fn inspect_file(path: &Path, options: &ReadOptions) -> Result<InspectReport> {
    let t0 = Instant::now();
    let (g, views) = if crate::geometry::io::scanset::is_scan_set(path) {
        let views = crate::geometry::io::scanset::read_scan_set(path, options)?;
        let placed: Vec<[f32; 3]> = views.iter().flat_map(|v| v.placed()).collect();
        (Geometry::Cloud(crate::geometry::mesh::PointCloud::new(placed, None, None)?), Some(views))
    } else {
        (read_geometry(path, options)?, None)
    };
    let read_seconds = t0.elapsed().as_secs_f64();
    let t1 = Instant::now();
    let (mesh, cloud) = inspect(&g);
    Ok(InspectReport {
        file: path.to_path_buf(),
        kind: if views.is_some() { "scan_set" } else { g.kind() },
        views,
        mesh,
        cloud,
        read_seconds,
        analyse_seconds: t1.elapsed().as_secs_f64(),
    })
}

/// One input of a comparison.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct InputSummary {
    /// Path.
    pub file: PathBuf,
    /// `mesh` or `point_cloud`.
    pub kind: &'static str,
    /// Vertices or points.
    pub vertices: usize,
    /// Faces (0 for a cloud).
    pub faces: usize,
}

impl InputSummary {
    fn of(path: &Path, g: &Geometry) -> Self {
        let faces = match g {
            Geometry::Mesh(m) => m.face_count(),
            Geometry::Cloud(_) => 0,
        };
        InputSummary { file: path.to_path_buf(), kind: g.kind(), vertices: g.positions().len(), faces }
    }
}

/// What `scanstation compare` reports.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct CompareReport {
    /// The measured surface.
    pub test: InputSummary,
    /// The surface measured against.
    pub reference: InputSummary,
    /// The distances.
    #[serde(flatten)]
    pub distance: DistanceReport,
    /// The error map written, if asked for.
    pub error_map: Option<PathBuf>,
    /// Top of the error map's colour scale (input units).
    pub error_map_scale: Option<f64>,
    /// Seconds to read both inputs.
    pub read_seconds: f64,
    /// Seconds to compare (and write the error map).
    pub compare_seconds: f64,
}

/// Read two files and measure their two-sided distance; optionally write an error map of TEST.
///
/// # Errors
/// Reader errors, [`compare`]'s errors, `resource.output` when the error map cannot be written or would
/// overwrite an input.
pub fn compare_files(
    test: &Path,
    reference: &Path,
    read: &ReadOptions,
    opts: &CompareOptions,
    error_map: Option<&Path>,
    progress: &dyn Progress,
) -> Result<CompareReport> {
    if let Some(out) = error_map {
        ensure_not_input(out, &[test, reference])?;
        crate::geometry::io::ensure_replaceable(out)?;
    }
    let t0 = Instant::now();
    let (a, b) = rayon::join(|| read_geometry(test, read), || read_geometry(reference, read));
    let (a, b) = (a?, b?);
    let read_seconds = t0.elapsed().as_secs_f64();
    let t1 = Instant::now();
    let distance = compare(&a, &b, opts, progress)?;
    let scale = error_map.map(|out| write_error_map(out, &a, &b, None).map(|m| m.scale)).transpose()?;
    Ok(CompareReport {
        test: InputSummary::of(test, &a),
        reference: InputSummary::of(reference, &b),
        distance,
        error_map: error_map.map(Path::to_path_buf),
        error_map_scale: scale,
        read_seconds,
        compare_seconds: t1.elapsed().as_secs_f64(),
    })
}

/// What `scanstation repair` reports.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct RepairFileReport {
    /// Input path.
    pub input_file: PathBuf,
    /// Output path.
    pub output_file: PathBuf,
    /// The stage's report.
    #[serde(flatten)]
    pub repair: crate::stages::repair::RepairReport,
}

/// Read a mesh, repair it and write the result (`.obj` as OBJ, anything else as binary PLY).
///
/// # Errors
/// Reader errors; `input.no-geometry` for a point cloud; `repair.failed`; `resource.output` when the output
/// cannot be written or names the input.
pub fn repair_file(
    input: &Path,
    output: &Path,
    read: &ReadOptions,
    opts: &crate::stages::repair::RepairOptions,
    progress: &dyn Progress,
) -> Result<RepairFileReport> {
    ensure_not_input(output, &[input])?;
    crate::geometry::io::ensure_replaceable(output)?;
    let mesh = crate::geometry::io::read_mesh(input, read)?;
    let (out, report) = crate::stages::repair::repair(&mesh, opts, progress).map_err(|e| e.in_file(input))?;
    write_mesh(output, &crate::geometry::mesh::PolyMesh::from(out), "repaired by scanstation")?;
    Ok(RepairFileReport { input_file: input.to_path_buf(), output_file: output.to_path_buf(), repair: report })
}

/// Write `mesh` as OBJ when `output` ends in `.obj` (polygons kept), else as binary PLY with `comment`.
pub(crate) fn write_mesh(
    output: &Path,
    mesh: &crate::geometry::mesh::PolyMesh,
    comment: &str,
) -> Result<crate::geometry::io::FileDigest> {
    if output.extension().is_some_and(|e| e.eq_ignore_ascii_case("obj")) {
        crate::geometry::io::write_obj(output, mesh)
    } else {
        crate::geometry::io::write_ply(output, mesh, &Default::default(), &[comment])
    }
}

/// What `scanstation remesh` reports.
#[derive(Clone, Debug, serde::Serialize)]
pub struct RemeshFileReport {
    /// Input path.
    pub input_file: PathBuf,
    /// Output path.
    pub output_file: PathBuf,
    /// The stage's report.
    #[serde(flatten)]
    pub remesh: crate::stages::remesh::RemeshReport,
}

/// Read a closed mesh (polygons are fan-triangulated), remesh it into pure quads and write OBJ (`.obj`) or
/// binary PLY.
///
/// # Errors
/// Reader errors; `input.no-geometry` for a point cloud; `remesh.input-not-closed`; `remesh.failed`;
/// `resource.output` when the output cannot be written or names the input.
pub fn remesh_file(
    input: &Path,
    output: &Path,
    read: &ReadOptions,
    opts: &crate::stages::remesh::RemeshOptions,
    progress: &dyn Progress,
) -> Result<RemeshFileReport> {
    ensure_not_input(output, &[input])?;
    crate::geometry::io::ensure_replaceable(output)?;
    let mesh = crate::geometry::io::read_mesh(input, read)?;
    let (tri, _) = mesh.triangulate();
    let (out, report) = crate::stages::remesh::remesh(&tri, opts, progress).map_err(|e| e.in_file(input))?;
    write_mesh(output, &out, "remeshed by scanstation")?;
    Ok(RemeshFileReport { input_file: input.to_path_buf(), output_file: output.to_path_buf(), remesh: report })
}

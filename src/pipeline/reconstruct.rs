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
    let (geometry, fused) = read_input_views(path, read, fuse)?;
    Ok((geometry, fused.map(|f| f.report)))
}

/// A scan set's fusion: its report and the views it fused (their points in their own frames; placed by the
/// report's `poses`).
pub struct Fused {
    /// How the views were fused.
    pub report: FusionReport,
    /// The views as read.
    pub views: Vec<crate::geometry::io::scanset::View>,
}

/// As [`read_input`], keeping a scan set's views (for what is measured on them later: their coverage of the
/// solid), so that no view file is read twice.
///
/// # Errors
/// As [`read_input`].
pub fn read_input_views(path: &Path, read: &ReadOptions, fuse: &FuseOptions) -> Result<(Geometry, Option<Fused>)> {
    // A directory is read as a scan set (one without a manifest is refused by name).
    if crate::geometry::io::scanset::is_scan_set(path) || path.is_dir() {
        let views = crate::geometry::io::scanset::read_scan_set(path, read)?;
        let (cloud, report) = crate::stages::reconstruct::fusion::fuse(&views, fuse).map_err(|e| e.in_file(path))?;
        return Ok((Geometry::Cloud(cloud), Some(Fused { report, views })));
    }
    Ok((read_geometry(path, read)?, None))
}

/// Check that the view file at `path` holds the `expect` points its scanner announced, reading it once; its
/// size and SHA-256 from that read (for the bundle's manifest, so the file is not read again to hash it).
///
/// # Errors
/// `input.io` when it is unreadable or holds another number of points (the message names both counts).
pub fn check_view(path: &Path, expect: u32, read: &ReadOptions) -> Result<crate::geometry::io::FileDigest> {
    let (geometry, digest) = crate::geometry::io::read_geometry_digest(path, read)
        .map_err(|e| Error::new(ErrorCode::InputIo, format!("the view {} is unreadable: {e}", path.display())))?;
    let count = geometry.positions().len();
    if count != expect as usize {
        return Err(Error::new(
            ErrorCode::InputIo,
            format!("the view {} holds {count} points, the scanner announced {expect}", path.display()),
        ));
    }
    Ok(digest)
}

/// [`view_coverage`] of a converted scan's solid by the views fusion kept (a rejected view saw nothing the
/// solid was built from).
pub fn fused_coverage(solid: &TriMesh, fused: &Fused) -> ViewCoverage {
    let f = &fused.report;
    view_coverage(solid, fused.views.iter().zip(&f.poses).filter(|(v, _)| !f.rejected.contains(&v.name)))
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

/// How much of a surface the views of a scan saw ([`view_coverage`]).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct ViewCoverage {
    /// Share of the surface's area (0–1) within `radius` of a point of some view.
    pub share: f64,
    /// The reach that counts as seen: [`COVERAGE_SPACINGS`] × `spacing`.
    pub radius: f64,
    /// The views' median point spacing (each view's median distance to its nearest neighbour; their median).
    pub spacing: f64,
    /// Points of the views measured.
    pub points: usize,
}

/// A surface point counts as seen when a view's point lies within this many point spacings: a hole in one
/// view's sampling is covered, a surface no view reached (a base on the table, a deep cavity) is not.
pub const COVERAGE_SPACINGS: f64 = 3.0;

/// Which share of `surface` the views saw (each with its pose into the surface's frame): area-weighted over the
/// surface's triangles, each seen when a view's point lies within [`COVERAGE_SPACINGS`] point spacings of
/// its centroid (triangles much smaller than the spacing, as a solid's tessellation has, make this the area
/// share). Cost: O(N) to index the N points, O(F) lookups.
pub fn view_coverage<'a>(
    surface: &TriMesh,
    placed_views: impl IntoIterator<Item = (&'a crate::geometry::io::scanset::View, &'a crate::geometry::pose::Pose)>,
) -> ViewCoverage {
    use crate::geometry::points::PointIndex;
    use crate::geometry::vec3::{add, scale};
    let (placed, spacing) = placed_and_spacing(placed_views);
    let all: Vec<[f32; 3]> = placed.concat();
    let radius = COVERAGE_SPACINGS * spacing;
    let index = PointIndex::new(&all, 4.0);
    let (mut seen, mut total) = (0.0, 0.0);
    for t in 0..surface.triangles.len() {
        let a = surface.triangle_area(t);
        let [p, q, r] = surface.corners(t);
        let c = scale(add(add(p, q), r), 1.0 / 3.0);
        total += a;
        if !all.is_empty() && index.nearest_within(c, radius).is_some() {
            seen += a;
        }
    }
    ViewCoverage { share: if total > 0.0 { seen / total } else { 0.0 }, radius, spacing, points: all.len() }
}

/// Each view with at least two points, placed by its pose, and the views' median point spacing (each
/// view's median distance to its nearest neighbour, over every 500th point at most; their median).
fn placed_and_spacing<'a>(
    placed_views: impl IntoIterator<Item = (&'a crate::geometry::io::scanset::View, &'a crate::geometry::pose::Pose)>,
) -> (Vec<Vec<[f32; 3]>>, f64) {
    use crate::geometry::points::PointIndex;
    use crate::geometry::vec3::wide;
    let mut spacings = Vec::new();
    let mut placed = Vec::new();
    let mut out = Vec::new();
    for (v, pose) in placed_views {
        if v.points.len() < 2 {
            continue;
        }
        let index = PointIndex::new(&v.points, 4.0);
        let step = (v.points.len() / 500).max(1);
        let mut d: Vec<f64> = v
            .points
            .iter()
            .step_by(step)
            .filter_map(|&p| {
                index.knn(wide(p), 2, &mut out);
                out.get(1).map(|x| x.1.sqrt())
            })
            .collect();
        d.sort_by(f64::total_cmp);
        if let Some(&m) = d.get(d.len() / 2) {
            spacings.push(m);
        }
        placed.push(crate::geometry::io::scanset::placed(&v.points, pose));
    }
    spacings.sort_by(f64::total_cmp);
    (placed, spacings.get(spacings.len() / 2).copied().unwrap_or(0.0))
}

/// Which surface of a scan's solid the views saw: per vertex, how many kept views saw it, and what no view
/// saw ([`seen_by_views`]).
#[derive(Clone, Debug)]
pub struct SeenBy {
    /// Per vertex of the solid: the kept views that saw it.
    pub counts: Vec<u16>,
    /// The kept views.
    pub views: u16,
    /// The surface no view saw.
    pub unseen: UnseenSurface,
}

impl SeenBy {
    /// Per vertex: no view saw it (surface the reconstruction invented).
    pub fn unseen_vertices(&self) -> Vec<bool> {
        self.counts.iter().map(|&n| n == 0).collect()
    }
}

/// The surface of a scan's solid that no view saw: a triangle is unseen when no view saw any of its corners.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct UnseenSurface {
    /// Its share of the solid's area (0–1).
    pub share: f64,
    /// Its area, model units².
    pub area: f64,
    /// Edge-connected patches of it.
    pub patches: usize,
    /// The largest patch's area, model units².
    pub largest_patch_area: f64,
    /// The largest patch's share of the solid's area (0–1).
    pub largest_patch_share: f64,
    /// The largest patch's centroid (area-weighted), model units.
    pub largest_patch_at: Option<[f64; 3]>,
}

/// [`fused_seen_by`] with the unseen surface measured ([`unseen_surface`]).
pub fn seen_by_views(solid: &TriMesh, fused: &Fused) -> SeenBy {
    let (counts, views) = fused_seen_by(solid, fused);
    let unseen = unseen_surface(solid, &counts);
    SeenBy { counts, views, unseen }
}

/// The unseen surface of `solid` (`counts`: per vertex, the views that saw it): a triangle is unseen when
/// all its corners are; patches join unseen triangles across shared edges. Cost: O(F α(F)).
pub fn unseen_surface(solid: &TriMesh, counts: &[u16]) -> UnseenSurface {
    use crate::geometry::topology::UnionFind;
    let unseen = |t: usize| solid.triangles[t].iter().all(|&v| counts.get(v as usize).is_some_and(|&n| n == 0));
    let n = solid.triangles.len();
    let mut uf = UnionFind::new(n);
    let mut by_edge: std::collections::HashMap<(u32, u32), u32> = std::collections::HashMap::new();
    let mut total = 0.0;
    for t in 0..n {
        total += solid.triangle_area(t);
        if !unseen(t) {
            continue;
        }
        let [a, b, c] = solid.triangles[t];
        for (u, v) in [(a, b), (b, c), (c, a)] {
            match by_edge.entry((u.min(v), u.max(v))) {
                std::collections::hash_map::Entry::Occupied(o) => uf.union(*o.get(), t as u32),
                std::collections::hash_map::Entry::Vacant(e) => {
                    e.insert(t as u32);
                }
            }
        }
    }
    // Area and area-weighted centroid per patch root, in triangle order (deterministic).
    let mut patches: std::collections::BTreeMap<u32, (f64, [f64; 3])> = std::collections::BTreeMap::new();
    for t in (0..n).filter(|&t| unseen(t)) {
        let a = solid.triangle_area(t);
        let [p, q, r] = solid.corners(t);
        let e = patches.entry(uf.find(t as u32)).or_insert((0.0, [0.0; 3]));
        e.0 += a;
        for k in 0..3 {
            e.1[k] += a * (p[k] + q[k] + r[k]) / 3.0;
        }
    }
    let area: f64 = patches.values().map(|p| p.0).sum();
    let largest = patches.values().copied().max_by(|x, y| x.0.total_cmp(&y.0));
    let share = |a: f64| if total > 0.0 { a / total } else { 0.0 };
    UnseenSurface {
        share: share(area),
        area,
        patches: patches.len(),
        largest_patch_area: largest.map_or(0.0, |l| l.0),
        largest_patch_share: share(largest.map_or(0.0, |l| l.0)),
        largest_patch_at: largest.filter(|l| l.0 > 0.0).map(|l| l.1.map(|c| c / l.0)),
    }
}

/// How many of a converted scan's kept views saw each vertex of `solid` (a view's point within
/// [`COVERAGE_SPACINGS`] point spacings of it), and how many views were kept: the coverage picture's data.
/// Cost: O(N) to index each view's points, O(V) lookups per view (in parallel over the vertices).
pub fn fused_seen_by(solid: &TriMesh, fused: &Fused) -> (Vec<u16>, u16) {
    seen_within(solid, fused, COVERAGE_SPACINGS)
}

/// [`fused_seen_by`] with a view's point within `spacings` point spacings counting as seen (a smaller reach
/// asks for denser sampling).
pub fn seen_within(solid: &TriMesh, fused: &Fused, spacings: f64) -> (Vec<u16>, u16) {
    use crate::geometry::points::PointIndex;
    use crate::geometry::vec3::wide;
    use rayon::prelude::*;
    let f = &fused.report;
    let kept = fused.views.iter().zip(&f.poses).filter(|(v, _)| !f.rejected.contains(&v.name));
    let (placed, spacing) = placed_and_spacing(kept);
    let radius = spacings * spacing;
    let indices: Vec<PointIndex> = placed.iter().map(|p| PointIndex::new(p, 4.0)).collect();
    let counts = solid
        .positions
        .par_iter()
        .map(|&p| indices.iter().filter(|ix| ix.nearest_within(wide(p), radius).is_some()).count() as u16)
        .collect();
    (counts, placed.len() as u16)
}

/// What one view added to a scan's solid ([`view_gains`]).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct ViewGain {
    /// The view's file, as the scan set names it.
    pub name: String,
    /// The share of the solid's area this view saw first, the views taken in the scan set's order (0–1).
    pub gain: f64,
    /// The share of the solid's area only this view saw (0–1).
    pub unique: f64,
}

/// Each kept view's gain on `solid`: the area it saw first, in the scan set's order (the capture's), and the
/// area no other view saw; seen as [`fused_seen_by`] counts it (a point within [`COVERAGE_SPACINGS`]
/// spacings of a vertex, each vertex weighing a third of the triangles around it). Rejected views gain
/// nothing and are not listed. Cost: as [`fused_seen_by`].
pub fn view_gains(solid: &TriMesh, fused: &Fused) -> Vec<ViewGain> {
    use crate::geometry::points::PointIndex;
    use crate::geometry::vec3::wide;
    use rayon::prelude::*;
    let f = &fused.report;
    let kept: Vec<_> = fused.views.iter().zip(&f.poses).filter(|(v, _)| !f.rejected.contains(&v.name)).collect();
    let (_, spacing) = placed_and_spacing(kept.iter().copied());
    let radius = COVERAGE_SPACINGS * spacing;
    let placed: Vec<Vec<[f32; 3]>> =
        kept.iter().map(|(v, pose)| crate::geometry::io::scanset::placed(&v.points, pose)).collect();
    let indices: Vec<PointIndex> = placed.iter().map(|p| PointIndex::new(p, 4.0)).collect();
    let area = vertex_area_shares(solid);
    // Per vertex: the first view that saw it, and whether it was the only one.
    let seen: Vec<Option<(usize, bool)>> = solid
        .positions
        .par_iter()
        .map(|&p| {
            let mut who = indices.iter().enumerate().filter(|(_, ix)| ix.nearest_within(wide(p), radius).is_some());
            let first = who.next()?.0;
            Some((first, who.next().is_none()))
        })
        .collect();
    let mut out: Vec<ViewGain> =
        kept.iter().map(|(v, _)| ViewGain { name: v.name.clone(), gain: 0.0, unique: 0.0 }).collect();
    for (v, s) in seen.iter().enumerate() {
        if let Some((first, only)) = *s {
            let share = area[v];
            out[first].gain += share;
            if only {
                out[first].unique += share;
            }
        }
    }
    out
}

/// Per vertex of `mesh`, a third of the area of each triangle around it, as a share of the whole (summing to
/// 1; all zero for a mesh with no area).
pub fn vertex_area_shares(mesh: &TriMesh) -> Vec<f64> {
    let mut area = vec![0.0; mesh.positions.len()];
    let mut total = 0.0;
    for (t, tri) in mesh.triangles.iter().enumerate() {
        let a = mesh.triangle_area(t);
        total += a;
        for &v in tri {
            area[v as usize] += a / 3.0;
        }
    }
    if total > 0.0 {
        area.iter_mut().for_each(|a| *a /= total);
    }
    area
}

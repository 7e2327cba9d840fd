//! **Repair** — every scan becomes a closed, consistently outward-oriented 2-manifold triangle mesh.
//!
//! Steps, in the order they run, each reporting what it changed:
//!
//! 1. [`weld`]: merge vertices within `weld_rel × diagonal`, drop collapsed/duplicate faces and unreferenced
//!    vertices;
//! 2. [`manifold`]: make non-manifold edges and vertices manifold, orient faces consistently, keep the
//!    components that matter (largest by area, plus any of at least `keep_share` of the area);
//! 3. [`holes`]: fill every hole (Liepa: minimum-weight triangulation, refinement, thin-plate fairing);
//!    then, optionally ([`handles`], `max_handle_loop_rel` > 0), cut handles whose shortest non-separating
//!    loop is shorter than `max_handle_loop_rel × diagonal` (topological noise of range-scan fusion) and fill
//!    both sides;
//! 4. [`intersections`]: delete intersecting triangles with a growing neighbourhood and refill, until none
//!    remain (after the first filling, so that fills are checked too);
//! 5. [`smooth`]: move spike vertices to their ring centroid; optional Taubin λ|μ smoothing;
//! 6. [`decimate`](crate::geometry::decimate) (optional): quadric-error edge collapses to a target vertex count, refusing collapses that
//!    break the link condition or fold faces; then a self-intersection search and removal;
//! 7. orient outward (positive signed volume).
//!
//! The result is checked with the foundation's topology report and measured against the input with
//! `compare`.

pub mod caps;
pub mod handles;
pub mod holes;
pub mod intersections;
pub mod manifold;
pub mod smooth;
pub mod weld;

use std::time::Instant;

use crate::error::{Error, ErrorCode, Result};
use crate::geometry::decimate;
use crate::geometry::mesh::{Geometry, PolyMesh, TriMesh};
use crate::geometry::polygon;
use crate::geometry::tolerance::WELD_REL;
use crate::geometry::topology::TopologyReport;
use crate::geometry::vec3::{V3, wide};
use crate::stages::quality::{CompareOptions, DistanceReport, compare};
use crate::stages::{NoProgress, Progress};

/// Settings of the repair stage.
#[derive(Copy, Clone, Debug)]
pub struct RepairOptions {
    /// Weld tolerance as a fraction of the bounding-box diagonal.
    pub weld_rel: f64,
    /// Components other than the largest are kept when they hold at least this share of the area.
    pub keep_share: f64,
    /// Samples per side for the final distance measurement.
    pub compare_samples: usize,
    /// Seed of the final distance measurement's samples (`convert` passes its own, and reuses the figure).
    pub compare_seed: u64,
    /// Move spike vertices to their ring centroid.
    pub remove_spikes: bool,
    /// Taubin λ|μ smoothing iterations (0: none).
    pub smooth_iterations: usize,
    /// Decimate to this many vertices at the end (None: keep all).
    pub target_vertices: Option<usize>,
    /// Cut handles whose shortest non-separating loop is shorter than this fraction of the bounding-box
    /// diagonal, filling both sides ([`handles`]); 0: keep every handle. Off by default: a closed manifold
    /// keeps its topology unless asked. `convert` sets it from the quad spacing (a quad mesh cannot carry a
    /// tunnel narrower than a few quads anyway).
    pub max_handle_loop_rel: f64,
    /// Most bytes the stage may allocate (checked against an estimate before starting).
    pub memory_budget: u64,
}

/// Estimated peak bytes per input face (positions, adjacency tables, BVH, quadrics; measured ≈ 330 MiB for
/// the dragon's 871k faces).
const BYTES_PER_FACE: u64 = 420;

impl Default for RepairOptions {
    fn default() -> Self {
        RepairOptions {
            weld_rel: WELD_REL,
            keep_share: 0.1,
            compare_samples: 200_000,
            compare_seed: 0,
            remove_spikes: true,
            smooth_iterations: 0,
            target_vertices: None,
            max_handle_loop_rel: 0.0,
            memory_budget: 8 << 30,
        }
    }
}

/// Everything the repair stage did and measured.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct RepairReport {
    /// The input as it came.
    pub input: TopologyReport,
    /// Step 1.
    pub weld: weld::WeldReport,
    /// Steps 2–3.
    pub manifold: manifold::ManifoldReport,
    /// Step 5.
    pub holes: holes::HoleReport,
    /// Step 3b: topological noise removed (when `max_handle_loop_rel` > 0).
    pub handles: handles::HandleReport,
    /// Step 4 (run after the first filling, as MeshFix does, so refills are checked too).
    pub intersections: intersections::IntersectionReport,
    /// Step 6.
    pub smooth: smooth::SmoothReport,
    /// Step 7, when a target vertex count was given.
    pub decimate: Option<decimate::DecimateReport>,
    /// Self-intersections after decimation, removed as in step 4.
    pub decimate_intersections: Option<intersections::IntersectionReport>,
    /// Closed pieces the closing cut off beside the body (under `keep_share` of the area), removed at the
    /// end as debris is ([`manifold::drop_small_pieces`]), and their faces.
    pub pieces_dropped: usize,
    /// See `pieces_dropped`.
    pub faces_removed_pieces: usize,
    /// Faces reversed at the end so that the signed volume is positive.
    pub flipped_outward: bool,
    /// The result.
    pub output: TopologyReport,
    /// Distance of the result (TEST) to the input (REFERENCE). Its test→reference side includes the fill
    /// patches, which lie where the input has no surface.
    pub distance: DistanceReport,
    /// Distance from the result's faces that are unchanged input faces to the input (fill patches and moved
    /// faces excluded): how far repair moved the surface that was there. `null` when no face is unchanged
    /// (after smoothing).
    pub distance_kept_surface: Option<crate::stages::quality::DistanceStats>,
    /// Wall time of the repair itself (without the final measurement).
    pub seconds: f64,
}

fn to_trimesh(p: &[V3], tris: Vec<[u32; 3]>) -> TriMesh {
    TriMesh { positions: p.iter().map(|q| q.map(|c| c as f32)).collect(), triangles: tris }
}

/// Faces of `out` that are faces of `input` (same three positions, bit for bit): repair never moves a kept
/// vertex, so these are the surface that was there, as opposed to fill patches.
fn faces_from_input(input: &TriMesh, out: &TriMesh) -> Vec<[u32; 3]> {
    let key = |p: &[[f32; 3]], t: &[u32; 3]| {
        let mut k = t.map(|i| p[i as usize].map(|c| if c == 0.0 { 0 } else { c.to_bits() }));
        k.sort_unstable();
        k
    };
    let set: std::collections::HashSet<_> = input.triangles.iter().map(|t| key(&input.positions, t)).collect();
    out.triangles.iter().filter(|t| set.contains(&key(&out.positions, t))).copied().collect()
}

/// Repair `mesh` (polygons are fan-triangulated first).
///
/// # Errors
/// `input.no-geometry` for an empty mesh; `repair.failed` naming the step when nothing is left after
/// cleaning or the result is not a closed oriented 2-manifold. The input is never modified.
///
/// Cost: O(F log F) plus O(n³) per hole of n boundary edges (n ≤ 240, longer loops are ear-clipped first).
///
/// # Example
/// ```
/// use scanstation::geometry::shapes::icosphere;
/// use scanstation::stages::{NoProgress, repair::{RepairOptions, repair}};
/// use scanstation::PolyMesh;
///
/// // A sphere with one triangle missing: repair fills the hole and closes it.
/// let mut sphere = icosphere(1.0, 3, [0.0; 3]);
/// sphere.triangles.pop();
/// let opts = RepairOptions { compare_samples: 2_000, ..Default::default() };
/// let (closed, report) = repair(&PolyMesh::from(sphere), &opts, &NoProgress)?;
/// assert!(report.output.closed);
/// assert_eq!(report.holes.holes_filled, 1);
/// assert!(closed.signed_volume() > 0.0);
/// # Ok::<(), scanstation::Error>(())
/// ```
pub fn repair(mesh: &PolyMesh, opts: &RepairOptions, progress: &dyn Progress) -> Result<(TriMesh, RepairReport)> {
    let t0 = Instant::now();
    if mesh.face_count() == 0 {
        return Err(Error::new(ErrorCode::InputNoGeometry, "the mesh has no faces"));
    }
    let need = BYTES_PER_FACE * mesh.corner_count() as u64 / 3;
    if need > opts.memory_budget {
        return Err(Error::new(
            ErrorCode::ResourceMemoryBudget,
            format!("repair needs about {need} bytes; the budget is {}", opts.memory_budget),
        )
        .with_hint("decimate the input first or raise the memory budget"));
    }
    let input = TopologyReport::compute(mesh);
    let (tri, _) = mesh.triangulate();
    let pos: Vec<V3> = tri.positions.iter().map(|&q| wide(q)).collect();
    progress.report(0.0, "weld");
    let (mut pos, tris, weld) = weld::weld(&pos, &tri.triangles, opts.weld_rel * input.bbox_diagonal);
    if tris.is_empty() {
        return Err(Error::new(ErrorCode::RepairFailed, "weld: every face collapsed; nothing is left"));
    }
    tracing::debug!(seconds = t0.elapsed().as_secs_f64(), "weld done");
    progress.report(0.2, "manifold");
    let (mut tris, manifold) = manifold::make_manifold(&mut pos, tris, opts.keep_share);
    if tris.is_empty() {
        return Err(Error::new(ErrorCode::RepairFailed, "manifold: no face is left after cleaning"));
    }
    tracing::debug!(seconds = t0.elapsed().as_secs_f64(), "manifold done");
    progress.report(0.4, "holes");
    let holes = holes::fill_holes(&mut pos, &mut tris, true);
    tracing::debug!(seconds = t0.elapsed().as_secs_f64(), "holes done");
    let mut handles = handles::HandleReport::default();
    if opts.max_handle_loop_rel > 0.0 {
        progress.report(0.5, "handles");
        handles = handles::remove_small_handles(&mut pos, &mut tris, opts.max_handle_loop_rel * input.bbox_diagonal);
        let (p2, t2, _) = polygon::drop_unreferenced(&pos, &tris);
        (pos, tris) = (p2, t2);
        tracing::debug!(seconds = t0.elapsed().as_secs_f64(), cuts = handles.cuts, "handles done");
    }
    progress.report(0.6, "intersections");
    let intersections = intersections::remove_self_intersections(&mut pos, &mut tris, opts.keep_share);
    if intersections.pairs_remaining > 0 {
        return Err(Error::new(
            ErrorCode::RepairFailed,
            format!(
                "intersections: {} intersecting triangle pairs remain after {} rounds",
                intersections.pairs_remaining, intersections.rounds
            ),
        ));
    }
    tracing::debug!(seconds = t0.elapsed().as_secs_f64(), "intersections done");
    progress.report(0.7, "smooth");
    let mut smooth = smooth::SmoothReport::default();
    if opts.remove_spikes || opts.smooth_iterations > 0 {
        let before = pos.clone();
        if opts.remove_spikes {
            smooth.spikes_removed = smooth::remove_spikes(&mut pos, &tris);
        }
        smooth::taubin(&mut pos, &tris, opts.smooth_iterations);
        smooth.taubin_iterations = opts.smooth_iterations;
        // Moving vertices may make the surface cross itself: keep the result only if it does not. Only
        // faces with a moved vertex can take part in a new crossing.
        let mut touched: Vec<u32> = (0..tris.len() as u32)
            .filter(|&f| tris[f as usize].iter().any(|&v| pos[v as usize] != before[v as usize]))
            .collect();
        touched.sort_unstable();
        if !touched.is_empty() && !crate::geometry::intersect::self_intersections_of(&pos, &tris, &touched).is_empty() {
            return Err(Error::new(
                ErrorCode::RepairFailed,
                "smooth: moving spikes / smoothing made the surface intersect itself; retry without them",
            ));
        }
    }
    tracing::debug!(seconds = t0.elapsed().as_secs_f64(), spikes = smooth.spikes_removed, "smooth done");
    let (mut decimated, mut decimate_intersections) = (None, None);
    if let Some(target) = opts.target_vertices {
        progress.report(0.75, "decimate");
        let (p2, t2, _) = polygon::drop_unreferenced(&pos, &tris);
        (pos, tris) = (p2, t2);
        let t = Instant::now();
        decimated = Some(decimate::decimate(&mut pos, &mut tris, target, 0, decimate::Crossings::Refuse));
        tracing::debug!(seconds = t.elapsed().as_secs_f64(), "decimated");
        let check = intersections::remove_self_intersections(&mut pos, &mut tris, opts.keep_share);
        if check.pairs_remaining > 0 {
            return Err(Error::new(
                ErrorCode::RepairFailed,
                format!("decimate: {} intersecting triangle pairs remain", check.pairs_remaining),
            ));
        }
        decimate_intersections = Some(check);
    }
    let (pieces_dropped, faces_removed_pieces) = manifold::drop_small_pieces(&pos, &mut tris, opts.keep_share);
    let (pos, tris, _) = polygon::drop_unreferenced(&pos, &tris);
    let mut out = to_trimesh(&pos, tris);
    let flipped_outward = out.signed_volume() < 0.0;
    if flipped_outward {
        out.triangles.iter_mut().for_each(|t| t.swap(1, 2));
    }
    let seconds = t0.elapsed().as_secs_f64();
    let out_poly = PolyMesh::from(out.clone());
    let output = TopologyReport::compute(&out_poly);
    if !output.closed || !output.consistently_oriented || output.nonmanifold_vertices > 0 {
        return Err(Error::new(
            ErrorCode::RepairFailed,
            format!(
                "holes: the result is not a closed oriented 2-manifold ({} boundary edges, {} non-manifold edges, \
                 {} non-manifold vertices, {} orientation conflicts)",
                output.boundary_edges,
                output.nonmanifold_edges,
                output.nonmanifold_vertices,
                output.orientation_conflicts
            ),
        ));
    }
    progress.report(0.8, "measure");
    let copts = CompareOptions {
        samples: opts.compare_samples,
        seed: opts.compare_seed,
        memory_budget: opts.memory_budget,
        ..Default::default()
    };
    let input_geometry = Geometry::Mesh(mesh.clone());
    let distance = compare(&Geometry::Mesh(out_poly), &input_geometry, &copts, &NoProgress)?;
    let kept = TriMesh { positions: out.positions.clone(), triangles: faces_from_input(&tri, &out) };
    let distance_kept_surface = if kept.triangles.is_empty() {
        None
    } else {
        Some(compare(&Geometry::Mesh(PolyMesh::from(kept)), &input_geometry, &copts, &NoProgress)?.test_to_reference)
    };
    progress.report(1.0, "done");
    let report = RepairReport {
        input,
        weld,
        manifold,
        holes,
        handles,
        intersections,
        smooth,
        decimate: decimated,
        decimate_intersections,
        pieces_dropped,
        faces_removed_pieces,
        flipped_outward,
        output,
        distance,
        distance_kept_surface,
        seconds,
    };
    Ok((out, report))
}

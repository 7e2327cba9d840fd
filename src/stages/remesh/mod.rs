//! **remesh** — field-aligned pure-quad remeshing (the Instant Meshes core, Jakob et al. 2015, followed by a
//! clean-up that guarantees a closed pure-quad mesh).
//!
//! Steps, each counted in [`RemeshReport`]:
//! 1. a working copy of the input at a resolution suited to the target: very dense inputs are decimated
//!    (QEM) to about [`WORK_PER_VERTEX`] vertices per output vertex, coarse ones are subdivided;
//! 2. a multi-resolution hierarchy ([`hierarchy`]);
//! 3. the extrinsic 4-RoSy orientation field, coarse to fine, pulled toward principal curvature directions
//!    where the curvature is clearly anisotropic, and harder where those directions agree over the whole
//!    surface ([`COHERENT_PULL`]; [`field`]);
//! 4. the 4-PoSy position field at lattice spacing `scale`;
//! 5. extraction of a quad-dominant mesh ([`extract`]), closed by construction;
//! 6. clean-up to a pure-quad mesh ([`quadify`]) by up to four routes, each tried only when every earlier
//!    result lost something (RMS above [`FALLBACK_TRIGGER_PCT`], more than [`MISSED_MAX`] of the working
//!    vertices missed, χ changed or a face flipped): the
//!    *split* route extracts at a quarter of the count, pairs triangles along straight strips and splits
//!    every n-gon into n quads (regular, but features thinner than twice the spacing can vanish; skipped
//!    where many are, [`SKIP_THIN_SHARE`]); the
//!    *adaptive split* route does the same with a finer spacing on thin parts and narrow gaps
//!    ([`thickness`], [`spacing_field`]); the *direct* route extracts at the full count and pairs every
//!    triangle along straight strips or bent paths, on its own finer working mesh
//!    ([`WORK_PER_VERTEX_DIRECT`]); the *refined direct* route does the same with a finer spacing on thin
//!    parts or where the direct result missed the input ([`REFINE_TRIES`]). A later result is kept only
//!    when it keeps χ and has no
//!    flipped face where the earlier does not, or the earlier one is more than [`FIDELITY_RATIO`] times
//!    farther from the input;
//!
//!    On the split routes, the kept attempt is extracted again with its position singularities cancelled
//!    in pairs, or into cones, on the integer edge steps ([`integer::TRIES`]), the count steered by
//!    re-solving the position field ([`CANCEL_RESCALES`]); that result replaces the first when it is as
//!    sound, within the vertex-count
//!    tolerance, has fewer irregular vertices and its RMS grows by at most [`CANCEL_TRADE`] times their
//!    relative drop ([`CANCEL_RMS_SLACK`] at most); only tries with fewer irregular vertices are fitted,
//!    fewest first, until one is kept. Every try is reported (`cancellation`);
//! 7. a valence pass (diagonal collapses and edge rotations that lower Σ|valence − 4|), then dipole
//!    transport ([`dipoles`]: chains of up to [`dipoles::TRANSPORT_DEPTH`] cost-neutral rotations, vertex
//!    splits and diagonal collapses that move a valence 3–5 pair until it cancels another, committed only
//!    when the chain ends in a strict drop of Σ|valence − 4| and leaves no quad folded), then projection
//!    onto the input surface (onto triangles facing the same way) and tangential relaxation;
//! 8. a least-squares fit of the vertices to the input, both ways ([`fit`]), on every route's result
//!    before the routes are weighed.
//!
//! Apart from the stage, [`local::refine_where_far`] refines a finished net 3 × 3 only where the input passes
//! far from it (`convert`'s deviation goal uses it).
//!
//! **How the vertex count is matched.** The split in step 6 turns a quad-dominant mesh with V vertices,
//! E edges and F faces into a pure-quad mesh with exactly V + E + F vertices (≈ 4V). The split route
//! therefore extracts at a quarter of the target; both routes repeat the extraction with the spacing
//! scaled by √(predicted / target) until the count is within [`COUNT_TOLERANCE`] (at most [`MAX_ATTEMPTS`] /
//! [`MAX_DIRECT_ATTEMPTS`] extractions). Attempts must be closed, edge-manifold and keep the input's Euler
//! characteristic; after [`PATIENCE`] attempts, or when none does, one that changes it is accepted and
//! flagged (`euler_characteristic_changed`).
//!
//! The stage needs a closed 2-manifold triangle mesh (`remesh.input-not-closed` otherwise: run `repair`
//! first). It is deterministic for a fixed seed, whatever the number of threads: the fields are updated by
//! colour classes, each class in parallel from the previous values of the other classes.

mod cascade;
pub mod dipoles;
pub mod extract;
pub mod field;
mod finish;
pub mod fit;
pub mod hierarchy;
pub mod integer;
pub mod local;
mod pick;
pub mod quadify;
mod report;
mod settings;
mod sizing;
mod spacing;
mod tries;
mod work;

pub use report::{Alternative, Attempt, CancelTrial, Mode, QuadStats, Refine, RemeshReport, SizingSummary, quad_stats};
pub use settings::*;

use std::time::Instant;

use crate::error::{Error, ErrorCode, Result};
use crate::geometry::bvh::TriangleBvh;
use crate::geometry::mesh::{Geometry, PolyMesh, TriMesh};
use crate::geometry::topology::TopologyReport;
use crate::stages::Progress;
use crate::stages::quality::{CompareOptions, compare};
use cascade::{Cascade, WorkingMeshes};
use finish::InputSide;

/// Remesh a closed 2-manifold triangle mesh into a pure-quad mesh of about `opts.target_vertices` vertices.
///
/// # Errors
/// `remesh.input-not-closed` for an open, non-manifold or inconsistently oriented input;
/// `input.bad-argument` for a target below 8 or above 10⁷ vertices; `resource.memory` when the
/// estimate exceeds `opts.memory_budget`; `remesh.failed` when no attempt yields a closed 2-manifold quad
/// mesh. An attempt with the input's Euler characteristic is preferred; when none has it, the closest
/// closed manifold one is returned with `euler_characteristic_changed` set.
///
/// Cost: O(V_work · iterations · levels) for the fields, O(V_out log F_in) for projection; memory about
/// 600 bytes per working vertex plus 80 bytes per input triangle.
///
/// # Example
/// ```
/// use scanstation::geometry::shapes::icosphere;
/// use scanstation::stages::{NoProgress, remesh::{RemeshOptions, remesh}};
///
/// let sphere = icosphere(1.0, 4, [0.0; 3]);
/// let opts = RemeshOptions { target_vertices: 400, compare_samples: 0, ..Default::default() };
/// let (quads, report) = remesh(&sphere, &opts, &NoProgress)?;
/// assert!(quads.faces().all(|f| f.len() == 4));
/// assert!((report.output.vertices as f64 / 400.0 - 1.0).abs() <= 0.10);
/// assert_eq!(report.output.euler_characteristic, 2);
/// # Ok::<(), scanstation::Error>(())
/// ```
pub fn remesh(mesh: &TriMesh, opts: &RemeshOptions, progress: &dyn Progress) -> Result<(PolyMesh, RemeshReport)> {
    let mut report = RemeshReport { target_vertices: opts.target_vertices, ..Default::default() };
    // 1. Validate: the target, a closed oriented 2-manifold, the memory estimate.
    let (poly, topo) = validate(mesh, opts)?;
    report.input_vertices = topo.referenced_vertices;
    report.input_faces = topo.faces;
    report.input_area = topo.area;
    report.input_euler_characteristic = topo.euler_characteristic;
    report.input_components = topo.components;

    // 2. Working meshes (steps 1–3 above): the split routes' one with its hierarchy and orientation field.
    progress.report(0.0, "working mesh, hierarchy, orientation field");
    let work = WorkingMeshes::build(mesh, opts, &mut report);
    progress.report(0.25, "position field");

    // 3. The input side every route is finished on and weighed against.
    let bvh = TriangleBvh::new(mesh);
    let input = InputSide::new(mesh, &bvh, topo.area, opts);

    // 4. The route cascade (steps 4–8), each route steering its count and finishing its kept attempt.
    let finished = Cascade::new(&input, opts, work).run(&mut report, progress)?;

    // 5. The pick.
    let clock = Instant::now();
    let out = pick::pick(finished, input.diagonal, &mut report);

    // 6. Measure the kept result against the input and check it.
    progress.report(0.9, "measure");
    report.vertex_count_error = report.output.vertices as f64 / opts.target_vertices as f64 - 1.0;
    if opts.compare_samples > 0 {
        let copts = CompareOptions { samples: opts.compare_samples, seed: opts.seed, ..Default::default() };
        let d = compare(&Geometry::Mesh(out.clone()), &Geometry::Mesh(poly), &copts, &crate::stages::NoProgress)?;
        report.distance = Some(d);
    }
    report.seconds.insert("measure".to_string(), clock.elapsed().as_secs_f64());
    check_output(&report)?;
    progress.report(1.0, "done");
    Ok((out, report))
}

/// The input as a polygon mesh and its topology, when the target is in range, the input a closed oriented
/// 2-manifold and the working memory within the budget (the errors of [`remesh`]).
fn validate(mesh: &TriMesh, opts: &RemeshOptions) -> Result<(PolyMesh, TopologyReport)> {
    if !(8..=10_000_000).contains(&opts.target_vertices) {
        return Err(Error::new(
            ErrorCode::InputBadArgument,
            format!("target of {} vertices is outside 8 ..= 10,000,000", opts.target_vertices),
        ));
    }
    let poly = PolyMesh::from(mesh.clone());
    let topo = TopologyReport::compute(&poly);
    if !topo.closed || topo.nonmanifold_edges > 0 || topo.nonmanifold_vertices > 0 || !topo.consistently_oriented {
        return Err(Error::new(
            ErrorCode::RemeshInputNotClosed,
            format!(
                "remesh needs a closed, oriented 2-manifold; this mesh has {} boundary edges, {} non-manifold \
                 edges, {} non-manifold vertices, {} orientation conflicts",
                topo.boundary_edges, topo.nonmanifold_edges, topo.nonmanifold_vertices, topo.orientation_conflicts
            ),
        )
        .with_hint("run `scanstation repair IN -o OUT` first"));
    }
    let work_estimate = 600
        * ((opts.work_per_vertex * opts.target_vertices as f64) as u64).max(mesh.positions.len() as u64)
        + 80 * mesh.triangles.len() as u64;
    if work_estimate > opts.memory_budget {
        return Err(Error::new(
            ErrorCode::ResourceMemoryBudget,
            format!("remesh needs about {work_estimate} bytes; the budget is {}", opts.memory_budget),
        ));
    }
    Ok((poly, topo))
}

/// `remesh.failed` unless the kept mesh is closed, manifold, all quads, with no more pieces than the input.
fn check_output(report: &RemeshReport) -> Result<()> {
    let o = &report.output;
    if !o.closed
        || o.nonmanifold_edges > 0
        || o.nonmanifold_vertices > 0
        || o.quad_fraction < 1.0
        || o.components > report.input_components
    {
        return Err(Error::new(
            ErrorCode::RemeshFailed,
            format!(
                "clean-up: the quad mesh has {} boundary edges, {} non-manifold edges, {} non-manifold vertices, \
                 {} components (input {}), faces by degree {:?}",
                o.boundary_edges,
                o.nonmanifold_edges,
                o.nonmanifold_vertices,
                o.components,
                report.input_components,
                o.faces_by_degree
            ),
        ));
    }
    Ok(())
}

//! **brep / step** — the fitted Catmull–Clark surface as a watertight solid of bicubic B-spline faces, and
//! its ISO 10303-21 (STEP AP214) text.
//!
//! Construction ([`build_solid`]):
//! 1. [`patches`]: one Bézier patch per face of the once-refined net (exact on regular faces, fitted with
//!    shared boundary curves around extraordinary vertices).
//! 2. Packing: greedy maximal rectangles of regular faces become one clamped bicubic B-spline face each
//!    (C² inside); every other face stays a single Bézier face.
//! 3. Topology: a B-rep edge for every refined edge between two different faces (its cubic curve shared by
//!    both), a vertex for every end of such an edge, one outer loop per face, counter-clockwise in (u, v)
//!    so `∂u × ∂v` points out of the solid.
//!
//! [`check`] is our own validity check (closed, each edge used once in each direction, loops chain, edge
//! curves on both faces' boundaries within [`BREP_EDGE_REL`] of the diagonal, positive volume). [`step`]
//! writes the solid.

mod assemble;
pub mod bspline;
mod check;
mod pack;
pub mod patches;
mod solid;
pub mod step;

pub use check::check;
pub use pack::MAX_PACK_SIDE;
pub use solid::{BrepReport, Coedge, Edge, FOLD_SAMPLES, Face, Solid};

use crate::error::{Error, ErrorCode, Result};
use crate::geometry::subdivision::LimitSurface;
use crate::geometry::subdivision::limit::FaceKind;
use crate::geometry::vec3::{Aabb, V3};
use assemble::{assemble, merge_edge_chains};
use pack::pack;

/// Build the solid from the fitted surface (`p1`: control points on the refined net).
///
/// # Errors
/// `brep.invalid` when the result fails [`check`] (a bug: the construction is watertight by design);
/// `internal.bug` when a local evaluation table cannot be built.
///
/// Cost: O(F) time and memory in the number of refined faces.
pub fn build_solid(surface: &LimitSurface, p1: &[V3]) -> Result<(Solid, BrepReport)> {
    let patches = patches::build(surface, p1)?;
    let jumps = patches::normal_jumps(surface, &patches);
    let blocks = pack(surface);
    let solid = merge_edge_chains(assemble(surface, &patches, &blocks, p1));
    let mut bbox = Aabb::EMPTY;
    for v in &solid.vertices {
        bbox.add(*v);
    }
    let dev = check(&solid, bbox.diagonal())?;
    let (volume, area) = solid.volume_and_area();
    let report = BrepReport {
        faces: solid.faces.len(),
        packed_faces: blocks.iter().filter(|b| b.w * b.h > 1).count(),
        patches: surface.net.faces.len(),
        extraordinary_patches: surface.kinds.iter().filter(|k| matches!(k, FaceKind::Extraordinary(_))).count(),
        edges: solid.edges.len(),
        vertices: solid.vertices.len(),
        volume,
        area,
        max_normal_jump_deg: jumps.max_deg,
        p99_normal_jump_deg: jumps.p99_deg,
        max_normal_jump_at: jumps.max_at,
        max_normal_jump_at_extraordinary: jumps.max_at_extraordinary,
        max_normal_jump_at_fraction: jumps.max_at_fraction,
        max_normal_jump_at_valences: jumps.max_at_valences,
        max_edge_deviation: dev,
        self_intersections: 0,
        self_intersection_at: None,
        quad_self_intersections: 0,
        folded_faces: 0,
        fold_at: None,
    };
    let (folded_faces, fold_at) = solid.folds();
    let report = BrepReport { folded_faces, fold_at, ..report };
    if !(volume > 0.0) {
        return Err(Error::new(
            ErrorCode::BrepInvalid,
            format!("the solid's volume {volume:.6e} is not positive: faces point inward"),
        ));
    }
    Ok((solid, report))
}

//! From the extracted quad-dominant mesh to a pure-quad mesh on the input surface.
//!
//! 1. Faces of degree ≥ 6 (holes the extraction left) are cut into quads along their shortest
//!    quad-cutting diagonals, pentagons into a quad and a triangle.
//! 2. Triangles are paired along straight quad strips ([`pair_triangles`]) and, in the direct route,
//!    along bent paths ([`pair_triangles_along_paths`]); doublets are merged ([`remove_doublets`]).
//! 3. Split route: one regular split (face centre + edge midpoints), every n-gon becomes n quads; the
//!    vertex count is V + E + F of the quad-dominant mesh, which the caller steers to the target.
//! 4. A valence pass ([`optimize_valence`]), projection onto the input surface with tangential relaxation
//!    ([`relax_and_project`]), and unfolding of flipped faces ([`untangle`]).

mod faces;
mod pairing;
mod surface;
mod valence;

pub(crate) use faces::{cut_large_faces, cut_pentagons, keep_largest_components, split_pinched};
pub(crate) use pairing::{pair_triangles, pair_triangles_along_paths, remove_doublets};
pub(crate) use surface::{collapse_quads, flipped_faces, flipped_faces_hinted, relax_and_project, untangle};
pub use valence::ValenceCounts;
pub(crate) use valence::optimize_valence;

/// Counts of what the clean-up changed.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct CleanupCounts {
    /// Faces of degree ≥ 6 cut into smaller faces.
    pub large_faces_cut: usize,
    /// Triangle pairs merged into quads.
    pub triangle_pairs_merged: usize,
    /// Faces that repeated a vertex (pinched) and were split at it.
    pub pinched_faces_split: usize,
    /// Pentagons cut into a quad and a triangle.
    pub pentagons_cut: usize,
    /// Quads re-diagonalised between paired triangles.
    pub strip_quads_rediagonalised: usize,
    /// Triangles no strip could pair (they force the split fallback).
    pub triangles_unpaired: usize,
    /// Valence-2 vertices removed by merging their two faces.
    pub doublets_removed: usize,
    /// Triangle pairs joined along bent paths, and the steps walked.
    pub path_pairs: usize,
    /// Steps walked by those paths.
    pub path_steps: usize,
    /// Extra pieces the extraction pinched off (a thin part cut through), dropped so the result has as many
    /// components as the input, and the faces they held.
    pub components_dropped: usize,
    /// Faces those pieces held.
    pub component_faces_dropped: usize,
    /// Quads still flipped after unfolding, collapsed along a diagonal ([`collapse_quads`]).
    pub flipped_quads_collapsed: usize,
}

#[cfg(test)]
mod tests;

//! Step 4: remove self-intersections the MeshFix way (Attene 2010): find intersecting triangle pairs with a
//! BVH, delete them with a neighbourhood that grows each round, clean up (manifold, components), refill
//! the holes, repeat until none remain.

use std::collections::HashSet;

use crate::geometry::bvh::TriangleBvh;
use crate::geometry::bvh::{BoxTree, box_of};
use crate::geometry::intersect::{mesh_triangles_intersect, self_intersections_involving};
use crate::geometry::mesh::TriMesh;
use crate::geometry::topology::VertexFaces;
use crate::geometry::vec3::{self, V3};
use crate::stages::repair::{holes, manifold};
use rayon::prelude::*;

/// Pieces cut off by a deletion are dropped only below this fraction of the `keep_share` threshold: what
/// a deletion separates is surface the scan had, not debris.
const DEBRIS_SHARE_FACTOR: f64 = 0.01;
/// Rounds at most.
pub const MAX_ROUNDS: usize = 10;
/// Rings of neighbours deleted with the intersecting faces in the first round (one more each round)...
const GROW_FIRST: usize = 1;
/// ...the first round only as long as the deleted faces hold at most this share of the mesh area: on coarse
/// meshes a grown neighbourhood would cut whole parts (an ear) off, which the component step would then
/// drop. Later rounds always grow, so that a refill that intersects again is replaced by a larger one.
const GROW_MAX_AREA_SHARE: f64 = 0.02;

/// What the step did.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct IntersectionReport {
    /// Intersecting triangle pairs found before the first round.
    pub pairs_found: usize,
    /// Rounds run (0 when there were none).
    pub rounds: usize,
    /// Faces deleted over all rounds.
    pub faces_removed: usize,
    /// Holes refilled over all rounds.
    pub holes_refilled: usize,
    /// Pairs left at the end (0 on success).
    pub pairs_remaining: usize,
    /// Refill vertices moved back onto the deleted surface, and those kept where the move would intersect.
    pub vertices_restored: usize,
    /// Refill vertices left where they were (moving them back would cross).
    pub vertices_not_restored: usize,
}

/// Remove self-intersections of the closed, oriented manifold `tris` in place.
pub fn remove_self_intersections(pos: &mut Vec<V3>, tris: &mut Vec<[u32; 3]>, keep_share: f64) -> IntersectionReport {
    let mut r = IntersectionReport::default();
    // Faces before this index are known to intersect nothing (vertices never move): only refills are checked.
    let mut first_unchecked = 0;
    let first_new_vertex = pos.len() as u32;
    let mut deleted: Vec<[[f32; 3]; 3]> = Vec::new();
    for round in 0..=MAX_ROUNDS {
        let t = std::time::Instant::now();
        let pairs = self_intersections_involving(pos, tris, first_unchecked);
        tracing::debug!(round, pairs = pairs.len(), seconds = t.elapsed().as_secs_f64(), "self-intersection search");
        if round == 0 {
            r.pairs_found = pairs.len();
        }
        r.pairs_remaining = pairs.len();
        if pairs.is_empty() || round == MAX_ROUNDS {
            break;
        }
        r.rounds += 1;
        let mut faces: HashSet<u32> = pairs.iter().flat_map(|&(a, b)| [a, b]).collect();
        if GROW_FIRST + round > 0 {
            let around = VertexFaces::new(pos.len(), tris);
            let faces_of = |v: u32| around.of(v);
            let area = |f: u32| vec3::tri_area(pos, tris[f as usize]);
            let total: f64 = (0..tris.len() as u32).map(area).sum();
            for _ in 0..GROW_FIRST + round {
                let verts: HashSet<u32> = faces.iter().flat_map(|&f| tris[f as usize]).collect();
                let grown: HashSet<u32> = verts.iter().flat_map(|&v| faces_of(v).iter().copied()).collect();
                if round == 0 && grown.iter().map(|&f| area(f)).sum::<f64>() > GROW_MAX_AREA_SHARE * total {
                    break;
                }
                faces = grown;
            }
        }
        r.faces_removed += faces.len();
        // Vertices of earlier refills are not original surface: keep only triangles of original vertices.
        deleted.extend(
            faces
                .iter()
                .map(|&f| tris[f as usize])
                .filter(|t| t.iter().all(|&v| v < first_new_vertex))
                .map(|t| t.map(|v| pos[v as usize].map(|c| c as f32))),
        );
        let mut rim: HashSet<u32> = faces.iter().flat_map(|&f| tris[f as usize]).collect();
        let kept: Vec<[u32; 3]> =
            tris.iter().enumerate().filter(|(f, _)| !faces.contains(&(*f as u32))).map(|(_, t)| *t).collect();
        let vertices_before_split = pos.len() as u32;
        let t = std::time::Instant::now();
        // Deleting faces cannot create non-manifold edges or orientation conflicts, only pinched vertices and
        // loose pieces.
        let (cleaned, _) = manifold::split_and_keep(pos, kept, &rim, keep_share * DEBRIS_SHARE_FACTOR);
        *tris = cleaned;
        // Kept faces stay in order at the front (they were checked); refills are appended after them.
        let t2 = std::time::Instant::now();
        first_unchecked = tris.len();
        // Every hole lies at the deleted faces' corners, or at copies the split made of them.
        rim.extend(vertices_before_split..pos.len() as u32);
        r.holes_refilled += holes::fill_holes_near(pos, tris, &rim).holes_filled;
        tracing::debug!(
            round,
            manifold_s = (t2 - t).as_secs_f64(),
            fill_s = t2.elapsed().as_secs_f64(),
            "removed and refilled"
        );
    }
    if r.pairs_remaining == 0 && !deleted.is_empty() {
        let t = std::time::Instant::now();
        restore_shape(pos, tris, first_new_vertex, &deleted, &mut r);
        tracing::debug!(seconds = t.elapsed().as_secs_f64(), restored = r.vertices_restored, "shape restored");
    }
    r
}

/// Move refill vertices onto the surface that was deleted (closest point on the deleted triangles), so a
/// deletion does not flatten a bulge such as an ear tip; a vertex whose move makes any triangle intersect
/// is moved back and kept where the fairing put it.
fn restore_shape(
    pos: &mut [V3],
    tris: &[[u32; 3]],
    first_new: u32,
    deleted: &[[[f32; 3]; 3]],
    r: &mut IntersectionReport,
) {
    let guide = TriMesh {
        positions: deleted.iter().flatten().copied().collect(),
        triangles: (0..deleted.len() as u32).map(|i| [3 * i, 3 * i + 1, 3 * i + 2]).collect(),
    };
    let bvh = TriangleBvh::new(&guide);
    let new: Vec<u32> = (first_new..pos.len() as u32).collect();
    let before: Vec<V3> = new.iter().map(|&v| pos[v as usize]).collect();
    for &v in &new {
        if let Some(c) = bvh.closest(pos[v as usize]) {
            pos[v as usize] = c.point;
        }
    }
    let mut moved: HashSet<u32> = new.iter().copied().collect();
    let old = |v: u32| if v >= first_new { before[(v - first_new) as usize] } else { pos[v as usize] };
    // One tree for every rollback state: each face's box covers its corners both moved and not.
    let boxes: Vec<_> = tris
        .par_iter()
        .map(|t| {
            let pts: Vec<V3> = t.iter().flat_map(|&v| [pos[v as usize], old(v)]).collect();
            box_of(&pts)
        })
        .collect();
    let tree = BoxTree::new(&boxes);
    let mut touched: Vec<u32> =
        (0..tris.len() as u32).filter(|&f| tris[f as usize].iter().any(|&v| v >= first_new)).collect();
    for _ in 0..MAX_ROUNDS * 4 {
        touched.retain(|&f| tris[f as usize].iter().any(|v| moved.contains(v)));
        let pairs: Vec<(u32, u32)> = touched
            .par_iter()
            .flat_map_iter(|&f| {
                let mut found = Vec::new();
                let (lo, hi) = boxes[f as usize];
                tree.overlapping(lo, hi, |g| {
                    if g != f && mesh_triangles_intersect(pos, tris[f as usize], tris[g as usize]) {
                        found.push((f, g));
                    }
                });
                found
            })
            .collect();
        if pairs.is_empty() {
            break;
        }
        for (a, b) in pairs {
            for v in tris[a as usize].iter().chain(&tris[b as usize]) {
                if moved.remove(v) {
                    pos[*v as usize] = before[(*v - first_new) as usize];
                }
            }
        }
    }
    r.vertices_restored = moved.len();
    r.vertices_not_restored = new.len() - moved.len();
}

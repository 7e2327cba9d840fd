//! Least-squares fit of the finished quad mesh to the input surface.
//!
//! Projection puts every quad vertex *on* the input, so each bilinear face cuts through the surface as a
//! chord: inside on convex parts, outside on concave ones, and across the middle of features narrower than
//! a face. The fit moves the vertices to lower the pooled squared distance of both sides — input samples to
//! the quad mesh and quad samples (vertices, face centres) to the input — the distance energy of Hoppe et
//! al. 1993 ("Mesh optimization"), with the closest-point correspondences refreshed every round. A round
//! moves each vertex by the weighted mean of the residuals of the samples it carries (weights: its
//! barycentric share of each sample's closest point), which is a gradient step preconditioned by the
//! vertex's total weight: stable (a uniformly offset surface is matched in one step) and zero exactly where
//! the least-squares gradient is. A tangential umbrella term keeps the quads even.
//!
//! Vertices end off the input surface by a fraction of the chord height; the quad mesh is the piecewise
//! bilinear surface closest to the input, which is what the surface stage fits from. A round never leaves
//! a face flipped: vertices of faces that the move turned over return to where they were.

use rayon::prelude::*;

use crate::geometry::bvh::TriangleBvh;
use crate::geometry::mesh::TriMesh;
use crate::geometry::vec3::{V3, add, cross, dot, norm2, scale, sub};

use super::quadify::{flipped_faces, flipped_faces_hinted};
use crate::geometry::polygon::{adjacency, polygon_centre, vertex_normals};

/// Fit rounds after the clean-up (each refreshes the correspondences).
pub const FIT_ROUNDS: usize = 4;

/// Input samples per quad vertex that the fit draws (area-uniform). 4 since 2026-12-03 (was 8): the same
/// route and result on the five shared meshes and the dragon (seeds 0–2) and the armadillo (seeds 1, 2), RMS
/// within 1.5 %, for a third fewer closest-point queries a round.
pub const FIT_SAMPLES_PER_VERTEX: usize = 4;

/// Weight of the tangential umbrella term against a vertex's own residual weight.
pub const FIT_SMOOTH: f64 = 0.5;

/// An input sample's closest point on the quad mesh: its triangle's corners, barycentric weights and the
/// residual (sample − closest point).
type Hit = ([u32; 3], [f64; 3], V3);

/// Passes that undo the moves around faces a fit round turned over, before the whole round is undone. An
/// undone corner can turn the next face of a sliver strip over: on the dragon's uniform split such a chain
/// needed 5 passes, and with 4 every round was undone whole (RMS 0.228 % instead of 0.139 %).
pub const UNDO_PASSES: usize = 16;

/// What the fit did.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct FitCounts {
    /// Rounds run.
    pub rounds: usize,
    /// Vertex moves undone because they flipped a face.
    pub moves_undone: usize,
    /// Mean squared residual over both sides' samples at the start of the first round (length², the
    /// input's units; both sides weigh half).
    pub mean_square_first: f64,
    /// The same at the start of the last round (the last move is not measured again, to save its
    /// queries).
    pub mean_square_last: f64,
    /// Wall time of the fit.
    pub seconds: f64,
}

/// Fit the closed quad mesh (`p`, `quads`) to the input surface of `bvh`, sampled by `samples` (points on
/// it, area-uniform), for `rounds` rounds; `surface_normal(t)` is input triangle t's normal (any length),
/// which decides whether a face is flipped.
///
/// Cost per round: a BVH over the quad mesh's 2F triangles, one closest-point query per sample into it
/// and one per vertex and face into the input's BVH. Deterministic: the residuals are summed in sample
/// order.
pub fn fit_to_surface(
    p: &mut [V3],
    quads: &[Vec<u32>],
    samples: &[V3],
    bvh: &TriangleBvh,
    surface_normal: impl Fn(u32) -> V3 + Sync,
    rounds: usize,
) -> FitCounts {
    let mut counts = FitCounts::default();
    let nv = p.len();
    if rounds == 0 || nv == 0 || quads.is_empty() || samples.is_empty() {
        return counts;
    }
    let clock = std::time::Instant::now();
    // Work at the precision the mesh is stored in (f32), so that the flip checks see the faces as written.
    for x in p.iter_mut() {
        *x = stored(*x);
    }
    let (off, adj) = adjacency(nv, quads);
    // The quad mesh as the measurement triangulates it (a fan from each face's first corner).
    let triangles: Vec<[u32; 3]> =
        quads.iter().flat_map(|f| (1..f.len() - 1).map(move |k| [f[0], f[k], f[k + 1]])).collect();
    // Faces flipped before the fit (the clean-up could not unfold them) keep their corners where they are.
    let mut frozen = vec![false; nv];
    let mut was_flipped = vec![false; quads.len()];
    for fi in flipped_faces(p, quads, bvh, &surface_normal) {
        was_flipped[fi] = true;
        for &v in &quads[fi] {
            frozen[v as usize] = true;
        }
    }
    let (mut sample_tri, mut vertex_tri, mut centre_tri) =
        (vec![None; samples.len()], vec![None; nv], vec![None; quads.len()]);
    for round in 0..rounds {
        let positions: Vec<[f32; 3]> = p.iter().map(|x| x.map(|c| c as f32)).collect();
        let tri = TriMesh { positions, triangles: triangles.clone() };
        let quad_bvh = TriangleBvh::new(&tri);
        // Input → quad, per sample: the closest quad triangle's corners, barycentric weights and residual.
        let p_now: &[V3] = p;
        // Each query starts from the previous round's answer (same answers, fewer boxes searched).
        let (hits, st): (Vec<Option<Hit>>, Vec<Option<u32>>) = samples
            .par_iter()
            .zip(&sample_tri)
            .map(|(&x, &hint)| {
                let Some(c) = quad_bvh.closest_hinted(x, hint) else { return (None, hint) };
                let t = triangles[c.index as usize];
                let w = barycentric(c.point, p_now[t[0] as usize], p_now[t[1] as usize], p_now[t[2] as usize]);
                (Some((t, w, sub(x, c.point))), Some(c.index))
            })
            .unzip();
        // Quad → input: every vertex, and every face centre (a quarter to each corner).
        let (at_vertex, vt): (Vec<V3>, Vec<Option<u32>>) = p_now
            .par_iter()
            .zip(&vertex_tri)
            .map(|(&x, &hint)| {
                bvh.closest_hinted(x, hint).map_or(([0.0; 3], hint), |c| (sub(c.point, x), Some(c.index)))
            })
            .unzip();
        let (at_centre, ct): (Vec<V3>, Vec<Option<u32>>) = quads
            .par_iter()
            .zip(&centre_tri)
            .map(|(f, &hint)| {
                let c = polygon_centre(p_now, f);
                bvh.closest_hinted(c, hint).map_or(([0.0; 3], hint), |h| (sub(h.point, c), Some(h.index)))
            })
            .unzip();
        (sample_tri, vertex_tri, centre_tri) = (st, vt, ct);
        // Both sides weigh the same in total, as in the two-sided RMS.
        let n_in = hits.len().max(1) as f64;
        let n_q = (nv + quads.len()) as f64;
        let ms = 0.5 * hits.iter().flatten().map(|h| norm2(h.2)).sum::<f64>() / n_in
            + 0.5 * (at_vertex.iter().chain(&at_centre).map(|&r| norm2(r)).sum::<f64>()) / n_q;
        if round == 0 {
            counts.mean_square_first = ms;
        }
        counts.mean_square_last = ms;
        let (a_in, a_q) = (0.5 / n_in, 0.5 / n_q);
        let mut weight = vec![0.0f64; nv];
        let mut pull = vec![[0.0f64; 3]; nv];
        for (t, w, r) in hits.iter().flatten() {
            for k in 0..3 {
                let v = t[k] as usize;
                weight[v] += a_in * w[k];
                pull[v] = add(pull[v], scale(*r, a_in * w[k]));
            }
        }
        for (v, r) in at_vertex.iter().enumerate() {
            weight[v] += a_q;
            pull[v] = add(pull[v], scale(*r, a_q));
        }
        for (f, r) in quads.iter().zip(&at_centre) {
            let share = a_q / f.len() as f64;
            for &v in f {
                weight[v as usize] += share;
                pull[v as usize] = add(pull[v as usize], scale(*r, share));
            }
        }
        let mean_weight = weight.iter().sum::<f64>() / nv as f64;
        let nrm = vertex_normals(p_now, quads);
        let next: Vec<V3> = (0..nv)
            .into_par_iter()
            .map(|v| {
                let x = p_now[v];
                if frozen[v] {
                    return x;
                }
                let nb = &adj[off[v] as usize..off[v + 1] as usize];
                let mut lap = [0.0; 3];
                if !nb.is_empty() {
                    for &u in nb {
                        lap = add(lap, p_now[u as usize]);
                    }
                    lap = sub(scale(lap, 1.0 / nb.len() as f64), x);
                    let n = nrm[v];
                    lap = sub(lap, scale(n, dot(lap, n)));
                }
                let mu = FIT_SMOOTH * mean_weight;
                let total = weight[v] + mu;
                if total <= 0.0 {
                    return x;
                }
                stored(add(x, scale(add(pull[v], scale(lap, mu)), 1.0 / total)))
            })
            .collect();
        let before = p.to_vec();
        p.copy_from_slice(&next);
        counts.moves_undone += undo_flips(p, &before, quads, bvh, &surface_normal, &centre_tri, &was_flipped);
        counts.rounds += 1;
    }
    counts.seconds = clock.elapsed().as_secs_f64();
    counts
}

/// Undoes the moves (from `before`) of the corners of faces a round turned over, a few times
/// ([`UNDO_PASSES`]): an undone corner can turn a neighbouring face over; the whole round is undone if faces
/// are still turned after that. Faces in `was_flipped` do not count. Returns the moves undone.
fn undo_flips(
    p: &mut [V3],
    before: &[V3],
    quads: &[Vec<u32>],
    bvh: &TriangleBvh,
    surface_normal: &(impl Fn(u32) -> V3 + Sync),
    centre_tri: &[Option<u32>],
    was_flipped: &[bool],
) -> usize {
    let mut undone = 0;
    for undo in 0..=UNDO_PASSES {
        let bad: Vec<usize> = flipped_faces_hinted(p, quads, bvh, surface_normal, centre_tri)
            .into_iter()
            .filter(|&f| !was_flipped[f])
            .collect();
        if bad.is_empty() {
            break;
        }
        if undo == UNDO_PASSES {
            undone += (0..p.len()).filter(|&v| p[v] != before[v]).count();
            p.copy_from_slice(before);
            break;
        }
        for fi in bad {
            for &v in &quads[fi] {
                if p[v as usize] != before[v as usize] {
                    p[v as usize] = before[v as usize];
                    undone += 1;
                }
            }
        }
    }
    undone
}

/// `x` rounded to the f32 precision the quad mesh is stored in.
fn stored(x: V3) -> V3 {
    x.map(|c| f64::from(c as f32))
}

/// Barycentric coordinates of `x` (on or near triangle a, b, c), clamped to the triangle; equal thirds for a
/// degenerate triangle.
fn barycentric(x: V3, a: V3, b: V3, c: V3) -> [f64; 3] {
    let n = cross(sub(b, a), sub(c, a));
    let nn = norm2(n);
    if !(nn > 0.0) {
        return [1.0 / 3.0; 3];
    }
    let wa = dot(cross(sub(b, x), sub(c, x)), n) / nn;
    let wb = dot(cross(sub(c, x), sub(a, x)), n) / nn;
    let w = [wa.max(0.0), wb.max(0.0), (1.0 - wa - wb).max(0.0)];
    let s = w[0] + w[1] + w[2];
    if s > 0.0 { [w[0] / s, w[1] / s, w[2] / s] } else { [1.0 / 3.0; 3] }
}

//! On the input surface: projection with tangential relaxation, flipped faces, their collapse and unfolding.

use rayon::prelude::*;

use super::valence::{Batch, collapse_keeps_manifold};
use crate::geometry::bvh::TriangleBvh;
use crate::geometry::polygon::{adjacency, compact, neighbour_lists, polygon_centre, polygon_normal, vertex_normals};
use crate::geometry::vec3::{self, V3, add, dot, scale, sub};

/// Project every vertex onto the surface of `bvh`, then `iterations` rounds of tangential Laplacian
/// relaxation (Jacobi, step `lambda`) each followed by re-projection. After the first round a vertex is
/// projected onto the nearest input triangle that faces the same way as the mesh at that vertex, so that
/// vertices on thin parts do not jump to the opposite sheet (which would flip faces).
pub(crate) fn relax_and_project(p: &mut [V3], faces: &[Vec<u32>], bvh: &TriangleBvh, iterations: usize, lambda: f64) {
    // Each vertex's last input triangle: the next query starts from it (same answers, fewer boxes).
    let mut hint: Vec<Option<u32>> = p
        .par_iter_mut()
        .map(|x| {
            let c = bvh.closest(*x)?;
            *x = c.point;
            Some(c.index)
        })
        .collect();
    let (off, adj) = adjacency(p.len(), faces);
    for _ in 0..iterations {
        let nrm = vertex_normals(p, faces);
        let cur: &[V3] = p;
        let next: Vec<(V3, Option<u32>)> = (0..cur.len())
            .into_par_iter()
            .map(|v| {
                let (lo, hi) = (off[v] as usize, off[v + 1] as usize);
                let n = nrm[v];
                let mut x = cur[v];
                if hi > lo {
                    let mut avg = [0.0; 3];
                    for &u in &adj[lo..hi] {
                        avg = add(avg, cur[u as usize]);
                    }
                    avg = scale(avg, 1.0 / (hi - lo) as f64);
                    let d = sub(avg, x);
                    x = add(x, scale(sub(d, scale(n, dot(d, n))), lambda));
                }
                let hit = if vec3::norm2(n) > 0.0 { bvh.closest_facing_hinted(x, n, hint[v]) } else { None };
                hit.or_else(|| bvh.closest_hinted(x, hint[v])).map_or((x, hint[v]), |c| (c.point, Some(c.index)))
            })
            .collect();
        for (v, (x, h)) in next.into_iter().enumerate() {
            p[v] = x;
            hint[v] = h;
        }
    }
}

/// Faces whose (Newell) normal points against `surface_normal` of the nearest input triangle to their centre,
/// ascending.
pub(crate) fn flipped_faces(
    p: &[V3],
    faces: &[Vec<u32>],
    bvh: &TriangleBvh,
    surface_normal: &(impl Fn(u32) -> V3 + Sync),
) -> Vec<usize> {
    flipped_faces_hinted(p, faces, bvh, surface_normal, &[])
}

/// [`flipped_faces`], each face's query started from `hints[face]` (an input triangle near its centre; the
/// same answer, fewer boxes searched; faces past the end of `hints` start without one).
pub(crate) fn flipped_faces_hinted(
    p: &[V3],
    faces: &[Vec<u32>],
    bvh: &TriangleBvh,
    surface_normal: &(impl Fn(u32) -> V3 + Sync),
    hints: &[Option<u32>],
) -> Vec<usize> {
    (0..faces.len())
        .into_par_iter()
        .filter(|&fi| face_flipped(p, &faces[fi], bvh, surface_normal, hints.get(fi).copied().flatten()))
        .collect()
}

/// Face `f`'s normal points against `surface_normal` of the nearest input triangle to its centre (the query
/// started from `hint`).
fn face_flipped(
    p: &[V3],
    f: &[u32],
    bvh: &TriangleBvh,
    surface_normal: &(impl Fn(u32) -> V3 + Sync),
    hint: Option<u32>,
) -> bool {
    bvh.closest_hinted(polygon_centre(p, f), hint)
        .is_some_and(|cl| dot(polygon_normal(p, f), surface_normal(cl.index)) < 0.0)
}

/// Collapse each of the quads `which` (of a closed pure-quad mesh) along a diagonal: its two opposite
/// corners merge at their midpoint and the quad disappears. The shorter diagonal is tried first; a collapse
/// is made only when it keeps the mesh 2-manifold (the two corners have no common neighbour but the other
/// two corners), the merged vertex has valence ≥ 3, and it does not touch the ring of another collapse in
/// the same call. The other two corners lose an edge each and may be left with valence 2: run
/// [`remove_doublets`] afterwards. For folds that relaxation cannot undo (a sliver quad turned over on a
/// sharp bend). Merged-away vertices are removed and `faces` renumbered. Returns the collapses made.
pub(crate) fn collapse_quads(p: &mut Vec<V3>, faces: &mut Vec<Vec<u32>>, which: &[usize]) -> usize {
    let nbrs = neighbour_lists(p.len(), faces);
    let val = |v: u32| nbrs[v as usize].len();
    let mut batch = Batch::new(p.len(), faces.len());
    let mut made = 0;
    for &fi in which {
        let f = &faces[fi];
        if f.len() != 4 || batch.removed[fi] {
            continue;
        }
        let mut diagonals = [[f[0], f[1], f[2], f[3]], [f[1], f[2], f[3], f[0]]];
        let len2 = |[a, _, c, _]: [u32; 4]| vec3::norm2(sub(p[a as usize], p[c as usize]));
        if len2(diagonals[1]) < len2(diagonals[0]) {
            diagonals.swap(0, 1);
        }
        let allowed = |[a, b, c, d]: [u32; 4]| {
            val(a) + val(c) >= 5 && batch.ring_free(&nbrs, &[a, b, c, d]) && collapse_keeps_manifold(&nbrs, a, c)
        };
        if let Some(q) = diagonals.into_iter().find(|&q| allowed(q)) {
            batch.collapse(p, fi, q);
            made += 1;
        }
    }
    if made > 0 {
        *faces = batch.rebuild(faces);
        *p = compact(p, faces);
    }
    made
}

/// Unfold flipped faces: a face is flipped when its normal points against `surface_normal` at its centre.
/// The vertices of flipped faces and their neighbours move to the average of their neighbours (not only
/// tangentially) and back onto the surface, for at most `rounds` rounds; the positions with the fewest
/// flipped faces seen are kept, so the result is never worse than the input. Returns the faces still
/// flipped.
pub(crate) fn untangle(
    p: &mut [V3],
    faces: &[Vec<u32>],
    bvh: &TriangleBvh,
    surface_normal: impl Fn(u32) -> V3 + Sync,
    rounds: usize,
) -> usize {
    let (off, adj) = adjacency(p.len(), faces);
    // Faces around each vertex, so that a round re-checks only the faces its moves touched.
    let mut vf_off = vec![0u32; p.len() + 1];
    for f in faces {
        for &v in f {
            vf_off[v as usize + 1] += 1;
        }
    }
    for k in 0..p.len() {
        vf_off[k + 1] += vf_off[k];
    }
    let mut vf = vec![0u32; vf_off[p.len()] as usize];
    let mut fill = vf_off.clone();
    for (fi, f) in faces.iter().enumerate() {
        for &v in f {
            vf[fill[v as usize] as usize] = fi as u32;
            fill[v as usize] += 1;
        }
    }
    let mut flag = vec![false; faces.len()];
    for fi in flipped_faces(p, faces, bvh, &surface_normal) {
        flag[fi] = true;
    }
    let mut bad: Vec<usize> = (0..faces.len()).filter(|&f| flag[f]).collect();
    // Keep the positions with the fewest flipped faces seen (the start included): never worse.
    let mut best = (bad.len(), p.to_vec());
    for _ in 0..rounds {
        if bad.is_empty() {
            break;
        }
        let mut verts: Vec<u32> = bad.iter().flat_map(|&f| faces[f].iter().copied()).collect();
        let ring: Vec<u32> = verts
            .iter()
            .flat_map(|&v| adj[off[v as usize] as usize..off[v as usize + 1] as usize].iter().copied())
            .collect();
        verts.extend(ring);
        verts.sort_unstable();
        verts.dedup();
        let moved: Vec<V3> = verts
            .iter()
            .map(|&v| {
                let nb = &adj[off[v as usize] as usize..off[v as usize + 1] as usize];
                let mut avg = [0.0; 3];
                for &u in nb {
                    avg = add(avg, p[u as usize]);
                }
                avg = scale(avg, 1.0 / nb.len().max(1) as f64);
                bvh.closest(avg).map_or(avg, |c| c.point)
            })
            .collect();
        for (&v, x) in verts.iter().zip(moved) {
            p[v as usize] = x;
        }
        let mut touched: Vec<u32> = verts
            .iter()
            .flat_map(|&v| vf[vf_off[v as usize] as usize..vf_off[v as usize + 1] as usize].iter().copied())
            .collect();
        touched.sort_unstable();
        touched.dedup();
        let p_now: &[V3] = p;
        let now: Vec<bool> = touched
            .par_iter()
            .map(|&fi| face_flipped(p_now, &faces[fi as usize], bvh, &surface_normal, None))
            .collect();
        for (&fi, b) in touched.iter().zip(now) {
            flag[fi as usize] = b;
        }
        bad = (0..faces.len()).filter(|&f| flag[f]).collect();
        if bad.len() < best.0 {
            best = (bad.len(), p.to_vec());
        }
    }
    if best.0 < bad.len() {
        p.copy_from_slice(&best.1);
    }
    best.0.min(bad.len())
}

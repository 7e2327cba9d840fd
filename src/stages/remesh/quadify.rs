//! From the extracted quad-dominant mesh to a pure-quad mesh on the input surface.
//!
//! 1. Faces of degree ≥ 6 (holes the extraction left) are cut into quads along their shortest
//!    quad-cutting diagonals, leaving at most one triangle or pentagon.
//! 2. Adjacent triangles are paired into quads.
//! 3. One regular split (face centre + edge midpoints): every n-gon becomes n quads. The final vertex
//!    count is V + E + F of the quad-dominant mesh, which the caller steers to the target.
//! 4. Vertices are moved onto the input surface and relaxed tangentially (closest-point projection).

use std::collections::HashMap;

use rayon::prelude::*;

use crate::geometry::bvh::TriangleBvh;
use crate::geometry::vec3::{self, V3, add, cross, dot, scale, sub};

/// Counts of what the clean-up changed.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct CleanupCounts {
    /// Faces of degree ≥ 6 cut into smaller faces.
    pub large_faces_cut: usize,
    /// Triangle pairs merged into quads.
    pub triangle_pairs_merged: usize,
    /// Faces that repeated a vertex (pinched) and were split at it.
    pub pinched_faces_split: usize,
}

/// Split faces that visit a vertex twice into simple cycles.
pub fn split_pinched(faces: &mut Vec<Vec<u32>>, counts: &mut CleanupCounts) {
    let mut out = Vec::with_capacity(faces.len());
    let mut stack: Vec<Vec<u32>> = faces.drain(..).collect();
    while let Some(f) = stack.pop() {
        let mut split = None;
        'outer: for i in 0..f.len() {
            for j in i + 1..f.len() {
                if f[i] == f[j] {
                    split = Some((i, j));
                    break 'outer;
                }
            }
        }
        match split {
            None => out.push(f),
            Some((i, j)) => {
                counts.pinched_faces_split += 1;
                let a: Vec<u32> = f[i..j].to_vec();
                let b: Vec<u32> = f[j..].iter().chain(&f[..i]).copied().collect();
                for part in [a, b] {
                    if part.len() >= 3 {
                        stack.push(part);
                    }
                }
            }
        }
    }
    out.reverse();
    *faces = out;
}

/// Cut faces of degree ≥ 6 into quads (plus at most one triangle or pentagon) along short diagonals.
pub fn cut_large_faces(p: &[V3], faces: &mut Vec<Vec<u32>>, counts: &mut CleanupCounts) {
    let mut out = Vec::with_capacity(faces.len());
    for f in faces.drain(..) {
        if f.len() < 6 {
            out.push(f);
            continue;
        }
        counts.large_faces_cut += 1;
        let mut poly = f;
        while poly.len() >= 6 {
            let n = poly.len();
            // Cut off the quad (k, k+1, k+2, k+3) with the shortest closing diagonal k+3 → k.
            let k = (0..n)
                .min_by(|&a, &b| {
                    let d = |k: usize| vec3::norm2(sub(p[poly[k] as usize], p[poly[(k + 3) % n] as usize]));
                    d(a).total_cmp(&d(b)).then(a.cmp(&b))
                })
                .expect("n ≥ 6");
            let quad: Vec<u32> = (0..4).map(|i| poly[(k + i) % n]).collect();
            let rest: Vec<u32> = (0..n - 2).map(|i| poly[(k + 3 + i) % n]).collect();
            out.push(quad);
            poly = rest;
        }
        out.push(poly);
    }
    *faces = out;
}

/// Merge pairs of adjacent triangles into quads (greedy, shortest shared edge last so that the
/// resulting quads are the most square-ish).
pub fn merge_triangle_pairs(p: &[V3], faces: &mut Vec<Vec<u32>>, counts: &mut CleanupCounts) {
    let mut edge_tris: HashMap<(u32, u32), Vec<u32>> = HashMap::new();
    for (fi, f) in faces.iter().enumerate() {
        if f.len() == 3 {
            for k in 0..3 {
                let (a, b) = (f[k], f[(k + 1) % 3]);
                edge_tris.entry((a.min(b), a.max(b))).or_default().push(fi as u32);
            }
        }
    }
    let mut cand: Vec<(f64, u32, u32, (u32, u32))> = edge_tris
        .iter()
        .filter(|(_, t)| t.len() == 2)
        .map(|(&(a, b), t)| (-vec3::norm2(sub(p[a as usize], p[b as usize])), t[0], t[1], (a, b)))
        .collect();
    cand.sort_unstable_by(|x, y| x.0.total_cmp(&y.0).then((x.1, x.2).cmp(&(y.1, y.2))));
    let mut used = vec![false; faces.len()];
    let mut merged: Vec<Vec<u32>> = Vec::new();
    for (_, t0, t1, (a, b)) in cand {
        if used[t0 as usize] || used[t1 as usize] {
            continue;
        }
        let f0 = &faces[t0 as usize];
        let f1 = &faces[t1 as usize];
        // f0 = (x, y, z) with the shared edge somewhere; rotate so that f0 = (u, v, w) with (u, v) shared.
        let k = (0..3).find(|&k| {
            let (u, v) = (f0[k], f0[(k + 1) % 3]);
            (u == a && v == b) || (u == b && v == a)
        });
        let Some(k) = k else { continue };
        let (u, v, w) = (f0[k], f0[(k + 1) % 3], f0[(k + 2) % 3]);
        let Some(&x) = f1.iter().find(|&&x| x != u && x != v) else { continue };
        if x == w {
            continue;
        }
        used[t0 as usize] = true;
        used[t1 as usize] = true;
        counts.triangle_pairs_merged += 1;
        merged.push(vec![u, x, v, w]);
    }
    let mut out: Vec<Vec<u32>> = faces.iter().zip(&used).filter(|(_, u)| !**u).map(|(f, _)| f.clone()).collect();
    out.extend(merged);
    *faces = out;
}

/// Number of vertices after [`split_to_quads`]: V + E + F.
pub fn split_vertex_count(nv: usize, faces: &[Vec<u32>]) -> usize {
    let corners: usize = faces.iter().map(Vec::len).sum();
    nv + corners / 2 + faces.len()
}

/// Split every n-gon into n quads around its centre. Returns positions and quads.
pub fn split_to_quads(p: &[V3], faces: &[Vec<u32>]) -> (Vec<V3>, Vec<[u32; 4]>) {
    let mut pos = p.to_vec();
    let mut mid: HashMap<(u32, u32), u32> = HashMap::new();
    let mut quads = Vec::with_capacity(faces.iter().map(Vec::len).sum());
    for f in faces {
        let n = f.len();
        let mut ms = Vec::with_capacity(n);
        for k in 0..n {
            let (a, b) = (f[k], f[(k + 1) % n]);
            let key = (a.min(b), a.max(b));
            let id = *mid.entry(key).or_insert_with(|| {
                pos.push(scale(add(p[a as usize], p[b as usize]), 0.5));
                (pos.len() - 1) as u32
            });
            ms.push(id);
        }
        let mut c = [0.0; 3];
        for &v in f {
            c = add(c, p[v as usize]);
        }
        pos.push(scale(c, 1.0 / n as f64));
        let cid = (pos.len() - 1) as u32;
        for k in 0..n {
            quads.push([f[k], ms[k], cid, ms[(k + n - 1) % n]]);
        }
    }
    (pos, quads)
}

/// Unit vertex normals of a quad mesh (sum of the quads' diagonal cross products).
pub fn quad_vertex_normals(p: &[V3], quads: &[[u32; 4]]) -> Vec<V3> {
    let mut nrm = vec![[0.0; 3]; p.len()];
    for q in quads {
        let c = quad_normal(p, q);
        for &v in q {
            nrm[v as usize] = add(nrm[v as usize], c);
        }
    }
    for v in &mut nrm {
        let l = vec3::norm(*v);
        if l > 0.0 {
            *v = scale(*v, 1.0 / l);
        }
    }
    nrm
}

/// Twice the vector area of a quad: the cross product of its diagonals.
#[inline]
pub fn quad_normal(p: &[V3], q: &[u32; 4]) -> V3 {
    let [a, b, c, d] = q.map(|i| p[i as usize]);
    cross(sub(c, a), sub(d, b))
}

/// Vertex adjacency (edge neighbours) of a quad mesh as CSR.
pub fn quad_adjacency(nv: usize, quads: &[[u32; 4]]) -> (Vec<u32>, Vec<u32>) {
    let mut pairs: Vec<(u32, u32)> = Vec::with_capacity(quads.len() * 8);
    for q in quads {
        for k in 0..4 {
            let (a, b) = (q[k], q[(k + 1) % 4]);
            pairs.push((a, b));
            pairs.push((b, a));
        }
    }
    pairs.sort_unstable();
    pairs.dedup();
    let mut off = vec![0u32; nv + 1];
    for &(a, _) in &pairs {
        off[a as usize + 1] += 1;
    }
    for i in 0..nv {
        off[i + 1] += off[i];
    }
    (off, pairs.into_iter().map(|(_, b)| b).collect())
}

/// Project every vertex onto the input surface, then `iterations` rounds of tangential Laplacian relaxation
/// (Jacobi, step `lambda`) each followed by re-projection.
pub fn relax_and_project(p: &mut [V3], quads: &[[u32; 4]], bvh: &TriangleBvh, iterations: usize, lambda: f64) {
    let project = |p: &mut [V3]| {
        p.par_iter_mut().for_each(|x| {
            if let Some(c) = bvh.closest(*x) {
                *x = c.point;
            }
        });
    };
    project(p);
    let (off, adj) = quad_adjacency(p.len(), quads);
    for _ in 0..iterations {
        let nrm = quad_vertex_normals(p, quads);
        let cur: &[V3] = p;
        let next: Vec<V3> = (0..cur.len())
            .into_par_iter()
            .map(|v| {
                let (lo, hi) = (off[v] as usize, off[v + 1] as usize);
                if hi == lo {
                    return cur[v];
                }
                let mut avg = [0.0; 3];
                for &u in &adj[lo..hi] {
                    avg = add(avg, cur[u as usize]);
                }
                avg = scale(avg, 1.0 / (hi - lo) as f64);
                let d = sub(avg, cur[v]);
                let n = nrm[v];
                let t = sub(d, scale(n, dot(d, n)));
                add(cur[v], scale(t, lambda))
            })
            .collect();
        p.copy_from_slice(&next);
        project(p);
    }
}

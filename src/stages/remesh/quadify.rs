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

use std::collections::HashMap;

use rayon::prelude::*;

use crate::geometry::bvh::TriangleBvh;
use crate::geometry::polygon::{
    adjacency, compact, edge_set, key, neighbour_lists, polygon_centre, polygon_normal, unique_edges, vertex_normals,
};
use crate::geometry::vec3::{self, V3, add, dot, scale, sub};

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
    pub path_steps: usize,
    /// Extra pieces the extraction pinched off (a thin part cut through), dropped so the result has as many
    /// components as the input, and the faces they held.
    pub components_dropped: usize,
    pub component_faces_dropped: usize,
    /// Quads still flipped after unfolding, collapsed along a diagonal ([`collapse_quads`]).
    pub flipped_quads_collapsed: usize,
}

/// Keep the `keep` largest connected pieces (by face count; ties to the piece with the lowest face index)
/// and drop the others, counting them in `counts`. Pieces are joined through shared vertices, which on a
/// manifold mesh is the same as through shared edges. A closed piece of a few quads that the extraction
/// pinched off a thin part is not part of the shape's boundary: written as a second shell inside one solid it
/// makes the STEP file invalid. Cost O(corners · α).
pub fn keep_largest_components(faces: &mut Vec<Vec<u32>>, keep: usize, counts: &mut CleanupCounts) {
    let keep = keep.max(1);
    let nv = faces.iter().flatten().map(|&v| v as usize + 1).max().unwrap_or(0);
    let mut uf = crate::geometry::topology::UnionFind::new(nv);
    for f in faces.iter() {
        for w in f.windows(2) {
            uf.union(w[0], w[1]);
        }
    }
    let root: Vec<u32> = faces.iter().map(|f| uf.find(f[0])).collect();
    // (faces, first face) per piece, keyed by root.
    let mut pieces: HashMap<u32, (usize, usize)> = HashMap::new();
    for (fi, &r) in root.iter().enumerate() {
        pieces.entry(r).or_insert((0, fi)).0 += 1;
    }
    if pieces.len() <= keep {
        return;
    }
    let mut order: Vec<(u32, (usize, usize))> = pieces.into_iter().collect();
    order.sort_by_key(|&(_, (n, first))| (std::cmp::Reverse(n), first));
    let kept: std::collections::HashSet<u32> = order.iter().take(keep).map(|&(r, _)| r).collect();
    for &(_, (n, _)) in &order[keep..] {
        counts.components_dropped += 1;
        counts.component_faces_dropped += n;
    }
    let mut k = 0;
    faces.retain(|_| {
        k += 1;
        kept.contains(&root[k - 1])
    });
}

/// Split faces that visit a vertex twice into simple cycles.
pub fn split_pinched(faces: &mut Vec<Vec<u32>>, counts: &mut CleanupCounts) {
    let mut out = Vec::with_capacity(faces.len());
    let mut stack: Vec<Vec<u32>> = std::mem::take(faces);
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
    let mut edges = edge_set(faces);
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
            let free = |k: usize| !edges.contains(&key(poly[k], poly[(k + 3) % n]));
            let Some(k) = (0..n).filter(|&k| free(k)).min_by(|&a, &b| {
                let d = |k: usize| vec3::norm2(sub(p[poly[k] as usize], p[poly[(k + 3) % n] as usize]));
                d(a).total_cmp(&d(b)).then(a.cmp(&b))
            }) else {
                break; // every cut would duplicate an edge: leave the polygon (the split handles any n-gon)
            };
            edges.insert(key(poly[k], poly[(k + 3) % n]));
            let quad: Vec<u32> = (0..4).map(|i| poly[(k + i) % n]).collect();
            let rest: Vec<u32> = (0..n - 2).map(|i| poly[(k + 3 + i) % n]).collect();
            out.push(quad);
            poly = rest;
        }
        out.push(poly);
    }
    *faces = out;
}

/// Project every vertex onto the surface of `bvh`, then `iterations` rounds of tangential Laplacian
/// relaxation (Jacobi, step `lambda`) each followed by re-projection. After the first round a vertex is
/// projected onto the nearest input triangle that faces the same way as the mesh at that vertex, so that
/// vertices on thin parts do not jump to the opposite sheet (which would flip faces).
pub fn relax_and_project(p: &mut [V3], faces: &[Vec<u32>], bvh: &TriangleBvh, iterations: usize, lambda: f64) {
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

/// Cut pentagons into a quad and a triangle along their shortest diagonal.
pub fn cut_pentagons(p: &[V3], faces: &mut [Vec<u32>], extra: &mut Vec<Vec<u32>>, counts: &mut CleanupCounts) {
    let mut edges = edge_set(faces);
    for f in faces.iter_mut() {
        if f.len() != 5 {
            continue;
        }
        let free = |k: usize| !edges.contains(&key(f[k], f[(k + 3) % 5]));
        let Some(k) = (0..5).filter(|&k| free(k)).min_by(|&a, &b| {
            let d = |k: usize| vec3::norm2(sub(p[f[k] as usize], p[f[(k + 3) % 5] as usize]));
            d(a).total_cmp(&d(b)).then(a.cmp(&b))
        }) else {
            continue;
        };
        edges.insert(key(f[k], f[(k + 3) % 5]));
        counts.pentagons_cut += 1;
        let quad: Vec<u32> = (0..4).map(|i| f[(k + i) % 5]).collect();
        let tri = vec![f[(k + 3) % 5], f[(k + 4) % 5], f[k]];
        *f = quad;
        extra.push(tri);
    }
}

/// A straight strip between two triangles: apexes, the two side chains and the faces it covers.
struct Strip {
    a: u32,
    b: u32,
    x: Vec<u32>,
    y: Vec<u32>,
    faces: Vec<u32>,
}

/// The new quads of a strip with the rungs shifted to (x[i+1], y[i]) (see [`pair_triangles`]).
fn strip_quads(a: u32, b: u32, x: &[u32], y: &[u32]) -> Vec<Vec<u32>> {
    let k = x.len() - 1;
    (0..=k)
        .map(|i| {
            let mut q = if i == 0 { vec![a, x[0]] } else { vec![y[i - 1], x[i]] };
            if i == k {
                q.extend([b, y[k]]);
            } else {
                q.extend([x[i + 1], y[i]]);
            }
            q
        })
        .collect()
}

/// Pair triangles along straight quad strips of at most `max_len` quads and re-diagonalise each strip, so
/// that the two triangles and the k quads between them become k + 1 quads. Euler characteristic and all
/// other faces are unchanged; two vertices at the strip's ends lose one edge each (the variant whose ends
/// have the higher valence is chosen, and no vertex drops below valence 3). Returns the triangles left.
pub fn pair_triangles(faces: &mut Vec<Vec<u32>>, max_len: usize, rounds: usize, counts: &mut CleanupCounts) -> usize {
    for _ in 0..rounds {
        let mut half: HashMap<(u32, u32), u32> = HashMap::with_capacity(faces.len() * 4);
        let mut valence: HashMap<u32, u32> = HashMap::new();
        for (fi, f) in faces.iter().enumerate() {
            for k in 0..f.len() {
                let (a, b) = (f[k], f[(k + 1) % f.len()]);
                half.insert((a, b), fi as u32);
                if a < b {
                    *valence.entry(a).or_insert(0) += 1;
                    *valence.entry(b).or_insert(0) += 1;
                }
            }
        }
        let tris: Vec<u32> = (0..faces.len() as u32).filter(|&f| faces[f as usize].len() == 3).collect();
        if tris.is_empty() {
            return 0;
        }
        // Candidate strips from every triangle in all three directions.
        let mut cands: Vec<Strip> = Vec::new();
        for &t in &tris {
            let f = &faces[t as usize];
            for k in 0..3 {
                let (mut xv, mut yv) = (f[k], f[(k + 1) % 3]);
                let a = f[(k + 2) % 3];
                let mut strip = Strip { a, b: u32::MAX, x: vec![xv], y: vec![yv], faces: vec![t] };
                for _ in 0..=max_len {
                    let Some(&g) = half.get(&(yv, xv)) else { break };
                    if strip.faces.contains(&g) {
                        break;
                    }
                    let gf = &faces[g as usize];
                    let j = gf.iter().position(|&v| v == yv).expect("half-edge face has the vertex");
                    strip.faces.push(g);
                    if gf.len() == 3 {
                        strip.b = gf[(j + 2) % 3];
                        break;
                    }
                    if gf.len() != 4 {
                        break;
                    }
                    let (nx, ny) = (gf[(j + 2) % 4], gf[(j + 3) % 4]);
                    strip.x.push(nx);
                    strip.y.push(ny);
                    xv = nx;
                    yv = ny;
                }
                if strip.b != u32::MAX && strip.faces.last() > Some(&t) {
                    cands.push(strip);
                }
            }
        }
        cands.sort_by_key(|s| (s.faces.len(), s.faces[0], s.faces[s.faces.len() - 1]));
        let mut used = vec![false; faces.len()];
        let mut new_edges: std::collections::HashSet<(u32, u32)> = std::collections::HashSet::new();
        let mut replaced: Vec<(Vec<u32>, Vec<Vec<u32>>)> = Vec::new();
        for s in cands {
            if s.faces.iter().any(|&f| used[f as usize]) {
                continue;
            }
            // All strip vertices distinct.
            let mut vs: Vec<u32> = s.x.iter().chain(&s.y).copied().chain([s.a, s.b]).collect();
            vs.sort_unstable();
            if vs.windows(2).any(|w| w[0] == w[1]) {
                continue;
            }
            let val = |v: u32| *valence.get(&v).unwrap_or(&0) as i64;
            let k = s.x.len() - 1;
            // Variant A: x[0] and y[k] lose an edge; variant B: y[0] and x[k].
            let gain = |u: u32, w: u32| -> Option<i64> {
                let (vu, vw) = (val(u), val(w));
                if vu <= 3 || vw <= 3 {
                    return None;
                }
                Some(((vu - 4).abs() - (vu - 5).abs()) + ((vw - 4).abs() - (vw - 5).abs()))
            };
            let ga = gain(s.x[0], s.y[k]);
            let gb = gain(s.y[0], s.x[k]);
            let use_b = match (ga, gb) {
                (None, None) => continue,
                (Some(a), Some(b)) => b > a,
                (Some(_), None) => false,
                (None, Some(_)) => true,
            };
            let quads = if use_b { variant_b(&s) } else { strip_quads(s.a, s.b, &s.x, &s.y) };
            // The new diagonals must not exist yet.
            let mut ok = true;
            let mut diag = Vec::new();
            for q in &quads {
                for i in 0..4 {
                    let (u, w) = (q[i], q[(i + 1) % 4]);
                    if !half.contains_key(&(u, w)) && !half.contains_key(&(w, u)) {
                        let e = (u.min(w), u.max(w));
                        if new_edges.contains(&e) {
                            ok = false;
                        }
                        diag.push(e);
                    }
                }
            }
            if !ok {
                continue;
            }
            new_edges.extend(diag);
            for &f in &s.faces {
                used[f as usize] = true;
            }
            counts.triangle_pairs_merged += 1;
            counts.strip_quads_rediagonalised += s.faces.len() - 2;
            replaced.push((s.faces.clone(), quads));
            // Valences change at the ends; refresh them for later candidates of this round.
            let ends = if use_b { [s.y[0], s.x[k]] } else { [s.x[0], s.y[k]] };
            for v in ends {
                *valence.get_mut(&v).expect("strip vertex has edges") -= 1;
            }
        }
        if replaced.is_empty() {
            break;
        }
        let mut out: Vec<Vec<u32>> = faces.iter().zip(&used).filter(|(_, u)| !**u).map(|(f, _)| f.clone()).collect();
        for (_, quads) in replaced {
            out.extend(quads);
        }
        *faces = out;
    }
    faces.iter().filter(|f| f.len() == 3).count()
}

fn variant_b(s: &Strip) -> Vec<Vec<u32>> {
    strip_quads(s.a, s.b, &s.y, &s.x)
        .into_iter()
        .map(|mut q| {
            q.reverse();
            q
        })
        .collect()
}

/// Remove valence-2 vertices shared by exactly two faces ("doublets"): the two faces merge into one.
/// Returns how many were removed.
pub fn remove_doublets(faces: &mut Vec<Vec<u32>>) -> usize {
    let mut removed = 0;
    loop {
        let mut vf: HashMap<u32, Vec<u32>> = HashMap::new();
        let mut nb: HashMap<u32, std::collections::BTreeSet<u32>> = HashMap::new();
        for (fi, f) in faces.iter().enumerate() {
            for k in 0..f.len() {
                vf.entry(f[k]).or_default().push(fi as u32);
                let (a, b) = (f[k], f[(k + 1) % f.len()]);
                nb.entry(a).or_default().insert(b);
                nb.entry(b).or_default().insert(a);
            }
        }
        let mut doublets: Vec<u32> = nb.iter().filter(|(_, s)| s.len() == 2).map(|(&v, _)| v).collect();
        doublets.sort_unstable();
        let mut used = vec![false; faces.len()];
        let mut merged = Vec::new();
        for v in doublets {
            let fs = &vf[&v];
            if fs.len() != 2 || used[fs[0] as usize] || used[fs[1] as usize] {
                continue;
            }
            let rot = |f: &Vec<u32>| -> Vec<u32> {
                let i = f.iter().position(|&x| x == v).expect("face has v");
                f[i..].iter().chain(&f[..i]).copied().collect()
            };
            let (f1, f2) = (rot(&faces[fs[0] as usize]), rot(&faces[fs[1] as usize]));
            // f1 = (v, b, …, a), f2 = (v, a, …, b).
            if f1[1] != *f2.last().expect("≥3") || f2[1] != *f1.last().expect("≥3") {
                continue;
            }
            let mut m: Vec<u32> = f1[1..].to_vec();
            m.extend_from_slice(&f2[2..f2.len() - 1]);
            let mut distinct = m.clone();
            distinct.sort_unstable();
            distinct.dedup();
            if m.len() < 3 || distinct.len() != m.len() {
                continue; // the merged face would visit a vertex twice
            }
            used[fs[0] as usize] = true;
            used[fs[1] as usize] = true;
            merged.push(m);
            removed += 1;
        }
        if merged.is_empty() {
            return removed;
        }
        let mut out: Vec<Vec<u32>> = faces.iter().zip(&used).filter(|(_, u)| !**u).map(|(f, _)| f.clone()).collect();
        out.extend(merged);
        *faces = out;
    }
}

/// Pair the triangles left after [`pair_triangles`] along bent paths: a triangle walks toward the nearest
/// other triangle (breadth-first over quads, at most `max_len` steps) by re-splitting, at each step, the
/// pentagon it forms with the next quad so that the triangle ends up on that quad's far side; when the two
/// triangles meet they merge into a quad. Every step keeps a closed, oriented polygon mesh with the same
/// Euler characteristic. Returns the triangles left.
pub fn pair_triangles_along_paths(
    p: &[V3],
    faces: &mut Vec<Vec<u32>>,
    max_len: usize,
    counts: &mut CleanupCounts,
) -> usize {
    let mut half: HashMap<(u32, u32), usize> = HashMap::with_capacity(faces.len() * 4);
    for (fi, f) in faces.iter().enumerate() {
        for k in 0..f.len() {
            half.insert((f[k], f[(k + 1) % f.len()]), fi);
        }
    }
    let set = |half: &mut HashMap<(u32, u32), usize>, faces: &mut Vec<Vec<u32>>, fi: usize, new: Vec<u32>| {
        let old = std::mem::take(&mut faces[fi]);
        for k in 0..old.len() {
            let e = (old[k], old[(k + 1) % old.len()]);
            if half.get(&e) == Some(&fi) {
                half.remove(&e);
            }
        }
        for k in 0..new.len() {
            half.insert((new[k], new[(k + 1) % new.len()]), fi);
        }
        faces[fi] = new;
    };
    let has_edge =
        |half: &HashMap<(u32, u32), usize>, a: u32, b: u32| half.contains_key(&(a, b)) || half.contains_key(&(b, a));
    let mut tris: Vec<usize> = (0..faces.len()).filter(|&f| faces[f].len() == 3).collect();
    tris.sort_unstable();
    for t0 in tris {
        if faces[t0].len() != 3 {
            continue;
        }
        // Breadth-first search over quads to the nearest other triangle.
        let mut prev: HashMap<usize, usize> = HashMap::new();
        prev.insert(t0, usize::MAX);
        let mut frontier = vec![t0];
        let mut goal = None;
        'bfs: for _ in 0..=max_len {
            let mut next = Vec::new();
            for &f in &frontier {
                let face = &faces[f];
                for k in 0..face.len() {
                    let Some(&g) = half.get(&(face[(k + 1) % face.len()], face[k])) else { continue };
                    if prev.contains_key(&g) {
                        continue;
                    }
                    prev.insert(g, f);
                    if faces[g].len() == 3 {
                        goal = Some(g);
                        break 'bfs;
                    }
                    if faces[g].len() == 4 {
                        next.push(g);
                    }
                }
            }
            if next.is_empty() {
                break;
            }
            frontier = next;
        }
        let Some(goal) = goal else { continue };
        let mut path = vec![goal];
        while let Some(&f) = prev.get(path.last().expect("non-empty")) {
            if f == usize::MAX {
                break;
            }
            path.push(f);
        }
        path.reverse(); // t0, quads…, goal
        // Walk the triangle along the path.
        let mut tri = t0;
        let mut ok = true;
        for w in 1..path.len() - 1 {
            let (q, next) = (path[w], path[w + 1]);
            let t = faces[tri].clone();
            let qf = faces[q].clone();
            // Shared edge: a→b in the triangle, b→a in the quad.
            let Some(k) = (0..3).find(|&k| half.get(&(t[(k + 1) % 3], t[k])) == Some(&q)) else {
                ok = false;
                break;
            };
            let (a, b, c) = (t[k], t[(k + 1) % 3], t[(k + 2) % 3]);
            let j = qf.iter().position(|&v| v == b).expect("quad has b");
            let (x, y) = (qf[(j + 2) % 4], qf[(j + 3) % 4]);
            let pent = [b, c, a, x, y];
            // The edge of the pentagon shared with the next face.
            let Some(i) = (0..5).find(|&i| half.get(&(pent[(i + 1) % 5], pent[i])) == Some(&next)) else {
                ok = false;
                break;
            };
            let opt = |s: usize| -> (Vec<u32>, Vec<u32>, (u32, u32)) {
                // Triangle (pent[s], pent[s+1], pent[s+2]); quad = the other four, diagonal pent[s]–pent[s+2].
                let tr = vec![pent[s % 5], pent[(s + 1) % 5], pent[(s + 2) % 5]];
                let qd = vec![pent[(s + 2) % 5], pent[(s + 3) % 5], pent[(s + 4) % 5], pent[s % 5]];
                (tr, qd, (pent[s % 5], pent[(s + 2) % 5]))
            };
            let mut choices: Vec<(f64, Vec<u32>, Vec<u32>)> = Vec::new();
            for s in [i, (i + 4) % 5] {
                let (tr, qd, (u, v)) = opt(s);
                if has_edge(&half, u, v) {
                    continue;
                }
                choices.push((vec3::norm2(sub(p[u as usize], p[v as usize])), tr, qd));
            }
            choices.sort_by(|l, r| l.0.total_cmp(&r.0));
            let Some((_, tr, qd)) = choices.into_iter().next() else {
                ok = false;
                break;
            };
            set(&mut half, faces, tri, qd);
            set(&mut half, faces, q, tr);
            tri = q;
            counts.path_steps += 1;
        }
        if !ok {
            continue;
        }
        // Merge the two adjacent triangles into a quad.
        let (t, g) = (faces[tri].clone(), faces[goal].clone());
        let Some(k) = (0..3).find(|&k| half.get(&(t[(k + 1) % 3], t[k])) == Some(&goal)) else { continue };
        let (u, v, w) = (t[k], t[(k + 1) % 3], t[(k + 2) % 3]);
        let Some(&xo) = g.iter().find(|&&z| z != u && z != v) else { continue };
        if xo == w {
            continue;
        }
        set(&mut half, faces, goal, Vec::new());
        set(&mut half, faces, tri, vec![u, xo, v, w]);
        counts.triangle_pairs_merged += 1;
        counts.path_pairs += 1;
    }
    faces.retain(|f| !f.is_empty());
    faces.iter().filter(|f| f.len() == 3).count()
}

/// Link condition of the diagonal collapse of quad (a, b, c, d): a and c share no neighbour but b and d
/// (which they always share), so merging them keeps the mesh 2-manifold.
fn collapse_keeps_manifold(nbrs: &[Vec<u32>], a: u32, c: u32) -> bool {
    nbrs[a as usize].iter().filter(|x| nbrs[c as usize].binary_search(x).is_ok()).count() == 2
}

/// Local operations of one pass over a quad mesh, applied so that no two touch each other's rings:
/// diagonal collapses merge a corner into its opposite one and remove the quad; [`Self::rebuild`] then
/// drops the removed quads and renumbers the merged corners.
struct Batch {
    touched: Vec<bool>,
    merge: Vec<u32>,
    removed: Vec<bool>,
}

impl Batch {
    fn new(nv: usize, nf: usize) -> Self {
        Batch { touched: vec![false; nv], merge: (0..nv as u32).collect(), removed: vec![false; nf] }
    }

    /// No vertex of `vs` nor any of their neighbours is touched yet.
    fn ring_free(&self, nbrs: &[Vec<u32>], vs: &[u32]) -> bool {
        vs.iter().all(|&v| !self.touched[v as usize] && nbrs[v as usize].iter().all(|&w| !self.touched[w as usize]))
    }

    fn touch(&mut self, vs: &[u32]) {
        for &v in vs {
            self.touched[v as usize] = true;
        }
    }

    /// Collapse quad `f` = (a, b, c, d): c merges into a at their midpoint.
    fn collapse(&mut self, p: &mut [V3], f: usize, [a, b, c, d]: [u32; 4]) {
        self.touch(&[a, b, c, d]);
        p[a as usize] = scale(add(p[a as usize], p[c as usize]), 0.5);
        self.merge[c as usize] = a;
        self.removed[f] = true;
    }

    /// The faces without the removed quads, merged corners renumbered.
    fn rebuild(&self, faces: &[Vec<u32>]) -> Vec<Vec<u32>> {
        faces
            .iter()
            .zip(&self.removed)
            .filter(|(_, r)| !**r)
            .map(|(f, _)| f.iter().map(|&v| self.merge[v as usize]).collect())
            .collect()
    }
}

/// What [`optimize_valence`] did.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct ValenceCounts {
    /// Quads removed by merging two opposite corners.
    pub diagonal_collapses: usize,
    /// Edges turned to the other diagonals of their two quads' hexagon.
    pub edge_rotations: usize,
    /// Σ|valence − 4| before and after.
    pub irregularity_before: usize,
    pub irregularity_after: usize,
}

/// Lower Σ|valence − 4| of a closed pure-quad mesh with two local operations, greedily, each applied only
/// when it strictly improves its vertices and keeps every valence ≥ 3 and the mesh 2-manifold:
/// - **diagonal collapse** of quad (a, b, c, d): a and c merge at their midpoint (needs N(a) ∩ N(c) =
///   {b, d}); b and d lose an edge;
/// - **edge rotation**: the edge shared by two quads is replaced by another diagonal of their hexagon.
///
/// Merged vertices are removed from `p` and `faces` renumbered. At most `passes` passes.
pub fn optimize_valence(p: &mut Vec<V3>, faces: &mut Vec<Vec<u32>>, passes: usize) -> ValenceCounts {
    let mut counts = ValenceCounts::default();
    let cost = |v: i64| (v - 4).unsigned_abs() as usize;
    for pass in 0..passes {
        let nv = p.len();
        let nbrs = neighbour_lists(nv, faces);
        let mut half: HashMap<(u32, u32), usize> = HashMap::with_capacity(faces.len() * 4);
        for (fi, f) in faces.iter().enumerate() {
            for k in 0..4 {
                half.insert((f[k], f[(k + 1) % 4]), fi);
            }
        }
        let val = |v: u32| nbrs[v as usize].len() as i64;
        if pass == 0 {
            counts.irregularity_before = (0..nv as u32).filter(|&v| val(v) > 0).map(|v| cost(val(v))).sum();
        }
        // Candidates: (gain, kind, data).
        enum Op {
            Collapse { f: usize, a: u32, c: u32 },
            Rotate { f1: usize, f2: usize, quads: [Vec<u32>; 2], u: u32, v: u32, x: u32, y: u32 },
        }
        let mut cands: Vec<(usize, usize, Op)> = Vec::new();
        for (fi, f) in faces.iter().enumerate() {
            for k in 0..2 {
                let (a, b, c, d) = (f[k], f[k + 1], f[(k + 2) % 4], f[(k + 3) % 4]);
                let m = val(a) + val(c) - 2;
                if val(b) < 4 || val(d) < 4 || m < 3 || !collapse_keeps_manifold(&nbrs, a, c) {
                    continue;
                }
                let before = cost(val(a)) + cost(val(b)) + cost(val(c)) + cost(val(d));
                let after = cost(m) + cost(val(b) - 1) + cost(val(d) - 1);
                if after < before {
                    cands.push((before - after, fi, Op::Collapse { f: fi, a, c }));
                }
            }
        }
        // Edges in face order (not the hash map's order, which differs between runs).
        let face_edges = faces.iter().enumerate().flat_map(|(fi, f)| (0..4).map(move |k| (f[k], f[(k + 1) % 4], fi)));
        for (u, v, f1) in face_edges {
            if u > v {
                continue;
            }
            let Some(&f2) = half.get(&(v, u)) else { continue };
            if val(u) < 4 || val(v) < 4 {
                continue;
            }
            let rot = |f: &Vec<u32>, s: u32| -> Vec<u32> {
                let i = f.iter().position(|&x| x == s).expect("face has vertex");
                (0..4).map(|k| f[(i + k) % 4]).collect()
            };
            let g1 = rot(&faces[f1], u); // (u, v, a, b)
            let g2 = rot(&faces[f2], v); // (v, u, c, d)
            let (a, b, c, d) = (g1[2], g1[3], g2[2], g2[3]);
            // Hexagon (v, a, b, u, c, d); the two other diagonals.
            for (x, y, q1, q2) in
                [(a, c, vec![a, b, u, c], vec![c, d, v, a]), (b, d, vec![b, u, c, d], vec![d, v, a, b])]
            {
                if x == y || nbrs[x as usize].binary_search(&y).is_ok() {
                    continue;
                }
                let before = cost(val(u)) + cost(val(v)) + cost(val(x)) + cost(val(y));
                let after = cost(val(u) - 1) + cost(val(v) - 1) + cost(val(x) + 1) + cost(val(y) + 1);
                if after < before {
                    cands.push((before - after, f1.min(f2), Op::Rotate { f1, f2, quads: [q1, q2], u, v, x, y }));
                }
            }
        }
        if cands.is_empty() {
            break;
        }
        cands.sort_by(|l, r| r.0.cmp(&l.0).then(l.1.cmp(&r.1)));
        let mut batch = Batch::new(nv, faces.len());
        let mut changed = vec![false; faces.len()];
        let mut applied = 0;
        for (_, _, op) in cands {
            match op {
                Op::Collapse { f, a, c } => {
                    if batch.removed[f] || changed[f] {
                        continue;
                    }
                    let (b, d) = {
                        let g = &faces[f];
                        let i = g.iter().position(|&x| x == a).expect("has a");
                        (g[(i + 1) % 4], g[(i + 3) % 4])
                    };
                    if !batch.ring_free(&nbrs, &[a, b, c, d]) {
                        continue;
                    }
                    batch.collapse(p, f, [a, b, c, d]);
                    counts.diagonal_collapses += 1;
                    applied += 1;
                }
                Op::Rotate { f1, f2, quads, u, v, x, y } => {
                    if batch.removed[f1]
                        || batch.removed[f2]
                        || changed[f1]
                        || changed[f2]
                        || !batch.ring_free(&nbrs, &[u, v, x, y])
                    {
                        continue;
                    }
                    batch.touch(&[u, v, x, y]);
                    let [q1, q2] = quads;
                    faces[f1] = q1;
                    faces[f2] = q2;
                    changed[f1] = true;
                    changed[f2] = true;
                    counts.edge_rotations += 1;
                    applied += 1;
                }
            }
        }
        if applied == 0 {
            break;
        }
        *faces = batch.rebuild(faces);
    }
    // Drop merged-away vertices.
    *p = compact(p, faces);
    let mut valence = vec![0usize; p.len()];
    for (a, b) in unique_edges(faces.iter().map(Vec::as_slice)) {
        valence[a as usize] += 1;
        valence[b as usize] += 1;
    }
    counts.irregularity_after = valence.iter().map(|&v| cost(v as i64)).sum();
    counts
}

/// Faces whose (Newell) normal points against `surface_normal` of the nearest input triangle to their centre,
/// ascending.
pub fn flipped_faces(
    p: &[V3],
    faces: &[Vec<u32>],
    bvh: &TriangleBvh,
    surface_normal: &(impl Fn(u32) -> V3 + Sync),
) -> Vec<usize> {
    flipped_faces_hinted(p, faces, bvh, surface_normal, &[])
}

/// [`flipped_faces`], each face's query started from `hints[face]` (an input triangle near its centre; the
/// same answer, fewer boxes searched; faces past the end of `hints` start without one).
pub fn flipped_faces_hinted(
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
pub fn collapse_quads(p: &mut Vec<V3>, faces: &mut Vec<Vec<u32>>, which: &[usize]) -> usize {
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
pub fn untangle(
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

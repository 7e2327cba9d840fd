//! Pieces and large faces: keep the input's components, split pinched vertices, cut faces of degree ≥ 6 and
//! pentagons.

use std::collections::HashMap;

use super::CleanupCounts;
use crate::geometry::polygon::{edge_set, key};
use crate::geometry::vec3::{self, V3, sub};

/// Keep the `keep` largest connected pieces (by face count; ties to the piece with the lowest face index)
/// and drop the others, counting them in `counts`. Pieces are joined through shared vertices, which on a
/// manifold mesh is the same as through shared edges. A closed piece of a few quads that the extraction
/// pinched off a thin part is not part of the shape's boundary: written as a second shell inside one solid it
/// makes the STEP file invalid. Cost O(corners · α).
pub(crate) fn keep_largest_components(faces: &mut Vec<Vec<u32>>, keep: usize, counts: &mut CleanupCounts) {
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
pub(crate) fn split_pinched(faces: &mut Vec<Vec<u32>>, counts: &mut CleanupCounts) {
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
pub(crate) fn cut_large_faces(p: &[V3], faces: &mut Vec<Vec<u32>>, counts: &mut CleanupCounts) {
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

/// Cut pentagons into a quad and a triangle along their shortest diagonal.
pub(crate) fn cut_pentagons(p: &[V3], faces: &mut [Vec<u32>], extra: &mut Vec<Vec<u32>>, counts: &mut CleanupCounts) {
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

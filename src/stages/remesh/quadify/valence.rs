//! The valence pass: diagonal collapses and edge rotations that lower Σ|valence − 4|.

use std::collections::HashMap;

use crate::geometry::polygon::{compact, neighbour_lists, unique_edges};
use crate::geometry::vec3::{V3, add, scale};

/// Link condition of the diagonal collapse of quad (a, b, c, d): a and c share no neighbour but b and d
/// (which they always share), so merging them keeps the mesh 2-manifold.
pub(super) fn collapse_keeps_manifold(nbrs: &[Vec<u32>], a: u32, c: u32) -> bool {
    nbrs[a as usize].iter().filter(|x| nbrs[c as usize].binary_search(x).is_ok()).count() == 2
}

/// Local operations of one pass over a quad mesh, applied so that no two touch each other's rings:
/// diagonal collapses merge a corner into its opposite one and remove the quad; [`Self::rebuild`] then
/// drops the removed quads and renumbers the merged corners.
pub(super) struct Batch {
    pub(super) touched: Vec<bool>,
    pub(super) merge: Vec<u32>,
    pub(super) removed: Vec<bool>,
}

impl Batch {
    pub(super) fn new(nv: usize, nf: usize) -> Self {
        Batch { touched: vec![false; nv], merge: (0..nv as u32).collect(), removed: vec![false; nf] }
    }

    /// No vertex of `vs` nor any of their neighbours is touched yet.
    pub(super) fn ring_free(&self, nbrs: &[Vec<u32>], vs: &[u32]) -> bool {
        vs.iter().all(|&v| !self.touched[v as usize] && nbrs[v as usize].iter().all(|&w| !self.touched[w as usize]))
    }

    pub(super) fn touch(&mut self, vs: &[u32]) {
        for &v in vs {
            self.touched[v as usize] = true;
        }
    }

    /// Collapse quad `f` = (a, b, c, d): c merges into a at their midpoint.
    pub(super) fn collapse(&mut self, p: &mut [V3], f: usize, [a, b, c, d]: [u32; 4]) {
        self.touch(&[a, b, c, d]);
        p[a as usize] = scale(add(p[a as usize], p[c as usize]), 0.5);
        self.merge[c as usize] = a;
        self.removed[f] = true;
    }

    /// The faces without the removed quads, merged corners renumbered.
    pub(super) fn rebuild(&self, faces: &[Vec<u32>]) -> Vec<Vec<u32>> {
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
    /// Σ|valence − 4| after.
    pub irregularity_after: usize,
}

/// Lower Σ|valence − 4| of a closed pure-quad mesh with two local operations, greedily, each applied only
/// when it strictly improves its vertices and keeps every valence ≥ 3 and the mesh 2-manifold:
/// - **diagonal collapse** of quad (a, b, c, d): a and c merge at their midpoint (needs N(a) ∩ N(c) =
///   {b, d}); b and d lose an edge;
/// - **edge rotation**: the edge shared by two quads is replaced by another diagonal of their hexagon.
///
/// Merged vertices are removed from `p` and `faces` renumbered. At most `passes` passes.
pub(crate) fn optimize_valence(p: &mut Vec<V3>, faces: &mut Vec<Vec<u32>>, passes: usize) -> ValenceCounts {
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

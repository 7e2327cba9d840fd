//! The multi-resolution vertex graph the fields are solved on (Instant Meshes' `downsample_graph`).
//!
//! Level 0 is the working triangle mesh's vertex graph. Each coarser level matches pairs of adjacent
//! vertices greedily: edges are ranked by normal agreement times area balance, so flat, even regions merge
//! first. Every level is greedily graph-coloured so that one colour class can be updated in parallel
//! without races (Gauss–Seidel over colour classes, deterministic for any thread count).

use crate::geometry::polygon::csr;
use crate::geometry::vec3::{self, V3};

/// One level of the hierarchy.
#[derive(Clone, Debug, Default)]
pub struct Level {
    /// Vertex positions.
    pub p: Vec<V3>,
    /// Unit normals.
    pub n: Vec<V3>,
    /// Dual (Voronoi-like) areas: one third of the adjacent triangles' areas, summed up the hierarchy.
    pub area: Vec<f64>,
    /// CSR offsets into `adj`/`w` (`p.len() + 1` entries).
    pub off: Vec<u32>,
    /// Neighbour indices.
    pub adj: Vec<u32>,
    /// Edge weights (number of fine edges merged into this one).
    pub w: Vec<f32>,
    /// Vertices of each colour class; no two vertices of one class are adjacent.
    pub colours: Vec<Vec<u32>>,
    /// Index of each vertex's parent on the next coarser level (empty on the coarsest).
    pub parent: Vec<u32>,
}

impl Level {
    /// Neighbours and weights of vertex `i`.
    #[inline]
    pub fn neighbours(&self, i: usize) -> impl Iterator<Item = (usize, f64)> + '_ {
        let (a, b) = (self.off[i] as usize, self.off[i + 1] as usize);
        self.adj[a..b].iter().zip(&self.w[a..b]).map(|(&j, &w)| (j as usize, w as f64))
    }

    /// Number of vertices.
    pub fn len(&self) -> usize {
        self.p.len()
    }

    /// True for an empty level.
    pub fn is_empty(&self) -> bool {
        self.p.is_empty()
    }
}

/// Build level 0 from a triangle mesh: area-weighted normals, dual areas and the edge graph.
///
/// Cost: O(F log F).
pub fn finest_level(p: &[V3], tris: &[[u32; 3]]) -> Level {
    let n = p.len();
    let mut normal = vec![[0.0; 3]; n];
    let mut area = vec![0.0; n];
    let mut edges: Vec<(u32, u32)> = Vec::with_capacity(tris.len() * 6);
    for &t in tris {
        let c = vec3::tri_cross(p, t);
        let a = 0.5 * vec3::norm(c);
        for k in 0..3 {
            let v = t[k] as usize;
            normal[v] = vec3::add(normal[v], c);
            area[v] += a / 3.0;
            let (x, y) = (t[k], t[(k + 1) % 3]);
            edges.push((x, y));
            edges.push((y, x));
        }
    }
    for nv in &mut normal {
        let l = vec3::norm(*nv);
        *nv = if l > 0.0 { vec3::scale(*nv, 1.0 / l) } else { [0.0, 0.0, 1.0] };
    }
    edges.sort_unstable();
    edges.dedup();
    let (off, adj) = csr(n, &edges);
    let w = vec![1.0; adj.len()];
    let mut level = Level { p: p.to_vec(), n: normal, area, off, adj, w, colours: Vec::new(), parent: Vec::new() };
    level.colours = colour(&level);
    level
}

/// Greedy colouring in vertex order: each vertex takes the smallest colour none of its neighbours has.
pub fn colour(level: &Level) -> Vec<Vec<u32>> {
    let n = level.len();
    let mut col = vec![u32::MAX; n];
    let mut used: Vec<u32> = Vec::new();
    let mut classes: Vec<Vec<u32>> = Vec::new();
    for i in 0..n {
        used.clear();
        used.extend(level.neighbours(i).map(|(j, _)| col[j]).filter(|&c| c != u32::MAX));
        used.sort_unstable();
        let mut c = 0u32;
        for &u in &used {
            if u == c {
                c += 1;
            } else if u > c {
                break;
            }
        }
        col[i] = c;
        if classes.len() <= c as usize {
            classes.resize_with(c as usize + 1, Vec::new);
        }
        classes[c as usize].push(i as u32);
    }
    classes
}

/// Match adjacent pairs and build the next coarser level; records `fine.parent`.
///
/// Cost: O(E log E).
pub fn coarsen(fine: &mut Level) -> Level {
    let n = fine.len();
    let mut cand: Vec<(f64, u32, u32)> = Vec::with_capacity(fine.adj.len() / 2);
    for i in 0..n {
        for (j, _) in fine.neighbours(i) {
            if j > i {
                let (ai, aj) = (fine.area[i], fine.area[j]);
                let balance = if ai > aj {
                    aj / ai
                } else if aj > 0.0 {
                    ai / aj
                } else {
                    1.0
                };
                cand.push((vec3::dot(fine.n[i], fine.n[j]) * balance, i as u32, j as u32));
            }
        }
    }
    // Descending score; ties broken by index so the result is deterministic.
    cand.sort_unstable_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
    let mut parent = vec![u32::MAX; n];
    let mut next = 0u32;
    for &(_, i, j) in &cand {
        if parent[i as usize] == u32::MAX && parent[j as usize] == u32::MAX {
            parent[i as usize] = next;
            parent[j as usize] = next;
            next += 1;
        }
    }
    for p in parent.iter_mut() {
        if *p == u32::MAX {
            *p = next;
            next += 1;
        }
    }
    let m = next as usize;
    let mut p = vec![[0.0; 3]; m];
    let mut nrm = vec![[0.0; 3]; m];
    let mut area = vec![0.0; m];
    for i in 0..n {
        let c = parent[i] as usize;
        let a = fine.area[i].max(1e-300);
        p[c] = vec3::add(p[c], vec3::scale(fine.p[i], a));
        nrm[c] = vec3::add(nrm[c], vec3::scale(fine.n[i], a));
        area[c] += a;
    }
    for c in 0..m {
        p[c] = vec3::scale(p[c], 1.0 / area[c]);
        nrm[c] = vec3::unit_or(nrm[c], [0.0, 0.0, 1.0]);
    }
    let mut pairs: Vec<(u32, u32, f32)> = Vec::with_capacity(fine.adj.len());
    for i in 0..n {
        for (j, w) in fine.neighbours(i) {
            let (a, b) = (parent[i], parent[j]);
            if a != b {
                pairs.push((a, b, w as f32));
            }
        }
    }
    pairs.sort_unstable_by_key(|x| (x.0, x.1));
    let mut merged: Vec<(u32, u32)> = Vec::with_capacity(pairs.len());
    let mut w: Vec<f32> = Vec::with_capacity(pairs.len());
    for (a, b, wt) in pairs {
        if merged.last() == Some(&(a, b)) {
            *w.last_mut().expect("pushed together") += wt;
        } else {
            merged.push((a, b));
            w.push(wt);
        }
    }
    let (off, adj) = csr(m, &merged);
    fine.parent = parent;
    let mut level = Level { p, n: nrm, area, off, adj, w, colours: Vec::new(), parent: Vec::new() };
    level.colours = colour(&level);
    level
}

/// The whole hierarchy, finest first, down to a few vertices (at most 25 levels).
pub fn build(p: &[V3], tris: &[[u32; 3]]) -> Vec<Level> {
    let mut levels = vec![finest_level(p, tris)];
    while levels.len() < 25 {
        let last = levels.last_mut().expect("non-empty");
        if last.len() <= 16 {
            break;
        }
        let before = last.len();
        let next = coarsen(last);
        if next.len() * 10 > before * 9 {
            // Matching stalled (e.g. isolated vertices): stop here.
            last.parent.clear();
            break;
        }
        levels.push(next);
    }
    levels
}

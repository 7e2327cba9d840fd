//! Quad control nets: half-edge adjacency, one Catmull–Clark refinement step expressed as sparse stencils,
//! and the 4×4 control grid of a regular face.
//!
//! Half-edge `h = 4·f + i` runs from corner `i` of face `f` to corner `i + 1`. Faces are counter-clockwise
//! seen from outside, so `∂u × ∂v` of a face frame that starts at a corner points outward.

use crate::error::{Error, ErrorCode, Result};
use std::collections::{HashMap, HashSet};

/// A block of faces as a lattice ([`QuadNet::lattice_block`]): the control grid's vertices, and each face of
/// the block with the corner at which its frame starts.
pub type LatticeBlock = (Vec<u32>, Vec<(u32, u8)>);

/// Marks a half-edge without a twin (boundary of a local patch).
pub const NO_TWIN: u32 = u32::MAX;

/// Sparse rows: row `r` is `entries[offsets[r]..offsets[r + 1]]`, each `(column, weight)`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Stencils {
    /// Start of each row in `entries`; one more than the rows.
    pub offsets: Vec<u32>,
    /// (column, weight) of every row, row after row.
    pub entries: Vec<(u32, f64)>,
}

impl Stencils {
    /// An empty matrix with no rows.
    pub fn new() -> Self {
        Stencils { offsets: vec![0], entries: Vec::new() }
    }

    /// Number of rows.
    pub fn rows(&self) -> usize {
        self.offsets.len() - 1
    }

    /// Row `r`.
    pub fn row(&self, r: usize) -> &[(u32, f64)] {
        &self.entries[self.offsets[r] as usize..self.offsets[r + 1] as usize]
    }

    /// Append a row, merging repeated columns (kept in first-seen order, so the result is deterministic).
    pub fn push_merged(&mut self, row: &[(u32, f64)]) {
        let start = self.entries.len();
        for &(c, w) in row {
            if let Some(e) = self.entries[start..].iter_mut().find(|e| e.0 == c) {
                e.1 += w;
            } else {
                self.entries.push((c, w));
            }
        }
        self.offsets.push(self.entries.len() as u32);
    }

    /// `values` (one `D`-vector per column) mapped through every row (rows in parallel).
    pub fn apply<const D: usize>(&self, values: &[[f64; D]]) -> Vec<[f64; D]> {
        use rayon::prelude::*;
        (0..self.rows())
            .into_par_iter()
            .map(|r| {
                let mut acc = [0.0; D];
                for &(c, w) in self.row(r) {
                    let v = &values[c as usize];
                    for k in 0..D {
                        acc[k] += w * v[k];
                    }
                }
                acc
            })
            .collect()
    }
}

/// `Σ w · p[i]` over a stencil row.
pub fn combine(row: &[(u32, f64)], p: &[[f64; 3]]) -> [f64; 3] {
    let mut acc = [0.0; 3];
    for &(i, w) in row {
        for k in 0..3 {
            acc[k] += w * p[i as usize][k];
        }
    }
    acc
}

/// A quad mesh with half-edge twins. Closed nets have a twin for every half-edge; local patches (used to
/// evaluate near extraordinary vertices) may have boundary half-edges.
#[derive(Clone, Debug)]
pub struct QuadNet {
    /// Corners of each face, counter-clockwise seen from outside.
    pub faces: Vec<[u32; 4]>,
    /// Vertices the faces index into.
    pub vertex_count: usize,
    /// Twin of each half-edge, or [`NO_TWIN`].
    pub twin: Vec<u32>,
    /// One outgoing half-edge per vertex; for a boundary vertex the one that starts its fan
    /// (no twin on its previous half-edge), so a CCW walk covers the whole fan.
    pub out: Vec<u32>,
}

impl QuadNet {
    /// Build adjacency.
    ///
    /// # Errors
    /// `surface.bad-net` when an index is out of range, a face repeats a vertex, a directed edge occurs twice
    /// (non-manifold or inconsistently oriented), a vertex is unused, or — with `closed` — an edge has one
    /// face only. The message names the first offending face or vertex. Cost: O(F) expected.
    pub fn new(faces: Vec<[u32; 4]>, vertex_count: usize, closed: bool) -> Result<Self> {
        let bad = |m: String| Error::new(ErrorCode::SurfaceBadNet, m);
        let mut directed: HashMap<(u32, u32), u32> = HashMap::with_capacity(faces.len() * 4);
        for (f, q) in faces.iter().enumerate() {
            for i in 0..4 {
                let (a, b) = (q[i], q[(i + 1) % 4]);
                if a as usize >= vertex_count || b as usize >= vertex_count {
                    return Err(bad(format!("face {f} refers to vertex {} of {vertex_count}", a.max(b))));
                }
                if q[..i].contains(&q[i]) {
                    return Err(bad(format!("face {f} uses vertex {} twice", q[i])));
                }
                if directed.insert((a, b), (4 * f + i) as u32).is_some() {
                    return Err(bad(format!(
                        "edge {a}→{b} occurs twice in the same direction (face {f}): non-manifold or misoriented"
                    )));
                }
            }
        }
        let mut twin = vec![NO_TWIN; faces.len() * 4];
        for (f, q) in faces.iter().enumerate() {
            for i in 0..4 {
                let (a, b) = (q[i], q[(i + 1) % 4]);
                match directed.get(&(b, a)) {
                    Some(&t) => twin[4 * f + i] = t,
                    None if closed => {
                        return Err(bad(format!("edge {a}–{b} of face {f} has no second face: the net is open")));
                    }
                    None => {}
                }
            }
        }
        let mut out = vec![NO_TWIN; vertex_count];
        for h in 0..faces.len() * 4 {
            let v = faces[h / 4][h % 4] as usize;
            let starts_fan = twin[prev(h as u32) as usize] == NO_TWIN;
            if out[v] == NO_TWIN || starts_fan {
                out[v] = h as u32;
            }
        }
        if let Some(v) = out.iter().position(|&h| h == NO_TWIN) {
            return Err(bad(format!("vertex {v} belongs to no face")));
        }
        let net = QuadNet { faces, vertex_count, twin, out };
        if closed {
            // Every vertex fan must be one disc: walking around it returns to the start within its degree.
            let mut degree = vec![0u32; vertex_count];
            for q in &net.faces {
                for &v in q {
                    degree[v as usize] += 1;
                }
            }
            for v in 0..vertex_count {
                if net.valence(v as u32) != degree[v] as usize {
                    return Err(bad(format!("vertex {v} is a pinch point (its faces form more than one fan)")));
                }
            }
        }
        Ok(net)
    }

    /// Start vertex of half-edge `h`.
    pub fn from(&self, h: u32) -> u32 {
        self.faces[(h / 4) as usize][(h % 4) as usize]
    }

    /// End vertex of half-edge `h`.
    pub fn to(&self, h: u32) -> u32 {
        self.from(next(h))
    }

    /// Outgoing half-edges of `v` in counter-clockwise order (for a boundary vertex, the fan in order).
    pub fn outgoing(&self, v: u32) -> Vec<u32> {
        let start = self.out[v as usize];
        let mut res = vec![start];
        let mut h = start;
        loop {
            let t = self.twin[prev(h) as usize];
            if t == NO_TWIN || t == start || res.len() > 64 {
                break;
            }
            res.push(t);
            h = t;
        }
        res
    }

    /// Number of edges at `v` for an interior vertex (number of faces around it).
    pub fn valence(&self, v: u32) -> usize {
        self.outgoing(v).len()
    }

    /// Whether the fan of `v` is complete (no boundary edge at `v`).
    pub fn is_interior(&self, v: u32) -> bool {
        let start = self.out[v as usize];
        self.twin[prev(start) as usize] != NO_TWIN
    }

    /// Undirected edges: the edge of every half-edge, and a representative half-edge (the lower-numbered
    /// of the two) of every edge, in order of first half-edge.
    pub fn edges(&self) -> (Vec<u32>, Vec<u32>) {
        let nh = self.faces.len() * 4;
        let mut edge_of = vec![u32::MAX; nh];
        let mut edge_half: Vec<u32> = Vec::with_capacity(nh / 2 + 1);
        for h in 0..nh {
            if edge_of[h] == u32::MAX {
                edge_of[h] = edge_half.len() as u32;
                let t = self.twin[h];
                if t != NO_TWIN {
                    edge_of[t as usize] = edge_half.len() as u32;
                }
                edge_half.push(h as u32);
            }
        }
        (edge_of, edge_half)
    }

    /// One Catmull–Clark step. New vertices: vertex points (same index as the old vertex), then one edge
    /// point per undirected edge (in order of first half-edge), then one face point per face. Sub-face
    /// `4·f + i` is the one at corner `i` of face `f`: `[vertex point, edge point of (i, i+1), face point,
    /// edge point of (i−1, i)]`. Boundary vertices and edges (local patches only) get simple averages whose
    /// values are never used for the regular sub-patches this module extracts.
    pub fn refine(&self) -> (QuadNet, Stencils) {
        let nv = self.vertex_count;
        let (edge_of, edges) = self.edges();
        let ne = edges.len();
        let nf = self.faces.len();
        let mut st = Stencils { offsets: Vec::with_capacity(nv + ne + nf + 1), entries: Vec::new() };
        st.offsets.push(0);
        let mut row: Vec<(u32, f64)> = Vec::with_capacity(64);
        // Vertex points.
        for v in 0..nv as u32 {
            row.clear();
            if self.is_interior(v) {
                let outs = self.outgoing(v);
                let n = outs.len() as f64;
                // (F + 2R + (n − 3)V) / n with F the mean face point, R the mean edge midpoint.
                row.push((v, (n - 3.0) / n));
                for &h in &outs {
                    let f = (h / 4) as usize;
                    for &c in &self.faces[f] {
                        row.push((c, 1.0 / (4.0 * n * n)));
                    }
                    row.push((v, 2.0 / (2.0 * n * n)));
                    row.push((self.to(h), 2.0 / (2.0 * n * n)));
                }
            } else {
                row.push((v, 1.0));
            }
            st.push_merged(&row);
        }
        // Edge points.
        for &h in &edges {
            row.clear();
            let t = self.twin[h as usize];
            let (a, b) = (self.from(h), self.to(h));
            if t == NO_TWIN {
                row.extend([(a, 0.5), (b, 0.5)]);
            } else {
                row.extend([(a, 0.25), (b, 0.25)]);
                for f in [h / 4, t / 4] {
                    for &c in &self.faces[f as usize] {
                        row.push((c, 1.0 / 16.0));
                    }
                }
            }
            st.push_merged(&row);
        }
        // Face points.
        for q in &self.faces {
            row.clear();
            row.extend(q.iter().map(|&c| (c, 0.25)));
            st.push_merged(&row);
        }
        let ep = |h: usize| nv as u32 + edge_of[h];
        let mut faces = Vec::with_capacity(4 * nf);
        for (f, q) in self.faces.iter().enumerate() {
            let fp = (nv + ne + f) as u32;
            for i in 0..4 {
                faces.push([q[i], ep(4 * f + i), fp, ep(4 * f + (i + 3) % 4)]);
            }
        }
        // Twins of the refined net follow from the old ones; rebuilding by hashing is simpler and as fast.
        let net = QuadNet::new(faces, nv + ne + nf, false).expect("refinement of a valid net is valid");
        (net, st)
    }

    /// The 4×4 control grid of face `f` in the frame whose origin is corner `start` (u toward corner
    /// `start + 1`, v toward corner `start + 3`): `grid[4·j + i]` is the vertex at lattice point
    /// `(i − 1, j − 1)`. `None` when the neighbourhood is not a regular 3×3 block of faces (a corner of
    /// valence ≠ 4, a boundary, or a fold).
    pub fn grid16(&self, f: usize, start: usize) -> Option<[u32; 16]> {
        let (g, _) = self.lattice_block(f, start, 1, 1)?;
        g.try_into().ok()
    }

    /// Control grid of a `w × h` block of faces whose lower-left face is `f` (frame from corner `start`):
    /// `(w + 3) × (h + 3)` vertices, row-major in v (`grid[(w + 3)·j + i]` at lattice `(i − 1, j − 1)`), and
    /// the block's own faces row-major over its cells (`cells[w·j + i]`), each with the corner where its
    /// frame (aligned with the block's) starts. `None` when the faces do not form such a block with a
    /// regular one-ring.
    pub fn lattice_block(&self, f: usize, start: usize, w: usize, h: usize) -> Option<LatticeBlock> {
        let (gw, gh) = (w + 3, h + 3);
        let mut grid = vec![u32::MAX; gw * gh];
        let mut seen: HashSet<u32> = HashSet::new();
        let in_block = |x: i64, y: i64| x >= -1 && x <= w as i64 && y >= -1 && y <= h as i64;
        // Face with its four corner lattice points, in the face's own corner order.
        let unit = [(0i64, 0i64), (1, 0), (1, 1), (0, 1)];
        let mut coords = [(0i64, 0i64); 4];
        for k in 0..4 {
            coords[(start + k) % 4] = unit[k];
        }
        let mut queue = vec![(f, coords)];
        seen.insert(f as u32);
        let mut used_cells: HashSet<(i64, i64)> = HashSet::new();
        let mut cells = vec![(u32::MAX, 0u8); w * h];
        while let Some((face, c)) = queue.pop() {
            let cell = (c.iter().map(|p| p.0).min().unwrap(), c.iter().map(|p| p.1).min().unwrap());
            if !used_cells.insert(cell) {
                return None;
            }
            if cell.0 >= 0 && cell.1 >= 0 && (cell.0 as usize) < w && (cell.1 as usize) < h {
                let k = c.iter().position(|&p| p == cell)? as u8;
                cells[cell.1 as usize * w + cell.0 as usize] = (face as u32, k);
            }
            for k in 0..4 {
                let (x, y) = c[k];
                let slot = ((y + 1) as usize) * gw + (x + 1) as usize;
                let v = self.faces[face][k];
                if grid[slot] == u32::MAX {
                    grid[slot] = v;
                } else if grid[slot] != v {
                    return None;
                }
            }
            for i in 0..4 {
                let (a, b, cc) = (c[i], c[(i + 1) % 4], c[(i + 2) % 4]);
                let d = (cc.0 - b.0, cc.1 - b.1);
                let t = self.twin[4 * face + i];
                let nb = [(a.0 - d.0, a.1 - d.1), (b.0 - d.0, b.1 - d.1)];
                let ncell = (a.0.min(b.0).min(nb[0].0), a.1.min(b.1).min(nb[0].1));
                if !in_block(ncell.0, ncell.1) {
                    continue;
                }
                if t == NO_TWIN {
                    return None;
                }
                let g = (t / 4) as usize;
                if !seen.insert(g as u32) {
                    continue;
                }
                let j = (t % 4) as usize;
                let mut gc = [(0i64, 0i64); 4];
                gc[j] = b;
                gc[(j + 1) % 4] = a;
                gc[(j + 2) % 4] = nb[0];
                gc[(j + 3) % 4] = nb[1];
                queue.push((g, gc));
            }
        }
        // Every cell of the block and its ring filled by a distinct face (a block wrapped around a handle
        // meets itself and leaves a cell empty).
        if grid.contains(&u32::MAX) || used_cells.len() != (w + 2) * (h + 2) {
            return None;
        }
        Some((grid, cells))
    }
}

/// Next half-edge in the same face.
pub fn next(h: u32) -> u32 {
    (h & !3) | ((h + 1) & 3)
}

/// Previous half-edge in the same face.
pub fn prev(h: u32) -> u32 {
    (h & !3) | ((h + 3) & 3)
}

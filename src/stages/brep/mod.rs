//! **brep / step** — the fitted Catmull–Clark surface as a watertight solid of bicubic B-spline faces, and
//! its ISO 10303-21 (STEP AP214) text.
//!
//! Construction ([`build_solid`]):
//! 1. [`patches`]: one Bézier patch per face of the once-refined net (exact on regular faces, fitted with
//!    shared boundary curves around extraordinary vertices).
//! 2. Packing: greedy maximal rectangles of regular faces become one clamped bicubic B-spline face each
//!    (C² inside); every other face stays a single Bézier face.
//! 3. Topology: a B-rep edge for every refined edge between two different faces (its cubic curve shared by
//!    both), a vertex for every end of such an edge, one outer loop per face, counter-clockwise in (u, v)
//!    so `∂u × ∂v` points out of the solid.
//!
//! [`check`] is our own validity check (closed, each edge used once in each direction, loops chain, edge
//! curves on both faces' boundaries within [`BREP_EDGE_REL`] of the diagonal, positive volume). [`step`]
//! writes the solid.

pub mod bspline;
pub mod patches;
pub mod step;

use rayon::prelude::*;

use crate::error::{Error, ErrorCode, Result};
use crate::geometry::mesh::TriMesh;
use crate::geometry::subdivision::limit::FaceKind;
use crate::geometry::subdivision::{LimitSurface, QuadNet};
use crate::geometry::tolerance::BREP_EDGE_REL;
use crate::geometry::vec3::{self, Aabb, V3};
use bspline::{BsplineSurface, bezier_point};
use patches::{FaceNet, Patches};

/// Largest packed face, in refined faces per side. Larger blocks halve the face count again, but faces that
/// wrap far around a thin part defeat gmsh's parametric surface mesher (measured on Spot at 48).
pub const MAX_PACK_SIDE: usize = 16;

/// A use of an edge by a face loop: the edge, whether the loop runs along the curve's direction, and the
/// parameter points of the coedge's start and end on the face surface (edges are iso-parameter lines).
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Coedge {
    pub edge: u32,
    pub forward: bool,
    pub uv: [[f64; 2]; 2],
}

/// A topological edge with its curve from `start` to `end`: a piecewise cubic Bézier over the ascending
/// breaks `knots` (span i, on `[knots[i], knots[i+1]]`, is `curve[3i..=3i+3]`), from 0 to the number of
/// refined edges it runs along; a face loop's coedge maps it linearly onto its `uv` segment.
#[derive(Clone, Debug, PartialEq)]
pub struct Edge {
    pub start: u32,
    pub end: u32,
    pub curve: Vec<V3>,
    pub knots: Vec<f64>,
}

impl Edge {
    /// Number of cubic spans.
    pub fn spans(&self) -> usize {
        (self.curve.len() - 1) / 3
    }

    /// Parameter length (the last break).
    pub fn length(&self) -> f64 {
        *self.knots.last().expect("a break")
    }

    /// The curve at parameter `t ∈ [0, length]`.
    pub fn point(&self, t: f64) -> V3 {
        let n = self.spans();
        let i = (0..n).find(|&i| t < self.knots[i + 1]).unwrap_or(n - 1);
        let span: [V3; 4] = std::array::from_fn(|k| self.curve[3 * i + k]);
        bezier_point(&span, (t - self.knots[i]) / (self.knots[i + 1] - self.knots[i]))
    }
}

/// A face: a B-spline surface bounded by one outer loop.
#[derive(Clone, Debug, PartialEq)]
pub struct Face {
    pub surface: BsplineSurface,
    pub bound: Vec<Coedge>,
}

/// A closed solid bounded by one shell.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct Solid {
    pub vertices: Vec<V3>,
    pub edges: Vec<Edge>,
    pub faces: Vec<Face>,
}

/// Numbers that describe a built solid.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct BrepReport {
    pub faces: usize,
    /// Faces that are packed blocks of more than one refined face.
    pub packed_faces: usize,
    /// Refined faces (one Bézier patch each before packing).
    pub patches: usize,
    pub extraordinary_patches: usize,
    pub edges: usize,
    pub vertices: usize,
    /// Enclosed volume (Gauss quadrature on the exact surfaces; exact up to rounding).
    pub volume: f64,
    pub area: f64,
    /// Largest normal jump across patch edges, degrees (11 samples per edge).
    pub max_normal_jump_deg: f64,
    /// 99th percentile over edges of the per-edge largest jump, degrees.
    pub p99_normal_jump_deg: f64,
    /// Where the largest jump is, and whether that edge touches an extraordinary patch.
    pub max_normal_jump_at: V3,
    pub max_normal_jump_at_extraordinary: bool,
    /// Fraction along that edge and the valences of its two vertices (refined net).
    pub max_normal_jump_at_fraction: f64,
    pub max_normal_jump_at_valences: [usize; 2],
    /// Largest distance between an edge curve and the face boundaries that use it, model units.
    pub max_edge_deviation: f64,
    /// Intersecting triangle pairs of a welded tessellation of the solid (set by the pipeline; 0 = the
    /// surface does not cross itself at that resolution).
    pub self_intersections: usize,
    /// A point of the first intersecting pair.
    pub self_intersection_at: Option<V3>,
    /// Intersecting triangle pairs of the quad control mesh it was built from (set by the pipeline).
    pub quad_self_intersections: usize,
    /// Faces whose surface folds over inside ([`Solid::folds`]): the normal turns by more than 90°
    /// between neighbouring samples 1/[`FOLD_SAMPLES`] of a knot span apart, or vanishes. Such a pleat need
    /// not make the tessellation cross itself, yet a mesher's parametric 2-D step can fail on the face.
    pub folded_faces: usize,
    /// A point of the first folded face.
    pub fold_at: Option<V3>,
}

/// Samples per knot span and direction of the fold check ([`Solid::folds`]).
pub const FOLD_SAMPLES: usize = 8;

/// A w × h block of refined faces that becomes one B-rep face.
struct Block {
    w: usize,
    h: usize,
    /// `(face, frame start)` row-major over the block's cells.
    cells: Vec<(u32, u8)>,
    /// Control grid of a packed regular block.
    grid: Option<Vec<u32>>,
}

/// The face across side `k` of face `f` (frame from corner `s`; sides 0: v = 0, 1: u = 1, 2: v = 1,
/// 3: u = 0) with the corner where its frame, aligned with `f`'s, starts.
fn across(net: &QuadNet, (f, s): (u32, u8), k: usize) -> Option<(u32, u8)> {
    let t = net.twin[4 * f as usize + (s as usize + k) % 4];
    if t == crate::geometry::subdivision::net::NO_TWIN {
        return None;
    }
    let j = (t % 4) as usize;
    Some((t / 4, ((j + 4 - (k + 2) % 4) % 4) as u8))
}

/// Greedy packing of the refined faces into rectangles whose interior vertices are all regular (valence
/// 4), grown alternately along u and v from each face not yet taken. A rectangle of regular faces with a
/// regular one-ring becomes a C² B-spline face; any other becomes a piecewise-Bézier B-spline face
/// (triple interior knots; its patches join as before packing).
fn pack(surface: &LimitSurface) -> Vec<Block> {
    let net = &surface.net;
    let nf = net.faces.len();
    let mut taken = vec![false; nf];
    let mut blocks = Vec::new();
    for f in 0..nf {
        if taken[f] {
            continue;
        }
        let first = (f as u32, surface.frame_start(f) as u8);
        let mut rows: Vec<Vec<(u32, u8)>> = vec![vec![first]];
        let mut members: std::collections::HashSet<u32> = [f as u32].into_iter().collect();
        let mut corners: std::collections::HashSet<u32> = net.faces[f].into_iter().collect();
        taken[f] = true;
        // Try to add a line of cells beyond side `k` (1: a column at u = w, 2: a row at v = h).
        let try_grow = |rows: &mut Vec<Vec<(u32, u8)>>,
                        members: &mut std::collections::HashSet<u32>,
                        corners: &mut std::collections::HashSet<u32>,
                        k: usize|
         -> bool {
            let (w, h) = (rows[0].len(), rows.len());
            let edge: Vec<(u32, u8)> =
                if k == 1 { (0..h).map(|j| rows[j][w - 1]).collect() } else { rows[h - 1].clone() };
            let along = if k == 1 { 2 } else { 1 };
            let mut new = Vec::with_capacity(edge.len());
            for &c in &edge {
                match across(net, c, k) {
                    Some(g) if !taken[g.0 as usize] && !members.contains(&g.0) && !new.contains(&g) => new.push(g),
                    _ => return false,
                }
            }
            // Consecutive new cells are neighbours along the line (closing the fans of the new interior
            // vertices), and no new cell touches the block anywhere else.
            for (i, &g) in new.iter().enumerate() {
                if i + 1 < new.len() && across(net, g, along) != Some(new[i + 1]) {
                    return false;
                }
                for side in 0..4 {
                    let Some(nb) = across(net, g, side) else { return false };
                    let expected = (side + 2) % 4 == k
                        || (side == along && i + 1 < new.len())
                        || ((side + 2) % 4 == along && i > 0);
                    if !expected && (members.contains(&nb.0) || new.iter().any(|x| x.0 == nb.0)) {
                        return false;
                    }
                }
            }
            // A line of n cells adds exactly n + 1 new corners: a cell whose far corner is already a
            // corner of the block would pinch the face's boundary into a loop through one vertex
            // (valid to OpenCASCADE, but gmsh cannot mesh such a face).
            let added: std::collections::HashSet<u32> =
                new.iter().flat_map(|g| net.faces[g.0 as usize]).filter(|v| !corners.contains(v)).collect();
            if added.len() != new.len() + 1 {
                return false;
            }
            corners.extend(added);
            if k == 1 {
                for (j, g) in new.iter().enumerate() {
                    rows[j].push(*g);
                }
            } else {
                rows.push(new.clone());
            }
            for g in new {
                members.insert(g.0);
            }
            true
        };
        let (mut grow_u, mut grow_v) = (true, true);
        while grow_u || grow_v {
            if grow_u {
                grow_u = rows[0].len() < MAX_PACK_SIDE && try_grow(&mut rows, &mut members, &mut corners, 1);
            }
            if grow_v {
                grow_v = rows.len() < MAX_PACK_SIDE && try_grow(&mut rows, &mut members, &mut corners, 2);
            }
        }
        let (w, h) = (rows[0].len(), rows.len());
        let cells: Vec<(u32, u8)> = rows.into_iter().flatten().collect();
        for &(g, _) in &cells {
            taken[g as usize] = true;
        }
        let all_regular = cells.iter().all(|&(g, _)| matches!(surface.kinds[g as usize], FaceKind::Regular(_)));
        let grid = if all_regular {
            net.lattice_block(cells[0].0 as usize, cells[0].1 as usize, w, h)
                .filter(|(_, c)| *c == cells)
                .map(|(g, _)| g)
        } else {
            None
        };
        blocks.push(Block { w, h, cells, grid });
    }
    blocks
}

/// A `w × h` block of face nets (`cells[w·j + i]`, in the block's frame) as one B-spline surface with
/// triple interior knots on `[0, w] × [0, h]`. Each column (row) has the union of its cells' breaks, and
/// every cell is cut there exactly (de Casteljau).
fn bezier_block(cells: &[FaceNet], w: usize, h: usize) -> BsplineSurface {
    let union = |lists: &mut dyn Iterator<Item = &Vec<f64>>| -> Vec<f64> {
        let mut b: Vec<f64> = lists.flatten().copied().collect();
        b.sort_by(f64::total_cmp);
        b.dedup();
        b
    };
    let col_breaks: Vec<Vec<f64>> = (0..w).map(|i| union(&mut (0..h).map(|j| &cells[w * j + i].bu))).collect();
    let row_breaks: Vec<Vec<f64>> = (0..h).map(|j| union(&mut (0..w).map(|i| &cells[w * j + i].bv))).collect();
    let global = |breaks: &[Vec<f64>]| -> Vec<f64> {
        let mut k = vec![0.0];
        for (x, b) in breaks.iter().enumerate() {
            k.extend(b[1..].iter().map(|t| x as f64 + t));
        }
        k
    };
    let (bu, bv) = (global(&col_breaks), global(&row_breaks));
    let (su, sv) = (bu.len() - 1, bv.len() - 1);
    let mut spans = Vec::with_capacity(su * sv);
    for (j, rb) in row_breaks.iter().enumerate() {
        for jj in 0..rb.len() - 1 {
            for (i, cb) in col_breaks.iter().enumerate() {
                for ii in 0..cb.len() - 1 {
                    spans.push(cells[w * j + i].extract([cb[ii], cb[ii + 1]], [rb[jj], rb[jj + 1]]));
                }
            }
        }
    }
    let (nu, nv) = (3 * su + 1, 3 * sv + 1);
    let mut poles = vec![[0.0; 3]; nu * nv];
    for j in 0..sv {
        for i in 0..su {
            let b = &spans[su * j + i];
            for bj in 0..4 {
                for bi in 0..4 {
                    poles[(3 * j + bj) * nu + 3 * i + bi] = b[4 * bj + bi];
                }
            }
        }
    }
    let knots = |b: &[f64]| -> Vec<f64> {
        let mut k = vec![b[0]; 4];
        for &x in &b[1..b.len() - 1] {
            k.extend([x; 3]);
        }
        k.extend([b[b.len() - 1]; 4]);
        k
    };
    BsplineSurface { nu, nv, poles, knots_u: knots(&bu), knots_v: knots(&bv) }
}

/// Build the solid from the fitted surface (`p1`: control points on the refined net).
///
/// # Errors
/// `brep.invalid` when the result fails [`check`] (a bug: the construction is watertight by design);
/// `internal.bug` when a local evaluation table cannot be built.
///
/// Cost: O(F) time and memory in the number of refined faces.
pub fn build_solid(surface: &LimitSurface, p1: &[V3]) -> Result<(Solid, BrepReport)> {
    let patches = patches::build(surface, p1)?;
    let jumps = patches::normal_jumps(surface, &patches);
    let blocks = pack(surface);
    let solid = merge_edge_chains(assemble(surface, &patches, &blocks, p1));
    let mut bbox = Aabb::EMPTY;
    for v in &solid.vertices {
        bbox.add(*v);
    }
    let dev = check(&solid, bbox.diagonal())?;
    let (volume, area) = solid.volume_and_area();
    let report = BrepReport {
        faces: solid.faces.len(),
        packed_faces: blocks.iter().filter(|b| b.w * b.h > 1).count(),
        patches: surface.net.faces.len(),
        extraordinary_patches: surface.kinds.iter().filter(|k| matches!(k, FaceKind::Extraordinary(_))).count(),
        edges: solid.edges.len(),
        vertices: solid.vertices.len(),
        volume,
        area,
        max_normal_jump_deg: jumps.max_deg,
        p99_normal_jump_deg: jumps.p99_deg,
        max_normal_jump_at: jumps.max_at,
        max_normal_jump_at_extraordinary: jumps.max_at_extraordinary,
        max_normal_jump_at_fraction: jumps.max_at_fraction,
        max_normal_jump_at_valences: jumps.max_at_valences,
        max_edge_deviation: dev,
        self_intersections: 0,
        self_intersection_at: None,
        quad_self_intersections: 0,
        folded_faces: 0,
        fold_at: None,
    };
    let (folded_faces, fold_at) = solid.folds();
    let report = BrepReport { folded_faces, fold_at, ..report };
    if !(volume > 0.0) {
        return Err(Error::new(
            ErrorCode::BrepInvalid,
            format!("the solid's volume {volume:.6e} is not positive: faces point inward"),
        ));
    }
    Ok((solid, report))
}

fn assemble(surface: &LimitSurface, patches: &Patches, blocks: &[Block], p1: &[V3]) -> Solid {
    let net = &surface.net;
    let mut block_of = vec![0u32; net.faces.len()];
    for (b, blk) in blocks.iter().enumerate() {
        for &(g, _) in &blk.cells {
            block_of[g as usize] = b as u32;
        }
    }
    // Edges between different blocks, vertices at their ends.
    let mut edge_id = vec![u32::MAX; patches.edge_half.len()];
    let mut vertex_id = vec![u32::MAX; net.vertex_count];
    let mut solid = Solid::default();
    for (e, &h) in patches.edge_half.iter().enumerate() {
        let t = net.twin[h as usize];
        if block_of[(h / 4) as usize] == block_of[(t / 4) as usize] {
            continue;
        }
        let mut vid = |v: u32, solid: &mut Solid| -> u32 {
            if vertex_id[v as usize] == u32::MAX {
                vertex_id[v as usize] = solid.vertices.len() as u32;
                solid.vertices.push(patches.vertex[v as usize]);
            }
            vertex_id[v as usize]
        };
        let (a, b) = (vid(net.from(h), &mut solid), vid(net.to(h), &mut solid));
        edge_id[e] = solid.edges.len() as u32;
        let c = &patches.edge_curve[e];
        solid.edges.push(Edge { start: a, end: b, curve: c.points.clone(), knots: c.knots.clone() });
    }
    for blk in blocks {
        let (w, h) = (blk.w, blk.h);
        let surface_geom = match &blk.grid {
            Some(grid) => {
                let pts: Vec<V3> = grid.iter().map(|&g| p1[g as usize]).collect();
                BsplineSurface::from_uniform_grid(&pts, w, h)
            }
            None => {
                let nets: Vec<FaceNet> = blk
                    .cells
                    .iter()
                    .map(|&(g, s)| patches.nets[g as usize].rotated(surface.frame_start(g as usize), s as usize))
                    .collect();
                bezier_block(&nets, w, h)
            }
        };
        let cell = |i: usize, j: usize| blk.cells[j * w + i];
        let mut bound = Vec::with_capacity(2 * (w + h));
        let mut push = |(g, s): (u32, u8), k: usize, uv: [[f64; 2]; 2]| {
            let half = 4 * g + ((s as usize + k) % 4) as u32;
            let e = patches.edge_of[half as usize] as usize;
            bound.push(Coedge { edge: edge_id[e], forward: patches.edge_half[e] == half, uv });
        };
        for i in 0..w {
            push(cell(i, 0), 0, [[i as f64, 0.0], [(i + 1) as f64, 0.0]]);
        }
        for j in 0..h {
            push(cell(w - 1, j), 1, [[w as f64, j as f64], [w as f64, (j + 1) as f64]]);
        }
        for i in (0..w).rev() {
            push(cell(i, h - 1), 2, [[(i + 1) as f64, h as f64], [i as f64, h as f64]]);
        }
        for j in (0..h).rev() {
            push(cell(0, j), 3, [[0.0, (j + 1) as f64], [0.0, j as f64]]);
        }
        solid.faces.push(Face { surface: surface_geom, bound });
    }
    solid
}

/// Merge runs of edges between the same two faces into one multi-span edge: a vertex where exactly two
/// edges meet, both between the same pair of faces, and where both faces' boundaries run straight on (the
/// same direction in (u, v) before and after) disappears. A closed run keeps one vertex.
fn merge_edge_chains(solid: Solid) -> Solid {
    let ne = solid.edges.len();
    let nv = solid.vertices.len();
    // Uses of every edge: (face, position in loop).
    let mut uses: Vec<Vec<(usize, usize)>> = vec![Vec::new(); ne];
    for (fi, f) in solid.faces.iter().enumerate() {
        for (k, c) in f.bound.iter().enumerate() {
            uses[c.edge as usize].push((fi, k));
        }
    }
    let mut incident: Vec<Vec<u32>> = vec![Vec::new(); nv];
    for (e, edge) in solid.edges.iter().enumerate() {
        incident[edge.start as usize].push(e as u32);
        incident[edge.end as usize].push(e as u32);
    }
    let dir = |c: &Coedge| [c.uv[1][0] - c.uv[0][0], c.uv[1][1] - c.uv[0][1]];
    let same_dir =
        |a: [f64; 2], b: [f64; 2]| (a[0] * b[1] - a[1] * b[0]).abs() < 1e-9 && a[0] * b[0] + a[1] * b[1] > 0.0;
    let mergeable: Vec<bool> = (0..nv)
        .map(|v| {
            let [e1, e2] = incident[v][..] else { return false };
            if e1 == e2 || uses[e1 as usize].len() != 2 || uses[e2 as usize].len() != 2 {
                return false;
            }
            let faces = |e: u32| {
                let mut f = [uses[e as usize][0].0, uses[e as usize][1].0];
                f.sort();
                f
            };
            if faces(e1) != faces(e2) {
                return false;
            }
            // In each face the two coedges follow each other and run on straight.
            uses[e1 as usize].iter().all(|&(fi, k1)| {
                let bound = &solid.faces[fi].bound;
                let Some(&(_, k2)) = uses[e2 as usize].iter().find(|u| u.0 == fi) else { return false };
                let n = bound.len();
                let consecutive = (k1 + 1) % n == k2 || (k2 + 1) % n == k1;
                consecutive && same_dir(dir(&bound[k1]), dir(&bound[k2]))
            })
        })
        .collect();
    // Chains: walk from every edge end that is not mergeable.
    let mut chain_of = vec![u32::MAX; ne];
    let mut new_edges: Vec<Edge> = Vec::new();
    // Whether each old edge runs along its chain's direction.
    let mut along = vec![true; ne];
    let walk = |start_v: u32, first: u32, chain_of: &mut Vec<u32>, new_edges: &mut Vec<Edge>, along: &mut Vec<bool>| {
        let id = new_edges.len() as u32;
        let mut v = start_v;
        let mut e = first;
        let mut pts: Vec<V3> = Vec::new();
        let mut knots: Vec<f64> = Vec::new();
        loop {
            chain_of[e as usize] = id;
            let edge = &solid.edges[e as usize];
            let forward = edge.start == v;
            let mut c = edge.curve.clone();
            let len = edge.length();
            let mut k: Vec<f64> = edge.knots.clone();
            if !forward {
                c.reverse();
                k = k.iter().rev().map(|x| len - x).collect();
            }
            let offset = knots.last().copied().unwrap_or(0.0);
            if pts.is_empty() {
                pts.extend(c);
                knots.extend(k);
            } else {
                pts.extend(c.into_iter().skip(1));
                knots.extend(k.into_iter().skip(1).map(|x| x + offset));
            }
            along[e as usize] = forward;
            v = if forward { edge.end } else { edge.start };
            if v == start_v || !mergeable[v as usize] {
                break;
            }
            let [a, b] = incident[v as usize][..] else { break };
            let next = if a == e { b } else { a };
            if chain_of[next as usize] != u32::MAX {
                break;
            }
            e = next;
        }
        new_edges.push(Edge { start: start_v, end: v, curve: pts, knots });
    };
    for v in 0..nv as u32 {
        if mergeable[v as usize] {
            continue;
        }
        for &e in &incident[v as usize].clone() {
            if chain_of[e as usize] == u32::MAX {
                walk(v, e, &mut chain_of, &mut new_edges, &mut along);
            }
        }
    }
    // Closed runs made only of mergeable vertices: start anywhere.
    for e in 0..ne as u32 {
        if chain_of[e as usize] == u32::MAX {
            let v = solid.edges[e as usize].start;
            walk(v, e, &mut chain_of, &mut new_edges, &mut along);
        }
    }
    // Rebuild loops: a run of coedges of one chain becomes one coedge.
    let mut faces = Vec::with_capacity(solid.faces.len());
    for f in &solid.faces {
        let n = f.bound.len();
        // Start the walk at a coedge that begins a run.
        let begins = |k: usize| chain_of[f.bound[k].edge as usize] != chain_of[f.bound[(k + n - 1) % n].edge as usize];
        let start = (0..n).find(|&k| begins(k)).unwrap_or(0);
        let mut bound: Vec<Coedge> = Vec::new();
        let mut k = 0;
        while k < n {
            let c0 = f.bound[(start + k) % n];
            let chain = chain_of[c0.edge as usize];
            let mut last = c0;
            let mut len = 1;
            while k + len < n && chain_of[f.bound[(start + k + len) % n].edge as usize] == chain {
                last = f.bound[(start + k + len) % n];
                len += 1;
            }
            // The loop runs along the chain when it runs along an old edge that runs along the chain.
            let forward = c0.forward == along[c0.edge as usize];
            bound.push(Coedge { edge: chain, forward, uv: [c0.uv[0], last.uv[1]] });
            k += len;
        }
        faces.push(Face { surface: f.surface.clone(), bound });
    }
    // Renumber the vertices still used.
    let mut vid = vec![u32::MAX; nv];
    let mut vertices = Vec::new();
    for e in &mut new_edges {
        for v in [&mut e.start, &mut e.end] {
            if vid[*v as usize] == u32::MAX {
                vid[*v as usize] = vertices.len() as u32;
                vertices.push(solid.vertices[*v as usize]);
            }
            *v = vid[*v as usize];
        }
    }
    Solid { vertices, edges: new_edges, faces }
}

/// Our own validity check. Returns the largest edge-curve-to-face-boundary deviation.
///
/// # Errors
/// `brep.invalid` naming the first offending face, edge or loop: an edge not used exactly once in each
/// direction, a loop whose coedges do not chain or that passes through a vertex twice (a pinched face), an
/// edge curve whose ends are not its vertices or that leaves a face boundary by more than
/// [`BREP_EDGE_REL`] × `diagonal`, or faces that fall into more than one connected piece.
pub fn check(solid: &Solid, diagonal: f64) -> Result<f64> {
    let bad = |m: String| Error::new(ErrorCode::BrepInvalid, m);
    let mut uses = vec![[0u32; 2]; solid.edges.len()];
    let tol = BREP_EDGE_REL * diagonal.max(f64::MIN_POSITIVE);
    let mut worst: f64 = 0.0;
    for (fi, face) in solid.faces.iter().enumerate() {
        if face.bound.is_empty() {
            return Err(bad(format!("face {fi} has an empty loop")));
        }
        // A loop through one vertex twice pinches the face (OCCT accepts it; gmsh's 2-D mesher cannot
        // recover the boundary there).
        let mut starts: Vec<u32> = face
            .bound
            .iter()
            .filter_map(|c| solid.edges.get(c.edge as usize).map(|e| if c.forward { e.start } else { e.end }))
            .collect();
        starts.sort_unstable();
        if let Some(w) = starts.windows(2).find(|w| w[0] == w[1]) {
            return Err(bad(format!("face {fi}: its loop passes through vertex {} twice (a pinched face)", w[0])));
        }
        for (k, c) in face.bound.iter().enumerate() {
            let Some(edge) = solid.edges.get(c.edge as usize).filter(|e| e.curve.len() >= 4 && e.curve.len() % 3 == 1)
            else {
                return Err(bad(format!("face {fi} uses edge {} that does not exist", c.edge)));
            };
            uses[c.edge as usize][usize::from(!c.forward)] += 1;
            let (_, end) = if c.forward { (edge.start, edge.end) } else { (edge.end, edge.start) };
            let nxt = face.bound[(k + 1) % face.bound.len()];
            let Some(ne) = solid.edges.get(nxt.edge as usize) else {
                return Err(bad(format!("face {fi} uses edge {} that does not exist", nxt.edge)));
            };
            let nstart = if nxt.forward { ne.start } else { ne.end };
            if end != nstart {
                return Err(bad(format!("face {fi}: loop does not chain after edge {}", c.edge)));
            }
            for (v, p) in [(edge.start, edge.curve[0]), (edge.end, *edge.curve.last().unwrap())] {
                let d = vec3::norm(vec3::sub(solid.vertices[v as usize], p));
                if d > tol {
                    return Err(bad(format!("edge {}: curve end is {d:.3e} from vertex {v}", c.edge)));
                }
            }
            if edge.knots.len() != edge.spans() + 1 || edge.knots.windows(2).any(|w| !(w[0] < w[1])) {
                return Err(bad(format!("edge {}: its breaks do not ascend one per span", c.edge)));
            }
            let len = edge.length();
            // 8 samples per span, at the edge's own breaks.
            let ts: Vec<f64> = edge
                .knots
                .windows(2)
                .flat_map(|w| (0..8).map(move |m| w[0] + (w[1] - w[0]) * m as f64 / 8.0))
                .chain(std::iter::once(len))
                .collect();
            for s in ts {
                let t = if c.forward { s / len } else { 1.0 - s / len };
                let uv = [c.uv[0][0] + t * (c.uv[1][0] - c.uv[0][0]), c.uv[0][1] + t * (c.uv[1][1] - c.uv[0][1])];
                let on_face = face.surface.eval(uv[0], uv[1]).0;
                let on_curve = edge.point(s);
                let d = vec3::norm(vec3::sub(on_face, on_curve));
                worst = worst.max(d);
                if !(d <= tol) {
                    return Err(bad(format!(
                        "face {fi}, edge {}: curve leaves the face boundary by {d:.3e} (tolerance {tol:.3e})",
                        c.edge
                    )));
                }
            }
        }
    }
    for (e, u) in uses.iter().enumerate() {
        if *u != [1, 1] {
            return Err(bad(format!(
                "edge {e} is used {} time(s) forward and {} backward; a closed shell needs once each",
                u[0], u[1]
            )));
        }
    }
    // One shell must be one connected piece (ISO 10303-42 connected_face_set).
    let mut uf = crate::geometry::topology::UnionFind::new(solid.faces.len());
    let mut edge_face = vec![u32::MAX; solid.edges.len()];
    for (fi, face) in solid.faces.iter().enumerate() {
        for c in &face.bound {
            match edge_face[c.edge as usize] {
                u32::MAX => edge_face[c.edge as usize] = fi as u32,
                other => uf.union(other, fi as u32),
            }
        }
    }
    if let Some(fi) = (0..solid.faces.len() as u32).find(|&f| uf.find(f) != 0) {
        let pieces = (0..solid.faces.len() as u32).filter(|&f| uf.find(f) == f).count();
        return Err(bad(format!(
            "the shell falls into {pieces} pieces: face {fi} is not connected to face 0; a closed shell must be \
             one connected piece"
        )));
    }
    Ok(worst)
}

const GAUSS5: [(f64, f64); 5] = [
    (-0.906_179_845_938_664, 0.236_926_885_056_189_1),
    (-0.538_469_310_105_683_1, 0.478_628_670_499_366_5),
    (0.0, 0.568_888_888_888_888_9),
    (0.538_469_310_105_683_1, 0.478_628_670_499_366_5),
    (0.906_179_845_938_664, 0.236_926_885_056_189_1),
];

impl Solid {
    /// Faces whose surface folds over: on a grid of [`FOLD_SAMPLES`] × [`FOLD_SAMPLES`] cells per knot
    /// span, two neighbouring samples whose normals differ by more than 90°, or a vanishing normal. Returns
    /// the count and a point of the first folded face (by index). Cost: 81 surface evaluations per span.
    pub fn folds(&self) -> (usize, Option<V3>) {
        let folded: Vec<Option<V3>> = self
            .faces
            .par_iter()
            .map(|face| {
                let s = &face.surface;
                let (ku, _) = bspline::knot_multiplicities(&s.knots_u);
                let (kv, _) = bspline::knot_multiplicities(&s.knots_v);
                let grid = |k: &[f64]| -> Vec<f64> {
                    let mut t: Vec<f64> = k
                        .windows(2)
                        .flat_map(|w| {
                            (0..FOLD_SAMPLES).map(move |i| w[0] + (w[1] - w[0]) * i as f64 / FOLD_SAMPLES as f64)
                        })
                        .collect();
                    t.push(*k.last().expect("a span"));
                    t
                };
                let (us, vs) = (grid(&ku), grid(&kv));
                let mut normals = vec![[0.0; 3]; us.len() * vs.len()];
                for (j, &v) in vs.iter().enumerate() {
                    for (i, &u) in us.iter().enumerate() {
                        let (p, pu, pv) = s.eval(u, v);
                        let n = vec3::cross(pu, pv);
                        if !(vec3::norm(n) > 0.0) {
                            return Some(p);
                        }
                        normals[j * us.len() + i] = vec3::scale(n, 1.0 / vec3::norm(n));
                    }
                }
                for j in 0..vs.len() {
                    for i in 0..us.len() {
                        let n = normals[j * us.len() + i];
                        let right = (i + 1 < us.len()).then(|| normals[j * us.len() + i + 1]);
                        let up = (j + 1 < vs.len()).then(|| normals[(j + 1) * us.len() + i]);
                        if [right, up].into_iter().flatten().any(|m| vec3::dot(n, m) < 0.0) {
                            return Some(s.eval(us[i], vs[j]).0);
                        }
                    }
                }
                None
            })
            .collect();
        (folded.iter().filter(|f| f.is_some()).count(), folded.into_iter().flatten().next())
    }

    /// Enclosed volume `⅓ ∮ p · n dA` and area, by 5×5-point Gauss quadrature per knot span (exact for
    /// the volume of bicubic patches).
    pub fn volume_and_area(&self) -> (f64, f64) {
        let mut vol = 0.0;
        let mut area = 0.0;
        for face in &self.faces {
            let s = &face.surface;
            let (ku, _) = bspline::knot_multiplicities(&s.knots_u);
            let (kv, _) = bspline::knot_multiplicities(&s.knots_v);
            for wu in ku.windows(2) {
                for wv in kv.windows(2) {
                    let (hu, hv) = ((wu[1] - wu[0]) / 2.0, (wv[1] - wv[0]) / 2.0);
                    for &(xu, au) in &GAUSS5 {
                        for &(xv, av) in &GAUSS5 {
                            let (u, v) = (wu[0] + hu * (xu + 1.0), wv[0] + hv * (xv + 1.0));
                            let (p, pu, pv) = s.eval(u, v);
                            let n = vec3::cross(pu, pv);
                            let w = au * av * hu * hv;
                            vol += w * vec3::dot(p, n) / 3.0;
                            area += w * vec3::norm(n);
                        }
                    }
                }
            }
        }
        (vol, area)
    }

    /// A triangle mesh through points of the exact surfaces, `per_span` × `per_span` quads per unit of
    /// parameter (one refined face), with vertices shared along edges inside a face (faces are separate
    /// sheets, whose shared boundaries are sampled at the same points). For distance checks.
    pub fn tessellate(&self, per_span: usize) -> Result<TriMesh> {
        let n = per_span.max(1);
        let mut pos: Vec<[f32; 3]> = Vec::new();
        let mut tris: Vec<[u32; 3]> = Vec::new();
        for face in &self.faces {
            let s = &face.surface;
            let (ku, _) = bspline::knot_multiplicities(&s.knots_u);
            let (kv, _) = bspline::knot_multiplicities(&s.knots_v);
            let us: Vec<f64> = param_points(&ku, n);
            let vs: Vec<f64> = param_points(&kv, n);
            let base = pos.len() as u32;
            for &v in &vs {
                for &u in &us {
                    let p = s.eval(u, v).0;
                    pos.push([p[0] as f32, p[1] as f32, p[2] as f32]);
                }
            }
            let cols = us.len() as u32;
            for j in 0..vs.len() as u32 - 1 {
                for i in 0..cols - 1 {
                    let a = base + j * cols + i;
                    tris.push([a, a + 1, a + cols + 1]);
                    tris.push([a, a + cols + 1, a + cols]);
                }
            }
        }
        TriMesh::new(pos, tris)
    }
}

/// `n` points per unit of parameter over the knots' range (faces are built in units of refined faces, so
/// two faces sample the boundary they share at the same points even when one has a knot in the middle of
/// a unit and the other does not), and the last knot.
fn param_points(knots: &[f64], n: usize) -> Vec<f64> {
    let (a, b) = (knots[0], *knots.last().expect("a knot"));
    let units = ((b - a).round() as usize).max(1);
    let mut out = Vec::with_capacity(units * n + 1);
    for k in 0..units * n {
        out.push(a + (b - a) * k as f64 / (units * n) as f64);
    }
    out.push(b);
    out
}

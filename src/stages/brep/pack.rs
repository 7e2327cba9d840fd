//! Packing: greedy maximal rectangles of regular faces become one clamped bicubic B-spline face each (C²
//! inside).

use super::bspline::BsplineSurface;
use super::patches::FaceNet;
use crate::geometry::subdivision::limit::FaceKind;
use crate::geometry::subdivision::{LimitSurface, QuadNet};

/// Largest packed face, in refined faces per side. Larger blocks halve the face count again, but faces that
/// wrap far around a thin part defeat gmsh's parametric surface mesher (measured on Spot at 48).
pub const MAX_PACK_SIDE: usize = 16;

/// A w × h block of refined faces that becomes one B-rep face.
pub(super) struct Block {
    pub(super) w: usize,
    pub(super) h: usize,
    /// `(face, frame start)` row-major over the block's cells.
    pub(super) cells: Vec<(u32, u8)>,
    /// Control grid of a packed regular block.
    pub(super) grid: Option<Vec<u32>>,
}

/// The face across side `k` of face `f` (frame from corner `s`; sides 0: v = 0, 1: u = 1, 2: v = 1,
/// 3: u = 0) with the corner where its frame, aligned with `f`'s, starts.
pub(super) fn across(net: &QuadNet, (f, s): (u32, u8), k: usize) -> Option<(u32, u8)> {
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
pub(super) fn pack(surface: &LimitSurface) -> Vec<Block> {
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
pub(super) fn bezier_block(cells: &[FaceNet], w: usize, h: usize) -> BsplineSurface {
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

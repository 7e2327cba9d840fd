//! Assembly: faces, the shared edges with their cubic curves, vertices and loops; chains of edges between the
//! same two faces merged.

use super::bspline::BsplineSurface;
use super::pack::{Block, bezier_block};
use super::patches::{FaceNet, Patches};
use super::solid::*;
use crate::geometry::subdivision::LimitSurface;
use crate::geometry::vec3::V3;

pub(super) fn assemble(surface: &LimitSurface, patches: &Patches, blocks: &[Block], p1: &[V3]) -> Solid {
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
pub(super) fn merge_edge_chains(solid: Solid) -> Solid {
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

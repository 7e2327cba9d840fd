//! The iso-surface of χ by marching tetrahedra: each grid cube split into the six tetrahedra around its
//! main diagonal (the Kuhn split, the same in every cube, so neighbours share faces), one vertex per grid
//! edge crossed (shared by every tetrahedron on that edge), triangles oriented toward larger χ (outside).
//! With the boundary fixed above the iso-value the surface is closed, and each tetrahedron adds a disk, so
//! it is a 2-manifold. Then connected components: those that enclose negative volume (bubbles inside) or
//! hold less than [`MIN_COMPONENT_SHARE`] of the largest one's area (blobs) are dropped.

use std::collections::HashMap;

use rayon::prelude::*;

use super::poisson::{Grid, Node};
use crate::geometry::mesh::TriMesh;
use crate::geometry::vec3::{V3, add, cross, dot, scale, sub};

/// Components smaller than this share of the largest one's area are dropped as blobs (and counted). 5 %:
/// the Stanford bunny's ten scans hold stray points beside the bunny that close into a 2 cm blob of 1.5 % of
/// its area (measured 2026-12-05); a solid is one part.
pub const MIN_COMPONENT_SHARE: f64 = 0.05;

/// A crossing of the grid edge between nodes `a < b`.
type EdgeKey = (u32, u32);

/// The six tetrahedra of a cube around the diagonal corner 0 → corner 7 (corners numbered by bits x, y, z).
const TETS: [[usize; 4]; 6] = [[0, 1, 3, 7], [0, 1, 5, 7], [0, 2, 3, 7], [0, 2, 6, 7], [0, 4, 5, 7], [0, 4, 6, 7]];

/// Where χ crosses `iso` on the edge between nodes `a` and `b` (kept strictly inside the edge, so no two
/// crossings coincide).
fn crossing(grid: &Grid, chi: &[Node], iso: f64, a: u32, b: u32) -> V3 {
    let (va, vb) = (f64::from(chi[a as usize]) - iso, f64::from(chi[b as usize]) - iso);
    let t = (va / (va - vb)).clamp(1e-3, 1.0 - 1e-3);
    let (pa, pb) = (grid.position(grid.coords(a as usize)), grid.position(grid.coords(b as usize)));
    add(pa, scale(sub(pb, pa), t))
}

/// Triangles of one z-layer of cubes, as edge keys, oriented outward.
fn layer(grid: &Grid, chi: &[Node], iso: f64, k: usize) -> Vec<[EdgeKey; 3]> {
    let mut out = Vec::new();
    let outside = |v: usize| f64::from(chi[v]) > iso;
    for j in 0..grid.n[1] - 1 {
        for i in 0..grid.n[0] - 1 {
            let corner = |c: usize| {
                let (x, y, z) = (i + (c & 1), j + ((c >> 1) & 1), k + ((c >> 2) & 1));
                x + grid.n[0] * (y + grid.n[1] * z)
            };
            let nodes: [usize; 8] = std::array::from_fn(corner);
            let first = outside(nodes[0]);
            if nodes.iter().all(|&v| outside(v) == first) {
                continue;
            }
            for t in TETS {
                let v = t.map(|c| nodes[c]);
                let (ins, outs): (Vec<usize>, Vec<usize>) = v.iter().partition(|&&x| !outside(x));
                if ins.is_empty() || outs.is_empty() {
                    continue;
                }
                let key = |a: usize, b: usize| -> EdgeKey { (a.min(b) as u32, a.max(b) as u32) };
                let tris: Vec<[EdgeKey; 3]> = match (ins.len(), outs.len()) {
                    (1, 3) => vec![[key(ins[0], outs[0]), key(ins[0], outs[1]), key(ins[0], outs[2])]],
                    (3, 1) => vec![[key(outs[0], ins[0]), key(outs[0], ins[1]), key(outs[0], ins[2])]],
                    _ => {
                        let (a, b, c, d) = (ins[0], ins[1], outs[0], outs[1]);
                        vec![[key(a, c), key(a, d), key(b, d)], [key(a, c), key(b, d), key(b, c)]]
                    }
                };
                // Orient each toward the outside nodes.
                let centre = |xs: &[usize]| {
                    let s = xs.iter().fold([0.0; 3], |acc, &x| add(acc, grid.position(grid.coords(x))));
                    scale(s, 1.0 / xs.len() as f64)
                };
                let towards = sub(centre(&outs), centre(&ins));
                for tri in tris {
                    let p = tri.map(|e| crossing(grid, chi, iso, e.0, e.1));
                    let n = cross(sub(p[1], p[0]), sub(p[2], p[0]));
                    out.push(if dot(n, towards) >= 0.0 { tri } else { [tri[0], tri[2], tri[1]] });
                }
            }
        }
    }
    out
}

/// The closed iso-surface of χ at `iso`, before component filtering.
pub fn marching_tetrahedra(grid: &Grid, chi: &[Node], iso: f64) -> TriMesh {
    let layers: Vec<Vec<[EdgeKey; 3]>> = (0..grid.n[2] - 1).into_par_iter().map(|k| layer(grid, chi, iso, k)).collect();
    let mut ids: HashMap<EdgeKey, u32> = HashMap::new();
    let mut positions = Vec::new();
    let mut triangles = Vec::new();
    for tris in layers {
        for tri in tris {
            let t = tri.map(|e| {
                *ids.entry(e).or_insert_with(|| {
                    let p = crossing(grid, chi, iso, e.0, e.1);
                    positions.push(p.map(|c| c as f32));
                    (positions.len() - 1) as u32
                })
            });
            triangles.push(t);
        }
    }
    TriMesh { positions, triangles }
}

/// What the component filter removed.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct Components {
    /// Components kept.
    pub kept: usize,
    /// Components enclosing negative volume (bubbles in the solid) removed.
    pub bubbles_removed: usize,
    /// Components below [`MIN_COMPONENT_SHARE`] of the largest area removed.
    pub blobs_removed: usize,
}

/// Keep the outward components of at least [`MIN_COMPONENT_SHARE`] of the largest one's area; vertices
/// renumbered in order of first use.
pub fn filter_components(mesh: &TriMesh) -> (TriMesh, Components) {
    let nv = mesh.positions.len();
    let mut parent: Vec<u32> = (0..nv as u32).collect();
    fn find(p: &mut [u32], mut x: u32) -> u32 {
        while p[x as usize] != x {
            p[x as usize] = p[p[x as usize] as usize];
            x = p[x as usize];
        }
        x
    }
    for t in &mesh.triangles {
        for k in 1..3 {
            let (a, b) = (find(&mut parent, t[0]), find(&mut parent, t[k]));
            if a != b {
                parent[a.max(b) as usize] = a.min(b);
            }
        }
    }
    let mut stats: HashMap<u32, (f64, f64)> = HashMap::new();
    let comp: Vec<u32> = mesh.triangles.iter().map(|t| find(&mut parent, t[0])).collect();
    for (t, &c) in mesh.triangles.iter().zip(&comp) {
        let p = t.map(|v| crate::geometry::vec3::wide(mesh.positions[v as usize]));
        let n = cross(sub(p[1], p[0]), sub(p[2], p[0]));
        let e = stats.entry(c).or_default();
        e.0 += 0.5 * crate::geometry::vec3::norm(n);
        e.1 += dot(p[0], cross(p[1], p[2])) / 6.0;
    }
    let largest = stats.values().map(|s| s.0).fold(0.0, f64::max);
    let mut report = Components::default();
    let mut keep: HashMap<u32, bool> = HashMap::new();
    let mut keys: Vec<&u32> = stats.keys().collect();
    keys.sort();
    for c in keys {
        let (area, volume) = stats[c];
        let ok = if volume <= 0.0 {
            report.bubbles_removed += 1;
            false
        } else if area < MIN_COMPONENT_SHARE * largest {
            report.blobs_removed += 1;
            false
        } else {
            report.kept += 1;
            true
        };
        keep.insert(*c, ok);
    }
    let mut map = vec![u32::MAX; nv];
    let mut out = TriMesh { positions: Vec::new(), triangles: Vec::new() };
    for (t, c) in mesh.triangles.iter().zip(&comp) {
        if !keep[c] {
            continue;
        }
        let t = t.map(|v| {
            if map[v as usize] == u32::MAX {
                map[v as usize] = out.positions.len() as u32;
                out.positions.push(mesh.positions[v as usize]);
            }
            map[v as usize]
        });
        out.triangles.push(t);
    }
    (out, report)
}

//! The immersed domain: a uniform background grid over the solid and, for every cell, the moments
//! ∫ t₁^a t₂^b t₃^c over the part of the cell inside the solid (a, b, c ≤ 4, t the cell's local coordinates).
//! With them every cell integral of the quadratic B-spline basis is exact up to the geometry.
//!
//! Inside/outside comes from lines parallel to x through each cell, `s × s` of them (`s` = subcells): every
//! triangle of the closed surface is rasterised onto the (y, z) lattice of lines with a shared-edge rule so
//! each line crosses the surface an even number of times; the inside of a line is then a union of exact
//! intervals, integrated exactly along x and by the midpoint rule across its (y, z) square. Cost:
//! O(T + L log L) for T triangles and L line crossings, then O(cells · s²) for the moments.

use rayon::prelude::*;

use crate::geometry::mesh::TriMesh;
use crate::geometry::vec3::{Aabb, V3, wide};

/// Monomial degrees 0..=4 per axis: the moments a cell carries.
pub const MOMENTS: usize = 5;
/// Moments of one cell, `m[(a * 5 + b) * 5 + c] = ∫ t₁^a t₂^b t₃^c` over the inside part, in local units
/// (the full cell has volume 1).
pub type Moments = [f64; MOMENTS * MOMENTS * MOMENTS];

/// The moments of the whole unit cell.
pub fn full_moments() -> Moments {
    let mut m = [0.0; 125];
    for a in 0..5 {
        for b in 0..5 {
            for c in 0..5 {
                m[(a * 5 + b) * 5 + c] = 1.0 / ((a + 1) * (b + 1) * (c + 1)) as f64;
            }
        }
    }
    m
}

/// A uniform grid of cubic cells of side `h` from `origin`, `n` cells per axis.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Grid {
    /// Corner of cell (0, 0, 0).
    pub origin: V3,
    /// Cell side.
    pub h: f64,
    /// Cells per axis.
    pub n: [usize; 3],
}

impl Grid {
    /// A grid of spacing `h` around `bbox`, centred, with at least a quarter cell of margin on every side.
    pub fn around(bbox: &Aabb, h: f64) -> Grid {
        let mut origin = [0.0; 3];
        let mut n = [0; 3];
        for k in 0..3 {
            let ext = bbox.max[k] - bbox.min[k];
            n[k] = ((ext / h + 0.5).ceil() as usize).max(1);
            origin[k] = bbox.min[k] - 0.5 * (n[k] as f64 * h - ext);
        }
        Grid { origin, h, n }
    }

    /// Number of cells.
    pub fn cells(&self) -> usize {
        self.n[0] * self.n[1] * self.n[2]
    }

    /// Linear index of cell `c`.
    #[inline]
    pub fn cell_index(&self, c: [usize; 3]) -> usize {
        (c[2] * self.n[1] + c[1]) * self.n[0] + c[0]
    }

    /// The cell holding `p` (clamped into the grid) and `p`'s local coordinates in it (in [0, 1] when inside).
    #[inline]
    pub fn locate(&self, p: V3) -> ([usize; 3], V3) {
        let mut c = [0; 3];
        let mut t = [0.0; 3];
        for k in 0..3 {
            let u = (p[k] - self.origin[k]) / self.h;
            let i = (u.floor().max(0.0) as usize).min(self.n[k] - 1);
            c[k] = i;
            t[k] = u - i as f64;
        }
        (c, t)
    }
}

/// Cells that hold part of the solid, with their moments.
pub struct Domain {
    /// The grid the cells belong to.
    pub grid: Grid,
    /// Linear cell index → inside moments, only for cells with inside volume.
    pub cells: Vec<(usize, CellFill)>,
    /// Lines whose crossings were odd (the surface is not closed there); should be 0.
    pub odd_lines: usize,
}

/// How much of a cell is inside.
#[derive(Clone, Debug)]
pub enum CellFill {
    /// Entirely inside.
    Full,
    /// Partly inside: its moments.
    Cut(Box<Moments>),
}

impl CellFill {
    /// Inside volume fraction.
    pub fn fraction(&self) -> f64 {
        match self {
            CellFill::Full => 1.0,
            CellFill::Cut(m) => m[0],
        }
    }
}

/// ∫_{t0}^{t1} t^m dt for m = 0..5.
#[inline]
fn monomial_integrals(t0: f64, t1: f64) -> [f64; 5] {
    let mut out = [0.0; 5];
    let (mut p0, mut p1) = (t0, t1);
    for (m, o) in out.iter_mut().enumerate() {
        *o = (p1 - p0) / (m + 1) as f64;
        p0 *= t0;
        p1 *= t1;
    }
    out
}

/// Crossings of the x-parallel lines with the surface, grouped per line and sorted.
struct Crossings {
    /// Lines along y and z.
    lines: [usize; 2],
    start: Vec<u32>,
    x: Vec<f64>,
}

impl Crossings {
    fn new(mesh: &TriMesh, grid: &Grid, s: usize) -> Crossings {
        let lines = [grid.n[1] * s, grid.n[2] * s];
        let d = grid.h / s as f64;
        // Line (j, k) passes through y = oy + (j + ½)·d, z = oz + (k + ½)·d.
        let hits: Vec<(u32, f64)> = mesh
            .triangles
            .par_iter()
            .fold(Vec::new, |mut acc, t| {
                let p = t.map(|v| wide(mesh.positions[v as usize]));
                rasterise(p, grid, d, lines, &mut acc);
                acc
            })
            .reduce(Vec::new, |mut a, mut b| {
                a.append(&mut b);
                a
            });
        let mut hits = hits;
        hits.par_sort_unstable_by(|a, b| a.0.cmp(&b.0).then(a.1.total_cmp(&b.1)));
        let nl = lines[0] * lines[1];
        let mut start = vec![0u32; nl + 1];
        for &(l, _) in &hits {
            start[l as usize + 1] += 1;
        }
        for i in 0..nl {
            start[i + 1] += start[i];
        }
        Crossings { lines, start, x: hits.into_iter().map(|h| h.1).collect() }
    }

    fn of(&self, j: usize, k: usize) -> &[f64] {
        let l = j * self.lines[1] + k;
        &self.x[self.start[l] as usize..self.start[l + 1] as usize]
    }
}

/// Push (line, x) for every lattice line through triangle `p` projected onto (y, z). An edge shared by two
/// triangles belongs to exactly one of them (a fixed rule on its direction), so closed surfaces give an even
/// number of crossings per line.
fn rasterise(p: [V3; 3], grid: &Grid, d: f64, lines: [usize; 2], out: &mut Vec<(u32, f64)>) {
    let q = |v: V3| [(v[1] - grid.origin[1]) / d - 0.5, (v[2] - grid.origin[2]) / d - 0.5];
    let (a, mut b, mut c) = (q(p[0]), q(p[1]), q(p[2]));
    let (xa, mut xb, mut xc) = (p[0][0], p[1][0], p[2][0]);
    let area = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
    if area == 0.0 || !area.is_finite() {
        return;
    }
    if area < 0.0 {
        std::mem::swap(&mut b, &mut c);
        std::mem::swap(&mut xb, &mut xc);
    }
    let area = area.abs();
    let lo = |u: f64| u.ceil().max(0.0) as usize;
    let hi = |u: f64, n: usize| (u.floor().min(n as f64 - 1.0)).max(-1.0);
    let (j0, j1) = (lo(a[0].min(b[0]).min(c[0])), hi(a[0].max(b[0]).max(c[0]), lines[0]));
    let (k0, k1) = (lo(a[1].min(b[1]).min(c[1])), hi(a[1].max(b[1]).max(c[1]), lines[1]));
    if j1 < 0.0 || k1 < 0.0 {
        return;
    }
    // Edge u→v owns the points exactly on it when it points "up" (or exactly left).
    let owns = |u: [f64; 2], v: [f64; 2]| {
        let e = [v[0] - u[0], v[1] - u[1]];
        e[1] > 0.0 || (e[1] == 0.0 && e[0] < 0.0)
    };
    let edges = [(b, c, owns(b, c)), (c, a, owns(c, a)), (a, b, owns(a, b))];
    for j in j0..=j1 as usize {
        for k in k0..=k1 as usize {
            let pt = [j as f64, k as f64];
            let mut w = [0.0; 3];
            let mut inside = true;
            for (i, &(u, v, own)) in edges.iter().enumerate() {
                let e = (v[0] - u[0]) * (pt[1] - u[1]) - (v[1] - u[1]) * (pt[0] - u[0]);
                if e < 0.0 || (e == 0.0 && !own) {
                    inside = false;
                    break;
                }
                w[i] = e;
            }
            if inside {
                let x = (w[0] * xa + w[1] * xb + w[2] * xc) / area;
                out.push(((j * lines[1] + k) as u32, x));
            }
        }
    }
}

impl Domain {
    /// Classify the grid's cells against the closed surface `mesh` and integrate their inside moments.
    /// Cost: O(T + L log L + cells · s²) time; O(L + cut cells · 1 KiB) memory.
    pub fn new(mesh: &TriMesh, grid: Grid, subcells: usize) -> Domain {
        let s = subcells;
        let crossings = Crossings::new(mesh, &grid, s);
        let [nx, ny, nz] = grid.n;
        let inv_h = 1.0 / grid.h;
        // Midpoint-rule weights across a line's (y, z) square: ∫ over the slab of t^m.
        let slab: Vec<[f64; 5]> =
            (0..s).map(|l| monomial_integrals(l as f64 / s as f64, (l + 1) as f64 / s as f64)).collect();
        let columns: Vec<(usize, usize)> = (0..nz).flat_map(|cz| (0..ny).map(move |cy| (cy, cz))).collect();
        let results: Vec<(Vec<(usize, CellFill)>, usize)> = columns
            .par_iter()
            .map(|&(cy, cz)| {
                // xm[(cx * s*s + line) * 5 + m]: ∫ t^m along x of the line's inside part in cell cx.
                let mut xm = vec![0.0f64; nx * s * s * 5];
                let mut full_lines = vec![0usize; nx];
                let mut odd = 0;
                for ly in 0..s {
                    for lz in 0..s {
                        let line = ly * s + lz;
                        let xs = crossings.of(cy * s + ly, cz * s + lz);
                        if xs.len() % 2 == 1 {
                            odd += 1;
                        }
                        for pair in xs.chunks_exact(2) {
                            let u0 = ((pair[0] - grid.origin[0]) * inv_h).max(0.0);
                            let u1 = ((pair[1] - grid.origin[0]) * inv_h).min(nx as f64);
                            if u1 <= u0 {
                                continue;
                            }
                            let c0 = (u0.floor() as usize).min(nx - 1);
                            let c1 = ((u1.ceil() as usize).max(1) - 1).min(nx - 1);
                            for cx in c0..=c1 {
                                let t0 = (u0 - cx as f64).max(0.0);
                                let t1 = (u1 - cx as f64).min(1.0);
                                if t1 <= t0 {
                                    continue;
                                }
                                if t0 == 0.0 && t1 == 1.0 {
                                    full_lines[cx] += 1;
                                }
                                let mi = monomial_integrals(t0, t1);
                                let o = (cx * s * s + line) * 5;
                                for m in 0..5 {
                                    xm[o + m] += mi[m];
                                }
                            }
                        }
                    }
                }
                let mut cells = Vec::new();
                for cx in 0..nx {
                    let idx = grid.cell_index([cx, cy, cz]);
                    if full_lines[cx] == s * s {
                        cells.push((idx, CellFill::Full));
                        continue;
                    }
                    let base = cx * s * s * 5;
                    if xm[base..base + s * s * 5].iter().all(|&v| v == 0.0) {
                        continue;
                    }
                    // M[a][b][c] = Σ_lines xm[line][a] · slab[ly][b] · slab[lz][c].
                    let mut mom = Box::new([0.0; 125]);
                    for ly in 0..s {
                        // Contract over lz first: t[a][c] = Σ_lz xm[ly, lz][a] · slab[lz][c].
                        let mut t = [[0.0; 5]; 5];
                        for lz in 0..s {
                            let o = base + (ly * s + lz) * 5;
                            for a in 0..5 {
                                let v = xm[o + a];
                                if v != 0.0 {
                                    for c in 0..5 {
                                        t[a][c] += v * slab[lz][c];
                                    }
                                }
                            }
                        }
                        for a in 0..5 {
                            for b in 0..5 {
                                let w = slab[ly][b];
                                for c in 0..5 {
                                    mom[(a * 5 + b) * 5 + c] += t[a][c] * w;
                                }
                            }
                        }
                    }
                    if mom[0] > 0.0 {
                        cells.push((idx, CellFill::Cut(mom)));
                    }
                }
                (cells, odd)
            })
            .collect();
        let mut cells = Vec::new();
        let mut odd_lines = 0;
        for (c, o) in results {
            cells.extend(c);
            odd_lines += o;
        }
        cells.sort_unstable_by_key(|c| c.0);
        Domain { grid, cells, odd_lines }
    }

    /// Inside volume (length units³).
    pub fn volume(&self) -> f64 {
        self.cells.iter().map(|c| c.1.fraction()).sum::<f64>() * self.grid.h.powi(3)
    }
}

//! Screened Poisson on a regular grid (Kazhdan & Hoppe 2013, discretised on grid edges).
//!
//! The indicator χ lives on the grid's nodes: −½ inside, +½ outside, fixed to +½ on the grid's boundary
//! (Dirichlet). Each oriented sample splats `nᵢ·aᵢ / h³` (its normal times its area, per volume) onto the
//! edges of the three axes with trilinear weights: the target gradient gₑ along each edge. χ minimises
//!
//! `Σₑ (χ_b − χ_a − h·gₑ)² + Σᵢ cᵢ χ(pᵢ)²`,  `cᵢ = screening · aᵢ / h²`,
//!
//! the first term fitting the gradient, the second (the screening) pulling χ to 0 at the samples, so the
//! surface passes through them instead of being smoothed away. Its normal equations `(L + S) χ = b` (L the
//! 7-point graph Laplacian, S = Σᵢ cᵢ wᵢ wᵢᵀ with wᵢ the trilinear weights of sample i) are solved by
//! conjugate gradients, coarse to fine (cascadic: each level starts from the coarser solution). Sums run in
//! fixed blocks, so the result does not depend on the number of threads.

use rayon::prelude::*;

use crate::geometry::vec3::{Aabb, V3, wide};

/// A regular grid of nodes.
#[derive(Clone, Debug)]
pub struct Grid {
    /// Nodes per axis.
    pub n: [usize; 3],
    /// Position of node (0, 0, 0).
    pub origin: V3,
    /// Node spacing.
    pub h: f64,
}

/// Relative margin around the points' box (each side), so the boundary lies outside the object.
pub const MARGIN: f64 = 0.1;

impl Grid {
    /// A grid with `res` nodes along the longest side of `bbox` enlarged by [`MARGIN`] each side.
    pub fn around(bbox: &Aabb, res: usize) -> Grid {
        let ext = bbox.extent();
        let longest = ext[0].max(ext[1]).max(ext[2]).max(f64::MIN_POSITIVE);
        let margin = MARGIN * longest;
        let h = (longest + 2.0 * margin) / (res - 1) as f64;
        let n = [0, 1, 2].map(|k| (((ext[k] + 2.0 * margin) / h).ceil() as usize + 1).max(4));
        let origin = [0, 1, 2].map(|k| {
            let span = (n[k] - 1) as f64 * h;
            bbox.min[k] - (span - ext[k]) / 2.0
        });
        Grid { n, origin, h }
    }

    /// Number of nodes.
    pub fn len(&self) -> usize {
        self.n[0] * self.n[1] * self.n[2]
    }

    /// Whether the grid has no nodes.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    #[inline]
    fn idx(&self, i: usize, j: usize, k: usize) -> usize {
        i + self.n[0] * (j + self.n[1] * k)
    }

    /// Stride of one step along `axis`.
    #[inline]
    fn stride(&self, axis: usize) -> usize {
        [1, self.n[0], self.n[0] * self.n[1]][axis]
    }

    /// Whether node `(i, j, k)` lies on the boundary.
    #[inline]
    fn on_boundary(&self, c: [usize; 3]) -> bool {
        (0..3).any(|a| c[a] == 0 || c[a] + 1 == self.n[a])
    }

    /// Node coordinates of linear index `v`.
    #[inline]
    pub fn coords(&self, v: usize) -> [usize; 3] {
        [v % self.n[0], (v / self.n[0]) % self.n[1], v / (self.n[0] * self.n[1])]
    }

    /// Position of node `c`.
    #[inline]
    pub fn position(&self, c: [usize; 3]) -> V3 {
        [0, 1, 2].map(|a| self.origin[a] + c[a] as f64 * self.h)
    }

    /// The 8 nodes around `p` (shifted by `shift`, in cells, per axis) and their trilinear weights; nodes
    /// clamped into the grid.
    #[inline]
    fn stencil(&self, p: V3, shift: [f64; 3]) -> [(usize, f64); 8] {
        let mut base = [0usize; 3];
        let mut f = [0.0; 3];
        for a in 0..3 {
            let x = ((p[a] - self.origin[a]) / self.h - shift[a]).clamp(0.0, (self.n[a] - 2) as f64);
            let b = (x.floor() as usize).min(self.n[a] - 2);
            base[a] = b;
            f[a] = x - b as f64;
        }
        let mut out = [(0usize, 0.0); 8];
        for (c, o) in out.iter_mut().enumerate() {
            let d = [c & 1, (c >> 1) & 1, (c >> 2) & 1];
            let w = (0..3).map(|a| if d[a] == 1 { f[a] } else { 1.0 - f[a] }).product::<f64>();
            *o = (self.idx(base[0] + d[0], base[1] + d[1], base[2] + d[2]), w);
        }
        out
    }

    /// Trilinear interpolation of node values `x` at `p`.
    pub fn sample(&self, x: &[f64], p: V3) -> f64 {
        self.stencil(p, [0.0; 3]).iter().map(|&(v, w)| w * x[v]).sum()
    }
}

/// Oriented samples with their areas.
pub struct Samples<'a> {
    /// Positions.
    pub points: &'a [[f32; 3]],
    /// Unit outward normals.
    pub normals: &'a [V3],
    /// Area each sample stands for.
    pub areas: &'a [f64],
}

/// How one level's solve went.
#[derive(Clone, Debug, serde::Serialize)]
pub struct LevelReport {
    /// Nodes per axis.
    pub nodes: [usize; 3],
    /// Conjugate-gradient iterations.
    pub iterations: usize,
    /// Final residual relative to the right-hand side.
    pub relative_residual: f64,
}

/// The right-hand side b = h·Σₐ (g_a[j − eₐ] − g_a[j]) from the splatted edge gradients (0 on the boundary).
fn rhs(grid: &Grid, s: &Samples) -> Vec<f64> {
    let h3 = grid.h * grid.h * grid.h;
    let mut b = vec![0.0; grid.len()];
    for a in 0..3 {
        // Edge j → j + eₐ sits half a cell along a from node j.
        let mut shift = [0.0; 3];
        shift[a] = 0.5;
        let mut g = vec![0.0; grid.len()];
        for i in 0..s.points.len() {
            let v = s.normals[i][a] * s.areas[i] / h3;
            for (e, w) in grid.stencil(wide(s.points[i]), shift) {
                g[e] += w * v;
            }
        }
        let st = grid.stride(a);
        b.par_iter_mut().enumerate().for_each(|(j, bj)| {
            let c = grid.coords(j);
            if grid.on_boundary(c) {
                return;
            }
            *bj += grid.h * (g[j - st] - g[j]);
        });
    }
    b
}

/// y = (L + S) x on the interior nodes (y = 0 on the boundary); x is read everywhere.
fn apply(grid: &Grid, s: &Samples, c: &[f64], x: &[f64], y: &mut [f64]) {
    let st = [grid.stride(0), grid.stride(1), grid.stride(2)];
    y.par_iter_mut().enumerate().for_each(|(j, yj)| {
        let co = grid.coords(j);
        *yj = if grid.on_boundary(co) {
            0.0
        } else {
            6.0 * x[j] - x[j - st[0]] - x[j + st[0]] - x[j - st[1]] - x[j + st[1]] - x[j - st[2]] - x[j + st[2]]
        };
    });
    // Screening: each sample's value, then scattered back (in sample order: deterministic).
    let vals: Vec<f64> = (0..s.points.len())
        .into_par_iter()
        .map(|i| c[i] * grid.stencil(wide(s.points[i]), [0.0; 3]).iter().map(|&(v, w)| w * x[v]).sum::<f64>())
        .collect();
    for (i, &t) in vals.iter().enumerate() {
        for (v, w) in grid.stencil(wide(s.points[i]), [0.0; 3]) {
            if !grid.on_boundary(grid.coords(v)) {
                y[v] += w * t;
            }
        }
    }
}

/// Σ a·b in fixed blocks of 4096, summed in order: the same bits for any number of threads.
fn dot_blocks(a: &[f64], b: &[f64]) -> f64 {
    let parts: Vec<f64> =
        a.par_chunks(4096).zip(b.par_chunks(4096)).map(|(x, y)| x.iter().zip(y).map(|(p, q)| p * q).sum()).collect();
    parts.iter().sum()
}

/// Solve one level by conjugate gradients from `chi` (boundary already +½). Stops at `tol` relative
/// residual or `max_iter`.
fn solve_level(grid: &Grid, s: &Samples, c: &[f64], chi: &mut [f64], tol: f64, max_iter: usize) -> LevelReport {
    let b = rhs(grid, s);
    let n = grid.len();
    let mut r = vec![0.0; n];
    apply(grid, s, c, chi, &mut r);
    r.par_iter_mut().zip(&b).for_each(|(ri, bi)| *ri = bi - *ri);
    let bnorm = dot_blocks(&b, &b).sqrt().max(f64::MIN_POSITIVE);
    let mut p = r.clone();
    let mut ap = vec![0.0; n];
    let mut rr = dot_blocks(&r, &r);
    let mut it = 0;
    while it < max_iter && rr.sqrt() > tol * bnorm {
        apply(grid, s, c, &p, &mut ap);
        let alpha = rr / dot_blocks(&p, &ap).max(f64::MIN_POSITIVE);
        chi.par_iter_mut().zip(&p).for_each(|(x, pi)| *x += alpha * pi);
        r.par_iter_mut().zip(&ap).for_each(|(ri, api)| *ri -= alpha * api);
        let rr_new = dot_blocks(&r, &r);
        let beta = rr_new / rr;
        rr = rr_new;
        p.par_iter_mut().zip(&r).for_each(|(pi, ri)| *pi = ri + beta * *pi);
        it += 1;
    }
    LevelReport { nodes: grid.n, iterations: it, relative_residual: rr.sqrt() / bnorm }
}

/// Settings of the solve.
#[derive(Clone, Copy, Debug)]
pub struct SolveSettings {
    /// Nodes along the longest side of the finest grid.
    pub resolution: usize,
    /// Screening weight (0: plain Poisson).
    pub screening: f64,
    /// Coarser levels solved first (each half the resolution of the next).
    pub coarse_levels: usize,
    /// Relative residual at which a level stops.
    pub tolerance: f64,
    /// Most iterations per level.
    pub max_iterations: usize,
}

/// Solve coarse to fine; the finest grid, χ on it, and one report per level.
pub fn solve(bbox: &Aabb, s: &Samples, set: &SolveSettings) -> (Grid, Vec<f64>, Vec<LevelReport>) {
    let mut levels = Vec::new();
    let mut prev: Option<(Grid, Vec<f64>)> = None;
    for l in (0..=set.coarse_levels).rev() {
        let res = (set.resolution >> l).max(8);
        let grid = Grid::around(bbox, res);
        let c: Vec<f64> = s.areas.iter().map(|a| set.screening * a / (grid.h * grid.h)).collect();
        let mut chi: Vec<f64> = (0..grid.len())
            .into_par_iter()
            .map(|v| {
                let co = grid.coords(v);
                match &prev {
                    _ if grid.on_boundary(co) => 0.5,
                    Some((g, x)) => g.sample(x, grid.position(co)),
                    None => 0.0,
                }
            })
            .collect();
        levels.push(solve_level(&grid, s, &c, &mut chi, set.tolerance, set.max_iterations));
        prev = Some((grid, chi));
    }
    let (grid, chi) = prev.expect("at least one level");
    (grid, chi, levels)
}

/// The iso-value: χ at the samples, area-weighted mean.
pub fn iso_value(grid: &Grid, chi: &[f64], s: &Samples) -> f64 {
    let (num, den) = (0..s.points.len())
        .map(|i| (s.areas[i] * grid.sample(chi, wide(s.points[i])), s.areas[i]))
        .fold((0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
    num / den.max(f64::MIN_POSITIVE)
}

/// Whether χ increases along the normals at the samples (outward), as a share of the area.
pub fn outward_share(grid: &Grid, chi: &[f64], s: &Samples) -> f64 {
    let h = grid.h;
    let (num, den) = (0..s.points.len())
        .map(|i| {
            let p = wide(s.points[i]);
            let n = s.normals[i];
            let ahead = grid.sample(chi, [0, 1, 2].map(|a| p[a] + h * n[a]));
            let behind = grid.sample(chi, [0, 1, 2].map(|a| p[a] - h * n[a]));
            (if ahead > behind { s.areas[i] } else { 0.0 }, s.areas[i])
        })
        .fold((0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
    num / den.max(f64::MIN_POSITIVE)
}

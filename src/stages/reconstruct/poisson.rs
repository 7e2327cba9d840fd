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
//! conjugate gradients preconditioned by a multigrid V-cycle (damped Jacobi, trilinear transfer). Sums run in
//! fixed blocks, so the result does not depend on the number of threads.
//!
//! Node values are single precision ([`Node`]), sums and coefficients double: the solve streams its vectors
//! through memory a few dozen times, so halving them halves its time and footprint, and χ is needed only to
//! a small part of a cell (the vertices are projected onto the points afterwards, see `project`).

use rayon::prelude::*;

use crate::geometry::vec3::{Aabb, V3, wide};

/// One node value of χ or of a solver vector.
pub type Node = f32;

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

/// Coarsening steps of the multigrid hierarchy at most; the finest grid's cell counts are multiples of
/// 2^steps, so every coarser grid's nodes are nodes of the finer one.
pub const MAX_COARSENING: usize = 6;
/// Nodes along the longest side of the coarsest grid (at least).
const COARSEST_NODES: usize = 9;

impl Grid {
    /// A grid with about `res` nodes along the longest side of `bbox` enlarged by [`MARGIN`] each side,
    /// its cell counts multiples of 2^`steps`.
    pub fn around(bbox: &Aabb, res: usize, steps: usize) -> Grid {
        let ext = bbox.extent();
        let longest = ext[0].max(ext[1]).max(ext[2]).max(f64::MIN_POSITIVE);
        let margin = MARGIN * longest;
        let h = (longest + 2.0 * margin) / (res.max(4) - 1) as f64;
        let m = 1usize << steps;
        let n = [0, 1, 2].map(|k| (((ext[k] + 2.0 * margin) / h / m as f64).ceil() as usize).max(2) * m + 1);
        let origin = [0, 1, 2].map(|k| bbox.min[k] - ((n[k] - 1) as f64 * h - ext[k]) / 2.0);
        Grid { n, origin, h }
    }

    /// Coarsening steps for `res` nodes along the longest side: down to about [`COARSEST_NODES`].
    pub fn steps_for(res: usize) -> usize {
        let mut steps = 0;
        while steps < MAX_COARSENING && (res >> (steps + 1)) >= COARSEST_NODES {
            steps += 1;
        }
        steps
    }

    /// The grid with every other node (exactly nested: node I is node 2I here).
    fn coarser(&self) -> Grid {
        Grid { n: self.n.map(|n| (n - 1) / 2 + 1), origin: self.origin, h: 2.0 * self.h }
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

    /// The cell holding `p` (shifted by `shift` cells per axis, clamped into the grid) and the fractions.
    #[inline]
    fn locate(&self, p: V3, shift: [f64; 3]) -> (usize, [f64; 3]) {
        let mut base = [0usize; 3];
        let mut f = [0.0; 3];
        for a in 0..3 {
            let x = ((p[a] - self.origin[a]) / self.h - shift[a]).clamp(0.0, (self.n[a] - 2) as f64);
            let b = (x.floor() as usize).min(self.n[a] - 2);
            base[a] = b;
            f[a] = x - b as f64;
        }
        (self.idx(base[0], base[1], base[2]), f)
    }

    /// The 8 nodes of the cell at `base` with fractions `f`, and their trilinear weights.
    #[inline]
    fn corners(&self, base: usize, f: [f64; 3]) -> [(usize, f64); 8] {
        let st = [self.stride(0), self.stride(1), self.stride(2)];
        std::array::from_fn(|c| {
            let d = [c & 1, (c >> 1) & 1, (c >> 2) & 1];
            let w = (0..3).map(|a| if d[a] == 1 { f[a] } else { 1.0 - f[a] }).product::<f64>();
            (base + d[0] * st[0] + d[1] * st[1] + d[2] * st[2], w)
        })
    }

    /// The 8 nodes around `p` (shifted by `shift` cells per axis) and their trilinear weights.
    #[inline]
    fn stencil(&self, p: V3, shift: [f64; 3]) -> [(usize, f64); 8] {
        let (base, f) = self.locate(p, shift);
        self.corners(base, f)
    }

    /// Trilinear interpolation of node values `x` at `p`.
    pub fn sample(&self, x: &[Node], p: V3) -> f64 {
        self.stencil(p, [0.0; 3]).iter().map(|&(v, w)| w * f64::from(x[v])).sum()
    }

    /// Run `f(j, k, row)` for every interior row (j, k) of `out` (a node array), in parallel over z-slices;
    /// boundary nodes are set to `edge(v)` (their linear index).
    fn for_interior_rows_or<T: Copy + Send>(
        &self,
        out: &mut [T],
        edge: impl Fn(usize) -> T + Sync,
        f: impl Fn(usize, usize, &mut [T]) + Sync,
    ) {
        let [n0, n1, n2] = self.n;
        let plane = n0 * n1;
        out.par_chunks_mut(plane).enumerate().for_each(|(k, slice)| {
            let fill = |row: &mut [T], first: usize| row.iter_mut().enumerate().for_each(|(i, x)| *x = edge(first + i));
            if k == 0 || k + 1 == n2 {
                fill(slice, k * plane);
                return;
            }
            for j in 0..n1 {
                let first = k * plane + j * n0;
                let row = &mut slice[j * n0..(j + 1) * n0];
                if j == 0 || j + 1 == n1 {
                    fill(row, first);
                    continue;
                }
                f(j, k, row);
                row[0] = edge(first);
                row[n0 - 1] = edge(first + n0 - 1);
            }
        });
    }

    /// [`Self::for_interior_rows_or`] with the boundary set to 0.
    fn for_interior_rows(&self, out: &mut [Node], f: impl Fn(usize, usize, &mut [Node]) + Sync) {
        self.for_interior_rows_or(out, |_| 0.0, f);
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

/// How the solve went.
#[derive(Clone, Debug, serde::Serialize)]
pub struct LevelReport {
    /// Nodes per axis.
    pub nodes: [usize; 3],
    /// Grids of the multigrid hierarchy (the finest included).
    pub multigrid_levels: usize,
    /// Conjugate-gradient iterations.
    pub iterations: usize,
    /// Final residual relative to the right-hand side.
    pub relative_residual: f64,
}

/// The right-hand side b = h·Σₐ (g_a[j − eₐ] − g_a[j]) from the splatted edge gradients (0 on the boundary).
/// Each axis's gradients are splatted in double precision (one grid of f64 at a time) and added into b.
fn rhs(grid: &Grid, s: &Samples) -> Vec<Node> {
    let h3 = grid.h * grid.h * grid.h;
    let mut b: Vec<Node> = vec![0.0; grid.len()];
    let mut g = vec![0.0f64; grid.len()];
    for a in 0..3 {
        // Edge j → j + eₐ sits half a cell along a from node j.
        let mut shift = [0.0; 3];
        shift[a] = 0.5;
        g.par_iter_mut().for_each(|x| *x = 0.0);
        for i in 0..s.points.len() {
            let v = s.normals[i][a] * s.areas[i] / h3;
            for (e, w) in grid.stencil(wide(s.points[i]), shift) {
                g[e] += w * v;
            }
        }
        let st = grid.stride(a);
        let g = &g;
        grid.for_interior_rows_or(
            &mut b,
            |_| 0.0,
            |j, k, row| {
                let base = grid.idx(0, j, k);
                for (i, r) in row.iter_mut().enumerate().skip(1) {
                    let v = base + i;
                    if v >= st {
                        *r += (grid.h * (g[v - st] - g[v])) as Node;
                    }
                }
            },
        );
    }
    b
}

/// The screening operator S = Σᵢ cᵢ wᵢ wᵢᵀ on one grid.
enum Screen {
    /// Per sample: its cell (base node and fractions); applied by gathering and scattering through the
    /// samples (the finest grid, where nodes far outnumber the samples' cells).
    Samples(Vec<(usize, [f64; 3])>),
    /// Assembled: per touched node its 27 couplings (offsets −1, 0, +1 per axis); applied node by node
    /// (coarse grids, where many samples share a cell and the per-sample form would dominate the V-cycle).
    Assembled { nodes: Vec<usize>, coef: Vec<[f64; 27]> },
}

/// Index of the offset (dx, dy, dz) ∈ {−1, 0, 1}³ among the 27.
#[inline]
fn offset_slot(d: [isize; 3]) -> usize {
    ((d[0] + 1) + 3 * (d[1] + 1) + 9 * (d[2] + 1)) as usize
}

/// One grid of the multigrid hierarchy: the operator α·L + S on it and its damped inverse diagonal.
struct Level {
    grid: Grid,
    /// The Galerkin scale of the Laplacian on this level (1 on the finest, ×2 per coarsening: PᵀLP = 2L for
    /// the trilinear P between nested grids, away from the boundary).
    alpha: f64,
    screen: Screen,
    /// `JACOBI_DAMPING / diagonal` per node: the smoother's step.
    step: Vec<Node>,
}

impl Level {
    fn new(grid: Grid, alpha: f64, s: &Samples, c: &[f64], assembled: bool) -> Level {
        let cells: Vec<(usize, [f64; 3])> = s.points.par_iter().map(|&p| grid.locate(wide(p), [0.0; 3])).collect();
        // The screening's share of the diagonal first, then the damped inverse of the whole diagonal.
        let mut step: Vec<Node> = vec![0.0; grid.len()];
        for (i, &(base, f)) in cells.iter().enumerate() {
            for (v, w) in grid.corners(base, f) {
                step[v] += (c[i] * w * w) as Node;
            }
        }
        let six = (6.0 * alpha) as Node;
        let damping = JACOBI_DAMPING as Node;
        step.par_iter_mut().for_each(|d| *d = damping / (six + *d));
        let screen = if assembled { Self::assemble(&grid, &cells, c) } else { Screen::Samples(cells) };
        Level { grid, alpha, screen, step }
    }

    /// S as 27 couplings per touched interior node, nodes in order of first touch (deterministic). Corner
    /// `a` of a cell sits at offset (a & 1, a >> 1 & 1, a >> 2 & 1) from its base node, so two corners'
    /// offset is the difference of their bits.
    fn assemble(grid: &Grid, cells: &[(usize, [f64; 3])], c: &[f64]) -> Screen {
        let mut slot: crate::geometry::cellhash::CellMap<usize> = Default::default();
        let (mut nodes, mut coef) = (Vec::new(), Vec::new());
        let bits = |a: usize| [(a & 1) as isize, ((a >> 1) & 1) as isize, ((a >> 2) & 1) as isize];
        for (i, &(base, f)) in cells.iter().enumerate() {
            let corners = grid.corners(base, f);
            let inner = !grid.on_boundary(grid.coords(base)) && !grid.on_boundary(grid.coords(corners[7].0));
            for (ia, &(a, wa)) in corners.iter().enumerate() {
                if !inner && grid.on_boundary(grid.coords(a)) {
                    continue;
                }
                let k = *slot.entry(a as u64).or_insert_with(|| {
                    nodes.push(a);
                    coef.push([0.0; 27]);
                    nodes.len() - 1
                });
                let da = bits(ia);
                for (ib, &(_, wb)) in corners.iter().enumerate() {
                    let db = bits(ib);
                    coef[k][offset_slot([db[0] - da[0], db[1] - da[1], db[2] - da[2]])] += c[i] * wa * wb;
                }
            }
        }
        Screen::Assembled { nodes, coef }
    }

    /// The Laplacian part α·L x of one interior row (j, k), written into `row` from index 1 to n₀ − 2.
    #[inline]
    fn laplace_row(&self, x: &[Node], j: usize, k: usize, row: &mut [Node]) {
        let g = &self.grid;
        let (sy, sz) = (g.stride(1), g.stride(2));
        let alpha = self.alpha as Node;
        let base = g.idx(0, j, k);
        let n0 = g.n[0];
        let (xc, xm, xp) = (&x[base..base + n0], &x[base - sy..base - sy + n0], &x[base + sy..base + sy + n0]);
        let (zm, zp) = (&x[base - sz..base - sz + n0], &x[base + sz..base + sz + n0]);
        for i in 1..n0 - 1 {
            row[i] = alpha * (6.0 * xc[i] - xc[i - 1] - xc[i + 1] - xm[i] - xp[i] - zm[i] - zp[i]);
        }
    }

    /// For each screened node v (interior), `f(v, (S x)[v])`: the samples' values gathered and scattered in
    /// sample order (deterministic).
    fn screen_apply(&self, c: &[f64], x: &[Node], mut f: impl FnMut(usize, f64)) {
        let g = &self.grid;
        match &self.screen {
            Screen::Samples(cells) => {
                let vals: Vec<f64> = cells
                    .par_iter()
                    .enumerate()
                    .map(|(i, &(b, fr))| c[i] * g.corners(b, fr).iter().map(|&(v, w)| w * f64::from(x[v])).sum::<f64>())
                    .collect();
                for (&(b, fr), &t) in cells.iter().zip(&vals) {
                    let corners = g.corners(b, fr);
                    // A sample's cell may touch the boundary on a small grid; the boundary stays exactly 0.
                    let inner = !g.on_boundary(g.coords(b)) && !g.on_boundary(g.coords(corners[7].0));
                    for (v, w) in corners {
                        if inner || !g.on_boundary(g.coords(v)) {
                            f(v, w * t);
                        }
                    }
                }
            }
            Screen::Assembled { nodes, coef } => {
                let st = [1isize, g.stride(1) as isize, g.stride(2) as isize];
                for (&v, cf) in nodes.iter().zip(coef) {
                    let mut acc = 0.0;
                    for (t, &w) in cf.iter().enumerate() {
                        if w != 0.0 {
                            let d = [(t % 3) as isize - 1, ((t / 3) % 3) as isize - 1, (t / 9) as isize - 1];
                            acc += w * f64::from(x[(v as isize + d[0] * st[0] + d[1] * st[1] + d[2] * st[2]) as usize]);
                        }
                    }
                    f(v, acc);
                }
            }
        }
    }

    /// y = (α·L + S) x on the interior nodes (y = 0 on the boundary); x is read everywhere.
    fn apply(&self, c: &[f64], x: &[Node], y: &mut [Node]) {
        self.grid.for_interior_rows(y, |j, k, row| self.laplace_row(x, j, k, row));
        self.screen_apply(c, x, |v, t| y[v] += t as Node);
    }

    /// y = r − (α·L + S) x on the interior nodes (y = 0 on the boundary).
    fn residual(&self, c: &[f64], r: &[Node], x: &[Node], y: &mut [Node]) {
        let n0 = self.grid.n[0];
        self.grid.for_interior_rows(y, |j, k, row| {
            self.laplace_row(x, j, k, row);
            let base = self.grid.idx(0, j, k);
            for (yv, rv) in row[1..n0 - 1].iter_mut().zip(&r[base + 1..base + n0 - 1]) {
                *yv = rv - *yv;
            }
        });
        self.screen_apply(c, x, |v, t| y[v] -= t as Node);
    }

    /// `rounds` of damped Jacobi on (α·L + S) x = r from `x`; `next` is scratch. The boundary of `x` stays.
    /// One pass per round: x' = x + step·(r − L x) row by row, then the screening's part at the few screened
    /// nodes, x' −= step·(S x).
    fn smooth(&self, c: &[f64], r: &[Node], x: &mut Vec<Node>, next: &mut Vec<Node>, rounds: usize) {
        let n0 = self.grid.n[0];
        for _ in 0..rounds {
            {
                let (xs, step) = (&x[..], &self.step[..]);
                self.grid.for_interior_rows_or(
                    next,
                    |v| xs[v],
                    |j, k, row| {
                        self.laplace_row(xs, j, k, row);
                        let base = self.grid.idx(0, j, k);
                        for i in 1..n0 - 1 {
                            let v = base + i;
                            row[i] = xs[v] + step[v] * (r[v] - row[i]);
                        }
                    },
                );
            }
            self.screen_apply(c, x, |v, t| next[v] -= self.step[v] * t as Node);
            std::mem::swap(x, next);
        }
    }
}

/// Damping of the Jacobi smoother (2/3 damps the 7-point Laplacian's high frequencies best).
const JACOBI_DAMPING: f64 = 2.0 / 3.0;
/// Jacobi rounds before and after each coarse-grid correction.
const SMOOTHING_ROUNDS: usize = 2;
/// Jacobi rounds on the coarsest grid.
const COARSEST_ROUNDS: usize = 60;

/// 1-D weights of the trilinear prolongation between nested grids: fine offset −1, 0, +1 from 2I.
const HAT: [Node; 3] = [0.5, 1.0, 0.5];

/// The transpose of [`prolong_add`] into `out`: each interior coarse node gathers the fine values around its
/// twin with the hat weights (parallel over coarse nodes: deterministic).
fn restrict(fine: &Grid, coarse: &Grid, x: &[Node], out: &mut [Node]) {
    coarse.for_interior_rows(out, |j, k, row| {
        for (i, r) in row.iter_mut().enumerate().take(coarse.n[0] - 1).skip(1) {
            let mut acc = 0.0;
            for (dk, wk) in HAT.iter().enumerate() {
                for (dj, wj) in HAT.iter().enumerate() {
                    let base = fine.idx(2 * i - 1, 2 * j + dj - 1, 2 * k + dk - 1);
                    acc += wk * wj * (0.5 * x[base] + x[base + 1] + 0.5 * x[base + 2]);
                }
            }
            *r = acc;
        }
    });
}

/// Add the coarse values interpolated at the fine nodes (trilinear between nested grids) to `out`, except
/// on the fine boundary. Row by row: the (at most four) coarse rows a fine row lies between are blended
/// first, then interpolated along x.
fn prolong_add(coarse: &Grid, fine: &Grid, x: &[Node], out: &mut [Node]) {
    let pair = |f: usize| -> ([usize; 2], [Node; 2]) {
        if f.is_multiple_of(2) { ([f / 2, f / 2], [1.0, 0.0]) } else { ([f / 2, f / 2 + 1], [0.5, 0.5]) }
    };
    let [n0, n1, n2] = fine.n;
    let c0 = coarse.n[0];
    out.par_chunks_mut(n0 * n1).enumerate().for_each_init(
        || vec![0.0; c0],
        |t, (k, slice)| {
            if k == 0 || k + 1 == n2 {
                return;
            }
            let (ck, wk) = pair(k);
            for j in 1..n1 - 1 {
                let (cj, wj) = pair(j);
                t.iter_mut().for_each(|v| *v = 0.0);
                for a in 0..2 {
                    for b in 0..2 {
                        let w = wk[a] * wj[b];
                        if w != 0.0 {
                            let row = coarse.idx(0, cj[b], ck[a]);
                            for (tv, xv) in t.iter_mut().zip(&x[row..row + c0]) {
                                *tv += w * xv;
                            }
                        }
                    }
                }
                let dst = &mut slice[j * n0..(j + 1) * n0];
                for (i, d) in dst.iter_mut().enumerate().take(n0 - 1).skip(1) {
                    *d += if i % 2 == 0 { t[i / 2] } else { 0.5 * (t[i / 2] + t[i / 2 + 1]) };
                }
            }
        },
    );
}

/// Scratch of one level for the V-cycle: its correction, a second buffer, its right-hand side (coarse levels).
struct Work {
    x: Vec<Node>,
    ax: Vec<Node>,
    r: Vec<Node>,
}

/// One V-cycle on `levels[0]` (coarser ones after it) for the residual `r` (or `work[0].r`): leaves an
/// approximation of (α·L + S)⁻¹ r in `work[0].x`; symmetric in r. `work[i]` is the scratch of `levels[i]`.
fn vcycle(levels: &[Level], c: &[f64], r: Option<&[Node]>, work: &mut [Work]) {
    let lev = &levels[0];
    let (here, below) = work.split_at_mut(1);
    let w = &mut here[0];
    let r: &[Node] = r.unwrap_or(&w.r);
    w.x.par_iter_mut().for_each(|v| *v = 0.0);
    if levels.len() == 1 {
        lev.smooth(c, r, &mut w.x, &mut w.ax, COARSEST_ROUNDS);
        return;
    }
    lev.smooth(c, r, &mut w.x, &mut w.ax, SMOOTHING_ROUNDS);
    lev.residual(c, r, &w.x, &mut w.ax);
    restrict(&lev.grid, &levels[1].grid, &w.ax, &mut below[0].r);
    vcycle(&levels[1..], c, None, below);
    prolong_add(&levels[1].grid, &lev.grid, &below[0].x, &mut w.x);
    lev.smooth(c, r, &mut w.x, &mut w.ax, SMOOTHING_ROUNDS);
}

/// Σ a·b in double precision, in fixed blocks of 4096 summed in order: the same bits for any number of
/// threads.
fn dot_blocks(a: &[Node], b: &[Node]) -> f64 {
    let parts: Vec<f64> = a
        .par_chunks(4096)
        .zip(b.par_chunks(4096))
        .map(|(x, y)| x.iter().zip(y).map(|(p, q)| f64::from(*p) * f64::from(*q)).sum())
        .collect();
    parts.iter().sum()
}

/// Solve (L + S) χ = b on the finest grid by conjugate gradients preconditioned with one multigrid V-cycle;
/// `chi` holds the start (boundary +½).
fn solve_mgpcg(levels: &[Level], s: &Samples, c: &[f64], chi: &mut [Node], tol: f64, max_iter: usize) -> LevelReport {
    let fine = &levels[0];
    let n = fine.grid.len();
    let mut r = rhs(&fine.grid, s);
    let bnorm = dot_blocks(&r, &r).sqrt().max(f64::MIN_POSITIVE);
    let mut work: Vec<Work> = levels
        .iter()
        .enumerate()
        .map(|(i, l)| Work {
            x: vec![0.0; l.grid.len()],
            ax: vec![0.0; l.grid.len()],
            r: if i == 0 { Vec::new() } else { vec![0.0; l.grid.len()] },
        })
        .collect();
    // r = b − A χ (the boundary's +½ enters through the Laplacian's neighbours), built in the scratch.
    fine.residual(c, &r, chi, &mut work[0].ax);
    std::mem::swap(&mut r, &mut work[0].ax);
    vcycle(levels, c, Some(&r), &mut work);
    let mut p = work[0].x.clone();
    let mut ap = vec![0.0; n];
    let mut rz = dot_blocks(&r, &work[0].x);
    let mut rnorm = dot_blocks(&r, &r).sqrt();
    let mut it = 0;
    while it < max_iter && rnorm > tol * bnorm {
        fine.apply(c, &p, &mut ap);
        let alpha = rz / dot_blocks(&p, &ap).max(f64::MIN_POSITIVE);
        let a = alpha as Node;
        chi.par_iter_mut().zip(&p).for_each(|(x, pi)| *x += a * pi);
        r.par_iter_mut().zip(&ap).for_each(|(ri, api)| *ri -= a * api);
        rnorm = dot_blocks(&r, &r).sqrt();
        vcycle(levels, c, Some(&r), &mut work);
        let z = &work[0].x;
        let rz_new = dot_blocks(&r, z);
        let beta = (rz_new / rz) as Node;
        rz = rz_new;
        p.par_iter_mut().zip(z).for_each(|(pi, zi)| *pi = zi + beta * *pi);
        it += 1;
    }
    LevelReport { nodes: fine.grid.n, multigrid_levels: levels.len(), iterations: it, relative_residual: rnorm / bnorm }
}

/// Settings of the solve.
#[derive(Clone, Copy, Debug)]
pub struct SolveSettings {
    /// Nodes along the longest side of the finest grid.
    pub resolution: usize,
    /// Screening weight (0: plain Poisson).
    pub screening: f64,
    /// Relative residual at which the solve stops.
    pub tolerance: f64,
    /// Most iterations.
    pub max_iterations: usize,
}

/// The finest grid the solve uses for `res` nodes along the longest side of `bbox`.
pub fn finest_grid(bbox: &Aabb, res: usize) -> Grid {
    Grid::around(bbox, res, Grid::steps_for(res))
}

/// Solve on the finest grid (multigrid-preconditioned CG); the grid, χ on it, and the solve's report.
pub fn solve(bbox: &Aabb, s: &Samples, set: &SolveSettings) -> (Grid, Vec<Node>, Vec<LevelReport>) {
    let steps = Grid::steps_for(set.resolution);
    let grid = Grid::around(bbox, set.resolution, steps);
    let c: Vec<f64> = s.areas.iter().map(|a| set.screening * a / (grid.h * grid.h)).collect();
    let mut levels = vec![Level::new(grid.clone(), 1.0, s, &c, false)];
    for _ in 0..steps {
        let last = levels.last().expect("one level");
        let coarse = last.grid.coarser();
        let alpha = 2.0 * last.alpha;
        levels.push(Level::new(coarse, alpha, s, &c, true));
    }
    let mut chi: Vec<Node> =
        (0..grid.len()).into_par_iter().map(|v| if grid.on_boundary(grid.coords(v)) { 0.5 } else { 0.0 }).collect();
    let report = solve_mgpcg(&levels, s, &c, &mut chi, set.tolerance, set.max_iterations);
    (grid, chi, vec![report])
}

/// The iso-value: χ at the samples, area-weighted mean.
pub fn iso_value(grid: &Grid, chi: &[Node], s: &Samples) -> f64 {
    let (num, den) = (0..s.points.len())
        .map(|i| (s.areas[i] * grid.sample(chi, wide(s.points[i])), s.areas[i]))
        .fold((0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
    num / den.max(f64::MIN_POSITIVE)
}

/// Whether χ increases along the normals at the samples (outward), as a share of the area.
pub fn outward_share(grid: &Grid, chi: &[Node], s: &Samples) -> f64 {
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

//! The linear system: active basis functions, stiffness blocks assembled cell by cell, weak supports
//! (Nitsche or penalty on surface quadrature points), loads, and the solve (faer's sparse Cholesky; Jacobi PCG when the
//! factor would not fit the memory budget).

use rayon::prelude::*;

use super::basis::{self, GradientIntegrals};
use super::domain::{CellFill, Domain, Grid, full_moments};
use crate::error::{Error, ErrorCode, Result};
use crate::geometry::vec3::{V3, dot};

/// Neighbour slots kept per function row: offsets (dx, dy, dz) ∈ [−2, 2]³ at or after (0, 0, 0) in
/// lexicographic (z, y, x) order, i.e. the upper half of the symmetric matrix. Slot 0 is the diagonal.
pub const SLOTS: usize = 63;

/// Slot of offset `d` (each in −2..=2) in the upper half; `None` for the lower half.
#[inline]
fn slot(d: [i64; 3]) -> Option<usize> {
    let s = ((d[2] + 2) * 5 + (d[1] + 2)) * 5 + (d[0] + 2);
    if s >= 62 { Some((s - 62) as usize) } else { None }
}

#[inline]
fn slot_offset(s: usize) -> [i64; 3] {
    let s = s as i64 + 62;
    [s % 5 - 2, (s / 5) % 5 - 2, s / 25 - 2]
}

/// Basis functions that touch an active cell, numbered in global (z, y, x) order.
pub struct Dofs {
    /// Functions per axis: grid cells + 2.
    pub nf: [usize; 3],
    /// Global function index → rank among active functions (`u32::MAX` when inactive).
    pub rank: Vec<u32>,
    /// Rank → global function index.
    pub functions: Vec<usize>,
}

impl Dofs {
    fn new(grid: &Grid, active_cells: &[usize]) -> Dofs {
        let nf = [grid.n[0] + 2, grid.n[1] + 2, grid.n[2] + 2];
        let mut mark = vec![false; nf[0] * nf[1] * nf[2]];
        for &c in active_cells {
            let [cx, cy, cz] = cell_coords(grid, c);
            for k in 0..3 {
                for j in 0..3 {
                    for i in 0..3 {
                        mark[((cz + k) * nf[1] + cy + j) * nf[0] + cx + i] = true;
                    }
                }
            }
        }
        let mut rank = vec![u32::MAX; mark.len()];
        let mut functions = Vec::new();
        for (f, &m) in mark.iter().enumerate() {
            if m {
                rank[f] = functions.len() as u32;
                functions.push(f);
            }
        }
        Dofs { nf, rank, functions }
    }

    /// Global indices of the 27 functions of cell `c`, local order (x fastest).
    #[inline]
    pub fn cell_functions(&self, c: [usize; 3]) -> [usize; 27] {
        let mut out = [0; 27];
        for k in 0..3 {
            for j in 0..3 {
                for i in 0..3 {
                    out[(k * 3 + j) * 3 + i] = ((c[2] + k) * self.nf[1] + c[1] + j) * self.nf[0] + c[0] + i;
                }
            }
        }
        out
    }

    /// Number of unknowns (3 per active function).
    pub fn len(&self) -> usize {
        3 * self.functions.len()
    }

    /// No active function (nothing to solve for).
    pub fn is_empty(&self) -> bool {
        self.functions.is_empty()
    }
}

/// Fill-reducing order of the active functions by geometric nested dissection of the function grid: split
/// the set's bounding box across its longest side by a separator two functions thick (functions couple
/// within ±2 indices, so the halves do not), order the halves recursively and the separator last. Returns
/// ranks in elimination order. Cost: O(F log F).
pub fn nested_dissection(dofs: &Dofs) -> Vec<u32> {
    let nf = dofs.nf;
    let coords = |f: usize| [f % nf[0], (f / nf[0]) % nf[1], f / (nf[0] * nf[1])];
    let all: Vec<u32> = (0..dofs.functions.len() as u32).collect();
    let mut order = Vec::with_capacity(all.len());
    fn recurse(set: Vec<u32>, dofs: &Dofs, coords: &dyn Fn(usize) -> [usize; 3], order: &mut Vec<u32>) {
        if set.len() <= 96 {
            order.extend(set);
            return;
        }
        let (mut lo, mut hi) = ([usize::MAX; 3], [0usize; 3]);
        for &r in &set {
            let c = coords(dofs.functions[r as usize]);
            for k in 0..3 {
                lo[k] = lo[k].min(c[k]);
                hi[k] = hi[k].max(c[k]);
            }
        }
        let axis = (0..3).max_by_key(|&k| (hi[k] - lo[k], 3 - k)).unwrap_or(0);
        if hi[axis] - lo[axis] < 4 {
            order.extend(set);
            return;
        }
        let m = (lo[axis] + hi[axis]) / 2;
        let (mut left, mut right, mut sep) = (Vec::new(), Vec::new(), Vec::new());
        for r in set {
            let c = coords(dofs.functions[r as usize])[axis];
            if c < m {
                left.push(r);
            } else if c < m + 2 {
                sep.push(r);
            } else {
                right.push(r);
            }
        }
        recurse(left, dofs, coords, order);
        recurse(right, dofs, coords, order);
        order.extend(sep);
    }
    recurse(all, dofs, &coords, &mut order);
    order
}

/// Cell coordinates of linear cell index `c`.
#[inline]
pub fn cell_coords(grid: &Grid, c: usize) -> [usize; 3] {
    [c % grid.n[0], (c / grid.n[0]) % grid.n[1], c / (grid.n[0] * grid.n[1])]
}

/// Upper-half block rows of the stiffness: `blocks[rank · SLOTS + slot][p · 3 + q]` = K_{(f, p), (g, q)}.
pub struct Stiffness {
    /// The blocks, 3×3 row-major.
    pub blocks: Vec<[f64; 9]>,
}

/// Lamé constants from E and ν.
pub fn lame(e: f64, nu: f64) -> (f64, f64) {
    (e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu)), e / (2.0 * (1.0 + nu)))
}

impl Stiffness {
    fn new(n_functions: usize) -> Stiffness {
        Stiffness { blocks: vec![[0.0; 9]; n_functions * SLOTS] }
    }

    /// Call `f(rank of a, slot, a, b)` for every local pair (a, b) of the cell's functions `f` in the upper half.
    fn upper_pairs(dofs: &Dofs, funcs: &[usize; 27], mut f: impl FnMut(usize, usize, usize, usize)) {
        for a in 0..27 {
            let ra = dofs.rank[funcs[a]] as usize;
            for b in 0..27 {
                let d = [
                    (b % 3) as i64 - (a % 3) as i64,
                    ((b / 3) % 3) as i64 - ((a / 3) % 3) as i64,
                    (b / 9) as i64 - (a / 9) as i64,
                ];
                if let Some(s) = slot(d) {
                    f(ra, s, a, b);
                }
            }
        }
    }

    /// Add an 81 × 81 element matrix over the cell's functions `f` (upper half only).
    fn add_element(&mut self, dofs: &Dofs, f: &[usize; 27], k: &[f64]) {
        Self::upper_pairs(dofs, f, |ra, s, a, b| {
            let blk = &mut self.blocks[ra * SLOTS + s];
            for p in 0..3 {
                for q in 0..3 {
                    blk[p * 3 + q] += k[(3 * a + p) * 81 + 3 * b + q];
                }
            }
        });
    }

    /// Add β·w·N_a·N_b·I₃ for one surface point with the cell's function values `n`.
    fn add_penalty(&mut self, dofs: &Dofs, f: &[usize; 27], n: &[f64; 27], bw: f64) {
        Self::upper_pairs(dofs, f, |ra, s, a, b| {
            let v = bw * n[a] * n[b];
            let blk = &mut self.blocks[ra * SLOTS + s];
            blk[0] += v;
            blk[4] += v;
            blk[8] += v;
        });
    }

    /// The stored blocks of function rank `r`: (slot, rank of the neighbour, block), skipping zero blocks
    /// off the diagonal.
    fn row<'a>(&'a self, dofs: &'a Dofs, r: usize) -> impl Iterator<Item = (usize, usize, &'a [f64; 9])> + 'a {
        let f = dofs.functions[r] as i64;
        let [nx, ny, _] = dofs.nf.map(|n| n as i64);
        (0..SLOTS).filter_map(move |s| {
            let blk = &self.blocks[r * SLOTS + s];
            if s > 0 && blk.iter().all(|&v| v == 0.0) {
                return None;
            }
            let d = slot_offset(s);
            let g = (f + (d[2] * ny + d[1]) * nx + d[0]) as usize;
            Some((s, dofs.rank[g] as usize, blk))
        })
    }

    /// y = K x (full symmetric product from the upper half).
    fn apply(&self, dofs: &Dofs, x: &[f64], y: &mut [f64]) {
        y.iter_mut().for_each(|v| *v = 0.0);
        for r in 0..dofs.functions.len() {
            for (s, rg, blk) in self.row(dofs, r) {
                for p in 0..3 {
                    for q in 0..3 {
                        let v = blk[p * 3 + q];
                        y[3 * r + p] += v * x[3 * rg + q];
                        if s > 0 {
                            y[3 * rg + q] += v * x[3 * r + p];
                        }
                    }
                }
            }
        }
    }
}

/// A point of surface quadrature: position, weight (area), outward unit normal.
#[derive(Clone, Copy, Debug)]
pub struct SurfacePoint {
    /// Position.
    pub p: V3,
    /// Weight (area).
    pub w: f64,
    /// Outward unit normal.
    pub n: V3,
}

/// Everything assembled: the active cells, functions, stiffness and load vector.
pub struct System {
    /// The active functions and their unknowns.
    pub dofs: Dofs,
    /// The stiffness matrix (upper half).
    pub stiffness: Stiffness,
    /// The load vector.
    pub rhs: Vec<f64>,
    /// Cut cells (partly inside).
    pub cut_cells: usize,
    /// All active cells (inside volume, or holding a surface point).
    pub active_cells: usize,
}

/// Assemble the bulk stiffness (λ, μ; fictitious factor α outside) over `domain`'s cells plus `extra_cells`
/// (cells holding surface points but no inside volume by the line sampling), and the body force `body`
/// (force per volume). Cost: O(cut cells · 60k + cells · 27² · 9) flops, O(functions · 63 · 72 B) memory.
pub fn assemble(domain: &Domain, extra_cells: &[usize], lambda: f64, mu: f64, alpha: f64, body: V3) -> System {
    let grid = &domain.grid;
    let mut active: Vec<usize> = domain.cells.iter().map(|c| c.0).chain(extra_cells.iter().copied()).collect();
    active.sort_unstable();
    active.dedup();
    let dofs = Dofs::new(grid, &active);
    let mut stiffness = Stiffness::new(dofs.functions.len());
    let mut rhs = vec![0.0; dofs.len()];
    let h = grid.h;
    let full = full_moments();
    let full_g = basis::gradient_integrals(&full);
    let k_full = basis::element_stiffness(&full_g, lambda, mu, h);
    let full_n = basis::value_integrals(&full);
    let h3 = h * h * h;
    let add_body = |rhs: &mut Vec<f64>, f: &[usize; 27], n: &[f64; 27]| {
        for a in 0..27 {
            let r = dofs.rank[f[a]] as usize;
            for p in 0..3 {
                rhs[3 * r + p] += body[p] * n[a] * h3;
            }
        }
    };
    // Cut cells (and extra cells: nothing inside) in chunks: element matrices in parallel, added in order.
    let mut cut: Vec<(usize, Option<&CellFill>)> = Vec::new();
    for (idx, fill) in &domain.cells {
        let f = dofs.cell_functions(cell_coords(grid, *idx));
        match fill {
            CellFill::Full => {
                stiffness.add_element(&dofs, &f, &k_full);
                add_body(&mut rhs, &f, &full_n);
            }
            CellFill::Cut(_) => cut.push((*idx, Some(fill))),
        }
    }
    let domain_set: std::collections::HashSet<usize> = domain.cells.iter().map(|c| c.0).collect();
    for &c in extra_cells {
        if !domain_set.contains(&c) {
            cut.push((c, None));
        }
    }
    cut.sort_unstable_by_key(|c| c.0);
    cut.dedup_by_key(|c| c.0);
    let cut_cells = cut.len();
    for chunk in cut.chunks(256) {
        let mats: Vec<(Vec<f64>, [f64; 27])> = chunk
            .par_iter()
            .map(|(_, fill)| {
                let inside = match fill {
                    Some(CellFill::Cut(m)) => **m,
                    _ => [0.0; 125],
                };
                // K = K(inside) + α K(outside) = K(inside + α (full − inside)).
                let mut eff = [0.0; 125];
                for i in 0..125 {
                    eff[i] = inside[i] + alpha * (full[i] - inside[i]);
                }
                let g: GradientIntegrals = basis::gradient_integrals(&eff);
                (basis::element_stiffness(&g, lambda, mu, h), basis::value_integrals(&inside))
            })
            .collect();
        for ((idx, _), (k, n)) in chunk.iter().zip(mats) {
            let f = dofs.cell_functions(cell_coords(grid, *idx));
            stiffness.add_element(&dofs, &f, &k);
            add_body(&mut rhs, &f, &n);
        }
    }
    System { dofs, stiffness, rhs, cut_cells, active_cells: active.len() }
}

impl System {
    /// Add a penalty support at surface points (β per unit area).
    pub fn add_support(&mut self, grid: &Grid, points: &[SurfacePoint], beta: f64) {
        for sp in points {
            let (c, t) = grid.locate(sp.p);
            let f = self.dofs.cell_functions(c);
            let (n, _) = basis::shape(t, grid.h);
            self.stiffness.add_penalty(&self.dofs, &f, &n, beta * sp.w);
        }
    }

    /// Nitsche's weak support, u = 0 at `points`: adds, cell by cell,
    /// −∫_Γ (σ(u)·n)·v − ∫_Γ (σ(v)·n)·u + β_c ∫_Γ u·v. Unlike a large penalty it is consistent (the exact
    /// solution satisfies the discrete equations), so a cell cut by the edge of a support does not lock as a
    /// whole. β_c = `stability` · λ_max of the cell's trace eigenproblem ∫_Γc |σ(v)·n|² = λ a_c(v, v) (the
    /// cell's own stiffness, fictitious part included), which keeps the form coercive however the cell is cut
    /// (β_c > 2 λ_max suffices). Returns β for every point (for the reaction).
    /// Cost: one 81 × 81 Cholesky and eigenvalue problem per cell holding support points.
    pub fn add_nitsche_support(&mut self, domain: &Domain, points: &[SurfacePoint], elastic: Elastic) -> Vec<f64> {
        let grid = &domain.grid;
        let h = grid.h;
        let fills: std::collections::HashMap<usize, &CellFill> = domain.cells.iter().map(|(i, f)| (*i, f)).collect();
        let mut order: Vec<(usize, usize)> =
            points.iter().enumerate().map(|(i, sp)| (grid.cell_index(grid.locate(sp.p).0), i)).collect();
        order.sort_unstable();
        let groups: Vec<&[(usize, usize)]> = order.chunk_by(|a, b| a.0 == b.0).collect();
        let full = full_moments();
        let local: Vec<(usize, Vec<f64>, f64)> = groups
            .par_iter()
            .map(|group| {
                let cell = group[0].0;
                let moments = match fills.get(&cell) {
                    Some(CellFill::Full) => full,
                    Some(CellFill::Cut(m)) => **m,
                    None => [0.0; 125],
                };
                let mut eff = [0.0; 125];
                for i in 0..125 {
                    eff[i] = moments[i] + elastic.alpha * (full[i] - moments[i]);
                }
                let k_cell = basis::element_stiffness(&basis::gradient_integrals(&eff), elastic.lambda, elastic.mu, h);
                let mut trace = vec![0.0; 81 * 81];
                let mut consistency = vec![0.0; 81 * 81];
                let mut mass = vec![0.0; 27 * 27];
                for &(_, i) in group.iter() {
                    let sp = &points[i];
                    let (_, t) = grid.locate(sp.p);
                    let (n, g) = basis::shape(t, h);
                    let tr = traction_operator(&g, sp.n, elastic);
                    for a in 0..27 {
                        for b in 0..27 {
                            mass[a * 27 + b] += sp.w * n[a] * n[b];
                        }
                    }
                    for ap in 0..81 {
                        let (a, p) = (ap / 3, ap % 3);
                        for bq in 0..81 {
                            let (b, q) = (bq / 3, bq % 3);
                            trace[ap * 81 + bq] += sp.w * dot(tr[ap], tr[bq]);
                            consistency[ap * 81 + bq] -= sp.w * (n[a] * tr[bq][p] + n[b] * tr[ap][q]);
                        }
                    }
                }
                let beta = elastic.stability * largest_generalised_eigenvalue(&trace, &k_cell);
                let mut k = consistency;
                for a in 0..27 {
                    for b in 0..27 {
                        for p in 0..3 {
                            k[(3 * a + p) * 81 + 3 * b + p] += beta * mass[a * 27 + b];
                        }
                    }
                }
                (cell, k, beta)
            })
            .collect();
        let mut betas = vec![0.0; points.len()];
        for ((cell, k, beta), group) in local.iter().zip(&groups) {
            let f = self.dofs.cell_functions(cell_coords(grid, *cell));
            self.stiffness.add_element(&self.dofs, &f, k);
            for &(_, i) in group.iter() {
                betas[i] = *beta;
            }
        }
        betas
    }

    /// Add a traction (force per area) at surface points; `traction(point)` gives it.
    pub fn add_traction(&mut self, grid: &Grid, points: &[SurfacePoint], traction: impl Fn(&SurfacePoint) -> V3) {
        for sp in points {
            let (c, t) = grid.locate(sp.p);
            let f = self.dofs.cell_functions(c);
            let (n, _) = basis::shape(t, grid.h);
            let tr = traction(sp);
            for a in 0..27 {
                let r = self.dofs.rank[f[a]] as usize;
                for p in 0..3 {
                    self.rhs[3 * r + p] += tr[p] * n[a] * sp.w;
                }
            }
        }
    }

    /// The lower triangle in compressed columns (column = row of the upper-half blocks).
    fn lower_csc(&self) -> (Vec<usize>, Vec<usize>, Vec<f64>) {
        let mut col_ptr = Vec::with_capacity(self.dofs.len() + 1);
        let mut row_idx = Vec::new();
        let mut val = Vec::new();
        col_ptr.push(0);
        for r in 0..self.dofs.functions.len() {
            for p in 0..3 {
                for (s, rg, blk) in self.stiffness.row(&self.dofs, r) {
                    let q0 = if s == 0 { p } else { 0 };
                    for q in q0..3 {
                        row_idx.push(3 * rg + q);
                        val.push(blk[p * 3 + q]);
                    }
                }
                col_ptr.push(row_idx.len());
            }
        }
        (col_ptr, row_idx, val)
    }

    /// Solve K u = f. Uses a sparse Cholesky factor when it fits `memory_budget` bytes, else Jacobi PCG.
    ///
    /// # Errors
    /// `fea.singular` when the factorisation meets a non-positive pivot; `fea.not-converged` when PCG does not
    /// reach 1e-10 relative residual; `internal.bug` for a malformed matrix.
    pub fn solve(&self, memory_budget: u64) -> Result<(Vec<f64>, SolverReport)> {
        use faer::dyn_stack::{MemBuffer, MemStack};
        use faer::linalg::cholesky::llt::factor::LltRegularization;
        use faer::sparse::linalg::cholesky::factorize_symbolic_cholesky;
        use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
        let n = self.dofs.len();
        let (col_ptr, row_idx, val) = self.lower_csc();
        let nnz = val.len();
        let sym = SymbolicSparseColMatRef::new_checked(n, n, &col_ptr, None, &row_idx);
        let mat = SparseColMatRef::new(sym, &val);
        let order = nested_dissection(&self.dofs);
        let fwd: Vec<usize> =
            order.iter().flat_map(|&r| [3 * r as usize, 3 * r as usize + 1, 3 * r as usize + 2]).collect();
        let mut inv = vec![0usize; n];
        for (new, &old) in fwd.iter().enumerate() {
            inv[old] = new;
        }
        let perm = faer::perm::PermRef::new_checked(&fwd, &inv, n);
        let ordering = faer::sparse::linalg::cholesky::SymmetricOrdering::Custom(perm);
        let symbolic = factorize_symbolic_cholesky(sym, faer::Side::Lower, ordering, Default::default())
            .map_err(|e| Error::internal(format!("symbolic Cholesky: {e:?}")))?;
        let factor_bytes = symbolic.len_val() as u64 * 8;
        if factor_bytes > memory_budget / 2 {
            tracing::info!(factor_mib = factor_bytes >> 20, "Cholesky factor over budget: PCG");
            return self.solve_pcg(nnz);
        }
        let par = faer::get_global_parallelism();
        let mut l_values = vec![0.0f64; symbolic.len_val()];
        let mut mem = MemBuffer::new(symbolic.factorize_numeric_llt_scratch::<f64>(par, Default::default()));
        let llt = symbolic
            .factorize_numeric_llt::<f64>(
                &mut l_values,
                mat,
                faer::Side::Lower,
                LltRegularization::default(),
                par,
                MemStack::new(&mut mem),
                Default::default(),
            )
            .map_err(|e| {
                Error::new(ErrorCode::FeaSingular, format!("the stiffness matrix is not positive definite ({e:?})"))
                    .with_hint("the supports must hold every rigid motion: fix an area, not a point or a line")
            })?;
        let mut x = faer::Mat::<f64>::from_fn(n, 1, |i, _| self.rhs[i]);
        let mut mem = MemBuffer::new(symbolic.solve_in_place_scratch::<f64>(1, par));
        llt.solve_in_place_with_conj(faer::Conj::No, x.as_mut(), par, MemStack::new(&mut mem));
        let u: Vec<f64> = (0..n).map(|i| x[(i, 0)]).collect();
        if u.iter().any(|v| !v.is_finite()) {
            return Err(Error::new(ErrorCode::FeaSingular, "the solution is not finite: the system is singular"));
        }
        let residual = self.relative_residual(&u);
        Ok((
            u,
            SolverReport {
                kind: "cholesky",
                matrix_nonzeros: nnz,
                factor_nonzeros: symbolic.len_val(),
                iterations: 1,
                relative_residual: residual,
            },
        ))
    }

    fn relative_residual(&self, u: &[f64]) -> f64 {
        let mut ku = vec![0.0; u.len()];
        self.stiffness.apply(&self.dofs, u, &mut ku);
        let r2: f64 = ku.iter().zip(&self.rhs).map(|(a, b)| (a - b) * (a - b)).sum();
        let f2: f64 = self.rhs.iter().map(|v| v * v).sum();
        (r2 / f2.max(1e-300)).sqrt()
    }

    fn solve_pcg(&self, nnz: usize) -> Result<(Vec<f64>, SolverReport)> {
        let n = self.dofs.len();
        let diag: Vec<f64> = (0..n)
            .map(|i| {
                let (r, p) = (i / 3, i % 3);
                self.stiffness.blocks[r * SLOTS][p * 4]
            })
            .collect();
        let fnorm = self.rhs.iter().map(|v| v * v).sum::<f64>().sqrt();
        let mut x = vec![0.0; n];
        let mut r = self.rhs.clone();
        let mut z: Vec<f64> = r.iter().zip(&diag).map(|(a, d)| a / d).collect();
        let mut p = z.clone();
        let mut ap = vec![0.0; n];
        let mut rz: f64 = r.iter().zip(&z).map(|(a, b)| a * b).sum();
        let max_iter = 20 * n.max(1000);
        for it in 0..max_iter {
            let rn = r.iter().map(|v| v * v).sum::<f64>().sqrt();
            if rn <= 1e-10 * fnorm {
                return Ok((
                    x,
                    SolverReport {
                        kind: "pcg",
                        matrix_nonzeros: nnz,
                        factor_nonzeros: 0,
                        iterations: it,
                        relative_residual: rn / fnorm,
                    },
                ));
            }
            self.stiffness.apply(&self.dofs, &p, &mut ap);
            let pap: f64 = p.iter().zip(&ap).map(|(a, b)| a * b).sum();
            if !(pap > 0.0) {
                return Err(Error::new(ErrorCode::FeaSingular, "PCG met a direction of non-positive stiffness"));
            }
            let alpha = rz / pap;
            for i in 0..n {
                x[i] += alpha * p[i];
                r[i] -= alpha * ap[i];
                z[i] = r[i] / diag[i];
            }
            let rz_new: f64 = r.iter().zip(&z).map(|(a, b)| a * b).sum();
            let beta = rz_new / rz;
            rz = rz_new;
            for i in 0..n {
                p[i] = z[i] + beta * p[i];
            }
        }
        Err(Error::new(ErrorCode::FeaNotConverged, format!("PCG did not converge in {max_iter} iterations"))
            .with_hint("raise --memory-budget so the direct solver is used, or coarsen the grid"))
    }
}

/// Material constants as the assembly uses them: Lamé λ, μ, the fictitious stiffness factor α, and the
/// Nitsche stability factor.
#[derive(Clone, Copy, Debug)]
pub struct Elastic {
    /// Lamé's λ.
    pub lambda: f64,
    /// Lamé's μ (shear modulus).
    pub mu: f64,
    /// Fictitious stiffness factor of the outside part of cut cells.
    pub alpha: f64,
    /// Nitsche stability factor.
    pub stability: f64,
}

/// t[3a + q] = σ(N_a e_q)·n, the traction of each local function and component at a point with gradients `g`
/// and unit normal `n`: λ n (∂_q N_a) + μ (e_q (∇N_a·n) + n_q ∇N_a).
pub fn traction_operator(g: &[[f64; 3]; 27], n: V3, e: Elastic) -> [V3; 81] {
    let mut t = [[0.0; 3]; 81];
    for a in 0..27 {
        let gn = dot(g[a], n);
        for q in 0..3 {
            let v = &mut t[3 * a + q];
            for i in 0..3 {
                v[i] = e.lambda * n[i] * g[a][q] + e.mu * n[q] * g[a][i];
            }
            v[q] += e.mu * gn;
        }
    }
    t
}

/// λ_max of A v = λ K v for symmetric positive semi-definite 81 × 81 matrices that vanish on the same rigid
/// motions: K is regularised by 1e-10 of its largest diagonal entry, factored K = L Lᵀ, and the largest
/// eigenvalue of L⁻¹ A L⁻ᵀ returned. Cost: ~1 Mflop.
fn largest_generalised_eigenvalue(a: &[f64], k: &[f64]) -> f64 {
    const N: usize = 81;
    let shift = 1e-10 * (0..N).map(|i| k[i * N + i]).fold(0.0, f64::max);
    // Cholesky, lower triangle in `l`.
    let mut l = vec![0.0; N * N];
    for j in 0..N {
        let mut d = k[j * N + j] + shift;
        for m in 0..j {
            d -= l[j * N + m] * l[j * N + m];
        }
        let d = d.max(shift).sqrt();
        l[j * N + j] = d;
        for i in j + 1..N {
            let mut v = k[i * N + j];
            for m in 0..j {
                v -= l[i * N + m] * l[j * N + m];
            }
            l[i * N + j] = v / d;
        }
    }
    // X = L⁻¹ A (column by column), then C = L⁻¹ Xᵀ = L⁻¹ A L⁻ᵀ.
    let forward = |b: &mut [f64]| {
        for i in 0..N {
            let mut v = b[i];
            for m in 0..i {
                v -= l[i * N + m] * b[m];
            }
            b[i] = v / l[i * N + i];
        }
    };
    let mut x = vec![0.0; N * N]; // column-major: x[c * N + r]
    for c in 0..N {
        let col = &mut x[c * N..(c + 1) * N];
        for r in 0..N {
            col[r] = a[r * N + c];
        }
        forward(col);
    }
    // Row r of X is column r of Xᵀ.
    let mut c_mat = faer::Mat::<f64>::zeros(N, N);
    let mut col = [0.0; N];
    for r in 0..N {
        for c in 0..N {
            col[c] = x[c * N + r];
        }
        forward(&mut col);
        for i in 0..N {
            c_mat[(i, r)] = col[i];
        }
    }
    // Symmetrise against rounding.
    for i in 0..N {
        for j in 0..i {
            let v = 0.5 * (c_mat[(i, j)] + c_mat[(j, i)]);
            c_mat[(i, j)] = v;
            c_mat[(j, i)] = v;
        }
    }
    match c_mat.as_ref().self_adjoint_eigenvalues(faer::Side::Lower) {
        Ok(e) => e.last().copied().unwrap_or(0.0),
        // The trace bounds the largest eigenvalue of a positive semi-definite matrix from above.
        Err(_) => (0..N).map(|i| c_mat[(i, i)].max(0.0)).sum(),
    }
}

/// How the system was solved.
#[derive(Clone, Debug, serde::Serialize)]
pub struct SolverReport {
    /// `cholesky` (faer sparse LLᵀ) or `pcg` (Jacobi-preconditioned CG).
    pub kind: &'static str,
    /// Stored entries of the lower triangle.
    pub matrix_nonzeros: usize,
    /// Entries of the Cholesky factor (0 for PCG).
    pub factor_nonzeros: usize,
    /// PCG iterations (1 for Cholesky).
    pub iterations: usize,
    /// ‖K u − f‖ / ‖f‖.
    pub relative_residual: f64,
}

//! Least-squares fitting of the control points so that the limit surface approximates a target surface.
//!
//! Samples sit at fixed parameters of the limit surface (an m×m grid per refined face), each a fixed linear
//! combination of control points. Every round moves each sample's target to the closest point of the scan
//! (on a triangle facing the same way) and solves
//! `min Σ a_s |x_s(P) − y_s|² + λ Σ_i |P_i − mean(neighbours of i)|²`
//! (a_s = the sample's area) by conjugate gradients with a Jacobi preconditioner, warm-started from the
//! previous round. The normal matrix is never assembled: it is applied as Sᵀ·Aᵀ·W·A·S, with S the
//! refinement stencils and A the per-sample weights on the refined net.

use crate::error::{Error, ErrorCode, Result};
use crate::geometry::bvh::TriangleBvh;
use crate::geometry::mesh::TriMesh;
use crate::geometry::subdivision::limit::{FaceKind, LimitSurface, bspline_basis, limit_stencil, point_weights};
use crate::geometry::subdivision::net::{QuadNet, Stencils, combine};
use crate::geometry::vec3::{self, V3};
use crate::stages::Progress;
use rayon::prelude::*;

/// Where the fitted surface should lie.
pub trait FitTarget: Sync {
    /// The closest target point to `p`, preferring parts of the target whose outward normal agrees with
    /// `normal`, with the target's unit normal there; `None` when the target is empty.
    fn closest(&self, p: V3, normal: V3) -> Option<(V3, V3)>;
}

/// A triangle mesh as target: closest points on triangles facing the same way (so thin parts do not
/// swap sides), with the triangle's normal.
pub struct MeshTarget {
    bvh: TriangleBvh,
    normals: Vec<V3>,
}

impl MeshTarget {
    /// Index `mesh`. Cost: O(F log F).
    pub fn new(mesh: &TriMesh) -> Self {
        let p: Vec<V3> = mesh.positions.iter().map(|&q| vec3::wide(q)).collect();
        let normals = mesh.triangles.iter().map(|&t| vec3::tri_unit_normal(&p, t).unwrap_or([0.0; 3])).collect();
        MeshTarget { bvh: TriangleBvh::new(mesh), normals }
    }
}

impl FitTarget for MeshTarget {
    fn closest(&self, p: V3, normal: V3) -> Option<(V3, V3)> {
        let c = self.bvh.closest_facing(p, normal).or_else(|| self.bvh.closest(p))?;
        Some((c.point, self.normals[c.index as usize]))
    }
}

/// Cosine of the angle between a sample's surface normal and its target's normal beyond which the sample
/// is fitted point-to-point instead of point-to-plane.
const CREASE_COS: f64 = 0.7;

/// A sphere as target (analytic oracle for tests).
#[derive(Copy, Clone, Debug)]
pub struct SphereTarget {
    /// Centre.
    pub center: V3,
    /// Radius.
    pub radius: f64,
}

impl FitTarget for SphereTarget {
    fn closest(&self, p: V3, _normal: V3) -> Option<(V3, V3)> {
        let d = vec3::unit_or(vec3::sub(p, self.center), [0.0, 0.0, 1.0]);
        Some((vec3::add(self.center, vec3::scale(d, self.radius)), d))
    }
}

/// The default weight of the umbrella smoothness term ([`FitOptions::smoothing`]). At 10⁻³ the fitted limit
/// surface pleated at parts thinner than about 1.5 control-net spacings: on the scorpion and the skull at 10k
/// (2026-12-06) the first solid had one folded face each, so `convert` built a second chain from another
/// seed (40 s instead of 22). At 10⁻² both pass every gate at the first seed, and on the nine shared meshes
/// the solids' RMS moves by at most 0.007 % of the diagonal: spot 0.0285 → 0.0281 %, fandisk 0.0045 →
/// 0.0059, armadillo 0.0212 → 0.0282, igea 0.0107 → 0.0147, scorpion 0.0236 (second seed) → 0.0213, skull
/// 0.0091 (second seed) → 0.0146, bunny 0.0266 → 0.0214, dragon 0.110 → 0.113. At 10⁻¹ the scorpion comes to
/// 0.0285 %.
pub const SMOOTHING: f64 = 1e-2;

/// Settings of the fit.
#[derive(Copy, Clone, Debug)]
pub struct FitOptions {
    /// Samples per refined face and direction (m; m² samples per refined face, 4m² per control quad).
    pub samples_per_side: usize,
    /// Closest-point rounds.
    pub rounds: usize,
    /// Weight of the umbrella smoothness term relative to the mean sample area per control point.
    pub smoothing: f64,
    /// Weight of the tangential part of each sample's distance relative to the normal part (point-to-plane
    /// fitting with a small point-to-point term: lets samples slide along the scan, converges fast).
    pub tangential_weight: f64,
    /// Relative residual at which conjugate gradients stop.
    pub cg_tolerance: f64,
    /// Most conjugate-gradient iterations per round.
    pub cg_max_iterations: usize,
}

impl Default for FitOptions {
    fn default() -> Self {
        FitOptions {
            samples_per_side: 2,
            rounds: 5,
            smoothing: SMOOTHING,
            tangential_weight: 0.01,
            cg_tolerance: 1e-8,
            cg_max_iterations: 400,
        }
    }
}

/// What one round achieved.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct RoundReport {
    /// Area-weighted RMS of the distance from the samples to their targets before the solve.
    pub rms_before: f64,
    /// The same after the solve (targets held fixed).
    pub rms_after: f64,
    /// Conjugate-gradient iterations of the solve.
    pub cg_iterations: usize,
}

/// Summary of a fit.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct FitReport {
    /// Control points fitted.
    pub control_points: usize,
    /// Limit-surface samples per round.
    pub samples: usize,
    /// Faces at an extraordinary vertex.
    pub extraordinary_faces: usize,
    /// Each closest-point round.
    pub rounds: Vec<RoundReport>,
    /// Area-weighted RMS sample-to-target distance after the last round (targets re-projected).
    pub final_rms: f64,
    /// Samples whose surface normal points against the target's normal at their closest point (folds).
    pub flipped_samples: usize,
    /// Largest sample-to-target distance after the last round, and where it is.
    pub final_max: f64,
    /// Where that largest distance is.
    pub final_max_at: V3,
}

/// Per-sample weights on the refined net: regular faces share per-slot basis tables, extraordinary samples
/// are explicit.
struct Samples {
    m: usize,
    /// Regular faces (level-1 ids) in sample order.
    regular: Vec<u32>,
    /// `[pos, du, dv]` basis products per slot: `m² × 16`.
    slot: Vec<[[f64; 16]; 3]>,
    /// Explicit rows for extraordinary samples.
    ev_pos: Stencils,
    ev_du: Stencils,
    ev_dv: Stencils,
    /// Area weight of every sample (regular first, then extraordinary).
    area: Vec<f64>,
}

impl Samples {
    fn count(&self) -> usize {
        self.regular.len() * self.m * self.m + self.ev_pos.rows()
    }

    fn build(surface: &LimitSurface, m: usize) -> Result<Self> {
        let mut slot = Vec::with_capacity(m * m);
        for j in 0..m {
            for i in 0..m {
                let (u, v) = ((i as f64 + 0.5) / m as f64, (j as f64 + 0.5) / m as f64);
                let (nu, du) = bspline_basis(u);
                let (nv, dv) = bspline_basis(v);
                let mut t = [[0.0; 16]; 3];
                for b in 0..4 {
                    for a in 0..4 {
                        t[0][4 * b + a] = nu[a] * nv[b];
                        t[1][4 * b + a] = du[a] * nv[b];
                        t[2][4 * b + a] = nu[a] * dv[b];
                    }
                }
                slot.push(t);
            }
        }
        let regular: Vec<u32> = (0..surface.kinds.len() as u32)
            .filter(|&f| matches!(surface.kinds[f as usize], FaceKind::Regular(_)))
            .collect();
        let ev_faces: Vec<usize> =
            (0..surface.kinds.len()).filter(|&f| matches!(surface.kinds[f], FaceKind::Extraordinary(_))).collect();
        let tables = surface.ev_patches()?;
        let rows: Vec<Result<Vec<_>>> = ev_faces
            .par_iter()
            .map(|&f| {
                let ev =
                    tables[f].as_ref().ok_or_else(|| Error::internal(format!("face {f} has no local evaluation")))?;
                let mut out = Vec::with_capacity(m * m);
                for j in 0..m {
                    for i in 0..m {
                        let (u, v) = ((i as f64 + 0.5) / m as f64, (j as f64 + 0.5) / m as f64);
                        out.push(point_weights(surface, f, u, v, Some(ev)));
                    }
                }
                Ok(out)
            })
            .collect();
        let (mut ev_pos, mut ev_du, mut ev_dv) = (Stencils::new(), Stencils::new(), Stencils::new());
        for r in rows {
            for w in r? {
                ev_pos.push_merged(&w.pos);
                ev_du.push_merged(&w.du);
                ev_dv.push_merged(&w.dv);
            }
        }
        Ok(Samples { m, regular, slot, ev_pos, ev_du, ev_dv, area: Vec::new() })
    }

    /// Positions (k = 0) or derivatives (k = 1, 2) of all samples from refined-net values.
    fn eval(&self, surface: &LimitSurface, p1: &[V3], k: usize) -> Vec<V3> {
        let mm = self.m * self.m;
        let mut out: Vec<V3> = self
            .regular
            .par_iter()
            .flat_map_iter(|&f| {
                let FaceKind::Regular(grid) = surface.kinds[f as usize] else { unreachable!() };
                (0..mm).map(move |s| {
                    let mut acc = [0.0; 3];
                    for (g, w) in grid.iter().zip(&self.slot[s][k]) {
                        let p = p1[*g as usize];
                        for c in 0..3 {
                            acc[c] += w * p[c];
                        }
                    }
                    acc
                })
            })
            .collect();
        let st = [&self.ev_pos, &self.ev_du, &self.ev_dv][k];
        out.extend(st.apply(p1));
        out
    }

    /// Aᵀ·r: sample values scattered back onto the refined net (per-face sums in parallel, then added).
    fn scatter(&self, surface: &LimitSurface, r: &[V3], n1: usize) -> Vec<V3> {
        let mm = self.m * self.m;
        let per_face: Vec<[V3; 16]> = self
            .regular
            .par_iter()
            .enumerate()
            .map(|(fi, _)| {
                let mut acc = [[0.0; 3]; 16];
                for s in 0..mm {
                    let rs = r[fi * mm + s];
                    for (a, w) in acc.iter_mut().zip(&self.slot[s][0]) {
                        for c in 0..3 {
                            a[c] += w * rs[c];
                        }
                    }
                }
                acc
            })
            .collect();
        let mut out = vec![[0.0; 3]; n1];
        for (&f, acc) in self.regular.iter().zip(&per_face) {
            let FaceKind::Regular(grid) = surface.kinds[f as usize] else { unreachable!() };
            for (g, a) in grid.iter().zip(acc) {
                let o = &mut out[*g as usize];
                for c in 0..3 {
                    o[c] += a[c];
                }
            }
        }
        let base = self.regular.len() * mm;
        for s in 0..self.ev_pos.rows() {
            let rs = r[base + s];
            for &(g, w) in self.ev_pos.row(s) {
                let o = &mut out[g as usize];
                for c in 0..3 {
                    o[c] += w * rs[c];
                }
            }
        }
        out
    }
}

/// Sᵀ·x for the refinement stencils.
fn refine_transpose(st: &Stencils, x: &[V3], n0: usize) -> Vec<V3> {
    let mut out = vec![[0.0; 3]; n0];
    for r in 0..st.rows() {
        for &(c, w) in st.row(r) {
            let o = &mut out[c as usize];
            for k in 0..3 {
                o[k] += w * x[r][k];
            }
        }
    }
    out
}

/// Umbrella operator on the control net: `(L P)_i = P_i − mean of its edge neighbours`.
struct Umbrella {
    nbrs: Vec<Vec<u32>>,
}

impl Umbrella {
    fn new(net: &QuadNet) -> Self {
        let nbrs = (0..net.vertex_count as u32).map(|v| net.outgoing(v).iter().map(|&h| net.to(h)).collect()).collect();
        Umbrella { nbrs }
    }

    fn apply(&self, p: &[V3]) -> Vec<V3> {
        self.nbrs
            .iter()
            .enumerate()
            .map(|(i, nb)| {
                let k = 1.0 / nb.len() as f64;
                let mut acc = p[i];
                for &j in nb {
                    for c in 0..3 {
                        acc[c] -= k * p[j as usize][c];
                    }
                }
                acc
            })
            .collect()
    }

    fn apply_transpose(&self, x: &[V3]) -> Vec<V3> {
        let mut out = x.to_vec();
        for (i, nb) in self.nbrs.iter().enumerate() {
            let k = 1.0 / nb.len() as f64;
            for &j in nb {
                for c in 0..3 {
                    out[j as usize][c] -= k * x[i][c];
                }
            }
        }
        out
    }
}

/// Fit the control points of the closed quad net `control` (initial positions `initial`, e.g. the quad mesh
/// vertices, which lie on the scan) so its Catmull–Clark limit surface approximates `target`.
///
/// Returns the fitted control points, the limit surface structure (refined net) and a report.
///
/// # Errors
/// `surface.bad-net` for a net that is not closed and 2-manifold; `surface.fit-diverged` when the solve
/// produces non-finite values or the residual grows by more than 10× over a round.
///
/// Cost: O(F·m²·(16 + CG iterations)) time; memory ≈ 3 · 24 bytes per sample plus the refined net.
pub fn fit_control_points(
    control: &QuadNet,
    initial: &[V3],
    target: &dyn FitTarget,
    opts: &FitOptions,
    progress: &dyn Progress,
) -> Result<(Vec<V3>, LimitSurface, FitReport)> {
    if initial.len() != control.vertex_count {
        return Err(Error::internal("control points and net disagree in count"));
    }
    if opts.samples_per_side == 0 || opts.samples_per_side > 16 {
        return Err(Error::new(ErrorCode::InputBadArgument, "samples per side must be in 1 ..= 16"));
    }
    progress.report(0.0, "surface: refine");
    let surface = LimitSurface::new(control)?;
    let n0 = control.vertex_count;
    let n1 = surface.net.vertex_count;
    let t0 = std::time::Instant::now();
    let mut samples = Samples::build(&surface, opts.samples_per_side)?;
    tracing::debug!(seconds = t0.elapsed().as_secs_f64(), samples = samples.count(), "surface fit: samples built");
    let mut report = FitReport {
        control_points: n0,
        samples: samples.count(),
        extraordinary_faces: samples.ev_pos.rows() / (opts.samples_per_side * opts.samples_per_side),
        ..Default::default()
    };

    // Start from limit interpolation: the limit point of every control vertex on its initial position.
    let lim: Vec<Vec<(u32, f64)>> = (0..n0 as u32).map(|v| limit_stencil(control, v)).collect();
    let mut p: Vec<V3> = initial.to_vec();
    for _ in 0..30 {
        p = (0..n0).map(|i| vec3::add(p[i], vec3::sub(initial[i], combine(&lim[i], &p)))).collect();
    }

    // Area weights from the initial surface.
    let p1 = surface.refine.apply(&p);
    let du = samples.eval(&surface, &p1, 1);
    let dv = samples.eval(&surface, &p1, 2);
    let cell = 1.0 / (opts.samples_per_side * opts.samples_per_side) as f64;
    samples.area = du.iter().zip(&dv).map(|(a, b)| vec3::norm(vec3::cross(*a, *b)) * cell).collect();
    let total_area: f64 = samples.area.iter().sum();
    if !(total_area.is_finite() && total_area > 0.0) {
        return Err(Error::new(ErrorCode::SurfaceFitDiverged, "the initial limit surface has no area"));
    }
    let umbrella = Umbrella::new(control);
    let lambda = opts.smoothing * total_area / n0 as f64;

    // Jacobi preconditioner: the diagonal of Sᵀ Aᵀ W A S, scaled each round by the mean of the per-sample
    // metric's diagonal (1/3 + μ), plus that of λ LᵀL (≈ 1 + 1/n).
    let data_diag = jacobi_diagonal(&surface, &samples, n0);

    let rms_of = |x: &[V3], y: &[V3]| -> f64 {
        let s: f64 = x.iter().zip(y).zip(&samples.area).map(|((a, b), w)| w * vec3::norm2(vec3::sub(*a, *b))).sum();
        (s / total_area).sqrt()
    };
    // Sample positions, their targets, the targets' normals and the surface's own (unnormalised) normals.
    let targets = |p: &[V3]| -> (Vec<V3>, Vec<V3>, Vec<V3>, Vec<V3>) {
        let p1 = surface.refine.apply(p);
        let x = samples.eval(&surface, &p1, 0);
        let nu = samples.eval(&surface, &p1, 1);
        let nv = samples.eval(&surface, &p1, 2);
        let facing: Vec<V3> = nu.iter().zip(&nv).map(|(a, b)| vec3::cross(*a, *b)).collect();
        let (y, n): (Vec<V3>, Vec<V3>) = (0..x.len())
            .into_par_iter()
            .map(|s| target.closest(x[s], facing[s]).unwrap_or((x[s], vec3::unit_or(facing[s], [0.0; 3]))))
            .unzip();
        (x, y, n, facing)
    };

    // Rounds: closest points, then a solve. A round that leaves the surface farther from the target than
    // before is undone and the tangential weight raised 10× (damping); a good round halves it again.
    let mut mu = opts.tangential_weight.max(0.0);
    let (mut x, mut y, mut normal, mut facing) = targets(&p);
    let mut current = rms_of(&x, &y);
    let mut bad_rounds = 0;
    for round in 0..opts.rounds {
        progress.report(0.1 + 0.85 * round as f64 / opts.rounds as f64, "surface: fit");
        // Per-sample metric a_s (n nᵀ + μ I): point-to-plane plus a little point-to-point. Where the target's
        // normal is far from the surface's (a crease finer than the net), point-to-point: a plane from the
        // other side of the crease would pull the surface past it into a pleat.
        let crease: Vec<bool> =
            (0..x.len()).map(|s| vec3::dot(vec3::unit_or(facing[s], [0.0; 3]), normal[s]) < CREASE_COS).collect();
        let metric = |s: usize, v: V3| -> V3 {
            let n = normal[s];
            let a = samples.area[s];
            if crease[s] {
                return vec3::scale(v, a * (1.0 + mu));
            }
            vec3::scale(vec3::add(vec3::scale(n, vec3::dot(n, v)), vec3::scale(v, mu)), a)
        };
        let apply_h = |xv: &[V3]| -> Vec<V3> {
            let x1 = surface.refine.apply(xv);
            let ax: Vec<V3> =
                samples.eval(&surface, &x1, 0).into_iter().enumerate().map(|(s, v)| metric(s, v)).collect();
            let mut out = refine_transpose(&surface.refine, &samples.scatter(&surface, &ax, n1), n0);
            if lambda > 0.0 {
                let lx = umbrella.apply_transpose(&umbrella.apply(xv));
                for (o, l) in out.iter_mut().zip(lx) {
                    for c in 0..3 {
                        o[c] += lambda * l[c];
                    }
                }
            }
            out
        };
        let diag_mu: Vec<f64> = data_diag.iter().map(|d| d * (1.0 / 3.0 + mu) + 1.25 * lambda).collect();
        // Right-hand side Sᵀ Aᵀ M y; the smoothness term pulls toward zero Laplacian.
        let my: Vec<V3> = (0..y.len()).map(|s| metric(s, y[s])).collect();
        let b = refine_transpose(&surface.refine, &samples.scatter(&surface, &my, n1), n0);
        let (sol, iters) = conjugate_gradients(&apply_h, &b, &p, &diag_mu, opts.cg_tolerance, opts.cg_max_iterations);
        if sol.iter().any(|q| !q.iter().all(|c| c.is_finite())) {
            return Err(Error::new(
                ErrorCode::SurfaceFitDiverged,
                format!("round {round}: the solve produced non-finite control points"),
            ));
        }
        let (nx, ny, nn, nf) = targets(&sol);
        let after = rms_of(&nx, &ny);
        report.rounds.push(RoundReport { rms_before: current, rms_after: after, cg_iterations: iters });
        tracing::debug!(round, seconds = t0.elapsed().as_secs_f64(), iters, after, mu, "surface fit: round");
        if after <= current {
            p = sol;
            (x, y, normal, facing) = (nx, ny, nn, nf);
            current = after;
            mu = (mu * 0.5).max(1e-3);
        } else {
            bad_rounds += 1;
            mu *= 10.0;
            if bad_rounds > opts.rounds {
                break;
            }
        }
    }
    report.final_rms = current;
    report.flipped_samples = (0..x.len()).filter(|&s| vec3::dot(facing[s], normal[s]) < 0.0).count();
    if let Some((s, d)) =
        (0..x.len()).map(|s| (s, vec3::norm(vec3::sub(x[s], y[s])))).max_by(|a, b| a.1.total_cmp(&b.1))
    {
        report.final_max = d;
        report.final_max_at = x[s];
    }
    if !current.is_finite() {
        return Err(Error::new(ErrorCode::SurfaceFitDiverged, "the fitted surface is not finite"));
    }
    progress.report(1.0, "surface: fit");
    Ok((p, surface, report))
}

/// Diagonal of Sᵀ Aᵀ W A S (the data term's normal matrix with scalar sample weights); 1 where zero.
fn jacobi_diagonal(surface: &LimitSurface, samples: &Samples, n0: usize) -> Vec<f64> {
    let mut diag = vec![0.0; n0];
    let mut acc = vec![0.0f64; n0];
    let mut touched: Vec<u32> = Vec::with_capacity(256);
    let mm = samples.m * samples.m;
    let mut add = |row: &mut dyn Iterator<Item = (u32, f64)>, area: f64, diag: &mut Vec<f64>| {
        for (q, w) in row {
            for &(pi, s) in surface.refine.row(q as usize) {
                if acc[pi as usize] == 0.0 {
                    touched.push(pi);
                }
                acc[pi as usize] += w * s;
            }
        }
        for &t in &touched {
            diag[t as usize] += area * acc[t as usize] * acc[t as usize];
            acc[t as usize] = 0.0;
        }
        touched.clear();
    };
    for (fi, &f) in samples.regular.iter().enumerate() {
        let FaceKind::Regular(grid) = surface.kinds[f as usize] else { unreachable!() };
        for s in 0..mm {
            let mut it = grid.iter().zip(&samples.slot[s][0]).map(|(g, w)| (*g, *w));
            add(&mut it, samples.area[fi * mm + s], &mut diag);
        }
    }
    let base = samples.regular.len() * mm;
    for s in 0..samples.ev_pos.rows() {
        let mut it = samples.ev_pos.row(s).iter().copied();
        add(&mut it, samples.area[base + s], &mut diag);
    }
    for d in &mut diag {
        if *d <= 0.0 {
            *d = 1.0;
        }
    }
    diag
}

/// Residual reduction per round at which conjugate gradients stop (each round re-solves a nearby problem
/// from the previous solution; 10⁻³ leaves an error far below the closest-point error of the round).
const CG_REDUCTION: f64 = 1e-3;

/// Preconditioned conjugate gradients on the 3n unknowns (coordinates coupled by the point-to-plane
/// metric). Returns the solution and the iterations used.
fn conjugate_gradients(
    apply: &dyn Fn(&[V3]) -> Vec<V3>,
    b: &[V3],
    x0: &[V3],
    diag: &[f64],
    tol: f64,
    max_iter: usize,
) -> (Vec<V3>, usize) {
    let n = b.len();
    let dot = |a: &[V3], b: &[V3]| -> f64 { a.iter().zip(b).map(|(u, v)| vec3::dot(*u, *v)).sum() };
    let mut x = x0.to_vec();
    let ax = apply(&x);
    let mut r: Vec<V3> = (0..n).map(|i| vec3::sub(b[i], ax[i])).collect();
    let bnorm = dot(b, b).sqrt().max(1e-300);
    // Warm-started: stop when the residual fell by `CG_REDUCTION` from its start, or below tol·|b|.
    let r0 = dot(&r, &r).sqrt();
    let stop = (tol * bnorm).max(CG_REDUCTION * r0);
    let mut z: Vec<V3> = (0..n).map(|i| vec3::scale(r[i], 1.0 / diag[i])).collect();
    let mut d = z.clone();
    let mut rz = dot(&r, &z);
    let mut iters = 0;
    for it in 0..max_iter {
        if dot(&r, &r).sqrt() <= stop {
            break;
        }
        iters = it + 1;
        let hd = apply(&d);
        let dhd = dot(&d, &hd);
        if !(dhd > 0.0) {
            break;
        }
        let alpha = rz / dhd;
        for i in 0..n {
            x[i] = vec3::add(x[i], vec3::scale(d[i], alpha));
            r[i] = vec3::sub(r[i], vec3::scale(hd[i], alpha));
            z[i] = vec3::scale(r[i], 1.0 / diag[i]);
        }
        let rz_new = dot(&r, &z);
        let beta = rz_new / rz;
        for i in 0..n {
            d[i] = vec3::add(z[i], vec3::scale(d[i], beta));
        }
        rz = rz_new;
    }
    (x, iters)
}

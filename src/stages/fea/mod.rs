//! **fea** — immersed ("meshless") linear elastostatics on a closed surface, after the finite cell method:
//! no volume mesh. A uniform background grid carries tri-quadratic C¹ B-splines ([`basis`]); cells that touch
//! the solid are active, cut cells are integrated exactly from their inside moments ([`domain`]), their
//! outside part keeps a small stiffness α; supports and loads are picked on the surface by location (sphere
//! or half-space), supports imposed weakly on surface quadrature points by Nitsche's method (or a penalty); the
//! system is solved by sparse Cholesky ([`system`]). Results: displacement, von Mises and principal stresses on the surface,
//! extremes with their location, probes, and the reaction balance.
//!
//! Units are the solid's (mm, N, MPa, t/mm³ by default). Deterministic for the same input and spec.

pub mod basis;
pub mod domain;
pub mod spec;
pub mod system;
pub mod vtu;

use std::time::Instant;

use rayon::prelude::*;

use crate::error::{Error, ErrorCode, Result};
use crate::geometry::linalg;
use crate::geometry::mesh::{PolyMesh, TriMesh};
use crate::geometry::topology::TopologyReport;
use crate::geometry::vec3::{V3, add, cross, norm, scale, sub, wide};
use crate::stages::Progress;
use domain::{Domain, Grid};
pub use spec::FeaSpec;
use system::{SolverReport, SurfacePoint};

/// Settings that are not part of the spec (they belong to the machine, not the problem).
#[derive(Clone, Debug)]
pub struct FeaOptions {
    /// Bytes the solver may use; the Cholesky factor gets at most half, else PCG is used.
    pub memory_budget: u64,
}

impl Default for FeaOptions {
    fn default() -> Self {
        FeaOptions { memory_budget: 8 << 30 }
    }
}

/// A value with the place it occurs.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Extreme {
    /// The value.
    pub value: f64,
    /// Where it occurs (a surface vertex).
    pub at: V3,
}

/// What one load or support region selected.
#[derive(Clone, Debug, serde::Serialize)]
pub struct SelectionReport {
    /// The region's name from the spec.
    pub name: String,
    /// Selected surface area.
    pub area: f64,
    /// Surface quadrature points selected.
    pub points: usize,
    /// Total force this load applies (zero for supports).
    pub force: V3,
}

/// Results at a probe.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ProbeReport {
    /// The probe's name from the spec.
    pub name: String,
    /// Where it is.
    pub point: V3,
    /// Displacement there.
    pub displacement: V3,
    /// Von Mises stress there.
    pub von_mises: f64,
    /// Principal stresses, largest first.
    pub principal_stress: [f64; 3],
    /// σxx, σyy, σzz, σxy, σyz, σzx.
    pub stress: [f64; 6],
}

/// The grid as solved.
#[derive(Clone, Debug, serde::Serialize)]
pub struct GridReport {
    /// Cell side.
    pub cell_size: f64,
    /// Cells per axis.
    pub cells: [usize; 3],
    /// Cells with part of the solid inside.
    pub active_cells: usize,
    /// Of those, cells the surface cuts.
    pub cut_cells: usize,
    /// Active B-spline functions.
    pub functions: usize,
    /// Unknowns (3 per function).
    pub unknowns: usize,
    /// Lines through cut cells whose surface crossings were odd (0 for a closed surface).
    pub odd_lines: usize,
}

/// The whole FEA report (the JSON `fea --json` prints).
#[derive(Clone, Debug, serde::Serialize)]
pub struct FeaReport {
    /// The grid as solved.
    pub grid: GridReport,
    /// Volume of the immersed domain (integrated inside moments).
    pub volume: f64,
    /// Volume enclosed by the surface (divergence theorem).
    pub surface_volume: f64,
    /// How the linear solve went.
    pub solver: SolverReport,
    /// What each support selected.
    pub supports: Vec<SelectionReport>,
    /// What each load selected.
    pub loads: Vec<SelectionReport>,
    /// Sum of applied forces: loads plus self-weight.
    pub total_load: V3,
    /// Sum of support reactions (force the supports exert on the solid).
    pub reaction: V3,
    /// |reaction + total_load| / |total_load|.
    pub imbalance: f64,
    /// Largest displacement magnitude over the surface vertices.
    pub max_displacement: Extreme,
    /// Largest von Mises stress over the surface vertices.
    pub max_von_mises: Extreme,
    /// Largest von Mises stress farther than `exclusion_distance` from every support point: the maximum that
    /// converges where clamps make the stress singular (CalculiX reference runs report it the same way).
    pub max_von_mises_away_from_supports: Extreme,
    /// The distance used for it: two cells.
    pub exclusion_distance: f64,
    /// Largest principal stress over the surface vertices.
    pub max_principal_stress: Extreme,
    /// Smallest principal stress over the surface vertices.
    pub min_principal_stress: Extreme,
    /// Results at the spec's probes.
    pub probes: Vec<ProbeReport>,
    /// Seconds per phase: domain, assemble, solve, results.
    pub seconds: std::collections::BTreeMap<&'static str, f64>,
}

/// Fields on the surface's vertices, for the VTU file.
pub struct SurfaceFields {
    /// Displacement per vertex.
    pub displacement: Vec<V3>,
    /// Von Mises stress per vertex.
    pub von_mises: Vec<f64>,
    /// Principal stresses per vertex, largest first.
    pub principal_stress: Vec<[f64; 3]>,
}

/// A solved problem: report, the surface as solved (oriented outward) and the fields on its vertices.
pub struct FeaSolution {
    /// The report.
    pub report: FeaReport,
    /// The surface as solved (oriented outward).
    pub surface: TriMesh,
    /// Fields on its vertices.
    pub fields: SurfaceFields,
}

/// 7-point degree-5 rule on a triangle: barycentric (a, b, c) and weight (sum 1).
const TRI_RULE: [([f64; 3], f64); 7] = {
    const A1: f64 = 0.059715871789770;
    const B1: f64 = 0.470142064105115;
    const W1: f64 = 0.132394152788506;
    const A2: f64 = 0.797426985353087;
    const B2: f64 = 0.101286507323456;
    const W2: f64 = 0.125939180544827;
    [
        ([1.0 / 3.0, 1.0 / 3.0, 1.0 / 3.0], 0.225),
        ([A1, B1, B1], W1),
        ([B1, A1, B1], W1),
        ([B1, B1, A1], W1),
        ([A2, B2, B2], W2),
        ([B2, A2, B2], W2),
        ([B2, B2, A2], W2),
    ]
};

/// Quadrature points on the triangles `tris` of the surface: each triangle split into m² pieces of edge ≤
/// `max_edge`, 7 points each.
fn surface_points(mesh: &TriMesh, tris: &[usize], max_edge: f64) -> Vec<SurfacePoint> {
    tris.par_iter()
        .flat_map_iter(|&t| {
            let [a, b, c] = mesh.corners(t);
            let nrm = cross(sub(b, a), sub(c, a));
            let area2 = norm(nrm);
            let mut out = Vec::new();
            if area2 <= 0.0 {
                return out.into_iter();
            }
            let n = scale(nrm, 1.0 / area2);
            let longest = norm(sub(b, a)).max(norm(sub(c, b))).max(norm(sub(a, c)));
            let m = ((longest / max_edge).ceil() as usize).clamp(1, 64);
            let inv = 1.0 / m as f64;
            let w_sub = 0.5 * area2 * inv * inv;
            let at = |i: f64, j: f64| add(a, add(scale(sub(b, a), i * inv), scale(sub(c, a), j * inv)));
            for i in 0..m {
                for j in 0..m - i {
                    let (fi, fj) = (i as f64, j as f64);
                    let mut tris = vec![[at(fi, fj), at(fi + 1.0, fj), at(fi, fj + 1.0)]];
                    if i + j + 1 < m {
                        tris.push([at(fi + 1.0, fj), at(fi + 1.0, fj + 1.0), at(fi, fj + 1.0)]);
                    }
                    for [p, q, r] in tris {
                        for (bc, w) in TRI_RULE {
                            let x = add(scale(p, bc[0]), add(scale(q, bc[1]), scale(r, bc[2])));
                            out.push(SurfacePoint { p: x, w: w * w_sub, n });
                        }
                    }
                }
            }
            out.into_iter()
        })
        .collect()
}

/// Stress (σxx, σyy, σzz, σxy, σyz, σzx) from the displacement gradient.
fn stress(grad: &[[f64; 3]; 3], lambda: f64, mu: f64) -> [f64; 6] {
    let e = |i: usize, j: usize| 0.5 * (grad[i][j] + grad[j][i]);
    let tr = grad[0][0] + grad[1][1] + grad[2][2];
    [
        lambda * tr + 2.0 * mu * e(0, 0),
        lambda * tr + 2.0 * mu * e(1, 1),
        lambda * tr + 2.0 * mu * e(2, 2),
        2.0 * mu * e(0, 1),
        2.0 * mu * e(1, 2),
        2.0 * mu * e(2, 0),
    ]
}

/// σ·n for a stress in the order of [`stress`].
fn stress_traction(s: &[f64; 6], n: V3) -> V3 {
    [
        s[0] * n[0] + s[3] * n[1] + s[5] * n[2],
        s[3] * n[0] + s[1] * n[1] + s[4] * n[2],
        s[5] * n[0] + s[4] * n[1] + s[2] * n[2],
    ]
}

/// Von Mises equivalent stress.
pub fn von_mises(s: &[f64; 6]) -> f64 {
    (0.5 * ((s[0] - s[1]).powi(2) + (s[1] - s[2]).powi(2) + (s[2] - s[0]).powi(2))
        + 3.0 * (s[3] * s[3] + s[4] * s[4] + s[5] * s[5]))
        .sqrt()
}

/// Principal stresses: the eigenvalues of the symmetric stress tensor (σxx, σyy, σzz, σxy, σyz, σzx),
/// largest first ([`linalg::symmetric_eigenvalues`]).
pub fn principal(s: &[f64; 6]) -> [f64; 3] {
    linalg::symmetric_eigenvalues(s)
}

/// Check that `mesh` bounds a solid: closed, consistently oriented 2-manifold with non-zero volume. Returns
/// the mesh oriented outward (flipped when its volume is negative) and the enclosed volume.
///
/// # Errors
/// `fea.open-surface` naming what is wrong.
pub fn closed_solid(mesh: &TriMesh) -> Result<(TriMesh, f64)> {
    let report = TopologyReport::compute(&PolyMesh::from(mesh.clone()));
    if !report.closed || !report.consistently_oriented || report.nonmanifold_edges > 0 {
        return Err(Error::new(
            ErrorCode::FeaOpenSurface,
            format!(
                "the surface does not bound a solid: {} boundary edges in {} holes, {} non-manifold edges, {} orientation conflicts",
                report.boundary_edges, report.boundary_loops, report.nonmanifold_edges, report.orientation_conflicts
            ),
        )
        .with_hint("run `scanstation repair` first"));
    }
    let v = mesh.signed_volume();
    if !(v.abs() > 0.0) {
        return Err(Error::new(ErrorCode::FeaOpenSurface, "the surface encloses no volume"));
    }
    if v < 0.0 {
        let tris = mesh.triangles.iter().map(|t| [t[0], t[2], t[1]]).collect();
        return Ok((TriMesh::new(mesh.positions.clone(), tris)?, -v));
    }
    Ok((mesh.clone(), v))
}

/// Solve the spec on the solid bounded by `mesh` (closed; see [`closed_solid`]).
///
/// # Errors
/// `fea.open-surface`, `fea.bad-spec`, `fea.empty-selection` (a region that selects no surface, named),
/// `fea.singular` (no supports, or supports that cannot hold the solid), `fea.not-converged`.
/// Cost: see [`domain::Domain::new`] and [`system::assemble`]; the solve dominates for large grids.
///
/// # Example
/// ```
/// use scanstation::geometry::shapes::rod;
/// use scanstation::stages::{NoProgress, fea::{FeaOptions, FeaSpec, solve}};
///
/// // A steel rod (d = 5 mm, L = 100 mm along x) clamped at x = 0, pulled by 100 N at x = 100:
/// // the tip moves F L / E A = 2.4e-4 mm.
/// let spec = FeaSpec::from_toml(r#"
///     [material]
///     youngs_modulus = 210000.0
///     poissons_ratio = 0.3
///     [[supports]]
///     name = "root"
///     plane = { point = [0.001, 0.0, 0.0], normal = [-1.0, 0.0, 0.0] }
///     [[loads]]
///     name = "tip"
///     plane = { point = [99.999, 0.0, 0.0], normal = [1.0, 0.0, 0.0] }
///     force = [100.0, 0.0, 0.0]
///     [resolution]
///     cell_size = 2.5
///     [[probes]]
///     name = "tip centre"
///     point = [100.0, 0.0, 0.0]
/// "#)?;
/// let sol = solve(&rod(2.5, 100.0, 32, 40), &spec, &FeaOptions::default(), &NoProgress)?;
/// let tip = sol.report.probes[0].displacement[0];
/// let expected = 100.0 * 100.0 / (210000.0 * std::f64::consts::PI * 2.5 * 2.5);
/// assert!((tip - expected).abs() < 0.05 * expected, "tip {tip} against {expected}");
/// # Ok::<(), scanstation::Error>(())
/// ```
pub fn solve(mesh: &TriMesh, spec: &FeaSpec, options: &FeaOptions, progress: &dyn Progress) -> Result<FeaSolution> {
    spec.validate()?;
    let (mesh, surface_volume) = closed_solid(mesh)?;
    let mut seconds = std::collections::BTreeMap::new();
    let t0 = Instant::now();
    progress.report(0.0, "domain");
    let bbox = mesh.bbox();
    let ext = bbox.extent();
    let longest = ext[0].max(ext[1]).max(ext[2]);
    let h = spec.resolution.cell_size.unwrap_or(longest / spec.resolution.cells_along_longest as f64);
    check_regions(spec, &bbox)?;
    check_not_all_held(&mesh, spec)?;
    SizeEstimate::new(&mesh, surface_volume, h).check(options.memory_budget)?;
    let grid = Grid::around(&bbox, h);
    let domain = Domain::new(&mesh, grid.clone(), spec.resolution.subcells);
    // Surface quadrature only where a region may select something.
    let regions: Vec<spec::Region> =
        spec.supports.iter().map(|s| s.region()).chain(spec.loads.iter().map(|l| l.region())).collect();
    let candidates: Vec<usize> = (0..mesh.triangles.len())
        .filter(|&t| {
            let c = mesh.corners(t);
            regions.iter().any(|r| r.may_touch(&c))
        })
        .collect();
    let points = surface_points(&mesh, &candidates, 0.5 * h);
    seconds.insert("domain", t0.elapsed().as_secs_f64());

    // Select supports and loads by location.
    let (supports, loads) = select_regions(spec, &points)?;

    // Assemble.
    let t1 = Instant::now();
    progress.report(0.2, "assemble");
    let m = &spec.material;
    let (lambda, mu) = system::lame(m.youngs_modulus, m.poissons_ratio);
    let gravity = spec.gravity.unwrap_or([0.0; 3]);
    let body = scale(gravity, m.density);
    let mut extra: Vec<usize> = points.iter().map(|sp| grid.cell_index(grid.locate(sp.p).0)).collect();
    extra.extend(mesh.positions.iter().map(|&p| grid.cell_index(grid.locate(wide(p)).0)));
    extra.extend(spec.probes.iter().map(|p| grid.cell_index(grid.locate(p.point).0)));
    extra.sort_unstable();
    extra.dedup();
    let res = &spec.resolution;
    let elastic = system::Elastic { lambda, mu, alpha: res.fictitious_stiffness, stability: res.nitsche_factor };
    let mut sys = system::assemble(&domain, &extra, lambda, mu, elastic.alpha, body);
    // β per support point (each support's points in order).
    let betas: Vec<Vec<f64>> = match res.support_method {
        spec::SupportMethod::Nitsche => {
            supports.iter().map(|(_, pts)| sys.add_nitsche_support(&domain, pts, elastic)).collect()
        }
        spec::SupportMethod::Penalty => {
            let beta = res.penalty_factor * m.youngs_modulus / h;
            supports
                .iter()
                .map(|(_, pts)| {
                    sys.add_support(&grid, pts, beta);
                    vec![beta; pts.len()]
                })
                .collect()
        }
    };
    let nitsche = res.support_method == spec::SupportMethod::Nitsche;
    let (load_reports, total_load) = apply_loads(&mut sys, &grid, spec, &loads, scale(body, domain.volume()));
    seconds.insert("assemble", t1.elapsed().as_secs_f64());

    // Solve.
    let t2 = Instant::now();
    progress.report(0.4, "solve");
    let (u, solver) = sys.solve(options.memory_budget)?;
    seconds.insert("solve", t2.elapsed().as_secs_f64());

    // Results.
    let t3 = Instant::now();
    progress.report(0.9, "results");
    let field = Field { grid: &grid, sys: &sys, u: &u, h };
    let eval = |p: V3| field.at(p);
    let (reaction, support_reports) = field.reactions(&supports, &betas, nitsche, lambda, mu);
    let imbalance = norm(add(reaction, total_load)) / norm(total_load).max(1e-300);
    let per_vertex: Vec<(V3, f64, [f64; 3])> = mesh
        .positions
        .par_iter()
        .map(|&p| {
            let (d, g) = eval(wide(p));
            let s = stress(&g, lambda, mu);
            (d, von_mises(&s), principal(&s))
        })
        .collect();
    let exclusion_distance = 2.0 * h;
    let x = SurfaceExtremes::of(&mesh, &per_vertex, &supports, exclusion_distance);
    let probes = spec
        .probes
        .iter()
        .map(|p| {
            let (d, g) = eval(p.point);
            let s = stress(&g, lambda, mu);
            ProbeReport {
                name: p.name.clone(),
                point: p.point,
                displacement: d,
                von_mises: von_mises(&s),
                principal_stress: principal(&s),
                stress: s,
            }
        })
        .collect();
    seconds.insert("results", t3.elapsed().as_secs_f64());
    progress.report(1.0, "done");
    let report = FeaReport {
        grid: GridReport {
            cell_size: h,
            cells: grid.n,
            active_cells: sys.active_cells,
            cut_cells: sys.cut_cells,
            functions: sys.dofs.functions.len(),
            unknowns: sys.dofs.len(),
            odd_lines: domain.odd_lines,
        },
        volume: domain.volume(),
        surface_volume,
        solver,
        supports: support_reports,
        loads: load_reports,
        total_load,
        reaction,
        imbalance,
        max_displacement: x.max_displacement,
        max_von_mises: x.max_von_mises,
        max_von_mises_away_from_supports: x.max_von_mises_away_from_supports,
        exclusion_distance,
        max_principal_stress: x.max_principal_stress,
        min_principal_stress: x.min_principal_stress,
        probes,
        seconds,
    };
    let fields = SurfaceFields {
        displacement: per_vertex.iter().map(|x| x.0).collect(),
        von_mises: per_vertex.iter().map(|x| x.1).collect(),
        principal_stress: per_vertex.iter().map(|x| x.2).collect(),
    };
    Ok(FeaSolution { report, surface: mesh, fields })
}

/// The supports' and loads' surface points, each selection named; every selection must take part of the
/// surface, the supports must hold every rigid motion and no load may sit on a support.
fn select_regions(spec: &FeaSpec, points: &[SurfacePoint]) -> Result<(Selections, Selections)> {
    let pick = |region: &spec::Region| -> Vec<SurfacePoint> {
        points.iter().filter(|sp| region.contains(sp.p)).copied().collect()
    };
    let supports: Selections = spec.supports.iter().enumerate().map(|(i, s)| (s.label(i), pick(&s.region()))).collect();
    let loads: Selections = spec.loads.iter().enumerate().map(|(i, l)| (l.label(i), pick(&l.region()))).collect();
    for (name, pts) in supports.iter().chain(&loads) {
        if pts.is_empty() {
            return Err(Error::new(ErrorCode::FeaEmptySelection, format!("{name} selects no part of the surface"))
                .with_hint("check the region against the solid's bounding box (same units)"));
        }
    }
    check_supports_hold(&supports)?;
    check_loads_free(&loads, spec)?;
    Ok((supports, loads))
}

/// The solved displacement field: the B-spline functions' coefficients `u` over `grid` (cell size `h`).
struct Field<'a> {
    grid: &'a Grid,
    sys: &'a system::System,
    u: &'a [f64],
    h: f64,
}

impl Field<'_> {
    /// The displacement at `p` and its gradient (∂uᵢ/∂xⱼ).
    fn at(&self, p: V3) -> (V3, [[f64; 3]; 3]) {
        let (c, t) = self.grid.locate(p);
        let f = self.sys.dofs.cell_functions(c);
        let (n, g) = basis::shape(t, self.h);
        let mut disp = [0.0; 3];
        let mut grad = [[0.0; 3]; 3];
        for a in 0..27 {
            let r = self.sys.dofs.rank[f[a]];
            if r == u32::MAX {
                continue;
            }
            let r = r as usize;
            for i in 0..3 {
                let ui = self.u[3 * r + i];
                disp[i] += ui * n[a];
                for j in 0..3 {
                    grad[i][j] += ui * g[a][j];
                }
            }
        }
        (disp, grad)
    }

    /// The total reaction of the supports and each support's report: the force each exerts is
    /// ∫ (σ(u)·n − β u) with Nitsche, −∫ β u with a penalty (`betas`: β per support point).
    fn reactions(
        &self,
        supports: &Selections,
        betas: &[Vec<f64>],
        nitsche: bool,
        lambda: f64,
        mu: f64,
    ) -> (V3, Vec<SelectionReport>) {
        let mut reaction = [0.0; 3];
        let mut support_reports = Vec::new();
        for ((name, pts), betas) in supports.iter().zip(betas) {
            let mut area = 0.0;
            for (sp, &beta) in pts.iter().zip(betas) {
                let (d, g) = self.at(sp.p);
                reaction = sub(reaction, scale(d, beta * sp.w));
                if nitsche {
                    let s = stress(&g, lambda, mu);
                    reaction = add(reaction, scale(stress_traction(&s, sp.n), sp.w));
                }
                area += sp.w;
            }
            support_reports.push(SelectionReport { name: name.clone(), area, points: pts.len(), force: [0.0; 3] });
        }
        (reaction, support_reports)
    }
}

/// Named selections of surface points.
type Selections = Vec<(String, Vec<SurfacePoint>)>;

/// Add each load's traction to `sys` (a force spread evenly over its selection's area, or a pressure along
/// the inward normal); returns the loads' reports and the total load, starting from `body_total` (gravity).
fn apply_loads(
    sys: &mut system::System,
    grid: &Grid,
    spec: &FeaSpec,
    loads: &Selections,
    body_total: V3,
) -> (Vec<SelectionReport>, V3) {
    let mut load_reports = Vec::new();
    let mut total_load = body_total;
    for (l, (name, pts)) in spec.loads.iter().zip(loads) {
        let area: f64 = pts.iter().map(|sp| sp.w).sum();
        let force = if let Some(f) = l.force {
            let t = scale(f, 1.0 / area);
            sys.add_traction(grid, pts, |_| t);
            f
        } else {
            let p = l.pressure.unwrap_or(0.0);
            sys.add_traction(grid, pts, |sp| scale(sp.n, -p));
            pts.iter().fold([0.0; 3], |acc, sp| add(acc, scale(sp.n, -p * sp.w)))
        };
        total_load = add(total_load, force);
        load_reports.push(SelectionReport { name: name.clone(), area, points: pts.len(), force });
    }
    (load_reports, total_load)
}

/// The extremes of the surface fields over the solid's vertices.
struct SurfaceExtremes {
    max_displacement: Extreme,
    max_von_mises: Extreme,
    max_von_mises_away_from_supports: Extreme,
    max_principal_stress: Extreme,
    min_principal_stress: Extreme,
}

impl SurfaceExtremes {
    /// From `per_vertex` (displacement, von Mises, principal stresses) over `mesh`'s vertices; "away from
    /// supports" leaves out vertices within `exclusion_distance` of a support point.
    fn of(mesh: &TriMesh, per_vertex: &[(V3, f64, [f64; 3])], supports: &Selections, exclusion_distance: f64) -> Self {
        // The largest `key` over the vertices that `keep` admits.
        type Key<'k> = &'k dyn Fn(&(V3, f64, [f64; 3])) -> f64;
        let extreme_where = |keep: &dyn Fn(usize) -> bool, key: Key| -> Extreme {
            let (i, v) = per_vertex
                .iter()
                .enumerate()
                .filter(|(i, _)| keep(*i))
                .map(|(i, x)| (i, key(x)))
                .fold((0, f64::NEG_INFINITY), |b, x| if x.1 > b.1 { x } else { b });
            Extreme { value: v, at: wide(mesh.positions[i]) }
        };
        let extreme = |key: Key| extreme_where(&|_| true, key);
        let max_displacement = extreme(&|x| norm(x.0));
        let max_von_mises = extreme(&|x| x.1);
        let support_cloud: Vec<[f32; 3]> =
            supports.iter().flat_map(|s| s.1.iter().map(|sp| sp.p.map(|x| x as f32))).collect();
        let support_bvh = crate::geometry::bvh::PointBvh::new(&support_cloud);
        let far: Vec<bool> =
            mesh.positions.par_iter().map(|&p| support_bvh.distance(wide(p)) > exclusion_distance).collect();
        let mut max_von_mises_away_from_supports = extreme_where(&|i| far[i], &|x| x.1);
        max_von_mises_away_from_supports.value = max_von_mises_away_from_supports.value.max(0.0);
        let max_principal_stress = extreme(&|x| x.2[0]);
        let mut min_principal_stress = extreme(&|x| -x.2[2]);
        min_principal_stress.value = -min_principal_stress.value;
        SurfaceExtremes {
            max_displacement,
            max_von_mises,
            max_von_mises_away_from_supports,
            max_principal_stress,
            min_principal_stress,
        }
    }
}

/// Bytes per B-spline function on the iterative path, the least the solve can take: 63 coupled functions ×
/// a 3×3 block of f64 with its index (system.rs's cost note, 63 · 72 B), the right-hand side and the PCG
/// vectors (6 · 3 · 8 B), and the function's cell maps (about 200 B).
pub const BYTES_PER_FUNCTION: u64 = 63 * 72 + 6 * 24 + 200;
/// Bytes per cut cell for its moments and integration lines (domain.rs's cost note).
pub const BYTES_PER_CUT_CELL: u64 = 1024;
/// Most B-spline functions (three unknowns each) a solve may have, whatever the budget: the time cap. The
/// bundled rod at cell_size 1 (12,180 functions) assembles and solves in 1.7 s on 2 cores; 4 million is
/// about a quarter of an hour there by the solver's growth.
pub const MAX_FUNCTIONS: u64 = 4_000_000;

/// The size of a solve, estimated from the solid before any allocation: interior cells from the volume,
/// cut cells from the area, functions from both (for the bundled rod at cell_size 1: 13,366 estimated,
/// 12,180 built; cut cells 4,743 estimated, 4,044 built).
#[derive(Clone, Copy, Debug)]
pub struct SizeEstimate {
    /// Cells that the surface cuts.
    pub cut_cells: u64,
    /// B-spline functions (3 unknowns each).
    pub functions: u64,
    /// Least bytes of the assembled system and the domain.
    pub bytes: u64,
}

impl SizeEstimate {
    /// Estimate for the closed `mesh` of volume `volume` on a grid of spacing `h`.
    pub fn new(mesh: &TriMesh, volume: f64, h: f64) -> SizeEstimate {
        let area = mesh.area();
        let cap = |x: f64| if x.is_finite() { x.min(u64::MAX as f64 / 4.0) as u64 } else { u64::MAX / 4 };
        let cut_cells = cap(1.5 * area / (h * h));
        let functions = cap(volume / (h * h * h)).saturating_add(cut_cells.saturating_mul(2));
        let bytes =
            functions.saturating_mul(BYTES_PER_FUNCTION).saturating_add(cut_cells.saturating_mul(BYTES_PER_CUT_CELL));
        SizeEstimate { cut_cells, functions, bytes }
    }

    /// Fail with `resource.memory` when the solve cannot fit `budget` or the time cap ([`MAX_FUNCTIONS`]).
    pub fn check(&self, budget: u64) -> Result<()> {
        if self.bytes > budget || self.functions > MAX_FUNCTIONS {
            return Err(Error::new(
                ErrorCode::ResourceMemoryBudget,
                format!(
                    "the grid would hold about {} functions ({} unknowns) and {} cut cells: at least {} MiB (budget {} MiB), at most {MAX_FUNCTIONS} functions",
                    self.functions,
                    self.functions.saturating_mul(3),
                    self.cut_cells,
                    self.bytes >> 20,
                    budget >> 20
                ),
            )
            .with_hint("raise resolution.cell_size (or lower cells_along_longest), or the memory budget"));
        }
        Ok(())
    }
}

/// Regions sized against the solid: a sphere larger than [`MAX_REGION_DIAGONALS`] diagonals, or one that
/// cannot reach the solid's bounding box, is `fea.bad-spec` before any work.
fn check_regions(spec: &FeaSpec, bbox: &crate::geometry::vec3::Aabb) -> Result<()> {
    let diag = bbox.diagonal();
    let named = spec.supports.iter().enumerate().map(|(i, s)| (s.label(i), s.sphere.clone()));
    let named = named.chain(spec.loads.iter().enumerate().map(|(i, l)| (l.label(i), l.sphere.clone())));
    for (name, sphere) in named {
        let Some(s) = sphere else { continue };
        if s.radius > MAX_REGION_DIAGONALS * diag {
            return Err(Error::new(
                ErrorCode::FeaBadSpec,
                format!("{name}: a sphere of radius {:e} is more than {MAX_REGION_DIAGONALS} times the solid's diagonal ({diag:.4})", s.radius),
            )
            .with_hint("use a plane region to select a whole side"));
        }
        let gap = (0..3)
            .map(|k| (bbox.min[k] - s.center[k]).max(s.center[k] - bbox.max[k]).max(0.0))
            .map(|d| d * d)
            .sum::<f64>()
            .sqrt();
        if gap > s.radius {
            return Err(Error::new(
                ErrorCode::FeaEmptySelection,
                format!(
                    "{name}: the sphere lies {gap} away from the solid's bounding box, beyond its radius {}",
                    s.radius
                ),
            )
            .with_hint("check the region against the solid's bounding box (same units)"));
        }
    }
    Ok(())
}

/// Largest sphere region, in diagonals of the solid's bounding box.
pub const MAX_REGION_DIAGONALS: f64 = 10.0;

/// Supports that hold every vertex of the surface leave nothing free to deform: `fea.bad-spec`, named.
fn check_not_all_held(mesh: &TriMesh, spec: &FeaSpec) -> Result<()> {
    let held = |p: V3| spec.supports.iter().any(|s| s.region().contains(p));
    if mesh.positions.iter().all(|&p| held(wide(p))) {
        let names: Vec<String> = spec.supports.iter().enumerate().map(|(i, s)| s.label(i)).collect();
        return Err(Error::new(
            ErrorCode::FeaBadSpec,
            format!("the supports ({}) hold the whole surface: nothing is free to deform", names.join(", ")),
        )
        .with_hint("fix a part of the surface, such as a base face, not all of it"));
    }
    Ok(())
}

/// A load that acts only where the solid is held moves nothing: `fea.bad-spec`, named.
fn check_loads_free(loads: &[(String, Vec<SurfacePoint>)], spec: &FeaSpec) -> Result<()> {
    let held = |p: V3| spec.supports.iter().any(|s| s.region().contains(p));
    for (name, pts) in loads {
        if pts.iter().all(|sp| held(sp.p)) {
            return Err(Error::new(
                ErrorCode::FeaBadSpec,
                format!("{name} acts only where the supports hold the solid"),
            )
            .with_hint("move the load off the supported part"));
        }
    }
    Ok(())
}

/// Supports must hold every rigid motion: their points together must not lie on one line.
fn check_supports_hold(supports: &[(String, Vec<SurfacePoint>)]) -> Result<()> {
    let pts: Vec<V3> = supports.iter().flat_map(|s| s.1.iter().map(|sp| sp.p)).collect();
    let n = pts.len() as f64;
    let c = pts.iter().fold([0.0; 3], |a, &p| add(a, scale(p, 1.0 / n)));
    // Largest distance from the centroid, then the largest distance from that line.
    let far = pts.iter().map(|&p| sub(p, c)).fold([0.0; 3], |a, d| if norm(d) > norm(a) { d } else { a });
    let r = norm(far);
    if r == 0.0 {
        return Err(Error::new(ErrorCode::FeaSingular, "the supports hold a single point: the solid can rotate")
            .with_hint("fix an area, not a point"));
    }
    let dir = scale(far, 1.0 / r);
    let off = pts.iter().map(|&p| norm(cross(sub(p, c), dir))).fold(0.0, f64::max);
    if off <= 1e-9 * r {
        return Err(Error::new(
            ErrorCode::FeaSingular,
            "the supports hold points on one line: the solid can rotate about it",
        )
        .with_hint("fix an area, not a line"));
    }
    Ok(())
}

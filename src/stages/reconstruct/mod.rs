//! **reconstruct** — a closed, outward-oriented 2-manifold triangle mesh from a point cloud.
//!
//! Steps (see [`reconstruct`]): neighbours on a grid index; normals given (checked) or estimated by PCA and
//! oriented along a minimum spanning tree with a global flux check ([`normals`]); screened Poisson on a
//! regular grid solved by multigrid-preconditioned conjugate gradients ([`poisson`]); the iso-surface by marching tetrahedra, closed and
//! manifold by construction, without bubbles and blobs ([`extract`]); the share of the surface far from every
//! point reported (a solid stays closed: regions without data are bridged, never cut open).
//!
//! Deterministic for the same cloud and settings on any number of threads.

pub mod extract;
pub mod fusion;
pub mod global;
pub mod normals;
pub mod passes;
pub mod poisson;
pub mod project;
pub mod refine;
pub mod register;
pub mod thin;

use std::collections::BTreeMap;
use std::time::Instant;

use rayon::prelude::*;

use crate::error::{Error, ErrorCode, Result};
use crate::geometry::mesh::{PointCloud, TriMesh};
use crate::geometry::points::PointIndex;
use crate::geometry::vec3::{Aabb, V3, add, cross, norm, scale, sub, wide};
use crate::stages::Progress;

/// Points per occupied cell of the one point index a reconstruction builds (neighbours, projection, far area).
pub const INDEX_POINTS_PER_CELL: f64 = 4.0;

/// Fewest points a cloud must have: below this no surface is defined by it.
pub const MIN_POINTS: usize = 300;

/// Neighbours of each point for normals and density (PCA over 16 is the usual choice, 10–30).
pub const NEIGHBOURS: usize = 16;

/// A point of the result farther than this many mean sample spacings from every input point is "far":
/// surface invented where the scan has no data.
pub const FAR_SPACINGS: f64 = 3.0;

/// Bytes per grid node during the solve: χ, the CG residual, direction and product, the V-cycle's correction
/// and second buffer, and the smoother's step (7 × f32), plus the coarser levels (4 × f32, 1/7 more), rounded
/// up; measured 2026-12-05 on igea at 193 × 257 × 257 nodes (12.7 M) and 200k points: 453 MiB peak RSS
/// (33 B per node beside the points and the process).
pub const BYTES_PER_NODE: u64 = 36;

/// Bytes per point: position, normal, area, screening weight, neighbour lists (16 × 4 B, twice for the
/// symmetric graph) and the orientation's heap and flags.
pub const BYTES_PER_POINT: u64 = 12 + 24 + 16 + 2 * 4 * NEIGHBOURS as u64 + 40;

/// Side of the cells a thinned cloud is merged into, in grid cells: a quarter (the grid and the projection use
/// nothing finer; see [`thin`]).
pub const THIN_CELL: f64 = 0.25;

/// Fewest merged points thinning may leave: a budget with no room for them beside the grid is too small.
pub const MIN_KEPT_POINTS: usize = 20_000;

/// Share of the stage's budget (after the input cloud) an automatic resolution may give the grid; the rest
/// holds the points, thinned if need be.
pub const GRID_SHARE: f64 = 0.6;

/// Bytes of the budget left to the process itself and the allocator's slack: 16 MiB (the CLI's resident size is
/// 6 MiB when a reader refuses at once; a 10M-point torus at `--memory-budget 250M` peaked 12 MiB above the
/// plan's sum before this allowance, 2026-12-05).
pub const PROCESS_BYTES: u64 = 16 << 20;

/// Relative residual at which the Poisson solve stops. The vertices are projected onto the points afterwards,
/// so χ is needed only to a fraction of a cell: measured 2026-12-05 on 200k-point clouds of igea and armadillo
/// (symmetric RMS to the mesh, % of the diagonal) at 10⁻⁶ / 10⁻⁴ / 10⁻³: 0.00413 / 0.00409 / 0.00413 and
/// 0.00798 / 0.00798 / –, with 9 / 6 / 4 iterations on igea.
pub const SOLVE_TOLERANCE: f64 = 1e-4;

/// Mean point spacing, in grid cells, at or below which an automatic split refines the surface once, when
/// the points are clean (noise ratio below [`project::TIGHT_BELOW`]; a noisy cloud's wide projection averages
/// over more than a cell, so finer triangles carry no finer detail): the points then hold about four samples
/// per triangle, enough for the midpoints. Measured 2026-12-05 (200k
/// points, spacing 0.42 cell on igea): symmetric RMS to the mesh 0.0041 → 0.0031 % (armadillo 0.0080 → 0.0052 %;
/// Open3D depth 9: 0.0054 %, 0.0073 %), at 1.5 s more.
pub const AUTO_SPLIT_SPACING: f64 = 0.5;

/// Largest automatic resolution for a noisy cloud (noise ratio at least [`project::TIGHT_BELOW`]): its wide
/// projection averages over more than a cell, and a finer grid follows the scan's own noise. Measured
/// 2026-12-05 on the bunny's ten fused range scans (noise ratio 0.34), bun_zipper → result RMS at 256 / 300 /
/// 350 nodes: 0.0248 / 0.0251 / 0.0253 % of the diagonal (Open3D depth 9 on the same points: 0.0250 %); on
/// 2M armadillo points with 0.05 % noise 384 nodes gave 0.0114 % against 0.0124 % at 256 (Open3D 0.0127 %).
pub const NOISY_MAX_RESOLUTION: usize = 256;

/// Lowest resolution the budget may push an automatic resolution down to.
pub const MIN_RESOLUTION: usize = 64;

/// How the budget is shared: the resolution, and the most points that fit beside the grid (`None`: all do).
#[derive(Clone, Debug)]
struct MemoryPlan {
    resolution: usize,
    max_points: Option<usize>,
    /// Bytes of the input cloud, the grid, and the points at their fewest.
    input: u64,
    grid: u64,
    points: u64,
}

impl MemoryPlan {
    /// `resource.memory`: the budget cannot hold the plan; `why` adds what was tried.
    /// The cloud thinned to the plan's most points, when the plan has a most (cells of [`THIN_CELL`] finest
    /// grid cells, merged wider until the count fits).
    ///
    /// # Errors
    /// `resource.memory-budget` when merging cells of up to the widest tried does not reach the count.
    fn thin(
        &self,
        cloud: &PointCloud,
        bbox: &Aabb,
        opts: &ReconstructOptions,
    ) -> Result<Option<(PointCloud, thin::Thinning)>> {
        let Some(max) = self.max_points else { return Ok(None) };
        let cell = poisson::finest_grid(bbox, self.resolution).h * THIN_CELL;
        let widest = cell * (1u64 << (thin::MAX_ATTEMPTS - 1)) as f64;
        let why = format!(", {max} at most, not reached by merging cells of up to {widest:.3e}");
        Ok(Some(thin::thin(cloud, cell, max).ok_or_else(|| self.too_small(opts, &why))?))
    }

    fn too_small(&self, opts: &ReconstructOptions, why: &str) -> Error {
        Error::new(
            ErrorCode::ResourceMemoryBudget,
            format!(
                "reconstruction at resolution {} needs about {} MiB (the input {} MiB, the grid {} MiB, the points {} MiB{why}, the process {} MiB); the budget is {} MiB",
                self.resolution,
                (self.input + self.grid + self.points + PROCESS_BYTES) >> 20,
                self.input >> 20,
                self.grid >> 20,
                self.points >> 20,
                PROCESS_BYTES >> 20,
                opts.memory_budget >> 20
            ),
        )
        .with_hint("raise the memory budget or lower the resolution")
    }
}

/// Share `opts.memory_budget` between the input cloud, the grid and the points, before allocating any of them:
/// an automatic resolution is lowered (down to [`MIN_RESOLUTION`]) until the grid takes at most
/// [`GRID_SHARE`] of what the input leaves; points that do not fit beside the grid are thinned.
///
/// # Errors
/// `resource.memory` when not even [`MIN_KEPT_POINTS`] points (or all, if fewer) fit beside the grid.
fn plan_memory(cloud: &PointCloud, bbox: &Aabb, opts: &ReconstructOptions) -> Result<MemoryPlan> {
    let n = cloud.positions.len();
    let input = cloud.heap_bytes();
    let budget = opts.memory_budget.saturating_sub(input).saturating_sub(PROCESS_BYTES);
    let grid_bytes = |res: usize| (poisson::finest_grid(bbox, res).len() as u64).saturating_mul(BYTES_PER_NODE);
    let mut resolution = if opts.resolution > 0 { opts.resolution } else { auto_resolution(n, opts.max_resolution) };
    if opts.resolution == 0 {
        while resolution > MIN_RESOLUTION && grid_bytes(resolution) as f64 > GRID_SHARE * budget as f64 {
            resolution = (resolution * 15 / 16).max(MIN_RESOLUTION);
        }
    }
    let grid = grid_bytes(resolution);
    let fits = (budget.saturating_sub(grid) / BYTES_PER_POINT).min(usize::MAX as u64) as usize;
    let least = n.min(MIN_KEPT_POINTS);
    let plan = MemoryPlan {
        resolution,
        max_points: (fits < n).then_some(fits),
        input,
        grid,
        points: least as u64 * BYTES_PER_POINT,
    };
    if fits < least {
        return Err(plan.too_small(opts, ""));
    }
    Ok(plan)
}

/// Settings of [`reconstruct`].
#[derive(Clone, Debug)]
pub struct ReconstructOptions {
    /// Grid nodes along the longest side (0: chosen from the point count, see [`auto_resolution`]).
    pub resolution: usize,
    /// Largest automatic resolution.
    pub max_resolution: usize,
    /// Screening weight (0: unscreened Poisson, smoother and farther from the points).
    pub screening: f64,
    /// Ignore the cloud's normals and estimate them.
    pub estimate_normals: bool,
    /// Move the extracted vertices onto the samples' local surfaces ([`project`]).
    pub project: bool,
    /// Times every triangle is split in four after the projection, the midpoints projected too ([`refine`]);
    /// `None`: once where the points are clean and denser than the grid (mean spacing at most
    /// [`AUTO_SPLIT_SPACING`] cells), were not thinned for the budget, and the split fits it; else not.
    pub split: Option<usize>,
    /// Most bytes the stage may allocate.
    pub memory_budget: u64,
    /// How the views of a scan set are fused ([`fusion`]).
    pub fusion: fusion::FuseOptions,
}

impl Default for ReconstructOptions {
    fn default() -> Self {
        ReconstructOptions {
            resolution: 0,
            max_resolution: 384,
            screening: 4.0,
            estimate_normals: false,
            project: true,
            split: None,
            memory_budget: 8 << 30,
            fusion: fusion::FuseOptions::default(),
        }
    }
}

/// What [`reconstruct`] did.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ReconstructReport {
    /// Input points.
    pub points: usize,
    /// Present when the points did not fit the budget beside the grid and were merged per cell ([`thin`]).
    pub thinning: Option<thin::Thinning>,
    /// Whether the cloud's own normals were used.
    pub normals_given: bool,
    /// Orientation of estimated normals (absent when given).
    pub orientation: Option<normals::Orientation>,
    /// Mean distance to the nearest neighbour.
    pub mean_spacing: f64,
    /// Grid nodes per axis and spacing.
    pub grid_nodes: [usize; 3],
    /// Grid spacing.
    pub cell_size: f64,
    /// The solve (one entry: the finest grid).
    pub levels: Vec<poisson::LevelReport>,
    /// Share of the sample area where χ increases along the normal (1 for a consistent outward field).
    pub outward_share: f64,
    /// The iso-value extracted.
    pub iso_value: f64,
    /// Components kept and removed.
    pub components: extract::Components,
    /// Vertices moved onto the samples' planes ([`project`]).
    pub projected_vertices: usize,
    /// The points' scatter about a smooth surface over their spacing ([`project::noise_ratio`]); above
    /// [`project::TIGHT_BELOW`] the projection averages over wider neighbourhoods.
    pub noise_ratio: f64,
    /// Vertices of the result.
    pub vertices: usize,
    /// Triangles of the result.
    pub triangles: usize,
    /// Times the triangles were split in four ([`refine`]).
    pub splits: usize,
    /// Share of the result's area farther than [`FAR_SPACINGS`] mean spacings from every point (measured
    /// before a split: the split's triangles cover their parents' surface).
    pub far_area_share: f64,
    /// Seconds per step.
    pub seconds: BTreeMap<String, f64>,
}

/// Grid resolution for `n` points: `0.6·√n` nodes along the longest side, between 64 and `max` (spot's 2,930
/// vertices as a cloud: points → surface RMS 0.236 % of the diagonal at 32 nodes).
pub fn auto_resolution(n: usize, max: usize) -> usize {
    ((0.6 * (n as f64).sqrt()).round() as usize).clamp(64, max.max(64))
}

/// Reconstruct a closed, outward-oriented 2-manifold from `cloud`.
///
/// # Errors
/// `reconstruct.too-few-points` below [`MIN_POINTS`]; `reconstruct.degenerate` for a flat or linear cloud;
/// `input.bad-normal` for zero or non-finite normals; `resource.memory` when the grid and the points do not
/// fit `memory_budget` (checked before allocating them); `reconstruct.failed` when no closed outward
/// component remains. Cost: O(n k log k) for neighbours, O(res³ · iterations) for the solve.
///
/// # Example
/// ```
/// use scanstation::geometry::mesh::PointCloud;
/// use scanstation::geometry::shapes::icosphere;
/// use scanstation::stages::{NoProgress, reconstruct::{reconstruct, ReconstructOptions}};
///
/// let sphere = icosphere(1.0, 4, [0.0; 3]);
/// let cloud = PointCloud::new(sphere.positions.clone(), None, None)?;
/// let (mesh, report) = reconstruct(&cloud, &ReconstructOptions::default(), &NoProgress)?;
/// assert_eq!(report.components.kept, 1);
/// assert!((mesh.signed_volume() - 4.18879).abs() < 0.1); // 4/3 π
/// # Ok::<(), scanstation::Error>(())
/// ```
pub fn reconstruct(
    cloud: &PointCloud,
    opts: &ReconstructOptions,
    progress: &dyn Progress,
) -> Result<(TriMesh, ReconstructReport)> {
    let mut seconds = BTreeMap::new();
    let mut t = Instant::now();
    let mut lap = |name: &str, t: &mut Instant| {
        seconds.insert(name.to_string(), t.elapsed().as_secs_f64());
        *t = Instant::now();
    };
    let points = &cloud.positions;
    let n = points.len();
    // 1. The cloud bounds a solid, and fits the budget.
    if n < MIN_POINTS {
        return Err(Error::new(
            ErrorCode::ReconstructTooFewPoints,
            format!("{n} points; at least {MIN_POINTS} are needed to reconstruct a surface"),
        ));
    }
    normals::check_not_flat(points)?;
    let bbox = Aabb::of_points(points);
    let input_bytes = cloud.heap_bytes();
    let plan = plan_memory(cloud, &bbox, opts)?;
    let res = plan.resolution;
    let thinned = plan.thin(cloud, &bbox, opts)?;
    let (cloud, thinning) = match &thinned {
        Some((c, t)) => (c, Some(t.clone())),
        None => (cloud, None),
    };
    let (input_points, points) = (n, &cloud.positions);
    lap("plan", &mut t);
    progress.report(0.0, "neighbours");
    // 2. Neighbours, spacing and the area each point stands for (π r_k² / k).
    let index = PointIndex::new(points, INDEX_POINTS_PER_CELL);
    let nb = normals::Neighbours::new(&index, points, NEIGHBOURS);
    let areas: Vec<f64> = nb.radius.iter().map(|&r| std::f64::consts::PI * r * r / nb.k as f64).collect();
    let mean_spacing = nb.mean_nearest(points);
    lap("neighbours", &mut t);
    // 3. Normals: given, or estimated and oriented.
    progress.report(0.1, "normals");
    let given = cloud.normals.as_ref().filter(|_| !opts.estimate_normals);
    let (normals, orientation) = match given {
        Some(g) => (normals::given_normals(g)?, None),
        None => {
            let mut est = normals::pca_normals(points, &nb);
            let o = normals::orient(points, &mut est, &areas, &nb);
            (est, Some(o))
        }
    };
    // The points' scatter: how wide the projection reaches, whether a split pays, how fine a grid helps.
    let noise_ratio = project::noise_ratio(&index, points, &normals);
    let res =
        if opts.resolution == 0 && noise_ratio >= project::TIGHT_BELOW { res.min(NOISY_MAX_RESOLUTION) } else { res };
    lap("normals", &mut t);
    // 4. Screened Poisson, multigrid-preconditioned CG.
    progress.report(0.3, "solve");
    let samples = poisson::Samples { points, normals: &normals, areas: &areas };
    let settings = poisson::SolveSettings {
        resolution: res,
        screening: opts.screening,
        tolerance: SOLVE_TOLERANCE,
        max_iterations: 200,
    };
    let (grid, chi, levels) = poisson::solve(&bbox, &samples, &settings);
    let iso = poisson::iso_value(&grid, &chi, &samples);
    let outward_share = poisson::outward_share(&grid, &chi, &samples);
    lap("solve", &mut t);
    // 5. The iso-surface, its outward components of real size.
    progress.report(0.8, "extract");
    let raw = extract::marching_tetrahedra(&grid, &chi, iso);
    let (mut mesh, components) = extract::filter_components(&raw);
    if mesh.triangles.is_empty() {
        return Err(Error::new(
            ErrorCode::ReconstructFailed,
            format!(
                "no closed outward surface: {} bubbles and {} blobs removed, χ increases outward on {:.0} % of the samples",
                components.bubbles_removed,
                components.blobs_removed,
                100.0 * outward_share
            ),
        )
        .with_hint("check the cloud's normals, or estimate them (--estimate-normals)"));
    }
    lap("extract", &mut t);
    // 6. Vertices onto the samples' planes; how much of the surface is far from every point.
    let reach = FAR_SPACINGS * mean_spacing.max(grid.h * 0.5);
    let target = project::Target { index: &index, points, normals: &normals, noise: noise_ratio, reach };
    let mut projected =
        if opts.project { project::onto_samples(0, &mut mesh, &target, grid.h, project::ROUNDS) } else { 0 };
    lap("project", &mut t);
    // 7. The share of the surface far from every point; then finer triangles where the grid's are coarse:
    //    split, the midpoints onto the samples' surface.
    drop((raw, chi));
    let far_area_share = far_share(&mesh, &index, reach);
    lap("far", &mut t);
    let auto = opts.split.is_none();
    // Not where the budget already thinned the points: memory is what binds there (a 10M-point torus under
    // 1 GiB peaked at 1039 MiB with the split, 849 MiB without).
    let dense = mean_spacing <= AUTO_SPLIT_SPACING * grid.h && noise_ratio < project::TIGHT_BELOW && thinning.is_none();
    let wanted = opts.split.unwrap_or(usize::from(dense));
    let mut splits = 0;
    for _ in 0..wanted {
        let held = input_bytes + points.len() as u64 * BYTES_PER_POINT + PROCESS_BYTES;
        if !split_fits(&mesh, held, opts.memory_budget, auto)? {
            break;
        }
        let (split, first) = refine::midpoint_split(&mesh);
        mesh = split;
        splits += 1;
        if opts.project {
            projected += project::onto_samples(first, &mut mesh, &target, grid.h * 0.5, project::MIDPOINT_ROUNDS);
        }
    }
    lap("split", &mut t);
    progress.report(1.0, "done");
    let report = ReconstructReport {
        points: input_points,
        thinning,
        normals_given: given.is_some(),
        orientation,
        mean_spacing,
        grid_nodes: grid.n,
        cell_size: grid.h,
        levels,
        outward_share,
        iso_value: iso,
        components,
        projected_vertices: projected,
        noise_ratio,
        vertices: mesh.positions.len(),
        triangles: mesh.triangles.len(),
        splits,
        far_area_share,
        seconds,
    };
    Ok((mesh, report))
}

/// Whether splitting `mesh` (4× the triangles, the midpoints, their table) fits the budget beside the
/// `held` bytes of the points.
///
/// # Errors
/// `resource.memory-budget` when it does not fit and the split was asked for (not `auto`).
fn split_fits(mesh: &TriMesh, held: u64, budget: u64, auto: bool) -> Result<bool> {
    let need = refine::split_bytes(mesh);
    let room = budget.saturating_sub(held);
    if need <= room {
        return Ok(true);
    }
    if auto {
        return Ok(false);
    }
    Err(Error::new(
        ErrorCode::ResourceMemoryBudget,
        format!(
            "splitting {} triangles needs about {} MiB; the budget leaves {} MiB beside the points",
            mesh.triangles.len(),
            need >> 20,
            room >> 20
        ),
    )
    .with_hint("raise the memory budget or split less (--split)"))
}

/// Share of `mesh`'s area whose triangle centroids lie farther than `reach` from every indexed point.
fn far_share(mesh: &TriMesh, index: &PointIndex, reach: f64) -> f64 {
    let (far, total) = mesh
        .triangles
        .par_iter()
        .map(|t| {
            let p: [V3; 3] = t.map(|v| wide(mesh.positions[v as usize]));
            let area = 0.5 * norm(cross(sub(p[1], p[0]), sub(p[2], p[0])));
            let c = scale(add(add(p[0], p[1]), p[2]), 1.0 / 3.0);
            (if index.nearest_within(c, reach).is_none() { area } else { 0.0 }, area)
        })
        .collect::<Vec<_>>()
        .into_iter()
        .fold((0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
    far / total.max(f64::MIN_POSITIVE)
}

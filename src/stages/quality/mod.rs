//! **Quality** — the two-sided surface distance between a result and the scan it came from; the one
//! instrument every stage reports with.
//!
//! Protocol (Metro-style, see `design/algorithms.md` §7):
//! * each surface is sampled **area-uniformly** (stratified) with `samples` points; a point cloud's samples are
//!   its points;
//! * each sample's distance to the other surface is the exact point–triangle distance to its nearest triangle
//!   (BVH query), or the nearest-neighbour distance to a cloud;
//! * `max` (the one-sided Hausdorff distance) also evaluates every referenced vertex of the sampled mesh, so
//!   sharp tips are not missed, and searches the triangles of the farthest samples for their farthest point
//!   (see `refine_max`), so a maximum inside a triangle is found rather than left to sampling luck;
//! * RMS, mean, median and p95 use the area samples; percentiles interpolate linearly (as numpy does);
//! * the symmetric figures pool both directions' samples; its max is the two-sided Hausdorff distance;
//! * every figure is also given as a percentage of the **reference's** bounding-box diagonal and as "1 part
//!   in N" (diagonal ÷ value).
//!
//! Each side's samples are drawn from a generator seeded by `seed` and the side's own content, so the result
//! is deterministic, and swapping TEST and REFERENCE swaps the two one-sided results exactly.

mod deviation;
mod error_map;

pub use deviation::{
    DEVIATION_BAND, DEVIATION_INSIDE, DEVIATION_NEAR, DEVIATION_OUTSIDE, deviation_colour, signed_vertex_distances,
    with_side,
};
pub use error_map::{ErrorMapFile, INVENTED_GREY, color_ramp, write_error_map};

use rayon::prelude::*;

use crate::error::{Error, ErrorCode, Result};
use crate::geometry::bvh::{PointBvh, TriangleBvh};
use crate::geometry::mesh::{Geometry, TriMesh};
use crate::geometry::sampling::{Rng, fnv1a, sample_area_uniform};
use crate::geometry::stats::percentile;
use crate::geometry::tolerance::DISTANCE_ZERO_REL;
use crate::geometry::vec3::{V3, wide};
use crate::stages::Progress;

/// Settings of a comparison.
#[derive(Copy, Clone, Debug)]
pub struct CompareOptions {
    /// Area samples per side (a cloud uses all its points).
    pub samples: usize,
    /// Seed of the sampling.
    pub seed: u64,
    /// Also evaluate every referenced vertex for `max`.
    pub include_vertices: bool,
    /// Most bytes the comparison may allocate.
    pub memory_budget: u64,
}

impl Default for CompareOptions {
    fn default() -> Self {
        CompareOptions { samples: 200_000, seed: 0, include_vertices: true, memory_budget: 8 << 30 }
    }
}

/// A length with its relative forms.
#[derive(Copy, Clone, Debug, PartialEq, serde::Serialize)]
pub struct Measure {
    /// In the input's units.
    pub value: f64,
    /// Percent of the reference's bounding-box diagonal.
    pub pct_of_diagonal: f64,
    /// Diagonal ÷ value ("1 part in N"); `null` when the value is at or below f32 noise
    /// ([`DISTANCE_ZERO_REL`] of the diagonal).
    pub one_part_in: Option<f64>,
}

impl Measure {
    fn new(value: f64, diagonal: f64) -> Self {
        let pct = if diagonal > 0.0 { 100.0 * value / diagonal } else { 0.0 };
        let one_part_in = (value > DISTANCE_ZERO_REL * diagonal && diagonal > 0.0).then(|| diagonal / value);
        Measure { value, pct_of_diagonal: pct, one_part_in }
    }
}

/// Statistics of one set of distances.
#[derive(Copy, Clone, Debug, PartialEq, serde::Serialize)]
pub struct DistanceStats {
    /// Area samples evaluated.
    pub samples: usize,
    /// Root mean square.
    pub rms: Measure,
    /// Mean.
    pub mean: Measure,
    /// Median.
    pub median: Measure,
    /// 95th percentile.
    pub p95: Measure,
    /// Maximum over samples and vertices (sampled Hausdorff distance).
    pub max: Measure,
}

/// The result of [`compare`].
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct DistanceReport {
    /// From samples of TEST to REFERENCE.
    pub test_to_reference: DistanceStats,
    /// From samples of REFERENCE to TEST.
    pub reference_to_test: DistanceStats,
    /// Both directions pooled; max = two-sided Hausdorff distance.
    pub symmetric: DistanceStats,
    /// The diagonal that percentages refer to (REFERENCE's bounding box).
    pub reference_bbox_diagonal: f64,
    /// Requested area samples per side.
    pub samples_per_side: usize,
    /// Sampling seed.
    pub seed: u64,
}

/// One surface prepared for comparison: its samples and its distance query.
enum Prepared<'a> {
    Mesh { mesh: &'a TriMesh, bvh: TriangleBvh },
    Cloud { points: &'a [[f32; 3]], bvh: PointBvh },
}

impl Prepared<'_> {
    fn distance(&self, p: V3) -> f64 {
        match self {
            Prepared::Mesh { bvh, .. } => bvh.distance(p),
            Prepared::Cloud { bvh, .. } => bvh.distance(p),
        }
    }

    fn content_hash(&self, seed: u64) -> u64 {
        let points: &[[f32; 3]] = match self {
            Prepared::Mesh { mesh, .. } => &mesh.positions,
            Prepared::Cloud { points, .. } => points,
        };
        let h = fnv1a(points.iter().flat_map(|p| p.iter().flat_map(|c| c.to_le_bytes())), seed);
        match self {
            Prepared::Mesh { mesh, .. } => {
                fnv1a(mesh.triangles.iter().flat_map(|t| t.iter().flat_map(|i| i.to_le_bytes())), h)
            }
            Prepared::Cloud { .. } => h,
        }
    }

    /// Sample points, their triangles (meshes only) and the referenced vertices (meshes only).
    fn samples(&self, opts: &CompareOptions) -> (Vec<V3>, Vec<u32>, Vec<V3>) {
        match self {
            Prepared::Mesh { mesh, .. } => {
                let mut rng = Rng::new(self.content_hash(opts.seed));
                let (s, t) = sample_area_uniform(mesh, opts.samples, &mut rng)
                    .into_iter()
                    .map(|s| (s.point, s.triangle))
                    .unzip();
                let verts = if opts.include_vertices {
                    let mut used = vec![false; mesh.positions.len()];
                    mesh.triangles.iter().flatten().for_each(|&i| used[i as usize] = true);
                    mesh.positions.iter().zip(&used).filter(|(_, u)| **u).map(|(p, _)| wide(*p)).collect()
                } else {
                    Vec::new()
                };
                (s, t, verts)
            }
            Prepared::Cloud { points, .. } => (points.iter().map(|&p| wide(p)).collect(), Vec::new(), Vec::new()),
        }
    }
}

fn prepare(g: &Geometry, tri: &mut Option<TriMesh>) -> Result<()> {
    if let Geometry::Mesh(m) = g {
        let (t, _) = m.triangulate();
        if t.area() <= 0.0 {
            return Err(Error::new(ErrorCode::InputNoGeometry, "the mesh has zero area"));
        }
        *tri = Some(t);
    }
    Ok(())
}

fn build<'a>(g: &'a Geometry, tri: &'a Option<TriMesh>) -> Prepared<'a> {
    match (g, tri) {
        (Geometry::Mesh(_), Some(t)) => Prepared::Mesh { mesh: t, bvh: TriangleBvh::new(t) },
        (Geometry::Cloud(c), _) => Prepared::Cloud { points: &c.positions, bvh: PointBvh::new(&c.positions) },
        (Geometry::Mesh(_), None) => unreachable!("prepare() triangulates every mesh"),
    }
}

/// Sums of a set of distances; adding two is commutative, so pooled figures do not depend on the order.
#[derive(Copy, Clone, Debug, Default)]
struct Sums {
    n: usize,
    sum: f64,
    sum2: f64,
    max: f64,
}

impl Sums {
    fn of(d: &[f64], vertex_max: f64) -> Self {
        let (sum, sum2, max) = d.iter().fold((0.0, 0.0, 0.0f64), |(s, s2, m), &x| (s + x, s2 + x * x, m.max(x)));
        Sums { n: d.len(), sum, sum2, max: max.max(vertex_max) }
    }
    fn plus(self, o: Sums) -> Sums {
        Sums { n: self.n + o.n, sum: self.sum + o.sum, sum2: self.sum2 + o.sum2, max: self.max.max(o.max) }
    }
}

/// Statistics of sample distances `d` (reordered) whose sums are `s`.
fn stats_with(d: &mut [f64], s: Sums, diagonal: f64) -> DistanceStats {
    let nf = s.n.max(1) as f64;
    let m = |v: f64| Measure::new(v, diagonal);
    let p95 = percentile(d, 0.95);
    let median = percentile(d, 0.5);
    DistanceStats {
        samples: s.n,
        rms: m((s.sum2 / nf).sqrt()),
        mean: m(s.sum / nf),
        median: m(median),
        p95: m(p95),
        max: m(s.max),
    }
}

fn distances(points: &[V3], to: &Prepared) -> Vec<f64> {
    let mut out = Vec::new();
    points.par_iter().map(|&p| to.distance(p)).collect_into_vec(&mut out);
    out
}

/// Samples whose neighbourhoods [`refine_max`] searches.
const REFINE_TOP: usize = 32;
/// Grid resolution (points per edge) of the first search over a triangle.
const REFINE_GRID: usize = 8;
/// Halvings of the hill-climbing step after the grid search.
const REFINE_STEPS: usize = 24;

/// Sampled maxima under-estimate the Hausdorff distance when it is attained inside a triangle (across a hole,
/// at a fold): the estimate then depends on luck and sample count. For the `REFINE_TOP` farthest samples,
/// search their triangle for the farthest point (a barycentric grid, then hill climbing with a halving step)
/// and return the largest distance found. About 32 × 90 closest-point queries.
fn refine_max(mesh: &TriMesh, triangles: &[u32], d: &[f64], to: &Prepared) -> f64 {
    let mut order: Vec<usize> = (0..d.len()).collect();
    let k = REFINE_TOP.min(order.len());
    if k == 0 {
        return 0.0;
    }
    order.select_nth_unstable_by(k - 1, |&a, &b| d[b].total_cmp(&d[a]).then(a.cmp(&b)));
    let mut tris: Vec<u32> = order[..k].iter().map(|&i| triangles[i]).collect();
    tris.sort_unstable();
    tris.dedup();
    tris.par_iter()
        .map(|&t| {
            let [a, b, c] = mesh.corners(t as usize);
            let at = |u: f64, v: f64| {
                let w = 1.0 - u - v;
                [0, 1, 2].map(|k| w * a[k] + u * b[k] + v * c[k])
            };
            let n = REFINE_GRID as f64;
            let (mut best, mut bu, mut bv) = (f64::NEG_INFINITY, 0.0, 0.0);
            for i in 0..=REFINE_GRID {
                for j in 0..=REFINE_GRID - i {
                    let (u, v) = (i as f64 / n, j as f64 / n);
                    let dist = to.distance(at(u, v));
                    if dist > best {
                        (best, bu, bv) = (dist, u, v);
                    }
                }
            }
            let mut step = 0.5 / n;
            for _ in 0..REFINE_STEPS {
                let mut moved = false;
                for (du, dv) in [(1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0), (1.0, -1.0), (-1.0, 1.0)] {
                    let (u, v) = (bu + du * step, bv + dv * step);
                    if u < 0.0 || v < 0.0 || u + v > 1.0 {
                        continue;
                    }
                    let dist = to.distance(at(u, v));
                    if dist > best {
                        (best, bu, bv, moved) = (dist, u, v, true);
                    }
                }
                if !moved {
                    step *= 0.5;
                }
            }
            best
        })
        .reduce(|| 0.0, f64::max)
}

/// Distances of `points` to a scan, and which points lie on invented surface ([`split_by_invented`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct InventedSplit {
    /// Per point: its distance to the scan.
    pub to_scan: Vec<f64>,
    /// Per point: `Some(t)` when it lies on the invented surface (nearer to its triangle `t` than to the
    /// scan), `None` on scanned surface.
    pub invented: Vec<Option<u32>>,
    /// Per point: its distance to the invented surface (infinite without one).
    pub to_invented: Vec<f64>,
}

/// Label `points` (the vertices of a surface made from `scan` closed by `invented`, the triangles repair added
/// over its holes): a point is on invented surface where `invented` is nearer than `scan`, a tie going to
/// the scan. Both distances are returned. A surface that follows its closed input within the chain's
/// accuracy is labelled as that input was: its vertices over a cap lie on the cap, far from any scan point;
/// those on a wall that curls under a cap lie on the wall.
///
/// Cost: O((F_scan + F_invented) log F) for the trees, O(P log F) for the queries (parallel).
pub fn split_by_invented(points: &[V3], scan: &TriMesh, invented: &TriMesh) -> InventedSplit {
    let scan_tree = TriangleBvh::new(scan);
    let fill_tree = (!invented.triangles.is_empty()).then(|| TriangleBvh::new(invented));
    let found: Vec<(f64, Option<(u32, f64)>)> = points
        .par_iter()
        .map(|&p| {
            let d = scan_tree.closest(p).map_or(f64::INFINITY, |c| c.distance);
            let f = fill_tree.as_ref().and_then(|t| t.closest(p)).map(|c| (c.index, c.distance));
            (d, f)
        })
        .collect();
    let mut split = InventedSplit::default();
    for (d, f) in found {
        split.to_scan.push(d);
        split.to_invented.push(f.map_or(f64::INFINITY, |(_, e)| e));
        split.invented.push(f.filter(|&(_, e)| e < d).map(|(t, _)| t));
    }
    split
}

/// Per-vertex distance of `from`'s vertices to `to` (for error maps).
///
/// # Errors
/// `input.no-geometry` for an empty or zero-area `to`.
pub fn vertex_distances(from: &Geometry, to: &Geometry) -> Result<Vec<f64>> {
    let mut tri = None;
    prepare(to, &mut tri)?;
    let target = build(to, &tri);
    let pts: Vec<V3> = from.positions().iter().map(|&p| wide(p)).collect();
    Ok(distances(&pts, &target))
}

/// Two-sided surface distance between `test` and `reference` (meshes or clouds).
///
/// # Errors
/// `input.no-geometry` when a mesh has zero area or a cloud no points; `input.bad-argument` for
/// `samples == 0` with a mesh; `resource.memory` when the estimate exceeds `opts.memory_budget`.
///
/// Cost: O((F_t + F_r) log F + S log F) time for S samples, memory ≈ 40 bytes per triangle + 32 per sample.
pub fn compare(
    test: &Geometry,
    reference: &Geometry,
    opts: &CompareOptions,
    progress: &dyn Progress,
) -> Result<DistanceReport> {
    let is_mesh = |g: &Geometry| matches!(g, Geometry::Mesh(_));
    if opts.samples == 0 && (is_mesh(test) || is_mesh(reference)) {
        return Err(Error::new(ErrorCode::InputBadArgument, "samples must be at least 1"));
    }
    for g in [test, reference] {
        if g.positions().is_empty() {
            return Err(Error::new(ErrorCode::InputNoGeometry, "nothing to compare: no points"));
        }
    }
    // Saturating: an absurd sample count (`--samples 18446744073709551615`) must give `resource.memory`, not
    // wrap to a small estimate and panic on allocation.
    let estimate = |g: &Geometry| -> u64 {
        match g {
            Geometry::Mesh(m) => (60 * m.corner_count() as u64)
                .saturating_add((opts.samples as u64).saturating_mul(32))
                .saturating_add(24 * m.positions.len() as u64),
            Geometry::Cloud(c) => 60 * c.positions.len() as u64,
        }
    };
    let need = estimate(test).saturating_add(estimate(reference));
    if need > opts.memory_budget {
        return Err(Error::new(
            ErrorCode::ResourceMemoryBudget,
            format!("the comparison needs about {need} bytes; the budget is {}", opts.memory_budget),
        )
        .with_hint("lower --samples or raise the memory budget"));
    }
    let diagonal = reference.bbox().diagonal();
    progress.report(0.0, "index");
    let (mut ta, mut tb) = (None, None);
    prepare(test, &mut ta)?;
    prepare(reference, &mut tb)?;
    let (a, b) = rayon::join(|| build(test, &ta), || build(reference, &tb));
    progress.report(0.1, "sample");

    let one_side = |from: &Prepared, to: &Prepared| -> (Vec<f64>, f64) {
        let (samples, triangles, verts) = from.samples(opts);
        let d = distances(&samples, to);
        let vmax = distances(&verts, to).into_iter().fold(0.0, f64::max);
        let refined = match from {
            Prepared::Mesh { mesh, .. } => refine_max(mesh, &triangles, &d, to),
            Prepared::Cloud { .. } => 0.0,
        };
        (d, vmax.max(refined))
    };
    let (mut d_ab, vmax_ab) = one_side(&a, &b);
    progress.report(0.55, "measure");
    let (mut d_ba, vmax_ba) = one_side(&b, &a);
    progress.report(0.95, "statistics");

    let (s_ab, s_ba) = (Sums::of(&d_ab, vmax_ab), Sums::of(&d_ba, vmax_ba));
    let test_to_reference = stats_with(&mut d_ab, s_ab, diagonal);
    let reference_to_test = stats_with(&mut d_ba, s_ba, diagonal);
    let mut pooled = d_ab;
    pooled.extend_from_slice(&d_ba);
    let symmetric = stats_with(&mut pooled, s_ab.plus(s_ba), diagonal);
    progress.report(1.0, "done");
    Ok(DistanceReport {
        test_to_reference,
        reference_to_test,
        symmetric,
        reference_bbox_diagonal: diagonal,
        samples_per_side: opts.samples,
        seed: opts.seed,
    })
}

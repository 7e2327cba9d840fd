//! Moving the extracted vertices onto the points: linear interpolation of a steep χ on the grid leaves the
//! iso-surface a fraction of a cell off (measured on a 20k-point sphere at 85³ nodes: RMS 0.072 % of the
//! diagonal, 9 % of a cell). Each vertex is projected onto the surface of its nearest samples: their
//! Gaussian-weighted centroid and oriented normal give a plane, and a quadric height field fitted over it
//! (second-order moving least squares; Alexa et al. 2003 for the first order) gives the surface, without the
//! plane's inward bias on curved parts. [`ROUNDS`] times, moving at most [`MAX_MOVE_CELLS`] cells in all;
//! tight or wide by the points' [`noise_ratio`] (`Width`). Vertices farther than `reach` from every sample
//! (bridged regions) stay where the smooth solution put them. On 20k-point spheres and tori (tests/reconstruct)
//! the RMS to the exact surface fell from 0.009–0.014 % of the diagonal (the plane) to 0.0002–0.0003 %.

use rayon::prelude::*;

use crate::geometry::mesh::TriMesh;
use crate::geometry::points::PointIndex;
use crate::geometry::vec3::{V3, add, dot, norm, norm2, scale, sub, wide};

/// Projection rounds of a vertex of the grid's surface (the second starts from the first's point, nearer
/// the surface, so its neighbours are the right ones).
pub const ROUNDS: usize = 2;
/// Projection rounds of a split's midpoint: it starts between two projected vertices, already near the
/// surface. Measured 2026-12-05 on 200k-point clouds of igea and armadillo (one split), symmetric RMS to the
/// mesh with 2 / 1 rounds: 0.00309 / 0.00307 % and 0.00519 / 0.00519 %, the split's time 2.6 / 1.7 s (igea).
pub const MIDPOINT_ROUNDS: usize = 1;
/// Largest total move of a vertex, in grid cells (the interpolation error is below one cell).
pub const MAX_MOVE_CELLS: f64 = 1.0;

/// The oriented samples a mesh is projected onto.
#[derive(Clone, Copy)]
pub struct Target<'a> {
    /// The index over `points`.
    pub index: &'a PointIndex<'a>,
    /// Sample positions.
    pub points: &'a [[f32; 3]],
    /// Their unit normals.
    pub normals: &'a [V3],
    /// Their [`noise_ratio`]: how tight or wide a projection reaches.
    pub noise: f64,
    /// A vertex farther than this from every sample stays where it is (a bridged region).
    pub reach: f64,
}

/// Project the vertices of `mesh` from `first` on onto `target` in `rounds` rounds, each vertex moving at most
/// `h` in all; returns how many vertices moved.
pub fn onto_samples(first: usize, mesh: &mut TriMesh, target: &Target, h: f64, rounds: usize) -> usize {
    let Target { index, points, normals, noise, reach } = *target;
    let first = first.min(mesh.positions.len());
    let width = Width::for_noise(noise);
    let moved: Vec<Option<[f32; 3]>> = mesh.positions[first..]
        .par_iter()
        .map_init(Vec::new, |buf, &p0| {
            let start = wide(p0);
            let mut p = start;
            for _ in 0..rounds {
                // Far from every sample (a bridged region): stays (a bounded search).
                let (k, j, div) = (width.samples, width.sigma_from, width.sigma_div);
                if !index.knn_near(p, k, reach, buf) {
                    return None;
                }
                // Gaussian weights, σ² = half the squared distance to the third-nearest sample: a tight
                // plane, so curved surfaces sampled sparsely keep their shape (see [`ROUNDS`]).
                let sigma2 = (buf[j.min(buf.len() - 1)].1 / div).max(f64::MIN_POSITIVE);
                let (mut c, mut n, mut wsum) = ([0.0; 3], [0.0; 3], 0.0);
                for &(i, d2) in buf.iter() {
                    let w = (-d2 / (2.0 * sigma2)).exp();
                    c = add(c, scale(wide(points[i as usize]), w));
                    n = add(n, scale(normals[i as usize], w));
                    wsum += w;
                }
                let (c, len) = (scale(c, 1.0 / wsum), norm(n));
                if len < 1e-9 * wsum {
                    return None;
                }
                let n = scale(n, 1.0 / len);
                p = match quadric_projection(p, c, n, buf, points, sigma2) {
                    Some(q) => q,
                    None => sub(p, scale(n, dot(sub(p, c), n))),
                };
            }
            let d = sub(p, start);
            let limit = MAX_MOVE_CELLS * h;
            let p = if norm2(d) > limit * limit { add(start, scale(d, limit / norm(d))) } else { p };
            Some(p.map(|c| c as f32))
        })
        .collect();
    let mut count = 0;
    for (q, m) in mesh.positions[first..].iter_mut().zip(moved) {
        if let Some(m) = m {
            *q = m;
            count += 1;
        }
    }
    count
}

/// Second-order MLS: the height over the plane (`c`, `n`) fitted as a quadric in the plane's coordinates,
/// `h = a + b u + c v + d u² + e uv + f v²` (weighted least squares, the same Gaussian weights), and `p`
/// moved onto it. A plane's fit lies inside a curved surface by about κ r²/4 (r the neighbourhood's radius:
/// on a sphere sampled by 20k points, 3·10⁻⁴ of its radius); the quadric has no such bias. `None` when the
/// neighbours do not determine a quadric (fewer than 8, or an ill-conditioned system): the plane is used.
fn quadric_projection(p: V3, c: V3, n: V3, near: &[(u32, f64)], points: &[[f32; 3]], sigma2: f64) -> Option<V3> {
    Quadric::fit(c, n, near, points, sigma2)?.project(p)
}

/// Smallest Cholesky pivot of a quadric fit, relative to its system's largest diagonal entry (see
/// `Quadric::fit`).
pub const MIN_PIVOT: f64 = 1e-6;

/// A quadric height field over a plane, in the plane's tangent frame (lengths in units of `s`).
struct Quadric {
    c: V3,
    n: V3,
    t1: V3,
    t2: V3,
    s: f64,
    k: nalgebra::Vector6<f64>,
}

impl Quadric {
    /// The weighted least-squares fit to `near` over the plane (`c`, `n`); `None` when ill-conditioned.
    fn fit(c: V3, n: V3, near: &[(u32, f64)], points: &[[f32; 3]], sigma2: f64) -> Option<Quadric> {
        use nalgebra::{Matrix6, Vector6};
        if near.len() < 8 {
            return None;
        }
        // A tangent frame, lengths in units of σ so the system is well scaled.
        let t1 = {
            let a = if n[0].abs() < 0.9 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
            let t = sub(a, scale(n, dot(a, n)));
            scale(t, 1.0 / norm(t))
        };
        let t2 = crate::geometry::vec3::cross(n, t1);
        let s = sigma2.sqrt().max(f64::MIN_POSITIVE);
        let (mut m, mut r) = (Matrix6::<f64>::zeros(), Vector6::<f64>::zeros());
        for &(i, d2) in near {
            let q = sub(wide(points[i as usize]), c);
            let (u, v, h) = (dot(q, t1) / s, dot(q, t2) / s, dot(q, n));
            let w = (-d2 / (2.0 * sigma2)).exp();
            let row = Vector6::new(1.0, u, v, u * u, u * v, v * v);
            m += w * row * row.transpose();
            r += w * h * row;
        }
        // Reject near-singular fits (neighbours on a line, or a narrow strip): a Cholesky pivot below
        // [`MIN_PIVOT`] of the largest diagonal entry (the smallest pivot bounds the smallest eigenvalue from
        // above, the largest diagonal entry the largest from below; cheaper than the eigenvalues, which took a
        // sixth of a 200k-point reconstruction).
        let top = (0..6).map(|i| m[(i, i)]).fold(0.0f64, f64::max);
        let chol = m.cholesky()?;
        let l = chol.l_dirty();
        if !(0..6).all(|i| l[(i, i)] * l[(i, i)] > MIN_PIVOT * top) {
            return None;
        }
        let k = chol.solve(&r);
        Some(Quadric { c, n, t1, t2, s, k })
    }

    /// `p` moved onto the height field (along the plane's normal); `None` if not finite.
    fn project(&self, p: V3) -> Option<V3> {
        let Quadric { c, n, t1, t2, s, k } = self;
        let q = sub(p, *c);
        let (u, v) = (dot(q, *t1) / s, dot(q, *t2) / s);
        let h = k[0] + k[1] * u + k[2] * v + k[3] * u * u + k[4] * u * v + k[5] * v * v;
        let out = add(add(*c, add(scale(*t1, u * s), scale(*t2, v * s))), scale(*n, h));
        out.iter().all(|x| x.is_finite()).then_some(out)
    }
}

/// How wide a projection reaches: samples, the neighbour whose squared distance sets σ², and its divisor.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Width {
    samples: usize,
    sigma_from: usize,
    sigma_div: f64,
}

/// Noise ratio below which the projection stays tight (see `Width::for_noise`). Measured 2026-12-05 (one
/// split): clean samples of armadillo give 0.08 at 200k points and 0.04 at 2M; with 0.05 % noise 0.41 and 0.74.
pub const TIGHT_BELOW: f64 = 0.2;

/// Samples of a wide projection per unit of noise ratio (24 to 128). Measured 2026-12-05 on armadillo with
/// 0.05 % noise, symmetric RMS to the mesh with 24 / 48 / 96 samples: 200k points (ratio 0.41) 0.0242 /
/// 0.0209 / 0.0267 %, 2M points (ratio 0.74) 0.0174 / 0.0138 / 0.0112 % (Open3D: 0.0200 %, 0.0127 %).
pub const WIDE_SAMPLES_PER_RATIO: f64 = 120.0;

impl Width {
    /// Tight (12 samples, σ² = d₃²/2) for clean clouds, where the quadric follows the shape closely; wide
    /// (k samples, σ² = d_k²/4, k growing with the noise: [`WIDE_SAMPLES_PER_RATIO`]) when the points scatter
    /// by more than [`TIGHT_BELOW`] of their spacing, so the fit averages the noise. Measured 2026-12-05 on
    /// 200k points sampled from armadillo, symmetric RMS to the mesh, one split: clean 0.0059 % tight against
    /// 0.0077 % wide (24); with 0.05 % noise 0.0368 % tight against 0.0242 % wide (24) (Open3D depth 9:
    /// 0.0074 %, 0.0200 %).
    fn for_noise(ratio: f64) -> Width {
        if ratio < TIGHT_BELOW {
            Width { samples: 12, sigma_from: 2, sigma_div: 2.0 }
        } else {
            let k = ((WIDE_SAMPLES_PER_RATIO * ratio).round() as usize).clamp(24, 128);
            Width { samples: k, sigma_from: k - 1, sigma_div: 4.0 }
        }
    }
}

/// Points whose neighbourhood the noise estimate fits, at most.
const NOISE_PROBES: usize = 2000;

/// The points' scatter about a smooth surface, as a share of their spacing: for up to [`NOISE_PROBES`]
/// points spread over the cloud, a quadric fitted to the 24 nearest (wide weights) and the RMS of their
/// heights off it, over the mean distance to the nearest neighbour; the median. A clean scan gives about
/// 0.01, one with noise of a tenth of the spacing about 0.1.
pub fn noise_ratio(index: &PointIndex, points: &[[f32; 3]], normals: &[V3]) -> f64 {
    let step = points.len().div_ceil(NOISE_PROBES).max(1);
    let mut ratios: Vec<f64> = (0..points.len())
        .step_by(step)
        .collect::<Vec<_>>()
        .par_iter()
        .map_init(Vec::new, |buf, &i| {
            let p = wide(points[i]);
            index.knn(p, 24, buf);
            if buf.len() < 12 {
                return None;
            }
            let spacing = buf[1].1.sqrt();
            let sigma2 = (buf[buf.len() - 1].1 / 4.0).max(f64::MIN_POSITIVE);
            let n = normals[i];
            let c = buf.iter().fold([0.0; 3], |a, &(j, _)| add(a, wide(points[j as usize])));
            let c = scale(c, 1.0 / buf.len() as f64);
            let quadric = Quadric::fit(c, n, buf, points, sigma2)?;
            let (mut r2, mut wsum) = (0.0, 0.0);
            for &(j, d2) in buf.iter() {
                let q = wide(points[j as usize]);
                let on = quadric.project(q)?;
                let w = (-d2 / (2.0 * sigma2)).exp();
                r2 += w * norm2(sub(q, on));
                wsum += w;
            }
            (spacing > 0.0).then(|| (r2 / wsum).sqrt() / spacing)
        })
        .flatten()
        .collect();
    if ratios.is_empty() {
        return 0.0;
    }
    let mid = ratios.len() / 2;
    *ratios.select_nth_unstable_by(mid, |a, b| a.total_cmp(b)).1
}

//! Global registration: two overlapping oriented clouds with no pose between them (a second pass of a scan,
//! the object turned over by hand), aligned by their geometry alone.
//!
//! 1. Both clouds are thinned on a voxel grid of [`GlobalOptions::voxel_rel`] of the larger diagonal (a
//!    point and a normal per voxel: the mean, in grid order).
//! 2. Each sample gets a Fast Point Feature Histogram (Rusu et al. 2009): for each neighbour within
//!    [`GlobalOptions::feature_voxels`] voxels, the Darboux frame's three angles, binned 11 ways each; a
//!    sample's histogram plus its neighbours' weighted by inverse distance.
//! 3. Each sample of the moving cloud is matched to the fixed sample with the nearest histogram, and kept
//!    when that match is mutual.
//! 4. RANSAC over the matches ([`GlobalOptions::iterations`] seeded draws of three): a draw whose pairwise
//!    distances disagree by more than 10 % is skipped; otherwise its rigid motion (Kabsch) is scored by
//!    the matches it carries within [`GlobalOptions::inlier_voxels`] voxels. The best is refitted to its
//!    inliers.
//! 5. Point-to-plane ICP on the samples ([`ICP_ITERATIONS`] steps, pairs within two voxels).
//!
//! The result says how well it holds ([`GlobalReport`]: the share of the moving samples that lie on the
//! fixed cloud, and their RMS distance); the caller decides whether that is an alignment. Deterministic for
//! the same input and seed (draws from [`crate::geometry::sampling::Rng`], sums in order).

use nalgebra::{Matrix3, SVD, Vector3};

use crate::error::{Error, ErrorCode, Result};
use crate::geometry::linalg::solve_dense;
use crate::geometry::points::PointIndex;
use crate::geometry::pose::{Pose, axis_angle};
use crate::geometry::sampling::Rng;
use crate::geometry::vec3::{Aabb, V3, add, cross, dot, norm, scale, sub, wide};

/// Steps of the final point-to-plane ICP.
pub const ICP_ITERATIONS: usize = 30;

/// Bins per angle of the feature histogram (three angles: 33 values).
pub const BINS: usize = 11;

/// How [`align`] works.
#[derive(Clone, Debug, PartialEq)]
pub struct GlobalOptions {
    /// The voxel of the thinning, as a share of the larger cloud's bounding-box diagonal.
    pub voxel_rel: f64,
    /// The feature's neighbourhood radius, in voxels.
    pub feature_voxels: f64,
    /// RANSAC draws.
    pub iterations: usize,
    /// A match carried within this many voxels counts as an inlier.
    pub inlier_voxels: f64,
    /// Seed of the draws.
    pub seed: u64,
}

impl Default for GlobalOptions {
    /// 2 % voxels, features over 5 voxels, 20,000 draws, inliers within 1.5 voxels, seed 0.
    fn default() -> Self {
        GlobalOptions { voxel_rel: 0.02, feature_voxels: 5.0, iterations: 20_000, inlier_voxels: 1.5, seed: 0 }
    }
}

/// What [`align`] found.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct GlobalReport {
    /// Samples of the fixed and the moving cloud.
    pub samples: [usize; 2],
    /// Mutual feature matches.
    pub matches: usize,
    /// Matches the best RANSAC motion carried within the inlier distance.
    pub inliers: usize,
    /// The voxel, model units.
    pub voxel: f64,
    /// Share of the moving samples within two voxels of a fixed sample after ICP (0–1).
    pub overlap: f64,
    /// Their RMS point-to-plane distance, model units.
    pub residual_rms: f64,
}

/// An oriented cloud: points and unit normals, one each.
#[derive(Clone, Copy, Debug)]
pub struct Oriented<'a> {
    /// Points.
    pub points: &'a [[f32; 3]],
    /// Unit normals.
    pub normals: &'a [[f32; 3]],
}

/// Thinned samples: a point and a unit normal per occupied voxel.
struct Samples {
    points: Vec<[f32; 3]>,
    normals: Vec<V3>,
}

fn thin(c: Oriented<'_>, voxel: f64) -> Samples {
    let mut cells: std::collections::BTreeMap<[i64; 3], (V3, V3, f64)> = std::collections::BTreeMap::new();
    for (p, n) in c.points.iter().zip(c.normals) {
        let p = wide(*p);
        let key = p.map(|x| (x / voxel).floor() as i64);
        let e = cells.entry(key).or_insert(([0.0; 3], [0.0; 3], 0.0));
        e.0 = add(e.0, p);
        e.1 = add(e.1, wide(*n));
        e.2 += 1.0;
    }
    let mut out = Samples { points: Vec::new(), normals: Vec::new() };
    for (s, n, k) in cells.into_values() {
        let len = norm(n);
        if len > 0.0 {
            out.points.push(scale(s, 1.0 / k).map(|x| x as f32));
            out.normals.push(scale(n, 1.0 / len));
        }
    }
    out
}

/// The three Darboux-frame angles of the pair (p, n_p) → (q, n_q), each mapped to a bin.
fn pair_bins(p: V3, np: V3, q: V3, nq: V3) -> Option<[usize; 3]> {
    let d = sub(q, p);
    let dist = norm(d);
    if dist <= 0.0 {
        return None;
    }
    let d = scale(d, 1.0 / dist);
    let u = np;
    let v = cross(u, d);
    let vl = norm(v);
    if vl <= 1e-12 {
        return None;
    }
    let v = scale(v, 1.0 / vl);
    let w = cross(u, v);
    let alpha = dot(v, nq); // −1..1
    let phi = dot(u, d); // −1..1
    let theta = dot(w, nq).atan2(dot(u, nq)); // −π..π
    let bin = |x: f64, lo: f64, hi: f64| (((x - lo) / (hi - lo) * BINS as f64) as usize).min(BINS - 1);
    Some([bin(alpha, -1.0, 1.0), bin(phi, -1.0, 1.0), bin(theta, -std::f64::consts::PI, std::f64::consts::PI)])
}

/// FPFH of every sample (each normalised to sum 1 per angle).
fn features(s: &Samples, radius: f64) -> Vec<[f64; 3 * BINS]> {
    use rayon::prelude::*;
    let index = PointIndex::new(&s.points, 4.0);
    let neighbours: Vec<Vec<(u32, f64)>> = (0..s.points.len())
        .into_par_iter()
        .map(|i| {
            let mut out = Vec::new();
            index.knn_near(wide(s.points[i]), 64, radius, &mut out);
            out.retain(|&(j, d2)| j as usize != i && d2 <= radius * radius);
            out
        })
        .collect();
    let spfh: Vec<[f64; 3 * BINS]> = (0..s.points.len())
        .into_par_iter()
        .map(|i| {
            let mut h = [0.0; 3 * BINS];
            let (p, np) = (wide(s.points[i]), s.normals[i]);
            for &(j, _) in &neighbours[i] {
                if let Some(b) = pair_bins(p, np, wide(s.points[j as usize]), s.normals[j as usize]) {
                    for (k, &bk) in b.iter().enumerate() {
                        h[k * BINS + bk] += 1.0;
                    }
                }
            }
            h
        })
        .collect();
    (0..s.points.len())
        .into_par_iter()
        .map(|i| {
            let mut f = spfh[i];
            let k = neighbours[i].len().max(1) as f64;
            for &(j, d2) in &neighbours[i] {
                let w = 1.0 / (k * d2.sqrt().max(1e-12 * radius));
                for (x, y) in f.iter_mut().zip(&spfh[j as usize]) {
                    *x += w * y;
                }
            }
            for a in 0..3 {
                let sum: f64 = f[a * BINS..(a + 1) * BINS].iter().sum();
                if sum > 0.0 {
                    f[a * BINS..(a + 1) * BINS].iter_mut().for_each(|x| *x /= sum);
                }
            }
            f
        })
        .collect()
}

/// The nearest histogram of `to` for each of `from` (squared L2; ties to the lower index).
fn nearest_features(from: &[[f64; 3 * BINS]], to: &[[f64; 3 * BINS]]) -> Vec<usize> {
    use rayon::prelude::*;
    from.par_iter()
        .map(|f| {
            let mut best = (0, f64::INFINITY);
            for (j, g) in to.iter().enumerate() {
                let d: f64 = f.iter().zip(g).map(|(a, b)| (a - b) * (a - b)).sum();
                if d < best.1 {
                    best = (j, d);
                }
            }
            best.0
        })
        .collect()
}

/// The rigid motion taking `from[i]` onto `to[i]` in the least-squares sense (Kabsch; a proper rotation).
fn kabsch(from: &[V3], to: &[V3]) -> Option<Pose> {
    let n = from.len() as f64;
    if from.len() < 3 {
        return None;
    }
    let mean = |ps: &[V3]| scale(ps.iter().fold([0.0; 3], |a, &p| add(a, p)), 1.0 / n);
    let (cf, ct) = (mean(from), mean(to));
    let mut h = Matrix3::zeros();
    for (a, b) in from.iter().zip(to) {
        let (a, b) = (sub(*a, cf), sub(*b, ct));
        h += Vector3::new(a[0], a[1], a[2]) * Vector3::new(b[0], b[1], b[2]).transpose();
    }
    let svd = SVD::new(h, true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    let mut d = Matrix3::identity();
    if (vt.transpose() * u.transpose()).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    let r = vt.transpose() * d * u.transpose();
    let rotation =
        [[r[(0, 0)], r[(0, 1)], r[(0, 2)]], [r[(1, 0)], r[(1, 1)], r[(1, 2)]], [r[(2, 0)], r[(2, 1)], r[(2, 2)]]];
    let turned = Pose { rotation, translation: [0.0; 3] }.apply(cf);
    Some(Pose { rotation, translation: sub(ct, turned) })
}

/// Align `moving` onto `fixed`: the pose that maps the moving cloud's frame into the fixed one's, and how
/// well it holds. Cost: O(N) to thin, O(S·k) features, O(S²) matching over the S samples (a few thousand),
/// `iterations` × O(matches) RANSAC, then the ICP.
///
/// # Errors
/// `reconstruct.views-disagree` when either cloud has fewer than 10 samples, or no draw is consistent.
pub fn align(fixed: Oriented<'_>, moving: Oriented<'_>, opts: &GlobalOptions) -> Result<(Pose, GlobalReport)> {
    // 1. Thin both on one grid.
    let mut b = Aabb::EMPTY;
    for p in fixed.points.iter().chain(moving.points) {
        b.add(wide(*p));
    }
    let voxel = opts.voxel_rel * b.diagonal().max(f64::MIN_POSITIVE);
    let (f, m) = (thin(fixed, voxel), thin(moving, voxel));
    let disagree = |why: String| Error::new(ErrorCode::ReconstructViewsDisagree, why);
    if f.points.len() < 10 || m.points.len() < 10 {
        return Err(disagree(format!("too few samples to align: {} and {}", f.points.len(), m.points.len())));
    }
    // 2–3. Features and mutual matches.
    let radius = opts.feature_voxels * voxel;
    let (ff, fm) = (features(&f, radius), features(&m, radius));
    let (m_to_f, f_to_m) = (nearest_features(&fm, &ff), nearest_features(&ff, &fm));
    let matches: Vec<(V3, V3)> = (0..m.points.len())
        .filter(|&i| f_to_m[m_to_f[i]] == i)
        .map(|i| (wide(m.points[i]), wide(f.points[m_to_f[i]])))
        .collect();
    if matches.len() < 3 {
        return Err(disagree(format!("{} mutual feature matches: nothing to align by", matches.len())));
    }
    // 4. RANSAC.
    let best = ransac(&matches, voxel, opts).ok_or_else(|| disagree("no consistent triple of matches".into()))?;
    let inlier_pairs: Vec<&(V3, V3)> =
        matches.iter().filter(|(a, c)| norm(sub(best.apply(*a), *c)) <= opts.inlier_voxels * voxel).collect();
    let (from, to): (Vec<V3>, Vec<V3>) = inlier_pairs.iter().map(|&&(a, c)| (a, c)).unzip();
    let pose = kabsch(&from, &to).unwrap_or(best);
    // 5. ICP.
    let (pose, overlap, residual_rms) = icp(&f, &m, pose, 2.0 * voxel);
    let report = GlobalReport {
        samples: [f.points.len(), m.points.len()],
        matches: matches.len(),
        inliers: inlier_pairs.len(),
        voxel,
        overlap,
        residual_rms,
    };
    Ok((pose, report))
}

/// Refine `pose` (moving frame → fixed frame, from [`align`]) by point-to-plane ICP on both clouds thinned
/// on a finer grid of `voxel` (model units), pairs within two voxels: the pose, the share of the moving
/// samples paired, and their RMS point-to-plane distance. Cost: O(N) to thin, [`ICP_ITERATIONS`] nearest
/// searches per moving sample.
pub fn polish(fixed: Oriented<'_>, moving: Oriented<'_>, pose: Pose, voxel: f64) -> (Pose, f64, f64) {
    let (f, m) = (thin(fixed, voxel), thin(moving, voxel));
    icp(&f, &m, pose, 2.0 * voxel)
}

/// The draw whose motion carries most matches within the inlier distance (ties to the first).
fn ransac(matches: &[(V3, V3)], voxel: f64, opts: &GlobalOptions) -> Option<Pose> {
    let mut rng = Rng::new(opts.seed ^ 0x6C0B_A1E5_7A11_2026);
    let n = matches.len();
    let reach = opts.inlier_voxels * voxel;
    let mut best: Option<(usize, Pose)> = None;
    for _ in 0..opts.iterations {
        let pick = [0, 1, 2].map(|_| (rng.next_f64() * n as f64) as usize % n);
        if pick[0] == pick[1] || pick[1] == pick[2] || pick[0] == pick[2] {
            continue;
        }
        let consistent = (0..3).all(|a| {
            let b = (a + 1) % 3;
            let dm = norm(sub(matches[pick[a]].0, matches[pick[b]].0));
            let df = norm(sub(matches[pick[a]].1, matches[pick[b]].1));
            dm > 2.0 * voxel && (dm - df).abs() <= 0.1 * dm.max(df)
        });
        if !consistent {
            continue;
        }
        let from = pick.map(|i| matches[i].0);
        let to = pick.map(|i| matches[i].1);
        let Some(pose) = kabsch(&from, &to) else { continue };
        let count = matches.iter().filter(|(a, c)| norm(sub(pose.apply(*a), *c)) <= reach).count();
        if best.as_ref().is_none_or(|b| count > b.0) {
            best = Some((count, pose));
        }
    }
    best.map(|b| b.1)
}

/// Point-to-plane ICP of the moving samples onto the fixed ones from `pose`: pairs within `reach`, the
/// linearised 6×6 step each time. The pose, the share of moving samples paired, and their RMS distance.
fn icp(f: &Samples, m: &Samples, mut pose: Pose, reach: f64) -> (Pose, f64, f64) {
    let index = PointIndex::new(&f.points, 4.0);
    let pairs = |pose: &Pose| -> Vec<(V3, V3, V3)> {
        m.points
            .iter()
            .filter_map(|&p| {
                let q = pose.apply(wide(p));
                let (j, _) = index.nearest_within(q, reach)?;
                Some((q, wide(f.points[j as usize]), f.normals[j as usize]))
            })
            .collect()
    };
    for _ in 0..ICP_ITERATIONS {
        let ps = pairs(&pose);
        if ps.len() < 6 {
            break;
        }
        let mut a = [[0.0; 6]; 6];
        let mut rhs = [0.0; 6];
        for &(q, c, n) in &ps {
            let row = {
                let x = cross(q, n);
                [x[0], x[1], x[2], n[0], n[1], n[2]]
            };
            let r = dot(sub(c, q), n);
            for i in 0..6 {
                rhs[i] += row[i] * r;
                for j in 0..6 {
                    a[i][j] += row[i] * row[j];
                }
            }
        }
        let Some(x) = solve_dense(a, rhs) else { break };
        let w = [x[0], x[1], x[2]];
        let angle = norm(w);
        let rot = if angle > 0.0 { axis_angle(scale(w, 1.0 / angle), angle) } else { Pose::IDENTITY.rotation };
        let step = Pose { rotation: rot, translation: [x[3], x[4], x[5]] };
        pose = step.then_after(&pose);
        if angle < 1e-9 && norm([x[3], x[4], x[5]]) < 1e-6 * reach {
            break;
        }
    }
    let ps = pairs(&pose);
    let rms = if ps.is_empty() {
        f64::INFINITY
    } else {
        (ps.iter().map(|&(q, c, n)| dot(sub(c, q), n).powi(2)).sum::<f64>() / ps.len() as f64).sqrt()
    };
    (pose, ps.len() as f64 / m.points.len().max(1) as f64, rms)
}

//! Normals of a cloud: the k nearest neighbours of every point, PCA normals (the eigenvector of the smallest
//! eigenvalue of the neighbourhood's covariance, by nalgebra), orientation propagated along a minimum
//! spanning tree of the kNN graph (Hoppe 1992: weight 1 − |nᵢ·nⱼ|), seeded at the highest point facing up,
//! and a global check by the flux Σ aᵢ nᵢ·(pᵢ − c) (3 × the volume for outward normals).

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use nalgebra::{Matrix3, SymmetricEigen};
use rayon::prelude::*;

use crate::error::{Error, ErrorCode, Result};
use crate::geometry::points::PointIndex;
use crate::geometry::vec3::{V3, add, dot, norm, scale, sub, wide};

/// Neighbour lists: `k` indices per point (nearest first, the point itself included), and the distance to
/// the farthest of them.
pub struct Neighbours {
    /// Neighbours per point.
    pub k: usize,
    /// `k` indices per point.
    pub ids: Vec<u32>,
    /// Distance to the k-th neighbour.
    pub radius: Vec<f64>,
}

impl Neighbours {
    /// The `k` nearest neighbours of every point of `points`, which `index` indexes. Cost: O(n k log k), in
    /// parallel.
    pub fn new(index: &PointIndex, points: &[[f32; 3]], k: usize) -> Neighbours {
        let k = k.min(points.len());
        let rows: Vec<(Vec<u32>, f64)> = points
            .par_iter()
            .map_init(Vec::new, |buf, &p| {
                index.knn(wide(p), k, buf);
                let r = buf.last().map_or(0.0, |x| x.1.sqrt());
                (buf.iter().map(|x| x.0).collect(), r)
            })
            .collect();
        let mut ids = Vec::with_capacity(points.len() * k);
        let mut radius = Vec::with_capacity(points.len());
        for (row, r) in rows {
            ids.extend(row);
            radius.push(r);
        }
        Neighbours { k, ids, radius }
    }

    /// Mean distance from each of `points` to its nearest other point (its second neighbour).
    pub fn mean_nearest(&self, points: &[[f32; 3]]) -> f64 {
        let n = points.len();
        let sum: f64 = (0..n)
            .map(|i| self.of(i).get(1).map_or(0.0, |&j| norm(sub(wide(points[j as usize]), wide(points[i])))))
            .sum();
        sum / n.max(1) as f64
    }

    /// The neighbours of point `i`.
    pub fn of(&self, i: usize) -> &[u32] {
        &self.ids[i * self.k..(i + 1) * self.k]
    }
}

/// Covariance eigen-decomposition of a point set: eigenvalues ascending, with their unit eigenvectors.
pub fn principal(points: impl Iterator<Item = V3> + Clone) -> ([f64; 3], [V3; 3]) {
    let (mut c, mut n) = ([0.0; 3], 0.0);
    for p in points.clone() {
        c = add(c, p);
        n += 1.0;
    }
    let c = scale(c, 1.0 / f64::max(n, 1.0));
    let mut m = Matrix3::<f64>::zeros();
    for p in points {
        let d = sub(p, c);
        for r in 0..3 {
            for s in 0..3 {
                m[(r, s)] += d[r] * d[s];
            }
        }
    }
    let e = SymmetricEigen::new(m / f64::max(n, 1.0));
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| e.eigenvalues[a].total_cmp(&e.eigenvalues[b]));
    let vals = order.map(|i| e.eigenvalues[i].max(0.0));
    let vecs = order.map(|i| {
        let v = e.eigenvectors.column(i);
        [v[0], v[1], v[2]]
    });
    (vals, vecs)
}

/// Refuse a cloud that is flat or a line: `reconstruct.degenerate` when the smallest spread of the whole
/// cloud is below [`FLAT_RATIO`] of the largest.
pub fn check_not_flat(points: &[[f32; 3]]) -> Result<()> {
    let (vals, _) = principal(points.iter().map(|&p| wide(p)));
    let what = if vals[1] <= FLAT_RATIO * vals[2] {
        "on one line"
    } else if vals[0] <= FLAT_RATIO * vals[2] {
        "in one plane"
    } else {
        return Ok(());
    };
    Err(Error::new(ErrorCode::ReconstructDegenerate, format!("all points lie {what}: they bound no solid"))
        .with_hint("scan the object from more sides"))
}

/// Smallest-to-largest variance ratio of the whole cloud below which it is flat (1e-10: a spread of 1e-5
/// of the size).
pub const FLAT_RATIO: f64 = 1e-10;

/// PCA normals (unoriented), one per point, from its neighbours.
pub fn pca_normals(points: &[[f32; 3]], nb: &Neighbours) -> Vec<V3> {
    pca_normals_and_spread(points, nb).0
}

/// PCA normals and the RMS distance of the neighbourhoods from their planes (noise plus curvature over the
/// neighbourhood: a range scan's noise level).
pub fn pca_normals_and_spread(points: &[[f32; 3]], nb: &Neighbours) -> (Vec<V3>, f64) {
    let rows: Vec<(V3, f64)> = (0..points.len())
        .into_par_iter()
        .map(|i| {
            let (vals, vecs) = principal(nb.of(i).iter().map(|&j| wide(points[j as usize])));
            (vecs[0], vals[0])
        })
        .collect();
    let spread = (rows.iter().map(|r| r.1).sum::<f64>() / rows.len().max(1) as f64).sqrt();
    (rows.into_iter().map(|r| r.0).collect(), spread)
}

/// Given normals: finite, non-zero, made unit.
///
/// # Errors
/// `input.bad-normal` naming the first bad one and how many there are.
pub fn given_normals(normals: &[[f32; 3]]) -> Result<Vec<V3>> {
    let bad: Vec<usize> = (0..normals.len())
        .filter(|&i| {
            let n = wide(normals[i]);
            !(n.iter().all(|c| c.is_finite()) && norm(n) > 1e-12)
        })
        .collect();
    if let Some(&first) = bad.first() {
        return Err(Error::new(
            ErrorCode::InputBadNormal,
            format!("{} normals are zero or not finite (the first at point {first})", bad.len()),
        )
        .with_hint("drop the normals to have them estimated"));
    }
    Ok(normals.iter().map(|&n| scale(wide(n), 1.0 / norm(wide(n)))).collect())
}

/// What orientation did.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct Orientation {
    /// Normals flipped while propagating along the spanning tree.
    pub flipped: usize,
    /// Tree edges whose normals disagree by more than 60° (|cos| < 0.5): orientation there is uncertain.
    pub uncertain: usize,
    /// Connected parts of the kNN graph (each seeded on its own).
    pub parts: usize,
    /// Whether the global flux check turned every normal over.
    pub turned_over: bool,
}

/// Orient `normals` consistently (Hoppe 1992), then outward by the flux check.
pub fn orient(points: &[[f32; 3]], normals: &mut [V3], areas: &[f64], nb: &Neighbours) -> Orientation {
    let n = points.len();
    // Symmetric adjacency (CSR) of the kNN graph.
    let mut deg = vec![0u32; n + 1];
    for i in 0..n {
        for &j in nb.of(i) {
            if j as usize != i {
                deg[i] += 1;
                deg[j as usize] += 1;
            }
        }
    }
    let mut start = vec![0u32; n + 1];
    for i in 0..n {
        start[i + 1] = start[i] + deg[i];
    }
    let mut fill = start.clone();
    let mut adj = vec![0u32; start[n] as usize];
    for i in 0..n {
        for &j in nb.of(i) {
            if j as usize != i {
                adj[fill[i] as usize] = j;
                fill[i] += 1;
                adj[fill[j as usize] as usize] = i as u32;
                fill[j as usize] += 1;
            }
        }
    }
    let mut report = Orientation::default();
    let mut visited = vec![false; n];
    // Seeds: the highest point first (its normal faces up), then any point not reached.
    let mut seeds: Vec<usize> = (0..n).collect();
    seeds.sort_by(|&a, &b| points[b][2].total_cmp(&points[a][2]).then(a.cmp(&b)));
    let mut heap = BinaryHeap::new();
    for seed in seeds {
        if visited[seed] {
            continue;
        }
        report.parts += 1;
        if normals[seed][2] < 0.0 {
            normals[seed] = scale(normals[seed], -1.0);
        }
        visited[seed] = true;
        let push = |heap: &mut BinaryHeap<_>, i: usize, normals: &[V3], visited: &[bool]| {
            for &j in &adj[start[i] as usize..start[i + 1] as usize] {
                if !visited[j as usize] {
                    let w = 1.0 - dot(normals[i], normals[j as usize]).abs();
                    heap.push(Reverse((w.max(0.0).to_bits(), j, i as u32)));
                }
            }
        };
        push(&mut heap, seed, normals, &visited);
        while let Some(Reverse((_, j, from))) = heap.pop() {
            let (j, from) = (j as usize, from as usize);
            if visited[j] {
                continue;
            }
            visited[j] = true;
            let c = dot(normals[from], normals[j]);
            if c < 0.0 {
                normals[j] = scale(normals[j], -1.0);
                report.flipped += 1;
            }
            if c.abs() < 0.5 {
                report.uncertain += 1;
            }
            push(&mut heap, j, normals, &visited);
        }
    }
    // Outward: the flux through the surface of x − c is 3 × the volume, positive for outward normals.
    let c = scale(points.iter().fold([0.0; 3], |a, &p| add(a, wide(p))), 1.0 / n as f64);
    let flux: f64 = (0..n).map(|i| areas[i] * dot(normals[i], sub(wide(points[i]), c))).sum();
    if flux < 0.0 {
        normals.iter_mut().for_each(|v| *v = scale(*v, -1.0));
        report.turned_over = true;
    }
    report
}

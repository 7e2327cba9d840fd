//! Step 6: remove spikes, then optional non-shrinking smoothing (Taubin λ|μ).
//!
//! A **spike** is a vertex farther than `SPIKE_FACTOR ×` its ring radius (mean distance of the one-ring
//! neighbours from their centroid) from the least-squares plane of those neighbours; it is moved to the ring's centroid (no topology change). Scans have
//! such outliers where a stray sample was meshed; a smooth surface or a sharp CAD corner does not come near
//! the threshold. **Taubin smoothing** alternates a shrinking step (λ) and an inflating step (μ < −λ) of the
//! uniform umbrella operator, which removes noise without the shrinkage of plain Laplacian smoothing.

use rayon::prelude::*;

use crate::geometry::linalg::smallest_eigenvector;
use crate::geometry::topology::MeshTopology;
use crate::geometry::vec3::{self, V3};

/// Distance from the ring plane, in ring radii, above which a vertex is a spike (a cube corner is at 0.6).
pub const SPIKE_FACTOR: f64 = 2.0;
/// Taubin's smoothing and inflation factors.
pub const TAUBIN_LAMBDA: f64 = 0.5;
/// Taubin's μ (the inflating step; λ is [`TAUBIN_LAMBDA`]).
pub const TAUBIN_MU: f64 = -0.53;

/// What the step changed.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct SmoothReport {
    /// Spike vertices moved to their ring centroid.
    pub spikes_removed: usize,
    /// Taubin iterations run (each one λ and one μ pass).
    pub taubin_iterations: usize,
}

/// Neighbour rows of every vertex (see [`MeshTopology::vertex_neighbours`]).
struct Neighbours {
    rows: Vec<u32>,
    cols: Vec<u32>,
}

impl Neighbours {
    fn new(n: usize, tris: &[[u32; 3]]) -> Self {
        let (rows, cols) = MeshTopology::from_triangles(tris).vertex_neighbours(n);
        Neighbours { rows, cols }
    }
    fn of(&self, v: usize) -> &[u32] {
        &self.cols[self.rows[v] as usize..self.rows[v + 1] as usize]
    }
}

/// Move spike vertices to their ring centroid; returns how many moved. All spikes are found on the
/// unmoved surface first (in parallel), then moved, so the result does not depend on vertex order.
pub fn remove_spikes(p: &mut [V3], tris: &[[u32; 3]]) -> usize {
    let nb = Neighbours::new(p.len(), tris);
    let spikes: Vec<(usize, V3)> = (0..p.len())
        .into_par_iter()
        .filter_map(|v| {
            let ring = nb.of(v);
            if ring.len() < 3 {
                return None;
            }
            let c =
                vec3::scale(ring.iter().fold([0.0; 3], |a, &u| vec3::add(a, p[u as usize])), 1.0 / ring.len() as f64);
            let mut cov = [[0.0; 3]; 3];
            let mut radius = 0.0;
            for &u in ring {
                let d = vec3::sub(p[u as usize], c);
                for i in 0..3 {
                    for j in 0..3 {
                        cov[i][j] += d[i] * d[j];
                    }
                }
                radius += vec3::norm(d);
            }
            radius /= ring.len() as f64;
            let n = smallest_eigenvector(cov);
            let height = vec3::dot(vec3::sub(p[v], c), n).abs();
            (height > SPIKE_FACTOR * radius).then_some((v, c))
        })
        .collect();
    for &(v, c) in &spikes {
        p[v] = c;
    }
    spikes.len()
}

/// `iterations` rounds of Taubin λ|μ smoothing with the uniform umbrella operator.
pub fn taubin(p: &mut [V3], tris: &[[u32; 3]], iterations: usize) {
    let nb = Neighbours::new(p.len(), tris);
    let mut delta = vec![[0.0; 3]; p.len()];
    for _ in 0..iterations {
        for factor in [TAUBIN_LAMBDA, TAUBIN_MU] {
            for (v, d) in delta.iter_mut().enumerate() {
                let ring = nb.of(v);
                *d = if ring.is_empty() {
                    [0.0; 3]
                } else {
                    let c = vec3::scale(
                        ring.iter().fold([0.0; 3], |a, &u| vec3::add(a, p[u as usize])),
                        1.0 / ring.len() as f64,
                    );
                    vec3::scale(vec3::sub(c, p[v]), factor)
                };
            }
            for (q, d) in p.iter_mut().zip(&delta) {
                *q = vec3::add(*q, *d);
            }
        }
    }
}

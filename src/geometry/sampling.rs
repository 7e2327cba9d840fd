//! Deterministic random numbers and area-uniform surface sampling.

use crate::geometry::mesh::TriMesh;
use crate::geometry::vec3::{V3, add, scale};

/// SplitMix64: a small, fast, well-mixed generator. Deterministic for a seed on every platform, which is
/// all the sampling needs (no cryptographic use).
#[derive(Clone, Debug)]
pub struct Rng(u64);

impl Rng {
    /// A generator from a seed.
    pub fn new(seed: u64) -> Self {
        Rng(seed)
    }
    /// Next 64 random bits.
    #[inline]
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1) with 53 random bits.
    #[inline]
    pub fn next_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }
}

/// FNV-1a over bytes: a cheap content hash to derive per-surface sampling seeds.
pub fn fnv1a(bytes: impl IntoIterator<Item = u8>, seed: u64) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64 ^ seed;
    for b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

/// A sample point on a mesh.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct SurfaceSample {
    /// Position.
    pub point: V3,
    /// Triangle it lies on.
    pub triangle: u32,
}

/// `n` points uniformly distributed by area on `mesh`, **stratified**: sample k is drawn at area coordinate
/// (k + u)/n of the running area sum, with u uniform in [0, 1), then uniformly inside its triangle. Each
/// sample is still uniform over the surface but the set has far less clumping than independent draws, and it
/// comes out ordered by triangle, which keeps closest-point queries cache-friendly.
///
/// Returns an empty vector when the mesh has no area. Cost: O(F + n).
pub fn sample_area_uniform(mesh: &TriMesh, n: usize, rng: &mut Rng) -> Vec<SurfaceSample> {
    let areas: Vec<f64> = (0..mesh.triangles.len()).map(|t| mesh.triangle_area(t)).collect();
    let total: f64 = areas.iter().sum();
    if !(total > 0.0) || n == 0 {
        return Vec::new();
    }
    let mut out = Vec::with_capacity(n);
    let mut t = 0usize;
    let mut acc = areas[0];
    for k in 0..n {
        let target = (k as f64 + rng.next_f64()) / n as f64 * total;
        while acc < target && t + 1 < areas.len() {
            t += 1;
            acc += areas[t];
        }
        // Skip zero-area triangles that the running sum may land on at a boundary.
        while areas[t] == 0.0 && t + 1 < areas.len() {
            t += 1;
            acc += areas[t];
        }
        let [a, b, c] = mesh.corners(t);
        let r1 = rng.next_f64().sqrt();
        let r2 = rng.next_f64();
        let p = add(add(scale(a, 1.0 - r1), scale(b, r1 * (1.0 - r2))), scale(c, r1 * r2));
        out.push(SurfaceSample { point: p, triangle: t as u32 });
    }
    out
}

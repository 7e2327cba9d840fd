//! A uniform-grid index over a point set for k-nearest-neighbour and radius queries: points sorted by cell,
//! a hash map from cell to its run. Deterministic (ties broken by index); queries are independent, so they
//! run in parallel.

use std::collections::HashMap;

use crate::geometry::vec3::{Aabb, V3, norm2, sub, wide};

/// The index. Cost: O(n log n) to build, memory 4 bytes per point plus 16 per occupied cell.
pub struct PointIndex<'a> {
    points: &'a [[f32; 3]],
    bbox: Aabb,
    origin: V3,
    cell: f64,
    /// Point indices sorted by cell key.
    order: Vec<u32>,
    /// Cell key → `order[start..end]`.
    cells: HashMap<u64, (u32, u32)>,
}

/// Pack integer cell coordinates (21 bits each) into one key.
fn key(c: [i64; 3]) -> u64 {
    let m = (1u64 << 21) - 1;
    ((c[0] as u64) & m) | (((c[1] as u64) & m) << 21) | (((c[2] as u64) & m) << 42)
}

impl<'a> PointIndex<'a> {
    /// Index `points` with about `per_cell` points per occupied cell on a surface-like set (cell side
    /// `diagonal · sqrt(per_cell / n)`).
    pub fn new(points: &'a [[f32; 3]], per_cell: f64) -> PointIndex<'a> {
        let bbox = Aabb::of_points(points);
        let n = points.len().max(1) as f64;
        let diag = bbox.diagonal().max(f64::MIN_POSITIVE);
        // At most 2^20 cells per axis, so keys never collide.
        let cell = (diag * (per_cell / n).sqrt()).max(diag / (1u64 << 20) as f64);
        let origin = if bbox.is_empty() { [0.0; 3] } else { bbox.min };
        let mut keyed: Vec<(u64, u32)> =
            (0..points.len()).map(|i| (key(Self::coords(origin, cell, wide(points[i]))), i as u32)).collect();
        keyed.sort_unstable();
        let mut cells = HashMap::with_capacity(keyed.len() / per_cell.max(1.0) as usize + 1);
        let mut start = 0;
        for i in 1..=keyed.len() {
            if i == keyed.len() || keyed[i].0 != keyed[start].0 {
                cells.insert(keyed[start].0, (start as u32, i as u32));
                start = i;
            }
        }
        PointIndex { points, bbox, origin, cell, order: keyed.into_iter().map(|k| k.1).collect(), cells }
    }

    fn coords(origin: V3, cell: f64, p: V3) -> [i64; 3] {
        [0, 1, 2].map(|k| ((p[k] - origin[k]) / cell).floor() as i64)
    }

    /// Cell side.
    pub fn cell_size(&self) -> f64 {
        self.cell
    }

    /// The points of the cell at integer coordinates `c`.
    fn cell_points(&self, c: [i64; 3]) -> &[u32] {
        if c.iter().any(|&x| !(0..(1 << 21)).contains(&x)) {
            return &[];
        }
        match self.cells.get(&key(c)) {
            Some(&(s, e)) => &self.order[s as usize..e as usize],
            None => &[],
        }
    }

    /// The `k` points nearest to `p` (itself included when `p` is a point of the set), nearest first, as
    /// (index, squared distance); fewer when the set is smaller. Ties go to the lower index.
    pub fn knn(&self, p: V3, k: usize, out: &mut Vec<(u32, f64)>) {
        out.clear();
        if k == 0 || self.points.is_empty() {
            return;
        }
        let c = Self::coords(self.origin, self.cell, p);
        let last = self.last_ring(p);
        let mut ring = 0i64;
        loop {
            self.visit_ring(c, ring, |i| {
                let d = norm2(sub(wide(self.points[i as usize]), p));
                if out.len() < k || (d, i) < (out[out.len() - 1].1, out[out.len() - 1].0) {
                    let at = out.partition_point(|&(j, dj)| (dj, j) < (d, i));
                    out.insert(at, (i, d));
                    out.truncate(k);
                }
            });
            // Points beyond this ring are at least `ring · cell` away.
            let reach = ring as f64 * self.cell;
            if out.len() == k && out[k - 1].1 <= reach * reach || ring >= last {
                return;
            }
            ring += 1;
        }
    }

    /// A ring beyond which no indexed point lies, seen from `p`.
    fn last_ring(&self, p: V3) -> i64 {
        let out: f64 =
            (0..3).map(|k| (self.bbox.min[k] - p[k]).max(p[k] - self.bbox.max[k]).max(0.0).powi(2)).sum::<f64>().sqrt();
        ((out + self.bbox.diagonal()) / self.cell).ceil() as i64 + 1
    }

    /// Call `f` for every point in the cells at Chebyshev distance exactly `ring` from cell `c`.
    fn visit_ring(&self, c: [i64; 3], ring: i64, mut f: impl FnMut(u32)) {
        for dz in -ring..=ring {
            for dy in -ring..=ring {
                let edge = dz.abs() == ring || dy.abs() == ring;
                let mut dx = -ring;
                while dx <= ring {
                    for &i in self.cell_points([c[0] + dx, c[1] + dy, c[2] + dz]) {
                        f(i);
                    }
                    // Inside the shell only the two x-faces belong to this ring.
                    dx += if edge || ring == 0 || dx == ring { 1 } else { 2 * ring };
                }
            }
        }
    }

    /// Squared distance from `p` to the nearest indexed point within `radius` (None beyond it).
    pub fn nearest_within(&self, p: V3, radius: f64) -> Option<(u32, f64)> {
        let c = Self::coords(self.origin, self.cell, p);
        let rings = ((radius / self.cell).ceil() as i64 + 1).min(self.last_ring(p));
        let mut best: Option<(u32, f64)> = None;
        for ring in 0..=rings {
            self.visit_ring(c, ring, |i| {
                let d = norm2(sub(wide(self.points[i as usize]), p));
                if d <= radius * radius && best.is_none_or(|(j, bd)| (d, i) < (bd, j)) {
                    best = Some((i, d));
                }
            });
            if let Some((_, d)) = best
                && d <= (ring as f64 * self.cell).powi(2)
            {
                break;
            }
        }
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn brute(points: &[[f32; 3]], p: V3, k: usize) -> Vec<u32> {
        let mut all: Vec<(f64, u32)> = (0..points.len()).map(|i| (norm2(sub(wide(points[i]), p)), i as u32)).collect();
        all.sort_by(|a, b| a.partial_cmp(b).unwrap());
        all.into_iter().take(k).map(|x| x.1).collect()
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(32))]
        /// kNN equals brute force (same indices, same order) for random sets and queries, any cell size.
        #[test]
        fn knn_matches_brute_force(seed in 0u64..1000, n in 1usize..400, k in 1usize..20, per_cell in 0.5f64..20.0) {
            let mut s = seed.wrapping_mul(2654435761).wrapping_add(1);
            let mut r = || { s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407); ((s >> 40) as f64 / (1u64 << 24) as f64) as f32 };
            let pts: Vec<[f32; 3]> = (0..n).map(|_| [r(), r() * 0.5, r() * 0.01]).collect();
            let idx = PointIndex::new(&pts, per_cell);
            let mut out = Vec::new();
            for q in 0..10 {
                let p = [r() as f64 * 1.4 - 0.2, r() as f64, r() as f64 * 0.3];
                idx.knn(p, k, &mut out);
                let got: Vec<u32> = out.iter().map(|x| x.0).collect();
                proptest::prop_assert_eq!(&got, &brute(&pts, p, k), "query {}", q);
                let near = idx.nearest_within(p, 0.3);
                let b = brute(&pts, p, 1)[0];
                let bd = norm2(sub(wide(pts[b as usize]), p));
                proptest::prop_assert_eq!(near.map(|x| x.0), (bd <= 0.09).then_some(b));
            }
        }
    }
}

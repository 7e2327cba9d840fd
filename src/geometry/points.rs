//! A uniform-grid index over a point set for k-nearest-neighbour and radius queries: points sorted by cell,
//! a hash map from cell to its run. Deterministic (ties broken by index); queries are independent, so they
//! run in parallel.

use crate::geometry::cellhash::CellMap;
use crate::geometry::vec3::{Aabb, V3, norm2, sub, wide};

/// The index. Cost: O(n log n) to build, memory 4 bytes per point plus 16 per occupied cell.
pub struct PointIndex<'a> {
    points: &'a [[f32; 3]],
    origin: V3,
    cell: f64,
    /// The highest occupied cell coordinate per axis (cells run from 0).
    top: [i64; 3],
    /// Point indices sorted by cell key.
    order: Vec<u32>,
    /// Cell key → `order[start..end]`.
    cells: CellMap<(u32, u32)>,
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
        let diag = bbox.diagonal();
        // At most 2^20 cells per axis, so keys never collide; a set of one repeated point (diagonal 0) is
        // one cell of any size.
        let cell = if diag > 0.0 { (diag * (per_cell / n).sqrt()).max(diag / (1u64 << 20) as f64) } else { 1.0 };
        let origin = if bbox.is_empty() { [0.0; 3] } else { bbox.min };
        let top = if bbox.is_empty() { [0; 3] } else { Self::coords(origin, cell, bbox.max) };
        let mut keyed: Vec<(u64, u32)> =
            (0..points.len()).map(|i| (key(Self::coords(origin, cell, wide(points[i]))), i as u32)).collect();
        keyed.sort_unstable();
        let mut cells =
            CellMap::with_capacity_and_hasher(keyed.len() / per_cell.max(1.0) as usize + 1, Default::default());
        let mut start = 0;
        for i in 1..=keyed.len() {
            if i == keyed.len() || keyed[i].0 != keyed[start].0 {
                cells.insert(keyed[start].0, (start as u32, i as u32));
                start = i;
            }
        }
        PointIndex { points, origin, cell, top, order: keyed.into_iter().map(|k| k.1).collect(), cells }
    }

    /// Integer cell coordinates of `p`, clamped to ±2^40 so that ring arithmetic never overflows (a query
    /// that far out sees every point from its clamped cell in the same order: the rings only bound the search).
    fn coords(origin: V3, cell: f64, p: V3) -> [i64; 3] {
        const FAR: f64 = (1u64 << 40) as f64;
        [0, 1, 2].map(|k| ((p[k] - origin[k]) / cell).floor().clamp(-FAR, FAR) as i64)
    }

    /// The rings (Chebyshev distances in cells from `c`) that can hold points: from the grid's nearest cell
    /// to its farthest.
    fn rings(&self, c: [i64; 3]) -> (i64, i64) {
        let first = (0..3).map(|k| (-c[k]).max(c[k] - self.top[k]).max(0)).max().unwrap_or(0);
        let last = (0..3).map(|k| c[k].abs().max((self.top[k] - c[k]).abs())).max().unwrap_or(0);
        (first, last)
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
        self.knn_near(p, k, f64::INFINITY, out);
    }

    /// [`Self::knn`] if some point lies within `radius` of `p` (returns true); otherwise false, with the
    /// search stopped at the rings that can hold such a point (a query far from every point costs no more
    /// than a [`Self::nearest_within`]).
    pub fn knn_near(&self, p: V3, k: usize, radius: f64, out: &mut Vec<(u32, f64)>) -> bool {
        out.clear();
        if k == 0 || self.points.is_empty() {
            return false;
        }
        let c = Self::coords(self.origin, self.cell, p);
        let (mut ring, last) = self.rings(c);
        let decide = (radius / self.cell).ceil().min((1u64 << 42) as f64) as i64 + 1;
        loop {
            self.visit_ring(c, ring, |i| {
                let d = norm2(sub(wide(self.points[i as usize]), p));
                if out.len() < k || (d, i) < (out[out.len() - 1].1, out[out.len() - 1].0) {
                    let at = out.partition_point(|&(j, dj)| (dj, j) < (d, i));
                    out.insert(at, (i, d));
                    out.truncate(k);
                }
            });
            // Points beyond this ring lie outside its cube of cells: at least `reach` away.
            let reach = self.beyond(c, ring, p);
            let near = |out: &Vec<(u32, f64)>| out.first().is_some_and(|f| f.1 <= radius * radius);
            if out.len() == k && out[k - 1].1 <= reach * reach || ring >= last {
                return near(out);
            }
            // Every point within `radius` lies in the rings up to `decide`.
            if ring >= decide && !near(out) {
                out.clear();
                return false;
            }
            ring += 1;
        }
    }

    /// Distance from `p` (in cell `c`) to the outside of the cube of cells within Chebyshev distance `ring`
    /// of `c`: no point beyond that ring is nearer. At least `ring · cell`.
    #[inline]
    fn beyond(&self, c: [i64; 3], ring: i64, p: V3) -> f64 {
        (0..3)
            .map(|a| {
                let lo = self.origin[a] + (c[a] - ring) as f64 * self.cell;
                let hi = self.origin[a] + (c[a] + ring + 1) as f64 * self.cell;
                (p[a] - lo).min(hi - p[a])
            })
            .fold(f64::INFINITY, f64::min)
            .max(ring as f64 * self.cell)
    }

    /// Call `f` for every point in the cells at Chebyshev distance exactly `ring` from cell `c`. Only cells
    /// inside the grid are visited, so a ring costs at most one slab of the grid however far out `c` lies.
    fn visit_ring(&self, c: [i64; 3], ring: i64, mut f: impl FnMut(u32)) {
        let span = |k: usize| ((c[k] - ring).max(0), (c[k] + ring).min(self.top[k]));
        let ((z0, z1), (y0, y1), (x0, x1)) = (span(2), span(1), span(0));
        for z in z0..=z1 {
            for y in y0..=y1 {
                if (z - c[2]).abs() == ring || (y - c[1]).abs() == ring {
                    for x in x0..=x1 {
                        self.cell_points([x, y, z]).iter().for_each(|&i| f(i));
                    }
                } else {
                    // Inside the shell (ring > 0 here) only the two x-faces belong to this ring.
                    for x in [c[0] - ring, c[0] + ring] {
                        if (x0..=x1).contains(&x) {
                            self.cell_points([x, y, z]).iter().for_each(|&i| f(i));
                        }
                    }
                }
            }
        }
    }

    /// Squared distance from `p` to the nearest indexed point within `radius` (None beyond it).
    pub fn nearest_within(&self, p: V3, radius: f64) -> Option<(u32, f64)> {
        let c = Self::coords(self.origin, self.cell, p);
        let (first, last) = self.rings(c);
        let reach = (radius / self.cell).ceil().min((1u64 << 42) as f64) as i64 + 1;
        let mut best: Option<(u32, f64)> = None;
        for ring in first..=last.min(reach) {
            self.visit_ring(c, ring, |i| {
                let d = norm2(sub(wide(self.points[i as usize]), p));
                if d <= radius * radius && best.is_none_or(|(j, bd)| (d, i) < (bd, j)) {
                    best = Some((i, d));
                }
            });
            if let Some((_, d)) = best
                && d <= self.beyond(c, ring, p).powi(2)
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

    /// CI regression (proptest, 2026-12-05: `seed = 0, n = 1, k = 1, per_cell = 0.5`): a set of one point has a
    /// zero diagonal, the cell came out at `f64::MIN_POSITIVE` and the last ring overflowed `i64`.
    #[test]
    fn one_point_and_repeated_points_answer_every_query() {
        for pts in [vec![[0.25f32, 0.5, 0.75]], vec![[1.0f32, 1.0, 1.0]; 50]] {
            for per_cell in [0.5, 16.0] {
                let idx = PointIndex::new(&pts, per_cell);
                let mut out = Vec::new();
                for p in [[0.25, 0.5, 0.75], [0.0, 0.0, 0.0], [1e12, -1e12, 3.0], [f64::MAX, 0.0, f64::MIN]] {
                    idx.knn(p, 3, &mut out);
                    assert_eq!(
                        out.iter().map(|x| x.0).collect::<Vec<_>>(),
                        brute(&pts, p, 3),
                        "{} points, query {p:?}",
                        pts.len()
                    );
                    let near = idx.nearest_within(p, 1.0);
                    let b = brute(&pts, p, 1)[0];
                    assert_eq!(
                        near.map(|x| x.0),
                        (norm2(sub(wide(pts[b as usize]), p)) <= 1.0).then_some(b),
                        "query {p:?}"
                    );
                }
            }
        }
    }

    /// A query a million diagonals away costs one pass over the grid, not a million empty rings.
    #[test]
    fn a_far_query_finds_the_nearest_points() {
        let pts: Vec<[f32; 3]> =
            (0..1000).map(|i| [(i % 10) as f32, ((i / 10) % 10) as f32, (i / 100) as f32]).collect();
        let idx = PointIndex::new(&pts, 4.0);
        let mut out = Vec::new();
        for p in [[1e7, 4.5, 4.5], [-3e6, -3e6, -3e6], [4.5, 4.5, 1e9]] {
            idx.knn(p, 5, &mut out);
            assert_eq!(out.iter().map(|x| x.0).collect::<Vec<_>>(), brute(&pts, p, 5), "query {p:?}");
            assert_eq!(idx.nearest_within(p, 10.0), None, "query {p:?}");
        }
    }
}

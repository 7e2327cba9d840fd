//! Thinning a cloud larger than the memory budget allows: the points of each cubic cell are merged into one.
//!
//! The grid cannot resolve detail finer than a fraction of its own cell, so a cloud of ten million points on a
//! 200-node grid carries far more points than the solve can use. When the points do not fit the budget beside
//! the grid, [`thin`] merges the points of each cell of side `cell` (a quarter of the grid's cell first, then
//! coarser until the count fits): the mean position, and for oriented clouds the normalised sum of the normals.
//! Points whose normals face opposite ways (the two sides of a wall thinner than a cell) go to different
//! merged points: the cell key includes the signed axis the normal points along most. Averaging also lowers
//! the noise, by √(points per cell).
//!
//! Sequential over the input order, so the result is the same on any number of threads. Cost: O(n) hash
//! inserts per attempt, at most [`MAX_ATTEMPTS`] attempts; memory O(merged points).

use crate::geometry::cellhash::CellMap;
use crate::geometry::mesh::PointCloud;

/// Cell sizes tried, each twice the last, before giving up.
pub const MAX_ATTEMPTS: usize = 6;

/// What thinning did (reported by [`super::reconstruct`]).
#[derive(Clone, Debug, serde::Serialize)]
pub struct Thinning {
    /// Points of the input.
    pub points_before: usize,
    /// Merged points the reconstruction used.
    pub points_after: usize,
    /// Side of the merging cells (model units).
    pub cell: f64,
    /// Why: the most points the budget left room for beside the grid.
    pub max_points: usize,
}

/// Sums of one cell's points.
#[derive(Clone, Copy, Default)]
struct Acc {
    position: [f64; 3],
    normal: [f64; 3],
    count: u32,
}

/// Merge the points of `cloud` per cubic cell, starting at side `cell` and doubling it until at most
/// `max_points` remain. Colours are dropped. `None` when even `cell · 2^(MAX_ATTEMPTS−1)` leaves too many.
pub fn thin(cloud: &PointCloud, cell: f64, max_points: usize) -> Option<(PointCloud, Thinning)> {
    let bbox = cloud.bbox();
    let mut side = cell;
    for _ in 0..MAX_ATTEMPTS {
        if let Some(merged) = merge(cloud, bbox.min, side, max_points) {
            let report = Thinning {
                points_before: cloud.positions.len(),
                points_after: merged.positions.len(),
                cell: side,
                max_points,
            };
            return Some((merged, report));
        }
        side *= 2.0;
    }
    None
}

/// One attempt at side `side`: `None` as soon as more than `max_points` cells are occupied.
fn merge(cloud: &PointCloud, origin: [f64; 3], side: f64, max_points: usize) -> Option<PointCloud> {
    let mut cells: CellMap<Acc> = CellMap::default();
    for (i, p) in cloud.positions.iter().enumerate() {
        let normal = cloud.normals.as_ref().map(|n| n[i]);
        let key = cell_key(*p, origin, side, normal);
        let acc = cells.entry(key).or_default();
        for a in 0..3 {
            acc.position[a] += p[a] as f64;
            if let Some(n) = normal {
                acc.normal[a] += n[a] as f64;
            }
        }
        acc.count += 1;
        if cells.len() > max_points {
            return None;
        }
    }
    // Sorted by key: the output order does not depend on the hash map's.
    let mut cells: Vec<(u64, Acc)> = cells.into_iter().collect();
    cells.sort_unstable_by_key(|c| c.0);
    let positions = cells.iter().map(|(_, a)| a.position.map(|s| (s / a.count as f64) as f32)).collect();
    let normals = cloud.normals.as_ref().map(|_| {
        cells
            .iter()
            .map(|(_, a)| {
                // Same-hemisphere normals (by the key) cannot cancel: the length is at least 1/√3 per point.
                let len = (a.normal.iter().map(|c| c * c).sum::<f64>()).sqrt().max(f64::MIN_POSITIVE);
                a.normal.map(|c| (c / len) as f32)
            })
            .collect()
    });
    Some(PointCloud { positions, normals, colors: None })
}

/// The key of `p`'s cell: 3 × 20 bits of cell coordinates and 3 bits for the normal's dominant signed axis.
fn cell_key(p: [f32; 3], origin: [f64; 3], side: f64, normal: Option<[f32; 3]>) -> u64 {
    let c = [0, 1, 2].map(|a| (((p[a] as f64 - origin[a]) / side).floor().max(0.0) as u64).min((1 << 20) - 1));
    let dir = normal.map_or(0, |n| {
        let a = (0..3).max_by(|&x, &y| n[x].abs().total_cmp(&n[y].abs())).unwrap_or(0) as u64;
        1 + 2 * a + u64::from(n[a as usize] < 0.0)
    });
    (dir << 60) | (c[2] << 40) | (c[1] << 20) | c[0]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plate(n: usize) -> PointCloud {
        // Two sides of a plate 0.001 thick, normals ±z, n × n points each on the unit square.
        let mut positions = Vec::new();
        let mut normals = Vec::new();
        for side in [0.0f32, 0.001] {
            for i in 0..n {
                for j in 0..n {
                    positions.push([i as f32 / n as f32, j as f32 / n as f32, side]);
                    normals.push([0.0, 0.0, if side == 0.0 { -1.0 } else { 1.0 }]);
                }
            }
        }
        PointCloud::new(positions, Some(normals), None).unwrap()
    }

    #[test]
    fn opposite_normals_in_one_cell_stay_apart_and_counts_fit() {
        let cloud = plate(100);
        // Cells of 0.0499 (not 0.05, whose borders would fall on points): 5 × 5 points each.
        let (thin, report) = thin(&cloud, 0.0499, 1000).expect("fits");
        // 20 × 20 cells per side, each side its own merged points.
        assert_eq!(thin.positions.len(), 800, "{report:?}");
        assert_eq!(report.cell, 0.0499);
        let normals = thin.normals.as_ref().unwrap();
        assert_eq!(normals.iter().filter(|n| n[2] == 1.0).count(), 400);
        assert_eq!(normals.iter().filter(|n| n[2] == -1.0).count(), 400);
        // Each merged point is the mean of its 5 × 5 points: x = 0.05 k + 0.02.
        for p in &thin.positions {
            let f = [0, 1].map(|a| ((p[a] as f64 - 0.02) / 0.05 + 0.5).fract() - 0.5);
            assert!(f.iter().all(|f| f.abs() < 1e-4), "{p:?} is {f:?} cells off a mean");
        }
    }

    #[test]
    fn the_cell_doubles_until_the_count_fits_or_gives_up() {
        let cloud = plate(100);
        let (thin, report) = thin(&cloud, 0.0499, 300).expect("fits at 0.0998");
        assert_eq!((report.cell, thin.positions.len()), (0.0998, 200));
        assert!(super::thin(&cloud, 0.0499, 1).is_none(), "two sides never fit in one point");
    }
}

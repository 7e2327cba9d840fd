//! The far tail of the scan → solid distance: what the `max-distance` gate judges ([`super::gates`]).
//!
//! The chain's comparison of the solid with the scan ([`crate::stages::quality::compare`]) already takes
//! the largest scan → solid distance over the scan's area samples, every scan vertex and the farthest
//! point inside the triangles of the farthest samples. This adds what a person needs to act on it: where
//! the farthest scan points are, how many scan vertices lie beyond the bound, and which scan vertices repair
//! itself left farther than the bound from its result (debris it dropped, spikes it flattened): those are
//! reported, not judged, since no solid made from the repaired mesh is meant to follow them.
//!
//! Cost: one BVH of the solid's mesh and one closest-point query per scan vertex (the dragon: 435k queries
//! against 1.5M triangles); a BVH of the repaired mesh and as many queries again only when repair moved
//! some part of the scan by more than the goal (the repair report's scan → result maximum says so).

use rayon::prelude::*;

use super::gates::FAR_TAIL_GOAL_GOALS;
use crate::geometry::bvh::TriangleBvh;
use crate::geometry::mesh::{Geometry, PolyMesh, TriMesh};
use crate::geometry::vec3::{V3, norm, sub, wide};
use crate::stages::repair::RepairReport;

/// The far tail of the scan → solid distance, as the `max-distance` gate judges it ([`Measured::max_distance_pct`]).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct FarTail {
    /// The largest distance from the scan repair kept to the solid, % of the diagonal.
    pub max_pct: f64,
    /// Where it is: the scan point farthest from the solid (input units).
    pub at: [f64; 3],
    /// The far-tail goal: [`FAR_TAIL_GOAL_GOALS`](super::gates::FAR_TAIL_GOAL_GOALS) × the RMS goal, % of the diagonal.
    pub goal_pct: f64,
    /// Scan vertices farther from the solid than the goal (of those repair kept).
    pub vertices_beyond_goal: usize,
    /// Up to [`FAR_TAIL_PLACES`] places where the scan lies beyond the goal, farthest first, at least
    /// [`PLACE_SEPARATION_REL`] of the diagonal apart (input units).
    pub places: Vec<[f64; 3]>,
    /// Scan vertices repair left farther than the goal from its own result (debris dropped, spikes
    /// flattened, the sides of a handle it cut): not judged by the gate.
    pub dropped_by_repair: usize,
    /// The largest distance of those to the solid, % of the diagonal (0 when none).
    pub dropped_max_pct: f64,
}

/// Places of the far tail a report keeps ([`FarTail::places`]).
pub const FAR_TAIL_PLACES: usize = 8;

/// Places of the far tail closer than this share of the diagonal to a farther one are the same place.
pub const PLACE_SEPARATION_REL: f64 = 0.05;

/// The far tail of a conversion's solid: `scan` is the input as read, the repaired mesh and repair's report;
/// `solid` the solid's welded mesh; `sampled_max` the chain's scan → solid maximum (input units); the goal
/// is [`FAR_TAIL_GOAL_GOALS`] × `rms_goal_pct`.
pub(super) fn measure(
    (scan, repaired, repair): (&Geometry, &TriMesh, &RepairReport),
    solid: &PolyMesh,
    sampled_max: f64,
    rms_goal_pct: f64,
    diag: f64,
) -> FarTail {
    let goal = FAR_TAIL_GOAL_GOALS * rms_goal_pct / 100.0 * diag;
    let repair_max = repair.distance.reference_to_test.max.value;
    far_tail(scan, &solid.triangulate().0, repaired, (sampled_max, repair_max), goal, diag)
}

/// The far tail of `scan` against `solid` (its welded mesh). `sampled_max` is the comparison's scan → solid
/// maximum (input units); `repair_max` the repair report's scan → repaired maximum; `goal` the far-tail goal
/// (input units); `diag` the scan's diagonal.
pub(super) fn far_tail(
    scan: &Geometry,
    solid: &TriMesh,
    repaired: &TriMesh,
    (sampled_max, repair_max): (f64, f64),
    goal: f64,
    diag: f64,
) -> FarTail {
    // 1. The scan's points: a mesh's referenced vertices, a cloud's points.
    let points = scan_points(scan);
    // 2. Those repair left beyond the goal (only looked for when its own maximum says there are any).
    let dropped: Vec<bool> = if repair_max > goal && matches!(scan, Geometry::Mesh(_)) {
        let bvh = TriangleBvh::new(repaired);
        points.par_iter().map(|&p| bvh.distance(p) > goal).collect()
    } else {
        vec![false; points.len()]
    };
    // 3. Every point's distance to the solid.
    let bvh = TriangleBvh::new(solid);
    let d: Vec<f64> = points.par_iter().map(|&p| bvh.distance(p)).collect();
    let pct = |x: f64| if diag > 0.0 { 100.0 * x / diag } else { 0.0 };
    let kept = || (0..points.len()).filter(|&i| !dropped[i]);
    let dropped_max = (0..points.len()).filter(|&i| dropped[i]).map(|i| d[i]).fold(0.0, f64::max);
    let dropped_count = dropped.iter().filter(|&&x| x).count();
    // 4. The gate's value: with nothing dropped, the comparison's maximum (samples and inside triangles
    // too); otherwise the kept vertices' (the comparison's may be a dropped vertex's).
    let far = kept().max_by(|&a, &b| d[a].total_cmp(&d[b]).then(b.cmp(&a)));
    let vertex_max = far.map_or(0.0, |i| d[i]);
    let max = if dropped_count == 0 { sampled_max.max(vertex_max) } else { vertex_max };
    // 5. Where: the farthest kept points beyond the goal, one per place.
    let mut beyond: Vec<usize> = kept().filter(|&i| d[i] > goal).collect();
    beyond.sort_by(|&a, &b| d[b].total_cmp(&d[a]).then(a.cmp(&b)));
    let mut places: Vec<V3> = Vec::new();
    for &i in &beyond {
        if places.len() == FAR_TAIL_PLACES {
            break;
        }
        if places.iter().all(|&q| norm(sub(q, points[i])) > PLACE_SEPARATION_REL * diag) {
            places.push(points[i]);
        }
    }
    FarTail {
        max_pct: pct(max),
        at: far.map_or([0.0; 3], |i| points[i]),
        goal_pct: pct(goal),
        vertices_beyond_goal: beyond.len(),
        places,
        dropped_by_repair: dropped_count,
        dropped_max_pct: pct(dropped_max),
    }
}

fn scan_points(scan: &Geometry) -> Vec<V3> {
    match scan {
        Geometry::Mesh(m) => {
            let mut used = vec![false; m.positions.len()];
            m.faces().flatten().for_each(|&i| used[i as usize] = true);
            m.positions.iter().zip(&used).filter(|(_, u)| **u).map(|(p, _)| wide(*p)).collect()
        }
        Geometry::Cloud(c) => c.positions.iter().map(|&p| wide(p)).collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::shapes::{cuboid, icosphere};

    /// A unit ball measured against a ball of radius 0.9: every scan vertex is 0.1 away (0.1 / 2 = 5 % of the
    /// ball's diagonal 2√3 ≈ 3.46: 2.89 %), all beyond a 1 % goal, one place per 5 % of the diagonal.
    #[test]
    fn a_shrunken_solid_is_far_everywhere_and_every_vertex_counts() {
        let scan = icosphere(1.0, 3, [0.0; 3]);
        let solid = icosphere(0.9, 4, [0.0; 3]);
        let diag = scan.bbox().diagonal();
        let t = far_tail(&Geometry::Mesh(PolyMesh::from(scan.clone())), &solid, &scan, (0.0, 0.0), 0.01 * diag, diag);
        assert!((t.max_pct - 100.0 * 0.1 / diag).abs() < 0.2, "{t:?}");
        assert_eq!(t.vertices_beyond_goal, scan.positions.len(), "{t:?}");
        assert_eq!(t.places.len(), FAR_TAIL_PLACES, "{t:?}");
        assert_eq!(t.dropped_by_repair, 0);
    }

    /// A box with a far speck of debris that repair dropped: the speck is counted as dropped and its distance
    /// reported, and the gate's maximum is the box's own (0 here), not the speck's.
    #[test]
    fn debris_repair_dropped_is_reported_not_judged() {
        let body = cuboid([0.0; 3], [1.0; 3]);
        let speck = cuboid([3.0; 3], [3.01; 3]);
        let mut scan = body.clone();
        let n = scan.positions.len() as u32;
        scan.positions.extend(&speck.positions);
        scan.triangles.extend(speck.triangles.iter().map(|t| t.map(|i| i + n)));
        let diag = scan.bbox().diagonal();
        let g = Geometry::Mesh(PolyMesh::from(scan));
        let t = far_tail(&g, &body, &body, (3.4, 3.4), 0.002 * diag, diag);
        assert_eq!(t.dropped_by_repair, 8, "{t:?}");
        assert!(t.dropped_max_pct > 50.0, "{t:?}");
        assert!(t.max_pct < 1e-6, "{t:?}");
        assert_eq!(t.vertices_beyond_goal, 0);
        assert!(t.places.is_empty());
    }
}

//! Self-intersection detection: the triangle–triangle test on cases with known answers, the BVH search
//! against brute force, and repair removing intersections (checked by brute force).

use proptest::prelude::*;
use scanstation::geometry::intersect::{self_intersections, self_intersections_brute_force, triangles_intersect};
use scanstation::geometry::shapes::icosphere;
use scanstation::stages::NoProgress;
use scanstation::stages::repair::{RepairOptions, repair};
use scanstation::{PolyMesh, TriMesh};

#[test]
fn triangle_pairs_with_known_answers() {
    let t = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    let piercing = [[0.2, 0.2, -1.0], [0.3, 0.2, 1.0], [0.2, 0.3, 1.0]];
    let above = [[0.2, 0.2, 0.5], [0.3, 0.2, 1.0], [0.2, 0.3, 1.0]];
    let coplanar_overlap = [[0.1, 0.1, 0.0], [2.0, 0.1, 0.0], [0.1, 2.0, 0.0]];
    let coplanar_apart = [[2.0, 2.0, 0.0], [3.0, 2.0, 0.0], [2.0, 3.0, 0.0]];
    let beside = [[2.0, 0.0, -1.0], [2.0, 0.0, 1.0], [2.0, 1.0, 0.0]];
    assert!(triangles_intersect(&t, &piercing));
    assert!(!triangles_intersect(&t, &above));
    assert!(triangles_intersect(&t, &coplanar_overlap));
    assert!(!triangles_intersect(&t, &coplanar_apart));
    assert!(!triangles_intersect(&t, &beside));
}

#[test]
fn mesh_neighbours_do_not_count_but_piercing_neighbours_do() {
    // Two faces sharing an edge: never an intersection.
    let p = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.3]];
    let tris = vec![[0, 1, 2], [1, 3, 2]];
    assert!(self_intersections_brute_force(&p, &tris).is_empty());
    // Sharing one vertex, the other's opposite edge crossing through: an intersection.
    let p = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.6, 0.2, -0.5], [0.2, 0.6, 0.5]];
    let tris = vec![[0, 1, 2], [0, 3, 4]];
    assert_eq!(self_intersections_brute_force(&p, &tris), vec![(0, 1)]);
}

fn sphere_with_vertex_pushed_through() -> TriMesh {
    let mut m = icosphere(1.0, 2, [0.0; 3]);
    m.positions[0] = m.positions[0].map(|c| -1.3 * c); // vertex 0 goes out through the opposite side
    m
}

#[test]
fn bvh_and_brute_force_agree_on_a_pushed_through_sphere() {
    let m = sphere_with_vertex_pushed_through();
    let p: Vec<[f64; 3]> = m.positions.iter().map(|q| q.map(|c| c as f64)).collect();
    let bvh = self_intersections(&p, &m.triangles);
    assert!(!bvh.is_empty());
    assert_eq!(bvh, self_intersections_brute_force(&p, &m.triangles));
    let clean = icosphere(1.0, 2, [0.0; 3]);
    let p: Vec<[f64; 3]> = clean.positions.iter().map(|q| q.map(|c| c as f64)).collect();
    assert!(self_intersections(&p, &clean.triangles).is_empty());
}

#[test]
fn repair_removes_the_intersections() {
    let m = sphere_with_vertex_pushed_through();
    let opts = RepairOptions { compare_samples: 2_000, ..Default::default() };
    let (out, rep) = repair(&PolyMesh::from(m), &opts, &NoProgress).unwrap();
    assert!(rep.intersections.pairs_found > 0);
    assert_eq!(rep.intersections.pairs_remaining, 0);
    let p: Vec<[f64; 3]> = out.positions.iter().map(|q| q.map(|c| c as f64)).collect();
    assert!(self_intersections_brute_force(&p, &out.triangles).is_empty(), "brute force finds intersections");
    assert!(rep.output.closed && rep.output.consistently_oriented && rep.output.components == 1);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    #[test]
    fn bvh_search_equals_brute_force_on_triangle_soups(coords in prop::collection::vec(-1.0f64..1.0, 9 * 2..9 * 40)) {
        let n = coords.len() / 9;
        let p: Vec<[f64; 3]> = coords.chunks(3).take(3 * n).map(|c| [c[0], c[1], c[2]]).collect();
        let tris: Vec<[u32; 3]> = (0..n as u32).map(|i| [3 * i, 3 * i + 1, 3 * i + 2]).collect();
        prop_assert_eq!(self_intersections(&p, &tris), self_intersections_brute_force(&p, &tris));
    }
}

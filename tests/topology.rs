//! The topology report of `inspect` against shapes whose answers are known by construction.

use proptest::prelude::*;
use scanstation::geometry::shapes::{cuboid, icosphere, torus};
use scanstation::geometry::topology::TopologyReport;
use scanstation::{PolyMesh, TriMesh, assert_rel_near};

fn report(positions: Vec<[f32; 3]>, faces: &[Vec<u32>]) -> TopologyReport {
    TopologyReport::compute(&PolyMesh::new(positions, faces).unwrap())
}

fn tri(t: TriMesh) -> TopologyReport {
    TopologyReport::compute(&PolyMesh::from(t))
}

#[test]
fn torus_has_genus_one_and_its_volume() {
    let (big, small) = (2.0, 0.5);
    let r = tri(torus(big, small, 128, 64));
    assert!(r.closed && r.consistently_oriented);
    assert_eq!((r.euler_characteristic, r.genus, r.components), (0, Some(1), 1));
    // Volume 2π²Rr², approached from below by the inscribed polyhedron: the 64-gon cross-section alone loses
    // 1 − sin(2π/64)/(2π/64) = 1.6e-3, the 128 segments around the axis 4e-4 more.
    let exact = 2.0 * std::f64::consts::PI.powi(2) * big * small * small;
    assert_rel_near!(r.volume.unwrap(), exact, 2.5e-3);
    assert!(r.volume.unwrap() < exact);
}

#[test]
fn box_counts() {
    let r = tri(cuboid([0.0; 3], [1.0, 2.0, 3.0]));
    assert_eq!((r.vertices, r.faces, r.edges, r.euler_characteristic, r.genus), (8, 12, 18, 2, Some(0)));
    assert_rel_near!(r.area, 22.0, 1e-12);
    assert_rel_near!(r.volume.unwrap(), 6.0, 1e-12);
}

#[test]
fn open_fan_has_one_boundary_loop() {
    // A square of 4 triangles around a centre vertex, plus one unreferenced vertex.
    let p =
        vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [5.0, 5.0, 5.0]];
    let r = report(p, &[vec![0, 1, 2], vec![0, 2, 3], vec![0, 3, 4], vec![0, 4, 1]]);
    assert_eq!((r.closed, r.boundary_loops, r.boundary_edges, r.unreferenced_vertices), (false, 1, 4, 1));
    assert_eq!((r.euler_characteristic, r.genus, r.volume), (1, Some(0), None));
}

#[test]
fn fin_edge_and_bowtie_vertex_are_non_manifold() {
    // Three triangles on one edge (a "fin").
    let p = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]];
    let r = report(p, &[vec![0, 1, 2], vec![1, 0, 3], vec![0, 1, 4]]);
    assert_eq!(r.nonmanifold_edges, 1);
    assert_eq!(r.genus, None);
    // Two triangles touching at one vertex (a bowtie).
    let p = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [-1.0, -1.0, 0.0]];
    let r = report(p, &[vec![0, 1, 2], vec![0, 3, 4]]);
    assert_eq!((r.nonmanifold_edges, r.nonmanifold_vertices, r.components, r.boundary_loops), (0, 1, 2, 1));
}

#[test]
fn flipped_face_breaks_orientation() {
    let mut t = cuboid([0.0; 3], [1.0; 3]);
    t.triangles[3].swap(0, 1);
    let r = tri(t);
    assert!(!r.consistently_oriented);
    assert_eq!(r.orientation_conflicts, 3, "each of the flipped triangle's edges is used twice in one direction");
    assert_eq!(r.genus, None);
}

#[test]
fn degenerate_and_coincident_are_counted() {
    let p = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 1.0, 0.0]];
    let r = report(p, &[vec![0, 1, 2], vec![0, 1, 3], vec![1, 2, 4]]);
    assert_eq!(r.degenerate_faces, 1, "collinear corners");
    assert_eq!(r.coincident_vertices, 1, "vertices 3 and 4 share a position");
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 16, ..ProptestConfig::default() })]

    #[test]
    fn spheres_are_closed_genus_zero_with_bounded_volume(level in 0u32..5, r in 0.01f64..100.0) {
        let rep = tri(icosphere(r, level, [1.0, 2.0, 3.0]));
        prop_assert!(rep.closed && rep.consistently_oriented);
        prop_assert_eq!((rep.euler_characteristic, rep.genus), (2, Some(0)));
        let v = rep.volume.unwrap();
        prop_assert!(v > 0.0 && v < 4.0 / 3.0 * std::f64::consts::PI * r.powi(3) * (1.0 + 1e-6));
    }

    #[test]
    fn removing_k_separate_faces_opens_k_loops(picks in prop::collection::btree_set(0usize..1280, 1..6)) {
        // Remove faces that share no vertex: each removal opens its own hole.
        let mut t = icosphere(1.0, 3, [0.0; 3]);
        let mut used = std::collections::HashSet::new();
        let chosen: Vec<usize> = picks.into_iter().filter(|&f| t.triangles[f].iter().all(|v| used.insert(*v))).collect();
        let k = chosen.len();
        for f in chosen.into_iter().rev() {
            t.triangles.remove(f);
        }
        let rep = tri(t);
        prop_assert_eq!(rep.boundary_loops, k);
        prop_assert_eq!(rep.genus, Some(0));
        prop_assert!(!rep.closed);
    }
}

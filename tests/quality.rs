//! The quality stage (two-sided surface distance) against analytic oracles, and its invariants as
//! property tests.

mod common;

use proptest::prelude::*;
use scanstation::geometry::bvh::{RAY_EDGE_SLACK, TriangleBvh, closest_point_on_triangle};
use scanstation::geometry::shapes::{cuboid, icosphere};
use scanstation::geometry::stats::percentile;
use scanstation::geometry::vec3::{cross, dot, norm, sub};
use scanstation::stages::NoProgress;
use scanstation::stages::quality::{CompareOptions, compare};
use scanstation::{ErrorCode, Geometry, PointCloud, PolyMesh, TriMesh, assert_near, assert_rel_near};

fn mesh(t: TriMesh) -> Geometry {
    Geometry::Mesh(PolyMesh::from(t))
}

fn opts(samples: usize) -> CompareOptions {
    CompareOptions { samples, ..Default::default() }
}

#[test]
fn concentric_spheres_report_the_radius_gap_both_ways() {
    // Fine icospheres (level 6: 40,962 vertices); chord sag is ~1e-4 of the radius, far below 0.5 %.
    let a = mesh(icosphere(1.0, 6, [0.0; 3]));
    let b = mesh(icosphere(1.05, 6, [0.0; 3]));
    let r = compare(&a, &b, &opts(200_000), &NoProgress).unwrap();
    for (name, s) in [("a→b", &r.test_to_reference), ("b→a", &r.reference_to_test), ("sym", &r.symmetric)] {
        for (fig, v) in [
            ("rms", s.rms.value),
            ("mean", s.mean.value),
            ("median", s.median.value),
            ("p95", s.p95.value),
            ("max", s.max.value),
        ] {
            assert_rel_near!(v, 0.05, 0.005, "{name} {fig}");
        }
    }
    // Percent of the reference diagonal (2·1.05·√3) and "1 part in N".
    let diag = 2.0 * 1.05 * 3f64.sqrt();
    assert_rel_near!(r.reference_bbox_diagonal, diag, 1e-3);
    assert_rel_near!(r.symmetric.rms.pct_of_diagonal, 100.0 * 0.05 / diag, 0.006);
    assert_rel_near!(r.symmetric.rms.one_part_in.unwrap(), diag / 0.05, 0.006);
}

#[test]
fn offset_unit_spheres_match_the_closed_form() {
    // Two unit spheres whose centres are d = 0.1 apart: the distance from a point at angle θ to the other
    // sphere is ≈ d·|cos θ| for small d: max d, RMS d/√3, mean d/2.
    let a = mesh(icosphere(1.0, 6, [0.0; 3]));
    let b = mesh(icosphere(1.0, 6, [0.1, 0.0, 0.0]));
    let r = compare(&a, &b, &opts(200_000), &NoProgress).unwrap();
    for (name, s) in [("a→b", &r.test_to_reference), ("b→a", &r.reference_to_test), ("sym", &r.symmetric)] {
        assert_rel_near!(s.max.value, 0.1, 0.02, "{name} max");
        assert_rel_near!(s.rms.value, 0.1 / 3f64.sqrt(), 0.02, "{name} rms");
        assert_rel_near!(s.mean.value, 0.05, 0.02, "{name} mean");
    }
}

#[test]
fn mesh_to_cloud_uses_nearest_points() {
    // The vertices of a sphere of radius 1.05 as a cloud, against the unit sphere.
    let b = icosphere(1.05, 5, [0.0; 3]);
    let cloud = Geometry::Cloud(PointCloud::new(b.positions.clone(), None, None).unwrap());
    let a = mesh(icosphere(1.0, 5, [0.0; 3]));
    let r = compare(&cloud, &a, &opts(50_000), &NoProgress).unwrap();
    // Cloud → mesh: every point is 0.05 off (minus chord sag of the level-5 mesh, ~2e-4).
    assert_rel_near!(r.test_to_reference.mean.value, 0.05, 0.01);
    assert_eq!(r.test_to_reference.samples, b.positions.len());
    // Mesh → cloud: at least the radial gap, more between the points.
    assert!(r.reference_to_test.min_ok(0.05 * 0.99), "{:?}", r.reference_to_test);
}

trait MinOk {
    fn min_ok(&self, lo: f64) -> bool;
}
impl MinOk for scanstation::stages::quality::DistanceStats {
    fn min_ok(&self, lo: f64) -> bool {
        self.median.value >= lo && self.rms.value >= lo
    }
}

#[test]
fn box_against_itself_is_zero_and_deterministic() {
    let a = mesh(cuboid([0.0; 3], [1.0, 2.0, 3.0]));
    let r1 = compare(&a, &a, &opts(10_000), &NoProgress).unwrap();
    let r2 = compare(&a, &a, &opts(10_000), &NoProgress).unwrap();
    assert_eq!(r1, r2, "same input and seed must give identical reports");
    assert_near!(r1.symmetric.max.value, 0.0, 1e-12);
    assert_eq!(r1.symmetric.rms.one_part_in, None);
    let other_seed = compare(&a, &a, &CompareOptions { seed: 7, ..opts(10_000) }, &NoProgress).unwrap();
    assert_eq!(other_seed.seed, 7);
}

#[test]
fn zero_area_and_empty_inputs_are_errors() {
    let flat = mesh(TriMesh::new(vec![[0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]], vec![[0, 1, 2]]).unwrap());
    let ok = mesh(cuboid([0.0; 3], [1.0; 3]));
    let e = compare(&flat, &ok, &opts(100), &NoProgress).unwrap_err();
    assert_eq!(e.code, ErrorCode::InputNoGeometry);
    let e = compare(&ok, &ok, &opts(0), &NoProgress).unwrap_err();
    assert_eq!(e.code, ErrorCode::InputBadArgument);
    let tiny = CompareOptions { memory_budget: 1000, ..opts(100) };
    assert_eq!(compare(&ok, &ok, &tiny, &NoProgress).unwrap_err().code, ErrorCode::ResourceMemoryBudget);
}

#[test]
fn percentile_interpolates_like_numpy() {
    let mut v = vec![4.0, 1.0, 3.0, 2.0];
    assert_near!(percentile(&mut v, 0.5), 2.5, 1e-15);
    assert_near!(percentile(&mut v, 0.95), 3.85, 1e-12);
    assert_near!(percentile(&mut v, 1.0), 4.0, 0.0);
    assert_near!(percentile(&mut [7.0], 0.3), 7.0, 0.0);
}

#[test]
fn closest_point_regions_of_a_triangle() {
    let (a, b, c) = ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
    let cases = [
        ([0.25, 0.25, 2.0], [0.25, 0.25, 0.0]), // face interior
        ([-1.0, -1.0, 0.0], a),                 // vertex regions
        ([2.0, -0.5, 0.0], b),
        ([-0.5, 2.0, 1.0], c),
        ([0.5, -1.0, 0.0], [0.5, 0.0, 0.0]), // edge ab
        ([-1.0, 0.5, 0.0], [0.0, 0.5, 0.0]), // edge ca
        ([1.0, 1.0, 0.0], [0.5, 0.5, 0.0]),  // edge bc
    ];
    for (p, want) in cases {
        let got = closest_point_on_triangle(p, a, b, c);
        assert_near!(norm(sub(got, want)), 0.0, 1e-15, "p = {p:?}: got {got:?}, want {want:?}");
    }
    // Degenerate triangles: a segment and a point.
    let q = closest_point_on_triangle([0.5, 1.0, 0.0], a, b, b);
    assert_near!(norm(sub(q, [0.5, 0.0, 0.0])), 0.0, 1e-15);
    let q = closest_point_on_triangle([1.0, 1.0, 1.0], a, a, a);
    assert_near!(norm(sub(q, a)), 0.0, 0.0);
}

fn random_mesh() -> impl Strategy<Value = TriMesh> {
    // A sphere of random radius/centre with each vertex jittered: closed, varied, non-convex.
    (0.2f64..3.0, prop::array::uniform3(-2.0f64..2.0), 0u32..3, any::<u64>()).prop_map(|(r, c, level, seed)| {
        let mut m = icosphere(r, level + 1, c);
        common::jitter(&mut m, seed, 0.2 * r);
        m
    })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

    #[test]
    fn distance_to_itself_is_zero(m in random_mesh()) {
        let diag = m.bbox().diagonal();
        let g = mesh(m);
        let r = compare(&g, &g, &opts(2_000), &NoProgress).unwrap();
        prop_assert!(r.symmetric.max.value <= 1e-6 * diag, "max {} (diag {diag})", r.symmetric.max.value);
    }

    #[test]
    fn swapping_inputs_swaps_the_sides(a in random_mesh(), b in random_mesh()) {
        let (a, b) = (mesh(a), mesh(b));
        let ab = compare(&a, &b, &opts(2_000), &NoProgress).unwrap();
        let ba = compare(&b, &a, &opts(2_000), &NoProgress).unwrap();
        prop_assert_eq!(ab.test_to_reference.rms.value, ba.reference_to_test.rms.value);
        prop_assert_eq!(ab.reference_to_test.max.value, ba.test_to_reference.max.value);
        prop_assert_eq!(ab.symmetric.rms.value, ba.symmetric.rms.value);
        prop_assert_eq!(ab.symmetric.max.value, ba.symmetric.max.value);
        prop_assert!((ab.symmetric.median.value - ba.symmetric.median.value).abs() <= 1e-12);
    }

    #[test]
    fn bvh_matches_brute_force(m in random_mesh(), p in prop::array::uniform3(-6.0f64..6.0)) {
        let bvh = TriangleBvh::new(&m);
        let brute = (0..m.triangles.len())
            .map(|t| { let [a, b, c] = m.corners(t); norm(sub(p, closest_point_on_triangle(p, a, b, c))) })
            .fold(f64::INFINITY, f64::min);
        prop_assert_eq!(bvh.distance(p), brute);
    }

    /// A query started from any triangle (a hint) gives the unhinted answer bit for bit: the same triangle,
    /// point and distance, facing filter or not, ties included (the icosphere's vertices are shared by five
    /// triangles, so points off a vertex tie).
    #[test]
    fn hinted_queries_match_unhinted_ones(
        m in random_mesh(),
        p in prop::array::uniform3(-6.0f64..6.0),
        f in prop::array::uniform3(-1.0f64..1.0),
        hint in 0u32..400,
        at_vertex in any::<bool>(),
    ) {
        let bvh = TriangleBvh::new(&m);
        // Half the cases sit just off a vertex, where the nearest triangles tie.
        let p = if at_vertex {
            let v = m.positions[hint as usize % m.positions.len()].map(f64::from);
            [v[0] + 1e-3 * p[0], v[1] + 1e-3 * p[1], v[2] + 1e-3 * p[2]]
        } else {
            p
        };
        let h = Some(hint % (m.triangles.len() as u32 + 3));
        prop_assert_eq!(bvh.closest_hinted(p, h), bvh.closest(p));
        prop_assert_eq!(bvh.closest_hinted(p, None), bvh.closest(p));
        prop_assert_eq!(bvh.closest_facing_hinted(p, f, h), bvh.closest_facing(p, f));
    }

    /// The ray cast finds the same first hit as testing every triangle (Möller–Trumbore in f64 on the
    /// same f32 corners), for both facing signs.
    #[test]
    fn ray_hit_matches_brute_force(
        m in random_mesh(),
        o in prop::array::uniform3(-6.0f64..6.0),
        d in prop::array::uniform3(-1.0f64..1.0),
        sign in prop::sample::select(vec![1.0f64, -1.0]),
    ) {
        let l = norm(d);
        prop_assume!(l > 0.1);
        let d = d.map(|c| c / l);
        let bvh = TriangleBvh::new(&m);
        let mut brute: Option<f64> = None;
        for t in 0..m.triangles.len() {
            let [a, b, c] = m.corners(t);
            let (e1, e2) = (sub(b, a), sub(c, a));
            if sign * dot(cross(e1, e2), d) <= 0.0 {
                continue;
            }
            let pv = cross(d, e2);
            let id = 1.0 / dot(e1, pv);
            let tv = sub(o, a);
            let (u, qv) = (dot(tv, pv) * id, cross(tv, e1));
            let v = dot(d, qv) * id;
            let h = dot(e2, qv) * id;
            let e = RAY_EDGE_SLACK;
            if (-e..=1.0 + e).contains(&u) && v >= -e && u + v <= 1.0 + e && h > 1e-9 && h < 20.0 {
                brute = Some(brute.map_or(h, |b: f64| b.min(h)));
            }
        }
        prop_assert_eq!(bvh.ray_hit(o, d, 1e-9, 20.0, sign), brute);
    }

    #[test]
    fn statistics_are_ordered(a in random_mesh(), b in random_mesh()) {
        let r = compare(&mesh(a), &mesh(b), &opts(1_000), &NoProgress).unwrap();
        for s in [&r.test_to_reference, &r.reference_to_test, &r.symmetric] {
            prop_assert!(s.median.value <= s.p95.value && s.p95.value <= s.max.value);
            prop_assert!(s.mean.value <= s.rms.value * (1.0 + 1e-12) && s.rms.value <= s.max.value);
        }
    }
}

/// Analytic oracle for the ray cast the remesher measures thickness with: from a point of a unit icosphere
/// along the inward normal, the far side is one diameter away (less the chordal sag at both ends); along
/// the outward normal nothing is hit; a front-facing search from outside stops at the near side. The
/// icosphere is centrally symmetric, so every inward ray leaves through the antipodal *vertex*: a ray
/// through a vertex must not slip between its triangles.
#[test]
fn ray_through_a_sphere_crosses_one_diameter() {
    let s = icosphere(1.0, 4, [0.0; 3]);
    let bvh = TriangleBvh::new(&s);
    let sag = 1.0 - (1.0 - 0.5 * (1.0f64 / 2f64.powi(4) * 1.2).powi(2)); // generous bound on the chordal gap
    for (i, p) in s.positions.iter().enumerate().step_by(97) {
        let p = p.map(|c| c as f64);
        let n = p.map(|c| c / norm(p));
        let inward = n.map(|c| -c);
        let t = bvh.ray_hit(p, inward, 1e-6, 10.0, 1.0).unwrap_or_else(|| panic!("vertex {i}: no far side"));
        assert!((t - 2.0).abs() <= 2.0 * sag, "vertex {i}: diameter {t}");
        assert_eq!(bvh.ray_hit(p, n, 1e-6, 10.0, -1.0), None, "vertex {i}: something outside the sphere");
        let outside = [3.0 * n[0], 3.0 * n[1], 3.0 * n[2]];
        let near = bvh.ray_hit(outside, inward, 0.0, 10.0, -1.0).expect("the near side");
        assert!((near - 2.0).abs() <= sag, "vertex {i}: near side at {near}");
    }
}

#[test]
fn hausdorff_inside_a_triangle_is_found_not_sampled() {
    // A unit square against the cloud of its 4 corners: the farthest point of the square from every corner is
    // its centre, at √2/2, inside the surface, never a vertex. 100 samples would rarely land near it.
    let square = mesh(
        TriMesh::new(
            vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]],
            vec![[0, 1, 2], [0, 2, 3]],
        )
        .unwrap(),
    );
    let corners = Geometry::Cloud(PointCloud::new(square_positions(), None, None).unwrap());
    let r = compare(&square, &corners, &opts(100), &NoProgress).unwrap();
    assert_near!(r.test_to_reference.max.value, 0.5f64.sqrt(), 1e-6);
    assert!(r.test_to_reference.p95.value < r.test_to_reference.max.value);
}

fn square_positions() -> Vec<[f32; 3]> {
    vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]]
}

/// `closest_facing` skips triangles that face away: on a thin plate (a flat box 0.01 thick) a point just
/// below the top face, asked for an upward-facing triangle, lands on the top face, not the nearer bottom.
#[test]
fn closest_facing_picks_the_sheet_facing_the_same_way() {
    let plate = scanstation::geometry::shapes::cuboid([0.0, 0.0, 0.0], [1.0, 1.0, 0.01]);
    let bvh = TriangleBvh::new(&plate);
    let p = [0.5, 0.5, 0.002];
    let plain = bvh.closest(p).unwrap();
    assert!(plain.point[2].abs() < 1e-12, "plain closest is the bottom face: {:?}", plain.point);
    let up = bvh.closest_facing(p, [0.0, 0.0, 1.0]).unwrap();
    assert!((up.point[2] - 0.01).abs() < 1e-6, "facing +z gives the top face: {:?}", up.point);
    assert!((up.distance - 0.008).abs() < 1e-6, "distance {}", up.distance);
    assert!(bvh.closest_facing(p, [0.0, 0.0, 0.0]).is_none(), "no triangle faces a zero vector");
}

/// An open scan's measure: points of the whole sphere against the sphere with a polar cap punched out, and
/// the flat disc that closes it as the invented surface. The points on the removed cap are labelled invented,
/// the rest scanned; their share is the hole's share of the sphere (a cap of half-angle θ has the share
/// (1 − cos θ)/2), and the scanned points lie on the scan. A point on the sphere just below the rim (a wall)
/// stays scanned although the disc is near; the pole, 0.2 above the disc, is invented although the rim is
/// the nearest scan.
#[test]
fn points_on_invented_surface_are_told_apart_from_scanned_ones() {
    use scanstation::stages::quality::split_by_invented;
    let full = scanstation::geometry::shapes::icosphere(1.0, 5, [0.0; 3]);
    let mut scan = full.clone();
    // Remove every triangle with a corner above z = 0.8 (a polar cap of half-angle about 36.9°).
    scan.triangles.retain(|t| t.iter().all(|&i| full.positions[i as usize][2] <= 0.8));
    // The invented surface: a 64-gon disc at z = 0.8 of the rim's radius, fanned from its centre.
    let r = (1.0f64 - 0.64).sqrt();
    let mut disc = TriMesh { positions: vec![[0.0, 0.0, 0.8]], triangles: Vec::new() };
    for k in 0..64u32 {
        let a = k as f64 * std::f64::consts::TAU / 64.0;
        disc.positions.push([(r * a.cos()) as f32, (r * a.sin()) as f32, 0.8]);
        disc.triangles.push([0, 1 + k, 1 + (k + 1) % 64]);
    }
    let pts: Vec<[f64; 3]> = full.positions.iter().map(|p| p.map(f64::from)).collect();
    let split = split_by_invented(&pts, &scan, &disc);
    assert_eq!(split.invented.len(), pts.len());
    let over: Vec<usize> = (0..pts.len()).filter(|&i| split.invented[i].is_some()).collect();
    let share = over.len() as f64 / pts.len() as f64;
    let expected = (1.0 - 0.8) / 2.0;
    assert!((share - expected).abs() < 0.02, "share on the invented disc {share:.4}, the cap's {expected:.4}");
    let off_max = (0..pts.len()).filter(|&i| split.invented[i].is_none()).map(|i| split.to_scan[i]).fold(0.0, f64::max);
    assert!(off_max < 1e-6, "points off the invented surface lie on the scan: {off_max:e}");
    let pole = pts.iter().position(|p| p[2] > 0.9999).expect("the icosphere has a vertex at its pole");
    assert!(
        split.invented[pole].is_some() && split.to_scan[pole] > 0.2,
        "the pole: {:?}, {}",
        split.invented[pole],
        split.to_scan[pole]
    );
    // Just below the rim, on the sphere: scanned (distance 0 to the scan, more to the disc).
    let wall = [0.0, (1.0f64 - 0.78 * 0.78).sqrt(), 0.78];
    let w = split_by_invented(&[wall], &scan, &disc);
    assert_eq!(
        w.invented[0], None,
        "a wall point below the rim: to scan {}, to disc {}",
        w.to_scan[0], w.to_invented[0]
    );
    // Nothing invented: everything is scanned.
    let none = split_by_invented(&pts, &full, &TriMesh::default());
    assert!(none.invented.iter().all(Option::is_none));
}

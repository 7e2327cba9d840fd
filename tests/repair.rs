//! The repair stage: analytic oracles (punched spheres refilled onto the sphere), invariants as property tests
//! (clean meshes pass unchanged, repair is idempotent), synthetic defects, and bad input.

mod common;

use proptest::prelude::*;
use scanstation::geometry::shapes::{icosphere, torus};
use scanstation::geometry::topology::TopologyReport;
use scanstation::stages::NoProgress;
use scanstation::stages::repair::{RepairOptions, repair};
use scanstation::{ErrorCode, PolyMesh, TriMesh};

fn opts() -> RepairOptions {
    RepairOptions { compare_samples: 5_000, ..Default::default() }
}

fn run(t: TriMesh) -> (TriMesh, scanstation::stages::repair::RepairReport) {
    repair(&PolyMesh::from(t), &opts(), &NoProgress).unwrap_or_else(|e| panic!("repair failed: {e}"))
}

fn assert_clean(r: &TopologyReport, what: &str) {
    assert!(r.closed, "{what}: not closed ({} boundary edges)", r.boundary_edges);
    assert!(r.consistently_oriented, "{what}: {} orientation conflicts", r.orientation_conflicts);
    assert_eq!((r.nonmanifold_edges, r.nonmanifold_vertices), (0, 0), "{what}: non-manifold");
    assert_eq!(r.components, 1, "{what}: components");
    assert!(r.volume.unwrap() > 0.0, "{what}: must face outward");
}

/// Remove the faces around each of `centres` (vertex indices) out to `rings` rings.
fn punch(mut t: TriMesh, centres: &[u32], rings: usize) -> TriMesh {
    let mut hit: std::collections::HashSet<u32> = centres.iter().copied().collect();
    for _ in 0..rings {
        let grow: Vec<u32> =
            t.triangles.iter().filter(|f| f.iter().any(|v| hit.contains(v))).flatten().copied().collect();
        hit.extend(grow);
    }
    // Faces with all corners inside the grown set go; a ring of the last vertices remains as the rim.
    t.triangles.retain(|f| !f.iter().all(|v| hit.contains(v)));
    t
}

fn max_radial_error(t: &TriMesh, r: f64) -> f64 {
    t.positions
        .iter()
        .map(|p| ((p.iter().map(|&c| (c as f64).powi(2)).sum::<f64>()).sqrt() - r).abs())
        .fold(0.0, f64::max)
}

#[test]
fn punched_sphere_is_refilled_onto_the_sphere() {
    let sphere = icosphere(1.0, 4, [0.0; 3]);
    let holed = punch(sphere, &[0, 7, 11], 3);
    let before = TopologyReport::compute(&PolyMesh::from(holed.clone()));
    assert_eq!(before.boundary_loops, 3);
    let (out, rep) = run(holed);
    assert_clean(&rep.output, "punched sphere");
    assert_eq!(rep.holes.holes_filled, 3);
    assert!(rep.holes.vertices_added > 0, "the fill is refined to the surrounding density");
    let err = max_radial_error(&out, 1.0);
    assert!(err <= 0.01, "filled vertices must lie within 1 % of the radius: max error {err}");
}

#[test]
fn synthetic_defects_are_repaired() {
    let mut t = icosphere(1.0, 3, [0.0; 3]);
    let n = t.positions.len() as u32;
    t.triangles[5].swap(1, 2); // a flipped face
    let dup = t.triangles[9];
    t.triangles.push(dup); // a duplicate face
    let e = t.triangles[20];
    t.positions.push([3.0, 3.0, 3.0]);
    t.triangles.push([e[0], e[1], n]); // a fin: third face on an edge
    t.positions.extend([[9.0, 9.0, 9.0], [9.01, 9.0, 9.0], [9.0, 9.01, 9.0]]);
    t.triangles.push([n + 1, n + 2, n + 3]); // debris far away
    t.positions.push([t.positions[0][0], t.positions[0][1], t.positions[0][2]]); // a coincident copy
    let c = t.triangles.iter().position(|f| f.contains(&0)).unwrap();
    t.triangles[c] = t.triangles[c].map(|v| if v == 0 { n + 4 } else { v });
    let (_, rep) = run(t);
    assert_clean(&rep.output, "synthetic defects");
    assert_eq!(rep.weld.merged_vertices, 1);
    assert_eq!(rep.weld.duplicate_faces, 1);
    assert!(rep.manifold.nonmanifold_edges >= 1);
    assert!(rep.manifold.components_found >= 2 && rep.manifold.components_kept == 1);
    assert_eq!(rep.output.genus, Some(0));
}

#[test]
fn inward_facing_mesh_is_turned_outward() {
    let mut t = icosphere(2.0, 2, [0.0; 3]);
    t.triangles.iter_mut().for_each(|f| f.swap(1, 2));
    let (_, rep) = run(t);
    assert!(rep.flipped_outward);
    assert_clean(&rep.output, "inward sphere");
}

#[test]
fn nothing_left_is_a_clear_error() {
    let t = TriMesh { positions: vec![[0.0; 3], [0.0; 3], [0.0; 3]], triangles: vec![[0, 1, 2]] };
    let e = repair(&PolyMesh::from(t), &opts(), &NoProgress).unwrap_err();
    assert_eq!(e.code, ErrorCode::RepairFailed);
    assert!(e.message.starts_with("weld:"), "the message names the step: {e}");
    let empty = PolyMesh::default();
    assert_eq!(repair(&empty, &opts(), &NoProgress).unwrap_err().code, ErrorCode::InputNoGeometry);
}

/// What `random_holes_are_filled_within_one_percent_of_the_radius` asks of a punched unit sphere after
/// repair: holes faired back onto the sphere within 1 % of the radius; a hole so large that repair caps it
/// (a rim radius of 8 % of the diagonal or more, issue 43) no bulge past its rim's plane beyond the rim's own
/// distance from it, and nothing outside the sphere by more than 1 %.
fn check_random_holes(out: &TriMesh, rep: &scanstation::stages::repair::RepairReport) -> Result<(), String> {
    let caps = &rep.holes.caps;
    let outward = out
        .positions
        .iter()
        .map(|p| (p.iter().map(|&c| (c as f64).powi(2)).sum::<f64>()).sqrt() - 1.0)
        .fold(0.0, f64::max);
    if caps.is_empty() {
        let err = max_radial_error(out, 1.0);
        return if err <= 0.01 { Ok(()) } else { Err(format!("max radial error {err}")) };
    }
    for c in caps {
        if c.bulge > c.rim_residual + 1e-9 {
            return Err(format!("a cap bulges {} past its plane, its rim {}", c.bulge, c.rim_residual));
        }
    }
    if outward > 0.01 { Err(format!("a vertex {outward} outside the sphere")) } else { Ok(()) }
}

/// Regression (proptest, 2026-12-06): four 3-ring holes punched close together on a unit sphere merge into
/// one hole large enough to be capped (rule `object-size`); the flat cap lies up to 2.2 % inside the sphere,
/// which the old "every fill within 1 % of the radius" property refused. The cap meets the cap bounds instead.
#[test]
fn merged_holes_large_enough_to_cap_are_capped_within_bounds() {
    let sphere = icosphere(1.0, 4, [0.0; 3]);
    let n = sphere.positions.len() as u64;
    let seed = 1494225052059885912u64;
    let centres: Vec<u32> =
        (0..4u64).map(|i| ((seed.wrapping_mul(2654435761).wrapping_add(i * 7919)) % n) as u32).collect();
    let (out, rep) = run(punch(sphere, &centres, 3));
    assert_clean(&rep.output, "merged holes");
    assert!(
        rep.holes.decisions.iter().any(|d| d.rule == scanstation::stages::repair::caps::HoleRule::ObjectSize),
        "{:?}",
        rep.holes.decisions
    );
    check_random_holes(&out, &rep).unwrap_or_else(|e| panic!("merged holes: {e}"));
}

fn jittered(level: u32, seed: u64, genus_one: bool) -> TriMesh {
    let mut m = if genus_one {
        torus(2.0, 0.6, 24 + level as usize * 8, 12 + level as usize * 4)
    } else {
        icosphere(1.5, level, [0.5, -1.0, 2.0])
    };
    common::jitter(&mut m, seed, 0.02);
    m
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 12, ..ProptestConfig::default() })]

    #[test]
    fn clean_closed_meshes_pass_unchanged(level in 1u32..4, seed in any::<u64>(), genus_one in any::<bool>()) {
        let m = jittered(level, seed, genus_one);
        let (out, rep) = run(m.clone());
        prop_assert_eq!(&out, &m);
        prop_assert_eq!(rep.holes.holes_filled, 0);
        prop_assert_eq!(rep.output.genus, Some(genus_one as i64));
    }

    #[test]
    fn repair_is_idempotent(level in 2u32..4, seed in any::<u64>(), holes in prop::collection::vec(0u32..600, 1..4)) {
        let m = jittered(level, seed, false);
        let n = m.positions.len() as u32;
        let holed = punch(m, &holes.iter().map(|h| h % n).collect::<Vec<_>>(), 1);
        let (once, _) = run(holed);
        let (twice, rep) = run(once.clone());
        prop_assert_eq!(rep.holes.holes_filled, 0);
        prop_assert_eq!(once, twice);
    }

    #[test]
    fn random_holes_are_filled_within_one_percent_of_the_radius(seed in any::<u64>(), k in 1usize..5, rings in 1usize..4) {
        let sphere = icosphere(1.0, 4, [0.0; 3]);
        let n = sphere.positions.len() as u64;
        let centres: Vec<u32> = (0..k as u64).map(|i| ((seed.wrapping_mul(2654435761).wrapping_add(i * 7919)) % n) as u32).collect();
        let (out, rep) = run(punch(sphere, &centres, rings));
        assert_clean(&rep.output, "random holes");
        check_random_holes(&out, &rep).map_err(TestCaseError::fail)?;
    }
}

#[test]
fn a_spike_is_pulled_back_and_taubin_does_not_shrink() {
    let mut t = icosphere(1.0, 3, [0.0; 3]);
    t.positions[5] = t.positions[5].map(|c| 1.8 * c); // a spike 0.8 out of a surface with ~0.3 edges
    let (out, rep) = run(t);
    assert_eq!(rep.smooth.spikes_removed, 1);
    let r5 =
        out.positions.iter().map(|p| p.iter().map(|&c| (c as f64).powi(2)).sum::<f64>().sqrt()).fold(0.0, f64::max);
    assert!(r5 < 1.01, "no vertex is left far outside the sphere: max radius {r5}");
    // Taubin λ|μ keeps the volume: a noisy sphere smoothed 10 times loses < 1 % of its volume.
    let noisy = jittered(3, 7, false);
    let v0 = TopologyReport::compute(&PolyMesh::from(noisy.clone())).volume.unwrap();
    let o = RepairOptions { smooth_iterations: 10, ..opts() };
    let (_, rep) = repair(&PolyMesh::from(noisy), &o, &NoProgress).unwrap();
    let v1 = rep.output.volume.unwrap();
    assert!((v1 - v0).abs() / v0 < 0.01, "volume {v0} → {v1}");
    assert_eq!(rep.smooth.taubin_iterations, 10);
}

#[test]
fn decimation_hits_the_target_and_keeps_topology_and_shape() {
    for (name, mesh, genus) in [("sphere", icosphere(1.0, 5, [0.0; 3]), 0), ("torus", torus(2.0, 0.6, 96, 48), 1)] {
        let o = RepairOptions { target_vertices: Some(800), ..opts() };
        let (out, rep) = repair(&PolyMesh::from(mesh.clone()), &o, &NoProgress).unwrap();
        let d = rep.decimate.as_ref().unwrap();
        assert_eq!(d.vertices_after, 800, "{name}: {d:?}");
        // Decimation refuses crossings itself: the search afterwards finds none to remove.
        assert_eq!(rep.decimate_intersections.as_ref().unwrap().pairs_found, 0, "{name}");
        assert_clean(&rep.output, name);
        assert_eq!(rep.output.genus, Some(genus), "{name}: genus");
        let p: Vec<[f64; 3]> = out.positions.iter().map(|q| q.map(|c| c as f64)).collect();
        assert!(scanstation::geometry::intersect::self_intersections_brute_force(&p, &out.triangles).is_empty());
        // Close to the original surface: symmetric max ≤ 2 % of the diagonal, rms ≤ 0.2 %.
        assert!(rep.distance.symmetric.max.pct_of_diagonal < 2.0, "{name}: {:?}", rep.distance.symmetric.max);
        assert!(rep.distance.symmetric.rms.pct_of_diagonal < 0.2, "{name}: {:?}", rep.distance.symmetric.rms);
        // Deterministic.
        let (again, _) = repair(&PolyMesh::from(mesh), &o, &NoProgress).unwrap();
        assert_eq!(out, again, "{name}: same input and settings, same output");
    }
}

#[test]
fn the_memory_budget_is_checked_first() {
    let o = RepairOptions { memory_budget: 10_000, ..opts() };
    let e = repair(&PolyMesh::from(icosphere(1.0, 4, [0.0; 3])), &o, &NoProgress).unwrap_err();
    assert_eq!(e.code, ErrorCode::ResourceMemoryBudget);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 8, ..ProptestConfig::default() })]

    #[test]
    fn decimation_keeps_a_clean_closed_manifold(seed in any::<u64>(), genus_one in any::<bool>(), target in 60usize..400) {
        let m = jittered(3, seed, genus_one);
        let o = RepairOptions { target_vertices: Some(target), ..opts() };
        let (out, rep) = repair(&PolyMesh::from(m), &o, &NoProgress).unwrap();
        assert_clean(&rep.output, "decimated");
        prop_assert_eq!(rep.output.genus, Some(genus_one as i64));
        prop_assert_eq!(rep.decimate.as_ref().unwrap().vertices_after, target);
        let p: Vec<[f64; 3]> = out.positions.iter().map(|q| q.map(|c| c as f64)).collect();
        prop_assert!(scanstation::geometry::intersect::self_intersections_brute_force(&p, &out.triangles).is_empty());
    }
}

/// Regression for the bunny's base: a hole whose rim is rough (radial noise of ±0.5 % on a unit sphere, the
/// bunny's base is rough at the 1 mm level) is filled by a patch that does not copy the noise: its vertices lie
/// within 0.25 % of one quadric through the patch, and within 1 % of the sphere. The fairing takes its boundary
/// tangents from a quadric fitted to the rim's surroundings (`holes::rim_anchors`).
#[test]
fn a_rough_rim_is_filled_smoothly() {
    let mut sphere = icosphere(1.0, 5, [0.0; 3]);
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    for p in &mut sphere.positions {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        let s = 1.0 + 0.005 * ((state >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0);
        *p = p.map(|c| (c as f64 * s) as f32);
    }
    let (out, rep) = run(punch(sphere, &[0], 6));
    assert_eq!(rep.holes.holes_filled, 1);
    let smooth = rep.holes.patch_smoothness[0];
    // Measured: 0.0016 (0.0032 with the rim's own tangents); radial 0.0050 (0.0070).
    assert!(smooth <= 0.0025, "the fill copies the rim's noise: {smooth} from a quadric through the patch");
    assert!(max_radial_error(&out, 1.0) <= 0.01, "radial error {}", max_radial_error(&out, 1.0));
}

/// Regression (issue 3: decimation must never create self-intersections): thin tori decimated to 30
/// vertices. Without the crossing test, collapses on the inner side push faces through the opposite wall
/// (10 and 6 crossing pairs, measured); with it, none. On the thinnest torus the refusals stall the
/// decimation short of the target (37 vertices for 30): it stops rather than cross.
#[test]
fn decimation_refuses_collapses_that_would_cross_the_surface() {
    use scanstation::geometry::decimate::{Crossings, decimate};
    use scanstation::geometry::intersect::self_intersections_brute_force;
    for (minor, crossing_without) in [(0.02, 10), (0.1, 6)] {
        let m = torus(1.0, minor, 160, 10);
        let p0: Vec<[f64; 3]> = m.positions.iter().map(|q| q.map(|c| c as f64)).collect();
        assert!(self_intersections_brute_force(&p0, &m.triangles).is_empty(), "minor {minor}: input crosses");
        let (mut p, mut t) = (p0.clone(), m.triangles.clone());
        decimate(&mut p, &mut t, 30, 1, Crossings::Ignore);
        let without = self_intersections_brute_force(&p, &t).len();
        assert_eq!(without, crossing_without, "minor {minor}: crossing pairs without the test");
        let (mut p, mut t) = (p0, m.triangles.clone());
        let r = decimate(&mut p, &mut t, 30, 1, Crossings::Refuse);
        assert!(r.refused_intersection > 0, "minor {minor}: {r:?}");
        assert!(r.vertices_after <= 40, "minor {minor}: {r:?}");
        let pairs = self_intersections_brute_force(&p, &t);
        assert!(pairs.is_empty(), "minor {minor}: {} crossing pairs with the test: {pairs:?}", pairs.len());
        let out = PolyMesh::from(TriMesh::new(p.iter().map(|q| q.map(|c| c as f32)).collect(), t).unwrap());
        let topo = TopologyReport::compute(&out);
        assert!(topo.closed && topo.nonmanifold_edges == 0, "minor {minor}: {topo:?}");
        assert_eq!(topo.genus, Some(1), "minor {minor}");
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 16, ..ProptestConfig::default() })]

    /// Invariant: a decimation that refuses crossings never makes a surface without self-intersections
    /// cross itself (noisy thin tori, random targets; brute-force check of every pair). The tori come at
    /// unit size and at a tenth of it (0.2 across, like a scan in metres), where the local test clears as
    /// many pairs as at unit size since its tolerance no longer depends on the scale.
    #[test]
    fn refusing_decimation_keeps_a_surface_free_of_crossings(
        seed in any::<u64>(),
        target in 24usize..120,
        size in prop::sample::select(vec![1.0, 0.1]),
    ) {
        use scanstation::geometry::intersect::self_intersections_brute_force;
        use scanstation::geometry::decimate::{Crossings, decimate};
        let mut m = torus(1.0, 0.08, 120, 12);
        common::jitter(&mut m, seed, 0.03);
        let mut p: Vec<[f64; 3]> = m.positions.iter().map(|q| q.map(|c| c as f64 * size)).collect();
        prop_assume!(self_intersections_brute_force(&p, &m.triangles).is_empty());
        let mut t = m.triangles.clone();
        decimate(&mut p, &mut t, target, seed, Crossings::Refuse);
        let pairs = self_intersections_brute_force(&p, &t);
        prop_assert!(pairs.is_empty(), "{} crossing pairs", pairs.len());
    }
}

/// The trust issue's open-base oracle: a cylinder (radius 1, length 4) standing on an open, slightly noisy
/// planar base (rim jittered by ±0.004 % of the diagonal along the axis) gets one planar cap: its vertices lie
/// within 0.01 % of the diagonal of the base plane, nothing bulges past the rim, and the report names the
/// cap with its area (the 48-gon's, 3.133) and its plane's fit residual. Thin-plate fairing of the same hole
/// continued the walls into a dome instead.
#[test]
fn an_open_planar_base_gets_a_flat_cap() {
    let mut rod = scanstation::geometry::shapes::rod(1.0, 4.0, 48, 16);
    // Drop the fan that closes the end at x = 0 (its centre vertex is the second to last).
    let c0 = (rod.positions.len() - 2) as u32;
    rod.triangles.retain(|t| !t.contains(&c0));
    let mut state = 7u64;
    for p in rod.positions.iter_mut().filter(|p| p[0] == 0.0) {
        state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        p[0] = (((state >> 33) as f64 / (1u64 << 31) as f64) * 2.0 - 1.0) as f32 * 2e-4;
    }
    let diagonal = (4.0f64 * 4.0 + 2.0 * 2.0 + 2.0 * 2.0).sqrt();
    let (out, rep) = run(rod);
    assert_clean(&rep.output, "capped cylinder");
    let caps = &rep.holes.caps;
    assert_eq!(caps.len(), 1, "{:?}", rep.holes);
    let cap = &caps[0];
    assert_eq!(cap.edges, 48);
    assert!(cap.normal[0] < -0.999, "the cap faces out of the cylinder: {:?}", cap.normal);
    assert!(cap.rim_residual <= 2e-4 * 1.01, "rim residual {}", cap.rim_residual);
    assert!((cap.area - 3.133).abs() <= 0.02 * 3.133, "cap area {}", cap.area);
    let bound = 1e-4 * diagonal;
    let off_plane = out
        .positions
        .iter()
        .filter(|p| p[0] < 0.05 && (p[1] * p[1] + p[2] * p[2]) < 0.9)
        .map(|p| (p[0] as f64).abs())
        .fold(0.0, f64::max);
    assert!(off_plane <= bound, "cap vertex {off_plane:.2e} off the base plane (bound {bound:.2e})");
    let lowest = out.positions.iter().map(|p| p[0] as f64).fold(f64::INFINITY, f64::min);
    assert!(lowest >= -bound, "the cap bulges {lowest:.2e} past the rim");
}

// ---- Issue 43: open bases. A large hole is capped within its rim's hull (planar, or a membrane over a
// non-planar rim) and bulges past the rim's best plane by no more than the rim's own non-planarity; a small
// dropout keeps the faired fill.

use scanstation::stages::repair::caps::{CapKind, HoleRule};

/// Bounding-box diagonal of a mesh's vertices.
fn diagonal_of(t: &TriMesh) -> f64 {
    scanstation::geometry::vec3::Aabb::of_points(&t.positions).diagonal()
}

/// 2-D convex hull (Andrew's monotone chain), counter-clockwise.
fn hull_2d(mut pts: Vec<[f64; 2]>) -> Vec<[f64; 2]> {
    pts.sort_by(|a, b| a[0].total_cmp(&b[0]).then(a[1].total_cmp(&b[1])));
    let cross = |o: [f64; 2], a: [f64; 2], b: [f64; 2]| (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]);
    let mut h: Vec<[f64; 2]> = Vec::new();
    for pass in 0..2 {
        let start = h.len();
        let it: Box<dyn Iterator<Item = &[f64; 2]>> =
            if pass == 0 { Box::new(pts.iter()) } else { Box::new(pts.iter().rev()) };
        for &p in it {
            while h.len() >= start + 2 && cross(h[h.len() - 2], h[h.len() - 1], p) <= 0.0 {
                h.pop();
            }
            h.push(p);
        }
        h.pop();
    }
    h
}

/// What an open-base oracle measured: the cap's kind, the rule that judged the hole, the cap's bulge past
/// the rim's plane and the rim's non-planarity (both % of the diagonal), and the farthest a cap vertex lies
/// outside the rim's hull (% of the diagonal; 0 inside).
struct CapCase {
    kind: Option<CapKind>,
    rule: HoleRule,
    bulge_pct: f64,
    rim_pct: f64,
    outside_hull_pct: f64,
}

/// Repair `open` (one hole), and measure its cap against the rim: every new vertex must lie in the slab
/// between the rim's lowest and highest points along the cap's normal and, projected onto the cap's plane,
/// inside the rim's projected convex hull (together: inside a prism that holds the rim's 3-D hull).
fn cap_case(name: &str, open: TriMesh) -> CapCase {
    let diag = diagonal_of(&open);
    let rim: Vec<[f64; 3]> = scanstation::stages::repair::holes::boundary_loops(&open.triangles)
        .concat()
        .iter()
        .map(|&v| open.positions[v as usize].map(f64::from))
        .collect();
    let known: std::collections::HashSet<[u32; 3]> = open.positions.iter().map(|p| p.map(f32::to_bits)).collect();
    let (out, rep) = run(open);
    assert_clean(&rep.output, name);
    assert_eq!(rep.holes.holes_filled, 1, "{name}: {:?}", rep.holes.decisions);
    assert_eq!(rep.holes.caps.len(), 1, "{name}: not capped: {:?}", rep.holes.decisions);
    let cap = &rep.holes.caps[0];
    use scanstation::geometry::vec3::{dot, plane_frame, sub};
    let (n, c) = (cap.normal, cap.point);
    let along = |p: [f64; 3]| dot(sub(p, c), n);
    let (u, w) = plane_frame(n);
    let flat = |p: [f64; 3]| [dot(sub(p, c), u), dot(sub(p, c), w)];
    let (lo, hi) =
        rim.iter().map(|&p| along(p)).fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), h| (a.min(h), b.max(h)));
    let hull = hull_2d(rim.iter().map(|&p| flat(p)).collect());
    let new: Vec<[f64; 3]> =
        out.positions.iter().filter(|p| !known.contains(&p.map(f32::to_bits))).map(|p| p.map(f64::from)).collect();
    assert!(!new.is_empty(), "{name}: the cap has no inner vertices");
    let mut outside: f64 = 0.0;
    for &p in &new {
        let h = along(p);
        outside = outside.max(h - hi).max(lo - h);
        let q = flat(p);
        for k in 0..hull.len() {
            let (a, b) = (hull[k], hull[(k + 1) % hull.len()]);
            let len = ((b[0] - a[0]).powi(2) + (b[1] - a[1]).powi(2)).sqrt();
            // Distance to the right of edge a→b (outside for a counter-clockwise hull).
            let right = -((b[0] - a[0]) * (q[1] - a[1]) - (b[1] - a[1]) * (q[0] - a[0])) / len;
            outside = outside.max(right);
        }
    }
    let bulge = new.iter().map(|&p| along(p)).fold(f64::NEG_INFINITY, f64::max);
    assert!(
        (bulge - cap.bulge).abs() <= 1e-9 * diag.max(1.0) || cap.bulge >= bulge,
        "{name}: the report's bulge {} against the measured {bulge}",
        cap.bulge
    );
    eprintln!(
        "{name}: {:?} {:?} cap, bulge {:.4} %, rim {:.4} %, outside hull {:.2e} %, {} new vertices",
        cap.kind,
        rep.holes.decisions[0].rule,
        100.0 * bulge / diag,
        100.0 * cap.rim_residual / diag,
        100.0 * outside.max(0.0) / diag,
        new.len()
    );
    CapCase {
        kind: cap.kind,
        rule: rep.holes.decisions[0].rule,
        bulge_pct: 100.0 * bulge / diag,
        rim_pct: 100.0 * cap.rim_residual / diag,
        outside_hull_pct: 100.0 * outside.max(0.0) / diag,
    }
}

/// The bounds every open-base oracle must meet: inside the rim's hull (to float rounding), no higher past the
/// plane than the rim itself, and at most 1 % of the diagonal past it.
fn assert_cap_bounds(name: &str, c: &CapCase) {
    assert!(
        c.outside_hull_pct <= 1e-6,
        "{name}: a cap vertex {:.2e} % of the diagonal outside the rim's hull",
        c.outside_hull_pct
    );
    assert!(
        c.bulge_pct <= c.rim_pct + 1e-6,
        "{name}: bulge {:.4} % past the plane, the rim only {:.4} %",
        c.bulge_pct,
        c.rim_pct
    );
    assert!(c.bulge_pct <= 1.0, "{name}: bulge {:.4} % of the diagonal", c.bulge_pct);
}

/// A cylinder (radius 1, length 4) open at one end, its rim wavy along the axis (three waves, amplitude 1 % of
/// the diagonal): a large hole (object size) with a non-planar rim gets a membrane cap inside the rim's hull,
/// bulging past the rim's plane no more than the rim's crests do.
#[test]
fn a_wavy_open_rim_gets_a_membrane_within_its_hull() {
    let mut rod = scanstation::geometry::shapes::rod(1.0, 4.0, 96, 64);
    let c0 = (rod.positions.len() - 2) as u32;
    rod.triangles.retain(|t| !t.contains(&c0));
    let diag = (4.0f64 * 4.0 + 2.0 * 2.0 + 2.0 * 2.0).sqrt();
    for p in rod.positions.iter_mut().filter(|p| p[0] == 0.0 && (p[1] != 0.0 || p[2] != 0.0)) {
        let a = (p[2] as f64).atan2(p[1] as f64);
        p[0] = (0.01 * diag * (3.0 * a).sin()) as f32;
    }
    let c = cap_case("wavy rim", rod);
    assert_eq!((c.kind, c.rule), (Some(CapKind::Membrane), HoleRule::ObjectSize));
    assert!((c.rim_pct - 1.0).abs() < 0.05, "the rim's non-planarity {:.4} %", c.rim_pct);
    assert_cap_bounds("wavy rim", &c);
}

/// A sphere cut by a tilted plane where its surface meets the plane at 25° from the cut's normal (the walls
/// curl under): the old planar-cut test (walls steeper than 30°) refused it and fairing continued the sphere,
/// 2.7 % of the diagonal past the plane. Now a large hole: capped flat within the rim's hull.
#[test]
fn a_tilted_cut_through_a_sphere_is_capped_not_domed() {
    let sphere = icosphere(1.0, 5, [0.0; 3]);
    let n = [0.3f64, 0.2, -1.0];
    let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    let n = n.map(|x| x / l);
    let d = 25f64.to_radians().cos();
    let mut cut = sphere.clone();
    cut.triangles.retain(|t| {
        t.iter().all(|&v| {
            let p = sphere.positions[v as usize];
            (0..3).map(|k| p[k] as f64 * n[k]).sum::<f64>() <= d
        })
    });
    let c = cap_case("tilted cut", cut);
    assert_eq!(c.rule, HoleRule::ObjectSize);
    assert_cap_bounds("tilted cut", &c);
}

/// A bust-like body (an ellipsoid 2.8 × 2 × 2.6) cut below its widest part, where the surface curls under
/// towards the cut (faces at the rim about 30° from the cut's normal), the cut itself slightly wavy (±0.5 %
/// of the diagonal): a membrane within the rim's hull.
#[test]
fn a_bust_that_curls_under_towards_its_cut_gets_a_membrane() {
    let mut body = icosphere(1.0, 5, [0.0; 3]);
    for p in &mut body.positions {
        *p = [p[0] * 1.4, p[1], p[2] * 1.3];
    }
    let diag = diagonal_of(&body);
    let cut_z = |p: [f32; 3]| {
        let a = (p[1] as f64).atan2(p[0] as f64);
        -0.85 * 1.3 + 0.005 * diag * (2.0 * a).sin()
    };
    let mut bust = body.clone();
    bust.triangles
        .retain(|t| t.iter().all(|&v| body.positions[v as usize][2] as f64 >= cut_z(body.positions[v as usize])));
    let c = cap_case("bust", bust);
    assert_eq!((c.kind, c.rule), (Some(CapKind::Membrane), HoleRule::ObjectSize));
    assert_cap_bounds("bust", &c);
}

/// A small dropout (4 rings of faces around one vertex of a unit sphere: 20 rim edges, a radius of 3.5 % of the
/// diagonal) is judged a dropout and keeps the faired fill, which continues the sphere: its vertices within
/// 0.05 % of the diagonal of it. Measured (2026-12-06), rings / edges / radius % / fill's radial error %:
/// 2 / 10 / 1.8 / 0.008, 3 / 15 / 2.7 / 0.014, 4 / 20 / 3.5 / 0.047, 5 / 25 / 4.4 / 0.081, 6 / 30 / 5.3 / 0.138:
/// the thin-plate fill (uniform umbrella) departs from the sphere as the hole grows.
#[test]
fn a_small_dropout_keeps_its_smooth_fill() {
    let sphere = icosphere(1.0, 5, [0.0; 3]);
    let diag = diagonal_of(&sphere);
    let (out, rep) = run(punch(sphere, &[0], 4));
    assert_clean(&rep.output, "dropout");
    eprintln!(
        "dropout: {:?}, radial error {:.4} % of the diagonal",
        rep.holes.decisions,
        100.0 * max_radial_error(&out, 1.0) / diag
    );
    assert_eq!(rep.holes.decisions.len(), 1);
    assert_eq!(rep.holes.decisions[0].rule, HoleRule::Dropout, "{:?}", rep.holes.decisions);
    assert!(rep.holes.caps.is_empty());
    let err = max_radial_error(&out, 1.0);
    assert!(err <= 5e-4 * diag, "the fill leaves the sphere by {:.4} % of the diagonal", 100.0 * err / diag);
}

/// `beetle.ply`'s field failure (2026-12-07): the crossings repair removed left the body and three small
/// closed pieces beside it (2,076, 418 and 186 of 78,160 faces), and the B-rep refused the four-piece shell
/// as an internal error. A closed piece under the kept share of the area beside the body is dropped at the
/// end as debris is; a piece of at least that share stays.
#[test]
fn closed_pieces_the_closing_cut_off_are_dropped_as_debris() {
    use scanstation::stages::repair::manifold::drop_small_pieces;
    let body = icosphere(1.0, 3, [0.0; 3]);
    let piece = icosphere(0.2, 2, [3.0, 0.0, 0.0]);
    let mut tris = body.triangles.clone();
    let n = body.positions.len() as u32;
    tris.extend(piece.triangles.iter().map(|t| t.map(|i| i + n)));
    let pos: Vec<[f64; 3]> = body.positions.iter().chain(&piece.positions).map(|p| p.map(f64::from)).collect();
    let mut kept = tris.clone();
    assert_eq!(drop_small_pieces(&pos, &mut kept, 0.1), (1, piece.triangles.len()));
    assert_eq!(kept, body.triangles, "the body is kept as it was");
    // At a kept share below the piece's (0.04 of the area) both stay.
    let mut kept = tris.clone();
    assert_eq!(drop_small_pieces(&pos, &mut kept, 0.01), (0, 0));
    assert_eq!(kept.len(), tris.len());
}

//! The remesh stage: field oracles (valence deficit 0 on a torus and exactly 8 on a sphere),
//! invariants of every output (closed, pure quads, χ kept, valence ≥ 3, count within 10 %), determinism,
//! and bad input.

use proptest::prelude::*;
use scanstation::geometry::shapes::{icosphere, torus};
use scanstation::stages::NoProgress;
use scanstation::stages::remesh::{Mode, QuadStats, RemeshOptions, RemeshReport, remesh};
use scanstation::{ErrorCode, PolyMesh, TriMesh};

fn opts(target: usize) -> RemeshOptions {
    RemeshOptions { target_vertices: target, compare_samples: 20_000, ..Default::default() }
}

fn run(mesh: &TriMesh, target: usize) -> (PolyMesh, RemeshReport) {
    remesh(mesh, &opts(target), &NoProgress).unwrap_or_else(|e| panic!("remesh failed: {e}"))
}

/// Every output must be a closed pure-quad 2-manifold with the input's Euler characteristic, no vertex of
/// valence below 3, no flipped face and a vertex count within 10 % of the target.
fn assert_valid(o: &QuadStats, r: &RemeshReport, what: &str) {
    assert_eq!(o.quad_fraction, 1.0, "{what}: faces by degree {:?}", o.faces_by_degree);
    assert!(o.closed, "{what}: {} boundary edges", o.boundary_edges);
    assert_eq!((o.nonmanifold_edges, o.nonmanifold_vertices), (0, 0), "{what}: non-manifold");
    assert_eq!(o.euler_characteristic, r.input_euler_characteristic, "{what}: Euler characteristic");
    assert!(o.min_valence >= 3, "{what}: valences {:?}", o.valence_histogram);
    assert_eq!(o.flipped_faces, 0, "{what}: flipped faces");
    assert!(r.vertex_count_error.abs() <= 0.10, "{what}: {} vertices for target {}", o.vertices, r.target_vertices);
}

#[test]
fn torus_field_is_nearly_regular() {
    // A torus admits a singularity-free cross field (along the principal directions). Its valences sum to
    // exactly 4V. The extrinsic smoothness alone keeps 16 orientation singularities here; the principal
    // directions are coherent over the whole torus (0.997), so the field follows them (COHERENT_PULL) and
    // has none. The isotropic lattice cannot tile rings of lengths 0.6·2π … 1.4·2π without position
    // singularities; they are cancelled in pairs. Measured: 8 irregular vertices of 1968 at seed 0 (71
    // without the coherent pull), 13–102 at seeds 1–5.
    let t = torus(1.0, 0.4, 200, 80);
    let (_, r) = run(&t, 2000);
    let o = &r.output;
    assert_valid(o, &r, "torus");
    assert_eq!(o.euler_characteristic, 0);
    let deficit: i64 = o.valence_histogram.iter().map(|(&k, &n)| (4 - k as i64) * n as i64).sum();
    assert_eq!(deficit, 0, "torus: valences {:?}", o.valence_histogram);
    println!(
        "torus: {} orientation singularities (coherence {:?}), irregular {} valences {:?}, mode {:?}, cancellation {:?}",
        r.orientation_singularities,
        r.curvature_coherence,
        o.irregular_vertices,
        o.valence_histogram,
        r.mode,
        r.cancellation
    );
    println!("torus: other routes {:?}", r.alternatives);
    let coherence = r.curvature_coherence.expect("the curvature pull is on");
    assert!(coherence > 0.99, "torus: principal directions coherent only to {coherence}");
    assert_eq!(r.orientation_singularities, 0, "torus: orientation singularities");
    assert!(
        o.irregular_fraction <= 0.01,
        "torus: {} irregular vertices {:?}",
        o.irregular_vertices,
        o.valence_histogram
    );
    // Without the coherent pull the field keeps its singularities (the oracle above is not vacuous).
    let plain = RemeshOptions { coherent_pull: 0.0, ..opts(2000) };
    let (_, r0) = remesh(&t, &plain, &NoProgress).unwrap();
    assert!(r0.orientation_singularities >= 8, "torus without the pull: {}", r0.orientation_singularities);
}

#[test]
fn sphere_field_has_eight_valence_deficits() {
    // Σ(4 − valence) = 4χ = 8 on a closed genus-0 quad mesh: at least 8 valence-3 vertices.
    let s = icosphere(1.0, 5, [0.0; 3]);
    let (q, r) = run(&s, 2000);
    let o = &r.output;
    assert_valid(o, &r, "sphere");
    let deficit: i64 = o.valence_histogram.iter().map(|(&k, &n)| (4 - k as i64) * n as i64).sum();
    assert_eq!(deficit, 8, "sphere: valences {:?}", o.valence_histogram);
    println!("sphere: irregular {} valences {:?}, {:?}", o.irregular_vertices, o.valence_histogram, r.dipole_transport);
    // Position singularities come in 3–5 pairs: 61 of 2000 as extracted; 22 once pairs are cancelled
    // (integer::cancel_pairs with the longer reach); 14 (11 of valence 3, 3 of valence 5) when paths may end
    // in the 8 cones (kept by the trade rule). The guarded dipole transport finds no chain for the three 3–5
    // pairs left, even at depth 8: each glides along its grid line past the cones, 2–3 edges away. The
    // settling phase (a chain's quads may fold on the way, its region is smoothed and checked at the end)
    // cancels one of them at depth 5: 12 (10 of valence 3, 2 of valence 5); depth 7 still leaves those two.
    // Why the cones do not take them up: each pair left is a dislocation (its valence-5 vertex two edges from a
    // valence-3 one), of Burgers vector one lattice step. A cone (a quarter turn R) absorbs only vectors
    // (R − I)t, t a lattice vector, whose two components sum to an even number, and turning by R keeps that
    // parity; so a unit dislocation stays until it meets the other one, far across the sphere. The issue's
    // target is 8 ± a few.
    assert!(o.irregular_vertices <= 12, "sphere: {} irregular {:?}", o.irregular_vertices, o.valence_histogram);
    assert!(r.dipole_transport.settled_chains >= 1, "sphere: {:?}", r.dipole_transport);
    let t = &r.dipole_transport;
    assert!(t.irregularity_after <= t.irregularity_before, "sphere: {t:?}");
    let kept: Vec<_> = r.cancellation.iter().filter(|t| t.kept).collect();
    assert_eq!(kept.len(), 1, "sphere: the cancelled extraction should win: {:?}", r.cancellation);
    assert!(kept[0].counts.singular_after * 2 < kept[0].counts.singular_before, "sphere: {:?}", kept[0].counts);
    assert!(kept[0].into_cones, "sphere: the try ending in cones should win: {:?}", r.cancellation);
    // Only tries with fewer irregular vertices are fitted, fewest first, until one is kept: none fitted has
    // more than the kept one, each fitted one was measured, and the kept one is the report's output.
    for t in &r.cancellation {
        assert!(!t.fitted || t.irregular_fraction <= kept[0].irregular_fraction, "sphere: {:?}", r.cancellation);
        assert_eq!(t.fitted, t.rms_pct_of_diagonal > 0.0, "sphere: {t:?}");
    }
    assert_eq!(kept[0].irregular_fraction, o.irregular_fraction, "sphere: the kept try is the output");
    // Analytic oracle: every vertex lies on the unit sphere up to the icosphere's chordal error.
    let worst = q.positions.iter().map(|p| (p.iter().map(|&c| (c as f64).powi(2)).sum::<f64>().sqrt() - 1.0).abs());
    let worst = worst.fold(0.0, f64::max);
    assert!(worst < 2e-3, "sphere: a vertex is {worst} off the sphere");
    let d = r.distance.as_ref().expect("measured");
    assert!(d.symmetric.rms.pct_of_diagonal < 0.1, "sphere: RMS {}% of diagonal", d.symmetric.rms.pct_of_diagonal);
}

#[test]
fn remesh_is_deterministic() {
    let t = torus(1.0, 0.3, 120, 40);
    let (a, _) = run(&t, 1500);
    let (b, _) = run(&t, 1500);
    assert_eq!(a, b);
}

#[test]
fn vertex_count_follows_the_target() {
    let s = icosphere(1.0, 5, [0.0; 3]);
    for target in [500, 1000, 4000] {
        let (_, r) = run(&s, target);
        assert_valid(&r.output, &r, &format!("sphere at {target}"));
    }
}

#[test]
fn open_input_is_refused_with_a_stable_code() {
    let mut s = icosphere(1.0, 3, [0.0; 3]);
    s.triangles.pop();
    let e = remesh(&s, &opts(500), &NoProgress).unwrap_err();
    assert_eq!(e.code, ErrorCode::RemeshInputNotClosed);
    assert!(e.to_string().contains("boundary edges"), "{e}");
}

#[test]
fn absurd_targets_and_budgets_are_refused() {
    let s = icosphere(1.0, 3, [0.0; 3]);
    assert_eq!(remesh(&s, &opts(3), &NoProgress).unwrap_err().code, ErrorCode::InputBadArgument);
    assert_eq!(remesh(&s, &opts(20_000_000), &NoProgress).unwrap_err().code, ErrorCode::InputBadArgument);
    let tight = RemeshOptions { memory_budget: 1000, ..opts(500) };
    assert_eq!(remesh(&s, &tight, &NoProgress).unwrap_err().code, ErrorCode::ResourceMemoryBudget);
}

proptest! {
    /// The field's inline floor and round are `f64::floor` / `f64::round` then `as i64`, bit for bit,
    /// from tiny to saturating magnitudes, halves and NaN included.
    #[test]
    fn inline_floor_and_round_match_std(m in -1.0e6f64..1.0e6, e in -30i32..70, half in any::<bool>()) {
        use scanstation::stages::remesh::field::{floor_i64, round_i64};
        let x = if half { (m.trunc() + 0.5).copysign(m) } else { m * 2f64.powi(e) };
        for y in [x, -x, f64::NAN, f64::INFINITY, -f64::INFINITY, 0.49999999999999994, -0.5, -0.0] {
            prop_assert_eq!(floor_i64(y), y.floor() as i64, "floor {}", y);
            prop_assert_eq!(round_i64(y), y.round() as i64, "round {}", y);
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 6, ..ProptestConfig::default() })]
    /// Tori of any proportions and targets give valid pure-quad meshes.
    #[test]
    fn tori_remesh_validly(minor in 0.25f64..0.5, target in 600usize..2000, seed in 0u64..1000) {
        let t = torus(1.0, minor, 120, 48);
        let o = RemeshOptions { seed, ..opts(target) };
        let (_, r) = remesh(&t, &o, &NoProgress).unwrap();
        assert_valid(&r.output, &r, &format!("torus minor {minor} target {target} seed {seed}"));
    }
}

/// The six quads of the unit cube whose vertex i is at (i & 1, i >> 1 & 1, i >> 2 & 1), outward.
fn cube_quads() -> Vec<Vec<u32>> {
    vec![vec![0, 2, 3, 1], vec![4, 5, 7, 6], vec![0, 1, 5, 4], vec![2, 6, 7, 3], vec![0, 4, 6, 2], vec![1, 3, 7, 5]]
}

/// The valence pass never applies an operation that would take a vertex below valence 3: on a cube
/// (eight valence-3 corners, the minimum for a closed genus-0 quad mesh) it changes nothing.
#[test]
fn valence_pass_leaves_a_cube_alone() {
    use scanstation::stages::remesh::quadify::optimize_valence;
    let mut p: Vec<[f64; 3]> = (0..8).map(|i| [(i & 1) as f64, ((i >> 1) & 1) as f64, ((i >> 2) & 1) as f64]).collect();
    let mut faces = cube_quads();
    // Faces as corner positions (the pass renumbers vertices in first-use order).
    let corners = |p: &[[f64; 3]], faces: &[Vec<u32>]| -> Vec<Vec<[f64; 3]>> {
        faces.iter().map(|f| f.iter().map(|&v| p[v as usize]).collect()).collect()
    };
    let before = corners(&p, &faces);
    let c = optimize_valence(&mut p, &mut faces, 5);
    assert_eq!((c.diagonal_collapses, c.edge_rotations), (0, 0));
    assert_eq!((c.irregularity_before, c.irregularity_after), (8, 8));
    assert_eq!(corners(&p, &faces), before);
    assert_eq!(p.len(), 8);
}

/// Regression (CI, dragon at 20k): extraction pinched a 12-quad closed piece off a thin part, and the solid
/// built on it had two shells. Pieces beyond the input's count are dropped, the smallest first, and
/// counted: here a cube (6 quads) beside a cube split 2 × 2 per side (24 quads).
#[test]
fn pieces_pinched_off_are_dropped_and_counted() {
    use scanstation::stages::remesh::quadify::{CleanupCounts, keep_largest_components};
    let small = cube_quads();
    let big = scanstation::geometry::shapes::quad_ball(1.0, 2);
    let off = 8u32;
    let mut faces: Vec<Vec<u32>> = small.clone();
    faces.extend(big.faces().map(|f| f.iter().map(|&v| v + off).collect::<Vec<u32>>()));
    let mut counts = CleanupCounts::default();
    let mut kept = faces.clone();
    keep_largest_components(&mut kept, 2, &mut counts);
    assert_eq!(kept, faces, "two pieces wanted, two kept");
    assert_eq!(counts.components_dropped, 0);
    keep_largest_components(&mut kept, 1, &mut counts);
    assert_eq!(kept.len(), 24, "the 24-quad ball stays");
    assert!(kept.iter().flatten().all(|&v| v >= off), "the cube's faces are gone");
    assert_eq!((counts.components_dropped, counts.component_faces_dropped), (1, 6));
}

/// An n × m quad grid on a torus (radii `big`, `small`): positions and quads; vertex (i, j) is `(i % n)·m + j % m`.
fn torus_grid(n: u32, m: u32, big: f64, small: f64) -> (Vec<[f64; 3]>, Vec<Vec<u32>>) {
    let id = move |i: u32, j: u32| (i % n) * m + (j % m);
    let mut p: Vec<[f64; 3]> = Vec::new();
    for i in 0..n {
        for j in 0..m {
            let (u, v) = (std::f64::consts::TAU * i as f64 / n as f64, std::f64::consts::TAU * j as f64 / m as f64);
            let r = big + small * v.cos();
            p.push([r * u.cos(), r * u.sin(), small * v.sin()]);
        }
    }
    let faces = (0..n)
        .flat_map(|i| (0..m).map(move |j| vec![id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1)]))
        .collect();
    (p, faces)
}

/// Regression (dragon at 20k, seeds 1 and 2): the bounded path search (60 steps) left the last two triangles
/// unpaired in 3 of 4 direct extractions, so the direct route was unusable. Two triangles 100 quads apart on
/// a 200 × 4 torus grid: the bounded search leaves both, an unbounded one pairs them and keeps a closed
/// pure-quad torus (χ 0).
#[test]
fn far_apart_triangles_pair_with_an_unbounded_search() {
    use scanstation::geometry::polygon::polygon_check;
    use scanstation::stages::remesh::quadify::{CleanupCounts, pair_triangles_along_paths};
    let (n, m) = (200u32, 4u32);
    let id = |i: u32, j: u32| (i % n) * m + (j % m);
    let (p, grid) = torus_grid(n, m, 10.0, 0.5);
    // Row 0, columns 0..=k: re-cut the strip of k quads into a triangle, k − 1 slanted quads and a triangle.
    let k = 100u32;
    let (b, t) = (|i: u32| id(i, 0), |i: u32| id(i, 1));
    // Grid face (i, j) is number i·m + j.
    let mut faces: Vec<Vec<u32>> = grid
        .into_iter()
        .enumerate()
        .filter(|&(f, _)| !(f as u32 % m == 0 && f as u32 / m < k))
        .map(|(_, q)| q)
        .collect();
    faces.push(vec![b(0), b(1), t(0)]);
    faces.extend((0..k - 1).map(|i| vec![b(i + 1), b(i + 2), t(i + 1), t(i)]));
    faces.push(vec![b(k), t(k), t(k - 1)]);
    assert_eq!(polygon_check(&faces), (0, true), "the re-cut torus is a closed manifold");
    let mut counts = CleanupCounts::default();
    let mut bounded = faces.clone();
    assert_eq!(pair_triangles_along_paths(&p, &mut bounded, 60, &mut counts), 2, "60 steps do not reach");
    let unbounded = faces.len();
    assert_eq!(pair_triangles_along_paths(&p, &mut faces, unbounded, &mut counts), 0);
    assert!(faces.iter().all(|f| f.len() == 4));
    assert_eq!(polygon_check(&faces), (0, true), "still a closed manifold torus");
    assert_eq!(faces.len(), (n * m) as usize, "V = F on a closed quad torus");
}

/// A quad still flipped after unfolding is collapsed along a diagonal: on an 8 × 6 torus grid the two
/// corners merge (valence 6), the other two drop to valence 3, and the mesh stays a closed pure-quad torus
/// with one vertex and one face fewer.
#[test]
fn collapsing_a_quad_keeps_a_closed_quad_torus() {
    use scanstation::geometry::polygon::polygon_check;
    use scanstation::stages::remesh::quadify::collapse_quads;
    let (n, m) = (8u32, 6u32);
    let (mut p, mut faces) = torus_grid(n, m, 2.0, 0.5);
    assert_eq!(collapse_quads(&mut p, &mut faces, &[7]), 1);
    assert_eq!((p.len(), faces.len()), ((n * m - 1) as usize, (n * m - 1) as usize));
    assert!(faces.iter().all(|f| f.len() == 4));
    assert_eq!(polygon_check(&faces), (0, true));
    let mut valence = std::collections::BTreeMap::new();
    for (a, b) in scanstation::geometry::polygon::unique_edges(faces.iter().map(Vec::as_slice)) {
        *valence.entry(a).or_insert(0) += 1;
        *valence.entry(b).or_insert(0) += 1;
    }
    let mut hist = std::collections::BTreeMap::new();
    for v in valence.values() {
        *hist.entry(*v).or_insert(0) += 1;
    }
    assert_eq!(hist, [(3, 2), (4, (n * m - 4) as usize), (6, 1)].into_iter().collect());
    // A second collapse touching the first one's ring is refused in the same call.
    let (mut p2, mut f2) = (p.clone(), faces.clone());
    let near: Vec<usize> = (0..f2.len()).filter(|&f| f2[f].iter().any(|&v| valence[&v] == 6)).collect();
    assert_eq!(collapse_quads(&mut p2, &mut f2, &near[..2]), 1);
}

/// The valence pass is deterministic (it must not depend on hash-map order, which differs between runs and
/// between map instances) and lowers Σ|valence − 4|: a torus quad grid made irregular by random edge
/// rotations is optimised twice with identical results, and ends more regular than it started.
#[test]
fn valence_pass_is_deterministic_and_improves() {
    use scanstation::geometry::sampling::Rng;
    use scanstation::stages::remesh::quadify::optimize_valence;
    let (n, m) = (24u32, 12u32);
    let (p, mut faces) = torus_grid(n, m, 1.0, 0.4);
    // Disturb: rotate the edge between quads (i, j) and (i + 1, j) at random, densely (pairs of columns do
    // not overlap, rows are adjacent), so that many equally good repairs compete and order decides.
    let mut rng = Rng::new(7);
    for i in (0..n).step_by(2) {
        for j in 0..m {
            if rng.next_f64() < 0.5 {
                let (f1, f2) = ((i * m + j) as usize, (((i + 1) % n) * m + j) as usize);
                // f1 = (a, b, c, d) with shared edge b–c; f2 = (b, e, f, c). New diagonal a–f… use (d, e).
                let (a, b, c, d) = (faces[f1][0], faces[f1][1], faces[f1][2], faces[f1][3]);
                let (e, f) = (faces[f2][1], faces[f2][2]);
                faces[f1] = vec![a, b, e, d];
                faces[f2] = vec![d, e, f, c];
            }
        }
    }
    let run = || {
        let (mut p2, mut f2) = (p.clone(), faces.clone());
        let c = optimize_valence(&mut p2, &mut f2, 10);
        (p2, f2, c.irregularity_before, c.irregularity_after, c.edge_rotations + c.diagonal_collapses)
    };
    let first = run();
    assert!(first.2 > 0, "the disturbed grid must be irregular");
    assert!(first.3 < first.2, "irregularity {} → {}", first.2, first.3);
    assert!(first.4 > 0, "some operation applied");
    for _ in 0..5 {
        let again = run();
        assert!(again.0 == first.0 && again.1 == first.1, "the valence pass must be deterministic");
    }
}

/// A torus (major radius 1) whose tube narrows from radius 0.3 at angle 0 to 0.065 opposite: a thin neck
/// on a thick body, closed, χ 0.
fn necked_torus() -> TriMesh {
    let mut t = torus(1.0, 0.3, 360, 48);
    for p in &mut t.positions {
        let (x, y, z) = (p[0] as f64, p[1] as f64, p[2] as f64);
        let phi = y.atan2(x);
        let (c, s) = (phi.cos(), phi.sin());
        // Scale the offset from the tube's centre line: 1 at phi = 0, 0.065/0.3 at phi = π.
        let f = 0.065 / 0.3 + (1.0 - 0.065 / 0.3) * 0.5 * (1.0 + c);
        let (dx, dy) = (x - c, y - s);
        *p = [(c + f * dx) as f32, (s + f * dy) as f32, (f * z) as f32];
    }
    t
}

/// The neck of `necked_torus` is thinner than twice the uniform split route's spacing: that route alone
/// loses it (the tube is cut or closed, so χ or the distance gives it away). The cascade keeps it through
/// the adaptive split route (finer spacing where the ray-cast thickness is small): χ 0, every invariant,
/// and the input → quad distance stays small.
#[test]
fn a_thin_neck_survives_through_the_adaptive_route() {
    let t = necked_torus();
    let target = 1500;
    // Without the cancellation of position singularities: its re-solve at a finer spacing (to bring back
    // the rows it removes) keeps this neck on the uniform route too (max 0.57 %), which is not what this
    // test is about. Nor the stronger curvature pull of coherent surfaces (this one is a surface of
    // revolution): with it the lattice follows the tube's rings and the uniform route keeps the neck too
    // (input→quad max 0.55 %).
    // Nor the direct routes, which the next test is about (on their finer working mesh the direct route
    // keeps this neck too, closer than the adaptive split).
    let base = RemeshOptions { cancel_singularities: false, coherent_pull: 0.0, try_direct: false, ..opts(target) };
    let uniform = RemeshOptions { adaptive_spacing: false, try_direct: false, ..base.clone() };
    let (_, u) = remesh(&t, &uniform, &NoProgress).unwrap();
    let du = u.distance.as_ref().unwrap().reference_to_test.max.pct_of_diagonal;
    println!("uniform split: χ {} input→quad max {du:.3} %", u.output.euler_characteristic);
    assert!(
        u.euler_characteristic_changed || du > 1.0,
        "the uniform split kept the neck (χ {}, max {du} %): the test shape no longer tests anything",
        u.output.euler_characteristic
    );
    let (_, r) = remesh(&t, &base, &NoProgress).unwrap();
    let o = &r.output;
    let d = r.distance.as_ref().unwrap();
    println!(
        "cascade: {:?}, {} thin working vertices, irregular {} ({:.2} %), RMS {:.4} %, input→quad max {:.3} %",
        r.mode,
        r.thin_vertices,
        o.irregular_vertices,
        100.0 * o.irregular_fraction,
        d.symmetric.rms.pct_of_diagonal,
        d.reference_to_test.max.pct_of_diagonal
    );
    println!("alternatives {:?}", r.alternatives);
    assert_valid(o, &r, "necked torus");
    assert_eq!(o.euler_characteristic, 0);
    assert_eq!(r.mode, Some(Mode::AdaptiveSplit), "alternatives {:?}", r.alternatives);
    assert!(r.thin_vertices > 0, "the neck was not measured as thin");
    // Measured: max 0.76 % and RMS 0.144 % (the uniform split: max 10 %, RMS 0.81 %).
    assert!(d.reference_to_test.max.pct_of_diagonal < 1.0, "a part of the neck is missing: {d:?}");
    assert!(d.symmetric.rms.pct_of_diagonal < 0.2, "RMS {} %", d.symmetric.rms.pct_of_diagonal);
}

/// Where the direct route's lattice cannot follow a thin part, the refined direct route solves again with a
/// finer spacing there ([`scanstation::stages::remesh::REFINE_TRIES`]) and is kept when it is
/// `FIDELITY_RATIO` times closer to the input. On the necked torus without the adaptive split route, the
/// uniform split loses the neck; on the direct routes' own finer working mesh
/// ([`scanstation::stages::remesh::WORK_PER_VERTEX_DIRECT`]) the direct route keeps it; on the coarser one
/// the split routes use, it keeps it only coarsely and the refined route is closer.
#[test]
fn the_refined_direct_route_recovers_what_the_direct_route_missed() {
    let t = necked_torus();
    let base = RemeshOptions { cancel_singularities: false, coherent_pull: 0.0, adaptive_spacing: false, ..opts(1500) };
    let (_, r) = remesh(&t, &base, &NoProgress).unwrap();
    let d = r.distance.as_ref().unwrap();
    println!(
        "finer direct working mesh ({} vertices): {:?}, RMS {:.4} %, input→quad max {:.3} %",
        r.direct_working_vertices, r.mode, d.symmetric.rms.pct_of_diagonal, d.reference_to_test.max.pct_of_diagonal
    );
    assert_valid(&r.output, &r, "necked torus, direct");
    assert_eq!(r.mode, Some(Mode::Direct), "alternatives {:?}", r.alternatives);
    assert!(r.direct_working_vertices > r.working_vertices, "{} working vertices", r.direct_working_vertices);
    // Measured: RMS 0.085 %, max 0.48 %.
    assert!(d.symmetric.rms.pct_of_diagonal < 0.1, "RMS {} %", d.symmetric.rms.pct_of_diagonal);
    assert!(d.reference_to_test.max.pct_of_diagonal < 1.0, "a part of the neck is missing: {d:?}");

    let o = RemeshOptions { work_per_vertex_direct: scanstation::stages::remesh::WORK_PER_VERTEX, ..base };
    let (_, r) = remesh(&t, &o, &NoProgress).unwrap();
    let d = r.distance.as_ref().unwrap();
    println!(
        "{:?}: missed {} working vertices, RMS {:.4} %, input→quad max {:.3} %, irregular {:.2} %, attempts {:?}, alternatives {:?}",
        r.mode,
        r.missed_vertices,
        d.symmetric.rms.pct_of_diagonal,
        d.reference_to_test.max.pct_of_diagonal,
        100.0 * r.output.irregular_fraction,
        r.attempts.iter().map(|a| (a.mode, a.refine)).collect::<Vec<_>>(),
        r.alternatives
    );
    assert_valid(&r.output, &r, "necked torus, refined");
    assert_eq!(r.mode, Some(Mode::RefinedDirect), "alternatives {:?}", r.alternatives);
    assert!(r.missed_vertices > 0, "nothing was missed");
    let direct = r.alternatives.iter().find(|a| a.mode == Mode::Direct).expect("the direct route ran");
    assert!(
        1.25 * d.symmetric.rms.pct_of_diagonal < direct.rms_pct_of_diagonal,
        "refined RMS {} % against direct {} %",
        d.symmetric.rms.pct_of_diagonal,
        direct.rms_pct_of_diagonal
    );
    assert!(d.reference_to_test.max.pct_of_diagonal < 1.0, "a part of the neck is missing: {d:?}");
}

/// A quad mesh of the unit sphere with its vertices on the sphere (the remesher without its fit), the
/// icosphere it came from and area samples of that icosphere for the fit. Built once.
/// Quad positions, quads, the icosphere and its area samples.
type SphereQuads = (Vec<[f64; 3]>, Vec<Vec<u32>>, TriMesh, Vec<[f64; 3]>);

fn sphere_quads() -> &'static SphereQuads {
    use scanstation::geometry::sampling::{Rng, sample_area_uniform};
    static CELL: std::sync::OnceLock<SphereQuads> = std::sync::OnceLock::new();
    CELL.get_or_init(|| {
        let s = icosphere(1.0, 5, [0.0; 3]);
        let (q, _) = remesh(&s, &RemeshOptions { fit_rounds: 0, ..opts(2000) }, &NoProgress).unwrap();
        let p: Vec<[f64; 3]> = q.positions.iter().map(|x| x.map(f64::from)).collect();
        let faces: Vec<Vec<u32>> = q.faces().map(<[u32]>::to_vec).collect();
        let samples = sample_area_uniform(&s, 8 * p.len(), &mut Rng::new(5)).into_iter().map(|x| x.point).collect();
        (p, faces, s, samples)
    })
}

/// Triangle t's normal (its edge cross product) on mesh `s`.
fn triangle_normal(s: &TriMesh, t: u32) -> [f64; 3] {
    let [a, b, c] = s.triangles[t as usize].map(|i| s.positions[i as usize].map(f64::from));
    let (u, v) = ([b[0] - a[0], b[1] - a[1], b[2] - a[2]], [c[0] - a[0], c[1] - a[1], c[2] - a[2]]);
    [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]
}

/// |x|, the distance from the sphere's centre.
fn radius(x: [f64; 3]) -> f64 {
    (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sqrt()
}

/// RMS of (|x| − 1) over area samples of the quad mesh (its quads split as the measurement splits them):
/// the distance to the exact unit sphere.
fn radial_rms(p: &[[f64; 3]], faces: &[Vec<u32>]) -> f64 {
    use scanstation::geometry::sampling::{Rng, sample_area_uniform};
    let positions = p.iter().map(|x| x.map(|c| c as f32)).collect();
    let q = PolyMesh::new(positions, faces).unwrap();
    let (t, _) = q.triangulate();
    let s = sample_area_uniform(&t, 100_000, &mut Rng::new(9));
    (s.iter().map(|x| (radius(x.point) - 1.0).powi(2)).sum::<f64>() / s.len() as f64).sqrt()
}

/// Analytic oracle of the least-squares fit: a quad mesh with its corners on the unit sphere lies inside
/// it by up to the chord height h of each face. The fit moves every vertex outward, by less than the
/// largest h, and the faces then straddle the sphere: the RMS distance to the exact sphere drops by more
/// than 55 % (measured 2026-12-03: 1.29e-3 → 4.39e-4, 66 %), and no face turns over.
#[test]
fn the_fit_moves_a_sphere_s_chords_outward_to_straddle_it() {
    use scanstation::geometry::bvh::TriangleBvh;
    use scanstation::geometry::polygon::polygon_centre;
    use scanstation::stages::remesh::fit::fit_to_surface;
    use scanstation::stages::remesh::quad_stats;
    let (p0, faces, s, samples) = sphere_quads();
    let bvh = TriangleBvh::new(s);
    let h_max = faces.iter().map(|f| 1.0 - radius(polygon_centre(p0, f))).fold(0.0, f64::max);
    let normal = |t: u32| triangle_normal(s, t);
    let mut p = p0.clone();
    let counts = fit_to_surface(&mut p, faces, samples, &bvh, normal, 4);
    let (before, after) = (radial_rms(p0, faces), radial_rms(&p, faces));
    let radii: Vec<f64> = p.iter().map(|&x| radius(x)).collect();
    let (lo, hi) = radii.iter().fold((f64::MAX, 0.0f64), |(l, h), &x| (l.min(x), h.max(x)));
    let msg = format!(
        "radial RMS {before:.3e} → {after:.3e}, vertex radii {lo:.6} … {hi:.6}, largest chord height {h_max:.3e}, {counts:?}"
    );
    println!("sphere fit: {msg}");
    assert!(after < 0.45 * before, "{msg}");
    // Outward (the icosphere's own chords lie up to ~2e-4 inside the sphere), by less than a chord.
    assert!(lo > 1.0 - 2e-4 && hi < 1.0 + h_max, "{msg}");
    assert!(radii.iter().sum::<f64>() / radii.len() as f64 > 1.0, "{msg}");
    assert!(counts.mean_square_last < counts.mean_square_first, "{msg}");
    let positions = p.iter().map(|x| x.map(|c| c as f32)).collect();
    let q = PolyMesh::new(positions, faces).unwrap();
    assert_eq!(quad_stats(&q, Some((s, &bvh))).flipped_faces, 0, "{msg}");
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 8, ..ProptestConfig::default() })]
    /// Invariant of the fit: a quad mesh of the sphere scaled by any k near 1 comes back — its mean radial
    /// offset shrinks to under a tenth of |k − 1| plus the chord heights' share — and its two-sided mean
    /// square residual falls.
    #[test]
    fn the_fit_pulls_an_offset_mesh_back_onto_the_surface(k in 0.96f64..1.04) {
        use scanstation::geometry::bvh::TriangleBvh;
        use scanstation::stages::remesh::fit::fit_to_surface;
        let (p0, faces, s, samples) = sphere_quads();
        let bvh = TriangleBvh::new(s);
        let normal = |t: u32| triangle_normal(s, t);
        let mut p: Vec<[f64; 3]> = p0.iter().map(|x| x.map(|c| c * k)).collect();
        let counts = fit_to_surface(&mut p, faces, samples, &bvh, normal, 4);
        let offset = p.iter().map(|&x| radius(x) - 1.0).sum::<f64>() / p.len() as f64;
        // The fitted sphere's own offset (outward, about half a chord height): measured below 1e-3.
        prop_assert!(offset.abs() < (k - 1.0).abs() / 10.0 + 1e-3, "k {}: mean offset {} ({:?})", k, offset, counts);
        prop_assert!(counts.mean_square_last < counts.mean_square_first, "k {}: {:?}", k, counts);
    }
}

/// Regression (proptest `tori_remesh_validly`, CI run of 2026-12-03): a thin torus at a small target.
#[test]
fn thin_torus_at_771_keeps_its_count() {
    let t = torus(1.0, 0.254585723866076, 120, 48);
    let o = RemeshOptions { seed: 705, ..opts(771) };
    let (_, r) = remesh(&t, &o, &NoProgress).unwrap();
    println!(
        "thin torus: mode {:?} vertices {} transport {:?} cancellation {:?} attempts {:?}",
        r.mode,
        r.output.vertices,
        r.dipole_transport,
        r.cancellation.iter().map(|c| (c.path_cost, c.into_cones, c.vertices, c.fitted, c.kept)).collect::<Vec<_>>(),
        r.attempts.iter().map(|a| (a.mode, a.predicted_vertices)).collect::<Vec<_>>()
    );
    assert_valid(&r.output, &r, "thin torus 771 seed 705");
}

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

/// Crossing triangle pairs of a polygon mesh's triangulation (exact predicates).
fn crossings(q: &PolyMesh) -> usize {
    let (t, _) = q.triangulate();
    let p: Vec<[f64; 3]> = t.positions.iter().map(|x| x.map(f64::from)).collect();
    scanstation::geometry::intersect::self_intersections(&p, &t.triangles).len()
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

/// A torus (major radius 1) whose tube narrows from radius 0.3 at angle 0 to 0.065 opposite: a thin neck
/// on a thick body, closed, χ 0.
fn necked_torus() -> TriMesh {
    necked_torus_with(360, 48, 0.065)
}

/// [`necked_torus`] with `n` × `m` vertices and the neck's radius `neck`.
fn necked_torus_with(n: usize, m: usize, neck: f64) -> TriMesh {
    let mut t = torus(1.0, 0.3, n, m);
    for p in &mut t.positions {
        let (x, y, z) = (p[0] as f64, p[1] as f64, p[2] as f64);
        let phi = y.atan2(x);
        let (c, s) = (phi.cos(), phi.sin());
        // Scale the offset from the tube's centre line: 1 at phi = 0, neck/0.3 at phi = π.
        let f = neck / 0.3 + (1.0 - neck / 0.3) * 0.5 * (1.0 + c);
        let (dx, dy) = (x - c, y - s);
        *p = [(c + f * dx) as f32, (s + f * dy) as f32, (f * z) as f32];
    }
    t
}

/// The neck of `necked_torus` is thinner than twice the uniform split route's spacing. That route alone lost
/// it (χ or the distance gave it away: input → quad max 10 %, RMS 0.81 %) until clusters whose members face
/// apart were turned about their fold's bisector (`extract::FOLD_MEAN`, 2026-12-06): now the uniform split
/// keeps it (measured: χ 0, max 0.452 %, RMS 0.048 %), with every invariant. (A neck of 0.055 it still loses,
/// χ 2, max 2.9 %, and so does the adaptive route: the thickness-driven spacing of issue 42 is still to come.)
#[test]
fn a_thin_neck_survives_the_uniform_split() {
    let t = necked_torus();
    let target = 1500;
    // Without the cancellation of position singularities and the stronger curvature pull of coherent
    // surfaces (this one is a surface of revolution), each of which kept this neck on their own before.
    let uniform = RemeshOptions {
        cancel_singularities: false,
        coherent_pull: 0.0,
        try_direct: false,
        adaptive_spacing: false,
        ..opts(target)
    };
    let (q, u) = remesh(&t, &uniform, &NoProgress).unwrap();
    let d = u.distance.as_ref().unwrap();
    println!(
        "uniform split: {:?}, χ {}, input→quad max {:.3} %, RMS {:.4} %",
        u.mode, u.output.euler_characteristic, d.reference_to_test.max.pct_of_diagonal, d.symmetric.rms.pct_of_diagonal
    );
    assert_valid(&u.output, &u, "necked torus, uniform split");
    assert_eq!(u.mode, Some(Mode::Split));
    assert_eq!(u.output.euler_characteristic, 0);
    assert_eq!(crossings(&q), 0, "the neck's sides cross");
    assert!(d.reference_to_test.max.pct_of_diagonal < 1.0, "a part of the neck is missing: {d:?}");
    assert!(d.symmetric.rms.pct_of_diagonal < 0.1, "RMS {} %", d.symmetric.rms.pct_of_diagonal);
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
    // The direct net keeps the neck. Since its working mesh is edge-split also when subdivision made as many
    // vertices as asked (2026-12-07: 28,076 vertices), it is as close as the uniform split's (0.0488 against
    // 0.0479 %), not `FIDELITY_RATIO` closer, so the uniform split, which ran first, is kept; before, the
    // direct net (0.085 %) was.
    let direct = std::iter::once((r.mode, d.symmetric.rms.pct_of_diagonal))
        .chain(r.alternatives.iter().map(|a| (Some(a.mode), a.rms_pct_of_diagonal)))
        .find(|(m, _)| *m == Some(Mode::Direct));
    assert!(direct.is_some_and(|(_, rms)| rms < 0.1), "the direct net: alternatives {:?}", r.alternatives);
    assert!(r.direct_working_vertices > r.working_vertices, "{} working vertices", r.direct_working_vertices);
    // Measured: RMS 0.085 %, max 0.48 % (2026-12-07: 0.048 %, 0.45 %).
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
    // The refined route must run and come 1.25 times closer than the direct one. Since the uniform split keeps
    // this neck (see above), the split result, run after the direct routes here, is closer still and kept
    // (measured 2026-12-06: direct 0.194 %, refined 0.065 %, split 0.048 %).
    let rms_of = |m: Mode| {
        if r.mode == Some(m) {
            Some(d.symmetric.rms.pct_of_diagonal)
        } else {
            r.alternatives.iter().find(|a| a.mode == m).map(|a| a.rms_pct_of_diagonal)
        }
    };
    let refined = rms_of(Mode::RefinedDirect).expect("the refined direct route ran");
    let direct = rms_of(Mode::Direct).expect("the direct route ran");
    assert!(1.25 * refined < direct, "refined RMS {refined} % against direct {direct} %");
    assert!(d.symmetric.rms.pct_of_diagonal <= refined, "kept {:?} farther than the refined route", r.mode);
    assert!(d.reference_to_test.max.pct_of_diagonal < 1.0, "a part of the neck is missing: {d:?}");
}

/// A scan coarser than the direct routes' working mesh asks for is used as it is (or subdivided), which left
/// about two edges to a lattice step: the direct extraction then collapsed rows (the 50k scorpion at 10k made
/// 4,429 vertices for 10,000). Its edges longer than half a step are split first
/// ([`scanstation::stages::remesh::WORK_EDGE_SPACINGS`]) and clusters already linked are not joined
/// ([`scanstation::stages::remesh::LINKED_GUARD`]). A necked torus of 1,920 vertices remeshed directly at 1,500
/// (its working mesh subdivided once, to 7,680, for 15,000 asked): the direct result keeps the neck, its
/// quads do not cross, and its working mesh grew by the split (measured: 16,928 vertices, RMS 0.060 %, max
/// 0.48 %, 4.14 % irregular).
#[test]
fn a_coarse_scan_is_split_for_the_direct_route() {
    let t = necked_torus_with(120, 16, 0.065);
    let base = RemeshOptions { cancel_singularities: false, coherent_pull: 0.0, adaptive_spacing: false, ..opts(1500) };
    let (q, r) = remesh(&t, &base, &NoProgress).unwrap();
    let d = r.distance.as_ref().unwrap();
    println!(
        "coarse necked torus: {} direct working vertices, {:?}, missed {}, RMS {:.4} %, max {:.3} %, irregular {:.2} %",
        r.direct_working_vertices,
        r.mode,
        r.missed_vertices,
        d.symmetric.rms.pct_of_diagonal,
        d.reference_to_test.max.pct_of_diagonal,
        100.0 * r.output.irregular_fraction
    );
    assert_valid(&r.output, &r, "coarse necked torus");
    assert!(r.direct_working_vertices > 7680, "not split: {} direct working vertices", r.direct_working_vertices);
    assert!(r.mode.is_some_and(Mode::is_direct), "alternatives {:?}", r.alternatives);
    assert_eq!(crossings(&q), 0, "the quads cross");
    assert!(d.symmetric.rms.pct_of_diagonal < 0.1, "RMS {} %", d.symmetric.rms.pct_of_diagonal);
    assert!(d.reference_to_test.max.pct_of_diagonal < 1.0, "a part of the neck is missing: {d:?}");
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

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]
    /// Splitting long edges leaves the surface as it was (the area, χ, closedness) and, given the passes,
    /// no edge longer than the bound; the new vertices lie on the old edges.
    #[test]
    fn splitting_long_edges_keeps_the_surface(max_len in 0.05f64..0.6, n in 6usize..24) {
        use scanstation::geometry::polygon::split_long_edges;
        use scanstation::geometry::topology::TopologyReport;
        let t = torus(1.0, 0.4, n, 6);
        let mut p: Vec<[f64; 3]> = t.positions.iter().map(|x| x.map(f64::from)).collect();
        let mut tris = t.triangles.clone();
        let before = TopologyReport::compute(&PolyMesh::from(t.clone()));
        let added = split_long_edges(&mut p, &mut tris, max_len, 12, usize::MAX);
        prop_assert_eq!(p.len(), t.positions.len() + added);
        let longest = tris
            .iter()
            .flat_map(|t| (0..3).map(move |k| (t[k], t[(k + 1) % 3])))
            .map(|(a, b)| scanstation::geometry::vec3::norm(scanstation::geometry::vec3::sub(p[a as usize], p[b as usize])))
            .fold(0.0, f64::max);
        prop_assert!(longest <= max_len, "longest edge {} > {}", longest, max_len);
        let m = TriMesh { positions: p.iter().map(|x| x.map(|c| c as f32)).collect(), triangles: tris };
        let after = TopologyReport::compute(&PolyMesh::from(m.clone()));
        prop_assert!(after.closed);
        prop_assert_eq!(after.euler_characteristic, before.euler_characteristic);
        prop_assert!((after.area - before.area).abs() <= 1e-5 * before.area, "area {} vs {}", after.area, before.area);
    }
}

/// The spacing at which `target` vertices cover `mesh`: √(area / target).
fn spacing_for(mesh: &TriMesh, target: usize) -> f64 {
    (mesh.area() / target as f64).sqrt()
}

/// Issue 42's thin-plate oracle: a disc flattened to 0.3 % of its diagonal (an icosphere squashed on z),
/// remeshed at 2,000 by `convert`'s routes, is 0.15 of a spacing thick. Its rim's clusters hold both sides'
/// members; their mean normal said nothing, the rotation system traced nonsense and every face was pruned
/// (`remesh.failed: no face was extracted`, as on the falcon statue's base). Turned about the fold's bisector
/// (`extract::FOLD_MEAN`), the net closes, keeps χ = 2 and its sides apart (measured: the split route, 1,907
/// vertices, 0 crossing pairs; its rim pulled in by about one lattice step, RMS 2.18 % of the diagonal).
#[test]
fn a_thin_plate_keeps_its_sides_apart() {
    let mut plate = icosphere(1.0, 6, [0.0; 3]);
    let thickness = 0.003 * 8f64.sqrt();
    for p in &mut plate.positions {
        p[2] *= (thickness / 2.0) as f32;
    }
    let o = RemeshOptions { target_vertices: 2000, compare_samples: 20_000, ..RemeshOptions::convert_default() };
    let (q, r) = remesh(&plate, &o, &NoProgress).unwrap_or_else(|e| panic!("thin plate: {e}"));
    let d = r.distance.as_ref().unwrap();
    println!(
        "thin plate ({:.2} spacings thick): {:?}, {} vertices, χ {}, crossing pairs {:?}, RMS {:.3} %",
        thickness / spacing_for(&plate, 2000),
        r.mode,
        r.output.vertices,
        r.output.euler_characteristic,
        r.output.crossing_pairs,
        d.symmetric.rms.pct_of_diagonal
    );
    assert_valid(&r.output, &r, "thin plate");
    assert_eq!(r.output.crossing_pairs, Some(0), "thin plate: the report's crossing count");
    assert_eq!(crossings(&q), 0, "thin plate: the sides cross");
}

/// Issue 42's cone-tip oracle: a ball under a 15° cone whose tip is a sharp point 3.9 radii up, as a surface of
/// revolution with near-isotropic triangles, remeshed at 10,000 by `convert`'s routes. The tip must not cross
/// itself and the shape keeps χ = 2 and its length (measured: split route, 10,466 vertices, 0 crossings, RMS
/// 0.014 %, max 1.7 % of the diagonal at the tip).
#[test]
fn a_cone_tip_keeps_its_sides_apart() {
    use scanstation::geometry::shapes::{cone_tip_profile, revolve};
    let mut step = 0.05;
    let mut cone = revolve(&cone_tip_profile(15.0, step), false, step);
    for _ in 0..2 {
        step = spacing_for(&cone, 10_000) / 3.0;
        cone = revolve(&cone_tip_profile(15.0, step), false, step);
    }
    let o = RemeshOptions { target_vertices: 10_000, compare_samples: 20_000, ..RemeshOptions::convert_default() };
    let (q, r) = remesh(&cone, &o, &NoProgress).unwrap_or_else(|e| panic!("cone tip: {e}"));
    let d = r.distance.as_ref().unwrap();
    let top = q.positions.iter().map(|p| p[2]).fold(f32::MIN, f32::max);
    println!(
        "cone tip: {} input vertices, {:?}, {} vertices, crossing pairs {:?}, RMS {:.4} %, max {:.3} %, top z {top:.3} of 3.864",
        cone.positions.len(),
        r.mode,
        r.output.vertices,
        r.output.crossing_pairs,
        d.symmetric.rms.pct_of_diagonal,
        d.symmetric.max.pct_of_diagonal
    );
    assert_valid(&r.output, &r, "cone tip");
    assert_eq!(crossings(&q), 0, "cone tip: the sides cross");
    assert!(d.symmetric.rms.pct_of_diagonal < 0.05, "cone tip: RMS {} %", d.symmetric.rms.pct_of_diagonal);
    assert!(top > 3.7, "cone tip: the tip is cut at z = {top}");
}

/// The oracles' surfaces of revolution are what they claim: closed 2-manifolds, outward (positive volume
/// near the analytic one), χ 2 for the open profiles and 0 for the folded sheet's closed one.
#[test]
fn the_thin_part_oracles_are_closed_outward_surfaces() {
    use scanstation::geometry::shapes::{cone_tip_profile, folded_sheet_profile, leg_profile, plate_profile, revolve};
    use scanstation::geometry::topology::TopologyReport;
    use std::f64::consts::PI;
    let h = 0.02;
    let cases = [
        ("plate", revolve(&plate_profile(0.01, h), false, h), 2, PI * 0.01),
        ("leg", revolve(&leg_profile(0.1, h), false, h), 2, 2.0 * 4.0 / 3.0 * PI + PI * 0.01 * 2.0),
        ("cone tip", revolve(&cone_tip_profile(30.0, h), false, h), 2, 0.0),
        ("folded sheet", revolve(&folded_sheet_profile(0.2, 0.02, h), true, h), 0, 0.0),
    ];
    for (name, mesh, chi, volume) in cases {
        let topo = TopologyReport::compute(&mesh.clone().into());
        let v = mesh.signed_volume();
        println!("{name}: {} vertices, χ {}, volume {v:.4}", mesh.positions.len(), topo.euler_characteristic);
        assert!(topo.closed && topo.nonmanifold_edges == 0 && topo.nonmanifold_vertices == 0, "{name}: {topo:?}");
        assert_eq!(topo.euler_characteristic, chi, "{name}: χ");
        assert!(v > 0.0, "{name}: inward ({v})");
        if volume > 0.0 {
            assert!((v - volume).abs() < 0.05 * volume, "{name}: volume {v} against {volume}");
        }
    }
}

/// `convert`'s default resolution, the deviation goal ([`scanstation::pipeline::goal`]): a net farther than
/// twice the goal from the input is made again ×1.5 finer before the surface is fitted, at most twice and
/// never above the cap, and the solid is built once, on the last net kept. Spot at 300 control vertices is
/// 0.2–0.5 % of its diagonal from the scan, far over 2 × 0.05 %, so both raises run (300 → 450 → 675 = the
/// cap; measured 2026-12-07: 450 kept, 675 not, being farther, 0.528 against 0.483 %); with an exact count
/// nothing is raised.
#[test]
fn the_deviation_goal_raises_a_net_that_misses_it_up_to_the_cap() {
    use scanstation::pipeline::{ConvertOptions, Resolution, convert_file};
    let spot = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/spot.ply");
    let dir = std::env::temp_dir().join(format!("scanstation-goal-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let read = scanstation::geometry::io::ReadOptions::default();
    let goal = ConvertOptions { resolution: Resolution::Goal { start: 300, cap: 675 }, ..Default::default() };
    let r = convert_file(&spot, &dir.join("goal.step"), &read, &goal, &NoProgress).unwrap();
    assert_eq!(r.attempts.len(), 1, "one solid: {:?}", r.attempts);
    let raises = &r.attempts[0].raises;
    let steps: Vec<(usize, usize)> = raises.iter().map(|x| (x.from_vertices, x.to_vertices)).collect();
    assert_eq!(steps, [(300, 450), (450, 675)], "{raises:?}");
    assert!(raises[0].kept, "the first finer net is nearer: {raises:?}");
    for x in raises {
        assert!(x.from_rms_pct > 0.1, "a raise only where the net misses 2 × the goal: {x:?}");
        let sound_and_nearer = x.to_rms_pct < x.from_rms_pct && x.to_crossing_pairs == 0 && !x.to_changed_topology;
        assert_eq!(x.kept, sound_and_nearer, "{x:?}");
    }
    let last = raises.iter().rev().find(|x| x.kept).unwrap();
    // The solid's net is the last one kept, refined locally (about a quarter more vertices at most).
    let local = &r.attempts[0].local;
    let before = local.kept.as_ref().map_or(r.attempts[0].control_vertices, |k| k.vertices_before) as f64;
    let want = last.to_vertices as f64;
    assert!((before / want - 1.0).abs() <= 0.1, "the solid is built on the last net kept ({want}): {before}");
    if let Some(k) = &local.kept {
        assert_eq!(k.vertices_after, r.attempts[0].control_vertices, "{local:?}");
        assert!(k.vertices_after as f64 <= 1.3 * before, "about a quarter more at most: {local:?}");
        assert!(k.rounds.iter().filter(|x| x.kept).all(|x| x.rms_after < x.rms_before), "{local:?}");
    }
    let kept_rms = r.remesh.distance.as_ref().unwrap().symmetric.rms.pct_of_diagonal;
    assert_eq!(kept_rms, last.to_rms_pct, "the report's remesh is the kept net's");
    // An exact count is kept as asked.
    let exact = ConvertOptions { resolution: Resolution::Vertices(300), ..Default::default() };
    let r = convert_file(&spot, &dir.join("exact.step"), &read, &exact, &NoProgress).unwrap();
    assert!(r.attempts.iter().all(|a| a.raises.is_empty() && a.target_vertices == 300), "{:?}", r.attempts);
    assert!(r.attempts.iter().all(|a| a.local.kept.is_none()), "an exact count is not refined: {:?}", r.attempts);
    std::fs::remove_dir_all(&dir).ok();
}

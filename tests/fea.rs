//! FEA stage: immersed quadratic B-spline linear statics. Analytic oracle (cantilever rod against beam
//! theory), invariants (translation, linearity, determinism, equilibrium), and bad specs and surfaces.

use scanstation::assert_near;
use scanstation::geometry::shapes;
use scanstation::geometry::vec3::{norm, sub};
use scanstation::stages::NoProgress;
use scanstation::stages::fea::{self, FeaOptions, FeaSpec, principal, von_mises};
use scanstation::{ErrorCode, TriMesh};

/// The shipped cantilever spec (root face fixed, 10 N tip load in y, probes at x = 50 and the tip centre).
fn rod_spec() -> FeaSpec {
    FeaSpec::from_toml(include_str!("../config/fea/cantilever-rod.toml")).unwrap()
}

/// d = 4.97 mm, L = 200 mm, 96 segments, a ring every 2 mm.
fn rod() -> TriMesh {
    shapes::rod(4.97 / 2.0, 200.0, 96, 100)
}

// Beam theory for the rod (d = 4.97, L = 200, E = 210 000).
const TIP_DEFLECTION: f64 = 4.2399; // F L³ / 3 E I, F = 10 N
const STRESS_X50: f64 = 124.46; // F (L − 50) / W
const STRESS_ROOT: f64 = 165.94; // F L / W
const AXIAL_TIP: f64 = 0.0014728; // Fx L / E A, Fx = 30 N

#[test]
fn cantilever_rod_matches_beam_theory() {
    let sol = fea::solve(&rod(), &rod_spec(), &FeaOptions::default(), &NoProgress).unwrap();
    let r = &sol.report;
    let tip = &r.probes[1];
    assert_near!(tip.displacement[1], TIP_DEFLECTION, 0.01 * TIP_DEFLECTION, "tip deflection (1 %)");
    assert_near!(r.max_displacement.value, TIP_DEFLECTION, 0.01 * TIP_DEFLECTION, "max |u| (1 %)");
    assert!(r.max_displacement.at[0] > 199.0, "max |u| at the tip, got {:?}", r.max_displacement.at);
    let x50 = &r.probes[0];
    assert_near!(x50.von_mises, STRESS_X50, 0.02 * STRESS_X50, "bending stress at x = 50 (2 %)");
    // The load bends the rod up (+y): the fibre at y = +r is in compression.
    assert_near!(x50.stress[0], -STRESS_X50, 0.02 * STRESS_X50, "σxx on the compressed fibre at x = 50");
    // The clamp's corner is singular: the raw maximum (at the corner) and the maximum two cells away.
    assert_near!(r.max_von_mises.value, STRESS_ROOT, 0.05 * STRESS_ROOT, "root max von Mises (5 %)");
    assert!(r.max_von_mises.at[0] < 1.0, "root max at the clamp, got {:?}", r.max_von_mises.at);
    let away = &r.max_von_mises_away_from_supports;
    assert_near!(away.value, STRESS_ROOT, 0.05 * STRESS_ROOT, "max von Mises 2h from the clamp (5 %)");
    // Equilibrium: reactions balance the load.
    assert!(r.imbalance <= 1e-6, "reaction {:?} vs load {:?}: imbalance {:.2e}", r.reaction, r.total_load, r.imbalance);
    assert_near!(r.reaction[1], -10.0, 1e-5, "reaction in y");
    // The immersed domain holds the rod's volume.
    assert_near!(r.volume, r.surface_volume, 2e-3 * r.surface_volume, "immersed volume");
    assert_eq!(r.grid.odd_lines, 0);
    assert_eq!(sol.fields.displacement.len(), rod().positions.len());
}

#[test]
fn axial_tip_load_matches_fl_over_ea() {
    let mut spec = rod_spec();
    spec.loads[0].force = Some([30.0, 10.0, 0.0]);
    let r = fea::solve(&rod(), &spec, &FeaOptions::default(), &NoProgress).unwrap().report;
    let tip = &r.probes[1];
    assert_near!(tip.displacement[0], AXIAL_TIP, 0.01 * AXIAL_TIP, "axial tip displacement (1 %)");
    assert_near!(tip.displacement[1], TIP_DEFLECTION, 0.01 * TIP_DEFLECTION, "bending unchanged");
    assert!(r.imbalance <= 1e-6, "imbalance {:.2e}", r.imbalance);
}

/// A short thick bar, fixed at x ≤ 0 and pulled and bent at its far end: small and fast.
fn bar_case(offset: [f64; 3], scale_force: f64) -> (TriMesh, FeaSpec) {
    let o = offset;
    let mesh = shapes::cuboid([o[0], o[1], o[2]], [o[0] + 20.0, o[1] + 4.0, o[2] + 4.0]);
    let text = format!(
        r#"
        gravity = [0.0, 0.0, -9810.0]
        [material]
        youngs_modulus = 70000.0
        poissons_ratio = 0.33
        density = 2.7e-9
        [[supports]]
        plane = {{ point = [{x0}, 0, 0], normal = [-1, 0, 0] }}
        [[loads]]
        sphere = {{ center = [{x1}, {yc}, {zc}], radius = 1.5 }}
        force = [{f1}, 0.0, {f2}]
        [resolution]
        cell_size = 1.0
        [[probes]]
        name = "end"
        point = [{x1}, {yc}, {zc}]
        "#,
        x0 = o[0] + 1e-3,
        x1 = o[0] + 20.0,
        yc = o[1] + 2.0,
        zc = o[2] + 2.0,
        f1 = 50.0 * scale_force,
        f2 = -5.0 * scale_force,
    );
    (mesh, FeaSpec::from_toml(&text).unwrap())
}

#[test]
fn results_do_not_depend_on_where_the_solid_sits_and_runs_repeat_exactly() {
    let (m0, s0) = bar_case([0.0; 3], 1.0);
    let a = fea::solve(&m0, &s0, &FeaOptions::default(), &NoProgress).unwrap().report;
    let again = fea::solve(&m0, &s0, &FeaOptions::default(), &NoProgress).unwrap().report;
    assert_eq!(a.probes[0].displacement, again.probes[0].displacement, "deterministic");
    assert_eq!(a.max_von_mises.value, again.max_von_mises.value, "deterministic");
    for offset in [[13.25, -7.5, 2.0], [-100.0, 40.0, 0.37]] {
        let (m, s) = bar_case(offset, 1.0);
        let b = fea::solve(&m, &s, &FeaOptions::default(), &NoProgress).unwrap().report;
        let (ua, ub) = (a.probes[0].displacement, b.probes[0].displacement);
        assert!(norm(sub(ua, ub)) <= 2e-3 * norm(ua), "offset {offset:?}: {ua:?} vs {ub:?}");
        assert_near!(
            a.max_displacement.value,
            b.max_displacement.value,
            2e-3 * a.max_displacement.value,
            "offset {offset:?}"
        );
        assert!(b.imbalance <= 1e-6, "offset {offset:?}: imbalance {:.2e}", b.imbalance);
    }
}

#[test]
fn loads_scale_linearly_apart_from_self_weight() {
    // u(2F) − u(F) = u(F) − u(0·F): the response is affine in the load (self-weight is the constant part).
    let solve = |k: f64| {
        let (m, s) = bar_case([0.0; 3], k);
        fea::solve(&m, &s, &FeaOptions::default(), &NoProgress).unwrap().report.probes[0].displacement
    };
    let (u0, u1, u2) = (solve(1e-12), solve(1.0), solve(2.0));
    for k in 0..3 {
        assert_near!(u2[k] - u1[k], u1[k] - u0[k], 1e-8 * norm(u1) + 1e-15, "component {k}");
    }
}

#[test]
fn stress_invariants_of_known_tensors() {
    // Uniaxial tension: von Mises = σ, principal = (σ, 0, 0).
    let s = [100.0, 0.0, 0.0, 0.0, 0.0, 0.0];
    assert_near!(von_mises(&s), 100.0, 1e-12);
    assert_eq!(principal(&s), [100.0, 0.0, 0.0]);
    // Pure shear τ: von Mises = √3 τ, principal = (τ, 0, −τ).
    let s = [0.0, 0.0, 0.0, 50.0, 0.0, 0.0];
    assert_near!(von_mises(&s), 50.0 * 3f64.sqrt(), 1e-9);
    let p = principal(&s);
    assert_near!(p[0], 50.0, 1e-9);
    assert_near!(p[1], 0.0, 1e-9);
    assert_near!(p[2], -50.0, 1e-9);
    // Hydrostatic: von Mises 0.
    assert_near!(von_mises(&[-7.0, -7.0, -7.0, 0.0, 0.0, 0.0]), 0.0, 1e-12);
    // A general symmetric tensor: eigenvalues sum to the trace and are ordered.
    let s = [10.0, -4.0, 3.0, 2.0, -1.5, 0.5];
    let p = principal(&s);
    assert_near!(p[0] + p[1] + p[2], 9.0, 1e-9);
    assert!(p[0] >= p[1] && p[1] >= p[2], "{p:?}");
}

fn code_of(r: scanstation::Result<fea::FeaSolution>) -> ErrorCode {
    match r {
        Ok(_) => panic!("expected an error"),
        Err(e) => e.code,
    }
}

#[test]
fn bad_specs_get_stable_codes() {
    let base = include_str!("../config/fea/cantilever-rod.toml");
    let cases = [
        ("youngs_modulus = 210000.0", "youngs_modulus = -5.0", ErrorCode::FeaBadSpec),
        ("poissons_ratio = 0.3", "poissons_ratio = 0.5", ErrorCode::FeaBadSpec),
        ("poissons_ratio = 0.3", "poissons_ratio = 0.3\nstiffness = 3", ErrorCode::FeaBadSpec),
        ("force = [0.0, 10.0, 0.0]", "force = [0.0, 10.0]", ErrorCode::FeaBadSpec),
        ("force = [0.0, 10.0, 0.0]", "", ErrorCode::FeaBadSpec),
        ("cell_size = 1.0", "cell_size = 0.0", ErrorCode::FeaBadSpec),
    ];
    for (from, to, code) in cases {
        assert!(base.contains(from), "{from}");
        let text = base.replacen(from, to, 1);
        match FeaSpec::from_toml(&text) {
            Ok(_) => panic!("{to:?} accepted"),
            Err(e) => assert_eq!(e.code, code, "{to:?}: {e}"),
        }
    }
    // No supports: singular.
    let no_supports: String = base.replace("[[supports]]", "[[ignored]]");
    let e = FeaSpec::from_toml(&no_supports).unwrap_err();
    assert!(matches!(e.code, ErrorCode::FeaBadSpec | ErrorCode::FeaSingular), "{e}");
    let mut spec = rod_spec();
    spec.supports.clear();
    assert_eq!(code_of(fea::solve(&rod(), &spec, &FeaOptions::default(), &NoProgress)), ErrorCode::FeaSingular);
}

#[test]
fn regions_that_select_nothing_and_open_surfaces_are_refused() {
    let mut spec = rod_spec();
    spec.supports[0].plane.as_mut().unwrap().point = [-5.0, 0.0, 0.0];
    let e = fea::solve(&rod(), &spec, &FeaOptions::default(), &NoProgress).err().unwrap();
    assert_eq!(e.code, ErrorCode::FeaEmptySelection);
    assert!(e.message.contains("root face"), "names the region: {e}");

    let mut open = rod();
    open.triangles.pop();
    assert_eq!(code_of(fea::solve(&open, &rod_spec(), &FeaOptions::default(), &NoProgress)), ErrorCode::FeaOpenSurface);
}

#[test]
fn inward_surfaces_are_turned_outward() {
    let mut m = rod();
    for t in &mut m.triangles {
        t.swap(1, 2);
    }
    let (fixed, v) = fea::closed_solid(&m).unwrap();
    assert!(fixed.signed_volume() > 0.0);
    assert_near!(v, rod().signed_volume(), 1e-9 * v);
}

/// `examples/rod.ply` (the README's FEA sample) is exactly `shapes::rod(2.485, 200, 96, 100)`; set
/// SCANSTATION_REGENERATE=1 to rewrite it.
#[test]
fn bundled_rod_is_the_generated_rod() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/rod.ply");
    let mesh = scanstation::PolyMesh::from(rod());
    if std::env::var_os("SCANSTATION_REGENERATE").is_some() {
        let comment =
            "round rod d = 4.97 mm, L = 200 mm along x (scanstation shapes::rod(2.485, 200, 96, 100)); units mm";
        scanstation::geometry::io::write_ply(&path, &mesh, &Default::default(), &[comment]).unwrap();
    }
    let read = scanstation::geometry::io::read_mesh(&path, &Default::default()).unwrap();
    assert_eq!(read.positions, mesh.positions, "{}", path.display());
    assert_eq!(read.corner_indices(), mesh.corner_indices(), "{}", path.display());
}

/// Patch test for the supports: a 10 × 2.1 × 2.8 bar (ν = 0), its end face x = x0 held, its other end pulled by a
/// uniform traction T, on a grid that cuts both end faces (h = 0.7, 0.36 of a cell in; the side faces lie half a cell in, where the
/// cut-cell line sampling is exact). The exact field
/// u = (T/E)(x − x0) eₓ is linear, so the B-splines hold it; Nitsche's method is consistent and must return it
/// to solver accuracy, while a penalty misses by about T/β at the held face.
#[test]
fn nitsche_supports_pass_the_patch_test_that_a_penalty_misses() {
    let (x0, x1) = (0.13, 10.13);
    let bar = shapes::cuboid([x0, 0.07, 0.11], [x1, 2.17, 2.91]);
    let spec_for = |method: &str| {
        FeaSpec::from_toml(&format!(
            r#"
            [material]
            youngs_modulus = 1000.0
            poissons_ratio = 0.0
            density = 1e-9
            [[supports]]
            plane = {{ point = [{s}, 0.0, 0.0], normal = [-1.0, 0.0, 0.0] }}
            [[loads]]
            plane = {{ point = [{l}, 0.0, 0.0], normal = [1.0, 0.0, 0.0] }}
            force = [12.0, 0.0, 0.0]
            [resolution]
            cell_size = 0.7
            support_method = "{method}"
            [[probes]]
            name = "near the free end"
            point = [9.43, 1.07, 1.51]
            [[probes]]
            name = "middle"
            point = [5.13, 0.5, 2.5]
            "#,
            s = x0 + 1e-3,
            l = x1 - 1e-3,
        ))
        .unwrap()
    };
    let traction = 12.0 / (2.1 * 2.8);
    let exact = |x: f64| traction * (x - x0) / 1000.0;
    let error = |method: &str| {
        let r = fea::solve(&bar, &spec_for(method), &FeaOptions::default(), &NoProgress).unwrap().report;
        assert!(r.imbalance <= 1e-9, "{method}: imbalance {:.2e}", r.imbalance);
        let mut worst: f64 = 0.0;
        for (p, x) in r.probes.iter().zip([9.43, 5.13]) {
            let u = p.displacement;
            worst = worst.max((u[0] - exact(x)).abs() / exact(x1));
            worst = worst.max(u[1].abs().max(u[2].abs()) / exact(x1));
        }
        worst
    };
    let nitsche = error("nitsche");
    let penalty = error("penalty");
    assert!(nitsche <= 1e-6, "Nitsche: relative error {nitsche:.2e} in a linear field");
    assert!(penalty >= 1e-5, "penalty: relative error {penalty:.2e}; expected about T/β");
}

/// The size estimate made before any allocation stays within a factor of 1.5 of what the solve builds (the
/// rod at cell sizes 2 and 1, and spot's solid-like sphere), never below 0.8 of it, so a spec the budget
/// cannot hold is refused up front; and a grid far too fine fails at once with `resource.memory` naming
/// the estimate.
#[test]
fn the_size_estimate_brackets_the_built_system_and_refuses_what_cannot_fit() {
    let cases = [(rod(), 2.0), (rod(), 1.0), (shapes::icosphere(10.0, 4, [0.0; 3]), 1.5)];
    for (mesh, h) in cases {
        let (mesh, volume) = fea::closed_solid(&mesh).unwrap();
        let est = fea::SizeEstimate::new(&mesh, volume, h);
        let mut spec = rod_spec();
        if mesh.bbox().extent()[0] < 100.0 {
            // The sphere: fix its bottom cap, load its top.
            spec.supports[0].plane = Some(fea::spec::HalfSpace { point: [0.0, 0.0, -9.0], normal: [0.0, 0.0, -1.0] });
            spec.loads[0].plane = Some(fea::spec::HalfSpace { point: [0.0, 0.0, 9.0], normal: [0.0, 0.0, 1.0] });
            spec.probes.clear();
        }
        spec.resolution.cell_size = Some(h);
        let built = match fea::solve(&mesh, &spec, &FeaOptions::default(), &NoProgress) {
            Ok(s) => s.report.grid,
            Err(e) => panic!("h {h}: {e}"),
        };
        for (what, e, b) in
            [("functions", est.functions, built.functions), ("cut cells", est.cut_cells, built.cut_cells)]
        {
            let r = e as f64 / b as f64;
            assert!((0.8..=1.5).contains(&r), "h {h}: {what} estimated {e}, built {b} (ratio {r:.2})");
        }
    }
    let mut spec = rod_spec();
    spec.resolution.cell_size = Some(0.05);
    let t = std::time::Instant::now();
    let e = fea::solve(&rod(), &spec, &FeaOptions { memory_budget: 1 << 30 }, &NoProgress).err().unwrap();
    assert_eq!(e.code, ErrorCode::ResourceMemoryBudget, "{e}");
    assert!(e.message.contains("functions") && e.message.contains("MiB"), "names the estimate: {e}");
    assert!(t.elapsed().as_secs_f64() < 5.0, "refused after {:?}", t.elapsed());
}

/// Spec bounds: counts of loads and supports, region sizes against the solid, supports that hold the
/// whole surface and loads that act only where it is held.
#[test]
fn specs_out_of_proportion_are_refused_by_name() {
    let base = include_str!("../config/fea/cantilever-rod.toml");
    let load =
        "\n[[loads]]\nplane = { point = [199.999, 0.0, 0.0], normal = [1.0, 0.0, 0.0] }\nforce = [0.0, 0.01, 0.0]\n";
    let e = FeaSpec::from_toml(&(base.to_string() + &load.repeat(fea::spec::MAX_LOADS))).unwrap_err();
    assert!(e.code == ErrorCode::FeaBadSpec && e.message.contains("at most 64"), "{e}");
    let solve = |spec: &FeaSpec| fea::solve(&rod(), spec, &FeaOptions::default(), &NoProgress).err().unwrap();
    let mut spec = rod_spec();
    spec.supports[0].plane = None;
    spec.supports[0].sphere = Some(fea::spec::Sphere { center: [0.0; 3], radius: 1e308 });
    let e = solve(&spec);
    assert!(e.code == ErrorCode::FeaBadSpec && e.message.contains("root face"), "{e}");
    let mut spec = rod_spec();
    spec.supports[0].plane.as_mut().unwrap().point = [250.0, 0.0, 0.0];
    let e = solve(&spec);
    assert!(e.code == ErrorCode::FeaBadSpec && e.message.contains("hold the whole surface"), "{e}");
    let mut spec = rod_spec();
    spec.loads[0].plane = Some(fea::spec::HalfSpace { point: [0.0005, 0.0, 0.0], normal: [-1.0, 0.0, 0.0] });
    let e = solve(&spec);
    assert!(e.code == ErrorCode::FeaBadSpec && e.message.contains("tip"), "a load on the clamped face: {e}");
}

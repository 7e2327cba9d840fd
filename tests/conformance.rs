//! Conformance suite: our numbers against tools no one here wrote. `compare` must agree with
//! `../shared/validators/mesh_dist.py` (point-cloud-utils, exact point–triangle distances in float64) on real
//! shared meshes: RMS and max within 2 %, per direction and symmetric.
//!
//! Needs the validators' Python environment: `scripts/setup-validators.sh` creates `.venv-validators/`
//! (override the interpreter with `SCANSTATION_VALIDATORS_PYTHON`, the kit with `SCANSTATION_VALIDATORS`).
//! Run with `cargo test --features conformance --test conformance` (`.ci/run` does). Fails, saying how to
//! install, when the environment is missing.

mod common;
#[path = "harness/mod.rs"]
mod harness;

use std::path::{Path, PathBuf};
use std::process::Command;

use scanstation::geometry::io::{ReadOptions, read_geometry};
use scanstation::stages::NoProgress;
use scanstation::stages::quality::{CompareOptions, DistanceStats, compare};
use serde_json::Value;

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn shared(var: &str, rel: &str) -> PathBuf {
    std::env::var_os(var).map(PathBuf::from).unwrap_or_else(|| root().join("../shared").join(rel))
}

fn python() -> PathBuf {
    let py = std::env::var_os("SCANSTATION_VALIDATORS_PYTHON")
        .map(PathBuf::from)
        .unwrap_or_else(|| root().join(".venv-validators/bin/python"));
    assert!(
        py.is_file(),
        "validator Python not found at {}: run `bash scripts/setup-validators.sh` (or set SCANSTATION_VALIDATORS_PYTHON)",
        py.display()
    );
    py
}

fn mesh_dist(a: &Path, b: &Path, samples: usize) -> Value {
    let script = shared("SCANSTATION_VALIDATORS", "validators").join("mesh_dist.py");
    assert!(script.is_file(), "{} missing: the shared validators kit is needed", script.display());
    let out = Command::new(python())
        .arg(&script)
        .arg(a)
        .arg(b)
        .args(["--samples", &samples.to_string()])
        .output()
        .expect("run mesh_dist.py");
    let v: Value = serde_json::from_slice(&out.stdout).unwrap_or_else(|e| {
        panic!("mesh_dist.py printed no JSON ({e}); stderr:\n{}", String::from_utf8_lossy(&out.stderr))
    });
    assert_eq!(v["ok"], true, "mesh_dist.py failed: {v}");
    v
}

fn within(ours: f64, theirs: f64, rel: f64, what: &str) {
    let gap = (ours - theirs).abs() / theirs.abs();
    assert!(gap <= rel, "{what}: ours {ours:.6e}, mesh_dist {theirs:.6e}, relative gap {gap:.4} > {rel}");
    println!("{what}: ours {ours:.6e}, mesh_dist {theirs:.6e}, relative gap {gap:.5}");
}

#[test]
fn compare_agrees_with_point_cloud_utils_on_real_meshes() {
    let data = shared("SCANSTATION_SHARED_DATA", "data");
    // Pairs whose vertices are all on the surface: mesh_dist's max also evaluates *unreferenced* vertices
    // (bun_zipper.ply has 1,113), which are not part of a surface, so our max (referenced vertices only)
    // rightly differs there. 10^6 samples a side make mesh_dist's purely sampled max converge to within
    // ~0.5 % of the true one, which our refined max finds at any sample count.
    let pairs = [
        ("bunny/reconstruction/bun_zipper_res4.ply", "bunny/reconstruction/bun_zipper_res3.ply"),
        ("bunny/reconstruction/bun_zipper_res3.ply", "bunny/reconstruction/bun_zipper_res2.ply"),
    ];
    let samples = 1_000_000;
    for (a, b) in pairs {
        let (pa, pb) = (data.join(a), data.join(b));
        let theirs = mesh_dist(&pa, &pb, samples);
        let opts = ReadOptions::default();
        let (ga, gb) = (read_geometry(&pa, &opts).unwrap(), read_geometry(&pb, &opts).unwrap());
        let ours = compare(&ga, &gb, &CompareOptions { samples, ..Default::default() }, &NoProgress).unwrap();
        let sides: [(&str, &DistanceStats, &Value); 3] = [
            ("a→b", &ours.test_to_reference, &theirs["a_to_b"]),
            ("b→a", &ours.reference_to_test, &theirs["b_to_a"]),
            ("symmetric", &ours.symmetric, &theirs["symmetric"]),
        ];
        for (side, o, t) in sides {
            within(o.rms.value, t["rms"].as_f64().unwrap(), 0.02, &format!("{a} vs {b} {side} rms"));
            within(o.max.value, t["max"].as_f64().unwrap(), 0.02, &format!("{a} vs {b} {side} max"));
        }
    }
}

/// Every repaired shared mesh is a valid volume for trimesh (`is_watertight`, `is_winding_consistent`,
/// `is_volume`), loaded as written (no processing).
#[test]
fn repaired_meshes_are_volumes_for_trimesh() {
    use scanstation::geometry::io::{VertexAttributes, read_mesh, write_ply};
    use scanstation::stages::repair::{RepairOptions, repair};
    let data = shared("SCANSTATION_SHARED_DATA", "data");
    let out_dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("conformance_repair");
    std::fs::create_dir_all(&out_dir).unwrap();
    let files = [
        "bunny/reconstruction/bun_zipper.ply",
        "bunny/reconstruction/bun_zipper_res2.ply",
        "bunny/reconstruction/bun_zipper_res3.ply",
        "bunny/reconstruction/bun_zipper_res4.ply",
        "meshes/spot.ply",
        "meshes/armadillo_50k.ply",
        "meshes/igea.ply",
        "meshes/fandisk.ply",
        "large/dragon_vrip_draco.ply.gz",
    ];
    let mut written = Vec::new();
    for f in files {
        let mesh = read_mesh(&data.join(f), &ReadOptions::default()).unwrap_or_else(|e| panic!("{f}: {e}"));
        let opts = RepairOptions { compare_samples: 2_000, ..Default::default() };
        let (out, _) = repair(&mesh, &opts, &NoProgress).unwrap_or_else(|e| panic!("{f}: {e}"));
        let path = out_dir.join(f.replace('/', "_").replace(".gz", ""));
        write_ply(&path, &out.into(), &VertexAttributes::default(), &[]).unwrap();
        written.push((f, path));
    }
    let script = [
        "import sys, json, trimesh",
        "for p in sys.argv[1:]:",
        "    m = trimesh.load(p, process=False)",
        "    print(json.dumps({'file': p, 'watertight': bool(m.is_watertight),",
        "                      'winding': bool(m.is_winding_consistent), 'volume': bool(m.is_volume)}))",
    ]
    .join("\n");
    let out = Command::new(python()).arg("-c").arg(script).args(written.iter().map(|(_, p)| p)).output().unwrap();
    assert!(out.status.success(), "trimesh check failed: {}", String::from_utf8_lossy(&out.stderr));
    let lines: Vec<Value> =
        String::from_utf8_lossy(&out.stdout).lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(lines.len(), written.len());
    for ((f, _), v) in written.iter().zip(&lines) {
        println!("{f}: {v}");
        for key in ["watertight", "winding", "volume"] {
            assert_eq!(v[key], true, "{f}: trimesh {key} is false: {v}");
        }
    }
}

/// Run a validator script of ours (`tests/tools/NAME`) or of the kit, returning its JSON.
fn run_json(script: &Path, args: &[&std::ffi::OsStr]) -> Value {
    assert!(script.is_file(), "{} missing", script.display());
    let out = Command::new(python()).arg(script).args(args).output().expect("run validator");
    serde_json::from_slice(&out.stdout).unwrap_or_else(|e| {
        panic!("{} printed no JSON ({e}); stderr:\n{}", script.display(), String::from_utf8_lossy(&out.stderr))
    })
}

/// `step_check.py`'s verdict on `what`'s STEP file (printed): OpenCASCADE reads exactly one valid solid with one
/// closed shell and no free edges.
fn assert_one_valid_solid(what: &str, v: &Value) {
    let s = &v["summary"];
    println!("{what}: step_check {s}");
    assert_eq!(s["solids"], 1, "{what}: OCCT solids: {s}");
    assert_eq!(s["shells"], 1, "{what}: OCCT shells: {s}");
    assert_eq!(s["valid"], true, "{what}: BRepCheck_Analyzer invalid: {}", v["occt"]["invalid_subshapes"]);
    assert_eq!(s["all_shells_closed"], true, "{what}: shell not closed: {s}");
    assert_eq!(s["free_edges"], 0, "{what}: free edges: {s}");
}

/// Issue 5 acceptance: every closed shared mesh (and the bunny, repaired on the way) converts to a STEP file
/// that OpenCASCADE reads as exactly one valid solid with one closed shell and no free edges, whose text is
/// closed and consistently oriented as written (OCCT heals on read), whose volume is within 0.5 % of the
/// input's, and that gmsh can tetrahedralise. On armadillo and igea the solid is within 0.05 % of the bbox
/// diagonal (RMS, two-sided) of the input, measured by the validator on the exact B-rep surfaces.
///
/// gmsh must tetrahedralise every one of them.
///
/// Our own checks must find no crossing of the solid's surface (a welded tessellation's triangle pairs) and
/// no folded face (`Solid::folds`), and every solid must keep its largest normal jump across patch edges,
/// ours and OpenCASCADE's, within `MAX_JUMP_DEG` (1°, the target). Until the crease-aware fit,
/// armadillo and the dragon had one folded face each and the dragon 34 crossing pairs.
///
/// An independent counter agrees: OpenCASCADE tessellates the STEP (`step_check.py --tess-out`, deflection
/// 2·10⁻⁴ of the diagonal) and `tests/tools/crossings.py` (numpy, no code of ours) counts its triangle pairs
/// that cross deeper than that deflection: none. (The scorpion's, measured 2026-12-06, has 8 pairs crossing
/// by at most 0.00034 where two faces meet at a tight bend, 0.15 of the 0.00225 deflection: the chords'
/// error, not the surfaces'.)
///
/// The thin-legged scorpion and the genus-2 skull (issue 42) are held to the same as the first six.
///
/// Since the deviation goal became `convert`'s default (issue 42, 2026-12-07) all nine shared meshes are
/// converted at the defaults, the falcon (open base, capped) too, each from one solid (one attempt): the
/// dragon's and the falcon's 10,000-vertex nets are over twice the goal and made again at 15,000 before the
/// fit (the dragon was held at a fixed 20,000 before, the falcon not converted here); the other seven are
/// the solids of a fixed 10,000 (spot was converted at 5,000 before).
#[test]
fn every_closed_shared_mesh_converts_to_a_valid_step_solid() {
    use scanstation::pipeline::{ConvertOptions, Resolution, convert_file};
    let data = shared("SCANSTATION_SHARED_DATA", "data");
    let kit = shared("SCANSTATION_VALIDATORS", "validators");
    let out_dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("conformance_convert");
    std::fs::create_dir_all(&out_dir).unwrap();
    // (file, control vertices, accuracy bound in % of the diagonal checked by the validator, gmsh's cells per
    // diagonal). The scorpion's legs are thinner than a 40th of its diagonal (0.28): at 40 cells gmsh's
    // surface mesh of a leg crosses itself and it makes no tetrahedron (measured 2026-12-06: volumes 1,
    // tetrahedra 0); at 100 it makes 64,700. The dragon and the falcon at the defaults (2026-12-07) keep parts
    // the 10k nets lost (the struts under the dragon's hind foot, the falcon's thin parts): at 40 cells gmsh's
    // surface mesh overlaps itself there ("overlapping facets" on one face, while OCCT's fine tessellation
    // has no crossing pair); at 60 it makes 60,685 and 88,750 tetrahedra.
    // `None`: the default resolution (the deviation goal).
    let cases: [(&str, Option<usize>, Option<f64>, u32); 9] = [
        ("meshes/spot.ply", None, None, 40),
        ("meshes/armadillo_50k.ply", None, Some(0.05), 40),
        ("meshes/igea.ply", None, Some(0.05), 40),
        ("meshes/fandisk.ply", None, None, 40),
        ("bunny/reconstruction/bun_zipper.ply", None, None, 40),
        ("large/dragon_vrip_draco.ply.gz", None, None, 60),
        ("meshes/scorpion.ply", None, None, 100),
        ("meshes/skull.ply", None, None, 40),
        ("meshes/falconstatue_boundary.ply", None, None, 60),
    ];
    // The validators of one solid (OCCT, crossings.py, gmsh: single-threaded Python) run on a thread while
    // the next mesh converts; at most one such thread at a time.
    let mut validating: Option<std::thread::JoinHandle<()>> = None;
    for (file, vertices, accuracy, gmsh_cells) in cases {
        let input = data.join(file);
        let step = out_dir.join(format!("{}.step", file.replace('/', "_").replace(".ply.gz", "").replace(".ply", "")));
        let resolution = vertices.map_or(ConvertOptions::default().resolution, Resolution::Vertices);
        let opts = ConvertOptions { resolution, compare_samples: 50_000, ..Default::default() };
        let report = convert_file(&input, &step, &ReadOptions::default(), &opts, &NoProgress)
            .unwrap_or_else(|e| panic!("{file}: convert failed: {e}"));
        // At the defaults: every gate passed, from one solid.
        assert_eq!(report.status, scanstation::pipeline::Status::Ok, "{file}: gates {:?}", report.gates);
        assert_eq!(report.attempts.len(), 1, "{file}: one solid, not {:?}", report.attempts);
        let solid_rms = report
            .stages
            .iter()
            .find(|s| s.stage == "brep")
            .unwrap()
            .distance
            .as_ref()
            .unwrap()
            .symmetric
            .rms
            .pct_of_diagonal;
        println!(
            "{file}: {} faces from {} quads, volume {:+.4} %, solid RMS {solid_rms:.4} % (ours), max normal jump {:.2}°, {:.1} s",
            report.brep.faces,
            report.fit.control_points,
            report.volume_error_pct,
            report.brep.max_normal_jump_deg,
            report.total_seconds
        );
        if let Some(v) = validating.take() {
            v.join().unwrap_or_else(|e| std::panic::resume_unwind(e));
        }
        let kit = kit.clone();
        validating = Some(std::thread::spawn(move || {
            validate_converted(&Converted { file, input, step, accuracy, gmsh_cells }, &report, &kit)
        }));
    }
    if let Some(v) = validating.take() {
        v.join().unwrap_or_else(|e| std::panic::resume_unwind(e));
    }
}

/// One solid of [`every_closed_shared_mesh_converts_to_a_valid_step_solid`] and what it is checked with.
struct Converted {
    file: &'static str,
    input: PathBuf,
    step: PathBuf,
    /// Accuracy bound checked by the validator, % of the diagonal.
    accuracy: Option<f64>,
    /// gmsh's cells per diagonal.
    gmsh_cells: u32,
}

/// The independent tools' verdicts on one converted solid (the checks of
/// [`every_closed_shared_mesh_converts_to_a_valid_step_solid`]).
fn validate_converted(c: &Converted, report: &scanstation::pipeline::ConvertReport, kit: &Path) {
    // The target. Extraordinary faces are cut towards their vertex until the jump there is below
    // `patches::JUMP_TARGET_DEG` (0.25°), so every solid is held to it.
    const MAX_JUMP_DEG: f64 = 1.0;
    let Converted { file, input, step, accuracy, gmsh_cells } = c;
    let (file, accuracy, gmsh_cells) = (*file, *accuracy, *gmsh_cells);
    let tess = step.with_extension("occt.ply");
    let mut args: Vec<&std::ffi::OsStr> = vec![step.as_os_str(), "--tess-out".as_ref(), tess.as_os_str()];
    if accuracy.is_some() {
        args.extend(["--ref".as_ref(), input.as_os_str(), "--samples".as_ref(), "20000".as_ref()]);
    }
    let v = run_json(&kit.join("step_check.py"), &args);
    assert_one_valid_solid(file, &v);
    let s = &v["summary"];
    assert_eq!(
        s["text_all_shells_closed"], true,
        "{file}: STEP text: an edge not used exactly twice: {}",
        v["step_text"]
    );
    assert_eq!(
        s["text_consistently_oriented"], true,
        "{file}: STEP text: inconsistent orientation: {}",
        v["step_text"]
    );
    assert_eq!(s["faces"].as_u64().unwrap() as usize, report.brep.faces, "{file}: OCCT face count differs from ours");
    // OpenCASCADE's own view of the joins between faces: the largest normal angle across every edge
    // shared by two faces (7 samples per edge), against the 1°.
    let c = &v["occt"]["continuity"];
    println!("{file}: OCCT continuity {c}");
    assert_eq!(c["failed"], 0, "{file}: OCCT could not evaluate some edges: {c}");
    let occt_jump = c["normal_angle_deg_max"].as_f64().unwrap();
    assert!(occt_jump <= MAX_JUMP_DEG, "{file}: OCCT normal angle across an edge {occt_jump:.3}° > {MAX_JUMP_DEG}°");
    let occt_volume = s["volume"].as_f64().unwrap();
    let gap = (occt_volume - report.input_volume).abs() / report.input_volume;
    assert!(
        gap <= 0.005,
        "{file}: OCCT volume {occt_volume:.6e} vs input {:.6e}: {:.3} % > 0.5 %",
        report.input_volume,
        100.0 * gap
    );
    if let Some(bound) = accuracy {
        let rms_pct = s["dist_rms_pct"].as_f64().unwrap();
        assert!(rms_pct <= bound, "{file}: solid RMS {rms_pct:.4} % of the diagonal (validator) > {bound} %");
    }
    let crossings = report.brep.self_intersections;
    println!(
        "{file}: self-intersecting triangle pairs of the solid's tessellation: {crossings} (quad mesh: {})",
        report.brep.quad_self_intersections
    );
    let deflection = v["tessellation"]["deflection"].as_f64().unwrap_or_else(|| panic!("{file}: no tessellation"));
    let x = run_json(
        &root().join("tests/tools/crossings.py"),
        &[tess.as_os_str(), "--tolerance".as_ref(), deflection.to_string().as_ref()],
    );
    println!("{file}: crossings.py on OCCT's tessellation {x}");
    assert_eq!(
        x["crossing_pairs"], 0,
        "{file}: OCCT's tessellation crosses itself deeper than its deflection {deflection:.3e}: {x}"
    );
    let folds = report.brep.folded_faces;
    println!("{file}: folded faces (normal turning > 90° inside a face): {folds} near {:?}", report.brep.fold_at);
    let g = run_json(
        &root().join("tests/tools/gmsh_tetrahedralise.py"),
        &[step.as_os_str(), gmsh_cells.to_string().as_ref()],
    );
    println!("{file}: gmsh {g}");
    assert_eq!(g["volumes"], 1, "{file}: gmsh sees {} volumes", g["volumes"]);
    assert!(g["tetrahedra"].as_u64().unwrap() > 0, "{file}: gmsh made no tetrahedra: {g}");
    assert_eq!(folds, 0, "{file}: {folds} folded faces near {:?}", report.brep.fold_at);
    assert!(
        report.brep.max_normal_jump_deg <= MAX_JUMP_DEG,
        "{file}: largest normal jump {:.3}° > {MAX_JUMP_DEG}° at {:?}",
        report.brep.max_normal_jump_deg,
        report.brep.max_normal_jump_at
    );
    assert_eq!(
        crossings, 0,
        "{file}: the solid intersects itself ({crossings} pairs near {:?})",
        report.brep.self_intersection_at
    );
}

/// Issue 42's quad nets: the scorpion and the skull, repaired as `convert` repairs them, remeshed at 10,000
/// vertices, seed 0, by `scanstation remesh`'s default routes (those of `convert`) and by Instant Meshes 1.0
/// (`quad_peer.py`) from the same file. Our net's triangles (quads fanned) must not cross, by our exact counter
/// (the report's `crossing_pairs`) and by `tests/tools/crossings.py`; the peer's counts are printed beside
/// them (measured 2026-12-06: 0 and 0 for both).
#[test]
fn quad_nets_of_thin_parts_do_not_cross_beside_instant_meshes() {
    use scanstation::geometry::io::{read_mesh, write_obj, write_ply};
    use scanstation::stages::remesh::{RemeshOptions, remesh};
    use scanstation::stages::repair::{RepairOptions, repair};
    let data = shared("SCANSTATION_SHARED_DATA", "data");
    let kit = shared("SCANSTATION_VALIDATORS", "validators");
    let out_dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("conformance_quad_nets");
    std::fs::create_dir_all(&out_dir).unwrap();
    const TARGET: usize = 10_000;
    for file in ["meshes/scorpion.ply", "meshes/skull.ply"] {
        let mesh = read_mesh(&data.join(file), &ReadOptions::default()).unwrap_or_else(|e| panic!("{file}: {e}"));
        let loop_len = scanstation::pipeline::small_handle_loop(
            scanstation::pipeline::Resolution::Vertices(TARGET),
            mesh.triangulate().0.area(),
        );
        let ro = RepairOptions {
            compare_samples: 1_000,
            max_handle_loop_rel: loop_len / mesh.bbox().diagonal(),
            ..Default::default()
        };
        let (tri, _) = repair(&mesh, &ro, &NoProgress).unwrap_or_else(|e| panic!("{file}: repair: {e}"));
        let stem = file.replace('/', "_").replace(".ply", "");
        let input = out_dir.join(format!("{stem}.repaired.ply"));
        write_ply(&input, &tri.clone().into(), &Default::default(), &[]).unwrap();
        let opts = RemeshOptions { target_vertices: TARGET, seed: 0, ..RemeshOptions::convert_default() };
        let (net, r) = remesh(&tri, &opts, &NoProgress).unwrap_or_else(|e| panic!("{file}: remesh: {e}"));
        let ours_path = out_dir.join(format!("{stem}.ours.obj"));
        write_obj(&ours_path, &net).unwrap();
        let ours = run_json(&root().join("tests/tools/crossings.py"), &[ours_path.as_os_str()]);
        let peer_path = out_dir.join(format!("{stem}.instant-meshes.obj"));
        let peer = run_json(
            &kit.join("quad_peer.py"),
            &[
                input.as_os_str(),
                "--vertices".as_ref(),
                TARGET.to_string().as_ref(),
                "--out".as_ref(),
                peer_path.as_os_str(),
            ],
        );
        let theirs = run_json(&root().join("tests/tools/crossings.py"), &[peer_path.as_os_str()]);
        println!(
            "{file}: ours {} vertices ({:?}), crossing pairs {:?} (ours) / {} (crossings.py); Instant Meshes {} vertices, \
             crossing pairs {} (crossings.py), {:.1} s",
            r.output.vertices,
            r.mode,
            r.output.crossing_pairs,
            ours["crossing_pairs"],
            peer["output"]["vertices_referenced"],
            theirs["crossing_pairs"],
            peer["wall_time_s"].as_f64().unwrap_or(f64::NAN)
        );
        assert_eq!(r.output.crossing_pairs, Some(0), "{file}: our net crosses itself (our counter)");
        assert_eq!(ours["crossing_pairs"], 0, "{file}: our net crosses itself (crossings.py): {ours}");
    }
}

/// The reconstruction issue's acceptance: the bunny's ten range scans (`bun.conf`, fused and registered) and
/// a cloud (igea's vertices without normals, as XYZ) convert to STEP files that OpenCASCADE reads as exactly
/// one valid solid with one closed shell and no free edges. Published even if a gate is missed (the gates
/// are the corpus suite's business; the status is printed), so this holds the STEP to OpenCASCADE alone.
#[test]
fn scan_sets_and_clouds_convert_to_valid_step_solids() {
    use scanstation::pipeline::{ConvertOptions, GateOptions, Resolution, convert_file};
    let data = shared("SCANSTATION_SHARED_DATA", "data");
    let kit = shared("SCANSTATION_VALIDATORS", "validators");
    let out_dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("conformance_scans");
    std::fs::create_dir_all(&out_dir).unwrap();
    let igea = read_geometry(&data.join("meshes/igea.ply"), &ReadOptions::default()).unwrap();
    let xyz: String = igea.positions().iter().map(|p| format!("{} {} {}\n", p[0], p[1], p[2])).collect();
    let cloud = out_dir.join("igea-cloud.xyz");
    std::fs::write(&cloud, xyz).unwrap();
    for (what, input) in [("bun.conf", data.join("bunny/scans/bun.conf")), ("igea-cloud.xyz", cloud)] {
        let step = out_dir.join(format!("{what}.step"));
        let opts = ConvertOptions {
            resolution: Resolution::Vertices(10_000),
            compare_samples: 50_000,
            gates: GateOptions { accept_degraded: true, ..Default::default() },
            ..Default::default()
        };
        let report = convert_file(&input, &step, &ReadOptions::default(), &opts, &NoProgress)
            .unwrap_or_else(|e| panic!("{what}: convert failed: {e}"));
        println!(
            "{what}: status {:?}, {} faces, volume {:+.4} %, {:.1} s",
            report.status, report.brep.faces, report.volume_error_pct, report.total_seconds
        );
        assert_one_valid_solid(what, &run_json(&kit.join("step_check.py"), &[step.as_os_str()]));
    }
}

/// The FEA result of the bundled rod opens in meshio (the reader ParaView users script with): a triangle
/// surface with the vertex count of the rod and the three point fields, whose largest displacement equals
/// the one our report names.
#[test]
fn fea_surface_vtu_opens_in_meshio() {
    use scanstation::stages::fea::FeaOptions;
    let dir = std::env::temp_dir().join(format!("scanstation-conformance-vtu-{}", std::process::id()));
    let rod = root().join("examples/rod.ply");
    let r = scanstation::pipeline::fea::fea_file(
        &rod,
        &root().join("config/fea/cantilever-rod.toml"),
        &dir,
        &ReadOptions::default(),
        &FeaOptions::default(),
        None,
        &NoProgress,
    )
    .unwrap();
    let script = [
        "import sys, json, meshio, numpy as np",
        "m = meshio.read(sys.argv[1])",
        "d = np.linalg.norm(m.point_data['displacement'], axis=1)",
        "print(json.dumps({'points': len(m.points), 'cells': {c.type: len(c.data) for c in m.cells},",
        "  'fields': sorted(m.point_data), 'max_u': float(d.max()), 'max_vm': float(m.point_data['von_mises'].max())}))",
    ]
    .join("\n");
    let out = Command::new(python()).arg("-c").arg(script).arg(dir.join("surface.vtu")).output().unwrap();
    assert!(out.status.success(), "meshio could not read surface.vtu: {}", String::from_utf8_lossy(&out.stderr));
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    println!("meshio: {v}");
    assert_eq!(v["points"], 9698, "{v}");
    assert_eq!(v["cells"]["triangle"], 19392, "{v}");
    assert_eq!(v["fields"], serde_json::json!(["displacement", "principal_stress", "von_mises"]), "{v}");
    let (ours, theirs) = (r.result.max_displacement.value, v["max_u"].as_f64().unwrap());
    assert!((ours - theirs).abs() <= 1e-9 * ours, "max |u|: report {ours}, VTU {theirs}");
    let (ours, theirs) = (r.result.max_von_mises.value, v["max_vm"].as_f64().unwrap());
    assert!((ours - theirs).abs() <= 1e-9 * ours, "max von Mises: report {ours}, VTU {theirs}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A scan on the simulated rig through the real daemon (`StartScan`, 12 views of spot) gives one valid OCCT
/// solid.
#[test]
fn a_scan_on_the_simulated_rig_gives_a_valid_step_solid() {
    use harness::*;
    let kit = shared("SCANSTATION_VALIDATORS", "validators");
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("conformance_scan");
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let bus = start_bus(&dir, OPEN_POLICY);
    let _rig = start_rig(&dir, 7);
    let mut st = Station::new(&dir, &bus, false, &scan_config(&dir, ""));
    st.start();
    start_scan(&st, &["3", "views", "u", "12", "name", "s", "spot", "vertices", "u", "3000"]);
    st.wait_done(1, std::time::Duration::from_secs(900));
    let step = only_entry(&st.spool("outbox")).join("spot.step");
    let v = run_json(&kit.join("step_check.py"), &[step.as_os_str()]);
    let s = &v["summary"];
    println!("scan of spot: step_check {s}");
    assert_eq!(s["solids"], 1, "OCCT solids: {s}");
    assert_eq!(s["shells"], 1, "OCCT shells: {s}");
    assert_eq!(s["valid"], true, "BRepCheck_Analyzer invalid: {}", v["occt"]["invalid_subshapes"]);
    assert_eq!(s["all_shells_closed"], true, "shell not closed: {s}");
    assert_eq!(s["free_edges"], 0, "free edges: {s}");
}

/// Issue 43: solids with invented bases are valid for the tools no one here wrote. Spot cut open by a tilted,
/// wavy plane (`common::cut_open`, 15 % of its height; its base becomes a membrane cap) and the same cut
/// through the skull (20 %, a genus-2 bust on a wavy base) convert at the defaults to STEP files that
/// OpenCASCADE reads as exactly one valid solid with one closed shell and no free edges, and that gmsh
/// tetrahedralises. Measured 2026-12-06: spot 466 faces, 20,509 tetrahedra; skull 1,422 faces, 47,256
/// tetrahedra (233 s for both, debug build with optimisation).
#[test]
fn statues_cut_open_at_the_base_are_valid_solids_for_occt_and_gmsh() {
    use scanstation::geometry::io::{read_mesh, write_ply};
    use scanstation::pipeline::{ConvertOptions, convert_file};
    let data = shared("SCANSTATION_SHARED_DATA", "data");
    let kit = shared("SCANSTATION_VALIDATORS", "validators");
    let out_dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("conformance_open_bases");
    std::fs::create_dir_all(&out_dir).unwrap();
    for (f, share, tilt) in [("meshes/spot.ply", 0.15, 0.2), ("meshes/skull.ply", 0.2, 0.1)] {
        let mesh =
            read_mesh(&data.join(f), &ReadOptions::default()).unwrap_or_else(|e| panic!("{f}: {e}")).triangulate().0;
        let input = out_dir.join(Path::new(f).file_name().unwrap());
        write_ply(&input, &common::cut_open(&mesh, 2, share, tilt).into(), &Default::default(), &[]).unwrap();
        let step = input.with_extension("step");
        let opts = ConvertOptions { compare_samples: 50_000, ..Default::default() };
        let report = convert_file(&input, &step, &ReadOptions::default(), &opts, &NoProgress)
            .unwrap_or_else(|e| panic!("{f} cut open: convert failed: {e}"));
        println!(
            "{f} cut open: status {:?}, {} faces, caps {:?}",
            report.status, report.brep.faces, report.repair.holes.caps
        );
        assert_eq!(report.repair.holes.caps.len(), 1, "{f} cut open: {:?}", report.repair.holes.decisions);
        let what = format!("{f} cut open");
        assert_one_valid_solid(&what, &run_json(&kit.join("step_check.py"), &[step.as_os_str()]));
        let g = run_json(&root().join("tests/tools/gmsh_tetrahedralise.py"), &[step.as_os_str()]);
        println!("{f} cut open: gmsh {g}");
        assert_eq!(g["volumes"], 1, "{f} cut open: gmsh sees {} volumes", g["volumes"]);
        assert!(g["tetrahedra"].as_u64().unwrap() > 0, "{f} cut open: gmsh made no tetrahedra: {g}");
    }
}

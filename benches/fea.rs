//! FEA benchmark: the cantilever rod (`config/fea/cantilever-rod.toml` on `shapes::rod(2.485, 200, 96, 100)`)
//! at a range of grid spacings, one run each: unknowns, errors against beam theory (tip deflection, bending
//! stress at x = 50, von Mises two cells from the clamp against the root value), reaction imbalance, wall
//! time per phase and peak RSS. Then spot (`config/fea/spot-standing.toml`, examples/spot.ply) at a few
//! resolutions: max displacement and its change, time and memory; then the same spot problem solved by the
//! peer, gmsh + CalculiX C3D10 (`../shared/validators/fea_ref.py` in `.venv-validators`, see
//! `scripts/setup-validators.sh`), on the STEP solid `convert` makes of spot, at a few mesh sizes, with the
//! ratio ours/peer. Prints Markdown tables. Run: `cargo bench --bench fea` (about 15 minutes on 2 cores).
//!
//! The peer runs with gmsh's high-order optimiser on (`Mesh.HighOrderOptimize = 2` in a gmsh options file
//! that `GMSH_HOME` points to; `fea_ref.py` itself is unchanged): without it gmsh's curving of the C3D10
//! mid-side nodes onto the solid inverts a few elements (5 of 54k at h = 0.05) and ccx stops with
//! "nonpositive jacobian". Our plane support y ≤ −0.69 is given to the peer as a sphere of radius 1000 whose
//! top touches that plane (`--fix-sphere`; it offers half-spaces only along x); over spot's footprint the two
//! differ by at most 1.5e-4 in height.

use std::path::{Path, PathBuf};
use std::process::Command;

use scanstation::geometry::io::{ReadOptions, read_mesh};
use scanstation::geometry::shapes;
use scanstation::pipeline::convert::{ConvertOptions, Resolution, convert_file};
use scanstation::pipeline::memory::StageMeter;
use scanstation::stages::NoProgress;
use scanstation::stages::fea::{self, FeaOptions, FeaSpec};

fn main() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let rod = shapes::rod(4.97 / 2.0, 200.0, 96, 100);
    let base = FeaSpec::read(&root.join("config/fea/cantilever-rod.toml")).unwrap();
    println!(
        "**Cantilever rod** (d = 4.97, L = 200, Fy = 10 N; beam theory: tip 4.2399 mm, σ(x=50) 124.46 MPa, σ(root) 165.94 MPa)\n"
    );
    println!(
        "| h (mm) | cells across d | unknowns | tip error % | σ(x=50) error % | σvM 2h from clamp vs root % | imbalance | domain s | assemble s | solve s | total s | peak RSS MiB |"
    );
    println!("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for h in [2.5, 2.0, 1.66, 1.25, 1.0, 0.8, 0.6] {
        let mut spec = base.clone();
        spec.resolution.cell_size = Some(h);
        let meter = StageMeter::start();
        let r = fea::solve(&rod, &spec, &FeaOptions::default(), &NoProgress).unwrap().report;
        let (secs, mem) = meter.finish();
        let pct = |a: f64, b: f64| 100.0 * (a - b) / b;
        println!(
            "| {h} | {:.1} | {} | {:+.3} | {:+.3} | {:+.2} | {:.1e} | {:.2} | {:.2} | {:.2} | {:.2} | {} |",
            4.97 / h,
            r.grid.unknowns,
            pct(r.probes[1].displacement[1], 4.2399),
            pct(r.probes[0].von_mises, 124.46),
            pct(r.max_von_mises_away_from_supports.value, 165.94),
            r.imbalance,
            r.seconds["domain"],
            r.seconds["assemble"],
            r.seconds["solve"],
            secs,
            mem.map(|m| format!("{m:.0}")).unwrap_or_else(|| "n/a".into()),
        );
    }
    let spot = read_mesh(&root.join("examples/spot.ply"), &ReadOptions::default()).unwrap().triangulate().0;
    let base = FeaSpec::read(&root.join("config/fea/spot-standing.toml")).unwrap();
    println!("\n**Spot standing** (self-weight + 2e-5 N on the back, held below y = -0.69: the hooves)\n");
    println!(
        "| cells along longest | h | unknowns | solver | max |u| | change vs previous % | total s | peak RSS MiB |"
    );
    println!("|---:|---:|---:|---|---:|---:|---:|---:|");
    let mut prev: Option<f64> = None;
    let mut ours = Vec::new();
    for n in [24, 32, 48, 64] {
        let mut spec = base.clone();
        spec.resolution.cells_along_longest = n;
        let meter = StageMeter::start();
        let r = fea::solve(&spot, &spec, &FeaOptions { memory_budget: 16 << 30 }, &NoProgress).unwrap().report;
        let (secs, mem) = meter.finish();
        let u = r.max_displacement.value;
        println!(
            "| {n} | {:.4} | {} | {} | {:.5e} | {} | {:.2} | {} |",
            r.grid.cell_size,
            r.grid.unknowns,
            r.solver.kind,
            u,
            prev.map(|p| format!("{:+.2}", 100.0 * (u - p) / p)).unwrap_or_default(),
            secs,
            mem.map(|m| format!("{m:.0}")).unwrap_or_else(|| "n/a".into()),
        );
        prev = Some(u);
        ours.push((n, u, secs));
    }
    reference(root, &base, &ours);
}

/// The same spot problem solved by gmsh + CalculiX C3D10 at a few mesh sizes; prints a table with the ratio
/// of our finest max |u| to each.
fn reference(root: &Path, spec: &FeaSpec, ours: &[(usize, f64, f64)]) {
    let kit = std::env::var_os("SCANSTATION_VALIDATORS")
        .map(PathBuf::from)
        .unwrap_or_else(|| root.join("../shared/validators"));
    let python = root.join(".venv-validators/bin/python");
    assert!(python.is_file(), "{} missing: run `bash scripts/setup-validators.sh`", python.display());
    let tmp = std::env::temp_dir().join(format!("scanstation-bench-fea-{}", std::process::id()));
    std::fs::create_dir_all(&tmp).unwrap();
    let step = tmp.join("spot.step");
    let opts = ConvertOptions { resolution: Resolution::Vertices(5000), ..Default::default() };
    convert_file(&root.join("examples/spot.ply"), &step, &ReadOptions::default(), &opts, &NoProgress).unwrap();
    std::fs::write(tmp.join(".gmsh-options"), "Mesh.HighOrderOptimize = 2;\n").unwrap();
    let (plane, load) = (&spec.supports[0], &spec.loads[0]);
    let plane = plane.plane.as_ref().expect("the spot spec holds it by a plane");
    assert_eq!(plane.normal, [0.0, -1.0, 0.0], "the peer gets the plane as a big sphere below it");
    let (big, y0) = (1000.0, plane.point[1]);
    let sphere = load.sphere.as_ref().expect("the spot load is a sphere");
    let force = load.force.expect("the spot load is a force");
    let m = &spec.material;
    let g = spec.gravity.unwrap_or([0.0; 3]);
    let num = |v: f64| format!("{v}");
    println!(
        "\n**Spot standing, peer: gmsh + CalculiX C3D10** (`fea_ref.py` on spot's STEP solid, 5k control vertices)\n"
    );
    println!(
        "| peer mesh size | nodes | elements | peer max |u| | peer s | ours (finest, {} cells) / peer |",
        ours.last().unwrap().0
    );
    println!("|---:|---:|---:|---:|---:|---:|");
    for h in [0.07, 0.05] {
        let mut cmd = Command::new(&python);
        cmd.env("GMSH_HOME", format!("{}/", tmp.display()))
            .arg(kit.join("fea_ref.py"))
            .arg(&step)
            .args(["--E", &num(m.youngs_modulus), "--nu", &num(m.poissons_ratio), "--density", &num(m.density)])
            .arg("--gravity")
            .args(g.map(num))
            .arg("--fix-sphere")
            .args([0.0, y0 - big, 0.41, big].map(num))
            .arg("--load")
            .args([sphere.center[0], sphere.center[1], sphere.center[2], sphere.radius].map(num))
            .args(force.map(num))
            .args(["--mesh-size", &num(h)]);
        let o = cmd.output().expect("run fea_ref.py");
        assert!(o.status.success(), "fea_ref.py failed: {}", String::from_utf8_lossy(&o.stdout));
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("fea_ref.py prints JSON");
        let peer = v["results"]["max_displacement"].as_f64().unwrap();
        println!(
            "| {h} | {} | {} | {:.5e} | {:.1} | {:.4} |",
            v["mesh"]["nodes"],
            v["mesh"]["elements"],
            peer,
            v["time_s"]["total"].as_f64().unwrap_or(f64::NAN),
            ours.last().unwrap().1 / peer,
        );
    }
    let _ = std::fs::remove_dir_all(&tmp);
}

//! Reconstruction benchmark against the peers in the same run: Open3D's and PyMeshLab's screened Poisson (the
//! validators kit's `poisson_peer.py` functions, driven by `scripts/poisson_run.py` in `.venv-validators`, see
//! `scripts/setup-validators.sh --peers`).
//!
//! 1. Clouds sampled from armadillo and igea (seeded, area-uniform): 200k and 2M points, each exact with the
//!    source's face normals, with 0.05 % Gaussian noise (of the diagonal) and those normals, and exact without
//!    normals (every tool estimates and orients them).
//! 2. Each tool reconstructs each cloud as its own process under `/usr/bin/time` (wall, peak RSS); ours is
//!    `scanstation reconstruct` at its defaults and with `--split 1`, the peers depth 9 at 200k and depth 10 at 2M points (the
//!    issue's anchors). The algorithm's own seconds are reported beside the process's (ours: the stage's
//!    steps, without reading, writing and the measurement against the points; the peers': normals and
//!    reconstruction, without Python's start and reading).
//! 3. Every result is measured the same way against the source mesh: symmetric RMS (% of the diagonal,
//!    `compare`), closed or not, and the inside-out area: the share of the result whose normal points against
//!    the nearest source triangle's (cos < −0.5).
//! 4. The bunny: the ten range scans placed by `bun.conf`, fused by us; ours and Open3D (depth 9) on the same
//!    fused points; Stanford's `bun_zipper.ply` → each result, RMS % of its diagonal.
//!
//! Run: `cargo bench --bench reconstruct` (all cases, about 30 min on 2 cores). `SCANSTATION_BENCH_POINTS`
//! (comma-separated, default `200000,2000000`) picks the sizes; PyMeshLab runs on the clouds with normals up
//! to `SCANSTATION_BENCH_PYMESHLAB_MAX` points (default 200000: at 200k it already takes minutes).
//! `SCANSTATION_BENCH_KEEP_CLOUDS=DIR` writes the clouds into DIR and runs nothing (to re-run one case by hand).

mod common;

use common::data_dir;

use std::path::{Path, PathBuf};
use std::process::Command;

use scanstation::geometry::bvh::TriangleBvh;
use scanstation::geometry::io::{ReadOptions, VertexAttributes, read_geometry, read_mesh, write_ply_cloud};
use scanstation::geometry::mesh::{Geometry, PointCloud, PolyMesh, TriMesh};
use scanstation::geometry::sampling::{Rng, sample_area_uniform};
use scanstation::geometry::topology::TopologyReport;
use scanstation::geometry::vec3::{cross, dot, norm, sub, wide};
use scanstation::stages::NoProgress;
use scanstation::stages::quality::{CompareOptions, compare};

/// Noise of the noisy clouds, % of the diagonal.
const NOISE_PCT: f64 = 0.05;

/// One tool's run on one cloud.
struct Run {
    tool: String,
    setting: String,
    wall: f64,
    algorithm: f64,
    peak_mib: f64,
    output: PathBuf,
}

/// What a result measures against the source.
struct Measured {
    rms_pct: f64,
    closed: bool,
    inverted_pct: f64,
    vertices: usize,
}

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn kit() -> PathBuf {
    std::env::var_os("SCANSTATION_VALIDATORS").map(PathBuf::from).unwrap_or_else(|| root().join("../shared/validators"))
}

/// `cmd` under `/usr/bin/time`: its stdout, wall seconds and peak RSS (MiB).
fn timed(cmd: &mut Command, what: &str) -> (String, f64, f64) {
    let times = std::env::temp_dir().join(format!("scanstation-bench-time-{}", std::process::id()));
    let mut wrapped = Command::new("/usr/bin/time");
    wrapped.args(["-f", "%e %M", "-o"]).arg(&times).arg(cmd.get_program()).args(cmd.get_args());
    if let Some(dir) = cmd.get_current_dir() {
        wrapped.current_dir(dir);
    }
    let o = wrapped.output().unwrap_or_else(|e| panic!("{what}: cannot run /usr/bin/time (apt-get install time): {e}"));
    assert!(
        o.status.success(),
        "{what} failed: {}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    let t = std::fs::read_to_string(&times).expect("time's output");
    let mut f = t.split_whitespace().rev().take(2).collect::<Vec<_>>().into_iter().rev();
    let wall: f64 = f.next().and_then(|s| s.parse().ok()).expect("wall");
    let kb: f64 = f.next().and_then(|s| s.parse().ok()).expect("peak");
    (String::from_utf8_lossy(&o.stdout).into_owned(), wall, kb / 1024.0)
}

fn ours(cloud: &Path, out: &Path, split: usize) -> Run {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_scanstation"));
    cmd.args(["--json", "reconstruct"]).arg(cloud).arg("-o").arg(out).args(["--split", &split.to_string()]);
    let (stdout, wall, peak_mib) = timed(&mut cmd, "scanstation reconstruct");
    let r: serde_json::Value = serde_json::from_str(&stdout).expect("JSON report");
    let algorithm = r["reconstruct"]["seconds"].as_object().expect("seconds").values().filter_map(|v| v.as_f64()).sum();
    let nodes = r["reconstruct"]["grid_nodes"].to_string();
    let noise = r["reconstruct"]["noise_ratio"].as_f64().unwrap_or(f64::NAN);
    let setting = format!("--split {split}, grid {nodes}, noise ratio {noise:.2}");
    Run { tool: "scanstation".into(), setting, wall, algorithm, peak_mib, output: out.into() }
}

fn peer(backend: &str, depth: u32, cloud: &Path, out: &Path, estimate: bool) -> Run {
    let python = root().join(".venv-validators/bin/python");
    assert!(python.is_file(), "{} missing: run `bash scripts/setup-validators.sh --peers`", python.display());
    let mut cmd = Command::new(&python);
    cmd.arg(root().join("scripts/poisson_run.py")).arg(kit()).arg(cloud).arg(out);
    cmd.args(["--backend", backend, "--depth", &depth.to_string()]);
    if estimate {
        cmd.arg("--force-estimate-normals");
    }
    let (stdout, wall, peak_mib) = timed(&mut cmd, backend);
    let r: serde_json::Value = serde_json::from_str(stdout.lines().last().unwrap_or("")).expect("poisson_run.py JSON");
    let s = &r["seconds"];
    let algorithm = s["normals"].as_f64().unwrap_or(0.0) + s["reconstruction"].as_f64().unwrap_or(0.0);
    let tool = if backend == "open3d" { "Open3D 0.20" } else { "PyMeshLab 2025.7" };
    Run { tool: tool.into(), setting: format!("depth {depth}"), wall, algorithm, peak_mib, output: out.into() }
}

/// Symmetric RMS to `source`, closedness, and the inside-out share of the area.
fn measure(result: &Path, source: &TriMesh, source_bvh: &TriangleBvh) -> Measured {
    let mesh = read_mesh(result, &ReadOptions::default()).unwrap_or_else(|e| panic!("{}: {e}", result.display()));
    let d = compare(
        &Geometry::Mesh(mesh.clone()),
        &Geometry::Mesh(PolyMesh::from(source.clone())),
        &CompareOptions::default(),
        &NoProgress,
    )
    .expect("compare");
    let topo = TopologyReport::compute(&mesh);
    let tri = mesh.triangulate().0;
    let (mut inverted, mut total) = (0.0, 0.0);
    for t in &tri.triangles {
        let p = t.map(|v| wide(tri.positions[v as usize]));
        let n = cross(sub(p[1], p[0]), sub(p[2], p[0]));
        let area = 0.5 * norm(n);
        let c = [0, 1, 2].map(|a| (p[0][a] + p[1][a] + p[2][a]) / 3.0);
        let Some(hit) = source_bvh.closest(c) else { continue };
        let s = source.triangles[hit.index as usize].map(|v| wide(source.positions[v as usize]));
        let ns = cross(sub(s[1], s[0]), sub(s[2], s[0]));
        let cos = dot(n, ns) / (norm(n) * norm(ns)).max(f64::MIN_POSITIVE);
        total += area;
        if cos < -0.5 {
            inverted += area;
        }
    }
    Measured {
        rms_pct: d.symmetric.rms.pct_of_diagonal,
        closed: topo.closed && topo.nonmanifold_edges == 0,
        inverted_pct: 100.0 * inverted / total.max(f64::MIN_POSITIVE),
        vertices: tri.positions.len(),
    }
}

/// `n` seeded samples of `mesh` with its face normals; noise `noise_pct` % of the diagonal.
fn sample_cloud(mesh: &TriMesh, n: usize, noise_pct: f64, normals: bool, seed: u64) -> PointCloud {
    let mut rng = Rng::new(seed);
    let samples = sample_area_uniform(mesh, n, &mut rng);
    let sigma = noise_pct / 100.0 * mesh.bbox().diagonal();
    let mut gauss = || {
        let (u, v) = (rng.next_f64().max(1e-300), rng.next_f64());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    };
    let positions = samples.iter().map(|s| s.point.map(|c| (c + sigma * gauss()) as f32)).collect();
    let normals = normals.then(|| {
        samples
            .iter()
            .map(|s| {
                let p = mesh.triangles[s.triangle as usize].map(|v| wide(mesh.positions[v as usize]));
                let n = cross(sub(p[1], p[0]), sub(p[2], p[0]));
                let l = norm(n).max(f64::MIN_POSITIVE);
                n.map(|c| (c / l) as f32)
            })
            .collect()
    });
    PointCloud::new(positions, normals, None).expect("finite samples")
}

fn row(cloud: &str, r: &Run, m: &Measured) {
    println!(
        "| {cloud} | {} | {} | {:.1} | {:.1} | {:.0} | {:.4} | {} | {:.3} | {} |",
        r.tool,
        r.setting,
        r.algorithm,
        r.wall,
        r.peak_mib,
        m.rms_pct,
        if m.closed { "yes" } else { "no" },
        m.inverted_pct,
        m.vertices
    );
}

fn main() {
    let data = data_dir();
    let tmp = std::env::temp_dir().join(format!("scanstation-bench-reconstruct-{}", std::process::id()));
    std::fs::create_dir_all(&tmp).unwrap();
    let sizes: Vec<usize> = std::env::var("SCANSTATION_BENCH_POINTS")
        .unwrap_or_else(|_| "200000,2000000".into())
        .split(',')
        .map(|s| s.trim().parse().expect("SCANSTATION_BENCH_POINTS: comma-separated counts"))
        .collect();
    let meshlab_max: usize =
        std::env::var("SCANSTATION_BENCH_PYMESHLAB_MAX").ok().and_then(|s| s.parse().ok()).unwrap_or(200_000);
    println!(
        "| cloud | tool | setting | algorithm s | process wall s | peak RSS MiB | RMS to source % diag | closed | inside-out area % | vertices |"
    );
    println!("|---|---|---|---:|---:|---:|---:|---|---:|---:|");
    for name in ["armadillo_50k", "igea"] {
        let source = read_mesh(&data.join(format!("meshes/{name}.ply")), &ReadOptions::default())
            .expect("source")
            .triangulate()
            .0;
        let bvh = TriangleBvh::new(&source);
        for &n in &sizes {
            let depth = if n >= 1_000_000 { 10 } else { 9 };
            for (variant, noise, normals) in
                [("normals", 0.0, true), ("normals, 0.05 % noise", NOISE_PCT, true), ("no normals", 0.0, false)]
            {
                let cloud = sample_cloud(&source, n, noise, normals, 0x5ca9 ^ n as u64);
                let file = tmp.join(format!("{name}-{n}-{}.ply", variant.len()));
                write_ply_cloud(&file, &cloud, &VertexAttributes::default(), &[]).expect("write cloud");
                drop(cloud);
                if let Some(keep) = std::env::var_os("SCANSTATION_BENCH_KEEP_CLOUDS") {
                    let kept = Path::new(&keep).join(format!(
                        "{name}-{}k-{}.ply",
                        n / 1000,
                        variant.replace([' ', ',', '.', '%'], "")
                    ));
                    std::fs::create_dir_all(&keep).expect("SCANSTATION_BENCH_KEEP_CLOUDS: a writable directory");
                    std::fs::rename(&file, &kept)
                        .or_else(|_| std::fs::copy(&file, &kept).map(|_| ()))
                        .expect("keep the cloud");
                    eprintln!("kept {}", kept.display());
                    continue;
                }
                let label = format!("{name} {}k, {variant}", n / 1000);
                let mut runs = vec![ours(&file, &tmp.join("ours.ply"), 0), ours(&file, &tmp.join("ours-split.ply"), 1)];
                runs.push(peer("open3d", depth, &file, &tmp.join("open3d.ply"), !normals));
                if normals && noise == 0.0 && n <= meshlab_max {
                    runs.push(peer("pymeshlab", depth, &file, &tmp.join("pymeshlab.ply"), false));
                }
                let measured: Vec<Measured> = runs.iter().map(|r| measure(&r.output, &source, &bvh)).collect();
                for (r, m) in runs.iter().zip(&measured) {
                    row(&label, r, m);
                }
                let best_peer = measured[2..].iter().map(|m| m.rms_pct).fold(f64::INFINITY, f64::min);
                for k in 0..2 {
                    eprintln!(
                        "{label}, {}: RMS ours/best peer {:.2}, algorithm time ours/Open3D {:.2}, peak ours/Open3D {:.2}",
                        runs[k].setting,
                        measured[k].rms_pct / best_peer,
                        runs[k].algorithm / runs[2].algorithm,
                        runs[k].peak_mib / runs[2].peak_mib
                    );
                }
                std::fs::remove_file(&file).ok();
            }
        }
    }
    if std::env::var_os("SCANSTATION_BENCH_KEEP_CLOUDS").is_none() {
        bunny(&data, &tmp);
    }
    std::fs::remove_dir_all(&tmp).ok();
}

/// Ours and Open3D on the bunny's fused points; bun_zipper → each, RMS % of its diagonal.
fn bunny(data: &Path, tmp: &Path) {
    let conf = data.join("bunny/scans/bun.conf");
    let (fused, _) =
        scanstation::pipeline::reconstruct::read_input(&conf, &ReadOptions::default(), &Default::default())
            .expect("fuse the bunny");
    let Geometry::Cloud(cloud) = fused else { panic!("a scan set fuses into a cloud") };
    let file = tmp.join("bunny-fused.ply");
    write_ply_cloud(&file, &cloud, &VertexAttributes::default(), &[]).expect("write fused");
    let zipper =
        read_geometry(&data.join("bunny/reconstruction/bun_zipper.ply"), &ReadOptions::default()).expect("zipper");
    println!(
        "\n| bunny, {} fused points (bun.conf) | tool | algorithm s | process wall s | peak RSS MiB | bun_zipper → result RMS % diag | closed |",
        cloud.positions.len()
    );
    println!("|---|---|---:|---:|---:|---:|---|");
    let runs = [
        ours(&file, &tmp.join("bunny-ours.ply"), 0),
        ours(&file, &tmp.join("bunny-ours-split.ply"), 1),
        peer("open3d", 9, &file, &tmp.join("bunny-open3d.ply"), false),
    ];
    for r in runs {
        let mesh = read_mesh(&r.output, &ReadOptions::default()).expect("result");
        let topo = TopologyReport::compute(&mesh);
        let d = compare(&Geometry::Mesh(mesh), &zipper, &CompareOptions::default(), &NoProgress).expect("compare");
        println!(
            "| | {} {} | {:.1} | {:.1} | {:.0} | {:.4} | {} |",
            r.tool,
            r.setting,
            r.algorithm,
            r.wall,
            r.peak_mib,
            d.reference_to_test.rms.pct_of_diagonal,
            if topo.closed { "yes" } else { "no" }
        );
    }
}

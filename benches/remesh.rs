//! Remesh benchmark against the peer, Instant Meshes (`pyinstantmeshes`, via
//! `../shared/validators/quad_peer.py` in `.venv-validators`, see `scripts/setup-validators.sh`): the nine
//! shared meshes, each repaired as `convert` repairs it at a 10k-vertex target (small handles cut, holes
//! filled), then remeshed at 10k, seed 0, by `scanstation remesh`'s default routes (the ones `convert` uses,
//! [`RemeshOptions::convert_default`]) and by the peer, one run each, same input file. Reports wall time, peak
//! RSS, vertex count, quad share, irregular vertices, two-sided RMS and crossing triangle pairs (our exact
//! counter on both nets' fan triangulations), and the time ratio ours/peer.
//! Run: `cargo bench --bench remesh` (data: `SCANSTATION_SHARED_DATA`; kit: `SCANSTATION_VALIDATORS`).

mod common;

use common::{data_dir, peak_mib, reset_peak};

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use scanstation::geometry::io::{ReadOptions, read_mesh, write_ply};
use scanstation::stages::NoProgress;
use scanstation::stages::remesh::{RemeshOptions, remesh};
use scanstation::stages::repair::{RepairOptions, repair};
use scanstation::{PolyMesh, TriMesh};

const TARGET: usize = 10_000;

fn peer(input: &Path, out: &Path) -> serde_json::Value {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let kit = std::env::var_os("SCANSTATION_VALIDATORS")
        .map(PathBuf::from)
        .unwrap_or_else(|| root.join("../shared/validators"));
    let python = root.join(".venv-validators/bin/python");
    assert!(python.is_file(), "{} missing: run `bash scripts/setup-validators.sh`", python.display());
    let o = Command::new(&python)
        .arg(kit.join("quad_peer.py"))
        .arg(input)
        .args(["--vertices", &TARGET.to_string(), "--out"])
        .arg(out)
        .args(["--samples", "100000"])
        .output()
        .expect("run quad_peer.py");
    assert!(o.status.success(), "quad_peer.py failed: {}", String::from_utf8_lossy(&o.stdout));
    serde_json::from_slice(&o.stdout).expect("quad_peer.py prints JSON")
}

/// Crossing triangle pairs of a polygon mesh file's fan triangulation (exact predicates).
fn crossings_of(path: &Path) -> usize {
    let q = read_mesh(path, &ReadOptions::default()).expect("read the peer's net");
    let (t, _) = q.triangulate();
    let p: Vec<[f64; 3]> = t.positions.iter().map(|x| x.map(f64::from)).collect();
    scanstation::geometry::intersect::self_intersections(&p, &t.triangles).len()
}

fn main() {
    let data = data_dir();
    let tmp = std::env::temp_dir().join(format!("scanstation-bench-remesh-{}", std::process::id()));
    std::fs::create_dir_all(&tmp).unwrap();
    let cases = [
        "meshes/spot.ply",
        "meshes/armadillo_50k.ply",
        "meshes/igea.ply",
        "meshes/fandisk.ply",
        "bunny/reconstruction/bun_zipper.ply",
        "large/dragon_vrip_draco.ply.gz",
        "meshes/scorpion.ply",
        "meshes/skull.ply",
        "meshes/falconstatue_boundary.ply",
    ];
    println!(
        "| input | tool | wall s | peak MiB | vertices | quads % | irregular % | two-sided RMS % diag | crossing pairs |"
    );
    println!("|---|---|---:|---:|---:|---:|---:|---:|---:|");
    let mut ratios = Vec::new();
    for file in cases {
        let name = Path::new(file).file_name().unwrap().to_string_lossy().split('.').next().unwrap().to_string();
        let mesh = read_mesh(&data.join(file), &ReadOptions::default()).expect("read");
        // Repaired as `convert` does at this target: handles under two quad spacings are cut.
        let loop_len = scanstation::pipeline::small_handle_loop(
            scanstation::pipeline::Resolution::Vertices(TARGET),
            mesh.triangulate().0.area(),
        );
        let o = RepairOptions {
            compare_samples: 1_000,
            max_handle_loop_rel: loop_len / mesh.bbox().diagonal(),
            ..Default::default()
        };
        let tri: TriMesh = repair(&mesh, &o, &NoProgress).expect("repair").0;
        let input = tmp.join("input.ply");
        write_ply(&input, &PolyMesh::from(tri.clone()), &Default::default(), &[]).unwrap();
        reset_peak();
        let opts =
            RemeshOptions { target_vertices: TARGET, compare_samples: 100_000, ..RemeshOptions::convert_default() };
        let t = Instant::now();
        let (_, r) = remesh(&tri, &opts, &NoProgress).expect("remesh");
        let ours_s = t.elapsed().as_secs_f64() - r.seconds.get("measure").copied().unwrap_or(0.0);
        let peak = peak_mib();
        let o = &r.output;
        let rms = r.distance.as_ref().map_or(f64::NAN, |d| d.symmetric.rms.pct_of_diagonal);
        println!(
            "| {name} | scanstation remesh ({:?} kept) | {ours_s:.2} | {peak:.0} | {} | {:.1} | {:.2} | {rms:.4} | {} |",
            r.mode.expect("chosen"),
            o.vertices,
            100.0 * o.quad_fraction,
            100.0 * o.irregular_fraction,
            o.crossing_pairs.expect("measured on the input"),
        );
        let peer_out = tmp.join("peer.obj");
        let p = peer(&input, &peer_out);
        let f = |k: &str| p.pointer(k).and_then(|v| v.as_f64()).unwrap_or(f64::NAN);
        let peer_s = f("/wall_time_s");
        println!(
            "| {name} | Instant Meshes 1.0.0 (quad-dominant) | {peer_s:.2} | n/a | {} | {:.1} | {:.2} | {:.4} | {} |",
            f("/output/vertices_referenced"),
            100.0 * f("/output/quad_fraction"),
            100.0 * f("/output/irregular_fraction"),
            f("/distance_to_input/symmetric/rms_pct"),
            crossings_of(&peer_out),
        );
        ratios.push((name, ours_s / peer_s));
    }
    println!();
    for (name, t) in ratios {
        println!("{name}: time ratio ours/peer {t:.2}");
    }
    let _ = std::fs::remove_dir_all(&tmp);
}

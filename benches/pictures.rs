//! Pictures benchmark: a job's pictures (deviation map, histogram, quad net, B-rep faces, thumbnail; the
//! convergence plot where the chain refined) and its self-contained page. Per input: the `pictures` stage as
//! the chain measured it (on the solid mesh `convert` wrote), the page's size, then the acceptance case — the
//! same solid split at its edge midpoints to at least 1.5M triangles, its signed distances to the input and
//! every picture timed with the peak RSS reset — against a peer measured in the same run on that same solid:
//! matplotlib (Agg, `Poly3DCollection`) drawing its error map in the same four views on one 1024 × 768 PNG
//! (`scripts/pictures_peer.py` in `.venv-validators`, from `scripts/setup-validators.sh`).
//! Run: `cargo bench --bench pictures` (data: `SCANSTATION_SHARED_DATA`).

mod common;

use std::path::Path;
use std::process::Command;
use std::time::Instant;

use common::data_dir;
use scanstation::geometry::io::{ReadOptions, read_mesh};
use scanstation::geometry::mesh::{Geometry, PolyMesh, TriMesh};
use scanstation::geometry::polygon::subdivide_midpoints;
use scanstation::pipeline::pictures::{AttemptPoint, ConvertPictures, Deviation, Up, write_convert_pictures};
use scanstation::pipeline::{ConvertOptions, Resolution, convert_file};
use scanstation::stages::NoProgress;
use scanstation::stages::quality::{signed_vertex_distances, write_error_map};

/// Triangles of the acceptance's solid mesh.
const TRIANGLES: usize = 1_500_000;

/// The solid `r` wrote (about 320k triangles at 10k control vertices: the check's tessellation is capped at
/// 8 × 8 per knot span), split at edge midpoints to [`TRIANGLES`] (the surface unchanged), as the
/// acceptance's 1.5M-triangle solid.
fn at_least_1_5m(r: &scanstation::pipeline::ConvertReport) -> (TriMesh, Vec<u32>) {
    let solid = read_mesh(&r.solid_mesh_file, &ReadOptions::default()).unwrap().triangulate().0;
    let mut p: Vec<[f64; 3]> = solid.positions.iter().map(|q| q.map(f64::from)).collect();
    let mut t = solid.triangles.clone();
    // Labels stand in for the B-rep faces (the solid mesh does not carry them): 512 triangles a face.
    let mut faces: Vec<u32> = (0..t.len() as u32).map(|k| k / 512).collect();
    while 4 * t.len() <= TRIANGLES {
        subdivide_midpoints(&mut p, &mut t);
        faces = faces.iter().flat_map(|&f| [f; 4]).collect();
    }
    // The rest by splitting the first triangles in four on their own midpoints (a crack along their edges
    // changes no picture's cost), to exactly the count asked for.
    let extra = TRIANGLES.saturating_sub(t.len()).div_ceil(3);
    for k in 0..extra.min(t.len()) {
        let [a, b, c] = t[k];
        let m = |i: u32, j: u32| {
            let (x, y) = (p[i as usize], p[j as usize]);
            [0.5 * (x[0] + y[0]), 0.5 * (x[1] + y[1]), 0.5 * (x[2] + y[2])]
        };
        let base = p.len() as u32;
        p.extend([m(a, b), m(b, c), m(c, a)]);
        let (ab, bc, ca) = (base, base + 1, base + 2);
        t[k] = [ab, bc, ca];
        t.extend([[a, ab, ca], [ab, b, bc], [ca, bc, c]]);
        faces.extend([faces[k]; 3]);
    }
    let mesh = TriMesh::new(p.iter().map(|q| q.map(|x| x as f32)).collect(), t).unwrap();
    (mesh, faces)
}

/// One row: `r`'s pictures stage as measured in the chain, then the pictures of its solid at ≥ 1.5M triangles
/// (signed distances to the input and every picture, timed and peak-reset), the page, and the peer on that
/// same 1.5M-triangle solid.
fn row(name: &str, input: &Path, r: &scanstation::pipeline::ConvertReport, tmp: &Path, python: &Path) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let in_chain = r.stages.iter().find(|s| s.stage == "pictures").expect("a pictures stage");
    let (_, page) = scanstation::pipeline::report_html::write_convert_page(r).unwrap();
    let (big, faces) = at_least_1_5m(r);
    let input_mesh = read_mesh(input, &ReadOptions::default()).unwrap();
    let map_path = tmp.join(format!("{name}.big.error-map.ply"));
    let big_geom = Geometry::Mesh(PolyMesh::from(big.clone()));
    let map = write_error_map(&map_path, &big_geom, &Geometry::Mesh(input_mesh.clone()), None).unwrap();
    let net = read_mesh(&tmp.join(format!("{name}.quads.obj")), &ReadOptions::default()).unwrap();
    common::reset_peak();
    let t0 = Instant::now();
    let side = signed_vertex_distances(&big, &input_mesh.triangulate().0);
    let signed = scanstation::stages::quality::with_side(&map.distances, &side);
    let t_sign = t0.elapsed().as_secs_f64();
    let diag = r.bbox_diagonal;
    let deviation = Deviation { signed: &signed, invented: None, band: 0.0005 * diag, diag, unit: "mm", far: &[] };
    let attempts = r
        .attempts
        .iter()
        .map(|a| AttemptPoint { target_vertices: a.target_vertices, rms_pct: a.solid_rms_pct, rejected: false })
        .collect();
    let p = ConvertPictures { solid: &big, face_of: &faces, deviation, net: &net, attempts, rms_bound_pct: 0.05 };
    let t1 = Instant::now();
    let pics = write_convert_pictures(&tmp.join(format!("{name}.big.step")), &p, Up::Y).unwrap();
    let t_pics = t1.elapsed().as_secs_f64();
    let peak = common::peak_mib();
    let peer = Command::new(python)
        .arg(root.join("scripts/pictures_peer.py"))
        .arg(&map_path)
        .arg(tmp.join(format!("{name}.peer.png")))
        .output()
        .unwrap();
    assert!(peer.status.success(), "peer: {}", String::from_utf8_lossy(&peer.stderr));
    let v: serde_json::Value = serde_json::from_slice(&peer.stdout).unwrap();
    let peer_s = v["seconds"].as_f64().unwrap();
    println!(
        "| {name} | {} | {:.2} | {} | {} | {:.2} | {:.2} | **{:.2}** | {peak:.0} | {} | {peer_s:.1} | {:.0} | {:.0} |",
        r.input_vertices,
        in_chain.seconds,
        in_chain.peak_rss_mib.map_or("n/a".into(), |m| format!("{m:.0}")),
        big.triangles.len(),
        t_sign,
        t_pics,
        t_sign + t_pics,
        page.bytes,
        v["peak_rss_mib"].as_f64().unwrap(),
        peer_s / (t_sign + t_pics)
    );
    assert_eq!(pics.len(), p.attempts.len().min(2) + 4, "{name}: pictures");
}

fn main() {
    let data = data_dir();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let python = root.join(".venv-validators/bin/python");
    assert!(python.is_file(), "{} missing: run `bash scripts/setup-validators.sh`", python.display());
    let tmp = std::env::temp_dir().join(format!("scanstation-bench-pictures-{}", std::process::id()));
    std::fs::create_dir_all(&tmp).unwrap();
    println!(
        "| input | input vertices | pictures in the chain s | its peak RSS MiB | solid triangles (split to 1.5M) | signed distances s | pictures s | **total s** | peak RSS MiB | page bytes | matplotlib s | its peak RSS MiB | time ratio (peer / ours) |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for (name, file) in [("igea", "meshes/igea.ply"), ("armadillo", "meshes/armadillo_50k.ply")] {
        let out = tmp.join(format!("{name}.step"));
        let opts = ConvertOptions {
            resolution: Resolution::Vertices(10_000),
            pictures: Some(Up::Y),
            quads_output: Some(tmp.join(format!("{name}.quads.obj"))),
            ..Default::default()
        };
        let r = convert_file(&data.join(file), &out, &ReadOptions::default(), &opts, &NoProgress)
            .unwrap_or_else(|e| panic!("{file}: {e}"));
        row(name, &data.join(file), &r, &tmp, &python);
    }
    let _ = std::fs::remove_dir_all(&tmp);
}

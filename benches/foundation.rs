//! Foundation benchmark: read the shared dragon (435k vertices, gzip), inspect it, and `compare` it with a
//! 10×-decimated copy of itself at 10⁶ samples a side. Reports wall time and peak RSS per stage, and runs the
//! peer (`../shared/validators/mesh_dist.py`, point-cloud-utils) on the same pair in the same run for a ratio.
//!
//! Run: `cargo bench --bench foundation` (data: `SCANSTATION_SHARED_DATA`, default `../shared/data`; peer:
//! `.venv-validators/bin/python` from `scripts/setup-validators.sh`, skipped with a note when absent).
//! Deterministic: fixed seed, fixed decimation.

mod common;

use common::{data_dir, peak_mib, reset_peak};

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use scanstation::geometry::io::{ReadOptions, VertexAttributes, read_geometry, write_ply};
use scanstation::geometry::topology::TopologyReport;
use scanstation::stages::NoProgress;
use scanstation::stages::quality::{CompareOptions, compare};
use scanstation::{Geometry, PolyMesh};

struct Row {
    stage: String,
    seconds: f64,
    peak_mib: f64,
    note: String,
}

fn timed<T>(rows: &mut Vec<Row>, stage: &str, f: impl FnOnce() -> (T, String)) -> T {
    let exact = reset_peak();
    let t = Instant::now();
    let (v, note) = f();
    let seconds = t.elapsed().as_secs_f64();
    let note = if exact { note } else { format!("{note} (peak is process-wide)") };
    rows.push(Row { stage: stage.into(), seconds, peak_mib: peak_mib(), note });
    v
}

/// Vertex-clustering decimation to about `target` vertices: snap vertices to a grid, average each cell,
/// drop collapsed and duplicate triangles. Crude but deterministic; only used to make a coarser copy.
fn decimate(mesh: &PolyMesh, target: usize) -> PolyMesh {
    let (tri, _) = mesh.triangulate();
    let bbox = mesh.bbox();
    let mut h = (tri.area() / target as f64).sqrt();
    for _ in 0..8 {
        let (out, n) = cluster(&tri, &bbox, h);
        let ratio = n as f64 / target as f64;
        if (0.97..1.03).contains(&ratio) {
            return out;
        }
        h *= ratio.sqrt();
    }
    cluster(&tri, &bbox, h).0
}

fn cluster(tri: &scanstation::TriMesh, bbox: &scanstation::geometry::vec3::Aabb, h: f64) -> (PolyMesh, usize) {
    use std::collections::HashMap;
    let key = |p: [f32; 3]| [0, 1, 2].map(|k| ((p[k] as f64 - bbox.min[k]) / h).floor() as i64);
    let mut cells: HashMap<[i64; 3], u32> = HashMap::new();
    let mut sums: Vec<[f64; 4]> = Vec::new();
    let remap: Vec<u32> = tri
        .positions
        .iter()
        .map(|&p| {
            let id = *cells.entry(key(p)).or_insert_with(|| {
                sums.push([0.0; 4]);
                (sums.len() - 1) as u32
            });
            let s = &mut sums[id as usize];
            (0..3).for_each(|k| s[k] += p[k] as f64);
            s[3] += 1.0;
            id
        })
        .collect();
    let positions: Vec<[f32; 3]> = sums.iter().map(|s| [0, 1, 2].map(|k| (s[k] / s[3]) as f32)).collect();
    let mut seen = std::collections::HashSet::new();
    let mut faces = Vec::new();
    for t in &tri.triangles {
        let f = t.map(|i| remap[i as usize]);
        if f[0] != f[1] && f[1] != f[2] && f[0] != f[2] {
            let mut k = f;
            k.sort_unstable();
            if seen.insert(k) {
                faces.push(f.to_vec());
            }
        }
    }
    let n = positions.len();
    (PolyMesh::new(positions, &faces).expect("decimated mesh is valid"), n)
}

/// Run the peer on the pair; returns (wall seconds, peak MiB, its symmetric rms, its max).
fn peer(a: &Path, b: &Path, samples: usize) -> Result<(f64, f64, f64, f64), String> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let py = std::env::var_os("SCANSTATION_VALIDATORS_PYTHON")
        .map(PathBuf::from)
        .unwrap_or_else(|| root.join(".venv-validators/bin/python"));
    let script = root.join("../shared/validators/mesh_dist.py");
    if !py.is_file() || !script.is_file() {
        return Err(format!(
            "peer not run: {} or {} missing (bash scripts/setup-validators.sh)",
            py.display(),
            script.display()
        ));
    }
    let t = Instant::now();
    let out = Command::new("/usr/bin/time")
        .args(["-f", "%M"])
        .arg(&py)
        .arg(&script)
        .arg(a)
        .arg(b)
        .args(["--samples", &samples.to_string()])
        .output()
        .map_err(|e| format!("peer not run: {e}"))?;
    let secs = t.elapsed().as_secs_f64();
    let err = String::from_utf8_lossy(&out.stderr);
    let peak_kb: f64 = err.lines().last().and_then(|l| l.trim().parse().ok()).unwrap_or(f64::NAN);
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).map_err(|e| format!("peer output: {e}: {err}"))?;
    if v["ok"] != true {
        return Err(format!("peer failed: {}", v["error"]));
    }
    Ok((
        secs,
        peak_kb / 1024.0,
        v["symmetric"]["rms"].as_f64().unwrap_or(f64::NAN),
        v["symmetric"]["max"].as_f64().unwrap_or(f64::NAN),
    ))
}

fn main() {
    let data = data_dir();
    let dragon_path = data.join("large/dragon_vrip_draco.ply.gz");
    assert!(dragon_path.is_file(), "{} not found (set SCANSTATION_SHARED_DATA)", dragon_path.display());
    let samples = 1_000_000;
    let mut rows = Vec::new();

    let dragon = timed(&mut rows, "read dragon (.ply.gz, 435,545 v / 871,306 f)", || {
        let g = read_geometry(&dragon_path, &ReadOptions::default()).expect("read dragon");
        (g, String::new())
    });
    let Geometry::Mesh(mesh) = &dragon else { panic!("dragon is a mesh") };
    timed(&mut rows, "inspect dragon (topology report)", || {
        let r = TopologyReport::compute(mesh);
        ((), format!("genus {:?}, {} degenerate faces", r.genus, r.degenerate_faces))
    });
    let coarse = decimate(mesh, mesh.positions.len() / 10);
    let tmp = Path::new(env!("CARGO_TARGET_TMPDIR")).join("bench");
    std::fs::create_dir_all(&tmp).unwrap();
    let coarse_path = tmp.join("dragon_decimated_10x.ply");
    write_ply(&coarse_path, &coarse, &VertexAttributes::default(), &["dragon, 10x vertex-clustering decimation"])
        .unwrap();
    let coarse_g = Geometry::Mesh(coarse.clone());
    let report = timed(&mut rows, "compare dragon ↔ 10×-decimated, 10⁶ samples a side", || {
        let opts = CompareOptions { samples, ..Default::default() };
        let r = compare(&coarse_g, &dragon, &opts, &NoProgress).expect("compare");
        let note = format!("sym. rms {:.4e}, max {:.4e}", r.symmetric.rms.value, r.symmetric.max.value);
        (r, note)
    });

    println!("\n## Foundation benchmark\n");
    println!(
        "machine: {} cores; decimated copy: {} vertices, {} faces\n",
        std::thread::available_parallelism().map_or(0, |n| n.get()),
        coarse.positions.len(),
        coarse.face_count()
    );
    println!("| stage | wall (s) | peak RSS (MiB) | note |\n|---|---:|---:|---|");
    for r in &rows {
        println!("| {} | {:.3} | {:.0} | {} |", r.stage, r.seconds, r.peak_mib, r.note);
    }
    // trimesh (the peer's loader) cannot read .ply.gz: give it the same mesh as plain binary PLY.
    let plain_path = tmp.join("dragon.ply");
    write_ply(&plain_path, mesh, &VertexAttributes::default(), &[]).unwrap();
    match peer(&coarse_path, &plain_path, samples) {
        Ok((secs, mib, rms, max)) => {
            let ours = rows.last().unwrap();
            println!(
                "| peer: mesh_dist.py (point-cloud-utils), same pair and samples; whole process (Python start, reading both files) | {secs:.3} | {mib:.0} | sym. rms {rms:.4e}, max {max:.4e} |"
            );
            println!(
                "\nratio peer/ours, same run (ours = read dragon + compare): time {:.2}×, peak memory {:.2}×; symmetric rms agree within {:.2} %",
                secs / (ours.seconds + rows[0].seconds),
                mib / ours.peak_mib,
                100.0 * (report.symmetric.rms.value - rms).abs() / rms
            );
        }
        Err(e) => println!("\n{e}"),
    }
}

//! Fixture helpers shared by the integration tests: a tiny DSL to write literal files into a per-test
//! scratch directory and to read them back.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

use scanstation::geometry::io::{ReadOptions, read_geometry};
use scanstation::{Error, Geometry};

/// The shared scan data folder (`SCANSTATION_SHARED_DATA`, default `../shared/data`); a missing one fails the
/// test saying how to point at it.
pub fn shared_data() -> PathBuf {
    let dir = std::env::var_os("SCANSTATION_SHARED_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data"));
    assert!(
        dir.join("README.md").is_file(),
        "shared scan data not found at {} (set SCANSTATION_SHARED_DATA to the folder holding data/README.md)",
        dir.display()
    );
    dir
}

/// A scratch directory for one test, under cargo's target tmp dir, emptied on creation.
pub fn scratch(test: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(test);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Write `bytes` as `name` in `dir` and return the path.
pub fn file(dir: &Path, name: &str, bytes: impl AsRef<[u8]>) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

/// Gzip `bytes`.
pub fn gz(bytes: &[u8]) -> Vec<u8> {
    use std::io::Write;
    let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    e.write_all(bytes).unwrap();
    e.finish().unwrap()
}

/// Read with default options.
pub fn read(p: &Path) -> Result<Geometry, Error> {
    read_geometry(p, &ReadOptions::default())
}

/// Read, expecting a mesh.
pub fn read_mesh(p: &Path) -> scanstation::PolyMesh {
    match read(p).unwrap_or_else(|e| panic!("{}: {e}", p.display())) {
        Geometry::Mesh(m) => m,
        Geometry::Cloud(_) => panic!("{}: read as a cloud, expected a mesh", p.display()),
    }
}

/// Read, expecting a cloud.
pub fn read_cloud(p: &Path) -> scanstation::PointCloud {
    match read(p).unwrap_or_else(|e| panic!("{}: {e}", p.display())) {
        Geometry::Cloud(c) => c,
        Geometry::Mesh(_) => panic!("{}: read as a mesh, expected a cloud", p.display()),
    }
}

/// Binary PLY header + body builder for literal test files.
pub fn ply_binary(header: &str, body: &[u8]) -> Vec<u8> {
    let mut v = header.as_bytes().to_vec();
    v.extend_from_slice(body);
    v
}

/// Move every vertex coordinate by a pseudo-random offset in [−amplitude/2, amplitude/2) (seeded LCG),
/// making synthetic shapes irregular but keeping them closed.
pub fn jitter(m: &mut scanstation::TriMesh, seed: u64, amplitude: f64) {
    let mut s = seed;
    for p in &mut m.positions {
        for x in p.iter_mut() {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            *x += (((s >> 40) as f64 / (1u64 << 24) as f64 - 0.5) * amplitude) as f32;
        }
    }
}

/// A statue or bust open at the base, made from a closed `mesh`: the faces with a corner below a cut are
/// dropped. The cut is a plane whose normal is axis `up` tilted by `tilt` towards the next axis, at `share` of
/// the mesh's height along that normal above its lowest point, waving by ±0.3 % of the bounding-box diagonal
/// (three waves round the centroid), so the rim is not planar (issue 43's class of input).
pub fn cut_open(mesh: &scanstation::TriMesh, up: usize, share: f64, tilt: f64) -> scanstation::TriMesh {
    let p: Vec<[f64; 3]> = mesh.positions.iter().map(|q| q.map(f64::from)).collect();
    let diag = scanstation::geometry::vec3::Aabb::of_points(&mesh.positions).diagonal();
    let (a, b) = ((up + 1) % 3, (up + 2) % 3);
    // Height along the cut's normal: `up` tilted towards axis `a`.
    let len = (1.0 + tilt * tilt).sqrt();
    let h: Vec<f64> = p.iter().map(|q| (q[up] + tilt * q[a]) / len).collect();
    let (hmin, hmax) = h.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(x, y), &v| (x.min(v), y.max(v)));
    let c = [0, 1, 2].map(|k| p.iter().map(|q| q[k]).sum::<f64>() / p.len() as f64);
    let keep: Vec<bool> = (0..p.len())
        .map(|i| {
            let ang = (p[i][b] - c[b]).atan2(p[i][a] - c[a]);
            h[i] >= hmin + share * (hmax - hmin) + 0.003 * diag * (3.0 * ang).sin()
        })
        .collect();
    let mut cut = mesh.clone();
    cut.triangles.retain(|t| t.iter().all(|&v| keep[v as usize]));
    cut
}

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

/// Where the browser tests keep their screenshots (`target/report-screenshots/`), named in closing notes.
pub fn screenshot_dir() -> PathBuf {
    let d = Path::new(env!("CARGO_TARGET_TMPDIR")).join("../report-screenshots");
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Open `page` in headless Chromium (`scripts/browser-check.py`) at `width` CSS pixels, save a full-page
/// screenshot as `screenshot_dir()/NAME.png`, and return what the browser saw (see the script). A missing
/// Chromium fails the test saying how to install it.
pub fn browser_check(page: &Path, name: &str, width: u32) -> serde_json::Value {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/browser-check.py");
    let shot = screenshot_dir().join(format!("{name}.png"));
    let out = std::process::Command::new("python3")
        .arg(&script)
        .arg(page)
        .arg(&shot)
        .args(["--width", &width.to_string()])
        .output()
        .expect("python3 runs scripts/browser-check.py");
    assert!(
        out.status.code() != Some(2),
        "headless Chromium is missing: apt-get install chromium (scripts/setup-daemon-tests.sh installs it)"
    );
    assert!(
        out.status.success(),
        "browser check of {} failed: {}",
        page.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap_or_else(|e| panic!("browser check output: {e}"))
}

/// The checks every report page must pass in the browser: every image loaded, no console error, no dialog,
/// no script, no inline handler, no request but the page itself and `data:` pictures; `images` pictures.
pub fn assert_safe_page(page: &Path, seen: &serde_json::Value, images: usize) {
    let what = page.display();
    let shown = seen["images"].as_array().unwrap();
    assert_eq!(shown.len(), images, "{what}: images {shown:?}");
    let images = shown;
    for i in images {
        assert!(i["natural_width"].as_u64().unwrap_or(0) > 0, "{what}: an image did not load: {i}");
        assert!(i["src"].as_str().unwrap_or("").starts_with("data:image/png"), "{what}: an image not embedded: {i}");
    }
    assert_eq!(seen["console_errors"], serde_json::json!([]), "{what}: console errors");
    assert_eq!(seen["dialogs"], serde_json::json!([]), "{what}: a script opened a dialog");
    assert_eq!(seen["scripts"], 0, "{what}: script elements");
    assert_eq!(seen["handlers"], 0, "{what}: inline event handlers");
    let page_url = format!("file://{}", page.canonicalize().unwrap().display());
    for r in seen["requests"].as_array().unwrap() {
        let r = r.as_str().unwrap();
        assert!(r == page_url || r.starts_with("data:image/png;base64,"), "{what}: a request outside the bundle: {r}");
    }
}

/// The `#gates` table's rows equal the report's gates: each name, and each value read back to the same
/// double as the JSON holds.
pub fn assert_gates_match(page: &Path, seen: &serde_json::Value, gates: &serde_json::Value) {
    let rows = seen["gates"].as_array().unwrap();
    let gates = gates.as_array().unwrap();
    assert_eq!(rows.len(), gates.len(), "{}: gate rows {rows:?}", page.display());
    for (row, g) in rows.iter().zip(gates) {
        assert_eq!(row[0], g["name"], "{}", page.display());
        let shown: f64 = row[1].as_str().unwrap().parse().unwrap_or(f64::NAN);
        assert_eq!(shown, g["value"].as_f64().unwrap(), "{}: gate {} shows {}", page.display(), g["name"], row[1]);
    }
}

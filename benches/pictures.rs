//! Pictures benchmark: a job's pictures (deviation map, histogram, quad net, B-rep faces, thumbnail; the
//! convergence plot where the chain refined) from the solid's ~1.5M-triangle tessellation, and the
//! self-contained report page with them embedded: wall time and peak RSS of the `pictures` stage, the page's
//! size, against a peer measured in the same run — matplotlib (Agg, `Poly3DCollection`) drawing the same
//! solid's error map in the same four views on one 1024 × 768 PNG (`scripts/pictures_peer.py` in
//! `.venv-validators`, from `scripts/setup-validators.sh`).
//! Run: `cargo bench --bench pictures` (data: `SCANSTATION_SHARED_DATA`).

mod common;

use std::path::Path;
use std::process::Command;

use common::data_dir;
use scanstation::geometry::io::ReadOptions;
use scanstation::pipeline::pictures::Up;
use scanstation::pipeline::{ConvertOptions, Resolution, convert_file};
use scanstation::stages::NoProgress;

/// Faces of a binary or ASCII PLY, from its header.
fn ply_faces(p: &Path) -> u64 {
    let head = std::fs::read(p).unwrap();
    let text = String::from_utf8_lossy(&head[..head.len().min(4096)]).into_owned();
    text.lines().find_map(|l| l.strip_prefix("element face ")).and_then(|n| n.trim().parse().ok()).unwrap_or(0)
}

fn main() {
    let data = data_dir();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let python = root.join(".venv-validators/bin/python");
    assert!(python.is_file(), "{} missing: run `bash scripts/setup-validators.sh`", python.display());
    let tmp = std::env::temp_dir().join(format!("scanstation-bench-pictures-{}", std::process::id()));
    std::fs::create_dir_all(&tmp).unwrap();
    println!(
        "| input | solid triangles | pictures s | pictures peak RSS MiB | page bytes | matplotlib s | matplotlib peak RSS MiB | time ratio (peer / ours) |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---:|");
    for (name, file, up) in [("igea", "meshes/igea.ply", Up::Y), ("armadillo", "meshes/armadillo_50k.ply", Up::Y)] {
        let out = tmp.join(format!("{name}.step"));
        let opts =
            ConvertOptions { resolution: Resolution::Vertices(10_000), pictures: Some(up), ..Default::default() };
        let r = convert_file(&data.join(file), &out, &ReadOptions::default(), &opts, &NoProgress)
            .unwrap_or_else(|e| panic!("{file}: {e}"));
        let stage = r.stages.iter().find(|s| s.stage == "pictures").expect("a pictures stage");
        let (page, digest) = scanstation::pipeline::report_html::write_convert_page(&r).unwrap();
        let peer = Command::new(&python)
            .arg(root.join("scripts/pictures_peer.py"))
            .arg(&r.error_map_file)
            .arg(tmp.join(format!("{name}.peer.png")))
            .output()
            .unwrap();
        assert!(peer.status.success(), "peer: {}", String::from_utf8_lossy(&peer.stderr));
        let p: serde_json::Value = serde_json::from_slice(&peer.stdout).unwrap();
        let peer_s = p["seconds"].as_f64().unwrap();
        println!(
            "| {name} | {} | {:.2} | {} | {} | {:.1} | {:.0} | {:.0} |",
            ply_faces(&r.solid_mesh_file),
            stage.seconds,
            stage.peak_rss_mib.map_or("n/a".into(), |m| format!("{m:.0}")),
            digest.bytes,
            peer_s,
            p["peak_rss_mib"].as_f64().unwrap(),
            peer_s / stage.seconds
        );
        let _ = page;
    }
    let _ = std::fs::remove_dir_all(&tmp);
}

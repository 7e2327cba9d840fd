//! Conversion benchmark: `convert` (read → repair → remesh → surface fit → B-rep → STEP) of the dragon,
//! armadillo and igea at fixed control-vertex counts, one run each. Prints a Markdown table per input: wall
//! time and peak RSS per stage (peak reset before every stage), the two-sided distance after each measured
//! stage, and the solid's faces, volume error and normal jumps, next to the seed paper's figure for the
//! dragon (B-rep vs input RMS 0.18 % of the diagonal, 9,540-vertex quad target, < 15 min with manual steps).
//! Run: `cargo bench --bench convert` (data: `SCANSTATION_SHARED_DATA`).

mod common;

use common::data_dir;
use scanstation::geometry::io::ReadOptions;
use scanstation::pipeline::{ConvertOptions, Resolution, convert_file};
use scanstation::stages::NoProgress;

fn main() {
    let data = data_dir();
    let tmp = std::env::temp_dir().join(format!("scanstation-bench-convert-{}", std::process::id()));
    std::fs::create_dir_all(&tmp).unwrap();
    let cases: [(&str, &str, usize); 4] = [
        ("dragon", "large/dragon_vrip_draco.ply.gz", 10_000),
        ("dragon", "large/dragon_vrip_draco.ply.gz", 20_000),
        ("armadillo", "meshes/armadillo_50k.ply", 10_000),
        ("igea", "meshes/igea.ply", 10_000),
    ];
    for (name, file, n) in cases {
        let out = tmp.join(format!("{name}-{n}.step"));
        let opts = ConvertOptions { resolution: Resolution::Vertices(n), ..Default::default() };
        let r = convert_file(&data.join(file), &out, &ReadOptions::default(), &opts, &NoProgress)
            .unwrap_or_else(|e| panic!("{file}: {e}"));
        println!(
            "\n**{name}**, {n} control vertices requested ({} made, {:.2} % irregular):\n",
            r.fit.control_points,
            100.0 * r.remesh.output.irregular_fraction
        );
        println!("| stage | wall s | peak RSS MiB | RMS % diag | p95 % diag | max % diag |");
        println!("|---|---:|---:|---:|---:|---:|");
        for s in &r.stages {
            let mem = s.peak_rss_mib.map(|m| format!("{m:.0}")).unwrap_or_else(|| "n/a".into());
            match &s.distance {
                Some(d) => println!(
                    "| {} | {:.2} | {mem} | {:.4} | {:.4} | {:.4} |",
                    s.stage,
                    s.seconds,
                    d.symmetric.rms.pct_of_diagonal,
                    d.symmetric.p95.pct_of_diagonal,
                    d.symmetric.max.pct_of_diagonal
                ),
                None => println!("| {} | {:.2} | {mem} | | | |", s.stage, s.seconds),
            }
        }
        println!("| **total** | **{:.2}** | | | | |", r.total_seconds);
        let b = &r.brep;
        println!(
            "\nsolid: {} faces from {} quads ({:.1}× fewer), {} edges, volume error {:+.4} %, normal jump max {:.2}° (p99 {:.3}°); STEP {} bytes",
            b.faces,
            r.remesh.output.faces,
            r.remesh.output.faces as f64 / b.faces as f64,
            b.edges,
            r.volume_error_pct,
            b.max_normal_jump_deg,
            b.p99_normal_jump_deg,
            std::fs::metadata(&out).map(|m| m.len()).unwrap_or(0)
        );
        // Every chain built (the stage rows are the kept one's; the total includes all of them).
        let tries: Vec<String> = r
            .attempts
            .iter()
            .map(|a| format!("seed {} → {} crossing pairs", a.seed, a.solid_self_intersections))
            .collect();
        println!(
            "chains: {}; kept: {} crossing pairs, {} folded faces",
            tries.join(", "),
            b.self_intersections,
            b.folded_faces
        );
    }
    let _ = std::fs::remove_dir_all(&tmp);
}

//! FEA benchmark: the cantilever rod (`config/fea/cantilever-rod.toml` on `shapes::rod(2.485, 200, 96, 100)`)
//! at a range of grid spacings, one run each: unknowns, errors against beam theory (tip deflection, bending
//! stress at x = 50, von Mises two cells from the clamp against the root value), reaction imbalance, wall
//! time per phase and peak RSS. Then spot (`config/fea/spot-standing.toml`, examples/spot.ply) at a few
//! resolutions: max displacement and its change, time and memory. Prints Markdown tables.
//! Run: `cargo bench --bench fea`.

use scanstation::geometry::io::{ReadOptions, read_mesh};
use scanstation::geometry::shapes;
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
    println!("\n**Spot standing** (self-weight + 2e-5 N on the back, four hooves fixed)\n");
    println!(
        "| cells along longest | h | unknowns | solver | max |u| | change vs previous % | total s | peak RSS MiB |"
    );
    println!("|---:|---:|---:|---|---:|---:|---:|---:|");
    let mut prev: Option<f64> = None;
    for n in [24, 32, 48] {
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
    }
}

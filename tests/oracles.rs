//! Synthetic fine-part oracles (issue 58): closed meshes whose truth is known by construction, converted at
//! `convert`'s defaults. Each names itself in every assertion. `cargo test --features oracles --test oracles`
//! (`.ci/run` runs it; about a minute per oracle on 2 cores). `SCANSTATION_ORACLES_OUT=DIR` keeps each
//! oracle's input PLY, STEP and report there (for `scripts/quality-gates.sh` and the closing notes).
//!
//! The shapes, at the 10,000-vertex spacing s = √(area / 10,000) of each:
//! - **plate**: a round plate 0.3 % of its diagonal thick;
//! - **leg**: two balls joined by a rod of radius 0.2 s;
//! - **cone tip**: a ball under a 15° cone ending in a sharp point;
//! - **folded sheet**: a sheet folded so its arms are 0.1 s apart (genus 1);
//! - **hand**: five fingers of radius 0.4 % of the diagonal on a ball;
//! - **blade**: a lens 0.2 % of its diagonal thick with a sharp rim;
//! - **creased block**: a 2 × 1 × 1 block with 90° edges and a 45° chamfer.

use std::path::{Path, PathBuf};

use scanstation::geometry::io::{ReadOptions, VertexAttributes, write_ply};
use scanstation::geometry::mesh::TriMesh;
use scanstation::geometry::shapes::{
    chamfered_block, cone_tip_profile, folded_sheet_profile, hand, leg_profile, lens_profile, plate_profile,
    revolve_rings,
};
use scanstation::geometry::topology::TopologyReport;
use scanstation::pipeline::{ConvertOptions, ConvertReport, convert_file};
use scanstation::stages::NoProgress;

/// One oracle: its mesh, Euler characteristic and (where known in closed form) volume.
struct Oracle {
    name: &'static str,
    mesh: TriMesh,
    chi: i64,
}

fn diagonal(m: &TriMesh) -> f64 {
    m.bbox().diagonal()
}

fn spacing_10k(m: &TriMesh) -> f64 {
    (m.area() / 10_000.0).sqrt()
}

/// A surface of revolution remade until its profile step is a third of its own 10k spacing (a scan several
/// times denser than the net), every ring at least 16 around (a thin rod or a tip sampled round).
fn revolved(profile: impl Fn(f64, f64) -> Vec<[f64; 2]>, closed: bool, size: impl Fn(&TriMesh) -> f64) -> TriMesh {
    let mut step = 0.05;
    let mut mesh = revolve_rings(&profile(1.0, step), closed, step, 16);
    for _ in 0..2 {
        let s = size(&mesh);
        step = spacing_10k(&mesh) / 3.0;
        mesh = revolve_rings(&profile(s, step), closed, step, 16);
    }
    mesh
}

fn oracle(name: &str) -> Oracle {
    let (mesh, chi) = match name {
        "plate" => (revolved(plate_profile, false, |m| 0.003 * diagonal(m)), 2),
        "leg" => (revolved(|r, h| leg_profile(r.min(0.5), h), false, |m| 0.2 * spacing_10k(m)), 2),
        "cone tip" => (revolved(|_, h| cone_tip_profile(15.0, h), false, |_| 0.0), 2),
        "folded sheet" => {
            (revolved(|g, h| folded_sheet_profile(0.2, g.min(0.1), h), true, |m| 0.1 * spacing_10k(m)), 0)
        }
        "blade" => (revolved(|t, h| lens_profile(t.min(0.05), h), false, |m| 0.002 * diagonal(m)), 2),
        "hand" => {
            let first = hand(0.02, 1.0, 6, 0.01);
            let r = 0.004 * diagonal(&first);
            (hand(r, 1.0, 6, r * std::f64::consts::TAU / 10.0), 2)
        }
        "creased block" => {
            let first = chamfered_block(0.3, 0.1);
            (chamfered_block(0.3, spacing_10k(&first) / 2.0), 2)
        }
        other => panic!("no oracle named {other}"),
    };
    Oracle { name: leak(name), mesh, chi }
}

fn leak(s: &str) -> &'static str {
    Box::leak(s.to_string().into_boxed_str())
}

const ALL: [&str; 7] = ["plate", "leg", "cone tip", "folded sheet", "hand", "blade", "creased block"];

/// Where an oracle's files go: `SCANSTATION_ORACLES_OUT` or a fresh temporary directory.
fn out_dir() -> PathBuf {
    match std::env::var_os("SCANSTATION_ORACLES_OUT") {
        Some(d) => PathBuf::from(d),
        None => std::env::temp_dir().join(format!("scanstation-oracles-{}", std::process::id())),
    }
}

fn file_name(name: &str, ext: &str) -> String {
    format!("{}.{ext}", name.replace(' ', "-"))
}

fn write_input(o: &Oracle, dir: &Path) -> PathBuf {
    std::fs::create_dir_all(dir).unwrap();
    let path = dir.join(file_name(o.name, "ply"));
    write_ply(&path, &o.mesh.clone().into(), &VertexAttributes::default(), &["scanstation oracle"])
        .unwrap_or_else(|e| panic!("{}: writing its PLY: {e}", o.name));
    path
}

/// Every oracle is what it claims: a closed, oriented 2-manifold of its Euler characteristic, outward, and
/// at its fine part as fine as asked (checked on the mesh: the plate's, the blade's and the finger's size).
#[test]
fn the_oracles_are_closed_outward_surfaces_of_known_genus() {
    for name in ALL {
        let o = oracle(name);
        let topo = TopologyReport::compute(&o.mesh.clone().into());
        let (d, s) = (diagonal(&o.mesh), spacing_10k(&o.mesh));
        println!(
            "{name}: {} vertices, χ {}, volume {:.5}, diagonal {d:.4}, 10k spacing {s:.5}",
            o.mesh.positions.len(),
            topo.euler_characteristic,
            o.mesh.signed_volume()
        );
        assert!(
            topo.closed && topo.nonmanifold_edges == 0 && topo.nonmanifold_vertices == 0 && topo.consistently_oriented,
            "{name}: {topo:?}"
        );
        assert_eq!(topo.components, 1, "{name}: one part");
        assert_eq!(topo.euler_characteristic, o.chi, "{name}: χ");
        assert!(o.mesh.signed_volume() > 0.0, "{name}: inward");
        if std::env::var_os("SCANSTATION_ORACLES_OUT").is_some() {
            write_input(&o, &out_dir());
        }
        let b = o.mesh.bbox();
        let thin = (b.max[2] - b.min[2]) / d;
        match name {
            "plate" => assert!((thin - 0.003).abs() < 3e-4, "{name}: {thin} of the diagonal thick"),
            "blade" => assert!((thin - 0.002).abs() < 2e-4, "{name}: {thin} of the diagonal thick"),
            _ => {}
        }
    }
}

/// What one oracle's conversion at the defaults measured.
fn convert(name: &str) -> (Oracle, ConvertReport) {
    let o = oracle(name);
    let keep = std::env::var_os("SCANSTATION_ORACLES_OUT").is_some();
    // A directory of its own, removed afterwards unless kept (the tests run side by side).
    let dir = if keep {
        out_dir()
    } else {
        std::env::temp_dir().join(format!("scanstation-oracle-{}-{}", name.replace(' ', "-"), std::process::id()))
    };
    let input = write_input(&o, &dir);
    let output = dir.join(file_name(name, "step"));
    let r = convert_file(&input, &output, &ReadOptions::default(), &ConvertOptions::default(), &NoProgress)
        .unwrap_or_else(|e| panic!("{name}: convert ended in {e}"));
    if keep {
        std::fs::write(dir.join(file_name(name, "json")), serde_json::to_vec_pretty(&r).unwrap()).unwrap();
    } else {
        std::fs::remove_dir_all(&dir).ok();
    }
    let gates: Vec<String> = r.gates.iter().map(|g| format!("{} {:.4} ({})", g.name, g.value, g.passed)).collect();
    println!(
        "{name}: {:?}, {} attempt(s), {} control vertices, far tail {:.3} % at {:?}, gates {gates:?}, {:.1} s",
        r.status,
        r.attempts.len(),
        r.attempts.last().map_or(0, |a| a.control_vertices),
        r.far_tail.max_pct,
        r.far_tail.at,
        r.total_seconds
    );
    (o, r)
}

/// Issue 58's acceptance for an oracle delivered at the defaults: one attempt, no crossing or fold, χ kept,
/// volume within 0.5 %, RMS within the gate and the farthest scan point within 0.2 % of the diagonal.
fn assert_delivered(o: &Oracle, r: &ConvertReport) {
    let name = o.name;
    assert!(r.verdict().is_ok(), "{name}: refused: {:?}", r.verdict());
    assert_eq!(r.attempts.len(), 1, "{name}: attempts {:?}", r.attempts.len());
    let gate = |g: &str| r.gates.iter().find(|x| x.name == g).unwrap_or_else(|| panic!("{name}: no {g} gate"));
    assert_eq!(gate("crossings").value, 0.0, "{name}: crossings");
    assert_eq!(gate("folds").value, 0.0, "{name}: folds");
    assert_eq!(r.remesh.output.euler_characteristic, o.chi, "{name}: χ of the net");
    assert!(r.volume_error_pct.abs() <= 0.5, "{name}: volume error {} %", r.volume_error_pct);
    assert!(gate("rms").passed, "{name}: RMS {} %", gate("rms").value);
    assert!(r.far_tail.max_pct <= 0.2, "{name}: farthest scan point {} % of the diagonal", r.far_tail.max_pct);
}

/// The cone tip and the hand's fingers are kept to their ends (measured 2026-12-08: the cone 0.109 % of the
/// diagonal at most, its tip; the hand 0.112 %, raised to 15,000 control vertices and refined for its tips).
#[test]
fn the_cone_tip_and_the_fingers_are_delivered_to_their_ends() {
    for name in ["cone tip", "hand"] {
        let (o, r) = convert(name);
        assert_delivered(&o, &r);
    }
}

/// The oracles the chain does not deliver to issue 58's bounds yet end in a verdict — delivered, or refused by a
/// named quality gate, never an internal error — and the far tail the report counts is the one the gate judged
/// (measured 2026-12-08: the plate's rim pulled in, 4.03 % of the diagonal, volume −6.2 %; the leg lost with a
/// ball, volume −50 %; the folded sheet 5 folds; the blade's rim 4.33 %, volume −2.5 %; the block delivered,
/// its corners rounded 0.216 %).
#[test]
fn the_oracles_not_yet_delivered_end_in_a_named_quality_verdict() {
    for name in ["plate", "leg", "folded sheet", "blade", "creased block"] {
        let (_, r) = convert(name);
        let gate = r.gates.iter().find(|g| g.name == "max-distance").expect("a max-distance gate");
        assert_eq!(gate.value, r.far_tail.max_pct, "{name}: the gate judges the far tail the report counts");
        match r.verdict() {
            Ok(()) => println!("{name}: delivered"),
            Err(e) => {
                let code = e.code.as_str();
                assert!(code.starts_with("quality."), "{name}: {code}: {e}");
                let missed: Vec<&str> = r.gates.iter().filter(|g| !g.passed).map(|g| g.name).collect();
                assert!(!missed.is_empty(), "{name}: refused with every gate passed");
            }
        }
    }
}

/// A machined block's flat faces (a uniform 524k-vertex triangulation) keep working vertices when it is
/// decimated for the net: decimation's quadric is zero inside a flat face, so the working mesh kept only the
/// faces' rims and the net had 8 vertices (volume −41.7 %, 2026-12-08); with the long edges split
/// (`DECIMATED_LONG_EDGE`) the net has the count asked, within 10 %.
#[test]
fn a_machined_block_is_remeshed_at_the_count_asked() {
    use scanstation::stages::remesh::{RemeshOptions, remesh};
    let o = oracle("creased block");
    assert!(
        o.mesh.positions.len() > 150_000,
        "creased block: dense enough to be decimated: {}",
        o.mesh.positions.len()
    );
    let opts = RemeshOptions { target_vertices: 10_000, compare_samples: 0, ..RemeshOptions::convert_default() };
    let (q, r) = remesh(&o.mesh, &opts, &NoProgress).unwrap_or_else(|e| panic!("creased block: {e}"));
    let n = q.positions.len() as f64;
    assert!((n / 10_000.0 - 1.0).abs() <= 0.1, "creased block: {n} vertices ({:?}, {})", r.mode, r.working_mesh);
    assert_eq!(r.output.euler_characteristic, 2, "creased block: χ");
}

//! Same input, same settings, any thread count: the same bytes. The remesh docs promise it (the fields are
//! updated by colour classes, sums are taken in order); these tests run the stage and the whole chain in a
//! 1-thread and a 2-thread rayon pool and compare the outputs bit for bit.

mod common;

use std::path::Path;

use scanstation::geometry::io::{ReadOptions, read_mesh};
use scanstation::geometry::shapes::torus;
use scanstation::pipeline::{ConvertOptions, Resolution, convert_file};
use scanstation::stages::NoProgress;
use scanstation::stages::remesh::{RemeshOptions, remesh};

const SPOT: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/examples/spot.ply");

fn pool(threads: usize) -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("a rayon pool")
}

#[test]
fn remesh_gives_the_same_quads_on_one_and_two_threads() {
    // The torus runs the cancellation tries (split route) and the spot scan the full cascade.
    let spot = read_mesh(Path::new(SPOT), &ReadOptions::default()).expect("examples/spot.ply").triangulate().0;
    for (name, mesh, target) in [("torus", torus(1.0, 0.4, 120, 48), 1500), ("spot", spot, 2000)] {
        let opts = RemeshOptions { target_vertices: target, compare_samples: 5_000, ..Default::default() };
        let run = |threads: usize| pool(threads).install(|| remesh(&mesh, &opts, &NoProgress)).expect(name);
        let ((one, r1), (two, r2)) = (run(1), run(2));
        assert_eq!(one.positions, two.positions, "{name}: positions differ between 1 and 2 threads");
        assert!(one.faces().eq(two.faces()), "{name}: faces differ between 1 and 2 threads");
        assert_eq!(r1.mode, r2.mode, "{name}: route");
        assert_eq!(r1.attempts.len(), r2.attempts.len(), "{name}: attempts");
        let rms = |r: &scanstation::stages::remesh::RemeshReport| r.distance.as_ref().map(|d| d.symmetric.rms.value);
        assert_eq!(rms(&r1), rms(&r2), "{name}: distance to the input");
    }
}

#[test]
fn convert_writes_the_same_bytes_on_one_and_two_threads() {
    let dir = common::scratch("determinism-convert");
    // With its pictures: the same job gives the same PNG bytes too (issue 45).
    let pictures = Some(scanstation::pipeline::pictures::Up::Y);
    // The default kind of resolution, the deviation goal, from 1,000 control vertices: spot's net there is
    // over twice the goal, so the net is made again at 1,500 (the cap) before the fit, on each thread count.
    let opts = ConvertOptions {
        resolution: Resolution::Goal { start: 1_000, cap: 1_500 },
        compare_samples: 20_000,
        pictures,
        ..Default::default()
    };
    let outputs: Vec<Vec<Vec<u8>>> = [1, 2]
        .iter()
        .map(|&threads| {
            // Same file name in both runs: the STEP header and the solid mesh's hash comment name it.
            let sub = dir.join(format!("{threads}-threads"));
            std::fs::create_dir_all(&sub).unwrap();
            let step = sub.join("spot.step");
            let report = pool(threads)
                .install(|| convert_file(Path::new(SPOT), &step, &ReadOptions::default(), &opts, &NoProgress))
                .expect("convert examples/spot.ply");
            let raised: Vec<(usize, usize, bool)> =
                report.attempts[0].raises.iter().map(|x| (x.from_vertices, x.to_vertices, x.kept)).collect();
            assert_eq!(raised, [(1_000, 1_500, true)], "{threads} threads");
            // The raised net is refined locally too (its scan → net RMS is over 1.5 × the goal at 1,500).
            let local = &report.attempts[0].local;
            assert!(
                local.kept.as_ref().is_some_and(|k| k.vertices_after > k.vertices_before),
                "{threads} threads: {local:?}"
            );
            let kinds: Vec<&str> = report.pictures.iter().map(|p| p.kind).collect();
            assert_eq!(kinds, ["deviation", "histogram", "net", "faces", "thumbnail"], "{threads} threads");
            let files = [&step, &report.solid_mesh_file, &report.error_map_file];
            files
                .into_iter()
                .chain(report.pictures.iter().map(|p| &p.file))
                .map(|p| std::fs::read(p).unwrap_or_else(|e| panic!("{}: {e}", p.display())))
                .collect()
        })
        .collect();
    let names = ["STEP file", "solid mesh", "error map", "deviation", "histogram", "net", "faces", "thumbnail"];
    for (k, what) in names.iter().enumerate() {
        let (a, b) = (&outputs[0][k], &outputs[1][k]);
        assert!(!a.is_empty(), "{what}: empty");
        assert!(a == b, "{what}: {} bytes on 1 thread and {} on 2 differ", a.len(), b.len());
    }
}

/// Reconstruction from spot's vertices (estimated normals, so the orientation's tree too): the same mesh on
/// one and two threads.
#[test]
fn reconstruct_gives_the_same_mesh_on_one_and_two_threads() {
    use scanstation::stages::reconstruct::{ReconstructOptions, reconstruct};
    let spot = read_mesh(Path::new(SPOT), &ReadOptions::default()).expect("examples/spot.ply");
    let cloud = scanstation::PointCloud::new(spot.positions.clone(), None, None).unwrap();
    let run = |threads: usize| {
        pool(threads).install(|| reconstruct(&cloud, &ReconstructOptions::default(), &NoProgress)).expect("spot")
    };
    let ((one, r1), (two, r2)) = (run(1), run(2));
    assert!(one.triangles.len() > 1000, "spot: {} triangles", one.triangles.len());
    assert_eq!(one.positions, two.positions, "spot: positions differ between 1 and 2 threads");
    assert_eq!(one.triangles, two.triangles, "spot: triangles differ between 1 and 2 threads");
    assert_eq!(r1.iso_value.to_bits(), r2.iso_value.to_bits(), "spot: iso-value");
}

/// Repair of an open base that gets a membrane cap (a cylinder whose open rim waves along the axis, issue
/// 43's oracle) gives the same bytes and the same report on one and two threads.
#[test]
fn repair_caps_an_open_base_the_same_on_one_and_two_threads() {
    use scanstation::stages::repair::{RepairOptions, repair};
    let mut rod = scanstation::geometry::shapes::rod(1.0, 4.0, 96, 64);
    let c0 = (rod.positions.len() - 2) as u32;
    rod.triangles.retain(|t| !t.contains(&c0));
    for p in rod.positions.iter_mut().filter(|p| p[0] == 0.0 && (p[1] != 0.0 || p[2] != 0.0)) {
        p[0] = (0.049 * (3.0 * (p[2] as f64).atan2(p[1] as f64)).sin()) as f32;
    }
    let mesh = scanstation::PolyMesh::from(rod);
    let opts = RepairOptions { compare_samples: 5_000, ..Default::default() };
    let run = |threads: usize| pool(threads).install(|| repair(&mesh, &opts, &NoProgress)).expect("repair");
    let ((one, r1), (two, r2)) = (run(1), run(2));
    assert_eq!(r1.holes.caps.len(), 1, "{:?}", r1.holes.decisions);
    assert_eq!(one, two, "the repaired meshes differ between 1 and 2 threads");
    assert_eq!(r1.holes.decisions, r2.holes.decisions, "the hole decisions differ");
    assert_eq!(r1.holes.caps, r2.holes.caps, "the caps differ");
    assert_eq!(r1.holes.invented, r2.holes.invented, "the invented surfaces differ");
}

//! What the commands print: a text summary of each report, or the report as JSON, and errors with their exit
//! codes.

use std::process::ExitCode;

use scanstation::pipeline::{self, CompareReport, InspectReport};
use scanstation::stages::quality::{DistanceStats, Measure};
use scanstation::{Error, ErrorClass};

/// Stdout cannot be written: a reader that went away (`| head`) ends the process quietly with 141 (128 +
/// SIGPIPE); any other failure is reported on stderr with exit status 74 (EX_IOERR).
pub fn stdout_failed(e: &std::io::Error) -> ! {
    if e.kind() == std::io::ErrorKind::BrokenPipe {
        std::process::exit(141);
    }
    eprintln!("scanstation: error: cannot write to stdout: {e}");
    std::process::exit(74);
}

/// Prints `report` as JSON (with `"ok": true`) or as `text` does.
pub fn emit<T: serde::Serialize>(json: bool, report: &T, text: fn(&T)) {
    if json { print_json(report) } else { text(report) }
}

pub fn print_picture(p: &pipeline::pictures::Picture) {
    outln!("{} picture written to {} ({} bytes)", p.kind, p.file.display(), p.bytes);
}

/// What `scanstation report` wrote.
#[derive(serde::Serialize)]
pub struct PageWritten {
    /// The page.
    pub file: std::path::PathBuf,
    /// Its size.
    pub bytes: u64,
    /// Its SHA-256.
    pub sha256: String,
}

pub fn print_page(p: &PageWritten) {
    outln!("report page written to {} ({} bytes)", p.file.display(), p.bytes);
}

pub fn print_fea(r: &pipeline::fea::FeaFileReport) {
    let f = &r.result;
    outln!(
        "{}: {} unknowns on a {:?} grid of h = {} ({} active cells, {} cut)",
        r.input_file.display(),
        f.grid.unknowns,
        f.grid.cells,
        f.grid.cell_size,
        f.grid.active_cells,
        f.grid.cut_cells
    );
    outln!("  volume {:.6} (surface {:.6})", f.volume, f.surface_volume);
    outln!("  max displacement {:.6} at {:?}", f.max_displacement.value, f.max_displacement.at);
    outln!("  max von Mises {:.4} at {:?}", f.max_von_mises.value, f.max_von_mises.at);
    outln!("  reaction {:?} for load {:?} (imbalance {:.2e})", f.reaction, f.total_load, f.imbalance);
    for p in &f.probes {
        outln!("  probe {}: displacement {:?}, von Mises {:.4}", p.name, p.displacement, p.von_mises);
    }
    outln!("  {:.2} s, written to {}", r.seconds, r.output_dir.display());
    for p in &r.pictures {
        outln!("  {} picture: {}", p.kind, p.file.display());
    }
}

pub fn print_convert(r: &pipeline::ConvertReport) {
    outln!("{} -> {}", r.input_file.display(), r.output_file.display());
    outln!("  stage      seconds  peak MiB   RMS (% diag)   p95 (% diag)   max (% diag)");
    for s in &r.stages {
        let mem = s.peak_rss_mib.map(|m| format!("{m:8.0}")).unwrap_or_else(|| "       -".into());
        match &s.distance {
            Some(d) => outln!(
                "  {:<9} {:8.2} {}   {:.3e} ({:.4}%)  {:.3e} ({:.4}%)  {:.3e} ({:.4}%)",
                s.stage,
                s.seconds,
                mem,
                d.symmetric.rms.value,
                d.symmetric.rms.pct_of_diagonal,
                d.symmetric.p95.value,
                d.symmetric.p95.pct_of_diagonal,
                d.symmetric.max.value,
                d.symmetric.max.pct_of_diagonal
            ),
            None => outln!("  {:<9} {:8.2} {}", s.stage, s.seconds, mem),
        }
    }
    let b = &r.brep;
    outln!(
        "  solid: {} faces ({} packed) from {} patches, {} edges, {} vertices; volume {:.6e} ({:+.3}% vs input), max normal jump {:.3}° (p99 {:.3}°); folded faces {}, crossing pairs {}",
        b.faces,
        b.packed_faces,
        b.patches,
        b.edges,
        b.vertices,
        b.volume,
        r.volume_error_pct,
        b.max_normal_jump_deg,
        b.p99_normal_jump_deg,
        b.folded_faces,
        b.self_intersections
    );
    outln!(
        "  control net: {} vertices, {:.2}% irregular; fit RMS {:.3e}; total {:.1} s",
        r.fit.control_points,
        100.0 * r.remesh.output.irregular_fraction,
        r.fit.final_rms,
        r.total_seconds
    );
    if let Some(z) = &r.remesh.sizing {
        print_sizing(z, r.bbox_diagonal);
    }
    print_net_changes(r);
    let status = match r.status {
        pipeline::Status::Ok => "ok",
        pipeline::Status::Degraded => "DEGRADED (published on request)",
        pipeline::Status::Failed => "FAILED",
    };
    if let Some(o) = &r.open_input {
        outln!(
            "  open input: {} holes ({} capped); scan -> solid RMS {:.4} %, solid -> scan off the invented region {:.4} %",
            o.holes_filled,
            o.caps,
            o.scan_to_solid_rms_pct,
            o.solid_to_scan_off_invented_rms_pct,
        );
        let inv = &o.invented;
        outln!(
            "  invented region: {:.1} % of the solid's area ({:.4e} units²), {:.4} % RMS from what repair invented (max {:.4} %)",
            100.0 * inv.area_fraction,
            inv.area,
            inv.to_repaired_rms_pct,
            inv.to_repaired_max_pct,
        );
        for c in &o.cap_measures {
            let kind = match c.kind {
                Some(scanstation::stages::repair::caps::CapKind::Membrane) => "membrane",
                _ => "planar",
            };
            outln!(
                "    {kind} cap ({} rim edges): area {:.4e} units², {:.4} % RMS from its plane, bulge past it {:.4} % (rim off its plane {:.4} %)",
                c.edges,
                c.area,
                c.plane_rms_pct,
                c.bulge_pct,
                c.rim_residual_pct,
            );
        }
    }
    print_far_tail(&r.far_tail);
    outln!("  quality: {status}");
    for g in &r.gates {
        let num = |x: f64| if g.unit == "%" { format!("{x:.4}") } else { format!("{x:.0}") };
        outln!(
            "    {:<12} {:>10} {:<6} bound {:<8} {}",
            g.name,
            num(g.value),
            g.unit,
            num(g.bound),
            if g.passed { "ok" } else { "MISSED" }
        );
    }
    if let Some(first) = r.pictures.first() {
        let kinds: Vec<&str> = r.pictures.iter().map(|p| p.kind).collect();
        let page = pipeline::report_html::convert_page_path(&r.output_file);
        outln!("  pictures: {} beside {}; page {}", kinds.join(", "), first.file.display(), page.display());
    }
}

/// The nets made again finer under the deviation goal, and the kept net's local refinement.
fn print_net_changes(r: &pipeline::ConvertReport) {
    for x in r.attempts.iter().flat_map(|a| &a.raises) {
        outln!(
            "  net raised: {} -> {} vertices (net RMS {:.4} % -> {:.4} % of the diagonal, goal x2 = {:.4} %; {} crossing pairs; {}; {:.1} s)",
            x.from_vertices,
            x.to_vertices,
            x.from_rms_pct,
            x.to_rms_pct,
            pipeline::goal::NET_GOAL_FACTOR * r.gates.iter().find(|g| g.name == "rms").map_or(f64::NAN, |g| g.bound),
            x.to_crossing_pairs,
            if x.kept { "kept" } else { "not kept" },
            x.seconds
        );
    }
    if let Some(a) = r.attempts.last() {
        if let Some(k) = &a.local.kept {
            let rounds: Vec<String> = k
                .rounds
                .iter()
                .filter(|x| x.kept)
                .map(|x| {
                    format!(
                        "+{} at {} far samples, scan -> net RMS {:.4} % -> {:.4} %, max {:.4} % -> {:.4} %",
                        x.added_vertices,
                        x.far_samples,
                        100.0 * x.rms_before / r.bbox_diagonal,
                        100.0 * x.rms_after / r.bbox_diagonal,
                        100.0 * x.max_before / r.bbox_diagonal,
                        100.0 * x.max_after / r.bbox_diagonal
                    )
                })
                .collect();
            let why = match a.local.trigger {
                Some(pipeline::refine::Trigger::FarTail) => "for the far tail",
                _ => "for the RMS",
            };
            outln!(
                "  net refined locally {why}: {} -> {} vertices ({}; {:.1} s)",
                k.vertices_before,
                k.vertices_after,
                rounds.join("; then "),
                k.seconds
            );
        }
        if a.local.given_up > 0 {
            outln!("  refined nets given up: {} (the solid crossed itself or folded there)", a.local.given_up);
        }
    }
}

/// The far tail of the scan → solid distance: its largest value, where, and how much lies beyond the goal.
fn print_sizing(z: &scanstation::stages::remesh::SizingSummary, diagonal: f64) {
    let pct = |x: f64| 100.0 * x / diagonal.max(f64::MIN_POSITIVE);
    outln!(
        "  sizing: lattice step asked {:.4} % of the diagonal at least, {:.4} % median (uniform {:.4} %; the net's spacing about half: each face is split in four); thin {:.1} %, bent {:.1} % of the area",
        pct(z.min_spacing),
        pct(z.median_spacing),
        pct(z.uniform_spacing),
        100.0 * z.thin_share,
        100.0 * z.curved_share
    );
}

fn print_far_tail(t: &pipeline::far_tail::FarTail) {
    outln!(
        "  far tail: scan -> solid at most {:.4} % of the diagonal, at ({:.4}, {:.4}, {:.4}); {} scan vertices beyond the goal {:.2} % in {} places{}",
        t.max_pct,
        t.at[0],
        t.at[1],
        t.at[2],
        t.vertices_beyond_goal,
        t.goal_pct,
        t.places.len(),
        if t.dropped_by_repair > 0 {
            format!("; {} left by repair (up to {:.4} %), not judged", t.dropped_by_repair, t.dropped_max_pct)
        } else {
            String::new()
        }
    );
}

/// Human-readable `reconstruct` report.
pub fn print_reconstruct(r: &pipeline::ReconstructFileReport) {
    let m = &r.reconstruct;
    outln!("{} -> {}", r.input_file.display(), r.output_file.display());
    outln!(
        "  {} points ({} normals), mean spacing {:.4}; grid {:?} nodes, cell {:.4}",
        m.points,
        if m.normals_given { "given" } else { "estimated" },
        m.mean_spacing,
        m.grid_nodes,
        m.cell_size
    );
    if let Some(t) = &m.thinning {
        outln!(
            "  thinned to fit the memory budget: {} points merged into {} (cells of {:.4}; room for {})",
            t.points_before,
            t.points_after,
            t.cell,
            t.max_points
        );
    }
    if let Some(o) = &m.orientation {
        outln!(
            "  orientation: {} normals turned along the tree, {} uncertain, {} parts{}",
            o.flipped,
            o.uncertain,
            o.parts,
            if o.turned_over { ", all turned outward by the flux check" } else { "" }
        );
    }
    for l in &m.levels {
        outln!("  solve {:?}: {} iterations, residual {:.1e}", l.nodes, l.iterations, l.relative_residual);
    }
    outln!(
        "  result: {} vertices, {} triangles, {} components ({} bubbles, {} blobs removed); {:.2} % of the area far from the points",
        m.vertices,
        m.triangles,
        m.components.kept,
        m.components.bubbles_removed,
        m.components.blobs_removed,
        100.0 * m.far_area_share
    );
    let d = &r.distance;
    outln!(
        "  points to surface RMS {:.5} % of the diagonal (max {:.4} %); surface to points RMS {:.5} % (max {:.4} %)",
        d.reference_to_test.rms.pct_of_diagonal,
        d.reference_to_test.max.pct_of_diagonal,
        d.test_to_reference.rms.pct_of_diagonal,
        d.test_to_reference.max.pct_of_diagonal
    );
    outln!("  seconds: {:?}", m.seconds);
}

/// Human-readable `remesh` report.
pub fn print_remesh(r: &pipeline::RemeshFileReport) {
    let m = &r.remesh;
    let o = &m.output;
    outln!("{} -> {}", r.input_file.display(), r.output_file.display());
    outln!(
        "  input: {} vertices, {} faces, χ = {}; working mesh {} ({} vertices), {} levels",
        m.input_vertices,
        m.input_faces,
        m.input_euler_characteristic,
        m.working_mesh,
        m.working_vertices,
        m.hierarchy_levels
    );
    for (i, a) in m.attempts.iter().enumerate() {
        outln!(
            "  attempt {i} ({:?}): scale {:.5}, {} extracted vertices, faces by degree {:?}, {} unpaired -> {} predicted{}",
            a.mode,
            a.scale,
            a.extracted_vertices,
            a.extracted_faces_by_degree,
            a.triangles_unpaired,
            a.predicted_vertices,
            if i == m.chosen_attempt { " (kept)" } else { "" }
        );
    }
    outln!(
        "  output: {} vertices ({:+.1}% of target {}), {} faces, {:.1}% quads, closed {}, χ = {}",
        o.vertices,
        100.0 * m.vertex_count_error,
        m.target_vertices,
        o.faces,
        100.0 * o.quad_fraction,
        o.closed,
        o.euler_characteristic
    );
    outln!(
        "  irregular vertices {} ({:.2}%), valences {:?}, flipped faces {}, non-manifold edges {}",
        o.irregular_vertices,
        100.0 * o.irregular_fraction,
        o.valence_histogram,
        o.flipped_faces,
        o.nonmanifold_edges
    );
    let t = &m.dipole_transport;
    outln!(
        "  dipole transport: {} chains ({} moves, {} settled), Σ|valence − 4| {} -> {}, vertices +{} -{}",
        t.chains,
        t.moves,
        t.settled_chains,
        t.irregularity_before,
        t.irregularity_after,
        t.vertices_added,
        t.vertices_removed
    );
    outln!(
        "  corner angle deviation mean {:.1}°, p95 {:.1}°; edge length {:.4} (cv {:.2})",
        o.angle_deviation_mean_deg,
        o.angle_deviation_p95_deg,
        o.edge_length_mean,
        o.edge_length_cv
    );
    if let Some(d) = &m.distance {
        outln!(
            "  distance to input: RMS {} ({:.4}% of diagonal), max {}",
            d.symmetric.rms.value,
            d.symmetric.rms.pct_of_diagonal,
            d.symmetric.max.value
        );
    }
    outln!("  seconds: {:?}", m.seconds);
}

pub fn print_json<T: serde::Serialize>(v: &T) {
    let mut value = serde_json::to_value(v).expect("reports serialise");
    if let serde_json::Value::Object(m) = &mut value {
        m.insert("ok".into(), true.into());
    }
    outln!("{}", serde_json::to_string_pretty(&value).expect("reports serialise"));
}

/// Exit codes: 2 bad input, 3 resource limit, 4 a failed quality gate, 70 internal error (EX_SOFTWARE).
pub fn report_error(e: &Error, json: bool) -> ExitCode {
    if json {
        outln!("{}", serde_json::json!({ "ok": false, "error": e, "error_code": e.code.as_str() }));
    }
    eprintln!("scanstation: error: {e}");
    exit_code(e)
}

/// The exit status of an error's class.
pub fn exit_code(e: &Error) -> ExitCode {
    ExitCode::from(match e.class() {
        ErrorClass::BadInput => 2,
        ErrorClass::Resource => 3,
        ErrorClass::Quality => 4,
        ErrorClass::Device => 5,
        ErrorClass::Internal => 70,
    })
}

/// A conversion whose solid failed a quality gate: its report was printed (with `"status": "failed"`), so
/// only the error goes to stderr; the files stay where they were written, for inspection.
pub fn report_quality_failure(e: &Error, r: &pipeline::ConvertReport) -> ExitCode {
    eprintln!("scanstation: error: {e}");
    eprintln!(
        "scanstation: the rejected solid is kept for inspection: {}, {}, {}",
        r.output_file.display(),
        r.solid_mesh_file.display(),
        r.error_map_file.display()
    );
    exit_code(e)
}

pub fn print_inspect(r: &InspectReport) {
    outln!("file:                  {}", r.file.display());
    outln!("kind:                  {}", r.kind);
    for v in r.views.iter().flatten() {
        outln!(
            "view {:<16} {:>8} points, t = {:?}, R = {:?}",
            v.name,
            v.point_count,
            v.pose.translation,
            v.pose.rotation
        );
    }
    if let Some(c) = &r.cloud {
        outln!("points:                {}", c.vertices);
        outln!("normals / colors:      {} / {}", c.has_normals, c.has_colors);
        outln!("bbox:                  {:?} .. {:?}", c.bbox.min, c.bbox.max);
        outln!("bbox diagonal:         {:.6}", c.bbox_diagonal);
    }
    if let Some(m) = &r.mesh {
        let degrees: Vec<String> = m.faces_by_degree.iter().map(|(d, n)| format!("{n} × {d}-gon")).collect();
        outln!(
            "vertices:              {} ({} referenced, {} unreferenced)",
            m.vertices,
            m.referenced_vertices,
            m.unreferenced_vertices
        );
        outln!("faces:                 {} ({})", m.faces, degrees.join(", "));
        outln!("edges:                 {}", m.edges);
        outln!("bbox:                  {:?} .. {:?}", m.bbox.min, m.bbox.max);
        outln!("bbox diagonal:         {:.6}", m.bbox_diagonal);
        outln!("area:                  {:.6}", m.area);
        match m.volume {
            Some(v) => outln!("volume:                {v:.6}"),
            None => outln!("volume:                - (not closed)"),
        }
        outln!("closed:                {}", m.closed);
        outln!("boundary loops:        {} ({} boundary edges)", m.boundary_loops, m.boundary_edges);
        outln!("non-manifold:          {} edges, {} vertices", m.nonmanifold_edges, m.nonmanifold_vertices);
        outln!("components:            {}", m.components);
        outln!("degenerate faces:      {}", m.degenerate_faces);
        outln!("coincident vertices:   {}", m.coincident_vertices);
        outln!(
            "orientation:           {} ({} conflicting directed edges)",
            if m.consistently_oriented { "consistent" } else { "inconsistent" },
            m.orientation_conflicts
        );
        outln!("euler characteristic:  {}", m.euler_characteristic);
        match m.genus {
            Some(g) => outln!("genus:                 {g}"),
            None => outln!("genus:                 - (not an orientable manifold)"),
        }
    }
    outln!("read / analyse:        {:.3} s / {:.3} s", r.read_seconds, r.analyse_seconds);
}

pub fn fmt_measure(m: &Measure) -> String {
    let part = m.one_part_in.map_or("-".to_string(), |n| format!("1:{n:.0}"));
    format!("{:>12.6e} {:>9.4}% {:>10}", m.value, m.pct_of_diagonal, part)
}

pub fn print_compare(r: &CompareReport) {
    outln!(
        "test:      {} ({}, {} vertices, {} faces)",
        r.test.file.display(),
        r.test.kind,
        r.test.vertices,
        r.test.faces
    );
    outln!(
        "reference: {} ({}, {} vertices, {} faces)",
        r.reference.file.display(),
        r.reference.kind,
        r.reference.vertices,
        r.reference.faces
    );
    let d = &r.distance;
    outln!(
        "reference bbox diagonal {:.6}; {} samples per side, seed {}",
        d.reference_bbox_diagonal,
        d.samples_per_side,
        d.seed
    );
    outln!("{:<18} {:<8} {:>12} {:>10} {:>10}", "direction", "figure", "value", "% diag", "1 part in");
    let rows: [(&str, &DistanceStats); 3] = [
        ("test→reference", &d.test_to_reference),
        ("reference→test", &d.reference_to_test),
        ("symmetric", &d.symmetric),
    ];
    for (name, s) in rows {
        for (fig, m) in [("rms", &s.rms), ("mean", &s.mean), ("median", &s.median), ("p95", &s.p95), ("max", &s.max)] {
            outln!("{name:<18} {fig:<8} {}", fmt_measure(m));
        }
    }
    if let Some(p) = &r.error_map {
        outln!("error map: {} (colour scale 0 .. {:.6e})", p.display(), r.error_map_scale.unwrap_or(0.0));
    }
    outln!("read / compare: {:.3} s / {:.3} s", r.read_seconds, r.compare_seconds);
}

pub fn print_repair(r: &pipeline::RepairFileReport) {
    let rep = &r.repair;
    outln!("input:   {} ({} vertices, {} faces)", r.input_file.display(), rep.input.vertices, rep.input.faces);
    let w = &rep.weld;
    outln!(
        "weld:    {} vertices merged, {} collapsed and {} duplicate faces dropped, {} unreferenced vertices dropped",
        w.merged_vertices,
        w.collapsed_faces,
        w.duplicate_faces,
        w.unreferenced_vertices
    );
    let m = &rep.manifold;
    outln!(
        "manifold: {} non-manifold edges ({} faces removed), {} faces flipped, {} removed for orientation, {} vertices split",
        m.nonmanifold_edges,
        m.faces_removed_at_nonmanifold_edges,
        m.faces_flipped,
        m.faces_removed_orientation,
        m.vertices_split
    );
    outln!(
        "components: {} found, {} kept ({:.2} % of the area), {} debris faces removed",
        m.components_found,
        m.components_kept,
        100.0 * m.area_share_kept,
        m.faces_removed_debris
    );
    let h = &rep.holes;
    outln!(
        "holes:   {} filled (largest {} edges), {} triangles and {} vertices added",
        h.holes_filled,
        h.largest_hole_edges,
        h.triangles_added,
        h.vertices_added
    );
    let hd = &rep.handles;
    if hd.max_loop > 0.0 {
        outln!(
            "handles: {} cut (genus −{}; loops under {:.4e}), {} faces removed, {} triangles added; {} seeds, {} \
             balls searched, {} searches given up",
            hd.cuts,
            hd.genus_removed,
            hd.max_loop,
            hd.faces_removed,
            hd.triangles_added,
            hd.seeds,
            hd.balls_searched,
            hd.searches_given_up
        );
    }
    let o = &rep.output;
    outln!(
        "output:  {} ({} vertices, {} faces, closed {}, genus {:?}, volume {:.6e})",
        r.output_file.display(),
        o.vertices,
        o.faces,
        o.closed,
        o.genus,
        o.volume.unwrap_or(f64::NAN)
    );
    let d = &rep.distance.symmetric;
    outln!(
        "distance to input: rms {:.4e} ({:.4} %), max {:.4e} ({:.4} %); repair took {:.3} s",
        d.rms.value,
        d.rms.pct_of_diagonal,
        d.max.value,
        d.max.pct_of_diagonal,
        rep.seconds
    );
}

//! `scanstation` — the command-line tool: inspect and compare scans (one-shot conversion and the D-Bus
//! client arrive with their issues). Thin: parsing, output formatting and exit codes only; the work is in
//! the library's `pipeline` layer.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use scanstation::geometry::io::ReadOptions;
use scanstation::pipeline::{self, CompareReport, InspectReport};
use scanstation::stages::NoProgress;
use scanstation::stages::quality::{CompareOptions, DistanceStats, Measure};
use scanstation::{Error, ErrorClass};

#[derive(Parser)]
#[command(name = "scanstation", version, about = "3D scan to CAD solid: inspect, compare (more stages to come)")]
struct Cli {
    /// Print the report as JSON on stdout (errors too, as {"ok": false, "error": {...}}).
    #[arg(long, global = true)]
    json: bool,
    /// Memory budget for reading and measuring, e.g. 512M, 4G.
    #[arg(long, global = true, default_value = "8G", value_parser = parse_bytes)]
    memory_budget: u64,
    /// More log output on stderr (-v info, -vv debug).
    #[arg(short, long, global = true, action = clap::ArgAction::Count)]
    verbose: u8,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Counts, size and topology of a mesh or point cloud (PLY, OBJ, STL, OFF, XYZ/PTS; .gz too).
    Inspect {
        /// The file to inspect.
        file: PathBuf,
    },
    /// Make a mesh a closed, outward-oriented 2-manifold: weld, fix non-manifold parts and orientation, drop
    /// debris, fill holes (smoothly); report each step and the distance to the input.
    Repair {
        /// The mesh to repair.
        input: PathBuf,
        /// Where to write the result (.ply binary, or .obj).
        #[arg(short, long)]
        output: PathBuf,
        /// Keep components other than the largest when they hold at least this share of the area.
        #[arg(long, default_value_t = 0.1)]
        keep_share: f64,
        /// Do not move spike vertices (far off their neighbours' plane) to their ring centroid.
        #[arg(long)]
        keep_spikes: bool,
        /// Taubin (non-shrinking) smoothing iterations.
        #[arg(long, default_value_t = 0)]
        smooth: usize,
        /// Decimate the repaired mesh to this many vertices (quadric error metric).
        #[arg(long)]
        target_vertices: Option<usize>,
        /// Cut handles (tunnels, bridges) whose shortest loop around them is shorter than this percentage of
        /// the bounding-box diagonal and fill both sides: topological noise of fused range scans (0: keep all).
        #[arg(long, default_value_t = 0.0)]
        max_handle_loop_pct: f64,
    },
    /// Field-aligned pure-quad remeshing of a closed mesh (run `repair` first): orientation and position
    /// fields, extraction, clean-up to all quads at the requested vertex count, projection onto the input.
    Remesh {
        /// The closed triangle mesh to remesh.
        input: PathBuf,
        /// Where to write the quad mesh (.obj keeps quads; anything else is binary PLY).
        #[arg(short, long)]
        output: PathBuf,
        /// Final vertex count wanted.
        #[arg(long, conflicts_with = "edge_length", required_unless_present = "edge_length")]
        vertices: Option<usize>,
        /// Target edge length instead (in the input's units): vertices = area / length².
        #[arg(long)]
        edge_length: Option<f64>,
        /// Seed of the random initial fields.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Gauss–Seidel sweeps per hierarchy level for each field.
        #[arg(long, default_value_t = scanstation::stages::remesh::RemeshOptions::default().iterations)]
        iterations: usize,
        /// Only the split route (extraction at a quarter of the count, then a regular split): fewer irregular
        /// vertices and faster, but features thinner than twice the spacing can be lost.
        #[arg(long)]
        split_only: bool,
        /// One spacing everywhere (no finer spacing on thin parts).
        #[arg(long)]
        uniform_spacing: bool,
        /// Extract from the position field as it is, without cancelling its singularities in pairs.
        #[arg(long)]
        keep_singularities: bool,
        /// Working-mesh vertices per output vertex.
        #[arg(long, default_value_t = scanstation::stages::remesh::RemeshOptions::default().work_per_vertex)]
        work_per_vertex: f64,
        /// Working-mesh vertices per output vertex for the direct routes (which extract at the full count).
        #[arg(long, default_value_t = scanstation::stages::remesh::RemeshOptions::default().work_per_vertex_direct)]
        work_per_vertex_direct: f64,
        /// No refined direct route (a finer spacing where the direct result missed thin parts).
        #[arg(long)]
        no_refine: bool,
        /// Rounds of the least-squares fit of the quad mesh to the input (0 = vertices stay on the input).
        #[arg(long, default_value_t = scanstation::stages::remesh::RemeshOptions::default().fit_rounds)]
        fit_rounds: usize,
        /// Longest chain of cost-neutral operations (edge rotations, vertex splits, diagonal collapses) that
        /// moves a dipole (valence 3–5 pair) until it cancels another (0 = no dipole transport).
        #[arg(long, default_value_t = scanstation::stages::remesh::RemeshOptions::default().dipole_depth)]
        dipole_depth: usize,
        /// Weight of the pull toward principal curvature directions (0 = off).
        #[arg(long, default_value_t = scanstation::stages::remesh::RemeshOptions::default().curvature_weight)]
        curvature_weight: f64,
        /// Extra pull, relative to the curvature weight, where the principal directions agree over the
        /// whole surface (tori, surfaces of revolution); 0 = off.
        #[arg(long, default_value_t = scanstation::stages::remesh::RemeshOptions::default().coherent_pull)]
        coherent_pull: f64,
    },
    /// The whole chain to a CAD solid: repair → quad remesh → fitted Catmull–Clark surface → B-spline B-rep
    /// → STEP (AP214), with a quality check, time and peak memory after every stage.
    Convert {
        /// The scan (a triangle or polygon mesh).
        input: PathBuf,
        /// The STEP file to write (written to a temporary name and renamed when complete).
        #[arg(short, long)]
        output: PathBuf,
        /// Control vertices of the quad net (default 10000).
        #[arg(long, conflicts_with = "tolerance")]
        vertices: Option<usize>,
        /// Refine coarse to fine until the solid's RMS distance to the input is at most this: a length in
        /// the input's units, or a percentage of the bounding-box diagonal such as 0.05%.
        #[arg(long)]
        tolerance: Option<String>,
        /// Write the full report as JSON here.
        #[arg(long, value_name = "R.json")]
        report: Option<PathBuf>,
        /// Also write the quad control net (.obj or .ply).
        #[arg(long)]
        quads: Option<PathBuf>,
        /// Length unit of the input, written into the STEP file: mm, cm or m.
        #[arg(long, default_value = "mm")]
        unit: String,
        /// Seed of remeshing and sampling.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Remesh by the split route only (see `remesh --split-only`): fewer extraordinary vertices, so fewer
        /// and larger faces, but features thinner than twice the spacing can be lost.
        #[arg(long)]
        split_only: bool,
        /// Keep handles (tunnels, bridges) too narrow for the quad net; by default repair cuts those whose
        /// loop is shorter than two quad spacings (π × the tolerance with --tolerance) and fills both sides.
        #[arg(long)]
        keep_small_handles: bool,
    },
    /// Immersed (meshless) linear statics on a solid: a closed mesh, or a STEP file `convert` wrote (through
    /// the NAME.solid.ply it writes beside it). Writes result.json and surface.vtu into OUTPUT.
    Fea {
        /// The solid: a closed tri-mesh (PLY, OBJ, STL, OFF) or a STEP file from `convert`.
        input: PathBuf,
        /// The spec (TOML): material, loads, supports, resolution, probes.
        #[arg(long)]
        spec: PathBuf,
        /// The result directory.
        #[arg(short, long)]
        output: PathBuf,
    },
    /// The station daemon's state (D-Bus client of scanstationd).
    Status {
        /// Use the session bus instead of the system bus.
        #[arg(long)]
        session: bool,
    },
    /// The station's jobs: queued, running and recently finished.
    Jobs {
        #[arg(long)]
        session: bool,
    },
    /// Queue a file on the station (its absolute path is sent; files outside the inbox are copied).
    Submit {
        file: PathBuf,
        /// Control vertices of the quad net for this job.
        #[arg(long)]
        vertices: Option<u32>,
        /// RMS tolerance (length) for this job instead of a vertex count.
        #[arg(long)]
        tolerance: Option<f64>,
        /// Follow the job until it finishes (exit status 1 when it fails).
        #[arg(long)]
        wait: bool,
        #[arg(long)]
        session: bool,
    },
    /// Cancel a job (by id or object path).
    Cancel {
        id: String,
        #[arg(long)]
        session: bool,
    },
    /// Follow progress: one job until it finishes, or every job until interrupted. A progress bar on a
    /// terminal, JSON lines otherwise (or with --json).
    Watch {
        id: Option<String>,
        #[arg(long)]
        session: bool,
    },
    /// Two-sided surface distance of TEST to REFERENCE (meshes or clouds): RMS, mean, median, p95, max.
    Compare {
        /// The surface to measure.
        test: PathBuf,
        /// The surface it is measured against (percentages use its bounding-box diagonal).
        reference: PathBuf,
        /// Area samples per side.
        #[arg(long, default_value_t = 200_000)]
        samples: usize,
        /// Sampling seed.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Write TEST with per-vertex distance and a colour ramp as binary PLY.
        #[arg(long, value_name = "OUT.ply")]
        error_map: Option<PathBuf>,
    },
}

fn parse_bytes(s: &str) -> Result<u64, String> {
    let s = s.trim();
    let (num, mult) = match s.chars().last().map(|c| c.to_ascii_uppercase()) {
        Some('K') => (&s[..s.len() - 1], 1u64 << 10),
        Some('M') => (&s[..s.len() - 1], 1 << 20),
        Some('G') => (&s[..s.len() - 1], 1 << 30),
        _ => (s, 1),
    };
    num.parse::<u64>().ok().and_then(|n| n.checked_mul(mult)).ok_or_else(|| format!("not a size: {s:?}"))
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let level = match cli.verbose {
        0 => tracing::Level::WARN,
        1 => tracing::Level::INFO,
        _ => tracing::Level::DEBUG,
    };
    tracing_subscriber::fmt().with_writer(std::io::stderr).with_max_level(level).init();
    let read = ReadOptions { memory_budget: cli.memory_budget };
    let result = match &cli.command {
        Command::Inspect { file } => {
            pipeline::inspect_file(file, &read).map(|r| if cli.json { print_json(&r) } else { print_inspect(&r) })
        }
        Command::Repair { input, output, keep_share, keep_spikes, smooth, target_vertices, max_handle_loop_pct } => {
            let opts = scanstation::stages::repair::RepairOptions {
                keep_share: *keep_share,
                remove_spikes: !keep_spikes,
                smooth_iterations: *smooth,
                target_vertices: *target_vertices,
                max_handle_loop_rel: max_handle_loop_pct / 100.0,
                memory_budget: cli.memory_budget,
                ..Default::default()
            };
            pipeline::repair_file(input, output, &read, &opts, &NoProgress)
                .map(|r| if cli.json { print_json(&r) } else { print_repair(&r) })
        }
        Command::Remesh {
            input,
            output,
            vertices,
            edge_length,
            seed,
            iterations,
            curvature_weight,
            coherent_pull,
            work_per_vertex,
            work_per_vertex_direct,
            no_refine,
            fit_rounds,
            dipole_depth,
            split_only,
            uniform_spacing,
            keep_singularities,
        } => {
            let opts = scanstation::stages::remesh::RemeshOptions {
                seed: *seed,
                iterations: *iterations,
                curvature_weight: *curvature_weight,
                coherent_pull: *coherent_pull,
                work_per_vertex: *work_per_vertex,
                work_per_vertex_direct: *work_per_vertex_direct,
                refine_missed: !*no_refine,
                fit_rounds: *fit_rounds,
                dipole_depth: *dipole_depth,
                try_direct: !*split_only,
                adaptive_spacing: !*uniform_spacing,
                cancel_singularities: !*keep_singularities,
                memory_budget: cli.memory_budget,
                ..Default::default()
            };
            remesh(input, output, *vertices, *edge_length, opts, &read)
                .map(|r| if cli.json { print_json(&r) } else { print_remesh(&r) })
        }
        Command::Convert {
            input,
            output,
            vertices,
            tolerance,
            report,
            quads,
            unit,
            seed,
            split_only,
            keep_small_handles,
        } => convert(
            input,
            output,
            *vertices,
            tolerance.as_deref(),
            report.as_deref(),
            quads,
            unit,
            *seed,
            !*split_only,
            !*keep_small_handles,
            &cli,
            &read,
        )
        .map(|r| if cli.json { print_json(&r) } else { print_convert(&r) }),
        Command::Fea { input, spec, output } => {
            let opts = scanstation::stages::fea::FeaOptions { memory_budget: cli.memory_budget };
            pipeline::fea::fea_file(input, spec, output, &read, &opts, &NoProgress)
                .map(|r| if cli.json { print_json(&r) } else { print_fea(&r) })
        }
        Command::Status { .. }
        | Command::Jobs { .. }
        | Command::Submit { .. }
        | Command::Cancel { .. }
        | Command::Watch { .. } => return station_client(&cli),
        Command::Compare { test, reference, samples, seed, error_map } => {
            let opts = CompareOptions {
                samples: *samples,
                seed: *seed,
                memory_budget: cli.memory_budget,
                ..Default::default()
            };
            pipeline::compare_files(test, reference, &read, &opts, error_map.as_deref(), &NoProgress)
                .map(|r| if cli.json { print_json(&r) } else { print_compare(&r) })
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => report_error(&e, cli.json),
    }
}

fn print_fea(r: &pipeline::fea::FeaFileReport) {
    let f = &r.result;
    println!(
        "{}: {} unknowns on a {:?} grid of h = {} ({} active cells, {} cut)",
        r.input_file.display(),
        f.grid.unknowns,
        f.grid.cells,
        f.grid.cell_size,
        f.grid.active_cells,
        f.grid.cut_cells
    );
    println!("  volume {:.6} (surface {:.6})", f.volume, f.surface_volume);
    println!("  max displacement {:.6} at {:?}", f.max_displacement.value, f.max_displacement.at);
    println!("  max von Mises {:.4} at {:?}", f.max_von_mises.value, f.max_von_mises.at);
    println!("  reaction {:?} for load {:?} (imbalance {:.2e})", f.reaction, f.total_load, f.imbalance);
    for p in &f.probes {
        println!("  probe {}: displacement {:?}, von Mises {:.4}", p.name, p.displacement, p.von_mises);
    }
    println!("  {:.2} s, written to {}", r.seconds, r.output_dir.display());
}

#[allow(clippy::too_many_arguments)]
fn convert(
    input: &std::path::Path,
    output: &std::path::Path,
    vertices: Option<usize>,
    tolerance: Option<&str>,
    report: Option<&std::path::Path>,
    quads: &Option<PathBuf>,
    unit: &str,
    seed: u64,
    direct: bool,
    remove_small_handles: bool,
    cli: &Cli,
    read: &ReadOptions,
) -> Result<pipeline::ConvertReport, Error> {
    use scanstation::ErrorCode;
    let bad = |m: String| Error::new(ErrorCode::InputBadArgument, m);
    let unit = scanstation::stages::brep::step::LengthUnit::parse(unit)
        .ok_or_else(|| bad(format!("unknown unit {unit:?}: use mm, cm or m")))?;
    let resolution = match (vertices, tolerance) {
        (Some(n), _) => pipeline::Resolution::Vertices(n),
        (None, Some(t)) => {
            let t = t.trim();
            let value = if let Some(pct) = t.strip_suffix('%') {
                let p: f64 = pct.trim().parse().map_err(|_| bad(format!("not a tolerance: {t:?}")))?;
                let mesh = scanstation::geometry::io::read_mesh(input, read)?;
                p / 100.0 * mesh.bbox().diagonal()
            } else {
                t.parse().map_err(|_| bad(format!("not a tolerance: {t:?}")))?
            };
            pipeline::Resolution::Tolerance(value)
        }
        (None, None) => pipeline::Resolution::Vertices(10_000),
    };
    if let Some(r) = report {
        scanstation::geometry::io::ensure_not_input(r, &[input, output])?;
    }
    let opts = pipeline::ConvertOptions {
        resolution,
        seed,
        unit,
        quads_output: quads.clone(),
        remove_small_handles,
        memory_budget: cli.memory_budget,
        remesh: scanstation::stages::remesh::RemeshOptions {
            try_direct: direct,
            ..scanstation::stages::remesh::RemeshOptions::convert_default()
        },
        ..Default::default()
    };
    let r = pipeline::convert_file(input, output, read, &opts, &NoProgress)?;
    if let Some(path) = report {
        let text = serde_json::to_string_pretty(&r).map_err(|e| Error::internal(e.to_string()))?;
        scanstation::geometry::io::write_atomic(path, |w| std::io::Write::write_all(w, text.as_bytes()))?;
    }
    Ok(r)
}

fn print_convert(r: &pipeline::ConvertReport) {
    println!("{} -> {}", r.input_file.display(), r.output_file.display());
    println!("  stage      seconds  peak MiB   RMS (% diag)   p95 (% diag)   max (% diag)");
    for s in &r.stages {
        let mem = s.peak_rss_mib.map(|m| format!("{m:8.0}")).unwrap_or_else(|| "       -".into());
        match &s.distance {
            Some(d) => println!(
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
            None => println!("  {:<9} {:8.2} {}", s.stage, s.seconds, mem),
        }
    }
    let b = &r.brep;
    println!(
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
    println!(
        "  control net: {} vertices, {:.2}% irregular; fit RMS {:.3e}; total {:.1} s",
        r.fit.control_points,
        100.0 * r.remesh.output.irregular_fraction,
        r.fit.final_rms,
        r.total_seconds
    );
}

fn remesh(
    input: &std::path::Path,
    output: &std::path::Path,
    vertices: Option<usize>,
    edge_length: Option<f64>,
    opts: scanstation::stages::remesh::RemeshOptions,
    read: &ReadOptions,
) -> Result<pipeline::RemeshFileReport, Error> {
    let target = match (vertices, edge_length) {
        (Some(v), _) => v,
        (None, Some(l)) => {
            if !(l.is_finite() && l > 0.0) {
                return Err(Error::new(scanstation::ErrorCode::InputBadArgument, "--edge-length must be > 0"));
            }
            let mesh = scanstation::geometry::io::read_mesh(input, read)?;
            let area = scanstation::geometry::topology::TopologyReport::compute(&mesh).area;
            (area / (l * l)).round().min(1e9) as usize
        }
        (None, None) => unreachable!("clap requires one of them"),
    };
    let opts = scanstation::stages::remesh::RemeshOptions { target_vertices: target, ..opts };
    pipeline::remesh_file(input, output, read, &opts, &NoProgress)
}

fn print_remesh(r: &pipeline::RemeshFileReport) {
    let m = &r.remesh;
    let o = &m.output;
    println!("{} -> {}", r.input_file.display(), r.output_file.display());
    println!(
        "  input: {} vertices, {} faces, χ = {}; working mesh {} ({} vertices), {} levels",
        m.input_vertices,
        m.input_faces,
        m.input_euler_characteristic,
        m.working_mesh,
        m.working_vertices,
        m.hierarchy_levels
    );
    for (i, a) in m.attempts.iter().enumerate() {
        println!(
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
    println!(
        "  output: {} vertices ({:+.1}% of target {}), {} faces, {:.1}% quads, closed {}, χ = {}",
        o.vertices,
        100.0 * m.vertex_count_error,
        m.target_vertices,
        o.faces,
        100.0 * o.quad_fraction,
        o.closed,
        o.euler_characteristic
    );
    println!(
        "  irregular vertices {} ({:.2}%), valences {:?}, flipped faces {}, non-manifold edges {}",
        o.irregular_vertices,
        100.0 * o.irregular_fraction,
        o.valence_histogram,
        o.flipped_faces,
        o.nonmanifold_edges
    );
    let t = &m.dipole_transport;
    println!(
        "  dipole transport: {} chains ({} moves, {} settled), Σ|valence − 4| {} -> {}, vertices +{} -{}",
        t.chains,
        t.moves,
        t.settled_chains,
        t.irregularity_before,
        t.irregularity_after,
        t.vertices_added,
        t.vertices_removed
    );
    println!(
        "  corner angle deviation mean {:.1}°, p95 {:.1}°; edge length {:.4} (cv {:.2})",
        o.angle_deviation_mean_deg, o.angle_deviation_p95_deg, o.edge_length_mean, o.edge_length_cv
    );
    if let Some(d) = &m.distance {
        println!(
            "  distance to input: RMS {} ({:.4}% of diagonal), max {}",
            d.symmetric.rms.value, d.symmetric.rms.pct_of_diagonal, d.symmetric.max.value
        );
    }
    println!("  seconds: {:?}", m.seconds);
}

/// The D-Bus client commands (thin: the work is in `scanstation::daemon::client::ops`).
fn station_client(cli: &Cli) -> ExitCode {
    use scanstation::daemon::client::ops;
    let rt = match tokio::runtime::Builder::new_current_thread().enable_all().build() {
        Ok(rt) => rt,
        Err(e) => return report_error(&Error::internal(format!("cannot start the async runtime: {e}")), cli.json),
    };
    let json = cli.json;
    let r: Result<bool, Error> = rt.block_on(async {
        match &cli.command {
            Command::Status { session } => {
                let conn = ops::connect(*session).await?;
                let s = ops::status(&conn).await?;
                if json {
                    print_json(&s);
                } else {
                    for (k, v) in s.as_object().into_iter().flatten() {
                        println!("{k:<14} {v}");
                    }
                }
                Ok(true)
            }
            Command::Jobs { session } => {
                let conn = ops::connect(*session).await?;
                let jobs = ops::jobs(&conn).await?;
                if json {
                    print_json(&serde_json::json!({ "jobs": jobs }));
                } else {
                    println!("{:<26}  {:<10}  {:>6}  {:<9}  {:<22}  input", "id", "state", "done", "stage", "error");
                    for j in &jobs {
                        println!(
                            "{:<26}  {:<10}  {:>5.1}%  {:<9}  {:<22}  {}",
                            j["Id"].as_str().unwrap_or(""),
                            j["State"].as_str().unwrap_or(""),
                            j["Progress"].as_f64().unwrap_or(0.0) * 100.0,
                            j["Stage"].as_str().unwrap_or(""),
                            j["ErrorCode"].as_str().unwrap_or(""),
                            j["Input"].as_str().unwrap_or("")
                        );
                    }
                }
                Ok(true)
            }
            Command::Submit { file, vertices, tolerance, wait, session } => {
                let conn = ops::connect(*session).await?;
                let path = ops::submit(&conn, file, *vertices, *tolerance).await?;
                if !*wait {
                    if json {
                        print_json(&serde_json::json!({ "job": path }));
                    } else {
                        println!("{path}");
                    }
                    return Ok(true);
                }
                let done = ops::watch(&conn, Some(&path), json).await?;
                if !json {
                    println!("{} {}", done["Result"], done["ErrorCode"]);
                }
                Ok(done["Result"] == "succeeded")
            }
            Command::Cancel { id, session } => {
                let conn = ops::connect(*session).await?;
                ops::cancel(&conn, id).await?;
                if json {
                    print_json(&serde_json::json!({ "cancelled": ops::job_path(id) }));
                }
                Ok(true)
            }
            Command::Watch { id, session } => {
                let conn = ops::connect(*session).await?;
                let done = ops::watch(&conn, id.as_deref(), json).await?;
                Ok(id.is_none() || done["Result"] == "succeeded")
            }
            _ => Ok(true),
        }
    });
    match r {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => ExitCode::from(1),
        Err(e) => report_error(&e, json),
    }
}

fn print_json<T: serde::Serialize>(v: &T) {
    let mut value = serde_json::to_value(v).expect("reports serialise");
    if let serde_json::Value::Object(m) = &mut value {
        m.insert("ok".into(), true.into());
    }
    println!("{}", serde_json::to_string_pretty(&value).expect("reports serialise"));
}

/// Exit codes: 2 bad input, 3 resource limit, 70 internal error (EX_SOFTWARE).
fn report_error(e: &Error, json: bool) -> ExitCode {
    if json {
        println!("{}", serde_json::json!({ "ok": false, "error": e, "error_code": e.code.as_str() }));
    }
    eprintln!("scanstation: error: {e}");
    ExitCode::from(match e.class() {
        ErrorClass::BadInput => 2,
        ErrorClass::Resource => 3,
        ErrorClass::Internal => 70,
    })
}

fn print_inspect(r: &InspectReport) {
    println!("file:                  {}", r.file.display());
    println!("kind:                  {}", r.kind);
    if let Some(c) = &r.cloud {
        println!("points:                {}", c.vertices);
        println!("normals / colors:      {} / {}", c.has_normals, c.has_colors);
        println!("bbox:                  {:?} .. {:?}", c.bbox.min, c.bbox.max);
        println!("bbox diagonal:         {:.6}", c.bbox_diagonal);
    }
    if let Some(m) = &r.mesh {
        let degrees: Vec<String> = m.faces_by_degree.iter().map(|(d, n)| format!("{n} × {d}-gon")).collect();
        println!(
            "vertices:              {} ({} referenced, {} unreferenced)",
            m.vertices, m.referenced_vertices, m.unreferenced_vertices
        );
        println!("faces:                 {} ({})", m.faces, degrees.join(", "));
        println!("edges:                 {}", m.edges);
        println!("bbox:                  {:?} .. {:?}", m.bbox.min, m.bbox.max);
        println!("bbox diagonal:         {:.6}", m.bbox_diagonal);
        println!("area:                  {:.6}", m.area);
        match m.volume {
            Some(v) => println!("volume:                {v:.6}"),
            None => println!("volume:                - (not closed)"),
        }
        println!("closed:                {}", m.closed);
        println!("boundary loops:        {} ({} boundary edges)", m.boundary_loops, m.boundary_edges);
        println!("non-manifold:          {} edges, {} vertices", m.nonmanifold_edges, m.nonmanifold_vertices);
        println!("components:            {}", m.components);
        println!("degenerate faces:      {}", m.degenerate_faces);
        println!("coincident vertices:   {}", m.coincident_vertices);
        println!(
            "orientation:           {} ({} conflicting directed edges)",
            if m.consistently_oriented { "consistent" } else { "inconsistent" },
            m.orientation_conflicts
        );
        println!("euler characteristic:  {}", m.euler_characteristic);
        match m.genus {
            Some(g) => println!("genus:                 {g}"),
            None => println!("genus:                 - (not an orientable manifold)"),
        }
    }
    println!("read / analyse:        {:.3} s / {:.3} s", r.read_seconds, r.analyse_seconds);
}

fn fmt_measure(m: &Measure) -> String {
    let part = m.one_part_in.map_or("-".to_string(), |n| format!("1:{n:.0}"));
    format!("{:>12.6e} {:>9.4}% {:>10}", m.value, m.pct_of_diagonal, part)
}

fn print_compare(r: &CompareReport) {
    println!(
        "test:      {} ({}, {} vertices, {} faces)",
        r.test.file.display(),
        r.test.kind,
        r.test.vertices,
        r.test.faces
    );
    println!(
        "reference: {} ({}, {} vertices, {} faces)",
        r.reference.file.display(),
        r.reference.kind,
        r.reference.vertices,
        r.reference.faces
    );
    let d = &r.distance;
    println!(
        "reference bbox diagonal {:.6}; {} samples per side, seed {}",
        d.reference_bbox_diagonal, d.samples_per_side, d.seed
    );
    println!("{:<18} {:<8} {:>12} {:>10} {:>10}", "direction", "figure", "value", "% diag", "1 part in");
    let rows: [(&str, &DistanceStats); 3] = [
        ("test→reference", &d.test_to_reference),
        ("reference→test", &d.reference_to_test),
        ("symmetric", &d.symmetric),
    ];
    for (name, s) in rows {
        for (fig, m) in [("rms", &s.rms), ("mean", &s.mean), ("median", &s.median), ("p95", &s.p95), ("max", &s.max)] {
            println!("{name:<18} {fig:<8} {}", fmt_measure(m));
        }
    }
    if let Some(p) = &r.error_map {
        println!("error map: {} (colour scale 0 .. {:.6e})", p.display(), r.error_map_scale.unwrap_or(0.0));
    }
    println!("read / compare: {:.3} s / {:.3} s", r.read_seconds, r.compare_seconds);
}

fn print_repair(r: &pipeline::RepairFileReport) {
    let rep = &r.repair;
    println!("input:   {} ({} vertices, {} faces)", r.input_file.display(), rep.input.vertices, rep.input.faces);
    let w = &rep.weld;
    println!(
        "weld:    {} vertices merged, {} collapsed and {} duplicate faces dropped, {} unreferenced vertices dropped",
        w.merged_vertices, w.collapsed_faces, w.duplicate_faces, w.unreferenced_vertices
    );
    let m = &rep.manifold;
    println!(
        "manifold: {} non-manifold edges ({} faces removed), {} faces flipped, {} removed for orientation, {} vertices split",
        m.nonmanifold_edges,
        m.faces_removed_at_nonmanifold_edges,
        m.faces_flipped,
        m.faces_removed_orientation,
        m.vertices_split
    );
    println!(
        "components: {} found, {} kept ({:.2} % of the area), {} debris faces removed",
        m.components_found,
        m.components_kept,
        100.0 * m.area_share_kept,
        m.faces_removed_debris
    );
    let h = &rep.holes;
    println!(
        "holes:   {} filled (largest {} edges), {} triangles and {} vertices added",
        h.holes_filled, h.largest_hole_edges, h.triangles_added, h.vertices_added
    );
    let hd = &rep.handles;
    if hd.max_loop > 0.0 {
        println!(
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
    println!(
        "output:  {} ({} vertices, {} faces, closed {}, genus {:?}, volume {:.6e})",
        r.output_file.display(),
        o.vertices,
        o.faces,
        o.closed,
        o.genus,
        o.volume.unwrap_or(f64::NAN)
    );
    let d = &rep.distance.symmetric;
    println!(
        "distance to input: rms {:.4e} ({:.4} %), max {:.4e} ({:.4} %); repair took {:.3} s",
        d.rms.value, d.rms.pct_of_diagonal, d.max.value, d.max.pct_of_diagonal, rep.seconds
    );
}

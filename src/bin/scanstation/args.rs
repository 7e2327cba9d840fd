//! One argument struct per command; each turns itself into the library's options.

use std::path::{Path, PathBuf};

use clap::Args;

use crate::ranges;
use scanstation::geometry::io::ReadOptions;
use scanstation::pipeline::pictures::Up;
use scanstation::pipeline::{self, ConvertOptions, ConvertReport, GateOptions, RemeshFileReport, Resolution};
use scanstation::stages::brep::step::LengthUnit;
use scanstation::stages::quality::CompareOptions;
use scanstation::stages::remesh::RemeshOptions;
use scanstation::stages::repair::RepairOptions;
use scanstation::{Error, ErrorCode};

/// Arguments of `scanstation inspect`.
#[derive(Args)]
pub struct InspectArgs {
    /// The file to inspect.
    pub file: PathBuf,
}

/// Arguments of `scanstation repair`.
#[derive(Args)]
pub struct RepairArgs {
    /// The mesh to repair.
    pub input: PathBuf,
    /// Where to write the result (.ply binary, or .obj).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Keep components other than the largest when they hold at least this share of the area (0 to 1).
    #[arg(long, default_value_t = 0.1, value_parser = ranges::share)]
    pub keep_share: f64,
    /// Do not move spike vertices (far off their neighbours' plane) to their ring centroid.
    #[arg(long)]
    pub keep_spikes: bool,
    /// Taubin (non-shrinking) smoothing iterations (0 to 1000).
    #[arg(long, default_value_t = 0, value_parser = ranges::rounds)]
    pub smooth: usize,
    /// Decimate the repaired mesh to this many vertices (quadric error metric; 16 to 10 million).
    #[arg(long, value_parser = ranges::vertices)]
    pub target_vertices: Option<usize>,
    /// Cut handles (tunnels, bridges) whose shortest loop around them is shorter than this percentage of
    /// the bounding-box diagonal and fill both sides: topological noise of fused range scans (0: keep all;
    /// 0 to 100).
    #[arg(long, default_value_t = 0.0, value_parser = ranges::pct)]
    pub max_handle_loop_pct: f64,
}

/// Arguments of `scanstation remesh`.
#[derive(Args)]
pub struct RemeshArgs {
    /// The closed triangle mesh to remesh.
    pub input: PathBuf,
    /// Where to write the quad mesh (.obj keeps quads; anything else is binary PLY).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Final vertex count wanted (16 to 10 million).
    #[arg(long, conflicts_with = "edge_length", required_unless_present = "edge_length", value_parser = ranges::vertices)]
    pub vertices: Option<usize>,
    /// Target edge length instead (in the input's units, 1e-12 to 1e12): vertices = area / length².
    #[arg(long, value_parser = ranges::length)]
    pub edge_length: Option<f64>,
    /// Seed of the random initial fields.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Gauss–Seidel sweeps per hierarchy level for each field (1 to 1000).
    #[arg(long, default_value_t = scanstation::stages::remesh::RemeshOptions::default().iterations, value_parser = ranges::sweeps)]
    pub iterations: usize,
    /// Only the split route (extraction at a quarter of the count, then a regular split): fewer irregular
    /// vertices and faster, but features thinner than twice the spacing can be lost.
    #[arg(long)]
    pub split_only: bool,
    /// Every route and finish, not only those `convert` uses: the adaptive split and refined direct routes,
    /// the least-squares fit of the net to the input and dipole transport (slower: minutes on a 50k scan).
    #[arg(long)]
    pub all_routes: bool,
    /// With `--all-routes`: one spacing everywhere (no adaptive split route).
    #[arg(long)]
    pub uniform_spacing: bool,
    /// Extract from the position field as it is, without cancelling its singularities in pairs.
    #[arg(long)]
    pub keep_singularities: bool,
    /// Working-mesh vertices per output vertex (1 to 64).
    #[arg(long, default_value_t = scanstation::stages::remesh::RemeshOptions::default().work_per_vertex, value_parser = ranges::per_vertex)]
    pub work_per_vertex: f64,
    /// Working-mesh vertices per output vertex for the direct routes (which extract at the full count; 1 to
    /// 64; default 6, or 10 with `--all-routes`).
    #[arg(long, value_parser = ranges::per_vertex)]
    pub work_per_vertex_direct: Option<f64>,
    /// With `--all-routes`: no refined direct route (a finer spacing where the direct result missed thin parts).
    #[arg(long)]
    pub no_refine: bool,
    /// Rounds of the least-squares fit of the quad mesh to the input (0 = vertices stay on the input; 0 to
    /// 1000; default 0, or 4 with `--all-routes`).
    #[arg(long, value_parser = ranges::rounds)]
    pub fit_rounds: Option<usize>,
    /// Longest chain of cost-neutral operations (edge rotations, vertex splits, diagonal collapses) that
    /// moves a dipole (valence 3–5 pair) until it cancels another (0 = no dipole transport; 0 to 16; default
    /// 0, or 5 with `--all-routes`).
    #[arg(long, value_parser = ranges::depth)]
    pub dipole_depth: Option<usize>,
    /// Weight of the pull toward principal curvature directions (0 = off; 0 to 100).
    #[arg(long, default_value_t = scanstation::stages::remesh::RemeshOptions::default().curvature_weight, value_parser = ranges::weight)]
    pub curvature_weight: f64,
    /// Extra pull, relative to the curvature weight, where the principal directions agree over the
    /// whole surface (tori, surfaces of revolution); 0 = off; 0 to 100.
    #[arg(long, default_value_t = scanstation::stages::remesh::RemeshOptions::default().coherent_pull, value_parser = ranges::weight)]
    pub coherent_pull: f64,
}

/// Arguments of `scanstation reconstruct`.
#[derive(Args)]
pub struct ReconstructArgs {
    /// The point cloud (a mesh's vertices are used as points).
    pub input: PathBuf,
    /// Where to write the closed mesh (.ply binary, or .obj).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Grid nodes along the longest side (default: 0.6·√points, 64 to 384; range 8 to 1024).
    #[arg(long, value_parser = ranges::grid_resolution)]
    pub resolution: Option<usize>,
    /// Screening weight: how strongly the surface is pulled through the points (0 = plain Poisson; 0 to 100).
    #[arg(long, default_value_t = scanstation::stages::reconstruct::ReconstructOptions::default().screening, value_parser = ranges::weight)]
    pub screening: f64,
    /// Ignore the cloud's normals and estimate them (PCA, oriented along a spanning tree).
    #[arg(long)]
    pub estimate_normals: bool,
    /// Keep the vertices where the grid put them (no projection onto the points' local planes).
    #[arg(long)]
    pub no_project: bool,
    /// Scan sets: place the views by their given poses only (no multi-view ICP refinement).
    #[arg(long)]
    pub no_refine: bool,
    /// Split every triangle in four this many times after the projection, the midpoints projected too
    /// (0 to 2; default: once where the points are denser than the grid and the budget allows).
    #[arg(long, value_parser = clap::value_parser!(u8).range(0..=2))]
    pub split: Option<u8>,
}

impl ReconstructArgs {
    /// Reconstruction's settings.
    pub fn options(&self, memory_budget: u64) -> scanstation::stages::reconstruct::ReconstructOptions {
        scanstation::stages::reconstruct::ReconstructOptions {
            resolution: self.resolution.unwrap_or(0),
            screening: self.screening,
            estimate_normals: self.estimate_normals,
            project: !self.no_project,
            memory_budget,
            fusion: scanstation::stages::reconstruct::fusion::FuseOptions { refine: !self.no_refine },
            split: self.split.map(usize::from),
            ..Default::default()
        }
    }
}

/// Arguments of `scanstation convert`.
#[derive(Args)]
pub struct ConvertArgs {
    /// The scan (a triangle or polygon mesh).
    pub input: PathBuf,
    /// The STEP file to write (written to a temporary name and renamed when complete).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Control vertices of the quad net, exactly (16 to 10 million). Without it (and without --tolerance)
    /// the quality gate's RMS bound (--max-rms) is the goal: the net starts at 10000 vertices and is made
    /// again finer, up to --max-vertices, while it is farther than twice the goal from the scan.
    #[arg(long, conflicts_with = "tolerance", value_parser = ranges::vertices)]
    pub vertices: Option<usize>,
    /// The deviation goal's cap on control vertices (16 to 10 million; ignored with --vertices or
    /// --tolerance).
    #[arg(long, default_value_t = pipeline::goal::GOAL_CAP, value_parser = ranges::vertices)]
    pub max_vertices: usize,
    /// Refine coarse to fine until the solid's RMS distance to the input is at most this: a length in
    /// the input's units, or a percentage of the bounding-box diagonal such as 0.05%.
    #[arg(long)]
    pub tolerance: Option<String>,
    /// Write the full report as JSON here.
    #[arg(long, value_name = "R.json")]
    pub report: Option<PathBuf>,
    /// Also write the quad control net (.obj or .ply).
    #[arg(long)]
    pub quads: Option<PathBuf>,
    /// Length unit of the input, written into the STEP file: mm, cm or m.
    #[arg(long, default_value = "mm")]
    pub unit: String,
    /// Seed of remeshing and sampling.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Remesh by the split route only (see `remesh --split-only`): fewer extraordinary vertices, so fewer
    /// and larger faces, but features thinner than twice the spacing can be lost.
    #[arg(long)]
    pub split_only: bool,
    /// Keep handles (tunnels, bridges) too narrow for the quad net; by default repair cuts those whose
    /// loop is shorter than two quad spacings (π × the tolerance with --tolerance) and fills both sides.
    #[arg(long)]
    pub keep_small_handles: bool,
    /// Quality gate: the most RMS distance of the solid to the scan, % of the diagonal, when no --tolerance
    /// is given (a tolerance is its own bound); 1e-6 to 100.
    #[arg(long, value_name = "PCT", default_value_t = pipeline::gates::DEFAULT_MAX_RMS_PCT, value_parser = ranges::gate_pct)]
    pub max_rms: f64,
    /// Quality gate: the most |volume error| of the solid against the input, % (1e-6 to 100).
    #[arg(long, value_name = "PCT", default_value_t = pipeline::gates::DEFAULT_MAX_VOLUME_ERROR_PCT, value_parser = ranges::gate_pct)]
    pub max_volume_error: f64,
    /// Quality gate: the most distance from any part of the scan to the solid, % of the diagonal (the far
    /// tail: a tip cut short, a crease rounded off; 1e-6 to 100). Under the default deviation goal the net
    /// is refined locally where the scan passes farther than this.
    #[arg(long, value_name = "PCT", default_value_t = pipeline::gates::DEFAULT_MAX_DISTANCE_PCT, value_parser = ranges::gate_pct)]
    pub max_distance: f64,
    /// Publish a solid that misses a quality gate anyway (exit 0, `"status": "degraded"` in the report);
    /// without it such a solid exits 4 with the gate's `quality.*` code.
    #[arg(long)]
    pub accept_degraded: bool,
    /// Also draw the job's pictures beside the STEP file (NAME.deviation.png, .net, .faces, .histogram,
    /// .convergence, .thumbnail) and the self-contained page NAME.report.html.
    #[arg(long)]
    pub pictures: bool,
    /// The object's up axis in the pictures: x, y or z.
    #[arg(long, default_value = "y", value_parser = ranges::up_axis)]
    pub up: Up,
}

/// Arguments of `scanstation fea`.
#[derive(Args)]
pub struct FeaArgs {
    /// The solid: a closed tri-mesh (PLY, OBJ, STL, OFF) or a STEP file from `convert`.
    pub input: PathBuf,
    /// The spec (TOML): material, loads, supports, resolution, probes.
    #[arg(long)]
    pub spec: PathBuf,
    /// The result directory.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Also draw the von Mises stress on the solid (stress.png in the result directory).
    #[arg(long)]
    pub pictures: bool,
    /// The object's up axis in the picture: x, y or z.
    #[arg(long, default_value = "y", value_parser = ranges::up_axis)]
    pub up: Up,
}

/// Arguments of `scanstation render`.
#[derive(Args)]
pub struct RenderArgs {
    /// The mesh to draw (PLY, OBJ, STL, OFF; a quad net for `net`).
    pub mesh: PathBuf,
    /// What the colours show: deviation (from --ref), net (the mesh's polygons), faces (each polygon its
    /// own colour), stress (the FEA under --spec) or coverage (by the views of the scan set --ref).
    #[arg(long, value_parser = ["deviation", "net", "faces", "stress", "coverage"])]
    pub color_by: String,
    /// The scan (deviation) or scan set (coverage).
    #[arg(long = "ref", value_name = "SCAN")]
    pub reference: Option<PathBuf>,
    /// The FEA spec (stress).
    #[arg(long)]
    pub spec: Option<PathBuf>,
    /// The PNG to write (1024 x 768: front, side, top and isometric views and a legend).
    #[arg(short, long)]
    pub output: PathBuf,
    /// The object's up axis: x, y or z.
    #[arg(long, default_value = "y", value_parser = ranges::up_axis)]
    pub up: Up,
    /// Deviation: half width of the neutral grey band, % of the scan's diagonal (1e-6 to 100).
    #[arg(long, value_name = "PCT", default_value_t = pipeline::gates::DEFAULT_MAX_RMS_PCT, value_parser = ranges::gate_pct)]
    pub band: f64,
    /// Deviation: the unit of the coordinates, for the legend: mm, cm or m.
    #[arg(long, default_value = "mm")]
    pub unit: String,
}

impl RenderArgs {
    /// The render's settings.
    ///
    /// # Errors
    /// `input.bad-argument` for an unknown unit.
    pub fn options(&self, memory_budget: u64) -> Result<pipeline::render::RenderOptions, Error> {
        let unit = LengthUnit::parse(&self.unit).ok_or_else(|| {
            Error::new(ErrorCode::InputBadArgument, format!("unknown unit {:?}: use mm, cm or m", self.unit))
        })?;
        let color_by = pipeline::render::ColorBy::parse(&self.color_by)
            .ok_or_else(|| Error::new(ErrorCode::InputBadArgument, format!("unknown colouring {:?}", self.color_by)))?;
        Ok(pipeline::render::RenderOptions {
            color_by,
            reference: self.reference.clone(),
            spec: self.spec.clone(),
            up: self.up,
            band_pct: self.band,
            unit: unit.symbol(),
            memory_budget,
        })
    }
}

/// Arguments of `scanstation report`.
#[derive(Args)]
pub struct ReportArgs {
    /// A job's bundle: its outbox or quarantine directory (or a `convert --pictures` output directory
    /// holding NAME.report.json).
    pub bundle: PathBuf,
}

#[cfg(feature = "daemon")]
/// Arguments of `scanstation status`.
#[derive(Args)]
pub struct StatusArgs {
    /// Use the session bus instead of the system bus.
    #[arg(long)]
    pub session: bool,
}

#[cfg(feature = "daemon")]
/// Arguments of `scanstation jobs`.
#[derive(Args)]
pub struct JobsArgs {
    #[arg(long)]
    pub session: bool,
}

#[cfg(feature = "daemon")]
/// Arguments of `scanstation submit`.
#[derive(Args)]
pub struct SubmitArgs {
    pub file: PathBuf,
    /// Control vertices of the quad net for this job (16 to 10 million).
    #[arg(long, value_parser = ranges::vertices_u32)]
    pub vertices: Option<u32>,
    /// RMS tolerance (length) for this job instead of a vertex count (1e-12 to 1e12).
    #[arg(long, value_parser = ranges::length)]
    pub tolerance: Option<f64>,
    /// Seed of the conversion's randomised steps.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Publish a solid that misses a quality gate anyway, as `degraded` (otherwise the job is quarantined).
    #[arg(long)]
    pub accept_degraded: bool,
    /// Follow the job until it finishes (exit status 1 when it fails).
    #[arg(long)]
    pub wait: bool,
    #[arg(long)]
    pub session: bool,
}

#[cfg(feature = "daemon")]
/// Arguments of `scanstation scan`.
#[derive(Args)]
pub struct ScanArgs {
    /// Views (stops of the turntable, evenly around unless --step-deg is given; 1 to 360). Default: the
    /// station's `[scan] views`.
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=360))]
    pub views: Option<u32>,
    /// Degrees between views.
    #[arg(long, value_parser = ranges::length)]
    pub step_deg: Option<f64>,
    /// A tilting table's rings after the level one, `TILT:VIEWS,…` (e.g. `-25:8,-45:8,50:6`; "" for none).
    /// Default: the station's `[scan] tilts`.
    #[arg(long, allow_hyphen_values = true)]
    pub tilts: Option<String>,
    /// After the plan, choose views where the surface is unseen until this share is seen (0 to 1, e.g.
    /// 0.99). Default: the station's `[scan] coverage`.
    #[arg(long)]
    pub coverage: Option<f64>,
    /// The most views in all, chosen ones included (2 to 720). Default: the station's `[scan] max_views`.
    #[arg(long, value_parser = clap::value_parser!(u32).range(2..=720))]
    pub max_views: Option<u32>,
    /// Passes (1 to 4): the plan taken once per pass; before each pass after the first the scan waits for
    /// the object to be turned over and `scanstation continue JOB`.
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=4))]
    pub passes: Option<u32>,
    /// The scan's name (its outbox directory's stem): letters, digits, '_', '-', '.'.
    #[arg(long)]
    pub name: Option<String>,
    /// An FEA spec to solve on the solid (coordinates in the table frame: z up the axis, 0 on the table top).
    #[arg(long)]
    pub fea: Option<PathBuf>,
    /// Control vertices of the quad net (16 to 10 million).
    #[arg(long, value_parser = ranges::vertices_u32)]
    pub vertices: Option<u32>,
    /// RMS tolerance (length) instead of a vertex count (1e-12 to 1e12).
    #[arg(long, value_parser = ranges::length)]
    pub tolerance: Option<f64>,
    /// Seed of the conversion's randomised steps.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Publish a solid that misses a quality gate anyway, as `degraded` (otherwise the scan is quarantined).
    #[arg(long)]
    pub accept_degraded: bool,
    /// Follow the scan until it finishes (exit status 1 when it fails).
    #[arg(long)]
    pub wait: bool,
    /// Use the session bus instead of the system bus.
    #[arg(long)]
    pub session: bool,
}

#[cfg(feature = "daemon")]
/// Arguments of `scanstation rig`.
#[derive(Args)]
pub struct RigArgs {
    #[command(subcommand)]
    pub action: RigAction,
    /// Use the session bus instead of the system bus.
    #[arg(long, global = true)]
    pub session: bool,
}

#[cfg(feature = "daemon")]
/// What `scanstation rig` does.
#[derive(clap::Subcommand)]
pub enum RigAction {
    /// The configured devices' properties (turntable, trigger; null when not configured).
    Status,
    /// Home the turntable (or unlock it, as configured).
    Home,
    /// Turn the table to an absolute angle, degrees.
    Move {
        /// Degrees (absolute, −1e6 to 1e6).
        #[arg(allow_negative_numbers = true)]
        degrees: f64,
        /// Tilt a tilting table's cradle to this too, degrees (within its `TiltRange`).
        #[arg(long, allow_negative_numbers = true)]
        tilt: Option<f64>,
    },
    /// Fire the scanner and wait for its view.
    Fire {
        /// The channel (pattern set, camera), 0 to 255.
        #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u32).range(0..=255))]
        channel: u32,
    },
}

#[cfg(feature = "daemon")]
/// Arguments of `scanstation cancel`.
#[derive(Args)]
pub struct CancelArgs {
    pub id: String,
    #[arg(long)]
    pub session: bool,
}

#[cfg(feature = "daemon")]
/// Arguments of `scanstation continue`.
#[derive(Args)]
pub struct ContinueArgs {
    /// The job (id or object path).
    pub id: String,
    /// Use the session bus.
    #[arg(long)]
    pub session: bool,
}

#[cfg(feature = "daemon")]
/// Arguments of `scanstation cluster-run`.
#[derive(Args)]
pub struct ClusterRunArgs {
    /// The job's cluster directory on the shared spool (`work/<id>/.slurm`, holding `job.json`).
    pub dir: PathBuf,
}

#[cfg(feature = "daemon")]
/// Arguments of `scanstation watch`.
#[derive(Args)]
pub struct WatchArgs {
    pub id: Option<String>,
    #[arg(long)]
    pub session: bool,
}

/// Arguments of `scanstation compare`.
#[derive(Args)]
pub struct CompareArgs {
    /// The surface to measure.
    pub test: PathBuf,
    /// The surface it is measured against (percentages use its bounding-box diagonal).
    pub reference: PathBuf,
    /// Area samples per side (100 to 100 million).
    #[arg(long, default_value_t = 200_000, value_parser = ranges::samples)]
    pub samples: usize,
    /// Sampling seed.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Write TEST with per-vertex distance and a colour ramp as binary PLY.
    #[arg(long, value_name = "OUT.ply")]
    pub error_map: Option<PathBuf>,
}

impl RepairArgs {
    /// Repair's settings.
    pub fn options(&self, memory_budget: u64) -> RepairOptions {
        RepairOptions {
            keep_share: self.keep_share,
            remove_spikes: !self.keep_spikes,
            smooth_iterations: self.smooth,
            target_vertices: self.target_vertices,
            max_handle_loop_rel: self.max_handle_loop_pct / 100.0,
            memory_budget,
            ..Default::default()
        }
    }
}

impl RemeshArgs {
    /// Remesh's settings, the target count aside (see [`Self::run`]): the routes `convert` uses
    /// ([`RemeshOptions::convert_default`]), or every one with `--all-routes` ([`RemeshOptions::default`]).
    pub fn options(&self, memory_budget: u64) -> RemeshOptions {
        let base = if self.all_routes { RemeshOptions::default() } else { RemeshOptions::convert_default() };
        RemeshOptions {
            seed: self.seed,
            iterations: self.iterations,
            curvature_weight: self.curvature_weight,
            coherent_pull: self.coherent_pull,
            work_per_vertex: self.work_per_vertex,
            work_per_vertex_direct: self.work_per_vertex_direct.unwrap_or(base.work_per_vertex_direct),
            refine_missed: base.refine_missed && !self.no_refine,
            fit_rounds: self.fit_rounds.unwrap_or(base.fit_rounds),
            dipole_depth: self.dipole_depth.unwrap_or(base.dipole_depth),
            try_direct: !self.split_only,
            adaptive_spacing: base.adaptive_spacing && !self.uniform_spacing,
            cancel_singularities: !self.keep_singularities,
            memory_budget,
            ..base
        }
    }

    /// Remeshes the input: `--vertices`, or `--edge-length` L as area / L² vertices.
    pub fn run(&self, read: &ReadOptions, memory_budget: u64) -> Result<RemeshFileReport, Error> {
        let target = match (self.vertices, self.edge_length) {
            (Some(v), _) => v,
            (None, Some(l)) => {
                if !(l.is_finite() && l > 0.0) {
                    return Err(Error::new(ErrorCode::InputBadArgument, "--edge-length must be > 0"));
                }
                let mesh = scanstation::geometry::io::read_mesh(&self.input, read)?;
                let area = scanstation::geometry::topology::TopologyReport::compute(&mesh).area;
                (area / (l * l)).round().min(1e9) as usize
            }
            (None, None) => return Err(Error::new(ErrorCode::InputBadArgument, "give --vertices or --edge-length")),
        };
        let opts = RemeshOptions { target_vertices: target, ..self.options(memory_budget) };
        pipeline::remesh_file(&self.input, &self.output, read, &opts, &crate::progress::LogProgress::new("remesh"))
    }
}

impl ConvertArgs {
    /// The conversion's settings.
    ///
    /// # Errors
    /// `input.bad-argument` for an unknown unit or a tolerance that is neither a length nor a percentage.
    pub fn options(&self, memory_budget: u64) -> Result<ConvertOptions, Error> {
        let unit = LengthUnit::parse(&self.unit).ok_or_else(|| {
            Error::new(ErrorCode::InputBadArgument, format!("unknown unit {:?}: use mm, cm or m", self.unit))
        })?;
        let tolerance = self.tolerance.as_deref().map(Resolution::parse_tolerance).transpose()?;
        Ok(ConvertOptions {
            resolution: Resolution::choose(self.vertices, tolerance, Resolution::goal(self.max_vertices)),
            seed: self.seed,
            unit,
            quads_output: self.quads.clone(),
            remove_small_handles: !self.keep_small_handles,
            memory_budget,
            pictures: self.pictures.then_some(self.up),
            remesh: RemeshOptions { try_direct: !self.split_only, ..RemeshOptions::convert_default() },
            gates: GateOptions {
                max_rms_pct: self.max_rms,
                max_volume_error_pct: self.max_volume_error,
                max_distance_pct: self.max_distance,
                accept_degraded: self.accept_degraded,
            }
            .validated()?,
            ..Default::default()
        })
    }

    /// Converts the input and writes the report where `--report` asks.
    pub fn run(&self, read: &ReadOptions, memory_budget: u64) -> Result<ConvertReport, Error> {
        let opts = self.options(memory_budget)?;
        if let Some(r) = &self.report {
            use scanstation::pipeline::provenance::{error_map_path, solid_artifact_path};
            let (solid, map) = (solid_artifact_path(&self.output), error_map_path(&self.output));
            let page = pipeline::report_html::convert_page_path(&self.output);
            let mut others = vec![self.input.as_path(), &self.output, &solid, &map];
            others.extend(self.quads.as_deref());
            if self.pictures {
                others.push(&page);
            }
            scanstation::geometry::io::ensure_not_input(r, &others)?;
            scanstation::geometry::io::ensure_replaceable(r)?;
        }
        let r = pipeline::convert_file(
            &self.input,
            &self.output,
            read,
            &opts,
            &crate::progress::LogProgress::new("convert"),
        )?;
        if let Some(path) = &self.report {
            write_report(path, &r)?;
        }
        if self.pictures {
            pipeline::report_html::write_convert_page(&r)?;
        }
        Ok(r)
    }
}

/// Writes `report` as pretty JSON to `path`, atomically.
fn write_report(path: &Path, report: &ConvertReport) -> Result<(), Error> {
    let text = serde_json::to_string_pretty(report).map_err(|e| Error::internal(e.to_string()))?;
    scanstation::geometry::io::write_atomic(path, |w| std::io::Write::write_all(w, text.as_bytes())).map(|_| ())
}

impl CompareArgs {
    /// The measurement's settings.
    pub fn options(&self, memory_budget: u64) -> CompareOptions {
        CompareOptions { samples: self.samples, seed: self.seed, memory_budget, ..Default::default() }
    }
}

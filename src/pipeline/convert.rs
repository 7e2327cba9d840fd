//! The whole chain for one file: read (a mesh, a cloud, or a scan set fused) → reconstruct (clouds) → repair
//! → remesh → surface fit → B-rep → STEP, then the solid mesh, the error map and the quality gates, with a
//! quality check and time and peak memory after every stage. [`convert_file`] returns the report;
//! [`convert_held`] also hands back what the chain held (the solid mesh, the fused views, the files' digests)
//! so that a caller reads nothing back.

use std::path::{Path, PathBuf};
use std::time::Instant;

use super::gates::{Gate, GateOptions, Measured, Status, judge};
pub use super::goal::NetRaise;
use super::memory::StageMeter;
pub use super::open_input::OpenInputMeasure;
use super::open_input::open_input_measure;
use super::refine::LocalRefinement;
use super::resolution::resolutions;
pub use super::resolution::{
    DEFAULT_VERTICES, HANDLE_LOOP_SPACINGS, Resolution, TOLERANCE_MAX, TOLERANCE_START, small_handle_loop,
};
use super::solid_mesh::{mesh_self_intersections, solid_self_intersections, tessellate_for_check, write_solid_mesh};
use crate::error::{Error, ErrorCode, Result};
use crate::geometry::io::{FileDigest, ReadOptions};
use crate::geometry::mesh::{Geometry, PolyMesh, TriMesh};
use crate::stages::brep::step::{LengthUnit, StepOptions, write_step};
use crate::stages::brep::{BrepReport, Solid, build_solid};
use crate::stages::quality::{CompareOptions, DistanceReport, ErrorMapFile, compare, write_error_map};
use crate::stages::reconstruct::{ReconstructOptions, ReconstructReport};
use crate::stages::remesh::{RemeshOptions, RemeshReport, remesh};
use crate::stages::repair::{RepairOptions, RepairReport, repair};
use crate::stages::surface::{FitOptions, FitReport, MeshTarget, control_net, fit_control_points};
use crate::stages::{Progress, ProgressSpan, check_cancelled};

/// Settings of a conversion.
#[derive(Clone, Debug)]
pub struct ConvertOptions {
    /// How fine the quad control net is.
    pub resolution: Resolution,
    /// Repair's settings (the chain sets the budget, the distance measure and the handle cut).
    pub repair: RepairOptions,
    /// Remesh's settings (the chain sets the target, the seed and the budget).
    pub remesh: RemeshOptions,
    /// The surface fit's settings.
    pub fit: FitOptions,
    /// Samples per side for every quality check.
    pub compare_samples: usize,
    /// Seed of remeshing and sampling; other seeds follow it when a chain is built again.
    pub seed: u64,
    /// Length unit written into the STEP file.
    pub unit: LengthUnit,
    /// Also write the quad control net here (OBJ or PLY).
    pub quads_output: Option<PathBuf>,
    /// Let repair cut handles too narrow for the quad net ([`small_handle_loop`]) unless
    /// `repair.max_handle_loop_rel` is set already.
    pub remove_small_handles: bool,
    /// Most bytes any stage may allocate (each checks its estimate first).
    pub memory_budget: u64,
    /// The quality gates' bounds, and whether a solid that misses one is still published ([`super::gates`]).
    pub gates: GateOptions,
    /// How a point-cloud input becomes a mesh first ([`crate::stages::reconstruct`]).
    pub reconstruct: ReconstructOptions,
    /// Hand a scan set's views back with the solid ([`Converted::fused`]) instead of dropping them once
    /// fused, for what the caller measures on them (their coverage of the solid) without reading them again.
    pub keep_views: bool,
    /// Also draw the job's pictures beside the STEP file, the object's up axis as given
    /// ([`super::pictures`]); listed in [`ConvertReport::pictures`].
    pub pictures: Option<super::pictures::Up>,
}

impl Default for ConvertOptions {
    fn default() -> Self {
        ConvertOptions {
            resolution: Resolution::goal(super::goal::GOAL_CAP),
            repair: RepairOptions::default(),
            remesh: RemeshOptions::convert_default(),
            fit: FitOptions::default(),
            compare_samples: 200_000,
            seed: 0,
            unit: LengthUnit::Millimetre,
            quads_output: None,
            pictures: None,
            remove_small_handles: true,
            memory_budget: 8 << 30,
            gates: GateOptions::default(),
            // No split: the remesh resamples the surface at its own density, so a finer reconstruction
            // would only make repair and remesh slower.
            reconstruct: ReconstructOptions { split: Some(0), ..ReconstructOptions::default() },
            keep_views: false,
        }
    }
}

/// Time, memory and (where it applies) distance to the input after one stage.
#[derive(Clone, Debug, serde::Serialize)]
pub struct StageReport {
    /// `read`, `repair`, `remesh`, `surface`, `brep`, `step` or `quality`.
    pub stage: &'static str,
    /// Wall seconds of the stage.
    pub seconds: f64,
    /// Peak resident memory of the process during the stage (Linux: the reset high-water mark where
    /// allowed, and a 5 ms `VmRSS` sampler; `null` elsewhere), MiB.
    pub peak_rss_mib: Option<f64>,
    /// Two-sided distance of the stage's result to the input.
    pub distance: Option<DistanceReport>,
}

/// One resolution tried.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Attempt {
    /// Control vertices asked for.
    pub target_vertices: usize,
    /// Control vertices of the net made.
    pub control_vertices: usize,
    /// The remesh seed of this try.
    pub seed: u64,
    /// Crossing triangle pairs of the solid's tessellation (a try with any, or with a folded face, is built
    /// again from another seed, up to [`SOLID_RETRIES`] times).
    pub solid_self_intersections: usize,
    /// Faces of the solid that fold over.
    pub solid_folded_faces: usize,
    /// Two-sided RMS distance of the solid to the input, model units.
    pub solid_rms: f64,
    /// The same in percent of the input's bounding-box diagonal.
    pub solid_rms_pct: f64,
    /// Under the default deviation goal: the nets made again finer before the surface was fitted
    /// ([`super::goal`]); the solid is built on the last one kept.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub raises: Vec<NetRaise>,
    /// Under the default deviation goal: the net refined locally where the scan passed far from it
    /// ([`super::refine`]).
    pub local: LocalRefinement,
}

/// What `scanstation convert` reports.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ConvertReport {
    /// The scan converted.
    pub input_file: PathBuf,
    /// The STEP file written.
    pub output_file: PathBuf,
    /// The solid's watertight tessellation written beside the STEP file for `fea` (NAME.solid.ply).
    pub solid_mesh_file: PathBuf,
    /// That tessellation coloured by its distance to the input (NAME.error-map.ply; see
    /// [`write_error_map`]).
    pub error_map_file: PathBuf,
    /// The error map's colour-scale top (red): the 99th percentile of its vertices' distances.
    pub error_map_scale: f64,
    /// Length unit of the STEP file.
    pub unit: LengthUnit,
    /// Vertices of the input mesh.
    pub input_vertices: usize,
    /// Faces of the input mesh.
    pub input_faces: usize,
    /// Bounding-box diagonal of the input, model units.
    pub bbox_diagonal: f64,
    /// Time, memory and distance after every stage.
    pub stages: Vec<StageReport>,
    /// What repair did.
    pub repair: RepairReport,
    /// What remesh did on the kept chain.
    pub remesh: RemeshReport,
    /// What the surface fit did on the kept chain.
    pub fit: FitReport,
    /// The solid's figures.
    pub brep: BrepReport,
    /// Volume of the repaired input mesh (closed).
    pub input_volume: f64,
    /// (solid − input) / input, percent.
    pub volume_error_pct: f64,
    /// Resolutions tried (one without a tolerance).
    pub attempts: Vec<Attempt>,
    /// For an open input (holes that repair filled): the distances the RMS gate judges it by.
    pub open_input: Option<OpenInputMeasure>,
    /// For a point-cloud input: how it became a closed mesh, and that mesh's distance to the points
    /// (`reference_to_test`: points to surface; `test_to_reference`: invented surface). Every later stage is
    /// measured against the points.
    pub reconstruct: Option<ReconstructStep>,
    /// The far tail of the scan → solid distance, which the `max-distance` gate judges: its largest value,
    /// where it is, how much of the scan lies beyond the far-tail goal and where, and what repair left
    /// ([`super::far_tail`]).
    pub far_tail: super::far_tail::FarTail,
    /// `ok` when the solid meets every gate; `failed` when it misses one (see [`ConvertReport::verdict`]);
    /// `degraded` when it misses one and was published anyway ([`GateOptions::accept_degraded`]).
    pub status: Status,
    /// Every quality gate with its measured value and bound ([`super::gates`]).
    pub gates: Vec<Gate>,
    /// Wall seconds of the whole conversion.
    pub total_seconds: f64,
    /// The pictures drawn, when [`ConvertOptions::pictures`] asked for them.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub pictures: Vec<super::pictures::Picture>,
    /// For a scan set whose views were kept ([`ConvertOptions::keep_views`]): the solid's surface no view
    /// saw (invented by the reconstruction), and its largest patch. The error map and the deviation picture
    /// mark it as invented.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub unseen: Option<super::reconstruct::UnseenSurface>,
}

impl ConvertReport {
    /// `Ok` unless the solid failed a quality gate: then the `quality.*` error of the first gate missed, with
    /// its measured value. A caller that publishes the files `convert_file` wrote must check this first.
    ///
    /// # Errors
    /// `quality.self-intersecting`, `quality.folded`, `quality.volume`, `quality.rms`, `quality.cap-bulge` or
    /// `quality.max-distance`.
    pub fn verdict(&self) -> Result<()> {
        super::gates::verdict(self.status, &self.gates)
    }
}

/// Time and memory of a stage, turned into its report.
struct Clock(StageMeter);

impl Clock {
    fn start() -> Self {
        Clock(StageMeter::start())
    }

    fn stop(self, stage: &'static str, distance: Option<DistanceReport>) -> StageReport {
        let (seconds, peak_rss_mib) = self.0.finish();
        StageReport { stage, seconds, peak_rss_mib, distance }
    }
}

/// The whole chain's memory need as a multiple of the input mesh's (see `convert_file`).
pub const CHAIN_MEMORY_FACTOR: u64 = 8;

/// Remesh attempts with other seeds when the quad mesh intersects itself.
pub const REMESH_RETRIES: usize = 3;

/// Whole remesh → surface → brep chains built again from other seeds when the solid's surface crosses
/// itself or a face folds over.
pub const SOLID_RETRIES: usize = 2;

/// A progress sink that passes on the largest fraction reported so far (with each new phase).
struct Monotonic<'a> {
    parent: &'a dyn Progress,
    last: std::sync::Mutex<f64>,
}

impl Progress for Monotonic<'_> {
    fn report(&self, fraction: f64, phase: &str) {
        let v = {
            let mut last = self.last.lock().unwrap_or_else(|p| p.into_inner());
            if fraction.is_finite() {
                *last = last.max(fraction);
            }
            *last
        };
        self.parent.report(v, phase);
    }

    fn cancelled(&self) -> bool {
        self.parent.cancelled()
    }
}

/// One remesh → surface → B-rep chain at one resolution and seed, measured.
struct SolidTry {
    quads: PolyMesh,
    /// Nets made again finer under the deviation goal.
    raises: Vec<NetRaise>,
    /// The net's local refinement under the deviation goal.
    local: LocalRefinement,
    /// A point of each crossing pair and each folded face of the solid.
    flaws: Vec<[f64; 3]>,
    /// Vertices of the control net.
    control_vertices: usize,
    remesh: RemeshReport,
    fit: FitReport,
    solid: Solid,
    brep: BrepReport,
    /// The remesh, surface and brep stages' reports.
    stages: Vec<StageReport>,
    /// The solid's two-sided RMS distance to the input.
    rms: f64,
    /// The one-sided RMS distance input → solid (the measure for an open input).
    input_to_solid_rms: f64,
    /// The largest distance input → solid (samples, vertices, inside the farthest samples' triangles).
    input_to_solid_max: f64,
    /// The solid's tessellation for the quality check (about 1.5M triangles), also the solid mesh written
    /// beside the STEP file.
    tessellation: TriMesh,
    /// The B-rep face of each of its triangles.
    tessellation_faces: Vec<u32>,
}

/// What every chain of a conversion works from: the input as read, its repaired form, and the settings.
struct Chain<'a> {
    input: &'a Path,
    input_geom: Geometry,
    repaired: TriMesh,
    /// The repaired mesh as the surface fit's target.
    target: MeshTarget,
    /// Points of the scan the local refinement measures against (made when first needed).
    samples: std::sync::OnceLock<Vec<[f64; 3]>>,
    /// Vertices of the surface repair invented (caps, fills): the local refinement keeps away from them.
    invented: Vec<[f64; 3]>,
    cmp_opts: CompareOptions,
    opts: &'a ConvertOptions,
    progress: &'a dyn Progress,
}

/// Read `input`, convert it to a solid and write it as STEP to `output` (atomically; nothing is left
/// behind on failure), with the solid's tessellation beside it as NAME.solid.ply (for `fea`), the error map
/// NAME.error-map.ply (that tessellation coloured by distance to the input) and, when asked, the quad
/// control net. The CLI and the daemon write this same bundle.
///
/// The solid is then judged by the quality gates ([`super::gates`]): crossings, folds, volume and RMS. A solid
/// that misses one is still written (for inspection or quarantine), but its report's `status` is `failed`
/// and [`ConvertReport::verdict`] gives the `quality.*` error: check it before publishing the files.
///
/// # Errors
/// Reader errors; `reconstruct.*` for a cloud or a scan set; `repair.failed`; `input.several-parts` for a scan
/// that repair leaves in several separate closed parts; `remesh.*`; `surface.*`; `brep.invalid`; `resource.output` when the output cannot be
/// written or would overwrite the input; `input.bad-argument` for a bad resolution; `cancelled` when
/// `progress` asks to stop (checked between stages, so nothing is written).
///
/// Progress: one monotonic overall fraction with phases `STAGE/phase`, STAGE one of `read`, `repair`,
/// `remesh`, `surface`, `brep`, `step`, `quality` (see [`ProgressSpan`]): read 0–0.02, repair –0.1, then per
/// resolution attempt remesh –0.5, surface –0.8, brep –0.95 (a tolerance's later attempts do not move it
/// back), step –0.98, quality (the error map) –1.
///
/// Cost: the stages' (a tolerance runs the chain at up to 6 resolutions; a self-crossing solid is built
/// again up to [`SOLID_RETRIES`] times, a folded one too); memory about [`CHAIN_MEMORY_FACTOR`] times the input mesh's.
///
/// # Example
/// ```no_run
/// use scanstation::geometry::io::ReadOptions;
/// use scanstation::pipeline::{ConvertOptions, Resolution, convert_file};
/// use scanstation::stages::NoProgress;
/// use std::path::Path;
///
/// let opts = ConvertOptions { resolution: Resolution::Vertices(5_000), ..Default::default() };
/// let report = convert_file(Path::new("examples/spot.ply"), Path::new("out/spot.step"),
///                           &ReadOptions::default(), &opts, &NoProgress)?;
/// report.verdict()?; // a solid that crosses itself, folds, or misses its accuracy is not a success
/// println!("solid within {:.4} % of the scan", report.attempts[0].solid_rms_pct);
/// # Ok::<(), scanstation::Error>(())
/// ```
pub fn convert_file(
    input: &Path,
    output: &Path,
    read: &ReadOptions,
    opts: &ConvertOptions,
    progress: &dyn Progress,
) -> Result<ConvertReport> {
    Ok(convert_held(input, output, read, opts, progress)?.report)
}

/// What [`convert_held`] hands back besides its files: the report, and what it held in memory so that the
/// caller reads none of it back (a scan's bundle measures coverage on the solid and the views, and solves
/// the FEA on the solid).
pub struct Converted {
    /// The report, as [`convert_file`] returns it.
    pub report: ConvertReport,
    /// The solid's watertight tessellation, as written beside the STEP file (`report.solid_mesh_file`).
    pub solid_mesh: PolyMesh,
    /// A scan set's fusion with its views, when [`ConvertOptions::keep_views`] asked for them.
    pub fused: Option<super::reconstruct::Fused>,
    /// The written files' sizes and SHA-256, taken while writing them.
    pub digests: Digests,
    /// For a scan set whose views were kept: which surface of the solid each view saw.
    pub seen_by: Option<super::reconstruct::SeenBy>,
}

/// The sizes and SHA-256 of the files [`convert_held`] wrote, taken while writing them.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Digests {
    /// The STEP file.
    pub step: FileDigest,
    /// The solid mesh beside it.
    pub solid_mesh: FileDigest,
    /// The error map.
    pub error_map: FileDigest,
}

/// [`convert_file`], handing back what the chain held ([`Converted`]).
///
/// # Errors
/// As [`convert_file`].
pub fn convert_held(
    input: &Path,
    output: &Path,
    read: &ReadOptions,
    opts: &ConvertOptions,
    progress: &dyn Progress,
) -> Result<Converted> {
    // Stages run again for another resolution (`--tolerance`) or another seed (a self-crossing solid);
    // the overall fraction must not go back when they do.
    let monotonic = Monotonic { parent: progress, last: std::sync::Mutex::new(0.0) };
    let progress: &dyn Progress = &monotonic;
    // 1. No output may overwrite the input or another output; the gates' bounds make sense.
    super::checks::check_outputs(input, output, &opts.gates, opts.quads_output.as_deref())?;
    let t_total = Instant::now();
    let mut stages = Vec::new();
    let cmp_opts = compare_options(opts);

    // 2. Read.
    let clock = Clock::start();
    ProgressSpan::new(progress, 0.0, 0.02, "read");
    let (input_geom, fused) = read_input(input, read, opts)?;
    let (fusion, fused) = (fused.as_ref().map(|f| f.report.clone()), fused.filter(|_| opts.keep_views));
    stages.push(clock.stop("read", None));
    // 2b. A cloud is reconstructed into a closed mesh first; the points stay the reference.
    let (reconstructed, reconstruct_step) =
        reconstruct_stage(input, &input_geom, fusion, opts, &cmp_opts, progress, &mut stages)?;
    let mesh = match (&reconstructed, &input_geom) {
        (Some(m), _) | (None, Geometry::Mesh(m)) => m,
        (None, Geometry::Cloud(_)) => return Err(Error::internal("a cloud was not reconstructed")),
    };
    let diag = input_geom.bbox().diagonal();
    let (input_vertices, input_faces) = (input_geom.positions().len(), mesh.face_count());
    let resolution = opts.resolution.resolved(diag);

    // 3. Repair (its distance to the input is the stage's).
    check_cancelled(progress)?;
    let clock = Clock::start();
    let span = ProgressSpan::new(progress, 0.02, 0.1, "repair");
    let repair_opts = repair_options(opts, resolution, mesh, diag, &cmp_opts);
    let (repaired, repair_report) =
        repair(mesh, &repair_opts, &span).and_then(super::checks::one_part).map_err(|e| e.in_file(input))?;
    stages.push(clock.stop("repair", Some(repair_report.distance.clone())));
    let input_volume = repaired.signed_volume();

    // 4. The chain at each resolution until one is fine enough.
    let targets = resolutions(resolution)?;
    let (target, samples, invented) =
        (MeshTarget::new(&repaired), Default::default(), repair_report.holes.invented.positions.clone());
    let chain = Chain { input, target, samples, invented, repaired, input_geom, cmp_opts, opts, progress };
    let mut attempts = Vec::new();
    let mut best = None;
    for (k, &n) in targets.iter().enumerate() {
        let kept = chain.solid_at(n, diag, &mut attempts)?;
        let done = match resolution {
            Resolution::Tolerance(t) => kept.rms <= t || k + 1 == targets.len(),
            _ => true,
        };
        tracing::info!(target_vertices = n, rms = kept.rms, "convert attempt");
        if done {
            best = Some(kept);
            break;
        }
    }
    let kept = best.ok_or_else(|| Error::internal("no resolution attempted"))?;
    stages.extend(kept.stages);
    let (kept_rms, kept_input_to_solid_rms, kept_folds) = (kept.rms, kept.input_to_solid_rms, kept.brep.folded_faces);

    // 5. Write the STEP file, the solid mesh beside it and the quad net.
    check_cancelled(progress)?;
    let clock = Clock::start();
    ProgressSpan::new(progress, 0.95, 0.98, "step");
    let name = input.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "scan".into());
    // Its digest is taken while writing: nothing reads it back to hash it.
    let step = write_step(output, &kept.solid, &StepOptions { name, unit: opts.unit, pcurves: true })?;
    let (solid_mesh_file, solid_mesh, solid_digest, kept_triangles) =
        write_solid_mesh(output, &step.sha256, kept.tessellation)?;
    let face_of: Vec<u32> = kept_triangles.iter().map(|&t| kept.tessellation_faces[t as usize]).collect();
    // The crossings gate: the coarse check that chose the chain, and the fine tessellation written.
    let kept_crossings = kept.brep.self_intersections.max(mesh_self_intersections(&solid_mesh));
    if let Some(q) = &opts.quads_output {
        super::write_mesh(q, &kept.quads, "quad control net by scanstation")?;
    }
    stages.push(clock.stop("step", None));

    // 6. An open input's measure (before the solid mesh goes to the error map), then the error map: the solid
    // mesh coloured by its distance to the input.
    check_cancelled(progress)?;
    let clock = Clock::start();
    ProgressSpan::new(progress, 0.98, 1.0, "quality");
    let cloud_scatter_pct = reconstruct_step.as_ref().map(|r| r.distance.reference_to_test.rms.pct_of_diagonal);
    let to_solid = (kept_input_to_solid_rms, kept.input_to_solid_max, diag);
    let (open_input, error_map_file, map, invented, seen_by, far_tail) =
        measure_and_map(output, &solid_mesh, &chain, to_solid, &repair_report, fused.as_ref())?;
    stages.push(clock.stop("quality", None));
    progress.report(1.0, "quality/done");

    // 7. The quality gates and the report.
    let volume_error_pct = 100.0 * (kept.brep.volume - input_volume) / input_volume.abs().max(f64::MIN_POSITIVE);
    // The RMS the gate judges: points → solid for a cloud, the open-input measure, or the two-sided RMS.
    let rms_pct = open_input.as_ref().map_or(100.0 * kept_rms / diag, |o| o.rms_pct);
    let rms_pct = if cloud_scatter_pct.is_some() { 100.0 * kept_input_to_solid_rms / diag } else { rms_pct };
    let tolerance_pct = if let Resolution::Tolerance(t) = resolution { Some(100.0 * t / diag) } else { None };
    let measured = Measured {
        crossings: kept_crossings,
        folded_faces: kept_folds,
        volume_error_pct,
        rms_pct,
        open_input: open_input.is_some(),
        cap_excess_pct: open_input.as_ref().and_then(OpenInputMeasure::cap_excess_pct),
        cloud_scatter_pct,
        tolerance_pct,
        max_distance_pct: far_tail.max_pct,
        cloud_max_pct: reconstruct_step.as_ref().map(|r| r.distance.reference_to_test.max.pct_of_diagonal),
    };
    let (status, gates) = judge_logged(&measured, &opts.gates);

    // 8. The pictures, when asked for.
    let (held, measured) = ((&solid_mesh, &face_of[..], &kept.quads), (&chain.repaired, &map, invented.as_deref()));
    let chain_figures = (&attempts[..], diag, tolerance_pct.unwrap_or(opts.gates.max_rms_pct), &far_tail.places[..]);
    let pictures = draw_pictures(output, opts, held, measured, chain_figures, &mut stages)?;
    let report = ConvertReport {
        input_file: input.to_path_buf(),
        output_file: output.to_path_buf(),
        solid_mesh_file,
        error_map_file,
        error_map_scale: map.scale,
        unit: opts.unit,
        input_vertices,
        input_faces,
        bbox_diagonal: diag,
        stages,
        repair: repair_report,
        remesh: kept.remesh,
        fit: kept.fit,
        brep: kept.brep,
        input_volume,
        volume_error_pct,
        attempts,
        open_input,
        reconstruct: reconstruct_step,
        far_tail,
        status,
        gates,
        total_seconds: t_total.elapsed().as_secs_f64(),
        pictures,
        unseen: seen_by.as_ref().map(|s| s.unseen.clone()),
    };
    let digests = Digests { step, solid_mesh: solid_digest, error_map: map.digest };
    Ok(Converted { report, solid_mesh, fused, digests, seen_by })
}

/// How the conversion measures distances: `opts`' samples, seed and memory budget, the vertices too.
fn compare_options(opts: &ConvertOptions) -> CompareOptions {
    CompareOptions {
        samples: opts.compare_samples,
        seed: opts.seed,
        include_vertices: true,
        memory_budget: opts.memory_budget,
    }
}

/// The gates on `m`, each missed one logged.
fn judge_logged(m: &Measured, opts: &GateOptions) -> (Status, Vec<super::gates::Gate>) {
    let (status, gates) = judge(m, opts);
    for g in gates.iter().filter(|g| !g.passed) {
        tracing::warn!(gate = g.name, value = g.value, bound = g.bound, ?status, "quality gate missed");
    }
    (status, gates)
}

/// What [`measure_and_map`] measured and wrote: an open input's measure, the error map's path, what it wrote,
/// the invented vertices (an open input's fills, a scan's unseen surface), what a scan's views saw, and the
/// far tail.
type MapMeasure = (
    Option<OpenInputMeasure>,
    PathBuf,
    ErrorMapFile,
    Option<Vec<bool>>,
    Option<super::reconstruct::SeenBy>,
    super::far_tail::FarTail,
);

/// Step 6 of [`convert_held`]: an open input's measure of `solid_mesh` (see [`OpenInputMeasure`]), the error
/// map beside `output` (the solid mesh coloured by its distance to the input, the invented region grey), and
/// the far tail of the scan → solid distance ([`super::far_tail`]). `to_solid` is the chain's input → solid
/// RMS and maximum and the input's diagonal.
fn measure_and_map(
    output: &Path,
    solid_mesh: &PolyMesh,
    chain: &Chain,
    (input_to_solid_rms, input_to_solid_max, diag): (f64, f64, f64),
    repair_report: &RepairReport,
    fused: Option<&super::reconstruct::Fused>,
) -> Result<MapMeasure> {
    let input = &chain.input_geom;
    let (open_input, invented) = open_input_measure(solid_mesh, input, input_to_solid_rms, repair_report, diag);
    // A scan's views: the surface none saw is invented too (the reconstruction closed it).
    let seen_by = fused.map(|f| super::reconstruct::seen_by_views(&solid_mesh.triangulate().0, f));
    let invented = match (invented, &seen_by) {
        (Some(m), Some(s)) => Some(m.iter().zip(&s.counts).map(|(&a, &n)| a || n == 0).collect()),
        (None, Some(s)) => Some(s.unseen_vertices()),
        (m, None) => m,
    };
    let error_map_file = super::provenance::error_map_path(output);
    let map = write_error_map(&error_map_file, &Geometry::Mesh(solid_mesh.clone()), input, invented.as_deref())?;
    let scan = (input, &chain.repaired, repair_report);
    let far_tail = super::far_tail::measure(scan, solid_mesh, input_to_solid_max, chain.opts.gates.max_rms_pct, diag);
    Ok((open_input, error_map_file, map, invented, seen_by, far_tail))
}

/// Step 8 of [`convert_held`]: the job's pictures beside `output` ([`super::pictures`]) when
/// [`ConvertOptions::pictures`] asks (its stage report pushed onto `stages`). The deviation is signed against
/// the repaired (closed) input: each vertex's distance to the input (`map.distances`), with the side of the
/// repaired surface it lies on; the tolerance band is the RMS gate's bound.
fn draw_pictures(
    output: &Path,
    opts: &ConvertOptions,
    (solid, face_of, net): (&PolyMesh, &[u32], &PolyMesh),
    (repaired, map, invented): (&TriMesh, &ErrorMapFile, Option<&[bool]>),
    (attempts, diag, bound_pct, far): (&[Attempt], f64, f64, &[[f64; 3]]),
    stages: &mut Vec<StageReport>,
) -> Result<Vec<super::pictures::Picture>> {
    use super::pictures::{AttemptPoint, ConvertPictures, Deviation, write_convert_pictures};
    let Some(up) = opts.pictures else { return Ok(Vec::new()) };
    let clock = Clock::start();
    let unit = opts.unit;
    let (solid, _) = solid.triangulate();
    let side = crate::stages::quality::signed_vertex_distances(&solid, repaired);
    let signed = crate::stages::quality::with_side(&map.distances, &side);
    let attempts = attempts
        .iter()
        .map(|a| AttemptPoint {
            target_vertices: a.target_vertices,
            rms_pct: a.solid_rms_pct,
            rejected: a.solid_self_intersections > 0 || a.solid_folded_faces > 0,
        })
        .collect();
    let band = bound_pct / 100.0 * diag;
    let deviation = Deviation { signed: &signed, invented, band, diag, unit: unit.symbol(), far };
    let p = ConvertPictures { solid: &solid, face_of, deviation, net, attempts, rms_bound_pct: bound_pct };
    let drawn = write_convert_pictures(output, &p, up)?;
    stages.push(clock.stop("pictures", None));
    Ok(drawn)
}

/// Step 2b of [`convert_file`]: reconstruct a cloud input, measured against its points (its stage report
/// pushed onto `stages`); nothing for a mesh.
fn reconstruct_stage(
    input: &Path,
    input_geom: &Geometry,
    fusion: Option<crate::stages::reconstruct::fusion::FusionReport>,
    opts: &ConvertOptions,
    cmp_opts: &CompareOptions,
    progress: &dyn Progress,
    stages: &mut Vec<StageReport>,
) -> Result<(Option<PolyMesh>, Option<ReconstructStep>)> {
    if !matches!(input_geom, Geometry::Cloud(_)) {
        return Ok((None, None));
    }
    check_cancelled(progress)?;
    let clock = Clock::start();
    let span = ProgressSpan::new(progress, 0.02, 0.08, "reconstruct");
    let ro = ReconstructOptions { memory_budget: opts.memory_budget, ..opts.reconstruct.clone() };
    let (m, report, distance) =
        super::reconstruct::reconstruct_measured(input_geom, &ro, cmp_opts, &span).map_err(|e| e.in_file(input))?;
    stages.push(clock.stop("reconstruct", Some(distance.clone())));
    Ok((Some(PolyMesh::from(m)), Some(ReconstructStep { fusion, report, distance })))
}

/// What reconstruction did for a point-cloud input.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ReconstructStep {
    /// For a scan set: how its views were fused.
    pub fusion: Option<crate::stages::reconstruct::fusion::FusionReport>,
    /// The stage's report.
    pub report: ReconstructReport,
    /// The reconstructed mesh (TEST) against the points (REFERENCE).
    pub distance: DistanceReport,
}

/// The input mesh or cloud, read within 1/[`CHAIN_MEMORY_FACTOR`] of the budget: the chain needs far more
/// than the mesh itself (repair alone ~420 bytes per face against ~30 for the mesh), so a larger input is
/// refused while reading, before it is allocated.
fn read_input(
    input: &Path,
    read: &ReadOptions,
    opts: &ConvertOptions,
) -> Result<(Geometry, Option<super::reconstruct::Fused>)> {
    let read = ReadOptions { memory_budget: read.memory_budget.min(opts.memory_budget / CHAIN_MEMORY_FACTOR), ..*read };
    super::reconstruct::read_input_views(input, &read, &opts.reconstruct.fusion).map_err(|e| {
        if e.code == ErrorCode::ResourceMemoryBudget {
            e.with_hint(format!(
                "the conversion needs about {CHAIN_MEMORY_FACTOR}x the input mesh's memory; raise the memory budget or decimate the scan"
            ))
        } else {
            e
        }
    })
}

/// Repair's settings in the chain: the chain's budget (each stage estimates its need before allocating), the
/// chain's distance measure, and handles too narrow for the quad net cut ([`small_handle_loop`]).
fn repair_options(
    opts: &ConvertOptions,
    resolution: Resolution,
    mesh: &PolyMesh,
    diag: f64,
    cmp: &CompareOptions,
) -> RepairOptions {
    let mut repair_opts = RepairOptions {
        memory_budget: opts.memory_budget,
        compare_samples: cmp.samples,
        compare_seed: cmp.seed,
        ..opts.repair
    };
    if opts.remove_small_handles && repair_opts.max_handle_loop_rel == 0.0 && diag > 0.0 {
        let loop_len = small_handle_loop(resolution, mesh.triangulate().0.area());
        if loop_len.is_finite() && loop_len > 0.0 {
            repair_opts.max_handle_loop_rel = loop_len / diag;
        }
    }
    repair_opts
}

impl Chain<'_> {
    /// The solid at `n` control vertices. A solid whose surface crosses itself or has a folded face (a pleat
    /// of the fitted surface at a thin part or a tight bend, which depends on the quad layout there) is built
    /// again from another seed's quads, up to [`SOLID_RETRIES`] times; the one with the fewest crossings, then
    /// the fewest folds, is kept (the first clean one ends the search). Every try goes into `attempts`.
    fn solid_at(&self, n: usize, diag: f64, attempts: &mut Vec<Attempt>) -> Result<SolidTry> {
        let mut best: Option<SolidTry> = None;
        for solid_try in 0..=SOLID_RETRIES {
            let seed = self.opts.seed.wrapping_add((solid_try * (REMESH_RETRIES + 1)) as u64);
            let t = self.chain(n, seed)?;
            let (crossings, folds) = (t.brep.self_intersections, t.brep.folded_faces);
            attempts.push(Attempt {
                target_vertices: n,
                control_vertices: t.control_vertices,
                seed,
                solid_self_intersections: crossings,
                solid_folded_faces: folds,
                solid_rms: t.rms,
                solid_rms_pct: 100.0 * t.rms / diag,
                raises: t.raises.clone(),
                local: t.local.clone(),
            });
            if crossings > 0 || folds > 0 {
                tracing::warn!(
                    pairs = crossings,
                    folds,
                    seed,
                    crossing_at = ?t.brep.self_intersection_at,
                    fold_at = ?t.brep.fold_at,
                    "the solid crosses itself or folds; trying another seed"
                );
            }
            let flaws = |t: &SolidTry| (t.brep.self_intersections, t.brep.folded_faces);
            if best.as_ref().is_none_or(|b| (crossings, folds) < flaws(b)) {
                best = Some(t);
            }
            if (crossings, folds) == (0, 0) {
                break;
            }
        }
        best.ok_or_else(|| Error::internal("no solid was built"))
    }

    /// One chain: remesh (other seeds while the quad mesh crosses itself), under the deviation goal refine
    /// the net locally ([`super::refine`]), fit the surface, build and measure the solid. A solid on a
    /// refined net that crosses itself or folds is built again on a net refined away from its flaws, then
    /// on the unrefined net.
    fn chain(&self, n: usize, seed: u64) -> Result<SolidTry> {
        let progress = self.progress;
        check_cancelled(progress)?;
        let mut clock = Some(Clock::start());
        let mut remesh_reading = None;
        let span = ProgressSpan::new(progress, 0.1, 0.5, "remesh");
        let (base, remesh_report, quad_crossings, raises) = self.net(n, seed, &span)?;
        let max_rms_pct = self.opts.gates.max_rms_pct;
        let scan_to_net = remesh_report.distance.as_ref().map_or(0.0, |d| d.reference_to_test.rms.pct_of_diagonal);
        let scan_to_net_max = remesh_report.distance.as_ref().map_or(0.0, |d| d.reference_to_test.max.pct_of_diagonal);
        let trigger = matches!(self.opts.resolution, Resolution::Goal { .. })
            .then(|| super::refine::trigger((scan_to_net, scan_to_net_max), max_rms_pct))
            .flatten();
        let (refines, by_max) = (trigger.is_some(), trigger == Some(super::refine::Trigger::FarTail));
        let mut local = LocalRefinement { trigger, ..Default::default() };
        let mut avoid = self.invented.clone();
        let mut earlier = [0.0; 2];
        loop {
            let tries = if by_max { super::refine::FAR_TAIL_SOLID_TRIES } else { super::refine::SOLID_TRIES };
            let refined = if refines && local.given_up < tries {
                let samples = self.samples.get_or_init(|| super::refine::scan_samples(&self.input_geom));
                let goal_abs = max_rms_pct / 100.0 * self.input_geom.bbox().diagonal();
                let (q, r) = super::refine::refine_net(&base, &self.repaired, samples, goal_abs, &avoid, by_max)?;
                (r.vertices_after > r.vertices_before).then_some((q, r))
            } else {
                None
            };
            let last = refined.is_none();
            let (quads, report) = refined.map_or((base.clone(), None), |(q, r)| (q, Some(r)));
            if let Some(c) = clock.take() {
                let r = c.stop("remesh", None);
                remesh_reading = Some((r.seconds, r.peak_rss_mib));
            }
            let mut t = self.solid_on(quads, quad_crossings, &span, remesh_reading)?;
            if last || (t.brep.self_intersections, t.brep.folded_faces) == (0, 0) {
                (t.stages[1].seconds, t.stages[2].seconds) =
                    (t.stages[1].seconds + earlier[0], t.stages[2].seconds + earlier[1]);
                local.kept = report;
                (t.remesh, t.raises, t.local) = (remesh_report, raises, local);
                return Ok(t);
            }
            tracing::warn!(
                pairs = t.brep.self_intersections,
                folds = t.brep.folded_faces,
                "the solid on the locally refined net crosses itself or folds; refining away from there"
            );
            earlier[0] += t.stages[1].seconds;
            earlier[1] += t.stages[2].seconds;
            local.given_up += 1;
            local.avoided += t.flaws.len();
            avoid.extend(t.flaws);
        }
    }

    /// Fit the surface to `quads`, build and measure the solid. `remesh` is the remesh stage's seconds and
    /// peak memory (its distance is measured here, on `quads`).
    fn solid_on(
        &self,
        quads: PolyMesh,
        quad_crossings: usize,
        span: &dyn Progress,
        remesh: Option<(f64, Option<f64>)>,
    ) -> Result<SolidTry> {
        let (opts, progress) = (self.opts, self.progress);
        let mut stages = Vec::new();
        let d = compare(&Geometry::Mesh(quads.clone()), &self.input_geom, &self.cmp_opts, span)?;
        let (seconds, peak_rss_mib) = remesh.unwrap_or((0.0, None));
        stages.push(StageReport { stage: "remesh", seconds, peak_rss_mib, distance: Some(d) });

        check_cancelled(progress)?;
        let clock = Clock::start();
        let span = ProgressSpan::new(progress, 0.5, 0.8, "surface");
        let (net, pos) = control_net(&quads)?;
        let (p, surface, fit_report) = fit_control_points(&net, &pos, &self.target, &opts.fit, &span)?;
        stages.push(clock.stop("surface", None));

        check_cancelled(progress)?;
        let clock = Clock::start();
        let span = ProgressSpan::new(progress, 0.8, 0.95, "brep");
        let p1 = surface.refine.apply(&p);
        let (solid, mut brep_report) = build_solid(&surface, &p1)?;
        brep_report.quad_self_intersections = quad_crossings;
        let mut flaws = solid_self_intersections(&solid)?;
        (brep_report.self_intersections, brep_report.self_intersection_at) = (flaws.len(), flaws.first().copied());
        if brep_report.folded_faces > 0 {
            flaws.extend(solid.fold_points());
        }
        let (tessellation, tessellation_faces) = tessellate_for_check(&solid, 1_500_000)?;
        let d =
            compare(&Geometry::Mesh(PolyMesh::from(tessellation.clone())), &self.input_geom, &self.cmp_opts, &span)?;
        let (rms, input_to_solid_rms, input_to_solid_max) =
            (d.symmetric.rms.value, d.reference_to_test.rms.value, d.reference_to_test.max.value);
        stages.push(clock.stop("brep", Some(d)));
        Ok(SolidTry {
            quads,
            raises: Vec::new(),
            local: LocalRefinement::default(),
            control_vertices: net.vertex_count,
            remesh: RemeshReport::default(),
            fit: fit_report,
            solid,
            brep: brep_report,
            stages,
            rms,
            input_to_solid_rms,
            input_to_solid_max,
            tessellation,
            tessellation_faces,
            flaws,
        })
    }

    /// The quad net the solid is built on: the one at `n` vertices ([`Chain::quads`]), and under the default
    /// deviation goal, while it misses the goal, one at a higher count when that is sound and nearer
    /// ([`super::goal`]; a raised net is made once, at the same seed).
    fn net(&self, n: usize, seed: u64, span: &dyn Progress) -> Result<(PolyMesh, RemeshReport, usize, Vec<NetRaise>)> {
        let Resolution::Goal { cap, .. } = self.opts.resolution else {
            let (quads, report, crossings) = self.quads(n, seed, false, span)?;
            return Ok((quads, report, crossings, Vec::new()));
        };
        // A net that may still be raised needs no last-resort route for being far ([`RemeshOptions::far_is_raised`]).
        let (mut quads, mut report, mut crossings) = self.quads(n, seed, n < cap, span)?;
        let mut raises = Vec::new();
        let net_rms = |r: &RemeshReport| r.distance.as_ref().map_or(f64::NAN, |d| d.symmetric.rms.pct_of_diagonal);
        let goal_pct = self.opts.gates.max_rms_pct;
        let mut m = n;
        while let Some(next) = super::goal::next_count(m, net_rms(&report), goal_pct, raises.len(), cap) {
            check_cancelled(self.progress)?;
            let clock = Instant::now();
            let far_is_raised = next < cap && raises.len() + 1 < super::goal::NET_RAISES;
            let (q, r, c) = self.remesh_once(next, seed, far_is_raised, span)?;
            let coarse = (net_rms(&report), crossings, report.euler_characteristic_changed);
            let fine = (net_rms(&r), c, r.euler_characteristic_changed);
            let kept = super::goal::keeps(coarse, fine);
            raises.push(NetRaise {
                from_vertices: m,
                from_rms_pct: coarse.0,
                to_vertices: next,
                to_rms_pct: fine.0,
                to_crossing_pairs: c,
                to_changed_topology: fine.2 && !coarse.2,
                kept,
                seconds: clock.elapsed().as_secs_f64(),
            });
            tracing::info!(
                from = m,
                to = next,
                net_rms_pct = coarse.0,
                finer_rms_pct = fine.0,
                crossings = c,
                kept,
                "the quad net misses the deviation goal; made again finer"
            );
            if !kept {
                break;
            }
            (quads, report, crossings, m) = (q, r, c, next);
        }
        Ok((quads, report, crossings, raises))
    }

    /// The quad mesh at `n` vertices: a quad mesh that folds through itself would give a self-intersecting
    /// solid, so other seeds are tried (up to [`REMESH_RETRIES`]) and the one with the fewest crossings kept.
    fn quads(
        &self,
        n: usize,
        seed: u64,
        far_is_raised: bool,
        span: &dyn Progress,
    ) -> Result<(PolyMesh, RemeshReport, usize)> {
        let mut best: Option<(PolyMesh, RemeshReport, usize)> = None;
        for retry in 0..=REMESH_RETRIES {
            let seed = seed.wrapping_add(retry as u64);
            let (q, r, crossings) = self.remesh_once(n, seed, far_is_raised, span)?;
            if crossings > 0 {
                tracing::warn!(crossings, seed, "the quad mesh intersects itself; trying another seed");
            }
            if best.as_ref().is_none_or(|b| crossings < b.2) {
                best = Some((q, r, crossings));
            }
            if crossings == 0 {
                break;
            }
        }
        best.ok_or_else(|| Error::internal("no remesh ran"))
    }

    /// One quad net of the repaired input at `n` vertices and `seed`, with its crossing triangle pairs.
    fn remesh_once(
        &self,
        n: usize,
        seed: u64,
        far_is_raised: bool,
        span: &dyn Progress,
    ) -> Result<(PolyMesh, RemeshReport, usize)> {
        let opts = self.opts;
        let ropts = RemeshOptions {
            target_vertices: n,
            seed,
            memory_budget: opts.memory_budget,
            far_is_raised,
            ..opts.remesh.clone()
        };
        let (q, r) = remesh(&self.repaired, &ropts, span).map_err(|e| e.in_file(self.input))?;
        let crossings = mesh_self_intersections(&q);
        Ok((q, r, crossings))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Record(std::sync::Mutex<Vec<f64>>);
    impl Progress for Record {
        fn report(&self, fraction: f64, _phase: &str) {
            self.0.lock().unwrap().push(fraction);
        }
    }

    /// A stage that runs again (another seed, another resolution) reports lower fractions; the caller
    /// still sees the overall fraction hold, not go back.
    #[test]
    fn progress_never_goes_back_when_stages_run_again() {
        let rec = Record(std::sync::Mutex::new(Vec::new()));
        let m = Monotonic { parent: &rec, last: std::sync::Mutex::new(0.0) };
        for f in [0.1, 0.5, 0.95, 0.1, 0.5, f64::NAN, 0.97, 1.0] {
            m.report(f, "x");
        }
        assert_eq!(*rec.0.lock().unwrap(), vec![0.1, 0.5, 0.95, 0.95, 0.95, 0.95, 0.97, 1.0]);
    }
}

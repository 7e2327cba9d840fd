//! `scanstation fea`: read a solid (a closed tri-mesh, or a STEP written by `convert` through the solid mesh
//! artifact beside it), solve the spec, write `result.json` and `surface.vtu` into the result directory.
//!
//! The artifact: `convert … -o NAME.step` also writes `NAME.solid.ply`, a watertight tessellation of the
//! B-rep's own surfaces (faces sampled on their knot spans and welded along their shared edges), whose header
//! comment `scanstation-solid-of sha256=…` names the STEP bytes it was made from. Given a STEP file, `fea`
//! reads that artifact and refuses it when the hash does not match (a STEP edited or replaced since).

use std::io::{Read as _, Write as _};
use std::path::{Path, PathBuf};

use super::memory::StageMeter;
use super::provenance::{SOLID_OF, sha256_file, solid_artifact_path};
use crate::error::{Error, ErrorCode, Result};
use crate::geometry::io::{ReadOptions, ensure_not_input, read_mesh, write_atomic};
use crate::geometry::mesh::PolyMesh;
use crate::stages::Progress;
use crate::stages::fea::{self, FeaOptions, FeaReport, FeaSpec};

/// What `scanstation fea` reports.
#[derive(Clone, Debug, serde::Serialize)]
pub struct FeaFileReport {
    /// The solid as given (a mesh or a STEP file).
    pub input_file: PathBuf,
    /// The mesh the solid was taken from (the input, or the STEP's solid artifact).
    pub solid_mesh_file: PathBuf,
    /// The spec file.
    pub spec_file: PathBuf,
    /// The spec as read.
    pub spec: FeaSpec,
    /// The result directory.
    pub output_dir: PathBuf,
    /// The files written into it.
    pub outputs: Vec<PathBuf>,
    /// Peak resident memory of the solve, MiB (`null` where it cannot be read).
    pub peak_rss_mib: Option<f64>,
    /// Wall seconds of the whole command.
    pub seconds: f64,
    #[serde(flatten)]
    /// The solve's report (flattened into this one).
    pub result: FeaReport,
    /// The stress picture (`stress.png`), when asked for.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub pictures: Vec<super::pictures::Picture>,
    /// Each output's size and SHA-256, taken while writing it (not serialised).
    #[serde(skip)]
    pub digests: Vec<(PathBuf, crate::geometry::io::FileDigest)>,
}

fn is_step(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("step") || e.eq_ignore_ascii_case("stp"))
}

/// The mesh file to solve on for `input`, checking a STEP's artifact against the STEP's hash.
fn solid_mesh_for(input: &Path) -> Result<PathBuf> {
    if !is_step(input) {
        return Ok(input.to_path_buf());
    }
    if !input.exists() {
        return Err(Error::new(ErrorCode::InputNotFound, "no such file").in_file(input));
    }
    let artifact = solid_artifact_path(input);
    let mut head = Vec::with_capacity(4096);
    std::fs::File::open(&artifact)
        .and_then(|f| f.take(4096).read_to_end(&mut head))
        .map_err(|_| {
            Error::new(ErrorCode::InputUnknownFormat, format!("no solid mesh artifact {} beside the STEP file", artifact.display()))
                .in_file(input)
                .with_hint("fea reads STEP files that `scanstation convert` wrote (it writes NAME.solid.ply beside NAME.step); for other solids give a closed mesh")
        })?;
    let text = String::from_utf8_lossy(&head);
    let want = sha256_file(input)?;
    let found = text.lines().find_map(|l| l.strip_prefix("comment ").and_then(|c| c.strip_prefix(SOLID_OF)));
    if found.map(str::trim) != Some(want.as_str()) {
        return Err(Error::new(
            ErrorCode::InputBadHeader,
            format!("{} was not made from this STEP file (its sha256 differs)", artifact.display()),
        )
        .in_file(input)
        .with_hint("run `scanstation convert` again to rewrite both"));
    }
    Ok(artifact)
}

/// Solve `spec_file` on the solid `input` and write `result.json` and `surface.vtu` into `output_dir`
/// (each file atomically, the JSON last; nothing is written when the solve fails), and `stress.png` when
/// `pictures` gives the object's up axis ([`super::pictures`]).
///
/// # Errors
/// Reader errors; `fea.*` (see [`fea::solve`]); `resource.output`.
pub fn fea_file(
    input: &Path,
    spec_file: &Path,
    output_dir: &Path,
    read: &ReadOptions,
    options: &FeaOptions,
    pictures: Option<super::pictures::Up>,
    progress: &dyn Progress,
) -> Result<FeaFileReport> {
    let meter = StageMeter::start();
    let spec = FeaSpec::read(spec_file)?;
    let mesh_file = solid_mesh_for(input)?;
    let outs = outputs_of(output_dir, &[input, spec_file, &mesh_file])?;
    let mesh = read_mesh(&mesh_file, read)?;
    solve_and_write(meter, spec, (input, &mesh_file, &mesh), spec_file, outs, (options, pictures), progress)
}

/// `surface.vtu` and `result.json` in `output_dir`, each checked to be neither one of `inputs` nor a file
/// that must not be replaced.
fn outputs_of(output_dir: &Path, inputs: &[&Path]) -> Result<[PathBuf; 3]> {
    let (vtu, json) = (output_dir.join("surface.vtu"), output_dir.join("result.json"));
    for out in [&vtu, &json] {
        ensure_not_input(out, inputs)?;
        crate::geometry::io::ensure_replaceable(out)?;
    }
    Ok([output_dir.to_path_buf(), vtu, json])
}

/// [`fea_file`] on a solid already in memory: `solid` is (its STEP file, its solid mesh's file, that mesh as
/// [`super::convert_held`] handed it back), so nothing is read back.
///
/// # Errors
/// As [`fea_file`], without the solid's reader errors.
pub fn fea_solid(
    (input, mesh_file, mesh): (&Path, &Path, &PolyMesh),
    spec_file: &Path,
    output_dir: &Path,
    options: &FeaOptions,
    pictures: Option<super::pictures::Up>,
    progress: &dyn Progress,
) -> Result<FeaFileReport> {
    let meter = StageMeter::start();
    let spec = FeaSpec::read(spec_file)?;
    let outs = outputs_of(output_dir, &[input, spec_file, mesh_file])?;
    solve_and_write(meter, spec, (input, mesh_file, mesh), spec_file, outs, (options, pictures), progress)
}

/// Solve `spec` on `mesh` and write `vtu`, then `json` (the report).
fn solve_and_write(
    meter: StageMeter,
    spec: FeaSpec,
    (input, mesh_file, mesh): (&Path, &Path, &PolyMesh),
    spec_file: &Path,
    [output_dir, vtu, json]: [PathBuf; 3],
    (options, pictures): (&FeaOptions, Option<super::pictures::Up>),
    progress: &dyn Progress,
) -> Result<FeaFileReport> {
    let (tri, _) = mesh.triangulate();
    let solution = fea::solve(&tri, &spec, options, progress).map_err(|e| e.in_file(input))?;
    let vtu_digest = write_atomic(&vtu, |w| fea::vtu::write_vtu(w, &solution.surface, &solution.fields))?;
    let pictures = match pictures {
        Some(up) => vec![stress_picture(&output_dir.join("stress.png"), &spec, &solution, up)?],
        None => Vec::new(),
    };
    let (seconds, peak_rss_mib) = meter.finish();
    let mut report = FeaFileReport {
        input_file: input.to_path_buf(),
        solid_mesh_file: mesh_file.to_path_buf(),
        spec_file: spec_file.to_path_buf(),
        spec,
        output_dir,
        outputs: [vtu.clone(), json.clone()].into_iter().chain(pictures.iter().map(|p| p.file.clone())).collect(),
        peak_rss_mib,
        seconds,
        result: solution.report,
        digests: Vec::new(),
        pictures,
    };
    let json_digest = write_atomic(&json, |w| {
        serde_json::to_writer_pretty(&mut *w, &report).map_err(std::io::Error::other)?;
        w.write_all(b"\n")
    })?;
    report.digests = vec![(vtu.clone(), vtu_digest), (json, json_digest)];
    report.digests.extend(report.pictures.iter().map(|p| (p.file.clone(), p.digest())));
    Ok(report)
}

/// Write the stress picture of a solution at `path`: von Mises on its surface, the vertices its supports
/// and loads select marked.
///
/// # Errors
/// `resource.output` when the file cannot be written.
pub fn stress_picture(
    path: &Path,
    spec: &FeaSpec,
    solution: &fea::FeaSolution,
    up: super::pictures::Up,
) -> Result<super::pictures::Picture> {
    let s = &solution.surface;
    let within = |regions: Vec<fea::spec::Region>| -> Vec<bool> {
        s.positions.iter().map(|p| regions.iter().any(|r| r.contains(p.map(f64::from)))).collect()
    };
    let supported = within(spec.supports.iter().map(|x| x.region()).collect());
    let loaded = within(spec.loads.iter().map(|x| x.region()).collect());
    let stress =
        super::pictures::Stress { von_mises: &solution.fields.von_mises, supported: &supported, loaded: &loaded };
    super::pictures::write_stress_picture(path, s, &stress, up)
}

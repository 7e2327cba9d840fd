//! What a scan's outbox bundle holds beyond a file's ([`super::worker`]): `views/` (every view's points as the
//! scanner wrote them, `scanset.toml` with their poses into the table frame, and `capture.json`), the fusion
//! report `<stem>.fusion.json` (per-view residuals before and after refinement, the calibrated axis, the
//! coverage: the share of the solid's surface some view saw) and, when the scan asked for one, the FEA
//! (`<stem>.fea.json`, `<stem>.fea.vtu`).

use std::path::{Path, PathBuf};

use super::config::Config;
use super::scan::{CaptureLog, ScanRequest, table_frame};
use crate::error::{Error, ErrorCode};
use crate::pipeline::Converted;

/// The views' directory in the bundle.
pub const VIEWS_DIR: &str = "views";

/// The files [`add`] put into the bundle.
#[derive(Default)]
pub struct Extras {
    /// Kind and path of each top-level file (listed in the manifest and `Outputs`).
    pub files: Vec<(&'static str, PathBuf)>,
    /// The manifest's `views` entry: the directory and each file's size and hash.
    pub views_manifest: Option<serde_json::Value>,
    /// The top-level files' sizes and SHA-256, taken while writing them.
    pub digests: std::collections::HashMap<PathBuf, crate::geometry::io::FileDigest>,
}

fn io_err(what: &str, p: &Path, e: impl std::fmt::Display) -> Error {
    Error::new(ErrorCode::ResourceOutput, format!("{what} {}: {e}", p.display()))
}

/// Where a scan's bundle is built and what it is made of.
pub struct ScanBundle<'a> {
    /// The job's scan directory (`work/<id>/<name>.scan/`).
    pub scan_dir: &'a Path,
    /// The bundle being built (`outbox/.<stem>-<id>.part`).
    pub part: &'a Path,
    /// The bundle's file stem.
    pub stem: &'a str,
    /// What `StartScan` asked for.
    pub scan: &'a ScanRequest,
    /// The station's settings.
    pub cfg: &'a Config,
}

/// Add a scan's views, fusion report and FEA to the bundle, from what the conversion held (`converted`: the
/// solid mesh, the fused views) and the capture's log: no file the pipeline wrote is read back, and the view
/// files are linked into the bundle (copied only across file systems), their hashes taken from the capture.
///
/// # Errors
/// `resource.output`; the FEA's errors (`fea.*`) when it was asked for and fails.
pub fn add(
    b: &ScanBundle<'_>,
    converted: &Converted,
    log: &CaptureLog,
    progress: &(dyn Fn(f64, &str) + Sync),
) -> Result<Extras, Error> {
    let mut extras = Extras { views_manifest: Some(link_views(b.scan_dir, b.part, log)?), ..Default::default() };
    let (fusion_path, digest) = write_fusion_report(b, converted, log)?;
    extras.digests.insert(fusion_path.clone(), digest);
    extras.files.push(("fusion-report", fusion_path));
    if let Some(seen) = &converted.seen_by {
        let solid = converted.solid_mesh.triangulate().0;
        let path = b.part.join(format!("{}.coverage.png", b.stem));
        let up = crate::pipeline::pictures::Up::Z;
        let pic = crate::pipeline::pictures::write_coverage_picture(&path, &solid, &seen.counts, seen.views, up)?;
        extras.digests.insert(path.clone(), pic.digest());
        extras.files.push(("coverage", path));
    }
    if let Some(spec) = &b.scan.fea {
        for (kind, path, digest) in fea(b, converted, spec, progress)? {
            extras.digests.insert(path.clone(), digest);
            extras.files.push((kind, path));
        }
    }
    Ok(extras)
}

/// `views/`: every file of the scan directory, hard-linked (the work directory stays whole until the job has
/// ended, for a quarantine; a copy where a link cannot be made). The manifest's entry: each file's size and
/// SHA-256 — a view's from the capture log, the small others (`capture.json`, `scanset.toml`) hashed here.
fn link_views(scan_dir: &Path, part: &Path, log: &CaptureLog) -> Result<serde_json::Value, Error> {
    let views_dir = part.join(VIEWS_DIR);
    std::fs::create_dir_all(&views_dir).map_err(|e| io_err("cannot create", &views_dir, e))?;
    let mut names: Vec<PathBuf> = std::fs::read_dir(scan_dir)
        .map_err(|e| io_err("cannot list", scan_dir, e))?
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.is_file() && !p.file_name().is_some_and(|n| n.to_string_lossy().starts_with('.')))
        .collect();
    names.sort();
    let mut listed = Vec::new();
    for p in &names {
        let name = p.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let to = views_dir.join(&name);
        if std::fs::hard_link(p, &to).is_err() {
            std::fs::copy(p, &to).map_err(|e| io_err("cannot copy", p, e))?;
            std::fs::File::open(&to).and_then(|f| f.sync_all()).map_err(|e| io_err("cannot fsync", &to, e))?;
        }
        let known = log.views.iter().find(|v| v.file == name && !v.sha256.is_empty());
        let (bytes, sha256) = match known {
            Some(v) => (v.bytes, v.sha256.clone()),
            None => {
                (std::fs::metadata(&to).map(|m| m.len()).unwrap_or(0), crate::pipeline::provenance::sha256_file(&to)?)
            }
        };
        listed.push(serde_json::json!({ "file": name, "bytes": bytes, "sha256": sha256 }));
    }
    super::durable::sync_dir(&views_dir).map_err(|e| io_err("cannot fsync", &views_dir, e))?;
    Ok(serde_json::json!({ "dir": VIEWS_DIR, "files": listed }))
}

/// `<stem>.fusion.json`: the calibrated axis, each view's capture and fit, the capture's counts, the fusion's
/// decision and the coverage of the solid by the views fusion kept (measured on the solid and views in
/// memory).
fn write_fusion_report(
    b: &ScanBundle<'_>,
    converted: &Converted,
    log: &CaptureLog,
) -> Result<(PathBuf, crate::geometry::io::FileDigest), Error> {
    let report = &converted.report;
    let fusion = report.reconstruct.as_ref().and_then(|r| r.fusion.clone());
    // The solid's triangles, once, for its coverage and the views' gains.
    let measured = converted.fused.as_ref().map(|f| (converted.solid_mesh.triangulate().0, f));
    let coverage = measured.as_ref().map(|(solid, f)| crate::pipeline::reconstruct::fused_coverage(solid, f));
    let gains =
        measured.as_ref().map(|(solid, f)| crate::pipeline::reconstruct::view_gains(solid, f)).unwrap_or_default();
    let per_view: Vec<serde_json::Value> = log
        .views
        .iter()
        .map(|v| {
            let fit = fusion.as_ref().and_then(|f| f.views.iter().find(|r| r.name == v.file));
            let gain = gains.iter().find(|g| g.name == v.file);
            let chosen = log.next_views.iter().find(|c| c.index == v.index);
            serde_json::json!({
                "index": v.index,
                "file": format!("{VIEWS_DIR}/{}", v.file),
                "angle_deg": v.angle_deg,
                "reached_deg": v.reached_deg,
                "tilt_deg": v.tilt_deg,
                "pass": v.pass,
                "gain": gain.map(|g| g.gain),
                "unique_gain": gain.map(|g| g.unique),
                "chosen": chosen.map(|c| serde_json::json!({ "round": c.round, "predicted_gain": c.predicted_gain })),
                "points": v.points,
                "tries": v.tries,
                "trigger_seq": v.seq,
                "view_ms": v.view_ms,
                "status": fit.map(|r| r.status),
                "residual_before_refinement": fit.map(|r| &r.given),
                "residual_after_refinement": fit.and_then(|r| r.refined.as_ref()),
                "refinement_moved_deg": fit.map(|r| r.moved_deg),
                "refinement_moved": fit.map(|r| r.moved),
            })
        })
        .collect();
    let fusion_json = serde_json::json!({
        "schema": 1,
        "frame": "table: origin at the table top's centre, z up the turntable's axis; views posed into it from the scanner's frame",
        "axis": {
            "point": log.axis_point,
            "direction": log.axis_direction,
            "frame": "scanner",
            "table_frame_from_scanner": table_frame(log.axis_point, log.axis_direction),
        },
        "planned_views": log.planned,
        "step_deg": b.scan.step_deg,
        "tilt_axis": log.tilt_axis.map(|(p, d)| serde_json::json!({ "point": p, "direction": d, "frame": "scanner" })),
        "rings": &b.scan.rings,
        "passes": {
            "planned": b.scan.passes,
            "turned_over": &log.turned_over,
            "aligned": fusion.as_ref().map(|f| &f.passes),
        },
        "next_views": {
            "coverage_target": b.scan.coverage,
            "max_views": b.scan.max_views.unwrap_or(b.cfg.scan.as_ref().map_or(0, |s| s.max_views)),
            "chosen": &log.next_views,
            "estimates": &log.estimates,
            "end": &log.next_views_end,
        },
        "views": per_view,
        "skipped": log.skipped,
        "capture": {
            "runs": log.runs,
            "homings": log.homings,
            "replugs": log.replugs,
            "retries": log.retries,
        },
        "refined": fusion.as_ref().map(|f| f.refined),
        "decision": fusion.as_ref().map(|f| f.decision.clone()),
        "pooled_residual_before": fusion.as_ref().and_then(|f| f.pooled_residual.0),
        "pooled_residual_after": fusion.as_ref().and_then(|f| f.pooled_residual.1),
        "rejected": fusion.as_ref().map(|f| f.rejected.clone()),
        "fused_points": fusion.as_ref().map(|f| f.points),
        "coverage": coverage,
        "unseen": converted.seen_by.as_ref().map(|s| &s.unseen),
    });
    let fusion_path = b.part.join(format!("{}.fusion.json", b.stem));
    let digest = super::durable::write_durable(
        &fusion_path,
        serde_json::to_string_pretty(&fusion_json).unwrap_or_default().as_bytes(),
    )
    .map_err(|e| io_err("cannot write", &fusion_path, e))?;
    Ok((fusion_path, digest))
}

/// The FEA the scan asked for (its spec's coordinates are the table frame's), solved on the solid mesh in
/// memory: `<stem>.fea.json` and `<stem>.fea.vtu`.
fn fea(
    b: &ScanBundle<'_>,
    converted: &Converted,
    spec: &Path,
    progress: &(dyn Fn(f64, &str) + Sync),
) -> Result<Vec<(&'static str, PathBuf, crate::geometry::io::FileDigest)>, Error> {
    let out = b.part.join(".fea");
    std::fs::create_dir_all(&out).map_err(|e| io_err("cannot create", &out, e))?;
    let report = &converted.report;
    let opts = crate::pipeline::FeaOptions { memory_budget: b.cfg.memory_budget };
    struct P<'a>(&'a (dyn Fn(f64, &str) + Sync));
    impl crate::pipeline::Progress for P<'_> {
        fn report(&self, fraction: f64, phase: &str) {
            (self.0)(fraction, phase);
        }
    }
    let solid = (report.output_file.as_path(), report.solid_mesh_file.as_path(), &converted.solid_mesh);
    let fea = crate::pipeline::fea::fea_solid(
        solid,
        spec,
        &out,
        &opts,
        Some(crate::pipeline::pictures::Up::Z),
        &P(progress),
    )?;
    let mut files = Vec::new();
    for (kind, from, to) in [
        ("fea-result", "result.json", format!("{}.fea.json", b.stem)),
        ("fea-surface", "surface.vtu", format!("{}.fea.vtu", b.stem)),
        ("stress", "stress.png", format!("{}.stress.png", b.stem)),
    ] {
        let (from, to) = (out.join(from), b.part.join(to));
        std::fs::rename(&from, &to).map_err(|e| io_err("cannot move", &from, e))?;
        let digest = fea.digests.iter().find(|(p, _)| *p == from).map(|(_, d)| d.clone());
        let digest = digest.ok_or_else(|| Error::internal(format!("no digest of {}", from.display())))?;
        files.push((kind, to, digest));
    }
    let _ = std::fs::remove_dir_all(&out);
    Ok(files)
}

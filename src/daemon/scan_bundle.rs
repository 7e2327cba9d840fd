//! What a scan's outbox bundle holds beyond a file's ([`super::worker`]): `views/` (every view's points as the
//! scanner wrote them, `scanset.toml` with their poses into the table frame, and `capture.json`), the fusion
//! report `<stem>.fusion.json` (per-view residuals before and after refinement, the calibrated axis, the
//! coverage: the share of the solid's surface some view saw) and, when the scan asked for one, the FEA
//! (`<stem>.fea.json`, `<stem>.fea.vtu`).

use std::path::{Path, PathBuf};

use super::config::Config;
use super::scan::{CaptureLog, ScanRequest, table_frame};
use crate::error::{Error, ErrorCode};
use crate::geometry::io::ReadOptions;
use crate::pipeline::convert::ConvertReport;

/// The views' directory in the bundle.
pub const VIEWS_DIR: &str = "views";

/// The files [`add`] put into the bundle.
#[derive(Default)]
pub struct Extras {
    /// Kind and path of each top-level file (listed in the manifest and `Outputs`).
    pub files: Vec<(&'static str, PathBuf)>,
    /// The manifest's `views` entry: the directory and each file's size and hash.
    pub views_manifest: Option<serde_json::Value>,
}

fn io_err(what: &str, p: &Path, e: impl std::fmt::Display) -> Error {
    Error::new(ErrorCode::ResourceOutput, format!("{what} {}: {e}", p.display()))
}

/// Add a scan's views, fusion report and FEA to the bundle being built in `part`. `scan_dir` is the job's
/// scan directory; `report` the conversion's.
///
/// # Errors
/// `resource.output`; the FEA's errors (`fea.*`) when it was asked for and fails.
pub fn add(
    scan_dir: &Path,
    part: &Path,
    stem: &str,
    report: &ConvertReport,
    scan: &ScanRequest,
    cfg: &Config,
    progress: &(dyn Fn(f64, &str) + Sync),
) -> Result<Extras, Error> {
    let mut extras = Extras::default();
    // 1. views/: copies (the work directory stays whole until the job has ended, for a quarantine).
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
        let to = views_dir.join(p.file_name().unwrap_or_default());
        std::fs::copy(p, &to).map_err(|e| io_err("cannot copy", p, e))?;
        std::fs::File::open(&to).and_then(|f| f.sync_all()).map_err(|e| io_err("cannot fsync", &to, e))?;
        listed.push(serde_json::json!({
            "file": to.file_name().map(|n| n.to_string_lossy().into_owned()),
            "bytes": std::fs::metadata(&to).map(|m| m.len()).unwrap_or(0),
            "sha256": crate::pipeline::provenance::sha256_file(&to)?,
        }));
    }
    super::journal::sync_dir(&views_dir).map_err(|e| io_err("cannot fsync", &views_dir, e))?;
    extras.views_manifest = Some(serde_json::json!({ "dir": VIEWS_DIR, "files": listed }));

    // 2. The fusion report.
    let log = CaptureLog::load(scan_dir).unwrap_or_default();
    let fusion = report.reconstruct.as_ref().and_then(|r| r.fusion.clone());
    let read = ReadOptions { memory_budget: cfg.memory_budget, max_input_size: cfg.max_input_size };
    let coverage = match &fusion {
        Some(f) => {
            let views = crate::geometry::io::scanset::read_scan_set(scan_dir, &read)?;
            let solid = crate::geometry::io::read_mesh(&report.solid_mesh_file, &read)?.triangulate().0;
            // Rejected views saw nothing the solid was built from.
            let (kv, kp): (Vec<_>, Vec<_>) =
                views.into_iter().zip(f.poses.iter().copied()).filter(|(v, _)| !f.rejected.contains(&v.name)).unzip();
            Some(crate::pipeline::reconstruct::view_coverage(&solid, &kv, &kp))
        }
        None => None,
    };
    let per_view: Vec<serde_json::Value> = log
        .views
        .iter()
        .map(|v| {
            let fit = fusion.as_ref().and_then(|f| f.views.iter().find(|r| r.name == v.file));
            serde_json::json!({
                "index": v.index,
                "file": format!("{VIEWS_DIR}/{}", v.file),
                "angle_deg": v.angle_deg,
                "reached_deg": v.reached_deg,
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
        "step_deg": scan.step_deg,
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
    });
    let fusion_path = part.join(format!("{stem}.fusion.json"));
    super::journal::write_durable(
        &fusion_path,
        serde_json::to_string_pretty(&fusion_json).unwrap_or_default().as_bytes(),
    )
    .map_err(|e| io_err("cannot write", &fusion_path, e))?;
    extras.files.push(("fusion-report", fusion_path));

    // 3. The FEA, when asked for (its spec's coordinates are the table frame's).
    if let Some(spec) = &scan.fea {
        let out = part.join(".fea");
        std::fs::create_dir_all(&out).map_err(|e| io_err("cannot create", &out, e))?;
        let step = &report.output_file;
        let opts = crate::stages::fea::FeaOptions { memory_budget: cfg.memory_budget };
        struct P<'a>(&'a (dyn Fn(f64, &str) + Sync));
        impl crate::stages::Progress for P<'_> {
            fn report(&self, fraction: f64, phase: &str) {
                (self.0)(fraction, phase);
            }
        }
        crate::pipeline::fea::fea_file(step, spec, &out, &read, &opts, &P(progress))?;
        for (kind, from, to) in [
            ("fea-result", "result.json", format!("{stem}.fea.json")),
            ("fea-surface", "surface.vtu", format!("{stem}.fea.vtu")),
        ] {
            let (from, to) = (out.join(from), part.join(to));
            std::fs::rename(&from, &to).map_err(|e| io_err("cannot move", &from, e))?;
            extras.files.push((kind, to));
        }
        let _ = std::fs::remove_dir_all(&out);
    }
    Ok(extras)
}

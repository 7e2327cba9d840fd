//! Passes of a scan set: the object turned over between two, so each pass's views share a frame but the
//! frames of two passes are unknown to each other. [`align_passes`] finds each later pass's frame in the
//! first pass's by the geometry alone, and refuses one that does not fit:
//!
//! 1. each pass's views, placed by their poses within the pass, form one oriented cloud (normals toward
//!    the scanners, as fusion estimates them);
//! 2. pass k is aligned onto passes 1 … k−1 (as aligned so far) by [`global::align`] (features, RANSAC,
//!    ICP on 2 % voxels), then [`global::polish`] on [`POLISH_VOXEL_REL`] voxels;
//! 3. the alignment is checked three ways, each against the views' own numbers:
//!    - **overlap**: at least [`MIN_PASS_OVERLAP`] of the pass's samples lie on the others (a turned-over
//!      object shows most of its sides again);
//!    - **residual**: their RMS point-to-plane distance at most [`PASS_NOISE_FACTOR`] × the views' noise
//!      (plus a tenth of a polish voxel, the thinning's own error);
//!    - **the table's plane**, where the passes were taken on a turntable (their frames are table frames):
//!      no more than [`MAX_BELOW_TABLE`] of either's points lie below the other's table top by more than
//!      the residual's tolerance. An object rests on the table in both passes; a wrong alignment pushes it
//!      through one of them.
//!
//! A pass that fails any is `reconstruct.views-disagree`, naming the pass and the check. Cost: a few
//! seconds per pass (the global search dominates).

use super::global::{self, GlobalOptions, GlobalReport, Oriented};
use crate::error::{Error, ErrorCode, Result};
use crate::geometry::io::scanset::{View, placed};
use crate::geometry::pose::Pose;
use crate::geometry::vec3::{Aabb, V3, dot, wide};

/// A later pass must have at least this share of its polish samples on the earlier passes.
pub const MIN_PASS_OVERLAP: f64 = 0.3;

/// A later pass's RMS point-to-plane distance to the earlier passes may be at most this many times the
/// views' noise (plus a tenth of a polish voxel).
pub const PASS_NOISE_FACTOR: f64 = 3.0;

/// The polish's voxel, as a share of the scan's bounding-box diagonal.
pub const POLISH_VOXEL_REL: f64 = 0.004;

/// At most this share of a pass's points may lie below another pass's table top (beyond the tolerance).
pub const MAX_BELOW_TABLE: f64 = 0.002;

/// How one later pass was found.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct PassReport {
    /// The pass (2, 3, …).
    pub pass: u32,
    /// Its views.
    pub views: usize,
    /// Its frame → the first pass's frame.
    pub motion: Pose,
    /// The motion's rotation, degrees, and translation, model units.
    pub turned_deg: f64,
    /// The motion's translation length.
    pub moved: f64,
    /// The global search.
    pub global: GlobalReport,
    /// Share of its polish samples on the earlier passes.
    pub overlap: f64,
    /// Their RMS point-to-plane distance, model units.
    pub residual_rms: f64,
    /// The tolerance the residual was held to, model units.
    pub residual_limit: f64,
    /// Share of its points below the first pass's table top, and of the earlier passes' below its own
    /// (beyond the tolerance); absent when the passes are not in table frames.
    pub below_table: Option<(f64, f64)>,
    /// Seconds it took.
    pub seconds: f64,
}

/// An oriented cloud owned: points and normals in one frame.
#[derive(Default)]
struct Cloud {
    points: Vec<[f32; 3]>,
    normals: Vec<[f32; 3]>,
}

impl Cloud {
    fn of(&self) -> Oriented<'_> {
        Oriented { points: &self.points, normals: &self.normals }
    }

    fn add(&mut self, view: &View, normals: &[V3], pose: &Pose) {
        self.points.extend(placed(&view.points, pose));
        self.normals.extend(normals.iter().map(|n| pose.apply_dir(*n).map(|c| c as f32)));
    }
}

/// Share of `points` more than `tol` below the table top of a frame whose up and height are `up`, `at`.
fn below(points: &[[f32; 3]], up: V3, at: f64, tol: f64) -> f64 {
    let n = points.iter().filter(|p| dot(wide(**p), up) < at - tol).count();
    n as f64 / points.len().max(1) as f64
}

/// Find every later pass's frame in the first's (see the module docs): the poses of all views in the first
/// pass's frame, and a report per later pass. `normals[k]` are view k's normals in its own frame; `noise`
/// the views' RMS noise. A scan set of one pass comes back as given.
///
/// # Errors
/// `reconstruct.views-disagree` naming the pass that cannot be found or does not fit, and why.
pub fn align_passes(views: &[View], normals: &[Vec<V3>], noise: f64) -> Result<(Vec<Pose>, Vec<PassReport>)> {
    let mut poses: Vec<Pose> = views.iter().map(|v| v.pose).collect();
    let last = views.iter().map(|v| v.pass).max().unwrap_or(1);
    let mut reports = Vec::new();
    if last <= 1 {
        return Ok((poses, reports));
    }
    let mut b = Aabb::EMPTY;
    views.iter().flat_map(|v| placed(&v.points, &v.pose)).for_each(|p| b.add(wide(p)));
    let voxel = POLISH_VOXEL_REL * b.diagonal();
    let table = views.iter().all(|v| v.table_frame);
    let mut earlier = Cloud::default();
    for (k, v) in views.iter().enumerate().filter(|(_, v)| v.pass == 1) {
        earlier.add(v, &normals[k], &poses[k]);
    }
    for pass in 2..=last {
        let t0 = std::time::Instant::now();
        let members: Vec<usize> = (0..views.len()).filter(|&k| views[k].pass == pass).collect();
        let mut this = Cloud::default();
        for &k in &members {
            this.add(&views[k], &normals[k], &views[k].pose);
        }
        let refuse = |why: String| {
            Error::new(
                ErrorCode::ReconstructViewsDisagree,
                format!("pass {pass} ({} views) does not fit the passes before it: {why}", members.len()),
            )
            .with_hint("was the same object turned over between the passes, and does each pass see much of what the others saw?")
        };
        let opts = GlobalOptions { seed: u64::from(pass), ..Default::default() };
        let (coarse, report) = global::align(earlier.of(), this.of(), &opts).map_err(|e| refuse(e.message))?;
        let (motion, overlap, residual_rms) = global::polish(earlier.of(), this.of(), coarse, voxel);
        let residual_limit = PASS_NOISE_FACTOR * noise + 0.1 * voxel;
        if overlap < MIN_PASS_OVERLAP {
            return Err(refuse(format!(
                "{:.1} % of it lies on them (at least {:.0} % is needed)",
                100.0 * overlap,
                100.0 * MIN_PASS_OVERLAP
            )));
        }
        if residual_rms > residual_limit {
            return Err(refuse(format!(
                "RMS distance {residual_rms:.3e} to them, above {PASS_NOISE_FACTOR} × the views' noise {noise:.3e} (limit {residual_limit:.3e})"
            )));
        }
        let moved_points: Vec<[f32; 3]> =
            this.points.iter().map(|p| motion.apply(wide(*p)).map(|c| c as f32)).collect();
        let below_table = table.then(|| {
            // Its points below the first pass's table (z = 0 there), and the earlier passes' below its own
            // table (its z = 0, moved by the motion).
            let up = motion.apply_dir([0.0, 0.0, 1.0]);
            let at = dot(up, motion.translation);
            (
                below(&moved_points, [0.0, 0.0, 1.0], 0.0, residual_limit.max(voxel)),
                below(&earlier.points, up, at, residual_limit.max(voxel)),
            )
        });
        if let Some((a, c)) = below_table
            && a.max(c) > MAX_BELOW_TABLE
        {
            return Err(refuse(format!(
                "aligned so, {:.2} % of it lies below the first pass's table top and {:.2} % of the earlier passes below its own: the object would pass through a table",
                100.0 * a,
                100.0 * c
            )));
        }
        for &k in &members {
            poses[k] = motion.then_after(&views[k].pose);
        }
        for &m in &members {
            earlier.add(&views[m], &normals[m], &poses[m]);
        }
        let (turned_deg, moved) = motion.difference(&Pose::IDENTITY);
        let seconds = t0.elapsed().as_secs_f64();
        tracing::info!(pass, turned_deg, overlap, residual_rms, seconds, "pass aligned");
        reports.push(PassReport {
            pass,
            views: members.len(),
            motion,
            turned_deg,
            moved,
            global: report,
            overlap,
            residual_rms,
            residual_limit,
            below_table,
            seconds,
        });
    }
    Ok((poses, reports))
}

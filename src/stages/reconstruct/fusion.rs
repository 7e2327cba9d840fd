//! Range-scan fusion: the views of a scan set placed by their poses, registered against each other, and
//! merged into one oriented cloud.
//!
//! Steps ([`fuse`]):
//! 0. a scan set of several passes (the object turned over between them) has each later pass found in the
//!    first pass's frame by its geometry ([`super::passes`]), or refused naming the pass;
//! 1. each view's normals are estimated within the view (PCA over its own neighbours, in its own frame) and
//!    turned toward its scanner (the view's +z, or its scanner's position where known: E57; see
//!    [`crate::geometry::io::scanset`]);
//! 2. each view's fit to the others is measured at the given poses: overlap share and RMS point-to-plane
//!    residual to the nearest agreeing point of another view within [`OVERLAP_SPACINGS`];
//! 3. the poses are refined by multi-view point-to-plane ICP ([`super::register`]) and measured again: only
//!    the views that do not fit ([`MISFIT_FACTOR`]) move while the others hold the frame, unless the views'
//!    median residual exceeds [`GLOBAL_FACTOR`] × their own noise (then all but the first). The
//!    refined poses are kept only when they fit better: pooled RMS residual down by at least
//!    [`MIN_IMPROVEMENT`] with no fewer pairs. Good poses are never degraded: when ICP cannot improve them
//!    measurably the given ones stay, and the report says which were used and why;
//! 4. a view that still does not fit (residual above [`REJECT_FACTOR`] × the views' median, or almost no
//!    overlap where the others overlap well) is left out and named; one without overlap in a set where no
//!    view overlaps much cannot be checked and is used, named as unverified. More than half left out, or a
//!    set of three or more views whose median overlap share is below [`MIN_OVERLAP`], is
//!    `reconstruct.views-disagree`;
//! 5. the kept views form one cloud. Each point has a confidence: the cosine between its normal and the
//!    direction to its scanner, zero on its view's edge ([`EDGE_SHIFT`]). Registration weights its pairs by
//!    it; the fused cloud drops a point whose confidence is below [`DROP_CONFIDENCE`] of the best among its
//!    neighbours from all views (grazing and edge points where another view saw the surface head-on).

use super::normals::{Neighbours, pca_normals_and_spread};
use super::register::{self, Fit, Refinement, ViewCloud};
use crate::error::{Error, ErrorCode, Result};
use crate::geometry::io::scanset::{View, placed};
use crate::geometry::mesh::PointCloud;
use crate::geometry::points::PointIndex;
use crate::geometry::pose::Pose;
use crate::geometry::vec3::{V3, add, dot, norm, scale, sub, wide};

pub use register::OVERLAP_SPACINGS;

/// Neighbours for a view's normals.
const VIEW_NEIGHBOURS: usize = 12;

/// Refined poses are kept when the pooled RMS residual drops by at least this share.
pub const MIN_IMPROVEMENT: f64 = 0.02;

/// A view whose residual exceeds this many times the median of the views' residuals does not fit.
pub const REJECT_FACTOR: f64 = 3.0;

/// Below this overlap share a view is not checked by the others.
pub const MIN_OVERLAP: f64 = 0.05;

/// Settings of [`fuse`].
#[derive(Clone, Debug)]
pub struct FuseOptions {
    /// Refine the poses by multi-view ICP.
    pub refine: bool,
}

impl Default for FuseOptions {
    fn default() -> Self {
        FuseOptions { refine: true }
    }
}

/// How one view fits the others.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ViewReport {
    /// The view's name.
    pub name: String,
    /// Its points.
    pub points: usize,
    /// Share of its points within [`OVERLAP_SPACINGS`] of an agreeing point of another view, at the poses used.
    pub overlap_share: f64,
    /// RMS point-to-plane residual of those points (input units) at the poses used; `null` without overlap.
    pub residual_rms: Option<f64>,
    /// The same two at the given poses.
    pub given: Fit,
    /// The same two at the refined poses (absent without refinement).
    pub refined: Option<Fit>,
    /// How far refinement moved the view: rotation (degrees) and translation (input units).
    pub moved_deg: f64,
    /// Translation of the refinement.
    pub moved: f64,
    /// `fits`, `unverified` (no overlap to check it by) or `rejected` (left out of the cloud).
    pub status: &'static str,
}

/// What fusion did.
#[derive(Clone, Debug, serde::Serialize)]
pub struct FusionReport {
    /// Views, in the order listed.
    pub views: Vec<ViewReport>,
    /// Points of the fused cloud.
    pub points: usize,
    /// Whether the refined poses were used.
    pub refined: bool,
    /// Why the given or the refined poses were used.
    pub decision: String,
    /// The registration's course (absent when not run).
    pub registration: Option<Refinement>,
    /// Pooled RMS residual over all views at the given poses, and at the refined ones.
    pub pooled_residual: (Option<f64>, Option<f64>),
    /// Views left out, by name.
    pub rejected: Vec<String>,
    /// The poses used, by view.
    pub poses: Vec<Pose>,
    /// Points dropped from the fused cloud for low relative confidence ([`DROP_CONFIDENCE`]).
    pub low_confidence_dropped: usize,
    /// Each later pass's alignment onto the first (empty for a scan set of one pass).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub passes: Vec<super::passes::PassReport>,
}

/// A view whose residual exceeds this many times the median, or whose overlap is below 1/this of the
/// median, is refined against the others, which stay.
pub const MISFIT_FACTOR: f64 = 1.5;

/// All views are refined (the first holding the frame) when the views' median residual exceeds this many
/// times their own noise (their neighbourhoods' RMS distance from their planes): the Stanford bunny's
/// `bun.conf` poses, which Stanford's zippered model was built from, give 2.5 × (0.163 mm against 0.066 mm); refining
/// all ten from there lowered the pooled residual by 5 % but moved views by up to 0.41° and 0.67 mm and
/// took the result from 0.0245 % to 0.0545 % of the diagonal off the zippered bunny.
pub const GLOBAL_FACTOR: f64 = 4.0;

/// Which views registration may move: the misfits alone (the views that fit hold the frame), or, when the
/// whole set is off its noise level, all but the first.
fn movable_views(fits: &[Fit], noise: f64) -> Vec<bool> {
    let med_res = median(fits.iter().filter_map(|f| f.residual_rms).collect());
    if med_res.is_some_and(|r| r > GLOBAL_FACTOR * noise) {
        return (0..fits.len()).map(|k| k > 0).collect();
    }
    let med_overlap = median(fits.iter().map(|f| f.overlap_share).collect()).unwrap_or(0.0);
    let mut movable: Vec<bool> = fits
        .iter()
        .map(|f| match (f.residual_rms, med_res) {
            (Some(r), Some(m)) => r > MISFIT_FACTOR * m || f.overlap_share * MISFIT_FACTOR < med_overlap,
            _ => med_overlap > MIN_OVERLAP,
        })
        .collect();
    if movable.iter().all(|&m| m) {
        movable[0] = false;
    }
    movable
}

/// A point whose neighbours' centroid lies farther than this share of its neighbourhood radius from it is on
/// the view's edge, where range scanners are least reliable (edge curl, mixed pixels).
pub const EDGE_SHIFT: f64 = 0.3;

/// Each point's confidence: its incidence cosine toward the scanner (the normal's z in the view's frame),
/// zero on the view's edge.
fn confidences(view: &View, nb: &Neighbours, normals: &[V3]) -> Vec<f32> {
    let points = &view.points;
    (0..points.len())
        .map(|i| {
            let ids = nb.of(i);
            let c = scale(ids.iter().fold([0.0; 3], |s, &j| add(s, wide(points[j as usize]))), 1.0 / ids.len() as f64);
            let edge = norm(sub(c, wide(points[i]))) > EDGE_SHIFT * nb.radius[i];
            if edge { 0.0 } else { dot(normals[i], view.toward_scanner(wide(points[i]))).abs() as f32 }
        })
        .collect()
}

/// Each fused point's confidence over the best confidence among its [`CONFIDENCE_NEIGHBOURS`] nearest fused
/// points (1 where none has any).
fn relative_confidence(positions: &[[f32; 3]], conf: &[f32]) -> Vec<f32> {
    use rayon::prelude::*;
    let index = PointIndex::new(positions, super::INDEX_POINTS_PER_CELL);
    (0..positions.len())
        .into_par_iter()
        .map_init(Vec::new, |buf, i| {
            index.knn(wide(positions[i]), CONFIDENCE_NEIGHBOURS, buf);
            let best = buf.iter().map(|&(j, _)| conf[j as usize]).fold(0.0f32, f32::max);
            if best > 0.0 { conf[i] / best } else { 1.0 }
        })
        .collect()
}

/// Neighbours compared by [`relative_confidence`].
pub const CONFIDENCE_NEIGHBOURS: usize = 16;

/// A fused point whose confidence is below this share of the best among its neighbours is dropped: where a
/// view saw the surface head-on, another's grazing or edge points there only add noise. Where a point is
/// the best there is (often at the edge of what any view saw, where the surface gets bridged) it stays.
/// Measured (bun_zipper → ours on the bunny; the fused sphere and the turntable torus of
/// `tests/reconstruct.rs`, RMS to the exact surface): keeping all 0.0249 % / 0.054 % / 0.020 %; dropping
/// below 0.2: 0.0228 / 0.064 / 0.022; 0.3: 0.0226 / 0.064 / 0.023; 0.4: 0.0222 / 0.085 / 0.022. Weighting
/// the Poisson samples by confidence instead (absolute or relative) was worse on every one: a sample's
/// weight scales its share of the normal field, so uneven weights shift the surface (sphere 0.31 %).
pub const DROP_CONFIDENCE: f32 = 0.3;

/// Pooled RMS residual and pair count over all views.
fn pooled(fits: &[Fit]) -> (Option<f64>, usize) {
    let pairs: usize = fits.iter().map(|f| f.pairs).sum();
    let ss: f64 = fits.iter().map(|f| f.residual_rms.unwrap_or(0.0).powi(2) * f.pairs as f64).sum();
    ((pairs > 0).then(|| (ss / pairs as f64).sqrt()), pairs)
}

fn median(mut v: Vec<f64>) -> Option<f64> {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied()
}

/// Each view in its own frame: its point index, mean spacing, normal spread (noise), normals turned toward
/// its scanner, and per-point confidence.
struct ViewPrep<'a> {
    indexes: Vec<PointIndex<'a>>,
    spacings: Vec<f64>,
    spreads: Vec<f64>,
    normals: Vec<Vec<V3>>,
    confidence: Vec<Vec<f32>>,
}

impl<'a> ViewPrep<'a> {
    /// # Errors
    /// `reconstruct.too-few-points` for a view with no more than [`VIEW_NEIGHBOURS`] points.
    fn of(views: &'a [View]) -> Result<Self> {
        let mut normals: Vec<Vec<V3>> = Vec::with_capacity(views.len());
        let mut spacings = Vec::with_capacity(views.len());
        let mut spreads = Vec::with_capacity(views.len());
        let mut confidence: Vec<Vec<f32>> = Vec::with_capacity(views.len());
        let indexes: Vec<PointIndex> =
            views.iter().map(|v| PointIndex::new(&v.points, super::INDEX_POINTS_PER_CELL)).collect();
        for (v, idx) in views.iter().zip(&indexes) {
            if v.points.len() <= VIEW_NEIGHBOURS {
                return Err(Error::new(
                    ErrorCode::ReconstructTooFewPoints,
                    format!("view {} has {} points", v.name, v.points.len()),
                ));
            }
            let nb = Neighbours::new(idx, &v.points, VIEW_NEIGHBOURS);
            spacings.push(nb.mean_nearest(&v.points));
            let (n, spread) = pca_normals_and_spread(&v.points, &nb);
            let toward = |i: usize| v.toward_scanner(wide(v.points[i]));
            normals.push(
                n.into_iter()
                    .enumerate()
                    .map(|(i, n)| if dot(n, toward(i)) < 0.0 { n.map(|c| -c) } else { n })
                    .collect(),
            );
            spreads.push(spread);
            confidence.push(confidences(v, &nb, normals.last().unwrap()));
        }
        Ok(ViewPrep { indexes, spacings, spreads, normals, confidence })
    }
}

/// The views disagree when three or more barely overlap (their poses cannot be checked) or more than half
/// of them were rejected.
///
/// # Errors
/// `reconstruct.views-disagree`, naming the rejected views.
fn check_views_agree(views: usize, med_overlap: f64, rejected: &[String]) -> Result<()> {
    if views >= 3 && med_overlap < MIN_OVERLAP {
        return Err(Error::new(
            ErrorCode::ReconstructViewsDisagree,
            format!(
                "the {} views barely overlap (median overlap share {:.3}): their poses cannot be checked",
                views, med_overlap
            ),
        )
        .with_hint("check the scan set's poses (or the turntable axis calibration)"));
    }
    if 2 * rejected.len() > views {
        return Err(Error::new(
            ErrorCode::ReconstructViewsDisagree,
            format!("{} of {} views do not fit the others: {}", rejected.len(), views, rejected.join(", ")),
        )
        .with_hint("check the scan set's poses (or the turntable axis calibration)"));
    }
    Ok(())
}

/// Fuse `views` into one cloud with normals facing each view's scanner (see the module docs).
///
/// # Errors
/// `reconstruct.too-few-points` for a view with fewer than 13 points; `reconstruct.views-disagree` when more
/// than half the views do not fit (named).
pub fn fuse(views: &[View], opts: &FuseOptions) -> Result<(PointCloud, FusionReport)> {
    // 1. Each view in its own frame: index, spacing, normals toward its scanner (+z).
    let ViewPrep { indexes, spacings, spreads, normals, confidence } = ViewPrep::of(views)?;
    let clouds: Vec<ViewCloud> = (0..views.len())
        .map(|k| ViewCloud {
            points: &views[k].points,
            normals: &normals[k],
            index: &indexes[k],
            spacing: spacings[k],
            confidence: &confidence[k],
        })
        .collect();
    let noise = (spreads.iter().map(|s| s * s).sum::<f64>() / spreads.len() as f64).sqrt();
    // 2. Later passes found in the first's frame (a scan set of one pass: the poses as given), then the fit
    //    at those poses.
    let (given_poses, passes) = super::passes::align_passes(views, &normals, noise)?;
    let given = register::fits(&clouds, &given_poses, OVERLAP_SPACINGS);
    let (given_rms, given_pairs) = pooled(&given);
    let movable = movable_views(&given, noise);
    // 3. Refinement, kept only when it fits measurably better.
    let (mut poses, mut used, mut refined_fits, mut registration, mut refined_rms) =
        (given_poses.clone(), given.clone(), None, None, None);
    let mut refined = false;
    let decision = if !opts.refine {
        "refinement switched off: the given poses".to_string()
    } else if views.len() < 2 {
        "one view: nothing to register".to_string()
    } else if !movable.iter().any(|&m| m) {
        format!(
            "given poses kept: every view fits the others within {MISFIT_FACTOR} × their median residual, which \
             is within {GLOBAL_FACTOR} × the views' own noise {noise:.3e}"
        )
    } else {
        let mut p = given_poses.clone();
        let course = register::refine(&clouds, &mut p, &movable);
        let after = register::fits(&clouds, &p, OVERLAP_SPACINGS);
        let (after_rms, after_pairs) = pooled(&after);
        refined_rms = after_rms;
        let better = match (given_rms, after_rms) {
            (None, Some(_)) => after_pairs > 0,
            (Some(g), Some(a)) => a < g * (1.0 - MIN_IMPROVEMENT) && after_pairs as f64 >= 0.98 * given_pairs as f64,
            _ => false,
        };
        let fmt = |r: Option<f64>| r.map_or("none".to_string(), |r| format!("{r:.3e}"));
        let d = format!(
            "pooled residual {} over {} pairs given, {} over {} pairs refined ({} sweeps)",
            fmt(given_rms),
            given_pairs,
            fmt(after_rms),
            after_pairs,
            course.sweeps
        );
        registration = Some(course);
        refined_fits = Some(after.clone());
        if better {
            (poses, used, refined) = (p, after, true);
            format!("refined poses: {d}")
        } else {
            format!("given poses kept (refinement did not fit better by {:.0} %): {d}", 100.0 * MIN_IMPROVEMENT)
        }
    };
    // 4. Judge each view at the poses used.
    let med_res = median(used.iter().filter_map(|f| f.residual_rms).collect());
    let med_overlap = median(used.iter().map(|f| f.overlap_share).collect()).unwrap_or(0.0);
    let mut reports = Vec::with_capacity(views.len());
    let mut rejected = Vec::new();
    for (k, v) in views.iter().enumerate() {
        let f = used[k];
        let off = match (f.residual_rms, med_res) {
            (Some(r), Some(m)) => r > REJECT_FACTOR * m && r > 0.5 * spacings[k],
            _ => false,
        };
        let status = if f.overlap_share < MIN_OVERLAP {
            if med_overlap >= 4.0 * MIN_OVERLAP { "rejected" } else { "unverified" }
        } else if off {
            "rejected"
        } else {
            "fits"
        };
        if status == "rejected" {
            rejected.push(v.name.clone());
        }
        let (moved_deg, moved) = poses[k].difference(&given_poses[k]);
        reports.push(ViewReport {
            name: v.name.clone(),
            points: v.points.len(),
            overlap_share: f.overlap_share,
            residual_rms: f.residual_rms,
            given: given[k],
            refined: refined_fits.as_ref().map(|r| r[k]),
            moved_deg,
            moved,
            status,
        });
    }
    check_views_agree(views.len(), med_overlap, &rejected)?;
    for name in &rejected {
        tracing::warn!(view = %name, "a view does not fit the others and is left out");
    }
    // 5. One cloud of the kept views, weighted by confidence relative to the best nearby.
    let (mut positions, mut fused_normals, mut conf) = (Vec::new(), Vec::new(), Vec::new());
    for (k, v) in views.iter().enumerate() {
        if reports[k].status == "rejected" {
            continue;
        }
        positions.extend(placed(&v.points, &poses[k]));
        fused_normals.extend(normals[k].iter().map(|n| poses[k].apply_dir(*n).map(|c| c as f32)));
        conf.extend_from_slice(&confidence[k]);
    }
    let relative = relative_confidence(&positions, &conf);
    let keep = |k: usize| relative[k] >= DROP_CONFIDENCE;
    let kept: Vec<usize> = (0..positions.len()).filter(|&k| keep(k)).collect();
    let low_confidence_dropped = positions.len() - kept.len();
    let positions: Vec<[f32; 3]> = kept.iter().map(|&k| positions[k]).collect();
    let fused_normals: Vec<[f32; 3]> = kept.iter().map(|&k| fused_normals[k]).collect();
    let points = positions.len();
    let cloud = PointCloud::new(positions, Some(fused_normals), None)?;
    Ok((
        cloud,
        FusionReport {
            views: reports,
            points,
            refined,
            decision,
            registration,
            pooled_residual: (given_rms, refined_rms),
            rejected,
            poses,
            low_confidence_dropped,
            passes,
        },
    ))
}

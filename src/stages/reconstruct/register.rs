//! Multi-view registration: point-to-plane ICP of each view against all the others (Chen & Medioni 1992;
//! the multi-view sweep of Pulli 1999), iterated until the poses stop moving.
//!
//! Every view keeps its points, normals and index in its own frame; only the poses change, so a query maps a
//! point into the other view's frame instead of re-indexing. A sweep visits the movable views in order
//! (Gauss–Seidel: each sees the others' newest poses; the fixed views hold the frame) and for each solves
//! the linearised 6×6 least-squares step over its correspondences:
//!
//! - a correspondence is the nearest point of any other view within the reach whose normal agrees within
//!   [`NORMAL_AGREEMENT_DEG`]; its residual is the distance along that normal;
//! - a pair counts with the product of its points' confidences (incidence cosines, zero on a view's edge) and
//!   residuals are weighted by Tukey's biweight at [`TUKEY_C`] robust standard deviations (MAD), so
//!   outliers and the edges of the overlap do not pull;
//! - directions of motion the overlap does not constrain (a view of a sphere turning about its centre, a
//!   plane sliding in itself) are left alone: the step is solved in the eigenbasis of the normal matrix and
//!   only along eigenvalues above [`CONSTRAINED_SHARE`] of the largest.
//!
//! The reach shrinks from [`INITIAL_REACH_SPACINGS`] to [`OVERLAP_SPACINGS`] mean spacings
//! (×0.7 per sweep), so coarse poses find their overlap and fine ones do not pair across nearby sheets.
//! Deterministic: points are sampled by a fixed stride and sums are taken in order.

use nalgebra::{Matrix6, SymmetricEigen, Vector3, Vector6};
use rayon::prelude::*;

use crate::geometry::points::PointIndex;
use crate::geometry::pose::{Pose, axis_angle};
use crate::geometry::vec3::{Aabb, V3, add, cross, dot, norm, norm2, scale, sub, wide};

/// Overlap reach, in mean point spacings of the view (what fusion counts as overlap, and where the
/// registration's reach ends).
pub const OVERLAP_SPACINGS: f64 = 3.0;

/// Correspondences must have normals within this angle (degrees): the two views' normals both face their
/// scanners, so on a shared surface they agree; across a thin wall they do not.
pub const NORMAL_AGREEMENT_DEG: f64 = 45.0;

/// Tukey's biweight constant in robust standard deviations (95 % efficiency under Gaussian noise).
pub const TUKEY_C: f64 = 4.685;

/// Eigenvalues of the step's normal matrix below this share of the largest are unconstrained directions.
pub const CONSTRAINED_SHARE: f64 = 1e-3;

/// The first sweep's reach, in mean spacings of the view (poses off by a few spacings still pair).
pub const INITIAL_REACH_SPACINGS: f64 = 12.0;

/// Points per view sampled for a sweep's correspondences (by a fixed stride).
pub const SAMPLES_PER_VIEW: usize = 4000;

/// Fewest correspondences for a view to move.
pub const MIN_CORRESPONDENCES: usize = 50;

/// Most sweeps over all views.
pub const MAX_SWEEPS: usize = 60;

/// The poses have stopped when no view moved more than this share of its mean spacing in a sweep (motion of
/// a view: rotation × its radius plus translation).
pub const STILL_SPACINGS: f64 = 0.01;

/// A view as registration sees it, all in its own frame.
pub struct ViewCloud<'a> {
    /// Points.
    pub points: &'a [[f32; 3]],
    /// Unit normals, facing the scanner.
    pub normals: &'a [V3],
    /// Index over `points`.
    pub index: &'a PointIndex<'a>,
    /// Mean distance to the nearest neighbour.
    pub spacing: f64,
    /// Confidence of each point in [0, 1]: how much its pairs count.
    pub confidence: &'a [f32],
}

/// One pairing: the view's point and the other view's point and normal, in the common frame.
#[derive(Clone, Copy)]
struct Pair {
    p: V3,
    q: V3,
    n: V3,
    /// Confidence of the pair: the product of the two points' incidence cosines toward their scanners.
    c: f64,
}

impl Pair {
    fn residual(&self) -> f64 {
        dot(sub(self.p, self.q), self.n)
    }
}

/// How far each view is from the others: overlap share and RMS point-to-plane residual, over every point.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct Fit {
    /// Share of the view's points with a correspondence within the reach.
    pub overlap_share: f64,
    /// RMS residual of those points (input units); `None` without overlap.
    pub residual_rms: Option<f64>,
    /// Points with a correspondence.
    pub pairs: usize,
}

/// What [`refine`] did.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Refinement {
    /// Sweeps run.
    pub sweeps: usize,
    /// Whether the poses stopped moving before [`MAX_SWEEPS`].
    pub converged: bool,
    /// Largest motion of a view in the last sweep, in its mean spacings.
    pub last_motion_spacings: f64,
}

/// The nearest agreeing point of another view within `reach` of view `a`'s point `p` (common frame).
fn pair(views: &[ViewCloud], poses: &[Pose], boxes: &[Aabb], a: usize, i: usize, reach: f64) -> Option<Pair> {
    let p = poses[a].apply(wide(views[a].points[i]));
    let n = poses[a].apply_dir(views[a].normals[i]);
    let cos = NORMAL_AGREEMENT_DEG.to_radians().cos();
    let mut best: Option<(f64, Pair)> = None;
    for (b, v) in views.iter().enumerate() {
        let bx = &boxes[b];
        if b == a || (0..3).any(|k| p[k] < bx.min[k] - reach || p[k] > bx.max[k] + reach) {
            continue;
        }
        let local = poses[b].inverse_apply(p);
        let Some((j, d2)) = v.index.nearest_within(local, reach) else { continue };
        if best.as_ref().is_some_and(|(bd, _)| *bd <= d2) {
            continue;
        }
        let nq = poses[b].apply_dir(v.normals[j as usize]);
        if dot(nq, n) < cos {
            continue;
        }
        let c = f64::from(views[a].confidence[i]) * f64::from(v.confidence[j as usize]);
        best = Some((d2, Pair { p, q: poses[b].apply(wide(v.points[j as usize])), n: nq, c }));
    }
    best.map(|(_, pr)| pr)
}

/// A view's box in the common frame.
fn view_box(v: &ViewCloud, pose: &Pose) -> Aabb {
    let mut b = Aabb::EMPTY;
    v.points.iter().for_each(|&p| b.add(pose.apply(wide(p))));
    b
}

/// The views' boxes in the common frame.
fn boxes(views: &[ViewCloud], poses: &[Pose]) -> Vec<Aabb> {
    views.iter().zip(poses).map(|(v, pose)| view_box(v, pose)).collect()
}

/// How each view fits the others at `poses`, over all its points, with the reach `reach_spacings` × its
/// spacing. Cost: O(n · views) nearest-point queries, pruned by the views' boxes.
pub fn fits(views: &[ViewCloud], poses: &[Pose], reach_spacings: f64) -> Vec<Fit> {
    let boxes = boxes(views, poses);
    (0..views.len())
        .map(|a| {
            let v = &views[a];
            let reach = reach_spacings * v.spacing;
            let res: Vec<Option<f64>> = (0..v.points.len())
                .into_par_iter()
                .map(|i| pair(views, poses, &boxes, a, i, reach).map(|pr| pr.residual()))
                .collect();
            let within: Vec<f64> = res.into_iter().flatten().collect();
            Fit {
                overlap_share: within.len() as f64 / v.points.len().max(1) as f64,
                residual_rms: (!within.is_empty())
                    .then(|| (within.iter().map(|e| e * e).sum::<f64>() / within.len() as f64).sqrt()),
                pairs: within.len(),
            }
        })
        .collect()
}

/// Refine in place the poses of the views marked `movable`; the others stay and hold the frame (keep at least
/// one fixed). Sweeps of point-to-plane ICP until no view moves more than [`STILL_SPACINGS`] of its spacing,
/// or [`MAX_SWEEPS`]. The caller judges the result ([`fits`] before and after). Cost: per sweep,
/// [`SAMPLES_PER_VIEW`] queries per movable view against every overlapping view.
pub fn refine(views: &[ViewCloud], poses: &mut [Pose], movable: &[bool]) -> Refinement {
    let mut last = f64::INFINITY;
    for sweep in 0..MAX_SWEEPS {
        let reach_spacings = (INITIAL_REACH_SPACINGS * 0.7f64.powi(sweep as i32)).max(OVERLAP_SPACINGS);
        let mut worst: f64 = 0.0;
        // Only the view that just moved changes its box.
        let mut boxes = boxes(views, poses);
        for a in (0..views.len()).filter(|&a| movable[a]) {
            let moved = step(views, poses, &boxes, a, reach_spacings * views[a].spacing);
            boxes[a] = view_box(&views[a], &poses[a]);
            worst = worst.max(moved / views[a].spacing);
        }
        last = worst;
        tracing::debug!(sweep, reach_spacings, worst_motion_spacings = worst, "registration sweep");
        let settled = reach_spacings <= OVERLAP_SPACINGS;
        if settled && worst < STILL_SPACINGS {
            return Refinement { sweeps: sweep + 1, converged: true, last_motion_spacings: worst };
        }
    }
    Refinement { sweeps: MAX_SWEEPS, converged: false, last_motion_spacings: last }
}

/// One ICP step of view `a`; returns how far it moved (rotation × radius + translation).
fn step(views: &[ViewCloud], poses: &mut [Pose], boxes: &[Aabb], a: usize, reach: f64) -> f64 {
    let v = &views[a];
    let stride = v.points.len().div_ceil(SAMPLES_PER_VIEW).max(1);
    // 1. Correspondences, in order.
    let pairs: Vec<Pair> = (0..v.points.len())
        .into_par_iter()
        .step_by(stride)
        .filter_map(|i| pair(views, poses, boxes, a, i, reach))
        .collect();
    if pairs.len() < MIN_CORRESPONDENCES {
        return 0.0;
    }
    // 2. Robust scale (MAD) and Tukey weights.
    let mut abs: Vec<f64> = pairs.iter().map(|p| p.residual().abs()).collect();
    abs.sort_by(f64::total_cmp);
    let sigma = (1.4826 * abs[abs.len() / 2]).max(1e-3 * v.spacing);
    let c = TUKEY_C * sigma;
    // 3. The normal equations about the pairs' centroid, rotation scaled by the radius for conditioning.
    let centre = scale(pairs.iter().fold([0.0; 3], |s, p| add(s, p.p)), 1.0 / pairs.len() as f64);
    let radius =
        (pairs.iter().map(|p| norm2(sub(p.p, centre))).sum::<f64>() / pairs.len() as f64).sqrt().max(v.spacing);
    let mut ata = Matrix6::<f64>::zeros();
    let mut atb = Vector6::<f64>::zeros();
    for pr in &pairs {
        let r = pr.residual();
        if r.abs() >= c {
            continue;
        }
        let w = (1.0 - (r / c).powi(2)).powi(2) * pr.c;
        let m = scale(cross(sub(pr.p, centre), pr.n), 1.0 / radius);
        let j = Vector6::new(m[0], m[1], m[2], pr.n[0], pr.n[1], pr.n[2]);
        ata += w * j * j.transpose();
        atb += w * r * j;
    }
    // 4. Solve along the constrained directions only.
    let eig = SymmetricEigen::new(ata);
    let top = eig.eigenvalues.iter().cloned().fold(0.0, f64::max);
    if top <= 0.0 {
        return 0.0;
    }
    let mut x = Vector6::<f64>::zeros();
    for k in 0..6 {
        let l = eig.eigenvalues[k];
        if l > CONSTRAINED_SHARE * top {
            let u = eig.eigenvectors.column(k);
            x -= u * (u.dot(&atb) / l);
        }
    }
    // 5. Apply: rotate by ω about the centre, then translate by τ.
    let omega = Vector3::new(x[0], x[1], x[2]) / radius;
    let tau = [x[3], x[4], x[5]];
    let angle = omega.norm();
    let rot = if angle > 0.0 {
        axis_angle([omega[0] / angle, omega[1] / angle, omega[2] / angle], angle)
    } else {
        Pose::IDENTITY.rotation
    };
    poses[a] = Pose::about(rot, centre, tau).then_after(&poses[a]);
    angle * radius + norm(tau)
}

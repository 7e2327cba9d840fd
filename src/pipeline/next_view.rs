//! Next best views: after a pass, which surface has no view seen, and which stops of the table (turn and
//! tilt) would see most of it.
//!
//! 1. [`estimate`] fuses the views taken so far (a scan set directory), reconstructs a coarse closed surface
//!    from them, and marks each of its vertices seen or not, as the fusion report measures coverage
//!    ([`super::reconstruct::fused_seen_by`]: a view's point within three spacings). It also measures the
//!    scanner's field of view from the views themselves (the widest point of every view, per image axis), so
//!    nothing about the optics needs configuring.
//! 2. [`choose`] predicts, for every candidate stop, which vertices seen by fewer than
//!    [`NextViewOptions::need`] views it would see: inside the measured frustum, facing the scanner within
//!    [`NextViewOptions::grazing_deg`], the ray to the scanner free of the surface and of the table's plate.
//!    Then it picks greedily: the stop that adds the most ([`Estimate::seen_share`]: each view up to `need`
//!    counts for its share of a vertex's area), that counted, again, until the predicted share reaches the
//!    target, the budget is spent, or no stop adds [`NextViewOptions::min_gain`].
//!
//! Plain functions over data; deterministic (candidates in a fixed order, ties to the first).

use std::path::Path;

use rayon::prelude::*;

use crate::error::{Error, ErrorCode, Result};
use crate::geometry::bvh::TriangleBvh;
use crate::geometry::io::ReadOptions;
use crate::geometry::mesh::{Geometry, TriMesh};
use crate::geometry::pose::Pose;
use crate::geometry::vec3::{V3, add, dot, norm, scale, sub, wide};
use crate::stages::reconstruct::fusion::FuseOptions;
use crate::stages::reconstruct::{ReconstructOptions, reconstruct};

/// What the views taken so far saw of a coarse surface reconstructed from them.
#[derive(Clone, Debug)]
pub struct Estimate {
    /// The surface, in the frame of the scan set's last pass (the table frame the next views are posed in;
    /// the first pass's for a scan of one pass).
    pub mesh: TriMesh,
    /// Per vertex: the views that saw it.
    pub counts: Vec<u16>,
    /// Per vertex: its share of the surface's area (a third of each triangle around it; sums to 1).
    pub area: Vec<f64>,
    /// Share of the area the views saw, as the fusion report measures it (one view is enough).
    pub coverage: f64,
    /// The scanner's field of view measured on the views: the largest `|x / z|` and `|y / z|` of their points.
    pub frustum: [f64; 2],
}

/// How [`choose`] picks.
#[derive(Clone, Debug, PartialEq)]
pub struct NextViewOptions {
    /// Stop when the predicted coverage reaches this share (0–1).
    pub target: f64,
    /// Most views to pick.
    pub budget: usize,
    /// A stop that would see less than this share of the area is not worth a view.
    pub min_gain: f64,
    /// A surface turned further than this from the scanner counts as unseen, degrees (the simulated scanner
    /// loses points from 60° on, all of them past 80°: at 65° three in four are kept).
    pub grazing_deg: f64,
    /// Views a surface needs to count as seen for choosing: a surface one view saw at a grazing angle is
    /// sampled thinly and noisily, and Poisson then bends it; a second view measures it (with 1, spot's
    /// solid was 0.09 % RMS from the truth at 0.99 coverage; see `tests/scan.rs`).
    pub need: u16,
    /// The table's plate: a disc of this radius about the axis in the table's plane hides what lies beyond
    /// it from below; `None`: the whole plane does.
    pub plate_radius: Option<f64>,
}

impl Default for NextViewOptions {
    /// Coverage 0.99, 12 views, 0.1 % of the area per view at least, 65° grazing, two views each, no plate
    /// known.
    fn default() -> Self {
        NextViewOptions { target: 0.99, budget: 12, min_gain: 0.001, grazing_deg: 65.0, need: 2, plate_radius: None }
    }
}

/// A stop [`choose`] picked.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct NextView {
    /// Table angle, degrees.
    pub angle_deg: f64,
    /// Cradle tilt, degrees.
    pub tilt_deg: f64,
    /// The share of the surface's area it is predicted to see first.
    pub predicted_gain: f64,
}

/// For choosing, a vertex counts as seen by a view with a point within this many point spacings: tighter
/// than the coverage's [`super::reconstruct::COVERAGE_SPACINGS`], so thinly sampled surface asks for
/// another view.
pub const SEEN_SPACINGS: f64 = 1.5;

/// Grid resolution of the coarse surface (nodes along the longest side): a tenth of a percent of the
/// diagonal is not needed to find where the views did not reach.
pub const ESTIMATE_RESOLUTION: usize = 128;

/// Fuse the views of the scan set `dir`, reconstruct a coarse surface and mark what the views saw of it.
/// Cost: the fusion and a Poisson solve at [`ESTIMATE_RESOLUTION`] (seconds for a few hundred thousand points).
///
/// # Errors
/// The scan set's reading and fusion errors; `reconstruct.failed` when no surface results.
pub fn estimate(dir: &Path, memory_budget: u64) -> Result<Estimate> {
    let fuse = FuseOptions::default();
    let (geometry, fused) = super::reconstruct::read_input_views(dir, &ReadOptions::default(), &fuse)?;
    let (Geometry::Cloud(cloud), Some(fused)) = (geometry, fused) else {
        return Err(Error::new(ErrorCode::InputNoGeometry, format!("{} is not a scan set", dir.display())));
    };
    let opts = ReconstructOptions {
        resolution: ESTIMATE_RESOLUTION,
        project: false,
        split: Some(0),
        memory_budget,
        ..Default::default()
    };
    let (mesh, _) = reconstruct(&cloud, &opts, &crate::stages::NoProgress)?;
    if mesh.triangles.is_empty() {
        return Err(Error::new(ErrorCode::ReconstructFailed, "no surface from the views taken so far"));
    }
    let (counts, _) = super::reconstruct::seen_within(&mesh, &fused, SEEN_SPACINGS);
    let coverage = super::reconstruct::fused_coverage(&mesh, &fused).share;
    let mut frustum = [0.0f64; 2];
    for p in fused.views.iter().flat_map(|v| &v.points) {
        let z = -f64::from(p[2]);
        if z > 0.0 {
            frustum[0] = frustum[0].max(f64::from(p[0]).abs() / z);
            frustum[1] = frustum[1].max(f64::from(p[1]).abs() / z);
        }
    }
    let area = super::reconstruct::vertex_area_shares(&mesh);
    // Fused in the first pass's frame; the next views are taken in the last pass's: the surface moved there
    // (the inverse of the motion fusion found for that pass).
    let mut mesh = mesh;
    if let Some(last) = fused.report.passes.last() {
        for p in &mut mesh.positions {
            *p = last.motion.inverse_apply(p.map(f64::from)).map(|c| c as f32);
        }
    }
    Ok(Estimate { counts, mesh, area, coverage, frustum })
}

/// The scanner at one stop, in the surface's frame.
struct Camera {
    eye: V3,
    axes: [V3; 3],
}

impl Camera {
    /// From the stop's pose (scanner frame → table frame; the scanner looks down its −z from its origin).
    fn of(pose: &Pose) -> Camera {
        let axes = [pose.apply_dir([1.0, 0.0, 0.0]), pose.apply_dir([0.0, 1.0, 0.0]), pose.apply_dir([0.0, 0.0, 1.0])];
        Camera { eye: pose.apply([0.0; 3]), axes }
    }

    /// Whether the scanner sees the point `p` with unit normal `n` (`eps`: the offset off the surface the
    /// occlusion ray starts at).
    fn sees(&self, (p, n): (V3, V3), est: &Estimate, (bvh, eps): (&TriangleBvh, f64), opts: &NextViewOptions) -> bool {
        let d = sub(self.eye, p);
        let len = norm(d);
        let depth = dot(d, self.axes[2]);
        if !(len > 0.0 && depth > 0.0) {
            return false;
        }
        let [fx, fy] = est.frustum;
        if dot(d, self.axes[0]).abs() > fx * depth || dot(d, self.axes[1]).abs() > fy * depth {
            return false;
        }
        let dir = scale(d, 1.0 / len);
        if dot(n, dir) < opts.grazing_deg.to_radians().cos() {
            return false;
        }
        // The plate: the segment from the point up to an eye below the table's plane crosses it.
        if self.eye[2] < 0.0 && p[2] >= 0.0 {
            let t = p[2] / (p[2] - self.eye[2]);
            let (x, y) = (p[0] + t * d[0], p[1] + t * d[1]);
            if opts.plate_radius.is_none_or(|r| x.hypot(y) <= r) {
                return false;
            }
        }
        bvh.ray_first(add(p, scale(n, eps)), dir, eps, len).is_none()
    }
}

impl Estimate {
    /// The share of the area seen, each vertex counting `min(views that saw it, need) / need` of its area: what
    /// [`choose`] raises to its target.
    pub fn seen_share(&self, need: u16) -> f64 {
        let need = need.max(1);
        self.counts.iter().zip(&self.area).map(|(&c, &a)| a * f64::from(c.min(need)) / f64::from(need)).sum()
    }
}

/// Pick the next views among `candidates` (turn, tilt: degrees; `pose_of` gives a stop's pose, scanner frame
/// → the estimate's frame), greedily, as the module says. Cost: one ray cast per unseen vertex and candidate
/// (in parallel over the candidates), then O(candidates × picks) to pick.
pub fn choose(
    est: &Estimate,
    candidates: &[(f64, f64)],
    pose_of: &(dyn Fn(f64, f64) -> Pose + Sync),
    opts: &NextViewOptions,
) -> Vec<NextView> {
    let positions: Vec<V3> = est.mesh.positions.iter().map(|&p| wide(p)).collect();
    let faces: Vec<Vec<u32>> = est.mesh.triangles.iter().map(|t| t.to_vec()).collect();
    let normals = crate::geometry::polygon::vertex_normals(&positions, &faces);
    let need = opts.need.max(1);
    let unseen: Vec<usize> = (0..est.counts.len()).filter(|&v| est.counts[v] < need && est.area[v] > 0.0).collect();
    let bvh = TriangleBvh::new(&est.mesh);
    let eps = 1e-4 * est.mesh.bbox().diagonal();
    let sees: Vec<Vec<usize>> = candidates
        .par_iter()
        .map(|&(a, t)| {
            let cam = Camera::of(&pose_of(a, t));
            (0..unseen.len())
                .filter(|&i| {
                    let v = unseen[i];
                    cam.sees((wide(est.mesh.positions[v]), normals[v]), est, (&bvh, eps), opts)
                })
                .collect()
        })
        .collect();
    // Views each unseen vertex has, predicted; each view up to `need` adds 1/need of its area.
    let mut have: Vec<u16> = unseen.iter().map(|&v| est.counts[v]).collect();
    let mut used = vec![false; candidates.len()];
    let mut coverage = est.seen_share(need);
    let step = |v: usize| est.area[v] / f64::from(need);
    let mut picked = Vec::new();
    while coverage < opts.target && picked.len() < opts.budget {
        let gain = |c: usize| sees[c].iter().filter(|&&i| have[i] < need).map(|&i| step(unseen[i])).sum::<f64>();
        let best = (0..candidates.len()).filter(|&c| !used[c]).map(|c| (c, gain(c))).fold(
            None,
            |b: Option<(usize, f64)>, x| match b {
                Some(b) if b.1 >= x.1 => Some(b),
                _ => Some(x),
            },
        );
        let Some((c, g)) = best.filter(|b| b.1 >= opts.min_gain) else { break };
        used[c] = true;
        for &i in &sees[c] {
            have[i] = (have[i] + 1).min(need);
        }
        coverage += g;
        picked.push(NextView { angle_deg: candidates[c].0, tilt_deg: candidates[c].1, predicted_gain: g });
    }
    picked
}

/// The stops a table can reach, in a fixed order: every `angle_step` degrees around, at tilt 0 and, for a
/// tilting table (`tilt_range`), every `tilt_step` degrees across its range.
pub fn candidates(angle_step: f64, tilt_range: Option<(f64, f64)>, tilt_step: f64) -> Vec<(f64, f64)> {
    let mut tilts = vec![0.0];
    if let Some((lo, hi)) = tilt_range {
        let mut t = (lo / tilt_step).ceil() * tilt_step;
        while t <= hi + 1e-9 {
            if t != 0.0 {
                tilts.push(t);
            }
            t += tilt_step;
        }
    }
    let turns = (360.0 / angle_step).round().max(1.0) as usize;
    tilts.iter().flat_map(|&t| (0..turns).map(move |i| (i as f64 * 360.0 / turns as f64, t))).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A unit sphere standing on the table (centre at z = 1) whose lower part (z < 0.5) no view saw, the
    /// scanner 6 units away on a tilting table: the first pick looks from below the table's plane past a
    /// small plate; a plate twice as wide as the sphere hides that part from every stop below the plane.
    #[test]
    fn the_pick_looks_where_no_view_looked() {
        use crate::geometry::pose::axis_angle;
        let mesh = crate::geometry::shapes::icosphere(1.0, 4, [0.0, 0.0, 1.0]);
        let counts: Vec<u16> = mesh.positions.iter().map(|p| if p[2] >= 0.5 { 2 } else { 0 }).collect();
        let area = crate::pipeline::reconstruct::vertex_area_shares(&mesh);
        let unseen_area: f64 = (0..counts.len()).filter(|&v| counts[v] == 0).map(|v| area[v]).sum();
        let est = Estimate { mesh, counts, area, coverage: 1.0 - unseen_area, frustum: [0.3, 0.3] };
        assert!((est.seen_share(2) - est.coverage).abs() < 1e-12);
        // Scanner frame → table frame at a stop: the scanner at (0, −6, 1) looking along +y (its −z), turned
        // back by the table's angle about z and the cradle's tilt about x.
        let pose_of = |a: f64, t: f64| {
            let look = Pose::about(axis_angle([1.0, 0.0, 0.0], 90f64.to_radians()), [0.0; 3], [0.0, -6.0, 1.0]);
            let tilt = Pose::about(axis_angle([1.0, 0.0, 0.0], -t.to_radians()), [0.0; 3], [0.0; 3]);
            let turn = Pose::about(axis_angle([0.0, 0.0, 1.0], -a.to_radians()), [0.0; 3], [0.0; 3]);
            turn.then_after(&tilt).then_after(&look)
        };
        let below = |v: &NextView| Camera::of(&pose_of(v.angle_deg, v.tilt_deg)).eye[2] < 0.0;
        let cands = candidates(45.0, Some((-60.0, 60.0)), 30.0);
        assert_eq!(cands.len(), 5 * 8);
        let opts = NextViewOptions { plate_radius: Some(0.3), ..Default::default() };
        let picked = choose(&est, &cands, &pose_of, &opts);
        assert!(!picked.is_empty() && below(&picked[0]), "the first pick looks from below: {picked:?}");
        assert!(picked[0].predicted_gain > 0.1 * unseen_area, "{picked:?} of {unseen_area}");
        assert!(picked.windows(2).all(|w| w[0].predicted_gain >= w[1].predicted_gain), "{picked:?}");
        let wide = NextViewOptions { plate_radius: Some(2.0), ..Default::default() };
        let none = choose(&est, &cands, &pose_of, &wide);
        assert!(none.iter().all(|v| !below(v)), "a wide plate hides it from below: {none:?}");
    }
}

//! Range-scan fusion: the views of a scan set placed by their poses into one oriented cloud. Each view's
//! normals are estimated within the view (PCA over its own neighbours) and turned toward its scanner, whose
//! direction is known from the pose (Stanford's convention: the scanner looks down the view's −z axis, so a
//! visible surface faces +z in the view's frame). Each view's residual against the others is measured
//! (point-to-plane distance to the nearest point of another view, where the views overlap), so a view that
//! does not fit is seen. Pose refinement (multi-view ICP) is not done yet: the report says so.

use rayon::prelude::*;

use super::normals::{Neighbours, pca_normals};
use crate::error::{Error, ErrorCode, Result};
use crate::geometry::io::scanset::View;
use crate::geometry::mesh::PointCloud;
use crate::geometry::points::PointIndex;
use crate::geometry::vec3::{V3, dot, sub, wide};

/// How one view fits the others.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ViewReport {
    /// The view's name.
    pub name: String,
    /// Its points.
    pub points: usize,
    /// Share of its points within [`OVERLAP_SPACINGS`] of another view's point.
    pub overlap_share: f64,
    /// RMS point-to-plane distance of those points to the nearest point of another view (its normal's
    /// plane), in the input's units; `null` without overlap.
    pub residual_rms: Option<f64>,
}

/// What fusion did.
#[derive(Clone, Debug, serde::Serialize)]
pub struct FusionReport {
    /// Views, in the order listed.
    pub views: Vec<ViewReport>,
    /// Points of the fused cloud.
    pub points: usize,
    /// Whether the poses were refined (multi-view ICP); not yet implemented, so always false.
    pub refined: bool,
}

/// Overlap reach, in mean point spacings of the view.
pub const OVERLAP_SPACINGS: f64 = 3.0;

/// Neighbours for a view's normals.
const VIEW_NEIGHBOURS: usize = 12;

/// Fuse `views` into one cloud with normals facing each view's scanner.
///
/// # Errors
/// `reconstruct.too-few-points` for a view with fewer than [`VIEW_NEIGHBOURS`] + 1 points.
pub fn fuse(views: &[View]) -> Result<(PointCloud, FusionReport)> {
    // 1. Each view in the common frame, with normals toward its scanner.
    let mut placed: Vec<(Vec<[f32; 3]>, Vec<V3>, f64)> = Vec::with_capacity(views.len());
    for v in views {
        if v.points.len() <= VIEW_NEIGHBOURS {
            return Err(Error::new(
                ErrorCode::ReconstructTooFewPoints,
                format!("view {} has {} points", v.name, v.points.len()),
            ));
        }
        let world = v.placed();
        let nb = Neighbours::new(&PointIndex::new(&world, super::INDEX_POINTS_PER_CELL), &world, VIEW_NEIGHBOURS);
        let toward = v.dir_to_world([0.0, 0.0, 1.0]);
        let spacing = nb.mean_nearest(&world);
        let normals: Vec<V3> = pca_normals(&world, &nb)
            .into_iter()
            .map(|n| if dot(n, toward) < 0.0 { n.map(|c| -c) } else { n })
            .collect();
        placed.push((world, normals, spacing));
    }
    // 2. Residuals: each view against every other.
    let indexes: Vec<PointIndex> =
        placed.iter().map(|(w, _, _)| PointIndex::new(w, super::INDEX_POINTS_PER_CELL)).collect();
    let mut reports = Vec::with_capacity(views.len());
    for (a, (world, _, spacing)) in placed.iter().enumerate() {
        let reach = OVERLAP_SPACINGS * spacing;
        let hits: Vec<Option<f64>> = world
            .par_iter()
            .map(|&p| {
                let p = wide(p);
                let mut best: Option<(f64, f64)> = None;
                for (b, idx) in indexes.iter().enumerate() {
                    if b == a {
                        continue;
                    }
                    if let Some((j, d2)) = idx.nearest_within(p, reach)
                        && best.is_none_or(|(bd, _)| d2 < bd)
                    {
                        let (q, n) = (wide(placed[b].0[j as usize]), placed[b].1[j as usize]);
                        best = Some((d2, dot(sub(p, q), n)));
                    }
                }
                best.map(|(_, e)| e)
            })
            .collect();
        let within: Vec<f64> = hits.iter().flatten().copied().collect();
        reports.push(ViewReport {
            name: views[a].name.clone(),
            points: world.len(),
            overlap_share: within.len() as f64 / world.len() as f64,
            residual_rms: (!within.is_empty())
                .then(|| (within.iter().map(|e| e * e).sum::<f64>() / within.len() as f64).sqrt()),
        });
    }
    // 3. One cloud.
    let mut positions = Vec::new();
    let mut normals = Vec::new();
    for (w, n, _) in placed {
        positions.extend(w);
        normals.extend(n.into_iter().map(|v| v.map(|c| c as f32)));
    }
    let points = positions.len();
    let cloud = PointCloud::new(positions, Some(normals), None)?;
    Ok((cloud, FusionReport { views: reports, points, refined: false }))
}

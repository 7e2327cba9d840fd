//! Error maps: the TEST surface with each vertex's distance to the REFERENCE as a scalar and a colour.

use std::path::Path;

use crate::error::Result;
use crate::geometry::io::{FileDigest, VertexAttributes, write_ply, write_ply_cloud};
use crate::geometry::mesh::Geometry;
use crate::geometry::stats::percentile;
use crate::stages::quality::vertex_distances;

/// Colour ramp blue → cyan → green → yellow → red for `t` in [0, 1] (clamped; NaN is magenta).
pub fn color_ramp(t: f64) -> [u8; 3] {
    if t.is_nan() {
        return [255, 0, 255];
    }
    const STOPS: [[f64; 3]; 5] =
        [[0.0, 0.0, 255.0], [0.0, 255.0, 255.0], [0.0, 255.0, 0.0], [255.0, 255.0, 0.0], [255.0, 0.0, 0.0]];
    let x = t.clamp(0.0, 1.0) * 4.0;
    let i = (x.floor() as usize).min(3);
    let f = x - i as f64;
    [0, 1, 2].map(|k| (STOPS[i][k] + (STOPS[i + 1][k] - STOPS[i][k]) * f).round() as u8)
}

/// Colour of invented surface (caps and fills that no scan saw) on an error map: neutral grey.
pub const INVENTED_GREY: [u8; 3] = [160, 160, 160];

/// What [`write_error_map`] wrote.
#[derive(Clone, Debug)]
pub struct ErrorMapFile {
    /// The colour scale's top (red), input units.
    pub scale: f64,
    /// The file's size and SHA-256.
    pub digest: FileDigest,
    /// Each vertex's distance to the reference, input units.
    pub distances: Vec<f64>,
}

/// Write `test` as a binary PLY with per-vertex `distance` (to `reference`, in input units) and a colour
/// ramp from 0 (blue) to the 99th percentile of the vertex distances (red; larger values clamp to red).
/// Vertices marked in `invented` (surface no scan saw) are neutral grey (`INVENTED_GREY`) instead, and left out of the
/// percentile; the file's comment says so. Returns the colour-scale top, the file's digest and the distances.
///
/// # Errors
/// As [`vertex_distances`]; `resource.output` when the file cannot be written.
pub fn write_error_map(
    path: &Path,
    test: &Geometry,
    reference: &Geometry,
    invented: Option<&[bool]>,
) -> Result<ErrorMapFile> {
    let d = vertex_distances(test, reference)?;
    let is_invented = |i: usize| invented.is_some_and(|m| m.get(i).copied().unwrap_or(false));
    let mut tmp: Vec<f64> = (0..d.len()).filter(|&i| !is_invented(i)).map(|i| d[i]).collect();
    let top = percentile(&mut tmp, 0.99).max(f64::MIN_POSITIVE);
    let colors: Vec<[u8; 3]> =
        (0..d.len()).map(|i| if is_invented(i) { INVENTED_GREY } else { color_ramp(d[i] / top) }).collect();
    let scalar: Vec<f32> = d.iter().map(|&x| x as f32).collect();
    let marked = (0..d.len()).filter(|&i| is_invented(i)).count();
    let mut comment = format!("scanstation error map: distance to reference; colour scale 0 (blue) .. {top:.6e} (red)");
    if marked > 0 {
        comment.push_str(&format!("; grey: invented surface (caps and fills no scan saw), {marked} vertices"));
    }
    let attrs = VertexAttributes { colors: Some(&colors), scalar: Some(("distance", &scalar)), normals: None };
    let digest = match test {
        Geometry::Mesh(m) => write_ply(path, m, &attrs, &[&comment])?,
        Geometry::Cloud(c) => {
            let bare = crate::geometry::mesh::PointCloud {
                positions: c.positions.clone(),
                normals: c.normals.clone(),
                colors: None,
            };
            write_ply_cloud(path, &bare, &attrs, &[&comment])?
        }
    };
    Ok(ErrorMapFile { scale: top, digest, distances: d })
}

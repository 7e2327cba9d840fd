//! The deviation map's data: each vertex's **signed** distance to a reference surface (positive outside it,
//! along its outward normal) and the diverging colour scale the map paints it with (blue inside, red
//! outside, a neutral tolerance band around zero, saturating at a symmetric range).

use rayon::prelude::*;

use crate::geometry::bvh::TriangleBvh;
use crate::geometry::mesh::TriMesh;
use crate::geometry::vec3::{cross, dot, sub, wide};

/// The scale's ends and its middle (ColorBrewer's RdBu, colour-blind safe): inside, neutral, outside.
pub const DEVIATION_INSIDE: [u8; 3] = [33, 102, 172];
/// Just past the tolerance band, either side.
pub const DEVIATION_NEAR: [u8; 3] = [247, 247, 247];
/// The far outside end.
pub const DEVIATION_OUTSIDE: [u8; 3] = [178, 24, 43];
/// Within the tolerance band: neutral grey.
pub const DEVIATION_BAND: [u8; 3] = [190, 190, 190];

/// Each vertex of `test`'s signed distance to `reference` (a closed, outward-oriented mesh): the distance
/// to its closest point, positive where the vertex lies on the side the closest triangle's normal points to.
/// Where the closest point is on an edge or corner the sign is that triangle's; such vertices are within
/// about the reference's facet size of its surface. Cost: O(V log F) after an O(F log F) tree.
pub fn signed_vertex_distances(test: &TriMesh, reference: &TriMesh) -> Vec<f64> {
    let bvh = TriangleBvh::new(reference);
    test.positions
        .par_iter()
        .map(|&p| {
            let p = wide(p);
            let Some(c) = bvh.closest(p) else { return f64::NAN };
            let [a, b, d] = reference.triangles[c.index as usize].map(|i| wide(reference.positions[i as usize]));
            let n = cross(sub(b, a), sub(d, a));
            if dot(sub(p, c.point), n) < 0.0 { -c.distance } else { c.distance }
        })
        .collect()
}

/// Unsigned distances `magnitudes` given the sign of `side` (each vertex's [`signed_vertex_distances`] to a
/// closed surface: negative inside): the deviation map's data when the distance is measured to one surface
/// (a scan, possibly open) and the side to another (its closed, repaired form).
pub fn with_side(magnitudes: &[f64], side: &[f64]) -> Vec<f64> {
    magnitudes.iter().zip(side).map(|(&d, &s)| if s < 0.0 { -d } else { d }).collect()
}

/// The colour of a signed deviation `d` on a symmetric scale to `range` (> 0) with a neutral band of half
/// width `band` (0 ≤ band < range): [`DEVIATION_BAND`] within the band, then from [`DEVIATION_NEAR`] at the
/// band's edge to [`DEVIATION_INSIDE`] (d ≤ −range) or [`DEVIATION_OUTSIDE`] (d ≥ range), linearly. NaN is the
/// band's grey.
pub fn deviation_colour(d: f64, range: f64, band: f64) -> [u8; 3] {
    if !(d.abs() > band) {
        return DEVIATION_BAND;
    }
    let t = ((d.abs() - band) / (range - band).max(f64::MIN_POSITIVE)).clamp(0.0, 1.0);
    let end = if d < 0.0 { DEVIATION_INSIDE } else { DEVIATION_OUTSIDE };
    std::array::from_fn(|k| {
        (f64::from(DEVIATION_NEAR[k]) + t * (f64::from(end[k]) - f64::from(DEVIATION_NEAR[k]))).round() as u8
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::raster::{BACKGROUND, View, render};
    use crate::geometry::shapes::icosphere;

    /// A sphere against the same sphere 1 % larger lies 1 % inside it everywhere: every vertex −0.0100 (to
    /// the facets' sag, 5e-6 here), one colour — the inside end of a ±1 % scale — on every vertex, and every
    /// pixel of its render that colour shaded (blue over red, the same hue).
    #[test]
    fn a_sphere_inside_one_one_percent_larger_is_one_colour() {
        let small = icosphere(1.0, 4, [0.0; 3]);
        let large = icosphere(1.01, 4, [0.0; 3]);
        let d = signed_vertex_distances(&small, &large);
        assert!(
            d.iter().all(|&x| (x + 0.01).abs() < 5e-5),
            "{:?}",
            d.iter().fold((1.0f64, -1.0f64), |m, &x| (m.0.min(x), m.1.max(x)))
        );
        let colours: Vec<[u8; 3]> = d.iter().map(|&x| deviation_colour(x, 0.01, 0.001)).collect();
        assert!(
            colours.iter().all(|&c| c == DEVIATION_INSIDE),
            "{:?}",
            colours.iter().find(|&&c| c != DEVIATION_INSIDE)
        );
        let out = signed_vertex_distances(&large, &small);
        assert!(out.iter().all(|&x| x > 0.0099), "the larger sphere lies outside the smaller");
        let img = render(&small, &colours, &View::front([0.0, 1.0, 0.0]), 160, 160);
        for p in img.rgb.chunks(3).filter(|p| *p != BACKGROUND) {
            assert!(p[2] > p[1] && p[1] > p[0], "a shade of the inside colour: {p:?}");
        }
    }

    #[test]
    fn the_scale_is_symmetric_with_a_neutral_band() {
        assert_eq!(deviation_colour(0.0005, 0.01, 0.001), DEVIATION_BAND);
        assert_eq!(deviation_colour(-0.001, 0.01, 0.001), DEVIATION_BAND);
        assert_eq!(deviation_colour(f64::NAN, 0.01, 0.001), DEVIATION_BAND);
        assert_eq!(deviation_colour(0.02, 0.01, 0.001), DEVIATION_OUTSIDE);
        assert_eq!(deviation_colour(-0.02, 0.01, 0.001), DEVIATION_INSIDE);
        let (a, b) = (deviation_colour(0.0055, 0.01, 0.001), deviation_colour(-0.0055, 0.01, 0.001));
        assert!(a[0] > a[2] && b[2] > b[0], "half way: reddish {a:?}, bluish {b:?}");
        assert_eq!(deviation_colour(0.0010001, 0.01, 0.001), DEVIATION_NEAR);
    }
}

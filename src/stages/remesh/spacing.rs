//! The spacing field: the local thickness of the working mesh, and a spacing per working vertex that is finer
//! on thin parts and narrow gaps ([`THIN_RATIO`]) or where the direct result missed the input
//! ([`REFINE_FACTOR`]), graded so the lattice bends gently.

use std::time::Instant;

use rayon::prelude::*;

use super::hierarchy;
use super::report::RemeshReport;
use super::settings::*;
use crate::geometry::bvh::TriangleBvh;
use crate::geometry::mesh::TriMesh;
use crate::geometry::vec3::{self, V3, sub};

/// [`thickness`], its time added to the report's `thickness` seconds.
pub(super) fn timed_thickness(
    level: &hierarchy::Level,
    p: &[V3],
    tris: &[[u32; 3]],
    reach: f64,
    report: &mut RemeshReport,
) -> Vec<f64> {
    let t0 = Instant::now();
    let t = thickness(level, p, tris, reach);
    *report.seconds.entry("thickness".into()).or_insert(0.0) += t0.elapsed().as_secs_f64();
    t
}

/// Thickness at each vertex of `level` (the working mesh `p`, `tris`): the shorter of the ray along −n to
/// the far side of the part and the ray along n across a gap to the surface facing back; infinite beyond
/// `reach`. Cost: two bounded ray casts per vertex.
pub(super) fn thickness(level: &hierarchy::Level, p: &[V3], tris: &[[u32; 3]], reach: f64) -> Vec<f64> {
    let positions: Vec<[f32; 3]> = p.iter().map(|x| x.map(|c| c as f32)).collect();
    let work = TriMesh { positions, triangles: tris.to_vec() };
    let bvh = TriangleBvh::new(&work);
    (0..level.len())
        .into_par_iter()
        .map(|i| {
            let (p, n) = (level.p[i], level.n[i]);
            let eps = 1e-4 * reach;
            let inside = bvh.ray_hit(p, vec3::scale(n, -1.0), eps, reach, 1.0);
            let gap = bvh.ray_hit(p, n, eps, reach, -1.0);
            inside.unwrap_or(f64::INFINITY).min(gap.unwrap_or(f64::INFINITY))
        })
        .collect()
}

/// Spacing per vertex for global spacing `s`: `THIN_RATIO · thickness`, clamped between a floor (the larger
/// of [`MIN_SPACING_FACTOR`]·s and [`SPACING_PER_WORK_EDGE`] mean edges of the working mesh at that vertex)
/// and s, then limited to grow by at most [`GRADATION`] per unit distance from any vertex (Gauss–Seidel
/// sweeps of `s_i ≤ s_j + GRADATION·|p_i − p_j|`, alternately forward and backward, until none changes, at most 100).
pub(super) fn spacing_field(level: &hierarchy::Level, thick: &[f64], s: f64) -> Vec<f64> {
    let floor = |i: usize| (MIN_SPACING_FACTOR * s).max(SPACING_PER_WORK_EDGE * mean_edge(level, i)).min(s);
    let sp: Vec<f64> = thick.iter().enumerate().map(|(i, &t)| (THIN_RATIO * t).clamp(floor(i), s)).collect();
    grade(level, sp, s)
}

/// Spacing per vertex for global spacing `s` on the refined direct route: [`REFINE_FACTOR`]·s at the
/// `missed` vertices (not below [`SPACING_PER_WORK_EDGE`] local working edges), graded as in
/// [`spacing_field`].
pub(super) fn refined_spacing(level: &hierarchy::Level, missed: &[bool], s: f64) -> Vec<f64> {
    let sp: Vec<f64> = missed
        .iter()
        .enumerate()
        .map(|(i, &m)| {
            if !m {
                return s;
            }
            (REFINE_FACTOR * s).max(SPACING_PER_WORK_EDGE * mean_edge(level, i)).min(s)
        })
        .collect();
    grade(level, sp, s)
}

/// Mean length of the edges at vertex `i` of `level` (0 for an isolated vertex).
pub(super) fn mean_edge(level: &hierarchy::Level, i: usize) -> f64 {
    let (mut sum, mut k) = (0.0, 0.0);
    for (j, _) in level.neighbours(i) {
        sum += vec3::norm(sub(level.p[i], level.p[j]));
        k += 1.0;
    }
    sum / f64::max(k, 1.0)
}

/// Limit `sp` to grow by at most [`GRADATION`] per unit distance from any vertex.
pub(super) fn grade(level: &hierarchy::Level, mut sp: Vec<f64>, s: f64) -> Vec<f64> {
    if sp.iter().all(|&x| x >= s) {
        return sp;
    }
    let n = level.len();
    for sweep in 0..100 {
        let mut changed = false;
        for k in 0..n {
            let i = if sweep % 2 == 0 { k } else { n - 1 - k };
            for (j, _) in level.neighbours(i) {
                let c = sp[j] + GRADATION * vec3::norm(sub(level.p[i], level.p[j]));
                if c < sp[i] {
                    sp[i] = c;
                    changed = true;
                }
            }
        }
        if !changed {
            break;
        }
    }
    sp
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::shapes::icosphere;
    use crate::geometry::vec3::wide;

    fn finest(m: &TriMesh) -> hierarchy::Level {
        let p: Vec<V3> = m.positions.iter().map(|&x| wide(x)).collect();
        hierarchy::finest_level(&p, &m.triangles)
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(24))]
        /// Invariants of the refined direct route's spacing, for any set of missed vertices: never above
        /// the global spacing, graded (across every edge it changes by at most GRADATION times the edge's
        /// length), and, on this sphere of nearly even edges where every vertex has about the same floor
        /// (REFINE_FACTOR · s or SPACING_PER_WORK_EDGE local edges), never below it and at it on every
        /// missed vertex.
        #[test]
        fn refined_spacing_is_bounded_and_graded(every in 2usize..40, offset in 0usize..40, s in 0.05f64..0.5) {
            let l = finest(&icosphere(1.0, 3, [0.0; 3]));
            let missed: Vec<bool> = (0..l.len()).map(|i| (i + offset) % every == 0).collect();
            let sp = refined_spacing(&l, &missed, s);
            for i in 0..l.len() {
                let floor = (REFINE_FACTOR * s).max(SPACING_PER_WORK_EDGE * mean_edge(&l, i)).min(s);
                proptest::prop_assert!(sp[i] <= s + 1e-12 && sp[i] >= floor.min(s) - 1e-12, "vertex {}: {} (s {}, floor {})", i, sp[i], s, floor);
                if missed[i] {
                    proptest::prop_assert!((sp[i] - floor).abs() < 1e-12, "missed vertex {}: {} not its floor {}", i, sp[i], floor);
                }
                for (j, _) in l.neighbours(i) {
                    let d = vec3::norm(sub(l.p[i], l.p[j]));
                    proptest::prop_assert!(sp[i] <= sp[j] + GRADATION * d + 1e-12, "edge {}–{}: {} vs {} over {}", i, j, sp[i], sp[j], d);
                }
            }
            // Nothing missed: the uniform spacing.
            let none = refined_spacing(&l, &vec![false; l.len()], s);
            proptest::prop_assert!(none.iter().all(|&x| x == s));
        }
    }
}

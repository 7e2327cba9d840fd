//! The spacing field: a spacing per working vertex that is finer on thin parts, narrow gaps and where the
//! surface bends fast (the feature size of [`super::sizing`], times [`THIN_RATIO`]) or where the direct result
//! missed the input ([`REFINE_FACTOR`]), graded so the lattice bends gently.

use std::time::Instant;

use super::hierarchy;
use super::report::RemeshReport;
use super::settings::*;
use super::sizing::Sizing;
use crate::geometry::vec3::{self, V3, sub};

/// A working mesh's thickness (the thin-part guard and the routes' `thin_share` go by it) and feature size
/// (the adaptive split route's spacing follows it: thickness or curvature, [`Sizing::feature_size`]).
pub(super) struct SizeField {
    pub thickness: Vec<f64>,
    pub feature: Vec<f64>,
}

/// The [`SizeField`] of `level` (the working mesh `p`, `tris`; the feature size at the net's spacing `s_net`),
/// its time added to the report's `thickness` seconds; the first one measured also fills the report's
/// `sizing` (its spacing asked at the split routes' spacing `s_split`).
pub(super) fn timed_feature_size(
    level: &hierarchy::Level,
    (p, tris): (&[V3], &[[u32; 3]]),
    reach: f64,
    (s_net, s_split): (f64, f64),
    report: &mut RemeshReport,
) -> SizeField {
    let t0 = Instant::now();
    let sizing = Sizing::measure(level, p, tris, reach);
    let f = sizing.feature_size(s_net);
    let seconds = t0.elapsed().as_secs_f64();
    *report.seconds.entry("thickness".into()).or_insert(0.0) += seconds;
    if report.sizing.is_none() {
        let sp = spacing_field(level, &f, s_split);
        report.sizing = Some(sizing.summary(level, &sp, s_split, seconds));
    }
    SizeField { thickness: sizing.thickness, feature: f }
}

/// Spacing per vertex for global spacing `s`: `THIN_RATIO · feature size`, clamped between a floor (the larger
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
    use crate::geometry::mesh::TriMesh;
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

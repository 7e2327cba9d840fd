//! The working meshes (steps 1–3): the input decimated or subdivided toward a multiple of the target count,
//! its hierarchy and its orientation field, pulled toward the principal curvature directions.

use std::time::Instant;

use super::settings::*;
use super::{field, hierarchy};
use crate::geometry::decimate::{Crossings, decimate};
use crate::geometry::vec3::{self, V3, cross, dot, sub};
use crate::geometry::{linalg, polygon};

/// Mesh `p`, `tris` decimated (QEM) or midpoint-subdivided toward `want` vertices, then its edges longer than
/// `max_edge` split (when it was decimated: longer than [`DECIMATED_LONG_EDGE`]) ([`polygon::split_long_edges`], up to
/// [`WORK_SPLIT_GROWTH`] × `want` vertices), and how
/// ("as-is", "decimated" or "subdivided ×k", with "+N split"). Cost: O(F log F) for the decimation.
pub(super) fn working_mesh(
    mut p: Vec<V3>,
    mut tris: Vec<[u32; 3]>,
    want: usize,
    max_edge: f64,
    seed: u64,
) -> (Vec<V3>, Vec<[u32; 3]>, String) {
    let mut label = "as-is".to_string();
    if p.len() > want * 3 / 2 {
        decimate(&mut p, &mut tris, want, seed, Crossings::Ignore);
        label = "decimated".into();
    } else {
        let mut k = 0;
        while p.len() * 4 <= want * 3 / 2 && k < 4 {
            polygon::subdivide_midpoints(&mut p, &mut tris);
            k += 1;
        }
        if k > 0 {
            label = format!("subdivided ×{k}");
        }
    }
    // A mesh decimated to `want` has about √(want / target) edges a step where the surface bends; one as it
    // is or subdivided may keep long triangles (an in-plane cap): it is split (see WORK_EDGE_SPACINGS). On a
    // flat face the quadric lets decimation keep only the face's rim: there the edges longer than
    // DECIMATED_LONG_EDGE (or `max_edge`, where shorter) are split.
    let (max_edge, passes) = if label != "decimated" {
        (max_edge, WORK_SPLIT_PASSES)
    } else {
        match flat_rims(&p, &tris, want) {
            Some(long) => (max_edge.min(long), DECIMATED_SPLIT_PASSES),
            None => (f64::INFINITY, WORK_SPLIT_PASSES),
        }
    };
    let cap = ((WORK_SPLIT_GROWTH * want as f64) as usize).max(p.len());
    let added = polygon::split_long_edges(&mut p, &mut tris, max_edge, passes, cap);
    if added > 0 {
        label = format!("{label}, +{added} split");
    }
    (p, tris, label)
}

/// When decimation kept only the rims of flat faces (more than [`FLAT_RIM_SHARE`] of the area in triangles
/// with an edge longer than [`DECIMATED_LONG_EDGE`] × √(area / `want`)), that length; `None` otherwise.
fn flat_rims(p: &[V3], tris: &[[u32; 3]], want: usize) -> Option<f64> {
    let area: f64 = tris.iter().map(|&t| vec3::tri_area(p, t)).sum();
    let long = DECIMATED_LONG_EDGE * (area / want.max(1) as f64).sqrt();
    let in_long: f64 = tris
        .iter()
        .filter(|t| (0..3).any(|k| vec3::norm(sub(p[t[k] as usize], p[t[(k + 1) % 3] as usize])) > long))
        .map(|&t| vec3::tri_area(p, t))
        .sum();
    (in_long > FLAT_RIM_SHARE * area).then_some(long)
}

/// A working mesh with its hierarchy and orientation field.
pub(super) struct Work {
    pub(super) p: Vec<V3>,
    pub(super) tris: Vec<[u32; 3]>,
    pub(super) levels: Vec<hierarchy::Level>,
    pub(super) qs: Vec<Vec<V3>>,
    /// "as-is", "decimated" or "subdivided ×k" (with ", +N split").
    pub(super) label: String,
    /// Its long edges were split ([`working_mesh`]): it is near two edges a lattice step.
    pub(super) edges_split: bool,
    pub(super) coherence: Option<f64>,
    pub(super) orientation_singularities: usize,
    pub(super) seconds: Vec<(&'static str, f64)>,
}

impl Work {
    /// The input decimated (QEM) or subdivided toward `per_vertex` × the target vertex count, its hierarchy
    /// and its orientation field. Cost: O(F_in log F_in) for the decimation, O(V_work · iterations) for the
    /// field.
    /// The hierarchy and orientation field of working mesh `p`, `tris` (made by [`working_mesh`]).
    /// Cost: O(V_work · iterations).
    pub(super) fn build(p: Vec<V3>, tris: Vec<[u32; 3]>, label: String, opts: &RemeshOptions) -> Work {
        let mut clock = Instant::now();
        let mut seconds = Vec::new();
        let mut lap = |name: &'static str, seconds: &mut Vec<(&'static str, f64)>| {
            seconds.push((name, clock.elapsed().as_secs_f64()));
            clock = Instant::now();
        };
        let levels = hierarchy::build(&p, &tris);
        lap("hierarchy", &mut seconds);
        let pulls: Option<Vec<_>> = (opts.curvature_weight > 0.0).then(|| {
            levels.iter().map(|l| curvature_directions(l, opts.curvature_weight, opts.coherent_pull)).collect()
        });
        let coherence = pulls.as_ref().map(|b: &Vec<(Vec<(V3, f64)>, f64)>| b[0].1);
        let bias: Option<Vec<Vec<(V3, f64)>>> = pulls.map(|b| b.into_iter().map(|(d, _)| d).collect());
        let qs = field::solve_orientation(&levels, opts.iterations, opts.seed, bias.as_deref());
        let orientation_singularities = orientation_singularities(&levels[0], &qs[0], &tris);
        lap("orientation", &mut seconds);
        let edges_split = label.ends_with(" split");
        Work { p, tris, levels, qs, label, edges_split, coherence, orientation_singularities, seconds }
    }
}

/// Triangles of the working mesh around which the 4-RoSy field has a non-zero index.
pub(super) fn orientation_singularities(level: &hierarchy::Level, q: &[V3], tris: &[[u32; 3]]) -> usize {
    tris.iter()
        .filter(|t| {
            let [a, b, c] = t.map(|v| v as usize);
            let k = |i: usize, j: usize| field::best_rotation(q[i], q[j], level.n[j]);
            // Rotation taking j's representative to i's, composed around a → b → c → a.
            (k(a, b) + k(b, c) + k(c, a)) % 4 != 0
        })
        .count()
}

/// Principal direction of largest |curvature| per vertex with a weight for how anisotropic the curvature
/// is (0 where it is umbilic or flat). Estimated from normal variation along the 1-ring edges.
/// The principal-curvature pull of every vertex of `level`: direction and weight, plus the level's
/// coherence (see [`COHERENT_PULL`]).
///
/// The weight is `weight · a²` where the curvature is clearly anisotropic (`a` = (|k1| − |k2|) / (|k1| + |k2|)
/// above [`ANISOTROPY_MIN`]). Where the principal directions agree almost everywhere (coherence above
/// [`COHERENCE_TRUST_MIN`]: tori, cylinders, surfaces of revolution) they are trusted more: the weight gains
/// `weight · coherent_pull · trust · b²`, with `b` = |k1 − k2| / (|k1| + |k2|) (saddles count too) and
/// `trust` rising from 0 at [`COHERENCE_TRUST_MIN`] to 1 at full coherence. Scans, whose principal directions
/// are coherent only in patches (0.45–0.79 on the shared meshes), get exactly the first term.
///
/// Cost: O(E) for the shape operators, O(E) for the coherence.
pub(super) fn curvature_directions(level: &hierarchy::Level, weight: f64, coherent_pull: f64) -> (Vec<(V3, f64)>, f64) {
    // (direction, weight a², saddle-aware b²)
    let dirs: Vec<(V3, f64, f64)> = (0..level.len())
        .map(|i| {
            let (pi, ni) = (level.p[i], level.n[i]);
            let x = field::tangent_unit([1.0, 0.3, 0.2], ni);
            let y = cross(ni, x);
            // Fit the 2×2 shape operator S from dn ≈ S dp over the ring (least squares via normal equations
            // of the symmetric form [a b; b c]).
            let mut m = [[0.0f64; 3]; 3];
            let mut r = [0.0f64; 3];
            let mut count = 0;
            for (j, _) in level.neighbours(i) {
                let dp = sub(level.p[j], pi);
                let dn = sub(level.n[j], ni);
                let (u, v) = (dot(dp, x), dot(dp, y));
                let (du, dv) = (dot(dn, x), dot(dn, y));
                // du = a u + b v ; dv = b u + c v
                let rows = [([u, v, 0.0], du), ([0.0, u, v], dv)];
                for (a, rhs) in rows {
                    for r0 in 0..3 {
                        for c0 in 0..3 {
                            m[r0][c0] += a[r0] * a[c0];
                        }
                        r[r0] += a[r0] * rhs;
                    }
                }
                count += 1;
            }
            if count < 3 {
                return (x, 0.0, 0.0);
            }
            let largest = m.iter().flatten().map(|x| x.abs()).fold(0.0, f64::max);
            let singular = |d: f64| d.abs() <= 1e-12 * largest.powi(3) || d == 0.0;
            let Some([a, b, c]) = linalg::solve3(m, r, singular) else { return (x, 0.0, 0.0) };
            // Eigen-decomposition of [a b; b c].
            let half_diff = 0.5 * (a - c);
            let disc = (half_diff * half_diff + b * b).sqrt();
            let mean = 0.5 * (a + c);
            let (k1, k2) = (mean + disc, mean - disc);
            let theta = 0.5 * (2.0 * b).atan2(a - c);
            let dir = vec3::add(vec3::scale(x, theta.cos()), vec3::scale(y, theta.sin()));
            // Scale-free: how much one principal curvature dominates (0 umbilic/flat … 1 cylinder-like).
            let scale = k1.abs() + k2.abs() + 1e-30;
            let aniso = (k1.abs() - k2.abs()).abs() / scale;
            let split = (k1 - k2).abs() / scale;
            (dir, if aniso > ANISOTROPY_MIN { aniso * aniso } else { 0.0 }, split * split)
        })
        .collect();
    // Coherence of the principal directions as a cross field: the mean of cos 4Δθ over each ring (1 where
    // neighbours agree up to quarter turns, 0 for random directions), weighted by area and b².
    let (mut num, mut den) = (0.0, 0.0);
    for (i, &(di, _, bi)) in dirs.iter().enumerate() {
        let ni = level.n[i];
        let (mut sum, mut ws) = (0.0, 0.0);
        for (j, w) in level.neighbours(i) {
            let dj = field::tangent_unit(dirs[j].0, ni);
            let c = dot(di, dj).abs().max(dot(di, cross(ni, dj)).abs());
            sum += w * (8.0 * c.powi(4) - 8.0 * c * c + 1.0);
            ws += w;
        }
        if ws > 0.0 {
            num += level.area[i] * bi * (sum / ws).max(0.0);
            den += level.area[i] * bi;
        }
    }
    let coherence = if den > 0.0 { num / den } else { 0.0 };
    let trust = ((coherence - COHERENCE_TRUST_MIN) / (1.0 - COHERENCE_TRUST_MIN)).clamp(0.0, 1.0);
    let out = dirs.into_iter().map(|(d, a2, b2)| (d, weight * (a2 + coherent_pull * trust * b2))).collect();
    (out, coherence)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::mesh::TriMesh;
    use crate::geometry::shapes::{icosphere, torus};
    use crate::geometry::vec3::wide;

    fn finest(m: &TriMesh) -> hierarchy::Level {
        let p: Vec<V3> = m.positions.iter().map(|&x| wide(x)).collect();
        hierarchy::finest_level(&p, &m.triangles)
    }

    /// Analytic oracle: on a torus the principal directions are the ring and tube directions, so they are
    /// coherent (close to 1) and the coherent pull is on; on a sphere (umbilic everywhere) the estimated
    /// directions are noise, the coherence is low and the weights are exactly the plain ones.
    #[test]
    fn principal_directions_are_coherent_on_a_torus_and_not_on_a_sphere() {
        let t = finest(&torus(1.0, 0.4, 120, 48));
        let (pull, coherence) = curvature_directions(&t, 1.0, COHERENT_PULL);
        assert!(coherence > 0.99, "torus coherence {coherence}");
        // On the tube's top circle the ring direction (about ±z × radial) is a principal direction.
        let mut top = 0;
        for (i, &(d, w)) in pull.iter().enumerate() {
            let p = t.p[i];
            if p[2] > 0.399 {
                top += 1;
                let ring = field::tangent_unit([-p[1], p[0], 0.0], t.n[i]);
                let c = dot(d, ring).abs().max(dot(d, cross(t.n[i], ring)).abs());
                assert!(c > 0.99, "vertex {i} at {p:?}: direction {d:?} is {c} from the ring");
                assert!(w > 5.0, "vertex {i}: pull {w}, the coherent term missing");
            }
        }
        assert_eq!(top, 120, "one top-circle vertex per ring step");
        let (off, _) = curvature_directions(&t, 1.0, 0.0);
        assert!(off.iter().all(|&(_, w)| w <= 1.0), "without the coherent pull every weight is a² ≤ 1");
        let s = finest(&icosphere(1.0, 4, [0.0; 3]));
        let (pull, coherence) = curvature_directions(&s, 1.0, COHERENT_PULL);
        let (plain, _) = curvature_directions(&s, 1.0, 0.0);
        assert!(coherence < COHERENCE_TRUST_MIN, "sphere coherence {coherence}");
        assert!(pull.iter().zip(&plain).all(|(a, b)| a.1 == b.1), "sphere: weights changed by the coherent pull");
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(24))]
        /// Invariants: the coherence lies in [0, 1] and does not depend on where the torus sits or how it
        /// is turned (the shape operator is fitted in each vertex's own tangent frame); the weights are
        /// never negative and never below the plain ones.
        #[test]
        fn coherence_is_a_rigid_motion_invariant(
            minor in 0.2f64..0.6,
            angle in 0.0f64..std::f64::consts::TAU,
            shift in -5.0f64..5.0,
        ) {
            let base = torus(1.0, minor, 90, 36);
            let (c, s) = (angle.cos(), angle.sin());
            let mut moved = base.clone();
            for p in &mut moved.positions {
                let (x, y, z) = (p[0] as f64, p[1] as f64, p[2] as f64);
                // A turn about the x axis, then a shift.
                *p = [(x + shift) as f32, (c * y - s * z) as f32, (s * y + c * z + shift) as f32];
            }
            let (w0, c0) = curvature_directions(&finest(&base), 1.0, COHERENT_PULL);
            let (w1, c1) = curvature_directions(&finest(&moved), 1.0, COHERENT_PULL);
            proptest::prop_assert!((0.0..=1.0).contains(&c0), "coherence {}", c0);
            proptest::prop_assert!((c0 - c1).abs() < 1e-3, "coherence {} moved {}", c0, c1);
            let (plain, _) = curvature_directions(&finest(&base), 1.0, 0.0);
            for ((a, b), p) in w0.iter().zip(&w1).zip(&plain) {
                proptest::prop_assert!(a.1 >= p.1 && p.1 >= 0.0, "weight {} below plain {}", a.1, p.1);
                proptest::prop_assert!((a.1 - b.1).abs() < 1e-2 * (1.0 + a.1), "weight {} moved {}", a.1, b.1);
            }
        }
    }
}

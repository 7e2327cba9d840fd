//! Extrinsic 4-RoSy orientation field and 4-PoSy position field (Jakob et al. 2015, §4–5).
//!
//! Each vertex carries a unit tangent `q` (defined up to rotations by 90° about its normal) and a
//! lattice origin `o` in its tangent plane (defined up to integer steps of `scale` along `q` and `n × q`).
//! Both are smoothed by Gauss–Seidel sweeps over colour classes, coarse to fine, comparing neighbours
//! directly in 3D ("extrinsic"), which lets the field follow curvature.

use rayon::prelude::*;

use super::hierarchy::Level;
use crate::geometry::sampling::Rng;
use crate::geometry::vec3::{self, V3, add, cross, dot, scale, sub};

/// Project `v` to the plane with unit normal `n` and normalise; a fallback tangent when `v` ∥ `n`.
#[inline]
pub fn tangent_unit(v: V3, n: V3) -> V3 {
    let t = sub(v, scale(n, dot(n, v)));
    let l = vec3::norm(t);
    if l > 1e-12 {
        return scale(t, 1.0 / l);
    }
    let a = if n[0].abs() < 0.9 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
    let t = cross(n, a);
    scale(t, 1.0 / vec3::norm(t))
}

/// `q` rotated by `k` quarter turns about `n`.
#[inline]
pub fn rotate90(q: V3, n: V3, k: u32) -> V3 {
    match k & 3 {
        0 => q,
        1 => cross(n, q),
        2 => scale(q, -1.0),
        _ => scale(cross(n, q), -1.0),
    }
}

/// Of the 4 representatives of (`q1`, `n1`), the number of quarter turns that best matches `q0`.
#[inline]
pub fn best_rotation(q0: V3, q1: V3, n1: V3) -> u32 {
    let t1 = cross(n1, q1);
    let (a, b) = (dot(q0, q1), dot(q0, t1));
    if a.abs() >= b.abs() {
        if a >= 0.0 { 0 } else { 2 }
    } else if b >= 0.0 {
        1
    } else {
        3
    }
}

/// Among {q0, n0×q0} × {q1, n1×q1}, the best-aligned pair with signs matched.
#[inline]
fn compat_orientation(q0: V3, n0: V3, q1: V3, n1: V3) -> (V3, V3) {
    let a = [q0, cross(n0, q0)];
    let b = [q1, cross(n1, q1)];
    let mut best = (-1.0, 0, 0);
    for (i, ai) in a.iter().enumerate() {
        for (j, bj) in b.iter().enumerate() {
            let s = dot(*ai, *bj).abs();
            if s > best.0 {
                best = (s, i, j);
            }
        }
    }
    let (ai, bj) = (a[best.1], b[best.2]);
    (ai, if dot(ai, bj) < 0.0 { scale(bj, -1.0) } else { bj })
}

/// Gauss–Seidel over colour classes: `iterations` sweeps; within a class every vertex is updated in
/// parallel by `update(i, values)` from the current values (no two vertices of a class are adjacent, so
/// the result does not depend on the thread count).
fn sweep(level: &Level, values: &mut [V3], iterations: usize, update: impl Fn(usize, &[V3]) -> V3 + Sync) {
    for _ in 0..iterations {
        for class in &level.colours {
            let cur: &[V3] = values;
            let updates: Vec<V3> = class.par_iter().map(|&i| update(i as usize, cur)).collect();
            for (&i, u) in class.iter().zip(updates) {
                values[i as usize] = u;
            }
        }
    }
}

/// Smooth the orientation field of `level` in place: `iterations` sweeps. `bias`, when given, pulls each
/// vertex toward a preferred direction with the given weight (principal curvature alignment).
pub fn smooth_orientation(level: &Level, q: &mut [V3], iterations: usize, bias: Option<&[(V3, f64)]>) {
    sweep(level, q, iterations, |i, q| {
        let ni = level.n[i];
        let mut sum = q[i];
        let mut wsum = 0.0;
        let mut step = |qj: V3, nj: V3, w: f64, sum: &mut V3| {
            let (a, b) = compat_orientation(*sum, ni, qj, nj);
            *sum = add(scale(a, wsum), scale(b, w));
            wsum += w;
            *sum = tangent_unit(*sum, ni);
        };
        for (j, w) in level.neighbours(i) {
            step(q[j], level.n[j], w, &mut sum);
        }
        if let Some(bias) = bias {
            let (d, w) = bias[i];
            if w > 0.0 {
                step(d, ni, w, &mut sum);
            }
        }
        sum
    });
}

/// The least-squares point on both tangent planes of an edge (Instant Meshes' `middle_point`).
#[inline]
pub fn middle_point(p0: V3, n0: V3, p1: V3, n1: V3) -> V3 {
    let n0p0 = dot(n0, p0);
    let n0p1 = dot(n0, p1);
    let n1p0 = dot(n1, p0);
    let n1p1 = dot(n1, p1);
    let n0n1 = dot(n0, n1);
    let denom = 1.0 / (1.0 - n0n1 * n0n1 + 1e-4);
    let l0 = 2.0 * (n0p1 - n0p0 - n0n1 * (n1p0 - n1p1)) * denom;
    let l1 = 2.0 * (n1p0 - n1p1 - n0n1 * (n0p1 - n0p0)) * denom;
    sub(scale(add(p0, p1), 0.5), scale(add(scale(n0, l0), scale(n1, l1)), 0.25))
}

/// `x.floor() as i64`, bit for bit (NaN → 0, saturating), without the libm call that `f64::floor` is on
/// baseline x86-64 (3.6 % of the dragon's remesh in a profile).
#[inline]
pub(crate) fn floor_i64(x: f64) -> i64 {
    let t = x as i64;
    if (t as f64) > x { t.saturating_sub(1) } else { t }
}

/// `x.round() as i64` (half away from zero), bit for bit (NaN → 0, saturating), without the libm call.
#[inline]
pub(crate) fn round_i64(x: f64) -> i64 {
    let t = x as i64;
    // Exact: the fractional part of a float is a float (and 0 where |x| ≥ 2⁵², ±∞ only for ±∞).
    let frac = x - t as f64;
    if frac >= 0.5 {
        t.saturating_add(1)
    } else if frac <= -0.5 {
        t.saturating_sub(1)
    } else {
        t
    }
}

/// Integer lattice coordinates (floor) of `p` in the frame (`o`, `q`, `n×q`) with spacing `s`.
#[inline]
fn lattice_floor(o: V3, q: V3, t: V3, p: V3, inv_s: f64) -> [i64; 2] {
    let d = sub(p, o);
    [floor_i64(dot(q, d) * inv_s), floor_i64(dot(t, d) * inv_s)]
}

#[inline]
fn lattice_point(o: V3, q: V3, t: V3, c: [i64; 2], s: f64) -> V3 {
    add(o, add(scale(q, c[0] as f64 * s), scale(t, c[1] as f64 * s)))
}

/// The vertex data one position-compatibility test needs.
#[derive(Copy, Clone, Debug)]
pub struct Frame {
    /// Position.
    pub p: V3,
    /// Normal.
    pub n: V3,
    /// Orientation field's representative direction.
    pub q: V3,
    /// Position field's lattice origin.
    pub o: V3,
    /// Lattice spacing at this vertex (varies slowly where the spacing adapts to thin parts).
    pub s: f64,
}

/// Closest pair of lattice points of two frames near their edge's middle point: their integer coordinates
/// relative to each frame's origin (frame 1 rotated to match frame 0 first; each frame on its own spacing)
/// and the points themselves. Cost: 8 lattice points and 16 distances.
#[inline]
fn compat_position_pair(f0: &Frame, f1: &Frame) -> ([i64; 2], [i64; 2], V3, V3) {
    let q1 = rotate90(f1.q, f1.n, best_rotation(f0.q, f1.q, f1.n));
    let t0 = cross(f0.n, f0.q);
    let t1 = cross(f1.n, q1);
    let m = middle_point(f0.p, f0.n, f1.p, f1.n);
    let b0 = lattice_floor(f0.o, f0.q, t0, m, 1.0 / f0.s);
    let b1 = lattice_floor(f1.o, q1, t1, m, 1.0 / f1.s);
    let corner = |b: [i64; 2], k: i64| [b[0] + (k & 1), b[1] + (k >> 1)];
    let x0s: [V3; 4] = std::array::from_fn(|i| lattice_point(f0.o, f0.q, t0, corner(b0, i as i64), f0.s));
    let x1s: [V3; 4] = std::array::from_fn(|j| lattice_point(f1.o, q1, t1, corner(b1, j as i64), f1.s));
    // The first strictly nearest pair, i outer; (0, 0) when no distance is finite (NaN input).
    let mut best = (f64::INFINITY, 0, 0);
    for (i, x0) in x0s.iter().enumerate() {
        for (j, x1) in x1s.iter().enumerate() {
            let d = vec3::norm2(sub(*x0, *x1));
            if d < best.0 {
                best = (d, i, j);
            }
        }
    }
    let (_, i, j) = best;
    (corner(b0, i as i64), corner(b1, j as i64), x0s[i], x1s[j])
}

/// The integer step from `f0`'s lattice point to `f1`'s in `f0`'s frame, the quarter turns taking `f1`'s
/// cross to `f0`'s, and the rounding residual (continuous offset minus the step, in spacings of `f0`'s
/// frame): the data [`super::integer`] works on.
#[inline]
pub fn compat_position_offset(f0: &Frame, f1: &Frame) -> ([i64; 2], u32, [f64; 2]) {
    let (c0, c1, x0, x1) = compat_position_pair(f0, f1);
    let r = best_rotation(f0.q, f1.q, f1.n);
    let t0 = cross(f0.n, f0.q);
    let g = sub(x1, x0);
    let inv = 2.0 / (f0.s + f1.s);
    ([c0[0] - c1[0], c0[1] - c1[1]], r, [dot(g, f0.q) * inv, dot(g, t0) * inv])
}

#[inline]
fn compat_position(f0: &Frame, f1: &Frame) -> (V3, V3) {
    let (_, _, x0, x1) = compat_position_pair(f0, f1);
    (x0, x1)
}

/// The lattice point of (`o`, `q`) nearest `p` (rounding), within the tangent plane at `p`.
#[inline]
pub fn lattice_round(o: V3, q: V3, n: V3, p: V3, s: f64) -> V3 {
    let t = cross(n, q);
    let d = sub(p, o);
    let inv_s = 1.0 / s;
    let c = [round_i64(dot(q, d) * inv_s), round_i64(dot(t, d) * inv_s)];
    lattice_point(o, q, t, c, s)
}

/// Smooth the position field of `level` in place (`o` holds lattice origins) with lattice spacing `s[i]`
/// at vertex i.
pub fn smooth_position(level: &Level, q: &[V3], o: &mut [V3], s: &[f64], iterations: usize) {
    sweep(level, o, iterations, |i, o| {
        let (pi, ni, qi, si) = (level.p[i], level.n[i], q[i], s[i]);
        let mut sum = o[i];
        let mut wsum = 0.0;
        for (j, w) in level.neighbours(i) {
            let f0 = Frame { p: pi, n: ni, q: qi, o: sum, s: si };
            let f1 = Frame { p: level.p[j], n: level.n[j], q: q[j], o: o[j], s: s[j] };
            let (a, b) = compat_position(&f0, &f1);
            sum = scale(add(scale(a, wsum), scale(b, w)), 1.0 / (wsum + w));
            wsum += w;
            sum = sub(sum, scale(ni, dot(ni, sub(sum, pi))));
        }
        lattice_round(sum, qi, ni, pi, si)
    });
}

/// Solve the orientation field on all levels, coarsest first; returns every level's field, finest first.
pub fn solve_orientation(
    levels: &[Level],
    iterations: usize,
    seed: u64,
    bias: Option<&[Vec<(V3, f64)>]>,
) -> Vec<Vec<V3>> {
    let mut rng = Rng::new(seed);
    let coarse = levels.last().expect("non-empty hierarchy");
    let mut q: Vec<V3> = coarse
        .n
        .iter()
        .map(|&n| tangent_unit([rng.next_f64() - 0.5, rng.next_f64() - 0.5, rng.next_f64() - 0.5], n))
        .collect();
    let mut all = vec![Vec::new(); levels.len()];
    for l in (0..levels.len()).rev() {
        let level = &levels[l];
        if l + 1 < levels.len() {
            q = (0..level.len()).map(|i| tangent_unit(q[level.parent[i] as usize], level.n[i])).collect();
        }
        smooth_orientation(level, &mut q, iterations, bias.map(|b| b[l].as_slice()));
        all[l] = q.clone();
    }
    all
}

/// Solve the position field on all levels (needs each level's orientation `qs[l]` and spacing `s[l]`, one
/// per vertex), coarsest first.
pub fn solve_position(levels: &[Level], qs: &[Vec<V3>], s: &[Vec<f64>], iterations: usize, seed: u64) -> Vec<V3> {
    let mut rng = Rng::new(seed ^ 0x9e37_79b9_7f4a_7c15);
    let last = levels.len() - 1;
    let coarse = &levels[last];
    let mut o: Vec<V3> = (0..coarse.len())
        .map(|i| {
            let (p, n, q) = (coarse.p[i], coarse.n[i], qs[last][i]);
            let t = cross(n, q);
            let s = s[last][i];
            add(p, add(scale(q, (rng.next_f64() - 0.5) * s), scale(t, (rng.next_f64() - 0.5) * s)))
        })
        .collect();
    for l in (0..levels.len()).rev() {
        let level = &levels[l];
        if l < last {
            o = (0..level.len())
                .map(|i| {
                    let op = o[level.parent[i] as usize];
                    let (p, n) = (level.p[i], level.n[i]);
                    sub(op, scale(n, dot(n, sub(op, p))))
                })
                .collect();
        }
        smooth_position(level, &qs[l], &mut o, &s[l], iterations);
    }
    o
}

/// Per-level spacings from the finest level's (`s0`, one per level-0 vertex): a coarse vertex takes the
/// smallest spacing of the fine vertices it stands for, so thin parts stay fine all the way up.
pub fn level_spacings(levels: &[Level], s0: Vec<f64>) -> Vec<Vec<f64>> {
    let mut all = vec![s0];
    for l in 0..levels.len() - 1 {
        let mut next = vec![f64::INFINITY; levels[l + 1].len()];
        for (i, &par) in levels[l].parent.iter().enumerate() {
            let p = par as usize;
            next[p] = next[p].min(all[l][i]);
        }
        all.push(next);
    }
    all
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    proptest! {
        /// The field's inline floor and round are `f64::floor` / `f64::round` then `as i64`, bit for bit,
        /// from tiny to saturating magnitudes, halves and NaN included.
        #[test]
        fn inline_floor_and_round_match_std(m in -1.0e6f64..1.0e6, e in -30i32..70, half in any::<bool>()) {
            use crate::stages::remesh::field::{floor_i64, round_i64};
            let x = if half { (m.trunc() + 0.5).copysign(m) } else { m * 2f64.powi(e) };
            for y in [x, -x, f64::NAN, f64::INFINITY, -f64::INFINITY, 0.49999999999999994, -0.5, -0.0] {
                prop_assert_eq!(floor_i64(y), y.floor() as i64, "floor {}", y);
                prop_assert_eq!(round_i64(y), y.round() as i64, "round {}", y);
            }
        }
    }
}

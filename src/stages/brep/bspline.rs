//! Non-rational cubic B-spline curves and surfaces: evaluation (de Boor), Bézier forms, knot insertion.

use crate::geometry::vec3::{self, V3};

/// Polynomial degree of every curve and surface we write.
pub const DEGREE: usize = 3;

/// Cubic Bernstein basis and its derivative at `t`.
pub fn bernstein(t: f64) -> ([f64; 4], [f64; 4]) {
    let s = 1.0 - t;
    (
        [s * s * s, 3.0 * t * s * s, 3.0 * t * t * s, t * t * t],
        [-3.0 * s * s, 3.0 * s * s - 6.0 * t * s, 6.0 * t * s - 3.0 * t * t, 3.0 * t * t],
    )
}

/// A point on a cubic Bézier curve.
pub fn bezier_point(c: &[V3; 4], t: f64) -> V3 {
    let (b, _) = bernstein(t);
    let mut p = [0.0; 3];
    for i in 0..4 {
        p = vec3::add(p, vec3::scale(c[i], b[i]));
    }
    p
}

/// A clamped cubic B-spline surface: `poles[j * nu + i]` (i along u, j along v), expanded knot vectors
/// (first and last knot repeated 4 times).
#[derive(Clone, Debug, PartialEq)]
pub struct BsplineSurface {
    /// Poles along u.
    pub nu: usize,
    /// Poles along v.
    pub nv: usize,
    /// Poles, u fastest (`poles[j · nu + i]`).
    pub poles: Vec<V3>,
    /// Clamped knot vector in u (`nu + 4` knots).
    pub knots_u: Vec<f64>,
    /// Clamped knot vector in v (`nv + 4` knots).
    pub knots_v: Vec<f64>,
}

/// Distinct knots and their multiplicities of an expanded knot vector.
pub fn knot_multiplicities(knots: &[f64]) -> (Vec<f64>, Vec<u32>) {
    let mut k: Vec<f64> = Vec::new();
    let mut m: Vec<u32> = Vec::new();
    for &x in knots {
        if k.last() == Some(&x) {
            *m.last_mut().unwrap() += 1;
        } else {
            k.push(x);
            m.push(1);
        }
    }
    (k, m)
}

impl BsplineSurface {
    /// The clamped equivalent of a uniform bicubic B-spline with a `(w + 3) × (h + 3)` control grid
    /// (`grid[(w + 3) * j + i]`), on `[0, w] × [0, h]` with simple interior knots (C² inside).
    pub fn from_uniform_grid(grid: &[V3], w: usize, h: usize) -> Self {
        let (gw, gh) = (w + 3, h + 3);
        // Clamp every row along u.
        let mut rows: Vec<Vec<V3>> = Vec::with_capacity(gh);
        let mut ku = Vec::new();
        for j in 0..gh {
            let (k, p) = clamp_uniform(&grid[j * gw..(j + 1) * gw], w);
            ku = k;
            rows.push(p);
        }
        // Then every column along v.
        let mut poles = vec![[0.0; 3]; gw * gh];
        let mut kv = Vec::new();
        for i in 0..gw {
            let col: Vec<V3> = (0..gh).map(|j| rows[j][i]).collect();
            let (k, p) = clamp_uniform(&col, h);
            kv = k;
            for j in 0..gh {
                poles[j * gw + i] = p[j];
            }
        }
        BsplineSurface { nu: gw, nv: gh, poles, knots_u: ku, knots_v: kv }
    }

    /// Parameter range `[u0, u1] × [v0, v1]`.
    pub fn range(&self) -> ([f64; 2], [f64; 2]) {
        ([self.knots_u[3], self.knots_u[self.nu]], [self.knots_v[3], self.knots_v[self.nv]])
    }

    /// Point and first derivatives at `(u, v)`.
    pub fn eval(&self, u: f64, v: f64) -> (V3, V3, V3) {
        self.combine(&basis(&self.knots_u, self.nu, u), &basis(&self.knots_v, self.nv, v))
    }

    /// Points and first derivatives on the grid `us × vs`, `out[j · us.len() + i]` at `(us[i], vs[j])`: the
    /// same values as [`BsplineSurface::eval`] there, each parameter's basis evaluated once.
    /// Cost: O(|us| · |vs|) plus the basis of each parameter (O(log n) to find its span).
    pub fn eval_grid(&self, us: &[f64], vs: &[f64]) -> Vec<(V3, V3, V3)> {
        let bu: Vec<Basis> = us.iter().map(|&u| basis(&self.knots_u, self.nu, u)).collect();
        let mut out = Vec::with_capacity(us.len() * vs.len());
        for &v in vs {
            let bv = basis(&self.knots_v, self.nv, v);
            out.extend(bu.iter().map(|b| self.combine(b, &bv)));
        }
        out
    }

    /// The surface's point and derivatives from the bases along u and v.
    fn combine(&self, &(iu, bu, du): &Basis, &(iv, bv, dv): &Basis) -> (V3, V3, V3) {
        let mut p = [0.0; 3];
        let mut pu = [0.0; 3];
        let mut pv = [0.0; 3];
        for b in 0..4 {
            for a in 0..4 {
                let q = self.poles[(iv + b) * self.nu + iu + a];
                p = vec3::add(p, vec3::scale(q, bu[a] * bv[b]));
                pu = vec3::add(pu, vec3::scale(q, du[a] * bv[b]));
                pv = vec3::add(pv, vec3::scale(q, bu[a] * dv[b]));
            }
        }
        (p, pu, pv)
    }
}

/// Index of the first of the 4 poles that act at a parameter, their basis values and derivatives.
type Basis = (usize, [f64; 4], [f64; 4]);

/// Index of the first of the 4 poles that act at `t`, their basis values and derivatives (Cox–de Boor).
fn basis(knots: &[f64], n: usize, t: f64) -> Basis {
    // Span k with knots[k] <= t < knots[k + 1], clamped into [3, n − 1].
    // (Knots ascend: the last knot at or before t, found by bisection.)
    let k = 3 + if n > 4 { knots[4..n].partition_point(|&x| x <= t) } else { 0 };
    // Degree-2 values for the derivative, degree-3 for the value.
    let mut nb = [0.0f64; 4];
    nb[0] = 1.0;
    let mut left = [0.0; 4];
    let mut right = [0.0; 4];
    let mut lower = [0.0; 4];
    for j in 1..=3 {
        left[j] = t - knots[k + 1 - j];
        right[j] = knots[k + j] - t;
        let mut saved = 0.0;
        for r in 0..j {
            let den = right[r + 1] + left[j - r];
            let temp = if den != 0.0 { nb[r] / den } else { 0.0 };
            nb[r] = saved + right[r + 1] * temp;
            saved = left[j - r] * temp;
        }
        nb[j] = saved;
        if j == 2 {
            lower = nb;
        }
    }
    // Derivative: N'_{i,3} = 3 (N_{i,2}/(t_{i+3} − t_i) − N_{i+1,2}/(t_{i+4} − t_{i+1})).
    let i0 = k - 3;
    let mut d = [0.0; 4];
    for a in 0..4 {
        let i = i0 + a;
        let n2 = |idx: usize| -> f64 {
            // lower[r] is N_{k−2+r, 2}; idx ranges over k−3 ..= k.
            if idx + 2 < k || idx > k { 0.0 } else { lower[idx + 2 - k] }
        };
        let den1 = knots[i + 3] - knots[i];
        let den2 = knots[i + 4] - knots[i + 1];
        let t1 = if den1 != 0.0 { n2(i) / den1 } else { 0.0 };
        let t2 = if den2 != 0.0 { n2(i + 1) / den2 } else { 0.0 };
        d[a] = 3.0 * (t1 - t2);
    }
    (i0, nb, d)
}

/// Try to remove one occurrence of the knot at `knots[r]` (its last occurrence, multiplicity `s`) from
/// every curve of `curves` (cubic B-splines sharing the expanded knot vector `knots`), as in Piegl &
/// Tiller's RemoveCurveKnot (The NURBS Book, A5.8, one removal). Succeeds, and changes `knots` and every
/// curve, only when each curve can lose the knot with its geometry moving by at most `tol` (a join that is
/// one order smoother than the multiplicity says); otherwise leaves everything as it was.
fn remove_knot_once(knots: &mut Vec<f64>, curves: &mut [Vec<V3>], r: usize, s: usize, tol: f64) -> bool {
    const P: usize = DEGREE;
    let u = knots[r];
    let (first, last) = (r - P, r - s);
    let off = first - 1;
    let mut news: Vec<Vec<V3>> = Vec::with_capacity(curves.len());
    for c in curves.iter() {
        let mut temp = vec![[0.0; 3]; last + 2 - off];
        temp[0] = c[off];
        temp[last + 1 - off] = c[last + 1];
        let (mut i, mut j, mut ii, mut jj) = (first, last, 1, last - off);
        while j > i {
            let ai = (u - knots[i]) / (knots[i + P + 1] - knots[i]);
            let aj = (u - knots[j]) / (knots[j + P + 1] - knots[j]);
            temp[ii] = vec3::scale(vec3::sub(c[i], vec3::scale(temp[ii - 1], 1.0 - ai)), 1.0 / ai);
            temp[jj] = vec3::scale(vec3::sub(c[j], vec3::scale(temp[jj + 1], aj)), 1.0 / (1.0 - aj));
            i += 1;
            ii += 1;
            j -= 1;
            jj -= 1;
        }
        let ok = if j < i {
            vec3::norm(vec3::sub(temp[ii - 1], temp[jj + 1])) <= tol
        } else {
            let ai = (u - knots[i]) / (knots[i + P + 1] - knots[i]);
            let q = vec3::add(vec3::scale(temp[ii + 1], ai), vec3::scale(temp[ii - 1], 1.0 - ai));
            vec3::norm(vec3::sub(c[i], q)) <= tol
        };
        if !ok {
            return false;
        }
        let mut n = c.clone();
        let (mut i, mut j) = (first, last);
        while j > i {
            n[i] = temp[i - off];
            n[j] = temp[j - off];
            i += 1;
            j -= 1;
        }
        n.remove((2 * r - s - P) / 2);
        news.push(n);
    }
    for (c, n) in curves.iter_mut().zip(news) {
        *c = n;
    }
    knots.remove(r);
    true
}

/// Remove from cubic B-splines sharing the expanded knot vector `knots` every interior knot occurrence
/// whose removal moves no curve by more than `tol` (each distinct knot left to right, down to
/// multiplicity 1).
pub fn remove_curve_knots(knots: &mut Vec<f64>, curves: &mut [Vec<V3>], tol: f64) {
    let (values, _) = knot_multiplicities(knots);
    for &x in &values[1..values.len() - 1] {
        for _ in 0..DEGREE - 1 {
            let s = knots.iter().filter(|&&k| k == x).count();
            let Some(r) = knots.iter().rposition(|&k| k == x) else { break };
            if s < 2 || !remove_knot_once(knots, curves, r, s, tol) {
                break;
            }
        }
    }
}

impl BsplineSurface {
    /// Remove every interior knot occurrence (along u, then v) whose removal moves no control point by
    /// more than `tol`: a piecewise-Bézier face (triple knots) whose pieces join C¹ or C² keeps one pole
    /// row per piece instead of three. Cost: O(knots · poles) per pass.
    pub fn remove_knots(&mut self, tol: f64) {
        for dir in 0..2 {
            let (mut knots, mut curves) = self.lines(dir);
            remove_curve_knots(&mut knots, &mut curves, tol);
            self.set_lines(dir, knots, curves);
        }
    }

    /// The pole lines along u (`dir` 0: one per v index) or along v (`dir` 1: one per u index), with that
    /// direction's expanded knots.
    fn lines(&self, dir: usize) -> (Vec<f64>, Vec<Vec<V3>>) {
        let (knots, count, along) =
            if dir == 0 { (&self.knots_u, self.nv, self.nu) } else { (&self.knots_v, self.nu, self.nv) };
        let pole =
            |l: usize, k: usize| if dir == 0 { self.poles[l * self.nu + k] } else { self.poles[k * self.nu + l] };
        (knots.clone(), (0..count).map(|l| (0..along).map(|k| pole(l, k)).collect()).collect())
    }

    /// Replace the pole lines of direction `dir` (see [`Self::lines`]) and that direction's knots.
    fn set_lines(&mut self, dir: usize, knots: Vec<f64>, curves: Vec<Vec<V3>>) {
        let along = curves[0].len();
        if dir == 0 {
            self.nu = along;
            self.poles = curves.concat();
            self.knots_u = knots;
        } else {
            self.nv = along;
            let mut poles = vec![[0.0; 3]; self.nu * along];
            for (l, c) in curves.iter().enumerate() {
                for (k, &q) in c.iter().enumerate() {
                    poles[k * self.nu + l] = q;
                }
            }
            self.poles = poles;
            self.knots_v = knots;
        }
    }
}

/// Insert knot `t` once (Boehm) into a cubic B-spline with expanded knots `knots` and poles `p`.
fn insert_knot(knots: &mut Vec<f64>, p: &mut Vec<V3>, t: f64) {
    // Span k with knots[k] <= t < knots[k + 1]; at the right end of the range use the last span (inserting
    // at a span's end through that span gives the same result).
    let k = knots.iter().rposition(|&x| x <= t).expect("t inside the knot range").min(p.len() - 1);
    let mut q = Vec::with_capacity(p.len() + 1);
    for i in 0..=p.len() {
        if i + 3 <= k {
            q.push(p[i]);
        } else if i > k {
            q.push(p[i - 1]);
        } else {
            let den = knots[i + 3] - knots[i];
            let a = if den != 0.0 { (t - knots[i]) / den } else { 0.0 };
            q.push(vec3::add(vec3::scale(p[i - 1], 1.0 - a), vec3::scale(p[i], a)));
        }
    }
    knots.insert(k + 1, t);
    *p = q;
}

/// Uniform cubic B-spline with `w + 3` poles on knots −3 … w + 3, as a clamped spline on [0, w]:
/// (expanded knots, `w + 3` poles).
fn clamp_uniform(poles: &[V3], w: usize) -> (Vec<f64>, Vec<V3>) {
    let mut knots: Vec<f64> = (0..w + 7).map(|i| i as f64 - 3.0).collect();
    let mut p = poles.to_vec();
    for _ in 0..3 {
        insert_knot(&mut knots, &mut p, 0.0);
    }
    for _ in 0..3 {
        insert_knot(&mut knots, &mut p, w as f64);
    }
    // Drop the three poles (and knots) on each side outside [0, w].
    let p = p[3..p.len() - 3].to_vec();
    let knots = knots[3..knots.len() - 3].to_vec();
    debug_assert_eq!(knots.len(), p.len() + 4);
    (knots, p)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Knot removal: a uniform bicubic spline written as triple-knot Bézier pieces loses every removable
    /// knot occurrence (back to simple knots, `(w + 3) × (h + 3)` poles) and evaluates the same; a join that
    /// is only C¹ keeps a double knot, a crease keeps its triple knot.
    #[test]
    fn knot_removal_undoes_bezier_splitting_and_keeps_what_is_needed() {
        let (w, h) = (4, 3);
        let grid: Vec<V3> = (0..(w + 3) * (h + 3))
            .map(|k| {
                let (i, j) = ((k % (w + 3)) as f64, (k / (w + 3)) as f64);
                [i, j, (0.9 * i).sin() * (0.4 * j).cos()]
            })
            .collect();
        let smooth = BsplineSurface::from_uniform_grid(&grid, w, h);
        // Triple every interior knot (insert each twice more), along u and v.
        let mut tripled = smooth.clone();
        for dir in 0..2 {
            let (mut k, mut curves) = tripled.lines(dir);
            let inner: Vec<f64> = (1..if dir == 0 { w } else { h }).map(|x| x as f64).collect();
            for &x in &inner {
                for _ in 0..2 {
                    let mut kk = k.clone();
                    for c in curves.iter_mut() {
                        kk = k.clone();
                        insert_knot(&mut kk, c, x);
                    }
                    k = kk;
                }
            }
            tripled.set_lines(dir, k, curves);
        }
        assert_eq!((tripled.nu, tripled.nv), (3 * w + 1, 3 * h + 1));
        let mut reduced = tripled.clone();
        reduced.remove_knots(1e-10);
        assert_eq!((reduced.nu, reduced.nv), (w + 3, h + 3), "every interior knot back to simple");
        for &(u, v) in &[(0.3, 0.2), (1.0, 1.0), (2.5, 2.9), (3.99, 0.01)] {
            let (a, b) = (smooth.eval(u, v).0, reduced.eval(u, v).0);
            assert!(vec3::norm(vec3::sub(a, b)) < 1e-12, "({u},{v}): {a:?} vs {b:?}");
        }
        // A crease: move the shared pole row of the first interior u-knot off the line of its neighbours.
        let mut creased = tripled.clone();
        for j in 0..creased.nv {
            creased.poles[j * creased.nu + 3][2] += 0.5;
        }
        creased.remove_knots(1e-10);
        let (_, mult) = knot_multiplicities(&creased.knots_u);
        assert_eq!(mult[1], 3, "the crease keeps its triple knot: {mult:?}");
        assert!(mult[2..mult.len() - 1].iter().all(|&m| m == 1), "the other knots become simple: {mult:?}");
    }

    /// The control grid of a wavy `w × h`-face uniform B-spline surface, `(w + 3) × (h + 3)` points.
    fn wavy_grid(w: usize, h: usize) -> Vec<V3> {
        (0..(w + 3) * (h + 3))
            .map(|k| {
                let (i, j) = ((k % (w + 3)) as f64, (k / (w + 3)) as f64);
                [i, j, (0.7 * i).sin() + 0.3 * (1.3 * j).cos() * i]
            })
            .collect()
    }

    /// Grid evaluation gives `eval`'s bits at every grid point, at knots (span ends) and between them,
    /// on a surface of several spans a side (where the span search walks, and now bisects).
    #[test]
    fn grid_evaluation_equals_pointwise_bit_for_bit() {
        let (w, h) = (7, 5);
        let s = BsplineSurface::from_uniform_grid(&wavy_grid(w, h), w, h);
        let us: Vec<f64> = (0..=4 * w).map(|k| k as f64 / 4.0).chain([0.3, 6.999, 7.0]).collect();
        let vs: Vec<f64> = (0..=3 * h).map(|k| k as f64 / 3.0).chain([2.5, 4.0001, 5.0]).collect();
        // The bisection finds the span the linear walk found, out of range and NaN included.
        let walk = |t: f64| {
            let mut k = 3;
            while k + 1 < s.nu && s.knots_u[k + 1] <= t {
                k += 1;
            }
            k - 3
        };
        for t in us.iter().copied().chain([-1.0, 8.0, f64::NAN, f64::INFINITY]) {
            assert_eq!(basis(&s.knots_u, s.nu, t).0, walk(t), "span at {t}");
        }
        let on_grid = s.eval_grid(&us, &vs);
        for (j, &v) in vs.iter().enumerate() {
            for (i, &u) in us.iter().enumerate() {
                assert_eq!(on_grid[j * us.len() + i], s.eval(u, v), "at ({u}, {v})");
            }
        }
    }

    #[test]
    fn clamped_grid_reproduces_the_uniform_spline() {
        // A wavy 5×4-face grid: compare clamped evaluation with direct uniform B-spline evaluation.
        let (w, h) = (5, 4);
        let grid = wavy_grid(w, h);
        let s = BsplineSurface::from_uniform_grid(&grid, w, h);
        assert_eq!((s.nu, s.nv), (w + 3, h + 3));
        for &(u, v) in &[(0.0, 0.0), (0.3, 2.7), (2.5, 1.5), (4.99, 3.2), (5.0, 4.0), (1.0, 3.0)] {
            let (p, pu, _) = s.eval(u, v);
            let (iu, iv) = ((u.floor() as usize).min(w - 1), (v.floor() as usize).min(h - 1));
            let (bu, du) = crate::geometry::subdivision::limit::bspline_basis(u - iu as f64);
            let (bv, _) = crate::geometry::subdivision::limit::bspline_basis(v - iv as f64);
            let mut q = [0.0; 3];
            let mut qu = [0.0; 3];
            for b in 0..4 {
                for a in 0..4 {
                    let g = grid[(iv + b) * (w + 3) + iu + a];
                    q = vec3::add(q, vec3::scale(g, bu[a] * bv[b]));
                    qu = vec3::add(qu, vec3::scale(g, du[a] * bv[b]));
                }
            }
            assert!(vec3::norm(vec3::sub(p, q)) < 1e-12, "({u},{v}): {p:?} vs {q:?}");
            assert!(vec3::norm(vec3::sub(pu, qu)) < 1e-10, "d/du at ({u},{v}): {pu:?} vs {qu:?}");
        }
    }
}

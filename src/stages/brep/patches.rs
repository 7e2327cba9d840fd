//! Bicubic Bézier patches, one per face of the refined net, that share their boundary curves exactly.
//!
//! - Regular faces: the exact B-spline patch converted to Bézier form.
//! - Edge curves: from a regular neighbour when there is one (exact); otherwise (both faces extraordinary)
//!   a cubic whose end tangents point exactly along the limit's tangent directions of the edge at its two
//!   vertices (so all patches at a vertex share its tangent plane, with their corners in cyclic order),
//!   their lengths fitted to the exact limit along the edge with its derivative in the limit's tangent
//!   planes.
//! - Extraordinary faces: the 12 boundary points come from the edge curves; the 4 interior points are a
//!   least-squares fit to the exact limit (positions inside; along the edges, the cross-boundary
//!   derivative in the limit's tangent plane, so neighbours agree in their normals).

use crate::error::{Error, Result};
use crate::geometry::linalg::NormalEquations;
use crate::geometry::vec3::{self, V3};
use crate::stages::brep::bspline::bernstein;
use crate::stages::surface::limit::{EvPatch, FaceKind, LimitSurface, limit_stencil, point_weights, tangent_stencils};
use crate::stages::surface::net::combine;
use rayon::prelude::*;

/// The Bézier net of every refined face (in its patch frame) and the curve of every refined edge.
#[derive(Clone, Debug)]
pub struct Patches {
    /// `bezier[f][4·j + i]`, frame from corner [`LimitSurface::frame_start`].
    pub bezier: Vec<[V3; 16]>,
    /// Curve of the edge of half-edge `edge_half[e]`, running from its start vertex to its end vertex.
    pub edge_curve: Vec<[V3; 4]>,
    /// A representative half-edge (the lower-numbered of the two) of every edge.
    pub edge_half: Vec<u32>,
    /// Edge of every half-edge.
    pub edge_of: Vec<u32>,
    /// Limit position of every refined vertex (the B-rep vertices).
    pub vertex: Vec<V3>,
}

const B2BEZ: [[f64; 4]; 4] = [
    [1.0 / 6.0, 4.0 / 6.0, 1.0 / 6.0, 0.0],
    [0.0, 4.0 / 6.0, 2.0 / 6.0, 0.0],
    [0.0, 2.0 / 6.0, 4.0 / 6.0, 0.0],
    [0.0, 1.0 / 6.0, 4.0 / 6.0, 1.0 / 6.0],
];

/// Positions of the 16 Bézier control points of a uniform B-spline patch with grid `g[4·j + i]`.
pub fn bspline_to_bezier(g: &[V3; 16]) -> [V3; 16] {
    let mut out = [[0.0; 3]; 16];
    for j in 0..4 {
        for i in 0..4 {
            let mut acc = [0.0; 3];
            for b in 0..4 {
                for a in 0..4 {
                    let w = B2BEZ[j][b] * B2BEZ[i][a];
                    if w != 0.0 {
                        acc = vec3::add(acc, vec3::scale(g[4 * b + a], w));
                    }
                }
            }
            out[4 * j + i] = acc;
        }
    }
    out
}

/// Boundary half-edges of face `f` in its frame: v = 0, u = 1, v = 1 (reversed), u = 0 (reversed).
fn frame_halfedges(f: usize, s: usize) -> [u32; 4] {
    std::array::from_fn(|k| (4 * f + (s + k) % 4) as u32)
}

/// Indices into a 4×4 net of the boundary row under frame half-edge `k`, in the half-edge's direction.
fn boundary_slots(k: usize) -> [usize; 4] {
    match k {
        0 => [0, 1, 2, 3],
        1 => [3, 7, 11, 15],
        2 => [15, 14, 13, 12],
        _ => [12, 8, 4, 0],
    }
}

/// Parameter `(u, v)` of a point at fraction `t` along frame half-edge `k`, and the inward unit direction
/// in parameter space.
fn edge_param(k: usize, t: f64) -> ((f64, f64), (f64, f64)) {
    match k {
        0 => ((t, 0.0), (0.0, 1.0)),
        1 => ((1.0, t), (-1.0, 0.0)),
        2 => ((1.0 - t, 1.0), (0.0, -1.0)),
        _ => ((0.0, 1.0 - t), (1.0, 0.0)),
    }
}

/// Build all patches from the fitted control points on the refined net (`p1`).
///
/// # Errors
/// `internal.bug` when an extraordinary face's local evaluation cannot be built.
///
/// Cost: O(F) with a constant of a few thousand flops per extraordinary face.
pub fn build(surface: &LimitSurface, p1: &[V3]) -> Result<Patches> {
    let net = &surface.net;
    let (edge_of, edge_half) = net.edges();
    let vertex: Vec<V3> =
        (0..net.vertex_count as u32).into_par_iter().map(|v| combine(&limit_stencil(net, v), p1)).collect();
    let tangents: Vec<[V3; 2]> = (0..net.vertex_count as u32)
        .into_par_iter()
        .map(|v| tangent_stencils(net, v).map(|t| combine(&t, p1)))
        .collect();
    let normal: Vec<V3> = tangents.iter().map(|[a, b]| vec3::unit_or(vec3::cross(*a, *b), [0.0; 3])).collect();
    // The exact limit tangent direction of the edge of outgoing half-edge `h` at its start vertex (the
    // eigen-tangents T0, T1 combined by the edge's angle 2πi/n around the vertex).
    let edge_direction = |h: u32| -> Option<V3> {
        let v = net.from(h);
        let outs = net.outgoing(v);
        let i = outs.iter().position(|&o| o == h)?;
        let angle = std::f64::consts::TAU * i as f64 / outs.len() as f64;
        let [a, b] = tangents[v as usize];
        let d = vec3::unit_or(vec3::add(vec3::scale(a, angle.cos()), vec3::scale(b, angle.sin())), [0.0; 3]);
        (d != [0.0; 3]).then_some(d)
    };
    let ev_tables: Vec<Option<EvPatch>> = (0..net.faces.len())
        .into_par_iter()
        .map(|f| match surface.kinds[f] {
            FaceKind::Extraordinary(c) => EvPatch::new(net, f, c as usize).map(Some),
            FaceKind::Regular(_) => Ok(None),
        })
        .collect::<Result<_>>()?;

    // Regular faces: exact Bézier nets.
    let mut bezier: Vec<[V3; 16]> = (0..net.faces.len())
        .into_par_iter()
        .map(|f| match surface.kinds[f] {
            FaceKind::Regular(grid) => bspline_to_bezier(&grid.map(|g| p1[g as usize])),
            FaceKind::Extraordinary(_) => [[0.0; 3]; 16],
        })
        .collect();

    // Edge curves.
    let edge_curve: Vec<[V3; 4]> = edge_half
        .par_iter()
        .map(|&h| {
            let t = net.twin[h as usize];
            let (a, b) = (net.from(h), net.to(h));
            for (half, reversed) in [(h, false), (t, true)] {
                let f = (half / 4) as usize;
                if let FaceKind::Regular(_) = surface.kinds[f] {
                    let k = ((half % 4) as usize + 4 - surface.frame_start(f)) % 4;
                    let slots = boundary_slots(k);
                    let mut c = slots.map(|s| bezier[f][s]);
                    if reversed {
                        c.reverse();
                    }
                    c[0] = vertex[a as usize];
                    c[3] = vertex[b as usize];
                    return c;
                }
            }
            // Both faces extraordinary: fit to the exact limit along the edge (seen from the face of h).
            let f = (h / 4) as usize;
            let k = ((h % 4) as usize + 4 - surface.frame_start(f)) % 4;
            let ev = ev_tables[f].as_ref().expect("extraordinary face has a table");
            let ends = [(vertex[a as usize], normal[a as usize]), (vertex[b as usize], normal[b as usize])];
            fit_edge_curve(surface, f, k, ev, p1, ends, edge_direction(h).zip(edge_direction(t)).map(|(a, b)| [a, b]))
        })
        .collect();

    // Boundary rows of every face from the shared edge curves (regular faces too, so both sides are equal
    // bit for bit), then the interiors of extraordinary faces.
    bezier.par_iter_mut().enumerate().try_for_each(|(f, b)| -> Result<()> {
        let s = surface.frame_start(f);
        for (k, half) in frame_halfedges(f, s).into_iter().enumerate() {
            let e = edge_of[half as usize] as usize;
            let mut c = edge_curve[e];
            if edge_half[e] != half {
                c.reverse();
            }
            for (slot, q) in boundary_slots(k).into_iter().zip(c) {
                b[slot] = q;
            }
        }
        if let FaceKind::Extraordinary(_) = surface.kinds[f] {
            let ev = ev_tables[f].as_ref().ok_or_else(|| Error::internal("missing table"))?;
            fit_interior(surface, f, ev, p1, b);
        }
        Ok(())
    })?;
    Ok(Patches { bezier, edge_curve, edge_half, edge_of, vertex })
}

/// Weight of a tangent-plane row (per unit of length residual) against a position row.
const G1_WEIGHT: f64 = 100.0;

/// The cubic of an edge between two extraordinary faces, from `ends[0]` to `ends[1]` (position, limit
/// normal), along frame side `k` of face `f`, fitted to the exact limit at 15 points along the edge:
/// positions, and the curve's derivative in the limit's tangent plane there (`n · c'(t) = 0`).
///
/// With `directions` (the exact limit tangent of this edge at each end; always, on a valid net) the end
/// tangents take those directions and only their two lengths are fitted (a third of the chord when a
/// fitted length is below a tenth of the chord or above the chord): the edges around a vertex then leave
/// it in their cyclic order, so no patch corner there turns over.
///
/// Without (a vanishing limit tangent), c1 and c2 are fitted freely with the end tangents heavily weighted
/// into the vertices' tangent planes, then projected exactly. That fit is kept only when its end tangents
/// point the way a positions-only fit's do, with a comparable length; otherwise the positions-only fit is
/// used.
fn fit_edge_curve(
    surface: &LimitSurface,
    f: usize,
    k: usize,
    ev: &EvPatch,
    p1: &[V3],
    ends: [(V3, V3); 2],
    directions: Option<[V3; 2]>,
) -> [V3; 4] {
    let [(p0, n0), (p3, n3)] = ends;
    // Unknowns: the two lengths α, β of c1 = p0 + α d0, c2 = p3 + β d3 (with directions), or c1 and c2.
    let mut lengths = NormalEquations::<2>::default();
    let mut plain = NormalEquations::<6>::default();
    let mut ne = NormalEquations::<6>::default();
    let n = 16;
    for m in 1..n {
        let t = m as f64 / n as f64;
        let ((u, v), _) = edge_param(k, t);
        let w = point_weights(surface, f, u, v, Some(ev));
        let x = combine(&w.pos, p1);
        let nrm = vec3::unit_or(vec3::cross(combine(&w.du, p1), combine(&w.dv, p1)), [0.0; 3]);
        let (bb, db) = bernstein(t);
        if let Some([d0, d3]) = directions {
            for c in 0..3 {
                let rhs = x[c] - (bb[0] + bb[1]) * p0[c] - (bb[2] + bb[3]) * p3[c];
                lengths.add_row(&[(0, bb[1] * d0[c]), (1, bb[2] * d3[c])], rhs, 1.0);
            }
            let rhs = -((db[0] + db[1]) * vec3::dot(nrm, p0) + (db[2] + db[3]) * vec3::dot(nrm, p3));
            lengths.add_row(&[(0, db[1] * vec3::dot(nrm, d0)), (1, db[2] * vec3::dot(nrm, d3))], rhs, G1_WEIGHT);
            continue;
        }
        for c in 0..3 {
            let rhs = x[c] - bb[0] * p0[c] - bb[3] * p3[c];
            plain.add_row(&[(c, bb[1]), (3 + c, bb[2])], rhs, 1.0);
            ne.add_row(&[(c, bb[1]), (3 + c, bb[2])], rhs, 1.0);
        }
        if nrm != [0.0; 3] {
            let rhs = -(db[0] * vec3::dot(nrm, p0) + db[3] * vec3::dot(nrm, p3));
            let row: Vec<(usize, f64)> = (0..3).flat_map(|c| [(c, db[1] * nrm[c]), (3 + c, db[2] * nrm[c])]).collect();
            ne.add_row(&row, rhs, G1_WEIGHT);
        }
    }
    if let Some([d0, d3]) = directions {
        let chord = vec3::norm(vec3::sub(p3, p0));
        let len = |x: f64| if (0.1 * chord..=chord).contains(&x) { x } else { chord / 3.0 };
        let [a, b] = lengths.solve().unwrap_or([chord / 3.0; 2]);
        return [p0, vec3::add(p0, vec3::scale(d0, len(a))), vec3::add(p3, vec3::scale(d3, len(b))), p3];
    }
    for (off, origin, nrm) in [(0, p0, n0), (3, p3, n3)] {
        let row: Vec<(usize, f64)> = (0..3).map(|c| (off + c, nrm[c])).collect();
        ne.add_row(&row, vec3::dot(nrm, origin), 1e6);
    }
    let split = |x: [f64; 6]| -> (V3, V3) { ([x[0], x[1], x[2]], [x[3], x[4], x[5]]) };
    // The positions-only system is the 2×2 Bernstein system per coordinate: singular only for a
    // degenerate sampling, never here.
    let reference = plain.solve().map(split).unwrap_or((p0, p3));
    let (mut c1, mut c2) = ne.solve().map(split).unwrap_or(reference);
    let agrees = |q: V3, r: V3, origin: V3| {
        let (a, b) = (vec3::sub(q, origin), vec3::sub(r, origin));
        vec3::dot(a, b) > 0.0 && (0.25..4.0).contains(&(vec3::norm(a) / vec3::norm(b).max(f64::MIN_POSITIVE)))
    };
    if !(agrees(c1, reference.0, p0) && agrees(c2, reference.1, p3)) {
        (c1, c2) = reference;
    }
    let project =
        |q: V3, origin: V3, nrm: V3| -> V3 { vec3::sub(q, vec3::scale(nrm, vec3::dot(vec3::sub(q, origin), nrm))) };
    [p0, project(c1, p0, n0), project(c2, p3, n3), p3]
}

/// Least-squares fit of the 4 interior points of an extraordinary face's Bézier net `b` (boundary fixed):
/// positions on an 8×8 grid of the exact limit, and along each edge the condition that the patch's
/// cross-boundary derivative lies in the exact limit's tangent plane (`n · ∂S = 0`; scale-free, so it
/// holds near the extraordinary vertex where the limit's parametric derivatives blow up or vanish). Both
/// patches at an edge satisfy the same condition, which bounds the normal jump between them.
fn fit_interior_weighted(surface: &LimitSurface, f: usize, ev: &EvPatch, p1: &[V3], b: &mut [V3; 16], g1_weight: f64) {
    const INTERIOR: [usize; 4] = [5, 6, 9, 10];
    // Unknowns: x[3·i + c] = coordinate c of interior point i.
    let mut ne = NormalEquations::<12>::default();
    let mut add_row = |row: &[(usize, f64)], rhs: f64, weight: f64| ne.add_row(row, rhs, weight);
    let n = 8;
    for j in 0..n {
        for i in 0..n {
            let (u, v) = ((i as f64 + 0.5) / n as f64, (j as f64 + 0.5) / n as f64);
            let x = combine(&point_weights(surface, f, u, v, Some(ev)).pos, p1);
            let (bu, _) = bernstein(u);
            let (bv, _) = bernstein(v);
            let coef: [f64; 16] = std::array::from_fn(|s| bu[s % 4] * bv[s / 4]);
            for c in 0..3 {
                let mut rhs = x[c];
                for (s, &w) in coef.iter().enumerate() {
                    if !INTERIOR.contains(&s) {
                        rhs -= w * b[s][c];
                    }
                }
                let row: Vec<(usize, f64)> = INTERIOR.iter().enumerate().map(|(i, &s)| (3 * i + c, coef[s])).collect();
                add_row(&row, rhs, 1.0);
            }
        }
    }
    for k in 0..4 {
        for m in 1..16 {
            let t = m as f64 / 16.0;
            let ((u, v), (du_dir, dv_dir)) = edge_param(k, t);
            let w = point_weights(surface, f, u, v, Some(ev));
            let nrm = vec3::unit_or(vec3::cross(combine(&w.du, p1), combine(&w.dv, p1)), [0.0; 3]);
            if nrm == [0.0; 3] {
                continue;
            }
            let (bu, dbu) = bernstein(u);
            let (bv, dbv) = bernstein(v);
            let coef: [f64; 16] =
                std::array::from_fn(|s| du_dir * dbu[s % 4] * bv[s / 4] + dv_dir * bu[s % 4] * dbv[s / 4]);
            let mut rhs = 0.0;
            for (s, &w) in coef.iter().enumerate() {
                if !INTERIOR.contains(&s) {
                    rhs -= w * vec3::dot(nrm, b[s]);
                }
            }
            let mut row = Vec::with_capacity(12);
            for (i, &s) in INTERIOR.iter().enumerate() {
                for c in 0..3 {
                    row.push((3 * i + c, coef[s] * nrm[c]));
                }
            }
            add_row(&row, rhs, g1_weight);
        }
    }
    if let Some(x) = ne.solve() {
        for (i, &s) in INTERIOR.iter().enumerate() {
            b[s] = [x[3 * i], x[3 * i + 1], x[3 * i + 2]];
        }
    }
}

/// [`fit_interior_weighted`] with the strongest tangent-plane weight that leaves the patch unfolded: its
/// normal within 90° of the exact limit's on the inner 7×7 points of a 9×9 grid (a strong weight constrains only the normal
/// component of the cross derivative, which can swing a weakly held interior over).
fn fit_interior(surface: &LimitSurface, f: usize, ev: &EvPatch, p1: &[V3], b: &mut [V3; 16]) {
    let boundary = *b;
    for weight in [G1_WEIGHT, G1_WEIGHT / 10.0, 1.0, 0.0] {
        *b = boundary;
        fit_interior_weighted(surface, f, ev, p1, b, weight);
        let unfolded = (0..=8).all(|j| {
            (0..=8).all(|i| {
                let (u, v) = (i as f64 / 8.0, j as f64 / 8.0);
                if u + v < 0.2 {
                    return true; // the corner's normal comes from the (shared) edge curves alone
                }
                let w = point_weights(surface, f, u, v, Some(ev));
                let exact = vec3::unit_or(vec3::cross(combine(&w.du, p1), combine(&w.dv, p1)), [0.0; 3]);
                let ours = vec3::unit_or(bezier_eval(b, u, v).1, [0.0; 3]);
                exact == [0.0; 3] || vec3::dot(exact, ours) > 0.0
            })
        });
        if unfolded {
            return;
        }
    }
    // No weight leaves the fit unfolded: the interior that gives the patch zero twist at its corners.
    *b = boundary;
    b[5] = vec3::sub(vec3::add(b[1], b[4]), b[0]);
    b[6] = vec3::sub(vec3::add(b[2], b[7]), b[3]);
    b[9] = vec3::sub(vec3::add(b[8], b[13]), b[12]);
    b[10] = vec3::sub(vec3::add(b[11], b[14]), b[15]);
}

/// Point, and unnormalised normal `∂u × ∂v`, of a Bézier net at `(u, v)`.
pub fn bezier_eval(b: &[V3; 16], u: f64, v: f64) -> (V3, V3) {
    let (bu, du) = bernstein(u);
    let (bv, dv) = bernstein(v);
    let mut p = [0.0; 3];
    let mut pu = [0.0; 3];
    let mut pv = [0.0; 3];
    for j in 0..4 {
        for i in 0..4 {
            let q = b[4 * j + i];
            p = vec3::add(p, vec3::scale(q, bu[i] * bv[j]));
            pu = vec3::add(pu, vec3::scale(q, du[i] * bv[j]));
            pv = vec3::add(pv, vec3::scale(q, bu[i] * dv[j]));
        }
    }
    (p, vec3::cross(pu, pv))
}

/// Normal jumps across patch edges (11 samples per edge): the largest, in degrees, where it is, whether
/// that edge touches an extraordinary patch, and the 99th percentile over edges of the per-edge largest.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct NormalJumps {
    pub max_deg: f64,
    pub max_at: V3,
    pub max_at_extraordinary: bool,
    /// Fraction along the edge (from its start vertex) where the largest jump is.
    pub max_at_fraction: f64,
    /// Valences (on the refined net) of the start and end vertex of that edge.
    pub max_at_valences: [usize; 2],
    pub p99_deg: f64,
}

/// Measure [`NormalJumps`].
pub fn normal_jumps(surface: &LimitSurface, patches: &Patches) -> NormalJumps {
    let per_edge: Vec<(f64, V3, f64)> = patches
        .edge_half
        .par_iter()
        .map(|&h| {
            let t = surface.net.twin[h as usize];
            let mut worst: (f64, V3, f64) = (0.0, [0.0; 3], 0.0);
            for m in 0..=10 {
                let x = m as f64 / 10.0;
                let mut normals = [[0.0; 3]; 2];
                let mut at = [0.0; 3];
                for (side, (half, frac)) in [(h, x), (t, 1.0 - x)].into_iter().enumerate() {
                    let f = (half / 4) as usize;
                    let k = ((half % 4) as usize + 4 - surface.frame_start(f)) % 4;
                    let ((u, v), _) = edge_param(k, frac);
                    let (p, n) = bezier_eval(&patches.bezier[f], u, v);
                    normals[side] = vec3::unit_or(n, [0.0; 3]);
                    at = p;
                }
                let c = vec3::dot(normals[0], normals[1]).clamp(-1.0, 1.0);
                let a = c.acos().to_degrees();
                if a > worst.0 {
                    worst = (a, at, x);
                }
            }
            worst
        })
        .collect();
    let Some((imax, &(max_deg, max_at, max_at_fraction))) =
        per_edge.iter().enumerate().max_by(|a, b| a.1.0.total_cmp(&b.1.0))
    else {
        return NormalJumps::default();
    };
    let h = patches.edge_half[imax];
    let t = surface.net.twin[h as usize];
    let max_at_extraordinary =
        [h, t].iter().any(|&x| matches!(surface.kinds[(x / 4) as usize], FaceKind::Extraordinary(_)));
    let mut v: Vec<f64> = per_edge.iter().map(|e| e.0).collect();
    let p99_deg = crate::stages::quality::percentile(&mut v, 0.99);
    let max_at_valences = [surface.net.valence(surface.net.from(h)), surface.net.valence(surface.net.to(h))];
    NormalJumps { max_deg, max_at, max_at_extraordinary, max_at_fraction, max_at_valences, p99_deg }
}

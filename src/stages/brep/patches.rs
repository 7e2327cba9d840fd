//! Bicubic Bézier patches on the refined net that share their boundary curves exactly.
//!
//! - Regular faces: the exact B-spline patch converted to Bézier form.
//! - Extraordinary faces (one extraordinary corner, where the face's frame starts) are cut towards that
//!   corner L times (L from 1 to [`EV_SPLIT_LEVELS`]), like the local subdivision that evaluates them:
//!   breaks at `0, 2⁻ᴸ, …, ¼, ½, 1` in u and in v ([`FaceNet`]). The faces of a vertex are cut once more
//!   while the largest normal jump at them exceeds [`JUMP_TARGET_DEG`].
//!   - Every cell but the corner one is the **exact** limit (a piece of a regular sub-patch of the local
//!     subdivision), so those cells join each other and the neighbouring faces exactly.
//!   - Only the corner cell, `[0, 2⁻ᴸ]²`, is approximated. Along its inner sides it takes the boundary and
//!     the second row of its exact neighbours, so it joins them C¹. Its corner is the limit point. Its two
//!     edges at the extraordinary vertex leave it along the limit's exact tangent directions of those edges
//!     (so every corner at the vertex has the vertex's normal, in cyclic order), with fitted lengths. Its
//!     one free interior point is fitted to the exact limit: positions, and, along its two edges at the
//!     vertex, the cross-boundary derivative in the limit's tangent plane, which bounds the normal jump
//!     between the corner cells of neighbouring faces.
//!
//!   The approximated region is 4⁻ᴸ of the face, and the only place a normal jump can remain; the limit's
//!   normal varies less and less over it as L grows.
//! - Edge curves ([`EdgeCurve`]): piecewise cubic over breaks along the edge. An edge at an extraordinary
//!   vertex has the face's breaks (its first span the fitted one, the others exact); every other edge is
//!   exact. Both faces take their boundary from the same curve.

use crate::error::{Error, Result};
use crate::geometry::linalg::NormalEquations;
use crate::geometry::subdivision::limit::{
    EvPatch, FaceKind, LimitSurface, limit_stencil, point_weights, tangent_stencils,
};
use crate::geometry::subdivision::net::combine;
use crate::geometry::vec3::{self, V3};
use crate::stages::brep::bspline::bernstein;
use rayon::prelude::*;

/// The most times an extraordinary face is cut towards its extraordinary corner (see the module docs).
pub const EV_SPLIT_LEVELS: usize = 4;

/// Normal jump (degrees) above which the faces of an extraordinary vertex are cut once more.
pub const JUMP_TARGET_DEG: f64 = 0.25;

/// The Bézier nets of one refined face over a tensor grid of parameter breaks, in the face's patch frame
/// (from corner [`LimitSurface::frame_start`]).
#[derive(Clone, Debug, PartialEq)]
pub struct FaceNet {
    /// Breaks along u, from 0 to 1.
    pub bu: Vec<f64>,
    /// Breaks along v, from 0 to 1.
    pub bv: Vec<f64>,
    /// `nets[(bu.len() − 1)·j + i]` over `[bu[i], bu[i+1]] × [bv[j], bv[j+1]]`, each on `[0, 1]²`.
    pub nets: Vec<[V3; 16]>,
}

/// The cell of `breaks` holding `t` and the parameter in it.
fn locate(breaks: &[f64], t: f64) -> (usize, f64) {
    let n = breaks.len() - 1;
    let i = (0..n).find(|&i| t < breaks[i + 1]).unwrap_or(n - 1);
    (i, (t - breaks[i]) / (breaks[i + 1] - breaks[i]))
}

impl FaceNet {
    /// One net over the whole face.
    pub fn whole(b: [V3; 16]) -> Self {
        FaceNet { bu: vec![0.0, 1.0], bv: vec![0.0, 1.0], nets: vec![b] }
    }

    /// Whether the face has more than one net.
    pub fn is_split(&self) -> bool {
        self.nets.len() > 1
    }

    fn cols(&self) -> usize {
        self.bu.len() - 1
    }

    /// Point and unnormalised normal at `(u, v) ∈ [0, 1]²` of the face's frame.
    pub fn eval(&self, u: f64, v: f64) -> (V3, V3) {
        let (i, a) = locate(&self.bu, u);
        let (j, b) = locate(&self.bv, v);
        let (p, n) = bezier_eval(&self.nets[self.cols() * j + i], a, b);
        let area = (self.bu[i + 1] - self.bu[i]) * (self.bv[j + 1] - self.bv[j]);
        (p, vec3::scale(n, 1.0 / area))
    }

    /// The same surface in the frame starting at corner `to`, given in the frame starting at `from`.
    pub fn rotated(&self, from: usize, to: usize) -> FaceNet {
        let mut cur = self.clone();
        for _ in 0..(to + 4 - from) % 4 {
            // One quarter turn: new (u, v) = old (1 − v, u)... as a net: new[4j + i] = old[4i + 3 − j].
            let old = cur;
            let (oc, or) = (old.cols(), old.bv.len() - 1);
            let bu = old.bv.clone();
            let bv: Vec<f64> = old.bu.iter().rev().map(|x| 1.0 - x).collect();
            let mut nets = Vec::with_capacity(old.nets.len());
            // New grid: or columns, oc rows; new cell (I, J) is old cell (oc − 1 − J, I).
            for jj in 0..oc {
                for ii in 0..or {
                    nets.push(rotate_once(&old.nets[oc * ii + (oc - 1 - jj)]));
                }
            }
            cur = FaceNet { bu, bv, nets };
        }
        cur
    }

    /// The Bézier net of the surface over `[u0, u1] × [v0, v1]`, which must lie inside one cell.
    pub fn extract(&self, [u0, u1]: [f64; 2], [v0, v1]: [f64; 2]) -> [V3; 16] {
        let (i, _) = locate(&self.bu, 0.5 * (u0 + u1));
        let (j, _) = locate(&self.bv, 0.5 * (v0 + v1));
        let (du, dv) = (self.bu[i + 1] - self.bu[i], self.bv[j + 1] - self.bv[j]);
        let lu = [(u0 - self.bu[i]) / du, (u1 - self.bu[i]) / du];
        let lv = [(v0 - self.bv[j]) / dv, (v1 - self.bv[j]) / dv];
        sub_net(&self.nets[self.cols() * j + i], lu, lv)
    }
}

/// A net turned by one quarter: `new[4j + i] = old[4i + 3 − j]`.
pub fn rotate_once(b: &[V3; 16]) -> [V3; 16] {
    std::array::from_fn(|k| {
        let (i, j) = (k % 4, k / 4);
        b[4 * i + (3 - j)]
    })
}

/// A piecewise cubic curve over `knots` (its breaks, ascending): span i, on `[knots[i], knots[i+1]]`, is
/// `points[3i..=3i+3]`.
#[derive(Clone, Debug, PartialEq)]
pub struct EdgeCurve {
    /// Breaks, ascending.
    pub knots: Vec<f64>,
    /// Bézier points, 3 per span plus one.
    pub points: Vec<V3>,
}

impl EdgeCurve {
    fn single(c: [V3; 4]) -> Self {
        EdgeCurve { knots: vec![0.0, 1.0], points: c.to_vec() }
    }

    /// The same curve run backwards, on `[0, knots.last]` again.
    pub fn reversed(&self) -> Self {
        let end = *self.knots.last().expect("a knot");
        EdgeCurve {
            knots: self.knots.iter().rev().map(|k| end - k).collect(),
            points: self.points.iter().rev().copied().collect(),
        }
    }

    /// Span `i`.
    pub fn span(&self, i: usize) -> [V3; 4] {
        std::array::from_fn(|k| self.points[3 * i + k])
    }
}

/// The nets of every refined face and the curve of every refined edge.
#[derive(Clone, Debug)]
pub struct Patches {
    /// Per refined face.
    pub nets: Vec<FaceNet>,
    /// Curve of the edge of half-edge `edge_half[e]`, on `[0, 1]`, from its start vertex to its end vertex.
    pub edge_curve: Vec<EdgeCurve>,
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

/// A cubic split at `t` by de Casteljau: the part over `[0, t]` and the part over `[t, 1]`, each on
/// `[0, 1]`.
pub fn split_at(c: [V3; 4], t: f64) -> ([V3; 4], [V3; 4]) {
    let lerp = |a: V3, b: V3| vec3::add(a, vec3::scale(vec3::sub(b, a), t));
    let (a, b, e) = (lerp(c[0], c[1]), lerp(c[1], c[2]), lerp(c[2], c[3]));
    let (d, g) = (lerp(a, b), lerp(b, e));
    let m = lerp(d, g);
    ([c[0], a, d, m], [m, g, e, c[3]])
}

/// The part of a cubic over `[t0, t1] ⊆ [0, 1]`, on `[0, 1]`.
pub fn sub_curve(c: [V3; 4], t0: f64, t1: f64) -> [V3; 4] {
    let left = if t1 < 1.0 { split_at(c, t1).0 } else { c };
    if t0 > 0.0 { split_at(left, t0 / t1).1 } else { left }
}

/// The part of a Bézier net over `[u0, u1] × [v0, v1] ⊆ [0, 1]²`.
pub fn sub_net(b: &[V3; 16], [u0, u1]: [f64; 2], [v0, v1]: [f64; 2]) -> [V3; 16] {
    if (u0, u1, v0, v1) == (0.0, 1.0, 0.0, 1.0) {
        return *b;
    }
    let mut out = *b;
    for j in 0..4 {
        let row = sub_curve(std::array::from_fn(|i| out[4 * j + i]), u0, u1);
        out[4 * j..4 * j + 4].copy_from_slice(&row);
    }
    for i in 0..4 {
        let col = sub_curve(std::array::from_fn(|j| out[4 * j + i]), v0, v1);
        for j in 0..4 {
            out[4 * j + i] = col[j];
        }
    }
    out
}

/// Side (0: v = 0, 1: u = 1, 2: v = 1, 3: u = 0) of half-edge `h` in the frame of its face.
fn side_of(surface: &LimitSurface, h: u32) -> usize {
    let f = (h / 4) as usize;
    ((h % 4) as usize + 4 - surface.frame_start(f)) % 4
}

/// The breaks `0, 2⁻ᴸ, …, ½, 1` of an extraordinary face.
pub fn ev_breaks(levels: usize) -> Vec<f64> {
    let mut b = vec![0.0];
    b.extend((0..levels).rev().map(|l| 0.5f64.powi(l as i32 + 1)));
    b.push(1.0);
    b
}

/// The exact cells of an extraordinary face (all but the corner, which is left zero), from the local
/// subdivision's regular sub-patches: cell `(i, j)` with `m = max(i, j) ≥ 1` lies in sub-patch level
/// `L + 1 − m`, quadrant by which of `i`, `j` equal `m`.
fn exact_cells(ev: &EvPatch, p1: &[V3], levels: usize) -> FaceNet {
    let breaks = ev_breaks(levels);
    let n = levels + 1;
    let quadrants: Vec<[[V3; 16]; 3]> =
        (1..=levels).map(|l| [1, 2, 3].map(|q| bspline_to_bezier(&ev.sub_grid(l, q, p1)))).collect();
    let mut nets = vec![[[0.0; 3]; 16]; n * n];
    for j in 0..n {
        for i in 0..n {
            let m = i.max(j);
            if m == 0 {
                continue;
            }
            let level = levels + 1 - m;
            let size = 0.5f64.powi(level as i32);
            let (hu, hv) = (i == m, j == m);
            let q = match (hu, hv) {
                (true, false) => 0,
                (true, true) => 1,
                _ => 2,
            };
            let (ou, ov) = (if hu { size } else { 0.0 }, if hv { size } else { 0.0 });
            let lu = [(breaks[i] - ou) / size, (breaks[i + 1] - ou) / size];
            let lv = [(breaks[j] - ov) / size, (breaks[j + 1] - ov) / size];
            nets[n * j + i] = sub_net(&quadrants[level - 1][q], lu, lv);
        }
    }
    FaceNet { bu: breaks.clone(), bv: breaks, nets }
}

/// What every pass of [`build`] reads: the refined net's limit points and tangents, the local evaluation
/// tables of its extraordinary faces and its edge table.
struct Limits<'a> {
    surface: &'a LimitSurface,
    p1: &'a [V3],
    edge_of: Vec<u32>,
    edge_half: Vec<u32>,
    vertex: Vec<V3>,
    tangents: Vec<[V3; 2]>,
    normal: Vec<V3>,
    ev_tables: &'a [Option<EvPatch>],
}

impl<'a> Limits<'a> {
    /// # Errors
    /// `internal.bug` when an extraordinary face's local evaluation cannot be built.
    fn new(surface: &'a LimitSurface, p1: &'a [V3]) -> Result<Self> {
        let net = &surface.net;
        let (edge_of, edge_half) = net.edges();
        let vertex: Vec<V3> =
            (0..net.vertex_count as u32).into_par_iter().map(|v| combine(&limit_stencil(net, v), p1)).collect();
        let tangents: Vec<[V3; 2]> = (0..net.vertex_count as u32)
            .into_par_iter()
            .map(|v| tangent_stencils(net, v).map(|t| combine(&t, p1)))
            .collect();
        let normal: Vec<V3> = tangents.iter().map(|[a, b]| vec3::unit_or(vec3::cross(*a, *b), [0.0; 3])).collect();
        let ev_tables = surface.ev_patches()?;
        Ok(Limits { surface, p1, edge_of, edge_half, vertex, tangents, normal, ev_tables })
    }

    /// The exact limit tangent direction of the edge of outgoing half-edge `h` at its start vertex (the
    /// eigen-tangents T0, T1 combined by the edge's angle 2πi/n around the vertex).
    fn edge_direction(&self, h: u32) -> Option<V3> {
        let net = &self.surface.net;
        let v = net.from(h);
        let outs = net.outgoing(v);
        let i = outs.iter().position(|&o| o == h)?;
        let angle = std::f64::consts::TAU * i as f64 / outs.len() as f64;
        let [a, b] = self.tangents[v as usize];
        let d = vec3::unit_or(vec3::add(vec3::scale(a, angle.cos()), vec3::scale(b, angle.sin())), [0.0; 3]);
        (d != [0.0; 3]).then_some(d)
    }

    /// Face `f`'s nets before its boundary is shared: a regular face's exact Bézier net, an extraordinary
    /// face's exact cells, cut `level` times.
    fn exact(&self, f: usize, level: usize) -> Result<FaceNet> {
        match (self.surface.kinds[f], &self.ev_tables[f]) {
            (FaceKind::Regular(grid), _) => Ok(FaceNet::whole(bspline_to_bezier(&grid.map(|g| self.p1[g as usize])))),
            (FaceKind::Extraordinary(_), Some(ev)) => Ok(exact_cells(ev, self.p1, level)),
            _ => Err(Error::internal(format!("face {f} has no local evaluation"))),
        }
    }

    /// The curve of edge `e`, from the faces' exact nets (`exact`, by [`Limits::exact`]): a regular face's
    /// boundary row; between two extraordinary faces, the exact cells of the face of `edge_half[e]`, with
    /// the span at an extraordinary vertex fitted.
    fn curve(&self, e: usize, exact: &[FaceNet]) -> Result<EdgeCurve> {
        let (surface, net) = (self.surface, &self.surface.net);
        let h = self.edge_half[e];
        let t = net.twin[h as usize];
        let (a, b) = (net.from(h), net.to(h));
        let mut c = 'curve: {
            for (half, reversed) in [(h, false), (t, true)] {
                let g = &exact[(half / 4) as usize];
                if !g.is_split() {
                    let mut c = boundary_slots(side_of(surface, half)).map(|s| g.nets[0][s]);
                    if reversed {
                        c.reverse();
                    }
                    break 'curve EdgeCurve::single(c);
                }
            }
            // Both faces extraordinary: read the exact cells of the face of h, and fit the span at an
            // extraordinary vertex.
            let f = (h / 4) as usize;
            let g = &exact[f];
            let levels = g.bu.len() - 2;
            let n = levels + 1;
            let cell = |i: usize, j: usize| &g.nets[n * j + i];
            let ev = self.ev_tables[f].as_ref().ok_or_else(|| Error::internal("missing table"))?;
            match side_of(surface, h) {
                // u = 1 and v = 1: exact, one span per cell along the side.
                1 => concat((0..n).map(|j| [3, 7, 11, 15].map(|s| cell(levels, j)[s])), g.bv.clone()),
                2 => concat(
                    (0..n).rev().map(|i| [15, 14, 13, 12].map(|s| cell(i, levels)[s])),
                    g.bu.iter().rev().map(|x| 1.0 - x).collect(),
                ),
                0 => {
                    let ends = (self.vertex[a as usize], self.normal[a as usize], self.edge_direction(h));
                    let spans: Vec<[V3; 4]> = (1..n).map(|i| [0, 1, 2, 3].map(|s| cell(i, 0)[s])).collect();
                    fit_ev_edge(surface, f, ev, self.p1, true, ends, (&spans, levels))
                }
                _ => {
                    let ends = (self.vertex[b as usize], self.normal[b as usize], self.edge_direction(t));
                    let spans: Vec<[V3; 4]> = (1..n).map(|j| [0, 4, 8, 12].map(|s| cell(0, j)[s])).collect();
                    fit_ev_edge(surface, f, ev, self.p1, false, ends, (&spans, levels)).reversed()
                }
            }
        };
        c.points[0] = self.vertex[a as usize];
        *c.points.last_mut().expect("points") = self.vertex[b as usize];
        Ok(c)
    }

    /// Face `f`'s nets with its boundary from the shared edge curves: a regular face takes its boundary
    /// rows from them; an extraordinary face builds its corner cell from the curves at the vertex and its
    /// exact neighbours.
    fn shared(&self, f: usize, mut g: FaceNet, curves: &[EdgeCurve]) -> Result<FaceNet> {
        let s = self.surface.frame_start(f);
        let side = |k: usize| -> EdgeCurve {
            let half = frame_halfedges(f, s)[k];
            let e = self.edge_of[half as usize] as usize;
            if self.edge_half[e] == half { curves[e].clone() } else { curves[e].reversed() }
        };
        if !g.is_split() {
            for k in 0..4 {
                let c = side(k);
                // A regular face's curves are its own (single-span) rows, or another regular face's.
                if c.knots.len() != 2 {
                    return Err(Error::internal(format!("regular face {f} has a split edge curve")));
                }
                for (slot, q) in boundary_slots(k).into_iter().zip(c.span(0)) {
                    g.nets[0][slot] = q;
                }
            }
            return Ok(g);
        }
        let ev = self.ev_tables[f].as_ref().ok_or_else(|| Error::internal("missing table"))?;
        g.nets[0] = ev_corner(self.surface, f, ev, self.p1, &g, &side(0), &side(3));
        Ok(g)
    }
}

/// Build all patches from the fitted control points on the refined net (`p1`).
///
/// # Errors
/// `internal.bug` when an extraordinary face's local evaluation cannot be built.
///
/// Cost: O(F) for the first pass, a few thousand flops per extraordinary face; at most
/// [`EV_SPLIT_LEVELS`] passes, each building again only the faces it cuts, their edges' curves and the
/// faces on those edges, and measuring the normal jumps of all faces (O(F)).
pub fn build(surface: &LimitSurface, p1: &[V3]) -> Result<Patches> {
    let net = &surface.net;
    let lim = Limits::new(surface, p1)?;
    // 1. Every extraordinary face cut once: exact nets, edge curves, nets with their shared boundary.
    let mut level = vec![1usize; net.faces.len()];
    let mut exact: Vec<FaceNet> =
        (0..net.faces.len()).into_par_iter().map(|f| lim.exact(f, level[f])).collect::<Result<_>>()?;
    let curves: Vec<EdgeCurve> =
        (0..lim.edge_half.len()).into_par_iter().map(|e| lim.curve(e, &exact)).collect::<Result<_>>()?;
    let nets: Vec<FaceNet> =
        exact.par_iter().enumerate().map(|(f, g)| lim.shared(f, g.clone(), &curves)).collect::<Result<_>>()?;
    let evs: Vec<Vec<usize>> = (0..net.vertex_count as u32)
        .filter(|&v| net.valence(v) != 4)
        .map(|v| net.outgoing(v).iter().map(|&h| (h / 4) as usize).collect())
        .collect();
    let mut patches = Patches {
        nets,
        edge_curve: curves,
        edge_half: lim.edge_half.clone(),
        edge_of: lim.edge_of.clone(),
        vertex: lim.vertex.clone(),
    };
    loop {
        // 2. The faces of an extraordinary vertex are cut again while the largest normal jump at them is
        //    above JUMP_TARGET_DEG (up to EV_SPLIT_LEVELS cuts).
        let jumps = face_jumps(surface, &patches);
        let mut cut = vec![false; net.faces.len()];
        for faces in &evs {
            let worst = faces.iter().map(|&f| jumps[f]).fold(0.0, f64::max);
            if worst > JUMP_TARGET_DEG && faces.iter().all(|&f| level[f] < EV_SPLIT_LEVELS) {
                for &f in faces {
                    level[f] += 1;
                    cut[f] = true;
                }
            }
        }
        if !cut.contains(&true) {
            return Ok(patches);
        }
        // 3. Built again: the cut faces' exact cells, the curves of their edges, the nets on those edges
        //    (the same functions of the same data as a whole pass: the same bytes).
        exact.par_iter_mut().enumerate().filter(|(f, _)| cut[*f]).try_for_each(|(f, g)| -> Result<()> {
            *g = lim.exact(f, level[f])?;
            Ok(())
        })?;
        let on_cut = |h: u32| cut[(h / 4) as usize] || cut[(net.twin[h as usize] / 4) as usize];
        let redo: Vec<bool> = lim.edge_half.iter().map(|&h| on_cut(h)).collect();
        let Patches { nets, edge_curve, .. } = &mut patches;
        edge_curve.par_iter_mut().enumerate().filter(|(e, _)| redo[*e]).try_for_each(|(e, c)| -> Result<()> {
            *c = lim.curve(e, &exact)?;
            Ok(())
        })?;
        let touched = |f: usize| cut[f] || (0..4).any(|k| redo[lim.edge_of[4 * f + k] as usize]);
        nets.par_iter_mut().enumerate().filter(|(f, _)| touched(*f)).try_for_each(|(f, g)| -> Result<()> {
            *g = lim.shared(f, exact[f].clone(), edge_curve)?;
            Ok(())
        })?;
    }
}

/// The corner cell of extraordinary face `f` (its net `g`, split into exact cells): the sides on the face's
/// boundary from the edge curves `s0` (v = 0) and `s3` (u = 0), the inner sides from the exact neighbours,
/// and the inner points fitted ([`fit_corner`]) so that the corner joins them C¹.
fn ev_corner(
    surface: &LimitSurface,
    f: usize,
    ev: &EvPatch,
    p1: &[V3],
    g: &FaceNet,
    s0: &EdgeCurve,
    s3: &EdgeCurve,
) -> [V3; 16] {
    let n = g.bu.len() - 1;
    let (r, tq) = (g.nets[1], g.nets[n]);
    let mut c = [[0.0; 3]; 16];
    c[..4].copy_from_slice(&s0.span(0));
    let last = s3.knots.len() - 2;
    for (slot, q) in [12, 8, 4, 0].into_iter().zip(s3.span(last)) {
        c[slot] = q;
    }
    // The inner sides are the exact neighbours' (R at u = 2⁻ᴸ, T at v = 2⁻ᴸ), and the corner joins them C¹:
    // its second column from u = 1 and second row from v = 1 mirror theirs (c[2] and c[8] already do,
    // through the edge curves).
    for k in 1..4 {
        c[4 * k + 3] = r[4 * k];
        c[12 + k] = tq[k];
    }
    c[15] = r[12];
    let ext = |a: V3, b: V3| vec3::sub(vec3::scale(a, 2.0), b);
    c[6] = ext(r[4], r[5]);
    c[9] = ext(tq[1], tq[5]);
    c[10] = vec3::scale(vec3::add(ext(r[8], r[9]), ext(tq[2], tq[6])), 0.5);
    fit_corner(surface, f, ev, p1, &mut c, g.bu[1]);
    c
}

/// A curve from consecutive spans (each starting where the last ended) over `knots`.
fn concat(spans: impl IntoIterator<Item = [V3; 4]>, knots: Vec<f64>) -> EdgeCurve {
    let mut points: Vec<V3> = Vec::new();
    for s in spans {
        if points.is_empty() {
            points.push(s[0]);
        }
        points.extend_from_slice(&s[1..]);
    }
    EdgeCurve { knots, points }
}

/// Weight of a tangent-plane row (per unit of length residual) against a position row.
const G1_WEIGHT: f64 = 100.0;

/// The curve of an edge between two extraordinary faces that ends at the extraordinary vertex, running
/// from that vertex over the face's breaks ([`ev_breaks`]): `exact` are the exact spans from the second on
/// (the boundary rows of face `f`'s exact cells, `levels` deep); the first is `[p0, p0 + α·d, 2·e[0] − e[1], e[0]]`
/// (`e` the second span), C¹ to the second, leaving the vertex (`ends`: limit point, limit normal, exact
/// limit tangent of the edge) along `d`. Only α is fitted, to the exact limit at 15 points of the first
/// span: positions, and the curve's derivative in the limit's tangent plane (`n · c'(t) = 0`). A fitted α
/// outside a tenth of the chord to the chord becomes a third of the chord. Without a tangent (a degenerate
/// vertex), `d` is the inner point's direction projected into the tangent plane.
fn fit_ev_edge(
    surface: &LimitSurface,
    f: usize,
    ev: &EvPatch,
    p1: &[V3],
    along_u: bool,
    (p0, n0, direction): (V3, V3, Option<V3>),
    (exact, levels): (&[[V3; 4]], usize),
) -> EdgeCurve {
    let size = 0.5f64.powi(levels as i32);
    let c3 = exact[0][0];
    let c2 = vec3::sub(vec3::scale(exact[0][0], 2.0), exact[0][1]);
    let chord = vec3::norm(vec3::sub(c3, p0));
    let d = direction.unwrap_or_else(|| {
        let q = vec3::sub(c2, p0);
        let q = vec3::sub(q, vec3::scale(n0, vec3::dot(q, n0)));
        let d = vec3::unit_or(q, [0.0; 3]);
        if d == [0.0; 3] { vec3::unit_or(vec3::sub(c3, p0), [0.0; 3]) } else { d }
    });
    let mut ne = NormalEquations::<1>::default();
    let n = 16;
    for m in 1..n {
        let t = m as f64 / n as f64;
        let (u, v) = if along_u { (size * t, 0.0) } else { (0.0, size * t) };
        let w = point_weights(surface, f, u, v, Some(ev));
        let x = combine(&w.pos, p1);
        let nrm = vec3::unit_or(vec3::cross(combine(&w.du, p1), combine(&w.dv, p1)), [0.0; 3]);
        let (bb, db) = bernstein(t);
        for c in 0..3 {
            let rhs = x[c] - (bb[0] + bb[1]) * p0[c] - bb[2] * c2[c] - bb[3] * c3[c];
            ne.add_row(&[(0, bb[1] * d[c])], rhs, 1.0);
        }
        let rhs = -((db[0] + db[1]) * vec3::dot(nrm, p0) + db[2] * vec3::dot(nrm, c2) + db[3] * vec3::dot(nrm, c3));
        ne.add_row(&[(0, db[1] * vec3::dot(nrm, d))], rhs, G1_WEIGHT);
    }
    let alpha = match ne.solve() {
        Some([a]) if (0.1 * chord..=chord).contains(&a) => a,
        _ => chord / 3.0,
    };
    let first = [p0, vec3::add(p0, vec3::scale(d, alpha)), c2, c3];
    concat(std::iter::once(first).chain(exact.iter().copied()), ev_breaks(levels))
}

/// Least-squares fit of the free interior point `c[5]` of the corner cell `c` of extraordinary face `f`
/// (over `[0, size]²` of the face): positions on an 8×8 grid of the exact limit, and along its two edges at
/// the extraordinary vertex the condition that the cross-boundary derivative lies in the exact limit's
/// tangent plane (`n · ∂S = 0`, scale-free). The corner cells of both faces at such an edge satisfy the
/// same condition, which bounds the normal jump between them.
fn fit_corner_weighted(
    surface: &LimitSurface,
    f: usize,
    ev: &EvPatch,
    p1: &[V3],
    c: &mut [V3; 16],
    size: f64,
    g1_weight: f64,
) {
    const FREE: usize = 5;
    let mut ne = NormalEquations::<3>::default();
    let n = 8;
    for j in 0..n {
        for i in 0..n {
            let (a, b) = ((i as f64 + 0.5) / n as f64, (j as f64 + 0.5) / n as f64);
            let x = combine(&point_weights(surface, f, size * a, size * b, Some(ev)).pos, p1);
            let (ba, _) = bernstein(a);
            let (bb, _) = bernstein(b);
            let coef: [f64; 16] = std::array::from_fn(|s| ba[s % 4] * bb[s / 4]);
            for k in 0..3 {
                let mut rhs = x[k];
                for (s, &w) in coef.iter().enumerate() {
                    if s != FREE {
                        rhs -= w * c[s][k];
                    }
                }
                ne.add_row(&[(k, coef[FREE])], rhs, 1.0);
            }
        }
    }
    for along_u in [true, false] {
        for m in 1..16 {
            let t = m as f64 / 16.0;
            let (a, b) = if along_u { (t, 0.0) } else { (0.0, t) };
            let w = point_weights(surface, f, size * a, size * b, Some(ev));
            let nrm = vec3::unit_or(vec3::cross(combine(&w.du, p1), combine(&w.dv, p1)), [0.0; 3]);
            if nrm == [0.0; 3] {
                continue;
            }
            let (ba, dba) = bernstein(a);
            let (bb, dbb) = bernstein(b);
            // The derivative across the edge: along v on v = 0, along u on u = 0.
            let coef: [f64; 16] =
                std::array::from_fn(|s| if along_u { ba[s % 4] * dbb[s / 4] } else { dba[s % 4] * bb[s / 4] });
            let mut rhs = 0.0;
            for (s, &w) in coef.iter().enumerate() {
                if s != FREE {
                    rhs -= w * vec3::dot(nrm, c[s]);
                }
            }
            let row: Vec<(usize, f64)> = (0..3).map(|k| (k, coef[FREE] * nrm[k])).collect();
            ne.add_row(&row, rhs, g1_weight);
        }
    }
    if let Some(x) = ne.solve() {
        c[FREE] = x;
    }
}

/// [`fit_corner_weighted`] with the strongest tangent-plane weight that leaves the corner cell unfolded:
/// its normal within 90° of the exact limit's on a 9×9 grid (away from the vertex itself, whose normal
/// comes from the shared edge curves alone). When no weight does, the interior point that gives the
/// corner zero twist.
fn fit_corner(surface: &LimitSurface, f: usize, ev: &EvPatch, p1: &[V3], c: &mut [V3; 16], size: f64) {
    for weight in [G1_WEIGHT, G1_WEIGHT / 10.0, 1.0, 0.0] {
        fit_corner_weighted(surface, f, ev, p1, c, size, weight);
        let unfolded = (0..=8).all(|j| {
            (0..=8).all(|i| {
                let (a, b) = (i as f64 / 8.0, j as f64 / 8.0);
                if a + b < 0.2 {
                    return true;
                }
                let w = point_weights(surface, f, size * a, size * b, Some(ev));
                let exact = vec3::unit_or(vec3::cross(combine(&w.du, p1), combine(&w.dv, p1)), [0.0; 3]);
                let ours = vec3::unit_or(bezier_eval(c, a, b).1, [0.0; 3]);
                exact == [0.0; 3] || vec3::dot(exact, ours) > 0.0
            })
        });
        if unfolded {
            return;
        }
    }
    c[5] = vec3::sub(vec3::add(c[1], c[4]), c[0]);
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
    /// The largest jump, degrees.
    pub max_deg: f64,
    /// Where it is.
    pub max_at: V3,
    /// That edge touches an extraordinary patch.
    pub max_at_extraordinary: bool,
    /// Fraction along the edge (from its start vertex) where the largest jump is.
    pub max_at_fraction: f64,
    /// Valences (on the refined net) of the start and end vertex of that edge.
    pub max_at_valences: [usize; 2],
    /// 99th percentile over edges of the per-edge largest jump, degrees.
    pub p99_deg: f64,
}

/// The largest normal jump across the edge of half-edge `h` (11 samples): degrees, where, and the fraction
/// along the edge from its start vertex.
fn edge_jump(surface: &LimitSurface, patches: &Patches, h: u32) -> (f64, V3, f64) {
    let t = surface.net.twin[h as usize];
    let mut worst: (f64, V3, f64) = (0.0, [0.0; 3], 0.0);
    for m in 0..=10 {
        let x = m as f64 / 10.0;
        let mut normals = [[0.0; 3]; 2];
        let mut at = [0.0; 3];
        for (side, (half, frac)) in [(h, x), (t, 1.0 - x)].into_iter().enumerate() {
            let f = (half / 4) as usize;
            let ((u, v), _) = edge_param(side_of(surface, half), frac);
            let (p, n) = patches.nets[f].eval(u, v);
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
}

/// The largest normal jump across the inner breaks of a face's nets (5 samples per cell side; C¹ by
/// construction, measured all the same): degrees and where.
fn inner_jump(g: &FaceNet) -> (f64, V3) {
    let (cols, rows) = (g.bu.len() - 1, g.bv.len() - 1);
    let mut worst = (0.0f64, [0.0; 3]);
    let mut pair = |x: &[V3; 16], ax: (f64, f64), y: &[V3; 16], ay: (f64, f64)| {
        let (p, na) = bezier_eval(x, ax.0, ax.1);
        let (_, nb) = bezier_eval(y, ay.0, ay.1);
        let c = vec3::dot(vec3::unit_or(na, [0.0; 3]), vec3::unit_or(nb, [0.0; 3])).clamp(-1.0, 1.0);
        let a = c.acos().to_degrees();
        if a > worst.0 {
            worst = (a, p);
        }
    };
    for j in 0..rows {
        for i in 0..cols {
            let here = &g.nets[cols * j + i];
            for m in 0..=4 {
                let x = m as f64 / 4.0;
                if i + 1 < cols {
                    pair(here, (1.0, x), &g.nets[cols * j + i + 1], (0.0, x));
                }
                if j + 1 < rows {
                    pair(here, (x, 1.0), &g.nets[cols * (j + 1) + i], (x, 0.0));
                }
            }
        }
    }
    worst
}

/// The largest normal jump at each face: across its four edges and its inner breaks, degrees.
fn face_jumps(surface: &LimitSurface, patches: &Patches) -> Vec<f64> {
    let per_edge: Vec<f64> = patches.edge_half.par_iter().map(|&h| edge_jump(surface, patches, h).0).collect();
    let mut out: Vec<f64> = patches.nets.par_iter().map(|g| if g.is_split() { inner_jump(g).0 } else { 0.0 }).collect();
    for (&h, &j) in patches.edge_half.iter().zip(&per_edge) {
        for f in [h / 4, surface.net.twin[h as usize] / 4] {
            out[f as usize] = out[f as usize].max(j);
        }
    }
    out
}

/// Measure [`NormalJumps`].
pub fn normal_jumps(surface: &LimitSurface, patches: &Patches) -> NormalJumps {
    let per_edge: Vec<(f64, V3, f64)> = patches.edge_half.par_iter().map(|&h| edge_jump(surface, patches, h)).collect();
    let Some((imax, &(max_deg, max_at, max_at_fraction))) =
        per_edge.iter().enumerate().max_by(|a, b| a.1.0.total_cmp(&b.1.0))
    else {
        return NormalJumps::default();
    };
    let inner = patches
        .nets
        .par_iter()
        .filter(|g| g.is_split())
        .map(inner_jump)
        .reduce(|| (0.0, [0.0; 3]), |a, b| if b.0 > a.0 { b } else { a });
    if inner.0 > max_deg {
        let mut v: Vec<f64> = per_edge.iter().map(|e| e.0).collect();
        let p99_deg = crate::geometry::stats::percentile(&mut v, 0.99);
        return NormalJumps {
            max_deg: inner.0,
            max_at: inner.1,
            max_at_extraordinary: true,
            max_at_fraction: 0.5,
            max_at_valences: [0, 0],
            p99_deg,
        };
    }
    let h = patches.edge_half[imax];
    let t = surface.net.twin[h as usize];
    let max_at_extraordinary =
        [h, t].iter().any(|&x| matches!(surface.kinds[(x / 4) as usize], FaceKind::Extraordinary(_)));
    let mut v: Vec<f64> = per_edge.iter().map(|e| e.0).collect();
    let p99_deg = crate::geometry::stats::percentile(&mut v, 0.99);
    let max_at_valences = [surface.net.valence(surface.net.from(h)), surface.net.valence(surface.net.to(h))];
    NormalJumps { max_deg, max_at, max_at_extraordinary, max_at_fraction, max_at_valences, p99_deg }
}

//! Evaluation of the Catmull–Clark limit surface as linear combinations of control points.
//!
//! The surface is evaluated on the net after one refinement step ([`LimitSurface::net`]), where every face
//! has at most one extraordinary corner. A face with four valence-4 corners is a uniform bicubic B-spline
//! patch of its 4×4 grid (exact). A face with one extraordinary corner is evaluated exactly by repeated
//! local subdivision ([`EvPatch`]): at level k the three sub-patches away from the corner are regular and
//! the corner sub-patch is subdivided again, down to [`EV_LEVELS`] levels (below that, 2⁻¹⁰ of the patch
//! size, the last level's patches are clamped; the position error there is below 10⁻³ of a patch size).

use super::net::{QuadNet, Stencils};
use crate::error::{Error, Result};
use rayon::prelude::*;
use std::collections::HashMap;
use std::sync::OnceLock;

/// Local subdivision depth used around extraordinary vertices.
pub const EV_LEVELS: usize = 10;

/// Uniform cubic B-spline basis at `t ∈ [0, 1]`: values and first derivatives.
pub fn bspline_basis(t: f64) -> ([f64; 4], [f64; 4]) {
    let s = 1.0 - t;
    let n = [
        s * s * s / 6.0,
        (3.0 * t * t * t - 6.0 * t * t + 4.0) / 6.0,
        (-3.0 * t * t * t + 3.0 * t * t + 3.0 * t + 1.0) / 6.0,
        t * t * t / 6.0,
    ];
    let d = [-s * s / 2.0, (3.0 * t * t - 4.0 * t) / 2.0, (-3.0 * t * t + 2.0 * t + 1.0) / 2.0, t * t / 2.0];
    (n, d)
}

/// Limit-position stencil of an interior vertex of valence n:
/// `(n²·v + 4·Σ edge neighbours + Σ diagonal neighbours) / (n(n + 5))`.
pub fn limit_stencil(net: &QuadNet, v: u32) -> Vec<(u32, f64)> {
    let outs = net.outgoing(v);
    let n = outs.len() as f64;
    let d = n * (n + 5.0);
    let mut row = vec![(v, n * n / d)];
    for &h in &outs {
        row.push((net.to(h), 4.0 / d));
        row.push((net.to(super::net::next(h)), 1.0 / d));
    }
    row
}

/// Two limit tangent stencils of an interior vertex (Halstead et al.'s masks); their cross product is the
/// outward limit normal for a counter-clockwise net.
pub fn tangent_stencils(net: &QuadNet, v: u32) -> [Vec<(u32, f64)>; 2] {
    let outs = net.outgoing(v);
    let n = outs.len();
    let nf = n as f64;
    let tau = std::f64::consts::TAU;
    let a = 1.0 + (tau / nf).cos() + (tau / (2.0 * nf)).cos() * (2.0 * (9.0 + (tau / nf).cos())).sqrt();
    let mut t = [Vec::with_capacity(2 * n), Vec::with_capacity(2 * n)];
    for (i, &h) in outs.iter().enumerate() {
        let (e, f) = (net.to(h), net.to(super::net::next(h)));
        let (c0, c1) = ((tau * i as f64 / nf).cos(), (tau * (i + 1) as f64 / nf).cos());
        let (s0, s1) = ((tau * i as f64 / nf).sin(), (tau * (i + 1) as f64 / nf).sin());
        t[0].push((e, a * c0));
        t[0].push((f, c0 + c1));
        t[1].push((e, a * s0));
        t[1].push((f, s0 + s1));
    }
    t
}

/// How a face of the refined net is evaluated.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum FaceKind {
    /// Bicubic B-spline of the 4×4 grid (frame from corner 0).
    Regular([u32; 16]),
    /// One extraordinary corner; the patch frame starts there.
    Extraordinary(u8),
}

/// A Catmull–Clark limit surface, held as the once-refined net with a kind per face.
#[derive(Clone, Debug)]
pub struct LimitSurface {
    /// The refined net (level 1).
    pub net: QuadNet,
    /// Level-1 vertices as combinations of level-0 control points.
    pub refine: Stencils,
    /// Per level-1 face.
    pub kinds: Vec<FaceKind>,
    /// The local evaluation of every extraordinary face, built once on first use ([`LimitSurface::ev_patches`]).
    ev: OnceLock<Vec<Option<EvPatch>>>,
}

impl LimitSurface {
    /// Refine a closed control net once and classify its faces.
    ///
    /// # Errors
    /// `surface.bad-net` when a refined face has more than one extraordinary corner or a regular face has no
    /// regular 4×4 grid (only for nets that are not closed 2-manifolds). Cost: O(F).
    pub fn new(control: &QuadNet) -> Result<Self> {
        let (net, refine) = control.refine();
        let valence: Vec<usize> = (0..net.vertex_count as u32).map(|v| net.valence(v)).collect();
        let mut kinds = Vec::with_capacity(net.faces.len());
        for (f, q) in net.faces.iter().enumerate() {
            let ev: Vec<usize> = (0..4).filter(|&i| valence[q[i] as usize] != 4).collect();
            let kind = match ev.as_slice() {
                [] => FaceKind::Regular(net.grid16(f, 0).ok_or_else(|| {
                    Error::new(
                        crate::error::ErrorCode::SurfaceBadNet,
                        format!("refined face {f} has no regular one-ring"),
                    )
                })?),
                [c] => FaceKind::Extraordinary(*c as u8),
                _ => {
                    return Err(Error::new(
                        crate::error::ErrorCode::SurfaceBadNet,
                        format!("refined face {f} has {} extraordinary corners", ev.len()),
                    ));
                }
            };
            kinds.push(kind);
        }
        Ok(LimitSurface { net, refine, kinds, ev: OnceLock::new() })
    }

    /// The local evaluation ([`EvPatch`]) of every extraordinary face (`None` for a regular one), built on
    /// the first call and kept: the surface fit and the B-rep both evaluate the same faces.
    ///
    /// # Errors
    /// `internal.bug` when a face's local evaluation cannot be built. Cost: the first call O(F) (ten local
    /// subdivisions per extraordinary face, in parallel), later calls O(1).
    pub fn ev_patches(&self) -> Result<&[Option<EvPatch>]> {
        if let Some(ev) = self.ev.get() {
            return Ok(ev);
        }
        let ev: Vec<Option<EvPatch>> = (0..self.net.faces.len())
            .into_par_iter()
            .map(|f| match self.kinds[f] {
                FaceKind::Extraordinary(c) => EvPatch::new(&self.net, f, c as usize).map(Some),
                FaceKind::Regular(_) => Ok(None),
            })
            .collect::<Result<_>>()?;
        Ok(self.ev.get_or_init(|| ev))
    }

    /// Corner index where the patch frame of face `f` starts.
    pub fn frame_start(&self, f: usize) -> usize {
        match self.kinds[f] {
            FaceKind::Regular(_) => 0,
            FaceKind::Extraordinary(c) => c as usize,
        }
    }
}

/// Exact evaluation of the limit on a face with one extraordinary corner, as weights over the level-1
/// vertices of its one-ring (`local`).
#[derive(Clone, Debug)]
pub struct EvPatch {
    /// Level-1 vertex ids the weights refer to.
    pub local: Vec<u32>,
    /// `EV_LEVELS × 3 quadrants × 16 grid points × local.len()` weights.
    weights: Vec<f64>,
}

/// Weights of a surface point and its two parameter derivatives.
#[derive(Clone, Debug, Default)]
pub struct PointWeights {
    /// Weights of the position.
    pub pos: Vec<(u32, f64)>,
    /// Weights of the derivative in u.
    pub du: Vec<(u32, f64)>,
    /// Weights of the derivative in v.
    pub dv: Vec<(u32, f64)>,
}

impl EvPatch {
    /// Tables for face `f` of `surface.net`, whose extraordinary corner is `start`. Cost: O(EV_LEVELS · n²)
    /// for valence n.
    ///
    /// # Errors
    /// `internal.bug` when a sub-patch that must be regular is not (a bug in refinement or cropping).
    pub fn new(net: &QuadNet, f: usize, start: usize) -> Result<Self> {
        // The cropped net has the face of interest first, so its sub-face at corner i is 4·0 + i.
        let (mut local_net, local) = crop(net, f);
        let k = local.len();
        let mut values: Vec<Vec<f64>> =
            (0..k).map(|i| (0..k).map(|j| if i == j { 1.0 } else { 0.0 }).collect()).collect();
        let mut weights = Vec::with_capacity(EV_LEVELS * 48 * k);
        let mut s = start;
        for _ in 0..EV_LEVELS {
            let (rnet, st) = local_net.refine();
            let rvalues: Vec<Vec<f64>> = (0..st.rows())
                .map(|r| {
                    let mut acc = vec![0.0; k];
                    for &(c, w) in st.row(r) {
                        for (a, b) in acc.iter_mut().zip(&values[c as usize]) {
                            *a += w * b;
                        }
                    }
                    acc
                })
                .collect();
            for q in 1..4 {
                let sub = (s + q) % 4;
                let grid = rnet
                    .grid16(sub, (4 - q) % 4)
                    .ok_or_else(|| Error::internal(format!("sub-patch {q} of an extraordinary face is not regular")))?;
                for g in grid {
                    weights.extend_from_slice(&rvalues[g as usize]);
                }
            }
            // Recurse into the corner sub-face, whose frame starts at its corner 0 (the vertex point).
            let (cnet, cl) = crop(&rnet, s);
            values = cl.iter().map(|&v| rvalues[v as usize].clone()).collect();
            local_net = cnet;
            s = 0;
        }
        Ok(EvPatch { local, weights })
    }

    /// The uniform B-spline control grid (`grid[4·j + i]`, frame from the extraordinary corner) of
    /// regular sub-patch `q` (1: `u ≥ ½, v < ½`, 2: both `≥ ½`, 3: `u < ½, v ≥ ½` of the level's corner
    /// square) at subdivision `level` (1 = the face split once), as positions from the level-1 control
    /// points `p1`. Its parameter square maps onto the quadrant linearly. Cost: O(16 · local).
    pub fn sub_grid(&self, level: usize, q: usize, p1: &[[f64; 3]]) -> [[f64; 3]; 16] {
        assert!((1..=EV_LEVELS).contains(&level) && (1..=3).contains(&q), "sub-patch {q} at level {level}");
        let k = self.local.len();
        let base = ((level - 1) * 3 + (q - 1)) * 16 * k;
        std::array::from_fn(|g| {
            let row = &self.weights[base + g * k..base + (g + 1) * k];
            let mut acc = [0.0; 3];
            for (&w, &v) in row.iter().zip(&self.local) {
                if w != 0.0 {
                    let x = p1[v as usize];
                    acc = [acc[0] + w * x[0], acc[1] + w * x[1], acc[2] + w * x[2]];
                }
            }
            acc
        })
    }

    /// Weights of the limit point at `(u, v)` (frame from the extraordinary corner) and of its derivatives,
    /// over [`EvPatch::local`] indices.
    pub fn eval(&self, u: f64, v: f64) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
        let k = self.local.len();
        let m = u.max(v).clamp(0.0, 1.0);
        let level = if m <= 0.0 { EV_LEVELS } else { ((-m.log2()).floor() as usize + 1).clamp(1, EV_LEVELS) };
        let scale = (1u64 << level) as f64;
        let (s, t) = (u * scale, v * scale);
        let (q, a, b) = if s >= 1.0 && t < 1.0 {
            (1, s - 1.0, t)
        } else if s >= 1.0 {
            (2, s - 1.0, t - 1.0)
        } else if t >= 1.0 {
            (3, s, t - 1.0)
        } else if s >= t {
            (1, 0.0, t)
        } else {
            (3, s, 0.0)
        };
        let (nu, du) = bspline_basis(a.clamp(0.0, 1.0));
        let (nv, dv) = bspline_basis(b.clamp(0.0, 1.0));
        let base = ((level - 1) * 3 + (q - 1)) * 16 * k;
        let mut pos = vec![0.0; k];
        let mut pu = vec![0.0; k];
        let mut pv = vec![0.0; k];
        for j in 0..4 {
            for i in 0..4 {
                let row = &self.weights[base + (4 * j + i) * k..base + (4 * j + i + 1) * k];
                let (w, wu, wv) = (nu[i] * nv[j], du[i] * nv[j] * scale, nu[i] * dv[j] * scale);
                for c in 0..k {
                    pos[c] += w * row[c];
                    pu[c] += wu * row[c];
                    pv[c] += wv * row[c];
                }
            }
        }
        (pos, pu, pv)
    }
}

/// The faces touching any corner of face `f`, as a local net whose face 0 is `f`; returns (net,
/// local→global vertex ids).
fn crop(net: &QuadNet, f: usize) -> (QuadNet, Vec<u32>) {
    let mut faces: Vec<usize> = vec![f];
    for &c in &net.faces[f] {
        for h in net.outgoing(c) {
            let g = (h / 4) as usize;
            if !faces.contains(&g) {
                faces.push(g);
            }
        }
    }
    let mut map: HashMap<u32, u32> = HashMap::new();
    let mut local = Vec::new();
    let lfaces: Vec<[u32; 4]> = faces
        .iter()
        .map(|&g| {
            net.faces[g].map(|v| {
                *map.entry(v).or_insert_with(|| {
                    local.push(v);
                    (local.len() - 1) as u32
                })
            })
        })
        .collect();
    let lnet = QuadNet::new(lfaces, local.len(), false).expect("a sub-net of a valid net is valid");
    (lnet, local)
}

/// Sparse weights of a point of the limit surface on level-1 face `f` at `(u, v)` in its patch frame,
/// with derivatives. `ev` must be the face's [`EvPatch`] when the face is extraordinary.
pub fn point_weights(surface: &LimitSurface, f: usize, u: f64, v: f64, ev: Option<&EvPatch>) -> PointWeights {
    match surface.kinds[f] {
        FaceKind::Regular(grid) => {
            let (nu, du) = bspline_basis(u);
            let (nv, dv) = bspline_basis(v);
            let mut w = PointWeights::default();
            for j in 0..4 {
                for i in 0..4 {
                    let g = grid[4 * j + i];
                    w.pos.push((g, nu[i] * nv[j]));
                    w.du.push((g, du[i] * nv[j]));
                    w.dv.push((g, nu[i] * dv[j]));
                }
            }
            w
        }
        FaceKind::Extraordinary(_) => {
            let ev = ev.expect("extraordinary face needs its EvPatch");
            let (p, pu, pv) = ev.eval(u, v);
            let pack = |x: Vec<f64>| ev.local.iter().zip(x).filter(|(_, w)| *w != 0.0).map(|(&g, w)| (g, w)).collect();
            PointWeights { pos: pack(p), du: pack(pu), dv: pack(pv) }
        }
    }
}

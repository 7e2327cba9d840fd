//! The solid's types: faces, edges, coedges, the report; and what a solid measures of itself (folds, volume
//! and area, tessellation).

use rayon::prelude::*;

use super::bspline::{self, BsplineSurface, bezier_point};
use crate::error::Result;
use crate::geometry::mesh::TriMesh;
use crate::geometry::vec3::{self, V3};

/// A use of an edge by a face loop: the edge, whether the loop runs along the curve's direction, and the
/// parameter points of the coedge's start and end on the face surface (edges are iso-parameter lines).
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Coedge {
    /// Index of the edge.
    pub edge: u32,
    /// The loop runs along the edge curve's direction.
    pub forward: bool,
    /// Parameter points of the coedge's start and end on the face surface.
    pub uv: [[f64; 2]; 2],
}

/// A topological edge with its curve from `start` to `end`: a piecewise cubic Bézier over the ascending
/// breaks `knots` (span i, on `[knots[i], knots[i+1]]`, is `curve[3i..=3i+3]`), from 0 to the number of
/// refined edges it runs along; a face loop's coedge maps it linearly onto its `uv` segment.
#[derive(Clone, Debug, PartialEq)]
pub struct Edge {
    /// Index of the start vertex.
    pub start: u32,
    /// Index of the end vertex.
    pub end: u32,
    /// Bézier points, 3 per span plus one.
    pub curve: Vec<V3>,
    /// Breaks, ascending, from 0.
    pub knots: Vec<f64>,
}

impl Edge {
    /// Number of cubic spans.
    pub fn spans(&self) -> usize {
        (self.curve.len() - 1) / 3
    }

    /// Parameter length (the last break).
    pub fn length(&self) -> f64 {
        *self.knots.last().expect("a break")
    }

    /// The curve at parameter `t ∈ [0, length]`.
    pub fn point(&self, t: f64) -> V3 {
        let n = self.spans();
        let i = (0..n).find(|&i| t < self.knots[i + 1]).unwrap_or(n - 1);
        let span: [V3; 4] = std::array::from_fn(|k| self.curve[3 * i + k]);
        bezier_point(&span, (t - self.knots[i]) / (self.knots[i + 1] - self.knots[i]))
    }
}

/// A face: a B-spline surface bounded by one outer loop.
#[derive(Clone, Debug, PartialEq)]
pub struct Face {
    /// The face's surface.
    pub surface: BsplineSurface,
    /// The outer loop, counter-clockwise in (u, v).
    pub bound: Vec<Coedge>,
}

/// A closed solid bounded by one shell.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct Solid {
    /// Vertex positions.
    pub vertices: Vec<V3>,
    /// Edges, each used once in each direction by the faces' loops.
    pub edges: Vec<Edge>,
    /// Faces of the one shell.
    pub faces: Vec<Face>,
}

/// Numbers that describe a built solid.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct BrepReport {
    /// Faces of the solid.
    pub faces: usize,
    /// Faces that are packed blocks of more than one refined face.
    pub packed_faces: usize,
    /// Refined faces (one Bézier patch each before packing).
    pub patches: usize,
    /// Refined faces at an extraordinary vertex (fitted corner cells).
    pub extraordinary_patches: usize,
    /// Edges of the solid.
    pub edges: usize,
    /// Vertices of the solid.
    pub vertices: usize,
    /// Enclosed volume (Gauss quadrature on the exact surfaces; exact up to rounding).
    pub volume: f64,
    /// Surface area (Gauss quadrature on the exact surfaces).
    pub area: f64,
    /// Largest normal jump across patch edges, degrees (11 samples per edge).
    pub max_normal_jump_deg: f64,
    /// 99th percentile over edges of the per-edge largest jump, degrees.
    pub p99_normal_jump_deg: f64,
    /// Where the largest jump is, and whether that edge touches an extraordinary patch.
    pub max_normal_jump_at: V3,
    /// That edge touches an extraordinary patch.
    pub max_normal_jump_at_extraordinary: bool,
    /// Fraction along that edge and the valences of its two vertices (refined net).
    pub max_normal_jump_at_fraction: f64,
    /// Valences of that edge's two vertices (refined net).
    pub max_normal_jump_at_valences: [usize; 2],
    /// Largest distance between an edge curve and the face boundaries that use it, model units.
    pub max_edge_deviation: f64,
    /// Intersecting triangle pairs of a welded tessellation of the solid (set by the pipeline; 0 = the
    /// surface does not cross itself at that resolution).
    pub self_intersections: usize,
    /// A point of the first intersecting pair.
    pub self_intersection_at: Option<V3>,
    /// Intersecting triangle pairs of the quad control mesh it was built from (set by the pipeline).
    pub quad_self_intersections: usize,
    /// Faces whose surface folds over inside ([`Solid::folds`]): the normal turns by more than 90°
    /// between neighbouring samples 1/[`FOLD_SAMPLES`] of a knot span apart, or vanishes. Such a pleat need
    /// not make the tessellation cross itself, yet a mesher's parametric 2-D step can fail on the face.
    pub folded_faces: usize,
    /// A point of the first folded face.
    pub fold_at: Option<V3>,
}

/// Samples per knot span and direction of the fold check ([`Solid::folds`]).
pub const FOLD_SAMPLES: usize = 8;

pub(super) const GAUSS5: [(f64, f64); 5] = [
    (-0.906_179_845_938_664, 0.236_926_885_056_189_1),
    (-0.538_469_310_105_683_1, 0.478_628_670_499_366_5),
    (0.0, 0.568_888_888_888_888_9),
    (0.538_469_310_105_683_1, 0.478_628_670_499_366_5),
    (0.906_179_845_938_664, 0.236_926_885_056_189_1),
];

impl Solid {
    /// Faces whose surface folds over: on a grid of [`FOLD_SAMPLES`] × [`FOLD_SAMPLES`] cells per knot
    /// span, two neighbouring samples whose normals differ by more than 90°, or a vanishing normal. Returns
    /// the count and a point of the first folded face (by index). Cost: 81 surface evaluations per span.
    pub fn folds(&self) -> (usize, Option<V3>) {
        let folded = self.fold_points();
        (folded.len(), folded.first().copied())
    }

    /// A point of each face whose surface folds over ([`Solid::folds`]), in face order. Cost: as
    /// [`Solid::folds`].
    pub fn fold_points(&self) -> Vec<V3> {
        let folded: Vec<Option<V3>> = self
            .faces
            .par_iter()
            .map(|face| {
                let s = &face.surface;
                let (ku, _) = bspline::knot_multiplicities(&s.knots_u);
                let (kv, _) = bspline::knot_multiplicities(&s.knots_v);
                let grid = |k: &[f64]| -> Vec<f64> {
                    let mut t: Vec<f64> = k
                        .windows(2)
                        .flat_map(|w| {
                            (0..FOLD_SAMPLES).map(move |i| w[0] + (w[1] - w[0]) * i as f64 / FOLD_SAMPLES as f64)
                        })
                        .collect();
                    t.push(*k.last().expect("a span"));
                    t
                };
                let (us, vs) = (grid(&ku), grid(&kv));
                let points = s.eval_grid(&us, &vs);
                let mut normals = vec![[0.0; 3]; us.len() * vs.len()];
                for (k, &(p, pu, pv)) in points.iter().enumerate() {
                    let n = vec3::cross(pu, pv);
                    if !(vec3::norm(n) > 0.0) {
                        return Some(p);
                    }
                    normals[k] = vec3::scale(n, 1.0 / vec3::norm(n));
                }
                for j in 0..vs.len() {
                    for i in 0..us.len() {
                        let n = normals[j * us.len() + i];
                        let right = (i + 1 < us.len()).then(|| normals[j * us.len() + i + 1]);
                        let up = (j + 1 < vs.len()).then(|| normals[(j + 1) * us.len() + i]);
                        if [right, up].into_iter().flatten().any(|m| vec3::dot(n, m) < 0.0) {
                            return Some(points[j * us.len() + i].0);
                        }
                    }
                }
                None
            })
            .collect();
        folded.into_iter().flatten().collect()
    }

    /// Enclosed volume `⅓ ∮ p · n dA` and area, by 5×5-point Gauss quadrature per knot span (exact for
    /// the volume of bicubic patches).
    pub fn volume_and_area(&self) -> (f64, f64) {
        let mut vol = 0.0;
        let mut area = 0.0;
        for face in &self.faces {
            let s = &face.surface;
            let (ku, _) = bspline::knot_multiplicities(&s.knots_u);
            let (kv, _) = bspline::knot_multiplicities(&s.knots_v);
            // Every Gauss point's parameter along u and along v, span by span, evaluated on their grid.
            let gauss = |k: &[f64]| -> Vec<f64> {
                k.windows(2).flat_map(|w| GAUSS5.map(|(x, _)| w[0] + (w[1] - w[0]) / 2.0 * (x + 1.0))).collect()
            };
            let (us, vs) = (gauss(&ku), gauss(&kv));
            let points = s.eval_grid(&us, &vs);
            for (su, wu) in ku.windows(2).enumerate() {
                for (sv, wv) in kv.windows(2).enumerate() {
                    let (hu, hv) = ((wu[1] - wu[0]) / 2.0, (wv[1] - wv[0]) / 2.0);
                    for (gu, &(_, au)) in GAUSS5.iter().enumerate() {
                        for (gv, &(_, av)) in GAUSS5.iter().enumerate() {
                            let (p, pu, pv) = points[(5 * sv + gv) * us.len() + 5 * su + gu];
                            let n = vec3::cross(pu, pv);
                            let w = au * av * hu * hv;
                            vol += w * vec3::dot(p, n) / 3.0;
                            area += w * vec3::norm(n);
                        }
                    }
                }
            }
        }
        (vol, area)
    }

    /// A triangle mesh through points of the exact surfaces, `per_span` × `per_span` quads per unit of
    /// parameter (one refined face), with vertices shared along edges inside a face (faces are separate
    /// sheets, whose shared boundaries are sampled at the same points). For distance checks.
    pub fn tessellate(&self, per_span: usize) -> Result<TriMesh> {
        Ok(self.tessellate_labelled(per_span)?.0)
    }

    /// [`Solid::tessellate`], with the face (index into `faces`) of every triangle.
    pub fn tessellate_labelled(&self, per_span: usize) -> Result<(TriMesh, Vec<u32>)> {
        let n = per_span.max(1);
        let mut pos: Vec<[f32; 3]> = Vec::new();
        let mut tris: Vec<[u32; 3]> = Vec::new();
        let mut labels: Vec<u32> = Vec::new();
        for (id, face) in self.faces.iter().enumerate() {
            let s = &face.surface;
            let (ku, _) = bspline::knot_multiplicities(&s.knots_u);
            let (kv, _) = bspline::knot_multiplicities(&s.knots_v);
            let us: Vec<f64> = param_points(&ku, n);
            let vs: Vec<f64> = param_points(&kv, n);
            let base = pos.len() as u32;
            pos.extend(s.eval_grid(&us, &vs).into_iter().map(|(p, _, _)| [p[0] as f32, p[1] as f32, p[2] as f32]));
            let cols = us.len() as u32;
            for j in 0..vs.len() as u32 - 1 {
                for i in 0..cols - 1 {
                    let a = base + j * cols + i;
                    tris.push([a, a + 1, a + cols + 1]);
                    tris.push([a, a + cols + 1, a + cols]);
                }
            }
            labels.resize(tris.len(), id as u32);
        }
        Ok((TriMesh::new(pos, tris)?, labels))
    }
}

/// `n` points per unit of parameter over the knots' range (faces are built in units of refined faces, so
/// two faces sample the boundary they share at the same points even when one has a knot in the middle of
/// a unit and the other does not), and the last knot.
pub(super) fn param_points(knots: &[f64], n: usize) -> Vec<f64> {
    let (a, b) = (knots[0], *knots.last().expect("a knot"));
    let units = ((b - a).round() as usize).max(1);
    let mut out = Vec::with_capacity(units * n + 1);
    for k in 0..units * n {
        out.push(a + (b - a) * k as f64 / (units * n) as f64);
    }
    out.push(b);
    out
}

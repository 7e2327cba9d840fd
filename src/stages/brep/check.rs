//! Our own validity check of a solid (closed, each edge used once in each direction, loops chain, edge curves
//! on both faces' boundaries, positive volume).

use super::solid::*;
use crate::error::{Error, ErrorCode, Result};
use crate::geometry::tolerance::BREP_EDGE_REL;
use crate::geometry::vec3;

/// Our own validity check. Returns the largest edge-curve-to-face-boundary deviation.
///
/// # Errors
/// `brep.invalid` naming the first offending face, edge or loop: an edge not used exactly once in each
/// direction, a loop whose coedges do not chain or that passes through a vertex twice (a pinched face), an
/// edge curve whose ends are not its vertices or that leaves a face boundary by more than
/// [`BREP_EDGE_REL`] × `diagonal`, or faces that fall into more than one connected piece.
pub fn check(solid: &Solid, diagonal: f64) -> Result<f64> {
    let bad = |m: String| Error::new(ErrorCode::BrepInvalid, m);
    let mut uses = vec![[0u32; 2]; solid.edges.len()];
    let tol = BREP_EDGE_REL * diagonal.max(f64::MIN_POSITIVE);
    let mut worst: f64 = 0.0;
    for (fi, face) in solid.faces.iter().enumerate() {
        if face.bound.is_empty() {
            return Err(bad(format!("face {fi} has an empty loop")));
        }
        // A loop through one vertex twice pinches the face (OCCT accepts it; gmsh's 2-D mesher cannot
        // recover the boundary there).
        let mut starts: Vec<u32> = face
            .bound
            .iter()
            .filter_map(|c| solid.edges.get(c.edge as usize).map(|e| if c.forward { e.start } else { e.end }))
            .collect();
        starts.sort_unstable();
        if let Some(w) = starts.windows(2).find(|w| w[0] == w[1]) {
            return Err(bad(format!("face {fi}: its loop passes through vertex {} twice (a pinched face)", w[0])));
        }
        for (k, c) in face.bound.iter().enumerate() {
            let Some(edge) = solid.edges.get(c.edge as usize).filter(|e| e.curve.len() >= 4 && e.curve.len() % 3 == 1)
            else {
                return Err(bad(format!("face {fi} uses edge {} that does not exist", c.edge)));
            };
            uses[c.edge as usize][usize::from(!c.forward)] += 1;
            let (_, end) = if c.forward { (edge.start, edge.end) } else { (edge.end, edge.start) };
            let nxt = face.bound[(k + 1) % face.bound.len()];
            let Some(ne) = solid.edges.get(nxt.edge as usize) else {
                return Err(bad(format!("face {fi} uses edge {} that does not exist", nxt.edge)));
            };
            let nstart = if nxt.forward { ne.start } else { ne.end };
            if end != nstart {
                return Err(bad(format!("face {fi}: loop does not chain after edge {}", c.edge)));
            }
            for (v, p) in [(edge.start, edge.curve[0]), (edge.end, *edge.curve.last().unwrap())] {
                let d = vec3::norm(vec3::sub(solid.vertices[v as usize], p));
                if d > tol {
                    return Err(bad(format!("edge {}: curve end is {d:.3e} from vertex {v}", c.edge)));
                }
            }
            if edge.knots.len() != edge.spans() + 1 || edge.knots.windows(2).any(|w| !(w[0] < w[1])) {
                return Err(bad(format!("edge {}: its breaks do not ascend one per span", c.edge)));
            }
            let len = edge.length();
            // 8 samples per span, at the edge's own breaks.
            let ts: Vec<f64> = edge
                .knots
                .windows(2)
                .flat_map(|w| (0..8).map(move |m| w[0] + (w[1] - w[0]) * m as f64 / 8.0))
                .chain(std::iter::once(len))
                .collect();
            for s in ts {
                let t = if c.forward { s / len } else { 1.0 - s / len };
                let uv = [c.uv[0][0] + t * (c.uv[1][0] - c.uv[0][0]), c.uv[0][1] + t * (c.uv[1][1] - c.uv[0][1])];
                let on_face = face.surface.eval(uv[0], uv[1]).0;
                let on_curve = edge.point(s);
                let d = vec3::norm(vec3::sub(on_face, on_curve));
                worst = worst.max(d);
                if !(d <= tol) {
                    return Err(bad(format!(
                        "face {fi}, edge {}: curve leaves the face boundary by {d:.3e} (tolerance {tol:.3e})",
                        c.edge
                    )));
                }
            }
        }
    }
    for (e, u) in uses.iter().enumerate() {
        if *u != [1, 1] {
            return Err(bad(format!(
                "edge {e} is used {} time(s) forward and {} backward; a closed shell needs once each",
                u[0], u[1]
            )));
        }
    }
    // One shell must be one connected piece (ISO 10303-42 connected_face_set).
    let mut uf = crate::geometry::topology::UnionFind::new(solid.faces.len());
    let mut edge_face = vec![u32::MAX; solid.edges.len()];
    for (fi, face) in solid.faces.iter().enumerate() {
        for c in &face.bound {
            match edge_face[c.edge as usize] {
                u32::MAX => edge_face[c.edge as usize] = fi as u32,
                other => uf.union(other, fi as u32),
            }
        }
    }
    if let Some(fi) = (0..solid.faces.len() as u32).find(|&f| uf.find(f) != 0) {
        let pieces = (0..solid.faces.len() as u32).filter(|&f| uf.find(f) == f).count();
        return Err(bad(format!(
            "the shell falls into {pieces} pieces: face {fi} is not connected to face 0; a closed shell must be \
             one connected piece"
        )));
    }
    Ok(worst)
}

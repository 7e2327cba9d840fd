//! Convex hulls in 3-D, and the faces a solid can rest on.
//!
//! [`convex_hull`] is incremental: the points are added in a fixed pseudo-random order; each point outside
//! the hull so far sees a connected set of faces (found by a walk across edges from the face it sees most),
//! which is replaced by a fan from the horizon to the point. Cost O(n·h) for n points and h hull faces (a
//! full scan of the faces per point): milliseconds for a few thousand points, a fraction of a second for
//! 50,000. Deterministic.
//!
//! [`resting_faces`] groups the hull's triangles into planar facets and keeps those a solid of uniform
//! density can rest on: its centre of mass projects inside the facet. What a person turning an object over
//! finds it settling on, and what the simulated rig does between two passes.

use std::collections::HashMap;

use crate::geometry::mesh::TriMesh;
use crate::geometry::sampling::Rng;
use crate::geometry::vec3::{Aabb, V3, add, cross, dot, norm, scale, sub, wide};

/// One face of a hull under construction: its corners (counter-clockwise seen from outside) and plane.
#[derive(Clone, Copy)]
struct Face {
    v: [u32; 3],
    n: V3,
    off: f64,
}

impl Face {
    fn new(p: &[V3], v: [u32; 3]) -> Face {
        let [a, b, c] = v.map(|i| p[i as usize]);
        let n = cross(sub(b, a), sub(c, a));
        let len = norm(n);
        let n = if len > 0.0 { scale(n, 1.0 / len) } else { n };
        Face { v, n, off: dot(n, a) }
    }

    fn height(&self, q: V3) -> f64 {
        dot(self.n, q) - self.off
    }

    fn edges(&self) -> [(u32, u32); 3] {
        let [a, b, c] = self.v;
        [(a, b), (b, c), (c, a)]
    }
}

/// The first tetrahedron: the extreme point along x, the farthest from it, the farthest from their line,
/// the farthest from their plane.
fn first_tetrahedron(p: &[V3], eps: f64) -> Result<[u32; 4], String> {
    let far = |key: &dyn Fn(V3) -> f64| {
        (0..p.len()).max_by(|&i, &j| key(p[i]).total_cmp(&key(p[j])).then(j.cmp(&i))).unwrap_or(0)
    };
    let a = far(&|q| -q[0]);
    let b = far(&|q| norm(sub(q, p[a])));
    let ab = sub(p[b], p[a]);
    if norm(ab) <= eps {
        return Err("the points all coincide".into());
    }
    let c = far(&|q| norm(cross(ab, sub(q, p[a]))) / norm(ab));
    let n = cross(ab, sub(p[c], p[a]));
    if norm(n) <= eps * norm(ab) {
        return Err("the points all lie on one line".into());
    }
    let d = far(&|q| dot(n, sub(q, p[a])).abs());
    if dot(n, sub(p[d], p[a])).abs() <= eps * norm(n) {
        return Err("the points all lie in one plane".into());
    }
    Ok([a, b, c, d].map(|i| i as u32))
}

/// The convex hull of `points`: triangles (indices into `points`), counter-clockwise seen from outside.
/// Points within 10⁻⁹ of the bounding box's diagonal of a face count as on it.
///
/// # Errors
/// A message when the points are fewer than four, not finite, or all in one plane.
pub fn convex_hull(points: &[V3]) -> Result<Vec<[u32; 3]>, String> {
    if points.len() < 4 {
        return Err(format!("{} points: a hull needs four", points.len()));
    }
    if points.iter().any(|q| q.iter().any(|c| !c.is_finite())) {
        return Err("a point is not finite".into());
    }
    let mut b = Aabb::EMPTY;
    points.iter().for_each(|&q| b.add(q));
    let eps = 1e-9 * b.diagonal();
    // 1. The first tetrahedron, its faces turned outward.
    let t = first_tetrahedron(points, eps)?;
    let mut faces: Vec<Option<Face>> = Vec::new();
    let mut by_edge: HashMap<(u32, u32), usize> = HashMap::new();
    let inner = scale(t.iter().fold([0.0; 3], |s, &i| add(s, points[i as usize])), 0.25);
    for skip in 0..4 {
        let v: Vec<u32> = (0..4).filter(|&k| k != skip).map(|k| t[k]).collect();
        let mut f = Face::new(points, [v[0], v[1], v[2]]);
        if f.height(inner) > 0.0 {
            f = Face::new(points, [v[0], v[2], v[1]]);
        }
        add_face(&mut faces, &mut by_edge, f);
    }
    // 2. Every other point, in a fixed shuffled order (sorted inputs would make the hull grow slowly).
    let mut order: Vec<u32> = (0..points.len() as u32).filter(|i| !t.contains(i)).collect();
    let mut rng = Rng::new(0x4855_4C4C);
    for k in (1..order.len()).rev() {
        order.swap(k, (rng.next_f64() * (k + 1) as f64) as usize % (k + 1));
    }
    for i in order {
        let q = points[i as usize];
        // The face it sees most, then the faces it sees connected to it.
        let Some((start, _)) = faces
            .iter()
            .enumerate()
            .filter_map(|(k, f)| f.map(|f| (k, f.height(q))))
            .filter(|&(_, h)| h > eps)
            .max_by(|a, b| a.1.total_cmp(&b.1).then(b.0.cmp(&a.0)))
        else {
            continue;
        };
        let mut visible = vec![start];
        let mut seen = std::collections::HashSet::from([start]);
        let mut next = 0;
        while next < visible.len() {
            let f = faces[visible[next]].expect("alive");
            next += 1;
            for (a, b) in f.edges() {
                if let Some(&g) = by_edge.get(&(b, a))
                    && !seen.contains(&g)
                    && faces[g].is_some_and(|g| g.height(q) > eps)
                {
                    seen.insert(g);
                    visible.push(g);
                }
            }
        }
        // The horizon: edges of seen faces whose twin is not seen.
        let mut horizon = Vec::new();
        for &k in &visible {
            let f = faces[k].expect("alive");
            for (a, b) in f.edges() {
                if by_edge.get(&(b, a)).is_none_or(|g| !seen.contains(g)) {
                    horizon.push((a, b));
                }
            }
        }
        for &k in &visible {
            let f = faces[k].take().expect("alive");
            for e in f.edges() {
                by_edge.remove(&e);
            }
        }
        for (a, b) in horizon {
            add_face(&mut faces, &mut by_edge, Face::new(points, [a, b, i]));
        }
    }
    Ok(faces.into_iter().flatten().map(|f| f.v).collect())
}

fn add_face(faces: &mut Vec<Option<Face>>, by_edge: &mut HashMap<(u32, u32), usize>, f: Face) {
    for e in f.edges() {
        by_edge.insert(e, faces.len());
    }
    faces.push(Some(f));
}

/// The centre of mass of a closed, outward-oriented mesh of uniform density, and its volume (signed
/// tetrahedra from the origin).
pub fn centre_of_mass(mesh: &TriMesh) -> (V3, f64) {
    let (mut c, mut vol) = ([0.0; 3], 0.0);
    for t in 0..mesh.triangles.len() {
        let [a, b, d] = mesh.corners(t);
        let v = dot(a, cross(b, d)) / 6.0;
        vol += v;
        c = add(c, scale(add(add(a, b), d), v / 4.0));
    }
    (if vol != 0.0 { scale(c, 1.0 / vol) } else { c }, vol)
}

/// A face a solid can rest on.
#[derive(Clone, Debug, PartialEq)]
pub struct Rest {
    /// The facet's outward unit normal (resting, it points down).
    pub normal: V3,
    /// The facet's plane offset: `dot(normal, p)` for its points.
    pub offset: f64,
    /// The support polygon's area.
    pub area: f64,
    /// How far the centre of mass projects inside the support polygon (its distance to the nearest edge).
    pub margin: f64,
    /// The centre of mass's height above the facet.
    pub height: f64,
}

impl Rest {
    /// The angle the solid must be tipped by before it falls off this face, degrees: how stable it rests.
    pub fn tipping_deg(&self) -> f64 {
        self.margin.atan2(self.height).to_degrees()
    }
}

/// The faces `mesh` (closed, outward) can rest on, most stable first ([`Rest::tipping_deg`]): the hull's
/// triangles grouped into facets (normals within 0.5°, corners within 10⁻⁶ of the diagonal of one plane), each
/// kept when the centre of mass projects inside it.
///
/// # Errors
/// Those of [`convex_hull`].
pub fn resting_faces(mesh: &TriMesh) -> Result<Vec<Rest>, String> {
    let points: Vec<V3> = mesh.positions.iter().map(|&p| wide(p)).collect();
    let hull = convex_hull(&points)?;
    let (com, _) = centre_of_mass(mesh);
    let diag = mesh.bbox().diagonal();
    let faces: Vec<Face> = hull.iter().map(|&v| Face::new(&points, v)).collect();
    let area = |f: &Face| {
        let [a, b, c] = f.v.map(|i| points[i as usize]);
        norm(cross(sub(b, a), sub(c, a))) / 2.0
    };
    let mut order: Vec<usize> = (0..faces.len()).collect();
    order.sort_by(|&i, &j| area(&faces[j]).total_cmp(&area(&faces[i])).then(i.cmp(&j)));
    let mut taken = vec![false; faces.len()];
    let mut rests = Vec::new();
    let cos_tol = 0.5f64.to_radians().cos();
    for &i in &order {
        if taken[i] {
            continue;
        }
        let f = faces[i];
        let mut corners = Vec::new();
        for &j in &order {
            let g = &faces[j];
            let on = |k: u32| (dot(f.n, points[k as usize]) - f.off).abs() <= 1e-6 * diag;
            if !taken[j] && dot(g.n, f.n) >= cos_tol && g.v.iter().all(|&k| on(k)) {
                taken[j] = true;
                corners.extend(g.v.map(|k| points[k as usize]));
            }
        }
        if let Some(r) = rest_on(f.n, f.off, &corners, com) {
            rests.push(r);
        }
    }
    rests.sort_by(|a, b| b.tipping_deg().total_cmp(&a.tipping_deg()));
    Ok(rests)
}

/// The rest on the facet of plane (`n`, `off`) with `corners`, when the centre of mass `com` projects
/// strictly inside its convex polygon.
fn rest_on(n: V3, off: f64, corners: &[V3], com: V3) -> Option<Rest> {
    let seed = if n[0].abs() < 0.9 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
    let u = cross(n, seed);
    let u = scale(u, 1.0 / norm(u));
    let w = cross(n, u);
    let flat = |p: V3| [dot(p, u), dot(p, w)];
    let poly = hull_2d(corners.iter().map(|&p| flat(p)).collect());
    if poly.len() < 3 {
        return None;
    }
    let c = flat(com);
    let mut margin = f64::INFINITY;
    let mut area = 0.0;
    for k in 0..poly.len() {
        let (a, b) = (poly[k], poly[(k + 1) % poly.len()]);
        let e = [b[0] - a[0], b[1] - a[1]];
        let len = e[0].hypot(e[1]);
        // Counter-clockwise: the inside is to the left.
        let left = (e[0] * (c[1] - a[1]) - e[1] * (c[0] - a[0])) / len;
        margin = margin.min(left);
        area += a[0] * b[1] - a[1] * b[0];
    }
    let height = off - dot(n, com);
    (margin > 0.0 && height > 0.0).then_some(Rest { normal: n, offset: off, area: area / 2.0, margin, height })
}

/// The convex hull of points in the plane, counter-clockwise (Andrew's monotone chain).
fn hull_2d(mut p: Vec<[f64; 2]>) -> Vec<[f64; 2]> {
    p.sort_by(|a, b| a[0].total_cmp(&b[0]).then(a[1].total_cmp(&b[1])));
    p.dedup();
    if p.len() < 3 {
        return p;
    }
    let turn = |o: [f64; 2], a: [f64; 2], b: [f64; 2]| (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]);
    let mut h: Vec<[f64; 2]> = Vec::with_capacity(2 * p.len());
    for pass in 0..2 {
        let start = h.len();
        let it: Box<dyn Iterator<Item = &[f64; 2]>> =
            if pass == 0 { Box::new(p.iter()) } else { Box::new(p.iter().rev()) };
        for &q in it {
            while h.len() >= start + 2 && turn(h[h.len() - 2], h[h.len() - 1], q) <= 0.0 {
                h.pop();
            }
            h.push(q);
        }
        h.pop();
    }
    h
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::sampling::Rng;

    /// Random points in a ball plus the eight corners of a cube around them: the hull is the cube (12
    /// triangles), every input point lies inside or on it, and its faces are closed and outward.
    #[test]
    fn the_hull_of_a_cube_with_points_inside_is_the_cube() {
        let mut rng = Rng::new(3);
        let mut p: Vec<V3> = (0..2000).map(|_| [0, 1, 2].map(|_| rng.next_f64() * 1.8 - 0.9)).collect();
        for k in 0..8 {
            p.push([k & 1, (k >> 1) & 1, (k >> 2) & 1].map(|b| if b == 1 { 1.0 } else { -1.0 }));
        }
        let h = convex_hull(&p).unwrap();
        assert_eq!(h.len(), 12, "{h:?}");
        assert!(h.iter().flatten().all(|&i| i >= 2000), "only the corners are on the hull");
        let mesh = TriMesh { positions: p.iter().map(|q| q.map(|c| c as f32)).collect(), triangles: h.clone() };
        let (_, vol) = centre_of_mass(&mesh);
        assert!((vol - 8.0).abs() < 1e-9, "volume {vol}");
        for t in &h {
            let f = Face::new(&p, *t);
            assert!(p.iter().all(|&q| f.height(q) <= 1e-9), "a point lies outside a face");
        }
    }

    /// Points on a sphere are all on its hull: the hull is a closed triangulation (Euler: F = 2V − 4).
    #[test]
    fn points_on_a_sphere_are_all_hull_vertices() {
        let mut rng = Rng::new(9);
        let p: Vec<V3> = (0..500)
            .map(|_| {
                let v = [0, 1, 2].map(|_| rng.next_f64() * 2.0 - 1.0);
                scale(v, 1.0 / norm(v))
            })
            .collect();
        let h = convex_hull(&p).unwrap();
        assert_eq!(h.len(), 2 * 500 - 4);
        assert!(convex_hull(&[[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0]]).is_err(), "flat");
    }

    /// A 1 × 2 × 4 box rests on each of its six faces; the big faces are the most stable (tipping 63.4°
    /// lying flat on 2 × 4, 14.0° standing on 1 × 2).
    #[test]
    fn a_box_rests_on_its_faces_most_stable_first() {
        let block = crate::geometry::shapes::cuboid([-0.5, -1.0, -2.0], [0.5, 1.0, 2.0]);
        let rests = resting_faces(&block).unwrap();
        assert_eq!(rests.len(), 6, "{rests:?}");
        assert!(rests[0].normal[0].abs() > 0.99, "{:?}", rests[0]);
        assert!((rests[0].tipping_deg() - 63.43).abs() < 0.01, "{}", rests[0].tipping_deg());
        assert!((rests[5].tipping_deg() - 14.04).abs() < 0.01, "{}", rests[5].tipping_deg());
        assert!((rests[0].area - 8.0).abs() < 1e-9);
    }
}

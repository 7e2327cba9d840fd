//! Triangle–triangle intersection and self-intersection search.
//!
//! The test is Möller's interval method ("A fast triangle-triangle intersection test", 1997) in f64, with a
//! 2-D overlap test for coplanar pairs. Triangles that share an edge are never reported (they meet along
//! it); triangles that share one vertex are reported only when an edge of one crosses the other away from
//! that vertex. Tolerances are relative to the triangles' size.

use rayon::prelude::*;

use crate::geometry::bvh::{BoxTree, box_of};
use crate::geometry::vec3::{V3, cross, dot, norm2, sub};

/// Relative tolerance for "on the plane" (fraction of |n|·edge length).
const PLANE_EPS: f64 = 1e-12;

fn interval(p: [f64; 3], d: [f64; 3]) -> Option<(f64, f64)> {
    let alone = if d[0] * d[1] > 0.0 {
        2
    } else if d[0] * d[2] > 0.0 {
        1
    } else if d[1] * d[2] > 0.0 || d[0] != 0.0 {
        0
    } else if d[1] != 0.0 {
        1
    } else if d[2] != 0.0 {
        2
    } else {
        return None;
    };
    let (a, b) = ((alone + 1) % 3, (alone + 2) % 3);
    let t = |o: usize| p[o] + (p[alone] - p[o]) * d[o] / (d[o] - d[alone]);
    let (t1, t2) = (t(a), t(b));
    Some((t1.min(t2), t1.max(t2)))
}

fn signed_dists(n: V3, p0: V3, q: &[V3; 3], scale: f64) -> [f64; 3] {
    let eps = PLANE_EPS * scale;
    q.map(|x| {
        let d = dot(n, sub(x, p0));
        if d.abs() < eps { 0.0 } else { d }
    })
}

/// 2-D segment intersection (proper or touching).
fn seg2(a: [f64; 2], b: [f64; 2], c: [f64; 2], d: [f64; 2]) -> bool {
    let orient = |p: [f64; 2], q: [f64; 2], r: [f64; 2]| (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0]);
    let (o1, o2, o3, o4) = (orient(a, b, c), orient(a, b, d), orient(c, d, a), orient(c, d, b));
    o1 * o2 < 0.0 && o3 * o4 < 0.0
}

fn inside2(p: [f64; 2], t: [[f64; 2]; 3]) -> bool {
    let orient = |a: [f64; 2], b: [f64; 2]| (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0]);
    let (s0, s1, s2) = (orient(t[0], t[1]), orient(t[1], t[2]), orient(t[2], t[0]));
    (s0 > 0.0 && s1 > 0.0 && s2 > 0.0) || (s0 < 0.0 && s1 < 0.0 && s2 < 0.0)
}

fn coplanar(n: V3, v: &[V3; 3], u: &[V3; 3]) -> bool {
    let k = (0..3).max_by(|&a, &b| n[a].abs().total_cmp(&n[b].abs())).unwrap();
    let (i, j) = ((k + 1) % 3, (k + 2) % 3);
    let v2 = v.map(|p| [p[i], p[j]]);
    let u2 = u.map(|p| [p[i], p[j]]);
    for a in 0..3 {
        for b in 0..3 {
            if seg2(v2[a], v2[(a + 1) % 3], u2[b], u2[(b + 1) % 3]) {
                return true;
            }
        }
    }
    v2.iter().any(|&p| inside2(p, u2)) || u2.iter().any(|&p| inside2(p, v2))
}

/// Do the closed triangles `v` and `u` intersect? (Shared vertices are not treated specially here.)
pub fn triangles_intersect(v: &[V3; 3], u: &[V3; 3]) -> bool {
    let n1 = cross(sub(v[1], v[0]), sub(v[2], v[0]));
    let n2 = cross(sub(u[1], u[0]), sub(u[2], u[0]));
    let len2 = |t: &[V3; 3]| norm2(sub(t[1], t[0])).max(norm2(sub(t[2], t[0]))).max(norm2(sub(t[2], t[1])));
    let scale2 = len2(v).max(len2(u));
    let du = signed_dists(n1, v[0], u, (norm2(n1) * scale2).sqrt());
    if du.iter().all(|&d| d > 0.0) || du.iter().all(|&d| d < 0.0) {
        return false;
    }
    let dv = signed_dists(n2, u[0], v, (norm2(n2) * scale2).sqrt());
    if dv.iter().all(|&d| d > 0.0) || dv.iter().all(|&d| d < 0.0) {
        return false;
    }
    if du.iter().all(|&d| d == 0.0) {
        return coplanar(n1, v, u);
    }
    let dir = cross(n1, n2);
    let k = (0..3).max_by(|&a, &b| dir[a].abs().total_cmp(&dir[b].abs())).unwrap();
    let (Some(a), Some(b)) = (interval(v.map(|p| p[k]), dv), interval(u.map(|p| p[k]), du)) else {
        return coplanar(n1, v, u);
    };
    a.1 >= b.0 && b.1 >= a.0
}

/// Does the segment p→q cross triangle t at a point other than its endpoints' neighbourhood of p?
/// (Möller–Trumbore; parallel segments do not count.)
fn segment_hits(p: V3, q: V3, t: &[V3; 3]) -> bool {
    let d = sub(q, p);
    let (e1, e2) = (sub(t[1], t[0]), sub(t[2], t[0]));
    let h = cross(d, e2);
    let a = dot(e1, h);
    if a * a <= 1e-28 * norm2(d) * norm2(e1) * norm2(e2) {
        return false;
    }
    let f = 1.0 / a;
    let s = sub(p, t[0]);
    let u = f * dot(s, h);
    let qv = cross(s, e1);
    let v = f * dot(d, qv);
    let w = f * dot(e2, qv);
    let eps = 1e-9;
    u > eps && v > eps && u + v < 1.0 - eps && w > eps && w < 1.0 - eps
}

/// Do two triangles of one mesh intersect other than along what they share? Corners are shared when they
/// are the same vertex or two vertices at exactly the same position (e.g. copies made to split a pinched
/// vertex): surfaces that only touch there do not cross.
pub fn mesh_triangles_intersect(p: &[V3], a: [u32; 3], b: [u32; 3]) -> bool {
    let ta = a.map(|i| p[i as usize]);
    let tb = b.map(|i| p[i as usize]);
    let same = |i: usize, j: usize| a[i] == b[j] || ta[i] == tb[j];
    let mut shared = (0..3).filter(|&i| (0..3).any(|j| same(i, j)));
    match (shared.next(), shared.count()) {
        (None, _) => triangles_intersect(&ta, &tb),
        (Some(ka), 0) => {
            // The edge opposite the shared corner of each must not pierce the other.
            let kb = (0..3).find(|&j| same(ka, j)).unwrap();
            let (a1, a2) = (ta[(ka + 1) % 3], ta[(ka + 2) % 3]);
            let (b1, b2) = (tb[(kb + 1) % 3], tb[(kb + 2) % 3]);
            segment_hits(a1, a2, &tb) || segment_hits(b1, b2, &ta)
        }
        _ => false,
    }
}

/// All pairs (i < j) of intersecting triangles, sorted. Cost: O(F log F) for typical meshes (BVH), parallel.
pub fn self_intersections(p: &[V3], tris: &[[u32; 3]]) -> Vec<(u32, u32)> {
    self_intersections_involving(p, tris, 0)
}

/// Intersecting pairs (i < j, sorted) in which at least one triangle is in `faces` (sorted, deduplicated).
pub fn self_intersections_of(p: &[V3], tris: &[[u32; 3]], faces: &[u32]) -> Vec<(u32, u32)> {
    pairs_from(p, tris, faces.par_iter().copied(), |j| faces.binary_search(&j).is_ok())
}

/// Intersecting pairs (i < j, sorted) in which at least one triangle has index ≥ `first_new`: after faces
/// are appended to a mesh known to be free of intersections, only the new ones need checking.
pub fn self_intersections_involving(p: &[V3], tris: &[[u32; 3]], first_new: usize) -> Vec<(u32, u32)> {
    pairs_from(p, tris, (first_new as u32..tris.len() as u32).into_par_iter(), |j| j as usize >= first_new)
}

/// Intersecting pairs found by querying the triangles `from` against all; `queried(j)` tells whether `j` is
/// queried itself (then the pair is counted from the smaller index only).
fn pairs_from(
    p: &[V3],
    tris: &[[u32; 3]],
    from: impl ParallelIterator<Item = u32>,
    queried: impl Fn(u32) -> bool + Sync,
) -> Vec<(u32, u32)> {
    let boxes: Vec<_> = tris.par_iter().map(|t| box_of(&t.map(|i| p[i as usize]))).collect();
    let tree = BoxTree::new(&boxes);
    let mut pairs: Vec<(u32, u32)> = from
        .flat_map_iter(|i| {
            let mut found = Vec::new();
            let (lo, hi) = boxes[i as usize];
            tree.overlapping(lo, hi, |j| {
                let counted = if queried(j) { j > i } else { true };
                if counted && mesh_triangles_intersect(p, tris[i as usize], tris[j as usize]) {
                    found.push((i.min(j), i.max(j)));
                }
            });
            found
        })
        .collect();
    pairs.sort_unstable();
    pairs
}

/// Brute force over all pairs: for tests on small meshes. Cost O(F²).
pub fn self_intersections_brute_force(p: &[V3], tris: &[[u32; 3]]) -> Vec<(u32, u32)> {
    let mut out = Vec::new();
    for i in 0..tris.len() {
        for j in i + 1..tris.len() {
            if mesh_triangles_intersect(p, tris[i], tris[j]) {
                out.push((i as u32, j as u32));
            }
        }
    }
    out
}

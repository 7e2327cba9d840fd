//! Bounding-volume hierarchies for closest-point queries on triangles and points.
//!
//! The tree is built top-down by median split on the axis of largest centroid spread (O(n log n), depth
//! ≤ 2·log₂ n), with up to [`LEAF_SIZE`] primitives per leaf. Primitives are copied into leaf order so a leaf's
//! primitives are contiguous in memory. Boxes are f32 (exact for f32 vertex data); distances are f64.
//! A query descends the nearer child first and prunes boxes farther than the best distance found: about
//! O(log n) for points near the surface.

use crate::geometry::mesh::{PointCloud, TriMesh};
use crate::geometry::vec3::{self, V3, wide};

/// Most primitives per leaf.
pub const LEAF_SIZE: usize = 4;

#[derive(Copy, Clone, Debug)]
struct Node {
    min: [f32; 3],
    max: [f32; 3],
    /// Leaf: first primitive (in leaf order). Inner: index of the left child (the right one follows it).
    start: u32,
    /// Leaf: number of primitives (> 0). Inner: 0.
    count: u32,
}

/// Squared distance from `p` to the box of `n` (0 inside).
#[inline]
fn box_dist2(n: &Node, p: V3) -> f64 {
    aabb_dist2(n.min, n.max, p)
}

/// Squared distance from `p` to the box `[min, max]` (0 inside).
#[inline]
fn aabb_dist2(min: [f32; 3], max: [f32; 3], p: V3) -> f64 {
    let mut d2 = 0.0;
    for k in 0..3 {
        let lo = min[k] as f64;
        let hi = max[k] as f64;
        let d = if p[k] < lo {
            lo - p[k]
        } else if p[k] > hi {
            p[k] - hi
        } else {
            0.0
        };
        d2 += d * d;
    }
    d2
}

/// The tree over abstract primitives, each given by its f32 bounding box.
#[derive(Clone, Debug)]
struct Tree {
    nodes: Vec<Node>,
    /// Original primitive id of each leaf-order slot.
    order: Vec<u32>,
}

impl Tree {
    fn build(boxes: &[([f32; 3], [f32; 3])]) -> Tree {
        let n = boxes.len();
        let mut order: Vec<u32> = (0..n as u32).collect();
        let centroid = |i: u32, k: usize| boxes[i as usize].0[k] + boxes[i as usize].1[k];
        let mut nodes = vec![Node { min: [0.0; 3], max: [0.0; 3], start: 0, count: 0 }];
        if n == 0 {
            return Tree { nodes, order };
        }
        // (node index, range start, range end)
        let mut work = vec![(0usize, 0usize, n)];
        while let Some((ni, s, e)) = work.pop() {
            let mut min = [f32::INFINITY; 3];
            let mut max = [f32::NEG_INFINITY; 3];
            let mut cmin = [f32::INFINITY; 3];
            let mut cmax = [f32::NEG_INFINITY; 3];
            for &i in &order[s..e] {
                let (bmin, bmax) = boxes[i as usize];
                for k in 0..3 {
                    min[k] = min[k].min(bmin[k]);
                    max[k] = max[k].max(bmax[k]);
                    let c = centroid(i, k);
                    cmin[k] = cmin[k].min(c);
                    cmax[k] = cmax[k].max(c);
                }
            }
            let axis = (0..3).max_by(|&a, &b| (cmax[a] - cmin[a]).total_cmp(&(cmax[b] - cmin[b]))).unwrap();
            if e - s <= LEAF_SIZE || cmax[axis] <= cmin[axis] && e - s <= 4 * LEAF_SIZE {
                nodes[ni] = Node { min, max, start: s as u32, count: (e - s) as u32 };
                continue;
            }
            let mid = s + (e - s) / 2;
            order[s..e].select_nth_unstable_by(mid - s, |&a, &b| {
                centroid(a, axis).total_cmp(&centroid(b, axis)).then(a.cmp(&b))
            });
            let left = nodes.len();
            nodes.push(Node { min, max, start: 0, count: 0 });
            nodes.push(Node { min, max, start: 0, count: 0 });
            nodes[ni] = Node { min, max, start: left as u32, count: 0 };
            work.push((left + 1, mid, e));
            work.push((left, s, mid));
        }
        Tree { nodes, order }
    }

    /// Call `f(slot)` for every primitive whose box overlaps the box `[min, max]`.
    fn overlapping(&self, min: [f32; 3], max: [f32; 3], mut f: impl FnMut(usize)) {
        if self.order.is_empty() {
            return;
        }
        let overlaps = |n: &Node| (0..3).all(|k| n.min[k] <= max[k] && n.max[k] >= min[k]);
        let mut stack: [u32; 64] = [0; 64];
        let mut sp = 1;
        while sp > 0 {
            sp -= 1;
            let node = &self.nodes[stack[sp] as usize];
            if !overlaps(node) {
                continue;
            }
            if node.count > 0 {
                (node.start as usize..(node.start + node.count) as usize).for_each(&mut f);
            } else {
                stack[sp] = node.start;
                stack[sp + 1] = node.start + 1;
                sp += 2;
            }
        }
    }

    /// Nearest primitive to `p` whose squared distance (from `dist2(slot, best)`, slot in leaf order, `best`
    /// the smallest found so far: `dist2` may answer ∞ for a primitive it can tell is no nearer) is below
    /// `bound2`. Returns (slot, squared distance).
    #[inline]
    fn nearest(&self, p: V3, bound2: f64, mut dist2: impl FnMut(usize, f64) -> f64) -> Option<(usize, f64)> {
        if self.order.is_empty() {
            return None;
        }
        let mut best = bound2;
        let mut hit = None;
        let mut stack: [(u32, f64); 64] = [(0, 0.0); 64];
        let mut sp = 0;
        stack[sp] = (0, box_dist2(&self.nodes[0], p));
        sp += 1;
        while sp > 0 {
            sp -= 1;
            let (ni, d2) = stack[sp];
            if d2 >= best {
                continue;
            }
            let node = &self.nodes[ni as usize];
            if node.count > 0 {
                let s = node.start as usize;
                for slot in s..s + node.count as usize {
                    let d = dist2(slot, best);
                    if d < best {
                        best = d;
                        hit = Some((slot, d));
                    }
                }
            } else {
                let l = node.start;
                let (dl, dr) = (box_dist2(&self.nodes[l as usize], p), box_dist2(&self.nodes[l as usize + 1], p));
                let (near, dn, far, df) = if dl <= dr { (l, dl, l + 1, dr) } else { (l + 1, dr, l, dl) };
                if df < best {
                    stack[sp] = (far, df);
                    sp += 1;
                }
                if dn < best {
                    stack[sp] = (near, dn);
                    sp += 1;
                }
            }
        }
        hit
    }
}

/// Closest point to `p` on triangle (a, b, c), by Voronoi regions (Ericson, *Real-Time Collision Detection*,
/// §5.1.5). Exact up to floating-point rounding, robust for degenerate triangles. Returns the point.
#[inline]
pub fn closest_point_on_triangle(p: V3, a: V3, b: V3, c: V3) -> V3 {
    use vec3::{add, dot, scale, sub};
    let ab = sub(b, a);
    let ac = sub(c, a);
    let ap = sub(p, a);
    let d1 = dot(ab, ap);
    let d2 = dot(ac, ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = sub(p, b);
    let d3 = dot(ab, bp);
    let d4 = dot(ac, bp);
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return add(a, scale(ab, v));
    }
    let cp = sub(p, c);
    let d5 = dot(ab, cp);
    let d6 = dot(ac, cp);
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return add(a, scale(ac, w));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return add(b, scale(sub(c, b), w));
    }
    let denom = va + vb + vc;
    if !(denom.abs() > 0.0) {
        // Degenerate (collinear) triangle that escaped the edge tests: fall back to the nearest corner.
        let da = vec3::norm2(sub(p, a));
        let db = vec3::norm2(sub(p, b));
        let dc = vec3::norm2(sub(p, c));
        return if da <= db && da <= dc {
            a
        } else if db <= dc {
            b
        } else {
            c
        };
    }
    let v = vb / denom;
    let w = vc / denom;
    add(a, add(scale(ab, v), scale(ac, w)))
}

/// Result of a closest-point query.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Closest {
    /// Index of the triangle (or point) in the source.
    pub index: u32,
    /// The closest point.
    pub point: V3,
    /// Euclidean distance.
    pub distance: f64,
}

/// Barycentric slack of [`TriangleBvh::ray_hit`]: a hit this close outside a triangle still counts.
pub const RAY_EDGE_SLACK: f64 = 1e-9;

/// BVH over the triangles of a mesh.
#[derive(Clone, Debug)]
pub struct TriangleBvh {
    tree: Tree,
    /// Triangle corners in leaf order.
    tris: Vec<[[f32; 3]; 3]>,
    /// Leaf-order slot of each source triangle (the inverse of `tree.order`), for hinted queries.
    slot_of: Vec<u32>,
}

impl TriangleBvh {
    /// Build over all triangles of `mesh`. Cost: O(F log F) time, ≈ 36·F + 32·(2F/LEAF_SIZE) bytes.
    pub fn new(mesh: &TriMesh) -> Self {
        let corners = |t: &[u32; 3]| t.map(|i| mesh.positions[i as usize]);
        let boxes: Vec<_> = mesh
            .triangles
            .iter()
            .map(|t| {
                let c = corners(t);
                let mut lo = c[0];
                let mut hi = c[0];
                for p in &c[1..] {
                    for k in 0..3 {
                        lo[k] = lo[k].min(p[k]);
                        hi[k] = hi[k].max(p[k]);
                    }
                }
                (lo, hi)
            })
            .collect();
        let tree = Tree::build(&boxes);
        let tris = tree.order.iter().map(|&t| corners(&mesh.triangles[t as usize])).collect();
        let mut slot_of = vec![0u32; tree.order.len()];
        for (slot, &t) in tree.order.iter().enumerate() {
            slot_of[t as usize] = slot as u32;
        }
        TriangleBvh { tree, tris, slot_of }
    }

    /// Approximate heap bytes used.
    pub fn memory_bytes(&self) -> usize {
        self.tree.nodes.len() * std::mem::size_of::<Node>() + self.tree.order.len() * 8 + self.tris.len() * 36
    }

    /// The closest point on the mesh to `p`, or `None` for a mesh without triangles.
    pub fn closest(&self, p: V3) -> Option<Closest> {
        self.closest_hinted(p, None)
    }

    /// [`TriangleBvh::closest`], bit for bit, started from the distance to triangle `hint` (a source index,
    /// e.g. the previous answer for a point that moved a little): the search then prunes every box farther
    /// than that triangle at once. The bound is the next float above the hint's squared distance, so the
    /// answer (the first nearest triangle in the tree's order) is the unhinted one even on ties. A hint out
    /// of range is ignored. Cost: as `closest`, less the boxes the bound prunes.
    pub fn closest_hinted(&self, p: V3, hint: Option<u32>) -> Option<Closest> {
        self.nearest_from(p, hint, |slot, best| self.dist2(slot, p, best))
    }

    /// The closest point to `p` on a triangle whose (unnormalised, corner-order) normal `n_t` satisfies
    /// `n_t · facing > 0`, i.e. a triangle facing the same way as `facing`; `None` when there is none.
    /// Used to project onto the right sheet of a thin part. Cost: as [`TriangleBvh::closest`], more when
    /// many near triangles face away.
    pub fn closest_facing(&self, p: V3, facing: V3) -> Option<Closest> {
        self.closest_facing_hinted(p, facing, None)
    }

    /// [`TriangleBvh::closest_facing`], bit for bit, started from the distance to triangle `hint` (ignored
    /// when it faces away or is out of range), as [`TriangleBvh::closest_hinted`].
    pub fn closest_facing_hinted(&self, p: V3, facing: V3, hint: Option<u32>) -> Option<Closest> {
        self.nearest_from(p, hint, |slot, best| self.facing_dist2(slot, p, facing, best))
    }

    /// The nearest triangle to `p` by `dist2` (∞ for triangles that do not qualify), searched within the
    /// next float above the hint's distance first and, when that finds none (a hint that does not qualify,
    /// or none given), without bound.
    fn nearest_from(&self, p: V3, hint: Option<u32>, dist2: impl Fn(usize, f64) -> f64) -> Option<Closest> {
        let slot = hint.and_then(|h| self.slot_of.get(h as usize)).map(|&s| s as usize);
        let bound = slot.map_or(f64::INFINITY, |s| dist2(s, f64::INFINITY).next_up());
        let (slot, d2) = self
            .tree
            .nearest(p, bound, &dist2)
            .or_else(|| if bound == f64::INFINITY { None } else { self.tree.nearest(p, f64::INFINITY, &dist2) })?;
        let [a, b, c] = self.tris[slot].map(wide);
        let point = closest_point_on_triangle(p, a, b, c);
        Some(Closest { index: self.tree.order[slot], point, distance: d2.sqrt() })
    }

    /// The squared distance from `p` to leaf slot `slot` when that triangle faces along `facing`, else ∞
    /// (∞ too when its box is farther than `best`).
    #[inline]
    fn facing_dist2(&self, slot: usize, p: V3, facing: V3, best: f64) -> f64 {
        if self.box_dist2(slot, p) >= best {
            return f64::INFINITY;
        }
        let [a, b, c] = self.tris[slot].map(wide);
        if vec3::dot(vec3::cross(vec3::sub(b, a), vec3::sub(c, a)), facing) <= 0.0 {
            return f64::INFINITY;
        }
        vec3::norm2(vec3::sub(p, closest_point_on_triangle(p, a, b, c)))
    }

    /// Distance along the ray `origin + t·dir` (barycentric slack [`RAY_EDGE_SLACK`], so a ray through an
    /// edge or a vertex cannot slip between its triangles) (`dir` a unit vector) to the first triangle hit with
    /// `t_min < t < t_max` whose (corner-order) normal `n_t` has `sign · (n_t · dir) > 0` (`sign` = 1: a
    /// triangle seen from behind, i.e. leaving the solid; −1: seen from the front). `None` when none is hit.
    /// Cost: O(log F) for a short ray, up to the triangles whose boxes the ray passes.
    pub fn ray_hit(&self, origin: V3, dir: V3, t_min: f64, t_max: f64, sign: f64) -> Option<f64> {
        self.ray_walk(origin, dir, t_min, t_max, Some(sign)).map(|(t, _)| t)
    }

    /// The first triangle the ray `origin + t·dir` (`dir` a unit vector) meets with `t_min < t < t_max`, from
    /// either side: its distance `t` and its unit (corner-order) normal. `None` when none is hit. Cost: as
    /// [`ray_hit`](Self::ray_hit).
    pub fn ray_first(&self, origin: V3, dir: V3, t_min: f64, t_max: f64) -> Option<(f64, V3)> {
        self.ray_walk(origin, dir, t_min, t_max, None).map(|(t, slot)| {
            let [a, b, c] = self.tris[slot].map(wide);
            let n = vec3::cross(vec3::sub(b, a), vec3::sub(c, a));
            let len = vec3::norm(n);
            (t, if len > 0.0 { vec3::scale(n, 1.0 / len) } else { [0.0, 0.0, 0.0] })
        })
    }

    /// The nearest hit and its leaf slot; `sign` filters by facing as [`ray_hit`](Self::ray_hit) says (`None`: both).
    fn ray_walk(&self, origin: V3, dir: V3, t_min: f64, t_max: f64, sign: Option<f64>) -> Option<(f64, usize)> {
        let nodes = &self.tree.nodes;
        if nodes.is_empty() {
            return None;
        }
        let inv = dir.map(|d| if d.abs() > 1e-300 { 1.0 / d } else { f64::INFINITY.copysign(d) });
        let slab = |n: &Node, best: f64| -> bool {
            let (mut t0, mut t1) = (t_min, best);
            for k in 0..3 {
                let a = (n.min[k] as f64 - origin[k]) * inv[k];
                let b = (n.max[k] as f64 - origin[k]) * inv[k];
                let (lo, hi) = if a <= b { (a, b) } else { (b, a) };
                t0 = t0.max(lo);
                t1 = t1.min(hi);
                if !(t0 <= t1) {
                    return false;
                }
            }
            true
        };
        let mut best = t_max;
        let mut hit = None;
        let mut stack: Vec<u32> = vec![0];
        while let Some(ni) = stack.pop() {
            let node = &nodes[ni as usize];
            if !slab(node, best) {
                continue;
            }
            if node.count > 0 {
                let s0 = node.start as usize;
                for slot in s0..s0 + node.count as usize {
                    let [a, b, c] = self.tris[slot].map(wide);
                    let (e1, e2) = (vec3::sub(b, a), vec3::sub(c, a));
                    let n = vec3::cross(e1, e2);
                    if sign.is_some_and(|s| s * vec3::dot(n, dir) <= 0.0) {
                        continue;
                    }
                    // Möller–Trumbore.
                    let pv = vec3::cross(dir, e2);
                    let det = vec3::dot(e1, pv);
                    if det.abs() < 1e-300 {
                        continue;
                    }
                    let id = 1.0 / det;
                    let tv = vec3::sub(origin, a);
                    let u = vec3::dot(tv, pv) * id;
                    if !(-RAY_EDGE_SLACK..=1.0 + RAY_EDGE_SLACK).contains(&u) {
                        continue;
                    }
                    let qv = vec3::cross(tv, e1);
                    let v = vec3::dot(dir, qv) * id;
                    if v < -RAY_EDGE_SLACK || u + v > 1.0 + RAY_EDGE_SLACK {
                        continue;
                    }
                    let t = vec3::dot(e2, qv) * id;
                    if t > t_min && t < best {
                        best = t;
                        hit = Some(slot);
                    }
                }
            } else {
                stack.push(node.start);
                stack.push(node.start + 1);
            }
        }
        hit.map(|slot| (best, slot))
    }

    /// The squared distance from `p` to leaf slot `slot`, or ∞ when the triangle's box is already farther than
    /// `best` (the closest point lies in the box, so the triangle cannot be nearer).
    #[inline]
    fn dist2(&self, slot: usize, p: V3, best: f64) -> f64 {
        if self.box_dist2(slot, p) >= best {
            return f64::INFINITY;
        }
        let [a, b, c] = self.tris[slot].map(wide);
        vec3::norm2(vec3::sub(p, closest_point_on_triangle(p, a, b, c)))
    }

    /// A lower bound on the squared distance from `p` to leaf slot `slot`: the distance to its corners' box,
    /// less a relative 1e-9 so that rounding in the closest-point arithmetic never makes it exceed the exact
    /// answer (the search's answers stay bit for bit those of a search without it).
    #[inline]
    fn box_dist2(&self, slot: usize, p: V3) -> f64 {
        let [a, b, c] = &self.tris[slot];
        let min = std::array::from_fn(|k| a[k].min(b[k]).min(c[k]));
        let max = std::array::from_fn(|k| a[k].max(b[k]).max(c[k]));
        aabb_dist2(min, max, p) * (1.0 - 1e-9)
    }

    /// Distance from `p` to the mesh (infinite for a mesh without triangles).
    #[inline]
    pub fn distance(&self, p: V3) -> f64 {
        self.tree
            .nearest(p, f64::INFINITY, |slot, best| self.dist2(slot, p, best))
            .map_or(f64::INFINITY, |(_, d2)| d2.sqrt())
    }
}

/// BVH over the points of a cloud, for nearest-neighbour queries.
#[derive(Clone, Debug)]
pub struct PointBvh {
    tree: Tree,
    points: Vec<[f32; 3]>,
}

impl PointBvh {
    /// Build over `points`. Cost: O(n log n).
    pub fn new(points: &[[f32; 3]]) -> Self {
        let boxes: Vec<_> = points.iter().map(|&p| (p, p)).collect();
        let tree = Tree::build(&boxes);
        let points = tree.order.iter().map(|&i| points[i as usize]).collect();
        PointBvh { tree, points }
    }

    /// Build over a cloud's points.
    pub fn from_cloud(cloud: &PointCloud) -> Self {
        Self::new(&cloud.positions)
    }

    /// Approximate heap bytes used.
    pub fn memory_bytes(&self) -> usize {
        self.tree.nodes.len() * std::mem::size_of::<Node>() + self.tree.order.len() * 4 + self.points.len() * 12
    }

    /// Nearest point to `p`.
    pub fn closest(&self, p: V3) -> Option<Closest> {
        let (slot, d2) = self.tree.nearest(p, f64::INFINITY, |s, _| vec3::norm2(vec3::sub(p, wide(self.points[s]))))?;
        Some(Closest { index: self.tree.order[slot], point: wide(self.points[slot]), distance: d2.sqrt() })
    }

    /// Distance from `p` to the nearest point (infinite for an empty cloud).
    #[inline]
    pub fn distance(&self, p: V3) -> f64 {
        self.tree
            .nearest(p, f64::INFINITY, |s, _| vec3::norm2(vec3::sub(p, wide(self.points[s]))))
            .map_or(f64::INFINITY, |(_, d2)| d2.sqrt())
    }
}

/// A BVH over axis-aligned boxes, for overlap queries (e.g. candidate pairs of intersecting triangles).
#[derive(Clone, Debug)]
pub struct BoxTree {
    tree: Tree,
}

/// The f32 box that contains the f64 points (rounded outward).
pub fn box_of(points: &[V3]) -> ([f32; 3], [f32; 3]) {
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for p in points {
        for k in 0..3 {
            let (d, u) = ((p[k] as f32).next_down(), (p[k] as f32).next_up());
            lo[k] = lo[k].min(d);
            hi[k] = hi[k].max(u);
        }
    }
    (lo, hi)
}

impl BoxTree {
    /// Build over `boxes` (index = primitive id). Cost: O(n log n).
    pub fn new(boxes: &[([f32; 3], [f32; 3])]) -> Self {
        BoxTree { tree: Tree::build(boxes) }
    }

    /// Call `f(id)` for every box overlapping `[min, max]`.
    pub fn overlapping(&self, min: [f32; 3], max: [f32; 3], mut f: impl FnMut(u32)) {
        self.tree.overlapping(min, max, |slot| f(self.tree.order[slot]));
    }
}

//! Step 5: fill every hole (Liepa 2003, "Filling holes in meshes").
//!
//! 1. **Triangulate** each boundary loop by a minimum-weight triangulation (dynamic programming, O(n³)); the
//!    weight is lexicographic: first the worst dihedral angle the patch makes (with the mesh across the loop
//!    and inside itself), then the total area. Degenerate triangles count as a 180° angle; triangles that
//!    would cross the existing surface, or reuse an existing edge, are not candidates. Loops longer than
//!    [`MWT_MAX_LOOP`] are first clipped down by ears of smallest angle.
//! 2. **Refine** so the patch density matches its surroundings: a triangle is split at its centroid when the
//!    centroid is farther than σ/√2 from each corner (σ = local edge length, interpolated from the loop), and
//!    patch edges are flipped towards Delaunay after each round.
//! 3. **Fair**: the new vertices minimise the discrete thin-plate energy Σ|L(x)|² (uniform umbrella L over
//!    the patch and its boundary ring, the rest fixed), solved by conjugate gradients on the normal equations,
//!    so the fill continues the surrounding curvature instead of lying flat. The boundary rows take their
//!    fixed positions from a quadric fitted around the loop ([`rim_anchors`]), so rim noise does not ripple
//!    into the fill.
//!
//! **Caps.** A large hole (the open base of a statue, a bust's cut) is not faired: thin-plate fairing would
//! continue the walls past the rim into a bulge (3.7 % of the diagonal below a lion's base). Such a hole is
//! triangulated in its rim's plane (`caps::triangulate_in_plane`; step 1 is the fallback when the projected
//! rim is not simple) and refined as above, then capped in that plane or by a membrane spanning its rim
//! ([`super::caps`], which also says how a hole is judged large). Each hole's decision and each cap are
//! reported; every fill's triangles are kept as the invented surface ([`InventedSurface`]).

use std::collections::{HashMap, HashSet};

use super::caps::{self, Cap, HoleDecision};
use crate::geometry::bvh::{BoxTree, box_of};
use crate::geometry::intersect::mesh_triangles_intersect;
use crate::geometry::linalg::solve_dense;
use crate::geometry::topology::{MeshTopology, VertexFaces};
use crate::geometry::vec3::{self, V3, tri_area, tri_unit_normal};

/// Longest loop triangulated by the O(n³) dynamic programme; longer loops are ear-clipped down to it first.
pub const MWT_MAX_LOOP: usize = 240;
/// Refinement rounds at most (each can split every patch triangle).
const REFINE_ROUNDS: usize = 40;
/// Conjugate-gradient iterations at most for fairing.
const FAIR_ITERATIONS: usize = 2000;
/// Rings of mesh vertices around a hole used as its rim when judging the fill.
const RIM_RINGS: usize = 1;

/// What hole filling did.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct HoleReport {
    /// Holes filled.
    pub holes_filled: usize,
    /// Boundary edges of the largest hole.
    pub largest_hole_edges: usize,
    /// Triangles added.
    pub triangles_added: usize,
    /// Vertices added by refinement.
    pub vertices_added: usize,
    /// Fairing: CG iterations used and final relative residual.
    pub fair_iterations: usize,
    /// Largest residual of the fairing solve.
    pub fair_residual: f64,
    /// Per hole: the largest distance of a new patch vertex from a quadric height field fitted to the two
    /// rings of mesh vertices around the hole (input units). Small when the fill continues the surrounding
    /// surface; a flat fan over a curved region shows the quadric's sag here.
    pub patch_quadric_deviation: Vec<f64>,
    /// Per hole: the largest residual of that quadric fit on the rim itself (how well one quadric describes
    /// the surroundings; the patch figure cannot be judged below this).
    pub rim_quadric_residual: Vec<f64>,
    /// Per hole: the largest distance of a new patch vertex from one quadric height field fitted to the rim
    /// and the patch together: whether the fill lies on a smooth surface with its surroundings.
    pub patch_joint_quadric_deviation: Vec<f64>,
    /// Per hole: the largest distance of a new patch vertex from one quadric height field fitted to the patch
    /// (its boundary loop and new vertices): whether the fill itself lies on a smooth surface. A flat fan
    /// has no new vertices (0 here) and shows in `patch_quadric_deviation` instead.
    pub patch_smoothness: Vec<f64>,
    /// How each hole was judged (small: faired; large: capped), in the order they were filled.
    pub decisions: Vec<HoleDecision>,
    /// The holes closed by a cap (planar or membrane) instead of a faired fill.
    pub caps: Vec<Cap>,
    /// The surface repair invented: every fill's triangles, as filled (not serialised).
    #[serde(skip)]
    pub invented: InventedSurface,
}

/// The triangles repair added over the holes (fills and caps), with their positions as filled: the part of
/// the closed mesh that no scan saw. Later stages label their own surface by it (a point is invented where
/// this surface is nearer than the scan).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct InventedSurface {
    /// Vertex positions.
    pub positions: Vec<V3>,
    /// Triangles.
    pub triangles: Vec<[u32; 3]>,
    /// Per triangle: the index in [`HoleReport::caps`] of its cap, or `None` for a faired fill.
    pub cap_of: Vec<Option<u32>>,
}

/// Boundary loops as vertex sequences v0, v1, … where the mesh has the half-edges v_i → v_{i+1}.
pub fn boundary_loops(tris: &[[u32; 3]]) -> Vec<Vec<u32>> {
    let topo = MeshTopology::from_triangles(tris);
    let idx = tris.as_flattened();
    let mut out_edge: HashMap<u32, u32> = HashMap::new(); // from-vertex -> to-vertex of boundary half-edges
    for e in 0..topo.edges.len() {
        if let [h] = *topo.edge_halfedges(e) {
            out_edge.insert(idx[h as usize], idx[topo.corner_next[h as usize] as usize]);
        }
    }
    let mut starts: Vec<u32> = out_edge.keys().copied().collect();
    starts.sort_unstable();
    let mut used = HashSet::new();
    let mut loops = Vec::new();
    for s in starts {
        if used.contains(&s) {
            continue;
        }
        let mut lp = vec![s];
        used.insert(s);
        let mut v = out_edge[&s];
        while v != s {
            if !used.insert(v) || lp.len() > out_edge.len() {
                break; // malformed chain: leave to the caller's closedness check
            }
            lp.push(v);
            match out_edge.get(&v) {
                Some(&w) => v = w,
                None => break,
            }
        }
        if lp.len() >= 3 {
            loops.push(lp);
        }
    }
    loops
}

fn angle_between(a: Option<V3>, b: Option<V3>) -> f64 {
    match (a, b) {
        (Some(a), Some(b)) => vec3::dot(a, b).clamp(-1.0, 1.0).acos(),
        _ => std::f64::consts::PI,
    }
}

/// Minimum-weight triangulation of a loop (Liepa). `outside[i]` is the normal of the mesh face across the
/// boundary edge v_i → v_{i+1}. Returns triangles oriented to close the mesh.
fn mwt(
    p: &[V3],
    lp: &[u32],
    outside: &[Option<V3>],
    exists: &HashSet<(u32, u32)>,
    crosses: &dyn Fn([u32; 3]) -> bool,
) -> Option<Vec<[u32; 3]>> {
    let n = lp.len();
    // A diagonal that is already a mesh edge would make that edge non-manifold.
    let blocked = |a: usize, b: usize| {
        b > a + 1 && !(a == 0 && b == n - 1) && exists.contains(&(lp[a].min(lp[b]), lp[a].max(lp[b])))
    };
    let tri = |i: usize, k: usize, j: usize| [lp[j], lp[k], lp[i]];
    // weight[(i, j)] = (max angle, area); best k in choice.
    let mut w = vec![(0.0f64, 0.0f64); n * n];
    let mut choice = vec![u32::MAX; n * n];
    let at = |i: usize, j: usize| i * n + j;
    for len in 2..n {
        for i in 0..n - len {
            let j = i + len;
            let mut best = (f64::INFINITY, f64::INFINITY);
            let mut best_k = u32::MAX;
            if blocked(i, j) {
                w[at(i, j)] = (f64::INFINITY, f64::INFINITY);
                continue;
            }
            for k in i + 1..j {
                if !(w[at(i, k)].0.is_finite() && w[at(k, j)].0.is_finite()) {
                    continue;
                }
                let t = tri(i, k, j);
                if crosses(t) {
                    continue;
                }
                let nt = tri_unit_normal(p, t);
                let side = |a: usize, b: usize| {
                    if b == a + 1 {
                        outside[a]
                    } else {
                        let m = choice[at(a, b)] as usize;
                        tri_unit_normal(p, tri(a, m, b))
                    }
                };
                let mut ang = angle_between(nt, side(i, k)).max(angle_between(nt, side(k, j)));
                if i == 0 && j == n - 1 {
                    ang = ang.max(angle_between(nt, outside[n - 1]));
                }
                let (wa, wb) = (w[at(i, k)], w[at(k, j)]);
                let cand = (ang.max(wa.0).max(wb.0), wa.1 + wb.1 + tri_area(p, t));
                if cand.0 < best.0 - 1e-12 || (cand.0 <= best.0 + 1e-12 && cand.1 < best.1) {
                    best = cand;
                    best_k = k as u32;
                }
            }
            w[at(i, j)] = best;
            choice[at(i, j)] = best_k;
        }
    }
    if !w[at(0, n - 1)].0.is_finite() {
        return None;
    }
    let mut out = Vec::with_capacity(n - 2);
    let mut stack = vec![(0usize, n - 1)];
    while let Some((i, j)) = stack.pop() {
        if j < i + 2 {
            continue;
        }
        let k = choice[at(i, j)] as usize;
        out.push(tri(i, k, j));
        stack.push((i, k));
        stack.push((k, j));
    }
    Some(out)
}

/// Fan from a new vertex at the loop's centroid: always valid topologically; used when every triangulation
/// of the loop would reuse an existing edge.
fn centroid_fan(p: &mut Vec<V3>, lp: &[u32]) -> Vec<[u32; 3]> {
    let n = lp.len();
    let c = lp.iter().fold([0.0; 3], |acc, &v| vec3::add(acc, p[v as usize]));
    p.push(vec3::scale(c, 1.0 / n as f64));
    let m = (p.len() - 1) as u32;
    (0..n).map(|i| [lp[(i + 1) % n], lp[i], m]).collect()
}

/// Clip ears of smallest interior angle until the loop is short enough for [`mwt`]. Returns the clipped
/// triangles and the remaining loop (with its outside normals).
fn clip_ears(
    p: &[V3],
    lp: &mut Vec<u32>,
    outside: &mut Vec<Option<V3>>,
    limit: usize,
    exists: &mut HashSet<(u32, u32)>,
) -> Vec<[u32; 3]> {
    let mut out = Vec::new();
    while lp.len() > limit {
        let n = lp.len();
        let angle = |i: usize| {
            let (a, b, c) = (p[lp[(i + n - 1) % n] as usize], p[lp[i] as usize], p[lp[(i + 1) % n] as usize]);
            let (u, v) = (vec3::sub(a, b), vec3::sub(c, b));
            let d = (vec3::norm(u) * vec3::norm(v)).max(f64::MIN_POSITIVE);
            (vec3::dot(u, v) / d).clamp(-1.0, 1.0).acos()
        };
        let free = |i: usize| {
            let (a, b) = (lp[(i + n - 1) % n], lp[(i + 1) % n]);
            !exists.contains(&(a.min(b), a.max(b)))
        };
        let Some(i) = (0..n).filter(|&i| free(i)).min_by(|&a, &b| angle(a).total_cmp(&angle(b)).then(a.cmp(&b))) else {
            break;
        };
        let (prev, next) = ((i + n - 1) % n, (i + 1) % n);
        let t = [lp[next], lp[i], lp[prev]];
        out.push(t);
        exists.insert((lp[prev].min(lp[next]), lp[prev].max(lp[next])));
        outside[prev] = tri_unit_normal(p, t);
        lp.remove(i);
        outside.remove(i);
    }
    out
}

/// Local edge length around each loop vertex: mean length of its mesh edges.
fn loop_sigma(p: &[V3], tris: &[[u32; 3]], lp: &[u32]) -> HashMap<u32, f64> {
    let on_loop: HashSet<u32> = lp.iter().copied().collect();
    let mut acc: HashMap<u32, (f64, usize)> = HashMap::new();
    for t in tris {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            let l = vec3::norm(vec3::sub(p[a as usize], p[b as usize]));
            for v in [a, b] {
                if on_loop.contains(&v) {
                    let e = acc.entry(v).or_insert((0.0, 0));
                    e.0 += l;
                    e.1 += 1;
                }
            }
        }
    }
    acc.into_iter().map(|(v, (s, n))| (v, s / n.max(1) as f64)).collect()
}

fn opposite_angle(p: &[V3], a: u32, b: u32, c: u32) -> f64 {
    // Angle at c in triangle (a, b, c).
    let (u, v) = (vec3::sub(p[a as usize], p[c as usize]), vec3::sub(p[b as usize], p[c as usize]));
    let d = (vec3::norm(u) * vec3::norm(v)).max(f64::MIN_POSITIVE);
    (vec3::dot(u, v) / d).clamp(-1.0, 1.0).acos()
}

/// Flip interior patch edges towards Delaunay (opposite angles summing to more than π), never creating an
/// edge that exists already (`fixed_edges` holds the mesh's edges among loop vertices).
fn relax(p: &[V3], patch: &mut [[u32; 3]], fixed_edges: &HashSet<(u32, u32)>) {
    let key = |a: u32, b: u32| (a.min(b), a.max(b));
    for _ in 0..8 {
        let mut edges: HashMap<(u32, u32), Vec<(usize, usize)>> = HashMap::new();
        for (f, t) in patch.iter().enumerate() {
            for k in 0..3 {
                edges.entry(key(t[k], t[(k + 1) % 3])).or_default().push((f, k));
            }
        }
        let mut keys: Vec<_> = edges.keys().copied().collect();
        keys.sort_unstable();
        let mut touched = HashSet::new();
        let mut created = HashSet::new();
        let mut flipped = 0;
        for e in keys {
            let hs = &edges[&e];
            if hs.len() != 2 || touched.contains(&hs[0].0) || touched.contains(&hs[1].0) {
                continue;
            }
            let ((f1, k1), (f2, k2)) = (hs[0], hs[1]);
            let (t1, t2) = (patch[f1], patch[f2]);
            let (a, b, c) = (t1[k1], t1[(k1 + 1) % 3], t1[(k1 + 2) % 3]);
            let d = t2[(k2 + 2) % 3];
            if t2[k2] != b
                || c == d
                || fixed_edges.contains(&key(c, d))
                || edges.contains_key(&key(c, d))
                || created.contains(&key(c, d))
            {
                continue;
            }
            if opposite_angle(p, a, b, c) + opposite_angle(p, a, b, d) <= std::f64::consts::PI + 1e-9 {
                continue;
            }
            let (n1, n2) = ([a, d, c], [b, c, d]);
            // Keep both new triangles facing the same way as the old pair.
            let old = vec3::add(tri_unit_normal(p, t1).unwrap_or([0.0; 3]), tri_unit_normal(p, t2).unwrap_or([0.0; 3]));
            let ok = |t| tri_unit_normal(p, t).is_some_and(|n| vec3::dot(n, old) > 0.0);
            if !ok(n1) || !ok(n2) {
                continue;
            }
            patch[f1] = n1;
            patch[f2] = n2;
            touched.insert(f1);
            touched.insert(f2);
            created.insert(key(c, d));
            flipped += 1;
        }
        if flipped == 0 {
            break;
        }
    }
}

/// Split patch triangles until their density matches σ (Liepa's √2 criterion); new vertices are appended
/// to `p`. Returns the number of vertices added.
fn refine(
    p: &mut Vec<V3>,
    patch: &mut Vec<[u32; 3]>,
    sigma: &mut HashMap<u32, f64>,
    fixed: &HashSet<(u32, u32)>,
) -> usize {
    let alpha = std::f64::consts::SQRT_2;
    let mut added = 0;
    for _ in 0..REFINE_ROUNDS {
        let mut next = Vec::with_capacity(patch.len() * 3);
        let mut split = 0;
        for &t in patch.iter() {
            let [a, b, c] = t.map(|i| p[i as usize]);
            let centre = vec3::scale(vec3::add(vec3::add(a, b), c), 1.0 / 3.0);
            let sc = t.iter().map(|v| sigma[v]).sum::<f64>() / 3.0;
            let far = t.iter().all(|&v| {
                let d = alpha * vec3::norm(vec3::sub(centre, p[v as usize]));
                d > sc && d > sigma[&v]
            });
            if far {
                p.push(centre);
                let m = (p.len() - 1) as u32;
                sigma.insert(m, sc);
                next.extend_from_slice(&[[t[0], t[1], m], [t[1], t[2], m], [t[2], t[0], m]]);
                split += 1;
                added += 1;
            } else {
                next.push(t);
            }
        }
        *patch = next;
        relax(p, patch, fixed);
        if split == 0 {
            break;
        }
    }
    added
}

/// The vertices (the seeds included) and faces reached from `seeds` in `rings` rings of faces, both sorted.
/// Cost: O(size of what is reached).
fn grow_rings(tris: &[[u32; 3]], around: &VertexFaces, seeds: &[u32], rings: usize) -> (Vec<u32>, Vec<u32>) {
    let mut vertices: HashSet<u32> = seeds.iter().copied().collect();
    let mut faces: HashSet<u32> = HashSet::new();
    let mut front: Vec<u32> = seeds.to_vec();
    for _ in 0..rings {
        let mut next = Vec::new();
        for &v in &front {
            for &f in around.of(v) {
                if faces.insert(f) {
                    next.extend(tris[f as usize].into_iter().filter(|&w| vertices.insert(w)));
                }
            }
        }
        front = next;
    }
    let mut vertices: Vec<u32> = vertices.into_iter().collect();
    vertices.sort_unstable();
    let mut faces: Vec<u32> = faces.into_iter().collect();
    faces.sort_unstable();
    (vertices, faces)
}

/// Rings of mesh vertices around a loop (beyond the loop itself) whose quadric gives the fairing its
/// boundary tangents.
const ANCHOR_RINGS: usize = 2;

/// Denoised positions for the fixed vertices in the boundary rows of the fairing energy: each loop vertex and
/// its mesh neighbours, moved onto one quadric height field fitted to the loop and [`ANCHOR_RINGS`] rings
/// around it. The patch still interpolates the loop itself; only the tangents it continues come from the
/// quadric, so scanner noise on the rim (the bunny's base is rough at the 1 mm level) does not ripple into
/// the fill. A loop whose surroundings are no height field over the frame (a face turned more than 60° from
/// its normal) or that the quadric misses by more than a quarter of the loop's radius keeps its own
/// positions.
fn rim_anchors(p: &[V3], tris: &[[u32; 3]], loops: &[Vec<u32>]) -> HashMap<u32, V3> {
    let mut anchors = HashMap::new();
    let around = VertexFaces::new(p.len(), tris);
    for lp in loops {
        let (pts, faces) = grow_rings(tris, &around, lp, ANCHOR_RINGS);
        let normals: Vec<V3> = faces.iter().filter_map(|&f| tri_unit_normal(p, tris[f as usize])).collect();
        let normal = normals.iter().fold([0.0; 3], |a, &n| vec3::add(a, n));
        let Some(q) = HeightQuadric::fit(p, &pts, normal) else { continue };
        if normals.iter().any(|&n| vec3::dot(n, q.n) < 0.0) {
            continue;
        }
        let centre = vec3::scale(lp.iter().fold([0.0; 3], |a, &v| vec3::add(a, p[v as usize])), 1.0 / lp.len() as f64);
        let radius = lp.iter().map(|&v| vec3::norm(vec3::sub(p[v as usize], centre))).sum::<f64>() / lp.len() as f64;
        let worst = pts.iter().map(|&v| q.offset(p[v as usize]).abs()).fold(0.0, f64::max);
        if worst > 0.5 * radius {
            continue;
        }
        let on_loop: HashSet<u32> = lp.iter().copied().collect();
        for &v in lp {
            anchors.insert(v, q.project(p[v as usize]));
            for &f in around.of(v) {
                for w in tris[f as usize] {
                    if !on_loop.contains(&w) {
                        anchors.insert(w, q.project(p[w as usize]));
                    }
                }
            }
        }
    }
    anchors
}

/// Thin-plate fairing of the vertices `free` (indices into `p`): minimise Σ_v |L_v(x)|² over the free
/// vertices and their neighbours v, L_v = mean of v's neighbours − x_v, all other vertices fixed. CG on
/// the normal equations, per coordinate. Returns (iterations, relative residual).
fn fair(p: &mut [V3], tris: &[[u32; 3]], free: &[u32], anchors: &HashMap<u32, V3>) -> (usize, f64) {
    if free.is_empty() {
        return (0, 0.0);
    }
    // Neighbour lists of the free vertices and of their neighbours (the rows of the energy) only.
    let free_set: HashSet<u32> = free.iter().copied().collect();
    let mut wanted: HashSet<u32> = free_set.clone();
    for t in tris {
        if t.iter().any(|v| free_set.contains(v)) {
            wanted.extend(t.iter().copied());
        }
    }
    let mut nbrs: HashMap<u32, Vec<u32>> = wanted.iter().map(|&v| (v, Vec::new())).collect();
    for t in tris {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            if let Some(n) = nbrs.get_mut(&a) {
                n.push(b);
            }
            if let Some(n) = nbrs.get_mut(&b) {
                n.push(a);
            }
        }
    }
    for n in nbrs.values_mut() {
        n.sort_unstable();
        n.dedup();
    }
    let col: HashMap<u32, usize> = free.iter().enumerate().map(|(i, &v)| (v, i)).collect();
    // Rows: free vertices and their neighbours.
    let mut rows: Vec<u32> = free.to_vec();
    for &v in free {
        rows.extend(nbrs[&v].iter().copied());
    }
    rows.sort_unstable();
    rows.dedup();
    // Sparse rows: (coefficients on free columns, fixed part per coordinate).
    let mut a_rows: Vec<Vec<(usize, f64)>> = Vec::with_capacity(rows.len());
    let mut fixed_part: Vec<V3> = Vec::with_capacity(rows.len());
    for &v in &rows {
        let nb = &nbrs[&v];
        let inv = 1.0 / nb.len().max(1) as f64;
        let mut coeffs: Vec<(usize, f64)> = Vec::new();
        let mut fx = [0.0; 3];
        // Rows of fixed (boundary) vertices see the denoised rim; rows of free vertices the rim as it is.
        let boundary_row = !col.contains_key(&v);
        let mut add = |u: u32, c: f64, coeffs: &mut Vec<(usize, f64)>| match col.get(&u) {
            Some(&j) => coeffs.push((j, c)),
            None => {
                let q = if boundary_row { anchors.get(&u).copied().unwrap_or(p[u as usize]) } else { p[u as usize] };
                (0..3).for_each(|k| fx[k] += c * q[k])
            }
        };
        for &u in nb {
            add(u, inv, &mut coeffs);
        }
        add(v, -1.0, &mut coeffs);
        a_rows.push(coeffs);
        fixed_part.push(fx);
    }
    let n = free.len();
    let mut iters = 0;
    let mut worst = 0.0f64;
    for k in 0..3 {
        // Minimise |A x + f|²  ->  AᵀA x = −Aᵀ f.
        let apply = |x: &[f64]| -> Vec<f64> {
            let ax: Vec<f64> = a_rows.iter().map(|r| r.iter().map(|&(j, c)| c * x[j]).sum()).collect();
            let mut out = vec![0.0; n];
            for (r, &v) in a_rows.iter().zip(&ax) {
                for &(j, c) in r {
                    out[j] += c * v;
                }
            }
            out
        };
        let mut b = vec![0.0; n];
        for (r, f) in a_rows.iter().zip(&fixed_part) {
            for &(j, c) in r {
                b[j] -= c * f[k];
            }
        }
        let mut x: Vec<f64> = free.iter().map(|&v| p[v as usize][k]).collect();
        let ax = apply(&x);
        let mut r: Vec<f64> = b.iter().zip(&ax).map(|(b, a)| b - a).collect();
        let mut d = r.clone();
        let b_norm = b.iter().map(|v| v * v).sum::<f64>().sqrt().max(1e-300);
        let mut rr: f64 = r.iter().map(|v| v * v).sum();
        let mut it = 0;
        while it < FAIR_ITERATIONS && rr.sqrt() > 1e-10 * b_norm {
            let ad = apply(&d);
            let dad: f64 = d.iter().zip(&ad).map(|(a, b)| a * b).sum();
            if !(dad > 0.0) {
                break;
            }
            let alpha = rr / dad;
            x.iter_mut().zip(&d).for_each(|(x, d)| *x += alpha * d);
            r.iter_mut().zip(&ad).for_each(|(r, a)| *r -= alpha * a);
            let rr_new: f64 = r.iter().map(|v| v * v).sum();
            let beta = rr_new / rr;
            rr = rr_new;
            d.iter_mut().zip(&r).for_each(|(d, r)| *d = r + beta * *d);
            it += 1;
        }
        iters = iters.max(it);
        worst = worst.max(rr.sqrt() / b_norm);
        for (i, &v) in free.iter().enumerate() {
            p[v as usize][k] = x[i];
        }
    }
    (iters, worst)
}

/// Fill every hole of the oriented manifold `tris` (in place), adding vertices to `p`. With `measure`, each
/// patch's smoothness against its surroundings is measured (the `*_quadric_*` fields) and candidate
/// triangles that would cross the existing surface are excluded (the self-intersection loop, which refills
/// the holes it makes with `measure` off, checks its refills itself).
///
/// Large holes are capped ([`caps`]); "large" is judged against the bounding-box diagonal of `p`.
pub fn fill_holes(p: &mut Vec<V3>, tris: &mut Vec<[u32; 3]>, measure: bool) -> HoleReport {
    let mut bbox = vec3::Aabb::EMPTY;
    p.iter().for_each(|&q| bbox.add(q));
    fill(p, tris, measure, None, bbox.diagonal())
}

/// [`fill_holes`], for the loops that pass through a vertex of `only` when it is given; holes are judged large
/// against `diagonal` ([`caps::judge`]; infinite: only planar cuts are capped).
fn fill(
    p: &mut Vec<V3>,
    tris: &mut Vec<[u32; 3]>,
    measure: bool,
    only: Option<&HashSet<u32>>,
    diagonal: f64,
) -> HoleReport {
    let mut report = HoleReport::default();
    let mut loops = boundary_loops(tris);
    if let Some(only) = only {
        loops.retain(|lp| lp.iter().any(|v| only.contains(v)));
    }
    if loops.is_empty() {
        return report;
    }
    // Normal of the face across each boundary half-edge.
    let mut face_of_edge: HashMap<(u32, u32), [u32; 3]> = HashMap::new();
    let on_loop: HashSet<u32> = loops.iter().flatten().copied().collect();
    let mut fixed_edges: HashSet<(u32, u32)> = HashSet::new();
    for t in tris.iter() {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            if on_loop.contains(&a) && on_loop.contains(&b) {
                face_of_edge.insert((a, b), *t);
                fixed_edges.insert((a.min(b), a.max(b)));
            }
        }
    }
    // Candidate fill triangles that would cross the existing surface are not used.
    let boxes: Vec<_> =
        if measure { tris.iter().map(|t| box_of(&t.map(|i| p[i as usize]))).collect() } else { Vec::new() };
    let mesh_tree = BoxTree::new(&boxes);
    let all_loops: Vec<u32> = loops.iter().flatten().copied().collect();
    let anchors = rim_anchors(p, tris, &loops);
    let original_faces = tris.len();
    let mut patches: Vec<Vec<u32>> = Vec::new();
    let all_sigma = loop_sigma(p, tris, &all_loops);
    let first_new_vertex = p.len();
    // New vertices of caps: already placed, not faired.
    let mut capped: HashSet<u32> = HashSet::new();
    // Each patch's cap index, in the order the patches are appended to `tris` after `original_faces`.
    let mut cap_of_patch: Vec<(usize, Option<u32>)> = Vec::new();
    for lp in loops {
        let mut lp = lp;
        report.largest_hole_edges = report.largest_hole_edges.max(lp.len());
        let n = lp.len();
        let mut outside: Vec<Option<V3>> =
            (0..n).map(|i| face_of_edge.get(&(lp[i], lp[(i + 1) % n])).and_then(|&t| tri_unit_normal(p, t))).collect();
        let mut sigma: HashMap<u32, f64> = lp.iter().map(|v| (*v, all_sigma[v])).collect();
        let (decision, cap) = caps::judge(p, &lp, &outside, diagonal);
        report.decisions.push(decision);
        // A cap's hole is triangulated in its plane; other holes (or a rim whose projection is not simple)
        // by ears of smallest angle and the minimum-weight triangulation.
        let in_plane = cap.as_ref().and_then(|c| caps::triangulate_in_plane(p, &lp, c, &fixed_edges));
        let mut patch = if in_plane.is_some() {
            Vec::new()
        } else {
            clip_ears(p, &mut lp, &mut outside, MWT_MAX_LOOP, &mut fixed_edges)
        };
        let crosses = |t: [u32; 3]| {
            let (lo, hi) = box_of(&t.map(|i| p[i as usize]));
            let mut hit = false;
            mesh_tree.overlapping(lo, hi, |f| {
                hit = hit || mesh_triangles_intersect(p, t, tris[f as usize]);
            });
            hit
        };
        let start = p.len();
        match in_plane.or_else(|| mwt(p, &lp, &outside, &fixed_edges, &crosses)) {
            Some(t) => patch.extend(t),
            None => {
                sigma.insert(p.len() as u32, lp.iter().map(|v| sigma[v]).sum::<f64>() / lp.len() as f64);
                patch.extend(centroid_fan(p, &lp));
            }
        }
        let before = p.len();
        report.vertices_added += refine(p, &mut patch, &mut sigma, &fixed_edges);
        report.triangles_added += patch.len();
        let cap_index = cap.map(|cap| {
            report.caps.push(place_cap(p, &patch, start, cap));
            capped.extend(start as u32..p.len() as u32);
            (report.caps.len() - 1) as u32
        });
        cap_of_patch.push((patch.len(), cap_index));
        let mut pv = lp.clone();
        pv.extend(patch.iter().flatten().copied().filter(|&v| v as usize >= before || !lp.contains(&v)));
        pv.sort_unstable();
        pv.dedup();
        patches.push(pv);
        report.holes_filled += 1;
        tris.extend(patch);
    }
    let free: Vec<u32> = (first_new_vertex as u32..p.len() as u32).filter(|v| !capped.contains(v)).collect();
    let (it, res) = fair(p, tris, &free, &anchors);
    report.fair_iterations = it;
    report.fair_residual = res;
    report.invented = invented_surface(p, &tris[original_faces..], &cap_of_patch);
    if !measure {
        return report;
    }
    // Faces of the original mesh around each vertex (fill patches excluded).
    let vertex_faces = VertexFaces::new(p.len(), &tris[..original_faces]);
    for pv in &patches {
        let (dev, rim, joint, own) = quadric_deviation(p, tris, &vertex_faces, pv, first_new_vertex as u32);
        report.patch_quadric_deviation.push(dev);
        report.rim_quadric_residual.push(rim);
        report.patch_joint_quadric_deviation.push(joint);
        report.patch_smoothness.push(own);
    }
    report
}

/// Put a large hole's new vertices (index ≥ `first`) where its cap wants them ([`caps::flatten_cap`] or
/// [`caps::membrane_cap`]) and measure the cap: area, triangles, bulge past its plane.
fn place_cap(p: &mut [V3], patch: &[[u32; 3]], first: usize, mut cap: Cap) -> Cap {
    match cap.kind {
        Some(caps::CapKind::Membrane) => caps::membrane_cap(p, patch, first, &cap),
        _ => caps::flatten_cap(p, patch, first, &cap),
    }
    cap.area = patch.iter().map(|t| tri_area(p, *t)).sum();
    cap.triangles = patch.len();
    let mut vs: Vec<usize> = patch.iter().flatten().map(|&v| v as usize).collect();
    vs.sort_unstable();
    vs.dedup();
    cap.bulge = caps::bulge(p, vs.into_iter(), &cap);
    cap
}

/// The fills' triangles (`added`, the patches one after another; `cap_of_patch`: each patch's length and
/// cap index) with their vertices' current positions, compacted.
fn invented_surface(p: &[V3], added: &[[u32; 3]], cap_of_patch: &[(usize, Option<u32>)]) -> InventedSurface {
    let mut index: HashMap<u32, u32> = HashMap::new();
    let mut out = InventedSurface::default();
    let mut rest = added;
    for &(len, cap) in cap_of_patch {
        let (patch, tail) = rest.split_at(len);
        rest = tail;
        for t in patch {
            let t = t.map(|v| {
                *index.entry(v).or_insert_with(|| {
                    out.positions.push(p[v as usize]);
                    (out.positions.len() - 1) as u32
                })
            });
            out.triangles.push(t);
            out.cap_of.push(cap);
        }
    }
    out
}

/// A quadric height field z = h(x, y) = a x² + b xy + c y² + d x + e y + f over a local frame (origin, u, v,
/// normal n), fitted by least squares.
#[derive(Clone, Copy, Debug)]
struct HeightQuadric {
    origin: V3,
    u: V3,
    v: V3,
    n: V3,
    coef: [f64; 6],
}

impl HeightQuadric {
    /// Fit to `pts` (at least 6) in the frame whose normal is `normal` (need not be unit). `None` when the
    /// points do not determine a quadric or the normal is zero.
    fn fit(p: &[V3], pts: &[u32], normal: V3) -> Option<Self> {
        let nl = vec3::norm(normal);
        if pts.len() < 6 || nl == 0.0 {
            return None;
        }
        let n = vec3::scale(normal, 1.0 / nl);
        let (u, v) = vec3::plane_frame(n);
        let origin =
            vec3::scale(pts.iter().fold([0.0; 3], |a, &i| vec3::add(a, p[i as usize])), 1.0 / pts.len() as f64);
        let mut q = HeightQuadric { origin, u, v, n, coef: [0.0; 6] };
        let mut ata = [[0.0; 6]; 6];
        let mut atb = [0.0; 6];
        for &i in pts {
            let (x, y, z) = q.local(p[i as usize]);
            let b = Self::basis(x, y);
            for r in 0..6 {
                for c in 0..6 {
                    ata[r][c] += b[r] * b[c];
                }
                atb[r] += b[r] * z;
            }
        }
        q.coef = solve_dense(ata, atb)?;
        Some(q)
    }

    fn basis(x: f64, y: f64) -> [f64; 6] {
        [x * x, x * y, y * y, x, y, 1.0]
    }

    fn local(&self, q: V3) -> (f64, f64, f64) {
        let d = vec3::sub(q, self.origin);
        (vec3::dot(d, self.u), vec3::dot(d, self.v), vec3::dot(d, self.n))
    }

    fn height(&self, x: f64, y: f64) -> f64 {
        Self::basis(x, y).iter().zip(&self.coef).map(|(b, c)| b * c).sum()
    }

    /// Signed height of `q` above the quadric, along the frame normal.
    fn offset(&self, q: V3) -> f64 {
        let (x, y, z) = self.local(q);
        z - self.height(x, y)
    }

    /// `q` moved along the frame normal onto the quadric.
    fn project(&self, q: V3) -> V3 {
        vec3::sub(q, vec3::scale(self.n, self.offset(q)))
    }
}

/// Rings of faces around the rim vertices that [`fill_holes_near`] hands to [`fill_holes`]: the fairing and
/// its anchors look [`ANCHOR_RINGS`] + 1 rings out.
const NEAR_RINGS: usize = ANCHOR_RINGS + 2;

/// [`fill_holes`] (without measuring) for the holes that pass through `rim` only, working on the faces within
/// [`NEAR_RINGS`] rings of those vertices instead of the whole mesh: after a local deletion the cost is that
/// of the neighbourhood plus one O(V + F) pass. Loops of the neighbourhood's own border are never touched
/// (they pass through no rim vertex). New vertices are appended to `p`, new faces to `tris`.
pub fn fill_holes_near(p: &mut Vec<V3>, tris: &mut Vec<[u32; 3]>, rim: &HashSet<u32>) -> HoleReport {
    if rim.is_empty() {
        return HoleReport::default();
    }
    let around = VertexFaces::new(p.len(), tris);
    let mut seeds: Vec<u32> = rim.iter().copied().collect();
    seeds.sort_unstable();
    let (global, faces) = grow_rings(tris, &around, &seeds, NEAR_RINGS);
    let local_of: HashMap<u32, u32> = global.iter().enumerate().map(|(i, &g)| (g, i as u32)).collect();
    let mut lp: Vec<V3> = global.iter().map(|&g| p[g as usize]).collect();
    let mut lt: Vec<[u32; 3]> = faces.iter().map(|&f| tris[f as usize].map(|v| local_of[&v])).collect();
    let local_rim: HashSet<u32> = rim.iter().filter_map(|v| local_of.get(v).copied()).collect();
    let (n_local, f_local) = (lp.len(), lt.len());
    let report = fill(&mut lp, &mut lt, false, Some(&local_rim), f64::INFINITY);
    // New local vertices become new global vertices, in order.
    let first_global = p.len() as u32;
    p.extend_from_slice(&lp[n_local..]);
    // Fairing moved only new vertices; loop vertices keep their positions.
    let to_global =
        |v: u32| if (v as usize) < n_local { global[v as usize] } else { first_global + v - n_local as u32 };
    tris.extend(lt[f_local..].iter().map(|t| t.map(to_global)));
    report
}

/// Quadric height fields around a filled hole, in a frame whose normal is the mean normal of the mesh faces
/// at the loop. Returns the largest distance of the patch's new vertices from the quadric fitted to (a) the
/// ring of mesh vertices around the loop, (c) that ring and the new vertices together, (d) the loop and the
/// new vertices; and (b) the largest residual of fit (a) on the ring itself. `patch` holds the loop and new
/// vertices; `first_new` is the first new vertex index.
fn quadric_deviation(
    p: &[V3],
    tris: &[[u32; 3]],
    vertex_faces: &VertexFaces,
    patch: &[u32],
    first_new: u32,
) -> (f64, f64, f64, f64) {
    let in_patch: HashSet<u32> = patch.iter().copied().collect();
    let mut rim: HashSet<u32> = HashSet::new();
    let mut front: HashSet<u32> = patch.iter().copied().filter(|v| (*v as usize) < p.len()).collect();
    let mut normal_sum = [0.0; 3];
    for _ in 0..RIM_RINGS {
        let mut next = HashSet::new();
        let mut faces: Vec<u32> = front.iter().flat_map(|&v| vertex_faces.of(v).iter().copied()).collect();
        faces.sort_unstable();
        faces.dedup();
        for f in faces {
            let t = tris[f as usize];
            normal_sum = vec3::add(normal_sum, tri_unit_normal(p, t).unwrap_or([0.0; 3]));
            for v in t {
                if !in_patch.contains(&v) && rim.insert(v) {
                    next.insert(v);
                }
            }
        }
        front = next;
    }
    let mut rim: Vec<u32> = rim.into_iter().collect();
    rim.sort_unstable();
    // The largest distance over `eval` from the quadric fitted to `fit`.
    let fit_and_measure = |fit: &[u32], eval: &[u32]| -> f64 {
        let Some(q) = HeightQuadric::fit(p, fit, normal_sum) else { return f64::NAN };
        eval.iter().map(|&i| q.offset(p[i as usize]).abs()).fold(0.0, f64::max)
    };
    let new: Vec<u32> = patch.iter().copied().filter(|&i| i >= first_new).collect();
    let both: Vec<u32> = rim.iter().chain(&new).copied().collect();
    (
        fit_and_measure(&rim, &new),
        fit_and_measure(&rim, &rim),
        fit_and_measure(&both, &new),
        if new.is_empty() { 0.0 } else { fit_and_measure(patch, &new) },
    )
}

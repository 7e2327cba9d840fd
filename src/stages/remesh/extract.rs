//! Extraction of a polygon mesh from the position field.
//!
//! 1. Every input edge gets the integer lattice offset between its endpoints' origins. A unit offset
//!    proposes an output edge; anything but 0 is dropped. Offset-0 edges join their endpoints into one
//!    output vertex (union–find), smallest rounding residual first, unless their two clusters are linked by
//!    a unit offset already: that join would swallow a lattice step, and chains of such joins collapse a
//!    thin part, or a whole region when the spacing is near the working edges (Instant Meshes' collapse rule,
//!    `extract_graph`; [`Extracted::linked_refused`]).
//! 2. Output vertices closer than [`SNAP`]·scale are merged; vertices left with fewer than 3 edges are
//!    removed (a valence-2 vertex between two quads is a "doublet": removing it merges them into one quad).
//! 3. Faces come from a rotation system: the neighbours of each output vertex are sorted by angle in its
//!    tangent plane and faces are traced by always taking the next edge clockwise. Any rotation system
//!    traces a closed, oriented surface, so the result has no boundary and no non-manifold edge by
//!    construction; edges with the same face on both sides and vertices a face visits twice are removed
//!    and the tracing repeated.

use super::field::tangent_unit;
use super::hierarchy::Level;
use super::integer;
use crate::geometry::topology::UnionFind;
use crate::geometry::vec3::{self, V3, add, cross, dot, scale, sub};
use rayon::prelude::*;

/// Vertices with fewer edges are pruned before faces are traced (a valence-2 vertex between two quads is a
/// doublet; keeping them instead was tried and caused more pinches on the dragon).
pub const MIN_DEGREE: u32 = 3;

/// Output vertices closer than this many lattice spacings are merged.
pub const SNAP: f64 = 0.3;

/// The extracted polygon mesh (positions not yet on the input surface).
#[derive(Clone, Debug, Default)]
pub struct Extracted {
    /// Vertex positions.
    pub positions: Vec<V3>,
    /// Vertex normals.
    pub normals: Vec<V3>,
    /// Faces (quad-dominant polygons).
    pub faces: Vec<Vec<u32>>,
    /// Output vertices removed because fewer than 3 edges met there.
    pub low_valence_removed: usize,
    /// Output vertex pairs merged because they were closer than `SNAP`·scale.
    pub snapped: usize,
    /// Offset-0 input edges not joined because their clusters were linked by a unit offset already.
    pub linked_refused: usize,
    /// Edges removed because the same face lay on both sides.
    pub dangling_edges_removed: usize,
    /// Vertices removed because a face visited them twice (a pinch).
    pub pinch_vertices_removed: usize,
    /// What the cancellation of position singularities did (when it ran).
    pub integer: Option<integer::CancelCounts>,
    /// The integer steps the extraction followed, when they were the position field's own (no cancellation):
    /// a cancellation of the same field starts from them instead of computing them again.
    pub steps: Option<integer::Offsets>,
}

/// Extract from level 0 with orientation `q`, lattice origins `o` and spacing `s[i]` at vertex i. With
/// `cancel` (the triangles level 0 was built from, a reach, blocked vertices), position singularities are first
/// cancelled in pairs ([`integer::cancel_pairs`]); the extraction then follows the changed steps, and the
/// clusters are placed by them ([`place_by_steps`]). `steps`, when given, are this field's steps as an earlier
/// extraction of it returned them ([`Extracted::steps`]); else they are computed.
pub fn extract(
    level: &Level,
    q: &[V3],
    o: &[V3],
    s: &[f64],
    cancel: Option<integer::Cancel>,
    steps: Option<integer::Offsets>,
    linked_guard: bool,
) -> Extracted {
    let n = level.len();
    // 1. Integer steps of every input edge (in parallel), optionally made consistent.
    let mut off = steps.unwrap_or_else(|| integer::Offsets::compute(level, q, o, s));
    let mut out = Extracted::default();
    if let Some(c) = cancel {
        out.integer = integer::cancel_pairs(&mut off, c.tris, c.reach, Some(c.blocked));
    }
    let mut uf = UnionFind::new(n);
    let links: Vec<(u32, u32)> =
        off.edges.iter().zip(&off.d).filter(|(_, d)| d[0].abs() + d[1].abs() == 1).map(|(&e, _)| e).collect();
    out.linked_refused = join_unlinked(&mut uf, n, &off, &links, linked_guard);
    // 2. Clusters, then snapping of near-coincident clusters (once).
    let mut graph = cluster_graph(level, o, s, &mut uf, &links);
    // With cancelled singularities the origins no longer agree with the steps along the paths: place the
    // clusters by the steps instead, so the stretch spreads before snapping and tracing.
    let steps = out.integer.is_some().then(|| link_vectors(level, q, s, &off));
    if let Some(steps) = &steps {
        place_by_steps(&mut graph, steps);
    }
    let mut snapped = 0;
    for &(a, b) in &graph.edges {
        let local = 0.5 * (graph.s[a as usize] + graph.s[b as usize]);
        if vec3::norm(sub(graph.p[a as usize], graph.p[b as usize])) < SNAP * local {
            let (ra, rb) = (graph.members[a as usize], graph.members[b as usize]);
            if uf.find(ra) != uf.find(rb) {
                uf.union(ra, rb);
                snapped += 1;
            }
        }
    }
    if snapped > 0 {
        graph = cluster_graph(level, o, s, &mut uf, &links);
        if let Some(steps) = &steps {
            place_by_steps(&mut graph, steps);
        }
    }
    out.snapped = snapped;
    // 3. Prune low valence, trace faces, remove dangling edges, repeat.
    let nv = graph.p.len();
    let mut alive_edges: Vec<(u32, u32)> = graph.edges.clone();
    let mut faces;
    loop {
        let (edges, removed) = prune_low_valence(nv, &alive_edges);
        out.low_valence_removed += removed;
        alive_edges = edges;
        let (f, dangling) = trace_faces(&graph.p, &graph.n, &alive_edges);
        faces = f;
        // A face that visits a vertex twice pinches the surface there: drop that vertex, merging its faces.
        let mut pinched: Vec<u32> = Vec::new();
        for face in &faces {
            let mut vs = face.clone();
            vs.sort_unstable();
            pinched.extend(vs.windows(2).filter(|w| w[0] == w[1]).map(|w| w[0]));
        }
        pinched.sort_unstable();
        pinched.dedup();
        if dangling.is_empty() && pinched.is_empty() {
            break;
        }
        out.dangling_edges_removed += dangling.len();
        out.pinch_vertices_removed += pinched.len();
        alive_edges.retain(|e| {
            dangling.binary_search(e).is_err()
                && pinched.binary_search(&e.0).is_err()
                && pinched.binary_search(&e.1).is_err()
        });
    }
    // Compact vertices.
    let mut used = vec![u32::MAX; nv];
    for f in &faces {
        for &v in f {
            used[v as usize] = 0;
        }
    }
    let mut next = 0;
    for u in used.iter_mut() {
        if *u == 0 {
            *u = next;
            next += 1;
        }
    }
    for (v, &u) in used.iter().enumerate() {
        if u != u32::MAX {
            out.positions.push(graph.p[v]);
            out.normals.push(graph.n[v]);
        }
    }
    out.faces = faces.into_iter().map(|f| f.into_iter().map(|v| used[v as usize]).collect()).collect();
    tracing::debug!(
        clusters = nv,
        links = links.len(),
        refused = out.linked_refused,
        snapped = out.snapped,
        low_valence = out.low_valence_removed,
        dangling = out.dangling_edges_removed,
        pinched = out.pinch_vertices_removed,
        vertices = out.positions.len(),
        faces = out.faces.len(),
        "extraction"
    );
    if out.integer.is_none() {
        out.steps = Some(off);
    }
    out
}

/// Join the endpoints of every offset-0 edge of `off` in `uf` (over `n` working vertices); with `guard`,
/// smallest rounding residual first (ties by edge), unless their clusters are linked by one of `links`
/// (unit-offset edges) already. Returns the refused joins.
///
/// Cost: O(E log E) for the order; each join merges the two clusters' link lists (a few dozen entries).
fn join_unlinked(uf: &mut UnionFind, n: usize, off: &integer::Offsets, links: &[(u32, u32)], guard: bool) -> usize {
    if !guard {
        for (&(i, j), d) in off.edges.iter().zip(&off.d) {
            if *d == [0, 0] {
                uf.union(i, j);
            }
        }
        return 0;
    }
    let residual = |e: usize| off.m[e][0] * off.m[e][0] + off.m[e][1] * off.m[e][1];
    let mut order: Vec<usize> = (0..off.edges.len()).filter(|&e| off.d[e] == [0, 0]).collect();
    order.sort_by(|&a, &b| residual(a).total_cmp(&residual(b)).then(a.cmp(&b)));
    // The working vertices each cluster's members are linked to, kept at the cluster's root.
    let mut linked: Vec<Vec<u32>> = vec![Vec::new(); n];
    for &(i, j) in links {
        linked[i as usize].push(j);
        linked[j as usize].push(i);
    }
    let mut refused = 0;
    for e in order {
        let (i, j) = off.edges[e];
        let (a, b) = (uf.find(i), uf.find(j));
        if a == b {
            continue;
        }
        if linked[a as usize].iter().any(|&k| uf.find(k) == b) {
            refused += 1;
            continue;
        }
        uf.union(a, b);
        let r = uf.find(a);
        let mut both = std::mem::take(&mut linked[a as usize]);
        both.append(&mut linked[b as usize]);
        let mut roots: Vec<u32> = both.into_iter().map(|k| uf.find(k)).filter(|&k| k != r).collect();
        roots.sort_unstable();
        roots.dedup();
        linked[r as usize] = roots;
    }
    refused
}

struct ClusterGraph {
    p: Vec<V3>,
    n: Vec<V3>,
    /// Area-weighted mean spacing of each cluster's members.
    s: Vec<f64>,
    /// One input vertex of each cluster (for re-joining).
    members: Vec<u32>,
    /// Cluster of every input vertex.
    cluster: Vec<u32>,
    /// Undirected edges (a < b), sorted, unique.
    edges: Vec<(u32, u32)>,
}

fn cluster_graph(level: &Level, o: &[V3], s: &[f64], uf: &mut UnionFind, links: &[(u32, u32)]) -> ClusterGraph {
    let n = level.len();
    let mut id = vec![u32::MAX; n];
    let mut roots = Vec::new();
    let mut cluster = vec![0u32; n];
    for i in 0..n {
        let r = uf.find(i as u32) as usize;
        if id[r] == u32::MAX {
            id[r] = roots.len() as u32;
            roots.push(i as u32);
        }
        cluster[i] = id[r];
    }
    let m = roots.len();
    let mut p = vec![[0.0; 3]; m];
    let mut nn = vec![[0.0; 3]; m];
    let mut w = vec![0.0; m];
    let mut cs = vec![0.0; m];
    for i in 0..n {
        let c = cluster[i] as usize;
        let a = level.area[i].max(1e-300);
        cs[c] += a * s[i];
        p[c] = add(p[c], scale(o[i], a));
        nn[c] = add(nn[c], scale(level.n[i], a));
        w[c] += a;
    }
    turn_folded_clusters(level, &cluster, &w, &mut nn);
    for c in 0..m {
        p[c] = scale(p[c], 1.0 / w[c]);
        cs[c] /= w[c];
        nn[c] = vec3::unit_or(nn[c], [0.0, 0.0, 1.0]);
    }
    let mut edges: Vec<(u32, u32)> = links
        .iter()
        .filter_map(|&(i, j)| {
            let (a, b) = (cluster[i as usize], cluster[j as usize]);
            (a != b).then(|| (a.min(b), a.max(b)))
        })
        .collect();
    edges.sort_unstable();
    edges.dedup();
    ClusterGraph { p, n: nn, s: cs, members: roots, cluster, edges }
}

/// A cluster whose area-weighted mean normal is shorter than this share of its area is folded: its members
/// face apart, as the two sides of a part thinner than the spacing do where they meet at its rim.
pub const FOLD_MEAN: f64 = 0.5;

/// The widest gap between a folded cluster's normals about the fold's axis, as a share of a turn, below which
/// it has no fold bisector ([`fold_bisector`]): a thin plate's rim spans half a turn (gap 1/2), noise a little
/// more.
pub const FOLD_GAP: f64 = 1.0 / 3.0;

/// A cluster whose members face apart (the two sides of a part thinner than the spacing, joined at its rim)
/// has a mean normal that says little: its summed normal `nn[c]` (area `w[c]`) is replaced by its fold's
/// bisector ([`fold_bisector`]), so its rotation system turns about that. `cluster[i]` is working vertex i's.
///
/// Cost: O(n) plus O(k log k) per folded cluster of k members.
fn turn_folded_clusters(level: &Level, cluster: &[u32], w: &[f64], nn: &mut [V3]) {
    let folded: Vec<usize> = (0..nn.len()).filter(|&c| vec3::norm(nn[c]) < FOLD_MEAN * w[c]).collect();
    if folded.is_empty() {
        return;
    }
    let mut slot = vec![usize::MAX; nn.len()];
    for (k, &c) in folded.iter().enumerate() {
        slot[c] = k;
    }
    let mut members: Vec<Vec<(V3, f64)>> = vec![Vec::new(); folded.len()];
    for (i, &c) in cluster.iter().enumerate() {
        if let Some(m) = members.get_mut(slot[c as usize]) {
            m.push((level.n[i], level.area[i].max(1e-300)));
        }
    }
    for (m, &c) in members.iter().zip(&folded) {
        if let Some(b) = fold_bisector(m) {
            nn[c] = scale(b, w[c]);
        }
    }
}

/// The middle of the arc a folded cluster's normals span: the fold's axis is the direction no member faces
/// (the smallest eigenvector of Σ a·n·nᵀ); about it, the members' normals cover an arc, and the bisector is
/// the direction opposite the middle of the widest gap between them. `None` when that gap is under
/// [`FOLD_GAP`] of a turn (no fold: the normals go round, as at a cone's tip) or there are fewer than two.
///
/// Cost: O(k log k) for k members.
fn fold_bisector(members: &[(V3, f64)]) -> Option<V3> {
    if members.len() < 2 {
        return None;
    }
    let mut c = [[0.0; 3]; 3];
    for &(nv, a) in members {
        for r in 0..3 {
            for k in 0..3 {
                c[r][k] += a * nv[r] * nv[k];
            }
        }
    }
    let axis = vec3::unit_or(crate::geometry::linalg::smallest_eigenvector(c), [0.0, 0.0, 1.0]);
    let u = tangent_unit([1.0, 0.0, 0.0], axis);
    let v = cross(axis, u);
    let mut angles: Vec<f64> = members.iter().map(|&(nv, _)| dot(nv, v).atan2(dot(nv, u))).collect();
    angles.sort_by(f64::total_cmp);
    let tau = std::f64::consts::TAU;
    let (mut gap, mut after) = (angles[0] + tau - angles[angles.len() - 1], angles[0]);
    for w in angles.windows(2) {
        if w[1] - w[0] > gap {
            (gap, after) = (w[1] - w[0], w[1]);
        }
    }
    // The normals span tau - gap; the arc starts at `after` and its middle is half that further on.
    if gap < FOLD_GAP * tau {
        return None;
    }
    let mid = after + 0.5 * (tau - gap);
    Some(add(scale(u, mid.cos()), scale(v, mid.sin())))
}

/// Weight of a cluster's pull back to its members' mean origin against its unit steps in [`place_by_steps`].
pub const PLACE_ANCHOR: f64 = 0.05;

/// Jacobi rounds of [`place_by_steps`] (a stretch spreads over about √rounds output edges).
pub const PLACE_ROUNDS: usize = 20;

/// Every unit-step input edge (i, j) as the 3D lattice vector of its step in i's frame.
fn link_vectors(level: &Level, q: &[V3], s: &[f64], off: &integer::Offsets) -> Vec<(u32, u32, V3)> {
    off.edges
        .iter()
        .zip(&off.d)
        .filter(|(_, d)| d[0].abs() + d[1].abs() == 1)
        .map(|(&(i, j), d)| {
            let iu = i as usize;
            let t = cross(level.n[iu], q[iu]);
            (i, j, scale(add(scale(q[iu], d[0] as f64), scale(t, d[1] as f64)), s[iu]))
        })
        .collect()
}

/// Place the clusters so that linked clusters lie one lattice step apart as their members' steps say
/// (mean of the steps between two clusters), weakly anchored at their mean origin: least squares by
/// Jacobi rounds.
fn place_by_steps(graph: &mut ClusterGraph, steps: &[(u32, u32, V3)]) {
    use std::collections::BTreeMap;
    let mut acc: BTreeMap<(u32, u32), (V3, f64)> = BTreeMap::new();
    for &(i, j, v) in steps {
        let (a, b) = (graph.cluster[i as usize], graph.cluster[j as usize]);
        if a == b {
            continue;
        }
        let (key, v) = if a < b { ((a, b), v) } else { ((b, a), scale(v, -1.0)) };
        let e = acc.entry(key).or_insert(([0.0; 3], 0.0));
        e.0 = add(e.0, v);
        e.1 += 1.0;
    }
    let m = graph.p.len();
    let mut adj: Vec<Vec<(u32, V3)>> = vec![Vec::new(); m];
    for (&(a, b), &(v, w)) in &acc {
        let v = scale(v, 1.0 / w);
        adj[a as usize].push((b, v));
        adj[b as usize].push((a, scale(v, -1.0)));
    }
    let anchor = graph.p.clone();
    for _ in 0..PLACE_ROUNDS {
        let cur = graph.p.clone();
        graph.p = (0..m)
            .into_par_iter()
            .map(|c| {
                let mut sum = scale(anchor[c], PLACE_ANCHOR);
                let mut w = PLACE_ANCHOR;
                for &(b, v) in &adj[c] {
                    sum = add(sum, sub(cur[b as usize], v));
                    w += 1.0;
                }
                scale(sum, 1.0 / w)
            })
            .collect();
    }
}

/// Remove vertices with fewer than 3 edges until none is left. Returns the remaining edges (sorted) and
/// how many vertices lost all their edges this way.
fn prune_low_valence(nv: usize, edges: &[(u32, u32)]) -> (Vec<(u32, u32)>, usize) {
    let mut deg = vec![0u32; nv];
    for &(a, b) in edges {
        deg[a as usize] += 1;
        deg[b as usize] += 1;
    }
    let mut alive = vec![true; edges.len()];
    let mut incident: Vec<Vec<u32>> = vec![Vec::new(); nv];
    for (e, &(a, b)) in edges.iter().enumerate() {
        incident[a as usize].push(e as u32);
        incident[b as usize].push(e as u32);
    }
    let mut stack: Vec<u32> = (0..nv as u32).filter(|&v| deg[v as usize] > 0 && deg[v as usize] < MIN_DEGREE).collect();
    let mut removed = 0;
    while let Some(v) = stack.pop() {
        if deg[v as usize] == 0 || deg[v as usize] >= MIN_DEGREE {
            continue;
        }
        removed += 1;
        for &e in &incident[v as usize] {
            if !alive[e as usize] {
                continue;
            }
            alive[e as usize] = false;
            let (a, b) = edges[e as usize];
            let other = if a == v { b } else { a };
            deg[v as usize] -= 1;
            deg[other as usize] -= 1;
            if deg[other as usize] > 0 && deg[other as usize] < MIN_DEGREE {
                stack.push(other);
            }
        }
    }
    (edges.iter().zip(&alive).filter(|(_, a)| **a).map(|(e, _)| *e).collect(), removed)
}

/// Trace the faces of the rotation system given by sorting each vertex's neighbours by angle about its
/// normal. Returns the faces and the (sorted) edges that have the same face on both sides.
fn trace_faces(p: &[V3], n: &[V3], edges: &[(u32, u32)]) -> (Vec<Vec<u32>>, Vec<(u32, u32)>) {
    let nv = p.len();
    let mut half: Vec<(u32, u32)> = Vec::with_capacity(edges.len() * 2);
    for &(a, b) in edges {
        half.push((a, b));
        half.push((b, a));
    }
    half.sort_unstable();
    let off: Vec<usize> = crate::geometry::polygon::csr(nv, &half).0.into_iter().map(|o| o as usize).collect();
    // Sort each vertex's outgoing half-edges counter-clockwise about its normal.
    for v in 0..nv {
        let (lo, hi) = (off[v], off[v + 1]);
        if hi - lo < 2 {
            continue;
        }
        let nv_ = n[v];
        let first = sub(p[half[lo].1 as usize], p[v]);
        let x = tangent_unit(first, nv_);
        let y = cross(nv_, x);
        let slice = &mut half[lo..hi];
        slice.sort_by(|a, b| {
            let ang = |h: &(u32, u32)| {
                let d = sub(p[h.1 as usize], p[v]);
                dot(d, y).atan2(dot(d, x))
            };
            ang(a).total_cmp(&ang(b)).then(a.1.cmp(&b.1))
        });
    }
    // Position of each half-edge's twin.
    let pos_in = |v: usize, target: u32, half: &[(u32, u32)]| -> usize {
        (off[v]..off[v + 1]).find(|&h| half[h].1 == target).expect("twin exists")
    };
    let mut face_of = vec![u32::MAX; half.len()];
    let mut faces = Vec::new();
    for start in 0..half.len() {
        if face_of[start] != u32::MAX {
            continue;
        }
        let fid = faces.len() as u32;
        let mut face = Vec::new();
        let mut h = start;
        loop {
            face_of[h] = fid;
            let (a, b) = half[h];
            face.push(a);
            // At b, arriving from a: the next outgoing edge is the one just before (b→a) counter-clockwise.
            let k = pos_in(b as usize, a, &half);
            let (lo, hi) = (off[b as usize], off[b as usize + 1]);
            let next = if k == lo { hi - 1 } else { k - 1 };
            h = next;
            if h == start {
                break;
            }
            if face_of[h] != u32::MAX || face.len() > half.len() {
                break; // cannot happen for a consistent rotation system; stop defensively
            }
        }
        faces.push(face);
    }
    let mut dangling = Vec::new();
    for (h, &(a, b)) in half.iter().enumerate() {
        if a < b {
            let t = pos_in(b as usize, a, &half);
            if face_of[h] == face_of[t] {
                dangling.push((a, b));
            }
        }
    }
    dangling.sort_unstable();
    (faces, dangling)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A thin plate's rim: normals from +z over the outward x to −z (and a little noise). The bisector is x,
    /// whatever the share of top and bottom area; the area-weighted mean would tip toward the larger side.
    #[test]
    fn a_rims_fold_turns_about_its_bisector() {
        let mut members = Vec::new();
        for k in 0..=8 {
            let a = std::f64::consts::PI * (0.5 - k as f64 / 8.0);
            members.push(([a.cos(), 0.0, a.sin()], 1.0));
        }
        members.extend([([0.0, 0.0, 1.0], 30.0), ([0.0, 0.0, -1.0], 5.0), ([0.02, 0.01, 0.9998], 3.0)]);
        let b = fold_bisector(&members).expect("a fold");
        assert!(dot(b, [1.0, 0.0, 0.0]) > 0.99, "bisector {b:?}");
    }

    /// Normals all round an axis (a cone's tip seen from its side) have no fold: no bisector.
    #[test]
    fn normals_all_round_have_no_bisector() {
        let members: Vec<(V3, f64)> = (0..12)
            .map(|k| {
                let a = std::f64::consts::TAU * k as f64 / 12.0;
                ([a.cos(), a.sin(), 0.0], 1.0)
            })
            .collect();
        assert_eq!(fold_bisector(&members), None);
    }
}

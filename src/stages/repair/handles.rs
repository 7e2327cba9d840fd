//! Step 3b (optional): remove *topological noise*, handles whose shortest non-separating loop is shorter
//! than a set length (the idea of Guskov & Wood 2001, "Topological noise removal").
//!
//! Range-scan fusion (VRIP and its kin) leaves tiny tunnels through thin sheets and tiny bridges across
//! narrow slots: the shared dragon has 20 of them below a millimetre, beside its one real handle. No quad
//! mesh near a useful vertex count can carry them, so every later stage would change the Euler
//! characteristic by accident. This step changes it on purpose, by the least surface, and says so.
//!
//! Method, for a closed oriented 2-manifold:
//! 1. **Seeds.** Vertices in index order; a vertex within `r / 2` (graph distance) of an earlier seed is
//!    skipped. Every loop shorter than about `r` then lies inside the ball of radius `r` around some seed.
//! 2. **Ball.** A Dijkstra front over the edge graph from the seed; the ball R holds the faces whose three
//!    corners lie within `r`. Its Euler characteristic χ(R), its boundary loops b and so its genus
//!    g(R) = (2 − χ(R) − b) / 2 are counted directly. A disk (g = 0, b = 1) holds no handle.
//! 3. **Separation.** Otherwise a breadth-first search over the faces outside R starts from every boundary
//!    loop at once and joins loops whose searches meet. A planar ball whose loops each bound their own
//!    outside part holds only separating loops (a ring around a finger); a ball whose loops all reach one
//!    outside part (or with g > 0) holds a handle. The search stops once at most one part is still open,
//!    or after [`SEARCH_BUDGET`] faces (then nothing is cut).
//! 4. **Cut.** The smallest radius of [`RADII`] · r that still shows a handle whose loops all reach one
//!    part is used: its ball is deleted and each of its b loops is filled as a hole (the step 5 filler:
//!    minimum-weight triangulation, refinement, thin-plate fairing). The genus drops by g(R) + b − 1 ≥ 1;
//!    the surface stays connected, closed and manifold. A ball touching itself at a vertex (a pinch on its
//!    boundary) takes in that vertex's faces first.
//!
//! Cost: O(V log V) for the seed pass (each vertex is in O(1) balls of O(r² / edge²) vertices) plus, per
//! ball that is not a disk, a search of at most [`SEARCH_BUDGET`] faces.

use std::cmp::Ordering;
use std::collections::{BinaryHeap, HashMap, HashSet, VecDeque};

use crate::geometry::topology::UnionFind;
use crate::geometry::vec3::{self, V3};

use super::holes;

/// Radii tried at a seed whose full ball holds a handle, as fractions of `r`, largest first: the smallest
/// that still shows a cuttable handle is cut, so the least surface is replaced.
pub const RADII: [f64; 4] = [1.0, 0.7, 0.5, 0.35];
/// Faces the separation search may visit outside one ball before it gives up (and cuts nothing).
pub const SEARCH_BUDGET: usize = 200_000;
/// Rounds of taking in the faces around a pinched boundary vertex before a ball is given up.
const PINCH_ROUNDS: usize = 4;
/// Rings of faces around the cut's loops handed to the hole filler (it looks 4 rings out).
const FILL_RINGS: usize = 7;

/// What the handle removal did.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct HandleReport {
    /// Longest loop length removed (input units; 0: the step was off).
    pub max_loop: f64,
    /// Seeds whose ball was grown.
    pub seeds: usize,
    /// Balls that were not disks (their outside was searched).
    pub balls_searched: usize,
    /// Balls whose separation search ran out of budget (nothing cut there).
    pub searches_given_up: usize,
    /// Cuts made.
    pub cuts: usize,
    /// Genus removed, summed over the cuts (Σ g(R) + b − 1).
    pub genus_removed: usize,
    /// Faces deleted, and triangles the fills added.
    pub faces_removed: usize,
    /// Triangles added by filling the cuts.
    pub triangles_added: usize,
    /// Radius of each cut's ball (input units).
    pub cut_radii: Vec<f64>,
}

/// Dijkstra queue entry, nearest first.
#[derive(Copy, Clone, PartialEq)]
struct Near(f64, u32);
impl Eq for Near {}
impl PartialOrd for Near {
    fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for Near {
    fn cmp(&self, o: &Self) -> Ordering {
        o.0.total_cmp(&self.0).then(o.1.cmp(&self.1))
    }
}

/// The mesh as it is being cut: faces with an alive flag and, per vertex, its alive faces.
struct Work<'a> {
    p: &'a mut Vec<V3>,
    tris: &'a mut Vec<[u32; 3]>,
    alive: Vec<bool>,
    around: Vec<Vec<u32>>,
    dist: Vec<f64>,
    /// Face stamps: `in_ball[f] == stamp` while f is in the current ball.
    in_ball: Vec<u32>,
    stamp: u32,
}

/// A grown ball and its topology.
struct Ball {
    faces: Vec<u32>,
    /// Boundary loops as half-edge chains (a → b with the ball's face on the left).
    loops: Vec<Vec<(u32, u32, u32)>>,
    genus: usize,
}

enum Verdict {
    Disk,
    Handle,
    /// A handle, but some loop bounds a part of its own (cutting would split the surface).
    HandleSplits,
    Separating,
    GaveUp,
}

impl<'a> Work<'a> {
    fn new(p: &'a mut Vec<V3>, tris: &'a mut Vec<[u32; 3]>) -> Self {
        let mut around = vec![Vec::new(); p.len()];
        for (f, t) in tris.iter().enumerate() {
            for &v in t {
                around[v as usize].push(f as u32);
            }
        }
        let n = p.len();
        let alive = vec![true; tris.len()];
        let in_ball = vec![0; tris.len()];
        Work { p, tris, alive, around, dist: vec![f64::INFINITY; n], in_ball, stamp: 0 }
    }

    /// The other alive face on edge {a, b} of face f (the mesh is manifold: at most one).
    fn across(&self, f: u32, a: u32, b: u32) -> Option<u32> {
        self.around[a as usize].iter().copied().find(|&g| g != f && self.tris[g as usize].contains(&b))
    }

    /// The corner after `v` in face f.
    fn after(&self, f: u32, v: u32) -> u32 {
        let t = self.tris[f as usize];
        let i = t.iter().position(|&x| x == v).expect("vertex of face");
        t[(i + 1) % 3]
    }

    /// Graph distances from `seed` up to `r`: the vertices reached, nearest first (`dist` holds them until
    /// [`Work::clear`]).
    fn front(&mut self, seed: u32, r: f64) -> Vec<u32> {
        let mut reached = Vec::new();
        let mut heap = BinaryHeap::new();
        self.dist[seed as usize] = 0.0;
        heap.push(Near(0.0, seed));
        while let Some(Near(d, v)) = heap.pop() {
            if d > self.dist[v as usize] {
                continue;
            }
            reached.push(v);
            for &f in &self.around[v as usize] {
                for w in self.tris[f as usize] {
                    let nd = d + vec3::norm(vec3::sub(self.p[w as usize], self.p[v as usize]));
                    if nd <= r && nd < self.dist[w as usize] {
                        if self.dist[w as usize].is_infinite() {
                            reached.push(w);
                        }
                        self.dist[w as usize] = nd;
                        heap.push(Near(nd, w));
                    }
                }
            }
        }
        reached.sort_unstable();
        reached.dedup();
        reached
    }

    fn clear(&mut self, reached: &[u32]) {
        for &v in reached {
            self.dist[v as usize] = f64::INFINITY;
        }
    }

    /// The ball of faces whose corners are all within `r` of the seed (distances from [`Work::front`] at
    /// radius ≥ r), with pinches taken in; None when it stays pinched.
    fn ball(&mut self, reached: &[u32], r: f64) -> Option<Ball> {
        self.stamp += 1;
        let stamp = self.stamp;
        let mut faces: Vec<u32> = Vec::new();
        for &v in reached {
            if self.dist[v as usize] > r {
                continue;
            }
            for &f in &self.around[v as usize] {
                if self.in_ball[f as usize] != stamp
                    && self.tris[f as usize].iter().all(|&w| self.dist[w as usize] <= r)
                {
                    self.in_ball[f as usize] = stamp;
                    faces.push(f);
                }
            }
        }
        if faces.is_empty() {
            return None;
        }
        for _ in 0..PINCH_ROUNDS {
            let loops = self.loops(&faces, stamp);
            let mut seen = HashSet::new();
            let pinched: Vec<u32> = loops.iter().flatten().map(|h| h.0).filter(|&v| !seen.insert(v)).collect();
            if pinched.is_empty() {
                faces.sort_unstable();
                let genus = self.genus(&faces, loops.len())?;
                return Some(Ball { faces, loops, genus });
            }
            for v in pinched {
                for &f in &self.around[v as usize] {
                    if self.in_ball[f as usize] != stamp {
                        self.in_ball[f as usize] = stamp;
                        faces.push(f);
                    }
                }
            }
        }
        None
    }

    /// Boundary loops of the faces stamped `stamp`: chains of (a, b, face) half-edges.
    fn loops(&self, faces: &[u32], stamp: u32) -> Vec<Vec<(u32, u32, u32)>> {
        let inside = |g: Option<u32>| g.is_some_and(|g| self.in_ball[g as usize] == stamp);
        let mut boundary: Vec<(u32, u32, u32)> = Vec::new();
        for &f in faces {
            let t = self.tris[f as usize];
            for i in 0..3 {
                let (a, b) = (t[i], t[(i + 1) % 3]);
                if !inside(self.across(f, a, b)) {
                    boundary.push((a, b, f));
                }
            }
        }
        boundary.sort_unstable();
        let mut used = vec![false; boundary.len()];
        let index: HashMap<(u32, u32), usize> = boundary.iter().enumerate().map(|(i, h)| ((h.0, h.1), i)).collect();
        let mut loops = Vec::new();
        for start in 0..boundary.len() {
            if used[start] {
                continue;
            }
            let mut chain = Vec::new();
            let mut i = start;
            while !used[i] {
                used[i] = true;
                let (_, b, f) = boundary[i];
                chain.push(boundary[i]);
                // Turn around b through the ball's faces to the next boundary half-edge out of b.
                let (mut g, mut c) = (f, self.after(f, b));
                let mut guard = 0;
                loop {
                    if let Some(&j) = index.get(&(b, c))
                        && boundary[j].2 == g
                    {
                        i = j;
                        break;
                    }
                    let Some(h) = self.across(g, b, c) else { return Vec::new() };
                    g = h;
                    c = self.after(g, b);
                    guard += 1;
                    if guard > 1000 {
                        return Vec::new();
                    }
                }
            }
            loops.push(chain);
        }
        loops
    }

    /// Genus of the ball from χ = V − E + F and its b boundary loops.
    fn genus(&self, faces: &[u32], b: usize) -> Option<usize> {
        let mut verts: Vec<u32> = faces.iter().flat_map(|&f| self.tris[f as usize]).collect();
        verts.sort_unstable();
        verts.dedup();
        let mut edges: Vec<(u32, u32)> = faces
            .iter()
            .flat_map(|&f| {
                let t = self.tris[f as usize];
                (0..3).map(move |i| (t[i].min(t[(i + 1) % 3]), t[i].max(t[(i + 1) % 3])))
            })
            .collect();
        edges.sort_unstable();
        edges.dedup();
        let chi = verts.len() as i64 - edges.len() as i64 + faces.len() as i64;
        let twice = 2 - chi - b as i64;
        (twice >= 0 && twice % 2 == 0).then_some((twice / 2) as usize)
    }

    /// Whether the ball's loops reach each other outside it (see the module doc).
    fn verdict(&self, ball: &Ball) -> Verdict {
        let b = ball.loops.len();
        if b == 0 {
            return Verdict::Disk; // a whole component: nothing to cut against
        }
        if ball.genus == 0 && b == 1 {
            return Verdict::Disk;
        }
        if b == 1 {
            return Verdict::Handle;
        }
        let stamp = self.stamp;
        let mut label: HashMap<u32, usize> = HashMap::new();
        let mut queues: Vec<VecDeque<u32>> = vec![VecDeque::new(); b];
        let mut uf = UnionFind::new(b);
        for (i, lp) in ball.loops.iter().enumerate() {
            for &(a, bb, f) in lp {
                if let Some(g) = self.across(f, a, bb) {
                    match label.get(&g) {
                        None => {
                            label.insert(g, i);
                            queues[i].push_back(g);
                        }
                        Some(&j) => uf.union(i as u32, j as u32),
                    }
                }
            }
        }
        let mut visited = 0usize;
        loop {
            // Classes, and whether each still has an open search.
            let mut open: HashMap<u32, bool> = HashMap::new();
            for (i, q) in queues.iter().enumerate() {
                *open.entry(uf.find(i as u32)).or_insert(false) |= !q.is_empty();
            }
            let classes = open.len();
            let still_open = open.values().filter(|&&o| o).count();
            if classes == 1 {
                return Verdict::Handle;
            }
            if still_open <= 1 {
                let mut size: HashMap<u32, usize> = HashMap::new();
                for i in 0..b {
                    *size.entry(uf.find(i as u32)).or_insert(0) += 1;
                }
                return if ball.genus > 0 || size.values().any(|&s| s > 1) {
                    Verdict::HandleSplits
                } else {
                    Verdict::Separating
                };
            }
            if visited > SEARCH_BUDGET {
                return Verdict::GaveUp;
            }
            for i in 0..b {
                let Some(f) = queues[i].pop_front() else { continue };
                visited += 1;
                let t = self.tris[f as usize];
                for k in 0..3 {
                    let Some(g) = self.across(f, t[k], t[(k + 1) % 3]) else { continue };
                    if self.in_ball[g as usize] == stamp {
                        continue;
                    }
                    match label.get(&g) {
                        None => {
                            label.insert(g, i);
                            queues[i].push_back(g);
                        }
                        Some(&j) => uf.union(i as u32, j as u32),
                    }
                }
            }
        }
    }

    /// Delete the ball and fill its loops; false (and nothing changed) when a loop was not filled.
    fn cut(&mut self, ball: &Ball) -> Option<usize> {
        for &f in &ball.faces {
            self.alive[f as usize] = false;
        }
        for &f in &ball.faces {
            for v in self.tris[f as usize] {
                self.around[v as usize].retain(|&g| g != f);
            }
        }
        let rim: Vec<u32> = ball.loops.iter().flatten().map(|h| h.0).collect();
        // The alive faces within FILL_RINGS rings of the rim, as a local mesh.
        let mut vs: HashSet<u32> = rim.iter().copied().collect();
        let mut fs: HashSet<u32> = HashSet::new();
        let mut front = rim.clone();
        for _ in 0..FILL_RINGS {
            let mut next = Vec::new();
            for &v in &front {
                for &f in &self.around[v as usize] {
                    if fs.insert(f) {
                        next.extend(self.tris[f as usize].into_iter().filter(|&w| vs.insert(w)));
                    }
                }
            }
            front = next;
        }
        let mut global: Vec<u32> = vs.into_iter().collect();
        global.sort_unstable();
        let mut faces: Vec<u32> = fs.into_iter().collect();
        faces.sort_unstable();
        let local_of: HashMap<u32, u32> = global.iter().enumerate().map(|(i, &g)| (g, i as u32)).collect();
        let mut lp: Vec<V3> = global.iter().map(|&g| self.p[g as usize]).collect();
        let mut lt: Vec<[u32; 3]> = faces.iter().map(|&f| self.tris[f as usize].map(|v| local_of[&v])).collect();
        let local_rim: HashSet<u32> = rim.iter().map(|v| local_of[v]).collect();
        let (n_local, f_local) = (lp.len(), lt.len());
        let filled = holes::fill_holes_near(&mut lp, &mut lt, &local_rim);
        if filled.holes_filled != ball.loops.len() {
            // Put the ball back.
            for &f in &ball.faces {
                self.alive[f as usize] = true;
                for v in self.tris[f as usize] {
                    self.around[v as usize].push(f);
                }
            }
            return None;
        }
        let first = self.p.len() as u32;
        self.p.extend_from_slice(&lp[n_local..]);
        self.dist.resize(self.p.len(), f64::INFINITY);
        self.around.resize(self.p.len(), Vec::new());
        let to_global = |v: u32| if (v as usize) < n_local { global[v as usize] } else { first + v - n_local as u32 };
        let added = lt.len() - f_local;
        for t in &lt[f_local..] {
            let f = self.tris.len() as u32;
            let t = t.map(to_global);
            self.tris.push(t);
            self.alive.push(true);
            self.in_ball.push(0);
            for v in t {
                self.around[v as usize].push(f);
            }
        }
        Some(added)
    }
}

/// Remove every handle whose shortest non-separating loop is shorter than about `max_loop` (input units)
/// from the closed oriented 2-manifold `tris`, in place (new fill vertices are appended to `p`; deleted
/// vertices stay, unreferenced). Deterministic: seeds and cuts go in vertex order.
///
/// Cost: see the module doc; about a second for the 435k-vertex dragon.
pub fn remove_small_handles(p: &mut Vec<V3>, tris: &mut Vec<[u32; 3]>, max_loop: f64) -> HandleReport {
    let mut report = HandleReport { max_loop, ..Default::default() };
    if !(max_loop > 0.0) || tris.is_empty() {
        return report;
    }
    let r = max_loop;
    let n = p.len();
    let mut w = Work::new(p, tris);
    let mut covered = vec![false; n];
    for s in 0..n as u32 {
        if covered[s as usize] || w.around[s as usize].is_empty() {
            continue;
        }
        report.seeds += 1;
        let reached = w.front(s, r);
        for &v in &reached {
            if (v as usize) < n && w.dist[v as usize] <= r / 2.0 {
                covered[v as usize] = true;
            }
        }
        let mut best: Option<(Ball, f64)> = None;
        let mut searched = false;
        for &frac in &RADII {
            let Some(ball) = w.ball(&reached, r * frac) else { break };
            match w.verdict(&ball) {
                Verdict::Handle => best = Some((ball, r * frac)),
                // A smaller ball may hold the handle without splitting the surface.
                Verdict::HandleSplits if best.is_none() => {}
                Verdict::GaveUp => {
                    report.searches_given_up += 1;
                    searched = true;
                    break;
                }
                Verdict::Disk => break,
                _ => {
                    searched = true;
                    break;
                }
            }
            searched = true;
        }
        if searched {
            report.balls_searched += 1;
        }
        w.clear(&reached);
        let Some((ball, radius)) = best else { continue };
        // Re-stamp the chosen ball (later radii overwrote the stamps), then cut it.
        w.stamp += 1;
        for &f in &ball.faces {
            w.in_ball[f as usize] = w.stamp;
        }
        let gain = ball.genus + ball.loops.len() - 1;
        if let Some(added) = w.cut(&ball) {
            report.cuts += 1;
            report.genus_removed += gain;
            report.faces_removed += ball.faces.len();
            report.triangles_added += added;
            report.cut_radii.push(radius);
            tracing::debug!(seed = s, radius, loops = ball.loops.len(), genus = ball.genus, "handle cut");
        }
    }
    let alive = std::mem::take(&mut w.alive);
    let mut k = 0;
    w.tris.retain(|_| {
        k += 1;
        alive[k - 1]
    });
    report
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::mesh::{PolyMesh, TriMesh};
    use crate::geometry::shapes;
    use crate::geometry::topology::TopologyReport;
    use crate::geometry::vec3::wide;
    use proptest::prelude::*;

    fn run(m: &TriMesh, max_loop: f64) -> (HandleReport, TopologyReport, Vec<V3>, Vec<[u32; 3]>) {
        let mut p: Vec<V3> = m.positions.iter().map(|&q| wide(q)).collect();
        let mut t = m.triangles.clone();
        let report = remove_small_handles(&mut p, &mut t, max_loop);
        let out = TriMesh { positions: p.iter().map(|q| q.map(|c| c as f32)).collect(), triangles: t.clone() };
        let topo = TopologyReport::compute(&PolyMesh::from(out));
        (report, topo, p, t)
    }

    fn assert_closed_manifold(topo: &TopologyReport, what: &str) {
        assert!(topo.closed, "{what}: {} boundary edges", topo.boundary_edges);
        assert_eq!(topo.nonmanifold_edges, 0, "{what}: non-manifold edges");
        assert_eq!(topo.nonmanifold_vertices, 0, "{what}: non-manifold vertices");
        assert_eq!(topo.orientation_conflicts, 0, "{what}: orientation conflicts");
        assert_eq!(topo.components, 1, "{what}: components");
    }

    /// Analytic oracle: a thin torus (tube radius 0.05, meridian 2π·0.05 ≈ 0.314) holds one handle whose
    /// shortest loop is the meridian. A limit above the meridian cuts it (genus 1 → 0, the tube capped where
    /// the ball was, every vertex still within the tube); a limit under half the meridian cannot wrap a ball
    /// around the tube and cuts nothing.
    #[test]
    fn a_thin_torus_loses_its_handle_only_above_its_meridian() {
        let minor = 0.05;
        let meridian = std::f64::consts::TAU * minor;
        let m = shapes::torus(1.0, minor, 160, 12);
        let (r, topo, p, t) = run(&m, 1.05 * meridian);
        assert_closed_manifold(&topo, "cut torus");
        assert_eq!(r.cuts, 1, "{r:?}");
        assert_eq!(r.genus_removed, 1, "{r:?}");
        assert_eq!(topo.genus, Some(0), "cut torus genus");
        // Every vertex in use lies in the solid tube (caps inside it), none beyond the tube surface.
        let mut used = vec![false; p.len()];
        t.iter().flatten().for_each(|&v| used[v as usize] = true);
        let worst = p
            .iter()
            .zip(&used)
            .filter(|(_, u)| **u)
            .map(|(q, _)| (q[0].hypot(q[1]) - 1.0).hypot(q[2]) - minor)
            .fold(f64::NEG_INFINITY, f64::max);
        assert!(worst <= 1e-3 * minor, "a vertex {worst:.3e} outside the tube");
        assert!(r.faces_removed < t.len() / 4, "the cut removed {} faces of {}", r.faces_removed, t.len());

        let (r, topo, _, t2) = run(&m, 0.45 * meridian);
        assert_eq!(r.cuts, 0, "{r:?}");
        assert_eq!(topo.genus, Some(1));
        assert_eq!(t2, m.triangles, "nothing cut, nothing changed");
    }

    /// A ball wrapped around a thin rod is an annulus whose two loops bound different parts (the tip and
    /// the rest): separating, so nothing is cut.
    #[test]
    fn a_ring_around_a_thin_rod_is_not_a_handle() {
        let m = shapes::rod(0.05, 1.0, 12, 60);
        let (r, topo, _, t) = run(&m, 0.5);
        assert!(r.balls_searched > 0, "the rod's balls are annuli: {r:?}");
        assert_eq!(r.cuts, 0, "{r:?}");
        assert_eq!(topo.genus, Some(0));
        assert_eq!(t, m.triangles);
    }

    /// A fat torus's handles are far longer than the limit: nothing is cut.
    #[test]
    fn a_fat_torus_keeps_its_handle() {
        let m = shapes::torus(1.0, 0.4, 64, 32);
        let (r, topo, _, t) = run(&m, 0.4);
        assert_eq!(r.cuts, 0, "{r:?}");
        assert_eq!(topo.genus, Some(1));
        assert_eq!(t, m.triangles);
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 12, ..ProptestConfig::default() })]
        /// Invariants: whatever is cut, the result is one closed oriented 2-manifold; the genus drops by
        /// exactly the reported amount; a mesh scaled by s with the limit scaled by s is cut the same way.
        #[test]
        fn cuts_keep_a_closed_manifold_and_scale_with_the_mesh(
            minor in 0.03f64..0.12,
            factor in 0.3f64..1.6,
            scale in prop::sample::select(vec![1e-3, 1.0, 1e3]),
        ) {
            let mut m = shapes::torus(1.0, minor, 120, 10);
            m.positions.iter_mut().for_each(|q| *q = q.map(|c| (c as f64 * scale) as f32));
            let limit = factor * std::f64::consts::TAU * minor * scale;
            let (r, topo, _, _) = run(&m, limit);
            assert_closed_manifold(&topo, "torus");
            prop_assert_eq!(topo.genus, Some(1 - r.genus_removed as i64));
            if factor >= 1.05 {
                prop_assert_eq!(r.cuts, 1, "{:?}", r);
            }
            if factor <= 0.45 {
                prop_assert_eq!(r.cuts, 0, "{:?}", r);
            }
            let unit = shapes::torus(1.0, minor, 120, 10);
            let (r1, _, _, _) = run(&unit, factor * std::f64::consts::TAU * minor);
            prop_assert_eq!(r1.cuts, r.cuts);
            prop_assert_eq!(r1.faces_removed, r.faces_removed);
        }
    }
}

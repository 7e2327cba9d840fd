//! Dipole transport and cancellation on a closed pure-quad mesh (connectivity editing in the manner of Peng,
//! Zhang, Jiang and Wonka 2011, with Tarini et al. 2010's quad-mesh operators).
//!
//! The greedy valence pass ([`super::quadify::optimize_valence`]) applies only operations that lower
//! Σ|valence − 4| at once. What it leaves is mostly **dipoles**: a valence-3 vertex next to a valence-5 one,
//! a dislocation of the quad grid. A dipole cannot be removed alone, but an operation that moves it one step
//! costs nothing (an edge rotation glides it along its grid line; a vertex split or a diagonal collapse
//! moves it across), and two dipoles of opposite sign that meet annihilate. [`transport_dipoles`] searches,
//! from every irregular vertex, chains of up to `depth` cost-neutral operations that end in one with a strict
//! gain, and commits a chain only when it ends so: no dipole is left moved without a cancellation to show for
//! it.
//!
//! Operations (on a closed, edge-manifold pure-quad mesh; valences stay ≥ 3 and the mesh stays manifold):
//! - **edge rotation**: the edge (u, v) shared by two quads is replaced by another diagonal (x, y) of their
//!   hexagon; u and v lose an edge, x and y gain one;
//! - **diagonal collapse** of quad (a, b, c, d): c merges into a at their midpoint (N(a) ∩ N(c) = {b, d});
//!   b and d lose an edge, the merged vertex has valence(a) + valence(c) − 2;
//! - **vertex split** (the collapse's inverse): vertex w of valence k is cut along two of its edges, to b and
//!   d, into w and a new w′, with the quad (w, b, w′, d) between them; w and w′ keep m + 1 and k − m + 1
//!   edges (m, k − m ≥ 2 of w's quads on each side), b and d gain one.
//!
//! Chains are searched twice. First every operation must leave the quads it touches sound as they stand (no
//! vertex moves; [`MIN_FACE_COS`], [`MIN_CORNER_SINE`]). Then, from vertices of valence > 4 with a deficit
//! within [`SETTLE_REACH`] edges, the **settling phase** lets the chain's intermediate quads fold and judges
//! only its end: the region it changed is smoothed tangentially ([`RELAX_ROUNDS`] rounds, the moves
//! journaled) and every quad at it must then be sound. A dislocation two edges from its partner often has to
//! pass through a folded quad on its way. Measured at 10k (seed 0): the repaired dragon 489 → 454 irregular
//! vertices, the armadillo 475 → 450, the test sphere 14 → 12; going on to depth 6 gave 448 and 442 for four
//! times the dragon's settling time.
//!
//! Σ|valence − 4| strictly drops with every chain, so the passes end. Cost: O(V · b^depth · r) for branching b
//! (cost-neutral operations near a chain, a handful) and r the operations in one ring; single-threaded and
//! deterministic (vertices in index order).

use crate::geometry::polygon;
use crate::geometry::vec3::{V3, add, cross, dot, norm, scale, sub};

/// Longest chain of cost-neutral operations searched before a cancelling one (about the reach, in edges).
/// Measured on the repaired dragon at 10k, seed 0: the kept result has 1215 irregular vertices without the
/// transport, 508 at depth 5 and 500 at depth 6. On the untransported result itself (Σ|valence − 4| 1256)
/// depths 3, 4, 5, 6 reach 586, 520, 494, 486 in 0.1–0.3 s each. Letting a chain first spend a unit of cost
/// (a budget of 2) reached 392 instead of 470 on the armadillo's result, but took 4 s at depth 3 and
/// minutes at depth 5, so chains are cost-neutral until their last step.
pub const TRANSPORT_DEPTH: usize = 5;

/// Least cosine between a quad's (Newell) normal and its corners' vertex normals after an operation: an
/// operation that would tilt a quad further is not made. Chosen with [`MIN_CORNER_SINE`] on the dragon and
/// armadillo at 10k (seed 0): with no check, moves folded quads that relaxation could not unfold (the
/// dragon's refined direct results kept 1–3 flipped faces and lost to the direct route, 0.083 % RMS); with
/// corners required convex (sine > 0.05; a rotation's new quads start with a straight corner) most moves were
/// refused (dragon 606 irregular vertices, armadillo 502); with 0.3 and −0.5: 508 and 470, no flipped face.
pub const MIN_FACE_COS: f64 = 0.3;

/// Least sine of a quad's corner (relative to its vertex normals) after an operation: reflex corners up to
/// 210° are let through (relaxation straightens them; a rotation's new quads start with a straight corner),
/// folded ones not. See [`MIN_FACE_COS`].
pub const MIN_CORNER_SINE: f64 = -0.5;

/// Passes over all vertices; each pass commits every chain it finds.
pub const TRANSPORT_PASSES: usize = 8;

/// Tangential smoothing rounds that settle a chain's region before its quads are checked, in the settling
/// phase ([`transport_dipoles`]).
pub const RELAX_ROUNDS: usize = 4;

/// The settling phase starts only from vertices of valence > 4 with one of valence < 4 within this many
/// edges. Measured on the repaired dragon at 10k (seed 0, depth 5): starting from every vertex of valence > 4
/// gave 453 irregular vertices for 1.6 s over the dragon's two transported results, from those with a
/// deficit within 2 edges 452–454 for 0.2 s.
pub const SETTLE_REACH: usize = 2;

/// What [`transport_dipoles`] did.
#[derive(Clone, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct TransportCounts {
    /// Chains committed (each ends in a strict gain).
    pub chains: usize,
    /// Cost-neutral operations inside those chains.
    pub moves: usize,
    /// Chains of them found by the settling phase (whose intermediate quads may fold; see the module docs).
    pub settled_chains: usize,
    /// The chains' final operations, by kind.
    pub cancelling_rotations: usize,
    /// Chains ending in a diagonal collapse.
    pub cancelling_collapses: usize,
    /// Chains ending in a vertex split.
    pub cancelling_splits: usize,
    /// Vertices added by splits and removed by collapses, over all chains.
    pub vertices_added: usize,
    /// Vertices removed by collapses.
    pub vertices_removed: usize,
    /// Σ|valence − 4| before and after.
    pub irregularity_before: usize,
    /// Σ|valence − 4| after.
    pub irregularity_after: usize,
}

fn cost(v: usize) -> i64 {
    (v as i64 - 4).abs()
}

/// An operation on the mesh, as found by the search.
#[derive(Clone, Debug)]
enum Op {
    /// Faces `f1` and `f2` become `n1`, `n2`.
    Rotate { f1: u32, f2: u32, n1: [u32; 4], n2: [u32; 4] },
    /// Quad `f` = (a, b, c, d) with c merged into a.
    Collapse { f: u32, a: u32, c: u32 },
    /// Vertex `w` split: the faces `side` (w's quads from d round to b) move to a new vertex, and the quad
    /// (w, b, w′, d) is added.
    Split { w: u32, b: u32, d: u32, side: Vec<u32> },
}

impl Op {
    /// The two faces of a rotation, ordered (to avoid undoing the previous step).
    fn pair(&self) -> Option<(u32, u32)> {
        match *self {
            Op::Rotate { f1, f2, .. } => Some((f1.min(f2), f1.max(f2))),
            _ => None,
        }
    }
}

/// A found operation: its gain and the vertices whose valence it changes.
struct Found {
    gain: i64,
    op: Op,
    touched: Vec<u32>,
}

/// One undoable change.
enum Change {
    Face(u32, [u32; 4]),
    PushedFace,
    Killed(u32),
    PushedVertex,
    Moved(u32, V3),
}

/// A closed pure-quad mesh with vertex → face incidence and a journal of changes, for local edits.
struct QuadEdit {
    p: Vec<V3>,
    /// Area-weighted vertex normals of the mesh as given (a split's new vertex takes its origin's).
    nrm: Vec<V3>,
    faces: Vec<[u32; 4]>,
    dead: Vec<bool>,
    vf: Vec<Vec<u32>>,
    journal: Vec<Change>,
}

impl QuadEdit {
    /// None unless `faces` is a closed, edge-manifold pure-quad mesh over `p`.
    fn new(p: Vec<V3>, faces: &[Vec<u32>]) -> Option<Self> {
        let mut fs = Vec::with_capacity(faces.len());
        let mut vf = vec![Vec::new(); p.len()];
        let mut half: Vec<(u32, u32)> = Vec::with_capacity(faces.len() * 4);
        for (fi, f) in faces.iter().enumerate() {
            let q: [u32; 4] = f.as_slice().try_into().ok()?;
            if (0..4).any(|k| (k + 1..4).any(|l| q[k] == q[l]) || q[k] as usize >= p.len()) {
                return None;
            }
            for k in 0..4 {
                vf[q[k] as usize].push(fi as u32);
                half.push((q[k], q[(k + 1) % 4]));
            }
            fs.push(q);
        }
        // Closed and edge-manifold: every directed edge once, and its twin present.
        half.sort_unstable();
        if half.windows(2).any(|w| w[0] == w[1]) || half.iter().any(|&(a, b)| half.binary_search(&(b, a)).is_err()) {
            return None;
        }
        let mut nrm = vec![[0.0; 3]; p.len()];
        for q in &fs {
            let n = polygon::polygon_normal(&p, q);
            for &v in q {
                nrm[v as usize] = add(nrm[v as usize], n);
            }
        }
        Some(QuadEdit { p, nrm, dead: vec![false; fs.len()], faces: fs, vf, journal: Vec::new() })
    }

    /// Valence (= incident quads on a closed manifold mesh).
    fn val(&self, v: u32) -> usize {
        self.vf[v as usize].len()
    }

    fn pos(f: &[u32; 4], v: u32) -> usize {
        f.iter().position(|&x| x == v).expect("vertex of face")
    }

    /// The corners after and before `v` in face `fi` (v → next is an edge of the face, prev → v too).
    fn around(&self, fi: u32, v: u32) -> (u32, u32) {
        let f = &self.faces[fi as usize];
        let i = Self::pos(f, v);
        (f[(i + 1) % 4], f[(i + 3) % 4])
    }

    /// x and y share an edge.
    fn adjacent(&self, x: u32, y: u32) -> bool {
        self.vf[x as usize].iter().any(|&fi| {
            let (next, prev) = self.around(fi, x);
            next == y || prev == y
        })
    }

    fn neighbours(&self, x: u32, out: &mut Vec<u32>) {
        out.clear();
        for &fi in &self.vf[x as usize] {
            let (next, prev) = self.around(fi, x);
            out.extend([next, prev]);
        }
        out.sort_unstable();
        out.dedup();
    }

    /// The face holding the directed edge u → v, if any.
    fn face_with(&self, u: u32, v: u32) -> Option<u32> {
        self.vf[u as usize].iter().copied().find(|&fi| self.around(fi, u).0 == v)
    }

    // --- journaled primitives -------------------------------------------------------------------------

    fn set_face(&mut self, fi: u32, new: [u32; 4]) {
        let old = self.faces[fi as usize];
        for v in old {
            self.vf[v as usize].retain(|&g| g != fi);
        }
        for v in new {
            self.vf[v as usize].push(fi);
        }
        self.faces[fi as usize] = new;
        self.journal.push(Change::Face(fi, old));
    }

    fn push_face(&mut self, new: [u32; 4]) {
        let fi = self.faces.len() as u32;
        self.faces.push(new);
        self.dead.push(false);
        for v in new {
            self.vf[v as usize].push(fi);
        }
        self.journal.push(Change::PushedFace);
    }

    fn kill_face(&mut self, fi: u32) {
        for v in self.faces[fi as usize] {
            self.vf[v as usize].retain(|&g| g != fi);
        }
        self.dead[fi as usize] = true;
        self.journal.push(Change::Killed(fi));
    }

    fn push_vertex(&mut self, x: V3, n: V3) -> u32 {
        self.p.push(x);
        self.nrm.push(n);
        self.vf.push(Vec::new());
        self.journal.push(Change::PushedVertex);
        self.p.len() as u32 - 1
    }

    fn move_vertex(&mut self, v: u32, x: V3) {
        self.journal.push(Change::Moved(v, self.p[v as usize]));
        self.p[v as usize] = x;
    }

    /// Undo every change after journal length `mark`.
    fn undo_to(&mut self, mark: usize) {
        while self.journal.len() > mark {
            match self.journal.pop().expect("journal entry") {
                Change::Face(fi, old) => {
                    for v in self.faces[fi as usize] {
                        self.vf[v as usize].retain(|&g| g != fi);
                    }
                    for v in old {
                        self.vf[v as usize].push(fi);
                    }
                    self.faces[fi as usize] = old;
                }
                Change::PushedFace => {
                    let fi = self.faces.len() as u32 - 1;
                    for v in self.faces.pop().expect("pushed face") {
                        self.vf[v as usize].retain(|&g| g != fi);
                    }
                    self.dead.pop();
                }
                Change::Killed(fi) => {
                    self.dead[fi as usize] = false;
                    for v in self.faces[fi as usize] {
                        self.vf[v as usize].push(fi);
                    }
                }
                Change::PushedVertex => {
                    self.p.pop();
                    self.nrm.pop();
                    self.vf.pop();
                }
                Change::Moved(v, x) => self.p[v as usize] = x,
            }
        }
    }

    // --- operations -------------------------------------------------------------------------------------

    /// Both rotations of the edge u → v of face `f1` (valid ones with a gain of at least `floor`).
    fn rotations(&self, f1: u32, u: u32, v: u32, floor: i64, out: &mut Vec<Found>) {
        let Some(f2) = self.face_with(v, u) else { return };
        if f2 == f1 || self.val(u) < 4 || self.val(v) < 4 {
            return;
        }
        let g1 = &self.faces[f1 as usize];
        let g2 = &self.faces[f2 as usize];
        let (i, j) = (Self::pos(g1, u), Self::pos(g2, v));
        let (a, b) = (g1[(i + 2) % 4], g1[(i + 3) % 4]);
        let (c, d) = (g2[(j + 2) % 4], g2[(j + 3) % 4]);
        let hex = [v, a, b, u, c, d];
        if (0..6).any(|k| (k + 1..6).any(|l| hex[k] == hex[l])) {
            return;
        }
        let base = cost(self.val(u)) + cost(self.val(v)) - cost(self.val(u) - 1) - cost(self.val(v) - 1);
        for (x, y, n1, n2) in [(a, c, [a, b, u, c], [c, d, v, a]), (b, d, [b, u, c, d], [d, v, a, b])] {
            let gain = base + cost(self.val(x)) + cost(self.val(y)) - cost(self.val(x) + 1) - cost(self.val(y) + 1);
            if gain < floor || self.adjacent(x, y) {
                continue;
            }
            out.push(Found { gain, op: Op::Rotate { f1, f2, n1, n2 }, touched: vec![u, v, x, y] });
        }
    }

    /// Both diagonal collapses of face `f` (valid ones without a loss only).
    fn collapses(&self, f: u32, scratch: &mut [Vec<u32>; 2], out: &mut Vec<Found>) {
        let q = self.faces[f as usize];
        for k in 0..2 {
            let (a, b, c, d) = (q[k], q[k + 1], q[(k + 2) % 4], q[(k + 3) % 4]);
            let (va, vb, vc, vd) = (self.val(a), self.val(b), self.val(c), self.val(d));
            let m = va + vc - 2;
            if vb < 4 || vd < 4 || m < 3 {
                continue;
            }
            let gain = cost(va) + cost(vb) + cost(vc) + cost(vd) - cost(m) - cost(vb - 1) - cost(vd - 1);
            if gain < 0 || self.adjacent(a, c) {
                continue;
            }
            let [na, nc] = scratch;
            self.neighbours(a, na);
            self.neighbours(c, nc);
            let common = na.iter().filter(|x| nc.binary_search(x).is_ok()).count();
            let shared_faces = self.vf[a as usize].iter().filter(|x| self.vf[c as usize].contains(x)).count();
            if common != 2 || shared_faces != 1 {
                continue;
            }
            out.push(Found { gain, op: Op::Collapse { f, a, c }, touched: vec![a, b, d] });
        }
    }

    /// w's quads in order round it (each next one across the edge to the previous one's first neighbour),
    /// or None when its fan is not one simple cycle.
    fn fan(&self, w: u32) -> Option<Vec<u32>> {
        let fs = &self.vf[w as usize];
        let k = fs.len();
        let first = |fi: u32| self.around(fi, w).0;
        let last = |fi: u32| self.around(fi, w).1;
        let mut order = Vec::with_capacity(k);
        let mut cur = *fs.first()?;
        for _ in 0..k {
            order.push(cur);
            let want = first(cur);
            cur = fs.iter().copied().find(|&g| last(g) == want)?;
        }
        if cur != order[0] {
            return None;
        }
        let mut firsts: Vec<u32> = order.iter().map(|&f| first(f)).collect();
        firsts.sort_unstable();
        firsts.dedup();
        (firsts.len() == k).then_some(order)
    }

    /// Every split of vertex `w` (valid ones without a loss only).
    fn splits(&self, w: u32, out: &mut Vec<Found>) {
        let k = self.val(w);
        if k < 4 {
            return;
        }
        let Some(order) = self.fan(w) else { return };
        let last = |fi: u32| self.around(fi, w).1;
        // Each quad of the fan lies between the edges to last(order[s]) and last(order[s + 1]). Side A,
        // faces i..j (exclusive), keeps w; side B, j..i round, goes to w′; the cut runs along the edges to
        // b = last(order[i]) and d = last(order[j]).
        for i in 0..k {
            for m in 2..=k - 2 {
                let j = (i + m) % k;
                if i > j && m * 2 == k {
                    continue; // the same cut as (j, i)
                }
                let (b, d) = (last(order[i]), last(order[j]));
                let (vb, vd) = (self.val(b), self.val(d));
                let gain = cost(k) + cost(vb) + cost(vd) - cost(m + 1) - cost(k - m + 1) - cost(vb + 1) - cost(vd + 1);
                if gain < 0 {
                    continue;
                }
                let side: Vec<u32> = (0..k - m).map(|s| order[(j + s) % k]).collect();
                out.push(Found { gain, op: Op::Split { w, b, d, side }, touched: vec![w, b, d] });
            }
        }
    }

    /// Every operation without a loss in the faces around `verts`.
    fn ops_near(&self, verts: &[u32], out: &mut Vec<Found>, scratch: &mut [Vec<u32>; 2]) {
        out.clear();
        let mut faces: Vec<u32> = verts.iter().flat_map(|&v| self.vf[v as usize].iter().copied()).collect();
        faces.sort_unstable();
        faces.dedup();
        for &fi in &faces {
            let f = self.faces[fi as usize];
            for k in 0..4 {
                let (u, v) = (f[k], f[(k + 1) % 4]);
                // Each undirected edge once: from the face holding u → v with u < v, or from either when
                // only one of its faces is in the set.
                if u > v && self.face_with(v, u).is_some_and(|g| faces.binary_search(&g).is_ok()) {
                    continue;
                }
                self.rotations(fi, u, v, 0, out);
            }
            self.collapses(fi, scratch, out);
        }
        for &v in verts {
            self.splits(v, out);
        }
    }

    /// Apply `op` (journaled). Returns the new vertex of a split.
    fn apply(&mut self, op: &Op) -> Option<u32> {
        match op {
            Op::Rotate { f1, f2, n1, n2 } => {
                self.set_face(*f1, *n1);
                self.set_face(*f2, *n2);
                None
            }
            Op::Collapse { f, a, c } => {
                self.kill_face(*f);
                let moved = self.vf[*c as usize].clone();
                for g in moved {
                    let mut q = self.faces[g as usize];
                    q[Self::pos(&q, *c)] = *a;
                    self.set_face(g, q);
                }
                let mid = scale(add(self.p[*a as usize], self.p[*c as usize]), 0.5);
                self.move_vertex(*a, mid);
                None
            }
            Op::Split { w, b, d, side } => {
                // w and w′ move a quarter of the way toward the centres of their own sides' neighbours.
                let pw = self.p[*w as usize];
                let centre = |fs: &mut dyn Iterator<Item = u32>| {
                    let (mut c, mut n) = ([0.0; 3], 0.0);
                    for fi in fs {
                        c = add(c, self.p[self.around(fi, *w).0 as usize]);
                        n += 1.0;
                    }
                    scale(c, 1.0 / n)
                };
                let kept: Vec<u32> = self.vf[*w as usize].iter().copied().filter(|f| !side.contains(f)).collect();
                let ca = centre(&mut kept.iter().copied());
                let cb = centre(&mut side.iter().copied());
                let w2 = self.push_vertex(add(scale(pw, 0.75), scale(cb, 0.25)), self.nrm[*w as usize]);
                self.move_vertex(*w, add(scale(pw, 0.75), scale(ca, 0.25)));
                for &g in side {
                    let mut q = self.faces[g as usize];
                    q[Self::pos(&q, *w)] = w2;
                    self.set_face(g, q);
                }
                self.push_face([*w, *b, w2, *d]);
                Some(w2)
            }
        }
    }

    /// Quad `fi` faces the way of its corners' vertex normals (cosine above [`MIN_FACE_COS`]) and no corner
    /// is folded (sine above [`MIN_CORNER_SINE`]).
    fn convex(&self, fi: u32) -> bool {
        let q = self.faces[fi as usize];
        let n = q.iter().fold([0.0; 3], |acc, &v| add(acc, self.nrm[v as usize]));
        let nn = norm(n);
        let qn = polygon::polygon_normal(&self.p, &q);
        if dot(qn, n) <= MIN_FACE_COS * norm(qn) * nn {
            return false;
        }
        (0..4).all(|i| {
            let c = self.p[q[i] as usize];
            let (e1, e2) = (sub(self.p[q[(i + 1) % 4] as usize], c), sub(self.p[q[(i + 3) % 4] as usize], c));
            // The corner's angle θ (from e1 to e2 about n) lies in (0°, 180° − asin(MIN_CORNER_SINE)): its sine
            // is above the bound and, where negative, its cosine too (θ ≤ 270°, not a corner folded back).
            let sine = dot(cross(e1, e2), n);
            sine > MIN_CORNER_SINE * norm(e1) * norm(e2) * nn && (sine >= 0.0 || dot(e1, e2) <= 0.0)
        })
    }

    /// Every face changed since journal length `mark` is [`Self::convex`].
    fn convex_since(&self, mark: usize) -> bool {
        self.journal[mark..].iter().enumerate().all(|(k, c)| match *c {
            Change::Face(fi, _) => self.dead[fi as usize] || self.convex(fi),
            Change::PushedFace => {
                // The face pushed by this entry: count the pushes before it.
                let later = self.journal[mark + k + 1..].iter().filter(|c| matches!(c, Change::PushedFace)).count();
                self.convex((self.faces.len() - 1 - later) as u32)
            }
            _ => true,
        })
    }

    /// The vertices of every face changed since journal length `mark`, and the vertices pushed since.
    fn vertices_since(&self, mark: usize) -> Vec<u32> {
        let mut out = Vec::new();
        let mut pushed_faces = 0;
        let mut pushed_vertices = 0;
        for c in self.journal[mark..].iter().rev() {
            match *c {
                Change::Face(fi, old) => {
                    out.extend(old);
                    out.extend(self.faces[fi as usize]);
                }
                Change::PushedFace => {
                    pushed_faces += 1;
                    out.extend(self.faces[self.faces.len() - pushed_faces]);
                }
                Change::Killed(fi) => out.extend(self.faces[fi as usize]),
                Change::PushedVertex => {
                    pushed_vertices += 1;
                    out.push((self.p.len() - pushed_vertices) as u32);
                }
                Change::Moved(v, _) => out.push(v),
            }
        }
        out.sort_unstable();
        out.dedup();
        out.retain(|&v| !self.vf[v as usize].is_empty());
        out
    }

    /// Settle the region a chain changed (every change since journal length `mark`): [`RELAX_ROUNDS`] rounds
    /// of tangential umbrella smoothing of its vertices (journaled moves), then true when every quad at them
    /// is [`Self::convex`]. The caller undoes the chain when it is not.
    fn settle_since(&mut self, mark: usize) -> bool {
        let region = self.vertices_since(mark);
        let mut nb = Vec::new();
        for _ in 0..RELAX_ROUNDS {
            for &v in &region {
                self.neighbours(v, &mut nb);
                let x = self.p[v as usize];
                let avg = nb.iter().fold([0.0; 3], |acc, &u| add(acc, self.p[u as usize]));
                let d = sub(scale(avg, 1.0 / nb.len().max(1) as f64), x);
                let n = self.nrm[v as usize];
                let nn = dot(n, n);
                let t = if nn > 0.0 { sub(d, scale(n, dot(d, n) / nn)) } else { d };
                self.move_vertex(v, add(x, scale(t, 0.5)));
            }
        }
        region.iter().all(|&v| self.vf[v as usize].iter().all(|&fi| self.convex(fi)))
    }

    /// A vertex of valence < 4 lies within `rings` edges of `v`. Cost: the vertices within that reach (a
    /// handful for 2 rings), checked against a short list rather than a mesh-sized mask.
    fn deficit_within(&self, v: u32, rings: usize) -> bool {
        let mut front = vec![v];
        let mut seen = vec![v];
        let mut nb = Vec::new();
        for _ in 0..rings {
            let mut next = Vec::new();
            for &x in &front {
                self.neighbours(x, &mut nb);
                for &u in &nb {
                    if !seen.contains(&u) {
                        if self.val(u) < 4 {
                            return true;
                        }
                        seen.push(u);
                        next.push(u);
                    }
                }
            }
            front = next;
        }
        false
    }

    /// Which vertices lie within `rings` face rings of `seeds` (breadth-first over shared quads).
    fn rings_around(&self, seeds: &[u32], rings: usize) -> Vec<bool> {
        let mut mark = vec![false; self.vf.len()];
        let mut front: Vec<u32> = Vec::new();
        for &v in seeds {
            if !std::mem::replace(&mut mark[v as usize], true) {
                front.push(v);
            }
        }
        for _ in 0..rings {
            let mut next = Vec::new();
            for &v in &front {
                for &fi in &self.vf[v as usize] {
                    for w in self.faces[fi as usize] {
                        if !std::mem::replace(&mut mark[w as usize], true) {
                            next.push(w);
                        }
                    }
                }
            }
            front = next;
        }
        mark
    }

    /// Σ|valence − 4| over live vertices.
    fn irregularity(&self) -> usize {
        self.vf.iter().filter(|f| !f.is_empty()).map(|f| cost(f.len()) as usize).sum()
    }
}

/// Depth-first search for a chain from `near`: a strict-gain operation there, or a cost-neutral one followed
/// (recursively) by such a chain. On success the chain stays applied and its length is returned; on
/// failure the mesh is as it was.
fn search(
    m: &mut QuadEdit,
    near: &[u32],
    depth: usize,
    last: Option<(u32, u32)>,
    settle: Option<usize>,
    scratch: &mut [Vec<u32>; 2],
    counts: &mut TransportCounts,
) -> Option<usize> {
    let mut ops = Vec::new();
    m.ops_near(near, &mut ops, scratch);
    // Strict gains, best first (ties: first found, which is deterministic); the first that keeps its quads
    // convex ends the chain.
    let mut gains: Vec<&Found> = ops.iter().filter(|o| o.gain > 0).collect();
    gains.sort_by_key(|o| std::cmp::Reverse(o.gain));
    for found in gains {
        let mark = m.journal.len();
        m.apply(&found.op);
        let ok = match settle {
            None => m.convex_since(mark),
            Some(root) => m.settle_since(root),
        };
        if ok {
            match found.op {
                Op::Rotate { .. } => counts.cancelling_rotations += 1,
                Op::Collapse { .. } => counts.cancelling_collapses += 1,
                Op::Split { .. } => counts.cancelling_splits += 1,
            }
            return Some(1);
        }
        m.undo_to(mark);
    }
    if depth == 0 {
        return None;
    }
    for found in ops.iter().filter(|o| o.gain == 0) {
        if found.op.pair().is_some() && found.op.pair() == last {
            continue;
        }
        let mark = m.journal.len();
        let mut touched = found.touched.clone();
        if let Some(w2) = m.apply(&found.op) {
            touched.push(w2);
        }
        if settle.is_none() && !m.convex_since(mark) {
            m.undo_to(mark);
            continue;
        }
        if let Some(n) = search(m, &touched, depth - 1, found.op.pair(), settle, scratch, counts) {
            return Some(n + 1);
        }
        m.undo_to(mark);
    }
    None
}

/// Move dipoles by cost-neutral operations until they cancel (see the module docs): chains of at most
/// `depth` moves, each committed only when it ends in a strict drop of Σ|valence − 4|, for at most `passes`
/// passes over the vertices, first guarded, then settling.
///
/// `faces` must be a closed, edge-manifold pure-quad mesh (anything else is left unchanged). Vertices may be
/// added (splits) and removed (collapses): `p` is compacted and `faces` renumbered. Deterministic.
pub fn transport_dipoles(p: &mut Vec<V3>, faces: &mut Vec<Vec<u32>>, depth: usize, passes: usize) -> TransportCounts {
    let mut counts = TransportCounts::default();
    let Some(mut m) = QuadEdit::new(p.clone(), faces) else { return counts };
    counts.irregularity_before = m.irregularity();
    if depth > 0 {
        for settling in [false, true] {
            run_phase(&mut m, depth, passes, settling, &mut counts);
        }
    }
    counts.irregularity_after = m.irregularity();
    let mut out: Vec<Vec<u32>> = m.faces.iter().zip(&m.dead).filter(|(_, d)| !**d).map(|(f, _)| f.to_vec()).collect();
    *p = polygon::compact(&m.p, &mut out);
    *faces = out;
    counts
}

/// One phase of [`transport_dipoles`] (guarded, or `settling`): up to `passes` passes, each committing every
/// chain it finds, counted into `counts`.
fn run_phase(m: &mut QuadEdit, depth: usize, passes: usize, settling: bool, counts: &mut TransportCounts) {
    let mut scratch = [Vec::new(), Vec::new()];
    // Starts: vertices of valence > 4 (every dipole and every cancelling pair has one; starting from the
    // valence-3 side as well finds the same chains at twice the cost: dragon 472 either way), first all of
    // them, then only those near a change of the previous pass (a search that failed fails again where
    // nothing within its reach changed). The settling phase starts over, from those with a deficit near.
    let mut starts: Vec<bool> = vec![true; m.vf.len()];
    for _ in 0..passes {
        let mut changed: Vec<u32> = Vec::new();
        for s in 0..m.vf.len() as u32 {
            let start = m.val(s) > 4
                && starts.get(s as usize).copied().unwrap_or(true)
                && (!settling || m.deficit_within(s, SETTLE_REACH));
            if !start {
                continue;
            }
            let mark = m.journal.len();
            let settle = settling.then_some(mark);
            if let Some(n) = search(m, &[s], depth, None, settle, &mut scratch, counts) {
                counts.chains += 1;
                counts.moves += n - 1;
                counts.settled_chains += usize::from(settling);
                changed.extend(m.vertices_since(mark));
                for c in &m.journal[mark..] {
                    match *c {
                        Change::PushedVertex => counts.vertices_added += 1,
                        Change::Killed(_) => counts.vertices_removed += 1,
                        _ => {}
                    }
                }
            }
            m.journal.clear();
        }
        // A committed chain always changes faces: nothing changed means nothing was found.
        if changed.is_empty() {
            break;
        }
        starts = m.rings_around(&changed, depth + 2);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use std::collections::{BTreeMap, HashSet};

    /// A regular n × m quad grid on a torus (major radius 3, minor 1): every vertex of valence 4, χ = 0.
    fn torus_grid(n: u32, m: u32) -> (Vec<V3>, Vec<Vec<u32>>) {
        let mut p = Vec::new();
        for i in 0..n {
            for j in 0..m {
                let (a, b) = (std::f64::consts::TAU * i as f64 / n as f64, std::f64::consts::TAU * j as f64 / m as f64);
                let r = 3.0 + b.cos();
                p.push([r * a.cos(), r * a.sin(), b.sin()]);
            }
        }
        let id = |i: u32, j: u32| (i % n) * m + (j % m);
        let faces =
            (0..n).flat_map(|i| (0..m).map(move |j| vec![id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1)]));
        (p, faces.collect())
    }

    /// Checks a closed, edge-manifold pure-quad mesh; returns χ and the valence histogram.
    fn closed_quads(nv: usize, faces: &[Vec<u32>]) -> (i64, BTreeMap<usize, usize>) {
        let mut half = HashSet::new();
        for q in faces {
            assert_eq!(q.len(), 4, "not a quad: {q:?}");
            assert_eq!(q.iter().collect::<HashSet<_>>().len(), 4, "repeated corner: {q:?}");
            for k in 0..4 {
                assert!(half.insert((q[k], q[(k + 1) % 4])), "edge {:?} twice", (q[k], q[(k + 1) % 4]));
            }
        }
        let mut val = vec![0usize; nv];
        for &(a, b) in &half {
            assert!(half.contains(&(b, a)), "open edge {:?}", (a, b));
            val[a as usize] += 1;
        }
        let mut hist = BTreeMap::new();
        for v in val {
            assert!(v >= 3, "valence {v}");
            *hist.entry(v).or_insert(0) += 1;
        }
        (nv as i64 - half.len() as i64 / 2 + faces.len() as i64, hist)
    }

    fn irregularity(hist: &BTreeMap<usize, usize>) -> usize {
        hist.iter().map(|(&k, &n)| (k as i64 - 4).unsigned_abs() as usize * n).sum()
    }

    /// Every rotation of every edge, whatever its gain (the search lists only those without a loss).
    fn any_rotations(m: &QuadEdit) -> Vec<Op> {
        let mut out = Vec::new();
        for (fi, f) in m.faces.iter().enumerate().filter(|(fi, _)| !m.dead[*fi]) {
            for k in 0..4 {
                let (u, v) = (f[k], f[(k + 1) % 4]);
                if u < v {
                    m.rotations(fi as u32, u, v, i64::MIN, &mut out);
                }
            }
        }
        out.into_iter().map(|found| found.op).collect()
    }

    fn faces_of(m: &QuadEdit) -> Vec<Vec<u32>> {
        m.faces.iter().zip(&m.dead).filter(|(_, d)| !**d).map(|(f, _)| f.to_vec()).collect()
    }

    /// Analytic oracle: one rotation on a regular torus grid makes two valence-3 and two valence-5 vertices
    /// (Σ|valence − 4| = 4); gliding one of the two dipoles away by free rotations leaves no operation with
    /// an immediate gain. The transport finds the way back: Σ = 0, χ = 0, the grid's vertex count.
    #[test]
    fn two_separated_dipoles_cancel() {
        let (p, faces) = torus_grid(16, 12);
        let mut m = QuadEdit::new(p, &faces).unwrap();
        let first = any_rotations(&m).into_iter().next().unwrap();
        m.apply(&first);
        let Op::Rotate { n1, n2, .. } = first else { unreachable!() };
        let mut near: Vec<u32> = n1.iter().chain(&n2).copied().filter(|&v| m.val(v) != 4).collect();
        assert_eq!(m.irregularity(), 4);
        // Glide: free rotations, each taking the moved dipole farthest from the other one.
        let mut scratch = [Vec::new(), Vec::new()];
        let mut last = first.pair();
        for _ in 0..3 {
            let mut ops = Vec::new();
            m.ops_near(&near, &mut ops, &mut scratch);
            let mut best: Option<(f64, usize)> = None;
            for (i, o) in ops.iter().enumerate() {
                if o.gain != 0 || o.op.pair().is_none() || o.op.pair() == last {
                    continue;
                }
                let mark = m.journal.len();
                m.apply(&o.op);
                let irr: Vec<u32> = (0..m.vf.len() as u32).filter(|&v| m.val(v) != 4).collect();
                let (moved, other): (Vec<u32>, Vec<u32>) = irr.iter().partition(|v| o.touched.contains(v));
                let gap = moved
                    .iter()
                    .flat_map(|&a| other.iter().map(move |&b| (a, b)))
                    .map(|(a, b)| norm(sub(m.p[a as usize], m.p[b as usize])))
                    .fold(f64::INFINITY, f64::min);
                m.undo_to(mark);
                if best.is_none_or(|b| gap > b.0) {
                    best = Some((gap, i));
                }
            }
            let glide = &ops[best.unwrap().1];
            m.apply(&glide.op);
            last = glide.op.pair();
            near = glide.touched.iter().copied().filter(|&v| m.val(v) != 4).collect();
        }
        m.journal.clear();
        assert_eq!(m.irregularity(), 4);
        let (mut p, mut faces) = (m.p.clone(), faces_of(&m));
        let (mut p0, mut faces0) = (p.clone(), faces.clone());
        // Without transport (depth 0: immediate gains only) nothing happens: the oracle is not vacuous.
        let none = transport_dipoles(&mut p0, &mut faces0, 0, TRANSPORT_PASSES);
        assert_eq!(none.chains, 0, "{none:?}");
        let counts = transport_dipoles(&mut p, &mut faces, TRANSPORT_DEPTH, TRANSPORT_PASSES);
        let (chi, hist) = closed_quads(p.len(), &faces);
        assert_eq!(chi, 0, "torus χ: {hist:?}");
        assert_eq!(irregularity(&hist), 0, "valences {hist:?}, {counts:?}");
        assert_eq!((counts.irregularity_before, counts.irregularity_after), (4, 0), "{counts:?}");
        assert!(counts.moves >= 1, "the dipoles met only by a transport: {counts:?}");
        assert_eq!(p.len(), 16 * 12, "{counts:?}");
    }

    /// Bad input is left as it was: an open quad mesh, a triangle among the quads, a repeated corner.
    #[test]
    fn anything_but_a_closed_quad_mesh_is_left_unchanged() {
        let (p, faces) = torus_grid(8, 6);
        let mut open = faces.clone();
        open.pop();
        let mut tri = faces.clone();
        tri[0].pop();
        let mut repeated = faces.clone();
        repeated[0][1] = repeated[0][0];
        for (what, f) in [("open", open), ("triangle", tri), ("repeated corner", repeated)] {
            let (mut p2, mut f2) = (p.clone(), f.clone());
            let counts = transport_dipoles(&mut p2, &mut f2, TRANSPORT_DEPTH, TRANSPORT_PASSES);
            assert_eq!((counts, &p2, &f2), (TransportCounts::default(), &p, &f), "{what}");
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]
        /// Invariants: after random rotations (any gain) on a torus grid, the transport keeps a closed
        /// edge-manifold pure-quad mesh of χ = 0 with valences ≥ 3, never raises Σ|valence − 4|, reports what
        /// it measured, and is deterministic.
        #[test]
        fn transport_keeps_a_closed_quad_torus(picks in proptest::collection::vec(0usize..10_000, 1..12)) {
            let (p, faces) = torus_grid(14, 10);
            let mut m = QuadEdit::new(p, &faces).unwrap();
            for k in picks {
                let ops = any_rotations(&m);
                let op = ops[k % ops.len()].clone();
                m.apply(&op);
            }
            m.journal.clear();
            let (mut p, mut faces) = (m.p.clone(), faces_of(&m));
            let before = irregularity(&closed_quads(p.len(), &faces).1);
            let (mut p2, mut faces2) = (p.clone(), faces.clone());
            let counts = transport_dipoles(&mut p, &mut faces, TRANSPORT_DEPTH, TRANSPORT_PASSES);
            let (chi, hist) = closed_quads(p.len(), &faces);
            prop_assert_eq!(chi, 0);
            let after = irregularity(&hist);
            prop_assert!(after <= before, "{} > {}", after, before);
            prop_assert_eq!(counts.irregularity_before, before);
            prop_assert_eq!(counts.irregularity_after, after);
            prop_assert_eq!(p.len() + counts.vertices_removed, 140 + counts.vertices_added);
            transport_dipoles(&mut p2, &mut faces2, TRANSPORT_DEPTH, TRANSPORT_PASSES);
            prop_assert_eq!(faces2, faces);
            prop_assert_eq!(p2, p);
        }
    }
}

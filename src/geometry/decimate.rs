//! Step 7 (optional): quadric-error decimation (Garland & Heckbert 1997) to a target vertex count.
//!
//! Each vertex carries the area-weighted quadric of its faces' planes. Edges are chosen by Wu & Kobbelt's
//! multiple-choice scheme ("Fast mesh decimation by multiple-choice techniques", 2002): each step draws 8
//! live edges at random (seeded, so the result is deterministic) and collapses the cheapest, to the point
//! minimising the summed quadric (or the best of the endpoints and the midpoint when that system is
//! singular). No priority queue: about as good as greedy order, several times faster. A collapse is refused
//! when it would
//! * break the **link condition** (the endpoints share more than the two opposite vertices), which would make
//!   an edge non-manifold, or shrink a tetrahedron;
//! * **fold** a face over (its normal turns by more than [`MAX_NORMAL_TURN_DEG`]) or make it degenerate;
//! * make the surface **cross itself**: every face the collapse changes is tested against the others it
//!   changes and against every live face whose bounding box it meets, found in a uniform grid of face
//!   boxes ([`FaceGrid`], cells twice the target edge length) that follows the collapses.
//!
//! Decimating a mesh without self-intersections therefore yields one without self-intersections; the repair
//! stage still searches the result from scratch (a BVH) and would remove any crossing it found.

use crate::geometry::intersect::mesh_triangles_intersect;
use crate::geometry::sampling::Rng;
use crate::geometry::vec3::{self, Aabb, V3};

/// Largest turn of a face normal a collapse may cause, in degrees.
pub const MAX_NORMAL_TURN_DEG: f64 = 60.0;
/// Live edges drawn per step; the cheapest is collapsed (Wu & Kobbelt's multiple-choice scheme).
const CHOICES: usize = 8;
/// Refused collapses in a row after which decimation stops short of the target.
const MAX_STALLED: usize = 100_000;
/// Grid cell edge as a multiple of the target mesh's mean edge length.
const CELL_EDGES: f64 = 2.0;
/// Most grid cells (the cell edge grows when the bounding box would need more).
const MAX_CELLS: usize = 1 << 22;

/// What decimation did.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct DecimateReport {
    /// Requested vertex count.
    pub target_vertices: usize,
    /// Vertices before and after.
    pub vertices_before: usize,
    /// Vertices after.
    pub vertices_after: usize,
    /// Edge collapses done.
    pub collapses: usize,
    /// Collapses refused by the link condition, and by the fold-over/degeneracy test.
    pub refused_link: usize,
    /// Collapses refused by the fold-over/degeneracy test.
    pub refused_fold: usize,
    /// Collapses refused because a changed face would cross another face.
    pub refused_intersection: usize,
    /// Largest quadric error of a collapse done: the area-weighted sum of squared distances to the merged
    /// vertices' face planes (input units⁴).
    pub max_error: f64,
}

type Quadric = [f64; 10]; // a², ab, ac, ad, b², bc, bd, c², cd, d²

fn plane_quadric(n: V3, d: f64, w: f64) -> Quadric {
    let [a, b, c] = n;
    [a * a, a * b, a * c, a * d, b * b, b * c, b * d, c * c, c * d, d * d].map(|x| x * w)
}

fn q_add(a: &mut Quadric, b: &Quadric) {
    a.iter_mut().zip(b).for_each(|(x, y)| *x += y);
}

fn q_eval(q: &Quadric, p: V3) -> f64 {
    let [x, y, z] = p;
    q[0] * x * x
        + 2.0 * q[1] * x * y
        + 2.0 * q[2] * x * z
        + 2.0 * q[3] * x
        + q[4] * y * y
        + 2.0 * q[5] * y * z
        + 2.0 * q[6] * y
        + q[7] * z * z
        + 2.0 * q[8] * z
        + q[9]
}

/// The minimiser of `q`, if the 3×3 system is well conditioned.
fn q_optimum(q: &Quadric) -> Option<V3> {
    let a = [[q[0], q[1], q[2]], [q[1], q[4], q[5]], [q[2], q[5], q[7]]];
    let scale = (q[0] + q[4] + q[7]).powi(3);
    crate::geometry::linalg::solve3(a, [-q[3], -q[6], -q[8]], |det| !(det.abs() > 1e-10 * scale))
}

/// Bounding box of triangle `t`.
fn tri_box(p: &[V3], t: [u32; 3]) -> Aabb {
    let mut b = Aabb::EMPTY;
    t.iter().for_each(|&i| b.add(p[i as usize]));
    b
}

/// Does `t` repeat a corner? (The two faces on a collapsed edge do: they die.)
fn degenerate(t: &[u32; 3]) -> bool {
    t[0] == t[1] || t[1] == t[2] || t[0] == t[2]
}

fn boxes_meet(a: &Aabb, b: &Aabb) -> bool {
    (0..3).all(|k| a.min[k] <= b.max[k] && b.min[k] <= a.max[k])
}

/// A box in grid quanta (a quantum is a grid cell / 2^shift): the corners rounded outward to whole quanta
/// with one quantum to spare, clamped to 0..=65535. It holds the exact box, so a test of two such boxes is
/// a conservative prefilter; 12 bytes.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
struct QBox {
    lo: [u16; 3],
    hi: [u16; 3],
}

impl QBox {
    fn meets(&self, o: &QBox) -> bool {
        (0..3).all(|k| self.lo[k] <= o.hi[k] && o.lo[k] <= self.hi[k])
    }
}

/// A face a collapse changes: its corners before and after, its grid box before (where it is filed) and
/// after, its exact box and its normal (unnormalised) after.
struct Changed {
    old_tri: [u32; 3],
    tri: [u32; 3],
    old_q: QBox,
    new_box: Aabb,
    new_q: QBox,
    normal: V3,
}

/// Does triangle `b` keep strictly to one side of the plane of `a` (normal `na`), apart from the corners it
/// shares with `a`? Then the two meet at most in those corners. "Strictly" means beyond a relative
/// tolerance, so that rounding never hides a crossing.
fn off_plane(p: &[V3], a: [u32; 3], na: V3, b: [u32; 3]) -> bool {
    let o = p[a[0] as usize];
    let scale = vec3::dot(na, na).sqrt();
    let (mut pos, mut neg) = (false, false);
    for &i in b.iter().filter(|i| !a.contains(i)) {
        let q = p[i as usize];
        let d = vec3::dot(na, vec3::sub(q, o));
        let size = vec3::dot(vec3::sub(q, o), vec3::sub(q, o)).sqrt();
        if d.abs() <= 1e-9 * scale * size {
            return false;
        }
        (pos, neg) = (pos || d > 0.0, neg || d < 0.0);
    }
    pos != neg
}

/// Is the star of vertex `w` (the triangles `faces`, each with `w` as a corner) embedded in its projection
/// along the star's summed normal? That holds when every triangle projects with positive orientation and
/// the star winds around `w` exactly once (the direction +x of the projection plane lies in exactly one
/// triangle's corner sector). Then no two of its triangles meet other than along what they share.
/// `corners` is scratch space. Cost: O(faces), two square roots, no trigonometry.
fn star_embedded(p: &[V3], w: u32, faces: &[[u32; 3]], corners: &mut Vec<(V3, V3)>) -> bool {
    let pw = p[w as usize];
    corners.clear();
    let mut n = [0.0; 3];
    for t in faces {
        let k = t.iter().position(|&x| x == w).unwrap_or(0);
        let (a, b) = (vec3::sub(p[t[(k + 1) % 3] as usize], pw), vec3::sub(p[t[(k + 2) % 3] as usize], pw));
        n = vec3::add(n, vec3::cross(a, b));
        corners.push((a, b));
    }
    // An orthonormal basis (e1, e2) of the plane normal to n. (Unit length matters: the orientation
    // tolerance below is a sine, the same for a mesh in metres and one in millimetres.)
    let k = (0..3).min_by(|&i, &j| n[i].abs().total_cmp(&n[j].abs())).unwrap_or(0);
    let mut axis = [0.0; 3];
    axis[k] = 1.0;
    let e1 = vec3::cross(n, axis);
    let e2 = vec3::cross(n, e1);
    let (l1, l2) = (vec3::norm(e1), vec3::norm(e2));
    if !(l1 > 0.0 && l2 > 0.0) {
        return false;
    }
    let (e1, e2) = (vec3::scale(e1, 1.0 / l1), vec3::scale(e2, 1.0 / l2));
    let mut winding = 0;
    for &(a, b) in corners.iter() {
        let (da, db) = ([vec3::dot(a, e1), vec3::dot(a, e2)], [vec3::dot(b, e1), vec3::dot(b, e2)]);
        let cross = da[0] * db[1] - da[1] * db[0];
        let (la, lb) = (da[0] * da[0] + da[1] * da[1], db[0] * db[0] + db[1] * db[1]);
        // Positive beyond a relative tolerance: sin of the projected corner angle > 1e-6.
        if !(cross > 0.0 && cross * cross > 1e-12 * la * lb) {
            return false;
        }
        winding += (da[1] <= 0.0 && db[1] > 0.0) as usize;
    }
    winding == 1
}

/// Could faces `a` and `b` (normals `na`, `nb`) of the mesh cross? A cheap plane-side test first, then the
/// exact one ([`mesh_triangles_intersect`]).
fn may_cross(p: &[V3], a: [u32; 3], na: V3, b: [u32; 3], nb: V3) -> bool {
    let shared = a.iter().filter(|i| b.contains(i)).count();
    if shared >= 2 || off_plane(p, a, na, b) || off_plane(p, b, nb, a) {
        return false;
    }
    mesh_triangles_intersect(p, a, b)
}

/// A face in a grid cell: its corners and its [`QBox`]. 24 bytes, so a query reads contiguous memory and
/// never the mesh arrays.
#[derive(Copy, Clone, Debug)]
struct CellEntry {
    tri: [u32; 3],
    bounds: QBox,
}

/// Live faces bucketed by a uniform grid: each face sits in every cell its [`QBox`] meets (boxes outside
/// the grid are clamped onto its border cells, the same way for insertion, removal and queries, and
/// everything is derived from the quantized box, so the three always agree).
/// Memory: 24 bytes per face and cell it meets (at most 2¹⁶ cells along an axis).
struct FaceGrid {
    origin: V3,
    inv_quantum: f64,
    shift: u32,
    dims: [usize; 3],
    cells: Vec<Vec<CellEntry>>,
}

impl FaceGrid {
    /// A grid over `p`'s bounding box with cells of edge `cell` (grown until at most [`MAX_CELLS`]
    /// cells), holding every face of `tris`.
    fn new(p: &[V3], tris: &[[u32; 3]], cell: f64) -> Self {
        let mut bounds = Aabb::EMPTY;
        p.iter().for_each(|&q| bounds.add(q));
        let extent = bounds.extent();
        let largest = extent.iter().copied().fold(0.0, f64::max);
        let mut cell = if cell.is_finite() && cell > 0.0 { cell } else { largest.max(1.0) };
        let dims = loop {
            let d: [usize; 3] = std::array::from_fn(|k| ((extent[k] / cell).floor() as usize + 1).max(1));
            if d.iter().product::<usize>() <= MAX_CELLS && d.iter().all(|&n| n <= u16::MAX as usize) {
                break d;
            }
            cell *= 1.5;
        };
        // Quanta of cell / 2^shift, as fine as 16 bits allow over the box (with room for the margins).
        let fits = if largest > 0.0 { 65_000.0 * cell / largest } else { f64::INFINITY };
        let shift = (0..=15).rev().find(|&s| f64::from(1u32 << s) <= fits).unwrap_or(0);
        let inv_quantum = f64::from(1u32 << shift) / cell;
        let cells = vec![Vec::new(); dims.iter().product()];
        let mut g = FaceGrid { origin: bounds.min, inv_quantum, shift, dims, cells };
        for &t in tris {
            g.insert(t, g.quantize(&tri_box(p, t)));
        }
        g
    }

    fn quantize(&self, b: &Aabb) -> QBox {
        let q = |x: f64, k: usize| (x - self.origin[k]) * self.inv_quantum;
        // floor(t) − 1 and floor(t) + 1, clamped to 0..=65535: `as u16` truncates toward zero and saturates,
        // which gives the same numbers without a call to floor.
        QBox {
            lo: std::array::from_fn(|k| (q(b.min[k], k) - 1.0) as u16),
            hi: std::array::from_fn(|k| (q(b.max[k], k) + 1.0) as u16),
        }
    }

    fn cell(&self, q: u16, k: usize) -> usize {
        ((q >> self.shift) as usize).min(self.dims[k] - 1)
    }

    fn span(&self, b: &QBox) -> [std::ops::RangeInclusive<usize>; 3] {
        std::array::from_fn(|k| self.cell(b.lo[k], k)..=self.cell(b.hi[k], k))
    }

    fn for_cells(&mut self, b: &QBox, mut f: impl FnMut(&mut Vec<CellEntry>)) {
        let [sx, sy, sz] = self.span(b);
        for z in sz {
            for y in sy.clone() {
                for x in sx.clone() {
                    f(&mut self.cells[(z * self.dims[1] + y) * self.dims[0] + x]);
                }
            }
        }
    }

    fn insert(&mut self, tri: [u32; 3], bounds: QBox) {
        self.for_cells(&bounds, |c| c.push(CellEntry { tri, bounds }));
    }

    /// Remove the face `tri`, which was inserted with the box `b`.
    fn remove(&mut self, tri: [u32; 3], b: QBox) {
        self.for_cells(&b, |c| {
            if let Some(i) = c.iter().position(|e| e.tri == tri) {
                c.swap_remove(i);
            }
        });
    }

    /// The faces whose boxes meet `query`, each once, into `out`.
    fn near(&self, query: &QBox, out: &mut Vec<CellEntry>) {
        out.clear();
        let [sx, sy, sz] = self.span(query);
        let start = [*sx.start(), *sy.start(), *sz.start()];
        for z in sz {
            for y in sy.clone() {
                for x in sx.clone() {
                    let at = [x, y, z];
                    for e in &self.cells[(z * self.dims[1] + y) * self.dims[0] + x] {
                        // Reported from the first cell that both its box and the query meet.
                        if e.bounds.meets(query) && (0..3).all(|k| at[k] == start[k].max(self.cell(e.bounds.lo[k], k)))
                        {
                            out.push(*e);
                        }
                    }
                }
            }
        }
    }
}

/// The crossing test of [`decimate`]: a [`FaceGrid`] of the live faces, their boxes, and scratch space.
struct CrossingGuard {
    grid: FaceGrid,
    changed: Vec<Changed>,
    near: Vec<CellEntry>,
    star: Vec<[u32; 3]>,
    corners: Vec<(V3, V3)>,
    ring: Vec<u32>,
    ring_ok: Vec<bool>,
}

impl CrossingGuard {
    fn new(p: &[V3], tris: &[[u32; 3]], cell: f64) -> Self {
        let grid = FaceGrid::new(p, tris, cell);
        CrossingGuard {
            grid,
            changed: Vec::new(),
            near: Vec::new(),
            star: Vec::new(),
            corners: Vec::new(),
            ring: Vec::new(),
            ring_ok: Vec::new(),
        }
    }

    /// Would collapsing `u` into `v` (already moved to its new place in `s.p`) make a face cross another?
    /// The faces around u and v, as they will be, are tested against each other and against every other
    /// live face nearby. Local pairs (sharing one corner) cannot cross when the stars of v and of its
    /// neighbours stay embedded in projection; only where one does not are they tested one by one.
    /// Cost: one grid query over the collapse's reach, then O(k · c) box tests for its k nearby and c
    /// changed faces (about 35 and 8 on the dragon) and exact tests only for pairs whose boxes meet.
    fn crosses(&mut self, s: &State, u: u32, v: u32, old_v: V3) -> bool {
        let merged = |t: [u32; 3]| t.map(|x| if x == u { v } else { x });
        self.changed.clear();
        for &w in &[u, v] {
            for &f in s.vertex_faces.get(w) {
                let old_tri = s.tris[f as usize];
                // A face with both ends was listed from u's side already.
                if !(w == v && old_tri.contains(&u)) {
                    // The box the face was filed under: its corners before the collapse.
                    let mut old_box = Aabb::EMPTY;
                    old_tri.iter().for_each(|&i| old_box.add(if i == v { old_v } else { s.p[i as usize] }));
                    let tri = merged(old_tri);
                    let new_box = tri_box(s.p, tri);
                    let (new_q, normal) = (self.grid.quantize(&new_box), vec3::tri_cross(s.p, tri));
                    let old_q = self.grid.quantize(&old_box);
                    self.changed.push(Changed { old_tri, tri, old_q, new_box, new_q, normal });
                }
            }
        }
        let mut reach = Aabb::EMPTY;
        for ch in &self.changed {
            reach.add(ch.new_box.min);
            reach.add(ch.new_box.max);
        }
        if reach.is_empty() {
            return false;
        }
        // Every live face whose box meets the reach: all faces around v's neighbours among them.
        self.grid.near(&self.grid.quantize(&reach), &mut self.near);
        let changed = &self.changed;
        let live = || changed.iter().filter(|c| !degenerate(&c.tri));
        // Which stars stay embedded: v's, and those of its neighbours (`ring`, sorted; `ring_ok` alongside).
        // A neighbour's star is its changed faces and its faces in `near` (those with u or v are the
        // changed ones, filed under their old corners).
        self.star.clear();
        self.star.extend(live().map(|c| c.tri));
        let v_ok = star_embedded(s.p, v, &self.star, &mut self.corners);
        self.ring.clear();
        self.ring.extend(self.star.iter().flatten().copied().filter(|&x| x != v));
        self.ring.sort_unstable();
        self.ring.dedup();
        self.ring_ok.clear();
        for &w in &self.ring {
            self.star.clear();
            self.star.extend(live().filter(|c| c.tri.contains(&w)).map(|c| c.tri));
            let theirs =
                self.near.iter().map(|e| e.tri).filter(|t| t.contains(&w) && !t.contains(&u) && !t.contains(&v));
            self.star.extend(theirs);
            self.ring_ok.push(star_embedded(s.p, w, &self.star, &mut self.corners));
        }
        // Two changed faces share v; when v's star is embedded, they cannot cross.
        if !v_ok {
            for (i, a) in live().enumerate() {
                for b in live().skip(i + 1) {
                    if boxes_meet(&a.new_box, &b.new_box) && may_cross(s.p, a.tri, a.normal, b.tri, b.normal) {
                        return true;
                    }
                }
            }
        }
        for e in &self.near {
            // Every face around u or v is one of the changed faces, tested above.
            let t = e.tri;
            if t.contains(&u) || t.contains(&v) {
                continue;
            }
            let mut nt = None;
            for a in live().filter(|a| a.new_q.meets(&e.bounds)) {
                let mut shared = a.tri.iter().filter(|i| t.contains(i));
                let (first, second) = (shared.next(), shared.next());
                // Sharing an edge: neighbours across it cannot cross. Sharing one corner w (a neighbour of
                // v, as faces with v or u are the changed ones): both lie in w's star.
                let in_embedded_star = first.is_some_and(|w| self.ring.binary_search(w).is_ok_and(|i| self.ring_ok[i]));
                if second.is_some() || in_embedded_star {
                    continue;
                }
                let nt = *nt.get_or_insert_with(|| vec3::tri_cross(s.p, t));
                if may_cross(s.p, a.tri, a.normal, t, nt) {
                    return true;
                }
            }
        }
        false
    }

    /// Move the faces the last tested collapse changed to their new places in the grid.
    fn commit(&mut self) {
        for ch in &self.changed {
            self.grid.remove(ch.old_tri, ch.old_q);
            if !degenerate(&ch.tri) {
                self.grid.insert(ch.tri, ch.new_q);
            }
        }
    }
}

/// Ids kept in place per vertex by [`FaceLists`] (with the length, one 64-byte cache line).
const INLINE_FACES: usize = 15;

/// One vertex's faces: up to [`INLINE_FACES`] ids in place; a longer list lives in [`FaceLists::spill`]
/// and `ids[0]` says where.
#[derive(Clone, Copy)]
#[repr(C, align(64))]
struct FaceSlot {
    len: u32,
    ids: [u32; INLINE_FACES],
}

/// The live faces around every vertex, in the order they were added. Reading a vertex's faces touches
/// one cache line (a `Vec` per vertex costs two scattered reads, and the lists are read around every
/// vertex of every candidate collapse).
struct FaceLists {
    slots: Vec<FaceSlot>,
    spill: Vec<Vec<u32>>,
}

impl FaceLists {
    fn new(n: usize) -> Self {
        FaceLists { slots: vec![FaceSlot { len: 0, ids: [0; INLINE_FACES] }; n], spill: Vec::new() }
    }

    fn get(&self, v: u32) -> &[u32] {
        let s = &self.slots[v as usize];
        match s.len as usize {
            n if n <= INLINE_FACES => &s.ids[..n],
            _ => &self.spill[s.ids[0] as usize],
        }
    }

    /// Change `v`'s list through `f` (moving it in place or out to the spill store as its length asks).
    fn edit(&mut self, v: u32, f: impl FnOnce(&mut Vec<u32>)) {
        let s = &mut self.slots[v as usize];
        let mut list = match s.len as usize {
            n if n <= INLINE_FACES => s.ids[..n].to_vec(),
            _ => std::mem::take(&mut self.spill[s.ids[0] as usize]),
        };
        let spilled = (s.len as usize > INLINE_FACES).then_some(s.ids[0]);
        f(&mut list);
        s.len = list.len() as u32;
        if list.len() <= INLINE_FACES {
            s.ids[..list.len()].copy_from_slice(&list);
        } else {
            let at = spilled.unwrap_or_else(|| {
                self.spill.push(Vec::new());
                (self.spill.len() - 1) as u32
            });
            s.ids[0] = at;
            self.spill[at as usize] = list;
        }
    }

    fn push(&mut self, v: u32, face: u32) {
        let s = &mut self.slots[v as usize];
        if (s.len as usize) < INLINE_FACES {
            s.ids[s.len as usize] = face;
            s.len += 1;
        } else {
            self.edit(v, |l| l.push(face));
        }
    }

    /// Keep the faces of `v`'s list for which `keep` holds, in their order (in place when the list is).
    fn retain(&mut self, v: u32, keep: impl Fn(u32) -> bool) {
        let s = &mut self.slots[v as usize];
        let n = s.len as usize;
        if n <= INLINE_FACES {
            let mut kept = 0;
            for i in 0..n {
                if keep(s.ids[i]) {
                    s.ids[kept] = s.ids[i];
                    kept += 1;
                }
            }
            s.len = kept as u32;
        } else {
            self.edit(v, |l| l.retain(|&f| keep(f)));
        }
    }
}

#[derive(Copy, Clone, Debug)]
struct Candidate {
    cost: f64,
    u: u32,
    v: u32,
    at: V3,
}

struct State<'a> {
    p: &'a mut Vec<V3>,
    tris: &'a mut Vec<[u32; 3]>,
    face_alive: Vec<bool>,
    vertex_faces: FaceLists,
    q: Vec<Quadric>,
    alive: Vec<bool>,
}

impl State<'_> {
    /// Collapsing the edge u–v, whose summed quadric is `q`: where to, and at what cost.
    fn candidate(&self, q: &Quadric, u: u32, v: u32) -> Candidate {
        let (pu, pv) = (self.p[u as usize], self.p[v as usize]);
        let mid = vec3::scale(vec3::add(pu, pv), 0.5);
        let mut best = (q_eval(q, mid), mid);
        for c in [pu, pv].into_iter().chain(q_optimum(q)) {
            let e = q_eval(q, c);
            if e < best.0 {
                best = (e, c);
            }
        }
        Candidate { cost: best.0.max(0.0), u, v, at: best.1 }
    }

    fn ring(&self, v: u32, out: &mut Vec<u32>) {
        out.clear();
        for &f in self.vertex_faces.get(v) {
            out.extend(self.tris[f as usize].iter().copied().filter(|&w| w != v));
        }
        out.sort_unstable();
        out.dedup();
    }

    /// Whether collapsing `u` into `v` at `at` folds or degenerates a face that survives it (its normal
    /// turns by more than the angle whose cosine is `min_cos`, or its area vanishes).
    fn folds(&self, u: u32, v: u32, at: V3, min_cos: f64) -> bool {
        for &w in &[u, v] {
            for &f in self.vertex_faces.get(w) {
                let t = self.tris[f as usize];
                if t.contains(&u) && t.contains(&v) {
                    continue;
                }
                let old = self.normal(t, u32::MAX, [0.0; 3], u32::MAX);
                let new = self.normal(t, u, at, v);
                let (lo, ln) = (vec3::norm(old), vec3::norm(new));
                if !(ln > 1e-12 * lo) || vec3::dot(old, new) < min_cos * lo * ln {
                    return true;
                }
            }
        }
        false
    }

    fn normal(&self, t: [u32; 3], moved: u32, to: V3, also: u32) -> V3 {
        let [a, b, c] = t.map(|i| if i == moved || i == also { to } else { self.p[i as usize] });
        vec3::cross(vec3::sub(b, a), vec3::sub(c, a))
    }
}

/// Which collapses [`decimate`] tests for self-intersection.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum Crossings {
    /// Every collapse (a grid of face boxes; about 3× the time on the dragon). For results that must
    /// not cross themselves when the input does not.
    Refuse,
    /// None: for a working copy whose crossings do not matter (the remesher's fields).
    Ignore,
}

/// Each vertex's quadric (the area-weighted plane quadrics of its faces) and its face list.
fn vertex_quadrics(p: &[V3], tris: &[[u32; 3]]) -> (Vec<Quadric>, FaceLists) {
    let n = p.len();
    let mut q = vec![[0.0; 10]; n];
    let mut vertex_faces = FaceLists::new(n);
    for (f, t) in tris.iter().enumerate() {
        if let Some(unit) = vec3::tri_unit_normal(p, *t) {
            let a = p[t[0] as usize];
            let pq = plane_quadric(unit, -vec3::dot(unit, a), vec3::tri_area(p, *t));
            for &v in t {
                q_add(&mut q[v as usize], &pq);
            }
        }
        for &v in t {
            vertex_faces.push(v, f as u32);
        }
    }
    (q, vertex_faces)
}

/// Decimate the closed oriented manifold (`p`, `tris`) to about `target` vertices, in place; `seed` fixes
/// the random edge choices; `crossings` says whether collapses that would make the surface cross itself
/// are refused. Cost: O(F) setup plus O(1) expected work per collapse.
pub fn decimate(
    p: &mut Vec<V3>,
    tris: &mut Vec<[u32; 3]>,
    target: usize,
    seed: u64,
    crossings: Crossings,
) -> DecimateReport {
    let n = p.len();
    let mut report = DecimateReport { target_vertices: target, vertices_before: n, ..Default::default() };
    let (q, vertex_faces) = vertex_quadrics(p, tris);
    let face_count = tris.len();
    if face_count == 0 {
        return report;
    }
    // Grid cells of CELL_EDGES target edge lengths: the target's mean face area, as an equilateral
    // triangle's edge.
    let area: f64 = tris.iter().map(|&t| vec3::tri_area(p, t)).sum();
    let target_face_area = area / (2.0 * target.max(4) as f64);
    let cell = CELL_EDGES * (4.0 * target_face_area / 3f64.sqrt()).sqrt();
    let mut guard = (crossings == Crossings::Refuse).then(|| CrossingGuard::new(p, tris, cell));
    let mut s = State { p, tris, face_alive: vec![true; face_count], vertex_faces, q, alive: vec![true; n] };
    let t0 = std::time::Instant::now();
    let mut rng = Rng::new(seed);
    let mut alive_count = n;
    let mut stalled = 0usize;
    let (mut ring_u, mut ring_v, mut faces_u) = (Vec::new(), Vec::new(), Vec::new());
    let min_cos = MAX_NORMAL_TURN_DEG.to_radians().cos();
    while alive_count > target && stalled < MAX_STALLED {
        // Multiple choice: the cheapest of CHOICES random live edges (dead faces are skipped, bounded tries).
        // The draws depend only on which faces are alive; the drawn faces' corners and quadrics are read
        // afterwards, all together, so that their cache misses overlap.
        let mut drawn = [(0usize, 0usize); CHOICES];
        let mut n_drawn = 0;
        for _ in 0..CHOICES * 8 {
            let f = (rng.next_u64() % face_count as u64) as usize;
            if !s.face_alive[f] {
                continue;
            }
            drawn[n_drawn] = (f, (rng.next_u64() % 3) as usize);
            n_drawn += 1;
            if n_drawn == CHOICES {
                break;
            }
        }
        let drawn = &drawn[..n_drawn];
        let edges: [(u32, u32); CHOICES] =
            std::array::from_fn(|i| drawn.get(i).map_or((0, 0), |&(f, k)| (s.tris[f][k], s.tris[f][(k + 1) % 3])));
        let sums: [Quadric; CHOICES] = std::array::from_fn(|i| {
            let (u, v) = edges[i];
            let mut q = s.q[u as usize];
            q_add(&mut q, &s.q[v as usize]);
            q
        });
        let mut best: Option<Candidate> = None;
        for (i, &(u, v)) in edges[..n_drawn].iter().enumerate() {
            let c = s.candidate(&sums[i], u, v);
            if best.is_none_or(|b| c.cost < b.cost) {
                best = Some(c);
            }
        }
        let Some(c) = best else {
            stalled += 1;
            continue;
        };
        let (u, v) = (c.u, c.v);
        s.ring(u, &mut ring_u);
        s.ring(v, &mut ring_v);
        if ring_u.binary_search(&v).is_err() {
            continue; // stale: no longer an edge
        }
        // Link condition: exactly the two opposite vertices are common neighbours; afterwards the merged
        // vertex keeps at least 3 neighbours and each opposite vertex too (no tetrahedron collapses flat).
        let mut shared = [0u32; 2];
        let mut n_shared = 0;
        for &w in &ring_u {
            if ring_v.binary_search(&w).is_ok() {
                if n_shared < 2 {
                    shared[n_shared] = w;
                }
                n_shared += 1;
            }
        }
        let merged_valence = ring_u.len() + ring_v.len() - n_shared - 2;
        let opposite_ok = n_shared == 2 && shared.iter().all(|&w| s.vertex_faces.get(w).len() >= 4);
        if !opposite_ok || merged_valence < 3 {
            report.refused_link += 1;
            stalled += 1;
            continue;
        }
        // Fold-over and degeneracy test on the faces that survive the collapse.
        if s.folds(u, v, c.at, min_cos) {
            report.refused_fold += 1;
            stalled += 1;
            continue;
        }
        // Crossing test, with v moved to where the collapse puts it.
        let old_v = s.p[v as usize];
        s.p[v as usize] = c.at;
        if guard.as_mut().is_some_and(|g| g.crosses(&s, u, v, old_v)) {
            s.p[v as usize] = old_v;
            report.refused_intersection += 1;
            stalled += 1;
            continue;
        }
        stalled = 0;
        if let Some(g) = guard.as_mut() {
            g.commit();
        }
        // Collapse u into v at c.at (already moved there).
        report.collapses += 1;
        report.max_error = report.max_error.max(c.cost);
        let qu = s.q[u as usize];
        q_add(&mut s.q[v as usize], &qu);
        s.alive[u as usize] = false;
        alive_count -= 1;
        faces_u.clear();
        faces_u.extend_from_slice(s.vertex_faces.get(u));
        s.vertex_faces.retain(u, |_| false);
        for &f in &faces_u {
            let t = &mut s.tris[f as usize];
            if t.contains(&v) {
                // The face dies: off the list of its third corner too (v's list is filtered below), so
                // that every vertex lists only live faces.
                s.face_alive[f as usize] = false;
                if let Some(&w) = t.iter().find(|&&x| x != u && x != v) {
                    s.vertex_faces.retain(w, |g| g != f);
                }
            } else {
                t.iter_mut().for_each(|x| {
                    if *x == u {
                        *x = v;
                    }
                });
                s.vertex_faces.push(v, f);
            }
        }
        let face_alive = &s.face_alive;
        s.vertex_faces.retain(v, |f| face_alive[f as usize]);
    }
    tracing::debug!(seconds = t0.elapsed().as_secs_f64(), collapses = report.collapses, "decimation loop done");
    let kept: Vec<[u32; 3]> = s.tris.iter().zip(&s.face_alive).filter(|(_, a)| **a).map(|(t, _)| *t).collect();
    let (pos, tris_out, _) = crate::geometry::polygon::drop_unreferenced(s.p, &kept);
    *s.p = pos;
    *s.tris = tris_out;
    report.vertices_after = s.p.len();
    report
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A fan of `n` triangles around the origin at scale `s`, the rim lifted by `lift` (a cone).
    fn fan(n: u32, s: f64, lift: f64) -> (Vec<V3>, Vec<[u32; 3]>) {
        let mut p = vec![[0.0; 3]];
        for i in 0..n {
            let a = std::f64::consts::TAU * f64::from(i) / f64::from(n);
            p.push([s * a.cos(), s * a.sin(), s * lift]);
        }
        let tris = (0..n).map(|i| [0, 1 + i, 1 + (i + 1) % n]).collect();
        (p, tris)
    }

    /// Regression: the projection basis was not normalised, so the sine tolerance shrank with the square of
    /// the mesh's scale and a plain fan of a mesh in metres (edges of 0.5 mm) counted as not embedded.
    #[test]
    fn star_test_does_not_depend_on_the_scale() {
        let mut scratch = Vec::new();
        for s in [1e3, 1.0, 5e-4, 1e-6] {
            for lift in [0.0, 0.3, -0.8] {
                let (p, tris) = fan(7, s, lift);
                assert!(star_embedded(&p, 0, &tris, &mut scratch), "fan at scale {s}, lift {lift}");
            }
            // A fan that winds twice around its centre is not embedded, at any scale.
            let (p, _) = fan(7, s, 0.0);
            let twice: Vec<[u32; 3]> = (0..7).map(|i| [0, 1 + (2 * i) % 7, 1 + (2 * i + 2) % 7]).collect();
            assert!(!star_embedded(&p, 0, &twice, &mut scratch), "double fan at scale {s}");
            // One triangle turned over: not embedded.
            let (p, mut tris) = fan(7, s, 0.0);
            tris[3].swap(1, 2);
            assert!(!star_embedded(&p, 0, &tris, &mut scratch), "turned-over triangle at scale {s}");
        }
    }

    /// Face lists keep their order through growth past the in-place capacity, removal and shrinking back.
    #[test]
    fn face_lists_spill_and_come_back() {
        let mut l = FaceLists::new(3);
        for f in 0..40 {
            l.push(1, f);
        }
        l.push(2, 7);
        assert_eq!(l.get(1), (0..40).collect::<Vec<_>>().as_slice());
        l.retain(1, |f| f % 3 == 0);
        assert_eq!(l.get(1), (0..40).step_by(3).collect::<Vec<_>>().as_slice());
        l.retain(1, |f| f != 3 && f < 20);
        assert_eq!(l.get(1), &[0, 6, 9, 12, 15, 18]);
        l.retain(1, |f| f != 12);
        assert_eq!(l.get(1), &[0, 6, 9, 15, 18]);
        assert_eq!((l.get(0), l.get(2)), (&[][..], &[7][..]));
    }
}

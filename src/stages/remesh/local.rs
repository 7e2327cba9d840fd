//! Local refinement of a finished quad net where it passes far from the input: the net stays as it is
//! everywhere else, and only the faces nearest to the input's far parts (a slot narrower than the spacing
//! that the net bridges, a crease it cuts) are split into 3 × 3, with conforming transition faces around
//! them, the new vertices cast onto the input along the net's normal. A bounded number of rounds; a site
//! whose refined faces cross the net or fold is given up, never the net.
//!
//! **Templates** (3-refinement, every edge next to a refined face split into thirds; a, b, c, d a face's
//! corners counter-clockwise, p on a→b, q on a→d, s on c→d, from their first corner):
//! - 4 split edges: the 3 × 3 grid (9 quads);
//! - 1 split edge (a→b): (a, p₁, x, d), (p₁, p₂, y, x), (p₂, b, c, y), (x, y, c, d) with x, y at ⅓ and ⅔
//!   across the middle (4 quads);
//! - 2 split edges meeting at a: (a, p₁, x, q₁), (p₁, p₂, y, x), (q₁, x, z, q₂), (p₂, b, c, y),
//!   (q₂, z, c, d), (x, y, c, z), x, y, z at (⅓, ⅓), (⅔, ⅓), (⅓, ⅔) (6 quads);
//! - 2 opposite split edges: three columns (3 quads);
//! - 3 split edges: the face is refined whole (a closure, repeated until no face has three).
//!
//! Every template keeps the net closed, manifold and pure-quad with the same Euler characteristic.
//!
//! **Casting** a new vertex: from its bilinear place on the old face, along ± the net's interpolated normal,
//! at most [`CAST_SPACINGS`] local edges, onto the nearer input triangle that faces the same way (so it lands
//! on the floor of a slot the face bridged, and never on the far side of a thin part: a ray whose first hit
//! faces away is not used); where no ray hits, the nearest input point facing the same way. Then
//! [`RELAX_ROUNDS`] rounds of smoothing along the input's tangent plane even out where the casts landed.
//!
//! **Given up**, with the faces two rings around them, and built again ([`SITE_TRIES`]): new faces that cross
//! any face of the net, turn over ([`FOLD_COS`]) or bend sharply from a neighbour ([`MAX_BEND_DEG`]), and
//! those holding a vertex that faces the other wall of a gap narrower than [`GAP_SPACINGS`] of its spacing
//! (a solid fitted there crosses itself).

use rayon::prelude::*;

use crate::error::{Error, ErrorCode, Result};
use crate::geometry::bvh::{PointBvh, TriangleBvh};
use crate::geometry::mesh::{PolyMesh, TriMesh};
use crate::geometry::topology::{MeshTopology, UnionFind};
use crate::geometry::vec3::{self, V3, add, cross, dot, norm, scale, sub, wide};

/// Longest cast of a new vertex onto the input, in edges of the face it came from: deep enough for the
/// floor of a slot 2.5 spacings deep (the falcon's talons at 15,000 vertices: 0.047 units at a 0.019
/// spacing), short enough not to reach another part of the shape across a wider gap.
pub const CAST_SPACINGS: f64 = 3.0;

/// A new face folds when its normal is more than 120° from the net's normal before casting there (cos
/// 120° = −0.5): a face down the wall of a slot the net bridged is at about 90°.
pub const FOLD_COS: f64 = 0.5;

/// Largest angle between the normals of a new face and a neighbour (degrees). The net's own bends reach
/// 72–78° at the 99th percentile and 127–130° at most on the falcon at 15,000; the new faces' (after
/// [`relax`]) 52° and 126°. A bound at 80° or 100° gave up most of the refinement (173 and 82 of 233 faces,
/// the talons' slots among them) and the solid stayed as far; so only a face turned over is refused here
/// ([`FOLD_COS`]), and the narrow gaps ([`GAP_SPACINGS`]) are what the fit could not follow.
pub const MAX_BEND_DEG: f64 = 150.0;

/// A new vertex whose input normal meets the other side of a gap within this many of its spacings (a third
/// of the old face's edge) is not kept: the fitted walls of a slot that narrow cross. Falcon at 15,000, first
/// refined net: at 0 the solid crossed itself (207 pairs at a gap 0.005–0.016 wide) and twice more refined
/// away from its flaws; at 0.7 no crossing, scan → solid 0.0475 %; at 1.0 and 1.5 no crossing either but
/// the talons' slots were given up too (0.0543 %, 0.0562 %; 0.0576 % unrefined).
pub const GAP_SPACINGS: f64 = 0.7;

/// Rounds of tangential smoothing of the new vertices after casting ([`relax`]).
pub const RELAX_ROUNDS: usize = 3;

/// How many times a round drops the sites whose refined faces cross or fold and builds again.
pub const SITE_TRIES: usize = 4;

/// Settings of [`refine_where_far`].
#[derive(Clone, Debug, PartialEq)]
pub struct LocalOptions {
    /// A sample of the input farther than this from the net (model units) marks its nearest net face.
    pub far: f64,
    /// Most rounds of marking, refining and checking.
    pub rounds: usize,
    /// Most vertices all rounds together may add, as a share of the net's (as faces to refine, at about 16
    /// vertices each with their transitions, so approximately).
    pub max_added_share: f64,
    /// Places the refinement keeps away from (where a solid fitted to an earlier refined net crossed
    /// itself or folded), and how far: a face with a corner within `avoid_radius` of one is not refined,
    /// nor any face within two rings of it.
    pub avoid: Vec<V3>,
    /// See `avoid` (model units).
    pub avoid_radius: f64,
    /// A round is kept only when it also brings the largest distance of the samples down (not only their
    /// RMS): for a net refined for its far tail (a tip cut short) rather than for its RMS, a round that
    /// leaves the farthest place where it was costs vertices and a fit for nothing.
    pub by_max: bool,
}

impl Default for LocalOptions {
    fn default() -> Self {
        LocalOptions {
            far: f64::INFINITY,
            rounds: 2,
            max_added_share: 0.25,
            avoid: Vec::new(),
            avoid_radius: 0.0,
            by_max: false,
        }
    }
}

/// One round of [`refine_where_far`].
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct LocalRound {
    /// Input samples farther than `far` from the net before the round.
    pub far_samples: usize,
    /// Net faces marked (nearest to a far sample).
    pub marked_faces: usize,
    /// Faces refined whole (the marked ones, within the budget and the closure), first build.
    pub refined_faces: usize,
    /// Connected sites of the first build (refined faces and their transitions).
    pub sites: usize,
    /// Refined faces given up because faces of theirs crossed the net or folded.
    pub faces_given_up: usize,
    /// Vertices the round added.
    pub added_vertices: usize,
    /// RMS distance samples → net before the round, model units.
    pub rms_before: f64,
    /// The same after.
    pub rms_after: f64,
    /// Largest distance samples → net before the round, model units.
    pub max_before: f64,
    /// The same after.
    pub max_after: f64,
    /// The round's net was kept (no crossing, no fold, nearer).
    pub kept: bool,
}

/// What [`refine_where_far`] did.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct LocalReport {
    /// The rounds run.
    pub rounds: Vec<LocalRound>,
    /// Vertices of the net before.
    pub vertices_before: usize,
    /// Vertices of the net after.
    pub vertices_after: usize,
    /// Seconds taken.
    pub seconds: f64,
}

/// Refine the pure-quad `net` locally where `samples` (points of the scan) lie farther than `opts.far` from
/// it, in up to `opts.rounds` rounds (module docs), casting new vertices onto `surface` (the closed input the
/// net was made from). A round is kept only when its net has no crossing triangle pair
/// and no folded face that the net before it did not have, and is nearer to the input (RMS of the
/// samples); otherwise the net before it is returned.
///
/// # Errors
/// `input.bad-argument` when `net` has a face that is not a quad, or `far` is not positive. Cost: per round
/// one BVH of the net, a closest-point query per sample, and a crossing check of the refined faces.
///
/// # Example
/// ```
/// use scanstation::geometry::shapes::{cuboid, icosphere};
/// use scanstation::stages::remesh::local::{LocalOptions, refine_where_far};
/// let cube = cuboid([0.0; 3], [1.0; 3]);
/// let net = scanstation::PolyMesh::from(cube.clone()); // triangles: refused
/// let samples: Vec<[f64; 3]> = cube.positions.iter().map(|p| p.map(f64::from)).collect();
/// let opts = LocalOptions { far: 0.01, ..Default::default() };
/// assert!(refine_where_far(&net, &cube, &samples, &opts).is_err());
/// # let _ = icosphere;
/// ```
pub fn refine_where_far(
    net: &PolyMesh,
    surface: &TriMesh,
    samples: &[V3],
    opts: &LocalOptions,
) -> Result<(PolyMesh, LocalReport)> {
    let t0 = std::time::Instant::now();
    if net.faces().any(|f| f.len() != 4) {
        return Err(Error::new(ErrorCode::InputBadArgument, "local refinement needs a pure-quad net"));
    }
    if !(opts.far > 0.0) {
        return Err(Error::new(ErrorCode::InputBadArgument, format!("far distance {} is not positive", opts.far)));
    }
    let bvh = TriangleBvh::new(surface);
    let avoid = (!opts.avoid.is_empty()).then(|| {
        let pts: Vec<[f32; 3]> = opts.avoid.iter().map(|p| p.map(|c| c as f32)).collect();
        PointBvh::new(&pts)
    });
    let budget = (opts.max_added_share * net.positions.len() as f64) as usize;
    let mut report = LocalReport { vertices_before: net.positions.len(), ..Default::default() };
    let mut cur = net.clone();
    let mut dist = Distances::measure(&cur, samples);
    for _ in 0..opts.rounds {
        let added_so_far = cur.positions.len() - net.positions.len();
        let left = budget.saturating_sub(added_so_far);
        let on = Surface { mesh: surface, bvh: &bvh };
        let Some((next, round)) = round(&cur, samples, &dist, &on, opts, avoid.as_ref(), left) else {
            break;
        };
        let kept = round.kept;
        report.rounds.push(round);
        if !kept {
            break;
        }
        dist = Distances::measure(&next, samples);
        cur = next;
    }
    report.vertices_after = cur.positions.len();
    report.seconds = t0.elapsed().as_secs_f64();
    Ok((cur, report))
}

/// Distances of the samples to a net and the net face nearest to each.
struct Distances {
    d: Vec<f64>,
    face: Vec<u32>,
}

impl Distances {
    fn measure(net: &PolyMesh, samples: &[V3]) -> Self {
        let (tris, origin) = net.triangulate();
        let bvh = TriangleBvh::new(&tris);
        let (d, face): (Vec<f64>, Vec<u32>) = samples
            .par_iter()
            .map(|&p| bvh.closest(p).map_or((f64::INFINITY, 0), |c| (c.distance, origin[c.index as usize])))
            .unzip();
        Distances { d, face }
    }

    fn rms(&self) -> f64 {
        (self.d.iter().map(|x| x * x).sum::<f64>() / self.d.len().max(1) as f64).sqrt()
    }

    fn max(&self) -> f64 {
        self.d.iter().cloned().fold(0.0, f64::max)
    }
}

/// One round: mark, refine, cast, drop the sites that cross or fold, measure. `None` when nothing is far.
fn round(
    net: &PolyMesh,
    samples: &[V3],
    dist: &Distances,
    surface: &Surface,
    opts: &LocalOptions,
    avoid: Option<&PointBvh>,
    budget: usize,
) -> Option<(PolyMesh, LocalRound)> {
    let far = opts.far;
    // 1. The faces nearest to far samples, farthest first, within the vertex budget.
    let far_samples: Vec<usize> = (0..samples.len()).filter(|&i| dist.d[i] > far).collect();
    if far_samples.is_empty() || budget == 0 {
        return None;
    }
    let mut worst = vec![0.0f64; net.face_count()];
    for &i in &far_samples {
        let f = dist.face[i] as usize;
        worst[f] = worst[f].max(dist.d[i]);
    }
    let mut marked: Vec<usize> = (0..net.face_count()).filter(|&f| worst[f] > 0.0).collect();
    marked.sort_by(|&a, &b| worst[b].total_cmp(&worst[a]).then(a.cmp(&b)));
    // A refined face adds about 16 vertices with its share of the transition around it (the falcon's
    // talons at 15,000: 4,613 for 285 faces).
    marked.truncate(budget / 16);
    if marked.is_empty() {
        return None;
    }
    let mut r = LocalRound {
        far_samples: far_samples.len(),
        marked_faces: marked.len(),
        rms_before: dist.rms(),
        max_before: dist.max(),
        ..Default::default()
    };
    // 2. Refine, and give up the sites whose faces cross or fold, a few times.
    let topo = Topo::new(net);
    let mut faces_of = vec![Vec::new(); net.positions.len()];
    for (f, q) in net.faces().enumerate() {
        for &v in q {
            faces_of[v as usize].push(f as u32);
        }
    }
    let mut refine = vec![false; net.face_count()];
    for &f in &marked {
        refine[f] = true;
    }
    let mut bad: Vec<u32> = match avoid {
        Some(tree) => (0..net.face_count() as u32)
            .filter(|&f| {
                let q = net.face(f as usize);
                q.iter().any(|&v| tree.distance(wide(net.positions[v as usize])) <= opts.avoid_radius)
            })
            .collect(),
        None => Vec::new(),
    };
    for attempt in 0..=SITE_TRIES {
        // Give up the refined faces within two rings of each bad one (nearer ones would come back through
        // the closure, or split its edges again).
        let before = refine.iter().filter(|&&b| b).count();
        let mut ring: Vec<u32> = std::mem::take(&mut bad);
        for _ in 0..2 {
            let verts: Vec<u32> = ring.iter().flat_map(|&f| net.face(f as usize).to_vec()).collect();
            ring = verts.iter().flat_map(|&v| faces_of[v as usize].iter().copied()).collect();
            ring.sort_unstable();
            ring.dedup();
        }
        for &f in &ring {
            refine[f as usize] = false;
        }
        if attempt > 0 {
            r.faces_given_up += before - refine.iter().filter(|&&b| b).count();
        }
        if !refine.contains(&true) || attempt == SITE_TRIES {
            break;
        }
        topo.close(&mut refine);
        let built = Built::new(net, &topo, &refine, surface);
        if attempt == 0 {
            r.sites = topo.sites(&refine);
            r.refined_faces = refine.iter().filter(|&&b| b).count();
        }
        bad = built.bad_origins(net);
        if bad.is_empty() {
            let d = Distances::measure(&built.mesh, samples);
            r.added_vertices = built.mesh.positions.len() - net.positions.len();
            (r.rms_after, r.max_after) = (d.rms(), d.max());
            r.kept = r.rms_after < r.rms_before && (!opts.by_max || r.max_after < r.max_before);
            return Some((built.mesh, r));
        }
    }
    (r.rms_after, r.max_after) = (r.rms_before, r.max_before);
    Some((net.clone(), r))
}

/// Edges of a quad net: each face's four edges as indices into one edge list, and each edge's faces.
struct Topo {
    /// Per face, its edges (edge k from corner k to corner k + 1).
    face_edges: Vec<[u32; 4]>,
    /// Per edge, its (lower, higher) vertex and its two faces.
    edges: Vec<([u32; 2], [u32; 2])>,
    /// The edges in the order the faces first name them (new vertices are numbered in it).
    order: Vec<u32>,
}

impl Topo {
    fn new(net: &PolyMesh) -> Self {
        let t = MeshTopology::new(net);
        let face_edges: Vec<[u32; 4]> = (0..net.face_count())
            .map(|f| {
                let start = net.face_start(f);
                [0, 1, 2, 3].map(|k| t.halfedge_edge[start + k])
            })
            .collect();
        let edges = (0..t.edges.len())
            .map(|e| {
                let mut faces = [u32::MAX; 2];
                for (slot, &h) in faces.iter_mut().zip(t.edge_halfedges(e)) {
                    *slot = t.corner_face[h as usize];
                }
                (t.edges[e], faces)
            })
            .collect();
        let mut seen = vec![false; t.edges.len()];
        let order =
            face_edges.iter().flatten().copied().filter(|&e| !std::mem::replace(&mut seen[e as usize], true)).collect();
        Topo { face_edges, edges, order }
    }

    /// Split edges: those of a refined face.
    fn split_edges(&self, refine: &[bool]) -> Vec<bool> {
        let mut split = vec![false; self.edges.len()];
        for (f, fe) in self.face_edges.iter().enumerate() {
            if refine[f] {
                for &e in fe {
                    split[e as usize] = true;
                }
            }
        }
        split
    }

    /// Refine whole every face with three split edges, until none is left.
    fn close(&self, refine: &mut [bool]) {
        loop {
            let split = self.split_edges(refine);
            let mut changed = false;
            for (f, fe) in self.face_edges.iter().enumerate() {
                if !refine[f] && fe.iter().filter(|&&e| split[e as usize]).count() >= 3 {
                    refine[f] = true;
                    changed = true;
                }
            }
            if !changed {
                return;
            }
        }
    }

    /// Sites: the faces a refinement touches (refined ones and those with a split edge), joined across
    /// split edges.
    fn sites(&self, refine: &[bool]) -> usize {
        let split = self.split_edges(refine);
        let mut uf = UnionFind::new(self.face_edges.len());
        let mut touched = refine.to_vec();
        for (e, &(_, faces)) in self.edges.iter().enumerate() {
            if split[e] && faces[1] != u32::MAX {
                uf.union(faces[0], faces[1]);
                touched[faces[0] as usize] = true;
                touched[faces[1] as usize] = true;
            }
        }
        let roots: std::collections::BTreeSet<u32> =
            (0..touched.len()).filter(|&f| touched[f]).map(|f| uf.find(f as u32)).collect();
        roots.len()
    }
}

/// A refined net and, per face, the old face it came from.
struct Built {
    mesh: PolyMesh,
    origin: Vec<u32>,
    /// The net's normal at each vertex before casting (interpolated for new ones).
    normal: Vec<V3>,
    /// New vertices that face the other side of a narrow gap.
    narrow: Vec<bool>,
}

impl Built {
    /// Refine the faces marked in `refine` (closed), with transitions around them; cast new vertices.
    fn new(net: &PolyMesh, topo: &Topo, refine: &[bool], surface: &Surface) -> Self {
        let split = topo.split_edges(refine);
        let p: Vec<V3> = net.positions.iter().map(|&x| wide(x)).collect();
        let normals = vertex_normals(net, &p);
        let spacing = vec![0.0; p.len()];
        let mut b = Builder { p: p.clone(), n: normals.clone(), spacing, faces: Vec::new(), origin: Vec::new() };
        // Edge thirds, numbered in the order the faces first name the edges (deterministic).
        let mut thirds = vec![[u32::MAX; 2]; topo.edges.len()];
        for &e in &topo.order {
            let (e, [u, v]) = (e as usize, topo.edges[e as usize].0);
            if split[e] {
                let len = norm(sub(p[v as usize], p[u as usize]));
                let (nu, nv) = (normals[u as usize], normals[v as usize]);
                thirds[e] =
                    [1.0 / 3.0, 2.0 / 3.0].map(|t| b.push(lerp(p[u as usize], p[v as usize], t), lerp(nu, nv, t), len));
            }
        }
        let from = |u: u32, v: u32, e: u32| {
            let t = thirds[e as usize];
            if u < v { t } else { [t[1], t[0]] }
        };
        for (f, c) in net.faces().enumerate() {
            let fe = topo.face_edges[f];
            let s: [bool; 4] = fe.map(|e| split[e as usize]);
            let k = s.iter().filter(|&&x| x).count();
            let c4 = [c[0], c[1], c[2], c[3]];
            match k {
                0 => b.face(f, c4),
                1 => {
                    let r = (0..4).find(|&i| s[i]).unwrap_or(0);
                    let q = rotate(c4, r);
                    b.one_edge(f, q, from(q[0], q[1], fe[r]));
                }
                2 if s[((0..4).find(|&i| s[i]).unwrap_or(0) + 2) % 4] => {
                    let r = (0..4).find(|&i| s[i]).unwrap_or(0);
                    let q = rotate(c4, r);
                    b.opposite(f, q, from(q[0], q[1], fe[r]), from(q[3], q[2], fe[(r + 2) % 4]));
                }
                2 => {
                    // The corner both split edges meet at: edge r (corner r → r+1) and edge r−1.
                    let r = (0..4).find(|&i| s[i] && s[(i + 3) % 4]).unwrap_or(0);
                    let q = rotate(c4, r);
                    b.corner(f, q, from(q[0], q[1], fe[r]), from(q[0], q[3], fe[(r + 3) % 4]));
                }
                _ => {
                    let e = [0, 1, 2, 3].map(|i| from(c4[i], c4[(i + 1) % 4], fe[i]));
                    b.grid(f, c4, e);
                }
            }
        }
        // Cast the new vertices onto the input.
        let first_new = net.positions.len();
        let (cast, mut tn): (Vec<V3>, Vec<V3>) = (first_new..b.p.len())
            .into_par_iter()
            .map(|i| cast_onto(surface, b.p[i], b.n[i], CAST_SPACINGS * b.spacing[i]))
            .unzip();
        b.p[first_new..].copy_from_slice(&cast);
        let mut tn_all = vec![[0.0; 3]; first_new];
        tn_all.append(&mut tn);
        relax(&mut b.p, &mut tn_all, &b.faces, first_new, surface);
        // A new vertex facing the other side of a gap narrower than GAP_SPACINGS of its spacing.
        let narrow: Vec<bool> = (first_new..b.p.len())
            .into_par_iter()
            .map(|i| {
                let reach = GAP_SPACINGS * b.spacing[i] / 3.0;
                reach > 0.0 && surface.bvh.ray_hit(b.p[i], tn_all[i], 1e-6 * reach, reach, -1.0).is_some()
            })
            .collect();
        let positions = b.p.iter().map(|x| x.map(|c| c as f32)).collect();
        let mesh = PolyMesh::new(positions, &b.faces).unwrap_or_default();
        let mut narrow_all = vec![false; first_new];
        narrow_all.extend(narrow);
        Built { mesh, origin: b.origin, normal: b.n, narrow: narrow_all }
    }

    /// Old faces whose refined faces cross another face of the net or fold against the old face.
    fn bad_origins(&self, old: &PolyMesh) -> Vec<u32> {
        let (tris, tri_face) = self.mesh.triangulate();
        let p: Vec<V3> = tris.positions.iter().map(|&x| wide(x)).collect();
        let new_faces: Vec<bool> = (0..self.origin.len())
            .map(|f| self.mesh.face(f).iter().any(|&v| v as usize >= old.positions.len()))
            .collect();
        let touched: Vec<u32> =
            (0..tris.triangles.len() as u32).filter(|&t| new_faces[tri_face[t as usize] as usize]).collect();
        let pairs = crate::geometry::intersect::self_intersections_of(&p, &tris.triangles, &touched);
        let mut bad: Vec<u32> =
            pairs.into_iter().flat_map(|(a, b)| [a, b]).map(|t| self.origin[tri_face[t as usize] as usize]).collect();
        for (f, &o) in self.origin.iter().enumerate() {
            let q = self.mesh.face(f);
            if !new_faces[f] {
                continue;
            }
            let (fnrm, n) = (quad_normal(&p, q), q.iter().fold([0.0; 3], |acc, &v| add(acc, self.normal[v as usize])));
            if dot(fnrm, n) <= -FOLD_COS * norm(fnrm) * norm(n) {
                bad.push(o);
            }
        }
        for (f, &o) in self.origin.iter().enumerate() {
            if self.mesh.face(f).iter().any(|&v| self.narrow[v as usize]) {
                bad.push(o);
            }
        }
        // Sharp bends between a new face and a neighbour: the fitted surface pleats there.
        let cos_max = MAX_BEND_DEG.to_radians().cos();
        let mut by_edge: std::collections::HashMap<[u32; 2], u32> = std::collections::HashMap::new();
        for f in 0..self.origin.len() {
            let q = self.mesh.face(f);
            for k in 0..4 {
                let key = [q[k].min(q[(k + 1) % 4]), q[k].max(q[(k + 1) % 4])];
                if let Some(g) = by_edge.insert(key, f as u32) {
                    let g = g as usize;
                    if !(new_faces[f] || new_faces[g]) {
                        continue;
                    }
                    let (a, b) = (quad_normal(&p, q), quad_normal(&p, self.mesh.face(g)));
                    if dot(a, b) < cos_max * norm(a) * norm(b) {
                        bad.push(self.origin[f]);
                        bad.push(self.origin[g]);
                    }
                }
            }
        }
        bad.sort_unstable();
        bad.dedup();
        bad
    }
}

/// The refined net being built: positions, normals and local edge length of every vertex, faces and origins.
struct Builder {
    p: Vec<V3>,
    n: Vec<V3>,
    spacing: Vec<f64>,
    faces: Vec<Vec<u32>>,
    origin: Vec<u32>,
}

impl Builder {
    fn push(&mut self, p: V3, n: V3, spacing: f64) -> u32 {
        self.p.push(p);
        self.n.push(vec3::unit_or(n, [0.0, 0.0, 1.0]));
        self.spacing.push(spacing);
        self.p.len() as u32 - 1
    }

    fn face(&mut self, origin: usize, q: [u32; 4]) {
        self.faces.push(q.to_vec());
        self.origin.push(origin as u32);
    }

    /// A new vertex at (u, v) of the old quad `q` (bilinear; u along q₀ → q₁, v along q₀ → q₃).
    fn inner(&mut self, q: [u32; 4], u: f64, v: f64) -> u32 {
        let [a, b, c, d] = q.map(|i| i as usize);
        let bil = |x: &[V3]| add(lerp(x[a], x[b], u), scale(sub(lerp(x[d], x[c], u), lerp(x[a], x[b], u)), v));
        let (p, n) = (bil(&self.p), bil(&self.n));
        let len = 0.5 * (norm(sub(self.p[b], self.p[a])) + norm(sub(self.p[d], self.p[a])));
        self.push(p, n, len)
    }

    fn one_edge(&mut self, f: usize, [a, b, c, d]: [u32; 4], [p1, p2]: [u32; 2]) {
        let x = self.inner([a, b, c, d], 1.0 / 3.0, 0.5);
        let y = self.inner([a, b, c, d], 2.0 / 3.0, 0.5);
        for q in [[a, p1, x, d], [p1, p2, y, x], [p2, b, c, y], [x, y, c, d]] {
            self.face(f, q);
        }
    }

    fn opposite(&mut self, f: usize, [a, b, c, d]: [u32; 4], [p1, p2]: [u32; 2], [s1, s2]: [u32; 2]) {
        // s runs from d to c: s₁ at ⅓ from d.
        for q in [[a, p1, s1, d], [p1, p2, s2, s1], [p2, b, c, s2]] {
            self.face(f, q);
        }
    }

    fn corner(&mut self, f: usize, [a, b, c, d]: [u32; 4], [p1, p2]: [u32; 2], [q1, q2]: [u32; 2]) {
        let x = self.inner([a, b, c, d], 1.0 / 3.0, 1.0 / 3.0);
        let y = self.inner([a, b, c, d], 2.0 / 3.0, 1.0 / 3.0);
        let z = self.inner([a, b, c, d], 1.0 / 3.0, 2.0 / 3.0);
        for q in [[a, p1, x, q1], [p1, p2, y, x], [q1, x, z, q2], [p2, b, c, y], [q2, z, c, d], [x, y, c, z]] {
            self.face(f, q);
        }
    }

    /// The 3 × 3 grid; `e[i]` the thirds of edge i from corner i.
    fn grid(&mut self, f: usize, q: [u32; 4], e: [[u32; 2]; 4]) {
        let mut g = [[0u32; 4]; 4];
        g[0][0] = q[0];
        g[0][3] = q[1];
        g[3][3] = q[2];
        g[3][0] = q[3];
        for t in 0..2 {
            g[0][1 + t] = e[0][t]; // q0 → q1 along row 0
            g[1 + t][3] = e[1][t]; // q1 → q2 up column 3
            g[3][2 - t] = e[2][t]; // q2 → q3 back along row 3
            g[2 - t][0] = e[3][t]; // q3 → q0 down column 0
        }
        for i in 1..3 {
            for j in 1..3 {
                g[i][j] = self.inner(q, j as f64 / 3.0, i as f64 / 3.0);
            }
        }
        for i in 0..3 {
            for j in 0..3 {
                self.face(f, [g[i][j], g[i][j + 1], g[i + 1][j + 1], g[i + 1][j]]);
            }
        }
    }
}

fn lerp(a: V3, b: V3, t: f64) -> V3 {
    add(a, scale(sub(b, a), t))
}

fn rotate(q: [u32; 4], r: usize) -> [u32; 4] {
    [q[r % 4], q[(r + 1) % 4], q[(r + 2) % 4], q[(r + 3) % 4]]
}

/// A quad's normal from its diagonals (twice its area when planar).
fn quad_normal(p: &[V3], q: &[u32]) -> V3 {
    let [a, b, c, d] = [q[0], q[1], q[2], q[3]].map(|i| p[i as usize]);
    cross(sub(c, a), sub(d, b))
}

/// Area-weighted vertex normals of a quad net.
fn vertex_normals(net: &PolyMesh, p: &[V3]) -> Vec<V3> {
    let mut n = vec![[0.0; 3]; p.len()];
    for q in net.faces() {
        let fnrm = quad_normal(p, q);
        for &v in q {
            n[v as usize] = add(n[v as usize], fnrm);
        }
    }
    n.into_iter().map(|x| vec3::unit_or(x, [0.0, 0.0, 1.0])).collect()
}

/// `p` cast along ± `n` (at most `reach`) onto the nearer input surface that faces like `n` where the ray
/// first meets the input (a ray whose first hit faces the other way, the far side of a thin part or another
/// part seen from inside, is not used); else the nearest input point facing like `n`; else `p`.
fn cast_onto(s: &Surface, p: V3, n: V3, reach: f64) -> (V3, V3) {
    let hit = |dir: V3| s.bvh.ray_first(p, dir, 0.0, reach).filter(|&(_, m)| dot(m, n) > 0.0);
    match (hit(scale(n, -1.0)), hit(n)) {
        (Some((t, _)), Some((u, m))) if u < t => (add(p, scale(n, u)), m),
        (Some((t, m)), _) => (add(p, scale(n, -t)), m),
        (None, Some((u, m))) => (add(p, scale(n, u)), m),
        (None, None) => s.nearest(p, n),
    }
}

/// The input surface new vertices are cast onto.
struct Surface<'a> {
    mesh: &'a TriMesh,
    bvh: &'a TriangleBvh,
}

impl Surface<'_> {
    /// The nearest point facing like `n` (else the nearest) and its triangle's unit normal; `p`, `n` when
    /// the surface is empty.
    fn nearest(&self, p: V3, n: V3) -> (V3, V3) {
        match self.bvh.closest_facing(p, n).or_else(|| self.bvh.closest(p)) {
            Some(c) => {
                let pw: Vec<V3> = self.mesh.triangles[c.index as usize]
                    .iter()
                    .map(|&v| wide(self.mesh.positions[v as usize]))
                    .collect();
                (c.point, vec3::unit_or(cross(sub(pw[1], pw[0]), sub(pw[2], pw[0])), n))
            }
            None => (p, n),
        }
    }
}

/// [`RELAX_ROUNDS`] rounds of tangential smoothing of the vertices from `first` on: each moves halfway to
/// its neighbours' mean within the input's tangent plane, then onto the nearest input point facing the same
/// way. Evens out where the casts landed (a new vertex on a slot's floor beside one on its rim).
fn relax(p: &mut [V3], tn: &mut [V3], faces: &[Vec<u32>], first: usize, s: &Surface) {
    let mut nb: Vec<Vec<u32>> = vec![Vec::new(); p.len() - first];
    for q in faces {
        for k in 0..q.len() {
            let (a, b) = (q[k], q[(k + 1) % q.len()]);
            if a as usize >= first && !nb[a as usize - first].contains(&b) {
                nb[a as usize - first].push(b);
            }
            if b as usize >= first && !nb[b as usize - first].contains(&a) {
                nb[b as usize - first].push(a);
            }
        }
    }
    for _ in 0..RELAX_ROUNDS {
        let moved: Vec<(V3, V3)> = (first..p.len())
            .into_par_iter()
            .map(|i| {
                let list = &nb[i - first];
                let mean = scale(
                    list.iter().fold([0.0; 3], |acc, &j| add(acc, p[j as usize])),
                    1.0 / list.len().max(1) as f64,
                );
                let d = sub(mean, p[i]);
                let t = sub(d, scale(tn[i], dot(d, tn[i])));
                s.nearest(add(p[i], scale(t, 0.5)), tn[i])
            })
            .collect();
        for (k, (q, n)) in moved.into_iter().enumerate() {
            p[first + k] = q;
            tn[first + k] = n;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::topology::TopologyReport;

    /// A cube's surface as a pure-quad net of k × k quads per side.
    fn cube_net(k: usize) -> PolyMesh {
        let mut pos: Vec<[f32; 3]> = Vec::new();
        let mut index = std::collections::HashMap::new();
        let mut faces = Vec::new();
        let mut id = |p: [i64; 3], pos: &mut Vec<[f32; 3]>| {
            *index.entry(p).or_insert_with(|| {
                pos.push(p.map(|c| c as f32 / k as f32));
                pos.len() as u32 - 1
            })
        };
        let k = k as i64;
        for axis in 0..3 {
            for side in [0, k] {
                for i in 0..k {
                    for j in 0..k {
                        let at = |a: i64, b: i64| {
                            let mut p = [0i64; 3];
                            p[axis] = side;
                            p[(axis + 1) % 3] = a;
                            p[(axis + 2) % 3] = b;
                            p
                        };
                        let mut q = [at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)];
                        if side == 0 {
                            q.reverse();
                        }
                        faces.push(q.map(|p| id(p, &mut pos)).to_vec());
                    }
                }
            }
        }
        PolyMesh::new(pos, &faces).unwrap()
    }

    /// Every pattern of refined faces keeps the net closed, manifold, pure-quad, with χ 2.
    #[test]
    fn templates_keep_the_net_closed_and_its_euler_characteristic() {
        let net = cube_net(4);
        let input = crate::geometry::shapes::cuboid([0.0; 3], [1.0; 3]);
        let bvh = TriangleBvh::new(&input);
        let topo = Topo::new(&net);
        for pattern in [vec![0usize], vec![0, 1], vec![0, 5], vec![0, 2], vec![3, 17, 40, 41, 42, 90]] {
            let mut refine = vec![false; net.face_count()];
            for f in &pattern {
                refine[*f] = true;
            }
            topo.close(&mut refine);
            let b = Built::new(&net, &topo, &refine, &Surface { mesh: &input, bvh: &bvh });
            assert!(b.mesh.faces().all(|f| f.len() == 4), "pattern {pattern:?}");
            let t = TopologyReport::compute(&b.mesh);
            assert_eq!(
                (t.boundary_edges, t.nonmanifold_edges, t.orientation_conflicts),
                (0, 0, 0),
                "pattern {pattern:?}"
            );
            assert_eq!(t.euler_characteristic, 2, "pattern {pattern:?}");
            assert!(b.bad_origins(&net).is_empty(), "pattern {pattern:?}: crossed or folded");
            assert!(b.mesh.positions.len() > net.positions.len(), "pattern {pattern:?}");
        }
    }

    /// A closed block [0, 1]³ whose top has a slot along x (0.3 < x < 0.7), `width` wide (centred) and `depth` deep, as a
    /// heightfield of `n` × `n` cells on top, the four sides and the bottom sharing its border.
    fn grooved_block(n: usize, width: f64, depth: f64) -> TriMesh {
        let h = |i: usize, j: usize| {
            let (x, y) = (i as f64 / n as f64, j as f64 / n as f64);
            if (y - 0.5).abs() < width / 2.0 && (x - 0.5).abs() < 0.2 { 1.0 - depth } else { 1.0 }
        };
        let mut pos: Vec<[f32; 3]> = Vec::new();
        let mut tris: Vec<[u32; 3]> = Vec::new();
        let id = |i: usize, j: usize| (i * (n + 1) + j) as u32;
        for i in 0..=n {
            for j in 0..=n {
                pos.push([i as f32 / n as f32, j as f32 / n as f32, h(i, j) as f32]);
            }
        }
        let bottom = pos.len() as u32;
        for i in 0..=n {
            for j in 0..=n {
                pos.push([i as f32 / n as f32, j as f32 / n as f32, 0.0]);
            }
        }
        for i in 0..n {
            for j in 0..n {
                let (a, b, c, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
                tris.push([a, b, c]);
                tris.push([a, c, d]);
                tris.push([bottom + a, bottom + c, bottom + b]);
                tris.push([bottom + a, bottom + d, bottom + c]);
            }
        }
        // Sides: the border loop of the top, counter-clockwise seen from above, joined to the bottom's.
        let mut border = Vec::new();
        border.extend((0..n).map(|i| id(i, 0)));
        border.extend((0..n).map(|j| id(n, j)));
        border.extend((0..n).map(|i| id(n - i, n)));
        border.extend((0..n).map(|j| id(0, n - j)));
        for k in 0..border.len() {
            let (a, b) = (border[k], border[(k + 1) % border.len()]);
            tris.push([a, bottom + b, b]);
            tris.push([a, bottom + a, bottom + b]);
        }
        TriMesh { positions: pos, triangles: tris }
    }

    fn crossings(m: &PolyMesh) -> usize {
        let (t, _) = m.triangulate();
        let p: Vec<V3> = t.positions.iter().map(|&x| wide(x)).collect();
        crate::geometry::intersect::self_intersections(&p, &t.triangles).len()
    }

    /// A net of 5 × 5 quads a side bridges a slot half a spacing wide and three quarters deep (the
    /// falcon's slots under the talons: 0.6–1 spacing wide, 2.5 deep): refined locally, it reaches into the
    /// slot (largest distance from the block to the net at most half of what it was), stays closed,
    /// pure-quad, uncrossed, with χ 2, adds vertices only near the groove, and is the same for the same input.
    #[test]
    fn a_net_bridging_a_groove_reaches_into_it_without_crossing() {
        let block = grooved_block(60, 0.1, 0.15);
        assert_eq!(TopologyReport::compute(&PolyMesh::from(block.clone())).boundary_edges, 0, "block closed");
        let net = cube_net(5);
        let samples: Vec<V3> = block.positions.iter().map(|&x| wide(x)).collect();
        // The three faces over the slot and their transitions (the default quarter of a 152-vertex net is
        // two faces).
        let opts = LocalOptions { far: 0.02, max_added_share: 3.0, ..Default::default() };
        let (refined, r) = refine_where_far(&net, &block, &samples, &opts).unwrap();
        let first = &r.rounds[0];
        assert!(first.kept && first.added_vertices > 0, "{r:?}");
        assert!(first.max_before > 0.12, "the net bridges the slot: {first:?}");
        let last = r.rounds.iter().rev().find(|x| x.kept).unwrap();
        assert!(last.max_after < 0.5 * first.max_before, "reached into the groove: {r:?}");
        let t = TopologyReport::compute(&refined);
        assert_eq!((t.boundary_edges, t.nonmanifold_edges, t.orientation_conflicts), (0, 0, 0));
        assert_eq!(t.euler_characteristic, 2);
        assert!(refined.faces().all(|f| f.len() == 4));
        assert_eq!(crossings(&refined), 0);
        for p in &refined.positions[net.positions.len()..] {
            assert!(
                p[2] > 0.84 && (p[1] - 0.5).abs() < 0.35 && (p[0] - 0.5).abs() < 0.45,
                "new vertex {p:?} far from the slot"
            );
        }
        let (again, _) = refine_where_far(&net, &block, &samples, &opts).unwrap();
        assert_eq!(again, refined, "deterministic");
    }

    /// Places to avoid keep the refinement away; a far distance no sample exceeds leaves the net as it is.
    #[test]
    fn avoided_places_and_near_nets_are_left_alone() {
        let block = grooved_block(60, 0.1, 0.3);
        let net = cube_net(5);
        let samples: Vec<V3> = block.positions.iter().map(|&x| wide(x)).collect();
        let opts = LocalOptions { far: 0.02, avoid: vec![[0.5, 0.5, 1.0]], avoid_radius: 2.0, ..Default::default() };
        let (same, r) = refine_where_far(&net, &block, &samples, &opts).unwrap();
        assert_eq!(same, net, "{r:?}");
        let opts = LocalOptions { far: 10.0, ..Default::default() };
        let (same, r) = refine_where_far(&net, &block, &samples, &opts).unwrap();
        assert_eq!((same == net, r.rounds.len()), (true, 0));
        assert!(refine_where_far(&net, &block, &samples, &LocalOptions { far: 0.0, ..Default::default() }).is_err());
    }
}

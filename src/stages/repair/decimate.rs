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
//! * **fold** a face over (its normal turns by more than [`MAX_NORMAL_TURN_DEG`]) or make it degenerate.
//!
//! A final self-intersection search checks the result; the repair loop removes any crossing it finds.

use crate::geometry::sampling::Rng;
use crate::geometry::vec3::{self, V3};

/// Largest turn of a face normal a collapse may cause, in degrees.
pub const MAX_NORMAL_TURN_DEG: f64 = 60.0;
/// Live edges drawn per step; the cheapest is collapsed (Wu & Kobbelt's multiple-choice scheme).
const CHOICES: usize = 8;
/// Refused collapses in a row after which decimation stops short of the target.
const MAX_STALLED: usize = 100_000;

/// What decimation did.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct DecimateReport {
    /// Requested vertex count.
    pub target_vertices: usize,
    /// Vertices before and after.
    pub vertices_before: usize,
    pub vertices_after: usize,
    /// Edge collapses done.
    pub collapses: usize,
    /// Collapses refused by the link condition, and by the fold-over/degeneracy test.
    pub refused_link: usize,
    pub refused_fold: usize,
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
    let b = [-q[3], -q[6], -q[8]];
    let det = a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1]) - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
        + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0]);
    let scale = (q[0] + q[4] + q[7]).powi(3);
    if !(det.abs() > 1e-10 * scale) {
        return None;
    }
    let solve = |k: usize| {
        let mut m = a;
        for r in 0..3 {
            m[r][k] = b[r];
        }
        (m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]))
            / det
    };
    Some([solve(0), solve(1), solve(2)])
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
    vertex_faces: Vec<Vec<u32>>,
    q: Vec<Quadric>,
    alive: Vec<bool>,
}

impl State<'_> {
    fn candidate(&self, u: u32, v: u32) -> Candidate {
        let mut q = self.q[u as usize];
        q_add(&mut q, &self.q[v as usize]);
        let (pu, pv) = (self.p[u as usize], self.p[v as usize]);
        let mid = vec3::scale(vec3::add(pu, pv), 0.5);
        let mut best = (q_eval(&q, mid), mid);
        for c in [pu, pv].into_iter().chain(q_optimum(&q)) {
            let e = q_eval(&q, c);
            if e < best.0 {
                best = (e, c);
            }
        }
        Candidate { cost: best.0.max(0.0), u, v, at: best.1 }
    }

    fn ring(&self, v: u32, out: &mut Vec<u32>) {
        out.clear();
        for &f in &self.vertex_faces[v as usize] {
            if self.face_alive[f as usize] {
                out.extend(self.tris[f as usize].iter().copied().filter(|&w| w != v));
            }
        }
        out.sort_unstable();
        out.dedup();
    }

    fn normal(&self, t: [u32; 3], moved: u32, to: V3, also: u32) -> V3 {
        let [a, b, c] = t.map(|i| if i == moved || i == also { to } else { self.p[i as usize] });
        vec3::cross(vec3::sub(b, a), vec3::sub(c, a))
    }
}

/// Decimate the closed oriented manifold (`p`, `tris`) to about `target` vertices, in place; `seed` fixes
/// the random edge choices. Cost: O(F) setup plus O(1) expected work per collapse.
pub fn decimate(p: &mut Vec<V3>, tris: &mut Vec<[u32; 3]>, target: usize, seed: u64) -> DecimateReport {
    let n = p.len();
    let mut report = DecimateReport { target_vertices: target, vertices_before: n, ..Default::default() };
    let mut q = vec![[0.0; 10]; n];
    let mut vertex_faces = vec![Vec::new(); n];
    for (f, t) in tris.iter().enumerate() {
        if let Some(unit) = vec3::tri_unit_normal(p, *t) {
            let a = p[t[0] as usize];
            let pq = plane_quadric(unit, -vec3::dot(unit, a), vec3::tri_area(p, *t));
            for &v in t {
                q_add(&mut q[v as usize], &pq);
            }
        }
        for &v in t {
            vertex_faces[v as usize].push(f as u32);
        }
    }
    let face_count = tris.len();
    if face_count == 0 {
        return report;
    }
    let mut s = State { p, tris, face_alive: vec![true; face_count], vertex_faces, q, alive: vec![true; n] };
    let t0 = std::time::Instant::now();
    let mut rng = Rng::new(seed);
    let mut alive_count = n;
    let mut stalled = 0usize;
    let (mut ring_u, mut ring_v, mut ring_w) = (Vec::new(), Vec::new(), Vec::new());
    let min_cos = MAX_NORMAL_TURN_DEG.to_radians().cos();
    while alive_count > target && stalled < MAX_STALLED {
        // Multiple choice: the cheapest of CHOICES random live edges (dead faces are skipped, bounded tries).
        let mut best: Option<Candidate> = None;
        let mut drawn = 0;
        for _ in 0..CHOICES * 8 {
            let f = (rng.next_u64() % face_count as u64) as usize;
            if !s.face_alive[f] {
                continue;
            }
            let k = (rng.next_u64() % 3) as usize;
            let t = s.tris[f];
            let c = s.candidate(t[k], t[(k + 1) % 3]);
            if best.is_none_or(|b| c.cost < b.cost) {
                best = Some(c);
            }
            drawn += 1;
            if drawn == CHOICES {
                break;
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
        let opposite_ok = n_shared == 2
            && shared.iter().all(|&w| {
                s.ring(w, &mut ring_w);
                ring_w.len() >= 4
            });
        if !opposite_ok || merged_valence < 3 {
            report.refused_link += 1;
            stalled += 1;
            continue;
        }
        // Fold-over and degeneracy test on the faces that survive the collapse.
        let mut ok = true;
        'faces: for &w in &[u, v] {
            for &f in &s.vertex_faces[w as usize] {
                let t = s.tris[f as usize];
                if !s.face_alive[f as usize] || (t.contains(&u) && t.contains(&v)) {
                    continue;
                }
                let old = s.normal(t, u32::MAX, [0.0; 3], u32::MAX);
                let new = s.normal(t, u, c.at, v);
                let (lo, ln) = (vec3::norm(old), vec3::norm(new));
                if !(ln > 1e-12 * lo) || vec3::dot(old, new) < min_cos * lo * ln {
                    ok = false;
                    break 'faces;
                }
            }
        }
        if !ok {
            report.refused_fold += 1;
            stalled += 1;
            continue;
        }
        stalled = 0;
        // Collapse u into v at c.at.
        report.collapses += 1;
        report.max_error = report.max_error.max(c.cost);
        s.p[v as usize] = c.at;
        let qu = s.q[u as usize];
        q_add(&mut s.q[v as usize], &qu);
        s.alive[u as usize] = false;
        alive_count -= 1;
        let faces_u = std::mem::take(&mut s.vertex_faces[u as usize]);
        for f in faces_u {
            if !s.face_alive[f as usize] {
                continue;
            }
            let t = &mut s.tris[f as usize];
            if t.contains(&v) {
                s.face_alive[f as usize] = false;
            } else {
                t.iter_mut().for_each(|x| {
                    if *x == u {
                        *x = v;
                    }
                });
                s.vertex_faces[v as usize].push(f);
            }
        }
        let face_alive = &s.face_alive;
        s.vertex_faces[v as usize].retain(|&f| face_alive[f as usize]);
    }
    tracing::debug!(seconds = t0.elapsed().as_secs_f64(), collapses = report.collapses, "decimation loop done");
    let kept: Vec<[u32; 3]> = s.tris.iter().zip(&s.face_alive).filter(|(_, a)| **a).map(|(t, _)| *t).collect();
    let (pos, tris_out, _) = crate::stages::repair::weld::compact(s.p, &kept);
    *s.p = pos;
    *s.tris = tris_out;
    report.vertices_after = s.p.len();
    report
}

//! Integer edge offsets of the position field, and the cancellation of position singularities in pairs.
//!
//! Every working-mesh edge (i, j) carries the integer lattice step `d` from i's lattice point to j's, in
//! i's frame, and the quarter turns `r` matching j's cross to i's. Around a triangle the steps, turned into
//! one frame, sum to zero except at a **position singularity** (a dislocation: the lattice gains or loses a
//! half row there), which the extraction turns into a triangle or pentagon next to a valence-5 or -3
//! vertex: two irregular vertices for every singular triangle, none of them needed by the surface.
//!
//! Dislocations come in pairs of opposite sign. [`cancel_pairs`] joins each to its cheapest partner by a
//! path in the dual graph and changes the steps of the edges the path crosses by one lattice unit, so both
//! triangles sum to zero and every triangle in between is unchanged (a greedy, local form of the
//! minimum-cost flow of QuadriFlow, Huang et al. 2018). A step's cost is how far the change moves it from
//! the continuous offset of the two origins: `|δ|² − 2 δ·m` with `m` the rounding residual, so a path runs
//! where the lattice is already strained and cutting or adding the half row costs least. The extraction
//! then reads the steps directly (0: same output vertex, a unit step: an output edge), so the stretch the
//! cancellation asks for is spread by the later relaxation instead of being re-rounded away.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use rayon::prelude::*;

use super::field::{Frame, compat_position_offset};
use super::hierarchy::Level;
use crate::geometry::vec3::V3;

/// One way of cancelling tried by [`super::remesh`]: the largest path cost (in lattice-unit changes,
/// `|δ|² − 2 δ·m`, between 0 and about 2 per crossed edge; a pair farther apart is left as it is) and whether
/// a path may end in a triangle where the cross field turns (an orientation singularity absorbs the
/// dislocation instead of a partner of opposite sign).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Reach {
    /// Largest path cost allowed.
    pub max_path_cost: f64,
    /// Paths may end in a cone (a triangle where the cross field turns).
    pub into_cones: bool,
}

/// The tries, in the order they are weighed. A result is kept only when it is as sound as without
/// cancellation and its RMS grows little for the irregular vertices it saves. Measured at 10k (seed 0): the
/// longer reach pays on spot (2.86 → 1.90 %) and the torus test, the shorter one on fandisk (1.09 %); ending
/// in cones pays on igea (1.73 → 1.63 %) and on the sphere test (22 → 14 of 2000, 8 of them the cones).
pub const TRIES: [Reach; 3] = [
    Reach { max_path_cost: 60.0, into_cones: false },
    Reach { max_path_cost: 200.0, into_cones: false },
    Reach { max_path_cost: 60.0, into_cones: true },
];

/// Cost floor per crossed edge (keeps paths short where many edges cost nothing).
pub const EDGE_COST_FLOOR: f64 = 0.05;

/// Extra cost of a change that makes an edge's step diagonal (the path then shears the lattice instead of
/// adding or removing a row).
pub const SHEAR_COST: f64 = 2.0;

/// Most dual nodes one search may settle (bounds the work per singularity).
pub const MAX_SETTLED: usize = 20_000;

/// What [`super::extract::extract`] needs to cancel singularities.
#[derive(Copy, Clone, Debug)]
pub struct Cancel<'a> {
    /// The triangles level 0 was built from.
    pub tris: &'a [[u32; 3]],
    /// Path cost and ends allowed ([`TRIES`]).
    pub reach: Reach,
    /// Vertices no path may touch.
    pub blocked: &'a [bool],
}

/// Parts thinner than this many local spacings (or gaps narrower) are closed to the cancellation paths: on
/// the repaired bunny at 10k, paths across the ear tips removed a row there (input→quad max 0.7 → 1.9 %).
pub const CANCEL_THIN: f64 = 2.5;

/// Integer steps of every working-mesh edge.
#[derive(Clone, Debug, Default)]
pub struct Offsets {
    /// Undirected edges (i < j), sorted.
    pub edges: Vec<(u32, u32)>,
    /// Lattice step from i's lattice point to j's, in i's frame.
    pub d: Vec<[i64; 2]>,
    /// Quarter turns taking j's cross representative to i's.
    pub r: Vec<u8>,
    /// Continuous offset minus `d`, in i's frame, in lattice spacings.
    pub m: Vec<[f64; 2]>,
}

/// What [`cancel_pairs`] did.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct CancelCounts {
    /// Triangles with a non-zero step sum (orientation singularities excluded), before.
    pub singular_before: usize,
    /// The same, after.
    pub singular_after: usize,
    /// Paths applied.
    pub pairs_cancelled: usize,
    /// Edge steps changed (an edge on two paths counts twice).
    pub steps_changed: usize,
}

/// Coordinates `w` turned by `k` quarter turns counter-clockwise.
#[inline]
fn rotc(w: [i64; 2], k: u32) -> [i64; 2] {
    match k & 3 {
        0 => w,
        1 => [-w[1], w[0]],
        2 => [-w[0], -w[1]],
        _ => [w[1], -w[0]],
    }
}

#[inline]
fn l1(w: [i64; 2]) -> i64 {
    w[0].abs() + w[1].abs()
}

impl Offsets {
    /// The steps of every edge of `level` from orientation `q`, origins `o` and spacings `s`.
    pub fn compute(level: &Level, q: &[V3], o: &[V3], s: &[f64]) -> Self {
        let n = level.len();
        type Step = ((u32, u32), [i64; 2], u8, [f64; 2]);
        let per: Vec<Vec<Step>> = (0..n)
            .into_par_iter()
            .map(|i| {
                let f0 = Frame { p: level.p[i], n: level.n[i], q: q[i], o: o[i], s: s[i] };
                level
                    .neighbours(i)
                    .filter(|&(j, _)| j > i)
                    .map(|(j, _)| {
                        let f1 = Frame { p: level.p[j], n: level.n[j], q: q[j], o: o[j], s: s[j] };
                        let (d, r, m) = compat_position_offset(&f0, &f1);
                        ((i as u32, j as u32), d, r as u8, m)
                    })
                    .collect()
            })
            .collect();
        let mut out = Offsets::default();
        for (e, d, r, m) in per.into_iter().flatten() {
            out.edges.push(e);
            out.d.push(d);
            out.r.push(r);
            out.m.push(m);
        }
        out
    }

    fn index(&self, a: u32, b: u32) -> Option<usize> {
        self.edges.binary_search(&(a.min(b), a.max(b))).ok()
    }
}

/// One directed edge of a triangle: the edge, whether it runs i → j, and the quarter turns σ taking the
/// edge's own frame (i's) to the triangle's frame (its first corner's), so that a change δ of the edge's
/// step changes the triangle's sum by `±rotc(δ, σ)`.
#[derive(Copy, Clone, Debug)]
struct Side {
    edge: u32,
    forward: bool,
    sigma: u32,
}

/// The triangles' sides, sums and orientation-singular flags.
struct Dual {
    sides: Vec<[Side; 3]>,
    /// Step sum in the triangle's frame.
    sum: Vec<[i64; 2]>,
    /// The cross field turns around the triangle (its frames do not close): left alone.
    turning: Vec<bool>,
    /// The two triangles of each edge (forward side first).
    faces_of_edge: Vec<[u32; 2]>,
}

impl Dual {
    fn new(off: &Offsets, tris: &[[u32; 3]]) -> Option<Self> {
        let mut sides = Vec::with_capacity(tris.len());
        let mut sum = Vec::with_capacity(tris.len());
        let mut turning = Vec::with_capacity(tris.len());
        let mut faces_of_edge = vec![[u32::MAX; 2]; off.edges.len()];
        for (t, tri) in tris.iter().enumerate() {
            let mut rho = 0u32;
            let mut s = [0i64; 2];
            let mut sd = [Side { edge: 0, forward: true, sigma: 0 }; 3];
            let mut turn_total = 0u32;
            for k in 0..3 {
                let (u, v) = (tri[k], tri[(k + 1) % 3]);
                let e = off.index(u, v)?;
                let forward = u < v;
                let re = off.r[e] as u32;
                // Step and turns of the directed edge u → v in u's frame.
                let (r_uv, d_uv) = if forward { (re, off.d[e]) } else { ((4 - re) % 4, neg(rotc(off.d[e], re))) };
                let rho_k = (4 - rho % 4) % 4; // frame of corner k → triangle frame
                let sigma = if forward { rho_k } else { (re + rho_k) % 4 };
                sd[k] = Side { edge: e as u32, forward, sigma };
                let c = rotc(d_uv, rho_k);
                s = [s[0] + c[0], s[1] + c[1]];
                let slot = usize::from(!forward);
                if faces_of_edge[e][slot] != u32::MAX {
                    return None; // not an oriented 2-manifold
                }
                faces_of_edge[e][slot] = t as u32;
                rho += r_uv;
                turn_total += r_uv;
            }
            sides.push(sd);
            sum.push(s);
            turning.push(!turn_total.is_multiple_of(4));
        }
        if faces_of_edge.iter().any(|f| f[0] == u32::MAX || f[1] == u32::MAX) {
            return None;
        }
        Some(Dual { sides, sum, turning, faces_of_edge })
    }

    fn singular(&self) -> usize {
        (0..self.sum.len()).filter(|&t| !self.turning[t] && self.sum[t] != [0, 0]).count()
    }

    /// The change δ of `side`'s edge step that changes its triangle's sum by `delta_sum`.
    fn step_for(side: Side, delta_sum: [i64; 2]) -> [i64; 2] {
        let w = if side.forward { delta_sum } else { neg(delta_sum) };
        rotc(w, (4 - side.sigma) % 4)
    }

    /// The change of `side`'s triangle's sum caused by a change δ of its edge step.
    fn sum_change(side: Side, delta: [i64; 2]) -> [i64; 2] {
        let c = rotc(delta, side.sigma);
        if side.forward { c } else { neg(c) }
    }
}

#[inline]
fn neg(w: [i64; 2]) -> [i64; 2] {
    [-w[0], -w[1]]
}

/// One triangle's state in a search.
#[derive(Copy, Clone, Debug, Default)]
struct Node {
    stamp: u32,
    done: bool,
    cost: u64,
    /// Sum change handed to this triangle by the path reaching it.
    carried: [i64; 2],
    via: u32,
    from: u32,
}

/// Fixed-point cost (micro-units) so the search order is exact and deterministic.
#[inline]
fn cost_units(delta: [i64; 2], m: [f64; 2]) -> u64 {
    let dd = (delta[0] * delta[0] + delta[1] * delta[1]) as f64;
    let c = dd - 2.0 * (delta[0] as f64 * m[0] + delta[1] as f64 * m[1]);
    (c.max(EDGE_COST_FLOOR) * 1e6) as u64
}

/// Cancel position singularities of `off` (steps of the working mesh `tris`) in pairs; paths do not enter
/// triangles with a `blocked` vertex (thin parts, where a row more or less changes the shape). Deterministic:
/// sources are taken in triangle order, ties broken by triangle index. Returns `None` (nothing changed)
/// when `tris` is not an oriented closed 2-manifold over `off`'s edges.
///
/// Cost: O(S · K log K) for S singular triangles and K dual nodes settled per search (≤ [`MAX_SETTLED`]).
pub fn cancel_pairs(
    off: &mut Offsets,
    tris: &[[u32; 3]],
    reach: Reach,
    blocked: Option<&[bool]>,
) -> Option<CancelCounts> {
    let Reach { max_path_cost, into_cones } = reach;
    let mut dual = Dual::new(off, tris)?;
    let mut open = vec![true; tris.len()];
    if let Some(b) = blocked {
        for (t, tri) in tris.iter().enumerate() {
            open[t] = !tri.iter().any(|&v| b[v as usize]);
        }
    }
    let mut counts = CancelCounts { singular_before: dual.singular(), ..Default::default() };
    let max_cost = (max_path_cost * 1e6) as u64;
    // Search state per triangle, valid when `stamp` is the current search.
    let mut nodes = vec![Node::default(); tris.len()];
    let mut search = 0u32;
    // One pass: a second found no further pair on the shared meshes (a singularity without a partner in
    // reach gains none when others are cancelled) and only doubled the time.
    for src in 0..tris.len() {
        if dual.turning[src] || !open[src] || dual.sum[src] == [0, 0] {
            continue;
        }
        // Dijkstra from src carrying the charge to hand on; the first triangle it cancels against wins.
        search += 1;
        let b = dual.sum[src];
        let mut heap = BinaryHeap::new();
        let touch = |t: usize, nodes: &mut [Node], c: u64, carried: [i64; 2], via: u32, from: u32| {
            nodes[t] = Node { stamp: search, done: false, cost: c, carried, via, from };
        };
        touch(src, &mut nodes, 0, neg(b), u32::MAX, u32::MAX);
        heap.push(Reverse((0u64, src as u32)));
        let mut settled = 0usize;
        let mut found = None;
        while let Some(Reverse((c, t))) = heap.pop() {
            let tu = t as usize;
            if nodes[tu].done || nodes[tu].cost != c {
                continue;
            }
            nodes[tu].done = true;
            settled += 1;
            if settled > MAX_SETTLED {
                break;
            }
            let carried = nodes[tu].carried;
            if tu != src && dual.turning[tu] {
                // Only reached `into_cones`: the cone takes the charge (its sum is not a lattice vector).
                found = Some(t);
                break;
            }
            if tu != src {
                // `carried` is the sum change this triangle would take if the path ended here.
                let s = dual.sum[tu];
                let after = [s[0] + carried[0], s[1] + carried[1]];
                if s != [0, 0] && l1(after) < l1(s) {
                    found = Some(t);
                    break;
                }
            }
            // Hand the charge on: this triangle must end unchanged (src: lose its sum).
            let to_cancel = if tu == src { neg(b) } else { neg(carried) };
            for side in dual.sides[tu] {
                let e = side.edge as usize;
                let pair = dual.faces_of_edge[e];
                let next = if pair[0] == t { pair[1] } else { pair[0] } as usize;
                let seen = nodes[next].stamp == search;
                if (dual.turning[next] && !into_cones) || !open[next] || (seen && nodes[next].done) {
                    continue;
                }
                let delta = Dual::step_for(side, to_cancel);
                let nd = [off.d[e][0] + delta[0], off.d[e][1] + delta[1]];
                if nd[0].abs() > 1 || nd[1].abs() > 1 {
                    continue; // a step of two lattice units has no input vertex between: a hole
                }
                let shear = if nd[0] != 0 && nd[1] != 0 { (SHEAR_COST * 1e6) as u64 } else { 0 };
                let c2 = c + cost_units(delta, off.m[e]) + shear;
                if c2 > max_cost || (seen && c2 >= nodes[next].cost) {
                    continue;
                }
                let other = dual.sides[next].iter().copied().find(|s| s.edge == side.edge)?;
                let carried_next = Dual::sum_change(other, delta);
                touch(next, &mut nodes, c2, carried_next, side.edge, t);
                heap.push(Reverse((c2, next as u32)));
            }
        }
        let Some(end) = found else { continue };
        // Apply along the path end → src.
        let carried_end = nodes[end as usize].carried;
        let mut t = end as usize;
        while t != src {
            let Node { via, from, .. } = nodes[t];
            let (e, from) = (via as usize, from as usize);
            let side_from = dual.sides[from].iter().copied().find(|s| s.edge == via)?;
            let to_cancel = if from == src { neg(b) } else { neg(nodes[from].carried) };
            let delta = Dual::step_for(side_from, to_cancel);
            off.d[e] = [off.d[e][0] + delta[0], off.d[e][1] + delta[1]];
            off.m[e] = [off.m[e][0] - delta[0] as f64, off.m[e][1] - delta[1] as f64];
            counts.steps_changed += 1;
            t = from;
        }
        if !dual.turning[end as usize] {
            let s = dual.sum[end as usize];
            dual.sum[end as usize] = [s[0] + carried_end[0], s[1] + carried_end[1]];
        }
        dual.sum[src] = [0, 0];
        counts.pairs_cancelled += 1;
    }
    counts.singular_after = dual.singular();
    debug_assert_eq!(Some(counts.singular_after), Dual::new(off, tris).map(|d| d.singular()));
    Some(counts)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::sampling::Rng;

    /// A flat n×n vertex grid (two triangles per cell, counter-clockwise) glued into a torus, with the
    /// lattice step of every edge taken from integer vertex coordinates `u` (one lattice point per 2×2
    /// vertices, so many steps are 0), each vertex's cross turned by a random gauge `g`.
    fn torus_grid(n: u32, seed: u64) -> (Offsets, Vec<[u32; 3]>) {
        let id = |i: u32, j: u32| (i % n) * n + (j % n);
        let mut tris = Vec::new();
        for i in 0..n {
            for j in 0..n {
                let (a, b, c, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
                tris.push([a, b, c]);
                tris.push([a, c, d]);
            }
        }
        let mut rng = Rng::new(seed);
        let g: Vec<u32> = (0..n * n).map(|_| (rng.next_f64() * 4.0) as u32 % 4).collect();
        // Lattice coordinates (wrapping consistently: n is a multiple of 2).
        let u = |v: u32| [(v / n / 2) as i64, (v % n / 2) as i64];
        let mut edges: Vec<(u32, u32)> = tris
            .iter()
            .flat_map(|t| (0..3).map(move |k| (t[k].min(t[(k + 1) % 3]), t[k].max(t[(k + 1) % 3]))))
            .collect();
        edges.sort_unstable();
        edges.dedup();
        let mut off = Offsets::default();
        let half = (n / 2) as i64;
        for &(i, j) in &edges {
            let (ui, uj) = (u(i), u(j));
            // Shortest step on the torus of n/2 × n/2 lattice points.
            let w = |x: i64| {
                if x > half / 2 {
                    x - half
                } else if x < -half / 2 {
                    x + half
                } else {
                    x
                }
            };
            let world = [w(uj[0] - ui[0]), w(uj[1] - ui[1])];
            // In i's turned frame; j's cross turned by r matches i's.
            let (gi, gj) = (g[i as usize], g[j as usize]);
            off.edges.push((i, j));
            off.d.push(rotc(world, (4 - gi) % 4));
            off.r.push(((gi + 4 - gj) % 4) as u8);
            off.m.push([0.0, 0.0]);
        }
        (off, tris)
    }

    #[test]
    fn a_planted_dislocation_pair_is_cancelled_through_any_frame_gauge() {
        for seed in 0..20 {
            let (mut off, tris) = torus_grid(24, seed);
            let dual = Dual::new(&off, &tris).expect("closed grid");
            assert_eq!(dual.singular(), 0, "seed {seed}: the consistent grid has no singularity");
            assert!(dual.turning.iter().all(|t| !t), "seed {seed}: a consistent gauge does not turn");
            // Change one interior step by a unit: its two triangles become a ± pair.
            let e = off.edges.len() / 2;
            let was = off.d[e];
            off.d[e] = [was[0] + 1, was[1]];
            off.m[e] = [-1.0, 0.0];
            assert_eq!(Dual::new(&off, &tris).unwrap().singular(), 2, "seed {seed}: planted pair");
            let c = cancel_pairs(&mut off, &tris, TRIES[0], None).expect("manifold");
            assert_eq!((c.singular_before, c.singular_after), (2, 0), "seed {seed}: {c:?}");
            assert_eq!((c.pairs_cancelled, c.steps_changed), (1, 1), "seed {seed}: {c:?}");
            assert_eq!(off.d[e], was, "seed {seed}: the cheapest fix restores the planted step");
        }
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(48))]
        /// Random unit changes on random edges, random residuals, random gauges: the cancellation never adds a
        /// singularity, its count is what the steps say, no edge gets a step of two units, and it is
        /// deterministic.
        #[test]
        fn cancellation_only_removes_singularities(
            seed in 0u64..10_000,
            changes in 1usize..12,
            cost in 1.0f64..80.0,
            into_cones in proptest::bool::ANY,
            cones in 0usize..3,
        ) {
            let (mut off, tris) = torus_grid(16, seed);
            let mut rng = Rng::new(seed ^ 0x5eed);
            for m in &mut off.m {
                *m = [rng.next_f64() - 0.5, rng.next_f64() - 0.5];
            }
            for _ in 0..changes {
                let e = (rng.next_f64() * off.edges.len() as f64) as usize % off.edges.len();
                let k = (rng.next_f64() * 4.0) as u32;
                let u = rotc([1, 0], k);
                let nd = [off.d[e][0] + u[0], off.d[e][1] + u[1]];
                if nd[0].abs() <= 1 && nd[1].abs() <= 1 {
                    off.d[e] = nd;
                }
            }
            // Cone pairs: an edge's frame turn changed.
            for _ in 0..cones {
                let e = (rng.next_f64() * off.edges.len() as f64) as usize % off.edges.len();
                off.r[e] = (off.r[e] + 1) % 4;
            }
            let before = off.d.clone();
            let mut again = off.clone();
            let reach = Reach { max_path_cost: cost, into_cones };
            let c = cancel_pairs(&mut off, &tris, reach, None).expect("manifold");
            let c2 = cancel_pairs(&mut again, &tris, reach, None).expect("manifold");
            proptest::prop_assert_eq!(&off.d, &again.d, "not deterministic");
            proptest::prop_assert_eq!(c.pairs_cancelled, c2.pairs_cancelled);
            proptest::prop_assert!(c.singular_after <= c.singular_before, "{:?}", c);
            proptest::prop_assert_eq!(c.singular_after, Dual::new(&off, &tris).unwrap().singular(), "{:?}", c);
            // Each path zeroes its source and lowers its target.
            proptest::prop_assert!(c.singular_before - c.singular_after >= c.pairs_cancelled, "{:?}", c);
            for (d, b) in off.d.iter().zip(&before) {
                if d != b {
                    proptest::prop_assert!(d[0].abs() <= 1 && d[1].abs() <= 1, "a two-unit step {:?}", d);
                }
            }
        }
    }

    /// Analytic oracle for ending in cones: one edge's frame turn is changed, so its two triangles turn
    /// (a cone pair); one unit more on another edge of one of them leaves a single dislocation next to it,
    /// with no partner anywhere. Only a path that may end in a cone removes it, in one step; the counts
    /// match the recomputed sums either way.
    #[test]
    fn a_dislocation_beside_a_cone_is_absorbed_only_into_cones() {
        for seed in 0..8 {
            let (mut off, tris) = torus_grid(16, seed);
            let t = &tris[100];
            let e0 = off.index(t[0], t[1]).unwrap();
            let e1 = off.index(t[1], t[2]).unwrap();
            off.r[e0] = (off.r[e0] + 1) % 4;
            off.d[e1][0] += if off.d[e1][0] > 0 { -1 } else { 1 };
            let dual = Dual::new(&off, &tris).unwrap();
            assert_eq!(dual.turning.iter().filter(|&&x| x).count(), 2, "seed {seed}: one cone pair");
            assert_eq!(dual.singular(), 1, "seed {seed}: one dislocation");
            let mut kept = off.clone();
            let plain = Reach { max_path_cost: 60.0, into_cones: false };
            let c = cancel_pairs(&mut kept, &tris, plain, None).unwrap();
            assert_eq!((c.singular_after, c.pairs_cancelled), (1, 0), "seed {seed}: {c:?}");
            assert_eq!(kept.d, off.d, "seed {seed}: nothing to pair with, nothing changed");
            let c = cancel_pairs(&mut off, &tris, Reach { into_cones: true, ..plain }, None).unwrap();
            assert_eq!((c.singular_after, c.pairs_cancelled, c.steps_changed), (0, 1, 1), "seed {seed}: {c:?}");
            assert_eq!(Dual::new(&off, &tris).unwrap().singular(), 0, "seed {seed}: recomputed");
        }
    }

    #[test]
    fn a_lone_pair_beyond_the_path_cost_is_left_alone() {
        let (mut off, tris) = torus_grid(24, 7);
        let e = off.edges.len() / 2;
        off.d[e][0] += 1;
        // The planted step now agrees with the continuous offset: undoing it costs 1 + 2 = 3 > 2.5.
        off.m[e] = [1.0, 0.0];
        let c = cancel_pairs(&mut off, &tris, Reach { max_path_cost: 2.5, into_cones: false }, None).expect("manifold");
        assert_eq!((c.singular_before, c.singular_after, c.pairs_cancelled), (2, 2, 0), "{c:?}");
    }
}

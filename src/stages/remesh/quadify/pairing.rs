//! Pairing triangles into quads: along straight strips ([`pair_triangles`]) and bent paths
//! ([`pair_triangles_along_paths`]), and merging doublets ([`remove_doublets`]).

use std::collections::HashMap;

use super::CleanupCounts;
use crate::geometry::vec3::{self, V3, sub};

/// A straight strip between two triangles: apexes, the two side chains and the faces it covers.
struct Strip {
    a: u32,
    b: u32,
    x: Vec<u32>,
    y: Vec<u32>,
    faces: Vec<u32>,
}

/// The new quads of a strip with the rungs shifted to (x[i+1], y[i]) (see [`pair_triangles`]).
fn strip_quads(a: u32, b: u32, x: &[u32], y: &[u32]) -> Vec<Vec<u32>> {
    let k = x.len() - 1;
    (0..=k)
        .map(|i| {
            let mut q = if i == 0 { vec![a, x[0]] } else { vec![y[i - 1], x[i]] };
            if i == k {
                q.extend([b, y[k]]);
            } else {
                q.extend([x[i + 1], y[i]]);
            }
            q
        })
        .collect()
}

/// Pair triangles along straight quad strips of at most `max_len` quads and re-diagonalise each strip, so
/// that the two triangles and the k quads between them become k + 1 quads. Euler characteristic and all
/// other faces are unchanged; two vertices at the strip's ends lose one edge each (the variant whose ends
/// have the higher valence is chosen, and no vertex drops below valence 3). Returns the triangles left.
pub(crate) fn pair_triangles(
    faces: &mut Vec<Vec<u32>>,
    max_len: usize,
    rounds: usize,
    counts: &mut CleanupCounts,
) -> usize {
    for _ in 0..rounds {
        let mut half: HashMap<(u32, u32), u32> = HashMap::with_capacity(faces.len() * 4);
        let mut valence: HashMap<u32, u32> = HashMap::new();
        for (fi, f) in faces.iter().enumerate() {
            for k in 0..f.len() {
                let (a, b) = (f[k], f[(k + 1) % f.len()]);
                half.insert((a, b), fi as u32);
                if a < b {
                    *valence.entry(a).or_insert(0) += 1;
                    *valence.entry(b).or_insert(0) += 1;
                }
            }
        }
        let tris: Vec<u32> = (0..faces.len() as u32).filter(|&f| faces[f as usize].len() == 3).collect();
        if tris.is_empty() {
            return 0;
        }
        // Candidate strips from every triangle in all three directions.
        let mut cands: Vec<Strip> = Vec::new();
        for &t in &tris {
            let f = &faces[t as usize];
            for k in 0..3 {
                let (mut xv, mut yv) = (f[k], f[(k + 1) % 3]);
                let a = f[(k + 2) % 3];
                let mut strip = Strip { a, b: u32::MAX, x: vec![xv], y: vec![yv], faces: vec![t] };
                for _ in 0..=max_len {
                    let Some(&g) = half.get(&(yv, xv)) else { break };
                    if strip.faces.contains(&g) {
                        break;
                    }
                    let gf = &faces[g as usize];
                    let j = gf.iter().position(|&v| v == yv).expect("half-edge face has the vertex");
                    strip.faces.push(g);
                    if gf.len() == 3 {
                        strip.b = gf[(j + 2) % 3];
                        break;
                    }
                    if gf.len() != 4 {
                        break;
                    }
                    let (nx, ny) = (gf[(j + 2) % 4], gf[(j + 3) % 4]);
                    strip.x.push(nx);
                    strip.y.push(ny);
                    xv = nx;
                    yv = ny;
                }
                if strip.b != u32::MAX && strip.faces.last() > Some(&t) {
                    cands.push(strip);
                }
            }
        }
        cands.sort_by_key(|s| (s.faces.len(), s.faces[0], s.faces[s.faces.len() - 1]));
        let mut used = vec![false; faces.len()];
        let mut new_edges: std::collections::HashSet<(u32, u32)> = std::collections::HashSet::new();
        let mut replaced: Vec<(Vec<u32>, Vec<Vec<u32>>)> = Vec::new();
        for s in cands {
            if s.faces.iter().any(|&f| used[f as usize]) {
                continue;
            }
            // All strip vertices distinct.
            let mut vs: Vec<u32> = s.x.iter().chain(&s.y).copied().chain([s.a, s.b]).collect();
            vs.sort_unstable();
            if vs.windows(2).any(|w| w[0] == w[1]) {
                continue;
            }
            let val = |v: u32| *valence.get(&v).unwrap_or(&0) as i64;
            let k = s.x.len() - 1;
            // Variant A: x[0] and y[k] lose an edge; variant B: y[0] and x[k].
            let gain = |u: u32, w: u32| -> Option<i64> {
                let (vu, vw) = (val(u), val(w));
                if vu <= 3 || vw <= 3 {
                    return None;
                }
                Some(((vu - 4).abs() - (vu - 5).abs()) + ((vw - 4).abs() - (vw - 5).abs()))
            };
            let ga = gain(s.x[0], s.y[k]);
            let gb = gain(s.y[0], s.x[k]);
            let use_b = match (ga, gb) {
                (None, None) => continue,
                (Some(a), Some(b)) => b > a,
                (Some(_), None) => false,
                (None, Some(_)) => true,
            };
            let quads = if use_b { variant_b(&s) } else { strip_quads(s.a, s.b, &s.x, &s.y) };
            // The new diagonals must not exist yet.
            let mut ok = true;
            let mut diag = Vec::new();
            for q in &quads {
                for i in 0..4 {
                    let (u, w) = (q[i], q[(i + 1) % 4]);
                    if !half.contains_key(&(u, w)) && !half.contains_key(&(w, u)) {
                        let e = (u.min(w), u.max(w));
                        if new_edges.contains(&e) {
                            ok = false;
                        }
                        diag.push(e);
                    }
                }
            }
            if !ok {
                continue;
            }
            new_edges.extend(diag);
            for &f in &s.faces {
                used[f as usize] = true;
            }
            counts.triangle_pairs_merged += 1;
            counts.strip_quads_rediagonalised += s.faces.len() - 2;
            replaced.push((s.faces.clone(), quads));
            // Valences change at the ends; refresh them for later candidates of this round.
            let ends = if use_b { [s.y[0], s.x[k]] } else { [s.x[0], s.y[k]] };
            for v in ends {
                *valence.get_mut(&v).expect("strip vertex has edges") -= 1;
            }
        }
        if replaced.is_empty() {
            break;
        }
        let mut out: Vec<Vec<u32>> = faces.iter().zip(&used).filter(|(_, u)| !**u).map(|(f, _)| f.clone()).collect();
        for (_, quads) in replaced {
            out.extend(quads);
        }
        *faces = out;
    }
    faces.iter().filter(|f| f.len() == 3).count()
}

fn variant_b(s: &Strip) -> Vec<Vec<u32>> {
    strip_quads(s.a, s.b, &s.y, &s.x)
        .into_iter()
        .map(|mut q| {
            q.reverse();
            q
        })
        .collect()
}

/// Remove valence-2 vertices shared by exactly two faces ("doublets"): the two faces merge into one.
/// Returns how many were removed.
pub(crate) fn remove_doublets(faces: &mut Vec<Vec<u32>>) -> usize {
    let mut removed = 0;
    loop {
        let mut vf: HashMap<u32, Vec<u32>> = HashMap::new();
        let mut nb: HashMap<u32, std::collections::BTreeSet<u32>> = HashMap::new();
        for (fi, f) in faces.iter().enumerate() {
            for k in 0..f.len() {
                vf.entry(f[k]).or_default().push(fi as u32);
                let (a, b) = (f[k], f[(k + 1) % f.len()]);
                nb.entry(a).or_default().insert(b);
                nb.entry(b).or_default().insert(a);
            }
        }
        let mut doublets: Vec<u32> = nb.iter().filter(|(_, s)| s.len() == 2).map(|(&v, _)| v).collect();
        doublets.sort_unstable();
        let mut used = vec![false; faces.len()];
        let mut merged = Vec::new();
        for v in doublets {
            let fs = &vf[&v];
            if fs.len() != 2 || used[fs[0] as usize] || used[fs[1] as usize] {
                continue;
            }
            let rot = |f: &Vec<u32>| -> Vec<u32> {
                let i = f.iter().position(|&x| x == v).expect("face has v");
                f[i..].iter().chain(&f[..i]).copied().collect()
            };
            let (f1, f2) = (rot(&faces[fs[0] as usize]), rot(&faces[fs[1] as usize]));
            // f1 = (v, b, …, a), f2 = (v, a, …, b).
            if f1[1] != *f2.last().expect("≥3") || f2[1] != *f1.last().expect("≥3") {
                continue;
            }
            let mut m: Vec<u32> = f1[1..].to_vec();
            m.extend_from_slice(&f2[2..f2.len() - 1]);
            let mut distinct = m.clone();
            distinct.sort_unstable();
            distinct.dedup();
            if m.len() < 3 || distinct.len() != m.len() {
                continue; // the merged face would visit a vertex twice
            }
            used[fs[0] as usize] = true;
            used[fs[1] as usize] = true;
            merged.push(m);
            removed += 1;
        }
        if merged.is_empty() {
            return removed;
        }
        let mut out: Vec<Vec<u32>> = faces.iter().zip(&used).filter(|(_, u)| !**u).map(|(f, _)| f.clone()).collect();
        out.extend(merged);
        *faces = out;
    }
}

/// Pair the triangles left after [`pair_triangles`] along bent paths: a triangle walks toward the nearest
/// other triangle (breadth-first over quads, at most `max_len` steps) by re-splitting, at each step, the
/// pentagon it forms with the next quad so that the triangle ends up on that quad's far side; when the two
/// triangles meet they merge into a quad. Every step keeps a closed, oriented polygon mesh with the same
/// Euler characteristic. Returns the triangles left.
pub(crate) fn pair_triangles_along_paths(
    p: &[V3],
    faces: &mut Vec<Vec<u32>>,
    max_len: usize,
    counts: &mut CleanupCounts,
) -> usize {
    let mut half: HashMap<(u32, u32), usize> = HashMap::with_capacity(faces.len() * 4);
    for (fi, f) in faces.iter().enumerate() {
        for k in 0..f.len() {
            half.insert((f[k], f[(k + 1) % f.len()]), fi);
        }
    }
    let set = |half: &mut HashMap<(u32, u32), usize>, faces: &mut Vec<Vec<u32>>, fi: usize, new: Vec<u32>| {
        let old = std::mem::take(&mut faces[fi]);
        for k in 0..old.len() {
            let e = (old[k], old[(k + 1) % old.len()]);
            if half.get(&e) == Some(&fi) {
                half.remove(&e);
            }
        }
        for k in 0..new.len() {
            half.insert((new[k], new[(k + 1) % new.len()]), fi);
        }
        faces[fi] = new;
    };
    let has_edge =
        |half: &HashMap<(u32, u32), usize>, a: u32, b: u32| half.contains_key(&(a, b)) || half.contains_key(&(b, a));
    let mut tris: Vec<usize> = (0..faces.len()).filter(|&f| faces[f].len() == 3).collect();
    tris.sort_unstable();
    for t0 in tris {
        if faces[t0].len() != 3 {
            continue;
        }
        // Breadth-first search over quads to the nearest other triangle.
        let mut prev: HashMap<usize, usize> = HashMap::new();
        prev.insert(t0, usize::MAX);
        let mut frontier = vec![t0];
        let mut goal = None;
        'bfs: for _ in 0..=max_len {
            let mut next = Vec::new();
            for &f in &frontier {
                let face = &faces[f];
                for k in 0..face.len() {
                    let Some(&g) = half.get(&(face[(k + 1) % face.len()], face[k])) else { continue };
                    if prev.contains_key(&g) {
                        continue;
                    }
                    prev.insert(g, f);
                    if faces[g].len() == 3 {
                        goal = Some(g);
                        break 'bfs;
                    }
                    if faces[g].len() == 4 {
                        next.push(g);
                    }
                }
            }
            if next.is_empty() {
                break;
            }
            frontier = next;
        }
        let Some(goal) = goal else { continue };
        let mut path = vec![goal];
        while let Some(&f) = prev.get(path.last().expect("non-empty")) {
            if f == usize::MAX {
                break;
            }
            path.push(f);
        }
        path.reverse(); // t0, quads…, goal
        // Walk the triangle along the path.
        let mut tri = t0;
        let mut ok = true;
        for w in 1..path.len() - 1 {
            let (q, next) = (path[w], path[w + 1]);
            let t = faces[tri].clone();
            let qf = faces[q].clone();
            // Shared edge: a→b in the triangle, b→a in the quad.
            let Some(k) = (0..3).find(|&k| half.get(&(t[(k + 1) % 3], t[k])) == Some(&q)) else {
                ok = false;
                break;
            };
            let (a, b, c) = (t[k], t[(k + 1) % 3], t[(k + 2) % 3]);
            let j = qf.iter().position(|&v| v == b).expect("quad has b");
            let (x, y) = (qf[(j + 2) % 4], qf[(j + 3) % 4]);
            let pent = [b, c, a, x, y];
            // The edge of the pentagon shared with the next face.
            let Some(i) = (0..5).find(|&i| half.get(&(pent[(i + 1) % 5], pent[i])) == Some(&next)) else {
                ok = false;
                break;
            };
            let opt = |s: usize| -> (Vec<u32>, Vec<u32>, (u32, u32)) {
                // Triangle (pent[s], pent[s+1], pent[s+2]); quad = the other four, diagonal pent[s]–pent[s+2].
                let tr = vec![pent[s % 5], pent[(s + 1) % 5], pent[(s + 2) % 5]];
                let qd = vec![pent[(s + 2) % 5], pent[(s + 3) % 5], pent[(s + 4) % 5], pent[s % 5]];
                (tr, qd, (pent[s % 5], pent[(s + 2) % 5]))
            };
            let mut choices: Vec<(f64, Vec<u32>, Vec<u32>)> = Vec::new();
            for s in [i, (i + 4) % 5] {
                let (tr, qd, (u, v)) = opt(s);
                if has_edge(&half, u, v) {
                    continue;
                }
                choices.push((vec3::norm2(sub(p[u as usize], p[v as usize])), tr, qd));
            }
            choices.sort_by(|l, r| l.0.total_cmp(&r.0));
            let Some((_, tr, qd)) = choices.into_iter().next() else {
                ok = false;
                break;
            };
            set(&mut half, faces, tri, qd);
            set(&mut half, faces, q, tr);
            tri = q;
            counts.path_steps += 1;
        }
        if !ok {
            continue;
        }
        // Merge the two adjacent triangles into a quad.
        let (t, g) = (faces[tri].clone(), faces[goal].clone());
        let Some(k) = (0..3).find(|&k| half.get(&(t[(k + 1) % 3], t[k])) == Some(&goal)) else { continue };
        let (u, v, w) = (t[k], t[(k + 1) % 3], t[(k + 2) % 3]);
        let Some(&xo) = g.iter().find(|&&z| z != u && z != v) else { continue };
        if xo == w {
            continue;
        }
        set(&mut half, faces, goal, Vec::new());
        set(&mut half, faces, tri, vec![u, xo, v, w]);
        counts.triangle_pairs_merged += 1;
        counts.path_pairs += 1;
    }
    faces.retain(|f| !f.is_empty());
    faces.iter().filter(|f| f.len() == 3).count()
}

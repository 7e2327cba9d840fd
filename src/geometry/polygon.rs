//! Helpers on polygon meshes given as positions and index lists (`Vec<u32>` faces, or `[u32; 3]` triangles):
//! edges, adjacency, the Euler characteristic and manifold check, normals and centres, compaction and the
//! regular split of n-gons into quads. Shared by the stages that build or clean meshes (repair, remesh) and by
//! the decimation.

use std::collections::HashMap;

use crate::geometry::vec3::{self, V3, add, cross, scale};

#[inline]
/// The undirected edge (a, b) as a key: the smaller index first.
pub fn key(a: u32, b: u32) -> (u32, u32) {
    (a.min(b), a.max(b))
}

/// The undirected edges of a polygon mesh, as [`key`]s.
pub fn edge_set(faces: &[Vec<u32>]) -> std::collections::HashSet<(u32, u32)> {
    unique_edges(faces.iter().map(Vec::as_slice)).into_iter().collect()
}

/// Euler characteristic V − E + F of a polygon mesh over its referenced vertices, and whether every
/// directed edge occurs once with its twin once (closed, edge-manifold, consistently oriented).
pub fn polygon_check(faces: &[Vec<u32>]) -> (i64, bool) {
    let mut half: Vec<(u32, u32)> =
        faces.iter().flat_map(|f| (0..f.len()).map(move |k| (f[k], f[(k + 1) % f.len()]))).collect();
    half.sort_unstable();
    let dup = half.windows(2).any(|w| w[0] == w[1]);
    let twins = half.iter().all(|&(a, b)| half.binary_search(&(b, a)).is_ok());
    let mut vs: Vec<u32> = faces.iter().flatten().copied().collect();
    vs.sort_unstable();
    vs.dedup();
    (vs.len() as i64 - (half.len() / 2) as i64 + faces.len() as i64, !dup && twins)
}

/// Keep only the vertices some face uses (in first-use order), renumbering the faces; works for triangles
/// (`[u32; 3]`) and polygons (`Vec<u32>`) alike.
pub fn compact<F: AsMut<[u32]>>(p: &[V3], faces: &mut [F]) -> Vec<V3> {
    let mut map = vec![u32::MAX; p.len()];
    let mut out = Vec::with_capacity(p.len());
    for f in faces.iter_mut() {
        for v in f.as_mut() {
            if map[*v as usize] == u32::MAX {
                map[*v as usize] = out.len() as u32;
                out.push(p[*v as usize]);
            }
            *v = map[*v as usize];
        }
    }
    out
}

/// The undirected edges (a < b) of a polygon mesh, sorted, each once.
pub fn unique_edges<'a>(faces: impl IntoIterator<Item = &'a [u32]>) -> Vec<(u32, u32)> {
    let mut edges: Vec<(u32, u32)> =
        faces.into_iter().flat_map(|f| (0..f.len()).map(move |k| key(f[k], f[(k + 1) % f.len()]))).collect();
    edges.sort_unstable();
    edges.dedup();
    edges
}

/// Number of vertices after [`split_to_quads`]: V + E + F.
pub fn split_vertex_count(nv: usize, faces: &[Vec<u32>]) -> usize {
    let corners: usize = faces.iter().map(Vec::len).sum();
    nv + corners / 2 + faces.len()
}

/// Split every n-gon into n quads around its centre. Returns positions and quads.
pub fn split_to_quads(p: &[V3], faces: &[Vec<u32>]) -> (Vec<V3>, Vec<Vec<u32>>) {
    let mut pos = p.to_vec();
    let mut mid: HashMap<(u32, u32), u32> = HashMap::new();
    let mut quads = Vec::with_capacity(faces.iter().map(Vec::len).sum());
    for f in faces {
        let n = f.len();
        let mut ms = Vec::with_capacity(n);
        for k in 0..n {
            let (a, b) = (f[k], f[(k + 1) % n]);
            let key = (a.min(b), a.max(b));
            let id = *mid.entry(key).or_insert_with(|| {
                pos.push(scale(add(p[a as usize], p[b as usize]), 0.5));
                (pos.len() - 1) as u32
            });
            ms.push(id);
        }
        let mut c = [0.0; 3];
        for &v in f {
            c = add(c, p[v as usize]);
        }
        pos.push(scale(c, 1.0 / n as f64));
        let cid = (pos.len() - 1) as u32;
        for k in 0..n {
            quads.push(vec![f[k], ms[k], cid, ms[(k + n - 1) % n]]);
        }
    }
    (pos, quads)
}

/// Unit vertex normals of a polygon mesh (sums of the faces' Newell normals).
pub fn vertex_normals(p: &[V3], faces: &[Vec<u32>]) -> Vec<V3> {
    let mut nrm = vec![[0.0; 3]; p.len()];
    for f in faces {
        let c = polygon_normal(p, f);
        for &v in f {
            nrm[v as usize] = add(nrm[v as usize], c);
        }
    }
    for v in &mut nrm {
        let l = vec3::norm(*v);
        if l > 0.0 {
            *v = scale(*v, 1.0 / l);
        }
    }
    nrm
}

/// Twice the vector area of a polygon (Newell).
#[inline]
pub fn polygon_normal(p: &[V3], f: &[u32]) -> V3 {
    let mut n = [0.0; 3];
    for k in 0..f.len() {
        n = add(n, cross(p[f[k] as usize], p[f[(k + 1) % f.len()] as usize]));
    }
    n
}

/// Vertex adjacency (edge neighbours) of a polygon mesh as CSR.
pub fn adjacency(nv: usize, faces: &[Vec<u32>]) -> (Vec<u32>, Vec<u32>) {
    let mut pairs: Vec<(u32, u32)> = Vec::with_capacity(faces.len() * 8);
    for f in faces {
        for k in 0..f.len() {
            let (a, b) = (f[k], f[(k + 1) % f.len()]);
            pairs.push((a, b));
            pairs.push((b, a));
        }
    }
    pairs.sort_unstable();
    pairs.dedup();
    csr(nv, &pairs)
}

/// Sorted, distinct neighbours of every vertex of a polygon mesh.
pub fn neighbour_lists(nv: usize, faces: &[Vec<u32>]) -> Vec<Vec<u32>> {
    let mut nbrs: Vec<Vec<u32>> = vec![Vec::new(); nv];
    for f in faces {
        for k in 0..f.len() {
            let (a, b) = (f[k], f[(k + 1) % f.len()]);
            nbrs[a as usize].push(b);
            nbrs[b as usize].push(a);
        }
    }
    for n in &mut nbrs {
        n.sort_unstable();
        n.dedup();
    }
    nbrs
}

/// Mean of face `f`'s corners.
pub fn polygon_centre(p: &[V3], f: &[u32]) -> V3 {
    let mut c = [0.0; 3];
    for &v in f {
        c = add(c, p[v as usize]);
    }
    scale(c, 1.0 / f.len() as f64)
}

/// Drop unreferenced vertices, keeping the order of the rest. Returns (positions, faces, dropped count).
pub fn drop_unreferenced(positions: &[V3], triangles: &[[u32; 3]]) -> (Vec<V3>, Vec<[u32; 3]>, usize) {
    let mut new_id = vec![u32::MAX; positions.len()];
    for t in triangles {
        for &i in t {
            new_id[i as usize] = 0;
        }
    }
    let mut pos = Vec::with_capacity(positions.len());
    for (i, id) in new_id.iter_mut().enumerate() {
        if *id == 0 {
            *id = pos.len() as u32;
            pos.push(positions[i]);
        }
    }
    let tris = triangles.iter().map(|t| t.map(|i| new_id[i as usize])).collect();
    let dropped = positions.len() - pos.len();
    (pos, tris, dropped)
}

/// CSR form of sorted (source, target) pairs over `n` sources: offsets (`n + 1`) and targets.
pub fn csr(n: usize, sorted_pairs: &[(u32, u32)]) -> (Vec<u32>, Vec<u32>) {
    let mut off = vec![0u32; n + 1];
    for &(a, _) in sorted_pairs {
        off[a as usize + 1] += 1;
    }
    for i in 0..n {
        off[i + 1] += off[i];
    }
    (off, sorted_pairs.iter().map(|&(_, b)| b).collect())
}

/// Split the edges of a triangle mesh longer than `max_len` at their midpoints until none is (the surface is
/// unchanged), as Instant Meshes prepares its input: a position field needs at least two edges per lattice
/// step. Each pass splits every long edge once, in both of its triangles (one long edge: two triangles; two:
/// three, the quad cut along its shorter diagonal; three: four), so the mesh stays conforming. At most
/// `max_passes` passes, and none once the mesh holds `max_vertices`. Returns the vertices added.
///
/// Cost: O(F) per pass; deterministic (new vertices are numbered in triangle order).
pub fn split_long_edges(
    p: &mut Vec<V3>,
    tris: &mut Vec<[u32; 3]>,
    max_len: f64,
    max_passes: usize,
    max_vertices: usize,
) -> usize {
    let start = p.len();
    let long = |p: &[V3], a: u32, b: u32| vec3::norm2(vec3::sub(p[a as usize], p[b as usize])) > max_len * max_len;
    for _ in 0..max_passes {
        if p.len() >= max_vertices || !(max_len > 0.0) {
            break;
        }
        let mut mid: HashMap<(u32, u32), u32> = HashMap::new();
        let mut out = Vec::with_capacity(tris.len() * 2);
        for &t in tris.iter() {
            let marked = [0, 1, 2].map(|k| long(p, t[k], t[(k + 1) % 3]));
            let count = marked.iter().filter(|&&m| m).count();
            if count == 0 {
                out.push(t);
                continue;
            }
            let mut m = [u32::MAX; 3];
            for k in 0..3 {
                if marked[k] {
                    let (a, b) = (t[k], t[(k + 1) % 3]);
                    m[k] = *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                        p.push(vec3::scale(vec3::add(p[a as usize], p[b as usize]), 0.5));
                        (p.len() - 1) as u32
                    });
                }
            }
            match count {
                1 => {
                    let k = (0..3).find(|&k| marked[k]).unwrap_or(0);
                    let (a, b, c) = (t[k], t[(k + 1) % 3], t[(k + 2) % 3]);
                    out.push([a, m[k], c]);
                    out.push([m[k], b, c]);
                }
                2 => {
                    // Edges k (a→b) and k+1 (b→c) are long, c→a is not.
                    let k = (0..3).find(|&k| marked[k] && marked[(k + 1) % 3]).unwrap_or(0);
                    let (a, b, c) = (t[k], t[(k + 1) % 3], t[(k + 2) % 3]);
                    let (m1, m2) = (m[k], m[(k + 1) % 3]);
                    out.push([m1, b, m2]);
                    let d = |x: u32, y: u32| vec3::norm2(vec3::sub(p[x as usize], p[y as usize]));
                    if d(a, m2) <= d(m1, c) {
                        out.push([a, m1, m2]);
                        out.push([a, m2, c]);
                    } else {
                        out.push([a, m1, c]);
                        out.push([m1, m2, c]);
                    }
                }
                _ => {
                    out.push([t[0], m[0], m[2]]);
                    out.push([t[1], m[1], m[0]]);
                    out.push([t[2], m[2], m[1]]);
                    out.push(m);
                }
            }
        }
        let split = !mid.is_empty();
        *tris = out;
        if !split {
            break;
        }
    }
    p.len() - start
}

/// Split every triangle into four at its edge midpoints (the surface is unchanged).
pub fn subdivide_midpoints(p: &mut Vec<V3>, tris: &mut Vec<[u32; 3]>) {
    let mut mid: HashMap<(u32, u32), u32> = HashMap::with_capacity(tris.len() * 3 / 2);
    let mut out = Vec::with_capacity(tris.len() * 4);
    for &t in tris.iter() {
        let mut m = [0u32; 3];
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            m[k] = *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                p.push(vec3::scale(vec3::add(p[a as usize], p[b as usize]), 0.5));
                (p.len() - 1) as u32
            });
        }
        out.push([t[0], m[0], m[2]]);
        out.push([t[1], m[1], m[0]]);
        out.push([t[2], m[2], m[1]]);
        out.push(m);
    }
    *tris = out;
}

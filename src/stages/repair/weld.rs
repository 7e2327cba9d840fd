//! Step 1: weld coincident vertices, drop faces that collapse or repeat, drop unreferenced vertices.

use std::collections::HashMap;

use crate::geometry::vec3::{self, V3};

/// What welding changed.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct WeldReport {
    /// Vertices merged into another vertex within the tolerance.
    pub merged_vertices: usize,
    /// Faces dropped because two of their corners became the same vertex.
    pub collapsed_faces: usize,
    /// Faces dropped because another face has the same three vertices.
    pub duplicate_faces: usize,
    /// Vertices used by no face, dropped.
    pub unreferenced_vertices: usize,
    /// The tolerance used (input units).
    pub tolerance: f64,
}

/// Merge vertices closer than `tol` (grid hashing, first vertex of a cluster wins, deterministic), remap
/// faces, drop collapsed and duplicate faces and unreferenced vertices. Cost: O(V + F) expected.
pub fn weld(positions: &[V3], triangles: &[[u32; 3]], tol: f64) -> (Vec<V3>, Vec<[u32; 3]>, WeldReport) {
    let (pos, tris, report, _) = weld_kept(positions, triangles, tol);
    (pos, tris, report)
}

/// [`weld`], with the index in `triangles` of every triangle kept (in order: the output's triangle k is the
/// input's `kept[k]`, remapped).
pub fn weld_kept(positions: &[V3], triangles: &[[u32; 3]], tol: f64) -> (Vec<V3>, Vec<[u32; 3]>, WeldReport, Vec<u32>) {
    let mut report = WeldReport { tolerance: tol, ..Default::default() };
    let cell = if tol > 0.0 { tol } else { 1.0 };
    let key = |p: V3| p.map(|c| (c / cell).floor() as i64);
    let mut grid: HashMap<[i64; 3], Vec<u32>> = HashMap::with_capacity(positions.len());
    let mut reps: Vec<V3> = Vec::with_capacity(positions.len());
    let mut map = Vec::with_capacity(positions.len());
    for &p in positions {
        let k = key(p);
        let mut found = None;
        'search: for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    if let Some(ids) = grid.get(&[k[0] + dx, k[1] + dy, k[2] + dz]) {
                        for &id in ids {
                            let q = reps[id as usize];
                            let d2 = vec3::norm2(vec3::sub(p, q));
                            if d2 <= tol * tol {
                                found = Some(id);
                                break 'search;
                            }
                        }
                    }
                }
            }
        }
        let id = found.unwrap_or_else(|| {
            reps.push(p);
            let id = (reps.len() - 1) as u32;
            grid.entry(k).or_default().push(id);
            id
        });
        if found.is_some() {
            report.merged_vertices += 1;
        }
        map.push(id);
    }
    let mut seen: HashMap<[u32; 3], ()> = HashMap::with_capacity(triangles.len());
    let mut out = Vec::with_capacity(triangles.len());
    let mut kept = Vec::with_capacity(triangles.len());
    for (k, t) in triangles.iter().enumerate() {
        let f = t.map(|i| map[i as usize]);
        if f[0] == f[1] || f[1] == f[2] || f[0] == f[2] {
            report.collapsed_faces += 1;
            continue;
        }
        let mut s = f;
        s.sort_unstable();
        if seen.insert(s, ()).is_some() {
            report.duplicate_faces += 1;
            continue;
        }
        out.push(f);
        kept.push(k as u32);
    }
    let (pos, tris, dropped) = crate::geometry::polygon::drop_unreferenced(&reps, &out);
    report.unreferenced_vertices = dropped;
    (pos, tris, report, kept)
}

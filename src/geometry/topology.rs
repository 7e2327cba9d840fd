//! Edge adjacency (a half-edge table that tolerates non-manifold input) and the topology report of
//! `scanstation inspect`.
//!
//! Half-edge `h` is face corner `h` of a [`PolyMesh`]: it starts at the corner's vertex and runs to the next
//! corner of the same face. Half-edges are grouped into undirected edges by sorting their vertex pairs, so any
//! number of faces may share an edge (non-manifold scans are common); on manifold edges the two half-edges are
//! each other's opposite. Building the table costs O(H log H) time for H half-edges and 24·H bytes.

use std::collections::BTreeMap;

use crate::geometry::mesh::PolyMesh;
use crate::geometry::tolerance::DEGENERATE_AREA_REL;
use crate::geometry::vec3::{self, Aabb, wide};

/// Union–find over `u32` ids with path halving and union by index (deterministic).
#[derive(Clone, Debug)]
pub struct UnionFind {
    parent: Vec<u32>,
}

impl UnionFind {
    /// `n` singleton sets.
    pub fn new(n: usize) -> Self {
        UnionFind { parent: (0..n as u32).collect() }
    }
    /// Representative of `x`'s set.
    pub fn find(&mut self, mut x: u32) -> u32 {
        while self.parent[x as usize] != x {
            let p = self.parent[self.parent[x as usize] as usize];
            self.parent[x as usize] = p;
            x = p;
        }
        x
    }
    /// Merge the sets of `a` and `b` (the smaller representative wins).
    pub fn union(&mut self, a: u32, b: u32) {
        let (ra, rb) = (self.find(a), self.find(b));
        if ra != rb {
            let (lo, hi) = if ra < rb { (ra, rb) } else { (rb, ra) };
            self.parent[hi as usize] = lo;
        }
    }
}

/// Undirected edges of a polygon mesh with their half-edges.
#[derive(Clone, Debug)]
pub struct MeshTopology {
    /// Endpoints of each undirected edge, smaller index first.
    pub edges: Vec<[u32; 2]>,
    /// Half-edges of edge `e` are `edge_he[edge_he_start[e]..edge_he_start[e + 1]]`.
    edge_he_start: Vec<u32>,
    edge_he: Vec<u32>,
    /// Edge of each half-edge.
    pub halfedge_edge: Vec<u32>,
    /// Face of each half-edge (corner).
    pub corner_face: Vec<u32>,
    /// Index of the next corner in the same face, for each corner.
    pub corner_next: Vec<u32>,
}

impl MeshTopology {
    /// Build the edge table of `mesh`. Cost: O(H log H), H = number of corners.
    pub fn new(mesh: &PolyMesh) -> Self {
        let mut corner_face = Vec::with_capacity(mesh.corner_count());
        let mut corner_next = Vec::with_capacity(mesh.corner_count());
        for (f, face) in mesh.faces().enumerate() {
            let s = mesh.face_start(f) as u32;
            let d = face.len() as u32;
            for k in 0..d {
                corner_face.push(f as u32);
                corner_next.push(s + (k + 1) % d);
            }
        }
        Self::build(mesh.corner_indices(), corner_face, corner_next)
    }

    /// Build the edge table of a triangle list (corner `3f + k` is corner `k` of triangle `f`).
    pub fn from_triangles(triangles: &[[u32; 3]]) -> Self {
        let n = triangles.len() as u32;
        let corner_face = (0..n).flat_map(|f| [f, f, f]).collect();
        let corner_next = (0..n).flat_map(|f| [3 * f + 1, 3 * f + 2, 3 * f]).collect();
        Self::build(triangles.as_flattened(), corner_face, corner_next)
    }

    fn build(idx: &[u32], corner_face: Vec<u32>, corner_next: Vec<u32>) -> Self {
        let h_count = idx.len();
        let mut keyed: Vec<(u64, u32)> = (0..h_count)
            .map(|h| {
                let (a, b) = (idx[h], idx[corner_next[h] as usize]);
                let (lo, hi) = if a <= b { (a, b) } else { (b, a) };
                (((lo as u64) << 32) | hi as u64, h as u32)
            })
            .collect();
        keyed.sort_unstable();
        let mut edges = Vec::new();
        let mut edge_he_start = Vec::new();
        let mut edge_he = Vec::with_capacity(h_count);
        let mut halfedge_edge = vec![0u32; h_count];
        let mut prev = u64::MAX;
        for &(key, h) in &keyed {
            if key != prev {
                edge_he_start.push(edge_he.len() as u32);
                edges.push([(key >> 32) as u32, key as u32]);
                prev = key;
            }
            halfedge_edge[h as usize] = (edges.len() - 1) as u32;
            edge_he.push(h);
        }
        edge_he_start.push(edge_he.len() as u32);
        MeshTopology { edges, edge_he_start, edge_he, halfedge_edge, corner_face, corner_next }
    }

    /// Half-edges (corners) that lie on edge `e`, in ascending order.
    #[inline]
    pub fn edge_halfedges(&self, e: usize) -> &[u32] {
        &self.edge_he[self.edge_he_start[e] as usize..self.edge_he_start[e + 1] as usize]
    }

    /// Neighbours of every vertex (`n` vertices) as compact rows: the neighbours of `v` are
    /// `cols[rows[v]..rows[v + 1]]`, ascending.
    pub fn vertex_neighbours(&self, n: usize) -> (Vec<u32>, Vec<u32>) {
        let mut rows = vec![0u32; n + 1];
        for &[a, b] in &self.edges {
            if a != b {
                rows[a as usize + 1] += 1;
                rows[b as usize + 1] += 1;
            }
        }
        for v in 0..n {
            rows[v + 1] += rows[v];
        }
        let mut fill = rows.clone();
        let mut cols = vec![0u32; rows[n] as usize];
        for &[a, b] in &self.edges {
            if a != b {
                cols[fill[a as usize] as usize] = b;
                fill[a as usize] += 1;
                cols[fill[b as usize] as usize] = a;
                fill[b as usize] += 1;
            }
        }
        for v in 0..n {
            cols[rows[v] as usize..rows[v + 1] as usize].sort_unstable();
        }
        (rows, cols)
    }

    /// Join, in `uf` (one set per corner), the corners of the two faces of every manifold edge at each of its
    /// endpoints. Afterwards the corners around a vertex fall into one set per fan of faces (a vertex with
    /// more than one set is pinched, i.e. non-manifold). `idx` holds each corner's vertex.
    pub fn join_fan_corners(&self, idx: &[u32], uf: &mut UnionFind) {
        for e in 0..self.edges.len() {
            if let [h1, h2] = *self.edge_halfedges(e) {
                // (corner at the edge's start, corner at its end) for each face.
                let (a1, b1) = (h1, self.corner_next[h1 as usize]);
                let (a2, b2) = (h2, self.corner_next[h2 as usize]);
                if idx[a1 as usize] == idx[a2 as usize] {
                    uf.union(a1, a2);
                    uf.union(b1, b2);
                } else {
                    uf.union(a1, b2);
                    uf.union(b1, a2);
                }
            }
        }
    }

    /// Number of faces using edge `e`.
    #[inline]
    pub fn edge_valence(&self, e: usize) -> usize {
        (self.edge_he_start[e + 1] - self.edge_he_start[e]) as usize
    }

    /// The opposite half-edge of `h` when its edge is manifold (exactly two faces), else `None`.
    #[inline]
    pub fn opposite(&self, h: u32) -> Option<u32> {
        let e = self.halfedge_edge[h as usize] as usize;
        match self.edge_halfedges(e) {
            [a, b] => Some(if *a == h { *b } else { *a }),
            _ => None,
        }
    }
}

/// Everything `scanstation inspect` reports about a mesh. Keys are the JSON keys.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct TopologyReport {
    /// Stored vertices (referenced or not).
    pub vertices: usize,
    /// Faces of any degree.
    pub faces: usize,
    /// Faces by number of vertices, e.g. `{"3": 69451}`.
    pub faces_by_degree: BTreeMap<usize, usize>,
    /// Vertices used by at least one face.
    pub referenced_vertices: usize,
    /// Vertices used by no face.
    pub unreferenced_vertices: usize,
    /// Bounding box of all vertices.
    pub bbox: Aabb,
    /// Length of the bounding-box diagonal.
    pub bbox_diagonal: f64,
    /// Total area (polygons fan-triangulated).
    pub area: f64,
    /// Signed enclosed volume, positive for outward faces; only when `closed`.
    pub volume: Option<f64>,
    /// Every edge is used by exactly two faces (and there is at least one face).
    pub closed: bool,
    /// Undirected edges.
    pub edges: usize,
    /// Edges used by one face.
    pub boundary_edges: usize,
    /// Connected chains of boundary edges (holes).
    pub boundary_loops: usize,
    /// Edges used by three or more faces.
    pub nonmanifold_edges: usize,
    /// Vertices whose faces form more than one edge-connected fan.
    pub nonmanifold_vertices: usize,
    /// Face-connected components (faces joined across edges used by exactly two faces).
    pub components: usize,
    /// Faces whose area is at most `DEGENERATE_AREA_REL × bbox_diagonal²` (zero up to f32 storage).
    pub degenerate_faces: usize,
    /// Referenced vertices that repeat another referenced vertex's exact position (vertices − distinct positions).
    pub coincident_vertices: usize,
    /// Directed edges (u→v) used by more than one face: each is an orientation conflict (or a non-manifold
    /// edge).
    pub orientation_conflicts: usize,
    /// No orientation conflicts: every manifold edge is traversed once in each direction.
    pub consistently_oriented: bool,
    /// χ = V − E + F over the referenced vertices.
    pub euler_characteristic: i64,
    /// Total genus Σ(2 − χᵢ − bᵢ)/2 over components, when the mesh is an orientable 2-manifold (with
    /// boundary); `null` otherwise.
    pub genus: Option<i64>,
}

impl TopologyReport {
    /// Inspect `mesh`. Cost: O(H log H) time, about 40·H bytes for H face corners.
    pub fn compute(mesh: &PolyMesh) -> Self {
        let topo = MeshTopology::new(mesh);
        Self::with_topology(mesh, &topo)
    }

    /// Inspect `mesh` with an edge table already built.
    pub fn with_topology(mesh: &PolyMesh, topo: &MeshTopology) -> Self {
        let nv = mesh.positions.len();
        let nf = mesh.face_count();
        let idx = mesh.corner_indices();

        let mut faces_by_degree = BTreeMap::new();
        for face in mesh.faces() {
            *faces_by_degree.entry(face.len()).or_insert(0) += 1;
        }
        let mut referenced = vec![false; nv];
        for &v in idx {
            referenced[v as usize] = true;
        }
        let referenced_vertices = referenced.iter().filter(|&&r| r).count();

        let bbox = mesh.bbox();
        let diag = bbox.diagonal();
        let degenerate_limit = DEGENERATE_AREA_REL * diag * diag;
        let mut area = 0.0;
        let mut degenerate_faces = 0;
        let mut six_volume = 0.0;
        let centre = if bbox.is_empty() { [0.0; 3] } else { vec3::scale(vec3::add(bbox.min, bbox.max), 0.5) };
        for face in mesh.faces() {
            let p0 = vec3::sub(wide(mesh.positions[face[0] as usize]), centre);
            let mut face_area = 0.0;
            for k in 1..face.len() - 1 {
                let p1 = vec3::sub(wide(mesh.positions[face[k] as usize]), centre);
                let p2 = vec3::sub(wide(mesh.positions[face[k + 1] as usize]), centre);
                face_area += 0.5 * vec3::norm(vec3::cross(vec3::sub(p1, p0), vec3::sub(p2, p0)));
                six_volume += vec3::dot(p0, vec3::cross(p1, p2));
            }
            area += face_area;
            if face_area <= degenerate_limit {
                degenerate_faces += 1;
            }
        }

        // Edge statistics, directed-edge conflicts, face components, vertex fans.
        let mut boundary_edges = 0;
        let mut nonmanifold_edges = 0;
        let mut orientation_conflicts = 0;
        let mut face_uf = UnionFind::new(nf);
        let mut corner_uf = UnionFind::new(idx.len());
        let mut boundary_uf = UnionFind::new(nv);
        let mut on_boundary = vec![false; nv];
        for e in 0..topo.edges.len() {
            let hs = topo.edge_halfedges(e);
            let [lo, _] = topo.edges[e];
            let forward = hs.iter().filter(|&&h| idx[h as usize] == lo).count();
            let backward = hs.len() - forward;
            orientation_conflicts += (forward > 1) as usize + (backward > 1) as usize;
            match hs.len() {
                1 => {
                    boundary_edges += 1;
                    let [a, b] = topo.edges[e];
                    boundary_uf.union(a, b);
                    on_boundary[a as usize] = true;
                    on_boundary[b as usize] = true;
                }
                2 => face_uf.union(topo.corner_face[hs[0] as usize], topo.corner_face[hs[1] as usize]),
                _ => nonmanifold_edges += 1,
            }
        }
        // A face that visits a vertex twice is a pinch, which the fan count below reports.
        topo.join_fan_corners(idx, &mut corner_uf);
        let mut fan_root = vec![u32::MAX; nv];
        let mut nonmanifold = vec![false; nv];
        for h in 0..idx.len() as u32 {
            let v = idx[h as usize] as usize;
            let r = corner_uf.find(h);
            if fan_root[v] == u32::MAX {
                fan_root[v] = r;
            } else if fan_root[v] != r {
                nonmanifold[v] = true;
            }
        }
        let nonmanifold_vertices = nonmanifold.iter().filter(|&&x| x).count();

        let mut comp_root = Vec::with_capacity(nf);
        for f in 0..nf as u32 {
            comp_root.push(face_uf.find(f));
        }
        let components = comp_root.iter().enumerate().filter(|&(f, &r)| r as usize == f).count();
        let boundary_loops = (0..nv as u32).filter(|&v| on_boundary[v as usize] && boundary_uf.find(v) == v).count();

        let coincident_vertices = {
            let mut keys: Vec<[u32; 3]> = (0..nv)
                .filter(|&v| referenced[v])
                .map(|v| mesh.positions[v].map(|c| if c == 0.0 { 0 } else { c.to_bits() }))
                .collect();
            keys.sort_unstable();
            keys.dedup();
            referenced_vertices - keys.len()
        };

        let closed = nf > 0 && boundary_edges == 0 && nonmanifold_edges == 0;
        let euler_characteristic = referenced_vertices as i64 - topo.edges.len() as i64 + nf as i64;
        let genus = if nonmanifold_edges == 0 && nonmanifold_vertices == 0 && orientation_conflicts == 0 {
            let twice = 2 * components as i64 - euler_characteristic - boundary_loops as i64;
            (twice >= 0 && twice % 2 == 0).then_some(twice / 2)
        } else {
            None
        };

        TopologyReport {
            vertices: nv,
            faces: nf,
            faces_by_degree,
            referenced_vertices,
            unreferenced_vertices: nv - referenced_vertices,
            bbox,
            bbox_diagonal: diag,
            area,
            volume: closed.then_some(six_volume / 6.0),
            closed,
            edges: topo.edges.len(),
            boundary_edges,
            boundary_loops,
            nonmanifold_edges,
            nonmanifold_vertices,
            components,
            degenerate_faces,
            coincident_vertices,
            orientation_conflicts,
            consistently_oriented: orientation_conflicts == 0,
            euler_characteristic,
            genus,
        }
    }
}

/// The faces around every vertex of a triangle list, as compact rows (a counting sort: O(V + F)).
#[derive(Clone, Debug)]
pub struct VertexFaces {
    rows: Vec<u32>,
    cols: Vec<u32>,
}

impl VertexFaces {
    /// Faces around each of the `n` vertices of `tris` (every index must be below `n`).
    pub fn new(n: usize, tris: &[[u32; 3]]) -> Self {
        let mut rows = vec![0u32; n + 1];
        for t in tris {
            for &v in t {
                rows[v as usize + 1] += 1;
            }
        }
        for v in 0..n {
            rows[v + 1] += rows[v];
        }
        let mut fill = rows.clone();
        let mut cols = vec![0u32; rows[n] as usize];
        for (f, t) in tris.iter().enumerate() {
            for &v in t {
                cols[fill[v as usize] as usize] = f as u32;
                fill[v as usize] += 1;
            }
        }
        VertexFaces { rows, cols }
    }

    /// Faces using vertex `v`, ascending.
    #[inline]
    pub fn of(&self, v: u32) -> &[u32] {
        &self.cols[self.rows[v as usize] as usize..self.rows[v as usize + 1] as usize]
    }
}

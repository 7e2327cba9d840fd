//! Mesh and point-cloud types.
//!
//! # Precision: positions are `f32`, arithmetic is `f64`
//! Positions are stored as `[f32; 3]` (12 bytes per point). A 20-million-point cloud then needs 240 MB for
//! positions (480 MB with normals) and fits a 1 GB budget; with f64 it would need 480 MB for positions
//! alone. f32 keeps 24 bits of mantissa: a relative resolution of 6e-8, i.e. 0.06 µm on a 1 m object,
//! three orders of magnitude below the noise of any structured-light or laser scanner, and every input
//! format we read (PLY, STL, E57) stores scans as f32 anyway. All geometric computation (areas, volumes,
//! distances, fitting) widens to f64 first, so no precision is lost in sums or in cancellation.
//!
//! Vertex indices are `u32` (4 billion vertices), half the memory of `usize` on 64-bit targets.

use crate::error::{Error, ErrorCode, Result};
use crate::geometry::vec3::{self, Aabb, V3, wide};

/// Checks shared by the constructors: finite positions, indices in range.
fn validate(positions: &[[f32; 3]], indices: &[u32]) -> Result<()> {
    if let Some(i) = positions.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
        return Err(Error::new(
            ErrorCode::InputNonFinite,
            format!("vertex {i} has a non-finite coordinate {:?}", positions[i]),
        ));
    }
    let n = positions.len();
    if let Some(&bad) = indices.iter().find(|&&i| i as usize >= n) {
        return Err(Error::new(ErrorCode::InputBadIndex, format!("vertex index {bad} out of range (0..{n})")));
    }
    Ok(())
}

/// An indexed triangle mesh.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TriMesh {
    /// Vertex positions.
    pub positions: Vec<[f32; 3]>,
    /// Triangles as counter-clockwise (outward-facing) vertex index triples.
    pub triangles: Vec<[u32; 3]>,
}

impl TriMesh {
    /// Build a triangle mesh, checking that coordinates are finite and indices in range.
    ///
    /// # Errors
    /// `input.non-finite`, `input.bad-index`. Cost: O(V + F).
    pub fn new(positions: Vec<[f32; 3]>, triangles: Vec<[u32; 3]>) -> Result<Self> {
        validate(&positions, triangles.as_flattened())?;
        Ok(TriMesh { positions, triangles })
    }

    /// Corner positions of triangle `t`, widened to f64.
    #[inline]
    pub fn corners(&self, t: usize) -> [V3; 3] {
        let [a, b, c] = self.triangles[t];
        [wide(self.positions[a as usize]), wide(self.positions[b as usize]), wide(self.positions[c as usize])]
    }

    /// Area of triangle `t`.
    #[inline]
    pub fn triangle_area(&self, t: usize) -> f64 {
        let [a, b, c] = self.corners(t);
        0.5 * vec3::norm(vec3::cross(vec3::sub(b, a), vec3::sub(c, a)))
    }

    /// Bounding box of all vertices (referenced or not).
    pub fn bbox(&self) -> Aabb {
        Aabb::of_points(&self.positions)
    }

    /// Total surface area. Cost: O(F).
    pub fn area(&self) -> f64 {
        (0..self.triangles.len()).map(|t| self.triangle_area(t)).sum()
    }

    /// Signed enclosed volume (divergence theorem; meaningful for closed meshes, positive when outward).
    pub fn signed_volume(&self) -> f64 {
        // Relative to the bbox centre to reduce cancellation for objects far from the origin.
        let c = {
            let b = self.bbox();
            if b.is_empty() { [0.0; 3] } else { vec3::scale(vec3::add(b.min, b.max), 0.5) }
        };
        (0..self.triangles.len())
            .map(|t| {
                let [a, b, d] = self.corners(t);
                let (a, b, d) = (vec3::sub(a, c), vec3::sub(b, c), vec3::sub(d, c));
                vec3::dot(a, vec3::cross(b, d))
            })
            .sum::<f64>()
            / 6.0
    }
}

/// A polygon mesh (quad-dominant or mixed), faces stored compactly.
///
/// Face `f` has the vertex indices `indices[offsets[f]..offsets[f + 1]]`, in counter-clockwise order.
#[derive(Clone, Debug, PartialEq)]
pub struct PolyMesh {
    /// Vertex positions.
    pub positions: Vec<[f32; 3]>,
    offsets: Vec<u32>,
    indices: Vec<u32>,
}

impl Default for PolyMesh {
    fn default() -> Self {
        PolyMesh { positions: Vec::new(), offsets: vec![0], indices: Vec::new() }
    }
}

impl PolyMesh {
    /// Build from positions and a face list; faces need at least 3 vertices.
    ///
    /// # Errors
    /// `input.non-finite`, `input.bad-index`, `input.bad-face`. Cost: O(V + corners).
    pub fn new(positions: Vec<[f32; 3]>, faces: &[Vec<u32>]) -> Result<Self> {
        let mut m = PolyMesh { positions, ..Default::default() };
        for f in faces {
            m.push_face_unchecked(f)?;
        }
        validate(&m.positions, &m.indices)?;
        Ok(m)
    }

    /// Build from the compact representation (`offsets` has `faces + 1` entries starting at 0).
    ///
    /// # Errors
    /// As [`PolyMesh::new`]; also `input.bad-face` for malformed offsets.
    pub fn from_parts(positions: Vec<[f32; 3]>, offsets: Vec<u32>, indices: Vec<u32>) -> Result<Self> {
        if offsets.first() != Some(&0)
            || *offsets.last().unwrap_or(&1) as usize != indices.len()
            || offsets.windows(2).any(|w| w[1] < w[0] + 3)
        {
            return Err(Error::new(ErrorCode::InputBadFace, "face offsets malformed or a face has < 3 vertices"));
        }
        validate(&positions, &indices)?;
        Ok(PolyMesh { positions, offsets, indices })
    }

    /// Start an empty mesh (positions are set by the reader) with capacity hints (caller-checked; never pass untrusted counts unclamped).
    pub(crate) fn with_capacity(faces: usize, corners: usize) -> Self {
        let mut offsets = Vec::with_capacity(faces + 1);
        offsets.push(0);
        PolyMesh { positions: Vec::new(), offsets, indices: Vec::with_capacity(corners) }
    }

    /// Append a face without range checks (readers validate all indices once at the end).
    pub(crate) fn push_face_unchecked(&mut self, face: &[u32]) -> Result<()> {
        if face.len() < 3 {
            return Err(Error::new(
                ErrorCode::InputBadFace,
                format!("face {} has {} vertices; at least 3 are needed", self.face_count(), face.len()),
            ));
        }
        self.indices.extend_from_slice(face);
        let end = u32::try_from(self.indices.len())
            .map_err(|_| Error::new(ErrorCode::InputAbsurdCount, "more than 2^32 face corners"))?;
        self.offsets.push(end);
        Ok(())
    }

    /// Check indices after a reader pushed faces unchecked.
    pub(crate) fn validate(&self) -> Result<()> {
        validate(&self.positions, &self.indices)
    }

    /// Number of faces.
    #[inline]
    pub fn face_count(&self) -> usize {
        self.offsets.len() - 1
    }

    /// Number of face corners (sum of face degrees) = number of half-edges.
    #[inline]
    pub fn corner_count(&self) -> usize {
        self.indices.len()
    }

    /// Vertex indices of face `f`.
    #[inline]
    pub fn face(&self, f: usize) -> &[u32] {
        &self.indices[self.offsets[f] as usize..self.offsets[f + 1] as usize]
    }

    /// Index of the first corner (half-edge) of face `f`.
    #[inline]
    pub fn face_start(&self, f: usize) -> usize {
        self.offsets[f] as usize
    }

    /// Iterate over faces.
    pub fn faces(&self) -> impl ExactSizeIterator<Item = &[u32]> + '_ {
        self.offsets.windows(2).map(move |w| &self.indices[w[0] as usize..w[1] as usize])
    }

    /// All corner indices, face after face.
    pub fn corner_indices(&self) -> &[u32] {
        &self.indices
    }

    /// True when every face is a triangle.
    pub fn is_triangle_mesh(&self) -> bool {
        self.indices.len() == 3 * self.face_count()
    }

    /// Fan-triangulate (faces of degree 3 are kept as they are). Returns the triangle mesh and, for each
    /// triangle, the polygon it came from.
    pub fn triangulate(&self) -> (TriMesh, Vec<u32>) {
        let ntri = self.indices.len() - 2 * self.face_count();
        let mut triangles = Vec::with_capacity(ntri);
        let mut origin = Vec::with_capacity(ntri);
        for (f, face) in self.faces().enumerate() {
            for k in 1..face.len() - 1 {
                triangles.push([face[0], face[k], face[k + 1]]);
                origin.push(f as u32);
            }
        }
        (TriMesh { positions: self.positions.clone(), triangles }, origin)
    }

    /// Bounding box of all vertices.
    pub fn bbox(&self) -> Aabb {
        Aabb::of_points(&self.positions)
    }
}

impl From<TriMesh> for PolyMesh {
    fn from(t: TriMesh) -> Self {
        let n = t.triangles.len();
        let offsets = (0..=n as u32).map(|i| 3 * i).collect();
        PolyMesh { positions: t.positions, offsets, indices: t.triangles.into_flattened() }
    }
}

/// A point cloud with optional per-point normals and colours.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PointCloud {
    /// Point positions.
    pub positions: Vec<[f32; 3]>,
    /// Unit normals, one per point, when the source has them.
    pub normals: Option<Vec<[f32; 3]>>,
    /// 8-bit RGB colours, one per point, when the source has them.
    pub colors: Option<Vec<[u8; 3]>>,
}

impl PointCloud {
    /// Build a cloud, checking finiteness and that attribute arrays match the point count.
    ///
    /// # Errors
    /// `input.non-finite`, `input.bad-record` (attribute length mismatch).
    pub fn new(positions: Vec<[f32; 3]>, normals: Option<Vec<[f32; 3]>>, colors: Option<Vec<[u8; 3]>>) -> Result<Self> {
        validate(&positions, &[])?;
        let n = positions.len();
        if normals.as_ref().is_some_and(|v| v.len() != n) || colors.as_ref().is_some_and(|v| v.len() != n) {
            return Err(Error::new(ErrorCode::InputBadRecord, "normals/colors do not match the point count"));
        }
        Ok(PointCloud { positions, normals, colors })
    }

    /// Bounding box.
    pub fn bbox(&self) -> Aabb {
        Aabb::of_points(&self.positions)
    }

    /// Bytes its arrays hold (positions, normals, colours).
    pub fn heap_bytes(&self) -> u64 {
        let per_point = 12 + if self.normals.is_some() { 12 } else { 0 } + if self.colors.is_some() { 3 } else { 0 };
        self.positions.len() as u64 * per_point
    }
}

/// What a reader returns: a mesh (faces present) or a point cloud.
#[derive(Clone, Debug, PartialEq)]
pub enum Geometry {
    /// A surface mesh (triangles or polygons).
    Mesh(PolyMesh),
    /// Points without faces.
    Cloud(PointCloud),
}

impl Geometry {
    /// Vertex (point) positions.
    pub fn positions(&self) -> &[[f32; 3]] {
        match self {
            Geometry::Mesh(m) => &m.positions,
            Geometry::Cloud(c) => &c.positions,
        }
    }

    /// Bounding box.
    pub fn bbox(&self) -> Aabb {
        Aabb::of_points(self.positions())
    }

    /// "mesh" or "point_cloud".
    pub fn kind(&self) -> &'static str {
        match self {
            Geometry::Mesh(_) => "mesh",
            Geometry::Cloud(_) => "point_cloud",
        }
    }
}

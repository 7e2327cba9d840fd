//! The solid's tessellations for `convert` ([`super::convert`]): the crossing check's (welded, 2 × 2 per
//! span), the quality check's (about 1.5M triangles, with each triangle's face), the solid mesh written
//! beside the STEP file; and the quad net's crossing count.

use std::path::{Path, PathBuf};

use crate::error::Result;
use crate::geometry::io::FileDigest;
use crate::geometry::mesh::{PolyMesh, TriMesh};
use crate::stages::brep::Solid;

/// Pairs of intersecting triangles of a polygon mesh, fan-triangulated (the quad net, or the welded solid mesh).
pub(super) fn mesh_self_intersections(mesh: &PolyMesh) -> usize {
    let (t, _) = mesh.triangulate();
    let p: Vec<[f64; 3]> = t.positions.iter().map(|q| q.map(f64::from)).collect();
    crate::geometry::intersect::self_intersections(&p, &t.triangles).len()
}

/// A point of each pair of intersecting triangles of a welded 2×2-per-span tessellation of the solid (faces
/// joined at their exactly shared boundaries); none for a solid whose surface does not cross itself (at
/// that resolution).
pub(super) fn solid_self_intersections(solid: &Solid) -> Result<Vec<[f64; 3]>> {
    let t = solid.tessellate(2)?;
    let p: Vec<[f64; 3]> = t.positions.iter().map(|q| q.map(f64::from)).collect();
    // Faces' boundary samples coincide exactly; anything closer than the edge tolerance is one point.
    let tol = crate::geometry::tolerance::BREP_EDGE_REL * t.bbox().diagonal();
    let (pts, tris, _) = crate::stages::repair::weld::weld(&p, &t.triangles, tol);
    let pairs = crate::geometry::intersect::self_intersections(&pts, &tris);
    Ok(pairs.iter().map(|&(a, _)| pts[tris[a as usize][0] as usize]).collect())
}

/// Write the solid's watertight tessellation (the quality check's, [`tessellate_for_check`]: each face's knot
/// spans sampled 8 × 8 at most, welded along the exactly shared edges) beside the STEP file as NAME.solid.ply,
/// its header naming the STEP's sha256 (see [`super::fea`]). Removes the STEP file again when this fails, so
/// the pair is written or neither.
pub(super) fn write_solid_mesh(
    step: &Path,
    step_sha256: &str,
    tessellation: TriMesh,
) -> Result<(PathBuf, PolyMesh, FileDigest, Vec<u32>)> {
    let result = (|| {
        let t = tessellation;
        let p: Vec<[f64; 3]> = t.positions.iter().map(|q| q.map(f64::from)).collect();
        let tol = crate::geometry::tolerance::BREP_EDGE_REL * t.bbox().diagonal();
        let (pts, tris, _, kept) = crate::stages::repair::weld::weld_kept(&p, &t.triangles, tol);
        let positions = pts.iter().map(|q| q.map(|x| x as f32)).collect();
        let mesh = TriMesh::new(positions, tris)?;
        let path = super::provenance::solid_artifact_path(step);
        let comment = format!("{}{step_sha256}", super::provenance::SOLID_OF);
        let mesh = PolyMesh::from(mesh);
        let digest = crate::geometry::io::write_ply(&path, &mesh, &Default::default(), &[&comment])?;
        Ok((path, mesh, digest, kept))
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(step);
    }
    result
}

/// Tessellation density for the solid's quality check: about `budget` triangles in all; with the face of
/// every triangle.
pub(super) fn tessellate_for_check(solid: &Solid, budget: usize) -> Result<(TriMesh, Vec<u32>)> {
    let spans: usize = solid.faces.iter().map(|f| (f.surface.nu - 3) * (f.surface.nv - 3)).sum::<usize>().max(1);
    let per = ((budget as f64 / (2.0 * spans as f64)).sqrt().floor() as usize).clamp(2, 8);
    solid.tessellate_labelled(per)
}

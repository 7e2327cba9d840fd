//! **surface** — the quad mesh as the control net of a Catmull–Clark surface whose control points are
//! *fitted* so that the limit surface approximates the scan.
//!
//! Copying the quad vertices as control points shrinks the surface (16 % of the radius on a 24-face sphere
//! cage); instead the fit ([`fit::fit_control_points`]) minimises the area-weighted squared distance from
//! dense limit-surface samples to their closest scan points, with a small smoothness term, over a few
//! closest-point rounds. The limit surface is evaluated exactly: bicubic B-splines on regular faces and
//! repeated local subdivision around extraordinary vertices ([`crate::geometry::subdivision::limit`]).
//!
//! The net and its limit evaluation are geometry ([`crate::geometry::subdivision`]); this stage is
//! [`fit`] (the least-squares fit).

pub mod fit;

pub use crate::geometry::subdivision::{LimitSurface, QuadNet};
pub use fit::{FitOptions, FitReport, FitTarget, MeshTarget, SphereTarget, fit_control_points};

use crate::error::{Error, ErrorCode, Result};
use crate::geometry::mesh::PolyMesh;
use crate::geometry::vec3::{V3, wide};

/// The control net of a pure-quad mesh, with its vertex positions in double precision.
///
/// # Errors
/// `surface.bad-net` when a face is not a quad, or the mesh is not a closed, oriented 2-manifold (the
/// message names the first offending face or vertex).
pub fn control_net(quads: &PolyMesh) -> Result<(QuadNet, Vec<V3>)> {
    let mut faces = Vec::with_capacity(quads.face_count());
    for (f, q) in quads.faces().enumerate() {
        if q.len() != 4 {
            return Err(Error::new(
                ErrorCode::SurfaceBadNet,
                format!("face {f} has {} corners; the control net must be pure quads", q.len()),
            ));
        }
        faces.push([q[0], q[1], q[2], q[3]]);
    }
    let net = QuadNet::new(faces, quads.positions.len(), true)?;
    Ok((net, quads.positions.iter().map(|&p| wide(p)).collect()))
}

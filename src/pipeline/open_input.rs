//! How a solid made from an open scan is measured.
//!
//! Where repair closed a hole, the solid has surface that no scan saw: a cap over a statue's base, a faired
//! fill over a dropout. Repair hands that invented surface on ([`InventedSurface`]); each vertex of the solid's
//! mesh is labelled invented where the invented surface is nearer to it than the scan
//! ([`split_by_invented`]). Then:
//! - the RMS gate judges scan → solid everywhere and solid → scan off the invented region;
//! - the invented region is reported on its own: its share and area, and per cap its distance to the cap's
//!   plane and its bulge past it, which the `caps` gate bounds ([`super::gates`]).

use crate::geometry::mesh::{Geometry, PolyMesh, TriMesh};
use crate::geometry::vec3::{self, V3};
use crate::stages::quality::split_by_invented;
use crate::stages::repair::RepairReport;
use crate::stages::repair::caps::{Cap, CapKind};
use crate::stages::repair::holes::InventedSurface;

/// How a solid of an open scan is measured (see the module). Percentages are of the input's bounding-box
/// diagonal.
#[derive(Clone, Debug, serde::Serialize)]
pub struct OpenInputMeasure {
    /// Holes repair filled.
    pub holes_filled: usize,
    /// Of those, closed by a cap (planar or membrane); the rest were faired.
    pub caps: usize,
    /// RMS distance from the scan to the solid (area samples of the scan).
    pub scan_to_solid_rms_pct: f64,
    /// RMS distance to the scan of the solid's mesh vertices off the invented region.
    pub solid_to_scan_off_invented_rms_pct: f64,
    /// The invented region of the solid.
    pub invented: InventedRegion,
    /// Per cap of the repair report, in its order: the solid over it.
    pub cap_measures: Vec<CapMeasure>,
    /// What the RMS gate judges: √((scan → solid² + solid → scan off the invented region²) / 2).
    pub rms_pct: f64,
}

/// The solid's invented region: its mesh vertices nearer to the surface repair invented than to the scan.
#[derive(Clone, Debug, serde::Serialize)]
pub struct InventedRegion {
    /// Share of the solid's mesh vertices.
    pub vertex_fraction: f64,
    /// Its area (each triangle of the solid's mesh counted by the share of its corners that are invented),
    /// input units².
    pub area: f64,
    /// Its share of the solid's area.
    pub area_fraction: f64,
    /// RMS distance of its vertices to the invented surface repair made (how far remeshing and fitting moved
    /// it).
    pub to_repaired_rms_pct: f64,
    /// The largest of those distances.
    pub to_repaired_max_pct: f64,
}

/// The solid over one cap.
#[derive(Clone, Debug, serde::Serialize)]
pub struct CapMeasure {
    /// Planar or membrane.
    pub kind: Option<CapKind>,
    /// Boundary edges of the hole.
    pub edges: usize,
    /// Area of the solid over the cap, input units².
    pub area: f64,
    /// RMS distance of the solid's vertices over the cap to the cap's plane.
    pub plane_rms_pct: f64,
    /// Largest distance of those vertices past the plane, outward (negative: none passes it).
    pub bulge_pct: f64,
    /// The rim's own non-planarity: its largest distance from the plane.
    pub rim_residual_pct: f64,
}

impl OpenInputMeasure {
    /// Measure `solid_mesh` against the open `scan` and what `repair` invented; `scan_to_solid_rms` is the
    /// chain's scan → solid RMS (input units). Also returns the per-vertex invented label (for the error map).
    /// Cost: two closest-point queries per solid vertex.
    pub fn measure(
        solid_mesh: &PolyMesh,
        scan: &PolyMesh,
        scan_to_solid_rms: f64,
        repair: &RepairReport,
        diag: f64,
    ) -> (Self, Vec<bool>) {
        let (tri, _) = solid_mesh.triangulate();
        let pts: Vec<V3> = tri.positions.iter().map(|q| q.map(f64::from)).collect();
        let holes = &repair.holes;
        let invented = invented_mesh(&holes.invented);
        let split = split_by_invented(&pts, &scan.triangulate().0, &invented);
        let pct = |x: f64| 100.0 * x / diag;
        let rms = |d: &mut dyn Iterator<Item = f64>| {
            let (s, n) = d.fold((0.0, 0usize), |(s, n), x| (s + x * x, n + 1));
            if n == 0 { 0.0 } else { (s / n as f64).sqrt() }
        };
        let mask: Vec<bool> = split.invented.iter().map(Option::is_some).collect();
        let off = rms(&mut (0..pts.len()).filter(|&i| !mask[i]).map(|i| split.to_scan[i]));
        // Per vertex: the cap it lies over, if any.
        let cap_of_vertex: Vec<Option<usize>> = split
            .invented
            .iter()
            .map(|t| t.and_then(|t| holes.invented.cap_of[t as usize]).map(|c| c as usize))
            .collect();
        let (area, total, cap_area) = region_areas(&tri, &pts, &mask, &cap_of_vertex, holes.caps.len());
        let inv: Vec<usize> = (0..pts.len()).filter(|&i| mask[i]).collect();
        let region = InventedRegion {
            vertex_fraction: inv.len() as f64 / pts.len().max(1) as f64,
            area,
            area_fraction: area / total.max(f64::MIN_POSITIVE),
            to_repaired_rms_pct: pct(rms(&mut inv.iter().map(|&i| split.to_invented[i]))),
            to_repaired_max_pct: pct(inv.iter().map(|&i| split.to_invented[i]).fold(0.0, f64::max)),
        };
        let cap_measures = holes
            .caps
            .iter()
            .enumerate()
            .map(|(k, cap)| cap_measure(cap, cap_area[k], &pts, &cap_of_vertex, k, diag))
            .collect();
        let measure = OpenInputMeasure {
            holes_filled: holes.holes_filled,
            caps: holes.caps.len(),
            scan_to_solid_rms_pct: pct(scan_to_solid_rms),
            solid_to_scan_off_invented_rms_pct: pct(off),
            invented: region,
            cap_measures,
            rms_pct: pct(((scan_to_solid_rms * scan_to_solid_rms + off * off) / 2.0).sqrt()),
        };
        (measure, mask)
    }

    /// The largest excess of a cap's bulge over its rim's non-planarity, % of the diagonal (what the `caps`
    /// gate bounds); `None` without caps.
    pub fn cap_excess_pct(&self) -> Option<f64> {
        self.cap_measures.iter().map(|c| c.bulge_pct - c.rim_residual_pct).reduce(f64::max)
    }
}

/// The invented surface as a triangle mesh.
fn invented_mesh(s: &InventedSurface) -> TriMesh {
    TriMesh { positions: s.positions.iter().map(|q| q.map(|c| c as f32)).collect(), triangles: s.triangles.clone() }
}

/// (invented area, total area, area per cap) of the triangle mesh `tri` (positions `pts`): each triangle
/// counted by the share of its corners labelled invented (`mask`), and per cap by the share over that cap.
fn region_areas(
    tri: &TriMesh,
    pts: &[V3],
    mask: &[bool],
    cap_of_vertex: &[Option<usize>],
    caps: usize,
) -> (f64, f64, Vec<f64>) {
    let (mut area, mut total, mut per_cap) = (0.0, 0.0, vec![0.0; caps]);
    for t in &tri.triangles {
        let a = vec3::tri_area(pts, *t);
        total += a;
        for &v in t {
            if mask[v as usize] {
                area += a / 3.0;
            }
            if let Some(c) = cap_of_vertex[v as usize] {
                per_cap[c] += a / 3.0;
            }
        }
    }
    (area, total, per_cap)
}

/// The solid's vertices over cap `k` against the cap's plane.
fn cap_measure(cap: &Cap, area: f64, pts: &[V3], cap_of_vertex: &[Option<usize>], k: usize, diag: f64) -> CapMeasure {
    let heights: Vec<f64> = (0..pts.len())
        .filter(|&i| cap_of_vertex[i] == Some(k))
        .map(|i| vec3::dot(vec3::sub(pts[i], cap.point), cap.normal))
        .collect();
    let rms = if heights.is_empty() {
        0.0
    } else {
        (heights.iter().map(|h| h * h).sum::<f64>() / heights.len() as f64).sqrt()
    };
    let bulge = heights.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    CapMeasure {
        kind: cap.kind,
        edges: cap.edges,
        area,
        plane_rms_pct: 100.0 * rms / diag,
        bulge_pct: if heights.is_empty() { 0.0 } else { 100.0 * bulge / diag },
        rim_residual_pct: 100.0 * cap.rim_residual / diag,
    }
}

/// For a mesh input whose holes repair filled: the open-input measure of the solid mesh and its invented
/// vertices (see [`OpenInputMeasure`]); `None` otherwise.
pub(super) fn open_input_measure(
    solid_mesh: &PolyMesh,
    input: &Geometry,
    input_to_solid_rms: f64,
    repair_report: &RepairReport,
    diag: f64,
) -> (Option<OpenInputMeasure>, Option<Vec<bool>>) {
    match input {
        Geometry::Mesh(scan) if repair_report.holes.holes_filled > 0 => {
            let (m, mask) = OpenInputMeasure::measure(solid_mesh, scan, input_to_solid_rms, repair_report, diag);
            (Some(m), Some(mask))
        }
        _ => (None, None),
    }
}

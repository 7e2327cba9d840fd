//! What [`remesh`](super::remesh) reports: the report, its parts, and the quality figures of a quad mesh.

use std::collections::BTreeMap;

use serde::Serialize;

use super::{dipoles, fit, integer, quadify};
use crate::geometry::bvh::TriangleBvh;
use crate::geometry::mesh::{PolyMesh, TriMesh};
use crate::geometry::polygon;
use crate::geometry::stats::percentile;
use crate::geometry::topology::TopologyReport;
use crate::geometry::vec3::{self, V3, cross, dot, sub, wide};
use crate::stages::quality::DistanceReport;

/// Quality figures of a quad(-dominant) mesh.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct QuadStats {
    /// Referenced vertices.
    pub vertices: usize,
    /// Faces.
    pub faces: usize,
    /// Faces by degree, e.g. `{"4": 9998}`.
    pub faces_by_degree: BTreeMap<usize, usize>,
    /// Share of faces that are quads.
    pub quad_fraction: f64,
    /// Vertices by valence (number of edges).
    pub valence_histogram: BTreeMap<usize, usize>,
    /// Vertices of valence ≠ 4.
    pub irregular_vertices: usize,
    /// `irregular_vertices / vertices`.
    pub irregular_fraction: f64,
    /// Smallest valence.
    pub min_valence: usize,
    /// Every edge is used by exactly two faces.
    pub closed: bool,
    /// Edges used by one face.
    pub boundary_edges: usize,
    /// Chains of boundary edges.
    pub boundary_loops: usize,
    /// Edges used by more than two faces.
    pub nonmanifold_edges: usize,
    /// Vertices whose faces do not form one fan.
    pub nonmanifold_vertices: usize,
    /// Face-connected pieces.
    pub components: usize,
    /// χ = V − E + F.
    pub euler_characteristic: i64,
    /// Faces whose normal points against the input surface's normal at the face centre.
    pub flipped_faces: usize,
    /// |corner angle − 90°| over all quad corners: mean and 95th percentile, degrees.
    pub angle_deviation_mean_deg: f64,
    /// 95th percentile of the same, degrees.
    pub angle_deviation_p95_deg: f64,
    /// Edge length: mean and coefficient of variation.
    pub edge_length_mean: f64,
    /// Coefficient of variation of the edge length.
    pub edge_length_cv: f64,
    /// Crossing triangle pairs of the mesh's fan triangulation (exact predicates,
    /// [`crate::geometry::intersect::self_intersections`]): where two sides of a thin part met. Measured with
    /// the input (`None` without).
    pub crossing_pairs: Option<usize>,
}

/// How the pure-quad mesh was made.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Mode {
    /// Extracted at the target spacing; triangles paired along quad strips.
    Direct,
    /// Extracted at twice the spacing, then every n-gon split into n quads.
    Split,
    /// As `Split`, with a finer spacing on thin parts and narrow gaps ([`THIN_RATIO`]).
    AdaptiveSplit,
    /// As `Direct`, with the spacing refined ([`REFINE_FACTOR`]) where the direct result missed the input
    /// (working vertices farther than [`MISS_SPACINGS`] spacings from it): struts and fins the lattice
    /// could not follow.
    RefinedDirect,
}

impl Mode {
    /// Extracted at the full count (no split into quads afterwards).
    pub fn is_direct(self) -> bool {
        matches!(self, Mode::Direct | Mode::RefinedDirect)
    }
}

/// One extraction while the vertex count was matched.
#[derive(Clone, Debug, Serialize)]
pub struct Attempt {
    /// The route of this extraction.
    pub mode: Mode,
    /// Lattice spacing of the quad-dominant mesh.
    pub scale: f64,
    /// Vertices of the quad-dominant mesh.
    pub extracted_vertices: usize,
    /// Faces of the quad-dominant mesh by degree, before clean-up.
    pub extracted_faces_by_degree: BTreeMap<usize, usize>,
    /// Triangles left after pairing (direct mode; the attempt is unusable when > 0).
    pub triangles_unpaired: usize,
    /// Vertices of the pure-quad mesh (split mode: V + E + F).
    pub predicted_vertices: usize,
    /// The quad-dominant mesh is closed, edge-manifold and has the input's Euler characteristic.
    pub topology_ok: bool,
    /// Position singularities before and after their cancellation (when it ran).
    pub position_singularities: Option<integer::CancelCounts>,
    /// The spacing of a refined direct attempt ([`Mode::RefinedDirect`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub refine: Option<Refine>,
}

/// How the refined direct route makes its spacing finer, tried in the order of [`REFINE_TRIES`] until one
/// result is sound.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Refine {
    /// [`THIN_RATIO`] times the local thickness on thin parts and narrow gaps (as the adaptive split).
    Thin,
    /// [`REFINE_FACTOR`] times the spacing where the direct result missed the input ([`MISS_SPACINGS`]).
    Missed,
    /// The finer of the two.
    Both,
}

/// Figures of the candidate not kept (when both routes ran).
#[derive(Clone, Debug, Serialize)]
pub struct Alternative {
    /// The route of that result.
    pub mode: Mode,
    /// Its two-sided RMS distance to the input, percent of the diagonal.
    pub rms_pct_of_diagonal: f64,
    /// Its share of irregular vertices.
    pub irregular_fraction: f64,
    /// Its Euler characteristic.
    pub euler_characteristic: i64,
    /// Its faces flipped against the input.
    pub flipped_faces: usize,
    /// Fraction of the route's working vertices farther than [`MISS_SPACINGS`] final spacings from it.
    pub missed_fraction: f64,
    /// Its crossing triangle pairs ([`QuadStats::crossing_pairs`]).
    pub crossing_pairs: Option<usize>,
}

/// One re-extraction of a route's kept attempt with its position singularities cancelled.
#[derive(Clone, Debug, Default, Serialize)]
pub struct CancelTrial {
    /// The route whose attempt was extracted again.
    pub mode: Option<Mode>,
    /// Largest path cost allowed ([`integer::TRIES`]).
    pub path_cost: f64,
    /// Paths could end in a cone (a triangle where the cross field turns).
    pub into_cones: bool,
    /// Position singularities before and after the cancellation.
    pub counts: integer::CancelCounts,
    /// Position fields re-solved at a finer spacing to bring the count back.
    pub rescales: usize,
    /// Vertices of the finished result (predicted when it was not finished: count off by more than
    /// [`CANCEL_COUNT_TOLERANCE`], not closed and manifold, or χ lost).
    pub vertices: usize,
    /// Irregular vertices of the cleaned-up result (0 when it was not cleaned up: count, χ or manifold
    /// lost).
    pub irregular_fraction: f64,
    /// Two-sided RMS of the fitted result (0 when it was not fitted).
    pub rms_pct_of_diagonal: f64,
    /// Share of the working vertices the fitted result missed (0 when it was not fitted; see
    /// [`MISSED_MAX`]).
    pub missed_fraction: f64,
    /// The result was fitted and weighed: it had fewer irregular vertices than the extraction as it was,
    /// and every try with fewer still was refused.
    pub fitted: bool,
    /// This result replaced the one extracted as it was.
    pub kept: bool,
}

/// What [`remesh`] did and measured. Keys are the JSON keys.
#[derive(Clone, Debug, Default, Serialize)]
pub struct RemeshReport {
    /// Vertices asked for.
    pub target_vertices: usize,
    /// Referenced vertices of the input.
    pub input_vertices: usize,
    /// Faces of the input.
    pub input_faces: usize,
    /// Surface area of the input.
    pub input_area: f64,
    /// Euler characteristic of the input.
    pub input_euler_characteristic: i64,
    /// Face-connected pieces of the input; the output has as many (extra pieces the extraction pinches off
    /// are dropped and counted in `cleanup.components_dropped`).
    pub input_components: usize,
    /// Vertices of the working copy the fields were solved on.
    pub working_vertices: usize,
    /// "as-is", "decimated" or "subdivided ×k".
    pub working_mesh: String,
    /// Levels of the multi-resolution hierarchy.
    pub hierarchy_levels: usize,
    /// Working vertices within reach of a thin part or a narrow gap (a finite thickness; measured only when an
    /// adaptive route ran; 0 otherwise).
    pub thin_vertices: usize,
    /// Share of the split routes' working vertices thinner than [`SKIP_THIN_SPACINGS`] uniform split
    /// spacings (measured when the adaptive split route is on; 0 otherwise).
    pub thin_share: f64,
    /// The sizing field of the first working mesh measured (`None`: no adaptive route was on).
    pub sizing: Option<SizingSummary>,
    /// The uniform split route was not run first: `thin_share` was above [`SKIP_THIN_SHARE`], so it would
    /// have lost thin parts and the adaptive split route runs first. It runs last when no other route gave a
    /// sound result (then `alternatives` or `mode` shows it).
    pub uniform_split_skipped: bool,
    /// The adaptive split route was not run before the direct routes: `thin_share` was above
    /// [`SKIP_ADAPTIVE_THIN_SHARE`] and the direct routes are on. It runs after them when none gave a sound
    /// result.
    pub adaptive_split_skipped: bool,
    /// Working vertices farther than [`MISS_SPACINGS`] direct spacings from the direct result (measured only
    /// when the direct route ran and `refine_missed` is on; 0 otherwise).
    pub missed_vertices: usize,
    /// Fraction of the kept result's working vertices farther than [`MISS_SPACINGS`] final spacings from it
    /// (a result is sound only up to [`MISSED_MAX`]).
    pub missed_fraction: f64,
    /// Vertices of the direct routes' working mesh (0 when they did not run).
    pub direct_working_vertices: usize,
    /// Working-mesh triangles around which the orientation field turns by a non-zero multiple of 90°.
    pub orientation_singularities: usize,
    /// Coherence of the working mesh's principal directions (0 random … 1 everywhere consistent; above
    /// [`COHERENCE_TRUST_MIN`] the field follows them more closely); absent without the curvature pull.
    pub curvature_coherence: Option<f64>,
    /// True when no attempt kept the input's Euler characteristic and a closed 2-manifold quad mesh with
    /// another one was returned (handles or gaps thinner than the quad spacing closed or opened); a
    /// warning is logged too.
    pub euler_characteristic_changed: bool,
    /// What the valence pass changed on the kept result.
    pub valence_optimization: quadify::ValenceCounts,
    /// What the dipole transport changed on the kept result ([`dipoles`]).
    pub dipole_transport: dipoles::TransportCounts,
    /// What the least-squares fit to the input did on the kept result.
    pub fit: fit::FitCounts,
    /// The other routes' results when more than one ran, for comparison.
    pub alternatives: Vec<Alternative>,
    /// The mode of the attempt kept.
    pub mode: Option<Mode>,
    /// Re-extractions of each split route's kept attempt with position singularities cancelled.
    pub cancellation: Vec<CancelTrial>,
    /// Every extraction, in the order made.
    pub attempts: Vec<Attempt>,
    /// Index of the attempt kept.
    pub chosen_attempt: usize,
    /// Extracted vertices snapped together.
    pub snapped_vertices: usize,
    /// Extracted vertices of valence below 3 removed.
    pub low_valence_vertices_removed: usize,
    /// Dangling extracted edges removed.
    pub dangling_edges_removed: usize,
    /// Extracted vertices that pinched two faces, removed.
    pub pinch_vertices_removed: usize,
    /// What the clean-up changed on the kept result.
    pub cleanup: quadify::CleanupCounts,
    /// The final pure-quad mesh.
    pub output: QuadStats,
    /// Vertex count error: (output − target) / target.
    pub vertex_count_error: f64,
    /// Two-sided distance of the output (its quads split into triangles) to the input.
    pub distance: Option<DistanceReport>,
    /// Seconds per phase.
    pub seconds: BTreeMap<String, f64>,
}

/// Quality figures of a polygon mesh; with `input` (mesh and its BVH) also the flipped-face count.
///
/// Cost: O(H log H) for H corners, plus one closest-point query per face with `input`.
pub fn quad_stats(mesh: &PolyMesh, input: Option<(&TriMesh, &TriangleBvh)>) -> QuadStats {
    let topo = TopologyReport::compute(mesh);
    let p: Vec<V3> = mesh.positions.iter().map(|&x| wide(x)).collect();
    let mut st = QuadStats {
        vertices: topo.referenced_vertices,
        faces: topo.faces,
        faces_by_degree: topo.faces_by_degree.clone(),
        closed: topo.closed,
        boundary_edges: topo.boundary_edges,
        boundary_loops: topo.boundary_loops,
        nonmanifold_edges: topo.nonmanifold_edges,
        nonmanifold_vertices: topo.nonmanifold_vertices,
        components: topo.components,
        euler_characteristic: topo.euler_characteristic,
        ..Default::default()
    };
    st.quad_fraction = *topo.faces_by_degree.get(&4).unwrap_or(&0) as f64 / topo.faces.max(1) as f64;
    let edges = polygon::unique_edges(mesh.faces());
    let mut valence = vec![0usize; p.len()];
    let mut lengths = Vec::with_capacity(edges.len());
    for &(a, b) in &edges {
        valence[a as usize] += 1;
        valence[b as usize] += 1;
        lengths.push(vec3::norm(sub(p[a as usize], p[b as usize])));
    }
    let mut referenced = vec![false; p.len()];
    for &v in mesh.corner_indices() {
        referenced[v as usize] = true;
    }
    st.min_valence = usize::MAX;
    for (v, &k) in valence.iter().enumerate() {
        if referenced[v] {
            *st.valence_histogram.entry(k).or_insert(0) += 1;
            st.min_valence = st.min_valence.min(k);
            if k != 4 {
                st.irregular_vertices += 1;
            }
        }
    }
    if st.min_valence == usize::MAX {
        st.min_valence = 0;
    }
    st.irregular_fraction = st.irregular_vertices as f64 / st.vertices.max(1) as f64;
    let mut dev = Vec::new();
    for f in mesh.faces() {
        if f.len() != 4 {
            continue;
        }
        for k in 0..4 {
            let c = p[f[k] as usize];
            let a = sub(p[f[(k + 3) % 4] as usize], c);
            let b = sub(p[f[(k + 1) % 4] as usize], c);
            let (na, nb) = (vec3::norm(a), vec3::norm(b));
            if na > 0.0 && nb > 0.0 {
                let cos = (dot(a, b) / (na * nb)).clamp(-1.0, 1.0);
                dev.push((cos.acos().to_degrees() - 90.0).abs());
            }
        }
    }
    if !dev.is_empty() {
        st.angle_deviation_mean_deg = dev.iter().sum::<f64>() / dev.len() as f64;
        st.angle_deviation_p95_deg = percentile(&mut dev, 0.95);
    }
    if !lengths.is_empty() {
        let mean = lengths.iter().sum::<f64>() / lengths.len() as f64;
        let var = lengths.iter().map(|l| (l - mean) * (l - mean)).sum::<f64>() / lengths.len() as f64;
        st.edge_length_mean = mean;
        st.edge_length_cv = if mean > 0.0 { var.sqrt() / mean } else { 0.0 };
    }
    if let Some((input, bvh)) = input {
        let ip: Vec<V3> = input.positions.iter().map(|&x| wide(x)).collect();
        for f in mesh.faces() {
            // Polygon normal (Newell) and centre.
            let mut nrm = [0.0; 3];
            let mut c = [0.0; 3];
            for k in 0..f.len() {
                let (a, b) = (p[f[k] as usize], p[f[(k + 1) % f.len()] as usize]);
                nrm = vec3::add(nrm, cross(a, b));
                c = vec3::add(c, a);
            }
            c = vec3::scale(c, 1.0 / f.len() as f64);
            if let Some(cl) = bvh.closest(c) {
                let tn = vec3::tri_cross(&ip, input.triangles[cl.index as usize]);
                if dot(tn, nrm) < 0.0 {
                    st.flipped_faces += 1;
                }
            }
        }
        let (t, _) = mesh.triangulate();
        st.crossing_pairs = Some(crate::geometry::intersect::self_intersections(&p, &t.triangles).len());
    }
    st
}

/// What the sizing field asked for (thickness and curvature on the split routes' working
/// mesh, `stages/remesh/sizing.rs`), spacings in the input's units.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct SizingSummary {
    /// The uniform spacing the field was measured against (the split route's lattice step √(4·area / target)).
    pub uniform_spacing: f64,
    /// The smallest spacing asked for (the floor: [`super::MIN_SPACING_FACTOR`] of the uniform one at least).
    pub min_spacing: f64,
    /// The area-weighted median spacing asked for.
    pub median_spacing: f64,
    /// Share of the working area whose thickness asks for a spacing finer than the uniform one.
    pub thin_share: f64,
    /// Share of the working area whose curvature (not its thickness) asks for a finer spacing.
    pub curved_share: f64,
    /// Wall seconds of the rays and the curvature.
    pub seconds: f64,
}

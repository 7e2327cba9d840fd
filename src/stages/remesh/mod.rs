//! **remesh** — field-aligned pure-quad remeshing (the Instant Meshes core, Jakob et al. 2015, followed by a
//! clean-up that guarantees a closed pure-quad mesh).
//!
//! Steps, each counted in [`RemeshReport`]:
//! 1. a working copy of the input at a resolution suited to the target: very dense inputs are decimated
//!    (QEM) to about [`WORK_PER_VERTEX`] vertices per output vertex, coarse ones are subdivided;
//! 2. a multi-resolution hierarchy ([`hierarchy`]);
//! 3. the extrinsic 4-RoSy orientation field, coarse to fine, pulled toward principal curvature directions
//!    where the curvature is clearly anisotropic, and harder where those directions agree over the whole
//!    surface ([`COHERENT_PULL`]; [`field`]);
//! 4. the 4-PoSy position field at lattice spacing `scale`;
//! 5. extraction of a quad-dominant mesh ([`extract`]), closed by construction;
//! 6. clean-up to a pure-quad mesh ([`quadify`]) by up to four routes, each tried only when every earlier
//!    result lost something (RMS above [`FALLBACK_TRIGGER_PCT`], more than [`MISSED_MAX`] of the working
//!    vertices missed, χ changed or a face flipped): the
//!    *split* route extracts at a quarter of the count, pairs triangles along straight strips and splits
//!    every n-gon into n quads (regular, but features thinner than twice the spacing can vanish; skipped
//!    where many are, [`SKIP_THIN_SHARE`]); the
//!    *adaptive split* route does the same with a finer spacing on thin parts and narrow gaps
//!    ([`thickness`], [`spacing_field`]); the *direct* route extracts at the full count and pairs every
//!    triangle along straight strips or bent paths, on its own finer working mesh
//!    ([`WORK_PER_VERTEX_DIRECT`]); the *refined direct* route does the same with a finer spacing on thin
//!    parts or where the direct result missed the input ([`REFINE_TRIES`]). A later result is kept only
//!    when it keeps χ and has no
//!    flipped face where the earlier does not, or the earlier one is more than [`FIDELITY_RATIO`] times
//!    farther from the input;
//!
//!    On the split routes, the kept attempt is extracted again with its position singularities cancelled
//!    in pairs, or into cones, on the integer edge steps ([`integer::TRIES`]), the count steered by
//!    re-solving the position field ([`CANCEL_RESCALES`]); that result replaces the first when it is as
//!    sound, within the vertex-count
//!    tolerance, has fewer irregular vertices and its RMS grows by at most [`CANCEL_TRADE`] times their
//!    relative drop ([`CANCEL_RMS_SLACK`] at most); only tries with fewer irregular vertices are fitted,
//!    fewest first, until one is kept. Every try is reported (`cancellation`);
//! 7. a valence pass (diagonal collapses and edge rotations that lower Σ|valence − 4|), then dipole
//!    transport ([`dipoles`]: chains of up to [`dipoles::TRANSPORT_DEPTH`] cost-neutral rotations, vertex
//!    splits and diagonal collapses that move a valence 3–5 pair until it cancels another, committed only
//!    when the chain ends in a strict drop of Σ|valence − 4| and leaves no quad folded), then projection
//!    onto the input surface (onto triangles facing the same way) and tangential relaxation;
//! 8. a least-squares fit of the vertices to the input, both ways ([`fit`]), on every route's result
//!    before the routes are weighed.
//!
//! **How the vertex count is matched.** The split in step 6 turns a quad-dominant mesh with V vertices,
//! E edges and F faces into a pure-quad mesh with exactly V + E + F vertices (≈ 4V). The split route
//! therefore extracts at a quarter of the target; both routes repeat the extraction with the spacing
//! scaled by √(predicted / target) until the count is within [`COUNT_TOLERANCE`] (at most [`MAX_ATTEMPTS`] /
//! [`MAX_DIRECT_ATTEMPTS`] extractions). Attempts must be closed, edge-manifold and keep the input's Euler
//! characteristic; after [`PATIENCE`] attempts, or when none does, one that changes it is accepted and
//! flagged (`euler_characteristic_changed`).
//!
//! The stage needs a closed 2-manifold triangle mesh (`remesh.input-not-closed` otherwise: run `repair`
//! first). It is deterministic for a fixed seed, whatever the number of threads: the fields are updated by
//! colour classes, each class in parallel from the previous values of the other classes.

pub mod dipoles;
pub mod extract;
pub mod field;
pub mod fit;
pub mod hierarchy;
pub mod integer;
pub mod quadify;

use std::collections::{BTreeMap, HashMap};
use std::time::Instant;

use rayon::prelude::*;
use serde::Serialize;

use crate::error::{Error, ErrorCode, Result};
use crate::geometry::bvh::TriangleBvh;
use crate::geometry::decimate::{Crossings, decimate};
use crate::geometry::mesh::{Geometry, PolyMesh, TriMesh};
use crate::geometry::polygon;
use crate::geometry::sampling::{Rng, sample_area_uniform};
use crate::geometry::stats::percentile;
use crate::geometry::topology::TopologyReport;
use crate::geometry::vec3::{self, V3, cross, dot, sub, wide};
use crate::stages::Progress;
use crate::stages::quality::{CompareOptions, DistanceReport, compare};

/// Thickness, in uniform split spacings (`√(4·area / target)`), below which a working vertex counts toward
/// [`RemeshReport::thin_share`].
pub const SKIP_THIN_SPACINGS: f64 = 0.75;

/// The uniform split route is skipped when more than this share of the working vertices is thinner than
/// [`SKIP_THIN_SPACINGS`] spacings. Measured at 10k (seed 0), share / the uniform split's missed share
/// (sound at most [`MISSED_MAX`]): igea 0.07 % / 0, repaired bunny 0.11 % / 0, fandisk 0 / 0.02 %, spot
/// 0.48 % / 0.19 % (all sound, kept); armadillo 2.05 % / 1.53 %, repaired dragon 5.6 % / 2.4 % (unsound;
/// the adaptive or a direct route was kept): skipping there saves two field solves and a finish (a quarter
/// of the dragon's CPU time) and changes no output byte (seeds 0–2).
pub const SKIP_THIN_SHARE: f64 = 0.01;

/// With the direct routes on, the adaptive split route runs after them (not before) when more than this share
/// of the working vertices is thinner than [`SKIP_THIN_SPACINGS`] uniform split spacings. Measured at 10k
/// (seed 0): the repaired dragon 5.6 %, whose adaptive split results miss 0.6–1.1 % of their working vertices
/// (RMS 0.11–0.15 %; never kept, the refined direct route is): skipping it saves three field solves and a
/// finish; the armadillo 2.05 %, whose adaptive split is kept (4.6 % irregular, RMS 0.054 %).
pub const SKIP_ADAPTIVE_THIN_SHARE: f64 = 0.04;

/// Working vertices per output vertex the working mesh is decimated to (Instant Meshes needs input edges
/// shorter than half the spacing, i.e. at least 4).
pub const WORK_PER_VERTEX: f64 = 6.0;
/// Relative tolerance on the final vertex count before another extraction is tried.
pub const COUNT_TOLERANCE: f64 = 0.03;
/// Largest relative error of the final vertex count a result may have and still be preferred to one that keeps
/// the count but loses something (issue 4's ±10 %). Regression `thin_torus_at_771_keeps_its_count`: on a torus
/// thinner than the spacing everywhere, the adaptive split's spacing sits at its floor and every attempt
/// gives 900 vertices for a target of 771 (+17 %); that sound result was kept over the uniform split's (758).
pub const COUNT_LIMIT: f64 = 0.10;

/// Most extractions tried while matching the vertex count.
pub const MAX_ATTEMPTS: usize = 8;

/// Settings of [`remesh`].
#[derive(Clone, Debug)]
pub struct RemeshOptions {
    /// Final vertex count wanted (of the pure-quad mesh).
    pub target_vertices: usize,
    /// Seed of the random initial fields.
    pub seed: u64,
    /// Also extract at the full target spacing (triangles paired along quad strips and bent paths) when the
    /// split routes lost something, and keep that result when it is much closer to the input
    /// ([`FIDELITY_RATIO`]). Keeps thin features; costs another field solve and more irregular vertices
    /// where it wins.
    pub try_direct: bool,
    /// Working-mesh vertices per output vertex (the working mesh is decimated or subdivided toward this).
    pub work_per_vertex: f64,
    /// The same for the direct routes, which extract at the full count ([`WORK_PER_VERTEX_DIRECT`]).
    pub work_per_vertex_direct: f64,
    /// Gauss–Seidel sweeps per hierarchy level, for each field.
    pub iterations: usize,
    /// Tangential relaxation rounds after projection.
    pub relax_iterations: usize,
    /// Rounds of the least-squares fit of the finished quad mesh to the input ([`fit`]; 0: vertices stay
    /// on the input surface).
    pub fit_rounds: usize,
    /// Weight of the principal-curvature pull (0 disables it).
    pub curvature_weight: f64,
    /// Extra pull, relative to `curvature_weight`, where the principal directions are coherent over the
    /// whole surface (tori, surfaces of revolution; [`COHERENCE_TRUST_MIN`]); 0 disables it.
    pub coherent_pull: f64,
    /// Samples per side for the distance to the input (0 skips it).
    pub compare_samples: usize,
    /// Finer spacing on parts thinner than the spacing allows ([`THIN_RATIO`]), so they are not lost.
    pub adaptive_spacing: bool,
    /// After the direct route, extract once more with the spacing refined where it missed the input
    /// ([`Mode::RefinedDirect`]); kept when it is [`FIDELITY_RATIO`] times closer to the input.
    pub refine_missed: bool,
    /// Cancel position singularities in pairs on the integer edge steps before extraction
    /// ([`integer::cancel_pairs`]).
    pub cancel_singularities: bool,
    /// Longest chain of cost-neutral operations (edge rotations, vertex splits, diagonal collapses) that
    /// moves a dipole toward one it cancels ([`dipoles::transport_dipoles`]; 0 disables the transport).
    pub dipole_depth: usize,
    /// Most bytes the stage may allocate.
    pub memory_budget: u64,
}

impl Default for RemeshOptions {
    fn default() -> Self {
        RemeshOptions {
            target_vertices: 10_000,
            seed: 0,
            work_per_vertex: WORK_PER_VERTEX,
            work_per_vertex_direct: WORK_PER_VERTEX_DIRECT,
            try_direct: true,
            iterations: 6,
            relax_iterations: 10,
            fit_rounds: fit::FIT_ROUNDS,
            curvature_weight: 1.0,
            coherent_pull: COHERENT_PULL,
            compare_samples: 200_000,
            adaptive_spacing: true,
            refine_missed: true,
            cancel_singularities: true,
            dipole_depth: dipoles::TRANSPORT_DEPTH,
            memory_budget: 8 << 30,
        }
    }
}

impl RemeshOptions {
    /// The settings the `convert` pipeline uses: the defaults without the adaptive split route. Its finer
    /// quads on thin parts fold the fitted limit surface: on the armadillo at 10k the solid then had 7
    /// folded faces and 132 crossing triangle pairs, and gmsh could not tetrahedralise it (with the direct
    /// route: 1 fold, 0 crossings). Until the surface fit copes with them, solids keep the old routes.
    ///
    /// Position singularities are cancelled as in `remesh` (conformance run of 2026-12-02: igea's solid has
    /// 450 faces instead of 553, fandisk's 356 instead of 472; every solid stays valid, unfolded and
    /// uncrossed, OpenCASCADE's largest normal angle 0.19° and 0.25°).
    ///
    /// Nor the refined direct route or the direct routes' finer working mesh (2026-12-02): on the dragon
    /// they give finer quads on its struts and slots, whose fitted surface gmsh has not been run on yet.
    ///
    /// Nor the least-squares fit of the quad mesh ([`fit`]; conformance run of 2026-12-03): from the
    /// fitted net the armadillo's limit surface had 2 folded faces and 6 crossing triangle pairs (gmsh still
    /// meshed it). The surface stage fits its own control points to the scan, so the net stays projected.
    ///
    /// Nor the dipole transport ([`dipoles`]; conformance run of 2026-12-03): the armadillo's solid came to
    /// 0.0599 % RMS from the scan by the validator (bound 0.05 %; 0.0405 % by our own measure), valid and
    /// unfolded otherwise. Until the surface fit is checked on the transported nets, solids keep the
    /// untransported ones.
    pub fn convert_default() -> Self {
        RemeshOptions {
            adaptive_spacing: false,
            refine_missed: false,
            fit_rounds: 0,
            dipole_depth: 0,
            work_per_vertex_direct: WORK_PER_VERTEX,
            ..Default::default()
        }
    }
}

/// Quality figures of a quad(-dominant) mesh.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct QuadStats {
    pub vertices: usize,
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
    pub closed: bool,
    pub boundary_edges: usize,
    pub boundary_loops: usize,
    pub nonmanifold_edges: usize,
    pub nonmanifold_vertices: usize,
    pub components: usize,
    pub euler_characteristic: i64,
    /// Faces whose normal points against the input surface's normal at the face centre.
    pub flipped_faces: usize,
    /// |corner angle − 90°| over all quad corners: mean and 95th percentile, degrees.
    pub angle_deviation_mean_deg: f64,
    pub angle_deviation_p95_deg: f64,
    /// Edge length: mean and coefficient of variation.
    pub edge_length_mean: f64,
    pub edge_length_cv: f64,
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

/// The refined direct route's tries. Each is another field solve, extraction and finish (about 2.5 s on the
/// repaired dragon at 10k); the cascade stops at the first sound result. On the dragon (seeds 0–2) the
/// direct route lost two thin struts under the hind foot (73 % of the input→quad mean square); which
/// spacing recovers them without folding a face differs from seed to seed.
pub const REFINE_TRIES: [Refine; 3] = [Refine::Thin, Refine::Missed, Refine::Both];

/// Below this curvature anisotropy ((|k1| − |k2|) / (|k1| + |k2|)) no principal direction is imposed.
pub const ANISOTROPY_MIN: f64 = 0.3;
/// Coherence of the principal directions (area-weighted mean of cos 4Δθ over rings) above which they are
/// trusted more than the smoothness ([`COHERENT_PULL`]). Measured: torus 0.999, fandisk 0.79, spot 0.53,
/// bunny 0.59, armadillo 0.47, igea 0.45.
pub const COHERENCE_TRUST_MIN: f64 = 0.9;
/// Default extra pull toward the principal directions (`RemeshOptions::coherent_pull`), relative to the
/// curvature weight, on a fully coherent surface. On the torus test (minor/major 0.4) the extrinsic
/// smoothness alone keeps 16 orientation singularities for any number of sweeps; this pull removes them.
pub const COHERENT_PULL: f64 = 10.0;

/// A later route's result replaces an earlier one of the same class (χ kept, no flipped face) when the
/// earlier one's two-sided RMS to the input is more than this many times the later one's (on the dragon the
/// adaptive split measures 0.228 % at 6.5 % irregular against the direct route's 0.155 % at 10.7 %).
pub const FIDELITY_RATIO: f64 = 1.25;

/// Share of irregular vertices a sound split result must meet to end the cascade; above it the direct routes run
/// too, and the pick keeps whichever result trades best ([`Finished::trades_well_against`]). Issue 4 asks for at
/// most 3 % on organic meshes. Measured on the armadillo at 10k, seeds 0–3 (irregular % at RMS % of the
/// diagonal): the adaptive split alone gave 4.42 @ 0.054, 4.65 (unsound; refined direct 3.81 @ 0.051),
/// 3.70 @ 0.057, 5.01 @ 0.054; with the direct routes 3.43 @ 0.049, 3.81 @ 0.051, 3.66 @ 0.053, 3.98 @ 0.058,
/// for 7–11 s instead of 4.5. The other shared meshes meet it with the split route (output bytes unchanged).
pub const IRREGULAR_GOAL: f64 = 0.03;

/// How many times an earlier result's RMS a result with `fewer` (a share) fewer irregular vertices may have:
/// 1 + [`CANCEL_TRADE`] · `fewer`, at most [`CANCEL_RMS_SLACK`].
fn rms_allowed(fewer: f64) -> f64 {
    (1.0 + CANCEL_TRADE * fewer).min(CANCEL_RMS_SLACK)
}

/// Attempts per mode after which a closed manifold attempt that changes χ is accepted.
pub const PATIENCE: usize = 3;

/// A later route (adaptive split, then direct) runs only when every earlier one's two-sided RMS exceeds this
/// percentage of the bounding-box diagonal, or it changed χ or left a face flipped: on the shared meshes the
/// uniform split measured 0.033–0.058 % where nothing is lost and 0.23–0.75 % where thin parts vanish
/// before the fit, which lowers both: since, 0.026–0.035 % (the adaptive split on the armadillo 0.054 %)
/// and 0.08–0.15 % (hence also [`MISSED_MAX`]); the threshold sits between, at the accuracy issue 4 asks
/// of the dragon (with 0.1 %, a dragon adaptive split at 0.085 % RMS counted as sound and ended the cascade:
/// a count steering tried on 2026-12-03 and not kept led there).
pub const FALLBACK_TRIGGER_PCT: f64 = 0.07;

/// A fitted result is sound only when at most this fraction of its working vertices lie farther than
/// [`MISS_SPACINGS`] final spacings from it: the fit ([`fit`]) pulls the faces next to a lost strut or
/// finger toward it, which hides much of the loss from the RMS but not from the missed vertices. Measured
/// at 10k (seeds 0–2, 2026-12-03): results that keep every feature miss 0–0.29 % (spot's split 0.22–0.29 %, the
/// armadillo's adaptive split and direct routes 0.09–0.24 %); results that lose one 0.41 % and more (the
/// dragon's direct route 0.67–0.76 % at 0.075–0.080 % RMS, its adaptive split 0.41–1.1 %, the armadillo's
/// uniform split 1.4–2.8 % with its fingers thinned).
pub const MISSED_MAX: f64 = 3e-3;

/// Passes of the valence optimisation (diagonal collapses and edge rotations) on the pure-quad mesh.
pub const VALENCE_PASSES: usize = 10;

/// Rounds of unfolding flipped faces after relaxation.
pub const UNTANGLE_ROUNDS: usize = 10;

/// Triangles left after the bounded path pairing that are paired by an unbounded search (O(F) each).
pub const PATH_UNBOUNDED_MAX: usize = 16;

/// Rounds of collapsing quads still flipped after unfolding (then unfolding again). 8 since 2026-12-02
/// (was 3): on the repaired dragon (seed 2) a refined direct result then ends with no flipped face instead
/// of 6, at little cost now that unfolding re-checks only the faces it moved.
pub const COLLAPSE_ROUNDS: usize = 8;

/// Most direct-mode extractions tried.
pub const MAX_DIRECT_ATTEMPTS: usize = 4;

/// Figures of the candidate not kept (when both routes ran).
#[derive(Clone, Debug, Serialize)]
pub struct Alternative {
    pub mode: Mode,
    pub rms_pct_of_diagonal: f64,
    pub irregular_fraction: f64,
    pub euler_characteristic: i64,
    pub flipped_faces: usize,
    /// Fraction of the route's working vertices farther than [`MISS_SPACINGS`] final spacings from it.
    pub missed_fraction: f64,
}

/// One route's kept attempt, finished (on the input surface) and measured.
struct Finished {
    /// Index of the attempt in the report.
    index: usize,
    c: Candidate,
    /// χ differs from the input's.
    changed: bool,
    out: PolyMesh,
    extra: quadify::CleanupCounts,
    /// Two-sided RMS distance to the input (0 when only one route can run).
    rms: f64,
    valence: quadify::ValenceCounts,
    dipoles: dipoles::TransportCounts,
    fit: fit::FitCounts,
    stats: QuadStats,
    /// Fraction of the route's working vertices farther than [`MISS_SPACINGS`] final spacings from `out`.
    missed: f64,
}

impl Finished {
    /// 0: χ kept and no flipped face; 1: one of them fails; 2: both.
    fn class(&self) -> u8 {
        u8::from(self.changed) + u8::from(self.stats.flipped_faces > 0)
    }

    /// Nothing lost: χ kept, no flipped face, RMS within [`FALLBACK_TRIGGER_PCT`] of the diagonal and, for a
    /// fitted result (whose RMS the fit lowers near a lost part), at most [`MISSED_MAX`] of the working
    /// vertices missed.
    fn sound(&self, diagonal: f64) -> bool {
        self.sound_within(diagonal, MISSED_MAX)
    }

    /// Fewer irregular vertices than `other` for at most [`CANCEL_TRADE`] times their relative drop in more RMS
    /// ([`CANCEL_RMS_SLACK`] at most): the trade the cancellation's tries are weighed by, also between routes.
    fn trades_well_against(&self, other: &Finished) -> bool {
        let fewer = 1.0 - self.stats.irregular_vertices as f64 / other.stats.irregular_vertices.max(1) as f64;
        fewer > 0.0 && self.rms <= rms_allowed(fewer) * other.rms
    }

    /// [`Self::sound`] with `missed_max` in place of [`MISSED_MAX`].
    fn sound_within(&self, diagonal: f64, missed_max: f64) -> bool {
        self.class() == 0
            && 100.0 * self.rms / diagonal <= FALLBACK_TRIGGER_PCT
            && (self.fit.rounds == 0 || self.missed <= missed_max)
    }
}

/// Scale of the first attempt relative to √(area / count): extraction loses a few vertices to snapping
/// and pruning, so start slightly finer.
pub const START_SCALE: f64 = 0.975;

struct Candidate {
    mode: Mode,
    ex: extract::Extracted,
    faces: Vec<Vec<u32>>,
    counts: quadify::CleanupCounts,
    by_degree: BTreeMap<usize, usize>,
    predicted: usize,
    topology_ok: bool,
}

/// Extract a candidate of route `mode` from the position field (origins `o`, spacings `s`) and clean it up to
/// the polygon mesh the route finishes: with `cancel`, position singularities are first cancelled, starting
/// from the field's own integer steps when they are given ([`extract::Extracted::steps`]).
fn candidate(
    level: &hierarchy::Level,
    q: &[V3],
    o: &[V3],
    s: &[f64],
    cancel: Option<(integer::Cancel, Option<integer::Offsets>)>,
    mode: Mode,
    components: usize,
) -> Candidate {
    let (cancel, steps) = cancel.map_or((None, None), |(c, steps)| (Some(c), steps));
    let ex = extract::extract(level, q, o, s, cancel, steps);
    let mut by_degree = BTreeMap::new();
    for f in &ex.faces {
        *by_degree.entry(f.len()).or_insert(0) += 1;
    }
    let mut faces = ex.faces.clone();
    let mut counts = quadify::CleanupCounts::default();
    counts.doublets_removed += quadify::remove_doublets(&mut faces);
    quadify::split_pinched(&mut faces, &mut counts);
    quadify::cut_large_faces(&ex.positions, &mut faces, &mut counts);
    let predicted = match mode {
        Mode::Split | Mode::AdaptiveSplit => {
            let mut extra = Vec::new();
            quadify::cut_pentagons(&ex.positions, &mut faces, &mut extra, &mut counts);
            faces.extend(extra);
            quadify::pair_triangles(&mut faces, 12, 8, &mut counts);
            counts.doublets_removed += quadify::remove_doublets(&mut faces);
            quadify::keep_largest_components(&mut faces, components, &mut counts);
            polygon::split_vertex_count(ex.positions.len(), &faces)
        }
        Mode::Direct | Mode::RefinedDirect => {
            let mut extra = Vec::new();
            quadify::cut_pentagons(&ex.positions, &mut faces, &mut extra, &mut counts);
            faces.extend(extra);
            counts.doublets_removed += quadify::remove_doublets(&mut faces);
            quadify::pair_triangles(&mut faces, 12, 8, &mut counts);
            for _ in 0..2 {
                quadify::pair_triangles_along_paths(&ex.positions, &mut faces, 60, &mut counts);
            }
            // The last few triangles may lie farther apart than 60 steps: search without a bound (each
            // search is O(F), and at most a handful are left).
            if (1..=PATH_UNBOUNDED_MAX).contains(&faces.iter().filter(|f| f.len() == 3).count()) {
                let unbounded = faces.len();
                quadify::pair_triangles_along_paths(&ex.positions, &mut faces, unbounded, &mut counts);
            }
            counts.doublets_removed += quadify::remove_doublets(&mut faces);
            quadify::keep_largest_components(&mut faces, components, &mut counts);
            counts.triangles_unpaired = faces.iter().filter(|f| f.len() == 3).count();
            if faces.iter().any(|f| f.len() != 4) {
                counts.triangles_unpaired = counts.triangles_unpaired.max(1);
            }
            let mut used = vec![false; ex.positions.len()];
            for f in &faces {
                for &v in f {
                    used[v as usize] = true;
                }
            }
            used.iter().filter(|&&u| u).count()
        }
    };
    Candidate { mode, ex, faces, counts, by_degree, predicted, topology_ok: false }
}

/// One re-extraction of a route's kept attempt with its position singularities cancelled.
#[derive(Clone, Debug, Default, Serialize)]
pub struct CancelTrial {
    pub mode: Option<Mode>,
    /// Largest path cost allowed ([`integer::TRIES`]).
    pub path_cost: f64,
    /// Paths could end in a cone (a triangle where the cross field turns).
    pub into_cones: bool,
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

/// A re-extraction with cancelled singularities is kept only when its two-sided RMS to the input is at most
/// this many times that of the extraction as it was (fewer singularities stretch some quads; measured on
/// the shared meshes at 10k: +0–13 % on igea and fandisk, +22 % on spot, +60 % on the repaired bunny,
/// whose ear tips lose a row).
pub const CANCEL_RMS_SLACK: f64 = 1.15;

/// Largest relative RMS increase accepted per relative drop of irregular vertices (igea at 10k: 38 % fewer
/// for 0.4 % more RMS is taken; spot: 18 % fewer for 21 % more is not).
pub const CANCEL_TRADE: f64 = 0.5;

/// A cancellation try may miss up to this many times the working vertices the result it would replace
/// misses (that result is sound: at most [`MISSED_MAX`]), up to [`MISSED_LOST`]. Spot's uniform split at 10k
/// (seed 0, with the settling phase of the dipole transport) misses 0.297 %, and its tries 0.335 %, 0.380 %
/// and 1.6 %: with [`MISSED_MAX`] as the bound none was kept, the uniform split counted as sound and ended
/// the cascade with 2.39 % irregular vertices. With this slack its longer-reach try is kept (1.54 %); that
/// misses more than [`MISSED_MAX`], so the cascade goes on to the adaptive split, as it did before the
/// settling phase, whose own try is kept: 1.48 %, RMS 0.0207 %.
pub const CANCEL_MISSED_SLACK: f64 = 1.15;

/// Missed share of the working vertices from which a result has surely lost a feature (the smallest such
/// measured: 0.41 %, see [`MISSED_MAX`]): no cancellation try may miss more.
pub const MISSED_LOST: f64 = 4e-3;

/// Most re-solves of the position field that steer a cancelled extraction's vertex count.
pub const CANCEL_RESCALES: usize = 2;

/// A re-extraction with cancelled singularities is kept only when its vertex count is within this
/// relative error of the target (rows are added and removed without steering the count).
pub const CANCEL_COUNT_TOLERANCE: f64 = 0.05;

/// What [`remesh`] did and measured. Keys are the JSON keys.
#[derive(Clone, Debug, Default, Serialize)]
pub struct RemeshReport {
    pub target_vertices: usize,
    pub input_vertices: usize,
    pub input_faces: usize,
    pub input_area: f64,
    pub input_euler_characteristic: i64,
    /// Face-connected pieces of the input; the output has as many (extra pieces the extraction pinches off
    /// are dropped and counted in `cleanup.components_dropped`).
    pub input_components: usize,
    /// Vertices of the working copy the fields were solved on.
    pub working_vertices: usize,
    /// "as-is", "decimated" or "subdivided ×k".
    pub working_mesh: String,
    pub hierarchy_levels: usize,
    /// Working vertices within reach of a thin part or a narrow gap (measured only when the adaptive split
    /// route ran; 0 otherwise).
    pub thin_vertices: usize,
    /// Share of the split routes' working vertices thinner than [`SKIP_THIN_SPACINGS`] uniform split
    /// spacings (measured when the adaptive split route is on; 0 otherwise).
    pub thin_share: f64,
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
    pub attempts: Vec<Attempt>,
    /// Index of the attempt kept.
    pub chosen_attempt: usize,
    pub snapped_vertices: usize,
    pub low_valence_vertices_removed: usize,
    pub dangling_edges_removed: usize,
    pub pinch_vertices_removed: usize,
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

/// Remesh a closed 2-manifold triangle mesh into a pure-quad mesh of about `opts.target_vertices` vertices.
///
/// # Errors
/// `remesh.input-not-closed` for an open, non-manifold or inconsistently oriented input;
/// `input.bad-argument` for a target below 8 or above 10⁷ vertices; `resource.memory` when the
/// estimate exceeds `opts.memory_budget`; `remesh.failed` when no attempt yields a closed 2-manifold quad
/// mesh. An attempt with the input's Euler characteristic is preferred; when none has it, the closest
/// closed manifold one is returned with `euler_characteristic_changed` set.
///
/// Cost: O(V_work · iterations · levels) for the fields, O(V_out log F_in) for projection; memory about
/// 600 bytes per working vertex plus 80 bytes per input triangle.
pub fn remesh(mesh: &TriMesh, opts: &RemeshOptions, progress: &dyn Progress) -> Result<(PolyMesh, RemeshReport)> {
    let mut report = RemeshReport { target_vertices: opts.target_vertices, ..Default::default() };

    if !(8..=10_000_000).contains(&opts.target_vertices) {
        return Err(Error::new(
            ErrorCode::InputBadArgument,
            format!("target of {} vertices is outside 8 ..= 10,000,000", opts.target_vertices),
        ));
    }
    let poly = PolyMesh::from(mesh.clone());
    let topo = TopologyReport::compute(&poly);
    if !topo.closed || topo.nonmanifold_edges > 0 || topo.nonmanifold_vertices > 0 || !topo.consistently_oriented {
        return Err(Error::new(
            ErrorCode::RemeshInputNotClosed,
            format!(
                "remesh needs a closed, oriented 2-manifold; this mesh has {} boundary edges, {} non-manifold \
                 edges, {} non-manifold vertices, {} orientation conflicts",
                topo.boundary_edges, topo.nonmanifold_edges, topo.nonmanifold_vertices, topo.orientation_conflicts
            ),
        )
        .with_hint("run `scanstation repair IN -o OUT` first"));
    }
    let work_estimate = 600
        * ((opts.work_per_vertex * opts.target_vertices as f64) as u64).max(mesh.positions.len() as u64)
        + 80 * mesh.triangles.len() as u64;
    if work_estimate > opts.memory_budget {
        return Err(Error::new(
            ErrorCode::ResourceMemoryBudget,
            format!("remesh needs about {work_estimate} bytes; the budget is {}", opts.memory_budget),
        ));
    }
    report.input_vertices = topo.referenced_vertices;
    report.input_faces = topo.faces;
    report.input_area = topo.area;
    report.input_euler_characteristic = topo.euler_characteristic;
    report.input_components = topo.components;
    let area = topo.area;

    // 1–3. Working mesh, hierarchy and orientation field.
    progress.report(0.0, "working mesh, hierarchy, orientation field");
    let t_work = Instant::now();
    let mut work_p: Vec<V3> = mesh.positions.iter().map(|&x| wide(x)).collect();
    let mut work_t = mesh.triangles.clone();
    work_p = polygon::compact(&work_p, &mut work_t);
    let want_main = (opts.work_per_vertex * opts.target_vertices as f64) as usize;
    let want_direct = (opts.work_per_vertex_direct * opts.target_vertices as f64) as usize;
    // The direct routes' working mesh when it was made on the way to the split routes' one.
    let mut staged: Option<(Vec<V3>, Vec<[u32; 3]>, String)> = None;
    let (pm, tm, label) =
        if opts.try_direct && want_direct > want_main && work_p.len() > STAGED_DECIMATION * want_direct {
            let (pf, tf, lf) = working_mesh(work_p.clone(), work_t.clone(), want_direct, opts.seed);
            let (pm, tm, _) = working_mesh(pf.clone(), tf.clone(), want_main, opts.seed);
            staged = Some((pf, tf, lf));
            (pm, tm, "decimated in two stages".to_string())
        } else {
            working_mesh(work_p.clone(), work_t.clone(), want_main, opts.seed)
        };
    let work_seconds = t_work.elapsed().as_secs_f64();
    let main = Work::build(pm, tm, label, opts);
    report.seconds.insert("working_mesh".into(), work_seconds);
    report.working_mesh = main.label.clone();
    report.working_vertices = main.p.len();
    report.hierarchy_levels = main.levels.len();
    report.curvature_coherence = main.coherence;
    report.orientation_singularities = main.orientation_singularities;
    progress.report(0.25, "position field");
    for (k, v) in &main.seconds {
        report.seconds.insert(k.to_string(), *v);
    }
    let mut clock: Instant;
    // The direct routes' working mesh (finer: WORK_PER_VERTEX_DIRECT), built when they first run.
    let mut fine: Option<Work> = None;

    // 4–6. Position field and extraction, steering the vertex count. The split route (quarter count, then
    // one regular split) always runs; with `try_direct`, extraction at the full count is the alternative,
    // kept when it is much closer to the input (it keeps features the coarser split route loses).
    let target = opts.target_vertices as f64;
    let mut t_pos = 0.0;
    let mut t_ext = 0.0;
    // The cascade: uniform split; adaptive split when that lost something; direct when both did.
    let mut modes = vec![Mode::Split];
    if opts.adaptive_spacing {
        modes.push(Mode::AdaptiveSplit);
    }
    if opts.try_direct {
        modes.push(Mode::Direct);
        if opts.refine_missed {
            modes.extend([Mode::RefinedDirect; REFINE_TRIES.len()]);
        }
    }
    if opts.adaptive_spacing {
        // The adaptive split (where it was skipped) and the uniform split once more, last, where they were
        // skipped and no later route was sound: a result of theirs may then be the only one without a
        // flipped face.
        if opts.try_direct {
            modes.push(Mode::AdaptiveSplit);
        }
        modes.push(Mode::Split);
    }
    // Working vertices the direct result missed (set when the direct route finished).
    let mut missed: Option<Vec<bool>> = None;
    let bvh = TriangleBvh::new(mesh);
    let input_p: Vec<V3> = mesh.positions.iter().map(|&x| wide(x)).collect();
    let input_geometry = Geometry::Mesh(poly);
    let diagonal = mesh.bbox().diagonal();
    // The two-sided RMS that weighs the routes and the cancellation's tries (samples on the input drawn once).
    let meter = TradeMeter::new(mesh, &bvh, TRADE_SAMPLES, opts.seed);
    // The fit's own samples of the input (not the meter's, which judge its result).
    let fit_samples: Vec<V3> = if opts.fit_rounds > 0 {
        let n = fit::FIT_SAMPLES_PER_VERTEX * opts.target_vertices;
        sample_area_uniform(mesh, n, &mut Rng::new(opts.seed ^ 0xf17)).into_iter().map(|s| s.point).collect()
    } else {
        Vec::new()
    };
    // Per mode: the best attempt with the input's χ (else the best closed manifold one), finished and
    // measured.
    let mut finished: Vec<Finished> = Vec::new();
    let mut t_finish = 0.0;
    // Local thickness of the working mesh (far side of thin parts and narrow gaps), for the adaptive route
    // and the cancellation's thin-part guard: measured once, when first needed, only as far as the coarsest
    // spacing tried could need.
    let mut thick_by: [Option<Vec<f64>>; 2] = [None, None];
    let reach = 1.5 * (area * 4.0 / target).sqrt() / THIN_RATIO;
    for (mi, &mode) in modes.iter().enumerate() {
        // A later route runs only when the earlier ones all lost something: RMS above FALLBACK_TRIGGER_PCT,
        // more than MISSED_MAX of the working vertices missed, χ changed or a face left flipped; the direct
        // routes run also when no sound result meets IRREGULAR_GOAL.
        if mi > 0
            && finished
                .iter()
                .any(|f| f.sound(diagonal) && !(mode.is_direct() && f.stats.irregular_fraction > IRREGULAR_GOAL))
        {
            break;
        }
        // The refined direct tries stop at the first one the final pick would prefer to the direct result.
        let direct = finished.iter().find(|f| f.c.mode == Mode::Direct);
        if mode == Mode::RefinedDirect
            && finished.iter().any(|f| {
                f.c.mode == Mode::RefinedDirect
                    && direct.is_some_and(|d| {
                        f.class() <= d.class() && (FIDELITY_RATIO * f.rms < d.rms || f.trades_well_against(d))
                    })
            })
        {
            continue;
        }
        let per_vertex = if mode.is_direct() { 1.0 } else { 4.0 };
        if mode == Mode::RefinedDirect && missed.as_ref().is_none_or(|m| !m.contains(&true)) {
            continue;
        }
        if mode == Mode::Split && mi > 0 && !report.uniform_split_skipped {
            continue;
        }
        // The adaptive split goes after the direct routes where even it would lose thin parts.
        if mode == Mode::AdaptiveSplit && mi == 1 && opts.try_direct && report.thin_share > SKIP_ADAPTIVE_THIN_SHARE {
            report.adaptive_split_skipped = true;
            continue;
        }
        if mode == Mode::AdaptiveSplit && mi > 1 && !report.adaptive_split_skipped {
            continue;
        }
        if mode == Mode::Split && mi == 0 && opts.adaptive_spacing {
            // Parts thinner than the uniform split's lattice spacing fold onto one lattice row: on a mesh
            // with many, that route cannot keep them, and the adaptive one runs instead.
            let t = thick_by[0]
                .get_or_insert_with(|| timed_thickness(&main.levels[0], &main.p, &main.tris, reach, &mut report));
            let s_split = (area * 4.0 / target).sqrt();
            report.thin_share =
                t.iter().filter(|&&x| x < SKIP_THIN_SPACINGS * s_split).count() as f64 / t.len().max(1) as f64;
            if report.thin_share > SKIP_THIN_SHARE {
                report.uniform_split_skipped = true;
                continue;
            }
        }
        if mode.is_direct() && report.direct_working_vertices == 0 {
            let t0 = Instant::now();
            let (pf, tf, lf) = staged.take().unwrap_or_else(|| {
                working_mesh(std::mem::take(&mut work_p), std::mem::take(&mut work_t), want_direct, opts.seed)
            });
            report.direct_working_vertices = pf.len();
            // Of the same size (an input too small to decimate either way): the split routes' one serves.
            if pf.len() != main.p.len() {
                fine = Some(Work::build(pf, tf, lf, opts));
            }
            *report.seconds.entry("direct_working_mesh".into()).or_insert(0.0) += t0.elapsed().as_secs_f64();
        }
        // The direct routes work on the finer working mesh where there is one.
        let w = if mode.is_direct() { fine.as_ref().unwrap_or(&main) } else { &main };
        let wi = usize::from(mode.is_direct() && fine.is_some());
        let (p, tris, levels, qs) = (&w.p, &w.tris, &w.levels, &w.qs);
        let thick_all = &mut thick_by[wi];
        if mode == Mode::AdaptiveSplit {
            let t = thick_all.get_or_insert_with(|| timed_thickness(&levels[0], p, tris, reach, &mut report));
            report.thin_vertices = t.iter().filter(|x| x.is_finite()).count();
        }
        // Which spacing the refined direct route tries this time (REFINE_TRIES, in order).
        let refine = (mode == Mode::RefinedDirect)
            .then(|| REFINE_TRIES[modes[..mi].iter().filter(|&&m| m == Mode::RefinedDirect).count()]);
        if refine.is_some_and(|r| r != Refine::Missed) {
            let t = thick_all.get_or_insert_with(|| timed_thickness(&levels[0], p, tris, reach, &mut report));
            report.thin_vertices = t.iter().filter(|x| x.is_finite()).count();
        }
        let thick = if mode == Mode::AdaptiveSplit { thick_all.as_deref() } else { None };
        let (miss, thin) = match refine {
            Some(Refine::Thin) => (None, thick_all.as_deref()),
            Some(Refine::Missed) => (missed.as_deref(), None),
            Some(Refine::Both) => (missed.as_deref(), thick_all.as_deref()),
            None => (None, thick),
        };
        // Spacing per working vertex for global spacing s.
        let spacing = |s: f64| -> Vec<f64> {
            match (thin, miss) {
                (Some(t), None) => spacing_field(&levels[0], t, s),
                (None, Some(m)) => refined_spacing(&levels[0], m, s),
                (Some(t), Some(m)) => {
                    let a = spacing_field(&levels[0], t, s);
                    refined_spacing(&levels[0], m, s).into_iter().zip(a).map(|(x, y)| x.min(y)).collect()
                }
                (None, None) => vec![s; levels[0].len()],
            }
        };
        let max_attempts = if mode.is_direct() { MAX_DIRECT_ATTEMPTS } else { MAX_ATTEMPTS };
        let mut s = START_SCALE * (area * per_vertex / target).sqrt();
        if thin.is_some() || miss.is_some() {
            // The finer spacing on thin parts adds vertices: start from the effective area at this spacing.
            for _ in 0..4 {
                let sp = spacing(s);
                let eff: f64 = levels[0].area.iter().zip(&sp).map(|(&a, &si)| a * (s / si).powi(2)).sum();
                s = START_SCALE * (eff * per_vertex / target).sqrt();
            }
        }
        // (count error, attempt index, candidate, its origins and spacings)
        type Kept = (f64, usize, Candidate, Vec<V3>, Vec<f64>);
        let mut best: Option<Kept> = None;
        let mut fallback: Option<Kept> = None;
        for _ in 0..max_attempts {
            progress.report((0.3 + 0.04 * report.attempts.len() as f64).min(0.75), "position field");
            let t0 = Instant::now();
            let s0 = spacing(s);
            let mut sl = field::level_spacings(levels, s0);
            let o = field::solve_position(levels, qs, &sl, opts.iterations, opts.seed);
            t_pos += t0.elapsed().as_secs_f64();
            let t0 = Instant::now();
            let mut c = candidate(&levels[0], &qs[0], &o, &sl[0], None, mode, report.input_components);
            let (chi, manifold) = polygon::polygon_check(&c.faces);
            c.topology_ok = manifold && chi == report.input_euler_characteristic;
            let usable = manifold && c.counts.triangles_unpaired == 0;
            t_ext += t0.elapsed().as_secs_f64();
            let predicted = c.predicted;
            let valid = usable && c.topology_ok;
            report.attempts.push(Attempt {
                mode,
                scale: s,
                extracted_vertices: c.ex.positions.len(),
                extracted_faces_by_degree: c.by_degree.clone(),
                triangles_unpaired: c.counts.triangles_unpaired,
                topology_ok: c.topology_ok,
                predicted_vertices: predicted,
                position_singularities: c.ex.integer,
                refine,
            });
            let err = (predicted as f64 / target - 1.0).abs();
            let index = report.attempts.len() - 1;
            if valid && best.as_ref().is_none_or(|b| err < b.0) {
                best = Some((err, index, c, o, sl.swap_remove(0)));
            } else if !valid && usable && fallback.as_ref().is_none_or(|b| err < b.0) {
                fallback = Some((err, index, c, o, sl.swap_remove(0)));
            }
            let tried = report.attempts.iter().filter(|a| a.mode == mode).count();
            // Stop when the count is met; after PATIENCE attempts, a usable one without χ will do.
            if predicted == 0
                || (valid && err <= COUNT_TOLERANCE)
                || (tried >= PATIENCE && usable && err <= COUNT_TOLERANCE)
            {
                break;
            }
            // Steer the count; an unusable attempt is retried at a slightly different spacing.
            s *= (predicted as f64 / target).sqrt() * if valid { 1.0 } else { 0.985 };
        }
        let (index, mut c, changed, o, s0) = match (best, fallback) {
            (Some((_, i, c, o, s0)), _) => (i, c, false, o, s0),
            (None, Some((_, i, c, o, s0))) => (i, c, true, o, s0),
            (None, None) => continue,
        };
        progress.report(0.8, "projection");
        let t0 = Instant::now();
        // Not on the direct route: on the repaired dragon at 10k it went from 10.7 % to 8.5 % irregular vertices
        // at +14 % RMS (0.155 → 0.176 %), which the trade rule refuses, for another field solve and finish.
        let cancel = opts.cancel_singularities && !mode.is_direct();
        let measure = |out: &PolyMesh| -> Result<f64> {
            if modes.len() == 1 && !cancel {
                return Ok(0.0);
            }
            Ok(meter.rms(out))
        };
        // The cancellation tries (below) need only this candidate, not its finished result: they may run
        // alongside the finish, and are dropped unless the result turns out sound.
        let thick_c: Option<&[f64]> = if cancel {
            Some(thick_all.get_or_insert_with(|| timed_thickness(&levels[0], p, tris, reach, &mut report)))
        } else {
            None
        };
        let input_components = report.input_components;
        let input_chi = report.input_euler_characteristic;
        // The tries of integer::TRIES in parallel (each search is sequential), then weighed in order.
        // (the try, its candidate, arranged mesh ([`arrange`]) and its figures when it was arranged, seconds
        // cancelling, seconds re-solving)
        type Arranged = (Candidate, Unfitted, QuadStats);
        type Try = (CancelTrial, Option<Arranged>, f64, f64);
        // The position field's own steps, from which the tries' cancellations start (until a re-solve).
        let field_steps = c.ex.steps.take();
        let try_cost = |reach: integer::Reach| -> Result<Try> {
            // Cancelling removes more rows than it adds: steer the count by re-solving the position
            // field at a finer spacing (at most CANCEL_RESCALES times).
            let (mut o2, mut s2) = (o.clone(), s0.clone());
            let (mut rescales, mut t_cancel, mut t_resolve) = (0, 0.0, 0.0);
            let mut c2 = loop {
                let blocked: Vec<bool> = thick_c
                    .unwrap_or_default()
                    .iter()
                    .zip(&s2)
                    .map(|(&t, &sp)| t < integer::CANCEL_THIN * sp)
                    .collect();
                let how = integer::Cancel { tris, reach, blocked: &blocked };
                let t1 = Instant::now();
                // Before a re-solve the field is the candidate's own: start from its steps.
                let steps = if rescales == 0 { field_steps.clone() } else { None };
                let c2 = candidate(&levels[0], &qs[0], &o2, &s2, Some((how, steps)), mode, input_components);
                t_cancel += t1.elapsed().as_secs_f64();
                let off = c2.predicted as f64 / target;
                if (off - 1.0).abs() <= CANCEL_COUNT_TOLERANCE || rescales == CANCEL_RESCALES || off == 0.0 {
                    break c2;
                }
                rescales += 1;
                let t1 = Instant::now();
                for x in &mut s2 {
                    *x *= off.sqrt();
                }
                let sl2 = field::level_spacings(levels, s2.clone());
                o2 = field::solve_position(levels, qs, &sl2, opts.iterations, opts.seed);
                t_resolve += t1.elapsed().as_secs_f64();
            };
            let (chi, manifold) = polygon::polygon_check(&c2.faces);
            c2.topology_ok = manifold && chi == input_chi;
            let mut trial = CancelTrial {
                mode: Some(mode),
                path_cost: reach.max_path_cost,
                into_cones: reach.into_cones,
                counts: c2.ex.integer.unwrap_or_default(),
                rescales,
                vertices: c2.predicted,
                ..Default::default()
            };
            let count_ok = (c2.predicted as f64 / target - 1.0).abs() <= CANCEL_COUNT_TOLERANCE;
            if !(count_ok && manifold && c2.counts.triangles_unpaired == 0 && c2.topology_ok) {
                return Ok((trial, None, t_cancel, t_resolve));
            }
            let u2 = arrange(&c2, &bvh, opts)?;
            let stats2 = quad_stats(&u2.mesh()?, None);
            trial.irregular_fraction = stats2.irregular_fraction;
            trial.vertices = stats2.vertices;
            Ok((trial, Some((c2, u2, stats2)), t_cancel, t_resolve))
        };
        let miss_reach = MISS_SPACINGS * report.attempts[index].scale / per_vertex.sqrt();
        let finish_this = || -> Result<_> {
            let (u, out, fitted) = finish(&c, mesh, &input_p, &bvh, &fit_samples, opts)?;
            let rms = measure(&out)?;
            let stats = quad_stats(&out, Some((mesh, &bvh)));
            // Missed working vertices: farther than MISS_SPACINGS final spacings from the result.
            let t1 = Instant::now();
            let mask = missed_mask(&out, &levels[0].p, miss_reach);
            Ok((u, out, fitted, rms, stats, mask, t1.elapsed().as_secs_f64()))
        };
        let run_tries = || -> Vec<Result<Try>> { integer::TRIES.par_iter().map(|&reach| try_cost(reach)).collect() };
        // Alongside the finish only where the result is likely sound (few thin parts, as for the uniform
        // split's skip): on the dragon's unsound split routes the dropped tries cost 12 s of --split-only's
        // 19 s (against 6.6 s without them).
        let speculate = cancel && opts.adaptive_spacing && report.thin_share <= SKIP_THIN_SHARE;
        let (finished_this, tries) = rayon::join(finish_this, || speculate.then(run_tries));
        let (Unfitted { extra, valence, dipoles, .. }, out, fitted, rms, stats, mask, t_missed) = finished_this?;
        *report.seconds.entry("missed".into()).or_insert(0.0) += t_missed;
        let missed_of = |m: &[bool]| m.iter().filter(|&&b| b).count() as f64 / m.len().max(1) as f64;
        let mut kept = Finished {
            index,
            c,
            changed,
            out,
            extra,
            rms,
            valence,
            dipoles,
            fit: fitted,
            stats,
            missed: missed_of(&mask),
        };
        // The same position field with its singularities cancelled in pairs: kept when it is sound too,
        // about as close to the input and has fewer irregular vertices. Only where this route's result is
        // sound, so the cascade ends with it. An unsound one sends the cascade on, and its cancelled form (at
        // most CANCEL_RMS_SLACK farther from the input) would rarely be picked over a later route: on the
        // dragon the four tries cost 11 s and none was. (Sound implies χ kept: `changed` is false here.)
        //
        // Only the tries with fewer irregular vertices are fitted and weighed, fewest first, until one is
        // kept: fitting every try cost a fifth of igea's time.
        let tries = (cancel && kept.sound(diagonal)).then(|| tries.unwrap_or_else(run_tries));
        if let Some(tries) = tries {
            // The tries with fewer irregular vertices than this result, fewest first (TRIES order on ties),
            // counted on the arranged mesh (settling, which only the fitted ones get, may yet collapse a quad
            // that stays flipped).
            // (irregular vertices, index in `arranged`)
            let mut order: Vec<(usize, usize)> = Vec::new();
            let mut arranged: Vec<Option<Arranged>> = Vec::new();
            let first_slot = report.cancellation.len();
            for t in tries {
                let (trial, pr, t_cancel, t_resolve) = t?;
                *report.seconds.entry("cancellation".into()).or_insert(0.0) += t_cancel;
                t_pos += t_resolve;
                if let Some((_, _, st)) = &pr
                    && st.irregular_vertices < kept.stats.irregular_vertices
                {
                    order.push((st.irregular_vertices, arranged.len()));
                }
                report.cancellation.push(trial);
                arranged.push(pr);
            }
            order.sort_unstable();
            // The first of them that, fitted, is sound and whose RMS grew by at most CANCEL_TRADE times its
            // relative drop of irregular vertices (CANCEL_RMS_SLACK at most) replaces this result.
            for (irregular, k) in order {
                let Some((c2, u2, _)) = arranged[k].take() else { continue };
                let slot = first_slot + k;
                let u2 = settle(u2, mesh, &input_p, &bvh, opts);
                let (out2, fit2) = fit_pack(&u2, mesh, &input_p, &bvh, &fit_samples, opts)?;
                let rms2 = measure(&out2)?;
                let stats2 = quad_stats(&out2, Some((mesh, &bvh)));
                let missed2 = missed_of(&missed_mask(&out2, &levels[0].p, miss_reach));
                let trial = &mut report.cancellation[slot];
                trial.fitted = true;
                trial.rms_pct_of_diagonal = 100.0 * rms2 / diagonal;
                trial.irregular_fraction = stats2.irregular_fraction;
                trial.missed_fraction = missed2;
                let f2 = Finished {
                    index,
                    c: c2,
                    changed: false,
                    out: out2,
                    extra: u2.extra,
                    rms: rms2,
                    valence: u2.valence,
                    dipoles: u2.dipoles,
                    fit: fit2,
                    stats: stats2,
                    missed: missed2,
                };
                // The trade of `trades_well_against`, on the arranged count the tries were ranked by.
                let fewer = 1.0 - irregular as f64 / kept.stats.irregular_vertices.max(1) as f64;
                let allowed = rms_allowed(fewer);
                // Sound, but measured against the result it would replace: a try may miss up to
                // CANCEL_MISSED_SLACK times as many working vertices (never more than MISSED_LOST).
                let missed_max = (CANCEL_MISSED_SLACK * kept.missed).clamp(MISSED_MAX, MISSED_LOST);
                if f2.sound_within(diagonal, missed_max) && f2.rms <= allowed * kept.rms {
                    trial.kept = true;
                    kept = f2;
                    break;
                }
            }
        }
        if mode == Mode::Direct && opts.refine_missed {
            // Where the direct result passes farther than MISS_SPACINGS spacings from the working mesh, the
            // lattice could not follow the surface (struts, fins): the refined route makes it finer there.
            report.missed_vertices = mask.iter().filter(|&&b| b).count();
            missed = Some(mask);
        }
        t_finish += t0.elapsed().as_secs_f64();
        finished.push(kept);
    }
    report.seconds.insert("position".into(), t_pos);
    report.seconds.insert("extraction".into(), t_ext);
    report.seconds.insert("projection".into(), t_finish);
    clock = Instant::now();
    if finished.is_empty() {
        return Err(Error::new(
            ErrorCode::RemeshFailed,
            format!(
                "extraction: none of {} attempts gave a closed 2-manifold quad mesh (input χ {})",
                report.attempts.len(),
                report.input_euler_characteristic
            ),
        )
        .with_hint("try more vertices (a finer spacing) or another --seed"));
    }
    // A result that keeps χ and has no flipped face beats one that does not, then one within COUNT_LIMIT of
    // the target beats one that is not, then a sound one beats one that is not; among equals a later route
    // (more irregular vertices, as a rule) wins only when the earlier one is more than FIDELITY_RATIO times
    // farther from the input, or when it has fewer irregular vertices for a small enough rise in RMS
    // (`trades_well_against`, as the cancellation's tries).
    let off_count = |f: &Finished| (f.stats.vertices as f64 / target - 1.0).abs() > COUNT_LIMIT;
    let mut pick = 0;
    for i in 1..finished.len() {
        let (a, b) = (&finished[pick], &finished[i]);
        let rank = |f: &Finished| (f.class(), off_count(f), !f.sound(diagonal));
        if rank(b) < rank(a) || (rank(b) == rank(a) && (a.rms > FIDELITY_RATIO * b.rms || b.trades_well_against(a))) {
            pick = i;
        }
    }
    for (i, other) in finished.iter().enumerate() {
        if i != pick {
            report.alternatives.push(Alternative {
                mode: other.c.mode,
                rms_pct_of_diagonal: 100.0 * other.rms / diagonal,
                irregular_fraction: other.stats.irregular_fraction,
                euler_characteristic: other.stats.euler_characteristic,
                flipped_faces: other.stats.flipped_faces,
                missed_fraction: other.missed,
            });
        }
    }
    let Finished { index: chosen_index, c: chosen, changed, out, extra, valence, dipoles, fit, stats, missed, .. } =
        finished.swap_remove(pick);
    report.missed_fraction = missed;
    report.valence_optimization = valence;
    report.dipole_transport = dipoles;
    report.fit = fit;
    if changed {
        tracing::warn!(
            input_chi = report.input_euler_characteristic,
            "remesh: no attempt kept the Euler characteristic; keeping a closed manifold one that does not"
        );
        report.euler_characteristic_changed = true;
    }
    report.chosen_attempt = chosen_index;
    let Candidate { ex, counts, mode, .. } = chosen;
    report.mode = Some(mode);
    report.snapped_vertices = ex.snapped;
    report.low_valence_vertices_removed = ex.low_valence_removed;
    report.dangling_edges_removed = ex.dangling_edges_removed;
    report.pinch_vertices_removed = ex.pinch_vertices_removed;
    report.cleanup = counts;
    report.cleanup.doublets_removed += extra.doublets_removed;
    report.cleanup.flipped_quads_collapsed = extra.flipped_quads_collapsed;

    progress.report(0.9, "measure");
    report.output = stats;
    report.vertex_count_error = report.output.vertices as f64 / target - 1.0;
    if opts.compare_samples > 0 {
        let copts = CompareOptions { samples: opts.compare_samples, seed: opts.seed, ..Default::default() };
        let d = compare(&Geometry::Mesh(out.clone()), &input_geometry, &copts, &crate::stages::NoProgress)?;
        report.distance = Some(d);
    }
    lap(&mut clock, "measure", &mut report);
    let o = &report.output;
    if !o.closed
        || o.nonmanifold_edges > 0
        || o.nonmanifold_vertices > 0
        || o.quad_fraction < 1.0
        || o.components > report.input_components
    {
        return Err(Error::new(
            ErrorCode::RemeshFailed,
            format!(
                "clean-up: the quad mesh has {} boundary edges, {} non-manifold edges, {} non-manifold vertices, \
                 {} components (input {}), faces by degree {:?}",
                o.boundary_edges,
                o.nonmanifold_edges,
                o.nonmanifold_vertices,
                o.components,
                report.input_components,
                o.faces_by_degree
            ),
        ));
    }
    progress.report(1.0, "done");
    Ok((out, report))
}

/// Direct-route working vertices per output vertex (`RemeshOptions::work_per_vertex_direct`). The direct
/// routes extract at the full count, so with [`WORK_PER_VERTEX`] their spacing spans only about 2.4 working
/// edges where the split routes' spans 4.9; on the repaired dragon at 10k the refined route then recovered the
/// struts under the hind foot at one seed of three (RMS 0.081 %), with 10 at all three (0.074–0.092 %).
pub const WORK_PER_VERTEX_DIRECT: f64 = 10.0;

/// Inputs with more than this many times the direct routes' working vertices are decimated in two stages:
/// to the direct routes' working mesh, then from it to the split routes' (on the dragon this saves a second
/// 375k-vertex decimation, 1.5 s, when the direct routes run, and costs about 0.4 s when they do not).
pub const STAGED_DECIMATION: usize = 3;

/// Mesh `p`, `tris` decimated (QEM) or midpoint-subdivided toward `want` vertices, and how ("as-is",
/// "decimated" or "subdivided ×k"). Cost: O(F log F) for the decimation.
fn working_mesh(mut p: Vec<V3>, mut tris: Vec<[u32; 3]>, want: usize, seed: u64) -> (Vec<V3>, Vec<[u32; 3]>, String) {
    let mut label = "as-is".to_string();
    if p.len() > want * 3 / 2 {
        decimate(&mut p, &mut tris, want, seed, Crossings::Ignore);
        label = "decimated".into();
    } else {
        let mut k = 0;
        while p.len() * 4 <= want * 3 / 2 && k < 4 {
            subdivide_midpoints(&mut p, &mut tris);
            k += 1;
        }
        if k > 0 {
            label = format!("subdivided ×{k}");
        }
    }
    (p, tris, label)
}

/// A working mesh with its hierarchy and orientation field.
struct Work {
    p: Vec<V3>,
    tris: Vec<[u32; 3]>,
    levels: Vec<hierarchy::Level>,
    qs: Vec<Vec<V3>>,
    /// "as-is", "decimated" or "subdivided ×k".
    label: String,
    coherence: Option<f64>,
    orientation_singularities: usize,
    seconds: Vec<(&'static str, f64)>,
}

impl Work {
    /// The input decimated (QEM) or subdivided toward `per_vertex` × the target vertex count, its hierarchy
    /// and its orientation field. Cost: O(F_in log F_in) for the decimation, O(V_work · iterations) for the
    /// field.
    /// The hierarchy and orientation field of working mesh `p`, `tris` (made by [`working_mesh`]).
    /// Cost: O(V_work · iterations).
    fn build(p: Vec<V3>, tris: Vec<[u32; 3]>, label: String, opts: &RemeshOptions) -> Work {
        let mut clock = Instant::now();
        let mut seconds = Vec::new();
        let mut lap = |name: &'static str, seconds: &mut Vec<(&'static str, f64)>| {
            seconds.push((name, clock.elapsed().as_secs_f64()));
            clock = Instant::now();
        };
        let levels = hierarchy::build(&p, &tris);
        lap("hierarchy", &mut seconds);
        let pulls: Option<Vec<_>> = (opts.curvature_weight > 0.0).then(|| {
            levels.iter().map(|l| curvature_directions(l, opts.curvature_weight, opts.coherent_pull)).collect()
        });
        let coherence = pulls.as_ref().map(|b: &Vec<(Vec<(V3, f64)>, f64)>| b[0].1);
        let bias: Option<Vec<Vec<(V3, f64)>>> = pulls.map(|b| b.into_iter().map(|(d, _)| d).collect());
        let qs = field::solve_orientation(&levels, opts.iterations, opts.seed, bias.as_deref());
        let orientation_singularities = orientation_singularities(&levels[0], &qs[0], &tris);
        lap("orientation", &mut seconds);
        Work { p, tris, levels, qs, label, coherence, orientation_singularities, seconds }
    }
}

/// A route's quad mesh before the fit: positions on the input, faces and what the clean-up counted.
struct Unfitted {
    qp: Vec<V3>,
    quads: Vec<Vec<u32>>,
    extra: quadify::CleanupCounts,
    valence: quadify::ValenceCounts,
    dipoles: dipoles::TransportCounts,
}

impl Unfitted {
    /// The mesh as stored (f32), unfitted.
    fn mesh(&self) -> Result<PolyMesh> {
        packed(&self.qp, &self.quads)
    }
}

/// Quad mesh positions (f64) and faces as the stored mesh (f32 positions).
fn packed(qp: &[V3], quads: &[Vec<u32>]) -> Result<PolyMesh> {
    PolyMesh::new(qp.iter().map(|x| x.map(|c| c as f32)).collect(), quads)
}

/// Clean up a candidate, [`arrange`] then [`settle`]: relax its polygon mesh on the input, split it to quads
/// (split mode), remove doublets, improve valences, relax again and unfold flipped faces (collapsing those
/// that stay flipped); then [`fit_pack`].
fn finish(
    c: &Candidate,
    input: &TriMesh,
    input_p: &[V3],
    bvh: &TriangleBvh,
    fit_samples: &[V3],
    opts: &RemeshOptions,
) -> Result<(Unfitted, PolyMesh, fit::FitCounts)> {
    let u = settle(arrange(c, bvh, opts)?, input, input_p, bvh, opts);
    let (out, fitted) = fit_pack(&u, input, input_p, bvh, fit_samples, opts)?;
    Ok((u, out, fitted))
}

/// The first part of the clean-up ([`finish`]), which decides the connectivity (all but the collapses of quads
/// that stay flipped): the candidate's polygon mesh relaxed on the input, split to quads (split mode), doublets
/// removed, valences improved and dipoles transported. The cancellation tries are ranked on it, so only the
/// tries that are fitted pay for [`settle`].
fn arrange(c: &Candidate, bvh: &TriangleBvh, opts: &RemeshOptions) -> Result<Unfitted> {
    if c.faces.is_empty() {
        return Err(Error::new(ErrorCode::RemeshFailed, "extraction: no face was extracted")
            .with_hint("the target may be too small for this shape; try more vertices"));
    }
    let mut coarse = c.ex.positions.clone();
    quadify::relax_and_project(&mut coarse, &c.faces, bvh, opts.relax_iterations, 0.5);
    let (qp, mut quads) = match c.mode {
        Mode::Split | Mode::AdaptiveSplit => polygon::split_to_quads(&coarse, &c.faces),
        Mode::Direct | Mode::RefinedDirect => (coarse, c.faces.clone()),
    };
    let extra = quadify::CleanupCounts { doublets_removed: quadify::remove_doublets(&mut quads), ..Default::default() };
    let mut qp = polygon::compact(&qp, &mut quads);
    let valence = quadify::optimize_valence(&mut qp, &mut quads, VALENCE_PASSES);
    // Keeps valences ≥ 3 and compacts `qp`, as the valence pass does: no doublet to remove after it.
    let dipoles = if opts.dipole_depth > 0 {
        dipoles::transport_dipoles(&mut qp, &mut quads, opts.dipole_depth, dipoles::TRANSPORT_PASSES)
    } else {
        dipoles::TransportCounts::default()
    };
    Ok(Unfitted { qp, quads, extra, valence, dipoles })
}

/// The second part of the clean-up ([`finish`]): relax the arranged mesh on the input and unfold flipped
/// faces, collapsing the quads that stay flipped (then removing doublets).
fn settle(u: Unfitted, input: &TriMesh, input_p: &[V3], bvh: &TriangleBvh, opts: &RemeshOptions) -> Unfitted {
    let Unfitted { mut qp, mut quads, mut extra, valence, dipoles } = u;
    quadify::relax_and_project(&mut qp, &quads, bvh, opts.relax_iterations, 0.5);
    let normal = |t: u32| vec3::tri_cross(input_p, input.triangles[t as usize]);
    let mut left = quadify::untangle(&mut qp, &quads, bvh, normal, UNTANGLE_ROUNDS);
    // Folds relaxation cannot undo (a sliver quad turned over on a sharp bend): collapse those quads and
    // unfold again.
    for _ in 0..COLLAPSE_ROUNDS {
        if left == 0 {
            break;
        }
        let bad = quadify::flipped_faces(&qp, &quads, bvh, &normal);
        let made = quadify::collapse_quads(&mut qp, &mut quads, &bad);
        if made == 0 {
            break;
        }
        extra.flipped_quads_collapsed += made;
        extra.doublets_removed += quadify::remove_doublets(&mut quads);
        qp = polygon::compact(&qp, &mut quads);
        // The merged corners sit at diagonal midpoints: back onto the surface (the others are on it).
        qp.par_iter_mut().for_each(|x| *x = bvh.closest(*x).map_or(*x, |c| c.point));
        left = quadify::untangle(&mut qp, &quads, bvh, normal, UNTANGLE_ROUNDS);
    }
    Unfitted { qp, quads, extra, valence, dipoles }
}

/// The cleaned-up mesh ([`settle`]) fitted to the input ([`fit`], `opts.fit_rounds` rounds, on `fit_samples`).
fn fit_pack(
    u: &Unfitted,
    input: &TriMesh,
    input_p: &[V3],
    bvh: &TriangleBvh,
    fit_samples: &[V3],
    opts: &RemeshOptions,
) -> Result<(PolyMesh, fit::FitCounts)> {
    let normal = |t: u32| vec3::tri_cross(input_p, input.triangles[t as usize]);
    let mut qp = u.qp.clone();
    let fitted = fit::fit_to_surface(&mut qp, &u.quads, fit_samples, bvh, normal, opts.fit_rounds);
    Ok((packed(&qp, &u.quads)?, fitted))
}

/// Which of `points` (a working mesh's vertices) lie farther than `reach` from the quad mesh `out`. Cost: a
/// BVH over `out`'s triangles and one closest-point query per point.
fn missed_mask(out: &PolyMesh, points: &[V3], reach: f64) -> Vec<bool> {
    let (tri, _) = out.triangulate();
    let out_bvh = TriangleBvh::new(&tri);
    points.par_iter().map(|&x| out_bvh.distance(x) > reach).collect()
}

/// Samples per side of the RMS estimate that weighs routes and cancellation tries (`TradeMeter`).
pub const TRADE_SAMPLES: usize = 50_000;

/// The two-sided RMS distance between a candidate quad mesh and the input, as `quality::compare` estimates it
/// (stratified area samples on both sides, closest-point distances, RMS of the pooled distances) but without
/// its vertex and maximum passes, with the input's samples drawn once and its BVH shared with the projection.
/// It only weighs results against each other; the report's distance comes from `compare`.
struct TradeMeter<'a> {
    input_samples: Vec<V3>,
    input_bvh: &'a TriangleBvh,
    samples: usize,
    seed: u64,
}

impl<'a> TradeMeter<'a> {
    /// Cost: O(F_in + samples).
    fn new(input: &TriMesh, input_bvh: &'a TriangleBvh, samples: usize, seed: u64) -> Self {
        let mut rng = Rng::new(seed ^ 0x7ade);
        let input_samples = sample_area_uniform(input, samples, &mut rng).into_iter().map(|s| s.point).collect();
        TradeMeter { input_samples, input_bvh, samples, seed }
    }

    /// Cost: O(F log F) for the candidate's BVH, O(samples · log) for the queries; deterministic for any
    /// thread count (the squared distances are summed in order).
    fn rms(&self, out: &PolyMesh) -> f64 {
        let (t, _) = out.triangulate();
        let out_bvh = TriangleBvh::new(&t);
        let mut rng = Rng::new(self.seed ^ 0x7adf);
        let on_out: Vec<V3> = sample_area_uniform(&t, self.samples, &mut rng).into_iter().map(|s| s.point).collect();
        let d2 =
            |bvh: &TriangleBvh, pts: &[V3]| -> Vec<f64> { pts.par_iter().map(|&p| bvh.distance(p).powi(2)).collect() };
        let a = d2(self.input_bvh, &on_out);
        let b = d2(&out_bvh, &self.input_samples);
        let n = a.len() + b.len();
        if n == 0 {
            return f64::INFINITY;
        }
        (a.iter().chain(&b).sum::<f64>() / n as f64).sqrt()
    }
}

fn lap(clock: &mut Instant, name: &str, report: &mut RemeshReport) {
    report.seconds.insert(name.to_string(), clock.elapsed().as_secs_f64());
    *clock = Instant::now();
}

/// Triangles of the working mesh around which the 4-RoSy field has a non-zero index.
fn orientation_singularities(level: &hierarchy::Level, q: &[V3], tris: &[[u32; 3]]) -> usize {
    tris.iter()
        .filter(|t| {
            let [a, b, c] = t.map(|v| v as usize);
            let k = |i: usize, j: usize| field::best_rotation(q[i], q[j], level.n[j]);
            // Rotation taking j's representative to i's, composed around a → b → c → a.
            (k(a, b) + k(b, c) + k(c, a)) % 4 != 0
        })
        .count()
}

/// Local spacing may be at most this fraction of the local thickness (a part thinner than about twice the
/// spacing can vanish in the extraction).
pub const THIN_RATIO: f64 = 0.4;

/// Working vertices farther than this many direct spacings from the direct result count as missed
/// ([`Mode::RefinedDirect`]).
pub const MISS_SPACINGS: f64 = 0.5;

/// Spacing on the missed parts, as a fraction of the global one ([`Mode::RefinedDirect`]).
pub const REFINE_FACTOR: f64 = 0.4;

/// Smallest local spacing, as a fraction of the global one.
pub const MIN_SPACING_FACTOR: f64 = 0.35;

/// Smallest local spacing in local working-mesh edge lengths (the fields need working edges shorter than
/// about half the spacing; measured on the armadillo, 2.0 left 4 flipped faces where 2.5 left none).
pub const SPACING_PER_WORK_EDGE: f64 = 2.5;

/// Largest change of the local spacing per unit distance (keeps the density graded, so the lattice bends
/// gently and few extra singularities appear).
pub const GRADATION: f64 = 0.3;

/// [`thickness`], its time added to the report's `thickness` seconds.
fn timed_thickness(
    level: &hierarchy::Level,
    p: &[V3],
    tris: &[[u32; 3]],
    reach: f64,
    report: &mut RemeshReport,
) -> Vec<f64> {
    let t0 = Instant::now();
    let t = thickness(level, p, tris, reach);
    *report.seconds.entry("thickness".into()).or_insert(0.0) += t0.elapsed().as_secs_f64();
    t
}

/// Thickness at each vertex of `level` (the working mesh `p`, `tris`): the shorter of the ray along −n to
/// the far side of the part and the ray along n across a gap to the surface facing back; infinite beyond
/// `reach`. Cost: two bounded ray casts per vertex.
fn thickness(level: &hierarchy::Level, p: &[V3], tris: &[[u32; 3]], reach: f64) -> Vec<f64> {
    let positions: Vec<[f32; 3]> = p.iter().map(|x| x.map(|c| c as f32)).collect();
    let work = TriMesh { positions, triangles: tris.to_vec() };
    let bvh = TriangleBvh::new(&work);
    (0..level.len())
        .into_par_iter()
        .map(|i| {
            let (p, n) = (level.p[i], level.n[i]);
            let eps = 1e-4 * reach;
            let inside = bvh.ray_hit(p, vec3::scale(n, -1.0), eps, reach, 1.0);
            let gap = bvh.ray_hit(p, n, eps, reach, -1.0);
            inside.unwrap_or(f64::INFINITY).min(gap.unwrap_or(f64::INFINITY))
        })
        .collect()
}

/// Spacing per vertex for global spacing `s`: `THIN_RATIO · thickness`, clamped between a floor (the larger
/// of [`MIN_SPACING_FACTOR`]·s and [`SPACING_PER_WORK_EDGE`] mean edges of the working mesh at that vertex)
/// and s, then limited to grow by at most [`GRADATION`] per unit distance from any vertex (Gauss–Seidel
/// sweeps of `s_i ≤ s_j + GRADATION·|p_i − p_j|`, alternately forward and backward, until none changes, at most 100).
fn spacing_field(level: &hierarchy::Level, thick: &[f64], s: f64) -> Vec<f64> {
    let floor = |i: usize| (MIN_SPACING_FACTOR * s).max(SPACING_PER_WORK_EDGE * mean_edge(level, i)).min(s);
    let sp: Vec<f64> = thick.iter().enumerate().map(|(i, &t)| (THIN_RATIO * t).clamp(floor(i), s)).collect();
    grade(level, sp, s)
}

/// Spacing per vertex for global spacing `s` on the refined direct route: [`REFINE_FACTOR`]·s at the
/// `missed` vertices (not below [`SPACING_PER_WORK_EDGE`] local working edges), graded as in
/// [`spacing_field`].
fn refined_spacing(level: &hierarchy::Level, missed: &[bool], s: f64) -> Vec<f64> {
    let sp: Vec<f64> = missed
        .iter()
        .enumerate()
        .map(|(i, &m)| {
            if !m {
                return s;
            }
            (REFINE_FACTOR * s).max(SPACING_PER_WORK_EDGE * mean_edge(level, i)).min(s)
        })
        .collect();
    grade(level, sp, s)
}

/// Mean length of the edges at vertex `i` of `level` (0 for an isolated vertex).
fn mean_edge(level: &hierarchy::Level, i: usize) -> f64 {
    let (mut sum, mut k) = (0.0, 0.0);
    for (j, _) in level.neighbours(i) {
        sum += vec3::norm(sub(level.p[i], level.p[j]));
        k += 1.0;
    }
    sum / f64::max(k, 1.0)
}

/// Limit `sp` to grow by at most [`GRADATION`] per unit distance from any vertex.
fn grade(level: &hierarchy::Level, mut sp: Vec<f64>, s: f64) -> Vec<f64> {
    if sp.iter().all(|&x| x >= s) {
        return sp;
    }
    let n = level.len();
    for sweep in 0..100 {
        let mut changed = false;
        for k in 0..n {
            let i = if sweep % 2 == 0 { k } else { n - 1 - k };
            for (j, _) in level.neighbours(i) {
                let c = sp[j] + GRADATION * vec3::norm(sub(level.p[i], level.p[j]));
                if c < sp[i] {
                    sp[i] = c;
                    changed = true;
                }
            }
        }
        if !changed {
            break;
        }
    }
    sp
}

/// Split every triangle into four at its edge midpoints (the surface is unchanged).
fn subdivide_midpoints(p: &mut Vec<V3>, tris: &mut Vec<[u32; 3]>) {
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

/// Principal direction of largest |curvature| per vertex with a weight for how anisotropic the curvature
/// is (0 where it is umbilic or flat). Estimated from normal variation along the 1-ring edges.
/// The principal-curvature pull of every vertex of `level`: direction and weight, plus the level's
/// coherence (see [`COHERENT_PULL`]).
///
/// The weight is `weight · a²` where the curvature is clearly anisotropic (`a` = (|k1| − |k2|) / (|k1| + |k2|)
/// above [`ANISOTROPY_MIN`]). Where the principal directions agree almost everywhere (coherence above
/// [`COHERENCE_TRUST_MIN`]: tori, cylinders, surfaces of revolution) they are trusted more: the weight gains
/// `weight · coherent_pull · trust · b²`, with `b` = |k1 − k2| / (|k1| + |k2|) (saddles count too) and
/// `trust` rising from 0 at [`COHERENCE_TRUST_MIN`] to 1 at full coherence. Scans, whose principal directions
/// are coherent only in patches (0.45–0.79 on the shared meshes), get exactly the first term.
///
/// Cost: O(E) for the shape operators, O(E) for the coherence.
fn curvature_directions(level: &hierarchy::Level, weight: f64, coherent_pull: f64) -> (Vec<(V3, f64)>, f64) {
    // (direction, weight a², saddle-aware b²)
    let dirs: Vec<(V3, f64, f64)> = (0..level.len())
        .map(|i| {
            let (pi, ni) = (level.p[i], level.n[i]);
            let x = field::tangent_unit([1.0, 0.3, 0.2], ni);
            let y = cross(ni, x);
            // Fit the 2×2 shape operator S from dn ≈ S dp over the ring (least squares via normal equations
            // of the symmetric form [a b; b c]).
            let mut m = [[0.0f64; 3]; 3];
            let mut r = [0.0f64; 3];
            let mut count = 0;
            for (j, _) in level.neighbours(i) {
                let dp = sub(level.p[j], pi);
                let dn = sub(level.n[j], ni);
                let (u, v) = (dot(dp, x), dot(dp, y));
                let (du, dv) = (dot(dn, x), dot(dn, y));
                // du = a u + b v ; dv = b u + c v
                let rows = [([u, v, 0.0], du), ([0.0, u, v], dv)];
                for (a, rhs) in rows {
                    for r0 in 0..3 {
                        for c0 in 0..3 {
                            m[r0][c0] += a[r0] * a[c0];
                        }
                        r[r0] += a[r0] * rhs;
                    }
                }
                count += 1;
            }
            if count < 3 {
                return (x, 0.0, 0.0);
            }
            let Some([a, b, c]) = solve3(m, r) else { return (x, 0.0, 0.0) };
            // Eigen-decomposition of [a b; b c].
            let half_diff = 0.5 * (a - c);
            let disc = (half_diff * half_diff + b * b).sqrt();
            let mean = 0.5 * (a + c);
            let (k1, k2) = (mean + disc, mean - disc);
            let theta = 0.5 * (2.0 * b).atan2(a - c);
            let dir = vec3::add(vec3::scale(x, theta.cos()), vec3::scale(y, theta.sin()));
            // Scale-free: how much one principal curvature dominates (0 umbilic/flat … 1 cylinder-like).
            let scale = k1.abs() + k2.abs() + 1e-30;
            let aniso = (k1.abs() - k2.abs()).abs() / scale;
            let split = (k1 - k2).abs() / scale;
            (dir, if aniso > ANISOTROPY_MIN { aniso * aniso } else { 0.0 }, split * split)
        })
        .collect();
    // Coherence of the principal directions as a cross field: the mean of cos 4Δθ over each ring (1 where
    // neighbours agree up to quarter turns, 0 for random directions), weighted by area and b².
    let (mut num, mut den) = (0.0, 0.0);
    for (i, &(di, _, bi)) in dirs.iter().enumerate() {
        let ni = level.n[i];
        let (mut sum, mut ws) = (0.0, 0.0);
        for (j, w) in level.neighbours(i) {
            let dj = field::tangent_unit(dirs[j].0, ni);
            let c = dot(di, dj).abs().max(dot(di, cross(ni, dj)).abs());
            sum += w * (8.0 * c.powi(4) - 8.0 * c * c + 1.0);
            ws += w;
        }
        if ws > 0.0 {
            num += level.area[i] * bi * (sum / ws).max(0.0);
            den += level.area[i] * bi;
        }
    }
    let coherence = if den > 0.0 { num / den } else { 0.0 };
    let trust = ((coherence - COHERENCE_TRUST_MIN) / (1.0 - COHERENCE_TRUST_MIN)).clamp(0.0, 1.0);
    let out = dirs.into_iter().map(|(d, a2, b2)| (d, weight * (a2 + coherent_pull * trust * b2))).collect();
    (out, coherence)
}

fn solve3(m: [[f64; 3]; 3], r: [f64; 3]) -> Option<[f64; 3]> {
    let det = |m: [[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let d = det(m);
    let scale_ = m.iter().flatten().map(|x| x.abs()).fold(0.0, f64::max);
    if d.abs() <= 1e-12 * scale_.powi(3) || d == 0.0 {
        return None;
    }
    let mut out = [0.0; 3];
    for k in 0..3 {
        let mut mk = m;
        for row in 0..3 {
            mk[row][k] = r[row];
        }
        out[k] = det(mk) / d;
    }
    Some(out)
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
    }
    st
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::shapes::{icosphere, torus};

    fn finest(m: &TriMesh) -> hierarchy::Level {
        let p: Vec<V3> = m.positions.iter().map(|&x| wide(x)).collect();
        hierarchy::finest_level(&p, &m.triangles)
    }

    /// Analytic oracle: on a torus the principal directions are the ring and tube directions, so they are
    /// coherent (close to 1) and the coherent pull is on; on a sphere (umbilic everywhere) the estimated
    /// directions are noise, the coherence is low and the weights are exactly the plain ones.
    #[test]
    fn principal_directions_are_coherent_on_a_torus_and_not_on_a_sphere() {
        let t = finest(&torus(1.0, 0.4, 120, 48));
        let (pull, coherence) = curvature_directions(&t, 1.0, COHERENT_PULL);
        assert!(coherence > 0.99, "torus coherence {coherence}");
        // On the tube's top circle the ring direction (about ±z × radial) is a principal direction.
        let mut top = 0;
        for (i, &(d, w)) in pull.iter().enumerate() {
            let p = t.p[i];
            if p[2] > 0.399 {
                top += 1;
                let ring = field::tangent_unit([-p[1], p[0], 0.0], t.n[i]);
                let c = dot(d, ring).abs().max(dot(d, cross(t.n[i], ring)).abs());
                assert!(c > 0.99, "vertex {i} at {p:?}: direction {d:?} is {c} from the ring");
                assert!(w > 5.0, "vertex {i}: pull {w}, the coherent term missing");
            }
        }
        assert_eq!(top, 120, "one top-circle vertex per ring step");
        let (off, _) = curvature_directions(&t, 1.0, 0.0);
        assert!(off.iter().all(|&(_, w)| w <= 1.0), "without the coherent pull every weight is a² ≤ 1");
        let s = finest(&icosphere(1.0, 4, [0.0; 3]));
        let (pull, coherence) = curvature_directions(&s, 1.0, COHERENT_PULL);
        let (plain, _) = curvature_directions(&s, 1.0, 0.0);
        assert!(coherence < COHERENCE_TRUST_MIN, "sphere coherence {coherence}");
        assert!(pull.iter().zip(&plain).all(|(a, b)| a.1 == b.1), "sphere: weights changed by the coherent pull");
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(24))]
        /// Invariants: the coherence lies in [0, 1] and does not depend on where the torus sits or how it
        /// is turned (the shape operator is fitted in each vertex's own tangent frame); the weights are
        /// never negative and never below the plain ones.
        #[test]
        fn coherence_is_a_rigid_motion_invariant(
            minor in 0.2f64..0.6,
            angle in 0.0f64..std::f64::consts::TAU,
            shift in -5.0f64..5.0,
        ) {
            let base = torus(1.0, minor, 90, 36);
            let (c, s) = (angle.cos(), angle.sin());
            let mut moved = base.clone();
            for p in &mut moved.positions {
                let (x, y, z) = (p[0] as f64, p[1] as f64, p[2] as f64);
                // A turn about the x axis, then a shift.
                *p = [(x + shift) as f32, (c * y - s * z) as f32, (s * y + c * z + shift) as f32];
            }
            let (w0, c0) = curvature_directions(&finest(&base), 1.0, COHERENT_PULL);
            let (w1, c1) = curvature_directions(&finest(&moved), 1.0, COHERENT_PULL);
            proptest::prop_assert!((0.0..=1.0).contains(&c0), "coherence {}", c0);
            proptest::prop_assert!((c0 - c1).abs() < 1e-3, "coherence {} moved {}", c0, c1);
            let (plain, _) = curvature_directions(&finest(&base), 1.0, 0.0);
            for ((a, b), p) in w0.iter().zip(&w1).zip(&plain) {
                proptest::prop_assert!(a.1 >= p.1 && p.1 >= 0.0, "weight {} below plain {}", a.1, p.1);
                proptest::prop_assert!((a.1 - b.1).abs() < 1e-2 * (1.0 + a.1), "weight {} moved {}", a.1, b.1);
            }
        }

        /// Invariants of the refined direct route's spacing, for any set of missed vertices: never above
        /// the global spacing, graded (across every edge it changes by at most GRADATION times the edge's
        /// length), and, on this sphere of nearly even edges where every vertex has about the same floor
        /// (REFINE_FACTOR · s or SPACING_PER_WORK_EDGE local edges), never below it and at it on every
        /// missed vertex.
        #[test]
        fn refined_spacing_is_bounded_and_graded(every in 2usize..40, offset in 0usize..40, s in 0.05f64..0.5) {
            let l = finest(&icosphere(1.0, 3, [0.0; 3]));
            let missed: Vec<bool> = (0..l.len()).map(|i| (i + offset) % every == 0).collect();
            let sp = refined_spacing(&l, &missed, s);
            for i in 0..l.len() {
                let floor = (REFINE_FACTOR * s).max(SPACING_PER_WORK_EDGE * mean_edge(&l, i)).min(s);
                proptest::prop_assert!(sp[i] <= s + 1e-12 && sp[i] >= floor.min(s) - 1e-12, "vertex {}: {} (s {}, floor {})", i, sp[i], s, floor);
                if missed[i] {
                    proptest::prop_assert!((sp[i] - floor).abs() < 1e-12, "missed vertex {}: {} not its floor {}", i, sp[i], floor);
                }
                for (j, _) in l.neighbours(i) {
                    let d = vec3::norm(sub(l.p[i], l.p[j]));
                    proptest::prop_assert!(sp[i] <= sp[j] + GRADATION * d + 1e-12, "edge {}–{}: {} vs {} over {}", i, j, sp[i], sp[j], d);
                }
            }
            // Nothing missed: the uniform spacing.
            let none = refined_spacing(&l, &vec![false; l.len()], s);
            proptest::prop_assert!(none.iter().all(|&x| x == s));
        }
    }
}

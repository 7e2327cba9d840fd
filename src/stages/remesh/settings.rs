//! The settings of [`remesh`](super::remesh) and its measured constants, grouped by the phase that uses them.

use super::report::Refine;
use super::{dipoles, fit};

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
    /// The caller makes a result that is sound but far from the input again at a higher count (`convert`'s
    /// deviation goal): the routes after the direct ones (the last uniform split) run only when no result
    /// is sound apart from its distance (no flipped face, no crossing, the input's χ). On the nine shared
    /// meshes the last split was never kept where the direct net was sound (dragon, falcon at 10k: 0.31 %
    /// and 4.2 % against 0.15 % and 0.11 %), and cost about 3 s each.
    pub far_is_raised: bool,
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
            far_is_raised: false,
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

// ---- Working meshes (steps 1–3)

/// Working vertices per output vertex the working mesh is decimated to (Instant Meshes needs input edges
/// shorter than half the spacing, i.e. at least 4).
pub const WORK_PER_VERTEX: f64 = 6.0;

/// Direct-route working vertices per output vertex (`RemeshOptions::work_per_vertex_direct`). The direct
/// routes extract at the full count, so with [`WORK_PER_VERTEX`] their spacing spans only about 2.4 working
/// edges where the split routes' spans 4.9; on the repaired dragon at 10k the refined route then recovered the
/// struts under the hind foot at one seed of three (RMS 0.081 %), with 10 at all three (0.074–0.092 %).
pub const WORK_PER_VERTEX_DIRECT: f64 = 10.0;

/// The direct routes' working-mesh edges longer than this share of their lattice step are split
/// ([`crate::geometry::polygon::split_long_edges`]), as Instant Meshes splits its input's edges longer than
/// half its scale: the position field rounds each edge's step to the lattice, and edges of more than half a
/// step skip lattice points. Measured on the repaired scorpion at 10k (2026-12-06): its 50k-vertex input was
/// the direct route's working mesh as it is (short of the midpoint subdivision's threshold), 2.2 edges to a
/// step; its extraction made 4,429 vertices for 10,000, and its result missed 61 % of the working vertices
/// (RMS 6.8 % of the diagonal), so `convert` kept the split route's net, which lost the legs (the solid: 253
/// crossing pairs, RMS 0.54 %). With the split: the direct result misses 0.4 %, its net has no crossing, and
/// the solid passes every gate (RMS 0.024 %). A working mesh not decimated (the input as it is, or
/// subdivided) is split, also when it has as many vertices as asked or more: the falcon at 15,000 was
/// subdivided once to 104k vertices for 90k asked, and unsplit its in-plane cap's long triangles kept edges
/// of more than half a step; the direct extraction then made 6,728 vertices for 15,000 (2,542 at a finer
/// spacing), crossed in 450 pairs and the split route's net was kept (RMS 0.222 % of the diagonal); split
/// (272k vertices) the direct net is 0.070 %, without a crossing (2026-12-07). A decimated one is not split:
/// splitting the dragon's raised the `remesh` default's RMS from 0.050 to 0.061 % and its irregular
/// vertices at seed 2 from 5.29 to 6.03 %. The split routes' working mesh is not split (4.9 edges a step).
pub const WORK_EDGE_SPACINGS: f64 = 0.5;

/// On a working mesh whose long edges were split ([`WORK_EDGE_SPACINGS`]: about two edges a lattice step), the
/// direct routes' extraction refuses an offset-0 join of two clusters already linked by a unit offset
/// (Instant Meshes' collapse rule; [`super::extract`]). There the rounding of neighbouring edges disagrees
/// often enough that chains of joins swallow rows: on the repaired skull at 10k, seed 0, the direct net
/// crosses itself in 3 triangle pairs without the rule and in none with it (scorpion: 0 and 0). Elsewhere
/// the plain joins stay: on the split routes the rule raised the irregular vertices (torus test 26 instead
/// of at most 20, igea 2.17 % instead of 1.63 %), and on the dragon's decimated direct working mesh (3.2
/// edges a step) the `remesh` default's result at seed 1 missed 0.97 % of the working vertices with it.
pub const LINKED_GUARD: bool = true;

/// Passes of [`WORK_EDGE_SPACINGS`]' edge splitting (each halves the longest edges).
pub const WORK_SPLIT_PASSES: usize = 4;

/// A decimated working mesh's edges longer than this many √(area / vertices) are split (a uniform mesh's
/// edges are about 1.5): on a flat face the quadric error of every inner vertex is zero, so decimation keeps
/// only the face's rim. The oracle block of `tests/oracles.rs` (2 × 1 × 1, chamfered, 524k uniform
/// triangles' vertices) kept 60,000 working vertices on its edges and none inside its faces: the direct
/// route's lattice had nothing to stand on and the net had 8 vertices (volume −41.7 %). A scan's noise gives
/// its flat parts a quadric, so few of its edges are this long.
pub const DECIMATED_LONG_EDGE: f64 = 4.0;

/// A decimated working mesh is split ([`DECIMATED_LONG_EDGE`]) only when more than this share of its area lies
/// in such long triangles.
pub const FLAT_RIM_SHARE: f64 = 0.1;

/// Passes of the splitting of a decimated mesh's long edges (each halves them; a face's edge of 2 units to
/// 0.05 takes 6).
pub const DECIMATED_SPLIT_PASSES: usize = 12;

/// The edge splitting stops once the working mesh holds this many times the vertices it was made for.
pub const WORK_SPLIT_GROWTH: f64 = 4.0;

/// Inputs with more than this many times the direct routes' working vertices are decimated in two stages:
/// to the direct routes' working mesh, then from it to the split routes' (on the dragon this saves a second
/// 375k-vertex decimation, 1.5 s, when the direct routes run, and costs about 0.4 s when they do not).
pub const STAGED_DECIMATION: usize = 3;

// ---- Orientation field: the principal-curvature pull

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

// ---- Spacing field: finer spacing on thin parts and where the direct result missed

/// The refined direct route's tries. Each is another field solve, extraction and finish (about 2.5 s on the
/// repaired dragon at 10k); the cascade stops at the first sound result. On the dragon (seeds 0–2) the
/// direct route lost two thin struts under the hind foot (73 % of the input→quad mean square); which
/// spacing recovers them without folding a face differs from seed to seed.
pub const REFINE_TRIES: [Refine; 3] = [Refine::Thin, Refine::Missed, Refine::Both];

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

// ---- Route cascade and count steering

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

/// Relative tolerance on the final vertex count before another extraction is tried.
pub const COUNT_TOLERANCE: f64 = 0.03;

/// Most extractions tried while matching the vertex count.
pub const MAX_ATTEMPTS: usize = 8;

/// Share of irregular vertices a sound split result must meet to end the cascade; above it the direct routes run
/// too, and the pick keeps whichever result trades best ([`Finished::trades_well_against`]). Issue 4 asks for at
/// most 3 % on organic meshes. Measured on the armadillo at 10k, seeds 0–3 (irregular % at RMS % of the
/// diagonal): the adaptive split alone gave 4.42 @ 0.054, 4.65 (unsound; refined direct 3.81 @ 0.051),
/// 3.70 @ 0.057, 5.01 @ 0.054; with the direct routes 3.43 @ 0.049, 3.81 @ 0.051, 3.66 @ 0.053, 3.98 @ 0.058,
/// for 7–11 s instead of 4.5. The other shared meshes meet it with the split route (output bytes unchanged).
pub const IRREGULAR_GOAL: f64 = 0.03;

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

/// Most direct-mode extractions tried.
pub const MAX_DIRECT_ATTEMPTS: usize = 4;

/// Scale of the first attempt relative to √(area / count): extraction loses a few vertices to snapping
/// and pruning, so start slightly finer.
pub const START_SCALE: f64 = 0.975;

// ---- Finish: clean-up, settling and the meter that weighs results

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

/// Samples per side of the RMS estimate that weighs routes and cancellation tries (`TradeMeter`).
pub const TRADE_SAMPLES: usize = 50_000;

// ---- Cancellation tries

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

// ---- Pick

/// Largest relative error of the final vertex count a result may have and still be preferred to one that keeps
/// the count but loses something (issue 4's ±10 %). Regression `thin_torus_at_771_keeps_its_count`: on a torus
/// thinner than the spacing everywhere, the adaptive split's spacing sits at its floor and every attempt
/// gives 900 vertices for a target of 771 (+17 %); that sound result was kept over the uniform split's (758).
pub const COUNT_LIMIT: f64 = 0.10;

/// A later route's result replaces an earlier one of the same class (χ kept, no flipped face) when the
/// earlier one's two-sided RMS to the input is more than this many times the later one's (on the dragon the
/// adaptive split measures 0.228 % at 6.5 % irregular against the direct route's 0.155 % at 10.7 %).
pub const FIDELITY_RATIO: f64 = 1.25;

//! A route's candidate and its finish: extraction and clean-up to the polygon mesh the route needs
//! ([`candidate`]), then [`arrange`] (connectivity), [`settle`] (on the input, unfolded) and [`fit_pack`];
//! what a finished route keeps ([`Finished`]), and the meter that weighs finished results against each other.

use std::collections::BTreeMap;

use rayon::prelude::*;

use std::time::Instant;

use super::report::{Mode, QuadStats, quad_stats};
use super::settings::*;
use super::{dipoles, extract, fit, hierarchy, integer, quadify};
use crate::error::{Error, ErrorCode, Result};
use crate::geometry::bvh::TriangleBvh;
use crate::geometry::mesh::{PolyMesh, TriMesh};
use crate::geometry::polygon;
use crate::geometry::sampling::{Rng, sample_area_uniform};
use crate::geometry::vec3::{self, V3};

/// How many times an earlier result's RMS a result with `fewer` (a share) fewer irregular vertices may have:
/// 1 + [`CANCEL_TRADE`] · `fewer`, at most [`CANCEL_RMS_SLACK`].
pub(super) fn rms_allowed(fewer: f64) -> f64 {
    (1.0 + CANCEL_TRADE * fewer).min(CANCEL_RMS_SLACK)
}

/// One route's kept attempt, finished (on the input surface) and measured.
pub(super) struct Finished {
    /// Index of the attempt in the report.
    pub(super) index: usize,
    pub(super) c: Candidate,
    /// χ differs from the input's.
    pub(super) changed: bool,
    pub(super) out: PolyMesh,
    pub(super) extra: quadify::CleanupCounts,
    /// Two-sided RMS distance to the input (0 when only one route can run).
    pub(super) rms: f64,
    pub(super) valence: quadify::ValenceCounts,
    pub(super) dipoles: dipoles::TransportCounts,
    pub(super) fit: fit::FitCounts,
    pub(super) stats: QuadStats,
    /// Fraction of the route's working vertices farther than [`MISS_SPACINGS`] final spacings from `out`.
    pub(super) missed: f64,
}

impl Finished {
    /// 0: χ kept, no flipped face and no crossing triangle pair; else how many of the three fail.
    pub(super) fn class(&self) -> u8 {
        u8::from(self.changed)
            + u8::from(self.stats.flipped_faces > 0)
            + u8::from(self.stats.crossing_pairs.is_some_and(|x| x > 0))
    }

    /// Nothing lost: χ kept, no flipped face, no crossing, RMS within [`FALLBACK_TRIGGER_PCT`] of the diagonal and, for a
    /// fitted result (whose RMS the fit lowers near a lost part), at most [`MISSED_MAX`] of the working
    /// vertices missed.
    pub(super) fn sound(&self, diagonal: f64) -> bool {
        self.sound_within(diagonal, MISSED_MAX)
    }

    /// Fewer irregular vertices than `other` for at most [`CANCEL_TRADE`] times their relative drop in more RMS
    /// ([`CANCEL_RMS_SLACK`] at most): the trade the cancellation's tries are weighed by, also between routes.
    pub(super) fn trades_well_against(&self, other: &Finished) -> bool {
        let fewer = 1.0 - self.stats.irregular_vertices as f64 / other.stats.irregular_vertices.max(1) as f64;
        fewer > 0.0 && self.rms <= rms_allowed(fewer) * other.rms
    }

    /// [`Self::sound`] with `missed_max` in place of [`MISSED_MAX`].
    pub(super) fn sound_within(&self, diagonal: f64, missed_max: f64) -> bool {
        self.class() == 0
            && 100.0 * self.rms / diagonal <= FALLBACK_TRIGGER_PCT
            && (self.fit.rounds == 0 || self.missed <= missed_max)
    }
}

pub(super) struct Candidate {
    pub(super) mode: Mode,
    pub(super) ex: extract::Extracted,
    pub(super) faces: Vec<Vec<u32>>,
    pub(super) counts: quadify::CleanupCounts,
    pub(super) by_degree: BTreeMap<usize, usize>,
    pub(super) predicted: usize,
    pub(super) topology_ok: bool,
}

/// What a candidate is extracted for: its route, the input's component count (the clean-up keeps as many),
/// and whether joins of clusters linked already are refused ([`LINKED_GUARD`]).
#[derive(Clone, Copy)]
pub(super) struct Extraction {
    pub(super) mode: Mode,
    pub(super) components: usize,
    pub(super) linked_guard: bool,
}

/// Extract a candidate of route `mode` from the position field (origins `o`, spacings `s`) and clean it up to
/// the polygon mesh the route finishes: with `cancel`, position singularities are first cancelled, starting
/// from the field's own integer steps when they are given ([`extract::Extracted::steps`]). `how` says the
/// route ([`Extraction`]).
pub(super) fn candidate(
    level: &hierarchy::Level,
    q: &[V3],
    o: &[V3],
    s: &[f64],
    cancel: Option<(integer::Cancel, Option<integer::Offsets>)>,
    how: Extraction,
) -> Candidate {
    let Extraction { mode, components, linked_guard } = how;
    let (cancel, steps) = cancel.map_or((None, None), |(c, steps)| (Some(c), steps));
    let ex = extract::extract(level, q, o, s, cancel, steps, linked_guard);
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

/// A route's quad mesh before the fit: positions on the input, faces and what the clean-up counted.
pub(super) struct Unfitted {
    pub(super) qp: Vec<V3>,
    pub(super) quads: Vec<Vec<u32>>,
    pub(super) extra: quadify::CleanupCounts,
    pub(super) valence: quadify::ValenceCounts,
    pub(super) dipoles: dipoles::TransportCounts,
}

impl Unfitted {
    /// The mesh as stored (f32), unfitted.
    pub(super) fn mesh(&self) -> Result<PolyMesh> {
        packed(&self.qp, &self.quads)
    }
}

/// Quad mesh positions (f64) and faces as the stored mesh (f32 positions).
pub(super) fn packed(qp: &[V3], quads: &[Vec<u32>]) -> Result<PolyMesh> {
    PolyMesh::new(qp.iter().map(|x| x.map(|c| c as f32)).collect(), quads)
}

/// Clean up a candidate, [`arrange`] then [`settle`]: relax its polygon mesh on the input, split it to quads
/// (split mode), remove doublets, improve valences, relax again and unfold flipped faces (collapsing those
/// that stay flipped); then [`fit_pack`].
pub(super) fn finish(
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
pub(super) fn arrange(c: &Candidate, bvh: &TriangleBvh, opts: &RemeshOptions) -> Result<Unfitted> {
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
pub(super) fn settle(
    u: Unfitted,
    input: &TriMesh,
    input_p: &[V3],
    bvh: &TriangleBvh,
    opts: &RemeshOptions,
) -> Unfitted {
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
pub(super) fn fit_pack(
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
pub(super) fn missed_mask(out: &PolyMesh, points: &[V3], reach: f64) -> Vec<bool> {
    let (tri, _) = out.triangulate();
    let out_bvh = TriangleBvh::new(&tri);
    points.par_iter().map(|&x| out_bvh.distance(x) > reach).collect()
}

/// The two-sided RMS distance between a candidate quad mesh and the input, as `quality::compare` estimates it
/// (stratified area samples on both sides, closest-point distances, RMS of the pooled distances) but without
/// its vertex and maximum passes, with the input's samples drawn once and its BVH shared with the projection.
/// It only weighs results against each other; the report's distance comes from `compare`.
pub(super) struct TradeMeter<'a> {
    pub(super) input_samples: Vec<V3>,
    pub(super) input_bvh: &'a TriangleBvh,
    pub(super) samples: usize,
    pub(super) seed: u64,
}

impl<'a> TradeMeter<'a> {
    /// Cost: O(F_in + samples).
    pub(super) fn new(input: &TriMesh, input_bvh: &'a TriangleBvh, samples: usize, seed: u64) -> Self {
        let mut rng = Rng::new(seed ^ 0x7ade);
        let input_samples = sample_area_uniform(input, samples, &mut rng).into_iter().map(|s| s.point).collect();
        TradeMeter { input_samples, input_bvh, samples, seed }
    }

    /// Cost: O(F log F) for the candidate's BVH, O(samples · log) for the queries; deterministic for any
    /// thread count (the squared distances are summed in order).
    pub(super) fn rms(&self, out: &PolyMesh) -> f64 {
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

/// The input side every route is finished on and measured against.
pub(super) struct InputSide<'a> {
    pub mesh: &'a TriMesh,
    /// The input's positions in double precision.
    pub p: Vec<V3>,
    pub bvh: &'a TriangleBvh,
    /// The two-sided RMS that weighs the routes and the cancellation's tries (samples on the input drawn once).
    pub meter: TradeMeter<'a>,
    /// The fit's own samples of the input (not the meter's, which judge its result).
    pub fit_samples: Vec<V3>,
    pub diagonal: f64,
    pub area: f64,
}

impl<'a> InputSide<'a> {
    /// Cost: O(F_in) for the samples.
    pub fn new(mesh: &'a TriMesh, bvh: &'a TriangleBvh, area: f64, opts: &RemeshOptions) -> Self {
        let p: Vec<V3> = mesh.positions.iter().map(|&x| vec3::wide(x)).collect();
        let diagonal = mesh.bbox().diagonal();
        let meter = TradeMeter::new(mesh, bvh, TRADE_SAMPLES, opts.seed);
        let fit_samples: Vec<V3> = if opts.fit_rounds > 0 {
            let n = fit::FIT_SAMPLES_PER_VERTEX * opts.target_vertices;
            sample_area_uniform(mesh, n, &mut Rng::new(opts.seed ^ 0xf17)).into_iter().map(|s| s.point).collect()
        } else {
            Vec::new()
        };
        InputSide { mesh, p, bvh, meter, fit_samples, diagonal, area }
    }
}

/// Two-sided RMS of `out` to the input by the route meter, or 0 where nothing is weighed (a single route
/// without cancellation).
pub(super) fn measure(input: &InputSide, weighs: bool, out: &PolyMesh) -> f64 {
    if !weighs {
        return 0.0;
    }
    input.meter.rms(out)
}

/// Quality figures of a finished route's mesh on the input.
pub(super) fn stats_on_input(input: &InputSide, out: &PolyMesh) -> QuadStats {
    quad_stats(out, Some((input.mesh, input.bvh)))
}

/// The route's finish alone ([`finish`], its RMS, figures and missed mask), for the tries' module.
pub(super) fn finish_alone(
    c: &Candidate,
    input: &InputSide,
    opts: &RemeshOptions,
    weighs: bool,
    level: &hierarchy::Level,
    miss_reach: f64,
) -> Result<FinishedAlone> {
    let (u, out, fitted) = finish(c, input.mesh, &input.p, input.bvh, &input.fit_samples, opts)?;
    let rms = measure(input, weighs, &out);
    let stats = stats_on_input(input, &out);
    // Missed working vertices: farther than MISS_SPACINGS final spacings from the result.
    let t1 = Instant::now();
    let mask = missed_mask(&out, &level.p, miss_reach);
    Ok((u, out, fitted, rms, stats, mask, t1.elapsed().as_secs_f64()))
}

/// The route's own finish: its arranged-and-settled mesh, the fitted mesh, the fit's counts, its RMS, figures,
/// missed mask and the seconds the mask took.
pub(super) type FinishedAlone = (Unfitted, PolyMesh, fit::FitCounts, f64, QuadStats, Vec<bool>, f64);

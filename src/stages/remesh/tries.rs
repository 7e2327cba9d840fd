//! A route's finish with the cancellation tries (step 6, split routes): the kept attempt is extracted again
//! with its position singularities cancelled in pairs or into cones ([`integer::TRIES`]), the count steered
//! by re-solving the position field ([`CANCEL_RESCALES`]). The tries are arranged, ranked by irregular
//! vertices, and only those with fewer than the route's own result are settled, fitted and weighed, fewest
//! first, until one is kept ([`CANCEL_TRADE`], [`CANCEL_RMS_SLACK`], [`CANCEL_MISSED_SLACK`]).

use std::time::Instant;

use rayon::prelude::*;

use super::finish::{
    Candidate, Extraction, Finished, InputSide, Unfitted, arrange, candidate, finish_alone, fit_pack, measure,
    missed_mask, rms_allowed, settle, stats_on_input,
};
use super::report::{CancelTrial, Mode, QuadStats, RemeshReport, quad_stats};
use super::settings::*;
use super::work::Work;
use super::{field, integer};
use crate::error::Result;
use crate::geometry::polygon;
use crate::geometry::vec3::V3;

/// A try's arranged result: its candidate, arranged mesh ([`arrange`]) and figures.
type Arranged = (Candidate, Unfitted, QuadStats);
/// A try: its report entry, its arranged result when it was arranged, seconds cancelling, seconds re-solving.
type Try = (CancelTrial, Option<Arranged>, f64, f64);
/// What the tries start from: the route's working mesh, its kept position field and spacing.
pub(super) struct Tries<'t> {
    pub w: &'t Work,
    pub mode: Mode,
    /// Thickness per working vertex (the thin-part guard of the cancellation); `None` without tries.
    pub thick: Option<&'t [f64]>,
    /// The kept attempt's origins and finest-level spacings.
    pub o: &'t [V3],
    pub s0: &'t [f64],
    pub input: &'t InputSide<'t>,
    pub opts: &'t RemeshOptions,
    /// The input's face-connected pieces and Euler characteristic.
    pub components: usize,
    pub chi: i64,
}

/// The route's kept attempt and how it is finished.
pub(super) struct Finishing {
    pub c: Candidate,
    /// Index of the attempt in the report.
    pub index: usize,
    /// χ differs from the input's.
    pub changed: bool,
    /// The cancellation tries run (split routes with `cancel_singularities`).
    pub cancel: bool,
    /// Results are weighed against each other (more than one route, or tries): the RMS is measured.
    pub weighs_routes: bool,
    /// Working vertices farther than this from a result count as missed.
    pub miss_reach: f64,
}

impl Tries<'_> {
    /// One try at path reach `reach`: cancel, steer the count by re-solving (at most [`CANCEL_RESCALES`]
    /// times), and arrange the result when its count, χ and manifoldness hold.
    fn cost(&self, reach: integer::Reach, field_steps: &Option<integer::Offsets>) -> Result<Try> {
        let (levels, qs, tris) = (&self.w.levels, &self.w.qs, &self.w.tris);
        let target = self.opts.target_vertices as f64;
        // Cancelling removes more rows than it adds: steer the count by re-solving the position field at a
        // finer spacing (at most CANCEL_RESCALES times).
        let (mut o2, mut s2) = (self.o.to_vec(), self.s0.to_vec());
        let (mut rescales, mut t_cancel, mut t_resolve) = (0, 0.0, 0.0);
        let mut c2 = loop {
            let blocked: Vec<bool> =
                self.thick.unwrap_or_default().iter().zip(&s2).map(|(&t, &sp)| t < integer::CANCEL_THIN * sp).collect();
            let how = integer::Cancel { tris, reach, blocked: &blocked };
            let t1 = Instant::now();
            // Before a re-solve the field is the candidate's own: start from its steps.
            let steps = if rescales == 0 { field_steps.clone() } else { None };
            let linked_guard = LINKED_GUARD && self.mode.is_direct() && self.w.edges_split;
            let route = Extraction { mode: self.mode, components: self.components, linked_guard };
            let c2 = candidate(&levels[0], &qs[0], &o2, &s2, Some((how, steps)), route);
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
            o2 = field::solve_position(levels, qs, &sl2, self.opts.iterations, self.opts.seed);
            t_resolve += t1.elapsed().as_secs_f64();
        };
        let (chi, manifold) = polygon::polygon_check(&c2.faces);
        c2.topology_ok = manifold && chi == self.chi;
        let mut trial = CancelTrial {
            mode: Some(self.mode),
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
        let u2 = arrange(&c2, self.input.bvh, self.opts)?;
        let stats2 = quad_stats(&u2.mesh()?, None);
        trial.irregular_fraction = stats2.irregular_fraction;
        trial.vertices = stats2.vertices;
        Ok((trial, Some((c2, u2, stats2)), t_cancel, t_resolve))
    }

    /// Every try of [`integer::TRIES`], in parallel (each search is sequential).
    fn run(&self, field_steps: &Option<integer::Offsets>) -> Vec<Result<Try>> {
        integer::TRIES.par_iter().map(|&reach| self.cost(reach, field_steps)).collect()
    }
}

/// Share of `m` that is set.
fn missed_of(m: &[bool]) -> f64 {
    m.iter().filter(|&&b| b).count() as f64 / m.len().max(1) as f64
}

/// Finishes the route's kept attempt and, where it is sound and `cancel` holds, weighs its cancellation tries:
/// the first try that, fitted, is sound and whose RMS grew by at most [`CANCEL_TRADE`] times its relative drop
/// of irregular vertices ([`CANCEL_RMS_SLACK`] at most) replaces it. Returns the kept result and the route's
/// own missed mask. Adds the re-solves' seconds to `t_position`.
///
/// The tries need only the candidate, not its finished result: they run alongside the finish where the
/// result is likely sound, and are dropped unless it turns out so.
pub(super) fn finish_with_tries(
    f: Finishing,
    tries: &Tries,
    report: &mut RemeshReport,
    t_position: &mut f64,
) -> Result<(Finished, Vec<bool>)> {
    let Finishing { mut c, index, changed, cancel, weighs_routes, miss_reach } = f;
    let (input, opts) = (tries.input, tries.opts);
    let diagonal = input.diagonal;
    let level = &tries.w.levels[0];
    // The position field's own steps, from which the tries' cancellations start (until a re-solve).
    let field_steps = c.ex.steps.take();
    let finish_this = || finish_alone(&c, input, opts, weighs_routes, level, miss_reach);
    // Alongside the finish only where the result is likely sound (few thin parts, as for the uniform
    // split's skip): on the dragon's unsound split routes the dropped tries cost 12 s of --split-only's
    // 19 s (against 6.6 s without them).
    let speculate = cancel && opts.adaptive_spacing && report.thin_share <= SKIP_THIN_SHARE;
    let (finished_this, speculated) = rayon::join(finish_this, || speculate.then(|| tries.run(&field_steps)));
    let (Unfitted { extra, valence, dipoles, .. }, out, fitted, rms, stats, mask, t_missed) = finished_this?;
    *report.seconds.entry("missed".into()).or_insert(0.0) += t_missed;
    let mut kept =
        Finished { index, c, changed, out, extra, rms, valence, dipoles, fit: fitted, stats, missed: missed_of(&mask) };
    // The same position field with its singularities cancelled in pairs: kept when it is sound too, about
    // as close to the input and has fewer irregular vertices. Only where this route's result is sound, so the
    // cascade ends with it. An unsound one sends the cascade on, and its cancelled form (at most
    // CANCEL_RMS_SLACK farther from the input) would rarely be picked over a later route: on the dragon the
    // four tries cost 11 s and none was. (Sound implies χ kept: `changed` is false here.)
    //
    // Only the tries with fewer irregular vertices are fitted and weighed, fewest first, until one is kept:
    // fitting every try cost a fifth of igea's time.
    let Some(all) = (cancel && kept.sound(diagonal)).then(|| speculated.unwrap_or_else(|| tries.run(&field_steps)))
    else {
        return Ok((kept, mask));
    };
    // The tries with fewer irregular vertices than this result, fewest first (TRIES order on ties), counted on
    // the arranged mesh (settling, which only the fitted ones get, may yet collapse a quad that stays flipped).
    // (irregular vertices, index in `arranged`)
    let mut order: Vec<(usize, usize)> = Vec::new();
    let mut arranged: Vec<Option<Arranged>> = Vec::new();
    let first_slot = report.cancellation.len();
    for t in all {
        let (trial, pr, t_cancel, t_resolve) = t?;
        *report.seconds.entry("cancellation".into()).or_insert(0.0) += t_cancel;
        *t_position += t_resolve;
        if let Some((_, _, st)) = &pr
            && st.irregular_vertices < kept.stats.irregular_vertices
        {
            order.push((st.irregular_vertices, arranged.len()));
        }
        report.cancellation.push(trial);
        arranged.push(pr);
    }
    order.sort_unstable();
    for (irregular, k) in order {
        let Some((c2, u2, _)) = arranged[k].take() else { continue };
        let u2 = settle(u2, input.mesh, &input.p, input.bvh, opts);
        let (out2, fit2) = fit_pack(&u2, input.mesh, &input.p, input.bvh, &input.fit_samples, opts)?;
        let rms2 = measure(input, weighs_routes, &out2);
        let stats2 = stats_on_input(input, &out2);
        let missed2 = missed_of(&missed_mask(&out2, &level.p, miss_reach));
        let trial = &mut report.cancellation[first_slot + k];
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
        // Sound, but measured against the result it would replace: a try may miss up to CANCEL_MISSED_SLACK
        // times as many working vertices (never more than MISSED_LOST).
        let missed_max = (CANCEL_MISSED_SLACK * kept.missed).clamp(MISSED_MAX, MISSED_LOST);
        if f2.sound_within(diagonal, missed_max) && f2.rms <= allowed * kept.rms {
            trial.kept = true;
            kept = f2;
            break;
        }
    }
    Ok((kept, mask))
}

//! The route cascade (steps 4–8): split, adaptive split, direct and refined direct routes, in the order
//! [`Cascade::routes`] lays out; each runs only when every earlier result lost something
//! ([`Cascade::ends_before`], [`Cascade::skips`]). A route steers the vertex count over a few extractions
//! ([`Route::steer`]), finishes its kept attempt, and on the split routes weighs the cancellation tries
//! ([`super::tries`]).

use std::time::Instant;

use super::field;
use super::finish::{Candidate, Extraction, Finished, InputSide, candidate};
use super::report::{Attempt, Mode, Refine, RemeshReport};
use super::settings::*;
use super::spacing::{SizeField, refined_spacing, spacing_field, timed_feature_size};
use super::tries::{self, Tries};
use super::work::{Work, working_mesh};
use crate::error::Result;
use crate::geometry::mesh::TriMesh;
use crate::geometry::polygon;
use crate::geometry::vec3::V3;
use crate::stages::Progress;

/// The working meshes of the routes: the split routes' one, and what the direct routes' finer one is made from.
pub(super) struct WorkingMeshes {
    /// The split routes' working mesh, with its hierarchy and orientation field.
    pub main: Work,
    /// The direct routes' working mesh (finer: [`WORK_PER_VERTEX_DIRECT`]), built when they first run; `None`
    /// also when it would be the size of `main` (an input too small to decimate either way).
    pub fine: Option<Work>,
    /// The direct routes' working mesh when it was made on the way to `main` (staged decimation).
    staged: Option<(Vec<V3>, Vec<[u32; 3]>, String)>,
    /// The compacted input, from which the direct routes' working mesh is made otherwise.
    input: (Vec<V3>, Vec<[u32; 3]>),
}

impl WorkingMeshes {
    /// The split routes' working mesh at `opts.work_per_vertex` × the target, decimated in two stages (through
    /// the direct routes' one) when the input is more than [`STAGED_DECIMATION`] times the latter. Fills the
    /// report's working-mesh figures. Cost: O(F_in log F_in) for the decimation, O(V_work · iterations) for
    /// the field.
    pub fn build(mesh: &TriMesh, opts: &RemeshOptions, report: &mut RemeshReport) -> Self {
        let t_work = Instant::now();
        let mut work_p: Vec<V3> = mesh.positions.iter().map(|&x| crate::geometry::vec3::wide(x)).collect();
        let mut work_t = mesh.triangles.clone();
        work_p = polygon::compact(&work_p, &mut work_t);
        let want_main = (opts.work_per_vertex * opts.target_vertices as f64) as usize;
        let want_direct = (opts.work_per_vertex_direct * opts.target_vertices as f64) as usize;
        // The split routes extract at a quarter of the count: 4.9 working edges to a step at WORK_PER_VERTEX
        // (splitting them anyway made the torus test's net less regular: 26 irregular vertices instead of 20).
        let edge_main = f64::INFINITY;
        let edge_direct = direct_work_edge(&work_p, &work_t, opts);
        let mut staged = None;
        let (main_p, main_t, label) =
            if opts.try_direct && want_direct > want_main && work_p.len() > STAGED_DECIMATION * want_direct {
                let (fine_p, fine_t, fine_label) =
                    working_mesh(work_p.clone(), work_t.clone(), want_direct, edge_direct, opts.seed);
                let (main_p, main_t, _) = working_mesh(fine_p.clone(), fine_t.clone(), want_main, edge_main, opts.seed);
                staged = Some((fine_p, fine_t, fine_label));
                (main_p, main_t, "decimated in two stages".to_string())
            } else {
                working_mesh(work_p.clone(), work_t.clone(), want_main, edge_main, opts.seed)
            };
        let work_seconds = t_work.elapsed().as_secs_f64();
        let main = Work::build(main_p, main_t, label, opts);
        report.seconds.insert("working_mesh".into(), work_seconds);
        report.working_mesh = main.label.clone();
        report.working_vertices = main.p.len();
        report.hierarchy_levels = main.levels.len();
        report.curvature_coherence = main.coherence;
        report.orientation_singularities = main.orientation_singularities;
        for (k, v) in &main.seconds {
            report.seconds.insert(k.to_string(), *v);
        }
        WorkingMeshes { main, fine: None, staged, input: (work_p, work_t) }
    }

    /// Builds the direct routes' working mesh (once). Cost: as [`Self::build`].
    fn build_fine(&mut self, opts: &RemeshOptions, report: &mut RemeshReport) {
        let t0 = Instant::now();
        let want_direct = (opts.work_per_vertex_direct * opts.target_vertices as f64) as usize;
        let (p, t, label) = self.staged.take().unwrap_or_else(|| {
            let (p, t) = std::mem::take(&mut self.input);
            let edge = direct_work_edge(&p, &t, opts);
            working_mesh(p, t, want_direct, edge, opts.seed)
        });
        report.direct_working_vertices = p.len();
        if p.len() != self.main.p.len() {
            self.fine = Some(Work::build(p, t, label, opts));
        }
        *report.seconds.entry("direct_working_mesh".into()).or_insert(0.0) += t0.elapsed().as_secs_f64();
    }
}

/// The longest edge of the direct routes' working mesh: [`WORK_EDGE_SPACINGS`] of their lattice step
/// √(area / target). Cost: O(F).
fn direct_work_edge(p: &[V3], tris: &[[u32; 3]], opts: &RemeshOptions) -> f64 {
    let area: f64 = tris.iter().map(|&t| crate::geometry::vec3::tri_area(p, t)).sum();
    WORK_EDGE_SPACINGS * (area / opts.target_vertices.max(1) as f64).sqrt()
}

/// Seconds of the cascade's phases, summed over the routes.
#[derive(Default)]
struct Clocks {
    position: f64,
    extraction: f64,
    finish: f64,
}

/// The cascade's state across its routes.
pub(super) struct Cascade<'a> {
    input: &'a InputSide<'a>,
    opts: &'a RemeshOptions,
    work: WorkingMeshes,
    /// The routes in the order they may run.
    modes: Vec<Mode>,
    /// Working vertices the direct result missed (set when the direct route finished).
    missed: Option<Vec<bool>>,
    /// Feature size of the split routes' (0) and the direct routes' (1) working mesh (thin parts, narrow gaps
    /// and fast bends, [`super::sizing`]), for the adaptive routes and the cancellation's thin-part guard: measured once,
    /// when first needed, only as far as the coarsest spacing tried could need ([`Self::reach`]).
    thick_by: [Option<SizeField>; 2],
    /// How far the thickness is measured.
    reach: f64,
    /// The net's spacing √(area / target) and the split routes' lattice step √(4·area / target).
    spacings: (f64, f64),
    /// Per route: its best attempt with the input's χ (else the best closed manifold one), finished and
    /// measured.
    finished: Vec<Finished>,
    clocks: Clocks,
}

/// A route's kept attempt: (count error, attempt index, candidate, its origins and spacings).
type Kept = (f64, usize, Candidate, Vec<V3>, Vec<f64>);

impl<'a> Cascade<'a> {
    pub fn new(input: &'a InputSide<'a>, opts: &'a RemeshOptions, work: WorkingMeshes) -> Self {
        let target = opts.target_vertices as f64;
        let reach = 1.5 * (input.area * 4.0 / target).sqrt() / THIN_RATIO;
        Cascade {
            input,
            opts,
            work,
            modes: Self::routes(opts),
            missed: None,
            thick_by: [None, None],
            reach,
            spacings: ((input.area / target).sqrt(), (input.area * 4.0 / target).sqrt()),
            finished: Vec::new(),
            clocks: Clocks::default(),
        }
    }

    /// The cascade: uniform split; adaptive split when that lost something; direct when both did; the
    /// refined direct tries ([`REFINE_TRIES`]); then the adaptive split (where it was skipped) and the uniform
    /// split once more, last, where they were skipped and no later route was sound: a result of theirs may
    /// then be the only one without a flipped face.
    fn routes(opts: &RemeshOptions) -> Vec<Mode> {
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
        if opts.adaptive_spacing && opts.try_direct {
            modes.push(Mode::AdaptiveSplit);
        }
        if opts.adaptive_spacing || opts.try_direct {
            modes.push(Mode::Split);
        }
        modes
    }

    /// Runs the routes in turn; returns every finished route's result (at least one).
    ///
    /// # Errors
    /// `remesh.failed` when no route gave a closed 2-manifold quad mesh; errors of the finish.
    pub fn run(mut self, report: &mut RemeshReport, progress: &dyn Progress) -> Result<Vec<Finished>> {
        for mi in 0..self.modes.len() {
            let mode = self.modes[mi];
            if self.ends_before(mi, mode) {
                break;
            }
            if self.skips(mi, mode, report) {
                continue;
            }
            if mode.is_direct() && report.direct_working_vertices == 0 {
                self.work.build_fine(self.opts, report);
            }
            if let Some(kept) = self.route(mi, mode, report, progress)? {
                self.finished.push(kept);
            }
        }
        report.seconds.insert("position".into(), self.clocks.position);
        report.seconds.insert("extraction".into(), self.clocks.extraction);
        report.seconds.insert("projection".into(), self.clocks.finish);
        if self.finished.is_empty() {
            return Err(crate::error::Error::new(
                crate::error::ErrorCode::RemeshFailed,
                format!(
                    "extraction: none of {} attempts gave a closed 2-manifold quad mesh (input χ {})",
                    report.attempts.len(),
                    report.input_euler_characteristic
                ),
            )
            .with_hint("try more vertices (a finer spacing) or another --seed"));
        }
        Ok(self.finished)
    }

    /// A later route runs only when the earlier ones all lost something: RMS above [`FALLBACK_TRIGGER_PCT`],
    /// more than [`MISSED_MAX`] of the working vertices missed, χ changed or a face left flipped; the direct
    /// routes run also when no sound result meets [`IRREGULAR_GOAL`].
    /// With `far_is_raised`, the last uniform split after the direct routes does not run where a result is
    /// sound apart from its distance: the caller raises the count instead.
    fn ends_before(&self, mi: usize, mode: Mode) -> bool {
        let diagonal = self.input.diagonal;
        let after_direct = self.modes[..mi].iter().any(|m| m.is_direct());
        let raised_instead = self.opts.far_is_raised && mode == Mode::Split && after_direct;
        mi > 0
            && self.finished.iter().any(|f| {
                (f.sound(diagonal) && !(mode.is_direct() && f.stats.irregular_fraction > IRREGULAR_GOAL))
                    || (raised_instead && f.class() == 0)
            })
    }

    /// Whether route `mi` is passed over: a refined direct try after one the pick would prefer to the direct
    /// result, or with nothing missed; the second uniform or adaptive split where the first ran; the uniform
    /// split first on a mesh with many thin parts (measures `thin_share`), the adaptive split before the
    /// direct routes where even it would lose them.
    fn skips(&mut self, mi: usize, mode: Mode, report: &mut RemeshReport) -> bool {
        let opts = self.opts;
        // The refined direct tries stop at the first one the final pick would prefer to the direct result.
        let direct = self.finished.iter().find(|f| f.c.mode == Mode::Direct);
        if mode == Mode::RefinedDirect
            && self.finished.iter().any(|f| {
                f.c.mode == Mode::RefinedDirect
                    && direct.is_some_and(|d| {
                        f.class() <= d.class() && (FIDELITY_RATIO * f.rms < d.rms || f.trades_well_against(d))
                    })
            })
        {
            return true;
        }
        if mode == Mode::RefinedDirect && self.missed.as_ref().is_none_or(|m| !m.contains(&true)) {
            return true;
        }
        if mode == Mode::Split && mi > 0 && !report.uniform_split_skipped {
            return true;
        }
        // The adaptive split goes after the direct routes where even it would lose thin parts.
        if mode == Mode::AdaptiveSplit && mi == 1 && opts.try_direct && report.thin_share > SKIP_ADAPTIVE_THIN_SHARE {
            report.adaptive_split_skipped = true;
            return true;
        }
        if mode == Mode::AdaptiveSplit && mi > 1 && !report.adaptive_split_skipped {
            return true;
        }
        if mode == Mode::Split && mi == 0 && (opts.adaptive_spacing || opts.try_direct) {
            // Parts thinner than the uniform split's lattice spacing fold onto one lattice row: on a mesh
            // with many, that route cannot keep them, and the adaptive one (or, without it, the direct one)
            // runs instead; the uniform split comes after the direct routes if they lose something too.
            let main = &self.work.main;
            let reach = self.reach;
            let s = self.spacings;
            let t = &self.thick_by[0]
                .get_or_insert_with(|| timed_feature_size(&main.levels[0], (&main.p, &main.tris), reach, s, report))
                .thickness;
            let s_split = s.1;
            report.thin_share =
                t.iter().filter(|&&x| x < SKIP_THIN_SPACINGS * s_split).count() as f64 / t.len().max(1) as f64;
            if report.thin_share > SKIP_THIN_SHARE {
                report.uniform_split_skipped = true;
                return true;
            }
        }
        false
    }

    /// Route `mi` (`mode`): steer the count, finish the kept attempt, weigh its cancellation tries. `None`
    /// when no attempt was usable.
    fn route(
        &mut self,
        mi: usize,
        mode: Mode,
        report: &mut RemeshReport,
        progress: &dyn Progress,
    ) -> Result<Option<Finished>> {
        // 1. The working mesh: the direct routes work on the finer one where there is one.
        let wi = usize::from(mode.is_direct() && self.work.fine.is_some());
        let w = if wi == 1 { self.work.fine.as_ref().unwrap_or(&self.work.main) } else { &self.work.main };
        let (reach, spacings) = (self.reach, self.spacings);
        // 2. The thickness this route's spacing needs, and which spacing a refined direct try uses
        // (REFINE_TRIES, in order).
        let thick_all = &mut self.thick_by[wi];
        if mode == Mode::AdaptiveSplit {
            let t = thick_all
                .get_or_insert_with(|| timed_feature_size(&w.levels[0], (&w.p, &w.tris), reach, spacings, report));
            report.thin_vertices = t.thickness.iter().filter(|x| x.is_finite()).count();
        }
        let refine = (mode == Mode::RefinedDirect)
            .then(|| REFINE_TRIES[self.modes[..mi].iter().filter(|&&m| m == Mode::RefinedDirect).count()]);
        if refine.is_some_and(|r| r != Refine::Missed) {
            let t = thick_all
                .get_or_insert_with(|| timed_feature_size(&w.levels[0], (&w.p, &w.tris), reach, spacings, report));
            report.thin_vertices = t.thickness.iter().filter(|x| x.is_finite()).count();
        }
        // 3. Steer the vertex count: the adaptive split follows the feature size (thickness and curvature), the
        // refined direct tries the thickness alone, as before (the curvature there is not measured yet: half the
        // dragon's area is bent enough to ask, its scales).
        let steered = {
            let feature = thick_all.as_ref().map(|f| f.feature.as_slice());
            let thickness = thick_all.as_ref().map(|f| f.thickness.as_slice());
            let thick = if mode == Mode::AdaptiveSplit { feature } else { None };
            let (miss, thin) = match refine {
                Some(Refine::Thin) => (None, thickness),
                Some(Refine::Missed) => (self.missed.as_deref(), None),
                Some(Refine::Both) => (self.missed.as_deref(), thickness),
                None => (None, thick),
            };
            let route = Route { w, mode, refine, thin, miss, target: self.opts.target_vertices as f64 };
            route.steer(self.input.area, self.opts, &mut self.clocks, report, progress)
        };
        let (index, c, changed, o, s0) = match steered {
            Steered { best: Some((_, i, c, o, s0)), .. } => (i, c, false, o, s0),
            Steered { best: None, fallback: Some((_, i, c, o, s0)) } => (i, c, true, o, s0),
            _ => return Ok(None),
        };
        // 4. Finish the kept attempt, with its cancellation tries on the split routes.
        progress.report(0.8, "projection");
        let t0 = Instant::now();
        let cancel = self.opts.cancel_singularities && !mode.is_direct();
        // The tries need the thickness for their thin-part guard.
        let thick_c: Option<&[f64]> = if cancel {
            let f = thick_all
                .get_or_insert_with(|| timed_feature_size(&w.levels[0], (&w.p, &w.tris), reach, spacings, report));
            Some(f.thickness.as_slice())
        } else {
            None
        };
        let per_vertex = if mode.is_direct() { 1.0 } else { 4.0 };
        let miss_reach = MISS_SPACINGS * report.attempts[index].scale / f64::sqrt(per_vertex);
        let weighs_routes = self.modes.len() > 1 || cancel;
        let tries = Tries {
            w,
            mode,
            thick: thick_c,
            o: &o,
            s0: &s0,
            input: self.input,
            opts: self.opts,
            components: report.input_components,
            chi: report.input_euler_characteristic,
        };
        let (kept, mask) = tries::finish_with_tries(
            tries::Finishing { c, index, changed, cancel, weighs_routes, miss_reach },
            &tries,
            report,
            &mut self.clocks.position,
        )?;
        // 5. Where the direct result passes farther than MISS_SPACINGS spacings from the working mesh, the
        // lattice could not follow the surface (struts, fins): the refined route makes it finer there.
        if mode == Mode::Direct && self.opts.refine_missed {
            report.missed_vertices = mask.iter().filter(|&&b| b).count();
            self.missed = Some(mask);
        }
        self.clocks.finish += t0.elapsed().as_secs_f64();
        Ok(Some(kept))
    }
}

/// The best attempts of a route's count steering.
struct Steered {
    /// The attempt closest to the count among those with the input's χ.
    best: Option<Kept>,
    /// The attempt closest to the count among the usable ones without it.
    fallback: Option<Kept>,
}

/// One route's working mesh and spacing inputs, for its count steering.
struct Route<'r> {
    w: &'r Work,
    mode: Mode,
    refine: Option<Refine>,
    /// Thickness per working vertex, where the spacing follows it.
    thin: Option<&'r [f64]>,
    /// Working vertices the direct result missed, where the spacing is refined there.
    miss: Option<&'r [bool]>,
    target: f64,
}

impl Route<'_> {
    /// Spacing per working vertex for global spacing `s`.
    fn spacing(&self, s: f64) -> Vec<f64> {
        let level = &self.w.levels[0];
        match (self.thin, self.miss) {
            (Some(t), None) => spacing_field(level, t, s),
            (None, Some(m)) => refined_spacing(level, m, s),
            (Some(t), Some(m)) => {
                let a = spacing_field(level, t, s);
                refined_spacing(level, m, s).into_iter().zip(a).map(|(x, y)| x.min(y)).collect()
            }
            (None, None) => vec![s; level.len()],
        }
    }

    /// Position field and extraction, repeated with the spacing scaled by √(predicted / target) until the
    /// count is within [`COUNT_TOLERANCE`] ([`MAX_ATTEMPTS`], or [`MAX_DIRECT_ATTEMPTS`] on the direct
    /// routes). Every attempt goes into the report.
    fn steer(
        &self,
        area: f64,
        opts: &RemeshOptions,
        clocks: &mut Clocks,
        report: &mut RemeshReport,
        progress: &dyn Progress,
    ) -> Steered {
        let (mode, target) = (self.mode, self.target);
        let (levels, qs) = (&self.w.levels, &self.w.qs);
        let per_vertex = if mode.is_direct() { 1.0 } else { 4.0 };
        let max_attempts = if mode.is_direct() { MAX_DIRECT_ATTEMPTS } else { MAX_ATTEMPTS };
        let mut s = START_SCALE * (area * per_vertex / target).sqrt();
        if self.thin.is_some() || self.miss.is_some() {
            // The finer spacing on thin parts adds vertices: start from the effective area at this spacing.
            for _ in 0..4 {
                let sp = self.spacing(s);
                let eff: f64 = levels[0].area.iter().zip(&sp).map(|(&a, &si)| a * (s / si).powi(2)).sum();
                s = START_SCALE * (eff * per_vertex / target).sqrt();
            }
        }
        let mut steered = Steered { best: None, fallback: None };
        for _ in 0..max_attempts {
            progress.report((0.3 + 0.04 * report.attempts.len() as f64).min(0.75), "position field");
            let t0 = Instant::now();
            let s0 = self.spacing(s);
            let mut sl = field::level_spacings(levels, s0);
            let o = field::solve_position(levels, qs, &sl, opts.iterations, opts.seed);
            clocks.position += t0.elapsed().as_secs_f64();
            let t0 = Instant::now();
            let linked_guard = LINKED_GUARD && mode.is_direct() && self.w.edges_split;
            let how = Extraction { mode, components: report.input_components, linked_guard };
            let mut c = candidate(&levels[0], &qs[0], &o, &sl[0], None, how);
            let (chi, manifold) = polygon::polygon_check(&c.faces);
            c.topology_ok = manifold && chi == report.input_euler_characteristic;
            let usable = manifold && c.counts.triangles_unpaired == 0;
            clocks.extraction += t0.elapsed().as_secs_f64();
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
                refine: self.refine,
            });
            let err = (predicted as f64 / target - 1.0).abs();
            let index = report.attempts.len() - 1;
            if valid && steered.best.as_ref().is_none_or(|b| err < b.0) {
                steered.best = Some((err, index, c, o, sl.swap_remove(0)));
            } else if !valid && usable && steered.fallback.as_ref().is_none_or(|b| err < b.0) {
                steered.fallback = Some((err, index, c, o, sl.swap_remove(0)));
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
        steered
    }
}

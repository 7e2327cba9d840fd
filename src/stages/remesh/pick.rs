//! The pick among the routes' finished results, and the report of the kept one.

use super::finish::{Candidate, Finished};
use super::report::{Alternative, RemeshReport};
use super::settings::*;
use crate::geometry::mesh::PolyMesh;

/// The kept result of `finished` (not empty); the others go into `report.alternatives`.
///
/// A result that keeps χ and has no flipped face and no crossing beats one that does not, then one within [`COUNT_LIMIT`] of
/// the target beats one that is not, then a sound one beats one that is not; among equals a later route (more
/// irregular vertices, as a rule) wins only when the earlier one is more than [`FIDELITY_RATIO`] times farther
/// from the input, or when it has fewer irregular vertices for a small enough rise in RMS
/// ([`Finished::trades_well_against`], as the cancellation's tries).
pub(super) fn pick(mut finished: Vec<Finished>, diagonal: f64, report: &mut RemeshReport) -> PolyMesh {
    let target = report.target_vertices as f64;
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
                crossing_pairs: other.stats.crossing_pairs,
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
    report.output = stats;
    out
}

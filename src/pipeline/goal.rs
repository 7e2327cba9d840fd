//! The default resolution of `convert`: a **deviation goal under a control-vertex cap** instead of a fixed
//! count. The goal is the RMS gate's bound (0.05 % of the diagonal by default, [`super::GateOptions`]).
//!
//! The chain starts at [`GOAL_START`] control vertices (or the cap, when lower). The quad net is measured
//! against the repaired input before any surface is fitted (the remesh stage's own two-sided measure); where
//! it is farther than [`NET_GOAL_FACTOR`] × the goal, the net is made again at [`NET_RAISE`] times the count,
//! at most [`NET_RAISES`] times and never above the cap, and the finer net is kept only when it is sound (no
//! crossing triangle pairs, the input's Euler characteristic) and nearer. The surface is fitted and the solid
//! built once, on the net kept: one attempt, each raise in the report ([`NetRaise`]). A net that may still be
//! raised is made without the remesh's last-resort route for far results (the uniform split after the direct
//! routes, [`crate::stages::remesh::RemeshOptions::far_is_raised`]): the raise is that net's fallback. It
//! saved 2.5–3 s of the dragon's and the falcon's remesh (17.3 → 14.8 s, 17.0 → 14.1 s), same STEP bytes.
//!
//! Measured on the nine shared meshes (2026-12-07, repaired as `convert` repairs them, 10,000 vertices,
//! seed 0; `cargo bench --bench remesh` and `bash scripts/quality-gates.sh`): the nets of the seven meshes
//! whose solids pass the RMS gate are 0.042–0.064 % of the diagonal from their input, their solids
//! 0.006–0.028 % (the fit halves a net's distance or better). The dragon's net is 0.149 % (its solid 0.144 %:
//! the struts under a hind foot are thinner than the 10k lattice can follow); at 15,000 its net is 0.062 %
//! and its solid 0.035 % (the whole conversion 46.6–50.6 s, one solid). The falcon's net is 0.108 % (its
//! solid 0.063 %: thin parts of the statue lost); at 15,000 its net is 0.070 % and its solid 0.042 %
//! (37.4 s). The other seven are not raised: same STEP bytes as at a fixed 10,000.

use serde::Serialize;

/// Control vertices the default goal starts from: the count at which seven of the nine shared meshes pass
/// every gate in one chain (a count, not a spacing: it bounds the fit's cost, about 2–3 s per 1,000).
pub const GOAL_START: usize = 10_000;

/// The default cap on control vertices: two raises from [`GOAL_START`]. The dragon (375k vertices) takes
/// 43.7 s at a fixed 15,000 against 33.4 s at 10,000, peak 748 MB against 585 MB; the falcon at a fixed
/// 22,500 took 92.6 s and 1.15 GB, its first solid crossing itself (66 pairs). A net that still misses the
/// goal at the cap is a shape the global lattice cannot follow (a thin part), not one that wants more
/// vertices everywhere.
pub const GOAL_CAP: usize = 22_500;

/// A net farther from the repaired input than this many times the goal is made again finer: the fit
/// brings a net's distance down by half or more on the shared meshes (nets 0.042–0.064 %, solids
/// 0.006–0.028 %), so a net within 2 × the goal gives a solid within the goal, and one beyond it has lost a
/// part the fit cannot find again (dragon 0.149 → 0.144 %).
pub const NET_GOAL_FACTOR: f64 = 2.0;

/// The count of a raised net: × 1.5 (the spacing × 0.82), enough for the dragon's struts (10k → 15k).
pub const NET_RAISE: f64 = 1.5;

/// Raises at most per solid.
pub const NET_RAISES: usize = 2;

/// One quad net made again at a higher count under the default's deviation goal, before the surface is
/// fitted.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct NetRaise {
    /// Control vertices asked for of the net that missed the goal.
    pub from_vertices: usize,
    /// That net's two-sided RMS distance to the repaired input, % of the diagonal.
    pub from_rms_pct: f64,
    /// Control vertices asked for of the finer net.
    pub to_vertices: usize,
    /// The finer net's RMS distance, % of the diagonal.
    pub to_rms_pct: f64,
    /// The finer net's crossing triangle pairs.
    pub to_crossing_pairs: usize,
    /// Whether the finer net changed the Euler characteristic where the coarser did not.
    pub to_changed_topology: bool,
    /// Whether the finer net was kept (sound and nearer).
    pub kept: bool,
    /// Wall seconds of the finer net (remesh and its measure).
    pub seconds: f64,
}

/// The count to make the net again at, when a net of `n` (asked) at `net_rms_pct` misses the goal
/// `goal_pct` by more than [`NET_GOAL_FACTOR`] and `raises` raises were made; `None` when it does not miss,
/// no raise is left, or `n` is at the cap already.
pub fn next_count(n: usize, net_rms_pct: f64, goal_pct: f64, raises: usize, cap: usize) -> Option<usize> {
    let misses = !(net_rms_pct <= NET_GOAL_FACTOR * goal_pct);
    (misses && raises < NET_RAISES && n < cap).then(|| ((n as f64 * NET_RAISE).round() as usize).min(cap))
}

/// Whether a finer net replaces the coarser: it has no crossing pair where the coarser has none or more,
/// keeps the topology when the coarser did, and is nearer.
pub fn keeps(coarse: (f64, usize, bool), fine: (f64, usize, bool)) -> bool {
    let ((rms_c, cross_c, changed_c), (rms_f, cross_f, changed_f)) = (coarse, fine);
    cross_f <= cross_c && cross_f == 0 && (changed_c || !changed_f) && rms_f < rms_c
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_net_within_twice_the_goal_is_not_raised() {
        assert_eq!(next_count(10_000, 0.064, 0.05, 0, GOAL_CAP), None);
        assert_eq!(next_count(10_000, 0.100, 0.05, 0, GOAL_CAP), None);
        assert_eq!(next_count(10_000, 0.149, 0.05, 0, GOAL_CAP), Some(15_000));
        // A NaN measure counts as missing.
        assert_eq!(next_count(10_000, f64::NAN, 0.05, 0, GOAL_CAP), Some(15_000));
    }

    #[test]
    fn raises_stop_at_the_cap_and_after_two() {
        assert_eq!(next_count(15_000, 0.2, 0.05, 1, GOAL_CAP), Some(22_500));
        assert_eq!(next_count(20_000, 0.2, 0.05, 1, GOAL_CAP), Some(GOAL_CAP));
        assert_eq!(next_count(22_500, 0.2, 0.05, 1, GOAL_CAP), None);
        assert_eq!(next_count(15_000, 0.2, 0.05, 2, GOAL_CAP), None);
        assert_eq!(next_count(10_000, 0.2, 0.05, 0, 10_000), None);
    }

    #[test]
    fn a_finer_net_is_kept_only_when_sound_and_nearer() {
        assert!(keeps((0.149, 0, false), (0.062, 0, false)));
        assert!(!keeps((0.127, 0, false), (0.090, 3, false)), "it crosses");
        assert!(!keeps((0.149, 0, false), (0.150, 0, false)), "it is not nearer");
        assert!(!keeps((0.149, 0, false), (0.062, 0, true)), "it changed the topology");
        assert!(keeps((0.149, 0, true), (0.062, 0, true)));
        assert!(keeps((0.149, 4, false), (0.062, 0, false)));
    }
}

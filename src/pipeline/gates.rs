//! Quality gates: what a solid must meet before the pipeline calls it a success.
//!
//! Every conversion ends by measuring its solid against these gates; the report lists each with its measured
//! value and bound, and a top-level [`Status`]. A solid that misses any gate is `failed`, and its
//! [`ConvertReport::verdict`](super::ConvertReport::verdict) is the `quality.*` error of the first gate missed
//! (the CLI exits 4, the daemon quarantines the job with its artifacts). With
//! [`GateOptions::accept_degraded`] it is published anyway as `degraded`.
//!
//! | gate | code | measured | bound |
//! |---|---|---|---|
//! | `crossings` | `quality.self-intersecting` | crossing triangle pairs of the solid's tessellation | 0 |
//! | `folds` | `quality.folded` | faces whose normal turns over inside the face | 0 |
//! | `volume` | `quality.volume` | \|solid − input\| / input volume, % | [`GateOptions::max_volume_error_pct`] |
//! | `rms` | `quality.rms` | RMS distance, % of the input's diagonal | the tolerance, or [`GateOptions::max_rms_pct`]; for a cloud √(that² + s²) |
//! | `caps` | `quality.cap-bulge` | an open input's caps: the largest bulge past a cap's rim plane beyond the rim's own non-planarity, % of the diagonal | the RMS bound |
//! | `max-distance` | `quality.max-distance` | the far tail: the largest distance from the scan repair kept to the solid, % of the diagonal | [`GateOptions::max_distance_pct`]; for a cloud plus its points' own largest distance from the reconstruction |
//!
//! The RMS hides a fine part cut short: a horn tip 1.5 % of the diagonal short moves spot's RMS by a few
//! thousandths of a percent. The `max-distance` gate bounds the far tail (every scan vertex, the scan's
//! area samples and the farthest point inside the triangles of the farthest samples, against the solid's
//! tessellation: [`crate::stages::quality`]). Scan vertices that repair itself left farther than the bound
//! from its result (debris it dropped, spikes it flattened) are not the solid's to follow: they are counted
//! and reported beside the gate ([`FarTail`](super::far_tail::FarTail)), not hidden.
//!
//! The RMS is two-sided for a closed input. For an open input (holes that repair filled) the solid's caps and
//! fills have no scan to be measured against: it is √((scan → solid² + solid → scan off the invented
//! region²) / 2) ([`OpenInputMeasure`](super::open_input::OpenInputMeasure)), and the invented region is
//! judged by its own gate, `caps` (only for an input with caps): a cap may bulge past its rim's best plane
//! by the rim's own non-planarity (a membrane over a wavy rim rises to the rim's crests, by construction no
//! higher) plus the accuracy goal (the remesh and the fit move the surface by up to about that much).
//!
//! For a point cloud the RMS is points → solid, and the points scatter about any surface: the reconstruction's
//! own points → surface RMS `s` (the scan's noise and the views' disagreement, measured on the best smooth
//! surface through them) is added in quadrature to the bound, so the gate judges what the chain after the
//! reconstruction adds. A clean cloud (s ≈ 0.005 %) keeps the bound as it is; the bunny's ten range scans
//! (s = 0.042 %, views disagreeing by 0.13–0.20 mm) get 0.065 % (measured 2026-12-05 through the daemon:
//! points → solid 0.0446 %; 0.0604 % with the first-order projection, which the widened bound let pass).

use crate::error::{Error, ErrorCode};

/// Default accuracy goal: the solid's RMS distance to the scan, % of the scan's bounding-box diagonal
/// (the project's goal for organic scans; measured 0.0045–0.0285 % on the closed shared meshes at the
/// defaults, 2026-12-05).
pub const DEFAULT_MAX_RMS_PCT: f64 = 0.05;

/// Default bound on the solid's volume error, % of the input's volume.
pub const DEFAULT_MAX_VOLUME_ERROR_PCT: f64 = 0.5;

/// Default bound on the far tail: the largest distance from the scan repair kept to the solid, % of the
/// scan's diagonal. An interim bound, measured (2026-12-07, the nine shared meshes at the defaults, the net
/// refined where its far tail is over [`FAR_TAIL_GOAL_GOALS`] × the RMS goal): spot 0.12 %, igea 0.19 %,
/// fandisk 0.21 %, the bunny 0.32 %, the armadillo 0.48 %, the skull 0.86 %, the scorpion 1.02 %, the
/// dragon 1.74 % and the falcon 1.79 % (thin struts, talons and spines the one-spacing net cannot enter);
/// scans outside the shared set that were delivered reach 1.0–1.61 %. It refuses a solid that lost a limb,
/// an ear or a handle's worth of the scan; the far-tail goal, [`FAR_TAIL_GOAL_GOALS`] × the RMS goal
/// (0.2 %), is what the net is refined toward and what the report counts and the page marks.
pub const DEFAULT_MAX_DISTANCE_PCT: f64 = 2.0;

/// The far-tail goal as a multiple of the RMS goal: 4 × 0.05 % = 0.2 % of the diagonal (0.6 mm on a 30 cm
/// figurine). The net is refined locally where the scan passes farther
/// ([`super::refine::LOCAL_FAR_GOALS`] is this), and [`FarTail`](super::far_tail::FarTail) counts and places what lies beyond it.
pub const FAR_TAIL_GOAL_GOALS: f64 = 4.0;

/// The gates' bounds, and whether a solid that misses one is still published.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct GateOptions {
    /// Most RMS distance to the input, % of its diagonal, when no tolerance was asked for (a tolerance is its
    /// own bound).
    pub max_rms_pct: f64,
    /// Most |volume error|, % of the input's volume.
    pub max_volume_error_pct: f64,
    /// Most distance from any part of the scan to the solid, % of its diagonal (the `max-distance` gate).
    pub max_distance_pct: f64,
    /// Publish a solid that misses a gate anyway, with status `degraded`.
    pub accept_degraded: bool,
}

impl Default for GateOptions {
    fn default() -> Self {
        GateOptions {
            max_rms_pct: DEFAULT_MAX_RMS_PCT,
            max_volume_error_pct: DEFAULT_MAX_VOLUME_ERROR_PCT,
            max_distance_pct: DEFAULT_MAX_DISTANCE_PCT,
            accept_degraded: false,
        }
    }
}

impl GateOptions {
    /// Checked settings.
    ///
    /// # Errors
    /// `input.bad-argument` for a bound that is not a positive finite number.
    pub fn validated(self) -> crate::error::Result<Self> {
        for (name, v) in [
            ("max_rms_pct", self.max_rms_pct),
            ("max_volume_error_pct", self.max_volume_error_pct),
            ("max_distance_pct", self.max_distance_pct),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(Error::new(ErrorCode::InputBadArgument, format!("{name} must be a positive percentage")));
            }
        }
        Ok(self)
    }
}

/// The verdict on a result.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Status {
    /// Every gate holds.
    Ok,
    /// A gate was missed and the result was published anyway, on request.
    Degraded,
    /// A gate was missed: the result is not a success.
    Failed,
}

/// One gate, measured.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Gate {
    /// `crossings`, `folds`, `volume` or `rms`.
    pub name: &'static str,
    /// The error code when it is missed.
    pub code: ErrorCode,
    /// The measured value.
    pub value: f64,
    /// The largest value that passes.
    pub bound: f64,
    /// Unit of `value` and `bound`.
    pub unit: &'static str,
    /// `value <= bound`.
    pub passed: bool,
    /// What was measured, for people.
    pub what: String,
}

impl Gate {
    fn new(name: &'static str, code: ErrorCode, value: f64, bound: f64, unit: &'static str, what: String) -> Self {
        // A value that is not a number (a measure that failed) does not pass.
        Gate { name, code, value, bound, unit, passed: value <= bound, what }
    }

    /// The `quality.*` error of this gate, naming the measured value.
    pub fn error(&self) -> Error {
        Error::new(
            self.code,
            format!(
                "{}: {} {} (bound {} {})",
                self.what,
                fmt_value(self.value),
                self.unit,
                fmt_value(self.bound),
                self.unit
            ),
        )
        .with_hint(
            "the solid was not published as a success; see the report's gates, try a finer resolution (--vertices, \
             --tolerance), or publish it anyway with --accept-degraded",
        )
    }
}

fn fmt_value(v: f64) -> String {
    if v == v.trunc() && v.abs() < 1e15 { format!("{v:.0}") } else { format!("{v:.4}") }
}

/// What the gates measure on one solid.
#[derive(Clone, Copy, Debug)]
pub struct Measured {
    /// Crossing triangle pairs of the solid's tessellation.
    pub crossings: usize,
    /// Faces that fold over.
    pub folded_faces: usize,
    /// (solid − input) / input volume, %.
    pub volume_error_pct: f64,
    /// The RMS distance the gate judges, % of the diagonal.
    pub rms_pct: f64,
    /// Whether that RMS is an open input's (the caps left out of the solid → scan side).
    pub open_input: bool,
    /// An open input's caps: the largest bulge past a cap's rim plane beyond the rim's own non-planarity, %
    /// of the diagonal ([`OpenInputMeasure::cap_excess_pct`](super::open_input::OpenInputMeasure::cap_excess_pct));
    /// `None` without caps (no `caps` gate then).
    pub cap_excess_pct: Option<f64>,
    /// For a point-cloud input, the reconstruction's points → surface RMS, % of the diagonal (the points'
    /// scatter, added to the bound in quadrature); `None` for a mesh. The RMS is then points → solid only (the
    /// other direction measures the cloud's sampling, not the solid; it is reported with the reconstruction).
    pub cloud_scatter_pct: Option<f64>,
    /// The RMS bound from a tolerance, % of the diagonal; `None` for the default goal.
    pub tolerance_pct: Option<f64>,
    /// The far tail: the largest distance from the scan repair kept to the solid, % of the diagonal.
    pub max_distance_pct: f64,
    /// For a point-cloud input, the points' own largest distance from the reconstructed surface, % of the
    /// diagonal (outliers no surface passes through): added to the `max-distance` bound.
    pub cloud_max_pct: Option<f64>,
}

/// The gates on `m`, in the order of the table above, and the status they give.
pub fn judge(m: &Measured, opts: &GateOptions) -> (Status, Vec<Gate>) {
    let rms_what = if m.cloud_scatter_pct.is_some() {
        "RMS distance scan points → solid, % of the diagonal"
    } else if m.open_input {
        "RMS distance solid ↔ scan away from the caps (open input), % of the diagonal"
    } else {
        "RMS distance solid ↔ scan, % of the diagonal"
    };
    let rms_bound = m.tolerance_pct.unwrap_or(opts.max_rms_pct);
    let rms_bound = m.cloud_scatter_pct.map_or(rms_bound, |s| rms_bound.hypot(s));
    let gates = vec![
        Gate::new(
            "crossings",
            ErrorCode::QualitySelfIntersecting,
            m.crossings as f64,
            0.0,
            "pairs",
            "the solid's surface crosses itself: intersecting triangle pairs of its tessellation".into(),
        ),
        Gate::new(
            "folds",
            ErrorCode::QualityFolded,
            m.folded_faces as f64,
            0.0,
            "faces",
            "faces of the solid fold over".into(),
        ),
        Gate::new(
            "volume",
            ErrorCode::QualityVolume,
            m.volume_error_pct.abs(),
            opts.max_volume_error_pct,
            "%",
            "the solid's volume error against the input".into(),
        ),
        Gate::new("rms", ErrorCode::QualityRms, m.rms_pct, rms_bound, "%", rms_what.into()),
    ];
    let mut gates = gates;
    if let Some(excess) = m.cap_excess_pct {
        gates.push(Gate::new(
            "caps",
            ErrorCode::QualityCapBulge,
            excess,
            rms_bound,
            "%",
            "an open input's cap bulges past its rim's plane beyond the rim's own non-planarity, % of the diagonal"
                .into(),
        ));
    }
    let (far_bound, far_what) = match m.cloud_max_pct {
        Some(c) => (
            opts.max_distance_pct + c,
            "largest distance scan points → solid (bound plus the points' own from the reconstruction), % of the diagonal",
        ),
        None => (
            opts.max_distance_pct,
            "largest distance scan → solid (a tip cut short, a crease rounded), % of the diagonal",
        ),
    };
    gates.push(Gate::new(
        "max-distance",
        ErrorCode::QualityMaxDistance,
        m.max_distance_pct,
        far_bound,
        "%",
        far_what.into(),
    ));
    let status = if gates.iter().all(|g| g.passed) {
        Status::Ok
    } else if opts.accept_degraded {
        Status::Degraded
    } else {
        Status::Failed
    };
    (status, gates)
}

/// `Ok` unless `status` is failed; then the first missed gate's error.
pub fn verdict(status: Status, gates: &[Gate]) -> crate::error::Result<()> {
    match (status, gates.iter().find(|g| !g.passed)) {
        (Status::Failed, Some(g)) => Err(g.error()),
        (Status::Failed, None) => Err(Error::internal("a failed status without a missed gate")),
        _ => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn clean() -> Measured {
        Measured {
            crossings: 0,
            folded_faces: 0,
            volume_error_pct: -0.011,
            rms_pct: 0.0285,
            open_input: false,
            cap_excess_pct: None,
            cloud_scatter_pct: None,
            tolerance_pct: None,
            max_distance_pct: 0.122,
            cloud_max_pct: None,
        }
    }

    #[test]
    fn a_clean_solid_passes_every_gate() {
        let (status, gates) = judge(&clean(), &GateOptions::default());
        assert_eq!(status, Status::Ok);
        assert_eq!(
            gates.iter().map(|g| g.name).collect::<Vec<_>>(),
            ["crossings", "folds", "volume", "rms", "max-distance"]
        );
        assert!(verdict(status, &gates).is_ok());
    }

    /// An open input with caps gets the `caps` gate, bounded by the RMS bound: a cap bulging 0.06 % of the
    /// diagonal past its rim's non-planarity fails it with `quality.cap-bulge`; at -0.03 % it passes (the
    /// falcon statue's planar cap, 2026-12-06: bulge 0.038–0.049 %, rim 0.081 %). Without caps there is no such gate.
    #[test]
    fn an_open_inputs_caps_are_judged_by_their_own_bound() {
        let open = Measured { open_input: true, cap_excess_pct: Some(0.06), ..clean() };
        let (status, gates) = judge(&open, &GateOptions::default());
        assert_eq!(status, Status::Failed);
        let names: Vec<_> = gates.iter().map(|g| g.name).collect();
        assert_eq!(names, ["crossings", "folds", "volume", "rms", "caps", "max-distance"]);
        let e = verdict(status, &gates).unwrap_err();
        assert_eq!(e.code, ErrorCode::QualityCapBulge);
        assert!(e.message.contains("0.0600"), "{}", e.message);
        let ok = Measured { cap_excess_pct: Some(-0.0323), ..open };
        assert_eq!(judge(&ok, &GateOptions::default()).0, Status::Ok);
    }

    /// The angel of the trust issue: 257 crossing pairs, 18 folded faces, RMS 1.02 %.
    #[test]
    fn a_crossing_solid_fails_with_the_first_gate_and_its_value() {
        let m = Measured { crossings: 257, folded_faces: 18, rms_pct: 1.02, ..clean() };
        let (status, gates) = judge(&m, &GateOptions::default());
        assert_eq!(status, Status::Failed);
        assert_eq!(gates.iter().filter(|g| !g.passed).count(), 3);
        let e = verdict(status, &gates).unwrap_err();
        assert_eq!(e.code, ErrorCode::QualitySelfIntersecting);
        assert_eq!(e.code.as_str(), "quality.self-intersecting");
        assert!(e.message.contains("257 pairs"), "{}", e.message);
        let (status, gates) = judge(&m, &GateOptions { accept_degraded: true, ..Default::default() });
        assert_eq!(status, Status::Degraded);
        assert!(verdict(status, &gates).is_ok());
    }

    #[test]
    fn a_tolerance_is_its_own_rms_bound_and_nan_never_passes() {
        let m = Measured { rms_pct: 0.03, tolerance_pct: Some(0.02), ..clean() };
        let e = verdict(judge(&m, &GateOptions::default()).0, &judge(&m, &GateOptions::default()).1).unwrap_err();
        assert_eq!(e.code, ErrorCode::QualityRms);
        assert!(e.message.contains("0.0300 %") && e.message.contains("bound 0.0200 %"), "{}", e.message);
        let m = Measured { volume_error_pct: f64::NAN, ..clean() };
        assert_eq!(judge(&m, &GateOptions::default()).0, Status::Failed);
        assert!(GateOptions { max_rms_pct: 0.0, ..Default::default() }.validated().is_err());
    }

    /// The far tail: spot's solid before the net was refined for it had its tail tip 1.548 % of the diagonal
    /// from the scan with an RMS of 0.028 %: within the RMS bound, missed at a far-tail bound of 0.2 %
    /// (`quality.max-distance`, naming the value), met at the default. A cloud's own largest distance from its
    /// reconstruction widens the bound.
    #[test]
    fn a_tip_cut_short_misses_the_far_tail_gate_though_the_rms_is_met() {
        let spot = Measured { rms_pct: 0.0281, max_distance_pct: 1.548, ..clean() };
        let strict = GateOptions { max_distance_pct: 0.2, ..Default::default() };
        let (status, gates) = judge(&spot, &strict);
        assert_eq!(status, Status::Failed);
        assert_eq!(gates.iter().filter(|g| !g.passed).map(|g| g.name).collect::<Vec<_>>(), ["max-distance"]);
        let e = verdict(status, &gates).unwrap_err();
        assert_eq!(e.code, ErrorCode::QualityMaxDistance);
        assert_eq!(e.code.as_str(), "quality.max-distance");
        assert!(e.message.contains("1.5480 %") && e.message.contains("bound 0.2000 %"), "{}", e.message);
        assert_eq!(judge(&spot, &GateOptions::default()).0, Status::Ok);
        let cloud = Measured { cloud_max_pct: Some(0.5), max_distance_pct: 0.6, ..clean() };
        let (status, gates) = judge(&cloud, &strict);
        assert_eq!(status, Status::Ok, "{gates:?}");
        assert!((gates[4].bound - 0.7).abs() < 1e-12, "{:?}", gates[4]);
        let far = Measured { max_distance_pct: f64::NAN, ..clean() };
        assert_eq!(judge(&far, &GateOptions::default()).0, Status::Failed, "a far tail not measured never passes");
        assert!(GateOptions { max_distance_pct: 0.0, ..Default::default() }.validated().is_err());
    }

    /// The bunny's range scans: points → solid 0.0604 % with the points scattering 0.0402 % about the
    /// reconstruction passes (bound √(0.05² + 0.0402²) = 0.0642 %); 0.07 % does not.
    #[test]
    fn a_clouds_scatter_widens_the_rms_bound_in_quadrature() {
        let m = Measured { rms_pct: 0.0604, cloud_scatter_pct: Some(0.0402), ..clean() };
        let (status, gates) = judge(&m, &GateOptions::default());
        assert_eq!(status, Status::Ok, "{gates:?}");
        assert!((gates[3].bound - 0.0642).abs() < 1e-4, "{:?}", gates[3]);
        assert!(gates[3].what.contains("points → solid"), "{}", gates[3].what);
        let m = Measured { rms_pct: 0.07, ..m };
        assert_eq!(judge(&m, &GateOptions::default()).0, Status::Failed);
    }
}

//! **Stages** — the steps of the scan-to-solid chain, each a plain, deterministic function over geometry
//! with a progress callback and a memory budget. Stages use the geometry core and nothing above it.
//!
//! In chain order: [`reconstruct`] (a closed mesh from a point cloud), [`repair`] (closed 2-manifold without
//! self-intersections), [`remesh`] (field-aligned pure quads), [`surface`] (fitted Catmull–Clark limit
//! surface), [`brep`] (B-spline B-rep and STEP), [`quality`] (the two-sided surface distance every stage
//! reports with) and [`fea`] (immersed linear statics).

pub mod brep;
pub mod fea;
pub mod quality;
pub mod reconstruct;
pub mod remesh;
pub mod repair;
pub mod surface;

/// Receives progress from a running stage: `fraction` in [0, 1], never decreasing within one stage call,
/// and a short phase name. Implementations must be cheap and thread-safe; stages call it from worker
/// threads.
pub trait Progress: Sync {
    /// Report progress.
    fn report(&self, fraction: f64, phase: &str);

    /// Whether the caller asked the work to stop. Chains check it between stages and return
    /// `cancelled`; the default never cancels.
    fn cancelled(&self) -> bool {
        false
    }
}

/// One stage's slice `[lo, hi]` of a chain's overall progress: a stage's own fraction `f` in [0, 1] is
/// reported to the parent as `lo + f·(hi − lo)` with phase `"STAGE/phase"`, never below what this span
/// reported before (stages that restart a sub-phase do not make the overall value go back).
pub struct ProgressSpan<'a> {
    parent: &'a dyn Progress,
    lo: f64,
    hi: f64,
    stage: &'static str,
    last: std::sync::Mutex<f64>,
}

impl<'a> ProgressSpan<'a> {
    /// A span of `parent` from `lo` to `hi` (fractions of the whole) for `stage`; reports its start.
    pub fn new(parent: &'a dyn Progress, lo: f64, hi: f64, stage: &'static str) -> Self {
        parent.report(lo, stage);
        ProgressSpan { parent, lo, hi, stage, last: std::sync::Mutex::new(lo) }
    }
}

impl Progress for ProgressSpan<'_> {
    fn report(&self, fraction: f64, phase: &str) {
        let f = if fraction.is_finite() { fraction.clamp(0.0, 1.0) } else { 0.0 };
        let v = {
            let mut last = self.last.lock().unwrap_or_else(|p| p.into_inner());
            *last = last.max(self.lo + f * (self.hi - self.lo));
            *last
        };
        self.parent.report(v, &format!("{}/{}", self.stage, phase));
    }

    fn cancelled(&self) -> bool {
        self.parent.cancelled()
    }
}

/// `Err(cancelled)` when `progress` says the caller asked to stop; called between stages.
///
/// # Errors
/// `cancelled`.
pub fn check_cancelled(progress: &dyn Progress) -> crate::error::Result<()> {
    if progress.cancelled() {
        return Err(crate::error::Error::new(
            crate::error::ErrorCode::Cancelled,
            "cancelled on request (the work stopped between stages)",
        ));
    }
    Ok(())
}

/// Discards progress.
#[derive(Copy, Clone, Debug, Default)]
pub struct NoProgress;

impl Progress for NoProgress {
    fn report(&self, _: f64, _: &str) {}
}

impl<F: Fn(f64, &str) + Sync> Progress for F {
    fn report(&self, fraction: f64, phase: &str) {
        self(fraction, phase)
    }
}

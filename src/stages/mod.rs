//! **Stages** — the steps of the scan-to-solid chain, each a plain, deterministic function over geometry
//! with a progress callback and a memory budget. Stages use the geometry core and nothing above it.
//!
//! Present so far: [`quality`] (the two-sided surface distance every other stage reports with),
//! [`repair`] (closed 2-manifold without self-intersections) and [`remesh`] (field-aligned pure quads).
//! Surface, brep/step, fea and reconstruction arrive with their issues.

pub mod brep;
pub mod fea;
pub mod quality;
pub mod remesh;
pub mod repair;
pub mod surface;

/// Receives progress from a running stage: `fraction` in [0, 1], never decreasing within one stage call,
/// and a short phase name. Implementations must be cheap and thread-safe; stages call it from worker
/// threads.
pub trait Progress: Sync {
    /// Report progress.
    fn report(&self, fraction: f64, phase: &str);
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

//! Named tolerances, with their units, and the `assert_near!` test macro.
//!
//! Lengths in scanstation are in the input's own units (mm by default for outputs). Tolerances that must
//! scale with the object are *relative to the bounding-box diagonal* and named `*_REL`.

/// Two vertices closer than this fraction of the bbox diagonal are "coincident" for welding (repair).
/// Unitless (fraction of the diagonal).
pub const WELD_REL: f64 = 1e-7;

/// A triangle whose area is at most `DEGENERATE_AREA_REL × diagonal²` is degenerate. Unitless. With positions
/// stored as f32 (24-bit mantissa), areas below ~1e-14·d² are rounding noise; 1e-15 keeps only true zeros and
/// collinear/coincident corners (the dragon's quantised faces) while no real scan triangle comes near it.
pub const DEGENERATE_AREA_REL: f64 = 1e-15;

/// Distances below this fraction of the diagonal are "zero" in distance reports (f32 storage noise).
pub const DISTANCE_ZERO_REL: f64 = 1e-7;

/// An edge curve of a B-rep must equal the boundary of both faces that use it within this fraction of the
/// bbox diagonal (OpenCASCADE's `Precision::Confusion()` is 1e-7 in model units). Unitless.
pub const BREP_EDGE_REL: f64 = 1e-7;

/// A knot of a B-rep face is removed only when no control point of the face moves by more than this
/// fraction of the face's bbox diagonal (the joins that are C¹ or C² by construction, up to rounding).
/// Unitless; a thousandth of [`BREP_EDGE_REL`].
pub const KNOT_REMOVAL_REL: f64 = 1e-10;

/// Assert that two floating-point values are within an absolute tolerance, printing both sides and the gap.
///
/// `assert_near!(a, b, tol)` or `assert_near!(a, b, tol, "context {}", x)`.
#[macro_export]
macro_rules! assert_near {
    ($a:expr, $b:expr, $tol:expr $(,)?) => {
        $crate::assert_near!($a, $b, $tol, "")
    };
    ($a:expr, $b:expr, $tol:expr, $($ctx:tt)+) => {{
        let (a, b, tol): (f64, f64, f64) = ($a as f64, $b as f64, $tol as f64);
        let gap = (a - b).abs();
        if !(gap <= tol) {
            panic!(
                "assert_near failed: {} = {a:.9e}, {} = {b:.9e}, |gap| = {gap:.3e} > tol {tol:.3e} {}",
                stringify!($a), stringify!($b), format!($($ctx)+)
            );
        }
    }};
}

/// Assert that `a` is within a *relative* tolerance of `b` (|a−b| ≤ rel·|b|), printing both sides.
#[macro_export]
macro_rules! assert_rel_near {
    ($a:expr, $b:expr, $rel:expr $(,)?) => {
        $crate::assert_rel_near!($a, $b, $rel, "")
    };
    ($a:expr, $b:expr, $rel:expr, $($ctx:tt)+) => {{
        let (a, b, rel): (f64, f64, f64) = ($a as f64, $b as f64, $rel as f64);
        let gap = (a - b).abs();
        if !(gap <= rel * b.abs()) {
            panic!(
                "assert_rel_near failed: {} = {a:.9e}, {} = {b:.9e}, relative gap {:.3e} > {rel:.3e} {}",
                stringify!($a), stringify!($b), gap / b.abs(), format!($($ctx)+)
            );
        }
    }};
}

//! How fine `convert`'s quad control net is: a fixed count, a tolerance (coarse to fine), or the default
//! deviation goal under a cap ([`super::goal`]); and the handle loops repair cuts for it.

use crate::error::{Error, ErrorCode, Result};

/// How fine the quad control net is.
#[derive(Copy, Clone, Debug, PartialEq)]
pub enum Resolution {
    /// A fixed number of control vertices.
    Vertices(usize),
    /// Raise the control-vertex count coarse to fine (×2 per attempt, from [`TOLERANCE_START`] up to
    /// [`TOLERANCE_MAX`]) until the solid's two-sided RMS distance to the input is at most this length.
    Tolerance(f64),
    /// [`Resolution::Tolerance`] given as a percentage of the input's bounding-box diagonal (`0.05%`); it
    /// becomes a length once the input is read ([`Resolution::resolved`]).
    TolerancePct(f64),
    /// The default: the RMS gate's bound as a deviation goal under a cap ([`super::goal`]). One solid from
    /// `start` control vertices; a quad net that misses the goal by more than
    /// [`super::goal::NET_GOAL_FACTOR`] is made again finer (up to `cap`) before the surface is fitted.
    Goal {
        /// Control vertices of the first net.
        start: usize,
        /// Most control vertices a raised net may have.
        cap: usize,
    },
}

/// Control vertices of the first net when neither a count nor a tolerance is asked for (the deviation
/// goal's start, [`super::goal::GOAL_START`]).
pub const DEFAULT_VERTICES: usize = super::goal::GOAL_START;

impl Resolution {
    /// The resolution a command line or a job asks for: a vertex count wins over a tolerance; neither gives
    /// `default` (a station's configured count, or [`Resolution::goal`]).
    pub fn choose(vertices: Option<usize>, tolerance: Option<Resolution>, default: Resolution) -> Resolution {
        match (vertices, tolerance) {
            (Some(n), _) => Resolution::Vertices(n),
            (None, Some(t)) => t,
            (None, None) => default,
        }
    }

    /// The default deviation goal under `cap` control vertices: from [`DEFAULT_VERTICES`] (or `cap`, when
    /// lower).
    pub fn goal(cap: usize) -> Resolution {
        Resolution::Goal { start: DEFAULT_VERTICES.min(cap), cap }
    }

    /// A tolerance as written: a length in the input's units (`0.2`) or a percentage of the bounding-box
    /// diagonal (`0.05%`).
    ///
    /// # Errors
    /// `input.bad-argument` for anything else.
    pub fn parse_tolerance(text: &str) -> Result<Resolution> {
        let t = text.trim();
        let bad = || Error::new(ErrorCode::InputBadArgument, format!("not a tolerance: {t:?}"));
        Ok(match t.strip_suffix('%') {
            Some(pct) => Resolution::TolerancePct(pct.trim().parse().map_err(|_| bad())?),
            None => Resolution::Tolerance(t.parse().map_err(|_| bad())?),
        })
    }

    /// With a percentage turned into a length of the input's bounding-box `diagonal`.
    pub fn resolved(self, diagonal: f64) -> Resolution {
        match self {
            Resolution::TolerancePct(p) => Resolution::Tolerance(p / 100.0 * diagonal),
            r => r,
        }
    }
}

/// First control-vertex count tried with a tolerance.
pub const TOLERANCE_START: usize = 2_500;
/// Most control vertices a tolerance may ask for.
pub const TOLERANCE_MAX: usize = 80_000;

/// Handle loops shorter than this many quad spacings √(area / n) are topological noise to `convert`: the
/// split route's lattice spacing is two quad spacings, and a tube needs about four quads around to be
/// carried; narrower tunnels are lost by remeshing anyway, only by accident instead of on purpose.
pub const HANDLE_LOOP_SPACINGS: f64 = 2.0;

/// The longest handle loop `convert` removes before remeshing a surface of `area` at `resolution`:
/// [`HANDLE_LOOP_SPACINGS`] · √(area / n) for a vertex count n (under the deviation goal, the count of its first
/// raised net: on the nine shared meshes only the dragon has handles that narrow, and at 15,000 its cuts
/// remove the same genus, 46, with 15,527 faces instead of 20,700, which kept its struts for the finer net:
/// solid 0.035 % against 0.063 % on the 10,000 cuts); π · t for a tolerance t (a tunnel narrower
/// than the tolerance, whose filling moves the surface by less than about t); NaN (no cut) for a percentage
/// not yet [`Resolution::resolved`] against the input's diagonal.
pub fn small_handle_loop(resolution: Resolution, area: f64) -> f64 {
    match resolution {
        Resolution::Vertices(n) => HANDLE_LOOP_SPACINGS * (area / n.max(1) as f64).sqrt(),
        // The goal may make the net finer: handles the first raised net could carry are kept.
        Resolution::Goal { start, cap } => {
            let n = ((start as f64 * super::goal::NET_RAISE).round() as usize).clamp(start, cap.max(start));
            HANDLE_LOOP_SPACINGS * (area / n.max(1) as f64).sqrt()
        }
        Resolution::Tolerance(t) => std::f64::consts::PI * t,
        Resolution::TolerancePct(_) => f64::NAN,
    }
}

/// The control-vertex counts to try: one for a count; for a tolerance, [`TOLERANCE_START`] doubling up to
/// [`TOLERANCE_MAX`].
pub(super) fn resolutions(resolution: Resolution) -> Result<Vec<usize>> {
    Ok(match resolution {
        Resolution::Vertices(n) | Resolution::Goal { start: n, .. } => vec![n],
        Resolution::TolerancePct(_) => return Err(Error::internal("a tolerance in percent was not resolved")),
        Resolution::Tolerance(t) => {
            if !(t.is_finite() && t > 0.0) {
                return Err(Error::new(ErrorCode::InputBadArgument, "the tolerance must be a positive length"));
            }
            let mut v = Vec::new();
            let mut n = TOLERANCE_START;
            while n <= TOLERANCE_MAX {
                v.push(n);
                n *= 2;
            }
            v
        }
    })
}

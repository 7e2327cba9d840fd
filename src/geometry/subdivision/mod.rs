//! Catmull–Clark subdivision surfaces: quad control nets ([`net`]: half-edge adjacency, one refinement step as
//! sparse stencils, the 4×4 grid of a regular face) and exact evaluation of the limit surface ([`limit`]).
//! The surface stage fits their control points; the B-rep stage turns them into B-spline faces.

pub mod limit;
pub mod net;

pub use limit::LimitSurface;
pub use net::QuadNet;

//! # scanstation
//!
//! Turns 3D scans (point clouds and triangle meshes) into CAD solids with a metric quality report.
//!
//! The crate is layered, bottom up; a lower layer never imports a higher one:
//! * [`geometry`] — **geometry core**: mesh/cloud types, adjacency, spatial indices, sampling, file formats.
//! * [`stages`] — the pipeline stages as plain functions (so far: [`stages::quality`]).
//! * [`pipeline`] — runs stages on a file and assembles reports.
//! * [`daemon`] — the unattended station: watch folders, job journal, D-Bus, systemd (tokio, zbus). Devices
//!   (turntable, trigger) arrive with their own issue.
//!
//! Errors everywhere are [`Error`] values with a stable [`ErrorCode`].
//!
//! # Example: the quality measure every stage reports with
//! ```
//! use scanstation::geometry::shapes::icosphere;
//! use scanstation::stages::{NoProgress, quality::{compare, CompareOptions}};
//! use scanstation::{Geometry, PolyMesh};
//!
//! let inner = Geometry::Mesh(PolyMesh::from(icosphere(1.0, 5, [0.0; 3])));
//! let outer = Geometry::Mesh(PolyMesh::from(icosphere(1.05, 5, [0.0; 3])));
//! let opts = CompareOptions { samples: 20_000, ..Default::default() };
//! let report = compare(&inner, &outer, &opts, &NoProgress)?;
//! assert!((report.symmetric.rms.value - 0.05).abs() < 0.05 * 0.005);
//! # Ok::<(), scanstation::Error>(())
//! ```

// `!(x > 0.0)` is deliberate: it is also true for NaN. Index loops over the 3 coordinates read better than
// zipped iterators in the geometry kernels.
#![warn(missing_docs)]
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop, clippy::collapsible_match)]

#[cfg(feature = "daemon")]
pub mod daemon;
#[cfg(feature = "daemon")]
pub mod devices;
pub mod error;
pub mod geometry;
pub mod pipeline;
pub mod stages;

pub use error::{Error, ErrorClass, ErrorCode, Location, Result};
pub use geometry::mesh::{Geometry, PointCloud, PolyMesh, TriMesh};

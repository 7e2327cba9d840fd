//! # scanstation
//!
//! Controls a 3D scanning station and turns its scans — posed range scans, point clouds and triangle meshes —
//! into CAD solids (STEP) with a metric quality report and a meshless FEA.
//!
//! The crate is layered, bottom up; a lower layer never imports a higher one (`tests/house.rs` checks it):
//! * [`geometry`] — **geometry core**: mesh/cloud types, adjacency, spatial indices, sampling, file formats.
//! * [`stages`] — the stages as plain functions over data: reconstruct, repair, remesh, surface, brep/STEP,
//!   quality, fea.
//! * [`pipeline`] — runs stages on files, enforces the quality gates, owns every artifact and report.
//! * `devices` — the rig: the turntable (Grbl 1.1, serial) and the scanner's trigger (CAN), with simulators
//!   (feature `daemon`).
//! * `daemon` — the unattended station: watch folders, job journal, scan sessions, D-Bus, systemd (tokio,
//!   zbus; feature `daemon`). It reaches the stages only through the pipeline.
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

//! **Geometry core** — the bottom layer: mesh and point-cloud types, adjacency, spatial indices, sampling,
//! synthetic shapes and file formats. Pure computation: no async runtime, no D-Bus, no global state.

pub mod bvh;
pub mod cellhash;
pub mod decimate;
pub mod hull;
pub mod intersect;
pub mod io;
pub mod linalg;
pub mod mesh;
pub mod points;
pub mod polygon;
pub mod pose;
pub mod raster;
pub mod sampling;
pub mod shapes;
pub mod stats;
pub mod subdivision;
pub mod tolerance;
pub mod topology;
pub mod vec3;

pub use mesh::{Geometry, PointCloud, PolyMesh, TriMesh};

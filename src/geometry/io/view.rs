//! One view of a scan set: its points in its own frame, its pose and where its scanner stood. Shared by the
//! scan-set readers ([`super::scanset`]: `.conf`, manifests; [`super::e57`]).

use std::path::PathBuf;

use crate::geometry::pose::Pose;
use crate::geometry::vec3::{V3, norm, scale, sub};

/// Most views in one scan set (a turntable scan at 1° steps has 360).
pub const MAX_VIEWS: usize = 4096;

/// One view of a scan set.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct View {
    /// The view's name (its file name as listed).
    pub name: String,
    /// Its file.
    pub file: PathBuf,
    /// Its pose: view frame → common frame.
    pub pose: Pose,
    /// Its points in its own frame.
    #[serde(skip)]
    pub points: Vec<[f32; 3]>,
    /// Its points' count.
    pub point_count: usize,
    /// Where the scanner stood in the view's frame, when known (E57: the origin); `None`: far along +z
    /// (the scanner looks down −z, Stanford's convention and the station's).
    pub scanner: Option<V3>,
    /// Its pass (1, 2, …): views of one pass share a common frame; the frames of two passes (the object
    /// turned over between them) are unknown to each other, and fusion finds them by their geometry.
    pub pass: u32,
    /// Whether its pass's common frame is a turntable's table frame (z up the axis, the table top at
    /// z = 0): the object rests on that plane, and no point of it lies below it.
    pub table_frame: bool,
}

impl View {
    /// The view's points in the common frame.
    pub fn placed(&self) -> Vec<[f32; 3]> {
        placed(&self.points, &self.pose)
    }

    /// The unit direction from the view's point `p` (its own frame) toward its scanner, in its own frame.
    pub fn toward_scanner(&self, p: V3) -> V3 {
        match self.scanner {
            None => [0.0, 0.0, 1.0],
            Some(s) => {
                let d = sub(s, p);
                let n = norm(d);
                if n > 0.0 { scale(d, 1.0 / n) } else { [0.0, 0.0, 1.0] }
            }
        }
    }
}

/// `points` moved by `pose`.
pub fn placed(points: &[[f32; 3]], pose: &Pose) -> Vec<[f32; 3]> {
    points.iter().map(|p| pose.apply(p.map(f64::from)).map(|c| c as f32)).collect()
}

//! The simulated structured-light scanner's optics: an object mesh standing on the simulated turntable, seen
//! by a camera with a projector beside it. [`RangeCamera::capture`] ray-casts one range image at a table
//! angle, as a real fringe-projection scanner measures one:
//!
//! - **resolution**: one ray per pixel of a `width × height` image over the field of view;
//! - **occlusion**: the first surface a ray meets, and only where the projector lights it too (a second ray
//!   from the point toward the projector, `baseline` to the camera's right, must reach it unblocked);
//! - **grazing dropouts**: a point whose surface turns away from the camera or the projector by more than
//!   `grazing_deg` is lost, and one between `grazing_deg − 20°` and it is lost with a probability rising
//!   linearly to one (fringes smear at grazing angles);
//! - **depth noise** along the ray, Gaussian, σ = `noise_rel` · (object diagonal) · (d / working distance)²
//!   (triangulation error grows with the square of the distance);
//! - **outliers**: a share `outliers` of the points moved along their ray by up to ±10 % of their depth.
//!
//! Every random draw comes from a generator seeded by (`seed`, the table angle in millidegrees, the pixel),
//! so a view depends only on its angle and the seed: the same scan twice gives the same points, whatever
//! order or how often the views are taken.
//!
//! Frames. The object mesh is placed on the table with its `up` axis along the table's axis, centred on it,
//! its lowest point on the table top. The camera looks at the object's middle from `distance` away, raised
//! by `elevation_deg`. Points are given in the **camera's frame**, which looks down −z (x right, y up; the
//! station's and Stanford's convention), and the table axis in that frame is [`RangeCamera::axis`] — what a
//! calibration gives the station (`[scan] axis_point`, `axis_direction`). The object at table angle 0 in the
//! camera frame is [`RangeCamera::truth_in_scanner`]; in the table frame the station fuses in,
//! [`RangeCamera::truth`]. The table top itself is not rendered (scanners crop it away by height), but it hides
//! what lies beyond it: a plate just wider than the object's footing ([`plate_radius`]).

use std::f64::consts::PI;

use crate::geometry::bvh::TriangleBvh;
use crate::geometry::hull::resting_faces;
use crate::geometry::mesh::TriMesh;
use crate::geometry::pose::{Pose, axis_angle};
use crate::geometry::sampling::Rng;
use crate::geometry::vec3::{Aabb, V3, add, cross, dot, norm, scale, sub, wide};

/// The simulated scanner's optical settings.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraSettings {
    /// Image width, pixels (one ray each).
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Vertical field of view, degrees.
    pub fov_deg: f64,
    /// From the camera to the object's middle, as a multiple of the object's bounding-box diagonal.
    pub distance_rel: f64,
    /// The camera's height above the table's plane, as an angle seen from the object's middle, degrees.
    pub elevation_deg: f64,
    /// The projector's offset to the camera's right, as a share of the working distance.
    pub baseline_rel: f64,
    /// Depth noise σ at the working distance, as a share of the object's diagonal (grows with distance²).
    pub noise_rel: f64,
    /// Points whose surface turns away from the camera or projector by more than this are lost, degrees.
    pub grazing_deg: f64,
    /// Share of points that are outliers (0–1).
    pub outliers: f64,
    /// Seed of every random draw.
    pub seed: u64,
}

impl Default for CameraSettings {
    /// 320 × 240 pixels over 30°, 2.2 diagonals away, 20° up, a 20 % baseline, σ 0.02 % of the diagonal,
    /// lost beyond 80° from the surface normal, no outliers, seed 1.
    fn default() -> Self {
        CameraSettings {
            width: 320,
            height: 240,
            fov_deg: 30.0,
            distance_rel: 2.2,
            elevation_deg: 20.0,
            baseline_rel: 0.2,
            noise_rel: 0.0002,
            grazing_deg: 80.0,
            outliers: 0.0,
            seed: 1,
        }
    }
}

impl CameraSettings {
    /// Check ranges.
    ///
    /// # Errors
    /// A message naming the setting.
    pub fn validate(&self) -> Result<(), String> {
        if !(8..=4096).contains(&self.width) || !(8..=4096).contains(&self.height) {
            return Err("resolution: width and height must be 8 to 4096 pixels".into());
        }
        let ranges = [
            ("fov_deg", self.fov_deg, 1.0, 120.0),
            ("distance_rel", self.distance_rel, 0.5, 100.0),
            ("elevation_deg", self.elevation_deg, -80.0, 80.0),
            ("baseline_rel", self.baseline_rel, 0.0, 2.0),
            ("noise_rel", self.noise_rel, 0.0, 0.1),
            ("grazing_deg", self.grazing_deg, 30.0, 90.0),
            ("outliers", self.outliers, 0.0, 0.5),
        ];
        for (name, v, lo, hi) in ranges {
            if !(v.is_finite() && (lo..=hi).contains(&v)) {
                return Err(format!("{name}: {v} is outside {lo}..={hi}"));
            }
        }
        Ok(())
    }
}

/// `mesh` with its faces facing outward: a closed, consistently oriented mesh whose enclosed volume is
/// negative (stored inside out) is reversed. The rig holds solid objects: a mesh with a hole, a non-manifold
/// edge or faces in conflict is refused, saying which.
///
/// # Errors
/// The reason, naming the counts and `scanstation repair` as the fix.
pub fn oriented_outward(mesh: &TriMesh) -> Result<TriMesh, String> {
    use crate::geometry::mesh::PolyMesh;
    use crate::geometry::topology::TopologyReport;
    let t = TopologyReport::compute(&PolyMesh::from(mesh.clone()));
    if !t.closed || t.nonmanifold_edges > 0 {
        return Err(format!(
            "the simulated rig holds closed objects: this mesh has {} boundary edges and {} non-manifold edges (close it first with `scanstation repair`)",
            t.boundary_edges, t.nonmanifold_edges
        ));
    }
    if !t.consistently_oriented {
        return Err(format!(
            "the simulated rig holds closed objects with consistently oriented faces: this mesh has {} orientation conflicts (`scanstation repair` orients them)",
            t.orientation_conflicts
        ));
    }
    let mut out = mesh.clone();
    if t.volume.unwrap_or(0.0) < 0.0 {
        out.triangles.iter_mut().for_each(|f| f.swap(1, 2));
    }
    Ok(out)
}

/// The radius of the plate an object stands on: 10 % beyond the farthest point of its footing (what lies
/// within 2 % of its height of the table), so a four-legged figure's plate reaches just past its feet and a
/// statue's just past its base, as a cradle's plate is chosen for what it carries. `object` in the table
/// frame (origin at the table top's centre, z up); `height` its extent along z.
fn plate_radius(object: &TriMesh, height: f64) -> f64 {
    let footing = object
        .positions
        .iter()
        .filter(|p| f64::from(p[2]) <= 0.02 * height)
        .map(|p| f64::from(p[0]).hypot(f64::from(p[1])))
        .fold(0.0, f64::max);
    1.1 * footing
}

/// Which mesh axis points up on the table.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Up {
    /// +y (most character models: spot, the Stanford bunny).
    Y,
    /// +z (CAD and many scans).
    Z,
}

/// The object on the table and the camera looking at it.
pub struct RangeCamera {
    settings: CameraSettings,
    /// The object in the table's frame (z up along the axis, origin on the axis at the table top).
    object: TriMesh,
    bvh: TriangleBvh,
    /// Camera centre, table frame.
    eye: V3,
    /// Camera axes (right, up, backward) in the table frame.
    axes: [V3; 3],
    /// Projector centre, table frame.
    projector: V3,
    /// Working distance (eye to the object's middle).
    distance: f64,
    /// The object's bounding-box diagonal.
    diagonal: f64,
    /// The table top's radius: the plate the object stands on ([`plate_radius`]).
    plate: f64,
    /// Mixed into every draw's key: 0 as first placed, the turn-over's seed after one (so a second pass's
    /// views draw other noise than the first pass's at the same stops).
    placing: u64,
}

impl RangeCamera {
    /// Place `mesh` on the table (`up` along the axis) and aim the camera at it: any closed mesh, its faces
    /// turned outward first ([`oriented_outward`]: one stored inside out would show the camera nothing).
    ///
    /// # Errors
    /// Settings out of range; a mesh with no triangles or no extent; one that is not closed, not manifold or
    /// not consistently oriented (the message says which, and how to fix it).
    pub fn new(mesh: &TriMesh, up: Up, settings: CameraSettings) -> Result<RangeCamera, String> {
        settings.validate()?;
        if mesh.triangles.is_empty() {
            return Err("the object mesh has no triangles".into());
        }
        let oriented = oriented_outward(mesh)?;
        let mesh = &oriented;
        // Mesh → table: `up` becomes +z (for y-up, (x, y, z) → (x, −z, y), a proper rotation).
        let turn = |p: [f32; 3]| -> V3 {
            let p = wide(p);
            match up {
                Up::Y => [p[0], -p[2], p[1]],
                Up::Z => p,
            }
        };
        let turned: Vec<V3> = mesh.positions.iter().map(|&p| turn(p)).collect();
        let mut b = Aabb::EMPTY;
        for &p in &turned {
            b.add(p);
        }
        let diagonal = b.diagonal();
        if !(diagonal > 0.0) {
            return Err("the object mesh has no extent".into());
        }
        let centre = [(b.min[0] + b.max[0]) / 2.0, (b.min[1] + b.max[1]) / 2.0, b.min[2]];
        let positions: Vec<[f32; 3]> = turned.iter().map(|&p| sub(p, centre).map(|c| c as f32)).collect();
        let object = TriMesh { positions, triangles: mesh.triangles.clone() };
        let bvh = TriangleBvh::new(&object);
        let height = b.max[2] - b.min[2];
        let aim = [0.0, 0.0, height / 2.0];
        let distance = settings.distance_rel * diagonal;
        let e = settings.elevation_deg.to_radians();
        let forward = [0.0, e.cos(), -e.sin()];
        let eye = sub(aim, scale(forward, distance));
        let right = [1.0, 0.0, 0.0];
        let back = scale(forward, -1.0);
        let upv = cross(back, right);
        let projector = add(eye, scale(right, settings.baseline_rel * distance));
        let plate = plate_radius(&object, height);
        Ok(RangeCamera {
            settings,
            object,
            bvh,
            eye,
            axes: [right, upv, back],
            projector,
            distance,
            diagonal,
            plate,
            placing: 0,
        })
    }

    /// Whether the ray `from + t·dir`, 0 < t ≤ `far`, crosses the table top: the plate the object stands
    /// on, a disc in the table frame's plane z = 0 ([`plate_radius`]), seen from either side.
    fn table_hit(&self, from: V3, dir: V3, far: f64) -> bool {
        if dir[2].abs() < 1e-12 {
            return false;
        }
        let t = -from[2] / dir[2];
        // The object's bottom lies in the table's plane: a ray that meets both there meets the table.
        if !(t > 1e-9 * self.diagonal && t < far + 1e-7 * self.diagonal) {
            return false;
        }
        let (x, y) = (from[0] + t * dir[0], from[1] + t * dir[1]);
        x * x + y * y <= self.plate * self.plate
    }

    /// The radius of the plate the object stands on ([`plate_radius`]), model units: what a station's
    /// calibration measures of its table.
    pub fn plate_radius(&self) -> f64 {
        self.plate
    }

    /// The settings.
    pub fn settings(&self) -> &CameraSettings {
        &self.settings
    }

    /// A table-frame point in the camera frame.
    fn to_camera(&self, p: V3) -> V3 {
        let d = sub(p, self.eye);
        [dot(self.axes[0], d), dot(self.axes[1], d), dot(self.axes[2], d)]
    }

    /// The table's axis in the camera frame: a point on it (the table top's centre) and its unit direction
    /// (up). What the station's calibration gives it.
    pub fn axis(&self) -> (V3, V3) {
        let p = self.to_camera([0.0; 3]);
        let d = [self.axes[0][2], self.axes[1][2], self.axes[2][2]];
        (p, d)
    }

    /// The object in the table frame (origin at the table top's centre, z up the axis, x the camera's right):
    /// the frame the station fuses a scan's views in, so what a scan should give back.
    pub fn truth(&self) -> TriMesh {
        self.object.clone()
    }

    /// The object at table angle 0 in the camera frame.
    pub fn truth_in_scanner(&self) -> TriMesh {
        let positions =
            self.object.positions.iter().map(|&p| self.to_camera(wide(p)).map(|c| c as f32)).collect::<Vec<_>>();
        TriMesh { positions, triangles: self.object.triangles.clone() }
    }

    /// The cradle's tilt axis in the camera frame, at 0° and 0°: a point on it (the table top's centre) and
    /// its unit direction (the camera's right, so a positive tilt turns the table's top toward the camera).
    /// What the station's calibration gives it for a tilting table.
    pub fn tilt_axis(&self) -> (V3, V3) {
        let p = self.to_camera([0.0; 3]);
        let d = [self.axes[0][0], self.axes[1][0], self.axes[2][0]];
        (p, d)
    }

    /// The object turned over, as a person does between two passes: it rests on the most stable face of its
    /// hull ([`resting_faces`]) that is turned more than 60° from the face it stands on now, turned about the
    /// table's axis by a seeded angle and set down a seeded distance (up to 5 % of its diagonal) off the axis.
    /// The rig (camera, projector, plate, axes) stays. Returns the camera over the turned object and the
    /// motion from this table frame to the new one (what the station is not told).
    ///
    /// # Errors
    /// A message when the object has no other face it can rest on (a ball), or no hull.
    pub fn turned_over(&self, seed: u64) -> Result<(RangeCamera, Pose), String> {
        let rests = resting_faces(&self.object)?;
        let down = [0.0, 0.0, -1.0];
        let rest = rests.iter().find(|r| dot(r.normal, down) < 0.5).ok_or_else(|| {
            format!(
                "the object has no other face to rest on ({} stable faces, none turned more than 60° from the one it stands on)",
                rests.len()
            )
        })?;
        // Rotate the facet's normal onto "down", then about the axis by the seeded angle.
        let n = rest.normal;
        let axis = cross(n, down);
        let tip = if norm(axis) > 1e-9 {
            axis_angle(scale(axis, 1.0 / norm(axis)), dot(n, down).clamp(-1.0, 1.0).acos())
        } else {
            axis_angle([1.0, 0.0, 0.0], std::f64::consts::PI)
        };
        let mut rng = Rng::new(seed ^ 0x7E24_0BE2);
        let yaw = axis_angle([0.0, 0.0, 1.0], 2.0 * PI * rng.next_f64());
        let turn =
            Pose { rotation: yaw, translation: [0.0; 3] }.then_after(&Pose { rotation: tip, translation: [0.0; 3] });
        let mut b = Aabb::EMPTY;
        self.object.positions.iter().for_each(|&p| b.add(turn.apply(wide(p))));
        let (r, phi) = (0.05 * self.diagonal * rng.next_f64(), 2.0 * PI * rng.next_f64());
        let shift =
            [r * phi.cos() - (b.min[0] + b.max[0]) / 2.0, r * phi.sin() - (b.min[1] + b.max[1]) / 2.0, -b.min[2]];
        let motion = Pose { rotation: turn.rotation, translation: shift };
        let positions = self.object.positions.iter().map(|&p| motion.apply(wide(p)).map(|c| c as f32)).collect();
        let object = TriMesh { positions, triangles: self.object.triangles.clone() };
        let bvh = TriangleBvh::new(&object);
        let camera = RangeCamera {
            settings: self.settings.clone(),
            object,
            bvh,
            placing: self.placing.wrapping_add(seed | 1),
            ..*self
        };
        Ok((camera, motion))
    }

    /// One range image with the table at `angle_deg` (the object turned by that angle about the axis,
    /// right-handed): the measured points in the camera frame, row by row. Cost: one or two ray casts per
    /// pixel, O(log F) each.
    pub fn capture(&self, angle_deg: f64) -> Vec<[f32; 3]> {
        self.capture_tilted(angle_deg, 0.0)
    }

    /// [`RangeCamera::capture`] on a tilting table: turned by `angle_deg`, then tilted by `tilt_deg` about the
    /// [`RangeCamera::tilt_axis`]. The table top (the plate, [`plate_radius`]) hides what rests on it:
    /// a tilt shows the object's underside only where it does not stand on the table.
    pub fn capture_tilted(&self, angle_deg: f64, tilt_deg: f64) -> Vec<[f32; 3]> {
        let s = &self.settings;
        // Turning the object by θ, then tilting it by φ about x, is moving the camera and projector by the
        // opposite tilt, then the opposite turn, around it (the table frame stays the object's).
        let (sin, cos) = (-angle_deg.to_radians()).sin_cos();
        let (sin_t, cos_t) = (-tilt_deg.to_radians()).sin_cos();
        let untilt = |v: V3| [v[0], cos_t * v[1] - sin_t * v[2], sin_t * v[1] + cos_t * v[2]];
        let rot = |v: V3| {
            let v = untilt(v);
            [cos * v[0] - sin * v[1], sin * v[0] + cos * v[1], v[2]]
        };
        let eye = rot(self.eye);
        let projector = rot(self.projector);
        let axes = self.axes.map(rot);
        let table = |from: V3, dir: V3, far: f64| self.table_hit(from, dir, far);
        let half = (s.fov_deg.to_radians() / 2.0).tan();
        let aspect = f64::from(s.width) / f64::from(s.height);
        let sigma0 = s.noise_rel * self.diagonal;
        let far = self.distance + 2.0 * self.diagonal;
        let grazing = s.grazing_deg.to_radians().cos();
        let ramp_start = (s.grazing_deg - 20.0).max(0.0).to_radians().cos();
        // Tilt 0 keeps the keys (and so the views) of a single-axis table.
        let key = (angle_deg * 1000.0).round() as i64 as u64
            ^ ((tilt_deg * 1000.0).round() as i64 as u64).wrapping_mul(0x94D0_49BB_1331_11EB)
            ^ self.placing.wrapping_mul(0xBF58_476D_1CE4_E5B9);
        let mut out = Vec::new();
        for j in 0..s.height {
            for i in 0..s.width {
                let mut rng = Rng::new(
                    s.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15)
                        ^ key.wrapping_mul(0xD1B5_4A32_D192_ED03)
                        ^ (u64::from(j) << 32 | u64::from(i)),
                );
                let u = ((f64::from(i) + 0.5) / f64::from(s.width) * 2.0 - 1.0) * half * aspect;
                let v = (1.0 - (f64::from(j) + 0.5) / f64::from(s.height) * 2.0) * half;
                let cam_dir = [u, v, -1.0];
                let len = norm(cam_dir);
                let cam_dir = scale(cam_dir, 1.0 / len);
                let dir = add(add(scale(axes[0], cam_dir[0]), scale(axes[1], cam_dir[1])), scale(axes[2], cam_dir[2]));
                let Some((t, n)) = self.bvh.ray_first(eye, dir, 0.0, far) else { continue };
                if table(eye, dir, t) {
                    continue;
                }
                let hit = add(eye, scale(dir, t));
                // Facing the camera, and lit by the projector.
                let cos_cam = -dot(n, dir);
                let to_proj = sub(projector, hit);
                let proj_dist = norm(to_proj);
                let to_proj = scale(to_proj, 1.0 / proj_dist);
                let cos_proj = dot(n, to_proj);
                let seen = cos_cam.min(cos_proj);
                if seen <= grazing {
                    continue;
                }
                if seen < ramp_start && rng.next_f64() > (seen - grazing) / (ramp_start - grazing) {
                    continue;
                }
                let eps = 1e-6 * self.diagonal;
                if self.bvh.ray_first(add(hit, scale(to_proj, eps)), to_proj, eps, proj_dist).is_some()
                    || table(add(hit, scale(to_proj, eps)), to_proj, proj_dist)
                {
                    continue;
                }
                let sigma = sigma0 * (t / self.distance).powi(2);
                let mut depth = t + sigma * gaussian(&mut rng);
                if s.outliers > 0.0 && rng.next_f64() < s.outliers {
                    depth *= 1.0 + 0.2 * (rng.next_f64() - 0.5);
                }
                out.push(scale(cam_dir, depth).map(|c| c as f32));
            }
        }
        out
    }
}

/// A standard normal draw (Box–Muller).
fn gaussian(rng: &mut Rng) -> f64 {
    let u1 = rng.next_f64().max(1e-300);
    let u2 = rng.next_f64();
    (-2.0 * u1.ln()).sqrt() * (2.0 * PI * u2).cos()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A closed axis-aligned box, outward triangles.
    fn cube(h: f32) -> TriMesh {
        let p = |x: f32, y: f32, z: f32| [x * h, y * h, z * h];
        let positions = vec![
            p(-1., -1., -1.),
            p(1., -1., -1.),
            p(1., 1., -1.),
            p(-1., 1., -1.),
            p(-1., -1., 1.),
            p(1., -1., 1.),
            p(1., 1., 1.),
            p(-1., 1., 1.),
        ];
        let triangles = vec![
            [0, 2, 1],
            [0, 3, 2],
            [4, 5, 6],
            [4, 6, 7],
            [0, 1, 5],
            [0, 5, 4],
            [1, 2, 6],
            [1, 6, 5],
            [2, 3, 7],
            [2, 7, 6],
            [3, 0, 4],
            [3, 4, 7],
        ];
        TriMesh { positions, triangles }
    }

    /// A cube stored inside out is turned outward and seen as the outward one is (the same views); an open
    /// mesh is refused, naming its boundary edges.
    #[test]
    fn an_inside_out_object_is_turned_outward_and_an_open_one_refused() {
        let s = CameraSettings { noise_rel: 0.0, width: 64, height: 48, ..Default::default() };
        let mut inside_out = cube(1.0);
        inside_out.triangles.iter_mut().for_each(|f| f.swap(1, 2));
        let (a, b) = (
            RangeCamera::new(&cube(1.0), Up::Z, s.clone()).unwrap(),
            RangeCamera::new(&inside_out, Up::Z, s.clone()).unwrap(),
        );
        for angle in [0.0, 45.0] {
            let (va, vb) = (a.capture(angle), b.capture(angle));
            assert!(va.len() > 200, "{} points", va.len());
            assert_eq!(va, vb, "angle {angle}: the inside-out cube is seen as the cube");
        }
        let mut open = cube(1.0);
        open.triangles.truncate(10);
        let e = RangeCamera::new(&open, Up::Z, s).err().expect("an open mesh is refused");
        assert!(e.contains("closed objects") && e.contains("boundary edges"), "{e}");
    }

    /// On a tilting table: noise-free views at several turns and tilts, placed by the composed pose about
    /// the reported axes ([`Pose::tilted_turntable`]), land on the truth; tilting toward the camera shows
    /// the cube's top, and the table top keeps its bottom hidden at every tilt.
    #[test]
    fn tilted_views_placed_by_the_composed_pose_lie_on_the_truth() {
        let s = CameraSettings { noise_rel: 0.0, width: 64, height: 48, ..Default::default() };
        let cam = RangeCamera::new(&cube(1.0), Up::Z, s).expect("camera");
        let truth = cam.truth_in_scanner();
        let bvh = TriangleBvh::new(&truth);
        let (axis, tilt) = (cam.axis(), cam.tilt_axis());
        let top = truth.positions.iter().map(|p| dot(wide(*p), axis.1)).fold(f64::MIN, f64::max);
        let bottom = truth.positions.iter().map(|p| dot(wide(*p), axis.1)).fold(f64::MAX, f64::min);
        let mut on_top = Vec::new();
        for (angle, tilt_deg) in [(0.0, 0.0), (30.0, 20.0), (135.0, -30.0), (270.0, 45.0), (60.0, 90.0)] {
            let view = cam.capture_tilted(angle, tilt_deg);
            assert!(view.len() > 100, "({angle}, {tilt_deg}): {} points", view.len());
            let pose = Pose::tilted_turntable(axis, tilt, angle, tilt_deg).expect("pose");
            let placed: Vec<V3> = view.iter().map(|&p| pose.apply(wide(p))).collect();
            let worst = placed.iter().map(|&p| bvh.distance(p)).fold(0.0, f64::max);
            assert!(worst < 1e-4, "({angle}, {tilt_deg}): a point is {worst} from the truth");
            let height = |p: &V3| dot(*p, axis.1);
            assert!(placed.iter().all(|p| height(p) > bottom + 1e-3), "({angle}, {tilt_deg}): the bottom was seen");
            on_top.push(placed.iter().filter(|p| (height(p) - top).abs() < 1e-6).count());
        }
        assert_eq!(cam.capture_tilted(30.0, 0.0), cam.capture(30.0), "tilt 0 is the single-axis view");
        assert!(on_top[4] > on_top[0], "tilted 90° toward the camera, the top faces it: {on_top:?}");
    }

    /// A 1 × 2 × 4 box standing on its small face, turned over, lies on a big face (the most stable one),
    /// on the table (its lowest point at 0), off the axis by at most 5 % of its diagonal; noise-free views of
    /// it, placed about the same axis and moved back by the motion, lie on the first placing's truth.
    #[test]
    fn a_turned_over_object_rests_on_another_face_at_a_pose_not_told() {
        let s = CameraSettings { noise_rel: 0.0, width: 64, height: 48, ..Default::default() };
        let mut tall = cube(1.0);
        tall.positions.iter_mut().for_each(|p| *p = [p[0] * 0.5, p[1], p[2] * 2.0]);
        let cam = RangeCamera::new(&tall, Up::Z, s).expect("camera");
        let (turned, motion) = cam.turned_over(7).expect("turned over");
        let t = turned.truth();
        let zmin = t.positions.iter().map(|p| p[2]).fold(f32::MAX, f32::min);
        let zmax = t.positions.iter().map(|p| p[2]).fold(f32::MIN, f32::max);
        assert!(zmin.abs() < 1e-5 && (zmax - 1.0).abs() < 1e-5, "lies on a 2 × 4 face: z {zmin}..{zmax}");
        let c = t.bbox();
        let off = ((c.min[0] + c.max[0]) / 2.0).hypot((c.min[1] + c.max[1]) / 2.0);
        assert!(off <= 0.05 * cam.diagonal + 1e-9, "{off}");
        assert_eq!(turned.axis(), cam.axis(), "the rig stays");
        let truth = TriangleBvh::new(&cam.truth());
        let (point, direction) = cam.axis();
        // Camera frame (table at 0°) → table frame.
        let to_table = |q: V3| {
            add(cam.eye, add(add(scale(cam.axes[0], q[0]), scale(cam.axes[1], q[1])), scale(cam.axes[2], q[2])))
        };
        for angle in [0.0, 120.0, 240.0] {
            let view = turned.capture(angle);
            assert!(view.len() > 100, "{angle}: {} points", view.len());
            let pose = crate::geometry::pose::Pose::turntable(point, direction, angle).expect("pose");
            let worst = view
                .iter()
                .map(|&p| truth.distance(motion.inverse_apply(to_table(pose.apply(wide(p))))))
                .fold(0.0, f64::max);
            assert!(worst < 1e-4, "{angle}: a point is {worst} from the truth");
        }
        assert!(cam.turned_over(8).unwrap().1 != motion, "another seed, another pose");
    }

    /// Noise-free views, placed by the turntable pose about the reported axis, land on the truth.
    #[test]
    fn noise_free_views_placed_about_the_axis_lie_on_the_truth() {
        let s = CameraSettings { noise_rel: 0.0, width: 64, height: 48, ..Default::default() };
        let cam = RangeCamera::new(&cube(1.0), Up::Z, s).expect("camera");
        let truth = TriangleBvh::new(&cam.truth_in_scanner());
        let (point, direction) = cam.axis();
        for angle in [0.0, 30.0, 135.0, 270.0] {
            let view = cam.capture(angle);
            assert!(view.len() > 200, "angle {angle}: {} points", view.len());
            let pose = Pose::turntable(point, direction, angle).expect("pose");
            let worst = view.iter().map(|&p| truth.distance(pose.apply(wide(p)))).fold(0.0, f64::max);
            assert!(worst < 1e-4, "angle {angle}: a point is {worst} from the truth");
        }
    }

    /// The same seed and angle give the same view; another seed other noise of the same size.
    #[test]
    fn views_depend_only_on_seed_and_angle() {
        let s = CameraSettings { width: 40, height: 30, noise_rel: 0.001, ..Default::default() };
        let a = RangeCamera::new(&cube(1.0), Up::Z, s.clone()).expect("camera");
        let b = RangeCamera::new(&cube(1.0), Up::Z, CameraSettings { seed: 2, ..s }).expect("camera");
        assert_eq!(a.capture(15.0), a.capture(15.0));
        assert_ne!(a.capture(15.0), b.capture(15.0));
    }

    /// Grazing faces are lost: looking straight at a face from 20° up, the top face (70° from the view) keeps
    /// points, and with a 60° limit it loses them all.
    #[test]
    fn grazing_faces_drop_out() {
        let s = CameraSettings { noise_rel: 0.0, width: 64, height: 48, ..Default::default() };
        let count_top = |grazing_deg: f64| {
            let cam = RangeCamera::new(&cube(1.0), Up::Z, CameraSettings { grazing_deg, ..s.clone() }).expect("cam");
            let (point, direction) = cam.axis();
            let pose = Pose::turntable(point, direction, 0.0).expect("pose");
            let truth = cam.truth_in_scanner();
            let top = truth.positions.iter().map(|p| dot(wide(*p), direction)).fold(f64::MIN, f64::max);
            cam.capture(0.0).iter().filter(|&&p| (dot(pose.apply(wide(p)), direction) - top).abs() < 1e-6).count()
        };
        assert!(count_top(89.0) > 50, "top face at 89°: {}", count_top(89.0));
        assert_eq!(count_top(60.0), 0);
    }
}

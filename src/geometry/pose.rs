//! Rigid poses: a rotation and a translation taking a view's frame to the common frame, `w = R·p + t`.
//!
//! Built from the three forms a scan set may give (see [`crate::geometry::io::scanset`]): a 4×4 matrix, a
//! translation and a unit quaternion, or a turntable angle about a calibrated axis. Constructors validate
//! and return the reason a pose is refused, which the readers turn into `input.bad-record` with the line.

use crate::geometry::vec3::{V3, add, cross, dot, norm, scale, sub};

/// How far a given rotation may be from orthonormal (largest entry of `RᵀR − I`, unitless): poses printed
/// with 6 significant digits are orthonormal to about 1e-6.
pub const ORTHONORMAL_TOLERANCE: f64 = 1e-3;

/// A rigid motion `w = R·p + t`.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Pose {
    /// Rotation, row-major (`w[i] = Σ_j rotation[i][j]·p[j] + translation[i]`).
    pub rotation: [[f64; 3]; 3],
    /// Translation.
    pub translation: V3,
}

impl Default for Pose {
    fn default() -> Self {
        Pose::IDENTITY
    }
}

impl Pose {
    /// The identity.
    pub const IDENTITY: Pose =
        Pose { rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], translation: [0.0; 3] };

    /// The rotation of the unit quaternion `q = (x, y, z, w)` (scalar last) followed by `t`.
    ///
    /// # Errors
    /// A non-finite value, or a quaternion whose length is not 1 within 1 %.
    pub fn from_quaternion(t: V3, q: [f64; 4]) -> Result<Pose, String> {
        if t.iter().chain(&q).any(|v| !v.is_finite()) {
            return Err("the pose has a value that is not a finite number".into());
        }
        let len = q.iter().map(|v| v * v).sum::<f64>().sqrt();
        if (len - 1.0).abs() > 0.01 {
            return Err(format!("the rotation quaternion has length {len:.4}, not 1"));
        }
        let [x, y, z, w] = q.map(|v| v / len);
        let rotation = [
            [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - z * w), 2.0 * (x * z + y * w)],
            [2.0 * (x * y + z * w), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - x * w)],
            [2.0 * (x * z - y * w), 2.0 * (y * z + x * w), 1.0 - 2.0 * (x * x + y * y)],
        ];
        Ok(Pose { rotation, translation: t })
    }

    /// A 4×4 homogeneous matrix, row-major, whose last row is `0 0 0 1`.
    ///
    /// # Errors
    /// A non-finite value, another last row, a rotation block farther than [`ORTHONORMAL_TOLERANCE`] from
    /// orthonormal, or a reflection (determinant −1).
    pub fn from_matrix(m: [[f64; 4]; 4]) -> Result<Pose, String> {
        if m.iter().flatten().any(|v| !v.is_finite()) {
            return Err("the matrix has a value that is not a finite number".into());
        }
        if m[3] != [0.0, 0.0, 0.0, 1.0] {
            return Err(format!("the matrix's last row is {:?}, not [0, 0, 0, 1]", m[3]));
        }
        let rotation: [[f64; 3]; 3] = std::array::from_fn(|i| [m[i][0], m[i][1], m[i][2]]);
        let mut worst: f64 = 0.0;
        for i in 0..3 {
            for j in 0..3 {
                let g: f64 = (0..3).map(|k| rotation[k][i] * rotation[k][j]).sum();
                worst = worst.max((g - if i == j { 1.0 } else { 0.0 }).abs());
            }
        }
        if worst > ORTHONORMAL_TOLERANCE {
            return Err(format!("the matrix's 3×3 block is not a rotation (RᵀR differs from I by {worst:.2e})"));
        }
        let det = dot(rotation[0], cross(rotation[1], rotation[2]));
        if det < 0.0 {
            return Err("the matrix's 3×3 block is a reflection (determinant −1), not a rotation".into());
        }
        Ok(Pose { rotation, translation: [m[0][3], m[1][3], m[2][3]] })
    }

    /// The pose of a view taken with the turntable at `angle_deg`: the table turned the object by that angle
    /// about the axis through `point` along `direction` (right-handed), so the view's points go back to the
    /// object's frame (the table at 0°) by the opposite turn.
    ///
    /// # Errors
    /// A non-finite value or a zero direction.
    pub fn turntable(point: V3, direction: V3, angle_deg: f64) -> Result<Pose, String> {
        if point.iter().chain(&direction).chain([&angle_deg]).any(|v| !v.is_finite()) {
            return Err("the turntable pose has a value that is not a finite number".into());
        }
        let len = norm(direction);
        if len < 1e-12 {
            return Err("the turntable axis direction is zero".into());
        }
        Ok(Pose::about(axis_angle(scale(direction, 1.0 / len), -angle_deg.to_radians()), point, [0.0; 3]))
    }

    /// The pose of a view taken on a tilting turntable: the table turned the object by `angle_deg` about its
    /// axis, then the cradle tilted table, axis and object by `tilt_deg` about the tilt axis (`axis` and
    /// `tilt`: a point and a direction each, in the view's frame at 0° and 0°; both right-handed). The view's
    /// points go back by the opposite tilt, then the opposite turn. With `tilt_deg` 0 it is
    /// [`Pose::turntable`].
    ///
    /// # Errors
    /// As [`Pose::turntable`], for either axis.
    pub fn tilted_turntable(axis: (V3, V3), tilt: (V3, V3), angle_deg: f64, tilt_deg: f64) -> Result<Pose, String> {
        let untilt = Pose::turntable(tilt.0, tilt.1, tilt_deg)?;
        let unturn = Pose::turntable(axis.0, axis.1, angle_deg)?;
        Ok(unturn.then_after(&untilt))
    }

    /// `rotation` about `centre`, then `shift`: `w = R·(p − c) + c + shift`.
    pub fn about(rotation: [[f64; 3]; 3], centre: V3, shift: V3) -> Pose {
        let turned = Pose { rotation, translation: [0.0; 3] }.apply_dir(centre);
        Pose { rotation, translation: add(sub(centre, turned), shift) }
    }

    /// The rotation as a unit quaternion `(x, y, z, w)`, `w ≥ 0` (Shepperd's method: from the largest of the
    /// four squared components, so it stays exact near every angle).
    pub fn quaternion(&self) -> [f64; 4] {
        let r = &self.rotation;
        let t = r[0][0] + r[1][1] + r[2][2];
        let q = if t > r[0][0].max(r[1][1]).max(r[2][2]) {
            let s = (1.0 + t).sqrt() * 2.0;
            [(r[2][1] - r[1][2]) / s, (r[0][2] - r[2][0]) / s, (r[1][0] - r[0][1]) / s, 0.25 * s]
        } else if r[0][0] >= r[1][1] && r[0][0] >= r[2][2] {
            let s = (1.0 + r[0][0] - r[1][1] - r[2][2]).sqrt() * 2.0;
            [0.25 * s, (r[0][1] + r[1][0]) / s, (r[0][2] + r[2][0]) / s, (r[2][1] - r[1][2]) / s]
        } else if r[1][1] >= r[2][2] {
            let s = (1.0 + r[1][1] - r[0][0] - r[2][2]).sqrt() * 2.0;
            [(r[0][1] + r[1][0]) / s, 0.25 * s, (r[1][2] + r[2][1]) / s, (r[0][2] - r[2][0]) / s]
        } else {
            let s = (1.0 + r[2][2] - r[0][0] - r[1][1]).sqrt() * 2.0;
            [(r[0][2] + r[2][0]) / s, (r[1][2] + r[2][1]) / s, 0.25 * s, (r[1][0] - r[0][1]) / s]
        };
        let len = q.iter().map(|v| v * v).sum::<f64>().sqrt();
        let sign = if q[3] < 0.0 { -1.0 } else { 1.0 };
        q.map(|v| sign * v / len)
    }

    /// `R·p + t`.
    pub fn apply(&self, p: V3) -> V3 {
        add(self.apply_dir(p), self.translation)
    }

    /// `R·d`.
    pub fn apply_dir(&self, d: V3) -> V3 {
        let r = &self.rotation;
        std::array::from_fn(|i| r[i][0] * d[0] + r[i][1] * d[1] + r[i][2] * d[2])
    }

    /// `Rᵀ·(w − t)`: a common-frame point in the view's frame.
    pub fn inverse_apply(&self, w: V3) -> V3 {
        let d = sub(w, self.translation);
        let r = &self.rotation;
        std::array::from_fn(|i| r[0][i] * d[0] + r[1][i] * d[1] + r[2][i] * d[2])
    }

    /// `self ∘ other`: first `other`, then `self`.
    pub fn then_after(&self, other: &Pose) -> Pose {
        let rotation = std::array::from_fn(|i| {
            std::array::from_fn(|j| (0..3).map(|k| self.rotation[i][k] * other.rotation[k][j]).sum())
        });
        Pose { rotation, translation: self.apply(other.translation) }
    }

    /// Rotation angle (degrees) and translation length of `self` relative to `other` (`self ∘ other⁻¹`).
    pub fn difference(&self, other: &Pose) -> (f64, f64) {
        // M = A·Bᵀ; its angle from the trace and the skew part (atan2 stays exact near 0 even for rotations
        // orthonormal only to the digits they were printed with).
        let m: [[f64; 3]; 3] = std::array::from_fn(|i| {
            std::array::from_fn(|j| (0..3).map(|k| self.rotation[i][k] * other.rotation[j][k]).sum())
        });
        let skew = [m[2][1] - m[1][2], m[0][2] - m[2][0], m[1][0] - m[0][1]];
        let angle = (0.5 * norm(skew)).atan2(0.5 * (m[0][0] + m[1][1] + m[2][2] - 1.0)).to_degrees();
        (angle, norm(sub(self.translation, other.translation)))
    }
}

/// The rotation by `angle` (radians) about the unit axis `u` (Rodrigues).
pub fn axis_angle(u: V3, angle: f64) -> [[f64; 3]; 3] {
    let (s, c) = angle.sin_cos();
    let k = 1.0 - c;
    let [x, y, z] = u;
    [
        [c + x * x * k, x * y * k - z * s, x * z * k + y * s],
        [y * x * k + z * s, c + y * y * k, y * z * k - x * s],
        [z * x * k - y * s, z * y * k + x * s, c + z * z * k],
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: V3, b: V3) -> bool {
        norm(sub(a, b)) < 1e-12
    }

    /// The three forms agree: a quarter turn about +z given as a quaternion, a matrix and a turntable angle
    /// (the table turning by −90° brings a view back by +90°).
    #[test]
    fn the_three_forms_agree_and_invert() {
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let q = Pose::from_quaternion([1.0, 2.0, 3.0], [0.0, 0.0, h, h]).unwrap();
        let m = Pose::from_matrix([
            [0.0, -1.0, 0.0, 1.0],
            [1.0, 0.0, 0.0, 2.0],
            [0.0, 0.0, 1.0, 3.0],
            [0.0, 0.0, 0.0, 1.0],
        ])
        .unwrap();
        assert!(close(q.apply([1.0, 0.0, 0.0]), [1.0, 3.0, 3.0]));
        assert!(close(m.apply([1.0, 0.0, 0.0]), [1.0, 3.0, 3.0]));
        let t = Pose::turntable([1.0, 1.0, 0.0], [0.0, 0.0, 1.0], -90.0).unwrap();
        // About the axis through (1, 1): (2, 1) → (1, 2); the axis point stays.
        assert!(close(t.apply([2.0, 1.0, 5.0]), [1.0, 2.0, 5.0]) && close(t.apply([1.0, 1.0, 0.0]), [1.0, 1.0, 0.0]));
        let p = [0.3, -0.7, 2.0];
        assert!(close(q.inverse_apply(q.apply(p)), p));
        let (angle, shift) = q.difference(&Pose::IDENTITY);
        assert!((angle - 90.0).abs() < 1e-9 && (shift - 14f64.sqrt()).abs() < 1e-12, "{angle} {shift}");
        assert!(close(q.then_after(&m).apply(p), q.apply(m.apply(p))));
        // The quaternion round trip, near 0°, 90° and 180° about several axes.
        for (axis, deg) in
            [([0.0, 0.0, 1.0], 90.0), ([1.0, 2.0, 3.0], 179.9), ([0.3, -1.0, 0.2], 0.01), ([1.0, 0.0, 0.0], 180.0)]
        {
            let n = norm(axis);
            let pose = Pose { rotation: axis_angle(scale(axis, 1.0 / n), f64::to_radians(deg)), translation: [0.0; 3] };
            let back = Pose::from_quaternion([0.0; 3], pose.quaternion()).unwrap();
            assert!(back.difference(&pose).0 < 1e-9, "{axis:?} {deg}°");
        }
    }

    #[test]
    fn bad_poses_are_refused_with_a_reason() {
        assert!(Pose::from_quaternion([0.0; 3], [0.0, 0.0, 0.0, 2.0]).unwrap_err().contains("length"));
        assert!(Pose::from_quaternion([f64::NAN, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]).is_err());
        let mut m = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]];
        m[2][2] = -1.0;
        assert!(Pose::from_matrix(m).unwrap_err().contains("reflection"));
        m[2][2] = 2.0;
        assert!(Pose::from_matrix(m).unwrap_err().contains("not a rotation"));
        m[2][2] = 1.0;
        m[3][0] = 1.0;
        assert!(Pose::from_matrix(m).unwrap_err().contains("last row"));
        assert!(Pose::turntable([0.0; 3], [0.0; 3], 10.0).unwrap_err().contains("zero"));
    }
}

//! Minimal f64 3-vector arithmetic for the numeric kernels (positions are stored as f32, see
//! [`crate::geometry::mesh`]; every computation widens to f64 first).

/// A 3-vector of f64.
pub type V3 = [f64; 3];

/// Widen an f32 position to f64.
#[inline]
pub fn wide(p: [f32; 3]) -> V3 {
    [p[0] as f64, p[1] as f64, p[2] as f64]
}
#[inline]
/// a − b.
pub fn sub(a: V3, b: V3) -> V3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
#[inline]
/// a + b.
pub fn add(a: V3, b: V3) -> V3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
#[inline]
/// s · a.
pub fn scale(a: V3, s: f64) -> V3 {
    [a[0] * s, a[1] * s, a[2] * s]
}
#[inline]
/// a · b.
pub fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
#[inline]
/// a × b.
pub fn cross(a: V3, b: V3) -> V3 {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}
#[inline]
/// |a|².
pub fn norm2(a: V3) -> f64 {
    dot(a, a)
}
#[inline]
/// |a|.
pub fn norm(a: V3) -> f64 {
    dot(a, a).sqrt()
}

/// `a` scaled to unit length, or `fallback` when its length is at most 1e-12.
#[inline]
pub fn unit_or(a: V3, fallback: V3) -> V3 {
    let l = norm(a);
    if l > 1e-12 { scale(a, 1.0 / l) } else { fallback }
}

/// Two unit vectors (u, v) spanning the plane with unit normal `n`, with u × v = n: u is n × x̂ (n × ŷ when `n`
/// is within about 26° of x̂), v = n × u.
pub fn plane_frame(n: V3) -> (V3, V3) {
    let helper = if n[0].abs() < 0.9 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
    let u = unit_or(cross(n, helper), [0.0, 0.0, 1.0]);
    (u, cross(n, u))
}

/// An axis-aligned box in f64. An empty box has `min > max`.
#[derive(Copy, Clone, Debug, PartialEq, serde::Serialize)]
pub struct Aabb {
    /// Smallest corner.
    pub min: V3,
    /// Largest corner.
    pub max: V3,
}

impl Aabb {
    /// The empty box (grows to fit the first point added).
    pub const EMPTY: Aabb = Aabb { min: [f64::INFINITY; 3], max: [f64::NEG_INFINITY; 3] };

    /// Grow to contain `p`.
    #[inline]
    pub fn add(&mut self, p: V3) {
        for k in 0..3 {
            self.min[k] = self.min[k].min(p[k]);
            self.max[k] = self.max[k].max(p[k]);
        }
    }

    /// Bounding box of f32 points; `EMPTY` for none.
    pub fn of_points(points: &[[f32; 3]]) -> Aabb {
        let mut b = Aabb::EMPTY;
        for &p in points {
            b.add(wide(p));
        }
        b
    }

    /// True when no point was added.
    pub fn is_empty(&self) -> bool {
        self.min[0] > self.max[0]
    }

    /// Edge lengths (zero for an empty box).
    pub fn extent(&self) -> V3 {
        if self.is_empty() { [0.0; 3] } else { sub(self.max, self.min) }
    }

    /// Length of the diagonal (zero for an empty box).
    pub fn diagonal(&self) -> f64 {
        norm(self.extent())
    }
}

/// (b − a) × (c − a) for the triangle `t` over positions `p`: its normal, scaled by twice its area.
#[inline]
pub fn tri_cross(p: &[V3], t: [u32; 3]) -> V3 {
    let [a, b, c] = t.map(|i| p[i as usize]);
    cross(sub(b, a), sub(c, a))
}

/// Area of triangle `t` over positions `p`.
#[inline]
pub fn tri_area(p: &[V3], t: [u32; 3]) -> f64 {
    0.5 * norm(tri_cross(p, t))
}

/// Unit normal of triangle `t` over positions `p`; `None` when it has no area.
#[inline]
pub fn tri_unit_normal(p: &[V3], t: [u32; 3]) -> Option<V3> {
    let n = tri_cross(p, t);
    let l = norm(n);
    (l > 0.0).then(|| scale(n, 1.0 / l))
}

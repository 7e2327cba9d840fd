//! Synthetic shapes with known answers, for tests, examples and benchmarks.

use std::collections::HashMap;

use crate::geometry::mesh::TriMesh;

/// An icosphere: the icosahedron subdivided `level` times, vertices projected onto the sphere of `radius`
/// around `center`. Outward-oriented, closed, genus 0; `10·4^level + 2` vertices, `20·4^level` triangles.
pub fn icosphere(radius: f64, level: u32, center: [f64; 3]) -> TriMesh {
    let t = (1.0 + 5f64.sqrt()) / 2.0;
    let mut v: Vec<[f64; 3]> = vec![
        [-1.0, t, 0.0],
        [1.0, t, 0.0],
        [-1.0, -t, 0.0],
        [1.0, -t, 0.0],
        [0.0, -1.0, t],
        [0.0, 1.0, t],
        [0.0, -1.0, -t],
        [0.0, 1.0, -t],
        [t, 0.0, -1.0],
        [t, 0.0, 1.0],
        [-t, 0.0, -1.0],
        [-t, 0.0, 1.0],
    ];
    let mut f: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    let unit = |p: [f64; 3]| {
        let n = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
        [p[0] / n, p[1] / n, p[2] / n]
    };
    v.iter_mut().for_each(|p| *p = unit(*p));
    for _ in 0..level {
        let mut mid: HashMap<(u32, u32), u32> = HashMap::new();
        let mut next = Vec::with_capacity(f.len() * 4);
        let mut midpoint = |a: u32, b: u32, v: &mut Vec<[f64; 3]>| {
            let key = (a.min(b), a.max(b));
            *mid.entry(key).or_insert_with(|| {
                let (p, q) = (v[a as usize], v[b as usize]);
                v.push(unit([(p[0] + q[0]) / 2.0, (p[1] + q[1]) / 2.0, (p[2] + q[2]) / 2.0]));
                (v.len() - 1) as u32
            })
        };
        for &[a, b, c] in &f {
            let ab = midpoint(a, b, &mut v);
            let bc = midpoint(b, c, &mut v);
            let ca = midpoint(c, a, &mut v);
            next.extend_from_slice(&[[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        f = next;
    }
    let positions = v.iter().map(|p| [0, 1, 2].map(|k| (center[k] + radius * p[k]) as f32)).collect();
    TriMesh { positions, triangles: f }
}

/// An axis-aligned box from `min` to `max`, 12 outward triangles.
pub fn cuboid(min: [f64; 3], max: [f64; 3]) -> TriMesh {
    let c = |i: usize| {
        [
            if i & 1 == 0 { min[0] } else { max[0] },
            if i & 2 == 0 { min[1] } else { max[1] },
            if i & 4 == 0 { min[2] } else { max[2] },
        ]
        .map(|x| x as f32)
    };
    let positions = (0..8).map(c).collect();
    let triangles = vec![
        [0, 2, 1],
        [1, 2, 3],
        [4, 5, 6],
        [5, 7, 6], // z- , z+
        [0, 1, 4],
        [1, 5, 4],
        [2, 6, 3],
        [3, 6, 7], // y- , y+
        [0, 4, 2],
        [2, 4, 6],
        [1, 3, 5],
        [3, 7, 5], // x- , x+
    ];
    TriMesh { positions, triangles }
}

/// A round rod along x from 0 to `length`: `n` segments around, `rings` + 1 rings of side vertices, each end
/// cap a fan of `n` triangles around its centre. Closed and outward; `n·(rings + 1) + 2` vertices.
pub fn rod(radius: f64, length: f64, n: usize, rings: usize) -> TriMesh {
    let n = n.max(3);
    let rings = rings.max(1);
    let mut positions = Vec::with_capacity(n * (rings + 1) + 2);
    for r in 0..=rings {
        let x = length * r as f64 / rings as f64;
        for i in 0..n {
            let a = std::f64::consts::TAU * i as f64 / n as f64;
            positions.push([x as f32, (radius * a.cos()) as f32, (radius * a.sin()) as f32]);
        }
    }
    let (c0, c1) = (positions.len() as u32, positions.len() as u32 + 1);
    positions.push([0.0, 0.0, 0.0]);
    positions.push([length as f32, 0.0, 0.0]);
    let v = |r: usize, i: usize| (r * n + i % n) as u32;
    let mut triangles = Vec::with_capacity(2 * n * (rings + 1));
    for r in 0..rings {
        for i in 0..n {
            triangles.push([v(r, i), v(r, i + 1), v(r + 1, i + 1)]);
            triangles.push([v(r, i), v(r + 1, i + 1), v(r + 1, i)]);
        }
    }
    for i in 0..n {
        triangles.push([c0, v(0, i + 1), v(0, i)]);
        triangles.push([c1, v(rings, i), v(rings, i + 1)]);
    }
    TriMesh { positions, triangles }
}

/// A torus around the z axis with major radius `major`, tube radius `minor`, `n` segments around the axis
/// and `m` around the tube: closed, outward, genus 1; `n·m` vertices, `2·n·m` triangles.
pub fn torus(major: f64, minor: f64, n: usize, m: usize) -> TriMesh {
    use std::f64::consts::TAU;
    let mut positions = Vec::with_capacity(n * m);
    for i in 0..n {
        let u = TAU * i as f64 / n as f64;
        for j in 0..m {
            let v = TAU * j as f64 / m as f64;
            let r = major + minor * v.cos();
            positions.push([(r * u.cos()) as f32, (r * u.sin()) as f32, (minor * v.sin()) as f32]);
        }
    }
    let id = |i: usize, j: usize| ((i % n) * m + (j % m)) as u32;
    let mut triangles = Vec::with_capacity(2 * n * m);
    for i in 0..n {
        for j in 0..m {
            let (a, b, c, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
            triangles.push([a, b, c]);
            triangles.push([a, c, d]);
        }
    }
    TriMesh { positions, triangles }
}

/// A quad ball: a cube's six faces each split into `k × k` quads, vertices projected onto the sphere of
/// `radius` around the origin. Outward-oriented, closed, genus 0; 8 valence-3 corners, all other vertices
/// valence 4; `6k²` quads, `6k² + 2` vertices. `k = 2` is the 24-face cage of the sphere oracle.
pub fn quad_ball(radius: f64, k: usize) -> crate::geometry::mesh::PolyMesh {
    let k = k.max(1);
    let mut pos: Vec<[f64; 3]> = Vec::new();
    let mut index: HashMap<[i64; 3], u32> = HashMap::new();
    let mut faces: Vec<Vec<u32>> = Vec::new();
    // (outward normal, u axis, v axis) with u × v = normal.
    let axes: [([f64; 3], [f64; 3], [f64; 3]); 6] = [
        ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]),
        ([-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]),
        ([0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]),
        ([0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]),
        ([0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]),
        ([0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]),
    ];
    for (n, a, b) in axes {
        let mut id = |i: usize, j: usize| -> u32 {
            let (s, t) = (2 * i as i64 - k as i64, 2 * j as i64 - k as i64);
            let key: [i64; 3] = std::array::from_fn(|c| n[c] as i64 * k as i64 + a[c] as i64 * s + b[c] as i64 * t);
            *index.entry(key).or_insert_with(|| {
                pos.push(key.map(|x| x as f64));
                (pos.len() - 1) as u32
            })
        };
        for j in 0..k {
            for i in 0..k {
                faces.push(vec![id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1)]);
            }
        }
    }
    let positions = pos
        .into_iter()
        .map(|p| {
            let l = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
            p.map(|c| (c / l * radius) as f32)
        })
        .collect();
    crate::geometry::mesh::PolyMesh::new(positions, &faces).expect("quad ball is valid")
}

/// A quad torus around the z axis: `n` quads around the major circle (radius `major`), `m` around the tube
/// (radius `minor`). Outward-oriented, closed, genus 1, every vertex valence 4.
pub fn quad_torus(major: f64, minor: f64, n: usize, m: usize) -> crate::geometry::mesh::PolyMesh {
    let (n, m) = (n.max(3), m.max(3));
    // Same vertices as the triangle torus; each pair of its triangles is one quad.
    let positions = torus(major, minor, n, m).positions;
    let id = |i: usize, j: usize| ((i % n) * m + j % m) as u32;
    let faces: Vec<Vec<u32>> = (0..n)
        .flat_map(|i| (0..m).map(move |j| vec![id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1)]))
        .collect();
    crate::geometry::mesh::PolyMesh::new(positions, &faces).expect("quad torus is valid")
}

/// A surface of revolution about the z axis: the profile's points `[r, z]` (r ≥ 0) swept round, each ring
/// with as many vertices as keep its edges at most `step` long (at least 3), neighbouring rings zipped
/// together by angle, so the triangles stay near-isotropic where the profile's points are about `step` apart
/// (a thin rod's ring gets 3 vertices, not as many as the widest ring's).
///
/// An open profile runs from a point on the axis (r = 0, the bottom pole) to another (the top pole),
/// counter-clockwise in the (r, z) plane: genus 0, its inner points become rings and each pole one vertex.
/// A closed profile (`closed`: the last point joins the first; every r > 0), counter-clockwise, is a genus-1
/// surface, as [`torus`]. Either way the result is closed and outward. Used by the thin-part oracles below.
///
/// # Panics
/// A profile with fewer than 3 points, or an open one whose ends are off the axis.
pub fn revolve(profile: &[[f64; 2]], closed: bool, step: f64) -> TriMesh {
    use std::f64::consts::TAU;
    assert!(profile.len() >= 3, "a profile needs 3 points");
    let rings: &[[f64; 2]] = if closed {
        profile
    } else {
        let ends = [profile[0][0], profile[profile.len() - 1][0]];
        assert!(ends.iter().all(|r| r.abs() < 1e-9), "an open profile ends on the axis");
        &profile[1..profile.len() - 1]
    };
    let mut positions = Vec::new();
    let mut first = Vec::with_capacity(rings.len() + 1);
    for &[r, z] in rings {
        let n = ((TAU * r / step).ceil() as usize).max(3);
        first.push(positions.len());
        for i in 0..n {
            let u = TAU * i as f64 / n as f64;
            positions.push([(r * u.cos()) as f32, (r * u.sin()) as f32, z as f32]);
        }
    }
    first.push(positions.len());
    let m = rings.len();
    let ring = |j: usize| (first[j % m], first[j % m + 1] - first[j % m]);
    let mut triangles = Vec::new();
    for j in 0..if closed { m } else { m - 1 } {
        let ((a0, na), (b0, nb)) = (ring(j), ring(j + 1));
        let (a, b) = (|i: usize| (a0 + i % na) as u32, |k: usize| (b0 + k % nb) as u32);
        let (mut i, mut k) = (0, 0);
        while i < na || k < nb {
            // Advance on the ring whose next vertex comes first by angle.
            if k == nb || (i < na && (i + 1) as f64 / na as f64 <= (k + 1) as f64 / nb as f64) {
                triangles.push([a(i), a(i + 1), b(k)]);
                i += 1;
            } else {
                triangles.push([a(i), b(k + 1), b(k)]);
                k += 1;
            }
        }
    }
    if !closed {
        let (bottom, top) = (positions.len() as u32, positions.len() as u32 + 1);
        positions.push([0.0, 0.0, profile[0][1] as f32]);
        positions.push([0.0, 0.0, profile[profile.len() - 1][1] as f32]);
        let ((a0, na), (b0, nb)) = (ring(0), ring(m - 1));
        for i in 0..na {
            triangles.push([bottom, (a0 + (i + 1) % na) as u32, (a0 + i) as u32]);
        }
        for i in 0..nb {
            triangles.push([(b0 + i) as u32, (b0 + (i + 1) % nb) as u32, top]);
        }
    }
    TriMesh { positions, triangles }
}

/// Points every `step` (at most) along a polyline from `a` to `b`, `a` included, `b` not.
fn segment(out: &mut Vec<[f64; 2]>, a: [f64; 2], b: [f64; 2], step: f64) {
    let k = (((b[0] - a[0]).hypot(b[1] - a[1]) / step).ceil() as usize).max(1);
    out.extend((0..k).map(|i| {
        let t = i as f64 / k as f64;
        [a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])]
    }));
}

/// Points every `step` (at most) along the arc of `radius` about `c` from angle `a0` to `a1` (radians,
/// counter-clockwise when `a1 > a0`), the start included, the end not.
fn arc(out: &mut Vec<[f64; 2]>, c: [f64; 2], radius: f64, a0: f64, a1: f64, step: f64) {
    let k = ((radius * (a1 - a0).abs() / step).ceil() as usize).max(1);
    out.extend((0..k).map(|i| {
        let a = a0 + (a1 - a0) * i as f64 / k as f64;
        [(c[0] + radius * a.cos()).max(0.0), c[1] + radius * a.sin()]
    }));
}

/// A round plate of radius 1 and `thickness`, its rim a half circle: genus 0. Profile points every `step`.
pub fn plate_profile(thickness: f64, step: f64) -> Vec<[f64; 2]> {
    use std::f64::consts::FRAC_PI_2;
    let h = thickness / 2.0;
    let mut p = Vec::new();
    segment(&mut p, [0.0, -h], [1.0 - h, -h], step);
    arc(&mut p, [1.0 - h, 0.0], h, -FRAC_PI_2, FRAC_PI_2, step);
    segment(&mut p, [1.0 - h, h], [0.0, h], step);
    p.push([0.0, h]);
    p
}

/// Two balls of radius 1, centres 4 apart on z, joined by a "leg": a round rod of `radius` (< 1): genus 0.
/// Profile points every `step`.
pub fn leg_profile(radius: f64, step: f64) -> Vec<[f64; 2]> {
    use std::f64::consts::FRAC_PI_2;
    let (c, a) = (2.0, radius.clamp(1e-6, 0.99).acos());
    let mut p = Vec::new();
    arc(&mut p, [0.0, -c], 1.0, -FRAC_PI_2, a, step);
    let z = (1.0 - radius * radius).sqrt();
    segment(&mut p, [radius, -c + z], [radius, c - z], step);
    arc(&mut p, [0.0, c], 1.0, -a, FRAC_PI_2, step);
    p.push([0.0, c + 1.0]);
    p
}

/// A ball of radius 1 under a cone of half-angle `half_angle_deg` whose tip is a sharp point on the axis,
/// tangent to the ball: genus 0. Profile points every `step`.
pub fn cone_tip_profile(half_angle_deg: f64, step: f64) -> Vec<[f64; 2]> {
    use std::f64::consts::FRAC_PI_2;
    let b = half_angle_deg.to_radians().clamp(0.01, 1.5);
    // The cone touches the ball at the half angle above the equator; its tip is at 1 / sin b.
    let touch = b;
    let mut p = Vec::new();
    arc(&mut p, [0.0, 0.0], 1.0, -FRAC_PI_2, touch, step);
    segment(&mut p, [touch.cos(), touch.sin()], [0.0, 1.0 / b.sin()], step);
    p.push([0.0, 1.0 / b.sin()]);
    p
}

/// A sheet of `thickness` folded in two, its arms `gap` apart, as a closed (r, z) profile for [`revolve`]:
/// the arms run from r = 1 to r = 2 and the fold is at r = 2, so the revolved shape is a genus-1 ring whose
/// two inner faces look at each other across `gap`. Points every `step` along the sheet's middle line.
pub fn folded_sheet_profile(thickness: f64, gap: f64, step: f64) -> Vec<[f64; 2]> {
    use std::f64::consts::FRAC_PI_2;
    let (w, h) = (thickness / 2.0, (gap + thickness) / 2.0);
    let (r0, r1) = (1.0, 2.0);
    let mut p = Vec::new();
    // Counter-clockwise around the band: the bottom arm's underside out to the fold, around the fold's outside,
    // the top arm's upper side back in, the top arm's end cap, the gap's two faces via the fold's inside, and
    // the bottom arm's end cap.
    segment(&mut p, [r0, -h - w], [r1, -h - w], step);
    arc(&mut p, [r1, 0.0], h + w, -FRAC_PI_2, FRAC_PI_2, step);
    segment(&mut p, [r1, h + w], [r0, h + w], step);
    arc(&mut p, [r0, h], w, FRAC_PI_2, 3.0 * FRAC_PI_2, step);
    segment(&mut p, [r0, h - w], [r1, h - w], step);
    arc(&mut p, [r1, 0.0], h - w, FRAC_PI_2, -FRAC_PI_2, step);
    segment(&mut p, [r1, -h + w], [r0, -h + w], step);
    arc(&mut p, [r0, -h], w, FRAC_PI_2, 3.0 * FRAC_PI_2, step);
    p
}

//! Synthetic shapes with known answers, for tests, examples and benchmarks.

use std::collections::HashMap;

use crate::geometry::mesh::TriMesh;
use crate::geometry::vec3::{dot, norm, plane_frame, sub};

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
    revolve_rings(profile, closed, step, 3)
}

/// [`revolve`] with at least `min_ring` vertices on every ring (a thin rod or a tip sampled round, as a scan
/// samples it, not as a triangle or a square).
///
/// # Panics
/// As [`revolve`].
pub fn revolve_rings(profile: &[[f64; 2]], closed: bool, step: f64, min_ring: usize) -> TriMesh {
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
        let n = ((TAU * r / step).ceil() as usize).max(min_ring.max(3));
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

/// A round plate of radius 1 and `thickness`, its rim a half circle: genus 0. Profile points every `step`, and
/// at least 8 around the rim.
pub fn plate_profile(thickness: f64, step: f64) -> Vec<[f64; 2]> {
    use std::f64::consts::FRAC_PI_2;
    let h = thickness / 2.0;
    let mut p = Vec::new();
    segment(&mut p, [0.0, -h], [1.0 - h, -h], step);
    arc(&mut p, [1.0 - h, 0.0], h, -FRAC_PI_2, FRAC_PI_2, step.min(std::f64::consts::PI * h / 8.0));
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

/// A lens of radius 1 and `thickness` at its centre, its rim a sharp edge (two spherical caps meeting at an
/// angle of about 2·thickness radians), as an open profile for [`revolve`]: genus 0. Points every `step`,
/// closer toward the rim (a tenth of `step` in the last 5 %), so the sharp edge is sampled as a scan of a
/// blade would be.
pub fn lens_profile(thickness: f64, step: f64) -> Vec<[f64; 2]> {
    let h = thickness / 2.0;
    // The caps' sphere: radius ρ through (0, ±h) and (1, 0), centre on the axis at ∓(ρ − h).
    let rho = (1.0 + h * h) / (2.0 * h);
    let at = |r: f64, up: bool| {
        let z = (rho * rho - r * r).sqrt() - (rho - h);
        [r, if up { z } else { -z }]
    };
    let mut radii = Vec::new();
    let mut r = 0.0;
    while r < 1.0 {
        radii.push(r);
        r += if r > 0.95 { step / 10.0 } else { step };
    }
    let mut p: Vec<[f64; 2]> = radii.iter().map(|&r| at(r, false)).collect();
    p.push([1.0, 0.0]);
    p.extend(radii.iter().rev().map(|&r| at(r, true)));
    p
}

/// A ball of radius 1 with five fingers: round rods of `finger_radius`, `finger_length` beyond the ball, each
/// ending in a half ball, fanned over the upper half (50° from +z, 36° apart around it), each widening to 2.5 ×
/// its radius where it meets the ball over 3 radii. The ball is an icosphere of `level` (its edges about
/// 1.05 / 2^level); the fingers' rings are about `step` apart. Closed, outward, genus 0.
pub fn hand(finger_radius: f64, finger_length: f64, level: u32, step: f64) -> TriMesh {
    let ball = icosphere(1.0, level, [0.0; 3]);
    let p: Vec<[f64; 3]> = ball.positions.iter().map(|x| x.map(f64::from)).collect();
    let dirs: Vec<[f64; 3]> = (0..5)
        .map(|k| {
            let (t, f) = (50f64.to_radians(), (36.0 * k as f64).to_radians());
            [t.sin() * f.cos(), t.sin() * f.sin(), t.cos()]
        })
        .collect();
    let foot = 2.5 * finger_radius;
    // 1. Holes: every ball triangle with a corner inside a finger's foot.
    let inside = |v: usize| dirs.iter().any(|&d| dot(p[v], d) > (1.0 - foot * foot).sqrt());
    let mut triangles: Vec<[u32; 3]> =
        ball.triangles.iter().copied().filter(|t| !t.iter().any(|&v| inside(v as usize))).collect();
    let mut positions = ball.positions.clone();
    // 2. Each hole's rim, walked along the remaining triangles' edges that have no twin.
    let twins: std::collections::HashSet<(u32, u32)> =
        triangles.iter().flat_map(|t| (0..3).map(move |k| (t[k], t[(k + 1) % 3]))).collect();
    let mut next: HashMap<u32, u32> = HashMap::new();
    for t in &triangles {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            if !twins.contains(&(b, a)) {
                next.insert(b, a); // the rim walked with the hole on the left: counter-clockwise seen from outside
            }
        }
    }
    for &d in &dirs {
        let (u, v) = plane_frame(d);
        let angle = |x: [f64; 3]| dot(x, v).atan2(dot(x, u)).rem_euclid(std::f64::consts::TAU);
        // The rim of this finger's hole, from the vertex nearest angle 0.
        let start = *next
            .keys()
            .filter(|&&a| dot(p[a as usize], d) > (3.0 * foot).cos())
            .min_by(|&&a, &&b| angle(p[a as usize]).total_cmp(&angle(p[b as usize])).then(a.cmp(&b)))
            .expect("a finger's hole has a rim");
        let mut rim = vec![start];
        while let Some(&n) = next.get(rim.last().unwrap()) {
            if n == start {
                break;
            }
            rim.push(n);
        }
        // 3. The finger's profile (radius, height along d): a collar from the rim, the rod, the half ball.
        let base = rim.iter().map(|&a| dot(p[a as usize], d)).fold(f64::MIN, f64::max);
        let top = 1.0 + finger_length;
        let mut prof = Vec::new();
        let mut h = base + step / 2.0;
        while h < top - finger_radius {
            let s = ((h - base) / (3.0 * finger_radius)).min(1.0);
            prof.push([finger_radius * (1.0 + 1.5 * (1.0 - s) * (1.0 - s)), h]);
            h += step;
        }
        let k = ((std::f64::consts::FRAC_PI_2 * finger_radius / step).ceil() as usize).max(2);
        for i in 0..k {
            let a = std::f64::consts::FRAC_PI_2 * i as f64 / k as f64;
            prof.push([finger_radius * a.cos(), top - finger_radius + finger_radius * a.sin()]);
        }
        // 4. Rings, zipped to each other (and the first to the rim) by the share of the way around.
        let mut prev: Vec<(u32, f64)> = {
            let pts: Vec<[f64; 3]> = rim.iter().map(|&a| p[a as usize]).collect();
            let mut along = vec![0.0];
            for i in 1..pts.len() {
                along.push(along[i - 1] + norm(sub(pts[i - 1], pts[i])));
            }
            let total = along[pts.len() - 1] + norm(sub(pts[pts.len() - 1], pts[0]));
            rim.iter().zip(along).map(|(&a, s)| (a, s / total)).collect()
        };
        for &[r, h] in &prof {
            let n = ((std::f64::consts::TAU * r / step).ceil() as usize).max(6);
            let ring: Vec<(u32, f64)> = (0..n)
                .map(|i| {
                    let a = std::f64::consts::TAU * i as f64 / n as f64;
                    let x = [0, 1, 2].map(|c| h * d[c] + r * (a.cos() * u[c] + a.sin() * v[c]));
                    positions.push(x.map(|c| c as f32));
                    ((positions.len() - 1) as u32, i as f64 / n as f64)
                })
                .collect();
            zip_loops(&prev, &ring, &mut triangles);
            prev = ring;
        }
        positions.push([0, 1, 2].map(|c| (top * d[c]) as f32));
        let tip = (positions.len() - 1) as u32;
        for i in 0..prev.len() {
            triangles.push([prev[i].0, prev[(i + 1) % prev.len()].0, tip]);
        }
    }
    // The ball's vertices inside the feet are left unreferenced: drop them.
    let wide: Vec<[f64; 3]> = positions.iter().map(|x| x.map(f64::from)).collect();
    let (kept, triangles, _) = crate::geometry::polygon::drop_unreferenced(&wide, &triangles);
    TriMesh { positions: kept.iter().map(|x| x.map(|c| c as f32)).collect(), triangles }
}

/// Triangles joining two closed loops around an axis (each vertex with its share of the way around, from
/// 0, increasing counter-clockwise seen from the `upper` side's end), advancing on the loop whose next vertex
/// comes first; outward when `lower` is below `upper`.
fn zip_loops(lower: &[(u32, f64)], upper: &[(u32, f64)], out: &mut Vec<[u32; 3]>) {
    let (na, nb) = (lower.len(), upper.len());
    let share = |l: &[(u32, f64)], i: usize| if i >= l.len() { 1.0 } else { l[i].1 };
    let (mut i, mut k) = (0, 0);
    while i < na || k < nb {
        if k == nb || (i < na && share(lower, i + 1) <= share(upper, k + 1)) {
            out.push([lower[i].0, lower[(i + 1) % na].0, upper[k % nb].0]);
            i += 1;
        } else {
            out.push([lower[i % na].0, upper[(k + 1) % nb].0, upper[k].0]);
            k += 1;
        }
    }
}

/// A block 2 × 1 × 1 (from the origin) with its 90° edges and one edge (along x at y = z = 1) cut by a 45°
/// chamfer of `chamfer` a side, its faces split into triangles of edges about `step` at most: closed, outward,
/// genus 0, every edge between two faces a crease of 90° or 135°.
pub fn chamfered_block(chamfer: f64, step: f64) -> TriMesh {
    let c = 1.0 - chamfer;
    let mut pts = vec![[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, c], [0.0, c, 1.0]];
    let far: Vec<[f64; 3]> = pts.iter().map(|q| [2.0, q[1], q[2]]).collect();
    pts.extend(far);
    let mut tris = crate::geometry::hull::convex_hull(&pts).expect("a block's corners span space");
    let mut p = pts;
    let longest = |p: &[[f64; 3]], t: &[[u32; 3]]| {
        t.iter()
            .flat_map(|t| (0..3).map(move |k| norm(sub(p[t[k] as usize], p[t[(k + 1) % 3] as usize]))))
            .fold(0.0, f64::max)
    };
    while longest(&p, &tris) > step {
        crate::geometry::polygon::subdivide_midpoints(&mut p, &mut tris);
    }
    TriMesh { positions: p.iter().map(|x| x.map(|c| c as f32)).collect(), triangles: tris }
}

//! Surface stage: Catmull–Clark limit evaluation and the least-squares fit.

use scanstation::geometry::shapes;
use scanstation::geometry::subdivision::limit::{EvPatch, FaceKind, LimitSurface, limit_stencil, point_weights};
use scanstation::geometry::vec3::{self, V3};
use scanstation::stages::NoProgress;
use scanstation::stages::surface::{FitOptions, QuadNet, SphereTarget, control_net, fit_control_points};

/// The quad ball of `shapes` as a control net with f64 positions.
pub fn quad_ball(k: usize) -> (QuadNet, Vec<V3>) {
    control_net(&shapes::quad_ball(1.0, k)).expect("quad ball is a closed net")
}

fn eval(s: &LimitSurface, p1: &[V3], f: usize, u: f64, v: f64, ev: Option<&EvPatch>) -> V3 {
    let w = point_weights(s, f, u, v, ev);
    let mut acc = [0.0; 3];
    for (g, wt) in w.pos {
        acc = vec3::add(acc, vec3::scale(p1[g as usize], wt));
    }
    acc
}

#[test]
fn quad_ball_is_outward_and_closed() {
    let (net, pos) = quad_ball(2);
    assert_eq!(net.faces.len(), 24);
    assert_eq!(pos.len(), 26);
    // Outward: (p1 − p0) × (p3 − p0) · p0 > 0 on every face.
    for q in &net.faces {
        let [a, b, _, d] = q.map(|i| pos[i as usize]);
        let n = vec3::cross(vec3::sub(b, a), vec3::sub(d, a));
        assert!(vec3::dot(n, a) > 0.0, "face {q:?} points inward");
    }
}

/// Exact evaluation near an extraordinary corner meets the limit point there and the neighbouring patches
/// along the shared boundary.
#[test]
fn extraordinary_patches_are_continuous() {
    let (net, pos) = quad_ball(2);
    let s = LimitSurface::new(&net).unwrap();
    let p1 = s.refine.apply(&pos);
    let evs = s.kinds.iter().filter(|k| matches!(k, FaceKind::Extraordinary(_))).count();
    assert_eq!(evs, 24, "8 valence-3 corners × 3 refined faces");
    for f in 0..s.net.faces.len() {
        let FaceKind::Extraordinary(c) = s.kinds[f] else { continue };
        let ev = EvPatch::new(&s.net, f, c as usize).unwrap();
        // Corner: limit stencil of the extraordinary vertex.
        let corner = s.net.faces[f][c as usize];
        let mut lim = [0.0; 3];
        for (g, w) in limit_stencil(&s.net, corner) {
            lim = vec3::add(lim, vec3::scale(p1[g as usize], w));
        }
        let near = eval(&s, &p1, f, 1e-6, 1e-6, Some(&ev));
        assert!(vec3::norm(vec3::sub(near, lim)) < 1e-3, "face {f}: {near:?} vs limit {lim:?}");
        // Far boundary u = 1 equals the neighbour across that edge (a regular face).
        let h = (4 * f + (c as usize + 1) % 4) as u32;
        let t = s.net.twin[h as usize];
        let g = (t / 4) as usize;
        let gev = match s.kinds[g] {
            FaceKind::Extraordinary(gc) => Some(EvPatch::new(&s.net, g, gc as usize).unwrap()),
            _ => None,
        };
        for k in 1..10 {
            let t_ = k as f64 / 10.0;
            let a = eval(&s, &p1, f, 1.0, t_, Some(&ev));
            // Find the same point on g by sampling its boundary: compare against the closest of a fine scan.
            let mut best = f64::INFINITY;
            for m in 0..=1000 {
                let x = m as f64 / 1000.0;
                for (u, v) in [(x, 0.0), (x, 1.0), (0.0, x), (1.0, x)] {
                    let b = eval(&s, &p1, g, u, v, gev.as_ref());
                    best = best.min(vec3::norm(vec3::sub(a, b)));
                }
            }
            assert!(best < 2e-3, "face {f} → {g}: boundary gap {best}");
        }
    }
}

/// Analytic oracle: the fitted limit surface of the 24-face ball is within the design's 0.00063 RMS of
/// the unit sphere (naive control points: 0.163).
#[test]
fn sphere_cage_fit_reaches_design_rms() {
    let (net, pos) = quad_ball(2);
    let opts = FitOptions { samples_per_side: 6, rounds: 8, smoothing: 0.0, ..Default::default() };
    let target = SphereTarget { center: [0.0; 3], radius: 1.0 };
    let (p, s, report) = fit_control_points(&net, &pos, &target, &opts, &NoProgress).unwrap();
    let p1 = s.refine.apply(&p);
    let mut sum = 0.0;
    let mut area = 0.0;
    let mut max: f64 = 0.0;
    let n = 16;
    for f in 0..s.net.faces.len() {
        let ev = match s.kinds[f] {
            FaceKind::Extraordinary(c) => Some(EvPatch::new(&s.net, f, c as usize).unwrap()),
            _ => None,
        };
        for j in 0..n {
            for i in 0..n {
                let (u, v) = ((i as f64 + 0.5) / n as f64, (j as f64 + 0.5) / n as f64);
                let w = point_weights(&s, f, u, v, ev.as_ref());
                let mut x = [0.0; 3];
                let mut du = [0.0; 3];
                let mut dv = [0.0; 3];
                for (g, wt) in &w.pos {
                    x = vec3::add(x, vec3::scale(p1[*g as usize], *wt));
                }
                for (g, wt) in &w.du {
                    du = vec3::add(du, vec3::scale(p1[*g as usize], *wt));
                }
                for (g, wt) in &w.dv {
                    dv = vec3::add(dv, vec3::scale(p1[*g as usize], *wt));
                }
                let a = vec3::norm(vec3::cross(du, dv));
                let e = vec3::norm(x) - 1.0;
                sum += a * e * e;
                area += a;
                max = max.max(e.abs());
            }
        }
    }
    let rms = (sum / area).sqrt();
    eprintln!("fit report {report:?}; limit-surface RMS {rms:.6}, max {max:.6}");
    assert!(rms <= 0.0007, "RMS {rms} > 0.0007");
}

/// Nets that are not closed pure-quad 2-manifolds are refused with `surface.bad-net` naming the element.
#[test]
fn bad_control_nets_are_refused_with_a_stable_code() {
    use scanstation::ErrorCode;
    // Open: one quad missing from the ball.
    let ball = shapes::quad_ball(1.0, 2);
    let faces: Vec<Vec<u32>> = ball.faces().skip(1).map(|f| f.to_vec()).collect();
    let open = scanstation::PolyMesh::new(ball.positions.clone(), &faces).unwrap();
    let e = control_net(&open).unwrap_err();
    assert_eq!(e.code, ErrorCode::SurfaceBadNet, "{e}");
    assert!(e.message.contains("open") || e.message.contains("no face"), "{e}");
    // A triangle.
    let tri = scanstation::PolyMesh::new(vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], &[vec![0, 1, 2]]).unwrap();
    let e = control_net(&tri).unwrap_err();
    assert_eq!(e.code, ErrorCode::SurfaceBadNet);
    assert!(e.message.contains("face 0 has 3 corners"), "{e}");
    // A flipped face: an edge used twice in the same direction.
    let mut faces: Vec<Vec<u32>> = ball.faces().map(|f| f.to_vec()).collect();
    faces[3].reverse();
    let flipped = scanstation::PolyMesh::new(ball.positions.clone(), &faces).unwrap();
    let e = control_net(&flipped).unwrap_err();
    assert_eq!(e.code, ErrorCode::SurfaceBadNet);
    assert!(e.message.contains("same direction"), "{e}");
}

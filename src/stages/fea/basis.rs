//! Tri-quadratic uniform B-splines (C¹) on the background grid, and the exact cell integrals of their
//! products from a cell's moments.
//!
//! On a cell with local coordinate t ∈ [0, 1] the three 1-D functions that do not vanish are
//! N₀ = (1 − t)²/2, N₁ = (1 + 2t − 2t²)/2, N₂ = t²/2; cell (i, j, k) carries the 27 functions with global
//! indices (i + a, j + b, k + c), a, b, c ∈ {0, 1, 2}, so there are n + 2 functions per axis.

use super::domain::Moments;

/// Monomial coefficients of N₀, N₁, N₂ (degree 2).
const N: [[f64; 3]; 3] = [[0.5, -1.0, 0.5], [0.5, 1.0, -1.0], [0.0, 0.0, 0.5]];
/// Monomial coefficients of dN/dt (degree 1, padded).
const DN: [[f64; 3]; 3] = [[-1.0, 1.0, 0.0], [1.0, -2.0, 0.0], [0.0, 1.0, 0.0]];

/// 1-D values and derivatives (d/dt) of the three functions at `t`.
#[inline]
pub fn values_1d(t: f64) -> ([f64; 3], [f64; 3]) {
    let s = 1.0 - t;
    ([0.5 * s * s, 0.5 + t - t * t, 0.5 * t * t], [-s, 1.0 - 2.0 * t, t])
}

/// The 27 local functions' values and physical gradients at local point `t` of a cell of side `h`.
/// Local function `a = (a₃·3 + a₂)·3 + a₁` (x fastest).
pub fn shape(t: [f64; 3], h: f64) -> ([f64; 27], [[f64; 3]; 27]) {
    let (vx, dx) = values_1d(t[0]);
    let (vy, dy) = values_1d(t[1]);
    let (vz, dz) = values_1d(t[2]);
    let mut n = [0.0; 27];
    let mut g = [[0.0; 3]; 27];
    let ih = 1.0 / h;
    for c in 0..3 {
        for b in 0..3 {
            for a in 0..3 {
                let i = (c * 3 + b) * 3 + a;
                n[i] = vx[a] * vy[b] * vz[c];
                g[i] = [dx[a] * vy[b] * vz[c] * ih, vx[a] * dy[b] * vz[c] * ih, vx[a] * vy[b] * dz[c] * ih];
            }
        }
    }
    (n, g)
}

/// Coefficients (degree ≤ 4) of the product of two polynomials of degree ≤ 2.
fn product(p: &[f64; 3], q: &[f64; 3]) -> [f64; 5] {
    let mut r = [0.0; 5];
    for i in 0..3 {
        for j in 0..3 {
            r[i + j] += p[i] * q[j];
        }
    }
    r
}

/// 1-D product tables: `table[da][db][a * 3 + b]` = coefficients of N_a^(da) · N_b^(db).
fn product_tables() -> [[[[f64; 5]; 9]; 2]; 2] {
    let mut t = [[[[0.0; 5]; 9]; 2]; 2];
    for da in 0..2 {
        for db in 0..2 {
            for a in 0..3 {
                for b in 0..3 {
                    let p = if da == 1 { &DN[a] } else { &N[a] };
                    let q = if db == 1 { &DN[b] } else { &N[b] };
                    t[da][db][a * 3 + b] = product(p, q);
                }
            }
        }
    }
    t
}

/// Gradient integrals of one cell: `g[i][j][pair]` = ∫ ∂ᵢN_a ∂ⱼN_b over the moments' region, in local
/// units (multiply by h for physical units), `pair = a * 27 + b`.
pub struct GradientIntegrals(pub Box<[[[f64; 729]; 3]; 3]>);

/// Sum-factorised ∫ ∂ᵢN_a ∂ⱼN_b dt³ for all 27 × 27 pairs and i, j ∈ 0..3. Cost: ≈ 9 · 7 000 flops.
pub fn gradient_integrals(m: &Moments) -> GradientIntegrals {
    let tables = product_tables();
    let mut out = Box::new([[[0.0; 729]; 3]; 3]);
    for i in 0..3 {
        for j in 0..3 {
            let tab = |k: usize| &tables[(k == i) as usize][(k == j) as usize];
            let (cx, cy, cz) = (tab(0), tab(1), tab(2));
            // t1[m1][m2][pz] = Σ_m3 M[m1][m2][m3] cz[pz][m3]
            let mut t1 = [[[0.0; 9]; 5]; 5];
            for m1 in 0..5 {
                for m2 in 0..5 {
                    for pz in 0..9 {
                        let mut acc = 0.0;
                        for m3 in 0..5 {
                            acc += m[(m1 * 5 + m2) * 5 + m3] * cz[pz][m3];
                        }
                        t1[m1][m2][pz] = acc;
                    }
                }
            }
            // t2[m1][py][pz] = Σ_m2 t1[m1][m2][pz] cy[py][m2]
            let mut t2 = [[[0.0; 9]; 9]; 5];
            for m1 in 0..5 {
                for py in 0..9 {
                    for pz in 0..9 {
                        let mut acc = 0.0;
                        for m2 in 0..5 {
                            acc += t1[m1][m2][pz] * cy[py][m2];
                        }
                        t2[m1][py][pz] = acc;
                    }
                }
            }
            let g = &mut out[i][j];
            for px in 0..9 {
                for py in 0..9 {
                    for pz in 0..9 {
                        let mut acc = 0.0;
                        for m1 in 0..5 {
                            acc += t2[m1][py][pz] * cx[px][m1];
                        }
                        // Pair (a, b) with a = (az·3 + ay)·3 + ax from px = ax·3 + bx etc.
                        let (ax, bx) = (px / 3, px % 3);
                        let (ay, by) = (py / 3, py % 3);
                        let (az, bz) = (pz / 3, pz % 3);
                        let a = (az * 3 + ay) * 3 + ax;
                        let b = (bz * 3 + by) * 3 + bx;
                        g[a * 27 + b] = acc;
                    }
                }
            }
        }
    }
    GradientIntegrals(out)
}

/// ∫ N_a dt³ over the moments' region for the 27 local functions (local units; multiply by h³).
pub fn value_integrals(m: &Moments) -> [f64; 27] {
    let mut out = [0.0; 27];
    for c in 0..3 {
        for b in 0..3 {
            for a in 0..3 {
                let mut acc = 0.0;
                for i in 0..3 {
                    for j in 0..3 {
                        for k in 0..3 {
                            acc += N[a][i] * N[b][j] * N[c][k] * m[(i * 5 + j) * 5 + k];
                        }
                    }
                }
                out[(c * 3 + b) * 3 + a] = acc;
            }
        }
    }
    out
}

/// The 81 × 81 element stiffness (local function a, component p → row 3a + p) of an isotropic material with
/// Lamé constants λ, μ over the region whose gradient integrals are `g`, for cell side `h`:
/// K_ab[p][q] = h · (λ G^{pq}_ab + μ G^{qp}_ab + μ δ_pq Σ_k G^{kk}_ab).
pub fn element_stiffness(g: &GradientIntegrals, lambda: f64, mu: f64, h: f64) -> Vec<f64> {
    let g = &g.0;
    let mut k = vec![0.0; 81 * 81];
    for a in 0..27 {
        for b in 0..27 {
            let pair = a * 27 + b;
            let lap = g[0][0][pair] + g[1][1][pair] + g[2][2][pair];
            for p in 0..3 {
                for q in 0..3 {
                    let mut v = lambda * g[p][q][pair] + mu * g[q][p][pair];
                    if p == q {
                        v += mu * lap;
                    }
                    k[(3 * a + p) * 81 + 3 * b + q] = v * h;
                }
            }
        }
    }
    k
}

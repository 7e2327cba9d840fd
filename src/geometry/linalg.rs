//! Small dense linear algebra for local least-squares fits (a few unknowns per patch or hole).

/// Solve `a x = b` by Gaussian elimination with partial pivoting; `None` when a pivot is below 10⁻³⁰⁰ or
/// not a number (singular). Cost: O(N³).
pub fn solve_dense<const N: usize>(mut a: [[f64; N]; N], mut b: [f64; N]) -> Option<[f64; N]> {
    for c in 0..N {
        let piv = (c..N).max_by(|&i, &j| a[i][c].abs().total_cmp(&a[j][c].abs()))?;
        if !(a[piv][c].abs() >= 1e-300) {
            return None;
        }
        a.swap(c, piv);
        b.swap(c, piv);
        for r in c + 1..N {
            let f = a[r][c] / a[c][c];
            for k in c..N {
                a[r][k] -= f * a[c][k];
            }
            b[r] -= f * b[c];
        }
    }
    let mut x = [0.0; N];
    for c in (0..N).rev() {
        let s: f64 = (c + 1..N).map(|k| a[c][k] * x[k]).sum();
        x[c] = (b[c] - s) / a[c][c];
    }
    Some(x)
}

/// Normal equations `AᵀW A x = AᵀW r` of a weighted least-squares problem with `N` unknowns, accumulated
/// row by row (rows are sparse: `(unknown, coefficient)` pairs).
#[derive(Clone, Debug)]
pub struct NormalEquations<const N: usize> {
    /// AᵀWA, accumulated.
    pub ata: [[f64; N]; N],
    /// AᵀWr, accumulated.
    pub atb: [f64; N],
}

impl<const N: usize> Default for NormalEquations<N> {
    fn default() -> Self {
        NormalEquations { ata: [[0.0; N]; N], atb: [0.0; N] }
    }
}

impl<const N: usize> NormalEquations<N> {
    /// Add the row `Σ coefficient · x[unknown] = rhs` with `weight`.
    pub fn add_row(&mut self, row: &[(usize, f64)], rhs: f64, weight: f64) {
        for &(i, a) in row {
            for &(j, c) in row {
                self.ata[i][j] += weight * a * c;
            }
            self.atb[i] += weight * a * rhs;
        }
    }

    /// The least-squares solution; `None` when the system is singular.
    pub fn solve(&self) -> Option<[f64; N]> {
        solve_dense(self.ata, self.atb)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solves_and_refuses_singular() {
        let x = solve_dense([[2.0, 1.0], [1.0, 3.0]], [3.0, 5.0]).unwrap();
        assert!((x[0] - 0.8).abs() < 1e-12 && (x[1] - 1.4).abs() < 1e-12, "{x:?}");
        assert!(solve_dense([[1.0, 2.0], [2.0, 4.0]], [1.0, 2.0]).is_none());
        let mut ne = NormalEquations::<1>::default();
        for (a, r) in [(1.0, 2.0), (2.0, 4.1)] {
            ne.add_row(&[(0, a)], r, 1.0);
        }
        assert!((ne.solve().unwrap()[0] - 10.2 / 5.0).abs() < 1e-12);
    }
}

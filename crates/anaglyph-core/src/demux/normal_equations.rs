//! The regularised normal equations of Eq. 6 for one measurement mask:
//! `H = C_mᵀ C_m + λ DᵀD`, `b = C_mᵀ p_m`, with D the (N−1)×N first-difference
//! operator and `C_m` the rows of C the mask keeps. λ is applied exactly as given.
//! Factored once per mask (faer Cholesky) and shared by every pixel with that mask:
//! the unconstrained solution is `ŝ = A p_m` with `A = H⁻¹ C_mᵀ`.

use crate::{Error, Result};
use faer::linalg::solvers::DenseSolveCore;
use faer::{Mat, Side};

/// Everything the solvers need for one mask.
#[derive(Debug, Clone)]
pub struct NormalEquations {
    /// Number of unknowns N.
    pub n: usize,
    /// Rows of C kept by the mask, in order.
    pub kept_rows: Vec<usize>,
    /// Kept rows of C, row-major `kept × n`.
    pub c: Vec<f64>,
    /// `H`, row-major `n × n`.
    pub h: Vec<f64>,
    /// `H⁻¹`, row-major `n × n`.
    pub h_inv: Vec<f64>,
    /// `Aᵀ = C_m H⁻¹`, row-major `kept × n`, so that `ŝᵀ = p_mᵀ Aᵀ` (batched product).
    pub a_t: Vec<f64>,
    /// `Aᵀ` rounded to f32, for measurements stored as f32.
    pub a_t32: Vec<f32>,
    pub lambda: f64,
}

/// `DᵀD` for the first-difference operator on `n` unknowns (tridiagonal 1, 2, …, 2, 1).
pub fn difference_gram(n: usize) -> Vec<f64> {
    let mut g = vec![0.0; n * n];
    for i in 0..n.saturating_sub(1) {
        g[i * n + i] += 1.0;
        g[(i + 1) * n + i + 1] += 1.0;
        g[i * n + i + 1] -= 1.0;
        g[(i + 1) * n + i] -= 1.0;
    }
    g
}

impl NormalEquations {
    /// Builds and factors the system for C (row-major `rows × n`) restricted to `kept_rows`.
    pub fn new(c_full: &[f64], n: usize, kept_rows: Vec<usize>, lambda: f64) -> Result<Self> {
        let m = kept_rows.len();
        let mut c = Vec::with_capacity(m * n);
        for &r in &kept_rows {
            c.extend_from_slice(&c_full[r * n..(r + 1) * n]);
        }
        let mut h = difference_gram(n);
        for v in &mut h {
            *v *= lambda;
        }
        for row in c.chunks_exact(n) {
            for i in 0..n {
                if row[i] == 0.0 {
                    continue;
                }
                for j in 0..n {
                    h[i * n + j] += row[i] * row[j];
                }
            }
        }
        let singular = || Error::SingularNormalMatrix {
            lambda,
            rows: m,
            cols: n,
        };
        let h_mat = Mat::from_fn(n, n, |i, j| h[i * n + j]);
        let llt = h_mat.llt(Side::Lower).map_err(|_| singular())?;
        // Cholesky succeeds on numerically semi-definite matrices too; check the pivots.
        let l = llt.L();
        let (mut dmin, mut dmax) = (f64::INFINITY, 0.0f64);
        for i in 0..n {
            let d = l[(i, i)];
            dmin = dmin.min(d);
            dmax = dmax.max(d);
        }
        if !(dmin > 0.0) || (dmin / dmax) < 1e-7 {
            return Err(singular());
        }
        let inv = llt.inverse();
        let h_inv: Vec<f64> = (0..n * n).map(|k| inv[(k / n, k % n)]).collect();
        let mut a_t = vec![0.0; m * n];
        for r in 0..m {
            for j in 0..n {
                a_t[r * n + j] = (0..n).map(|k| c[r * n + k] * h_inv[k * n + j]).sum();
            }
        }
        let a_t32 = a_t.iter().map(|&v| v as f32).collect();
        Ok(NormalEquations {
            n,
            kept_rows,
            c,
            h,
            h_inv,
            a_t,
            a_t32,
            lambda,
        })
    }

    /// `b = C_mᵀ p_m` for the kept measurements `p`.
    pub fn rhs(&self, p: &[f64], b: &mut [f64]) {
        b.fill(0.0);
        for (row, &pv) in self.c.chunks_exact(self.n).zip(p) {
            for (bi, ci) in b.iter_mut().zip(row) {
                *bi += ci * pv;
            }
        }
    }

    /// The Eq. 6 objective `‖C_m s − p‖² + λ‖Ds‖²`.
    pub fn objective(&self, s: &[f64], p: &[f64]) -> f64 {
        let data: f64 = self
            .c
            .chunks_exact(self.n)
            .zip(p)
            .map(|(row, pv)| {
                let r = row.iter().zip(s).map(|(c, s)| c * s).sum::<f64>() - pv;
                r * r
            })
            .sum();
        let smooth: f64 = s.windows(2).map(|w| (w[1] - w[0]) * (w[1] - w[0])).sum();
        data + self.lambda * smooth
    }

    /// Largest eigenvalue of H (Lipschitz constant of the half-gradient), by power iteration.
    pub fn largest_eigenvalue(&self) -> f64 {
        let n = self.n;
        // A start with components along every eigenvector (a constant vector may be one).
        let mut v: Vec<f64> = (0..n).map(|i| 1.0 + i as f64 / n as f64).collect();
        let mut w = vec![0.0; n];
        let mut estimate = 0.0;
        for _ in 0..200 {
            for i in 0..n {
                w[i] = (0..n).map(|j| self.h[i * n + j] * v[j]).sum();
            }
            let norm = w.iter().map(|x| x * x).sum::<f64>().sqrt();
            if norm == 0.0 {
                return 0.0;
            }
            let next: f64 = w.iter().zip(&v).map(|(a, b)| a * b).sum();
            v.iter_mut().zip(&w).for_each(|(v, w)| *v = w / norm);
            if (next - estimate).abs() <= 1e-12 * next.abs() {
                return next;
            }
            estimate = next;
        }
        estimate
    }
}

/// In-place Cholesky solve of the SPD system `a x = b` (`a` row-major `n × n`, overwritten);
/// returns false if `a` is not positive definite. Hand-written because it runs per pixel
/// on tiny systems (n ≤ 128) inside the active-set loop, where it must not allocate.
pub fn cholesky_solve_small(a: &mut [f64], n: usize, b: &mut [f64]) -> bool {
    for j in 0..n {
        let mut d = a[j * n + j];
        for k in 0..j {
            d -= a[j * n + k] * a[j * n + k];
        }
        if !(d > 0.0) {
            return false;
        }
        let d = d.sqrt();
        a[j * n + j] = d;
        for i in j + 1..n {
            let mut v = a[i * n + j];
            for k in 0..j {
                v -= a[i * n + k] * a[j * n + k];
            }
            a[i * n + j] = v / d;
        }
    }
    for i in 0..n {
        let mut v = b[i];
        for k in 0..i {
            v -= a[i * n + k] * b[k];
        }
        b[i] = v / a[i * n + i];
    }
    for i in (0..n).rev() {
        let mut v = b[i];
        for k in i + 1..n {
            v -= a[k * n + i] * b[k];
        }
        b[i] = v / a[i * n + i];
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identity_sensing_has_the_closed_form_inverse() {
        // C = I (2×2), λ = 0.5: H = [[1.5, −0.5], [−0.5, 1.5]], H⁻¹ = [[0.75, 0.25], [0.25, 0.75]].
        let eq = NormalEquations::new(&[1.0, 0.0, 0.0, 1.0], 2, vec![0, 1], 0.5).unwrap();
        for (got, want) in eq.h_inv.iter().zip([0.75, 0.25, 0.25, 0.75]) {
            assert!((got - want).abs() < 1e-14);
        }
        assert!((eq.largest_eigenvalue() - 2.0).abs() < 1e-9);
        let mut a = eq.h.clone();
        let mut b = vec![1.0, 3.0];
        assert!(cholesky_solve_small(&mut a, 2, &mut b));
        assert!((b[0] - 1.5).abs() < 1e-14 && (b[1] - 2.5).abs() < 1e-14);
    }

    #[test]
    fn singular_system_is_reported() {
        // One measurement of two unknowns and no smoothness: rank 1.
        let err = NormalEquations::new(&[1.0, 1.0], 2, vec![0], 0.0).unwrap_err();
        assert!(matches!(err, Error::SingularNormalMatrix { .. }));
        // With λ > 0 the same C is solvable.
        NormalEquations::new(&[1.0, 1.0], 2, vec![0], 0.01).unwrap();
    }
}

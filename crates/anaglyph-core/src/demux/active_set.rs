//! Exact non-negative solution of Eq. 6 by block principal pivoting (Júdice & Pires
//! 1994; Kim & Park 2011): the KKT conditions `Hs − b = y`, `s ≥ 0`, `y ≥ 0`, `sᵢyᵢ = 0`
//! are met by guessing the free set F (bound set G = not F), solving the equality
//! subproblem `s_G = 0, y_F = 0`, and exchanging every infeasible index at once, with
//! Kim & Park's backup rule (after three non-improving full exchanges, exchange only the
//! largest infeasible index) to guarantee termination. Warm-started from the sign pattern
//! of the unconstrained solution, it usually ends in one or two exchanges.
//!
//! The subproblem solver is pluggable: the fast path uses a Schur complement on the
//! precomputed `H⁻¹` (cheap when few indices are bound), the reference a dense Cholesky of
//! `H_FF`, and the paper's iterative methods (CG, LSQR) solve it iteratively.

use super::normal_equations::{cholesky_solve_small, NormalEquations};
use crate::{Error, Result};

/// Non-improving full exchanges allowed before the single-index backup rule (Kim & Park).
const FULL_EXCHANGE_BACKUPS: usize = 3;

/// Per-thread buffers, sized once for `n` unknowns.
#[derive(Debug, Clone)]
pub struct Scratch {
    pub free: Vec<bool>,
    pub s: Vec<f64>,
    pub y: Vec<f64>,
    pub b: Vec<f64>,
    pub dense: DenseWork,
    pub work: [Vec<f64>; 4],
}

/// Buffers of the small dense subproblems: an index set, a matrix and a right-hand side.
#[derive(Debug, Clone)]
pub struct DenseWork {
    pub index: Vec<usize>,
    pub matrix: Vec<f64>,
    pub vector: Vec<f64>,
}

impl Scratch {
    pub fn new(n: usize, rows: usize) -> Self {
        let big = n.max(rows);
        Scratch {
            free: vec![true; n],
            s: vec![0.0; n],
            y: vec![0.0; n],
            b: vec![0.0; n],
            dense: DenseWork {
                index: Vec::with_capacity(n),
                matrix: vec![0.0; n * n],
                vector: vec![0.0; n],
            },
            work: [
                vec![0.0; big],
                vec![0.0; big],
                vec![0.0; big],
                vec![0.0; big],
            ],
        }
    }
}

/// Runs block principal pivoting from the free set in `free`; `subproblem(free, s, y)` must
/// set `s` (zero on G) and `y` (zero on F, `(Hs − b)_G` on G). Returns the iterations used.
pub fn block_principal_pivoting(
    free: &mut [bool],
    s: &mut [f64],
    y: &mut [f64],
    tolerance_s: f64,
    tolerance_y: f64,
    mut subproblem: impl FnMut(&[bool], &mut [f64], &mut [f64]) -> Result<()>,
) -> Result<usize> {
    let n = free.len();
    let max_iterations = 50 * n + 100;
    let mut best_infeasible = n + 1;
    let mut backups = FULL_EXCHANGE_BACKUPS;
    for iteration in 1..=max_iterations {
        subproblem(free, s, y)?;
        let infeasible = |i: usize, free: &[bool], s: &[f64], y: &[f64]| {
            if free[i] {
                s[i] < -tolerance_s
            } else {
                y[i] < -tolerance_y
            }
        };
        let count = (0..n).filter(|&i| infeasible(i, free, s, y)).count();
        if count == 0 {
            for (si, &f) in s.iter_mut().zip(free.iter()) {
                *si = if f { si.max(0.0) } else { 0.0 };
            }
            return Ok(iteration);
        }
        if count < best_infeasible {
            best_infeasible = count;
            backups = FULL_EXCHANGE_BACKUPS;
        } else if backups > 0 {
            backups -= 1;
        } else {
            let last = (0..n)
                .rev()
                .find(|&i| infeasible(i, free, s, y))
                .unwrap_or(0);
            free[last] = !free[last];
            continue;
        }
        for i in 0..n {
            if infeasible(i, free, s, y) {
                free[i] = !free[i];
            }
        }
    }
    Err(Error::NoConvergence {
        op: "block principal pivoting".into(),
        iterations: max_iterations,
    })
}

/// Fast subproblem: with `ŝ = H⁻¹b` known, `s = ŝ + H⁻¹[:,G] y_G` where
/// `H⁻¹[G,G] y_G = −ŝ_G`; when more than half the indices are bound, solves `H_FF s_F = b_F`
/// instead. `b` must hold `H ŝ`.
pub fn subproblem_schur(
    eq: &NormalEquations,
    s_hat: &[f64],
    b: &[f64],
    free: &[bool],
    s: &mut [f64],
    y: &mut [f64],
    work: &mut DenseWork,
) -> Result<()> {
    let n = eq.n;
    let bound = free.iter().filter(|f| !**f).count();
    if bound * 2 > n {
        return subproblem_dense(eq, b, free, s, y, work);
    }
    let DenseWork {
        index,
        matrix,
        vector,
    } = work;
    index.clear();
    index.extend((0..n).filter(|&i| !free[i]));
    let g = index.len();
    for (a, &i) in index.iter().enumerate() {
        for (c, &j) in index.iter().enumerate() {
            matrix[a * g + c] = eq.h_inv[i * n + j];
        }
        vector[a] = -s_hat[i];
    }
    if g > 0 && !cholesky_solve_small(&mut matrix[..g * g], g, &mut vector[..g]) {
        return subproblem_dense(eq, b, free, s, y, work);
    }
    s.copy_from_slice(s_hat);
    y.fill(0.0);
    for (a, &j) in index.iter().enumerate() {
        let yj = vector[a];
        y[j] = yj;
        for i in 0..n {
            s[i] += eq.h_inv[i * n + j] * yj;
        }
    }
    for &j in index.iter() {
        s[j] = 0.0;
    }
    Ok(())
}

/// Reference subproblem: dense Cholesky of `H_FF`, then `y_G = (H s − b)_G`.
pub fn subproblem_dense(
    eq: &NormalEquations,
    b: &[f64],
    free: &[bool],
    s: &mut [f64],
    y: &mut [f64],
    work: &mut DenseWork,
) -> Result<()> {
    let n = eq.n;
    let DenseWork {
        index,
        matrix,
        vector,
    } = work;
    index.clear();
    index.extend((0..n).filter(|&i| free[i]));
    let f = index.len();
    for (a, &i) in index.iter().enumerate() {
        for (c, &j) in index.iter().enumerate() {
            matrix[a * f + c] = eq.h[i * n + j];
        }
        vector[a] = b[i];
    }
    if f > 0 && !cholesky_solve_small(&mut matrix[..f * f], f, &mut vector[..f]) {
        return Err(Error::SingularNormalMatrix {
            lambda: eq.lambda,
            rows: eq.kept_rows.len(),
            cols: n,
        });
    }
    s.fill(0.0);
    for (a, &i) in index.iter().enumerate() {
        s[i] = vector[a];
    }
    bound_multipliers(eq, b, free, s, y);
    Ok(())
}

/// `y_G = (H s − b)_G`, `y_F = 0`.
pub fn bound_multipliers(eq: &NormalEquations, b: &[f64], free: &[bool], s: &[f64], y: &mut [f64]) {
    let n = eq.n;
    for i in 0..n {
        y[i] = if free[i] {
            0.0
        } else {
            eq.h[i * n..(i + 1) * n]
                .iter()
                .zip(s)
                .map(|(h, s)| h * s)
                .sum::<f64>()
                - b[i]
        };
    }
}

/// Tolerances scaled to the problem: `(for s, for y)`.
pub fn tolerances(eq: &NormalEquations, s_hat: &[f64], b: &[f64], relative: f64) -> (f64, f64) {
    let s_scale = s_hat.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let b_scale = b.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let h_scale = (0..eq.n).fold(0.0f64, |m, i| m.max(eq.h[i * eq.n + i]));
    (
        relative * (1.0 + s_scale),
        relative * (b_scale + h_scale * (1.0 + s_scale)),
    )
}

//! The paper's two Krylov methods as subproblem solvers of the active-set loop: conjugate
//! gradient on the free block of the normal equations `H_FF s_F = b_F`, and LSQR (Paige &
//! Saunders 1982) on the equivalent stacked least-squares problem
//! `min ‖[C_F; √λ D_F] s_F − [p; 0]‖` (never forming H). Inside block principal pivoting
//! both reach the same constrained minimiser as the exact path, to their tolerance.

use super::active_set::bound_multipliers;
use super::normal_equations::NormalEquations;
use crate::{Error, Result};

/// CG on `H_FF x = b_F`, warm-started from `s_F`; `y` gets the bound multipliers.
#[allow(clippy::too_many_arguments)]
pub fn subproblem_conjugate_gradient(
    eq: &NormalEquations,
    b: &[f64],
    free: &[bool],
    s: &mut [f64],
    y: &mut [f64],
    tolerance: f64,
    max_iterations: usize,
    work: &mut [Vec<f64>; 4],
    iterations: &mut usize,
) -> Result<()> {
    let n = eq.n;
    let [r, d, hd, _] = work;
    let h_times = |v: &[f64], out: &mut [f64]| {
        for i in 0..n {
            out[i] = if free[i] {
                (0..n)
                    .filter(|&j| free[j])
                    .map(|j| eq.h[i * n + j] * v[j])
                    .sum()
            } else {
                0.0
            };
        }
    };
    for i in 0..n {
        if !free[i] {
            s[i] = 0.0;
        }
    }
    h_times(s, &mut hd[..n]);
    let mut b_norm = 0.0f64;
    for i in 0..n {
        r[i] = if free[i] { b[i] - hd[i] } else { 0.0 };
        d[i] = r[i];
        if free[i] {
            b_norm += b[i] * b[i];
        }
    }
    let b_norm = b_norm.sqrt().max(f64::MIN_POSITIVE);
    let mut rr: f64 = r[..n].iter().map(|v| v * v).sum();
    let mut k = 0;
    while rr.sqrt() > tolerance * b_norm {
        if k == max_iterations {
            return Err(Error::NoConvergence {
                op: "conjugate gradient".into(),
                iterations: k,
            });
        }
        h_times(&d[..n], &mut hd[..n]);
        let dhd: f64 = d[..n].iter().zip(&hd[..n]).map(|(a, b)| a * b).sum();
        if dhd <= 0.0 {
            break;
        }
        let alpha = rr / dhd;
        for i in 0..n {
            s[i] += alpha * d[i];
            r[i] -= alpha * hd[i];
        }
        let rr_next: f64 = r[..n].iter().map(|v| v * v).sum();
        let beta = rr_next / rr;
        for i in 0..n {
            d[i] = r[i] + beta * d[i];
        }
        rr = rr_next;
        k += 1;
    }
    *iterations += k;
    bound_multipliers(eq, b, free, s, y);
    Ok(())
}

/// LSQR on `[C_F; √λ D_F] x ≈ [p; 0]` (x on F, zero on G); `y` gets the bound multipliers.
#[allow(clippy::too_many_arguments)]
pub fn subproblem_lsqr(
    eq: &NormalEquations,
    p: &[f64],
    b: &[f64],
    free: &[bool],
    s: &mut [f64],
    y: &mut [f64],
    tolerance: f64,
    max_iterations: usize,
    iterations: &mut usize,
) -> Result<()> {
    let n = eq.n;
    let m = eq.kept_rows.len();
    let rows = m + n.saturating_sub(1);
    let root_lambda = eq.lambda.sqrt();
    // A x: first m entries C_F x, then √λ (x[i+1] − x[i]).
    let apply = |x: &[f64], out: &mut Vec<f64>| {
        out.clear();
        for row in eq.c.chunks_exact(n) {
            out.push((0..n).filter(|&j| free[j]).map(|j| row[j] * x[j]).sum());
        }
        for i in 0..n.saturating_sub(1) {
            let a = if free[i] { x[i] } else { 0.0 };
            let c = if free[i + 1] { x[i + 1] } else { 0.0 };
            out.push(root_lambda * (c - a));
        }
    };
    let apply_t = |u: &[f64], out: &mut [f64]| {
        out.fill(0.0);
        for (row, &ur) in eq.c.chunks_exact(n).zip(&u[..m]) {
            for j in 0..n {
                out[j] += row[j] * ur;
            }
        }
        for i in 0..n.saturating_sub(1) {
            let v = root_lambda * u[m + i];
            out[i + 1] += v;
            out[i] -= v;
        }
        for j in 0..n {
            if !free[j] {
                out[j] = 0.0;
            }
        }
    };
    let norm = |v: &[f64]| v.iter().map(|x| x * x).sum::<f64>().sqrt();
    // Right-hand side [p; 0]; LSQR from x = 0 (Paige & Saunders, Algorithm LSQR).
    let mut u: Vec<f64> = p
        .iter()
        .copied()
        .chain(std::iter::repeat_n(0.0, rows - m))
        .collect();
    let mut beta = norm(&u);
    let mut x = vec![0.0; n];
    if beta == 0.0 {
        s.fill(0.0);
        bound_multipliers(eq, b, free, s, y);
        return Ok(());
    }
    u.iter_mut().for_each(|v| *v /= beta);
    let mut v = vec![0.0; n];
    apply_t(&u, &mut v);
    let mut alpha = norm(&v);
    if alpha > 0.0 {
        v.iter_mut().for_each(|e| *e /= alpha);
    }
    let mut w = v.clone();
    let (mut phi_bar, mut rho_bar) = (beta, alpha);
    let mut au = Vec::with_capacity(rows);
    let mut atv = vec![0.0; n];
    let mut k = 0;
    let mut a_norm_sq = alpha * alpha;
    while alpha > 0.0 && k < max_iterations {
        apply(&v, &mut au);
        for (ui, ai) in u.iter_mut().zip(&au) {
            *ui = ai - alpha * *ui;
        }
        beta = norm(&u);
        if beta > 0.0 {
            u.iter_mut().for_each(|e| *e /= beta);
        }
        apply_t(&u, &mut atv);
        for (vi, ai) in v.iter_mut().zip(&atv) {
            *vi = ai - beta * *vi;
        }
        alpha = norm(&v);
        if alpha > 0.0 {
            v.iter_mut().for_each(|e| *e /= alpha);
        }
        a_norm_sq += alpha * alpha + beta * beta;
        let rho = (rho_bar * rho_bar + beta * beta).sqrt();
        let c = rho_bar / rho;
        let sn = beta / rho;
        let theta = sn * alpha;
        rho_bar = -c * alpha;
        let phi = c * phi_bar;
        phi_bar *= sn;
        for j in 0..n {
            x[j] += (phi / rho) * w[j];
            w[j] = v[j] - (theta / rho) * w[j];
        }
        k += 1;
        // Paige & Saunders' test 2: ‖Aᵀr‖ / (‖A‖ ‖r‖) ≤ tolerance, with ‖Aᵀr‖ = φ̄ α |c|.
        let residual = phi_bar;
        if residual == 0.0 || phi_bar * alpha * c.abs() <= tolerance * a_norm_sq.sqrt() * residual {
            break;
        }
    }
    if k == max_iterations && alpha > 0.0 {
        return Err(Error::NoConvergence {
            op: "LSQR".into(),
            iterations: k,
        });
    }
    *iterations += k;
    for j in 0..n {
        s[j] = if free[j] { x[j] } else { 0.0 };
    }
    bound_multipliers(eq, b, free, s, y);
    Ok(())
}

//! Projected gradient descent on Eq. 6, the paper's first method: a gradient step
//! on `½sᵀHs − bᵀs` with step `1/L` (L the largest eigenvalue of H), then projection onto
//! `s ≥ 0`. Plain projected gradient needs of the order of cond(H) iterations, so we use
//! its accelerated form (FISTA, Beck & Teboulle 2009) with gradient-based restart
//! (O'Donoghue & Candès 2015); it converges to the same minimiser, only faster.

use super::normal_equations::NormalEquations;

/// Minimises from `s = 0`; stops when the projected-gradient step moves `s` by less than
/// `tolerance · (1 + ‖s‖∞)`. Returns the iterations used.
pub fn projected_gradient(
    eq: &NormalEquations,
    b: &[f64],
    lipschitz: f64,
    tolerance: f64,
    max_iterations: usize,
    s: &mut [f64],
    work: &mut [Vec<f64>; 4],
) -> usize {
    let n = eq.n;
    let [momentum, gradient, next, _] = work;
    s.fill(0.0);
    momentum[..n].fill(0.0);
    let step = 1.0 / lipschitz;
    let mut t = 1.0f64;
    for iteration in 1..=max_iterations {
        for i in 0..n {
            gradient[i] = eq.h[i * n..(i + 1) * n]
                .iter()
                .zip(&momentum[..n])
                .map(|(h, v)| h * v)
                .sum::<f64>()
                - b[i];
        }
        let mut moved = 0.0f64;
        let mut size = 0.0f64;
        let mut restart = 0.0;
        for i in 0..n {
            next[i] = (momentum[i] - step * gradient[i]).max(0.0);
            moved = moved.max((next[i] - s[i]).abs());
            size = size.max(next[i].abs());
            restart += gradient[i] * (next[i] - s[i]);
        }
        let t_next = 0.5 * (1.0 + (1.0 + 4.0 * t * t).sqrt());
        let beta = if restart > 0.0 {
            0.0
        } else {
            (t - 1.0) / t_next
        };
        t = if restart > 0.0 { 1.0 } else { t_next };
        for i in 0..n {
            momentum[i] = next[i] + beta * (next[i] - s[i]);
            s[i] = next[i];
        }
        if moved <= tolerance * (1.0 + size) * step.min(1.0) {
            return iteration;
        }
    }
    max_iterations
}

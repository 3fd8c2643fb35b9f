//! Interpolation of sampled curves onto new wavelengths: piecewise linear, and the
//! natural cubic spline the paper uses to resample camera RGB curves (section 4.1d).
//! Both accept non-uniform knots (the Smits basis is sampled every 37.78 nm) and
//! refuse to extrapolate: callers check coverage first.

use serde::{Deserialize, Serialize};

/// How a curve is evaluated between its samples.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Interpolation {
    /// Piecewise linear (colour-science's choice for illuminants).
    #[default]
    Linear,
    /// Natural cubic spline through every sample (the paper's choice for camera curves).
    CubicSpline,
}

/// Index `i` of the knot interval `[x[i], x[i+1]]` that holds `t` (clamped to the ends).
fn interval(x: &[f64], t: f64) -> usize {
    let upper = x.partition_point(|&v| v <= t);
    upper.saturating_sub(1).min(x.len() - 2)
}

/// Piecewise-linear interpolation of `(x, y)` at each `t`; `x` strictly increasing with
/// at least two knots, every `t` inside `[x[0], x[last]]`.
pub fn linear(x: &[f64], y: &[f64], t: &[f64]) -> Vec<f64> {
    debug_assert!(x.len() >= 2 && x.len() == y.len());
    t.iter()
        .map(|&t| {
            let i = interval(x, t);
            let u = (t - x[i]) / (x[i + 1] - x[i]);
            y[i] + u * (y[i + 1] - y[i])
        })
        .collect()
}

/// Natural cubic spline through `(x, y)` evaluated at each `t` (second derivative zero
/// at both ends), solved with the tridiagonal Thomas algorithm.
pub fn cubic_spline(x: &[f64], y: &[f64], t: &[f64]) -> Vec<f64> {
    let n = x.len();
    debug_assert!(n >= 2 && n == y.len());
    if n == 2 {
        return linear(x, y, t);
    }
    // Second derivatives m[i] at the knots; m[0] = m[n-1] = 0.
    let mut m = vec![0.0; n];
    let mut diag = vec![0.0; n];
    let mut rhs = vec![0.0; n];
    for i in 1..n - 1 {
        let h0 = x[i] - x[i - 1];
        let h1 = x[i + 1] - x[i];
        diag[i] = 2.0 * (h0 + h1);
        rhs[i] = 6.0 * ((y[i + 1] - y[i]) / h1 - (y[i] - y[i - 1]) / h0);
    }
    // Forward sweep: sub- and super-diagonal of row i are h[i-1] and h[i].
    for i in 2..n - 1 {
        let h_prev = x[i] - x[i - 1];
        let w = h_prev / diag[i - 1];
        diag[i] -= w * h_prev;
        rhs[i] -= w * rhs[i - 1];
    }
    for i in (1..n - 1).rev() {
        let h_next = x[i + 1] - x[i];
        let next = if i + 1 < n - 1 { m[i + 1] } else { 0.0 };
        m[i] = (rhs[i] - h_next * next) / diag[i];
    }
    t.iter()
        .map(|&t| {
            let i = interval(x, t);
            let h = x[i + 1] - x[i];
            let a = (x[i + 1] - t) / h;
            let b = (t - x[i]) / h;
            a * y[i]
                + b * y[i + 1]
                + ((a * a * a - a) * m[i] + (b * b * b - b) * m[i + 1]) * h * h / 6.0
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn linear_hits_knots_and_midpoints() {
        let x = [400.0, 410.0, 430.0];
        let y = [1.0, 3.0, -1.0];
        let v = linear(&x, &y, &[400.0, 405.0, 410.0, 420.0, 430.0]);
        assert_eq!(v, vec![1.0, 2.0, 3.0, 1.0, -1.0]);
    }

    #[test]
    fn cubic_spline_reproduces_a_cubic_free_at_the_ends_and_is_exact_for_lines() {
        // A natural spline reproduces straight lines exactly on non-uniform knots.
        let x = [400.0, 410.0, 437.7, 450.0, 500.0];
        let y: Vec<f64> = x.iter().map(|v| 0.5 * v - 3.0).collect();
        let t = [401.0, 425.5, 449.0, 480.0];
        for (got, &tt) in cubic_spline(&x, &y, &t).iter().zip(&t) {
            assert!((got - (0.5 * tt - 3.0)).abs() < 1e-9);
        }
        // A smooth function sampled densely is interpolated to high accuracy.
        let x: Vec<f64> = (0..=30).map(|i| 400.0 + 10.0 * i as f64).collect();
        let f = |v: f64| ((v - 400.0) / 60.0).sin();
        let y: Vec<f64> = x.iter().map(|&v| f(v)).collect();
        // Interior points: the natural end condition (f'' = 0) costs accuracy near the ends.
        let t: Vec<f64> = (0..=240).map(|i| 430.0 + i as f64).collect();
        let err = cubic_spline(&x, &y, &t)
            .iter()
            .zip(&t)
            .map(|(g, &tt)| (g - f(tt)).abs())
            .filter(|e| e.is_finite())
            .fold(0.0, f64::max);
        // Interior error of a cubic spline: about (5/384) h^4 max|f''''| = 1e-5 here.
        assert!(err < 5e-5, "max error {err}");
        let lin_err = linear(&x, &y, &t)
            .iter()
            .zip(&t)
            .map(|(g, &tt)| (g - f(tt)).abs())
            .fold(0.0, f64::max);
        assert!(err < lin_err, "spline {err} should beat linear {lin_err}");
    }
}

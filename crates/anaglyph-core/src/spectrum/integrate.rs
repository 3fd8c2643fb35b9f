//! Integration over wavelength: trapezoid weights on a uniform grid (how the sensing
//! matrix and the forward model integrate Eq. 1) and the exact integral of a
//! piecewise-linear curve over a band.

use super::SpectralShape;

/// Trapezoid-rule weights (in nm) for a uniform grid: `∫ f ≈ Σ w_i f(λ_i)`.
pub fn trapezoid_weights(shape: &SpectralShape) -> Vec<f64> {
    let mut w = vec![shape.step; shape.count];
    if shape.count == 1 {
        return vec![0.0];
    }
    w[0] *= 0.5;
    w[shape.count - 1] *= 0.5;
    w
}

/// Exact integral over `[lo, hi]` of the piecewise-linear interpolant of `(x, y)`;
/// the band must lie inside `[x[0], x[last]]` (checked by the caller).
pub fn integrate_linear(x: &[f64], y: &[f64], lo: f64, hi: f64) -> f64 {
    debug_assert!(x.len() >= 2 && x.len() == y.len() && lo <= hi);
    let value_at = |t: f64| super::linear(x, y, &[t])[0];
    let mut total = 0.0;
    let mut a = lo;
    let mut fa = value_at(lo);
    for (&xi, &yi) in x.iter().zip(y) {
        if xi <= lo {
            continue;
        }
        if xi >= hi {
            break;
        }
        total += 0.5 * (fa + yi) * (xi - a);
        a = xi;
        fa = yi;
    }
    total + 0.5 * (fa + value_at(hi)) * (hi - a)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trapezoid_integrates_a_line_exactly() {
        let shape = SpectralShape::from_range(400.0, 700.0, 1.0).unwrap();
        let w = trapezoid_weights(&shape);
        let integral: f64 = shape
            .wavelengths()
            .iter()
            .zip(&w)
            .map(|(l, w)| w * (2.0 * l + 1.0))
            .sum();
        // ∫_400^700 (2λ + 1) dλ = 700² − 400² + 300
        assert!((integral - (490_000.0 - 160_000.0 + 300.0)).abs() < 1e-6);
    }

    #[test]
    fn band_integral_of_a_hat_is_its_area() {
        let x = [400.0, 410.0, 420.0, 430.0];
        let y = [0.0, 1.0, 0.0, 0.0];
        assert!((integrate_linear(&x, &y, 400.0, 430.0) - 10.0).abs() < 1e-12);
        assert!((integrate_linear(&x, &y, 405.0, 410.0) - 3.75).abs() < 1e-12);
        assert!((integrate_linear(&x, &y, 402.0, 403.0) - 0.25).abs() < 1e-12);
    }
}

//! Image interpolation kernels shared by rectification and warping.

/// Catmull–Rom (Keys, a = −½) weights of the taps at −1, 0, 1, 2 for fractional position
/// `t` in [0, 1): they sum to one, and reproduce linear ramps exactly.
#[inline]
pub fn catmull_rom_weights(t: f64) -> [f64; 4] {
    let (t2, t3) = (t * t, t * t * t);
    [
        0.5 * (-t + 2.0 * t2 - t3),
        0.5 * (2.0 - 5.0 * t2 + 3.0 * t3),
        0.5 * (t + 4.0 * t2 - 3.0 * t3),
        0.5 * (-t2 + t3),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weights_sum_to_one_interpolate_and_keep_ramps() {
        for t in [0.0, 0.25, 0.5, 0.9] {
            let w = catmull_rom_weights(t);
            assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-12);
            // A ramp v(i) = 3 + 2i sampled at −1..2 returns 3 + 2t.
            let ramp: f64 = (0..4).map(|i| w[i] * (3.0 + 2.0 * (i as f64 - 1.0))).sum();
            assert!((ramp - (3.0 + 2.0 * t)).abs() < 1e-12);
        }
        assert_eq!(catmull_rom_weights(0.0), [0.0, 1.0, 0.0, 0.0]);
    }
}

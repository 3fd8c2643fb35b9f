//! Removing the illumination (paper section 4.3: "remove the illumination interference
//! first, which can be obtained through capturing a standard white board"). Two ways:
//! - with the illuminant folded into C, a raw capture `P` is put into C's units with the
//!   white-board capture `W` of the same camera: `P' = P / W · (C w)`, which also cancels
//!   each camera's unknown exposure and gain; the solve then yields reflectance;
//! - with C for radiance (no illuminant), the reconstructed radiance is divided by the
//!   reconstructed white board, band by band.

/// `p[px][r] ← p[px][r] / white[px][r] · white_response[r]`; `white` holds one row per pixel
/// or a single row for all. A dark or non-finite white reading makes the value NaN
/// (missing), never a huge number.
pub fn normalise_by_white(p: &mut [f64], rows: usize, white: &[f64], white_response: &[f64]) {
    let per_pixel = white.len() == p.len();
    for (px, values) in p.chunks_exact_mut(rows).enumerate() {
        let w = if per_pixel {
            &white[px * rows..(px + 1) * rows]
        } else {
            &white[..rows]
        };
        for ((v, &wv), &cw) in values.iter_mut().zip(w).zip(white_response) {
            *v = if wv.is_finite() && wv > 0.0 {
                *v / wv * cw
            } else {
                f64::NAN
            };
        }
    }
}

/// `cube[px][b] ← cube[px][b] / white[b] · white_reflectance`, NaN where the white is zero.
pub fn divide_by_white_spectrum(cube: &mut [f64], white: &[f64], white_reflectance: f64) {
    let n = white.len();
    for values in cube.chunks_exact_mut(n) {
        for (v, &w) in values.iter_mut().zip(white) {
            *v = if w > 0.0 {
                *v / w * white_reflectance
            } else {
                f64::NAN
            };
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn white_normalisation_cancels_gain() {
        // Camera gain 3 on both the scene and the white: P' = C s exactly.
        let response = [0.8, 0.5];
        let mut p = vec![3.0 * 0.4, 3.0 * 0.1, 3.0 * 0.8, 3.0 * 0.5];
        let white = [3.0 * 0.8, 3.0 * 0.5];
        normalise_by_white(&mut p, 2, &white, &response);
        for (a, b) in p.iter().zip([0.4, 0.1, 0.8, 0.5]) {
            assert!((a - b).abs() < 1e-15);
        }
        let mut q = vec![1.0, 1.0];
        normalise_by_white(&mut q, 2, &[0.0, f64::NAN], &response);
        assert!(q.iter().all(|v| v.is_nan()));
        let mut cube = vec![0.2, 0.4];
        divide_by_white_spectrum(&mut cube, &[0.4, 0.8], 0.9);
        assert!((cube[0] - 0.45).abs() < 1e-15 && (cube[1] - 0.45).abs() < 1e-15);
    }
}

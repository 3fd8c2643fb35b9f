//! Structural similarity (Wang, Bovik, Sheikh & Simoncelli 2004) with the paper's
//! settings: 11×11 Gaussian window, σ = 1.5, K1 = 0.01, K2 = 0.03, dynamic range L.
//! The mean is taken over window positions fully inside the image (scikit-image's
//! `gaussian_weights=True, use_sample_covariance=False` crops the same border).

/// Window side.
pub const SSIM_WINDOW: usize = 11;
/// Gaussian σ of the window.
pub const SSIM_SIGMA: f64 = 1.5;
pub const SSIM_K1: f64 = 0.01;
pub const SSIM_K2: f64 = 0.03;

fn gaussian_kernel() -> [f64; SSIM_WINDOW] {
    let mut k = [0.0; SSIM_WINDOW];
    let r = (SSIM_WINDOW / 2) as f64;
    for (i, v) in k.iter_mut().enumerate() {
        let x = i as f64 - r;
        *v = (-x * x / (2.0 * SSIM_SIGMA * SSIM_SIGMA)).exp();
    }
    let sum: f64 = k.iter().sum();
    k.iter_mut().for_each(|v| *v /= sum);
    k
}

/// Separable "valid" Gaussian filtering of a `width × height` plane.
fn filter_valid(plane: &[f64], width: usize, height: usize, k: &[f64; SSIM_WINDOW]) -> Vec<f64> {
    let ow = width - SSIM_WINDOW + 1;
    let oh = height - SSIM_WINDOW + 1;
    let mut rows = vec![0.0; ow * height];
    for y in 0..height {
        for x in 0..ow {
            rows[y * ow + x] = (0..SSIM_WINDOW)
                .map(|i| k[i] * plane[y * width + x + i])
                .sum();
        }
    }
    let mut out = vec![0.0; ow * oh];
    for y in 0..oh {
        for x in 0..ow {
            out[y * ow + x] = (0..SSIM_WINDOW)
                .map(|i| k[i] * rows[(y + i) * ow + x])
                .sum();
        }
    }
    out
}

/// The SSIM map of two planes: `(map, map_width, map_height)`, entry (x, y) for the window
/// centred on pixel (x + 5, y + 5); None if a plane is smaller than the window.
pub fn ssim_map(
    a: &[f64],
    b: &[f64],
    width: usize,
    height: usize,
    range: f64,
) -> Option<(Vec<f64>, usize, usize)> {
    if width < SSIM_WINDOW
        || height < SSIM_WINDOW
        || a.len() != width * height
        || b.len() != a.len()
    {
        return None;
    }
    let k = gaussian_kernel();
    let prod = |f: &dyn Fn(f64, f64) -> f64| -> Vec<f64> {
        a.iter().zip(b).map(|(&x, &y)| f(x, y)).collect()
    };
    let mu_a = filter_valid(a, width, height, &k);
    let mu_b = filter_valid(b, width, height, &k);
    let aa = filter_valid(&prod(&|x, _| x * x), width, height, &k);
    let bb = filter_valid(&prod(&|_, y| y * y), width, height, &k);
    let ab = filter_valid(&prod(&|x, y| x * y), width, height, &k);
    let c1 = (SSIM_K1 * range).powi(2);
    let c2 = (SSIM_K2 * range).powi(2);
    let map = (0..mu_a.len())
        .map(|i| {
            let (ma, mb) = (mu_a[i], mu_b[i]);
            let va = aa[i] - ma * ma;
            let vb = bb[i] - mb * mb;
            let cov = ab[i] - ma * mb;
            ((2.0 * ma * mb + c1) * (2.0 * cov + c2)) / ((ma * ma + mb * mb + c1) * (va + vb + c2))
        })
        .collect();
    Some((map, width - SSIM_WINDOW + 1, height - SSIM_WINDOW + 1))
}

/// Mean SSIM of two planes with dynamic range `range`; NaN if smaller than the window.
pub fn ssim(a: &[f64], b: &[f64], width: usize, height: usize, range: f64) -> f64 {
    match ssim_map(a, b, width, height, range) {
        Some((map, _, _)) => map.iter().sum::<f64>() / map.len() as f64,
        None => f64::NAN,
    }
}

/// Mean SSIM over the windows centred on pixels where `mask` is true; NaN if none.
pub fn masked_ssim(
    a: &[f64],
    b: &[f64],
    width: usize,
    height: usize,
    range: f64,
    mask: &[bool],
) -> f64 {
    let Some((map, mw, mh)) = ssim_map(a, b, width, height, range) else {
        return f64::NAN;
    };
    let r = SSIM_WINDOW / 2;
    let (mut sum, mut n) = (0.0, 0usize);
    for y in 0..mh {
        for x in 0..mw {
            if mask.get((y + r) * width + x + r) == Some(&true) {
                sum += map[y * mw + x];
                n += 1;
            }
        }
    }
    if n == 0 {
        f64::NAN
    } else {
        sum / n as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identical_planes_score_one_and_constant_offsets_follow_the_closed_form() {
        let (w, h) = (16, 13);
        let a: Vec<f64> = (0..w * h)
            .map(|i| ((i * 37) % 101) as f64 / 100.0)
            .collect();
        assert!((ssim(&a, &a, w, h, 1.0) - 1.0).abs() < 1e-12);
        // Two constant planes x and y: SSIM = (2xy + C1) / (x² + y² + C1) exactly.
        let x = vec![0.2; w * h];
        let y = vec![0.6; w * h];
        let c1 = 1e-4;
        let want = (2.0 * 0.2 * 0.6 + c1) / (0.04 + 0.36 + c1);
        assert!((ssim(&x, &y, w, h, 1.0) - want).abs() < 1e-12);
        assert!(ssim(&a, &a, 5, 5, 1.0).is_nan());
    }

    /// Values from scikit-image 0.26.0, `structural_similarity(a, x, gaussian_weights=True,
    /// sigma=1.5, use_sample_covariance=False, data_range=1.0)`, with this script:
    ///
    /// ```text
    /// w, h = 20, 17
    /// i = np.arange(w * h, dtype=np.float64)
    /// a = ((i * 37) % 101) / 100.0
    /// b = np.clip(a + 0.1 * np.sin(i / 3.0), 0, 1)
    /// c = 0.5 * a + 0.2
    /// ```
    #[test]
    fn matches_scikit_image() {
        let (w, h) = (20, 17);
        let a: Vec<f64> = (0..w * h)
            .map(|i| ((i * 37) % 101) as f64 / 100.0)
            .collect();
        let b: Vec<f64> = a
            .iter()
            .enumerate()
            .map(|(i, v)| (v + 0.1 * (i as f64 / 3.0).sin()).clamp(0.0, 1.0))
            .collect();
        let c: Vec<f64> = a.iter().map(|v| 0.5 * v + 0.2).collect();
        assert!((ssim(&a, &b, w, h, 1.0) - 0.9817899177237879).abs() < 1e-12);
        assert!((ssim(&a, &c, w, h, 1.0) - 0.7963952821925857).abs() < 1e-12);
    }
}

//! The matching images of registration, made to agree across filters: each camera's
//! calibrated channels are mixed into an estimate of one signal that every camera of the
//! array can estimate, so that a surface looks alike in all views before the cross-spectral
//! matcher compares them. It sits between calibration and the matcher
//! (`calibrate -> common signal -> register -> warp -> demux`).
//!
//! A camera's luminance is no such signal: behind a red filter a red–blue grating is bright
//! on red, behind a teal one bright on blue, and a contrast inversion looks like a
//! half-period shift to any local matching cost. The weights here come from a generalised
//! canonical correlation analysis (the "SUMCOR" form of Kettenring 1971) over a generic
//! distribution of smooth reflectances: a Gaussian process over the sensing matrix's knots
//! with a squared-exponential kernel, which owes nothing to any measured reflectance set.
//! With `Σ_kl = C_k K C_lᵀ` the covariance of cameras k and l, the weights g maximise
//! `Σ_kl g_kᵀ Σ_kl g_l` subject to `Σ_k g_kᵀ (Σ_kk + σ² I) g_k = 1`, where σ² is the sensor
//! noise: a generalised symmetric eigenproblem whose leading vector holds every camera's
//! weights. The noise term keeps a camera's dim channels from being amplified into noise.

use super::NormalisedView;
use crate::rig::SensingMatrix;
use crate::stereo::GreyImage;
use crate::{Error, Result};
use faer::{Mat, Side};
use serde::Serialize;

/// Reflectance standard deviation of the generic prior (`K = σ_r² exp(−Δλ²/2ℓ²)`).
pub const PRIOR_REFLECTANCE_SD: f64 = 0.2;
/// Correlation length ℓ of the generic prior, in nm: 40–80 nm predict measured reflectances
/// (ColorChecker, CIE test colours, 190 patches) across the paper's rig equally well; 60 is
/// the middle.
pub const PRIOR_CORRELATION_NM: f64 = 60.0;
/// Sensor noise assumed in C's units (white-calibrated). The simulator's captures carry
/// 0.004–0.012 per channel on a white board; assuming 0.015 regularises more than that and
/// measured best over the presets (all views at 640×480, the default pipeline: 0.007 /
/// 0.015 / 0.03 gave the periodic scene's r0c0 30.1 / 30.4 / 28.8 dB with two signals,
/// 31.99 / 28.84 dB with three at 0.015 / 0.03; the tabletop and clutter within 0.6 dB).
pub const MEASUREMENT_NOISE: f64 = 0.015;

/// How many common signals registration matches by (the leading ones). One is not
/// enough: two materials can look alike in it (the tabletop's striped sphere did, and its
/// r0c0 fell from 35.3 to 29.8 dB); three gave the best mean over the presets.
pub const COMMON_SIGNALS: usize = 3;

/// Shared variance, relative to the leading signal's, at or below which a signal is no
/// signal: the cameras share nothing in it beyond rounding, as where every camera has the
/// same one spectral response (a monochrome array without filter curves, whose covariance
/// has rank one). Such a signal's weights are an arbitrary vector of the null space (some
/// exactly zero), and matching by it only spent the network's time: on the 3×3 array of
/// one response at 1600×1200 the fine level's features took twice as long.
const UNSHARED: f64 = 1e-9;

/// What multi-baseline registration compares the views by.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum MatchingImage {
    /// Each camera's luminance (Rec. 709 weights): the paper's input to the matcher.
    Luminance,
    /// The leading [`COMMON_SIGNALS`] common signals of the array (see the module docs).
    #[default]
    CommonSignals,
}

crate::choice::named_choices!(MatchingImage, "matching image" {
    CommonSignals = "common-signals" "The leading common signals of the array: each camera's channels mixed into what every camera can estimate, so that filters do not invert contrast between views.",
    Luminance = "luminance" "Each camera's luminance (the paper's input).",
});

/// Per camera, the weights of its channels in the common signal, and how well each
/// camera's estimate follows the common signal under the prior.
#[derive(Debug, Clone, Serialize)]
pub struct CommonSignal {
    /// `weights[k][c]`: channel c of camera k (cameras in sensing-matrix order).
    pub weights: Vec<Vec<f64>>,
    /// Per camera, the correlation of its noisy estimate with the mean of all cameras'.
    pub correlation: Vec<f64>,
}

/// The `count` leading common signals of the cameras whose channel counts are
/// `channels` (their rows of `sensing`, in order), the best first, fewer where the cameras
/// share fewer ([`UNSHARED`]; never none). Each later signal is uncorrelated with the
/// earlier ones under the prior.
pub fn common_signals(
    sensing: &SensingMatrix,
    channels: &[usize],
    count: usize,
) -> Result<Vec<CommonSignal>> {
    let m = sensing.rows();
    if channels.iter().sum::<usize>() != m || channels.contains(&0) {
        return Err(Error::Shape {
            op: "common signal: camera channels against the rows of C".into(),
            got: channels.to_vec(),
            expected: vec![m],
        });
    }
    let wavelengths = sensing.unknowns.wavelengths();
    let n = wavelengths.len();
    let kernel = Mat::<f64>::from_fn(n, n, |i, j| {
        let d = (wavelengths[i] - wavelengths[j]) / PRIOR_CORRELATION_NM;
        PRIOR_REFLECTANCE_SD.powi(2) * (-0.5 * d * d).exp()
    });
    let c = Mat::<f64>::from_fn(m, n, |r, j| sensing.row(r)[j]);
    let covariance = &c * &kernel * c.transpose();
    let blocks: Vec<std::ops::Range<usize>> = channels
        .iter()
        .scan(0, |first, &ch| {
            let range = *first..*first + ch;
            *first += ch;
            Some(range)
        })
        .collect();
    let in_block = |i: usize, j: usize| blocks.iter().any(|b| b.contains(&i) && b.contains(&j));
    let noise = MEASUREMENT_NOISE * MEASUREMENT_NOISE;
    let within = Mat::<f64>::from_fn(m, m, |i, j| {
        if !in_block(i, j) {
            0.0
        } else if i == j {
            covariance[(i, j)] + noise
        } else {
            covariance[(i, j)]
        }
    });
    let eigen = |a: &Mat<f64>, what: &str| {
        a.self_adjoint_eigen(Side::Lower)
            .map_err(|e| Error::LinearAlgebra {
                op: format!("common signal: {what}"),
                message: format!("{e:?}"),
            })
    };
    // D^{-1/2}: D is block-diagonal and positive definite (the noise term).
    let d = eigen(&within, "within-camera covariance")?;
    let (du, ds) = (d.U(), d.S().column_vector());
    let inv_sqrt = Mat::<f64>::from_fn(m, m, |i, j| {
        (0..m)
            .map(|k| du[(i, k)] * du[(j, k)] / ds[k].max(f64::MIN_POSITIVE).sqrt())
            .sum()
    });
    let whitened = &inv_sqrt * &covariance * &inv_sqrt;
    let symmetric = Mat::<f64>::from_fn(m, m, |i, j| 0.5 * (whitened[(i, j)] + whitened[(j, i)]));
    let top = eigen(&symmetric, "between-camera covariance")?;
    // Eigenvalues come in nondecreasing order: the leading vectors are the last.
    let shared = top.S().column_vector();
    (0..count.min(m))
        .take_while(|&rank| rank == 0 || shared[m - 1 - rank] > UNSHARED * shared[m - 1])
        .map(|rank| {
            let leading: Vec<f64> = (0..m).map(|i| top.U()[(i, m - 1 - rank)]).collect();
            signal_of(sensing, &inv_sqrt, &leading, &covariance, noise, &blocks)
        })
        .collect()
}

/// The weights `D^{-1/2} v` of eigenvector `v`, oriented and scored (see [`common_signals`]).
fn signal_of(
    sensing: &SensingMatrix,
    inv_sqrt: &Mat<f64>,
    leading: &[f64],
    covariance: &Mat<f64>,
    noise: f64,
    blocks: &[std::ops::Range<usize>],
) -> Result<CommonSignal> {
    let m = leading.len();
    let mut g: Vec<f64> = (0..m)
        .map(|i| (0..m).map(|k| inv_sqrt[(i, k)] * leading[k]).sum())
        .collect();
    // Orient the signal so that a white surface reads positive.
    let white: f64 = (0..m)
        .map(|r| g[r] * sensing.row(r).iter().sum::<f64>())
        .sum();
    if white < 0.0 {
        g.iter_mut().for_each(|v| *v = -*v);
    }
    if g.iter().any(|v| !v.is_finite()) {
        return Err(Error::LinearAlgebra {
            op: "common signal".into(),
            message: "the weights are not finite".into(),
        });
    }
    // Correlations under the prior: estimate k is g_kᵀ(C_k r + noise); the mean estimate
    // is the average over cameras.
    let k_count = blocks.len() as f64;
    let weight = |k: usize, r: usize| if blocks[k].contains(&r) { g[r] } else { 0.0 };
    let mean_weight = |r: usize| g[r] / k_count;
    let cov_of = |a: &dyn Fn(usize) -> f64, b: &dyn Fn(usize) -> f64, with_noise: bool| {
        let mut sum = 0.0;
        for i in 0..m {
            for j in 0..m {
                sum += a(i) * covariance[(i, j)] * b(j);
            }
            if with_noise {
                sum += a(i) * noise * b(i);
            }
        }
        sum
    };
    let mean_var = cov_of(&mean_weight, &mean_weight, true);
    let correlation = (0..blocks.len())
        .map(|k| {
            let own = |r: usize| weight(k, r);
            let var = cov_of(&own, &own, true);
            cov_of(&own, &mean_weight, true) / (var * mean_var).sqrt().max(f64::MIN_POSITIVE)
        })
        .collect();
    let weights = blocks.iter().map(|b| g[b.clone()].to_vec()).collect();
    Ok(CommonSignal {
        weights,
        correlation,
    })
}

/// Each calibrated view mixed by its camera's weights (see the module docs). Pixels without
/// a value (NaN in any channel: saturated, or outside a rectified camera's frame) take the
/// nearest value of their row, so that matching costs stay finite.
pub fn common_signal_images(views: &[NormalisedView], signal: &CommonSignal) -> Vec<GreyImage> {
    views
        .iter()
        .zip(&signal.weights)
        .map(|(view, weights)| {
            // A one-channel camera's estimate is its capture scaled, and the matcher
            // normalises every image, so only the sign of its weight matters: ±1 makes the
            // images of signals of one sign equal, and their features are computed once.
            let sign_only = [match weights.first() {
                Some(&g) if g > 0.0 => 1.0,
                Some(&g) if g < 0.0 => -1.0,
                _ => 0.0,
            }];
            let weights: &[f64] = if view.image.channels == 1 {
                &sign_only
            } else {
                weights
            };
            let mut data: Vec<f32> = view
                .image
                .data
                .chunks_exact(view.image.channels)
                .map(|p| {
                    p.iter()
                        .zip(weights)
                        .map(|(&v, &g)| v as f64 * g)
                        .sum::<f64>() as f32
                })
                .collect();
            for row in data.chunks_exact_mut(view.image.width) {
                super::fill_from_nearest(row);
            }
            GreyImage {
                channels: 1,
                width: view.image.width,
                height: view.image.height,
                data,
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::Image;
    use crate::spectrum::SpectralShape;

    /// A camera of three Gaussian channels (peak 1 on a white surface) behind nothing.
    fn camera(peaks_nm: [f64; 3], wavelengths: &[f64]) -> Vec<f64> {
        let mut rows = Vec::new();
        for peak in peaks_nm {
            let row: Vec<f64> = wavelengths
                .iter()
                .map(|w| (-0.5 * ((w - peak) / 40.0).powi(2)).exp())
                .collect();
            let total: f64 = row.iter().sum();
            rows.extend(row.iter().map(|v| v / total));
        }
        rows
    }

    /// `Σ_c g_c (C_k s)_c` for camera k of `sensing`.
    fn estimate(sensing: &SensingMatrix, weights: &[f64], first_row: usize, s: &[f64]) -> f64 {
        weights
            .iter()
            .enumerate()
            .map(|(c, g)| {
                let row = sensing.row(first_row + c);
                g * row.iter().zip(s).map(|(a, b)| a * b).sum::<f64>()
            })
            .sum()
    }

    /// A red and a blue material: the reddish camera sees the red one brighter, the bluish
    /// camera the blue one, so their luminances invert the contrast; the leading common
    /// signal gives both cameras the same contrast, of the same sign.
    #[test]
    fn the_common_signal_undoes_a_contrast_inversion_between_filters() {
        let shape = SpectralShape::new(450.0, 8.0, 24).unwrap();
        let wavelengths = shape.wavelengths();
        let mut values = camera([560.0, 600.0, 630.0], &wavelengths);
        values.extend(camera([470.0, 510.0, 560.0], &wavelengths));
        let sensing = SensingMatrix::from_dense(6, shape, values).unwrap();
        let step = |w: f64, rising: bool| {
            let t = 1.0 / (1.0 + (-(w - 545.0) / 15.0).exp());
            if rising {
                0.1 + 0.7 * t
            } else {
                0.8 - 0.7 * t
            }
        };
        let red: Vec<f64> = wavelengths.iter().map(|&w| step(w, true)).collect();
        let blue: Vec<f64> = wavelengths.iter().map(|&w| step(w, false)).collect();
        let luminance = [1.0 / 3.0; 3];
        let contrast = |weights: &[f64], first_row: usize| {
            estimate(&sensing, weights, first_row, &red)
                - estimate(&sensing, weights, first_row, &blue)
        };
        // Luminance: opposite signs.
        assert!(contrast(&luminance, 0) > 0.1 && contrast(&luminance, 3) < -0.1);

        let signals = common_signals(&sensing, &[3, 3], 2).unwrap();
        assert_eq!(signals.len(), 2);
        let leading = &signals[0];
        assert_eq!(leading.weights.len(), 2);
        let (a, b) = (
            contrast(&leading.weights[0], 0),
            contrast(&leading.weights[1], 3),
        );
        assert!(
            a * b > 0.0 && (a - b).abs() < 0.2 * a.abs().max(b.abs()),
            "contrasts {a} and {b}"
        );
        assert!(
            leading.correlation.iter().all(|&r| r > 0.9),
            "{:?}",
            leading.correlation
        );
        // A white surface reads positive in both cameras.
        let white = vec![1.0; wavelengths.len()];
        assert!(estimate(&sensing, &leading.weights[0], 0, &white) > 0.0);
        assert!(estimate(&sensing, &leading.weights[1], 3, &white) > 0.0);
        // The second signal agrees less well than the first.
        let mean = |s: &CommonSignal| s.correlation.iter().sum::<f64>() / 2.0;
        assert!(mean(&signals[1]) <= mean(leading) + 1e-9);

        assert_eq!(
            common_signals(&sensing, &[3, 2], 1).err().map(|e| e.kind()),
            Some("Shape")
        );
        assert_eq!(
            common_signals(&sensing, &[6, 0], 1).err().map(|e| e.kind()),
            Some("Shape")
        );
    }

    /// Cameras of one spectral response share one signal and nothing else: one signal
    /// comes back, with every camera's weight of one sign and none zero. Cameras behind
    /// different narrow bands share more, and get all the signals asked for.
    #[test]
    fn cameras_of_one_response_share_one_signal() {
        let shape = SpectralShape::new(450.0, 8.0, 24).unwrap();
        let wavelengths = shape.wavelengths();
        let band = |peak: f64| -> Vec<f64> {
            let row: Vec<f64> = wavelengths
                .iter()
                .map(|w| (-0.5 * ((w - peak) / 30.0).powi(2)).exp())
                .collect();
            let total: f64 = row.iter().sum();
            row.iter().map(|v| v / total).collect()
        };
        let alike = SensingMatrix::from_dense(5, shape, band(550.0).repeat(5)).unwrap();
        let signals = common_signals(&alike, &[1; 5], COMMON_SIGNALS).unwrap();
        assert_eq!(signals.len(), 1);
        let weights: Vec<f64> = signals[0].weights.iter().map(|w| w[0]).collect();
        assert!(weights.iter().all(|&g| g > 0.0), "{weights:?}");

        let peaks = [470.0, 510.0, 550.0, 590.0, 630.0];
        let values: Vec<f64> = peaks.iter().flat_map(|&p| band(p)).collect();
        let distinct = SensingMatrix::from_dense(5, shape, values).unwrap();
        let signals = common_signals(&distinct, &[1; 5], COMMON_SIGNALS).unwrap();
        assert_eq!(signals.len(), COMMON_SIGNALS);
    }

    /// The images mix each view's channels by its weights; missing values take the row's
    /// nearest value.
    #[test]
    fn images_mix_each_view_by_its_weights() {
        let view = NormalisedView {
            image: Image {
                width: 3,
                height: 1,
                channels: 2,
                data: vec![1.0, 2.0, f32::NAN, 1.0, 0.5, 0.5],
            },
        };
        let signal = CommonSignal {
            weights: vec![vec![2.0, -1.0]],
            correlation: vec![1.0],
        };
        let images = common_signal_images(&[view], &signal);
        assert_eq!(images[0].data, vec![0.0, 0.0, 0.5]);
    }
}

//! End-to-end spectral recovery trials without images: a set of measured reflectances is
//! rendered through a rig on the fine (1 nm) grid with the capture noise model, normalised
//! by a white-board capture, demultiplexed, and compared with the truth at the band
//! centres. This is the paper's Table 1 evaluation with perfect registration, and what
//! `anaglyph demo` and the accuracy tests run. [`light_field`] scores whole reconstructed
//! views against the simulator's truth (`anaglyph eval`).

mod light_field;

pub use light_field::{bad_pixel_share, score_cube, seen_by_all_views, BandScores, SAME_POINT_PX};

use crate::capture::{measure_spectra, spectra_on_grid, CameraNoise};
use crate::demux::{demultiplex, normalise_by_white, DemuxOptions, DemuxReport};
use crate::metrics::{mean_spectral_angle, psnr, psnr_per_band, rmse};
use crate::rig::{EffectiveResponses, SensingMatrix};
use crate::spectrum::{Interpolation, ResponseCurve};
use crate::Result;
use serde::Serialize;

/// Settings of a trial.
#[derive(Debug, Clone, Copy)]
pub struct TrialSettings {
    /// None: noise-free measurements.
    pub noise: Option<CameraNoise>,
    pub seed: u64,
    pub options: DemuxOptions,
}

/// Measured accuracy of a trial.
#[derive(Debug, Clone, Serialize)]
pub struct TrialResult {
    pub samples: usize,
    /// PSNR per reported band, peak 1.
    pub band_psnr: Vec<f64>,
    /// PSNR over all bands and samples.
    pub psnr: f64,
    pub rmse: f64,
    /// Mean spectral angle, degrees.
    pub spectral_angle_deg: f64,
    /// Largest absolute error over all bands and samples.
    pub max_abs_error: f64,
    pub saturated_measurements: usize,
    pub report: DemuxReport,
    /// Reconstructed spectra, `samples × bands`.
    #[serde(skip)]
    pub estimate: Vec<f64>,
    /// True spectra at the band centres, `samples × bands`.
    #[serde(skip)]
    pub truth: Vec<f64>,
}

/// Runs a trial of `reflectances` (one column per sample) through the rig described by
/// `responses` and `sensing`. A perfect white board is captured with the same noise.
pub fn recover_reflectances(
    reflectances: &ResponseCurve,
    responses: &EffectiveResponses,
    sensing: &SensingMatrix,
    settings: &TrialSettings,
) -> Result<TrialResult> {
    let rows = sensing.rows();
    let spectra = spectra_on_grid(reflectances, responses)?;
    let clean = measure_spectra(&spectra, responses, sensing);
    let white_clean = measure_spectra(&[vec![1.0; responses.grid.count]], responses, sensing);
    let (mut measured, white, saturated) = match settings.noise {
        Some(noise) => {
            let scene = noise.apply(&clean, settings.seed);
            // Average 16 white frames, as one would when calibrating.
            let frames: Vec<f64> = white_clean
                .iter()
                .cycle()
                .take(rows * 16)
                .copied()
                .collect();
            let w = noise.apply(&frames, settings.seed ^ 0x5757_5757);
            let mean: Vec<f64> = (0..rows)
                .map(|r| (0..16).map(|f| w.values[f * rows + r]).sum::<f64>() / 16.0)
                .collect();
            let mut values = scene.values;
            let count = scene.saturated.iter().filter(|s| **s).count();
            for (v, s) in values.iter_mut().zip(&scene.saturated) {
                if *s {
                    *v = f64::NAN;
                }
            }
            (values, mean, count)
        }
        None => (clean, white_clean.clone(), 0),
    };
    // White response in C's units: C · 1.
    let white_response: Vec<f64> = (0..rows).map(|r| sensing.row(r).iter().sum()).collect();
    normalise_by_white(&mut measured, rows, &white, &white_response);
    let bands = sensing.reported.count;
    let output = sensing.reported_offset..sensing.reported_offset + bands;
    let (estimate, report) = demultiplex(
        sensing.values(),
        rows,
        &measured,
        None,
        output,
        &settings.options,
    )?;
    let centres = sensing.reported.wavelengths();
    let mut truth = Vec::with_capacity(reflectances.channel_count() * bands);
    for c in 0..reflectances.channel_count() {
        truth.extend(reflectances.sample(c, &centres, Interpolation::Linear)?);
    }
    let max_abs_error = truth
        .iter()
        .zip(&estimate)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    Ok(TrialResult {
        samples: reflectances.channel_count(),
        band_psnr: psnr_per_band(&truth, &estimate, bands, 1.0),
        psnr: psnr(&truth, &estimate, 1.0),
        rmse: rmse(&truth, &estimate),
        spectral_angle_deg: mean_spectral_angle(&truth, &estimate, bands).to_degrees(),
        max_abs_error,
        saturated_measurements: saturated,
        report,
        estimate,
        truth,
    })
}

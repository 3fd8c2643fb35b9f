//! A spectral prior learned from the scene itself, for pixels that some cameras do not
//! see (beyond the paper). Runs after the inconsistent pixels, before the confidence weights and the guided filter.
//!
//! Why: near a view's border and behind occluders, fewer cameras see a pixel, so it has
//! fewer measurements than bands; the smoothness term of Eq. 6 then decides the spectrum,
//! and a smooth spectrum is a poor guess. The pixels every camera sees are well
//! determined, and the same materials usually appear among them. Their spectra are
//! clustered (k-means) into a mixture of Gaussians, each with a weight, a mean μ_m and a
//! covariance Σ_m. Each under-measured pixel, with measurements P_a through the rows C_a
//! of C that see it, takes the posterior mean under that mixture: per component the
//! linear minimum mean square error estimate
//!
//! ŝ_m = μ_m + Σ_m C_aᵀ (C_a Σ_m C_aᵀ + R)⁻¹ (P_a − C_a μ_m),
//!
//! weighted by how well the component explains P_a, clamped to ŝ ≥ 0. R is the
//! measurement noise, estimated from the residuals of the complete pixels. With one
//! component this is the plain linear estimate under the scene's mean and covariance.
//! The prior comes from the reconstruction, not from a spectral library, so the
//! simulator's reflectance sets stay out of the reconstruction (no inverse crime).
//!
//! A pixel whose measurements no component finds plausible (the innovation
//! `P_a − C_a μ_m` far out in its χ² distribution: a wrong match, or a material the
//! complete pixels lack) keeps its Eq. 6 spectrum, since the estimate would extrapolate
//! wildly there. The gate is looser for pixels that at most a quarter of the rows see:
//! Eq. 6 has little to go on there, so falling back to it costs more.
//!
//! Some materials are never seen completely (a surface along the top of a view, which
//! the lower row of cameras cannot reach). Propagation rounds ([`ScenePrior::fill_view`])
//! add them: components learned from the filled estimates of pixels at least half the
//! rows see join the mixture, and every under-measured pixel is estimated again.
//!
//! In: C (rows × knots), a view's measurements (`pixels × rows`, NaN where not seen), its
//! spectra on all knots and their residuals ([`crate::solve::measurement_residuals`]). Out: the

mod estimate;
mod gaussian;
mod k_means;
mod mixture;
#[cfg(test)]
mod tests;
mod whitening;

pub use mixture::ScenePrior;

use super::{measurement_residuals, SolveStage, ViewSolve};
use crate::rig::SensingMatrix;
use crate::{Error, Result};
use mixture::{Eligible, NOISE_FLOOR};
use serde::Serialize;

/// A propagation round clusters its samples into this many times fewer clusters than the
/// complete pixels (they hold the few materials the complete pixels lack): on the clutter
/// preset 8 instead of 32 gave the same PSNR (36.95 / 36.97 dB with true disparities) at
/// two thirds of the time.
const EXTENSION_CLUSTER_DIVISOR: usize = 4;

/// Settings of the scene prior, as recorded in the manifest.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ScenePriorSettings {
    /// Multiplies the noise level learned from the complete pixels' residuals: larger
    /// trusts the measurements less and the prior's means more.
    pub noise_scale: f64,
    /// Clusters per k-means run; 1 gives a single Gaussian (the scene's mean and
    /// covariance).
    pub clusters: usize,
    /// Rounds that extend the mixture with the materials the complete pixels lack, from
    /// the pixels at least half the rows measure (see [`fill_view`]); 0 keeps
    /// the complete pixels' mixture alone.
    pub propagation_rounds: usize,
}

impl Default for ScenePriorSettings {
    fn default() -> Self {
        // Measured on the presets at 640×480 (docs/reconstruction.md, "Scene prior"): noise scales of
        // 0.3 and 0.5 gain alike in PSNR, 0.5 keeps SSIM; 3 leans so hard on the mean that
        // it loses 7 dB. 32 clusters beat 16 and 64.
        ScenePriorSettings {
            noise_scale: 0.5,
            clusters: 32,
            propagation_rounds: 2,
        }
    }
}

impl ScenePriorSettings {
    /// Checks the numbers before any work.
    pub fn validate(&self) -> Result<()> {
        if !(self.noise_scale > 0.0) || !self.noise_scale.is_finite() {
            return Err(Error::OutOfRange {
                setting: "scene prior noise scale".into(),
                value: self.noise_scale,
                expected: "a finite value > 0".into(),
            });
        }
        if self.clusters == 0 {
            return Err(Error::OutOfRange {
                setting: "scene prior clusters".into(),
                value: 0.0,
                expected: "at least 1".into(),
            });
        }
        Ok(())
    }
}

/// What the prior did to one view, for the manifest.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ScenePriorReport {
    /// Complete pixels whose spectra built the prior.
    pub samples: usize,
    /// Incompletely but well measured pixels (at least half the rows) whose estimates
    /// added components in the last propagation round.
    pub propagated_samples: usize,
    /// Gaussians in the mixture.
    pub components: usize,
    /// Pixels whose spectra were replaced by the prior's estimate.
    pub filled_pixels: usize,
    /// Under-measured pixels left as they were because the prior found their
    /// measurements implausible.
    pub rejected_pixels: usize,
    /// The measurement noise assumed, in reflectance units (rms per measurement).
    pub noise: f64,
    /// The mixture was the previous frame's (a sequence's temporal reuse), not learned
    /// from this view.
    pub carried: bool,
}

impl ScenePriorReport {
    /// The share of the under-measured pixels the prior left as they were.
    pub fn rejected_share(&self) -> f64 {
        let total = self.filled_pixels + self.rejected_pixels;
        if total == 0 {
            0.0
        } else {
            self.rejected_pixels as f64 / total as f64
        }
    }
}

/// The stage: learns the prior from the view's complete pixels and fills the
/// under-measured ones ([`fill_view`]).
#[derive(Debug, Clone, Copy)]
pub struct ScenePriorStage {
    pub settings: ScenePriorSettings,
}

impl SolveStage for ScenePriorStage {
    fn name(&self) -> &'static str {
        "scene prior"
    }

    fn needs_residuals(&self) -> bool {
        true
    }

    /// With a carried prior (a sequence's previous frame), fills with it unless it meets
    /// a new material; else learns the prior. The prior used stays in `solve.prior` for
    /// the next frame.
    fn run(&self, solve: &mut ViewSolve<'_>) -> Result<()> {
        solve.check_full(self.name())?;
        let sensing = solve.context.sensing;
        let mut residuals = solve.residuals.take().unwrap_or_default();
        let (measurements, spectra) = (&solve.measurements, &mut solve.spectra);
        let carried = match solve.prior.take() {
            Some(prior) => fill_carried(
                &prior,
                sensing,
                measurements,
                spectra,
                &mut residuals,
                &self.settings,
            )
            .map(|filled| filled.map(|report| (report, prior))),
            None => Ok(None),
        };
        let filled = match carried {
            Ok(None) => learn_and_fill(
                sensing,
                measurements,
                spectra,
                &mut residuals,
                &self.settings,
            ),
            other => other,
        };
        solve.residuals = Some(residuals);
        let filled = filled?;
        solve.report.scene_prior = filled.as_ref().map(|(report, _)| *report);
        solve.prior = filled.map(|(_, prior)| prior);
        Ok(())
    }
}

/// The whole stage for one view: learns the prior from the complete pixels and fills
/// the under-measured ones, then propagates it `settings.propagation_rounds` times.
///
/// Why propagate: a material the complete pixels lack (a surface near the top of the
/// view, which the lower row of cameras cannot see) has no component, so its pixels
/// take a wrong material's spectrum or fall back to Eq. 6. Where at least half the
/// rows measure such a surface, its filled estimate is good (the clutter preset's
/// pixels seen by the upper row alone: 38.4 dB). So each round learns further
/// components from those pixels — incomplete, at least half the rows, residual no
/// larger than the complete pixels' median — adds them to the complete pixels'
/// mixture (weights by sample count), and refills every under-measured pixel.
///
/// `residuals` (per pixel, [`measurement_residuals`]) must match `spectra` (on every
/// knot of C) on entry and are updated to the final spectra. None when too few complete
/// pixels qualify (the spectra are left alone).
pub fn fill_view(
    sensing: &SensingMatrix,
    measurements: &[f32],
    spectra: &mut [f32],
    residuals: &mut Vec<f32>,
    settings: &ScenePriorSettings,
) -> Result<Option<ScenePriorReport>> {
    let filled = learn_and_fill(sensing, measurements, spectra, residuals, settings)?;
    Ok(filled.map(|(report, _)| report))
}

/// [`fill_view`], with the final mixture as the next frame of a sequence carries it.
fn learn_and_fill(
    sensing: &SensingMatrix,
    measurements: &[f32],
    spectra: &mut [f32],
    residuals: &mut Vec<f32>,
    settings: &ScenePriorSettings,
) -> Result<Option<(ScenePriorReport, CarriedPrior)>> {
    let (rows, knots) = (sensing.rows(), sensing.cols());
    let Some(prior) = ScenePrior::learn(
        rows,
        knots,
        measurements,
        spectra,
        residuals,
        settings.clusters,
    )?
    else {
        return Ok(None);
    };
    // Every round estimates all under-measured pixels again, so that a pixel the
    // extended mixture rejects keeps the previous round's estimate.
    let mut report = prior.fill_incomplete(sensing, measurements, spectra, settings.noise_scale)?;
    *residuals = measurement_residuals(sensing, measurements, spectra)?;
    let mut last = prior.clone();
    for _ in 0..settings.propagation_rounds {
        let Some(extension) = ScenePrior::learn_from(
            rows,
            knots,
            measurements,
            spectra,
            residuals,
            settings.clusters.div_ceil(EXTENSION_CLUSTER_DIVISOR),
            Eligible {
                measured: rows.div_ceil(2)..rows,
                max_residual: Some(prior.noise.max(NOISE_FLOOR) as f32),
            },
        )?
        else {
            break;
        };
        let added = extension.samples;
        let extended = prior.clone().merged(extension);
        report = extended.fill_incomplete(sensing, measurements, spectra, settings.noise_scale)?;
        report.samples = prior.samples;
        report.propagated_samples = added;
        *residuals = measurement_residuals(sensing, measurements, spectra)?;
        last = extended;
    }
    let carried = CarriedPrior {
        mixture: last,
        rejected: report.rejected_share(),
    };
    Ok(Some((report, carried)))
}

/// A view's scene prior as one frame of a sequence hands it to the next
/// ([`crate::reconstruct::FrameCarry`]): the final mixture, and the share of the
/// under-measured pixels it found implausible in the frame it was learned in.
#[derive(Debug, Clone)]
pub struct CarriedPrior {
    mixture: ScenePrior,
    rejected: f64,
}

/// A carried prior that finds more than `RELEARN_FACTOR` times (plus `RELEARN_SLACK`)
/// the share of implausible pixels it found when it was learned meets a material it does
/// not know, and the view learns its prior again.
const RELEARN_FACTOR: f64 = 1.5;
const RELEARN_SLACK: f64 = 0.01;

/// Fills the under-measured pixels with `carried`'s mixture (one estimate, no learning,
/// no propagation rounds: the mixture already holds the rounds' components). None, with
/// the spectra and residuals as they came, when the mixture finds clearly more of the
/// view's pixels implausible than when it was learned.
fn fill_carried(
    carried: &CarriedPrior,
    sensing: &SensingMatrix,
    measurements: &[f32],
    spectra: &mut [f32],
    residuals: &mut Vec<f32>,
    settings: &ScenePriorSettings,
) -> Result<Option<ScenePriorReport>> {
    let before = spectra.to_vec();
    let mut report =
        carried
            .mixture
            .fill_incomplete(sensing, measurements, spectra, settings.noise_scale)?;
    if report.rejected_share() > RELEARN_FACTOR * carried.rejected + RELEARN_SLACK {
        spectra.copy_from_slice(&before);
        return Ok(None);
    }
    *residuals = measurement_residuals(sensing, measurements, spectra)?;
    report.carried = true;
    Ok(Some(report))
}

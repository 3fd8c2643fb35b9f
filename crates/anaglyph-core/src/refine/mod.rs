//! Guided spectral refinement, the last stage of a view's solve (beyond the paper; see
//! [`crate::solve`] for the stages before it): each view's reflectance cube is filtered
//! with that view's own capture as the guide ([`guided_filter`]).
//!
//! Why: a view's own capture is the one measurement that needs no warping. The other
//! cameras' measurements reach it through interpolation at fractional disparities and
//! carry sensor noise that the solve amplifies, so the per-pixel spectrum is noisy and
//! blurred across texture and occlusion edges. In each small window the reflectance bands
//! are well modelled as an affine function of the view's own colour (few materials per
//! window); fitting that model by ridge regression and averaging the fits keeps the edges
//! of the capture and averages the noise. Pixels weigh by how well one spectrum explains
//! their warped measurements ([`crate::solve::confidence_weights`]), so misregistered pixels hardly
//! enter the fits. On the paper rig's tabletop at 640×480 this takes the reference view
//! from 29.5 to 35.4 dB (docs/reconstruction.md, "Refinement").
//!
//! In: a view's reflectance (`pixels × bands`, NaN where unmeasured), its white-normalised
//! capture. Out: the refined reflectance; unmeasured pixels stay NaN, and pixels whose own
//! capture is saturated keep their demultiplexed value.

mod guided_filter;

pub use guided_filter::{guided_filter, GuidedFilter, MAX_GUIDE_CHANNELS};

use crate::image::Image;
use crate::register::NormalisedView;
use crate::{Error, Result};
use serde::Serialize;

/// Settings of the refinement stage, as recorded in the manifest.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct GuidedRefinement {
    /// Window half-width in pixels.
    pub radius: usize,
    /// Ridge weight on the guide's window covariance, in squared reflectance units: the
    /// guide variance under which a window is smoothed rather than followed.
    pub epsilon: f64,
    /// Pixels weigh `1 / (1 + (ρ / σ)²)` in the fits, ρ their measurement residual and σ
    /// this multiple of the view's median residual
    /// ([`crate::solve::confidence_weights`]); None: every
    /// measured pixel weighs the same.
    pub confidence_scale: Option<f64>,
}

impl GuidedRefinement {
    /// Checks the numbers before any work.
    pub fn validate(&self) -> Result<()> {
        if self.radius == 0 {
            return Err(Error::OutOfRange {
                setting: "refinement radius".into(),
                value: 0.0,
                expected: "at least 1 pixel".into(),
            });
        }
        if !(self.epsilon > 0.0) || !self.epsilon.is_finite() {
            return Err(Error::OutOfRange {
                setting: "refinement epsilon".into(),
                value: self.epsilon,
                expected: "a finite value > 0".into(),
            });
        }
        match self.confidence_scale {
            Some(scale) if !(scale > 0.0) || !scale.is_finite() => Err(Error::OutOfRange {
                setting: "refinement confidence".into(),
                value: scale,
                expected: "a finite value > 0".into(),
            }),
            _ => Ok(()),
        }
    }
}

impl Default for GuidedRefinement {
    fn default() -> Self {
        GuidedRefinement {
            radius: 4,
            epsilon: 1e-4,
            confidence_scale: Some(1.5),
        }
    }
}

/// Refines `reflectance` (`height × width × bands`) in place, guided by `view`, whose
/// channel c is divided by `white_response[c]` (its value for a perfect white, in C's
/// units) so that the guide reads as reflectance.
pub fn refine_view(
    reflectance: &mut Vec<f32>,
    bands: usize,
    view: &NormalisedView,
    white_response: &[f64],
    weights: Option<&[f32]>,
    settings: GuidedRefinement,
) -> Result<()> {
    if white_response.len() != view.image.channels
        || white_response.iter().any(|r| !(*r > 0.0) || !r.is_finite())
    {
        return Err(Error::captures(
            "white responses of the guiding camera".to_string(),
            format!("{white_response:?}"),
            format!("{} positive, finite values", view.image.channels),
        ));
    }
    let guide: Vec<f32> = view
        .image
        .data
        .chunks_exact(view.image.channels)
        .flat_map(|pixel| {
            pixel
                .iter()
                .zip(white_response)
                .map(|(&v, &r)| (v as f64 / r) as f32)
        })
        .collect();
    let guide = Image::new(
        view.image.width,
        view.image.height,
        view.image.channels,
        guide,
    )?;
    let input = Image::new(
        view.image.width,
        view.image.height,
        bands,
        std::mem::take(reflectance),
    )?;
    *reflectance = guided_filter(
        &guide,
        &input,
        weights,
        GuidedFilter {
            radius: settings.radius,
            epsilon: settings.epsilon,
        },
    )?;
    Ok(())
}

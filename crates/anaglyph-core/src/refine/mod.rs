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
    let guide = guide_of(view, white_response)?;
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

/// The view's capture less its white response per channel: the filter's guide.
fn guide_of(view: &NormalisedView, white_response: &[f64]) -> Result<Image<f32>> {
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
    Image::new(
        view.image.width,
        view.image.height,
        view.image.channels,
        guide,
    )
}

/// Rows (and columns) of the tiles [`refine_view_near`] filters again.
pub const NEAR_TILE: usize = 64;
/// When the tiles to filter again, with their margins, would cover more than this share
/// of the image, [`refine_view_near`] filters the whole image instead (cheaper then).
pub const NEAR_MAX_SHARE: f64 = 0.6;

/// [`refine_view`] of the pixels near `changed` ones alone (a sequence's temporal
/// reuse): every other pixel takes `previous`, the filter's output of a frame whose input
/// it shares. The image is cut into [`NEAR_TILE`]-pixel tiles; a tile within twice the
/// radius of a changed pixel (the reach of a guided filter) is filtered again, with
/// neighbouring tiles of a row together and a margin of twice the radius around them, so
/// that its pixels get what the filter of the whole image gives them (up to rounding).
#[allow(clippy::too_many_arguments)]
pub fn refine_view_near(
    reflectance: &mut Vec<f32>,
    bands: usize,
    view: &NormalisedView,
    white_response: &[f64],
    weights: Option<&[f32]>,
    settings: GuidedRefinement,
    changed: &[bool],
    previous: &[f32],
) -> Result<()> {
    let (w, h) = (view.image.width, view.image.height);
    if changed.len() != w * h || previous.len() != reflectance.len() {
        return Err(Error::Shape {
            op: "refinement near changed pixels: mask and previous output".into(),
            got: vec![changed.len(), previous.len()],
            expected: vec![w * h, reflectance.len()],
        });
    }
    let guide = guide_of(view, white_response)?;
    let input = Image::new(w, h, bands, std::mem::take(reflectance))?;
    let reach = 2 * settings.radius;
    let filter = GuidedFilter {
        radius: settings.radius,
        epsilon: settings.epsilon,
    };
    let (columns, rows) = (w.div_ceil(NEAR_TILE), h.div_ceil(NEAR_TILE));
    // Per tile: a changed pixel within `reach` of it.
    let near = |tx: usize, ty: usize| {
        let ys = (ty * NEAR_TILE).saturating_sub(reach)..((ty + 1) * NEAR_TILE + reach).min(h);
        let xs = (tx * NEAR_TILE).saturating_sub(reach)..((tx + 1) * NEAR_TILE + reach).min(w);
        ys.into_iter()
            .any(|y| changed[y * w + xs.start..y * w + xs.end].iter().any(|&c| c))
    };
    // Runs of neighbouring tiles of a row to filter again: (x0, x1, y0, y1).
    let mut runs = Vec::new();
    for ty in 0..rows {
        let mut tx = 0;
        while tx < columns {
            if !near(tx, ty) {
                tx += 1;
                continue;
            }
            let first = tx;
            while tx < columns && near(tx, ty) {
                tx += 1;
            }
            let (x0, x1) = (first * NEAR_TILE, (tx * NEAR_TILE).min(w));
            runs.push((x0, x1, ty * NEAR_TILE, ((ty + 1) * NEAR_TILE).min(h)));
        }
    }
    let margin = |a: usize, b: usize, end: usize| (a.saturating_sub(reach), (b + reach).min(end));
    let area: usize = runs
        .iter()
        .map(|&(x0, x1, y0, y1)| {
            let ((cx0, cx1), (cy0, cy1)) = (margin(x0, x1, w), margin(y0, y1, h));
            (cx1 - cx0) * (cy1 - cy0)
        })
        .sum();
    if area as f64 > NEAR_MAX_SHARE * (w * h) as f64 {
        *reflectance = guided_filter(&guide, &input, weights, filter)?;
        return Ok(());
    }
    let mut output = previous.to_vec();
    for (x0, x1, y0, y1) in runs {
        {
            // Tiles x0..x1 of rows y0..y1, filtered with their margin.
            let ((cx0, cx1), (cy0, cy1)) = (margin(x0, x1, w), margin(y0, y1, h));
            let crop_guide = guide.crop(cx0..cx1, cy0..cy1)?;
            let crop_input = input.crop(cx0..cx1, cy0..cy1)?;
            let crop_weights: Option<Vec<f32>> = weights.map(|all| {
                (cy0..cy1)
                    .flat_map(|y| all[y * w + cx0..y * w + cx1].iter().copied())
                    .collect()
            });
            let filtered =
                guided_filter(&crop_guide, &crop_input, crop_weights.as_deref(), filter)?;
            let cw = cx1 - cx0;
            for y in y0..y1 {
                let from = ((y - cy0) * cw + (x0 - cx0)) * bands;
                let to = (y * w + x0) * bands;
                let n = (x1 - x0) * bands;
                output[to..to + n].copy_from_slice(&filtered[from..from + n]);
            }
        }
    }
    *reflectance = output;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const W: usize = 300;
    const H: usize = 200;

    /// A 300×200 view with a textured three-channel guide and a noisy two-band cube.
    fn inputs() -> (NormalisedView, Vec<f32>, Vec<f32>) {
        let (w, h) = (W, H);
        let guide = (0..w * h * 3)
            .map(|i| {
                let (x, y) = ((i / 3) % w, (i / 3) / w);
                0.3 + 0.2 * ((x as f32 * 0.21 + i as f32 % 3.0).sin() * (y as f32 * 0.13).cos())
            })
            .collect();
        let cube = (0..w * h * 2)
            .map(|i| 0.4 + 0.1 * (((i * 7919) % 97) as f32 / 97.0 - 0.5))
            .collect();
        let weights = (0..w * h)
            .map(|i| 0.5 + 0.5 * ((i % 13) as f32 / 13.0))
            .collect();
        let view = NormalisedView {
            image: Image::new(w, h, 3, guide).unwrap(),
        };
        (view, cube, weights)
    }

    #[test]
    fn filtering_near_changed_pixels_gives_the_whole_filter_there_and_keeps_the_rest() {
        let (view, cube, weights) = inputs();
        let settings = GuidedRefinement::default();
        let white = [1.0, 1.0, 1.0];
        let mut whole = cube.clone();
        refine_view(&mut whole, 2, &view, &white, Some(&weights), settings).unwrap();
        let previous = vec![-1.0f32; cube.len()];
        let at = |x: usize, y: usize| (y * W + x) * 2;
        let near = |changed: &[bool]| {
            let mut near = cube.clone();
            refine_view_near(
                &mut near,
                2,
                &view,
                &white,
                Some(&weights),
                settings,
                changed,
                &previous,
            )
            .unwrap();
            near
        };
        let close = |a: f32, b: f32| (a - b).abs() < 1e-5;
        // Every pixel changed: the whole filter, up to rounding.
        let all = near(&vec![true; W * H]);
        assert!(whole.iter().zip(&all).all(|(a, b)| close(*a, *b)));
        // Row 20 changed: the first row of tiles is filtered (as one run, with its margin),
        // the rest kept.
        let mut band = vec![false; W * H];
        band[20 * W..21 * W].fill(true);
        let banded = near(&band);
        for (x, y) in [(0, 0), (150, 30), (299, 63), (64, 10)] {
            assert!(close(banded[at(x, y)], whole[at(x, y)]), "({x}, {y})");
        }
        assert_eq!(banded[at(150, 64)], -1.0);
        assert_eq!(banded[at(250, 150)], -1.0);
        // One changed pixel at (20, 20): its tile.
        let mut one = vec![false; W * H];
        one[20 * W + 20] = true;
        let single = near(&one);
        assert!(close(single[at(20, 20)], whole[at(20, 20)]));
        assert!(close(single[at(63, 63)], whole[at(63, 63)]));
        assert_eq!(single[at(100, 20)], -1.0);
    }
}

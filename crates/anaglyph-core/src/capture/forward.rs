//! Eq. 1 on the fine grid: `p_r = ∫ s(λ) e_r(λ) dλ / row_scale_r`, in the sensing matrix's
//! normalised units (a perfect white gives at most 1 in each camera).

use crate::rig::{EffectiveResponses, SensingMatrix};
use crate::spectrum::{Interpolation, ResponseCurve};
use crate::Result;
use rayon::prelude::*;

/// Every channel of `set` linearly interpolated onto the fine grid of `responses`;
/// wavelengths beyond the set's range take its end values (measured reflectance sets stop
/// at 380/780 nm, where the cameras' response is nearly nil).
pub fn spectra_on_grid(
    set: &ResponseCurve,
    responses: &EffectiveResponses,
) -> Result<Vec<Vec<f64>>> {
    let (lo, hi) = set.domain();
    let at: Vec<f64> = responses
        .grid
        .wavelengths()
        .iter()
        .map(|w| w.clamp(lo, hi))
        .collect();
    (0..set.channel_count())
        .map(|c| set.sample(c, &at, Interpolation::Linear))
        .collect()
}

/// Noise-free measurements (`spectra.len() × rows`, row-major) of spectra on the fine grid.
pub fn measure_spectra(
    spectra: &[Vec<f64>],
    responses: &EffectiveResponses,
    sensing: &SensingMatrix,
) -> Vec<f64> {
    let rows = responses.rows.len();
    let mut p = vec![0.0; spectra.len() * rows];
    p.par_chunks_mut(rows).zip(spectra).for_each(|(out, s)| {
        responses.integrate(s, out);
        for (v, scale) in out.iter_mut().zip(&sensing.row_scale) {
            *v /= scale;
        }
    });
    p
}

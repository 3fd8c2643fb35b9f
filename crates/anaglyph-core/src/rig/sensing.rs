//! The sensing matrix C (Eqs. 2–3) and the per-channel effective responses it is built
//! from. Row `3(m−1)+k` belongs to channel k of camera m; its effective response is
//! `sensor_k(λ) · filter_m(λ) · illuminant(λ)` on a fine (≈1 nm) grid over the whole
//! support of the sensor curves.
//!
//! **Out-of-band light.** Eq. 2 taken literally (8 nm bands 446–638 nm) ignores what the
//! cameras collect outside the reconstruction range, up to a third of a channel's signal
//! for wide-band filters. We model the spectrum as a piecewise-linear function with
//! knots at the band centres (hat basis `φ_j`), so `C[r][j] = ∫ e_r(λ) φ_j(λ) dλ`, and:
//! - [`OutOfBand::Extend`] (default) continues the knots at the same step over the whole
//!   support; the extra knots are unknowns held by the same smoothness prior and only the
//!   requested bands are reported;
//! - [`OutOfBand::Clamp`] keeps only the requested knots and lets the first and last hat
//!   extend flat to the ends of the support (the spectrum is taken as constant beyond).
//!
//! **Normalisation.** Each camera's rows are divided by that camera's largest response
//! to a perfect white (`Σ_j C[r][j]`), as an exposure that just avoids clipping would
//! do; a capture normalised by its white-board reading lives in the same units.

use super::Rig;
use crate::spectrum::{trapezoid_weights, Interpolation, ResponseCurve, SpectralShape};
use crate::{Error, Result};
use serde::{Deserialize, Serialize};

/// cond(C) above which the CLI warns (wide-band filters routinely reach 1e8; with
/// λ > 0 such a C is still solvable).
pub const ILL_CONDITIONED_WARNING: f64 = 1e6;
/// Target spacing (nm) of the fine integration grid.
const FINE_STEP_NM: f64 = 1.0;

/// How light outside the reconstruction bands enters C (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum OutOfBand {
    /// Extra unknowns at the same step over the whole support (default).
    #[default]
    Extend,
    /// Edge bands absorb the tails (spectrum constant beyond the edge bands).
    Clamp,
    /// Eq. 2 literally: light outside the band edges is ignored (for comparison only).
    Ignore,
}

crate::choice::named_choices!(OutOfBand, "out-of-band model" {
    Extend = "extend" "Extra unknowns at the same step over the curves' whole support (default).",
    Clamp = "clamp" "Edge bands absorb the tails (spectrum constant beyond the edge bands).",
    Ignore = "ignore" "Eq. 2 literally: light outside the band edges is ignored (for comparison only).",
});

/// Effective responses of every camera channel on a fine grid.
#[derive(Debug, Clone)]
pub struct EffectiveResponses {
    /// The fine integration grid.
    pub grid: SpectralShape,
    /// Trapezoid weights on `grid`, nm.
    pub weights: Vec<f64>,
    /// `rows[r][t]`: response of channel r at `grid.wavelength(t)`.
    pub rows: Vec<Vec<f64>>,
    /// "<camera>:{channel}" per row ("<camera>" for a monochrome camera).
    pub labels: Vec<String>,
    /// Camera index (in rig order) of each row.
    pub camera_of_row: Vec<usize>,
}

/// Spectra need every camera's filter: an error naming the first camera of `rig` without
/// one (a registration-only run needs none).
pub fn check_filters(rig: &Rig) -> Result<()> {
    match rig.cameras.iter().find(|c| c.filter.is_none()) {
        Some(c) => Err(Error::curve(
            format!("camera {}", c.name),
            format!("no filter in rig '{}'", rig.file.name),
            "its `filter` (a curve, gaussian:CENTRE:FWHM or builtin:<name>): spectra need \
             every camera's; a registration-only run (--output registered) needs none",
        )),
        None => Ok(()),
    }
}

impl EffectiveResponses {
    /// Sensor × filter × illuminant for every camera channel of `rig`; an error naming
    /// the first camera whose filter the rig does not give ([`check_filters`]).
    pub fn of_rig(rig: &Rig) -> Result<Self> {
        check_filters(rig)?;
        let cameras: Vec<(&ResponseCurve, &ResponseCurve, String)> = rig
            .cameras
            .iter()
            .filter_map(|c| Some((&c.sensor, c.filter.as_ref()?, c.name.clone())))
            .collect();
        Self::of_cameras(
            &cameras,
            rig.illuminant.as_ref(),
            rig.file.sensor_interpolation,
        )
    }

    /// Effective responses of cameras given as `(sensor, filter, label)`. The support is
    /// the range every sensor curve covers; filters and illuminant must cover it.
    pub fn of_cameras(
        cameras: &[(&ResponseCurve, &ResponseCurve, String)],
        illuminant: Option<&ResponseCurve>,
        sensor_interpolation: Interpolation,
    ) -> Result<Self> {
        let mut lo = f64::NEG_INFINITY;
        let mut hi = f64::INFINITY;
        for (sensor, _, _) in cameras {
            let (a, b) = sensor.domain();
            lo = lo.max(a);
            hi = hi.min(b);
        }
        if cameras.is_empty() || !(hi > lo) {
            return Err(Error::curve(
                "rig",
                "sensor curves without a common wavelength range",
                "sensors whose curves overlap",
            ));
        }
        let count = ((hi - lo) / FINE_STEP_NM).round().max(1.0) as usize + 1;
        let grid = SpectralShape::new(lo, (hi - lo) / (count - 1) as f64, count)?;
        let at = grid.wavelengths();
        let light = match illuminant {
            Some(light) => light.sample(0, &at, Interpolation::Linear)?,
            None => vec![1.0; at.len()],
        };
        let mut rows = Vec::new();
        let mut labels = Vec::new();
        let mut camera_of_row = Vec::new();
        for (m, (sensor, filter, label)) in cameras.iter().enumerate() {
            let transmission = filter.sample(0, &at, Interpolation::Linear)?;
            for k in 0..sensor.channel_count() {
                let sensitivity = sensor.sample(k, &at, sensor_interpolation)?;
                rows.push(
                    sensitivity
                        .iter()
                        .zip(&transmission)
                        .zip(&light)
                        .map(|((s, f), l)| (s * f * l).max(0.0))
                        .collect(),
                );
                labels.push(match sensor.channel_count() {
                    1 => label.to_string(),
                    _ => format!("{label}:{}", sensor.channel_names()[k]),
                });
                camera_of_row.push(m);
            }
        }
        Ok(EffectiveResponses {
            weights: trapezoid_weights(&grid),
            grid,
            rows,
            labels,
            camera_of_row,
        })
    }

    /// Eq. 1 on the fine grid: the raw (unnormalised) measurement of each row for a
    /// spectrum given at the grid's wavelengths.
    pub fn integrate(&self, spectrum_on_grid: &[f64], out: &mut [f64]) {
        for (o, row) in out.iter_mut().zip(&self.rows) {
            *o = row
                .iter()
                .zip(&self.weights)
                .zip(spectrum_on_grid)
                .map(|((e, w), s)| e * w * s)
                .sum();
        }
    }
}

/// The matrix C with its wavelength grids and normalisation.
#[derive(Debug, Clone)]
pub struct SensingMatrix {
    /// Row-major `rows × unknowns.count`.
    values: Vec<f64>,
    rows: usize,
    /// Knots of the spectrum the solver estimates (the reported bands, possibly extended).
    pub unknowns: SpectralShape,
    /// The reconstruction bands the user asked for.
    pub reported: SpectralShape,
    /// Index of the first reported band within `unknowns`.
    pub reported_offset: usize,
    /// Divide a raw fine-grid integral of row r by `row_scale[r]` to get C's units.
    pub row_scale: Vec<f64>,
    pub row_labels: Vec<String>,
    pub out_of_band: OutOfBand,
}

impl SensingMatrix {
    /// A user-supplied matrix (e.g. from `.npy`): no extension, no normalisation.
    pub fn from_dense(rows: usize, reported: SpectralShape, values: Vec<f64>) -> Result<Self> {
        if values.len() != rows * reported.count || rows == 0 {
            return Err(Error::Shape {
                op: "sensing matrix".into(),
                got: vec![values.len()],
                expected: vec![rows, reported.count],
            });
        }
        if let Some(v) = values.iter().find(|v| !v.is_finite()) {
            return Err(Error::NonFinite {
                what: "a value of the sensing matrix".into(),
                value: *v,
            });
        }
        Ok(SensingMatrix {
            values,
            rows,
            unknowns: reported,
            reported,
            reported_offset: 0,
            row_scale: vec![1.0; rows],
            row_labels: (0..rows).map(|r| format!("row {r}")).collect(),
            out_of_band: OutOfBand::Clamp,
        })
    }

    /// C for `responses` on the reconstruction bands `reported`.
    pub fn from_responses(
        responses: &EffectiveResponses,
        reported: SpectralShape,
        mode: OutOfBand,
    ) -> Result<Self> {
        reported.validate()?;
        let (lo, hi) = (responses.grid.start, responses.grid.end());
        if reported.start < lo - 1e-9 || reported.end() > hi + 1e-9 {
            return Err(Error::CurveNotCovering {
                name: "sensor support".into(),
                have_start: lo,
                have_end: hi,
                need_start: reported.start,
                need_end: reported.end(),
            });
        }
        let (below, above) = match mode {
            OutOfBand::Extend => (
                ((reported.start - lo) / reported.step - 1e-9)
                    .ceil()
                    .max(0.0) as usize,
                ((hi - reported.end()) / reported.step - 1e-9)
                    .ceil()
                    .max(0.0) as usize,
            ),
            OutOfBand::Clamp | OutOfBand::Ignore => (0, 0),
        };
        let unknowns = SpectralShape::new(
            reported.start - below as f64 * reported.step,
            reported.step,
            reported.count + below + above,
        )?;
        let n = unknowns.count;
        let half = 0.5 * reported.step;
        // Basis value of knot j at wavelength t.
        let basis = |j: usize, t: f64| -> f64 {
            let c = unknowns.wavelength(j);
            match mode {
                OutOfBand::Clamp if j == 0 && t <= c => 1.0,
                OutOfBand::Clamp if j == n - 1 && t >= c => 1.0,
                OutOfBand::Ignore if t < reported.start - half || t > reported.end() + half => 0.0,
                _ => (1.0 - (t - c).abs() / unknowns.step).max(0.0),
            }
        };
        let rows = responses.rows.len();
        let mut values = vec![0.0; rows * n];
        for (t_idx, t) in responses.grid.wavelengths().into_iter().enumerate() {
            let first =
                (((t - unknowns.start) / unknowns.step).floor().max(0.0) as usize).min(n - 1);
            for j in first.saturating_sub(1)..(first + 2).min(n) {
                let phi = basis(j, t);
                if phi == 0.0 {
                    continue;
                }
                for r in 0..rows {
                    values[r * n + j] += responses.weights[t_idx] * responses.rows[r][t_idx] * phi;
                }
            }
        }
        // Per-camera exposure normalisation: each camera's brightest white response is 1.
        let cameras = responses
            .camera_of_row
            .iter()
            .copied()
            .max()
            .map_or(0, |m| m + 1);
        let mut camera_peak = vec![0.0f64; cameras];
        for r in 0..rows {
            let white: f64 = values[r * n..(r + 1) * n].iter().sum();
            let m = responses.camera_of_row[r];
            camera_peak[m] = camera_peak[m].max(white);
        }
        let mut row_scale = vec![1.0; rows];
        for r in 0..rows {
            let peak = camera_peak[responses.camera_of_row[r]];
            if peak <= 0.0 {
                return Err(Error::unusable(
                    format!("the camera of row '{}'", responses.labels[r]),
                    "it sees no light at all (sensor × filter × illuminant is zero)",
                ));
            }
            row_scale[r] = peak;
            for v in &mut values[r * n..(r + 1) * n] {
                *v /= peak;
            }
        }
        Ok(SensingMatrix {
            values,
            rows,
            unknowns,
            reported,
            reported_offset: below,
            row_scale,
            row_labels: responses.labels.clone(),
            out_of_band: mode,
        })
    }

    /// C of a rig with its own reconstruction settings.
    pub fn of_rig(rig: &Rig) -> Result<Self> {
        Self::with_rig_settings(&EffectiveResponses::of_rig(rig)?, rig)
    }

    /// C of `responses` with `rig`'s reconstruction shape and out-of-band mode.
    fn with_rig_settings(responses: &EffectiveResponses, rig: &Rig) -> Result<Self> {
        Self::from_responses(
            responses,
            rig.reconstruction_shape()?,
            rig.file.reconstruction.out_of_band,
        )
    }

    /// C of a rig for a registration-only run, and the cameras whose filter curves it set
    /// aside. A camera without a filter, or whose filter lets none of its sensor's light
    /// through (sensor × filter × illuminant is zero, which spectra refuse), counts as
    /// unfiltered (transmission 1 over its sensor's range). Such a run uses C only to shape
    /// the common signals multi-channel cameras are matched by.
    pub fn for_registration(rig: &Rig) -> Result<(Self, Vec<String>)> {
        let clear: Vec<ResponseCurve> = rig
            .cameras
            .iter()
            .map(|c| {
                let (lo, hi) = c.sensor.domain();
                ResponseCurve::new(
                    "none given (unfiltered)",
                    vec![lo, hi],
                    vec!["transmission".into()],
                    vec![vec![1.0, 1.0]],
                )
            })
            .collect::<Result<_>>()?;
        // The responses with each camera's filter, or the clear one where `unfiltered`.
        let responses = |unfiltered: &[bool]| {
            let cameras: Vec<(&ResponseCurve, &ResponseCurve, String)> = rig
                .cameras
                .iter()
                .zip(&clear)
                .zip(unfiltered)
                .map(|((c, clear), &u)| {
                    let filter = if u {
                        clear
                    } else {
                        c.filter.as_ref().unwrap_or(clear)
                    };
                    (&c.sensor, filter, c.name.clone())
                })
                .collect();
            EffectiveResponses::of_cameras(
                &cameras,
                rig.illuminant.as_ref(),
                rig.file.sensor_interpolation,
            )
        };
        let missing: Vec<bool> = rig.cameras.iter().map(|c| c.filter.is_none()).collect();
        let first = responses(&missing)?;
        let unlit: Vec<bool> = (0..rig.cameras.len())
            .map(|m| {
                !first
                    .rows
                    .iter()
                    .zip(&first.camera_of_row)
                    .any(|(row, &c)| c == m && row.iter().any(|&v| v > 0.0))
            })
            .collect();
        let set_aside: Vec<String> = rig
            .cameras
            .iter()
            .zip(&unlit)
            .filter(|(c, &dark)| dark && c.filter.is_some())
            .map(|(c, _)| c.name.clone())
            .collect();
        let responses = if set_aside.is_empty() {
            first
        } else {
            let unfiltered: Vec<bool> = missing.iter().zip(&unlit).map(|(a, b)| *a || *b).collect();
            responses(&unfiltered)?
        };
        Ok((Self::with_rig_settings(&responses, rig)?, set_aside))
    }

    pub fn rows(&self) -> usize {
        self.rows
    }

    /// Number of unknowns (knots) per pixel.
    pub fn cols(&self) -> usize {
        self.unknowns.count
    }

    /// Row-major values.
    pub fn values(&self) -> &[f64] {
        &self.values
    }

    /// Row `r`.
    pub fn row(&self, r: usize) -> &[f64] {
        &self.values[r * self.cols()..(r + 1) * self.cols()]
    }

    /// `C · s` for a spectrum on the unknown knots.
    pub fn apply(&self, s: &[f64], out: &mut [f64]) {
        for (r, o) in out.iter_mut().enumerate() {
            *o = self.row(r).iter().zip(s).map(|(c, s)| c * s).sum();
        }
    }

    /// Singular values of C, largest first.
    pub fn singular_values(&self) -> Result<Vec<f64>> {
        let m = faer::MatRef::from_row_major_slice(&self.values, self.rows, self.cols());
        m.singular_values().map_err(|e| Error::LinearAlgebra {
            op: "singular values of C".into(),
            message: format!("{e:?}"),
        })
    }

    /// cond(C) = σ_max / σ_min over its min(rows, cols) singular values (∞ if rank-deficient).
    pub fn condition_number(&self) -> Result<f64> {
        Ok(condition_from_singular_values(&self.singular_values()?))
    }

    /// For each row, the fraction of its response to a flat spectrum that lies inside
    /// the reconstruction range `[first band − step/2, last band + step/2]`.
    pub fn in_band_fraction(responses: &EffectiveResponses, reported: &SpectralShape) -> Vec<f64> {
        let lo = reported.start - 0.5 * reported.step;
        let hi = reported.end() + 0.5 * reported.step;
        responses
            .rows
            .iter()
            .map(|row| {
                let (mut inside, mut total) = (0.0, 0.0);
                for (t, (e, w)) in row.iter().zip(&responses.weights).enumerate() {
                    let l = responses.grid.wavelength(t);
                    total += e * w;
                    if l >= lo && l <= hi {
                        inside += e * w;
                    }
                }
                if total > 0.0 {
                    inside / total
                } else {
                    1.0
                }
            })
            .collect()
    }
}

/// σ_max / σ_min, or ∞ when σ_min is zero.
pub fn condition_from_singular_values(sv: &[f64]) -> f64 {
    match (sv.first(), sv.last()) {
        (Some(&max), Some(&min)) if min > 0.0 => max / min,
        _ => f64::INFINITY,
    }
}

//! Spectral sampling and response curves: the first stage of the pipeline.
//!
//! Everything spectral in anaglyph (sensor sensitivities, filter transmissions,
//! illuminants, reflectances) enters as a [`ResponseCurve`] loaded from the CSV layout
//! `wavelength_nm,<channel>,...`, is resampled ([`Interpolation::Linear`] or
//! [`Interpolation::CubicSpline`], the paper's choice for camera curves) onto a
//! [`SpectralShape`], and is integrated over bands. A curve asked for a wavelength it
//! does not cover is an error, never a silent zero.

mod curve;
mod integrate;
mod resample;
mod shape;

pub use curve::{ResponseCurve, MAX_CSV_BYTES, MAX_CURVE_CHANNELS};
pub use integrate::{integrate_linear, trapezoid_weights};
pub use resample::{cubic_spline, linear, Interpolation};
pub use shape::SpectralShape;

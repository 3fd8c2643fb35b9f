//! Filter calibration (paper section 3.2): a spectrometer reads a target without the
//! filter (`s0`) and through it (`s1`); the transmission is `s1 / s0`. With several
//! columns (e.g. the 24 chart patches the paper measured) the per-wavelength estimate is
//! the least-squares ratio `Σ s1·s0 / Σ s0²`, which weights bright patches most.
//!
//! Eq. 7 bounds the relative error of the ratio by `|Δs1/s1| + |Δs0/s0|`, i.e. by `2E`
//! when the spectrometer's relative error is at most `E`.

use crate::spectrum::{Interpolation, ResponseCurve};
use crate::{Error, Result};

/// Below this fraction of its peak, `s0` is too dark for a trustworthy ratio.
const DARK_REFERENCE_FRACTION: f64 = 0.01;

/// The result of [`calibrate_filter`].
#[derive(Debug, Clone)]
pub struct FilterCalibration {
    /// Estimated transmission on the wavelengths of `s0` covered by `s1`.
    pub transmission: ResponseCurve,
    /// Eq. 7 relative error bound, `2E`.
    pub relative_bound: f64,
    /// Largest absolute error bound over wavelengths, `2E · max t`.
    pub max_absolute_bound: f64,
    /// Wavelengths where `s0` is under 1 % of its peak (ratio unreliable).
    pub dark_wavelengths: Vec<f64>,
    /// Samples where the ratio was negative and was set to zero.
    pub clamped_negative: usize,
    /// Samples above 1 (noise or a fluorescent filter).
    pub above_one: usize,
}

/// Computes `s1 / s0` and the Eq. 7 bound for spectrometer relative error `relative_error`.
pub fn calibrate_filter(
    without: &ResponseCurve,
    with: &ResponseCurve,
    relative_error: f64,
) -> Result<FilterCalibration> {
    if !(relative_error.is_finite() && (0.0..1.0).contains(&relative_error)) {
        return Err(Error::out_of_range(
            "filter calibration relative error",
            relative_error,
            "0 <= E < 1",
        ));
    }
    if without.channel_count() != with.channel_count() {
        return Err(Error::curve(
            "filter calibration",
            format!(
                "'{}' has {} columns but '{}' has {}",
                without.name(),
                without.channel_count(),
                with.name(),
                with.channel_count()
            ),
            "the same targets in both readings",
        ));
    }
    let (a, b) = with.domain();
    let wavelengths: Vec<f64> = without
        .wavelengths()
        .iter()
        .copied()
        .filter(|&w| w >= a && w <= b)
        .collect();
    if wavelengths.len() < 2 {
        return Err(Error::CurveNotCovering {
            name: with.name().into(),
            have_start: a,
            have_end: b,
            need_start: without.domain().0,
            need_end: without.domain().1,
        });
    }
    let s0: Vec<Vec<f64>> = (0..without.channel_count())
        .map(|c| without.sample(c, &wavelengths, Interpolation::Linear))
        .collect::<Result<_>>()?;
    let s1: Vec<Vec<f64>> = (0..with.channel_count())
        .map(|c| with.sample(c, &wavelengths, Interpolation::Linear))
        .collect::<Result<_>>()?;
    let energy: Vec<f64> = (0..wavelengths.len())
        .map(|i| s0.iter().map(|col| col[i] * col[i]).sum::<f64>())
        .collect();
    let peak = energy.iter().cloned().fold(0.0, f64::max);
    if peak <= 0.0 {
        return Err(Error::unusable(
            format!("reference reading '{}'", without.name()),
            "it is zero everywhere",
        ));
    }
    let mut dark = Vec::new();
    let (mut clamped, mut above) = (0, 0);
    let mut t = Vec::with_capacity(wavelengths.len());
    for (i, &w) in wavelengths.iter().enumerate() {
        if energy[i].sqrt() < DARK_REFERENCE_FRACTION * peak.sqrt() {
            dark.push(w);
        }
        let cross: f64 = s0.iter().zip(&s1).map(|(a, b)| a[i] * b[i]).sum();
        let mut ratio = if energy[i] > 0.0 {
            cross / energy[i]
        } else {
            0.0
        };
        if ratio < 0.0 {
            ratio = 0.0;
            clamped += 1;
        }
        if ratio > 1.0 {
            above += 1;
        }
        t.push(ratio);
    }
    let max_t = t.iter().cloned().fold(0.0, f64::max);
    if !(max_t > 0.0) {
        return Err(Error::unusable(
            format!("filter reading '{}'", with.name()),
            format!(
                "the transmission it gives is zero at all {} wavelengths ({clamped} ratios to \
                 the reference negative; expected a positive transmission somewhere): readings \
                 of opposite sign, or a dark reading in place of the filter's?",
                t.len()
            ),
        ));
    }
    let transmission = ResponseCurve::new(
        with.name(),
        wavelengths,
        vec!["transmission".into()],
        vec![t],
    )?;
    Ok(FilterCalibration {
        transmission,
        relative_bound: 2.0 * relative_error,
        max_absolute_bound: 2.0 * relative_error * max_t,
        dark_wavelengths: dark,
        clamped_negative: clamped,
        above_one: above,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::builtin;

    #[test]
    fn recovers_a_known_filter_from_chart_readings() {
        // s0: the 24 ColorChecker patches under CIE A; s1: the same through a gel.
        let chart = builtin::reflectances("colorchecker_n_ohta").unwrap();
        let light = builtin::illuminant("cie_a").unwrap();
        let gel = builtin::filter("gel_magenta").unwrap();
        let w = chart.wavelengths().to_vec();
        let a = light.sample(0, &w, Interpolation::Linear).unwrap();
        let t = gel.sample(0, &w, Interpolation::Linear).unwrap();
        let names: Vec<String> = chart.channel_names().to_vec();
        let s0: Vec<Vec<f64>> = (0..24)
            .map(|c| {
                chart
                    .channel(c)
                    .iter()
                    .zip(&a)
                    .map(|(r, l)| r * l)
                    .collect()
            })
            .collect();
        let s1: Vec<Vec<f64>> = s0
            .iter()
            .map(|col| col.iter().zip(&t).map(|(v, t)| v * t).collect())
            .collect();
        let without = ResponseCurve::new("s0", w.clone(), names.clone(), s0).unwrap();
        let with = ResponseCurve::new("s1", w.clone(), names, s1).unwrap();
        let cal = calibrate_filter(&without, &with, 0.02).unwrap();
        for (got, want) in cal.transmission.channel(0).iter().zip(&t) {
            assert!((got - want).abs() < 1e-12);
        }
        assert_eq!(cal.relative_bound, 0.04);
        // CIE A is dim in the near UV: only the blue end may be flagged as dark.
        assert!(
            cal.dark_wavelengths.iter().all(|&w| w < 400.0),
            "{:?}",
            cal.dark_wavelengths
        );
    }

    #[test]
    fn eq7_bound_holds_for_perturbed_readings() {
        // Worst-case perturbations of ±E on both readings stay within 2E (first order).
        let e = 0.01;
        let w = vec![400.0, 500.0, 600.0];
        let s0 = ResponseCurve::new("s0", w.clone(), vec!["a".into()], vec![vec![1.0, 2.0, 3.0]])
            .unwrap();
        let s1 = ResponseCurve::new("s1", w.clone(), vec!["a".into()], vec![vec![0.5, 0.2, 2.7]])
            .unwrap();
        let exact = calibrate_filter(&s0, &s1, e).unwrap();
        let s1p = ResponseCurve::new(
            "s1",
            w.clone(),
            vec!["a".into()],
            vec![vec![0.505, 0.202, 2.727]],
        )
        .unwrap();
        let s0m =
            ResponseCurve::new("s0", w, vec!["a".into()], vec![vec![0.99, 1.98, 2.97]]).unwrap();
        let worst = calibrate_filter(&s0m, &s1p, e).unwrap();
        for (a, b) in exact
            .transmission
            .channel(0)
            .iter()
            .zip(worst.transmission.channel(0))
        {
            let rel = (b - a).abs() / a;
            // Eq. 7 is first order; the exact worst case is (1 + E)/(1 − E) − 1 = 2E/(1 − E).
            assert!(rel <= exact.relative_bound / (1.0 - e) + 1e-12, "{rel}");
            assert!(
                rel > 0.019,
                "perturbation should nearly reach the bound: {rel}"
            );
        }
    }

    #[test]
    fn mismatched_inputs_are_errors() {
        let a = ResponseCurve::from_csv_str("a", "wavelength_nm,x\n400,1\n500,1\n").unwrap();
        let b = ResponseCurve::from_csv_str("b", "wavelength_nm,x,y\n400,1,1\n500,1,1\n").unwrap();
        assert_eq!(
            calibrate_filter(&a, &b, 0.01).err().map(|e| e.kind()),
            Some("Curve")
        );
        assert_eq!(
            calibrate_filter(&a, &a, 1.5).err().map(|e| e.kind()),
            Some("OutOfRange")
        );
        let far = ResponseCurve::from_csv_str("c", "wavelength_nm,x\n600,1\n700,1\n").unwrap();
        assert_eq!(
            calibrate_filter(&a, &far, 0.01).err().map(|e| e.kind()),
            Some("CurveNotCovering")
        );
        let negative =
            ResponseCurve::from_csv_str("n", "wavelength_nm,x\n400,-1\n500,-2\n").unwrap();
        let refused = calibrate_filter(&a, &negative, 0.01).err();
        let message = refused.as_ref().map(|e| e.to_string()).unwrap_or_default();
        assert_eq!(refused.map(|e| e.kind()), Some("Unusable"));
        assert!(
            message.contains("zero at all 2 wavelengths (2 ratios"),
            "{message}"
        );
    }
}

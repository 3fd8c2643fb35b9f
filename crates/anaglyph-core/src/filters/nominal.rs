//! Narrow-band filters known only by their datasheet: `gaussian:CENTRE_NM:FWHM_NM` (and
//! an optional `:PEAK`, the transmission at the centre, 1 by default), the usual
//! description of the interference filters of monochrome multispectral arrays when no
//! measured curve is at hand.
//!
//! In: the text after `gaussian:`. Out: a one-column transmission curve sampled every
//! nanometre over 200–1200 nm, or an error naming the field and its expected range.

use crate::spectrum::ResponseCurve;
use crate::{Error, Result};

/// The prefix of a nominal filter reference in a rig file.
pub const GAUSSIAN_PREFIX: &str = "gaussian:";
/// The wavelengths a nominal curve covers, nm (every sensor curve lies inside).
pub const NOMINAL_RANGE_NM: (f64, f64) = (200.0, 1200.0);

/// The centre (nm) of a nominal filter reference `gaussian:CENTRE_NM:…`; None for any
/// other reference.
pub fn nominal_centre(reference: &str) -> Option<f64> {
    let spec = reference.strip_prefix(GAUSSIAN_PREFIX)?;
    spec.split(':').next()?.trim().parse().ok()
}

/// The Gaussian transmission `peak · exp(−4 ln 2 (λ − centre)² / fwhm²)` described by
/// `spec` = `CENTRE:FWHM[:PEAK]` (nm, nm, fraction).
pub fn gaussian_filter(spec: &str) -> Result<ResponseCurve> {
    let reference = format!("{GAUSSIAN_PREFIX}{spec}");
    let fields: Vec<&str> = spec.split(':').collect();
    if !(2..=3).contains(&fields.len()) {
        return Err(Error::curve(
            format!("filter '{reference}'"),
            format!("{} fields", fields.len()),
            "gaussian:CENTRE_NM:FWHM_NM or gaussian:CENTRE_NM:FWHM_NM:PEAK",
        ));
    }
    let number = |i: usize, what: &str| -> Result<f64> {
        fields[i].trim().parse::<f64>().map_err(|_| {
            Error::curve(
                format!("filter '{reference}' {what}"),
                format!("'{}'", fields[i]),
                "a number",
            )
        })
    };
    let (low, high) = NOMINAL_RANGE_NM;
    let centre = number(0, "centre")?;
    let fwhm = number(1, "FWHM")?;
    let peak = if fields.len() == 3 {
        number(2, "peak")?
    } else {
        1.0
    };
    if !(centre >= low + 50.0 && centre <= high - 50.0) {
        return Err(Error::out_of_range(
            format!("filter '{reference}' centre (nm)"),
            centre,
            format!("{} to {}", low + 50.0, high - 50.0),
        ));
    }
    if !(1.0..=300.0).contains(&fwhm) {
        return Err(Error::out_of_range(
            format!("filter '{reference}' FWHM (nm)"),
            fwhm,
            "1 to 300",
        ));
    }
    if !(peak > 0.0 && peak <= 1.0) {
        return Err(Error::out_of_range(
            format!("filter '{reference}' peak"),
            peak,
            "in (0, 1]",
        ));
    }
    let wavelengths: Vec<f64> = (0..=(high - low) as usize)
        .map(|i| low + i as f64)
        .collect();
    let spread = 4.0 * std::f64::consts::LN_2 / (fwhm * fwhm);
    let transmission = wavelengths
        .iter()
        .map(|w| peak * (-spread * (w - centre).powi(2)).exp())
        .collect();
    ResponseCurve::new(
        reference,
        wavelengths,
        vec!["transmission".into()],
        vec![transmission],
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_curve_has_its_centre_fwhm_and_peak() {
        let curve = gaussian_filter("550:40:0.8").unwrap();
        let t = curve.channel(0);
        let at = |nm: f64| t[(nm - NOMINAL_RANGE_NM.0) as usize];
        assert!((at(550.0) - 0.8).abs() < 1e-12);
        assert!((at(530.0) - 0.4).abs() < 1e-12 && (at(570.0) - 0.4).abs() < 1e-12);
        assert!(at(450.0) < 1e-7 && at(450.0) > 0.0);
        assert_eq!(curve.name(), "gaussian:550:40:0.8");
    }

    #[test]
    fn fields_out_of_range_are_named() {
        for (spec, kind, words) in [
            ("550", "Curve", "1 fields"),
            ("550:forty", "Curve", "FWHM"),
            ("100:40", "OutOfRange", "centre"),
            ("550:0", "OutOfRange", "FWHM"),
            ("550:40:1.5", "OutOfRange", "peak"),
            ("550:nan", "OutOfRange", "FWHM"),
        ] {
            let refused = gaussian_filter(spec).err();
            let message = refused.as_ref().map(|e| e.to_string()).unwrap_or_default();
            assert_eq!(refused.map(|e| e.kind()), Some(kind), "{spec}");
            assert!(message.contains(words), "{spec}: {message}");
        }
    }
}

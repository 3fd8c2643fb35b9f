//! A parametric model of wide-band gel filters, and the library of 20 modelled curves
//! shipped in `data/filters/`. No measured gel data is available to us, so these are
//! **modelled, not measured**: smooth logistic edges, peak transmission below 1, a
//! non-zero floor, shapes after common theatre-gel colours (long-pass, short-pass,
//! band-pass, band-stop and two-band mixtures). Users replace them with their own
//! measured CSVs in the same layout.

use crate::spectrum::{ResponseCurve, SpectralShape};
use crate::Result;

/// Sampling of the shipped filter CSVs: 380–780 nm every 5 nm, as the vendored data.
pub const GEL_LIBRARY_SHAPE: SpectralShape = SpectralShape {
    start: 380.0,
    step: 5.0,
    count: 81,
};

/// Transmission shape before scaling to `[floor, peak]`; edges in nm, widths in nm
/// (the 10–90 % rise of a logistic edge is 4.4 widths).
#[derive(Debug, Clone, Copy)]
pub enum GelShape {
    /// Passes above `edge`.
    LongPass { edge: f64, width: f64 },
    /// Passes below `edge`.
    ShortPass { edge: f64, width: f64 },
    /// Passes between `low` and `high`.
    BandPass { low: f64, high: f64, width: f64 },
    /// Blocks between `low` and `high` down to `1 - depth` of the peak.
    BandStop {
        low: f64,
        high: f64,
        width: f64,
        depth: f64,
    },
    /// Passes below `blue_edge` and above `red_edge` (magenta/violet gels).
    TwoBand {
        blue_edge: f64,
        red_edge: f64,
        width: f64,
        blue_gain: f64,
    },
}

/// One modelled filter.
#[derive(Debug, Clone, Copy)]
pub struct GelFilter {
    pub name: &'static str,
    pub shape: GelShape,
    /// Highest transmission (gels lose 5–15 % to surface reflections and absorption).
    pub peak: f64,
    /// Transmission in the blocked region (gels leak a few per cent).
    pub floor: f64,
}

fn logistic(x: f64) -> f64 {
    1.0 / (1.0 + (-x).exp())
}

impl GelFilter {
    /// Transmission at `nm`.
    pub fn transmission(&self, nm: f64) -> f64 {
        let rise = |edge: f64, width: f64| logistic((nm - edge) / width);
        let unit = match self.shape {
            GelShape::LongPass { edge, width } => rise(edge, width),
            GelShape::ShortPass { edge, width } => 1.0 - rise(edge, width),
            GelShape::BandPass { low, high, width } => rise(low, width) * (1.0 - rise(high, width)),
            GelShape::BandStop {
                low,
                high,
                width,
                depth,
            } => 1.0 - depth * rise(low, width) * (1.0 - rise(high, width)),
            GelShape::TwoBand {
                blue_edge,
                red_edge,
                width,
                blue_gain,
            } => (blue_gain * (1.0 - rise(blue_edge, width)) + rise(red_edge, width)).min(1.0),
        };
        self.floor + (self.peak - self.floor) * unit
    }

    /// The curve on [`GEL_LIBRARY_SHAPE`], rounded to 6 decimals as written to CSV.
    pub fn curve(&self) -> Result<ResponseCurve> {
        let values = GEL_LIBRARY_SHAPE
            .wavelengths()
            .iter()
            .map(|&nm| (self.transmission(nm) * 1e6).round() / 1e6)
            .collect();
        ResponseCurve::from_shape(
            self.name,
            &GEL_LIBRARY_SHAPE,
            "modelled transmission",
            values,
        )
    }
}

/// The modelled gels as (name, shape, peak transmission, floor), in hue order from yellow
/// through red, magenta and blue to green (the model: data/filters/README.md).
#[rustfmt::skip]
const GELS: [(&str, GelShape, f64, f64); 20] = {
    use GelShape::*;
    [
        ("gel_straw", LongPass { edge: 470.0, width: 14.0 }, 0.90, 0.30),
        ("gel_yellow", LongPass { edge: 500.0, width: 8.0 }, 0.90, 0.03),
        ("gel_deep_yellow", LongPass { edge: 525.0, width: 7.0 }, 0.88, 0.02),
        ("gel_amber", LongPass { edge: 550.0, width: 12.0 }, 0.86, 0.08),
        ("gel_orange", LongPass { edge: 570.0, width: 8.0 }, 0.86, 0.03),
        ("gel_red", LongPass { edge: 600.0, width: 7.0 }, 0.85, 0.02),
        ("gel_deep_red", LongPass { edge: 630.0, width: 7.0 }, 0.83, 0.02),
        ("gel_salmon", BandStop { low: 440.0, high: 570.0, width: 12.0, depth: 0.65 }, 0.88, 0.05),
        ("gel_pink", BandStop { low: 480.0, high: 570.0, width: 10.0, depth: 0.55 }, 0.90, 0.05),
        ("gel_magenta", BandStop { low: 490.0, high: 595.0, width: 9.0, depth: 0.95 }, 0.85, 0.03),
        ("gel_lavender", BandStop { low: 520.0, high: 620.0, width: 14.0, depth: 0.45 }, 0.88, 0.05),
        ("gel_violet", TwoBand { blue_edge: 465.0, red_edge: 640.0, width: 9.0, blue_gain: 0.9 }, 0.80, 0.02),
        ("gel_deep_blue", BandPass { low: 420.0, high: 490.0, width: 8.0 }, 0.75, 0.02),
        ("gel_blue", ShortPass { edge: 510.0, width: 9.0 }, 0.80, 0.03),
        ("gel_light_blue", ShortPass { edge: 560.0, width: 16.0 }, 0.85, 0.20),
        ("gel_cyan", ShortPass { edge: 585.0, width: 9.0 }, 0.82, 0.03),
        ("gel_teal", BandPass { low: 460.0, high: 545.0, width: 9.0 }, 0.78, 0.03),
        ("gel_green", BandPass { low: 490.0, high: 580.0, width: 9.0 }, 0.80, 0.02),
        ("gel_yellow_green", BandPass { low: 510.0, high: 610.0, width: 10.0 }, 0.84, 0.04),
        ("gel_emerald", BandPass { low: 475.0, high: 555.0, width: 6.0 }, 0.72, 0.02),
    ]
};

/// The 20 modelled gels, in hue order from yellow through red, magenta and blue to green.
pub fn gel_library() -> Vec<GelFilter> {
    GELS.iter()
        .map(|&(name, shape, peak, floor)| GelFilter {
            name,
            shape,
            peak,
            floor,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;

    fn filters_dir() -> PathBuf {
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../data/filters")
    }

    /// The shipped CSVs are this model's output. Regenerate with
    /// `REGENERATE=1 cargo test -p anaglyph-core shipped_filter`.
    #[test]
    fn shipped_filter_files_match_the_model() {
        let regenerate = std::env::var_os("REGENERATE").is_some();
        for gel in gel_library() {
            let curve = gel.curve().unwrap();
            let path = filters_dir().join(format!("{}.csv", gel.name));
            if regenerate {
                curve.save_csv(&path).unwrap();
            }
            let shipped = ResponseCurve::load_csv(&path).unwrap();
            assert_eq!(shipped.channel(0), curve.channel(0), "{}", gel.name);
        }
        assert_eq!(gel_library().len(), crate::builtin::FILTERS.len());
    }

    #[test]
    fn gels_are_physically_plausible() {
        for gel in gel_library() {
            let c = gel.curve().unwrap();
            let v = c.channel(0);
            let max = v.iter().cloned().fold(0.0, f64::max);
            let min = v.iter().cloned().fold(1.0, f64::min);
            assert!(max < 0.95 && max > 0.5, "{} peak {max}", gel.name);
            assert!(
                gel.floor > 0.0 && min >= gel.floor - 1e-6,
                "{} floor {min}",
                gel.name
            );
            assert!(
                max - min > 0.3,
                "{} is not wide-band coloured: {min}..{max}",
                gel.name
            );
            // Smooth edges: no jump above 0.25 between 5 nm samples.
            assert!(
                v.windows(2).all(|w| (w[1] - w[0]).abs() < 0.25),
                "{}",
                gel.name
            );
        }
    }
}

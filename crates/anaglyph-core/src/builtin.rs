//! Spectral data compiled into the library, so that the CLI and the demo run from any
//! directory: the files vendored under `data/` (sources, citations and licences in
//! `data/README.md` and `data/spectra/SOURCES.md`) and the modelled gel-filter library
//! of `data/filters/`. A rig refers to them as `builtin:<name>`.

use crate::spectrum::ResponseCurve;
use crate::{Error, Result};

macro_rules! embedded {
    ($($name:literal => $path:literal),* $(,)?) => {
        &[$(($name, include_str!(concat!("../../../data/", $path)))),*]
    };
}

/// Camera sensitivities (columns r, g, b).
pub const SENSORS: &[(&str, &str)] = embedded! {
    "canon_eos_5d_mark_ii" => "spectra/sensors/canon_eos_5d_mark_ii.csv",
    "nikon_5100" => "spectra/sensors/nikon_5100.csv",
    "sigma_sdmerill" => "spectra/sensors/sigma_sdmerill.csv",
};

/// Illuminant relative spectral power distributions.
pub const ILLUMINANTS: &[(&str, &str)] = embedded! {
    "cie_a" => "spectra/illuminants/cie_a.csv",
    "cie_d65" => "spectra/illuminants/cie_d65.csv",
    "cie_f2" => "spectra/illuminants/cie_f2.csv",
    "iso_7589_tungsten" => "spectra/illuminants/iso_7589_tungsten.csv",
};

/// Measured reflectance sets (one column per sample).
pub const REFLECTANCES: &[(&str, &str)] = embedded! {
    "colorchecker_n_ohta" => "spectra/reflectances/colorchecker_n_ohta.csv",
    "tcs_cfi2017_99" => "spectra/reflectances/tcs_cfi2017_99.csv",
    "rawtoaces_190_patches" => "spectra/reflectances/rawtoaces_190_patches.csv",
};

/// RGB-to-spectrum bases (Mallett & Yuksel 2019 sRGB basis).
pub const RECOVERY: &[(&str, &str)] = embedded! {
    "mallett2019" => "spectra/recovery/mallett2019.csv",
};

/// CIE 1931 2° colour-matching functions.
pub const CIE_1931_CMF: &str =
    include_str!("../../../data/spectra/observers/cie_1931_2deg_cmf.csv");

/// The modelled wide-band gel filters (see `filters::gel_library`), as shipped CSV files.
pub const FILTERS: &[(&str, &str)] = embedded! {
    "gel_straw" => "filters/gel_straw.csv",
    "gel_yellow" => "filters/gel_yellow.csv",
    "gel_deep_yellow" => "filters/gel_deep_yellow.csv",
    "gel_amber" => "filters/gel_amber.csv",
    "gel_orange" => "filters/gel_orange.csv",
    "gel_red" => "filters/gel_red.csv",
    "gel_deep_red" => "filters/gel_deep_red.csv",
    "gel_salmon" => "filters/gel_salmon.csv",
    "gel_pink" => "filters/gel_pink.csv",
    "gel_magenta" => "filters/gel_magenta.csv",
    "gel_lavender" => "filters/gel_lavender.csv",
    "gel_violet" => "filters/gel_violet.csv",
    "gel_deep_blue" => "filters/gel_deep_blue.csv",
    "gel_blue" => "filters/gel_blue.csv",
    "gel_light_blue" => "filters/gel_light_blue.csv",
    "gel_cyan" => "filters/gel_cyan.csv",
    "gel_teal" => "filters/gel_teal.csv",
    "gel_green" => "filters/gel_green.csv",
    "gel_yellow_green" => "filters/gel_yellow_green.csv",
    "gel_emerald" => "filters/gel_emerald.csv",
};

fn find(kind: &str, table: &[(&str, &str)], name: &str) -> Result<ResponseCurve> {
    let (key, text) = table
        .iter()
        .find(|(k, _)| *k == name)
        .ok_or_else(|| Error::NotFound {
            what: format!("built-in {kind}"),
            name: name.to_string(),
            available: table.iter().map(|(k, _)| *k).collect::<Vec<_>>().join(", "),
        })?;
    ResponseCurve::from_csv_str(*key, text)
}

/// A built-in sensor by name.
pub fn sensor(name: &str) -> Result<ResponseCurve> {
    find("sensor", SENSORS, name)
}

/// A built-in illuminant by name.
pub fn illuminant(name: &str) -> Result<ResponseCurve> {
    find("illuminant", ILLUMINANTS, name)
}

/// A built-in reflectance set by name.
pub fn reflectances(name: &str) -> Result<ResponseCurve> {
    find("reflectance set", REFLECTANCES, name)
}

/// A built-in modelled filter by name.
pub fn filter(name: &str) -> Result<ResponseCurve> {
    find("filter", FILTERS, name)
}

/// Any built-in curve by name, searched in every table.
pub fn any(name: &str) -> Result<ResponseCurve> {
    if name == PANCHROMATIC {
        return panchromatic();
    }
    for table in [SENSORS, ILLUMINANTS, REFLECTANCES, FILTERS, RECOVERY] {
        if table.iter().any(|(k, _)| *k == name) {
            return find("curve", table, name);
        }
    }
    if name == "cie_1931_2deg_cmf" {
        return ResponseCurve::from_csv_str(name, CIE_1931_CMF);
    }
    Err(Error::NotFound {
        what: "built-in curve".into(),
        name: name.to_string(),
        available: "see `anaglyph rig init --help` for the list".into(),
    })
}

/// A monochrome sensor curve derived from a measured RGB one (see [`panchromatic`]).
pub const PANCHROMATIC: &str = "panchromatic";

/// The sum of the Canon EOS 5D Mark II's three channels: a stand-in for a monochrome
/// sensor's quantum efficiency (silicon behind the camera's infrared cut), for the rig
/// presets and tests; no measured monochrome curve is vendored (data/README.md).
pub fn panchromatic() -> Result<ResponseCurve> {
    let canon = find("curve", SENSORS, "canon_eos_5d_mark_ii")?;
    let mut csv = String::from("wavelength_nm,mono\n");
    for (k, wavelength) in canon.wavelengths().iter().enumerate() {
        let sum: f64 = (0..canon.channel_count())
            .map(|c| canon.channel(c)[k])
            .sum();
        csv.push_str(&format!("{wavelength},{sum}\n"));
    }
    ResponseCurve::from_csv_str(PANCHROMATIC, &csv)
}

/// Names of all built-in filters.
pub fn filter_names() -> Vec<&'static str> {
    FILTERS.iter().map(|(k, _)| *k).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_builtin_parses_and_covers_the_visible_range() {
        for table in [SENSORS, ILLUMINANTS, REFLECTANCES, FILTERS] {
            for (name, _) in table {
                let c = any(name).unwrap();
                c.check_covers(400.0, 680.0).unwrap();
            }
        }
        let cc = reflectances("colorchecker_n_ohta").unwrap();
        assert_eq!(cc.channel_count(), 24);
        assert_eq!(cc.channel_names()[0], "dark skin");
        assert!(sensor("no_such")
            .unwrap_err()
            .to_string()
            .contains("canon_eos_5d_mark_ii"));
    }
}

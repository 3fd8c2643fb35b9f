//! Colour previews of a reflectance cube (8-bit PNG, for looking, not for measuring):
//! - *pseudo-colour*, the paper's rendering: reflectance seen through the camera's RGB
//!   curves, resampled to the band centres by cubic spline, each channel scaled so that a
//!   perfect white is white;
//! - *sRGB*: reflectance under CIE D65 through the CIE 1931 2° observer, to linear sRGB
//!   and the sRGB transfer curve, a perfect white at Y = 1.
//!
//! Both see only the reconstructed bands (450–634 nm for the paper's rig), so deep blues
//! and far reds are darker than a full-range rendering would show them. Pixels without a
//! reconstruction are drawn mid-grey.

use crate::image::Image;
use crate::io::write_atomically;
use crate::spectrum::{Interpolation, ResponseCurve};
use crate::{builtin, Error, Result};
use std::path::Path;

/// Colour of pixels without a reconstruction.
const UNMEASURED: [u8; 3] = [96, 96, 96];
/// XYZ (D65 white) to linear sRGB (IEC 61966-2-1).
const XYZ_TO_SRGB: [[f64; 3]; 3] = [
    [3.2406, -1.5372, -0.4986],
    [-0.9689, 1.8758, 0.0415],
    [0.0557, -0.2040, 1.0570],
];

/// CIE D65 white point, XYZ with Y = 1.
const D65_WHITE: [f64; 3] = [0.95047, 1.0, 1.08883];

/// An 8-bit RGB picture (three channels).
pub type RgbPreview = Image<u8>;

impl Image<u8> {
    /// Writes the picture as PNG.
    pub fn save(&self, path: &Path) -> Result<()> {
        write_atomically(path, |out| {
            use image::ImageEncoder;
            image::codecs::png::PngEncoder::new(out)
                .write_image(
                    &self.data,
                    self.width as u32,
                    self.height as u32,
                    image::ExtendedColorType::Rgb8,
                )
                .map_err(std::io::Error::other)
        })
    }
}

/// The sRGB transfer curve of a linear value, as 8 bits.
pub fn srgb_encode(v: f64) -> u8 {
    let v = if v.is_finite() {
        v.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let e = if v <= 0.0031308 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    };
    (e * 255.0).round() as u8
}

/// Renders every pixel as `weights (3 × bands) · s`, then applies `to_rgb`.
fn render(
    cube: &Image<f32>,
    weights: &[[f64; 3]],
    to_rgb: impl Fn([f64; 3]) -> [f64; 3],
) -> Result<RgbPreview> {
    let (width, height, bands) = (cube.width, cube.height, cube.channels);
    if cube.data.len() != width * height * bands || weights.len() != bands {
        return Err(Error::Shape {
            op: "colour preview: cube against the band centres".into(),
            got: vec![cube.data.len(), bands],
            expected: vec![width * height * bands, weights.len()],
        });
    }
    let mut data = Vec::with_capacity(width * height * 3);
    for s in cube.data.chunks_exact(bands) {
        if s.iter().any(|v| !v.is_finite()) {
            data.extend(UNMEASURED);
            continue;
        }
        let mut acc = [0.0f64; 3];
        for (v, w) in s.iter().zip(weights) {
            for c in 0..3 {
                acc[c] += *v as f64 * w[c];
            }
        }
        data.extend(to_rgb(acc).map(srgb_encode));
    }
    Image::new(width, height, 3, data)
}

/// The paper's pseudo-colour rendering through `sensor` (1 or 3 channels).
pub fn pseudo_colour(
    cube: &Image<f32>,
    centres: &[f64],
    sensor: &ResponseCurve,
) -> Result<RgbPreview> {
    let channels = sensor.channel_count();
    let curves: Vec<Vec<f64>> = (0..channels)
        .map(|c| sensor.sample(c, centres, Interpolation::CubicSpline))
        .collect::<Result<_>>()?;
    let mut weights = vec![[0.0; 3]; centres.len()];
    for k in 0..3 {
        let curve = &curves[k.min(channels - 1)];
        let total: f64 = curve.iter().map(|v| v.max(0.0)).sum();
        if !(total > 0.0) {
            return Err(Error::unusable(
                format!("sensor '{}'", sensor.name()),
                "a channel has no response over the reconstruction bands",
            ));
        }
        for (b, v) in curve.iter().enumerate() {
            weights[b][k] = v.max(0.0) / total;
        }
    }
    render(cube, &weights, |rgb| rgb)
}

/// sRGB rendering under D65 (see the module docs).
pub fn srgb_preview(cube: &Image<f32>, centres: &[f64]) -> Result<RgbPreview> {
    let observer = builtin::any("cie_1931_2deg_cmf")?;
    let d65 = builtin::illuminant("cie_d65")?.sample(0, centres, Interpolation::Linear)?;
    let cmf: Vec<Vec<f64>> = (0..3)
        .map(|c| observer.sample(c, centres, Interpolation::Linear))
        .collect::<Result<_>>()?;
    let white_y: f64 = d65.iter().zip(&cmf[1]).map(|(e, y)| e * y).sum();
    if !(white_y > 0.0) {
        return Err(Error::unusable(
            "sRGB preview",
            "no luminance over the bands",
        ));
    }
    // The truncated range shifts the white point; scale X and Z so that a perfect white
    // lands on D65's (a von Kries step in XYZ), keeping Y = 1.
    let white: [f64; 3] =
        [0, 1, 2].map(|c| d65.iter().zip(&cmf[c]).map(|(e, v)| e * v).sum::<f64>() / white_y);
    let weights: Vec<[f64; 3]> = (0..centres.len())
        .map(|b| [0, 1, 2].map(|c| d65[b] * cmf[c][b] / white_y * D65_WHITE[c] / white[c]))
        .collect();
    render(cube, &weights, |xyz| {
        XYZ_TO_SRGB.map(|row| row[0] * xyz[0] + row[1] * xyz[1] + row[2] * xyz[2])
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_perfect_white_is_white_and_black_is_black() {
        let centres: Vec<f64> = (0..24).map(|b| 450.0 + 8.0 * b as f64).collect();
        let mut values = vec![1.0f32; 24];
        values.extend(vec![0.0f32; 24]);
        values.extend(vec![f32::NAN; 24]);
        let cube = Image::new(3, 1, 24, values).unwrap();
        let sensor = builtin::sensor("canon_eos_5d_mark_ii").unwrap();
        let pseudo = pseudo_colour(&cube, &centres, &sensor).unwrap();
        assert_eq!(&pseudo.data[..3], &[255, 255, 255]);
        assert_eq!(&pseudo.data[3..6], &[0, 0, 0]);
        assert_eq!(&pseudo.data[6..], &UNMEASURED);
        let srgb = srgb_preview(&cube, &centres).unwrap();
        assert!(
            srgb.data[..3].iter().all(|&v| v >= 254),
            "{:?}",
            &srgb.data[..3]
        );
        assert_eq!(&srgb.data[3..6], &[0, 0, 0]);
    }
}

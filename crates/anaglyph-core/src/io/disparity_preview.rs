//! Colour-mapped disparity previews (8-bit PNG): near is warm, far is cool, on a
//! perceptually ordered ramp from dark blue through green to yellow and red; invalid
//! pixels are black. For looking at results, never for reading them back (that is PFM).

use super::write_atomically;
use crate::{Error, Result};
use std::path::Path;

/// Anchor colours of the ramp, evenly spaced from 0 (far) to 1 (near).
const RAMP: [[f32; 3]; 6] = [
    [0.19, 0.07, 0.23],
    [0.16, 0.45, 0.90],
    [0.10, 0.80, 0.65],
    [0.65, 0.95, 0.25],
    [0.98, 0.65, 0.15],
    [0.70, 0.05, 0.02],
];

/// The ramp's colour at `t` in [0, 1].
pub fn ramp_colour(t: f32) -> [u8; 3] {
    let t = t.clamp(0.0, 1.0) * (RAMP.len() - 1) as f32;
    let i = (t.floor() as usize).min(RAMP.len() - 2);
    let f = t - i as f32;
    [0, 1, 2].map(|c| ((RAMP[i][c] * (1.0 - f) + RAMP[i + 1][c] * f) * 255.0).round() as u8)
}

/// Writes `disparity` (row-major, NaN or infinite = invalid) mapped over `span`
/// (`[far, near]`: the smallest disparity is the coolest colour).
pub fn write_disparity_preview(
    path: &Path,
    disparity: &[f32],
    width: usize,
    height: usize,
    span: [f32; 2],
) -> Result<()> {
    if disparity.len() != width * height || width == 0 || height == 0 {
        return Err(Error::Shape {
            op: "write_disparity_preview".into(),
            got: vec![disparity.len()],
            expected: vec![width * height],
        });
    }
    let [far, near] = span;
    let scale = if near > far { 1.0 / (near - far) } else { 1.0 };
    let pixels: Vec<u8> = disparity
        .iter()
        .flat_map(|&d| {
            if d.is_finite() {
                ramp_colour((d - far) * scale)
            } else {
                [0, 0, 0]
            }
        })
        .collect();
    write_atomically(path, |out| {
        use image::ImageEncoder;
        image::codecs::png::PngEncoder::new(out)
            .write_image(
                &pixels,
                width as u32,
                height as u32,
                image::ExtendedColorType::Rgb8,
            )
            .map_err(std::io::Error::other)
    })
}

//! A preview of a simulation: every capture in its place on the array grid, as an 8-bit
//! sRGB PNG. All views share one scale (the 99.5th percentile over all captures), so the
//! different filters show as different colours and brightnesses, as the cameras saw them.

use super::Simulation;
use crate::io::write_atomically;
use crate::Result;
use std::path::Path;

/// Widest sheet written; tiles are box-filtered down by a whole factor to fit.
const MAX_SHEET_WIDTH: usize = 1600;
/// Pixels between tiles.
const GAP: usize = 4;

fn srgb_encode(v: f64) -> u8 {
    let v = v.clamp(0.0, 1.0);
    let e = if v <= 0.0031308 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    };
    (e * 255.0).round() as u8
}

/// Writes the contact sheet of `simulation` for an array of `rows × cols` to `path`.
pub fn write_contact_sheet(
    path: &Path,
    simulation: &Simulation,
    rows: usize,
    cols: usize,
) -> Result<()> {
    let (w, h) = (simulation.settings.width, simulation.settings.height);
    let factor = (cols * w).div_ceil(MAX_SHEET_WIDTH).max(1);
    let (tw, th) = (w / factor, h / factor);
    let mut all: Vec<f32> = simulation
        .views
        .iter()
        .flat_map(|v| v.capture.iter().copied())
        .collect();
    let index = ((all.len() as f64 * 0.995) as usize).min(all.len().saturating_sub(1));
    let (_, scale, _) = all.select_nth_unstable_by(index, f32::total_cmp);
    let gain = if *scale > 0.0 {
        1.0 / *scale as f64
    } else {
        1.0
    };
    let (sw, sh) = (cols * tw + (cols + 1) * GAP, rows * th + (rows + 1) * GAP);
    let mut sheet = vec![40u8; sw * sh * 3];
    for view in &simulation.views {
        let (ox, oy) = (GAP + view.col * (tw + GAP), GAP + view.row * (th + GAP));
        for ty in 0..th {
            for tx in 0..tw {
                let mut rgb = [0.0f64; 3];
                for dy in 0..factor {
                    for dx in 0..factor {
                        let p = ((ty * factor + dy) * w + tx * factor + dx) * view.channels;
                        for (c, value) in rgb.iter_mut().enumerate() {
                            *value += view.capture[p + c.min(view.channels - 1)] as f64;
                        }
                    }
                }
                let q = ((oy + ty) * sw + ox + tx) * 3;
                for c in 0..3 {
                    sheet[q + c] = srgb_encode(rgb[c] * gain / (factor * factor) as f64);
                }
            }
        }
    }
    write_atomically(path, |out| {
        use image::ImageEncoder;
        image::codecs::png::PngEncoder::new(out)
            .write_image(&sheet, sw as u32, sh as u32, image::ExtendedColorType::Rgb8)
            .map_err(std::io::Error::other)
    })
}

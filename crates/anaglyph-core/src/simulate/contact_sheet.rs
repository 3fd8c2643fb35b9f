//! A preview of a simulation: every capture at its camera's place in the array (seen from
//! behind, as the rig's positions), as an 8-bit sRGB PNG. All views share one scale (the 99.5th percentile over all captures), so the
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

/// Where tiles of `tw × th` go for cameras at `positions_mm`: the top-left corner of each
/// and the sheet's size. The layout is scaled as little as keeps every two tiles apart.
fn tile_layout(positions_mm: &[[f64; 2]], tw: usize, th: usize) -> (Vec<[usize; 2]>, [usize; 2]) {
    let (pw, ph) = ((tw + GAP) as f64, (th + GAP) as f64);
    let mut scale = 0.0f64;
    for (i, a) in positions_mm.iter().enumerate() {
        for b in &positions_mm[i + 1..] {
            let (dx, dy) = ((a[0] - b[0]).abs(), (a[1] - b[1]).abs());
            scale = scale.max((pw / dx).min(ph / dy));
        }
    }
    let low = |k: usize| {
        positions_mm
            .iter()
            .map(|p| p[k])
            .fold(f64::INFINITY, f64::min)
    };
    let (x0, y0) = (low(0), low(1));
    let corners: Vec<[usize; 2]> = positions_mm
        .iter()
        .map(|p| {
            [
                GAP + ((p[0] - x0) * scale).round() as usize,
                GAP + ((p[1] - y0) * scale).round() as usize,
            ]
        })
        .collect();
    let extent =
        |k: usize, tile: usize| corners.iter().map(|c| c[k]).max().unwrap_or(0) + tile + GAP;
    let size = [extent(0, tw), extent(1, th)];
    (corners, size)
}

/// Writes the contact sheet of `simulation`, whose cameras sit at `positions_mm`, to
/// `path`.
pub fn write_contact_sheet(
    path: &Path,
    simulation: &Simulation,
    positions_mm: &[[f64; 2]],
) -> Result<()> {
    let (w, h) = (simulation.settings.width, simulation.settings.height);
    let mut factor = 1;
    let (corners, [sw, sh]) = loop {
        let (corners, size) = tile_layout(positions_mm, w / factor, h / factor);
        if size[0] <= MAX_SHEET_WIDTH || w / factor <= 1 {
            break (corners, size);
        }
        factor += 1;
    };
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
    let mut sheet = vec![40u8; sw * sh * 3];
    for (view, &[ox, oy]) in simulation.views.iter().zip(&corners) {
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

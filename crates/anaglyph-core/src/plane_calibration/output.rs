//! The output folder of `anaglyph calibrate --checkerboard`:
//!
//! ```text
//! OUT/<camera>.json         OpenCV FileStorage: `homography` (camera pixel -> reference
//!                            pixel), image_width, image_height; what the rig's
//!                            `calibration` key and `reconstruct --calibration OUT` read
//! OUT/corners/<camera>.png  the capture with its detected corners (first one green)
//! OUT/manifest.json          pattern, model, reference, per-camera residuals (RMS and
//!                            largest, px), time, the run id and every file with its CRC
//! ```
//!
//! In: a [`PlaneCalibration`] and the captures it came from. Out: the files above, written
//! into an [`OutputFolder`] (the caller commits it).

use super::board::stretched_8bit;
use super::{BoardCapture, PlaneCalibration};
use crate::io::{write_atomically, OutputFolder};
use crate::{Error, Result};
use std::path::Path;

/// Half-length of the cross drawn on each corner, pixels.
const MARK_PX: i64 = 4;

/// Writes `calibration` into `folder` (the manifest last); returns the number of files.
pub fn write_plane_calibration(
    folder: &OutputFolder,
    calibration: &PlaneCalibration,
    captures: &[BoardCapture],
) -> Result<usize> {
    let dir = folder.path();
    let corners_dir = dir.join("corners");
    std::fs::create_dir_all(&corners_dir).map_err(|e| Error::io(&corners_dir, e))?;
    for (fit, capture) in calibration.cameras.iter().zip(captures) {
        let name = fit.name.clone();
        let storage = serde_json::json!({
            "homography": {
                "type_id": "opencv-matrix",
                "rows": 3,
                "cols": 3,
                "dt": "d",
                "data": fit.homography.concat(),
            },
            "image_width": calibration.width,
            "image_height": calibration.height,
            "reference": calibration.reference,
        });
        let text = serde_json::to_string_pretty(&storage).map_err(|e| Error::output(&name, e))?;
        write_atomically(&dir.join(format!("{name}.json")), |w| {
            w.write_all(text.as_bytes())
        })?;
        write_corner_picture(
            &corners_dir.join(format!("{name}.png")),
            capture,
            &fit.corners,
        )?;
    }
    folder.write_manifest(calibration)
}

/// The capture (stretched to 8 bits as the detector saw it, without the blur) with a red cross on every corner, green on the first.
fn write_corner_picture(path: &Path, capture: &BoardCapture, corners: &[[f64; 2]]) -> Result<()> {
    let image = &capture.image;
    let grey = stretched_8bit(image);
    let mut picture = image::RgbImage::from_fn(image.width as u32, image.height as u32, |x, y| {
        let g = grey[y as usize * image.width + x as usize];
        image::Rgb([g, g, g])
    });
    for (k, c) in corners.iter().enumerate() {
        let colour = if k == 0 {
            image::Rgb([0, 255, 0])
        } else {
            image::Rgb([255, 0, 0])
        };
        let (cx, cy) = (c[0].round() as i64, c[1].round() as i64);
        for o in -MARK_PX..=MARK_PX {
            for (x, y) in [(cx + o, cy), (cx, cy + o)] {
                if x >= 0 && y >= 0 && (x as u32) < picture.width() && (y as u32) < picture.height()
                {
                    picture.put_pixel(x as u32, y as u32, colour);
                }
            }
        }
    }
    picture
        .save(path)
        .map_err(|e| Error::output(path.display().to_string(), e))
}

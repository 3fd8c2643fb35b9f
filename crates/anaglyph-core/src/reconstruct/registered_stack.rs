//! The registered stack of a view, what users of narrow-band arrays start from when the
//! filter curves are unknown: every camera channel warped into the view.
//!
//! In: a view's warped measurements (`height × width × Σ channels`, NaN where a camera
//! does not see the point) and the rig. Out: `registered/NAME.hdr` + `.img` (band names
//! = camera channels such as `r0c1` or `r0c1:R`; wavelengths = the filters' nominal
//! centres when every filter is a `gaussian:` one) and `registered/NAME_seen.png`, the
//! number of cameras that see each pixel (black: none, white: all).

use super::FieldLayout;
use crate::filters::nominal_centre;
use crate::image::Image;
use crate::io::{write_envi, EnviCube};
use crate::rig::Rig;
use crate::{Error, Result};
use std::path::Path;

/// Writes the stack and its visibility picture for view `name` under `dir/registered/`.
pub fn write_registered_stack(
    dir: &Path,
    name: &str,
    rig: &Rig,
    layout: &FieldLayout,
    image: Image<f32>,
) -> Result<()> {
    let channels = layout.channel_labels.len();
    if (image.width, image.height, image.channels) != (layout.width, layout.height, channels) {
        return Err(Error::Shape {
            op: format!("registered stack of view {name}"),
            got: vec![image.width, image.height, image.channels],
            expected: vec![layout.width, layout.height, channels],
        });
    }
    let firsts: Vec<usize> = (0..rig.cameras.len())
        .map(|m| rig.channel_rows(m).start)
        .collect();
    let seen = seen_counts(&image, &firsts)?;
    let path = dir.join(format!("registered/{name}_seen.png"));
    seen.save(&path).map_err(|e| Error::Output {
        what: path.display().to_string(),
        message: e.to_string(),
    })?;
    write_envi(
        &dir.join(format!("registered/{name}.hdr")),
        &EnviCube {
            image,
            wavelengths: nominal_centres(rig).filter(|c| c.len() == channels),
            band_names: Some(layout.channel_labels.clone()),
        },
        &format!(
            "anaglyph registered stack: every camera warped into view {name}, NaN where unseen"
        ),
    )
}

/// Per pixel, the number of cameras whose first channel (`firsts`: its index in the
/// stack) is finite, scaled so that every camera is 255.
fn seen_counts(stack: &Image<f32>, firsts: &[usize]) -> Result<image::GrayImage> {
    if firsts.iter().any(|&c| c >= stack.channels) {
        return Err(Error::Shape {
            op: "registered stack channels".into(),
            got: vec![stack.channels],
            expected: vec![firsts.iter().max().map_or(0, |c| c + 1)],
        });
    }
    let cameras = firsts.len().max(1) as f32;
    let levels = stack
        .data
        .chunks_exact(stack.channels)
        .map(|pixel| {
            let seen = firsts.iter().filter(|&&c| pixel[c].is_finite()).count();
            (255.0 * seen as f32 / cameras).round() as u8
        })
        .collect();
    image::GrayImage::from_raw(stack.width as u32, stack.height as u32, levels).ok_or(
        Error::Shape {
            op: "registered stack visibility".into(),
            got: vec![stack.width, stack.height],
            expected: vec![stack.width, stack.height],
        },
    )
}

/// Per camera channel (rig order), the centre of its camera's nominal narrow-band filter
/// (`gaussian:CENTRE_NM:FWHM_NM`); None unless every filter is one.
fn nominal_centres(rig: &Rig) -> Option<Vec<f64>> {
    let mut centres = Vec::new();
    for cam in &rig.cameras {
        let centre = nominal_centre(cam.filter.as_ref()?.name())?;
        centres.extend(std::iter::repeat_n(
            centre,
            cam.sensor.channel_names().len(),
        ));
    }
    Some(centres)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_seen_picture_counts_the_cameras_whose_first_channel_is_finite() {
        // Two cameras: an RGB one (3 channels) and a monochrome one; 3 pixels.
        let nan = f32::NAN;
        let data = vec![
            0.1, 0.2, 0.3, 0.4, // both see it
            nan, nan, nan, 0.4, // only the monochrome camera
            nan, nan, nan, nan, // nobody
        ];
        let stack = Image::new(3, 1, 4, data).unwrap();
        let seen = seen_counts(&stack, &[0, 3]).unwrap();
        assert_eq!(seen.into_raw(), vec![255, 128, 0]);
        assert!(seen_counts(&stack, &[0, 4]).is_err());
    }
}

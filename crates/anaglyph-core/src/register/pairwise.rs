//! Pairwise registration: each view matched with its nearest row neighbour and nearest
//! column neighbour by [`match_pair`] / [`match_vertical`] (left–right checked, failures
//! NaN); the two maps, in disparity-baseline units, are averaged where they agree within
//! [`FUSION_TOLERANCE_PX`], either one is kept where only it is valid, and what is left is
//! filled from the background side.

use super::RegistrationSettings;
use super::{fill_from_background, ArrayGeometry, Registration, ViewImage, SUBPIXEL_WINDOW_RADIUS};
use crate::disparity::{DisparityConvention, DisparityMap};
use crate::stereo::{match_pair, match_vertical, GreyImage, LeftRight, MatchSettings};
use crate::{Error, Result};
use std::time::Instant;

/// Largest difference (px per column step) between the row and the column estimate that
/// still counts as agreement.
pub const FUSION_TOLERANCE_PX: f32 = 1.0;

/// The image mirrored left to right.
fn mirror(image: &GreyImage) -> GreyImage {
    let w = image.width;
    GreyImage {
        channels: 1,
        data: image
            .data
            .chunks_exact(w)
            .flat_map(|row| row.iter().rev().copied())
            .collect(),
        ..image.clone()
    }
}

/// The image flipped top to bottom.
fn flip(image: &GreyImage) -> GreyImage {
    let w = image.width;
    GreyImage {
        channels: 1,
        data: image
            .data
            .chunks_exact(w)
            .rev()
            .flat_map(|row| row.iter().copied())
            .collect(),
        ..image.clone()
    }
}

fn with_data(like: &GreyImage, data: Vec<f32>) -> GreyImage {
    GreyImage {
        channels: 1,
        width: like.width,
        height: like.height,
        data,
    }
}

/// Disparities of view `i` against its nearest row neighbour (`vertical` false) or column
/// neighbour (true), in disparity-baseline units, NaN where the left–right check fails;
/// None without such a neighbour. A neighbour on the left or above is matched mirrored
/// or flipped, so that it becomes one on the right or below.
fn along_line(
    images: &[ViewImage],
    geometry: &ArrayGeometry,
    i: usize,
    vertical: bool,
    settings: &RegistrationSettings<'_>,
) -> Result<Option<Vec<f32>>> {
    let (forward, found) = match geometry.nearest_along(i, vertical, true) {
        Some(found) => (true, found),
        None => match geometry.nearest_along(i, vertical, false) {
            Some(found) => (false, found),
            None => return Ok(None),
        },
    };
    let (j, step) = found;
    let chain = MatchSettings {
        left_right: LeftRight::Check,
        subpixel_window: Some(SUBPIXEL_WINDOW_RADIUS),
        ..MatchSettings::for_cost(&settings.cost, settings.range.scaled(step))
    };
    let turn: fn(&GreyImage) -> GreyImage = match (forward, vertical) {
        (true, _) => GreyImage::clone,
        (false, false) => mirror,
        (false, true) => flip,
    };
    let (me, other) = (turn(&images[i].image), turn(&images[j].image));
    let out = if vertical {
        match_vertical(&me, &other, &settings.cost, &chain)?
    } else {
        match_pair(&me, &other, &settings.cost, &chain)?
    };
    let disparity = turn(&with_data(&images[i].image, out.disparity.data)).data;
    Ok(Some(
        disparity
            .into_iter()
            .map(|d| (d as f64 / step) as f32)
            .collect(),
    ))
}

/// Fuses a row and a column estimate (see the module docs).
pub fn fuse(row: Option<Vec<f32>>, column: Option<Vec<f32>>, pixels: usize) -> Vec<f32> {
    match (row, column) {
        (Some(a), Some(b)) => a
            .iter()
            .zip(&b)
            .map(|(&p, &q)| match (p.is_finite(), q.is_finite()) {
                (true, true) if (p - q).abs() <= FUSION_TOLERANCE_PX => 0.5 * (p + q),
                (true, true) => f32::NAN,
                (true, false) => p,
                (false, true) => q,
                (false, false) => f32::NAN,
            })
            .collect(),
        (Some(a), None) | (None, Some(a)) => a,
        (None, None) => vec![f32::NAN; pixels],
    }
}

/// Pairwise registration of every view (see the module docs).
pub fn pairwise_disparities(
    images: &[ViewImage],
    geometry: &ArrayGeometry,
    settings: &RegistrationSettings<'_>,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Registration> {
    let alone = (0..images.len()).find(|&i| {
        [false, true].iter().all(|&vertical| {
            geometry.nearest_along(i, vertical, true).is_none()
                && geometry.nearest_along(i, vertical, false).is_none()
        })
    });
    if let Some(i) = alone {
        return Err(Error::rig_layout(
            "pairwise registration",
            format!(
                "camera {} with no other camera on its row or column",
                geometry.names[i]
            ),
            "a row or column neighbour for every camera (multi-baseline registration takes \
             any layout)",
        ));
    }
    let (w, h) = (images[0].image.width, images[0].image.height);
    let mut disparities = Vec::with_capacity(images.len());
    let (mut row_seconds, mut column_seconds) = (0.0, 0.0);
    for i in 0..images.len() {
        let clock = Instant::now();
        let row = along_line(images, geometry, i, false, settings)?;
        row_seconds += clock.elapsed().as_secs_f64();
        let clock = Instant::now();
        let column = along_line(images, geometry, i, true, settings)?;
        column_seconds += clock.elapsed().as_secs_f64();
        let mut fused = fuse(row, column, w * h);
        fill_from_background(&mut fused, w);
        disparities.push(DisparityMap::new(
            w,
            h,
            DisparityConvention::ColumnStep,
            fused,
        )?);
        progress(i + 1, images.len());
    }
    Ok(Registration {
        disparities,
        timings: vec![
            ("row pairs".into(), row_seconds),
            ("column pairs".into(), column_seconds),
        ],
        moved_to_planes: None,
        banded: None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mirror_and_flip_are_involutions() {
        let image = GreyImage {
            channels: 1,
            width: 3,
            height: 2,
            data: vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0],
        };
        assert_eq!(mirror(&image).data, [3.0, 2.0, 1.0, 6.0, 5.0, 4.0]);
        assert_eq!(flip(&image).data, [4.0, 5.0, 6.0, 1.0, 2.0, 3.0]);
        assert_eq!(mirror(&mirror(&image)), image);
        assert_eq!(flip(&flip(&image)), image);
    }

    #[test]
    fn fusion_averages_agreement_and_drops_conflict() {
        let nan = f32::NAN;
        let fused = fuse(
            Some(vec![10.0, 10.0, 3.0, nan]),
            Some(vec![10.5, 14.0, nan, nan]),
            4,
        );
        assert_eq!(fused[0], 10.25);
        assert!(fused[1].is_nan());
        assert_eq!(fused[2], 3.0);
        assert!(fused[3].is_nan());
    }

    /// A triangle's apex has no camera on its row or column: pairwise registration names it
    /// instead of leaving its map empty.
    #[test]
    fn a_camera_without_row_or_column_neighbour_is_refused() {
        let geometry = ArrayGeometry {
            names: vec!["left".into(), "right".into(), "apex".into()],
            positions: vec![[0.0, 0.0], [1.0, 0.0], [0.5, 0.866]],
        };
        let image = GreyImage {
            channels: 1,
            width: 32,
            height: 24,
            data: vec![0.5; 32 * 24],
        };
        let images = vec![
            ViewImage {
                image,
                matching: Vec::new(),
                measured: None,
            };
            3
        ];
        let settings = RegistrationSettings {
            mode: super::super::RegistrationMode::Pairwise,
            cost: crate::stereo::MatchingCost::Census,
            range: crate::stereo::DisparityRange::up_to(4).unwrap(),
            coarse_to_fine: super::super::CoarseToFine::Off,
            previous: None,
        };
        let error = pairwise_disparities(&images, &geometry, &settings, &|_, _| {})
            .unwrap_err()
            .to_string();
        assert!(
            error.contains("camera apex with no other camera"),
            "{error}"
        );
    }
}

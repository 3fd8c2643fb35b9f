//! Pairwise registration: each view matched with one row neighbour and one column
//! neighbour by [`match_pair`] / [`match_vertical`] (left–right checked, failures NaN);
//! the two maps, in column-step units, are averaged where they agree within
//! [`FUSION_TOLERANCE_PX`], either one is kept where only it is valid, and what is left is
//! filled from the background side.

use super::RegistrationSettings;
use super::{
    fill_from_background, find, ArrayGeometry, GridImage, Registration, SUBPIXEL_WINDOW_RADIUS,
};
use crate::stereo::{match_pair, match_vertical, GreyImage, LeftRight, MatchSettings};
use crate::Result;
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

/// Disparities of view `i` against its row neighbour (column-step units), NaN where the
/// left–right check fails; None without a row neighbour.
fn along_row(
    images: &[GridImage],
    i: usize,
    settings: &RegistrationSettings<'_>,
) -> Result<Option<Vec<f32>>> {
    let view = &images[i];
    let chain = MatchSettings {
        left_right: LeftRight::Check,
        subpixel_window: Some(SUBPIXEL_WINDOW_RADIUS),
        ..MatchSettings::for_cost(&settings.cost, settings.range)
    };
    if let Some(j) = find(images, view.row, view.col + 1) {
        let out = match_pair(&view.image, &images[j].image, &settings.cost, &chain)?;
        return Ok(Some(out.disparity.into_column_step()?.data));
    }
    if let Some(j) = view
        .col
        .checked_sub(1)
        .and_then(|c| find(images, view.row, c))
    {
        // Mirrored, the left neighbour becomes a right one.
        let out = match_pair(
            &mirror(&view.image),
            &mirror(&images[j].image),
            &settings.cost,
            &chain,
        )?;
        return Ok(Some(
            mirror(&with_data(&view.image, out.disparity.data)).data,
        ));
    }
    Ok(None)
}

/// Disparities of view `i` against its column neighbour, converted to column-step units;
/// None without a column neighbour.
fn along_column(
    images: &[GridImage],
    i: usize,
    geometry: &ArrayGeometry,
    settings: &RegistrationSettings<'_>,
) -> Result<Option<Vec<f32>>> {
    let view = &images[i];
    let ratio = geometry.baseline_ratio;
    let chain = MatchSettings {
        left_right: LeftRight::Check,
        subpixel_window: Some(SUBPIXEL_WINDOW_RADIUS),
        ..MatchSettings::for_cost(&settings.cost, settings.range.scaled(ratio))
    };
    let to_columns = |d: Vec<f32>| d.into_iter().map(|v| (v as f64 / ratio) as f32).collect();
    if let Some(j) = find(images, view.row + 1, view.col) {
        let out = match_vertical(&view.image, &images[j].image, &settings.cost, &chain)?;
        return Ok(Some(to_columns(out.disparity.data)));
    }
    if let Some(j) = view
        .row
        .checked_sub(1)
        .and_then(|r| find(images, r, view.col))
    {
        let out = match_vertical(
            &flip(&view.image),
            &flip(&images[j].image),
            &settings.cost,
            &chain,
        )?;
        return Ok(Some(to_columns(
            flip(&with_data(&view.image, out.disparity.data)).data,
        )));
    }
    Ok(None)
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
    images: &[GridImage],
    geometry: &ArrayGeometry,
    settings: &RegistrationSettings<'_>,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Registration> {
    let (w, h) = (images[0].image.width, images[0].image.height);
    let mut disparities = Vec::with_capacity(images.len());
    let (mut row_seconds, mut column_seconds) = (0.0, 0.0);
    for i in 0..images.len() {
        let clock = Instant::now();
        let row = along_row(images, i, settings)?;
        row_seconds += clock.elapsed().as_secs_f64();
        let clock = Instant::now();
        let column = along_column(images, i, geometry, settings)?;
        column_seconds += clock.elapsed().as_secs_f64();
        let mut fused = fuse(row, column, w * h);
        fill_from_background(&mut fused, w);
        disparities.push(fused);
        progress(i + 1, images.len());
    }
    Ok(Registration {
        disparities,
        timings: vec![
            ("row pairs".into(), row_seconds),
            ("column pairs".into(), column_seconds),
        ],
        moved_to_planes: None,
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
}

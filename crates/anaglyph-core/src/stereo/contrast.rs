//! Whether a pair's contrast is inverted: behind complementary filters (red against cyan,
//! foliage under blue against near infrared) a surface bright in one view is dark in the
//! other, and every cost that compares like with like, learned ones included, then matches
//! nothing. An inverted pair is matched with its right image negated.
//!
//! The estimate votes over textured windows of the left image: for each, the disparity
//! whose 9×9 normalised cross-correlation with the right image is largest in magnitude,
//! and that correlation's sign, weighted by its square (true matches correlate strongly,
//! spurious best matches weakly and with either sign).
//!
//! In: the two unit-range images and the search range. Out: the share of the vote that
//! is negative and the decision.

use super::{DisparityRange, GreyImage};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// How `match` treats the sign of a pair's contrast.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Contrast {
    /// The right image as it is.
    #[default]
    Same,
    /// The right image negated (the pair is known to invert).
    Inverted,
    /// Inverted when [`estimate_contrast`] says so.
    Auto,
    /// Either sign at every pixel and disparity: the cost of the right image as it is or
    /// negated, whichever is lower (for scenes that invert only in part).
    Either,
}

crate::choice::named_choices!(Contrast, "contrast" {
    Auto = "auto" "Vote on the sign of the windows' correlations and negate the right image when the pair inverts (red against cyan filters).",
    Same = "same" "The right image as it is.",
    Inverted = "inverted" "The right image negated: the pair is known to invert.",
    Either = "either" "Either sign at every pixel: the lower cost of the right image as it is or negated (scenes that invert only in part); one more network pass.",
});

/// The vote of [`estimate_contrast`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ContrastEstimate {
    /// Share of the vote for an inverted pair (0: surely the same contrast, 1: surely
    /// inverted).
    pub inverted_share: f64,
    /// Windows that voted.
    pub windows: usize,
    pub inverted: bool,
}

/// Half-size of the correlation windows (9×9).
const RADIUS: usize = 4;
/// Distance between the centres of voting windows, pixels.
const STEP: usize = 6;
/// Standard deviation (unit range) under which a window is too flat to vote.
const MIN_DEVIATION: f32 = 0.02;
/// Share of the vote above which a pair counts as inverted. On the held-out pairs of
/// `examples/stereo_quality.rs` (12 scenes at 256×192), the 24 pairs of one sign voted at
/// most 0.43 and the 12 inverted cross-channel pairs at least 0.57; the closest were
/// cross-channel pairs whose scene itself inverts in part.
pub const INVERTED_SHARE: f64 = 0.5;

/// Estimates whether `right` shows `left`'s contrast inverted (see the module docs); both
/// in unit range, of one size.
pub fn estimate_contrast(
    left: &GreyImage,
    right: &GreyImage,
    range: DisparityRange,
) -> ContrastEstimate {
    let (w, h) = (left.width, left.height);
    let rows: Vec<usize> = (RADIUS..h.saturating_sub(RADIUS)).step_by(STEP).collect();
    let (negative, total, windows) = rows
        .par_iter()
        .map(|&y| {
            // Every right window of the row once: each serves up to 64 / STEP left ones.
            let right_windows: Vec<Option<Window>> = (0..w)
                .map(|xr| (xr >= RADIUS && xr + RADIUS < w).then(|| Window::at(right, xr, y))?)
                .collect();
            let (mut negative, mut total, mut windows) = (0.0f64, 0.0f64, 0usize);
            for x in (RADIUS..w.saturating_sub(RADIUS)).step_by(STEP) {
                let Some(left_window) = Window::at(left, x, y) else {
                    continue;
                };
                let best = (range.min..range.max)
                    .filter_map(|d| {
                        let xr = usize::try_from(x as i64 - i64::from(d)).ok()?;
                        right_windows.get(xr)?.as_ref()
                    })
                    .map(|right_window| left_window.correlation(right_window))
                    .max_by(|a, b| a.abs().total_cmp(&b.abs()));
                if let Some(c) = best {
                    let weight = f64::from(c * c);
                    total += weight;
                    negative += if c < 0.0 { weight } else { 0.0 };
                    windows += 1;
                }
            }
            (negative, total, windows)
        })
        .reduce(|| (0.0, 0.0, 0), |a, b| (a.0 + b.0, a.1 + b.1, a.2 + b.2));
    let inverted_share = if total > 0.0 { negative / total } else { 0.0 };
    ContrastEstimate {
        inverted_share,
        windows,
        inverted: inverted_share > INVERTED_SHARE,
    }
}

/// A 9×9 window's values less their mean, and their norm.
struct Window {
    values: [f32; (2 * RADIUS + 1) * (2 * RADIUS + 1)],
    norm: f32,
}

impl Window {
    /// The window centred at (x, y) (inside the image), None if it is flat or holds NaN.
    fn at(image: &GreyImage, x: usize, y: usize) -> Option<Self> {
        let side = 2 * RADIUS + 1;
        let mut values = [0f32; (2 * RADIUS + 1) * (2 * RADIUS + 1)];
        for (k, v) in values.iter_mut().enumerate() {
            let (dx, dy) = (k % side, k / side);
            *v = image.data[(y + dy - RADIUS) * image.width + x + dx - RADIUS];
        }
        let mean = values.iter().sum::<f32>() / values.len() as f32;
        values.iter_mut().for_each(|v| *v -= mean);
        let norm = values.iter().map(|v| v * v).sum::<f32>().sqrt();
        let deviation = norm / (values.len() as f32).sqrt();
        (deviation >= MIN_DEVIATION && norm.is_finite()).then_some(Window { values, norm })
    }

    fn correlation(&self, other: &Window) -> f32 {
        let dot: f32 = self
            .values
            .iter()
            .zip(&other.values)
            .map(|(a, b)| a * b)
            .sum();
        dot / (self.norm * other.norm)
    }
}

/// `image` with its contrast inverted within its own range.
pub fn negated(image: &GreyImage) -> GreyImage {
    let (lo, hi) = image
        .data
        .iter()
        .filter(|v| v.is_finite())
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &v| {
            (lo.min(v), hi.max(v))
        });
    GreyImage {
        data: image.data.iter().map(|&v| lo + hi - v).collect(),
        ..image.clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A textured pair 5 px apart: the same contrast votes same, the negated right image
    /// votes inverted, and a flat right image does not vote at all.
    #[test]
    fn the_vote_follows_the_sign_of_the_correlation() {
        let (w, h) = (96usize, 64usize);
        let texture = |x: f32, y: f32| {
            0.5 + 0.2 * (0.41 * x + 0.13 * y).sin()
                + 0.15 * (0.23 * y - 0.31 * x).cos()
                + 0.1 * (1.7 * x).sin() * (0.9 * y).cos()
        };
        let image = |shift: f32| GreyImage {
            channels: 1,
            width: w,
            height: h,
            data: (0..w * h)
                .map(|i| texture((i % w) as f32 + shift, (i / w) as f32))
                .collect(),
        };
        let (left, right) = (image(0.0), image(5.0));
        let range = DisparityRange::up_to(16).unwrap();
        let same = estimate_contrast(&left, &right, range);
        assert!(!same.inverted && same.inverted_share < 0.05, "{same:?}");
        let inverted = estimate_contrast(&left, &negated(&right), range);
        assert!(
            inverted.inverted && inverted.inverted_share > 0.95,
            "{inverted:?}"
        );
        assert!(same.windows > 50, "{same:?}");
        let flat = GreyImage {
            data: vec![0.5; w * h],
            ..right.clone()
        };
        let none = estimate_contrast(&left, &flat, range);
        assert!(!none.inverted && none.windows == 0, "{none:?}");
        let back = negated(&negated(&right));
        assert!(back
            .data
            .iter()
            .zip(&right.data)
            .all(|(a, b)| (a - b).abs() < 1e-6));
    }
}

//! Disparity maps with their convention written on the type. Two conventions meet in
//! anaglyph, and a map converts between them only explicitly:
//!
//! - [`DisparityConvention::Pair`]: a rectified pair, the first image the reference:
//!   `x_second = x_first − d` along the pair's axis (Middlebury for a horizontal pair; what
//!   `match` computes; a vertical pair reads `y_bottom = y_top − d`);
//! - [`DisparityConvention::ColumnStep`]: an array view, in pixels per column step of the
//!   array geometry: view (r + Δr, c + Δc) sees pixel (x, y) at
//!   `(x − Δc·d, y − Δr·d·b_y/b_x)` (what registration and the simulator compute).
//!
//! A horizontal pair whose right camera is the left one's column neighbour reads the same
//! numbers in both. In memory, unknown disparities are NaN in both conventions; PFM files
//! mark them +inf ([`DisparityMap::to_pfm`], [`DisparityMap::from_pfm`]).
//!
//! Disparities are signed. An array rectified to infinity sees every point at d ≥ 0; an
//! array calibrated to a plane (every camera mapped onto the reference through a
//! checkerboard at the working distance) sees that plane at d = 0, nearer points at d > 0
//! and farther ones at d < 0. What is searched is a [`DisparityRange`].

use crate::image::Image;
use crate::io::PfmImage;
use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;

/// Largest magnitude of a searched disparity (pixels).
pub const MAX_DISPARITY_MAGNITUDE: i32 = 1 << 15;

/// The disparities searched, `min ≤ d < max` (whole pixels; `--max-disp N` is `0:N`,
/// `--disp-range -24:8` searches 32 disparities from −24 to 7).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DisparityRange {
    pub min: i32,
    /// One past the largest disparity searched.
    pub max: i32,
}

impl DisparityRange {
    /// `[min, max)`: an error unless `min < max` and both lie within
    /// ±[`MAX_DISPARITY_MAGNITUDE`].
    pub fn new(min: i32, max: i32) -> Result<Self> {
        if min >= max {
            return Err(Error::disparity_range(
                "disparity range",
                format!("{min}:{max}"),
                "MIN:MAX with MIN < MAX (MAX is one past the largest disparity searched)",
            ));
        }
        for (name, v) in [("smallest", min), ("largest", max)] {
            if v.abs() > MAX_DISPARITY_MAGNITUDE {
                return Err(Error::out_of_range(
                    format!("{name} disparity of the range"),
                    v as f64,
                    format!("within ±{MAX_DISPARITY_MAGNITUDE}"),
                ));
            }
        }
        Ok(DisparityRange { min, max })
    }

    /// `[0, count)`, the range of an array rectified to infinity.
    pub fn up_to(count: usize) -> Result<Self> {
        let max = i32::try_from(count).unwrap_or(i32::MAX);
        Self::new(0, max)
    }

    /// How many disparities are searched.
    pub fn count(&self) -> usize {
        (self.max as i64 - self.min as i64).max(0) as usize
    }

    /// The disparity at index `k` of a cost volume over this range.
    pub fn at(&self, k: usize) -> f32 {
        (self.min as i64 + k as i64) as f32
    }

    /// The range covering every disparity of this one times `factor` (> 0), e.g. a
    /// column-step range in pixels along a vertical baseline `b_y/b_x` times as long.
    pub fn scaled(&self, factor: f64) -> Self {
        let min = (self.min as f64 * factor).floor() as i32;
        let max = ((self.max as f64 * factor).ceil() as i32).max(min + 1);
        DisparityRange { min, max }
    }

    /// How many of `values` lie within half a pixel of an end of this range (searched
    /// within `whole`) that is not an end of `whole`: a search narrowed to this range that
    /// missed surfaces piles its disparities there.
    pub fn count_at_inner_ends(
        &self,
        whole: DisparityRange,
        values: impl IntoIterator<Item = f32>,
    ) -> usize {
        let low = (self.min > whole.min).then_some(self.min as f32);
        let high = (self.max < whole.max).then_some((self.max - 1) as f32);
        if low.is_none() && high.is_none() {
            return 0;
        }
        values
            .into_iter()
            .filter(|&d| low.is_some_and(|l| d <= l + 0.5) || high.is_some_and(|h| d >= h - 0.5))
            .count()
    }

    /// Whether `d` lies between the smallest and the largest disparity searched.
    pub fn contains(&self, d: f32) -> bool {
        d >= self.min as f32 && d <= (self.max - 1) as f32
    }

    /// The largest disparity magnitude searched.
    pub fn magnitude(&self) -> usize {
        self.min.unsigned_abs().max((self.max - 1).unsigned_abs()) as usize
    }

    /// Checks that images `width` pixels wide can overlap at every disparity searched.
    pub fn check_width(&self, width: usize, what: &str) -> Result<()> {
        if self.count() < 2 || self.magnitude() >= width {
            return Err(Error::disparity_range(
                format!("disparity range {self} against {what}"),
                format!(
                    "{} disparities, up to {} px",
                    self.count(),
                    self.magnitude()
                ),
                format!("at least 2 disparities, each smaller than the width {width}"),
            ));
        }
        Ok(())
    }
}

impl fmt::Display for DisparityRange {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}:{}", self.min, self.max)
    }
}

impl FromStr for DisparityRange {
    type Err = Error;

    /// `MIN:MAX`, e.g. `-24:8`.
    fn from_str(text: &str) -> Result<Self> {
        let bad = || {
            Error::disparity_range(
                "disparity range",
                format!("'{text}'"),
                "MIN:MAX in whole pixels, e.g. -24:8 (MAX one past the largest searched)",
            )
        };
        let (min, max) = text.trim().split_once(':').ok_or_else(bad)?;
        let parse = |v: &str| v.trim().parse::<i32>().map_err(|_| bad());
        Self::new(parse(min)?, parse(max)?)
    }
}

/// What a disparity value means.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum DisparityConvention {
    /// A pair along `axis`, the first image the reference: the second sees its pixel
    /// d pixels towards smaller coordinates.
    Pair { axis: PairAxis },
    /// Pixels per column step of the array geometry.
    ColumnStep,
}

/// The axis of a rectified pair.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum PairAxis {
    /// Left (reference) and right: `x_right = x_left − d`.
    Horizontal,
    /// Top (reference) and bottom: `y_bottom = y_top − d`.
    Vertical,
}

/// A disparity per pixel, row-major, NaN where unknown.
#[derive(Debug, Clone, PartialEq)]
pub struct DisparityMap {
    pub width: usize,
    pub height: usize,
    pub convention: DisparityConvention,
    pub data: Vec<f32>,
}

impl DisparityMap {
    /// A map of the given size over `data` (`width × height` values, NaN where unknown).
    pub fn new(
        width: usize,
        height: usize,
        convention: DisparityConvention,
        data: Vec<f32>,
    ) -> Result<Self> {
        let image = Image::new(width, height, 1, data)?;
        Ok(DisparityMap {
            width,
            height,
            convention,
            data: image.data,
        })
    }

    /// A horizontal pair's map as a column-step map of the array, for a reference whose
    /// right neighbour is the pair's second camera one column step away (the values are
    /// the same; the type says which); any other convention is an error.
    pub fn into_column_step(self) -> Result<Self> {
        match self.convention {
            DisparityConvention::ColumnStep => Ok(self),
            DisparityConvention::Pair {
                axis: PairAxis::Horizontal,
            } => Ok(DisparityMap {
                convention: DisparityConvention::ColumnStep,
                ..self
            }),
            other => Err(Error::setting(
                "disparity map convention",
                format!("{other:?} (no column-step reading without the array geometry)"),
                "ColumnStep or a horizontal pair",
            )),
        }
    }

    /// Checks that the map has the given size and convention.
    pub fn check(
        &self,
        width: usize,
        height: usize,
        convention: DisparityConvention,
    ) -> Result<()> {
        if (self.width, self.height, self.data.len()) != (width, height, width * height) {
            return Err(Error::Shape {
                op: "disparity map against the images".into(),
                got: vec![self.width, self.height, self.data.len()],
                expected: vec![width, height, width * height],
            });
        }
        if self.convention != convention {
            return Err(Error::setting(
                "disparity map convention",
                format!("{:?}", self.convention),
                format!("{convention:?}"),
            ));
        }
        Ok(())
    }

    /// The smallest and largest known disparity ([+inf, −inf] when none is known).
    pub fn range(&self) -> [f32; 2] {
        self.data
            .iter()
            .filter(|d| d.is_finite())
            .fold([f32::INFINITY, f32::NEG_INFINITY], |[a, b], &v| {
                [a.min(v), b.max(v)]
            })
    }

    /// The map as a one-channel PFM image, +inf where unknown (Middlebury).
    pub fn to_pfm(&self) -> PfmImage {
        PfmImage {
            width: self.width,
            height: self.height,
            channels: 1,
            data: self
                .data
                .iter()
                .map(|&d| if d.is_finite() { d } else { f32::INFINITY })
                .collect(),
        }
    }

    /// A one-channel PFM image as a map of the given convention; infinite values become
    /// unknown.
    pub fn from_pfm(image: PfmImage, convention: DisparityConvention) -> Result<Self> {
        if image.channels != 1 {
            return Err(Error::Shape {
                op: "disparity map from PFM: channels".into(),
                got: vec![image.channels],
                expected: vec![1],
            });
        }
        let data = image
            .data
            .into_iter()
            .map(|d| if d.is_finite() { d } else { f32::NAN })
            .collect();
        Self::new(image.width, image.height, convention, data)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_range_reads_min_colon_max_and_refuses_an_empty_one() {
        let r: DisparityRange = "-24:8".parse().unwrap();
        assert_eq!((r.min, r.max, r.count(), r.magnitude()), (-24, 8, 32, 24));
        assert_eq!((r.at(0), r.at(31)), (-24.0, 7.0));
        assert!(r.contains(-24.0) && r.contains(7.0) && !r.contains(7.5) && !r.contains(-24.1));
        assert_eq!(r.to_string(), "-24:8");
        assert_eq!(
            DisparityRange::up_to(64).unwrap(),
            DisparityRange { min: 0, max: 64 }
        );
        for bad in ["8:8", "8:-24", "-24", "a:b", "1:99999999"] {
            let kind = bad.parse::<DisparityRange>().err().map(|e| e.kind());
            assert!(
                kind == Some("DisparityRange") || kind == Some("OutOfRange"),
                "{bad}"
            );
        }
        assert!(r.check_width(25, "the images").is_ok());
        assert_eq!(
            r.check_width(24, "the images").err().map(|e| e.kind()),
            Some("DisparityRange")
        );
    }

    #[test]
    fn pfm_marks_unknown_as_infinity_and_back() {
        let map =
            DisparityMap::new(2, 1, DisparityConvention::ColumnStep, vec![3.5, f32::NAN]).unwrap();
        let pfm = map.to_pfm();
        assert_eq!(pfm.data[1], f32::INFINITY);
        let back = DisparityMap::from_pfm(pfm, DisparityConvention::ColumnStep).unwrap();
        assert!(back.data[1].is_nan() && back.data[0] == 3.5);
        assert_eq!(back.range(), [3.5, 3.5]);
        assert!(matches!(
            DisparityMap::new(2, 2, DisparityConvention::ColumnStep, vec![0.0; 3]),
            Err(Error::Shape { .. })
        ));
    }

    #[test]
    fn only_a_horizontal_pair_reads_as_column_steps() {
        let pair =
            |axis| DisparityMap::new(1, 1, DisparityConvention::Pair { axis }, vec![2.0]).unwrap();
        let map = pair(PairAxis::Horizontal).into_column_step().unwrap();
        assert_eq!(map.convention, DisparityConvention::ColumnStep);
        assert_eq!(
            pair(PairAxis::Vertical)
                .into_column_step()
                .err()
                .map(|e| e.kind()),
            Some("Setting")
        );
        assert!(map.check(1, 1, DisparityConvention::ColumnStep).is_ok());
        assert_eq!(
            map.check(2, 1, DisparityConvention::ColumnStep)
                .err()
                .map(|e| e.kind()),
            Some("Shape")
        );
        assert_eq!(
            pair(PairAxis::Horizontal)
                .check(1, 1, DisparityConvention::ColumnStep)
                .err()
                .map(|e| e.kind()),
            Some("Setting")
        );
    }
}

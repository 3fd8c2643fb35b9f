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

use crate::image::Image;
use crate::io::PfmImage;
use crate::{Error, Result};
use serde::Serialize;

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
            other => Err(Error::mismatch(
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
            return Err(Error::mismatch(
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
            Some("Mismatch")
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
            Some("Mismatch")
        );
    }
}

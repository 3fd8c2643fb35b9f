//! What a user names to match a pair: the matching method (`match --method`,
//! `anaglyph.match(method=...)`), with the network it needs and the cost it gives, and the
//! part of a colour image that is matched. In: names and, for the learned costs, an
//! optional weights file; out: a [`MatchingCost`] and the grey plane to match.

use super::{GreyImage, MatchingCost, MatchingNetwork};
use crate::choice::named_choices;
use crate::image::Image;
use crate::{Error, Result};
use std::path::Path;

/// Rounds of mutual information, each from the previous round's disparities (census +
/// SGM first), as Hirschmüller iterates it.
pub const MUTUAL_INFORMATION_ITERATIONS: usize = 3;

/// A matching method by name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum MatchMethod {
    /// The learned cross-spectral cost, MC-CNN fast (weights built in).
    #[default]
    Mccnn,
    /// MC-CNN fast with 32 maps per layer (weights built in): about twice as fast.
    MccnnLean,
    /// MC-CNN accurate (its weights are not built in: give a model file).
    MccnnAccurate,
    /// Census transform, 7×9 window.
    Census,
    /// Zero-mean normalised cross-correlation, 9×9 window.
    Zncc,
    /// Hirschmüller's mutual information, iterated from census disparities.
    Mi,
}

named_choices!(MatchMethod, "matching method" {
    Mccnn = "mccnn" "Learned cross-spectral cost, MC-CNN fast (the default).",
    MccnnLean = "mccnn-lean" "MC-CNN fast with 32 maps a layer: about twice as fast, a little less accurate across channels.",
    MccnnAccurate = "mccnn-accurate" "MC-CNN accurate (needs a model: its weights are not embedded).",
    Census = "census" "Census transform, 7x9 window.",
    Zncc = "zncc" "Zero-mean normalised cross-correlation, 9x9 window.",
    Mi = "mi" "Hirschmüller's mutual information, iterated from census disparities.",
});

impl MatchMethod {
    /// Whether the method is a learned cost.
    pub fn is_learned(self) -> bool {
        matches!(
            self,
            MatchMethod::Mccnn | MatchMethod::MccnnLean | MatchMethod::MccnnAccurate
        )
    }

    /// The network the method needs (None for the classical costs): the weights at
    /// `model`, else the built-in fast network. A model of the other architecture, a model
    /// for a classical cost and the accurate method without a model are errors.
    pub fn network(self, model: Option<&Path>) -> Result<Option<MatchingNetwork>> {
        let network = match (self, model) {
            (m, Some(path)) if m.is_learned() => MatchingNetwork::load(path)?,
            (MatchMethod::Mccnn, None) => MatchingNetwork::default_fast()?,
            (MatchMethod::MccnnLean, None) => MatchingNetwork::lean_fast()?,
            (MatchMethod::MccnnAccurate, None) => {
                return Err(Error::unusable(
                    "method mccnn-accurate",
                    "it needs a model file (train one with `anaglyph train --arch accurate`)",
                ))
            }
            (m, Some(path)) => {
                return Err(Error::unusable(
                    format!("model {}", path.display()),
                    format!(
                        "method {m} is not learned (a model applies to mccnn, mccnn-lean or mccnn-accurate)"
                    ),
                ))
            }
            (_, None) => return Ok(None),
        };
        if (self == MatchMethod::MccnnAccurate) != network.is_accurate() {
            return Err(Error::setting(
                format!("model for method {self}"),
                format!(
                    "the {} network",
                    if network.is_accurate() {
                        "accurate"
                    } else {
                        "fast"
                    }
                ),
                format!("the network of method {self}"),
            ));
        }
        Ok(Some(network))
    }

    /// The method's cost, borrowing the network [`MatchMethod::network`] gave.
    pub fn cost(self, network: Option<&MatchingNetwork>) -> Result<MatchingCost<'_>> {
        Ok(match (self, network) {
            (MatchMethod::Census, _) => MatchingCost::Census,
            (MatchMethod::Zncc, _) => MatchingCost::Zncc,
            (MatchMethod::Mi, _) => MatchingCost::MutualInformation {
                iterations: MUTUAL_INFORMATION_ITERATIONS,
            },
            (_, Some(n)) => MatchingCost::Learned(n),
            (_, None) => {
                return Err(Error::unusable(
                    format!("method {self}"),
                    "it needs its network (MatchMethod::network)",
                ))
            }
        })
    }
}

/// Which part of a colour image is matched.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum GreyChannel {
    /// Rec. 709 luminance of RGB; grey images as they are.
    #[default]
    Luminance,
    R,
    G,
    B,
}

named_choices!(GreyChannel, "channel" {
    Luminance = "luminance" "Rec. 709 luminance of RGB (grey images as they are).",
    R = "r" "",
    G = "g" "",
    B = "b" "",
});

impl GreyChannel {
    /// The plane of `image` to match; `what` names the image in errors. A colour channel
    /// of a grey image is an error.
    pub fn of(self, image: &Image<f32>, what: &str) -> Result<GreyImage> {
        let c = image.channels;
        if !matches!(c, 1 | 3) {
            return Err(Error::raster(
                what,
                format!("{c} channels"),
                "1 (grey) or 3 (RGB)",
            ));
        }
        if c == 1 && self != GreyChannel::Luminance {
            return Err(Error::raster(
                format!("{what} with channel {self}"),
                "a grey image",
                "an RGB image (or channel luminance)",
            ));
        }
        let data = image
            .data
            .chunks_exact(c)
            .map(|p| match (c, self) {
                (1, _) => p[0],
                (_, GreyChannel::Luminance) => 0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2],
                (_, GreyChannel::R) => p[0],
                (_, GreyChannel::G) => p[1],
                (_, GreyChannel::B) => p[2],
            })
            .collect();
        Image::new(image.width, image.height, 1, data)
    }
}

//! The whole stereo chain for one rectified pair (paper section 2.2):
//! `contrast -> cost -> cross-based aggregation -> SGM -> cross-based aggregation ->
//! winner-take-all -> left–right check and filling -> subpixel -> 5×5 median -> bilateral`
//! (the right image negated first when the pair inverts contrast, [`Contrast`]), every stage
//! switchable for ablation, with per-stage timings. Costs: the learned MC-CNN (fast or
//! accurate), census, ZNCC, and mutual information (iterated from census disparities).

use super::contrast::{estimate_contrast, negated, Contrast, ContrastEstimate};
use super::{
    bilateral_filter, census_cost_volume, classify, cross_based_aggregation, fill_inconsistent,
    learned_cost_volume, learned_cost_volume_either_sign, median_filter,
    mutual_information_cost_volume, normalise_image, right_disparity, semi_global_matching,
    subpixel_disparity, windowed_subpixel, winner_take_all, zncc_cost_volume, Bilateral,
    Consistency, CostVolume, CrossAggregation, GreyImage, MatchingNetwork, SgmParameters,
};
use crate::disparity::{DisparityConvention, DisparityMap, DisparityRange, PairAxis};
use crate::{Error, Result};
use std::time::Instant;

/// A matching cost.
#[derive(Debug, Clone, Copy)]
pub enum MatchingCost<'a> {
    Learned(&'a MatchingNetwork),
    Census,
    Zncc,
    /// Hirschmüller's MI, `iterations` rounds starting from census + SGM disparities.
    MutualInformation {
        iterations: usize,
    },
}

impl MatchingCost<'_> {
    pub fn name(&self) -> &'static str {
        match self {
            MatchingCost::Learned(n) if n.is_accurate() => "mccnn-accurate",
            MatchingCost::Learned(_) => "mccnn",
            MatchingCost::Census => "census",
            MatchingCost::Zncc => "zncc",
            MatchingCost::MutualInformation { .. } => "mi",
        }
    }
}

/// What the left–right stage does.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LeftRight {
    Off,
    /// Inconsistent pixels become invalid (NaN).
    Check,
    /// Inconsistent pixels are filled (occlusions from the left, mismatches by the
    /// 16-direction median).
    CheckAndFill,
}

crate::choice::named_choices!(LeftRight, "left-right stage" {
    Off = "off" "",
    Check = "check" "Inconsistent pixels become invalid.",
    CheckAndFill = "fill" "Inconsistent pixels are filled (occlusions from the background side, mismatches by a 16-direction median).",
});

/// Every stage's settings; `None`/`Off`/`false` switches a stage off.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MatchSettings {
    /// The disparities searched (signed: `x_right = x_left − d`).
    pub range: DisparityRange,
    pub aggregation_before_sgm: Option<CrossAggregation>,
    pub sgm: Option<SgmParameters>,
    pub aggregation_after_sgm: Option<CrossAggregation>,
    pub left_right: LeftRight,
    pub subpixel: bool,
    /// With `subpixel`: None refines on the aggregated costs by a parabola (MC-CNN);
    /// Some(radius) uses [`windowed_subpixel`] on the raw costs (no pixel locking).
    pub subpixel_window: Option<usize>,
    pub median: bool,
    pub bilateral: Option<Bilateral>,
    /// Whether the right image is negated first ([`Contrast`]).
    pub contrast: Contrast,
}

impl MatchSettings {
    /// MC-CNN fast's published KITTI 2015 chain (no cross-based aggregation).
    pub fn mc_cnn_fast(range: DisparityRange) -> Self {
        MatchSettings {
            range,
            aggregation_before_sgm: None,
            sgm: Some(SgmParameters::MC_CNN_FAST_KITTI),
            aggregation_after_sgm: None,
            left_right: LeftRight::CheckAndFill,
            subpixel: true,
            subpixel_window: None,
            median: true,
            bilateral: Some(Bilateral {
                sigma: 4.64,
                threshold: 5.0,
                radius: 5,
            }),
            contrast: Contrast::Same,
        }
    }

    /// The default chain of the fast network and the classical costs: MC-CNN fast's
    /// chain with P2 at 2.64 (published 21.15 on our cost scale) and no bilateral filter,
    /// found by `examples/stereo_tuning.rs` (coordinate descent on the validation scenes:
    /// bad-2 26.6 % with the published values, 18.1 % with these).
    pub fn tuned_fast(range: DisparityRange) -> Self {
        MatchSettings {
            sgm: Some(SgmParameters {
                p2: 2.64375,
                ..SgmParameters::MC_CNN_FAST_KITTI
            }),
            bilateral: None,
            ..Self::mc_cnn_fast(range)
        }
    }

    /// MC-CNN accurate's published KITTI 2015 chain.
    pub fn mc_cnn_accurate(range: DisparityRange) -> Self {
        let cbca = |iterations| CrossAggregation {
            intensity: 0.03,
            distance: 5,
            iterations,
        };
        MatchSettings {
            aggregation_before_sgm: Some(cbca(2)),
            sgm: Some(SgmParameters::MC_CNN_ACCURATE_KITTI),
            aggregation_after_sgm: Some(cbca(4)),
            bilateral: Some(Bilateral {
                sigma: 5.99,
                threshold: 5.0,
                radius: 6,
            }),
            ..Self::mc_cnn_fast(range)
        }
    }

    /// Winner-take-all on the raw costs: every refinement stage off.
    pub fn raw(range: DisparityRange) -> Self {
        MatchSettings {
            range,
            aggregation_before_sgm: None,
            sgm: None,
            aggregation_after_sgm: None,
            left_right: LeftRight::Off,
            subpixel: false,
            subpixel_window: None,
            median: false,
            bilateral: None,
            contrast: Contrast::Same,
        }
    }

    /// The default chain for a cost: tuned for the fast network and the classical costs
    /// (the same chain for all, so that costs compare), published for the accurate one.
    pub fn for_cost(cost: &MatchingCost<'_>, range: DisparityRange) -> Self {
        match cost {
            MatchingCost::Learned(n) if n.is_accurate() => Self::mc_cnn_accurate(range),
            _ => Self::tuned_fast(range),
        }
    }

    /// MC-CNN's published chain for a cost (accurate for the accurate network, fast for
    /// everything else).
    pub fn published_for_cost(cost: &MatchingCost<'_>, range: DisparityRange) -> Self {
        match cost {
            MatchingCost::Learned(n) if n.is_accurate() => Self::mc_cnn_accurate(range),
            _ => Self::mc_cnn_fast(range),
        }
    }
}

/// A pair's disparity map (NaN where invalid) with per-stage timings.
#[derive(Debug, Clone)]
pub struct MatchOutput {
    pub disparity: DisparityMap,
    /// The vote on the pair's contrast, when [`Contrast::Auto`] asked for one.
    pub contrast: Option<ContrastEstimate>,
    /// (stage, seconds) in the order run.
    pub timings: Vec<(&'static str, f64)>,
}

/// The image scaled so that its 0.1 and 99.9 percentiles map to 0 and 1 (so that the
/// intensity thresholds of SGM and aggregation do not depend on exposure).
pub fn unit_range(image: &GreyImage) -> GreyImage {
    let mut sorted: Vec<f32> = image
        .data
        .iter()
        .cloned()
        .filter(|v| v.is_finite())
        .collect();
    if sorted.is_empty() {
        return image.clone();
    }
    let n = sorted.len();
    let lo_index = n / 1000;
    let hi_index = (n - 1 - n / 1000).max(lo_index);
    let (_, &mut lo, _) = sorted.select_nth_unstable_by(lo_index, f32::total_cmp);
    let (_, &mut hi, _) = sorted.select_nth_unstable_by(hi_index, f32::total_cmp);
    let span = if hi > lo { hi - lo } else { 1.0 };
    GreyImage {
        channels: 1,
        width: image.width,
        height: image.height,
        data: image.data.iter().map(|&v| (v - lo) / span).collect(),
    }
}

/// Refuses a pair whose matching would not fit in memory, before anything is allocated:
/// at least the cost volume (a value per pixel and disparity) and, for a learned cost,
/// one image's feature maps are held at once.
fn check_memory(left: &GreyImage, cost: &MatchingCost<'_>, settings: &MatchSettings) -> Result<()> {
    let pixels = (left.width * left.height) as u64;
    let features = match cost {
        MatchingCost::Learned(network) => network.feature_maps() as u64,
        _ => 0,
    };
    let count = settings.range.count() as u64;
    let values = pixels.saturating_mul(count.saturating_add(features));
    crate::memory::check_fits(
        &format!(
            "matching {}x{} px over {} disparities ({}; a smaller range or image needs less)",
            left.width, left.height, count, settings.range
        ),
        crate::memory::f32_bytes(values),
    )
}

fn validate(left: &GreyImage, right: &GreyImage, range: DisparityRange) -> Result<()> {
    if left.width != right.width || left.height != right.height {
        return Err(Error::Shape {
            op: "stereo matching: the right image".into(),
            got: vec![right.width, right.height],
            expected: vec![left.width, left.height],
        });
    }
    for (name, image) in [("left", left), ("right", right)] {
        if image.channels != 1 || image.data.len() != image.width * image.height {
            return Err(Error::Shape {
                op: format!("stereo matching: {name} image channels and data"),
                got: vec![image.channels, image.data.len()],
                expected: vec![1, image.width * image.height],
            });
        }
        if let Some(bad) = image.data.iter().find(|v| !v.is_finite()) {
            return Err(Error::NonFinite {
                what: format!("a value of the {name} image"),
                value: *bad as f64,
            });
        }
    }
    if left.width < 2 || left.height < 1 {
        return Err(Error::raster(
            "stereo matching: image size",
            format!("{}×{}", left.width, left.height),
            "at least 2×1",
        ));
    }
    range.check_width(left.width, "the stereo pair")
}

/// Runs the chain on a rectified pair (left is the reference).
pub fn match_pair(
    left: &GreyImage,
    right: &GreyImage,
    cost: &MatchingCost<'_>,
    settings: &MatchSettings,
) -> Result<MatchOutput> {
    validate(left, right, settings.range)?;
    check_memory(left, cost, settings)?;
    let (w, h, range) = (left.width, left.height, settings.range);
    let mut timings = Vec::new();
    let mut clock = Instant::now();
    let mut lap = |name: &'static str, timings: &mut Vec<(&'static str, f64)>| {
        timings.push((name, clock.elapsed().as_secs_f64()));
        clock = Instant::now();
    };
    let (left_unit, given_right_unit) = (unit_range(left), unit_range(right));
    let (inverted, contrast) = match settings.contrast {
        Contrast::Same | Contrast::Either => (false, None),
        Contrast::Inverted => (true, None),
        Contrast::Auto => {
            let vote = estimate_contrast(&left_unit, &given_right_unit, range);
            lap("contrast vote", &mut timings);
            (vote.inverted, Some(vote))
        }
    };
    let negated_right = inverted.then(|| negated(right));
    let right = negated_right.as_ref().unwrap_or(right);
    let right_unit = if inverted {
        unit_range(right)
    } else {
        given_right_unit
    };
    let (sgm, pair) = (
        settings.sgm.as_ref(),
        ((left, &left_unit), (right, &right_unit)),
    );
    let mut volume = if settings.contrast == Contrast::Either {
        either_sign_cost_volume(cost, pair.0, pair.1, range, sgm)
    } else {
        cost_volume(cost, pair.0, pair.1, range, sgm)
    };
    lap("cost", &mut timings);
    let raw = (settings.subpixel && settings.subpixel_window.is_some()).then(|| volume.clone());
    if let Some(cbca) = &settings.aggregation_before_sgm {
        cross_based_aggregation(&mut volume, &left_unit, &right_unit, cbca);
        lap("aggregation before SGM", &mut timings);
    }
    if let Some(p) = &settings.sgm {
        volume = semi_global_matching(&volume, &left_unit, &right_unit, p);
        lap("SGM", &mut timings);
    }
    if let Some(cbca) = &settings.aggregation_after_sgm {
        cross_based_aggregation(&mut volume, &left_unit, &right_unit, cbca);
        lap("aggregation after SGM", &mut timings);
    }
    let mut disparity = winner_take_all(&volume);
    lap("winner-take-all", &mut timings);
    if settings.left_right != LeftRight::Off {
        let classes = classify(&disparity, &right_disparity(&volume), w, range);
        disparity = if settings.left_right == LeftRight::CheckAndFill {
            fill_inconsistent(&disparity, &classes, w, h)
        } else {
            disparity
                .iter()
                .zip(&classes)
                .map(|(&d, c)| {
                    if *c == Consistency::Correct {
                        d
                    } else {
                        f32::NAN
                    }
                })
                .collect()
        };
        lap("left-right check", &mut timings);
    }
    if settings.subpixel {
        disparity = match (&raw, settings.subpixel_window) {
            (Some(raw), Some(radius)) => windowed_subpixel(raw, &disparity, radius),
            _ => subpixel_disparity(&volume, &disparity),
        };
        lap("subpixel", &mut timings);
    }
    if settings.median {
        disparity = median_filter(&disparity, w, h, 2);
        lap("median", &mut timings);
    }
    if let Some(bilateral) = &settings.bilateral {
        disparity = bilateral_filter(&disparity, &normalise_image(left), bilateral);
        lap("bilateral", &mut timings);
    }
    Ok(MatchOutput {
        disparity: DisparityMap::new(
            w,
            h,
            DisparityConvention::Pair {
                axis: PairAxis::Horizontal,
            },
            disparity,
        )?,
        contrast,
        timings,
    })
}

/// The cost volume of a pair: `left` and `right` as given (the learned cost normalises
/// them itself) and in unit range (the classical costs). Mutual information starts from
/// census disparities, refined by SGM when `sgm` is set.
fn cost_volume(
    cost: &MatchingCost<'_>,
    (left, left_unit): (&GreyImage, &GreyImage),
    (right, right_unit): (&GreyImage, &GreyImage),
    range: DisparityRange,
    sgm: Option<&SgmParameters>,
) -> CostVolume {
    let sgm_or_raw = |volume: CostVolume| match sgm {
        Some(p) => semi_global_matching(&volume, left_unit, right_unit, p),
        None => volume,
    };
    match cost {
        MatchingCost::Learned(network) => learned_cost_volume(network, left, right, range),
        MatchingCost::Census => census_cost_volume(left_unit, right_unit, range),
        MatchingCost::Zncc => zncc_cost_volume(left_unit, right_unit, range),
        MatchingCost::MutualInformation { iterations } => {
            let census = census_cost_volume(left_unit, right_unit, range);
            let mut disparity = winner_take_all(&sgm_or_raw(census));
            let mut volume =
                mutual_information_cost_volume(left_unit, right_unit, range, &disparity);
            for _ in 1..*iterations {
                disparity = winner_take_all(&sgm_or_raw(volume));
                volume = mutual_information_cost_volume(left_unit, right_unit, range, &disparity);
            }
            volume
        }
    }
}

/// [`cost_volume`] for either sign of the right image at every pixel and disparity: the
/// lower of the costs against `right` and against it negated.
fn either_sign_cost_volume(
    cost: &MatchingCost<'_>,
    left: (&GreyImage, &GreyImage),
    right: (&GreyImage, &GreyImage),
    range: DisparityRange,
    sgm: Option<&SgmParameters>,
) -> CostVolume {
    if let MatchingCost::Learned(network) = cost {
        return learned_cost_volume_either_sign(network, left.0, right.0, range);
    }
    let negated_right = negated(right.0);
    let negated_unit = unit_range(&negated_right);
    let mut volume = cost_volume(cost, left, right, range, sgm);
    volume.keep_lower(&cost_volume(
        cost,
        left,
        (&negated_right, &negated_unit),
        range,
        sgm,
    ));
    volume
}

/// The image with rows and columns swapped.
pub fn transpose(image: &GreyImage) -> GreyImage {
    let (w, h) = (image.width, image.height);
    GreyImage {
        channels: 1,
        width: h,
        height: w,
        data: (0..w * h)
            .map(|i| image.data[(i % h) * w + i / h])
            .collect(),
    }
}

/// Runs the chain on a vertical pair: `top` is the reference and `bottom` the camera one
/// row below, so `y_bottom = y_top − d` (the column convention turned by 90°). Matches the
/// transposed images and transposes the disparity back.
pub fn match_vertical(
    top: &GreyImage,
    bottom: &GreyImage,
    cost: &MatchingCost<'_>,
    settings: &MatchSettings,
) -> Result<MatchOutput> {
    let out = match_pair(&transpose(top), &transpose(bottom), cost, settings)?;
    let transposed = GreyImage {
        channels: 1,
        width: out.disparity.width,
        height: out.disparity.height,
        data: out.disparity.data,
    };
    let back = transpose(&transposed);
    Ok(MatchOutput {
        disparity: DisparityMap::new(
            back.width,
            back.height,
            DisparityConvention::Pair {
                axis: PairAxis::Vertical,
            },
            back.data,
        )?,
        contrast: out.contrast,
        timings: out.timings,
    })
}

//! Heterogeneous stereo matching (paper section 2.2), the stage
//! `captures -> stereo (cost -> aggregate -> sgm -> refine)`. In: a rectified pair, left as
//! reference; out: a disparity map with the Middlebury sign (`x_right = x_left − d`, over
//! a signed [`DisparityRange`], NaN where invalid). Costs: the learned cross-spectral
//! MC-CNN (weights from `anaglyph-cnn`, its tower in plain Rust), census, ZNCC and
//! mutual information, in a common [`CostVolume`]; then cross-based aggregation,
//! semi-global matching, winner-take-all, left–right check with filling, subpixel,
//! median and bilateral filtering, chained by [`match_pair`].

#[cfg(target_arch = "x86_64")]
mod amx;
mod census;
mod contrast;
mod cost_volume;
mod cross_aggregation;
mod disparity_filters;
mod learned;
mod matcher;
mod method;
mod mutual_information;
mod network;
mod refine;
mod sgm;
mod tower;
mod winograd;
mod zncc;

pub use census::census_cost_volume;
pub use contrast::{estimate_contrast, negated, Contrast, ContrastEstimate, INVERTED_SHARE};
pub use cost_volume::{CostVolume, DisparityRange, GreyImage};
pub use cross_aggregation::{cross_based_aggregation, CrossAggregation};
pub use disparity_filters::{
    bilateral_filter, classify, fill_inconsistent, median_filter, right_disparity, Bilateral,
    Consistency,
};
pub use learned::{cosine_costs, learned_cost_volume, learned_cost_volume_either_sign};
pub use matcher::{
    match_pair, match_vertical, transpose, unit_range, LeftRight, MatchOutput, MatchSettings,
    MatchingCost,
};
pub use method::{GreyChannel, MatchMethod, MUTUAL_INFORMATION_ITERATIONS};
pub use mutual_information::{mutual_information_cost_volume, mutual_information_table, BINS};
pub use network::{ConvLayer, DenseLayer, MatchingNetwork, DEFAULT_FAST_WEIGHTS};
pub use refine::{
    left_right_check, subpixel_disparity, windowed_subpixel, winner_take_all, LEFT_RIGHT_TOLERANCE,
};
pub use sgm::{semi_global_matching, SgmParameters};
pub use tower::{normalise_image, tower_features, tower_features_mapped, FeatureMap};
pub use zncc::zncc_cost_volume;

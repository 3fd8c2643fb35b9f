//! Heterogeneous stereo matching (paper section 2.2), the stage
//! `captures -> stereo (cost -> aggregate -> sgm -> refine)`. In: a rectified pair, left as
//! reference; out: a disparity map with the Middlebury sign (`x_right = x_left − d`,
//! search range `[0, max_disp)`, NaN where invalid). So far the classical costs (census,
//! ZNCC) in a common [`CostVolume`], semi-global matching, and the winner-take-all with
//! left–right check and subpixel refinement; the learned cross-spectral cost comes next.

mod census;
mod cost_volume;
mod refine;
mod sgm;
mod zncc;

pub use census::census_cost_volume;
pub use cost_volume::{CostVolume, GreyImage};
pub use refine::{left_right_check, subpixel_disparity, winner_take_all, LEFT_RIGHT_TOLERANCE};
pub use sgm::{semi_global_matching, SgmParameters};
pub use zncc::zncc_cost_volume;

//! The camera array: its geometry, each camera's sensor and filter, the illuminant, and
//! the reconstruction grid (paper sections 2.1 and 3.1), loaded from a TOML rig file;
//! and the sensing matrix C of Eqs. 2–3 that maps a spectrum to the array's 3M
//! measurements, built so that it accounts for all the light the cameras integrate.

mod layout;
mod response_plot;
mod rig_file;
mod sensing;

pub use layout::{grid_name, MAX_FREE_CAMERAS, MAX_NEIGHBOUR_SPACING};
pub use response_plot::plot_effective_responses;
pub use rig_file::{
    curve_file, resolve_curve, resolve_optional_curve, Baseline, Camera, CameraEntry,
    ReconstructionSettings, Rig, RigFile, BUILTIN_PREFIX, MAX_BANDS, MAX_RIG_SIDE,
    MIN_PLANE_BASELINES, PAPER_RIG, PAPER_RIG_FILTERS, RIG_PRESETS,
};
pub use sensing::{
    check_filters, condition_from_singular_values, EffectiveResponses, OutOfBand, SensingMatrix,
    ILL_CONDITIONED_WARNING,
};

//! Wide-band colour filters: the modelled gel library that stands in for the paper's
//! ~18 plastic filters, calibration of a filter from spectrometer readings with and
//! without it (section 3.2, Eq. 7), and the choice of the subset that makes the
//! sensing matrix best conditioned or least noisy (section 3.2, "Filter selection");
//! nominal narrow-band filters from their centre and width (`gaussian:550:40`).

mod calibration;
mod gel_model;
mod nominal;
mod selection;

pub use calibration::{calibrate_filter, FilterCalibration};
pub use gel_model::{gel_library, GelFilter, GelShape, GEL_LIBRARY_SHAPE};
pub use nominal::{gaussian_filter, nominal_centre, GAUSSIAN_PREFIX, NOMINAL_RANGE_NM};
pub use selection::{
    builtin_candidates, select_filters, select_for_sensor, NoiseModel, SelectionCamera,
    SelectionCriterion, SelectionOptions, SelectionReport, SubsetScore, EXHAUSTIVE_LIMIT,
    SELECTION_PRIOR,
};

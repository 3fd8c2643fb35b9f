//! What a camera records (paper Eq. 1): the forward model that integrates a spectrum
//! against every channel's effective response on the fine grid, and the sensor noise
//! (photon shot noise, read noise, quantisation, clipping) of a real exposure. Shared by
//! the demo, the tests and the simulator, and deliberately independent of C's hat basis:
//! spectra enter at 1 nm, so a reconstruction on 8 nm knots never sees its own model.

mod forward;
mod noise;

pub use forward::{measure_spectra, spectra_on_grid};
pub use noise::{CameraNoise, NoisyMeasurements};

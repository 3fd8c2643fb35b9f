//! The physically based simulator of a filtered camera array (stage `scene -> captures`):
//! every view of a rig looking at a [`crate::scene::Scene`] is ray cast with supersampling,
//! the reflectance of each pixel is kept on the 5 nm grid over the sensors' whole support,
//! and each camera records `∫ reflectance × illuminant × filter × sensor` (Eq. 1) through
//! the same effective responses and integration code as the sensing matrix, with shot and
//! read noise, quantisation, clipping and a per-camera exposure. Ground truth comes out
//! alongside: reflectance at the reconstruction bands, depth and disparity.
//!
//! The simulator renders on a finer (5 nm) and wider (whole support) grid than the
//! reconstruction assumes (8 nm knots), so tests never commit the inverse crime.

mod contact_sheet;
mod dark;
mod output;
mod render;

pub use contact_sheet::write_contact_sheet;
pub use dark::{DarkSignal, DARK_FRAMES, MAX_DARK_LEVEL};
pub use output::{write_simulation, write_simulation_frames};
pub use render::{
    render_view, PoseJitter, RenderedView, Simulation, SimulationSettings, NOISE_FREE_EXPOSURE,
};

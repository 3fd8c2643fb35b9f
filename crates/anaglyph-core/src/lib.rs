//! # anaglyph-core
//!
//! The spectral core of anaglyph: from spectral curves and a camera-array rig to the
//! reconstructed spectrum of every pixel. Modules follow the data flow of the pipeline:
//!
//! ```text
//! spectrum (curves) + filters + rig -> sensing matrix C -> capture (forward model, noise)
//! checkerboard captures -> plane_calibration (homographies onto the reference camera)
//! scene -> simulate -> captures -> rectify -> stereo -> register (disparity per view, warp)
//!   -> solve (per view: demux's Eq. 6, then the stages that repair what registration
//!      got wrong) -> refine (guided by each view's own capture)
//!   -> reconstruct (the driver of all of the above: the light field) -> metrics
//! io for the file formats at the edges
//! ```
//!
//! ```
//! use anaglyph_core::{builtin, demux, rig::{Rig, SensingMatrix}};
//! # fn main() -> anaglyph_core::Result<()> {
//! let file = Rig::paper_rig_file(&[
//!     "gel_yellow", "gel_red", "gel_magenta", "gel_blue",
//!     "gel_cyan", "gel_green", "gel_orange", "gel_violet",
//! ]);
//! let rig = Rig::from_file(file, ".".into())?;
//! let c = SensingMatrix::of_rig(&rig)?;               // 24 × (24 + out-of-band knots)
//! let mut p = vec![0.0; c.rows()];
//! c.apply(&vec![0.5; c.cols()], &mut p);              // a flat 50 % grey
//! let bands = c.reported_offset..c.reported_offset + c.reported.count;
//! let (s, _) = demux::demultiplex(c.values(), c.rows(), &p, None, bands, &Default::default())?;
//! assert!(s.iter().all(|v| (v - 0.5).abs() < 1e-3));
//! # Ok(()) }
//! ```

// `!(x > 0.0)` is used on purpose: unlike `x <= 0.0` it also rejects NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]
// Small dense linear algebra reads best with explicit indices.
#![allow(clippy::needless_range_loop)]

pub mod builtin;
pub mod capture;
pub mod choice;
mod cpu;
pub mod demux;
pub mod disparity;
mod error;
pub mod evaluation;
pub mod filters;
pub mod image;
pub mod interpolation;
pub mod io;
pub mod memory;
pub mod metrics;
pub mod plane_calibration;
pub mod reconstruct;
pub mod rectify;
pub mod refine;
pub mod register;
pub mod rig;
pub mod scene;
mod scratch;
pub mod simulate;
pub mod solve;
pub mod spectrum;
pub mod stereo;

pub use error::{Error, ErrorClass, Result, ERROR_KINDS};

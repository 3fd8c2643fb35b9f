//! The core's integration tests, each file a module of this one binary (one link step
//! instead of five): the simulator, the spectral core, stereo, rectification and the
//! whole reconstruction, against truth the code under test does not compute.

mod plane_calibration;
mod reconstruction;
mod rectification;
mod simulator;
mod spectral_core;
mod stereo;
mod temporal_reuse;
mod zarr_store;

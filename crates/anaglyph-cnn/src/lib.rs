//! # anaglyph-cnn
//!
//! The cross-spectral matching network of anaglyph (paper section 2.2, after Zbontar &
//! LeCun, JMLR 2016). This crate is the only one that will link candle, for training; the
//! rest of the workspace stays light. It holds the network architectures, their
//! published hyper-parameters and the shape arithmetic both training and inference share.

mod architecture;

pub use architecture::{Architecture, ArchitectureError, FC_UNITS_ACCURATE, KERNEL};

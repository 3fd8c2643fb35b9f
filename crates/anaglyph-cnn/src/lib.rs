//! # anaglyph-cnn
//!
//! Training of the cross-spectral matching network of anaglyph (paper section 2.2, after
//! Zbontar & LeCun, JMLR 2016). This crate is the only one that links candle: it holds the
//! architectures, the training data drawn from the simulator, the candle model and the
//! training loop. Inference runs in `anaglyph_core::stereo` (im2col + gemm), which reads
//! the safetensors files written here.

mod architecture;
pub mod checkpoint;
pub mod dataset;
pub mod model;
pub mod optimiser;
pub mod train;

pub use architecture::{Architecture, ArchitectureError, FC_UNITS_ACCURATE, KERNEL};
pub use checkpoint::Checkpoint;
pub use model::MatchingNet;
pub use train::{
    train, train_segment, Outcome, Segment, TrainSettings, TrainedModel, ValidationPoint,
};

/// Errors of training.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error(transparent)]
    Candle(#[from] candle_core::Error),
    #[error(transparent)]
    Core(#[from] anaglyph_core::Error),
    #[error(transparent)]
    Architecture(#[from] ArchitectureError),
    #[error("cannot serialise the model: {0}")]
    Serialise(String),
    #[error(
        "found only {filled} of {wanted} training triplets in {attempts} draws: the pairs have \
         no pixel with known disparity whose patches fit inside the image (images too small?)"
    )]
    NoTrainingPixels {
        attempts: usize,
        filled: usize,
        wanted: usize,
    },
    #[error("training checkpoint {0}")]
    Checkpoint(String),
    #[error("training diverged at step {step} (loss {loss})")]
    Diverged { step: usize, loss: f64 },
}

pub type Result<T> = std::result::Result<T, Error>;

//! MC-CNN architectures: a Siamese tower of 3×3 convolutions with ReLU between layers,
//! and for the accurate variant four fully connected layers over the concatenated
//! features. Values from Zbontar & LeCun (2016), Table 3 (KITTI 2015), and the paper
//! (4 × 112 conv maps, 4 × 384 FC units).

use serde::{Deserialize, Serialize};

/// Convolution kernel side.
pub const KERNEL: usize = 3;
/// Units per fully connected layer of the accurate network (the paper: 384).
pub const FC_UNITS_ACCURATE: usize = 384;

/// Errors in an architecture description.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ArchitectureError {
    #[error("{what} is {got} (expected {expected})")]
    OutOfRange {
        what: &'static str,
        got: usize,
        expected: &'static str,
    },
}

/// A matching-network architecture.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Architecture {
    /// Cosine similarity of L2-normalised tower outputs (default: 4 layers × 64 maps).
    Fast {
        conv_layers: usize,
        feature_maps: usize,
    },
    /// Concatenated tower outputs through fully connected layers and a sigmoid
    /// (the paper: 4 conv layers × 112 maps, 4 FC layers × 384 units).
    Accurate {
        conv_layers: usize,
        feature_maps: usize,
        fc_layers: usize,
        fc_units: usize,
    },
}

impl Architecture {
    /// MC-CNN fast, KITTI setting.
    pub const FAST: Architecture = Architecture::Fast {
        conv_layers: 4,
        feature_maps: 64,
    };
    /// MC-CNN accurate as used by the paper.
    pub const ACCURATE: Architecture = Architecture::Accurate {
        conv_layers: 4,
        feature_maps: 112,
        fc_layers: 4,
        fc_units: FC_UNITS_ACCURATE,
    };

    /// Side of the square patch one output pixel sees: `1 + layers · (KERNEL − 1)`.
    pub fn receptive_field(&self) -> usize {
        1 + self.conv_layers() * (KERNEL - 1)
    }

    pub fn conv_layers(&self) -> usize {
        match *self {
            Architecture::Fast { conv_layers, .. } | Architecture::Accurate { conv_layers, .. } => {
                conv_layers
            }
        }
    }

    pub fn feature_maps(&self) -> usize {
        match *self {
            Architecture::Fast { feature_maps, .. }
            | Architecture::Accurate { feature_maps, .. } => feature_maps,
        }
    }

    /// Number of trainable parameters (weights and biases) for single-channel input.
    pub fn parameter_count(&self) -> usize {
        let maps = self.feature_maps();
        let k2 = KERNEL * KERNEL;
        let tower = (k2 + 1) * maps + (self.conv_layers() - 1) * (k2 * maps + 1) * maps;
        match *self {
            Architecture::Fast { .. } => tower,
            Architecture::Accurate {
                fc_layers,
                fc_units,
                ..
            } => {
                let first = (2 * maps + 1) * fc_units;
                let hidden = (fc_layers - 1) * (fc_units + 1) * fc_units;
                tower + first + hidden + fc_units + 1
            }
        }
    }

    /// Checks the sizes are usable.
    pub fn validate(&self) -> Result<(), ArchitectureError> {
        let check = |what, got: usize, lo: usize, hi: usize, expected| {
            if got < lo || got > hi {
                Err(ArchitectureError::OutOfRange {
                    what,
                    got,
                    expected,
                })
            } else {
                Ok(())
            }
        };
        check("conv_layers", self.conv_layers(), 1, 16, "1 to 16")?;
        check("feature_maps", self.feature_maps(), 1, 1024, "1 to 1024")?;
        if let Architecture::Accurate {
            fc_layers,
            fc_units,
            ..
        } = *self
        {
            check("fc_layers", fc_layers, 1, 16, "1 to 16")?;
            check("fc_units", fc_units, 1, 4096, "1 to 4096")?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn published_architectures_have_a_9x9_receptive_field() {
        assert_eq!(Architecture::FAST.receptive_field(), 9);
        assert_eq!(Architecture::ACCURATE.receptive_field(), 9);
        // Fast: 10·64 + 3·(9·64 + 1)·64 = 111 424 parameters.
        assert_eq!(Architecture::FAST.parameter_count(), 640 + 3 * 577 * 64);
        Architecture::ACCURATE.validate().unwrap();
        let bad = Architecture::Fast {
            conv_layers: 0,
            feature_maps: 64,
        };
        assert!(bad.validate().is_err());
    }
}

//! Trained weights of the cross-spectral matching network (MC-CNN, Zbontar & LeCun 2016),
//! read from safetensors: the input of the learned cost in the stage
//! `captures -> stereo (cost -> ...)`. Training happens in the `anaglyph-cnn` crate with
//! candle; this side only reads the tensors it wrote, so that inference needs no candle.
//!
//! Tensor names and layouts (candle's): `conv{i}.weight` `[out, in, 3, 3]`,
//! `conv{i}.bias` `[out]`, and for the accurate network `fc{j}.weight` `[out, in]`,
//! `fc{j}.bias` `[out]`, the last FC layer having one output (a sigmoid follows).

use crate::{Error, Result};
use safetensors::{Dtype, SafeTensors};

/// The default fast network, trained on simulated cross-spectral pairs (see
/// `models/README.md` for the command that reproduces it).
pub const DEFAULT_FAST_WEIGHTS: &[u8] =
    include_bytes!("../../../../models/mccnn-fast-12k.safetensors");

/// The lean fast network: the default's recipe with 32 maps per layer instead of 64,
/// about a quarter of the tower's products (`models/README.md` has its command and
/// figures).
pub const LEAN_FAST_WEIGHTS: &[u8] =
    include_bytes!("../../../../models/mccnn-fast32-12k.safetensors");

/// Side of every convolution kernel.
pub const KERNEL: usize = 3;

/// One 3×3 convolution, weights rearranged for im2col: `weight[(ky·3 + kx)·in + c][out]`.
#[derive(Debug, Clone, PartialEq)]
pub struct ConvLayer {
    pub inputs: usize,
    pub outputs: usize,
    pub weight: Vec<f32>,
    pub bias: Vec<f32>,
}

/// One fully connected layer, weights transposed to `weight[in][out]`.
#[derive(Debug, Clone, PartialEq)]
pub struct DenseLayer {
    pub inputs: usize,
    pub outputs: usize,
    pub weight: Vec<f32>,
    pub bias: Vec<f32>,
}

/// A matching network: a convolutional tower (ReLU between layers, none after the last)
/// and, for the accurate variant, fully connected layers over the two concatenated
/// feature vectors (ReLU between, a sigmoid at the end).
#[derive(Debug, Clone, PartialEq)]
pub struct MatchingNetwork {
    pub conv: Vec<ConvLayer>,
    pub dense: Vec<DenseLayer>,
    /// The safetensors metadata (architecture, training recipe), if any.
    pub metadata: Vec<(String, String)>,
}

impl MatchingNetwork {
    /// The default shipped fast network.
    pub fn default_fast() -> Result<Self> {
        Self::from_safetensors(DEFAULT_FAST_WEIGHTS, "built-in mccnn-fast")
    }

    /// The shipped lean fast network ([`LEAN_FAST_WEIGHTS`]).
    pub fn lean_fast() -> Result<Self> {
        Self::from_safetensors(LEAN_FAST_WEIGHTS, "built-in mccnn-lean")
    }

    /// Reads a network from the bytes of a safetensors file.
    pub fn from_safetensors(bytes: &[u8], context: &str) -> Result<Self> {
        let invalid = |message: String| Error::decode(context, message);
        let (_, header) = SafeTensors::read_metadata(bytes)
            .map_err(|e| invalid(format!("not a safetensors file ({e})")))?;
        let tensors = SafeTensors::deserialize(bytes)
            .map_err(|e| invalid(format!("not a safetensors file ({e})")))?;
        let tensor = |name: &str| -> Result<(Vec<usize>, Vec<f32>)> {
            let view = tensors
                .tensor(name)
                .map_err(|_| invalid(format!("tensor '{name}' is missing")))?;
            if view.dtype() != Dtype::F32 {
                return Err(invalid(format!(
                    "tensor '{name}' is {:?}, expected F32",
                    view.dtype()
                )));
            }
            let values: Vec<f32> = view
                .data()
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect();
            if let Some(bad) = values.iter().find(|v| !v.is_finite()) {
                return Err(invalid(format!("tensor '{name}' holds {bad}")));
            }
            Ok((view.shape().to_vec(), values))
        };
        let mut conv = Vec::new();
        while tensors
            .tensor(&format!("conv{}.weight", conv.len()))
            .is_ok()
        {
            let i = conv.len();
            let (shape, w) = tensor(&format!("conv{i}.weight"))?;
            let (bias_shape, bias) = tensor(&format!("conv{i}.bias"))?;
            let expected_inputs = conv.last().map_or(1, |l: &ConvLayer| l.outputs);
            if shape.len() != 4
                || shape[1] != expected_inputs
                || shape[2] != KERNEL
                || shape[3] != KERNEL
                || bias_shape != [shape[0]]
            {
                return Err(Error::Shape {
                    op: format!("{context}: conv{i}"),
                    got: [shape.clone(), bias_shape].concat(),
                    expected: vec![shape[0], expected_inputs, KERNEL, KERNEL, shape[0]],
                });
            }
            let (outputs, inputs) = (shape[0], shape[1]);
            let mut weight = vec![0f32; KERNEL * KERNEL * inputs * outputs];
            for o in 0..outputs {
                for c in 0..inputs {
                    for k in 0..KERNEL * KERNEL {
                        weight[(k * inputs + c) * outputs + o] =
                            w[(o * inputs + c) * KERNEL * KERNEL + k];
                    }
                }
            }
            conv.push(ConvLayer {
                inputs,
                outputs,
                weight,
                bias,
            });
        }
        if conv.is_empty() {
            return Err(invalid("no conv0.weight tensor".into()));
        }
        let features = conv.last().map_or(0, |l| l.outputs);
        let mut dense = Vec::new();
        while tensors.tensor(&format!("fc{}.weight", dense.len())).is_ok() {
            let j = dense.len();
            let (shape, w) = tensor(&format!("fc{j}.weight"))?;
            let (bias_shape, bias) = tensor(&format!("fc{j}.bias"))?;
            let expected_inputs = dense
                .last()
                .map_or(2 * features, |l: &DenseLayer| l.outputs);
            if shape.len() != 2 || shape[1] != expected_inputs || bias_shape != [shape[0]] {
                return Err(Error::Shape {
                    op: format!("{context}: fc{j}"),
                    got: [shape.clone(), bias_shape].concat(),
                    expected: vec![shape[0], expected_inputs, shape[0]],
                });
            }
            let (outputs, inputs) = (shape[0], shape[1]);
            let mut weight = vec![0f32; inputs * outputs];
            for o in 0..outputs {
                for i in 0..inputs {
                    weight[i * outputs + o] = w[o * inputs + i];
                }
            }
            dense.push(DenseLayer {
                inputs,
                outputs,
                weight,
                bias,
            });
        }
        if dense.last().is_some_and(|l| l.outputs != 1) {
            return Err(invalid(format!(
                "the last fully connected layer has {} outputs, expected 1",
                dense.last().map_or(0, |l| l.outputs)
            )));
        }
        let mut metadata: Vec<(String, String)> = header
            .metadata()
            .as_ref()
            .map(|m| m.iter().map(|(k, v)| (k.clone(), v.clone())).collect())
            .unwrap_or_default();
        metadata.sort();
        Ok(MatchingNetwork {
            conv,
            dense,
            metadata,
        })
    }

    /// Reads a network from a safetensors file.
    pub fn load(path: &std::path::Path) -> Result<Self> {
        let bytes = std::fs::read(path).map_err(|source| Error::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_safetensors(&bytes, &path.display().to_string())
    }

    /// Whether this is the accurate variant (fully connected layers after the towers).
    pub fn is_accurate(&self) -> bool {
        !self.dense.is_empty()
    }

    /// Feature maps of the tower's output.
    pub fn feature_maps(&self) -> usize {
        self.conv.last().map_or(0, |l| l.outputs)
    }

    /// Side of the patch one output pixel sees.
    pub fn receptive_field(&self) -> usize {
        1 + self.conv.len() * (KERNEL - 1)
    }

    /// A metadata value, if the file carries it.
    pub fn metadata(&self, key: &str) -> Option<&str> {
        self.metadata
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    }
}

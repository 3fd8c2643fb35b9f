//! The trainable MC-CNN in candle: a Siamese tower of 3×3 convolutions and, for the
//! accurate variant, fully connected layers over the concatenated features. Tensor names
//! (`conv{i}.*`, `fc{j}.*`) are those `anaglyph_core::stereo::MatchingNetwork` reads, so
//! a trained model goes straight to the plain-Rust inference path.

use crate::Architecture;
use candle_core::{DType, Device, Module, Result, Tensor, D};
use candle_nn::{Conv2d, Conv2dConfig, Linear, VarBuilder, VarMap};
use std::collections::HashMap;

/// A matching network with its variables.
pub struct MatchingNet {
    pub architecture: Architecture,
    pub varmap: VarMap,
    conv: Vec<Conv2d>,
    fc: Vec<Linear>,
}

impl MatchingNet {
    /// A freshly initialised network (candle's default Kaiming-uniform initialisation,
    /// seeded through the device).
    pub fn new(architecture: Architecture, device: &Device) -> Result<Self> {
        let varmap = VarMap::new();
        let vb = VarBuilder::from_varmap(&varmap, DType::F32, device);
        let maps = architecture.feature_maps();
        let conv = (0..architecture.conv_layers())
            .map(|i| {
                let inputs = if i == 0 { 1 } else { maps };
                candle_nn::conv2d(
                    inputs,
                    maps,
                    crate::KERNEL,
                    Conv2dConfig::default(),
                    vb.pp(format!("conv{i}")),
                )
            })
            .collect::<Result<Vec<_>>>()?;
        let fc = match architecture {
            Architecture::Fast { .. } => Vec::new(),
            Architecture::Accurate {
                fc_layers,
                fc_units,
                ..
            } => (0..fc_layers)
                .map(|j| {
                    let inputs = if j == 0 { 2 * maps } else { fc_units };
                    let outputs = if j + 1 == fc_layers { 1 } else { fc_units };
                    candle_nn::linear(inputs, outputs, vb.pp(format!("fc{j}")))
                })
                .collect::<Result<Vec<_>>>()?,
        };
        Ok(MatchingNet {
            architecture,
            varmap,
            conv,
            fc,
        })
    }

    fn is_accurate(&self) -> bool {
        matches!(self.architecture, Architecture::Accurate { .. })
    }

    /// Tower over `[n, 1, h, w]` images; `padded` gives "same" convolutions (inference on
    /// whole images), otherwise valid ones (a 9×9 patch becomes one feature vector). ReLU
    /// between layers, and after the last for the accurate network.
    pub fn tower(&self, images: &Tensor, padded: bool) -> Result<Tensor> {
        let mut x = images.clone();
        let layers = self.conv.len();
        for (i, conv) in self.conv.iter().enumerate() {
            x = if padded {
                let y = x.conv2d(conv.weight(), 1, 1, 1, 1)?;
                match conv.bias() {
                    Some(b) => y.broadcast_add(&b.reshape((1, b.dim(0)?, 1, 1))?)?,
                    None => y,
                }
            } else {
                conv.forward(&x)?
            };
            if i + 1 < layers || self.is_accurate() {
                x = x.relu()?;
            }
        }
        Ok(x)
    }

    /// Feature vectors `[n, maps]` of `[n, 1, 9, 9]` patches (L2-normalised for the fast
    /// network).
    pub fn patch_features(&self, patches: &Tensor) -> Result<Tensor> {
        let f = self.tower(patches, false)?.flatten_from(1)?;
        if self.is_accurate() {
            Ok(f)
        } else {
            l2_normalise(&f)
        }
    }

    /// Similarity logits (accurate) or cosine similarities (fast) of feature pairs.
    pub fn similarity(&self, left: &Tensor, right: &Tensor) -> Result<Tensor> {
        if self.is_accurate() {
            let mut x = Tensor::cat(&[left, right], 1)?;
            for (j, fc) in self.fc.iter().enumerate() {
                x = fc.forward(&x)?;
                if j + 1 < self.fc.len() {
                    x = x.relu()?;
                }
            }
            x.squeeze(1)
        } else {
            (left * right)?.sum(1)
        }
    }

    /// The variables as safetensors bytes, with `metadata`.
    pub fn to_safetensors(&self, metadata: HashMap<String, String>) -> crate::Result<Vec<u8>> {
        let data = self
            .varmap
            .data()
            .lock()
            .map_err(|_| crate::Error::Serialise("the variable map lock is poisoned".into()))?;
        let mut tensors: Vec<(String, Tensor)> = data
            .iter()
            .map(|(k, v)| (k.clone(), v.as_tensor().clone()))
            .collect();
        tensors.sort_by(|a, b| a.0.cmp(&b.0));
        safetensors::serialize(tensors, Some(metadata))
            .map_err(|e| crate::Error::Serialise(e.to_string()))
    }
}

/// Rows divided by their L2 norms.
pub fn l2_normalise(x: &Tensor) -> Result<Tensor> {
    let norm = x
        .sqr()?
        .sum_keepdim(D::Minus1)?
        .sqrt()?
        .clamp(1e-8, f64::MAX)?;
    x.broadcast_div(&norm)
}

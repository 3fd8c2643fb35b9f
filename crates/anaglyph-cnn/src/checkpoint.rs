//! A training run's full state at a step, so that a run can stop and continue bit for bit:
//! the weights, the optimiser's moments and update count, the sampler's random stream
//! position, the loss accumulated since the last validation, the curve so far, the time
//! spent, and the recipe ([`TrainSettings`]) the run must keep.
//!
//! Stored as one safetensors file: the tensors (weights under their names, moments under
//! `adamw.first_moment/…` and `adamw.second_moment/…`) and the rest as metadata (numbers
//! written so that they read back exactly).

use crate::train::{TrainSettings, ValidationPoint};
use crate::{Error, Result};
use candle_core::{Device, Tensor};
use std::collections::{BTreeMap, HashMap};
use std::path::Path;

/// The metadata key that marks a file as a training checkpoint, and its format version.
const FORMAT_KEY: &str = "anaglyph_training_checkpoint";
const FORMAT_VERSION: &str = "1";

/// Where a training run stands after a step.
#[derive(Debug, Clone)]
pub struct Checkpoint {
    pub settings: TrainSettings,
    /// Steps done.
    pub step: usize,
    /// Weights and optimiser moments by name.
    pub tensors: HashMap<String, Tensor>,
    /// Optimiser updates taken (equal to `step`).
    pub optimiser_steps: usize,
    /// Position of the sampler's random stream (ChaCha8 words).
    pub rng_word_pos: u128,
    /// Training loss summed since the last validation point, and over how many steps.
    pub loss_sum: f64,
    pub loss_count: usize,
    /// Training time so far, seconds (all segments).
    pub seconds: f64,
    pub curve: Vec<ValidationPoint>,
    /// What the caller keeps with the run (e.g. the command that started it), carried
    /// from segment to segment.
    pub notes: BTreeMap<String, String>,
}

/// Prefix of the notes' metadata keys.
const NOTE: &str = "note.";

impl Checkpoint {
    /// The checkpoint as safetensors bytes.
    pub fn to_bytes(&self) -> Result<Vec<u8>> {
        let mut tensors: Vec<(&String, &Tensor)> = self.tensors.iter().collect();
        tensors.sort_by(|a, b| a.0.cmp(b.0));
        let json = |what: &str, r: serde_json::Result<String>| {
            r.map_err(|e| Error::Serialise(format!("{what}: {e}")))
        };
        let metadata: HashMap<String, String> = [
            (FORMAT_KEY, FORMAT_VERSION.to_string()),
            (
                "settings",
                json("settings", serde_json::to_string(&self.settings))?,
            ),
            ("step", self.step.to_string()),
            ("optimiser_steps", self.optimiser_steps.to_string()),
            ("rng_word_pos", self.rng_word_pos.to_string()),
            // Rust writes the shortest decimal that reads back as the same f64.
            ("loss_sum", self.loss_sum.to_string()),
            ("loss_count", self.loss_count.to_string()),
            ("seconds", self.seconds.to_string()),
            ("curve", json("curve", serde_json::to_string(&self.curve))?),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_string(), v))
        .chain(
            self.notes
                .iter()
                .map(|(k, v)| (format!("{NOTE}{k}"), v.clone())),
        )
        .collect();
        safetensors::serialize(tensors, Some(metadata)).map_err(|e| Error::Serialise(e.to_string()))
    }

    /// Reads a checkpoint written by [`Checkpoint::to_bytes`]; `context` names the file.
    pub fn from_bytes(bytes: &[u8], context: &str) -> Result<Self> {
        let bad = |what: String| Error::Checkpoint(format!("{context}: {what}"));
        let (_, header) = safetensors::SafeTensors::read_metadata(bytes)
            .map_err(|e| bad(format!("not a safetensors file ({e})")))?;
        let metadata = header.metadata().clone().unwrap_or_default();
        match metadata.get(FORMAT_KEY).map(String::as_str) {
            Some(FORMAT_VERSION) => {}
            Some(other) => {
                return Err(bad(format!(
                    "checkpoint format {other} (expected {FORMAT_VERSION})"
                )))
            }
            None => {
                return Err(bad(
                    "safetensors without a training state (expected a checkpoint that \
                     `anaglyph train --checkpoint` wrote, not trained weights)"
                        .into(),
                ))
            }
        }
        let field = |key: &str| {
            metadata
                .get(key)
                .ok_or_else(|| bad(format!("the checkpoint lacks '{key}'")))
        };
        fn number<T: std::str::FromStr>(
            text: &str,
            key: &str,
            bad: &dyn Fn(String) -> Error,
        ) -> Result<T> {
            text.parse()
                .map_err(|_| bad(format!("'{key}' is '{text}' (expected a number)")))
        }
        let settings: TrainSettings = serde_json::from_str(field("settings")?)
            .map_err(|e| bad(format!("unreadable settings ({e})")))?;
        let curve: Vec<ValidationPoint> = serde_json::from_str(field("curve")?)
            .map_err(|e| bad(format!("unreadable curve ({e})")))?;
        let tensors = candle_core::safetensors::load_buffer(bytes, &Device::Cpu)?;
        Ok(Checkpoint {
            settings,
            step: number(field("step")?, "step", &bad)?,
            tensors,
            optimiser_steps: number(field("optimiser_steps")?, "optimiser_steps", &bad)?,
            rng_word_pos: number(field("rng_word_pos")?, "rng_word_pos", &bad)?,
            loss_sum: number(field("loss_sum")?, "loss_sum", &bad)?,
            loss_count: number(field("loss_count")?, "loss_count", &bad)?,
            seconds: number(field("seconds")?, "seconds", &bad)?,
            curve,
            notes: metadata
                .iter()
                .filter_map(|(k, v)| Some((k.strip_prefix(NOTE)?.to_string(), v.clone())))
                .collect(),
        })
    }

    /// Reads a checkpoint file.
    pub fn load(path: &Path) -> Result<Self> {
        let bytes = std::fs::read(path)
            .map_err(|e| Error::Checkpoint(format!("{}: {e}", path.display())))?;
        Self::from_bytes(&bytes, &path.display().to_string())
    }
}

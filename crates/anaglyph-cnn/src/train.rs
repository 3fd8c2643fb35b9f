//! Training of the matching network with candle: MC-CNN's triplet sampling on simulated
//! cross-spectral pairs, hinge loss (fast) or binary cross-entropy (accurate), AdamW with
//! a cosine learning-rate decay, seeded initialisation and sampling, and a held-out
//! validation (triplet ranking error, and the winner-take-all bad-2 of the plain-Rust
//! inference path on whole validation pairs) every `validate_every` steps.
//!
//! A run may go in segments ([`train_segment`]): each stops after a number of steps or a
//! time and hands back a [`Checkpoint`]; the next resumes from it, and the run's weights,
//! curve and random draws are those of the run made at once.

use crate::checkpoint::Checkpoint;
use crate::dataset::{
    channel_swap_pairs, sample_triplets, simulated_pairs, Augmentation, PairKind, PairSettings,
    Sampling, StereoPair, TripletBatch, PATCH,
};
use crate::model::MatchingNet;
use crate::optimiser::AdamW;
use crate::{Architecture, Error, Result};
use anaglyph_core::stereo::{
    learned_cost_volume, winner_take_all, DisparityRange, MatchingNetwork,
};
use candle_core::{DType, Device, Tensor};
use candle_nn::ParamsAdamW;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::collections::{BTreeMap, HashMap};
use std::time::{Duration, Instant};

/// Hinge margin of the fast network's loss (MC-CNN: 0.2).
pub const HINGE_MARGIN: f64 = 0.2;
/// First scene seed of the validation pairs (training scenes never reach it).
pub const VALIDATION_SEED: u64 = 900_000;
/// Share of training triplets drawn from the channel-swapped textures.
pub const CHANNEL_SWAP_SHARE: f64 = 0.2;
/// First scene seed of the training pairs.
pub const TRAINING_SEED: u64 = 1_000_000;

/// Everything that determines a training run.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TrainSettings {
    pub architecture: Architecture,
    pub steps: usize,
    pub seed: u64,
    /// Triplets per step.
    pub batch: usize,
    /// Peak AdamW learning rate; it decays along a cosine to a tenth at the last step.
    pub learning_rate: f64,
    pub training_scenes: usize,
    pub validation_scenes: usize,
    pub pairs: PairSettings,
    /// Where the triplets' right patches lie ([`Sampling::MC_CNN_KITTI`] in the recipes
    /// before it was an option, absent from their checkpoints).
    #[serde(default)]
    pub sampling: Sampling,
    pub augmentation: Augmentation,
    pub validate_every: usize,
    /// Whether to add the channel-swapped texture pairs.
    pub channel_swaps: bool,
}

impl TrainSettings {
    /// Defaults for an architecture (the values the shipped models were trained with).
    pub fn new(architecture: Architecture) -> Self {
        TrainSettings {
            architecture,
            steps: 20_000,
            seed: 1,
            batch: 128,
            learning_rate: match architecture {
                Architecture::Fast { .. } => 2e-3,
                Architecture::Accurate { .. } => 5e-4,
            },
            training_scenes: 96,
            validation_scenes: 8,
            pairs: PairSettings::default(),
            sampling: Sampling::MC_CNN_KITTI,
            augmentation: Augmentation::MC_CNN_KITTI,
            validate_every: 500,
            channel_swaps: true,
        }
    }
}

/// One point of the validation curve.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ValidationPoint {
    pub step: usize,
    pub seconds: f64,
    /// Mean training loss since the previous point.
    pub train_loss: f64,
    /// % of held-out triplets (no augmentation) ranked wrongly.
    pub triplet_error: f64,
    /// Winner-take-all bad-2 (%) of the whole held-out pairs, by kind (fast networks; NaN
    /// for accurate ones, written as JSON null).
    #[serde(deserialize_with = "nan_if_null")]
    pub bad2_heterogeneous: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub bad2_homogeneous: f64,
}

/// JSON writes NaN as null; it reads back as NaN.
fn nan_if_null<'de, D: serde::Deserializer<'de>>(d: D) -> std::result::Result<f64, D::Error> {
    Ok(<Option<f64> as serde::Deserialize>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// What a training step reports.
#[derive(Debug, Clone)]
pub struct StepReport<'a> {
    pub step: usize,
    pub loss: f64,
    pub validation: Option<&'a ValidationPoint>,
}

/// A trained network with its curve.
pub struct TrainedModel {
    pub net: MatchingNet,
    pub curve: Vec<ValidationPoint>,
    pub seconds: f64,
}

/// Seeded He-uniform weights and small uniform biases, in name order.
fn initialise(net: &mut MatchingNet, seed: u64) -> Result<()> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut names: Vec<(String, Vec<usize>)> = net
        .varmap
        .data()
        .lock()
        .map_err(|_| crate::Error::Serialise("the variable map lock is poisoned".into()))?
        .iter()
        .map(|(k, v)| (k.clone(), v.as_tensor().dims().to_vec()))
        .collect();
    names.sort();
    for (name, shape) in names {
        let fan_in: usize = if name.ends_with(".weight") {
            shape[1..].iter().product()
        } else {
            // Bias: the fan-in of its layer's weight.
            let weight = name.replace(".bias", ".weight");
            let data =
                net.varmap.data().lock().map_err(|_| {
                    crate::Error::Serialise("the variable map lock is poisoned".into())
                })?;
            data.get(&weight)
                .map(|w| w.as_tensor().dims()[1..].iter().product())
                .unwrap_or(1)
        };
        let bound = if name.ends_with(".weight") {
            (6.0 / fan_in as f64).sqrt()
        } else {
            1.0 / (fan_in as f64).sqrt()
        } as f32;
        let count: usize = shape.iter().product();
        let values: Vec<f32> = (0..count)
            .map(|_| rng.random_range(-bound..=bound))
            .collect();
        let tensor = Tensor::from_vec(values, shape.as_slice(), &Device::Cpu)?;
        net.varmap.set_one(&name, &tensor)?;
    }
    Ok(())
}

fn patches(values: &[f32], batch: usize) -> Result<Tensor> {
    Ok(Tensor::from_slice(
        values,
        (batch, 1, PATCH, PATCH),
        &Device::Cpu,
    )?)
}

/// Mean binary cross-entropy of logits `z` against targets `t` in the overflow-free form
/// `max(z, 0) − z·t + ln(1 + e^−|z|)` (candle's version goes through `ln(sigmoid(z))`,
/// which turned NaN at step 217 of the first accurate run).
fn stable_binary_cross_entropy(z: &Tensor, t: &Tensor) -> Result<Tensor> {
    let softplus = (z.abs()?.neg()?.exp()? + 1.0)?.log()?;
    Ok(((z.relu()? - (z * t)?)? + softplus)?.mean_all()?)
}

/// Loss and wrongly ranked share of a batch.
fn batch_loss(net: &MatchingNet, batch: &TripletBatch) -> Result<(Tensor, f64)> {
    let b = batch.batch;
    let all = Tensor::cat(
        &[
            patches(&batch.left, b)?,
            patches(&batch.positive, b)?,
            patches(&batch.negative, b)?,
        ],
        0,
    )?;
    let features = net.patch_features(&all)?;
    let left = features.narrow(0, 0, b)?;
    let positive = features.narrow(0, b, b)?;
    let negative = features.narrow(0, 2 * b, b)?;
    let sp = net.similarity(&left, &positive)?;
    let sn = net.similarity(&left, &negative)?;
    let wrong = sn
        .ge(&sp)?
        .to_dtype(DType::F32)?
        .mean_all()?
        .to_scalar::<f32>()? as f64;
    let loss = match net.architecture {
        Architecture::Fast { .. } => ((sn - sp)? + HINGE_MARGIN)?.relu()?.mean_all()?,
        Architecture::Accurate { .. } => {
            let logits = Tensor::cat(&[&sp, &sn], 0)?;
            let targets = Tensor::cat(
                &[
                    Tensor::ones(b, DType::F32, &Device::Cpu)?,
                    Tensor::zeros(b, DType::F32, &Device::Cpu)?,
                ],
                0,
            )?;
            stable_binary_cross_entropy(&logits, &targets)?
        }
    };
    Ok((loss, wrong))
}

/// Winner-take-all bad-2 (%) of a network over whole pairs (pixels with known disparity
/// below the search range; invalid counts as bad).
pub fn winner_take_all_bad2(network: &MatchingNetwork, pairs: &[&StereoPair]) -> f64 {
    let (mut bad, mut total) = (0usize, 0usize);
    for pair in pairs {
        let max_disp = 64.min(pair.left.width);
        let range = DisparityRange {
            min: 0,
            max: max_disp as i32,
        };
        let volume = learned_cost_volume(network, &pair.left, &pair.right, range);
        let estimate = winner_take_all(&volume);
        for (e, t) in estimate.iter().zip(&pair.disparity) {
            if t.is_finite() && *t < max_disp as f32 - 1.0 {
                total += 1;
                bad += usize::from(!e.is_finite() || (e - t).abs() > 2.0);
            }
        }
    }
    100.0 * bad as f64 / total.max(1) as f64
}

/// Whole-pair validation, for fast networks only: the accurate head over every pixel and
/// disparity of the validation pairs would take minutes per point (NaN then).
fn whole_pair_bad2(network: &MatchingNetwork, pairs: &[&StereoPair]) -> f64 {
    if network.is_accurate() {
        f64::NAN
    } else {
        winner_take_all_bad2(network, pairs)
    }
}

/// The network as the inference path sees it.
pub fn to_inference(net: &MatchingNet) -> Result<MatchingNetwork> {
    let bytes = net.to_safetensors(HashMap::new())?;
    Ok(MatchingNetwork::from_safetensors(
        &bytes,
        "training snapshot",
    )?)
}

/// How far one call of [`train_segment`] goes, where it starts, and how it saves.
pub struct Segment<'a> {
    /// Continue this run's checkpoint (its settings must be the run's).
    pub resume: Option<Checkpoint>,
    /// Stop once this many steps of the run are done (before the last step: a pause).
    pub stop_at_step: Option<usize>,
    /// Stop after the step during which this much time (this call's) has passed.
    pub time_limit: Option<Duration>,
    /// Hand a checkpoint to `save` this often, and always when the segment ends.
    pub checkpoint_every: Option<Duration>,
    pub save: Option<&'a mut SaveCheckpoint<'a>>,
}

/// Where a segment's checkpoints go (a file, a list, …).
pub type SaveCheckpoint<'a> = dyn FnMut(&Checkpoint) -> Result<()> + 'a;

impl Segment<'_> {
    /// The whole run at once, without checkpoints.
    pub fn whole() -> Self {
        Segment {
            resume: None,
            stop_at_step: None,
            time_limit: None,
            checkpoint_every: None,
            save: None,
        }
    }
}

/// How a segment ended.
pub enum Outcome {
    /// The run's last step is done.
    Finished(TrainedModel),
    /// The segment stopped early; the checkpoint continues the run.
    Paused(Box<Checkpoint>),
}

/// Trains a network at once; `report` is called after every step.
pub fn train(settings: &TrainSettings, report: impl FnMut(StepReport<'_>)) -> Result<TrainedModel> {
    match train_segment(settings, Segment::whole(), report)? {
        Outcome::Finished(model) => Ok(model),
        Outcome::Paused(_) => unreachable!("a whole run does not pause"),
    }
}

/// Trains a segment of a run: from the start or `segment.resume`, up to the run's last
/// step or until the segment's step or time limit; `report` is called after every step.
pub fn train_segment(
    settings: &TrainSettings,
    mut segment: Segment<'_>,
    mut report: impl FnMut(StepReport<'_>),
) -> Result<Outcome> {
    let started = Instant::now();
    settings.architecture.validate()?;
    if let Some(checkpoint) = &segment.resume {
        if &checkpoint.settings != settings {
            return Err(Error::Checkpoint(format!(
                "of another recipe ({}; expected the run's own)",
                recipe_differences(&checkpoint.settings, settings).join(", ")
            )));
        }
        if checkpoint.step > settings.steps {
            return Err(Error::Checkpoint(format!(
                "at step {} (expected at most the run's {} steps)",
                checkpoint.step, settings.steps
            )));
        }
    }
    let training = simulated_pairs(
        TRAINING_SEED + settings.seed * 10_000,
        settings.training_scenes,
        &settings.pairs,
    )?;
    let swaps = if settings.channel_swaps {
        channel_swap_pairs()?
    } else {
        Vec::new()
    };
    let groups = [
        (training.as_slice(), 1.0 - CHANNEL_SWAP_SHARE),
        (swaps.as_slice(), CHANNEL_SWAP_SHARE),
    ];
    let validation = simulated_pairs(VALIDATION_SEED, settings.validation_scenes, &settings.pairs)?;
    tracing::info!(
        "{} training pairs, {} validation pairs in {:.1} s",
        training.len() + swaps.len(),
        validation.len(),
        started.elapsed().as_secs_f64()
    );
    let mut validation_rng = ChaCha8Rng::seed_from_u64(VALIDATION_SEED);
    let validation_batch = sample_triplets(
        &[(&validation, 1.0)],
        1024,
        // One yardstick for every recipe's curve, whatever its own sampling.
        &Sampling::MC_CNN_KITTI,
        &Augmentation::NONE,
        &mut validation_rng,
    )?;
    let heterogeneous: Vec<&StereoPair> = validation
        .iter()
        .filter(|p| p.kind == PairKind::Heterogeneous)
        .collect();
    let homogeneous: Vec<&StereoPair> = validation
        .iter()
        .filter(|p| p.kind == PairKind::Homogeneous)
        .collect();

    let mut net = MatchingNet::new(settings.architecture, &Device::Cpu)?;
    initialise(&mut net, settings.seed)?;
    let optimiser = AdamW::new(
        &net.varmap,
        ParamsAdamW {
            lr: settings.learning_rate,
            weight_decay: 1e-4,
            ..ParamsAdamW::default()
        },
    )?;
    let mut run = RunState {
        net,
        optimiser,
        rng: ChaCha8Rng::seed_from_u64(settings.seed),
        loss: (0.0, 0),
        curve: Vec::new(),
        notes: BTreeMap::new(),
        step: 0,
        earlier_seconds: 0.0,
    };
    if let Some(checkpoint) = segment.resume.take() {
        run.resume(checkpoint)?;
    }
    let seconds = |run: &RunState| run.earlier_seconds + started.elapsed().as_secs_f64();
    let mut last_save = Instant::now();
    for step in run.step + 1..=settings.steps {
        let progress = (step - 1) as f64 / settings.steps.max(1) as f64;
        let decay = 0.1 + 0.9 * 0.5 * (1.0 + (std::f64::consts::PI * progress).cos());
        run.optimiser
            .set_learning_rate(settings.learning_rate * decay);
        let batch = sample_triplets(
            &groups,
            settings.batch,
            &settings.sampling,
            &settings.augmentation,
            &mut run.rng,
        )?;
        let (loss, _) = batch_loss(&run.net, &batch)?;
        run.optimiser.backward_step(&loss)?;
        let loss = loss.to_scalar::<f32>()? as f64;
        if !loss.is_finite() {
            return Err(Error::Diverged { step, loss });
        }
        run.loss = (run.loss.0 + loss, run.loss.1 + 1);
        run.step = step;
        let mut point = None;
        if step % settings.validate_every == 0 || step == settings.steps {
            let (_, wrong) = batch_loss(&run.net, &validation_batch)?;
            let inference = to_inference(&run.net)?;
            run.curve.push(ValidationPoint {
                step,
                seconds: seconds(&run),
                train_loss: run.loss.0 / run.loss.1.max(1) as f64,
                triplet_error: 100.0 * wrong,
                bad2_heterogeneous: whole_pair_bad2(&inference, &heterogeneous),
                bad2_homogeneous: whole_pair_bad2(&inference, &homogeneous),
            });
            run.loss = (0.0, 0);
            point = run.curve.last();
        }
        report(StepReport {
            step,
            loss,
            validation: point,
        });
        let stop = step < settings.steps
            && (segment.stop_at_step.is_some_and(|s| step >= s)
                || segment.time_limit.is_some_and(|t| started.elapsed() >= t));
        if stop {
            break;
        }
        if let (Some(every), Some(save)) = (segment.checkpoint_every, segment.save.as_mut()) {
            if last_save.elapsed() >= every && step < settings.steps {
                save(&run.checkpoint(settings, seconds(&run))?)?;
                last_save = Instant::now();
            }
        }
    }
    let state = run.checkpoint(settings, seconds(&run))?;
    if let Some(save) = segment.save.as_mut() {
        save(&state)?;
    }
    if run.step < settings.steps {
        return Ok(Outcome::Paused(Box::new(state)));
    }
    Ok(Outcome::Finished(TrainedModel {
        seconds: seconds(&run),
        net: run.net,
        curve: run.curve,
    }))
}

/// The settings in which `saved` and `asked` differ, as "name: saved in the checkpoint,
/// asked".
fn recipe_differences(saved: &TrainSettings, asked: &TrainSettings) -> Vec<String> {
    let fields = |s: &TrainSettings| match serde_json::to_value(s) {
        Ok(serde_json::Value::Object(map)) => map,
        _ => serde_json::Map::new(),
    };
    let (saved, asked) = (fields(saved), fields(asked));
    saved
        .iter()
        .filter(|(k, v)| asked.get(*k) != Some(*v))
        .map(|(k, v)| {
            let here = asked.get(k).map_or("none".to_string(), ToString::to_string);
            format!("{k}: {v} in the checkpoint, {here} asked")
        })
        .collect()
}

/// What a run carries from step to step.
struct RunState {
    net: MatchingNet,
    optimiser: AdamW,
    /// The sampler's random stream.
    rng: ChaCha8Rng,
    /// Training loss summed since the last validation point, and over how many steps.
    loss: (f64, usize),
    curve: Vec<ValidationPoint>,
    notes: BTreeMap<String, String>,
    /// Steps done.
    step: usize,
    /// Time spent in earlier segments, seconds.
    earlier_seconds: f64,
}

impl RunState {
    /// Takes up where `checkpoint` left off.
    fn resume(&mut self, checkpoint: Checkpoint) -> Result<()> {
        restore_weights(&mut self.net, &checkpoint)?;
        self.optimiser.restore(
            &checkpoint.tensors,
            checkpoint.optimiser_steps,
            "the checkpoint",
        )?;
        self.rng.set_word_pos(checkpoint.rng_word_pos);
        self.loss = (checkpoint.loss_sum, checkpoint.loss_count);
        self.curve = checkpoint.curve;
        self.notes = checkpoint.notes;
        self.step = checkpoint.step;
        self.earlier_seconds = checkpoint.seconds;
        Ok(())
    }

    /// The run's state now, `seconds` into it.
    fn checkpoint(&self, settings: &TrainSettings, seconds: f64) -> Result<Checkpoint> {
        let mut tensors: HashMap<String, Tensor> = self
            .net
            .varmap
            .data()
            .lock()
            .map_err(|_| Error::Serialise("the variable map lock is poisoned".into()))?
            .iter()
            .map(|(k, v)| Ok((k.clone(), v.as_tensor().copy()?)))
            .collect::<Result<_>>()?;
        for (name, tensor) in self.optimiser.state() {
            tensors.insert(name, tensor.copy()?);
        }
        Ok(Checkpoint {
            settings: settings.clone(),
            step: self.step,
            tensors,
            optimiser_steps: self.optimiser.steps_taken(),
            rng_word_pos: self.rng.get_word_pos(),
            loss_sum: self.loss.0,
            loss_count: self.loss.1,
            seconds,
            curve: self.curve.clone(),
            notes: self.notes.clone(),
        })
    }
}

/// The checkpoint's weights into `net`.
fn restore_weights(net: &mut MatchingNet, checkpoint: &Checkpoint) -> Result<()> {
    let names: Vec<(String, Vec<usize>)> = net
        .varmap
        .data()
        .lock()
        .map_err(|_| Error::Serialise("the variable map lock is poisoned".into()))?
        .iter()
        .map(|(k, v)| (k.clone(), v.as_tensor().dims().to_vec()))
        .collect();
    for (name, dims) in names {
        let saved = checkpoint.tensors.get(&name).ok_or_else(|| {
            Error::Checkpoint(format!(
                "lacks the weight {name} of {:?}",
                checkpoint.settings.architecture
            ))
        })?;
        if saved.dims() != dims.as_slice() {
            return Err(Error::Checkpoint(format!(
                "weight {name} has shape {:?} (expected {dims:?})",
                saved.dims()
            )));
        }
        net.varmap.set_one(&name, saved)?;
    }
    Ok(())
}

impl TrainedModel {
    /// Safetensors bytes with the recipe in the metadata.
    pub fn to_safetensors(&self, settings: &TrainSettings, command: &str) -> Result<Vec<u8>> {
        let mut metadata = HashMap::new();
        metadata.insert(
            "architecture".to_string(),
            serde_json::to_string(&settings.architecture).unwrap_or_default(),
        );
        metadata.insert("command".to_string(), command.to_string());
        metadata.insert("steps".to_string(), settings.steps.to_string());
        metadata.insert("seed".to_string(), settings.seed.to_string());
        metadata.insert("batch".to_string(), settings.batch.to_string());
        metadata.insert(
            "learning_rate".to_string(),
            settings.learning_rate.to_string(),
        );
        metadata.insert(
            "training_scenes".to_string(),
            settings.training_scenes.to_string(),
        );
        metadata.insert("seconds".to_string(), format!("{:.0}", self.seconds));
        metadata.insert(
            "validation_curve".to_string(),
            serde_json::to_string(&self.curve).unwrap_or_default(),
        );
        self.net.to_safetensors(metadata)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn binary_cross_entropy_is_exact_and_finite_for_huge_logits() {
        let z = Tensor::new(&[-3.0f32, 0.5, 2.0, 1e4, -1e4], &Device::Cpu).unwrap();
        let t = Tensor::new(&[0.0f32, 1.0, 0.0, 1.0, 0.0], &Device::Cpu).unwrap();
        let got: f32 = stable_binary_cross_entropy(&z, &t)
            .unwrap()
            .to_scalar()
            .unwrap();
        let sigmoid = |v: f64| 1.0 / (1.0 + (-v).exp());
        // The last two terms are exactly 0 (confidently right).
        let want =
            (-(1.0 - sigmoid(-3.0)).ln() - sigmoid(0.5).ln() - (1.0 - sigmoid(2.0)).ln()) / 5.0;
        assert!((got as f64 - want).abs() < 1e-5, "{got} vs {want}");
    }
}

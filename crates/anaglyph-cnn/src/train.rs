//! Training of the matching network with candle: MC-CNN's triplet sampling on simulated
//! cross-spectral pairs, hinge loss (fast) or binary cross-entropy (accurate), AdamW with
//! a cosine learning-rate decay, seeded initialisation and sampling, and a held-out
//! validation (triplet ranking error, and the winner-take-all bad-2 of the plain-Rust
//! inference path on whole validation pairs) every `validate_every` steps.

use crate::dataset::{
    channel_swap_pairs, sample_triplets, simulated_pairs, Augmentation, PairKind, PairSettings,
    StereoPair, TripletBatch, PATCH,
};
use crate::model::MatchingNet;
use crate::{Architecture, Result};
use anaglyph_core::stereo::{
    learned_cost_volume, winner_take_all, DisparityRange, MatchingNetwork,
};
use candle_core::{DType, Device, Tensor};
use candle_nn::{AdamW, Optimizer, ParamsAdamW};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::collections::HashMap;
use std::time::Instant;

/// Hinge margin of the fast network's loss (MC-CNN: 0.2).
pub const HINGE_MARGIN: f64 = 0.2;
/// First scene seed of the validation pairs (training scenes never reach it).
pub const VALIDATION_SEED: u64 = 900_000;
/// Share of training triplets drawn from the channel-swapped textures.
pub const CHANNEL_SWAP_SHARE: f64 = 0.2;
/// First scene seed of the training pairs.
pub const TRAINING_SEED: u64 = 1_000_000;

/// Everything that determines a training run.
#[derive(Debug, Clone)]
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
            augmentation: Augmentation::MC_CNN_KITTI,
            validate_every: 500,
            channel_swaps: true,
        }
    }
}

/// One point of the validation curve.
#[derive(Debug, Clone, serde::Serialize)]
pub struct ValidationPoint {
    pub step: usize,
    pub seconds: f64,
    /// Mean training loss since the previous point.
    pub train_loss: f64,
    /// % of held-out triplets (no augmentation) ranked wrongly.
    pub triplet_error: f64,
    /// Winner-take-all bad-2 (%) of the whole held-out pairs, by kind (fast networks; NaN
    /// for accurate ones).
    pub bad2_heterogeneous: f64,
    pub bad2_homogeneous: f64,
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

/// Trains a network; `report` is called after every step.
pub fn train(
    settings: &TrainSettings,
    mut report: impl FnMut(StepReport<'_>),
) -> Result<TrainedModel> {
    let started = Instant::now();
    settings.architecture.validate()?;
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
    let mut optimiser = AdamW::new(
        net.varmap.all_vars(),
        ParamsAdamW {
            lr: settings.learning_rate,
            weight_decay: 1e-4,
            ..ParamsAdamW::default()
        },
    )?;
    let mut rng = ChaCha8Rng::seed_from_u64(settings.seed);
    let mut curve = Vec::new();
    let (mut loss_sum, mut loss_count) = (0.0, 0usize);
    for step in 1..=settings.steps {
        let progress = (step - 1) as f64 / settings.steps.max(1) as f64;
        let decay = 0.1 + 0.9 * 0.5 * (1.0 + (std::f64::consts::PI * progress).cos());
        optimiser.set_learning_rate(settings.learning_rate * decay);
        let batch = sample_triplets(&groups, settings.batch, &settings.augmentation, &mut rng)?;
        let (loss, _) = batch_loss(&net, &batch)?;
        optimiser.backward_step(&loss)?;
        let loss = loss.to_scalar::<f32>()? as f64;
        if !loss.is_finite() {
            return Err(crate::Error::Diverged { step, loss });
        }
        loss_sum += loss;
        loss_count += 1;
        let mut point = None;
        if step % settings.validate_every == 0 || step == settings.steps {
            let (_, wrong) = batch_loss(&net, &validation_batch)?;
            let inference = to_inference(&net)?;
            curve.push(ValidationPoint {
                step,
                seconds: started.elapsed().as_secs_f64(),
                train_loss: loss_sum / loss_count.max(1) as f64,
                triplet_error: 100.0 * wrong,
                bad2_heterogeneous: whole_pair_bad2(&inference, &heterogeneous),
                bad2_homogeneous: whole_pair_bad2(&inference, &homogeneous),
            });
            (loss_sum, loss_count) = (0.0, 0);
            point = curve.last();
        }
        report(StepReport {
            step,
            loss,
            validation: point,
        });
    }
    Ok(TrainedModel {
        net,
        curve,
        seconds: started.elapsed().as_secs_f64(),
    })
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

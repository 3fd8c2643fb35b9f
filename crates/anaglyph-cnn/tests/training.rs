//! The candle model and the plain-Rust inference path agree; a few training steps run,
//! lower the loss, and write weights the inference path reads.

use anaglyph_cnn::dataset::{
    sample_triplets, simulated_pair, Augmentation, PairKind, PairSettings, Sampling, StereoPair,
    PATCH,
};
use anaglyph_cnn::train::to_inference;
use anaglyph_cnn::{
    train, train_segment, Architecture, Checkpoint, MatchingNet, Outcome, Segment, TrainSettings,
};
use anaglyph_core::stereo::{
    learned_cost_volume, tower_features, DisparityRange, GreyImage, MatchingNetwork,
};
use candle_core::{Device, Tensor};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::collections::HashMap;

fn random_image(w: usize, h: usize, seed: u64) -> GreyImage {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    GreyImage {
        channels: 1,
        width: w,
        height: h,
        data: (0..w * h).map(|_| rng.random::<f32>()).collect(),
    }
}

/// Small architectures keep the test fast; the code paths are those of the full ones.
const SMALL_FAST: Architecture = Architecture::Fast {
    conv_layers: 4,
    feature_maps: 16,
};
const SMALL_ACCURATE: Architecture = Architecture::Accurate {
    conv_layers: 4,
    feature_maps: 12,
    fc_layers: 3,
    fc_units: 24,
};

#[test]
fn candle_and_the_gemm_inference_path_agree() {
    let (w, h) = (23, 17);
    let image = random_image(w, h, 1);
    let normalised = anaglyph_core::stereo::normalise_image(&image);
    for arch in [SMALL_FAST, SMALL_ACCURATE] {
        let net = MatchingNet::new(arch, &Device::Cpu).unwrap();
        let ours = tower_features(&to_inference(&net).unwrap(), &image);
        let input = Tensor::from_vec(normalised.data.clone(), (1, 1, h, w), &Device::Cpu).unwrap();
        // [1, maps, h, w] -> per pixel vectors.
        let theirs = net.tower(&input, true).unwrap().squeeze(0).unwrap();
        let maps = arch.feature_maps();
        let theirs: Vec<f32> = theirs
            .permute((1, 2, 0))
            .unwrap()
            .flatten_all()
            .unwrap()
            .to_vec1()
            .unwrap();
        assert_eq!(ours.channels, maps);
        let mut worst = 0f32;
        for (p, pixel) in theirs.chunks_exact(maps).enumerate() {
            let reference: Vec<f32> = if matches!(arch, Architecture::Fast { .. }) {
                let norm = pixel.iter().map(|v| v * v).sum::<f32>().sqrt();
                pixel.iter().map(|v| v / norm).collect()
            } else {
                pixel.to_vec()
            };
            for (a, b) in ours.data[p * maps..(p + 1) * maps].iter().zip(&reference) {
                worst = worst.max((a - b).abs());
            }
        }
        assert!(worst < 1e-4, "{arch:?}: worst feature difference {worst}");
    }
}

#[test]
fn accurate_costs_equal_the_candle_head_on_patches() {
    // Cost of (x, d) = 1 − sigmoid(head(f_L(x), f_R(x − d))): compare a few entries.
    let (w, h) = (20, 12);
    let (left, right) = (random_image(w, h, 2), random_image(w, h, 3));
    let net = MatchingNet::new(SMALL_ACCURATE, &Device::Cpu).unwrap();
    let inference = to_inference(&net).unwrap();
    // A signed range: the head also runs where the right pixel lies right of the left one.
    let range = DisparityRange::new(-2, 4).unwrap();
    let volume = learned_cost_volume(&inference, &left, &right, range);
    let fl = tower_features(&inference, &left);
    let fr = tower_features(&inference, &right);
    for (x, y, d) in [(5, 4, 0i32), (9, 7, 3), (17, 11, -2), (6, 0, 2), (19, 3, 3)] {
        let a = Tensor::from_slice(fl.pixel(x, y), (1, fl.channels), &Device::Cpu).unwrap();
        let xr = (x as i32 - d) as usize;
        let b = Tensor::from_slice(fr.pixel(xr, y), (1, fr.channels), &Device::Cpu).unwrap();
        let logit: f32 = net.similarity(&a, &b).unwrap().to_vec1().unwrap()[0];
        let want = 1.0 / (1.0 + logit.exp());
        let got = volume.pixel(x, y)[(d - range.min) as usize];
        assert!(
            (got - want).abs() < 1e-4,
            "({x}, {y}, {d}): {got} vs {want}"
        );
    }
}

#[test]
fn a_few_training_steps_lower_the_loss_and_save_readable_weights() {
    let mut settings = TrainSettings::new(SMALL_FAST);
    settings.steps = 60;
    settings.batch = 64;
    settings.training_scenes = 3;
    settings.validation_scenes = 2;
    settings.validate_every = 30;
    settings.pairs = PairSettings {
        width: 96,
        height: 72,
        homogeneous_share: 0.3,
        ..PairSettings::default()
    };
    let mut losses = Vec::new();
    let model = train(&settings, |r| losses.push(r.loss)).unwrap();
    assert_eq!(losses.len(), 60);
    assert_eq!(model.curve.len(), 2);
    let early: f64 = losses[..10].iter().sum::<f64>() / 10.0;
    let late: f64 = losses[50..].iter().sum::<f64>() / 10.0;
    assert!(late < early, "loss went from {early} to {late}");
    let bytes = model.to_safetensors(&settings, "test").unwrap();
    let network = MatchingNetwork::from_safetensors(&bytes, "test").unwrap();
    assert_eq!(network.feature_maps(), 16);
    assert_eq!(network.metadata("steps"), Some("60"));
    assert!(!network.is_accurate());
}

/// A small run that validates four times.
fn small_run(steps: usize) -> TrainSettings {
    let mut settings = TrainSettings::new(SMALL_FAST);
    settings.steps = steps;
    settings.batch = 32;
    settings.training_scenes = 3;
    settings.validation_scenes = 2;
    settings.validate_every = steps / 4;
    settings.pairs = PairSettings {
        width: 96,
        height: 72,
        homogeneous_share: 0.3,
        ..PairSettings::default()
    };
    settings
}

#[test]
fn a_run_paused_and_resumed_equals_the_run_made_at_once() {
    let settings = small_run(200);
    let whole = train(&settings, |_| {}).unwrap();
    // 100 steps, saved as bytes (as `train --checkpoint` writes them), then the rest.
    let mut saved = Vec::new();
    let mut save = |c: &Checkpoint| {
        saved.push(c.to_bytes()?);
        Ok(())
    };
    let first = Segment {
        stop_at_step: Some(100),
        save: Some(&mut save),
        ..Segment::whole()
    };
    let Outcome::Paused(paused) = train_segment(&settings, first, |_| {}).unwrap() else {
        panic!("the segment did not pause");
    };
    assert_eq!((paused.step, saved.len()), (100, 1));
    let checkpoint = Checkpoint::from_bytes(&saved[0], "test").unwrap();
    assert_eq!(checkpoint.step, 100);
    assert_eq!(checkpoint.curve, paused.curve);
    let mut steps = Vec::new();
    let rest = Segment {
        resume: Some(checkpoint),
        ..Segment::whole()
    };
    let Outcome::Finished(resumed) =
        train_segment(&settings, rest, |r| steps.push(r.step)).unwrap()
    else {
        panic!("the resumed segment did not finish");
    };
    assert_eq!(steps, (101..=200).collect::<Vec<_>>());
    // Bit for bit: the weights' bytes and the curve (but for the time spent).
    assert_eq!(
        resumed.net.to_safetensors(HashMap::new()).unwrap(),
        whole.net.to_safetensors(HashMap::new()).unwrap()
    );
    let untimed = |curve: &[anaglyph_cnn::ValidationPoint]| {
        curve
            .iter()
            .map(|p| {
                [
                    p.step as f64,
                    p.train_loss,
                    p.triplet_error,
                    p.bad2_heterogeneous,
                    p.bad2_homogeneous,
                ]
                .map(f64::to_bits)
            })
            .collect::<Vec<_>>()
    };
    assert_eq!(untimed(&resumed.curve), untimed(&whole.curve));
    assert_eq!(resumed.curve.len(), 4);
}

#[test]
fn a_checkpoint_resumes_only_its_own_recipe_and_weights_are_not_a_checkpoint() {
    let settings = small_run(8);
    let first = Segment {
        stop_at_step: Some(4),
        ..Segment::whole()
    };
    let Outcome::Paused(paused) = train_segment(&settings, first, |_| {}).unwrap() else {
        panic!("the segment did not pause");
    };
    let mut other = settings.clone();
    other.seed = 2;
    let resume = Segment {
        resume: Some(*paused),
        ..Segment::whole()
    };
    let error = train_segment(&other, resume, |_| {})
        .err()
        .unwrap()
        .to_string();
    assert!(
        error.contains("another recipe") && error.contains("seed: 1 in the checkpoint, 2 asked"),
        "{error}"
    );
    let model = train(&settings, |_| {}).unwrap();
    let weights = model.to_safetensors(&settings, "test").unwrap();
    let error = Checkpoint::from_bytes(&weights, "m.safetensors")
        .unwrap_err()
        .to_string();
    assert!(
        error.contains("m.safetensors") && error.contains("not trained weights"),
        "{error}"
    );
}

#[test]
fn triplets_put_the_positive_on_the_true_match() {
    // Without augmentation and positive offsets, the positive patch of a homogeneous pair
    // is much closer to the left patch than the negative one.
    let pair = simulated_pair(
        77,
        &PairSettings {
            width: 128,
            height: 96,
            homogeneous_share: 1.0,
            ..PairSettings::default()
        },
    )
    .unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let batch = sample_triplets(
        &[(std::slice::from_ref(&pair), 1.0)],
        256,
        &Sampling::MC_CNN_KITTI,
        &Augmentation::NONE,
        &mut rng,
    )
    .unwrap();
    let n = PATCH * PATCH;
    let distance = |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(p, q)| (p - q).abs()).sum::<f32>();
    let closer = (0..256)
        .filter(|&i| {
            let l = &batch.left[i * n..(i + 1) * n];
            distance(l, &batch.positive[i * n..(i + 1) * n])
                < distance(l, &batch.negative[i * n..(i + 1) * n])
        })
        .count();
    assert!(
        closer > 200,
        "{closer} of 256 positives closer than their negatives"
    );
}

#[test]
fn sampling_from_pairs_without_usable_pixels_is_an_error_not_a_hang() {
    let mut pair = simulated_pair(
        78,
        &PairSettings {
            width: 64,
            height: 48,
            homogeneous_share: 0.0,
            ..PairSettings::default()
        },
    )
    .unwrap();
    pair.disparity.iter_mut().for_each(|d| *d = f32::NAN);
    let mut rng = ChaCha8Rng::seed_from_u64(6);
    let result = sample_triplets(
        &[(std::slice::from_ref(&pair), 1.0)],
        8,
        &Sampling::MC_CNN_KITTI,
        &Augmentation::NONE,
        &mut rng,
    );
    let message = result.expect_err("no usable pixel").to_string();
    assert!(message.contains("0 of 8"), "{message}");
}

#[test]
fn narrow_band_pairs_join_a_recipe_without_changing_its_gel_pairs() {
    let plain = PairSettings {
        width: 64,
        height: 48,
        ..PairSettings::default()
    };
    let mixed = PairSettings {
        narrow_band_share: 0.5,
        ..plain
    };
    let bits = |p: &StereoPair| {
        (p.left.data.iter().chain(&p.right.data))
            .map(|v| v.to_bits())
            .collect::<Vec<_>>()
    };
    let mut narrow = 0;
    for seed in 0..16 {
        let a = simulated_pair(seed, &plain).unwrap();
        let b = simulated_pair(seed, &mixed).unwrap();
        assert_eq!(a.kind, b.kind, "seed {seed}");
        if !b.label.contains("gaussian:") {
            assert_eq!(bits(&a), bits(&b), "seed {seed}: {} / {}", a.label, b.label);
            continue;
        }
        narrow += 1;
        assert!(b.label.ends_with("(panchromatic)"), "{}", b.label);
        let centres: Vec<f64> = b
            .label
            .split(" vs ")
            .map(|f| f.split(':').nth(1).unwrap().parse().unwrap())
            .collect();
        match b.kind {
            PairKind::Homogeneous => assert_eq!(centres[0], centres[1], "{}", b.label),
            _ => assert!((centres[0] - centres[1]).abs() >= 29.5, "{}", b.label),
        }
        assert!(b.disparity.iter().filter(|d| d.is_finite()).count() > 64 * 48 / 2);
    }
    assert!(
        (3..=13).contains(&narrow),
        "{narrow} of 16 narrow-band pairs"
    );
}

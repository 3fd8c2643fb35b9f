//! The scene prior against closed forms and small synthetic scenes whose truth is known.

use super::whitening::Gain;
use super::{fill_view, ScenePrior, ScenePriorSettings};
use crate::solve::measurement_residuals;
use crate::solve::test_support::matrix;
use faer::linalg::solvers::Solve;
use faer::{Mat, Side};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Spectra on 6 knots from a rank-2 model `μ + B z`, seen through 6 positive rows;
/// pixels whose index is a multiple of 3 lose rows 2..6.
fn low_rank_scene(pixels: usize) -> (Vec<f64>, Vec<f32>, Vec<f32>, Vec<f32>) {
    let (rows, knots) = (6, 6);
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let c: Vec<f64> = (0..rows * knots)
        .map(|_| rng.random_range(0.1..1.0))
        .collect();
    let mean = [0.4, 0.45, 0.5, 0.5, 0.45, 0.4];
    let basis = [
        [0.1, 0.1, 0.1, 0.1, 0.1, 0.1],
        [0.1, 0.06, 0.02, -0.02, -0.06, -0.1],
    ];
    let mut truth = Vec::with_capacity(pixels * knots);
    let mut measurements = Vec::with_capacity(pixels * rows);
    for px in 0..pixels {
        let z: [f64; 2] = [rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)];
        let s: Vec<f64> = (0..knots)
            .map(|k| mean[k] + z[0] * basis[0][k] + z[1] * basis[1][k])
            .collect();
        for row in c.chunks_exact(knots) {
            let value: f64 = row.iter().zip(&s).map(|(a, b)| a * b).sum();
            let seen = px % 3 != 0 || measurements.len() % rows < 2;
            measurements.push(if seen { value as f32 } else { f32::NAN });
        }
        truth.extend(s.iter().map(|&v| v as f32));
    }
    // What Eq. 6 would leave for the under-measured pixels: a flat guess.
    let spectra: Vec<f32> = truth
        .chunks_exact(knots)
        .enumerate()
        .flat_map(|(px, s)| {
            let flat = s.iter().sum::<f32>() / knots as f32;
            s.iter()
                .map(move |&v| if px % 3 == 0 { flat } else { v })
                .collect::<Vec<_>>()
        })
        .collect();
    (c, measurements, spectra, truth)
}

#[test]
fn a_low_rank_scene_is_recovered_from_two_measurements() {
    let pixels = 3000;
    let (c, measurements, mut spectra, truth) = low_rank_scene(pixels);
    let residuals: Vec<f32> = (0..pixels)
        .map(|px| if px % 3 == 0 { 0.0 } else { 1e-4 })
        .collect();
    let prior = ScenePrior::learn(6, 6, &measurements, &spectra, &residuals, 1)
        .unwrap()
        .unwrap();
    assert_eq!(prior.samples, 2000);
    let complete_before: Vec<f32> = spectra
        .chunks_exact(6)
        .enumerate()
        .filter(|(px, _)| px % 3 != 0)
        .flat_map(|(_, s)| s.to_vec())
        .collect();
    let report = prior
        .fill_incomplete(&matrix(6, c.clone()), &measurements, &mut spectra, 1.0)
        .unwrap();
    assert_eq!((report.filled_pixels, report.rejected_pixels), (1000, 0));
    assert_eq!(report.noise, 1e-3);
    let mut worst = 0.0f32;
    for (px, (s, t)) in spectra
        .chunks_exact(6)
        .zip(truth.chunks_exact(6))
        .enumerate()
    {
        if px % 3 == 0 {
            for (a, b) in s.iter().zip(t) {
                worst = worst.max((a - b).abs());
            }
        }
    }
    // Two measurements pin a rank-2 model: errors of the noise floor's order (1e-3
    // of white) instead of the flat guess's 0.2.
    assert!(worst < 0.01, "worst error {worst}");
    let complete_after: Vec<f32> = spectra
        .chunks_exact(6)
        .enumerate()
        .filter(|(px, _)| px % 3 != 0)
        .flat_map(|(_, s)| s.to_vec())
        .collect();
    assert_eq!(complete_before, complete_after);
}

#[test]
fn measurements_the_prior_finds_implausible_keep_their_spectrum() {
    let pixels = 3000;
    let (c, mut measurements, mut spectra, _) = low_rank_scene(pixels);
    let residuals = vec![1e-4f32; pixels];
    let prior = ScenePrior::learn(6, 6, &measurements, &spectra, &residuals, 1)
        .unwrap()
        .unwrap();
    // Pixel 0 sees rows 0 and 1; make them disagree (as a wrong match would).
    measurements[0] *= 3.0;
    let before = spectra[..6].to_vec();
    let report = prior
        .fill_incomplete(&matrix(6, c.clone()), &measurements, &mut spectra, 1.0)
        .unwrap();
    assert_eq!((report.filled_pixels, report.rejected_pixels), (999, 1));
    assert_eq!(&spectra[..6], &before[..]);
}

#[test]
fn more_assumed_noise_leans_on_the_mean() {
    let pixels = 3000;
    let (c, measurements, spectra, truth) = low_rank_scene(pixels);
    let residuals = vec![1e-4f32; pixels];
    let prior = ScenePrior::learn(6, 6, &measurements, &spectra, &residuals, 1)
        .unwrap()
        .unwrap();
    let error_with = |scale: f64| {
        let mut filled = spectra.clone();
        prior
            .fill_incomplete(&matrix(6, c.clone()), &measurements, &mut filled, scale)
            .unwrap();
        let mut sum = 0.0f64;
        for (px, (s, t)) in filled
            .chunks_exact(6)
            .zip(truth.chunks_exact(6))
            .enumerate()
        {
            if px % 3 == 0 {
                sum += s
                    .iter()
                    .zip(t)
                    .map(|(a, b)| ((a - b) as f64).powi(2))
                    .sum::<f64>();
            }
        }
        (sum / 6000.0).sqrt()
    };
    let (sharp, vague) = (error_with(1.0), error_with(1e4));
    // A noise of 1 (white) swamps the measurements: the estimate is the scene's mean,
    // whose error is the spread of the spectra (about 0.08 rms).
    assert!(sharp < 0.005 && vague > 0.05, "{sharp} {vague}");
}

#[test]
fn too_few_complete_pixels_give_no_prior_and_bad_input_is_refused() {
    let (c, measurements, mut spectra, _) = low_rank_scene(150);
    let residuals = vec![0.0f32; 150];
    // 100 complete pixels: under 20 per knot.
    assert!(
        ScenePrior::learn(6, 6, &measurements, &spectra, &residuals, 1)
            .unwrap()
            .is_none()
    );
    assert_eq!(
        ScenePrior::learn(6, 6, &measurements, &spectra[1..], &residuals, 1)
            .err()
            .map(|e| e.kind()),
        Some("Shape")
    );
    assert_eq!(
        ScenePrior::learn(6, 6, &measurements, &spectra, &residuals[1..], 1)
            .err()
            .map(|e| e.kind()),
        Some("Shape")
    );
    let (_, m, s, _) = low_rank_scene(3000);
    let prior = ScenePrior::learn(6, 6, &m, &s, &vec![0.0; 3000], 1)
        .unwrap()
        .unwrap();
    assert_eq!(
        prior
            .fill_incomplete(&matrix(6, c.clone()), &measurements, &mut spectra, 0.0)
            .err()
            .map(|e| e.kind()),
        Some("OutOfRange")
    );
    assert_eq!(
        prior
            .fill_incomplete(&matrix(6, c.clone()), &measurements, &mut spectra, f64::NAN)
            .err()
            .map(|e| e.kind()),
        Some("OutOfRange")
    );
    assert_eq!(
        prior
            .fill_incomplete(
                &matrix(6, c[..30].to_vec()),
                &measurements,
                &mut spectra,
                1.0
            )
            .err()
            .map(|e| e.kind()),
        Some("Shape")
    );
    assert_eq!(
        ScenePrior::learn(6, 6, &m, &s, &vec![0.0; 3000], 0)
            .err()
            .map(|e| e.kind()),
        Some("OutOfRange")
    );
}

/// Two materials on 6 knots, each varying along its own direction, seen through 6
/// rows; pixels whose index is a multiple of 3 keep rows 0 and 1 only.
fn two_material_scene(pixels: usize) -> (Vec<f64>, Vec<f32>, Vec<f32>, Vec<f32>) {
    let (rows, knots) = (6, 6);
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let c: Vec<f64> = (0..rows * knots)
        .map(|_| rng.random_range(0.1..1.0))
        .collect();
    let means = [
        [0.2, 0.25, 0.3, 0.5, 0.7, 0.8],
        [0.7, 0.6, 0.4, 0.3, 0.25, 0.2],
    ];
    let directions = [
        [0.1, -0.1, 0.1, -0.1, 0.1, -0.1],
        [0.0, 0.1, 0.1, -0.1, -0.1, 0.0],
    ];
    let mut truth = Vec::with_capacity(pixels * knots);
    let mut measurements = Vec::with_capacity(pixels * rows);
    for px in 0..pixels {
        let material = usize::from(rng.random_bool(0.5));
        let z: f64 = rng.random_range(-1.0..1.0);
        let s: Vec<f64> = (0..knots)
            .map(|k| means[material][k] + z * directions[material][k])
            .collect();
        for (r, row) in c.chunks_exact(knots).enumerate() {
            let value: f64 = row.iter().zip(&s).map(|(a, b)| a * b).sum();
            let seen = px % 3 != 0 || r < 2;
            measurements.push(if seen { value as f32 } else { f32::NAN });
        }
        truth.extend(s.iter().map(|&v| v as f32));
    }
    let spectra: Vec<f32> = truth
        .chunks_exact(knots)
        .enumerate()
        .flat_map(|(px, s)| {
            let flat = s.iter().sum::<f32>() / knots as f32;
            s.iter()
                .map(move |&v| if px % 3 == 0 { flat } else { v })
                .collect::<Vec<_>>()
        })
        .collect();
    (c, measurements, spectra, truth)
}

/// Root mean square error over the under-measured pixels of `two_material_scene`.
fn under_measured_error(spectra: &[f32], truth: &[f32]) -> f64 {
    let (mut sum, mut count) = (0.0f64, 0);
    for (px, (s, t)) in spectra
        .chunks_exact(6)
        .zip(truth.chunks_exact(6))
        .enumerate()
    {
        if px % 3 == 0 {
            sum += s
                .iter()
                .zip(t)
                .map(|(a, b)| ((a - b) as f64).powi(2))
                .sum::<f64>();
            count += 6;
        }
    }
    (sum / count as f64).sqrt()
}

#[test]
fn a_mixture_recovers_what_one_gaussian_blurs() {
    let pixels = 3000;
    let (c, measurements, spectra, truth) = two_material_scene(pixels);
    let residuals = vec![1e-4f32; pixels];
    let error_with = |clusters: usize| {
        let prior = ScenePrior::learn(6, 6, &measurements, &spectra, &residuals, clusters)
            .unwrap()
            .unwrap();
        let mut filled = spectra.clone();
        let report = prior
            .fill_incomplete(&matrix(6, c.clone()), &measurements, &mut filled, 1.0)
            .unwrap();
        assert_eq!(report.filled_pixels + report.rejected_pixels, 1000);
        (under_measured_error(&filled, &truth), report)
    };
    let (single, single_report) = error_with(1);
    let (mixture, mixture_report) = error_with(2);
    assert_eq!(single_report.components, 1);
    // Two clusters from each of the k-means runs.
    assert_eq!(
        mixture_report.components,
        2 * super::mixture::K_MEANS_RUNS as usize
    );
    assert_eq!(mixture_report.rejected_pixels, 0);
    // Two measurements cannot pin the three directions the scene's covariance spans
    // (the two materials' own variations and the step between them); they pin one
    // material's single direction once the mixture has told the materials apart.
    assert!(mixture < 0.005, "mixture {mixture}");
    assert!(single > 5.0 * mixture, "single {single}, mixture {mixture}");
    // The flat guess it started from.
    assert!(under_measured_error(&spectra, &truth) > 0.1);
}

#[test]
fn propagation_adds_a_material_the_complete_pixels_lack() {
    // Material 0 is seen completely where px % 3 != 0; material 1 never is: rows 0..4
    // there (at least half, and their spectra as good as Eq. 6 from four rows would
    // give), rows 0 and 1 alone where px % 3 == 0 (as for material 0).
    let (rows, knots, pixels) = (6, 6, 6000);
    let (c, mut measurements, mut spectra, truth) = two_material_scene(pixels);
    let material_of = |s: &[f32]| usize::from(s[0] > s[5]);
    for px in 0..pixels {
        let t = &truth[px * knots..(px + 1) * knots];
        if material_of(t) == 1 && px % 3 != 0 {
            measurements[px * rows + 4..(px + 1) * rows].fill(f32::NAN);
            spectra[px * knots..(px + 1) * knots].copy_from_slice(t);
        }
    }
    let error_with = |rounds: usize| {
        let mut filled = spectra.clone();
        let mut residuals =
            measurement_residuals(&matrix(rows, c.clone()), &measurements, &filled).unwrap();
        let settings = ScenePriorSettings {
            noise_scale: 1.0,
            clusters: 2,
            propagation_rounds: rounds,
        };
        let report = fill_view(
            &matrix(rows, c.clone()),
            &measurements,
            &mut filled,
            &mut residuals,
            &settings,
        )
        .unwrap()
        .unwrap();
        // The residuals follow the final spectra.
        let expected =
            measurement_residuals(&matrix(rows, c.clone()), &measurements, &filled).unwrap();
        assert_eq!(residuals, expected);
        let (mut sum, mut count) = (0.0f64, 0);
        for px in (0..pixels).step_by(3) {
            let t = &truth[px * knots..(px + 1) * knots];
            if material_of(t) == 1 {
                let s = &filled[px * knots..(px + 1) * knots];
                sum += s
                    .iter()
                    .zip(t)
                    .map(|(a, b)| ((a - b) as f64).powi(2))
                    .sum::<f64>();
                count += knots;
            }
        }
        ((sum / count as f64).sqrt(), report)
    };
    let (alone, alone_report) = error_with(0);
    let (propagated, report) = error_with(2);
    assert_eq!(alone_report.propagated_samples, 0);
    assert!(report.propagated_samples > 500, "{report:?}");
    assert!(report.components > alone_report.components, "{report:?}");
    // Without the material, its two-row pixels are rejected (keeping the flat guess)
    // or pulled towards the other material.
    // (Measured: 0.19 without, 0.0045 with.)
    assert!(alone > 0.1, "without propagation {alone}");
    assert!(propagated < 0.01, "with propagation {propagated}");
}

#[test]
fn whitening_solves_against_the_cholesky_factor() {
    let a = 5;
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let m = Mat::from_fn(a, a, |_, _| rng.random_range(-1.0..1.0));
    let system = &m * m.transpose() + Mat::<f64>::identity(a, a);
    let llt = system.llt(Side::Lower).unwrap();
    let mut lower = Vec::new();
    for j in 0..a {
        lower.extend((j..a).map(|i| llt.L()[(i, j)]));
    }
    let gain = Gain {
        log_weight: 0.0,
        offset: vec![0.0; a],
        lower,
        log_det: 0.0,
    };
    let n = 3;
    let batch: Vec<Vec<f64>> = (0..n)
        .map(|_| (0..a).map(|_| rng.random_range(-1.0..1.0)).collect())
        .collect();
    let mut rows_across = vec![0.0; a * n];
    for (k, x) in batch.iter().enumerate() {
        for (i, v) in x.iter().enumerate() {
            rows_across[i * n + k] = *v;
        }
    }
    let mut distances = vec![0.0; n];
    gain.whiten_batch(&mut rows_across, &mut distances);
    for (k, x) in batch.iter().enumerate() {
        let expected = llt.solve(Mat::from_fn(a, 1, |i, _| x[i]));
        let quadratic: f64 = (0..a).map(|i| x[i] * expected[(i, 0)]).sum();
        let mut y = x.clone();
        let distance = gain.whiten(&mut y);
        for (i, v) in y.iter().enumerate() {
            assert!((v - rows_across[i * n + k]).abs() < 1e-12);
        }
        gain.unwhiten(&mut y);
        assert!(
            (distance - quadratic).abs() < 1e-10,
            "{distance} {quadratic}"
        );
        assert!((distances[k] - quadratic).abs() < 1e-10);
        for (i, v) in y.iter().enumerate() {
            assert!(
                (v - expected[(i, 0)]).abs() < 1e-10,
                "{v} {}",
                expected[(i, 0)]
            );
        }
    }
}

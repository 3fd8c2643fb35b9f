//! The stereo quality table of the README: every matching cost, raw (winner-take-all) and
//! with its full refinement chain, on held-out simulated pairs (scene seeds never used in
//! training or validation), heterogeneous (different gels or channels) and homogeneous
//! (same gel and channel). Prints a Markdown table of bad-2.0, average error, density and
//! time per megapixel per 100 disparities.
//!
//! `cargo run --release --example stereo_quality -- [SCENES] [WIDTH] [HEIGHT]`; with
//! `ANAGLYPH_SCENE=tabletop` (or another preset) every pair shows that preset instead of a
//! random scene, the gels, sensor, channels and noise still drawn per seed.

use anaglyph_cnn::dataset::{simulated_pair_with, PairKind, PairSettings, StereoPair};
use anaglyph_core::scene::SceneFile;
use anaglyph_core::stereo::{match_pair, MatchSettings, MatchingCost, MatchingNetwork};
use std::time::Instant;

/// First scene seed of the test pairs (training starts at 1 000 000, validation 900 000).
const TEST_SEED: u64 = 800_000;

struct Score {
    bad2: f64,
    error: f64,
    density: f64,
    seconds_per_mpx_100d: f64,
}

fn score(pairs: &[&StereoPair], cost: &MatchingCost<'_>, refine: bool, max_disp: usize) -> Score {
    let (mut bad, mut total, mut error_sum, mut error_count, mut valid) = (0, 0, 0.0, 0, 0);
    let mut seconds = 0.0;
    let mut megapixels = 0.0;
    for pair in pairs {
        let settings = if refine {
            MatchSettings::for_cost(cost, max_disp)
        } else {
            MatchSettings::raw(max_disp)
        };
        let started = Instant::now();
        let out = match_pair(&pair.left, &pair.right, cost, &settings).expect("match");
        seconds += started.elapsed().as_secs_f64();
        megapixels += (pair.left.width * pair.left.height) as f64 / 1e6;
        for (e, t) in out.disparity.iter().zip(&pair.disparity) {
            if !t.is_finite() || *t >= max_disp as f32 - 1.0 {
                continue;
            }
            total += 1;
            if e.is_finite() {
                valid += 1;
                error_sum += (e - t).abs() as f64;
                error_count += 1;
            }
            bad += usize::from(!e.is_finite() || (e - t).abs() > 2.0);
        }
    }
    Score {
        bad2: 100.0 * bad as f64 / total.max(1) as f64,
        error: error_sum / error_count.max(1) as f64,
        density: 100.0 * valid as f64 / total.max(1) as f64,
        seconds_per_mpx_100d: seconds / megapixels / (max_disp as f64 / 100.0),
    }
}

fn main() -> anyhow::Result<()> {
    let args: Vec<usize> = std::env::args()
        .skip(1)
        .map(|a| a.parse())
        .collect::<Result<_, _>>()?;
    let count = args.first().copied().unwrap_or(16);
    let settings = PairSettings {
        width: args.get(1).copied().unwrap_or(320),
        height: args.get(2).copied().unwrap_or(240),
        homogeneous_share: 0.5,
    };
    let max_disp = 64 * settings.width / 256;
    // Every held-out scene twice, once with different gels or channels, once with the
    // same: the two kinds differ only in the filters.
    let mut pairs = Vec::new();
    for i in 0..count as u64 {
        for homogeneous in [false, true] {
            let scene = match std::env::var("ANAGLYPH_SCENE") {
                Ok(name) => Some(SceneFile::preset(&name)?),
                Err(_) => None,
            };
            pairs.push(simulated_pair_with(
                TEST_SEED + i,
                &settings,
                Some(homogeneous),
                scene,
            )?);
        }
    }
    let fast = MatchingNetwork::default_fast()?;
    let accurate = std::env::var("ANAGLYPH_ACCURATE_MODEL")
        .ok()
        .map(|p| MatchingNetwork::load(std::path::Path::new(&p)))
        .transpose()?;
    let mut costs = vec![
        MatchingCost::Learned(&fast),
        MatchingCost::Census,
        MatchingCost::Zncc,
        MatchingCost::MutualInformation { iterations: 3 },
    ];
    if let Some(n) = &accurate {
        costs.insert(1, MatchingCost::Learned(n));
    }
    let kinds = [PairKind::Heterogeneous, PairKind::Homogeneous];
    println!(
        "{count} held-out pairs at {}×{}, {max_disp} disparities",
        settings.width, settings.height
    );
    println!(
        "| cost | chain | pairs | bad-2.0 % | avg error px | density % | s / Mpx / 100 disp |"
    );
    println!("|---|---|---|---|---|---|---|");
    for cost in &costs {
        for refine in [false, true] {
            for kind in kinds {
                let subset: Vec<&StereoPair> = pairs.iter().filter(|p| p.kind == kind).collect();
                let s = score(&subset, cost, refine, max_disp);
                println!(
                    "| {} | {} | {} ({}) | {:.1} | {:.2} | {:.1} | {:.2} |",
                    cost.name(),
                    if refine { "refined" } else { "raw" },
                    if kind == PairKind::Heterogeneous {
                        "heterogeneous"
                    } else {
                        "homogeneous"
                    },
                    subset.len(),
                    s.bad2,
                    s.error,
                    s.density,
                    s.seconds_per_mpx_100d
                );
            }
        }
    }
    Ok(())
}

//! The stereo quality table of docs/stereo.md: every matching cost, raw (winner-take-all) and
//! with its full refinement chain, on held-out simulated pairs (scene seeds never used in
//! training or validation), heterogeneous (different gels or channels) and homogeneous
//! (same gel and channel). Prints a Markdown table of bad-2.0, average error, density and
//! time per megapixel per 100 disparities.
//!
//! `cargo run --release --example stereo_quality -- [SCENES] [WIDTH] [HEIGHT]` (random
//! scenes, random gels, sensors and channels); with `ANAGLYPH_PAIRS=rig`, the paper rig's
//! own neighbouring cameras on the three presets instead (`ANAGLYPH_PRESETS=tabletop` for
//! fewer); with `ANAGLYPH_PAIRS=narrow`, the same held-out scenes seen by two monochrome
//! cameras behind narrow-band filters (`PairSettings::narrow_band_share`); with
//! `ANAGLYPH_PAIRS=camera`, the same held-out scenes and gels recorded as real cameras
//! record them (`PairSettings::camera_effects_share`: defocus, vignetting, pixel gains,
//! noise at a gain and exposure of their own, saturation, gamma-encoded 8-bit files).
//! `ANAGLYPH_ACCURATE_MODEL=models/mccnn-accurate.safetensors` adds the accurate network;
//! `ANAGLYPH_FAST_MODEL=M.safetensors` replaces the embedded fast network with another
//! fast one (to compare weights on the same pairs); `ANAGLYPH_COSTS=mccnn,mccnn-accurate`
//! keeps only the named costs. A third group is every heterogeneous pair with its right image's contrast inverted, a fourth the same
//! pairs with only the right image's lower half inverted. The refined chain runs with
//! `match`'s default contrast vote (`Contrast::Auto`; `ANAGLYPH_CONTRAST=same` turns it
//! off, `ANAGLYPH_CONTRAST=either` takes either sign per pixel), which also prints how many
//! pairs of each group it took for inverted (`ANAGLYPH_VOTES=1` prints every pair's vote).
//! `ANAGLYPH_WRITE_PAIRS=DIR` also writes every group's pairs to DIR (`GROUP-K-left.pfm`,
//! `-right.pfm`, `-truth.pfm` with NaN where the truth is unknown, and `index.tsv`) for
//! other matchers: `scripts/sgbm_baseline.py DIR` scores OpenCV's SGBM on them.

use anaglyph_cnn::dataset::{
    rig_pair, simulated_pair_with, PairKind, PairSettings, RigPair, StereoPair,
};
use anaglyph_core::scene::SceneFile;
use anaglyph_core::stereo::{
    match_pair, negated, Contrast, DisparityRange, MatchMethod, MatchSettings, MatchingCost,
    MatchingNetwork,
};
use std::time::Instant;

/// The horizontal neighbours of the paper's 2×4 rig.
const RIG_NEIGHBOURS: [[&str; 2]; 6] = [
    ["gel_deep_red", "gel_salmon"],
    ["gel_salmon", "gel_magenta"],
    ["gel_magenta", "gel_lavender"],
    ["gel_violet", "gel_teal"],
    ["gel_teal", "gel_yellow_green"],
    ["gel_yellow_green", "gel_emerald"],
];

/// First scene seed of the test pairs (training starts at 1 000 000, validation 900 000).
const TEST_SEED: u64 = 800_000;

struct Score {
    bad2: f64,
    error: f64,
    density: f64,
    seconds_per_mpx_100d: f64,
    /// Pairs the contrast vote took for inverted.
    voted_inverted: usize,
}

fn score(pairs: &[&StereoPair], cost: &MatchingCost<'_>, refine: bool, max_disp: usize) -> Score {
    let range = DisparityRange::up_to(max_disp).expect("a non-empty search range");
    let (mut bad, mut total, mut error_sum, mut error_count, mut valid) = (0, 0, 0.0, 0, 0);
    let mut seconds = 0.0;
    let mut megapixels = 0.0;
    let mut voted_inverted = 0;
    for pair in pairs {
        let settings = if refine {
            MatchSettings {
                contrast: match std::env::var("ANAGLYPH_CONTRAST").as_deref() {
                    Ok("same") => Contrast::Same,
                    Ok("either") => Contrast::Either,
                    _ => Contrast::Auto,
                },
                ..MatchSettings::for_cost(cost, range)
            }
        } else {
            MatchSettings::raw(range)
        };
        let started = Instant::now();
        let out = match_pair(&pair.left, &pair.right, cost, &settings).expect("match");
        voted_inverted += usize::from(out.contrast.is_some_and(|c| c.inverted));
        if let (Some(c), Ok(_)) = (out.contrast, std::env::var("ANAGLYPH_VOTES")) {
            eprintln!(
                "{}: inverted share {:.3} of {} windows",
                pair.label, c.inverted_share, c.windows
            );
        }
        seconds += started.elapsed().as_secs_f64();
        megapixels += (pair.left.width * pair.left.height) as f64 / 1e6;
        for (e, t) in out.disparity.data.iter().zip(&pair.disparity) {
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
        voted_inverted,
    }
}

fn main() -> anyhow::Result<()> {
    let args: Vec<usize> = std::env::args()
        .skip(1)
        .map(|a| a.parse())
        .collect::<Result<_, _>>()?;
    let count = args.first().copied().unwrap_or(12);
    let (width, height) = (
        args.get(1).copied().unwrap_or(256),
        args.get(2).copied().unwrap_or(192),
    );
    let rig_mode = std::env::var("ANAGLYPH_PAIRS").is_ok_and(|v| v == "rig");
    let mut pairs = Vec::new();
    let max_disp;
    if rig_mode {
        // The paper rig's horizontal neighbours on the three presets, at the rig's own
        // 1800 px focal length (disparities 20–46 px), each also with the left gel on
        // both cameras.
        max_disp = 64;
        let presets = std::env::var("ANAGLYPH_PRESETS")
            .unwrap_or_else(|_| "tabletop,clutter,periodic".into());
        for (k, preset) in presets.split(',').enumerate() {
            for pair in RIG_NEIGHBOURS {
                for filters in [pair, [pair[0], pair[0]]] {
                    let camera = RigPair {
                        filters,
                        sensor: "canon_eos_5d_mark_ii",
                        focal_length_px: 1800.0,
                    };
                    pairs.push(rig_pair(
                        SceneFile::preset(preset)?,
                        &camera,
                        width,
                        height,
                        TEST_SEED + k as u64,
                    )?);
                }
            }
        }
        println!(
            "the paper rig's 6 horizontal neighbours on {presets} at {width}×{height}, \
             f = 1800 px, {max_disp} disparities"
        );
    } else {
        // Every held-out scene twice, once with different gels or channels, once with
        // the same: the two kinds differ only in the filters.
        let kind = std::env::var("ANAGLYPH_PAIRS").unwrap_or_default();
        let narrow = kind == "narrow";
        let camera = kind == "camera";
        let settings = PairSettings {
            width,
            height,
            homogeneous_share: 0.5,
            narrow_band_share: if narrow { 1.0 } else { 0.0 },
            camera_effects_share: if camera { 1.0 } else { 0.0 },
        };
        max_disp = 64 * width / 256;
        for i in 0..count as u64 {
            for homogeneous in [false, true] {
                pairs.push(simulated_pair_with(
                    TEST_SEED + i,
                    &settings,
                    Some(homogeneous),
                    None,
                )?);
            }
        }
        println!(
            "{count} held-out random scenes (seeds {TEST_SEED}+) at {width}×{height}, \
             {max_disp} disparities{}",
            match (narrow, camera) {
                (true, _) => ", monochrome cameras behind narrow-band filters",
                (_, true) => ", recorded through camera effects (CameraEffects)",
                _ => "",
            }
        );
    }
    let model = std::env::var_os("ANAGLYPH_FAST_MODEL").map(std::path::PathBuf::from);
    let fast = MatchMethod::Mccnn
        .network(model.as_deref())?
        .ok_or_else(|| anyhow::anyhow!("mccnn is a learned method"))?;
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
    if let Ok(only) = std::env::var("ANAGLYPH_COSTS") {
        let only: Vec<&str> = only.split(',').collect();
        costs.retain(|c| only.contains(&c.name()));
    }
    let inverted: Vec<StereoPair> = pairs
        .iter()
        .filter(|p| p.kind == PairKind::Heterogeneous)
        .map(|p| StereoPair {
            right: negated(&p.right),
            ..p.clone()
        })
        .collect();
    // The same pairs with only the right image's lower half inverted: a scene whose
    // filters invert some surfaces and not others.
    let half_inverted: Vec<StereoPair> = inverted
        .iter()
        .zip(pairs.iter().filter(|p| p.kind == PairKind::Heterogeneous))
        .map(|(negative, p)| {
            let split = p.right.width * (p.right.height / 2);
            let mut right = p.right.clone();
            right.data[split..].copy_from_slice(&negative.right.data[split..]);
            StereoPair { right, ..p.clone() }
        })
        .collect();
    let groups: [(&str, Vec<&StereoPair>); 4] = [
        (
            "heterogeneous",
            pairs
                .iter()
                .filter(|p| p.kind == PairKind::Heterogeneous)
                .collect(),
        ),
        (
            "homogeneous",
            pairs
                .iter()
                .filter(|p| p.kind == PairKind::Homogeneous)
                .collect(),
        ),
        ("inverted", inverted.iter().collect()),
        ("half inverted", half_inverted.iter().collect()),
    ];
    if let Some(dir) = std::env::var_os("ANAGLYPH_WRITE_PAIRS") {
        write_pairs(std::path::Path::new(&dir), &groups, max_disp)?;
    }
    println!(
        "| cost | chain | pairs | bad-2.0 % | avg error px | density % | s / Mpx / 100 disp | voted inverted |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for cost in &costs {
        for refine in [false, true] {
            for (name, subset) in &groups {
                let s = score(subset, cost, refine, max_disp);
                println!(
                    "| {} | {} | {name} ({}) | {:.1} | {:.2} | {:.1} | {:.2} | {} |",
                    cost.name(),
                    if refine { "refined" } else { "raw" },
                    subset.len(),
                    s.bad2,
                    s.error,
                    s.density,
                    s.seconds_per_mpx_100d,
                    if refine {
                        s.voted_inverted.to_string()
                    } else {
                        "-".into()
                    }
                );
            }
        }
    }
    Ok(())
}

/// Writes every group's pairs to `dir` as PFM (left, right and the truth, NaN where it is
/// unknown), with `index.tsv`: group, file stem, the pair's label and the disparities
/// searched (`0..max_disp`; the scores count pixels whose truth is below `max_disp − 1`).
fn write_pairs(
    dir: &std::path::Path,
    groups: &[(&str, Vec<&StereoPair>)],
    max_disp: usize,
) -> anyhow::Result<()> {
    use anaglyph_core::image::Image;
    use anaglyph_core::io::write_pfm;
    std::fs::create_dir_all(dir)?;
    let mut index = String::from("group\tstem\tlabel\tmax_disp\n");
    for (name, subset) in groups {
        for (k, pair) in subset.iter().enumerate() {
            let stem = format!("{}-{k:02}", name.replace(' ', "-"));
            let (w, h) = (pair.left.width, pair.left.height);
            write_pfm(&dir.join(format!("{stem}-left.pfm")), &pair.left)?;
            write_pfm(&dir.join(format!("{stem}-right.pfm")), &pair.right)?;
            let truth = Image::new(w, h, 1, pair.disparity.clone())?;
            write_pfm(&dir.join(format!("{stem}-truth.pfm")), &truth)?;
            index.push_str(&format!("{name}\t{stem}\t{}\t{max_disp}\n", pair.label));
        }
    }
    std::fs::write(dir.join("index.tsv"), index)?;
    println!("wrote the pairs to {}", dir.display());
    Ok(())
}

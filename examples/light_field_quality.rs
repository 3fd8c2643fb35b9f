//! The light-field quality table of the README and docs/reconstruction.md: the paper rig (2×4, filters chosen by
//! cond(C), f = 1800 px) renders each preset scene; every view is reconstructed with the
//! simulator's true disparities (the registration ceiling), pairwise registration and
//! multi-baseline registration; the reference view r0c0 and the mean over all views are
//! scored (PSNR / SSIM band averages on reflectance, as the paper's Table 1).
//!
//! `cargo run --release --example light_field_quality -- [WIDTH] [HEIGHT]`
//! (default 640 480); `ANAGLYPH_PRESETS=tabletop` and
//! `ANAGLYPH_MODES=truth,pairwise,multi-baseline` narrow the run (`multi-baseline-luminance`
//! matches luminance instead of the default common signals);
//! `ANAGLYPH_REFINEMENTS=none,4:1e-4:1.5` lists the guided refinements scored for each
//! mode (`none`, or radius:epsilon:confidence with confidence 0 for equal weights;
//! registration runs once per mode), each optionally followed by
//! `+NOISE_SCALE[@CLUSTERS][^ROUNDS]` to add the scene prior (`+0.5@1`: one Gaussian
//! instead of the default mixture; `+0.5^0`: no propagation rounds).
//! `ANAGLYPH_DISPUTED=T` sets the disputed measurements' residual tolerance (default
//! `DISPUTED_TOLERANCE`; 0: the cameras' maps decide visibility alone).
//! `ANAGLYPH_FAST_MODEL=M.safetensors` registers with another fast network than the
//! embedded one (`models/mccnn-fast-4k.safetensors` reproduces the figures measured with
//! the previous default).

use anaglyph_core::disparity::{DisparityConvention, DisparityMap};
use anaglyph_core::evaluation::{score_cube, seen_by_all_views};
use anaglyph_core::reconstruct::{
    reconstruct, ArrayCaptures, Disparities, DisparitySearch, LightField, PipelineSettings,
};
use anaglyph_core::refine::GuidedRefinement;
use anaglyph_core::register::{ArrayGeometry, MatchingImage, RegistrationMode};
use anaglyph_core::rig::{Rig, PAPER_RIG_FILTERS};
use anaglyph_core::scene::{MetamerVariation, Scene, SceneFile, TEST_SCENES};
use anaglyph_core::simulate::{Simulation, SimulationSettings};
use anaglyph_core::solve::{
    ScenePriorSettings, SolveSettings, DISPUTED_TOLERANCE, INCONSISTENCY_FACTOR,
};
use anaglyph_core::stereo::{DisparityRange, MatchMethod, MatchingCost};
use std::time::Instant;

/// Margin of the search range over the scene's largest true disparity (its nearest
/// surface), as a user sets `--max-disp` from the rig's working distance.
const SEARCH_MARGIN: f32 = 1.1;

fn main() -> anyhow::Result<()> {
    let args: Vec<usize> = std::env::args()
        .skip(1)
        .map(|a| a.parse())
        .collect::<Result<_, _>>()?;
    let (width, height) = (
        args.first().copied().unwrap_or(640),
        args.get(1).copied().unwrap_or(480),
    );
    let presets: Vec<String> = match std::env::var("ANAGLYPH_PRESETS") {
        Ok(list) => list.split(',').map(str::to_string).collect(),
        Err(_) => TEST_SCENES.iter().map(|k| k.to_string()).collect(),
    };
    let modes: Vec<String> = match std::env::var("ANAGLYPH_MODES") {
        Ok(list) => list.split(',').map(str::to_string).collect(),
        Err(_) => vec!["truth".into(), "pairwise".into(), "multi-baseline".into()],
    };
    let disputed_tolerance = match std::env::var("ANAGLYPH_DISPUTED") {
        Ok(text) => Some(text.parse::<f64>()?).filter(|&t| t > 0.0),
        Err(_) => Some(DISPUTED_TOLERANCE),
    };
    let refinements: Vec<Refinement> = std::env::var("ANAGLYPH_REFINEMENTS")
        .unwrap_or_else(|_| "none,4:1e-4:1.5".into())
        .split(',')
        .map(parse_refinement)
        .collect::<anyhow::Result<_>>()?;
    // ANAGLYPH_METAMERS=AMPLITUDE: texture spectra vary at fixed colour (10 mm features).
    let metamers = match std::env::var("ANAGLYPH_METAMERS") {
        Ok(text) => Some(MetamerVariation {
            amplitude: text.parse()?,
            scale_mm: 10.0,
        }),
        Err(_) => None,
    };
    let rig = Rig::from_file(Rig::paper_rig_file(&PAPER_RIG_FILTERS), ".".into())?;
    let geometry = ArrayGeometry::of_rig(&rig);
    let model = std::env::var_os("ANAGLYPH_FAST_MODEL").map(std::path::PathBuf::from);
    let network = MatchMethod::Mccnn
        .network(model.as_deref())?
        .ok_or_else(|| anyhow::anyhow!("mccnn is a learned method"))?;
    println!("| scene | registration | refinement | r0c0 PSNR | r0c0 SSIM | r0c0 seen-by-all PSNR | all views PSNR | all views SSIM | seconds |");
    println!("|---|---|---|---|---|---|---|---|---|");
    for preset in &presets {
        let scene = Scene::resolve(SceneFile::preset(preset)?, std::path::Path::new("."))?;
        let settings = SimulationSettings {
            width,
            height,
            metamers,
            ..SimulationSettings::default()
        };
        let simulation = Simulation::run(&rig, &scene, settings)?;
        let captures = ArrayCaptures::from_simulation(&simulation);
        let truth_maps: Vec<Vec<f32>> = simulation
            .views
            .iter()
            .map(|v| v.disparity.clone())
            .collect();
        let largest = truth_maps
            .iter()
            .flatten()
            .filter(|d| d.is_finite())
            .fold(0.0f32, |a, &b| a.max(b));
        let max_disp = (largest * SEARCH_MARGIN).ceil() as usize + 2;
        for mode in &modes {
            let (registration_mode, given) = registration_of(mode, &truth_maps)?;
            let matching_image = if mode == "multi-baseline-luminance" {
                MatchingImage::Luminance
            } else {
                MatchingImage::CommonSignals
            };
            let search = DisparitySearch::Fixed(DisparityRange::up_to(max_disp)?);
            let disparities = match given {
                Some(maps) => Disparities::Given(column_step_maps(maps, width, height)?),
                None => Disparities::Search(search),
            };
            let mut pipeline = PipelineSettings {
                registration: registration_mode,
                disparities,
                matching_image,
                white_reflectance: simulation.settings.white_reflectance,
                solve: solve_settings(refinements[0], disputed_tolerance),
                ..PipelineSettings::new(MatchingCost::Learned(&network))
            };
            let start = Instant::now();
            let field = reconstruct(&rig, &captures, &pipeline, &|_, _, _| {})?;
            let seconds = start.elapsed().as_secs_f64();
            // The other refinements reuse this registration.
            pipeline.disparities =
                Disparities::Given(field.views.iter().map(|v| v.disparity.clone()).collect());
            for (k, &refinement) in refinements.iter().enumerate() {
                let (field, seconds) = if k == 0 {
                    (field.clone(), seconds)
                } else {
                    pipeline.solve = solve_settings(refinement, disputed_tolerance);
                    let start = Instant::now();
                    let refined = reconstruct(&rig, &captures, &pipeline, &|_, _, _| {})?;
                    (refined, start.elapsed().as_secs_f64())
                };
                let label = label_of(refinement);
                let row = TableRow {
                    preset,
                    mode,
                    label: &label,
                    seconds,
                };
                print_scores(&row, &field, &simulation, &geometry)?;
                eprintln!("{preset} {mode} {label}: {:?}", field.timings);
                if k > 0 {
                    continue;
                }
                print_bad2(&field, &truth_maps);
            }
        }
    }
    Ok(())
}

/// The solve's stages for a (refinement, scene prior) pair: the inconsistent pixels run
/// with the scene prior, which estimates them.
fn solve_settings(
    (refinement, scene_prior): (Option<GuidedRefinement>, Option<ScenePriorSettings>),
    disputed_tolerance: Option<f64>,
) -> SolveSettings {
    SolveSettings {
        disputed_tolerance,
        inconsistency_factor: scene_prior.map(|_| INCONSISTENCY_FACTOR),
        scene_prior,
        refinement,
    }
}

/// Maps per column step of the array (the simulator's convention) as disparity maps.
fn column_step_maps(
    maps: Vec<Vec<f32>>,
    width: usize,
    height: usize,
) -> anyhow::Result<Vec<DisparityMap>> {
    maps.into_iter()
        .map(|m| {
            Ok(DisparityMap::new(
                width,
                height,
                DisparityConvention::ColumnStep,
                m,
            )?)
        })
        .collect()
}

/// A refinement and scene prior to compare.
type Refinement = (Option<GuidedRefinement>, Option<ScenePriorSettings>);

/// `none` or `RADIUS:EPSILON:CONFIDENCE`, then `+NOISE_SCALE[@CLUSTERS][^ROUNDS]` for the
/// scene prior.
fn parse_refinement(item: &str) -> anyhow::Result<Refinement> {
    let (item, prior) = match item.split_once('+') {
        Some((item, prior)) => (item, Some(parse_prior(prior)?)),
        None => (item, None),
    };
    if item == "none" {
        return Ok((None, prior));
    }
    let fields: Vec<&str> = item.split(':').collect();
    let [radius, epsilon, confidence] = fields[..] else {
        anyhow::bail!(
            "refinement {item}: expected none or RADIUS:EPSILON:CONFIDENCE, then +NOISE_SCALE[@CLUSTERS][^ROUNDS] for the scene prior"
        );
    };
    let confidence: f64 = confidence.parse()?;
    Ok((
        Some(GuidedRefinement {
            radius: radius.parse()?,
            epsilon: epsilon.parse()?,
            confidence_scale: (confidence > 0.0).then_some(confidence),
        }),
        prior,
    ))
}

/// `NOISE_SCALE[@CLUSTERS][^ROUNDS]`, the defaults where left out.
fn parse_prior(text: &str) -> anyhow::Result<ScenePriorSettings> {
    let defaults = ScenePriorSettings::default();
    let (prior, rounds) = match text.split_once('^') {
        Some((prior, rounds)) => (prior, rounds.parse()?),
        None => (text, defaults.propagation_rounds),
    };
    let (scale, clusters) = match prior.split_once('@') {
        Some((scale, clusters)) => (scale, clusters.parse()?),
        None => (prior, defaults.clusters),
    };
    Ok(ScenePriorSettings {
        noise_scale: scale.parse()?,
        clusters,
        propagation_rounds: rounds,
    })
}

/// The registration of a mode, and the maps it is given instead (the truth, or the truth
/// with seeded Gaussian errors of σ px for `truth+σ`: how much subpixel error costs).
fn registration_of(
    mode: &str,
    truth_maps: &[Vec<f32>],
) -> anyhow::Result<(RegistrationMode, Option<Vec<Vec<f32>>>)> {
    Ok(match mode {
        "truth" => (RegistrationMode::Pairwise, Some(truth_maps.to_vec())),
        jittered if jittered.starts_with("truth+") => {
            let sigma: f32 = jittered["truth+".len()..].parse()?;
            let mut state = 0x9E37_79B9_7F4A_7C15u64;
            let mut gauss = move || {
                let mut uniform = || {
                    state ^= state << 13;
                    state ^= state >> 7;
                    state ^= state << 17;
                    (state >> 11) as f32 / (1u64 << 53) as f32
                };
                let (u, v) = (uniform().max(1e-12), uniform());
                (-2.0 * u.ln()).sqrt() * (std::f32::consts::TAU * v).cos()
            };
            let maps = truth_maps
                .iter()
                .map(|m| m.iter().map(|&d| d + sigma * gauss()).collect())
                .collect();
            (RegistrationMode::Pairwise, Some(maps))
        }
        "pairwise" => (RegistrationMode::Pairwise, None),
        "multi-baseline" | "multi-baseline-luminance" => (RegistrationMode::MultiBaseline, None),
        other => anyhow::bail!("unknown mode {other}"),
    })
}

/// The table's label of a refinement and scene prior.
fn label_of(refinement: Refinement) -> String {
    let mut label = match refinement.0 {
        None => "none".to_string(),
        Some(r) => format!(
            "guided r={} ε={:e} confidence {}",
            r.radius,
            r.epsilon,
            r.confidence_scale.unwrap_or(0.0)
        ),
    };
    if let Some(prior) = refinement.1 {
        label += &format!(
            ", scene prior ×{} in {} clusters, {} propagation rounds",
            prior.noise_scale, prior.clusters, prior.propagation_rounds
        );
    }
    label
}

/// Each view's bad-2 (% of pixels with a positive true disparity off by more than 2 px).
fn print_bad2(field: &LightField, truth_maps: &[Vec<f32>]) {
    for (view, truth) in field.views.iter().zip(truth_maps) {
        let (bad, total) = view
            .disparity
            .data
            .iter()
            .zip(truth)
            .filter(|(_, t)| t.is_finite() && **t > 0.0)
            .fold((0, 0), |(b, n), (e, t)| {
                (b + usize::from((e - t).abs() > 2.0 || e.is_nan()), n + 1)
            });
        eprint!(
            " {} bad-2 {:.1} %",
            view.name,
            100.0 * bad as f64 / total.max(1) as f64
        );
    }
    eprintln!();
}

/// What a row of the table is about.
struct TableRow<'a> {
    preset: &'a str,
    mode: &'a str,
    label: &'a str,
    seconds: f64,
}

/// Prints the table's row of `field`: r0c0 over all pixels and over the pixels every
/// camera sees, and the mean over views.
fn print_scores(
    row: &TableRow<'_>,
    field: &LightField,
    simulation: &Simulation,
    geometry: &ArrayGeometry,
) -> anyhow::Result<()> {
    let (width, height) = (simulation.settings.width, simulation.settings.height);
    let nb = field.bands.len();
    let (mut psnr_sum, mut ssim_sum) = (0.0, 0.0);
    let mut reference = None;
    for (i, view) in field.views.iter().enumerate() {
        let truth = &simulation.views[i].truth;
        let all = score_cube(truth, &view.cube()?.data, width, height, nb, None)?;
        psnr_sum += all.psnr;
        ssim_sum += all.ssim;
        if i == 0 {
            let mask = seen_by_all_views(&simulation.disparity_maps(), geometry, 0);
            let seen = score_cube(truth, &view.cube()?.data, width, height, nb, Some(&mask))?;
            reference = Some((all, seen));
        }
    }
    let n = field.views.len() as f64;
    if let Some((all, seen)) = reference {
        println!(
            "| {} | {} | {} | {:.2} | {:.4} | {:.2} | {:.2} | {:.4} | {:.1} |",
            row.preset,
            row.mode,
            row.label,
            all.psnr,
            all.ssim,
            seen.psnr,
            psnr_sum / n,
            ssim_sum / n,
            row.seconds
        );
    }
    Ok(())
}

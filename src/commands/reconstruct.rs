//! `anaglyph reconstruct`: a rig's captures to a multispectral light field in the fixed
//! output layout of `anaglyph_core::reconstruct::write_light_field`, with a progress bar
//! per stage.

use super::{begin_output, format_seconds, optional_curve, rig_inputs};
use crate::cli::{ReconstructArgs, SearchRangeArg, TuningArgs, ViewList};
use anaglyph_core::disparity::{DisparityConvention, DisparityMap};
use anaglyph_core::io::{read_pfm, verify_output_subfolder};
use anaglyph_core::reconstruct::{
    reconstruct, write_light_field, ArrayCaptures, LightField, OutputOptions, PipelineSettings,
    Stage,
};
use anaglyph_core::refine::GuidedRefinement;
use anaglyph_core::rig::Rig;
use anaglyph_core::solve::{ScenePriorSettings, SolveSettings};
use anaglyph_core::stereo::MatchingCost;
use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The simulator's true disparity maps in rig order (per column step of the array).
fn true_disparities(
    dir: &Path,
    rig: &Rig,
    width: usize,
    height: usize,
) -> anyhow::Result<Vec<DisparityMap>> {
    rig.cameras
        .iter()
        .map(|cam| {
            let path = dir.join(format!("truth/{}_disparity.pfm", cam.name));
            let map = DisparityMap::from_pfm(read_pfm(&path)?, DisparityConvention::ColumnStep)
                .with_context(|| path.display().to_string())?;
            map.check(width, height, DisparityConvention::ColumnStep)
                .with_context(|| format!("{}: against the captures", path.display()))?;
            Ok(map)
        })
        .collect()
}

/// A bar whose message names the stage and whose length follows it.
fn stage_bar() -> ProgressBar {
    let bar = ProgressBar::new(1);
    bar.set_style(
        ProgressStyle::with_template("{msg:<16} [{bar:30}] {pos}/{len} views [{elapsed}]")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    bar
}

pub fn run(args: ReconstructArgs) -> anyhow::Result<()> {
    let started = Instant::now();
    let method = args.registration.method;
    let network = method.network(args.registration.model.as_deref())?;
    let cost = method.cost(network.as_ref())?;
    let mut settings = pipeline_settings(&args, cost);
    settings.validate()?;
    let rig = load_rig(&args)?;
    for (option, dir) in [
        ("--truth", &args.truth),
        ("--true-disparity", &args.true_disparity),
    ] {
        if let Some(dir) = dir {
            verify_output_subfolder(dir, "truth").with_context(|| {
                format!(
                    "{option} {}: not one simulation's complete output",
                    dir.display()
                )
            })?;
        }
    }
    let folder = begin_output(&args.out, args.force, &input_paths(&args, &rig))?;
    let captures = ArrayCaptures::load(
        &rig,
        args.captures.as_deref(),
        args.white.as_deref(),
        args.calibration.as_deref(),
    )?;
    let options = OutputOptions {
        products: args.output,
        probes: args.probe.clone().map(|p| p.0).unwrap_or_default(),
        truth: args.truth.clone(),
        parameters: manifest_parameters(&args, &rig, &settings),
        loading_seconds: 0.0,
    };
    let views = settings
        .views
        .clone()
        .unwrap_or_else(|| rig.cameras.iter().map(|c| c.name.clone()).collect());
    let bands = rig.reconstruction_shape()?.count;
    let views: Vec<&str> = views.iter().map(String::as_str).collect();
    options.check(captures.width, captures.height, bands, &views)?;
    if let Some(dir) = &args.true_disparity {
        let maps = true_disparities(dir, &rig, captures.width, captures.height)?;
        settings.given_disparities = Some(maps);
        settings.automatic_search_range = false;
    }
    let options = OutputOptions {
        loading_seconds: started.elapsed().as_secs_f64(),
        ..options
    };
    let bar = stage_bar();
    let field = reconstruct(&rig, &captures, &settings, &|stage, done, total| {
        bar.set_message(match stage {
            Stage::Rectification => "rectification",
            Stage::Registration => "registration",
            Stage::Views => "views",
        });
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    })?;
    bar.finish_and_clear();
    let count = write_light_field(&folder, &rig, &field, &options)?;
    let out = folder.commit()?;
    print_summary(&field);
    println!(
        "wrote {count} files under {} in {}",
        out.display(),
        format_seconds(started.elapsed().as_secs_f64())
    );
    Ok(())
}

/// Every path the run reads, which the output folder must not hold.
fn input_paths(args: &ReconstructArgs, rig: &Rig) -> Vec<PathBuf> {
    let given = [
        Some(&args.rig),
        args.captures.as_ref(),
        args.white.as_ref(),
        args.calibration.as_ref(),
        args.truth.as_ref(),
        args.true_disparity.as_ref(),
        args.registration.model.as_ref(),
    ];
    let mut paths: Vec<PathBuf> = given.into_iter().flatten().cloned().collect();
    paths.extend(rig_inputs(rig));
    paths
}

/// The rig, with `--illuminant` folded in (`none`: no illuminant, white boards only).
fn load_rig(args: &ReconstructArgs) -> anyhow::Result<Rig> {
    let mut rig = Rig::load(&args.rig)?;
    if let Some(reference) = &args.illuminant {
        let light =
            optional_curve(reference).with_context(|| format!("--illuminant {reference}"))?;
        if let Some(light) = &light {
            for cam in &rig.cameras {
                let (lo, hi) = cam.sensor.domain();
                light.check_covers(lo, hi)?;
            }
        }
        rig.illuminant = light;
    }
    Ok(rig)
}

/// The preset's settings with every option the user gave applied over them.
fn pipeline_settings<'a>(args: &ReconstructArgs, cost: MatchingCost<'a>) -> PipelineSettings<'a> {
    let tuning = &args.tuning;
    let mut settings = PipelineSettings::with_preset(cost, args.preset);
    settings.registration.mode = args.registration.registration;
    if let SearchRangeArg::Fixed(range) = args.search_range() {
        settings.registration.range = range;
        settings.automatic_search_range = false;
    }
    settings.keep_registered = args.output.registered();
    settings.white_reflectance = args.white_reflectance;
    settings.saturation_level = args.saturation;
    settings.demux.solver = tuning.solver;
    settings.views = match &args.views {
        ViewList::All => None,
        ViewList::Some(list) => Some(list.clone()),
    };
    if let Some(choice) = tuning.matching_image {
        settings.matching_image = choice;
    }
    if let Some(choice) = tuning.warp_kernel {
        settings.warp_kernel = choice;
    }
    settings.solve = solve_settings(tuning, settings.solve);
    settings
}

/// The preset's solve with the tuning options applied: a stage's option switches it on,
/// `--no-…` off, 0 off where documented.
fn solve_settings(tuning: &TuningArgs, preset: SolveSettings) -> SolveSettings {
    let mut solve = preset;
    if let Some(t) = tuning.disputed_tolerance {
        solve.disputed_tolerance = (t > 0.0).then_some(t);
    }
    let prior_asked = tuning.scene_prior_noise.is_some()
        || tuning.scene_prior_clusters.is_some()
        || tuning.scene_prior_rounds.is_some();
    if prior_asked && solve.scene_prior.is_none() {
        solve.scene_prior = Some(ScenePriorSettings::default());
    }
    if let Some(prior) = &mut solve.scene_prior {
        prior.noise_scale = tuning.scene_prior_noise.unwrap_or(prior.noise_scale);
        prior.clusters = tuning
            .scene_prior_clusters
            .map_or(prior.clusters, |c| c as usize);
        prior.propagation_rounds = tuning
            .scene_prior_rounds
            .map_or(prior.propagation_rounds, |r| r as usize);
    }
    if let Some(k) = tuning.scene_prior_inconsistency {
        solve.inconsistency_factor = (k > 0.0).then_some(k);
    }
    if tuning.no_scene_prior {
        solve.scene_prior = None;
        solve.inconsistency_factor = None;
    }
    let refine_asked = tuning.refine_radius.is_some()
        || tuning.refine_epsilon.is_some()
        || tuning.refine_confidence.is_some();
    if refine_asked && solve.refinement.is_none() {
        solve.refinement = Some(GuidedRefinement::default());
    }
    if let Some(refinement) = &mut solve.refinement {
        refinement.radius = tuning
            .refine_radius
            .map_or(refinement.radius, |r| r as usize);
        refinement.epsilon = tuning.refine_epsilon.unwrap_or(refinement.epsilon);
        if let Some(scale) = tuning.refine_confidence {
            refinement.confidence_scale = (scale > 0.0).then_some(scale);
        }
    }
    if tuning.no_refine {
        solve.refinement = None;
    }
    solve
}

/// Inputs and settings as the manifest records them.
fn manifest_parameters(
    args: &ReconstructArgs,
    rig: &Rig,
    settings: &PipelineSettings<'_>,
) -> serde_json::Value {
    let path = |p: &Option<std::path::PathBuf>| p.as_ref().map(|p| p.display().to_string());
    serde_json::json!({
        "rig": args.rig.display().to_string(),
        "captures": path(&args.captures),
        "white": path(&args.white),
        "calibration": path(&args.calibration),
        "illuminant": args.illuminant,
        "preset": args.preset.to_string(),
        "output": args.output,
        "registration": if settings.given_disparities.is_some() {
            "true disparities".to_string()
        } else {
            format!("{:?}", settings.registration.mode)
        },
        "matching_image": settings.matching_image,
        "true_disparity": path(&args.true_disparity),
        "method": args.registration.method.to_string(),
        "model": path(&args.registration.model),
        "disp_range": match args.search_range() {
            SearchRangeArg::Fixed(range) => serde_json::json!(range),
            SearchRangeArg::Auto => serde_json::json!("auto"),
        },
        "white_reflectance": args.white_reflectance,
        "saturation": args.saturation,
        "solver": format!("{:?}", settings.demux.solver),
        "lambda": rig.file.reconstruction.lambda,
        "refinement": settings.solve.refinement,
        "scene_prior": settings.solve.scene_prior,
        "disputed_tolerance": settings.solve.disputed_tolerance,
        "inconsistency_factor": settings.solve.inconsistency_factor,
        "warp_kernel": settings.warp_kernel,
        "out_of_band": rig.file.reconstruction.out_of_band,
        "probes": args.probe.as_ref().map(|p| p.0.clone()),
    })
}

/// Warnings on standard error; what was reconstructed, per view and per stage, on
/// standard output.
fn print_summary(field: &LightField) {
    for warning in &field.warnings {
        eprintln!("warning: {warning}");
    }
    println!(
        "reconstructed {} view(s) of {}x{} px, {} bands ({}–{} nm); cond(C) = {:.3e}",
        field.views.len(),
        field.width,
        field.height,
        field.bands.len(),
        field.bands.first().copied().unwrap_or(0.0),
        field.bands.last().copied().unwrap_or(0.0),
        field.condition_number
    );
    if let Some(range) = &field.search_range {
        println!(
            "  search range {} chosen from a {}x coarse registration (confirmed disparities within {:.1} to {:.1} px)",
            range.range, range.factor, range.covered_disparity_px[0], range.covered_disparity_px[1]
        );
    }
    for view in &field.views {
        println!(
            "  {}: {:.1} % of pixels seen by every camera, {} without a measurement",
            view.name,
            100.0 * view.visibility.seen_by_all,
            view.solve.demux.unmeasured_pixels
        );
        let pairs: Vec<String> = view
            .pair_agreements
            .iter()
            .map(|p| format!("{} {:.1} %", p.neighbour, 100.0 * p.agreeing))
            .collect();
        if !pairs.is_empty() {
            println!("    maps agree within 1 px with {}", pairs.join(", "));
        }
    }
    for (stage, seconds) in &field.timings {
        println!("  {stage:<40} {}", format_seconds(*seconds));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cli::{Args, Command};
    use anaglyph_core::disparity::DisparityRange;
    use anaglyph_core::register::WarpKernel;
    use clap::Parser;

    fn settings_of(extra: &[&str]) -> PipelineSettings<'static> {
        let mut argv = vec!["anaglyph", "reconstruct", "--rig", "r.toml", "--out", "o"];
        argv.extend_from_slice(extra);
        let Command::Reconstruct(args) = Args::try_parse_from(argv).unwrap().command else {
            panic!("not reconstruct");
        };
        pipeline_settings(&args, MatchingCost::Census)
    }

    #[test]
    fn presets_choose_the_stages_and_options_override_them() {
        let default = settings_of(&[]);
        assert_eq!(default.solve, SolveSettings::default());
        assert_eq!(default.warp_kernel, WarpKernel::Lanczos3);
        assert!(default.automatic_search_range);

        let paper = settings_of(&["--preset", "paper"]);
        assert_eq!(paper.solve, SolveSettings::paper());
        assert_eq!(paper.warp_kernel, WarpKernel::Bilinear);

        let fast = settings_of(&["--preset", "fast"]);
        let prior = fast.solve.scene_prior.unwrap();
        assert_eq!((prior.clusters, prior.propagation_rounds), (8, 0));

        // A stage's option switches it on over a preset without it.
        let refined = settings_of(&["--preset", "paper", "--refine-radius", "3"]);
        assert_eq!(refined.solve.refinement.unwrap().radius, 3);
        assert!(refined.solve.scene_prior.is_none());

        // --no-scene-prior also switches off the stage that hands its pixels to the prior.
        let no_prior = settings_of(&["--no-scene-prior", "--max-disp", "40"]);
        assert!(no_prior.solve.scene_prior.is_none());
        assert!(no_prior.solve.inconsistency_factor.is_none());
        no_prior.validate().unwrap();
        assert_eq!(
            no_prior.registration.range,
            DisparityRange { min: 0, max: 40 }
        );
        assert!(!no_prior.automatic_search_range);
        let signed = settings_of(&["--disp-range", "-24:8"]);
        assert_eq!(
            signed.registration.range,
            DisparityRange { min: -24, max: 8 }
        );
        assert!(!signed.automatic_search_range);
        assert!(settings_of(&["--disp-range", "auto"]).automatic_search_range);

        let off = settings_of(&["--disputed-tolerance", "0", "--refine-confidence", "0"]);
        assert!(off.solve.disputed_tolerance.is_none());
        assert!(off.solve.refinement.unwrap().confidence_scale.is_none());
    }
}

//! `anaglyph reconstruct`: a rig's captures to a multispectral light field in the fixed
//! output layout of `anaglyph_core::reconstruct::write_light_field`, with a progress bar
//! per stage.

use super::format_seconds;
use super::match_pair::{load_network, matching_cost};
use crate::cli::{
    MatchingImageChoice, ReconstructArgs, RegistrationChoice, SearchRangeArg, ViewList,
    WarpKernelChoice,
};
use anaglyph_core::demux::DemuxOptions;
use anaglyph_core::io::read_pfm;
use anaglyph_core::reconstruct::{
    reconstruct, write_light_field, ArrayCaptures, OutputOptions, PipelineSettings, Stage,
};
use anaglyph_core::refine::GuidedRefinement;
use anaglyph_core::register::{MatchingImage, RegistrationMode, RegistrationSettings, WarpKernel};
use anaglyph_core::rig::{resolve_curve, Rig};
use anaglyph_core::solve::{ScenePriorSettings, SolveSettings};
use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};
use std::path::Path;
use std::time::Instant;

/// The simulator's true disparity maps in rig order.
fn true_disparities(
    dir: &Path,
    rig: &Rig,
    width: usize,
    height: usize,
) -> anyhow::Result<Vec<Vec<f32>>> {
    rig.cameras
        .iter()
        .map(|cam| {
            let path = dir.join(format!("truth/r{}c{}_disparity.pfm", cam.row, cam.col));
            let map = read_pfm(&path)?;
            if (map.width, map.height, map.channels) != (width, height, 1) {
                anyhow::bail!(
                    "{}: {}x{}x{} (expected {width}x{height}x1, the captures' size)",
                    path.display(),
                    map.width,
                    map.height,
                    map.channels
                );
            }
            Ok(map.data)
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
    if !(args.white_reflectance > 0.0 && args.white_reflectance <= 1.0) {
        anyhow::bail!(
            "--white-reflectance {} (expected in (0, 1])",
            args.white_reflectance
        );
    }
    if !(args.saturation > 0.0 && args.saturation <= 1.0) {
        anyhow::bail!("--saturation {} (expected in (0, 1])", args.saturation);
    }
    let mut rig = Rig::load(&args.rig)?;
    if let Some(reference) = &args.illuminant {
        let light = resolve_curve(reference, Path::new("."))
            .with_context(|| format!("--illuminant {reference}"))?;
        for cam in &rig.cameras {
            let (lo, hi) = cam.sensor.domain();
            light.check_covers(lo, hi)?;
        }
        rig.illuminant = Some(light);
    }
    let captures = ArrayCaptures::load(
        &rig,
        args.captures.as_deref(),
        args.white.as_deref(),
        args.calibration.as_deref(),
    )?;
    let (w, h) = (captures.width, captures.height);
    let given = args
        .true_disparity
        .as_deref()
        .map(|dir| true_disparities(dir, &rig, w, h))
        .transpose()?;
    let network = load_network(args.method, args.model.as_deref())?;
    let cost = matching_cost(args.method, network.as_ref())?;
    let mode = match args.registration {
        RegistrationChoice::MultiBaseline => RegistrationMode::MultiBaseline,
        RegistrationChoice::Pairwise => RegistrationMode::Pairwise,
    };
    let settings = PipelineSettings {
        registration: RegistrationSettings {
            mode,
            cost,
            max_disp: match args.max_disp {
                SearchRangeArg::Fixed(n) => n,
                SearchRangeArg::Auto => 64, // replaced by the estimate
            },
        },
        white_reflectance: args.white_reflectance,
        saturation_level: args.saturation,
        demux: DemuxOptions {
            solver: args.solver.into(),
            ..DemuxOptions::default()
        },
        views: match &args.views {
            ViewList::All => None,
            ViewList::Some(list) => Some(list.clone()),
        },
        automatic_search_range: args.max_disp == SearchRangeArg::Auto && given.is_none(),
        given_disparities: given,
        matching_image: match args.matching_image {
            MatchingImageChoice::CommonSignals => MatchingImage::CommonSignals,
            MatchingImageChoice::Luminance => MatchingImage::Luminance,
        },
        solve: SolveSettings {
            disputed_tolerance: (args.disputed_tolerance > 0.0).then_some(args.disputed_tolerance),
            inconsistency_factor: (!args.no_scene_prior && args.scene_prior_inconsistency > 0.0)
                .then_some(args.scene_prior_inconsistency),
            scene_prior: (!args.no_scene_prior).then_some(ScenePriorSettings {
                noise_scale: args.scene_prior_noise,
                clusters: args.scene_prior_clusters as usize,
                propagation_rounds: args.scene_prior_rounds as usize,
            }),
            refinement: (!args.no_refine).then_some(GuidedRefinement {
                radius: args.refine_radius as usize,
                epsilon: args.refine_epsilon,
                confidence_scale: (args.refine_confidence > 0.0).then_some(args.refine_confidence),
            }),
        },
        warp_kernel: match args.warp_kernel {
            WarpKernelChoice::Lanczos3 => WarpKernel::Lanczos3,
            WarpKernelChoice::Bilinear => WarpKernel::Bilinear,
        },
    };
    let loading = started.elapsed().as_secs_f64();
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
    let parameters = serde_json::json!({
        "rig": args.rig.display().to_string(),
        "captures": args.captures.as_ref().map(|p| p.display().to_string()),
        "white": args.white.as_ref().map(|p| p.display().to_string()),
        "calibration": args.calibration.as_ref().map(|p| p.display().to_string()),
        "illuminant": args.illuminant,
        "registration": if settings.given_disparities.is_some() { "true disparities".to_string() } else { format!("{mode:?}") },
        "matching_image": settings.matching_image,
        "true_disparity": args.true_disparity.as_ref().map(|p| p.display().to_string()),
        "method": format!("{:?}", args.method),
        "model": args.model.as_ref().map(|p| p.display().to_string()),
        "max_disp": match args.max_disp {
            SearchRangeArg::Fixed(n) => serde_json::json!(n),
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
    });
    let options = OutputOptions {
        probes: args.probe.clone().map(|p| p.0).unwrap_or_default(),
        truth: args.truth.clone(),
        parameters,
        loading_seconds: loading,
    };
    let files = write_light_field(&args.out, &rig, &field, &options)?;
    for warning in &field.warnings {
        eprintln!("warning: {warning}");
    }
    println!(
        "reconstructed {} view(s) of {}x{} px, {} bands ({}–{} nm); cond(C) = {:.3e}",
        field.views.len(),
        w,
        h,
        field.bands.len(),
        field.bands.first().copied().unwrap_or(0.0),
        field.bands.last().copied().unwrap_or(0.0),
        field.condition_number
    );
    if let Some(range) = &field.search_range {
        println!(
            "  search range [0, {}) chosen from a {}x coarse registration (98 % of disparities below {:.1} px)",
            range.max_disp, range.factor, range.covered_disparity_px
        );
    }
    for view in &field.views {
        println!(
            "  r{}c{}: {:.1} % of pixels seen by every camera, {} without a measurement",
            view.row,
            view.col,
            100.0 * view.visibility.seen_by_all,
            view.solve.demux.unmeasured_pixels
        );
    }
    for (stage, seconds) in &field.timings {
        println!("  {stage:<40} {}", format_seconds(*seconds));
    }
    println!(
        "wrote {} files under {} in {}",
        files.len(),
        args.out.display(),
        format_seconds(started.elapsed().as_secs_f64())
    );
    Ok(())
}

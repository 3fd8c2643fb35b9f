//! `anaglyph reconstruct`: a rig's captures to a multispectral light field in the fixed
//! output layout of `anaglyph_core::reconstruct::write_light_field`, each view written as
//! soon as it is done, with a progress bar per stage.

use super::{begin_output, format_seconds, optional_curve, rig_inputs};
use crate::cli::{ReconstructArgs, ViewList};
use anaglyph_core::disparity::{DisparityConvention, DisparityMap};
use anaglyph_core::io::{read_pfm, verify_output_subfolder, LightFieldStore, PendingWrite};
use anaglyph_core::reconstruct::{
    reconstruct_next, reconstruct_streaming, ArrayCaptures, Disparities, FrameCarry, FrameFiles,
    FrameSequence, LightField, LightFieldWriter, OutputOptions, PipelineSettings,
    ReconstructOptions, ReuseReport, SolveTuning, Stage,
};
use anaglyph_core::rig::Rig;
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

/// Whether `--out` names a Zarr store.
fn is_store(out: &Path) -> bool {
    out.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("zarr"))
}

pub fn run(args: ReconstructArgs) -> anyhow::Result<()> {
    if args.frames.is_some() || is_store(&args.out) {
        return run_sequence(args);
    }
    let started = Instant::now();
    let request = reconstruct_options(&args);
    request.validate()?;
    let network = request.network()?;
    let mut settings = request.settings(network.as_ref())?;
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
    if let Some(dir) = &args.true_disparity {
        let maps = true_disparities(dir, &rig, captures.width, captures.height)?;
        settings.disparities = Disparities::Given(maps);
    }
    let options = OutputOptions {
        products: args.output,
        probes: args.probe.clone().map(|p| p.0).unwrap_or_default(),
        truth: args.truth.clone(),
        parameters: manifest_parameters(&args, &rig, &request, &settings),
        loading_seconds: 0.0,
    };
    let views = settings
        .views
        .clone()
        .unwrap_or_else(|| rig.cameras.iter().map(|c| c.name.clone()).collect());
    let bands = rig.reconstruction_shape()?.count;
    let views: Vec<&str> = views.iter().map(String::as_str).collect();
    options.check(captures.width, captures.height, bands, &views)?;
    let options = OutputOptions {
        loading_seconds: started.elapsed().as_secs_f64(),
        ..options
    };
    let bar = stage_bar();
    // Each view is written as soon as it is done, and its images dropped.
    let mut writer = LightFieldWriter::new(&folder, &rig, &options)?;
    let field = reconstruct_streaming(
        &rig,
        &captures,
        &settings,
        &|stage, done, total| {
            bar.set_message(stage.name());
            bar.set_length(total as u64);
            bar.set_position(done as u64);
        },
        &mut |layout, view| writer.view(layout, view),
    )?;
    bar.finish_and_clear();
    let count = writer.finish(&field)?;
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
        args.darks.as_ref(),
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

/// What the command line asks of reconstruction: the one conversion of its options into
/// the core's, which both the CLI and the Python package turn into settings.
fn reconstruct_options(args: &ReconstructArgs) -> ReconstructOptions {
    let t = &args.tuning;
    ReconstructOptions {
        preset: args.preset,
        registration: args.registration.registration,
        method: args.registration.method,
        model: args.registration.model.clone(),
        disp_range: args.search_range(),
        output: args.output,
        views: match &args.views {
            ViewList::All => None,
            ViewList::Some(list) => Some(list.clone()),
        },
        white_reflectance: args.white_reflectance,
        saturation: args.saturation,
        solver: t.solver,
        matching_image: t.matching_image,
        warp_kernel: t.warp_kernel,
        coarse_to_fine: t.coarse_to_fine,
        tuning: SolveTuning {
            disputed_tolerance: t.disputed_tolerance,
            scene_prior_inconsistency: t.scene_prior_inconsistency,
            no_scene_prior: t.no_scene_prior,
            scene_prior_noise: t.scene_prior_noise,
            scene_prior_clusters: t.scene_prior_clusters.map(|c| c as usize),
            scene_prior_rounds: t.scene_prior_rounds.map(|r| r as usize),
            no_refine: t.no_refine,
            refine_radius: t.refine_radius.map(|r| r as usize),
            refine_epsilon: t.refine_epsilon,
            refine_confidence: t.refine_confidence,
        },
        temporal_reuse: !args.no_reuse,
    }
}

/// Inputs and settings as the manifest records them.
fn manifest_parameters(
    args: &ReconstructArgs,
    rig: &Rig,
    request: &ReconstructOptions,
    settings: &PipelineSettings<'_>,
) -> serde_json::Value {
    let path = |p: &Option<std::path::PathBuf>| p.as_ref().map(|p| p.display().to_string());
    let mut record = request.record(settings, rig);
    let inputs = serde_json::json!({
        "interface": "cli",
        "rig": args.rig.display().to_string(),
        "captures": path(&args.captures),
        "white": path(&args.white),
        "calibration": path(&args.calibration),
        "illuminant": args.illuminant,
        "true_disparity": path(&args.true_disparity),
        "probes": args.probe.as_ref().map(|p| p.0.clone()),
    });
    if let (Some(record), serde_json::Value::Object(inputs)) = (record.as_object_mut(), inputs) {
        record.extend(inputs);
    }
    record
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

/// `reconstruct` into a Zarr store: the frames of `--frames` (or the one frame of the
/// captures), each written as it finishes, with one progress bar.
fn run_sequence(args: ReconstructArgs) -> anyhow::Result<()> {
    let started = Instant::now();
    if !is_store(&args.out) {
        anyhow::bail!(
            "--out {}: a sequence (--frames) goes to a Zarr store (expected a path ending in .zarr)",
            args.out.display()
        );
    }
    for (option, given) in [
        ("--probe", args.probe.is_some()),
        ("--truth", args.truth.is_some()),
        ("--true-disparity", args.true_disparity.is_some()),
    ] {
        if given {
            anyhow::bail!(
                "{option} with --out {}: a Zarr store holds no probe plots or true disparities \
                 (expected an output folder for them)",
                args.out.display()
            );
        }
    }
    let request = reconstruct_options(&args);
    request.validate()?;
    let network = request.network()?;
    let settings = request.settings(network.as_ref())?;
    let rig = load_rig(&args)?;
    let out = std::path::absolute(&args.out).unwrap_or_else(|_| args.out.clone());
    for input in input_paths(&args, &rig) {
        let input = std::path::absolute(&input).unwrap_or(input);
        if input.starts_with(&out) || out == input {
            anyhow::bail!(
                "--out {}: holds the input {} (expected a store apart from the inputs)",
                args.out.display(),
                input.display()
            );
        }
    }
    // Every frame's files are found, and the first frame read, before any work.
    let frames: Vec<Option<FrameFiles>> = match (args.frames, &args.captures) {
        (Some(range), Some(dir)) => {
            let mut sequence = FrameSequence::discover(&rig, dir, args.layout, range)?;
            if let Some(darks) = &args.darks {
                sequence = sequence.with_darks(&rig, darks)?;
            }
            for (first, last) in sequence.gaps() {
                eprintln!("note: frames {first} to {last} are missing from the numbering");
            }
            sequence.frames.into_iter().map(Some).collect()
        }
        _ => vec![None],
    };
    let numbers: Vec<i64> = frames
        .iter()
        .map(|f| f.as_ref().map_or(0, |f| f.number))
        .collect();
    let load = |frame: &Option<FrameFiles>| -> anyhow::Result<ArrayCaptures> {
        let (white, calibration) = (args.white.as_deref(), args.calibration.as_deref());
        Ok(match frame {
            Some(files) => ArrayCaptures::load_frame(&rig, files, white, calibration)
                .with_context(|| format!("frame {}", files.number))?,
            None => ArrayCaptures::load(&rig, args.captures.as_deref(), white, calibration)?,
        })
    };
    let first = load(&frames[0])?;
    let layout = request.store_layout(
        &settings,
        &rig,
        numbers.clone(),
        (first.width, first.height),
    )?;
    let store = LightFieldStore::create(&args.out, layout, args.force)?;
    let done = store.frames_done()?;
    let todo = done.iter().filter(|d| !**d).count();
    if todo < frames.len() {
        eprintln!(
            "note: {} of {} frames are already in {}; computing the other {todo}",
            frames.len() - todo,
            frames.len(),
            args.out.display()
        );
    }
    let bar = ProgressBar::new(todo as u64);
    bar.set_style(
        ProgressStyle::with_template(
            "frame {msg:<24} [{bar:30}] {pos}/{len} frames [{elapsed}<{eta}]",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    let mut first = Some(first);
    let mut seconds = Vec::new();
    // What the last frame computed hands to the next (temporal reuse).
    let mut carry: Option<FrameCarry> = None;
    let mut reused = ReuseTally::default();
    // The last frame's write, on a thread of its own while the next frame is computed
    // (waited for before the next write; dropped on an error, it still ends).
    let mut pending: Option<PendingWrite> = None;
    for ((frame, &number), done) in frames.iter().zip(&numbers).zip(done) {
        if done {
            // The next frame computed follows a gap: nothing to carry over it.
            first = None;
            carry = None;
            continue;
        }
        let clock = Instant::now();
        let captures = match first.take() {
            Some(captures) => captures,
            None => load(frame)?,
        };
        let progress = |stage: Stage, done, total| {
            bar.set_message(format!("{number}: {} {done}/{total}", stage.name()));
        };
        let previous = carry.take().filter(|_| request.temporal_reuse);
        let (field, next) =
            reconstruct_next(&rig, &captures, &settings, &progress, previous.as_ref())
                .with_context(|| format!("frame {number}"))?;
        carry = Some(next);
        for warning in &field.warnings {
            bar.suspend(|| eprintln!("warning: frame {number}: {warning}"));
        }
        if let Some(report) = &field.reuse {
            reused.add(report);
            if report.cut {
                bar.suspend(|| {
                    eprintln!("note: frame {number} is a cut: reconstructed without reuse")
                });
            }
        }
        let frame_seconds = clock.elapsed().as_secs_f64();
        seconds.push(frame_seconds);
        finish_write(pending.take())?;
        pending = Some(store.write_frame_in_background(number, field, frame_seconds)?);
        bar.inc(1);
    }
    finish_write(pending.take())?;
    bar.finish_and_clear();
    if request.temporal_reuse && seconds.len() > 1 {
        println!("{}", reused.summary());
    }
    let mut sorted = seconds.clone();
    sorted.sort_by(f64::total_cmp);
    let median = sorted.get(sorted.len() / 2).copied().unwrap_or(0.0);
    println!(
        "wrote {} frame(s) into {} (median {} per frame) in {}",
        seconds.len(),
        args.out.display(),
        format_seconds(median),
        format_seconds(started.elapsed().as_secs_f64())
    );
    Ok(())
}

/// Waits for a frame's write into the store; its error names the frame.
fn finish_write(write: Option<PendingWrite>) -> anyhow::Result<()> {
    if let Some(write) = write {
        let frame = write.frame();
        write.wait().with_context(|| format!("frame {frame}"))?;
    }
    Ok(())
}

/// What the frames of a run reused, summed for one line at the end.
#[derive(Default)]
struct ReuseTally {
    frames: usize,
    cuts: usize,
    narrowed: usize,
    fallbacks: usize,
    priors_carried: usize,
    priors: usize,
}

impl ReuseTally {
    fn add(&mut self, report: &ReuseReport) {
        if !report.previous {
            return;
        }
        self.frames += 1;
        self.cuts += usize::from(report.cut);
        self.narrowed += usize::from(report.narrowed_range.is_some() && !report.range_fallback);
        self.fallbacks += usize::from(report.range_fallback);
        self.priors_carried += report.priors_carried;
        self.priors += report.priors_carried + report.priors_learned;
    }

    fn summary(&self) -> String {
        format!(
            "temporal reuse over {} frame(s) after the first: {} cut(s), search range narrowed \
             in {} (widened again in {}), {} of {} scene priors carried",
            self.frames, self.cuts, self.narrowed, self.fallbacks, self.priors_carried, self.priors
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cli::{Args, Command};
    use anaglyph_core::disparity::DisparityRange;
    use anaglyph_core::reconstruct::{DisparitySearch, Preset};
    use clap::Parser;

    fn options_of(extra: &[&str]) -> ReconstructOptions {
        let mut argv = vec!["anaglyph", "reconstruct", "--rig", "r.toml", "--out", "o"];
        argv.extend_from_slice(extra);
        let Command::Reconstruct(args) = Args::try_parse_from(argv).unwrap().command else {
            panic!("not reconstruct");
        };
        reconstruct_options(&args)
    }

    #[test]
    fn every_option_reaches_the_core_s_options() {
        assert_eq!(options_of(&[]), ReconstructOptions::default());
        let given = options_of(&[
            "--preset",
            "paper",
            "--method",
            "census",
            "--disp-range",
            "-24:8",
            "--views",
            "r0c0,r1c1",
            "--no-scene-prior",
            "--refine-radius",
            "3",
            "--scene-prior-clusters",
            "5",
            "--solver",
            "lsqr",
            "--output",
            "both",
            "--frames",
            "all",
            "--captures",
            "c",
            "--no-reuse",
        ]);
        assert!(!given.temporal_reuse);
        assert_eq!(given.preset, Preset::Paper);
        assert_eq!(
            given.disp_range,
            DisparitySearch::Fixed(DisparityRange { min: -24, max: 8 })
        );
        assert_eq!(given.views, Some(vec!["r0c0".into(), "r1c1".into()]));
        assert!(given.tuning.no_scene_prior);
        assert_eq!(given.tuning.refine_radius, Some(3));
        assert_eq!(given.tuning.scene_prior_clusters, Some(5));
        assert_eq!(given.solver.to_string(), "lsqr");
        assert!(given.output.registered() && given.output.cubes());
        assert_eq!(
            options_of(&["--max-disp", "40"]).disp_range,
            DisparitySearch::Fixed(DisparityRange { min: 0, max: 40 })
        );
        let settings = given.settings(None).unwrap();
        assert!(settings.solve.scene_prior.is_none());
    }
}

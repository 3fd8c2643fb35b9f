//! `anaglyph train`: trains the matching network on simulated cross-spectral pairs with a
//! progress bar and the held-out validation printed as it goes; writes safetensors with
//! the recipe in the metadata.

use super::{check_output_files, format_seconds};
use crate::cli::{ArchitectureChoice, TrainArgs};
use anaglyph_cnn::dataset::Sampling;
use anaglyph_cnn::{train_segment, Architecture, Checkpoint, Outcome, Segment, TrainSettings};
use anaglyph_core::io::write_atomically;
use clap::ValueEnum;
use indicatif::{ProgressBar, ProgressStyle};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// The checkpoint's file and its curve's in a checkpoint folder.
const CHECKPOINT_FILE: &str = "checkpoint.safetensors";
const CHECKPOINT_CURVE: &str = "curve.csv";

pub fn run(args: TrainArgs) -> anyhow::Result<()> {
    let minutes = |option: &str, value: f64| -> anyhow::Result<Duration> {
        if !(value.is_finite() && value > 0.0 && value <= 1e6) {
            anyhow::bail!("{option} {value}: expected a positive number of minutes");
        }
        Ok(Duration::from_secs_f64(value * 60.0))
    };
    let checkpoint_every = minutes("--checkpoint-minutes", args.checkpoint_minutes)?;
    let segment_time = args
        .segment_minutes
        .map(|m| minutes("--segment-minutes", m))
        .transpose()?;
    let folder = args.checkpoint.as_deref().or(args.resume.as_deref());
    if folder.is_none() {
        if let Some(m) = args.segment_minutes {
            anyhow::bail!(
                "--segment-minutes {m}: a run that stops before its last step must save where \
                 it stands (expected --checkpoint DIR with it)"
            );
        }
        if let Some(s) = args.stop_at_step {
            anyhow::bail!(
                "--stop-at-step {s}: a run that stops before its last step must save where it \
                 stands (expected --checkpoint DIR with it)"
            );
        }
    }
    let resumed = args
        .resume
        .as_deref()
        .map(|dir| -> anyhow::Result<Checkpoint> {
            let file = dir.join(CHECKPOINT_FILE);
            if dir.is_file() {
                anyhow::bail!(
                    "--resume {}: is a file (expected the folder given to --checkpoint)",
                    dir.display()
                );
            }
            if !file.is_file() {
                anyhow::bail!(
                    "--resume {}: no {CHECKPOINT_FILE} there (expected a folder that \
                     `anaglyph train --checkpoint` wrote)",
                    dir.display()
                );
            }
            Ok(Checkpoint::load(&file)?)
        })
        .transpose()?;
    let settings = match &resumed {
        Some(checkpoint) => recipe_of_checkpoint(&args, checkpoint)?,
        None => recipe(&args)?,
    };
    let mut outputs = vec![("--out", args.out.as_path())];
    outputs.extend(args.curve.as_deref().map(|p| ("--curve", p)));
    check_output_files(&outputs, &[])?;
    if let Some(dir) = &args.checkpoint {
        prepare_checkpoint_folder(dir)?;
    }
    // The checkpoint's own files are rewritten; they must be neither --out nor --curve.
    let checkpoint_file = folder.map(|dir| dir.join(CHECKPOINT_FILE));
    let checkpoint_curve = folder.map(|dir| dir.join(CHECKPOINT_CURVE));
    outputs.extend(checkpoint_file.as_deref().map(|p| ("the checkpoint", p)));
    outputs.extend(
        checkpoint_curve
            .as_deref()
            .map(|p| ("the checkpoint's curve", p)),
    );
    check_output_files(&outputs, &[])?;
    if let (Some(stop), Some(checkpoint)) = (args.stop_at_step, &resumed) {
        if stop as usize <= checkpoint.step {
            anyhow::bail!(
                "--stop-at-step {stop}: the checkpoint is at step {} already (expected a later step)",
                checkpoint.step
            );
        }
    }
    // The command that makes the same weights at once (a run in segments ends bit for bit
    // where the run made at once does), with the first segment's outputs.
    let command = match resumed.as_ref().and_then(|c| c.notes.get("command")) {
        Some(first) => first.clone(),
        None => recipe_command(&settings, &args),
    };
    let start = resumed.as_ref().map_or(0, |c| c.step);
    eprintln!(
        "training {:?} for {} steps (batch {}, {} scenes, seed {}, peak learning rate {}){}",
        settings.architecture,
        settings.steps,
        settings.batch,
        settings.training_scenes,
        settings.seed,
        settings.learning_rate,
        if start > 0 {
            format!(", resumed at step {start}")
        } else {
            String::new()
        }
    );
    eprintln!("rendering training and validation pairs…");
    let bar = ProgressBar::new(settings.steps as u64);
    bar.set_style(
        ProgressStyle::with_template("{bar:40} {pos}/{len} steps, loss {msg} [{elapsed} < {eta}]")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar.set_position(start as u64);
    bar.reset_eta();
    let mut save = |checkpoint: &Checkpoint| -> anaglyph_cnn::Result<()> {
        let (Some(file), Some(curve)) = (&checkpoint_file, &checkpoint_curve) else {
            return Ok(());
        };
        let mut checkpoint = checkpoint.clone();
        checkpoint
            .notes
            .entry("command".into())
            .or_insert_with(|| command.clone());
        let bytes = checkpoint.to_bytes()?;
        write_atomically(file, |w| w.write_all(&bytes))?;
        write_atomically(curve, |w| write_curve(w, &checkpoint.curve))?;
        Ok(())
    };
    let segment = Segment {
        resume: resumed,
        stop_at_step: args.stop_at_step.map(|s| s as usize),
        time_limit: segment_time,
        checkpoint_every: Some(checkpoint_every),
        save: Some(&mut save),
    };
    let mut smoothed = f64::NAN;
    let outcome = train_segment(&settings, segment, |report| {
        smoothed = if smoothed.is_nan() {
            report.loss
        } else {
            0.98 * smoothed + 0.02 * report.loss
        };
        bar.set_position(report.step as u64);
        bar.set_message(format!("{smoothed:.4}"));
        if let Some(v) = report.validation {
            let line = format!(
                "step {:>6} {:>8}: train loss {:.4}, held-out triplet error {:.2} %, \
                 winner-take-all bad-2 {:.2} % heterogeneous, {:.2} % homogeneous",
                v.step,
                format_seconds(v.seconds),
                v.train_loss,
                v.triplet_error,
                v.bad2_heterogeneous,
                v.bad2_homogeneous
            );
            if bar.is_hidden() {
                eprintln!("{line}");
            } else {
                bar.println(line);
            }
        }
    });
    bar.finish_and_clear();
    let model = match outcome? {
        Outcome::Finished(model) => model,
        Outcome::Paused(checkpoint) => {
            let dir = folder.unwrap_or(Path::new("."));
            let mut again = format!(
                "anaglyph train --resume {} --out {}",
                dir.display(),
                args.out.display()
            );
            if let Some(curve) = &args.curve {
                again.push_str(&format!(" --curve {}", curve.display()));
            }
            if let Some(m) = args.segment_minutes {
                again.push_str(&format!(" --segment-minutes {m}"));
            }
            eprintln!(
                "paused at step {} of {} after {} of training (checkpoint in {}); continue \
                 with: {again}",
                checkpoint.step,
                settings.steps,
                format_seconds(checkpoint.seconds),
                dir.display()
            );
            return Ok(());
        }
    };
    let bytes = model.to_safetensors(&settings, &command)?;
    write_atomically(&args.out, |w| w.write_all(&bytes))?;
    if let Some(path) = &args.curve {
        write_atomically(path, |w| write_curve(w, &model.curve))?;
    }
    eprintln!(
        "wrote {} ({} KB) after {}",
        args.out.display(),
        bytes.len() / 1024,
        format_seconds(model.seconds)
    );
    Ok(())
}

/// The network `--arch` names, with `--feature-maps` if given.
fn architecture(choice: ArchitectureChoice, feature_maps: Option<u64>) -> Architecture {
    let mut architecture = match choice {
        ArchitectureChoice::Fast => Architecture::FAST,
        ArchitectureChoice::Accurate => Architecture::ACCURATE,
    };
    if let Some(maps) = feature_maps {
        match &mut architecture {
            Architecture::Fast { feature_maps, .. }
            | Architecture::Accurate { feature_maps, .. } => *feature_maps = maps as usize,
        }
    }
    architecture
}

/// The `--arch` choice that names an architecture.
fn choice_of(architecture: &Architecture) -> ArchitectureChoice {
    match architecture {
        Architecture::Fast { .. } => ArchitectureChoice::Fast,
        Architecture::Accurate { .. } => ArchitectureChoice::Accurate,
    }
}

/// An `--arch` value as the command line spells it.
fn choice_name(choice: ArchitectureChoice) -> String {
    choice
        .to_possible_value()
        .map_or_else(String::new, |v| v.get_name().to_string())
}

/// The settings the recipe options ask for, with the defaults for those not given.
fn recipe(args: &TrainArgs) -> anyhow::Result<TrainSettings> {
    let architecture = architecture(
        args.arch.unwrap_or(ArchitectureChoice::Fast),
        args.feature_maps,
    );
    let mut settings = TrainSettings::new(architecture);
    if let Some(steps) = args.steps {
        settings.steps = steps as usize;
    }
    if let Some(seed) = args.seed {
        settings.seed = seed;
    }
    if let Some(batch) = args.batch {
        settings.batch = batch as usize;
    }
    if let Some(scenes) = args.scenes {
        settings.training_scenes = scenes as usize;
    }
    if let Some(every) = args.validate_every {
        settings.validate_every = every as usize;
    }
    if let Some(lr) = args.learning_rate {
        if !(lr.is_finite() && lr > 0.0 && lr < 1.0) {
            anyhow::bail!("--learning-rate {lr}: expected a number in (0, 1)");
        }
        settings.learning_rate = lr;
    }
    if let Some(share) = args.narrow_band_share {
        if !(0.0..=1.0).contains(&share) {
            anyhow::bail!("--narrow-band-share {share}: expected a share in [0, 1]");
        }
        settings.pairs.narrow_band_share = share;
    }
    if let Some(share) = args.camera_effects_share {
        if !(0.0..=1.0).contains(&share) {
            anyhow::bail!("--camera-effects-share {share}: expected a share in [0, 1]");
        }
        settings.pairs.camera_effects_share = share;
    }
    if let Some(offset) = args.positive_offset {
        if !(offset.is_finite() && (0.0..=4.0).contains(&offset)) {
            anyhow::bail!("--positive-offset {offset}: expected pixels in [0, 4]");
        }
        settings.sampling.positive_offset = offset;
    }
    if let Some(negatives) = args.negatives {
        settings.sampling.negative_offsets = negatives;
    }
    let sampling = settings.sampling;
    if sampling.negative_offsets.0 <= sampling.positive_offset {
        anyhow::bail!(
            "--negatives {}:{}: the nearest negative must lie farther from the true match \
             than the farthest positive ({} px)",
            sampling.negative_offsets.0,
            sampling.negative_offsets.1,
            sampling.positive_offset
        );
    }
    Ok(settings)
}

/// `anaglyph train` with every recipe option spelled out, and the outputs.
fn recipe_command(settings: &TrainSettings, args: &TrainArgs) -> String {
    let choice = choice_of(&settings.architecture);
    let maps = settings.architecture.feature_maps();
    let width = if maps == architecture(choice, None).feature_maps() {
        String::new()
    } else {
        format!(" --feature-maps {maps}")
    };
    let mut command = format!(
        "anaglyph train --arch {}{width} --steps {} --seed {} --batch {} --scenes {} \
         --learning-rate {} --validate-every {} --out {}",
        choice_name(choice),
        settings.steps,
        settings.seed,
        settings.batch,
        settings.training_scenes,
        settings.learning_rate,
        settings.validate_every,
        args.out.display()
    );
    if settings.pairs.narrow_band_share > 0.0 {
        command.push_str(&format!(
            " --narrow-band-share {}",
            settings.pairs.narrow_band_share
        ));
    }
    if settings.pairs.camera_effects_share > 0.0 {
        command.push_str(&format!(
            " --camera-effects-share {}",
            settings.pairs.camera_effects_share
        ));
    }
    if settings.sampling != Sampling::MC_CNN_KITTI {
        let s = settings.sampling;
        command.push_str(&format!(
            " --positive-offset {} --negatives {}:{}",
            s.positive_offset, s.negative_offsets.0, s.negative_offsets.1
        ));
    }
    if let Some(curve) = &args.curve {
        command.push_str(&format!(" --curve {}", curve.display()));
    }
    command
}

/// The checkpoint's recipe, after checking that the recipe options given agree with it.
fn recipe_of_checkpoint(
    args: &TrainArgs,
    checkpoint: &Checkpoint,
) -> anyhow::Result<TrainSettings> {
    let saved = &checkpoint.settings;
    let given: [(&str, Option<String>, String); 12] = [
        (
            "--arch",
            args.arch.map(choice_name),
            choice_name(choice_of(&saved.architecture)),
        ),
        (
            "--feature-maps",
            args.feature_maps.map(|v| v.to_string()),
            saved.architecture.feature_maps().to_string(),
        ),
        (
            "--steps",
            args.steps.map(|v| v.to_string()),
            saved.steps.to_string(),
        ),
        (
            "--seed",
            args.seed.map(|v| v.to_string()),
            saved.seed.to_string(),
        ),
        (
            "--batch",
            args.batch.map(|v| v.to_string()),
            saved.batch.to_string(),
        ),
        (
            "--scenes",
            args.scenes.map(|v| v.to_string()),
            saved.training_scenes.to_string(),
        ),
        (
            "--validate-every",
            args.validate_every.map(|v| v.to_string()),
            saved.validate_every.to_string(),
        ),
        (
            "--learning-rate",
            args.learning_rate.map(|v| v.to_string()),
            saved.learning_rate.to_string(),
        ),
        (
            "--narrow-band-share",
            args.narrow_band_share.map(|v| v.to_string()),
            saved.pairs.narrow_band_share.to_string(),
        ),
        (
            "--camera-effects-share",
            args.camera_effects_share.map(|v| v.to_string()),
            saved.pairs.camera_effects_share.to_string(),
        ),
        (
            "--positive-offset",
            args.positive_offset.map(|v| v.to_string()),
            saved.sampling.positive_offset.to_string(),
        ),
        (
            "--negatives",
            args.negatives.map(|(near, far)| format!("{near}:{far}")),
            format!(
                "{}:{}",
                saved.sampling.negative_offsets.0, saved.sampling.negative_offsets.1
            ),
        ),
    ];
    for (option, asked, kept) in given {
        if let Some(asked) = asked.filter(|a| *a != kept) {
            anyhow::bail!(
                "{option} {asked}: the run checkpointed in {} has {kept} (a resumed run keeps \
                 its recipe: leave the option out, or start a new run with --checkpoint)",
                args.resume.as_deref().unwrap_or(Path::new(".")).display()
            );
        }
    }
    Ok(saved.clone())
}

/// Creates the checkpoint folder (its parent must exist) or checks that it holds no
/// other run's checkpoint.
fn prepare_checkpoint_folder(dir: &Path) -> anyhow::Result<()> {
    let file: PathBuf = dir.join(CHECKPOINT_FILE);
    if file.exists() {
        let step = Checkpoint::load(&file)
            .map(|c| format!("at step {} of {}", c.step, c.settings.steps))
            .unwrap_or_else(|_| "unreadable".into());
        anyhow::bail!(
            "--checkpoint {}: holds a run's checkpoint ({step}) (expected a new or empty \
             folder; continue that run with --resume {})",
            dir.display(),
            dir.display()
        );
    }
    if dir.exists() && !dir.is_dir() {
        anyhow::bail!(
            "--checkpoint {}: is a file (expected a folder)",
            dir.display()
        );
    }
    if !dir.exists() {
        std::fs::create_dir(dir).map_err(|e| {
            anyhow::anyhow!(
                "--checkpoint {}: cannot create the folder: {e} (expected its parent folder \
                 to exist)",
                dir.display()
            )
        })?;
    }
    Ok(())
}

/// The validation curve as CSV.
fn write_curve(w: &mut dyn Write, curve: &[anaglyph_cnn::ValidationPoint]) -> std::io::Result<()> {
    writeln!(
        w,
        "step,seconds,train_loss,triplet_error_percent,bad2_heterogeneous_percent,bad2_homogeneous_percent"
    )?;
    for v in curve {
        writeln!(
            w,
            "{},{:.1},{:.5},{:.3},{:.3},{:.3}",
            v.step,
            v.seconds,
            v.train_loss,
            v.triplet_error,
            v.bad2_heterogeneous,
            v.bad2_homogeneous
        )?;
    }
    Ok(())
}

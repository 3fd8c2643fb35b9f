//! `anaglyph train`: trains the matching network on simulated cross-spectral pairs with a
//! progress bar and the held-out validation printed as it goes; writes safetensors with
//! the recipe in the metadata.

use super::{check_output_files, format_seconds};
use crate::cli::{ArchitectureChoice, TrainArgs};
use anaglyph_cnn::{train, Architecture, TrainSettings};
use anaglyph_core::io::write_atomically;
use indicatif::{ProgressBar, ProgressStyle};

pub fn run(args: TrainArgs) -> anyhow::Result<()> {
    let architecture = match args.arch {
        ArchitectureChoice::Fast => Architecture::FAST,
        ArchitectureChoice::Accurate => Architecture::ACCURATE,
    };
    let mut settings = TrainSettings::new(architecture);
    settings.steps = args.steps as usize;
    settings.seed = args.seed;
    settings.batch = args.batch as usize;
    settings.training_scenes = args.scenes as usize;
    settings.validate_every = args.validate_every as usize;
    if let Some(lr) = args.learning_rate {
        if !(lr.is_finite() && lr > 0.0 && lr < 1.0) {
            anyhow::bail!("--learning-rate {lr}: expected a number in (0, 1)");
        }
        settings.learning_rate = lr;
    }
    let mut outputs = vec![("--out", args.out.as_path())];
    outputs.extend(args.curve.as_deref().map(|p| ("--curve", p)));
    check_output_files(&outputs, &[])?;
    let command: Vec<String> = std::iter::once("anaglyph".to_string())
        .chain(std::env::args().skip(1))
        .collect();
    let command = command.join(" ");
    eprintln!(
        "training {:?} for {} steps (batch {}, {} scenes, seed {}, peak learning rate {})",
        architecture,
        settings.steps,
        settings.batch,
        settings.training_scenes,
        settings.seed,
        settings.learning_rate
    );
    eprintln!("rendering training and validation pairs…");
    let bar = ProgressBar::new(settings.steps as u64);
    bar.set_style(
        ProgressStyle::with_template("{bar:40} {pos}/{len} steps, loss {msg} [{elapsed} < {eta}]")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let mut smoothed = f64::NAN;
    let model = train(&settings, |report| {
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
    })?;
    bar.finish_and_clear();
    let bytes = model.to_safetensors(&settings, &command)?;
    write_atomically(&args.out, |w| w.write_all(&bytes))?;
    if let Some(path) = &args.curve {
        write_atomically(path, |w| {
            writeln!(w, "step,seconds,train_loss,triplet_error_percent,bad2_heterogeneous_percent,bad2_homogeneous_percent")?;
            for v in &model.curve {
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
        })?;
    }
    eprintln!(
        "wrote {} ({} KB) after {}",
        args.out.display(),
        bytes.len() / 1024,
        format_seconds(model.seconds)
    );
    Ok(())
}

//! `anaglyph rig init` (the paper's 2×4 rig with selected filters) and `anaglyph rig show`
//! (the rig, cond(C), out-of-band light, a plot of the effective responses).

use super::select_filters::{load_candidates, print_report, run_selection, SelectionInputs};
use super::{check_output_files, optional_curve, rig_curve_files};
use crate::cli::{RigCommand, RigInitArgs, RigShowArgs};
use anaglyph_core::capture::CameraNoise;
use anaglyph_core::filters::SelectionOptions;
use anaglyph_core::io::write_npy_f64;
use anaglyph_core::rig::{
    plot_effective_responses, resolve_curve, EffectiveResponses, OutOfBand, Rig, SensingMatrix,
    ILL_CONDITIONED_WARNING,
};
use anyhow::bail;
use std::path::{Path, PathBuf};

pub fn run(command: RigCommand) -> anyhow::Result<()> {
    match command {
        RigCommand::Init(args) => init(args),
        RigCommand::Show(args) => show(args),
    }
}

fn init(args: RigInitArgs) -> anyhow::Result<()> {
    if args.out.exists() && !args.force {
        bail!("{} exists (use --force to overwrite)", args.out.display());
    }
    let curves = super::curve_files(&[&args.sensor, &args.illuminant]);
    let inputs: Vec<(&str, &Path)> = curves.iter().map(|p| ("curve", p.as_path())).collect();
    check_output_files(&[("--out", &args.out)], &inputs)?;
    let inputs = SelectionInputs {
        candidates: load_candidates(None)?,
        sensor: resolve_curve(&args.sensor, Path::new("."))?,
        illuminant: optional_curve(&args.illuminant)?,
    };
    let options = SelectionOptions {
        count: 8,
        criterion: args.criterion,
        noise: CameraNoise::default(),
        lambda: 0.01,
        keep: 3,
        exhaustive_limit: anaglyph_core::filters::EXHAUSTIVE_LIMIT,
    };
    let (report, seconds) = run_selection(&inputs, &options, OutOfBand::Extend)?;
    print_report(&report, seconds);
    let best = &report.best[0];
    let names: Vec<&str> = best
        .filters
        .iter()
        .map(|&f| report.candidates[f].as_str())
        .collect();
    let mut file = Rig::paper_rig_file(&names);
    file.sensor = args.sensor.clone();
    file.illuminant =
        (!args.illuminant.eq_ignore_ascii_case("none")).then(|| args.illuminant.clone());
    file.save(&args.out)?;
    println!(
        "wrote {} (2×4, filters {})",
        args.out.display(),
        names.join(", ")
    );
    Ok(())
}

fn show(args: RigShowArgs) -> anyhow::Result<()> {
    let rig = Rig::load(&args.rig)?;
    let plot = args
        .plot
        .clone()
        .unwrap_or_else(|| default_plot_path(&args.rig));
    let mut outputs = vec![("--plot", plot.as_path())];
    outputs.extend(args.export_c.as_deref().map(|p| ("--export-c", p)));
    let curves = rig_curve_files(&rig);
    let mut inputs = vec![("--rig", args.rig.as_path())];
    inputs.extend(curves.iter().map(|p| ("the rig's curve", p.as_path())));
    check_output_files(&outputs, &inputs)?;
    let f = &rig.file;
    let shape = rig.reconstruction_shape()?;
    let layout = match (f.rows, f.cols, f.baseline_mm) {
        (Some(rows), Some(cols), Some(b)) => format!(
            "{rows} × {cols} cameras, baselines {} mm × {} mm",
            b.horizontal, b.vertical
        ),
        _ => format!(
            "{} cameras at their positions, disparities per {:.2} mm",
            rig.cameras.len(),
            rig.disparity_baseline_mm
        ),
    };
    let focal = f
        .focal_length_px
        .map_or("no focal length (reconstruction only)".to_string(), |v| {
            format!("focal length {v} px")
        });
    println!(
        "rig '{}': {layout}, reference {}, {focal}",
        f.name, rig.cameras[rig.reference].name
    );
    println!(
        "sensor {} ({:?}), illuminant {}",
        f.sensor,
        f.sensor_interpolation,
        f.illuminant.as_deref().unwrap_or("none (C maps radiance)")
    );
    println!(
        "reconstruction: {shape}, λ = {}, out-of-band light: {:?}",
        f.reconstruction.lambda, f.reconstruction.out_of_band
    );
    for cam in &rig.cameras {
        let (name, domain) = match &cam.filter {
            Some(filter) => {
                let (lo, hi) = filter.domain();
                (filter.name(), format!("({lo}–{hi} nm)"))
            }
            None => ("none given", String::new()),
        };
        println!(
            "  {:<6} [{:>7.1}, {:>7.1}] mm  filter {:<20} {domain}  sensor {} ({} ch){}",
            cam.name,
            cam.position_mm[0],
            cam.position_mm[1],
            name,
            cam.sensor.name(),
            cam.sensor.channel_count(),
            cam.image
                .as_ref()
                .map(|p| format!("  image {}", p.display()))
                .unwrap_or_default()
        );
    }
    let unfiltered: Vec<&str> = rig
        .cameras
        .iter()
        .filter(|c| c.filter.is_none())
        .map(|c| c.name.as_str())
        .collect();
    if !unfiltered.is_empty() && args.export_c.is_none() {
        println!(
            "sensing matrix C: none ({} give no filter; spectra need every camera's, a \
             registration-only run none)",
            unfiltered.join(", ")
        );
        return Ok(());
    }
    let responses = EffectiveResponses::of_rig(&rig)?;
    let c = SensingMatrix::from_responses(&responses, shape, f.reconstruction.out_of_band)?;
    let sv = c.singular_values()?;
    let cond = c.condition_number()?;
    println!(
        "sensing matrix C: {} × {} (unknown knots {}), integrated over {}–{} nm",
        c.rows(),
        c.cols(),
        c.unknowns,
        responses.grid.start,
        responses.grid.end()
    );
    println!(
        "cond(C) = {cond:.4e}  (σ_max {:.4e}, σ_min {:.4e})",
        sv[0],
        sv[sv.len() - 1]
    );
    if cond > ILL_CONDITIONED_WARNING {
        eprintln!(
            "warning: cond(C) = {cond:.3e} > {ILL_CONDITIONED_WARNING:.0e}: C alone is ill-conditioned; the smoothness prior (λ = {}) keeps the solve stable",
            f.reconstruction.lambda
        );
    }
    let inside = SensingMatrix::in_band_fraction(&responses, &shape);
    let (worst, label) = inside
        .iter()
        .zip(&c.row_labels)
        .map(|(f, l)| (1.0 - f, l))
        .fold(
            (0.0, &c.row_labels[0]),
            |a, b| if b.0 > a.0 { b } else { a },
        );
    println!(
        "light outside {}–{} nm: up to {:.1} % of a channel's signal ({label}); mean {:.1} %",
        shape.start - shape.step / 2.0,
        shape.end() + shape.step / 2.0,
        100.0 * worst,
        100.0 * inside.iter().map(|f| 1.0 - f).sum::<f64>() / inside.len() as f64
    );
    plot_effective_responses(
        &plot,
        &responses,
        &c,
        &shape,
        &format!(
            "{}: effective responses (shaded: reconstruction range)",
            f.name
        ),
    )?;
    println!("wrote {}", plot.display());
    if let Some(path) = &args.export_c {
        write_npy_f64(path, &[c.rows(), c.cols()], c.values().to_vec())?;
        println!(
            "wrote {} (C, {} × {}; reported bands are columns {}..{})",
            path.display(),
            c.rows(),
            c.cols(),
            c.reported_offset,
            c.reported_offset + shape.count
        );
    }
    Ok(())
}

/// `<stem>-responses.svg` beside the rig, or in the working folder when the rig lies in
/// a folder anaglyph wrote (a file added there would make the folder fail verification
/// and stop the next run into it).
fn default_plot_path(rig: &Path) -> PathBuf {
    let stem = rig
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "rig".into());
    let name = format!("{stem}-responses.svg");
    let in_output_folder = rig
        .parent()
        .is_some_and(|dir| dir.join(anaglyph_core::io::MANIFEST).is_file());
    if in_output_folder {
        PathBuf::from(name)
    } else {
        rig.with_file_name(name)
    }
}

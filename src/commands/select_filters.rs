//! `anaglyph select-filters`: the subset of candidate filters with the best sensing
//! matrix (paper section 3.2), exhaustive while tractable.

use super::{format_seconds, optional_curve};
use crate::cli::SelectFiltersArgs;
use crate::progress::spinner;
use anaglyph_core::capture::CameraNoise;
use anaglyph_core::filters::{
    builtin_candidates, select_for_sensor, SelectionOptions, SelectionReport,
};
use anaglyph_core::io::write_atomically;
use anaglyph_core::rig::{resolve_curve, OutOfBand};
use anaglyph_core::spectrum::ResponseCurve;
use anyhow::{bail, Context};
use std::path::Path;
use std::time::Instant;

/// Inputs of a selection, resolved.
pub struct SelectionInputs {
    pub candidates: Vec<ResponseCurve>,
    pub sensor: ResponseCurve,
    pub illuminant: Option<ResponseCurve>,
}

/// Loads every `*.csv` in `dir`, or the built-in gel library.
pub fn load_candidates(dir: Option<&Path>) -> anyhow::Result<Vec<ResponseCurve>> {
    let Some(dir) = dir else {
        return Ok(builtin_candidates()?);
    };
    let mut paths: Vec<_> = std::fs::read_dir(dir)
        .with_context(|| format!("reading candidate folder {}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("csv")))
        .collect();
    paths.sort();
    if paths.is_empty() {
        bail!("no .csv filter curves in {}", dir.display());
    }
    paths
        .iter()
        .map(|p| Ok(ResponseCurve::load_csv(p)?))
        .collect()
}

/// Runs the search with a spinner and reports its duration.
pub fn run_selection(
    inputs: &SelectionInputs,
    options: &SelectionOptions,
    out_of_band: OutOfBand,
) -> anyhow::Result<(SelectionReport, f64)> {
    let bar = spinner(format!(
        "searching {} of {} filters by {:?}",
        options.count,
        inputs.candidates.len(),
        options.criterion
    ));
    let start = Instant::now();
    let report = select_for_sensor(
        &inputs.candidates,
        &inputs.sensor,
        inputs.illuminant.as_ref(),
        options,
        out_of_band,
    )?;
    bar.finish_and_clear();
    Ok((report, start.elapsed().as_secs_f64()))
}

/// Prints the best subsets.
pub fn print_report(report: &SelectionReport, seconds: f64) {
    println!(
        "searched {} subsets {} in {}",
        report.evaluated,
        if report.exhaustive {
            "exhaustively"
        } else {
            "(greedy + swaps)"
        },
        format_seconds(seconds)
    );
    println!(
        "{:>4}  {:>12}  {:>13}  filters",
        "rank", "cond(C)", "expected RMSE"
    );
    for (i, s) in report.best.iter().enumerate() {
        let names: Vec<&str> = s
            .filters
            .iter()
            .map(|&f| report.candidates[f].as_str())
            .collect();
        println!(
            "{:>4}  {:>12.4e}  {:>13.5}  {}",
            i + 1,
            s.condition_number,
            s.expected_rmse,
            names.join(" ")
        );
    }
}

pub fn run(args: SelectFiltersArgs) -> anyhow::Result<()> {
    if !(args.lambda.is_finite() && args.lambda >= 0.0) {
        bail!("--lambda {} must be finite and >= 0", args.lambda);
    }
    if !(args.full_well > 0.0 && args.read_noise >= 0.0) {
        bail!("--full-well must be > 0 and --read-noise >= 0");
    }
    if let Some(json) = &args.json {
        let curves = super::curve_files(&[&args.sensor, &args.illuminant]);
        let inputs: Vec<(&str, &Path)> = curves.iter().map(|p| ("curve", p.as_path())).collect();
        super::check_output_files(&[("--json", json)], &inputs)?;
    }
    let inputs = SelectionInputs {
        candidates: load_candidates(args.candidates.as_deref())?,
        sensor: resolve_curve(&args.sensor, Path::new("."))?,
        illuminant: optional_curve(&args.illuminant)?,
    };
    let options = SelectionOptions {
        count: args.count,
        criterion: args.criterion,
        noise: CameraNoise {
            full_well_electrons: args.full_well,
            read_noise_electrons: args.read_noise,
            ..CameraNoise::default()
        },
        lambda: args.lambda,
        keep: args.keep,
        exhaustive_limit: args.exhaustive_limit,
    };
    let (report, seconds) = run_selection(&inputs, &options, args.out_of_band)?;
    print_report(&report, seconds);
    if let Some(path) = &args.json {
        let text = serde_json::to_string_pretty(&report)?;
        write_atomically(path, |w| w.write_all(text.as_bytes()))?;
    }
    Ok(())
}

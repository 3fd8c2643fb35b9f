//! `anaglyph calibrate-filter`: transmission = s1 / s0 with the Eq. 7 error bound.

use crate::cli::CalibrateFilterArgs;
use anaglyph_core::filters::calibrate_filter;
use anaglyph_core::spectrum::ResponseCurve;

pub fn run(args: CalibrateFilterArgs) -> anyhow::Result<()> {
    super::check_output_files(
        &[("--out", &args.out)],
        &[("--without", &args.without), ("--with", &args.with_filter)],
    )?;
    let without = ResponseCurve::load_csv(&args.without)?;
    let with = ResponseCurve::load_csv(&args.with_filter)?;
    let cal = calibrate_filter(&without, &with, args.relative_error)?;
    let stem = args
        .out
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    cal.transmission.clone().renamed(stem).save_csv(&args.out)?;
    let (lo, hi) = cal.transmission.domain();
    let t = cal.transmission.channel(0);
    let peak = t.iter().cloned().fold(0.0, f64::max);
    println!(
        "wrote {} ({} samples, {lo}–{hi} nm, {} target column(s)); peak transmission {peak:.4}",
        args.out.display(),
        t.len(),
        without.channel_count()
    );
    println!(
        "Eq. 7 error bound: relative {:.2} % (2E with E = {:.2} %), absolute at most {:.5}",
        100.0 * cal.relative_bound,
        100.0 * args.relative_error,
        cal.max_absolute_bound
    );
    if !cal.dark_wavelengths.is_empty() {
        let (a, b) = (
            cal.dark_wavelengths[0],
            cal.dark_wavelengths[cal.dark_wavelengths.len() - 1],
        );
        eprintln!(
            "warning: the reference reading is under 1 % of its peak at {} wavelengths ({a}–{b} nm); the ratio there is unreliable",
            cal.dark_wavelengths.len()
        );
    }
    if cal.clamped_negative > 0 {
        eprintln!(
            "warning: {} negative ratios were set to 0",
            cal.clamped_negative
        );
    }
    if cal.above_one > 0 {
        eprintln!(
            "warning: {} ratios exceed 1 (noise, or a fluorescent filter)",
            cal.above_one
        );
    }
    Ok(())
}

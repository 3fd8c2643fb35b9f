//! `anaglyph match`: the disparity of one rectified pair through the full stereo chain,
//! written as PFM (+inf where invalid), with an optional colour-mapped preview and a JSON
//! report of the settings and per-stage timings.

use super::{check_output_files, format_seconds};
use crate::cli::MatchArgs;
use crate::progress::spinner;
use anaglyph_core::io::{read_linear_image, write_atomically, write_disparity_preview, write_pfm};
use anaglyph_core::reconstruct::check_signal;
use anaglyph_core::stereo::{match_pair, DisparityRange, GreyChannel, GreyImage, MatchSettings};
use std::path::Path;
use std::time::Instant;

/// Reads one image as the grey plane to match.
fn load_grey(path: &Path, channel: GreyChannel) -> anyhow::Result<GreyImage> {
    let image = read_linear_image(path)?;
    Ok(channel.of(&image, &path.display().to_string())?)
}

pub fn run(args: MatchArgs) -> anyhow::Result<()> {
    let started = Instant::now();
    let mut outputs = vec![("--out", args.out.as_path())];
    outputs.extend(args.preview.as_deref().map(|p| ("--preview", p)));
    outputs.extend(args.report.as_deref().map(|p| ("--report", p)));
    let mut inputs = vec![
        ("--left", args.left.as_path()),
        ("--right", args.right.as_path()),
    ];
    inputs.extend(args.model.as_deref().map(|p| ("--model", p)));
    check_output_files(&outputs, &inputs)?;
    let left = load_grey(&args.left, args.channel)?;
    let right = load_grey(&args.right, args.channel)?;
    if (left.width, left.height) != (right.width, right.height) {
        anyhow::bail!(
            "{} is {}×{} but {} is {}×{}; a rectified pair has equal sizes",
            args.left.display(),
            left.width,
            left.height,
            args.right.display(),
            right.width,
            right.height
        );
    }
    let range = match (args.disp_range, args.max_disp) {
        (Some(range), _) => range,
        (None, Some(n)) => DisparityRange::up_to(n as usize)?,
        (None, None) => {
            anyhow::bail!("give the disparities searched: --disp-range MIN:MAX or --max-disp N")
        }
    };
    if range.magnitude() >= left.width {
        anyhow::bail!(
            "the search range {range} reaches {} px, but the images are {} px wide",
            range.magnitude(),
            left.width
        );
    }
    let network = args.method.network(args.model.as_deref())?;
    let cost = args.method.cost(network.as_ref())?;
    let mut settings = if args.raw {
        MatchSettings::raw(range)
    } else if args.published {
        MatchSettings::published_for_cost(&cost, range)
    } else {
        MatchSettings::for_cost(&cost, range)
    };
    if args.no_aggregation {
        settings.aggregation_before_sgm = None;
        settings.aggregation_after_sgm = None;
    }
    if args.no_sgm {
        settings.sgm = None;
    }
    if let Some(sgm) = &mut settings.sgm {
        sgm.paths = if args.sgm_paths >= 8 { 8 } else { 4 };
    }
    if !args.raw {
        settings.left_right = args.left_right;
    }
    settings.subpixel &= !args.no_subpixel;
    settings.median &= !args.no_median;
    if args.no_bilateral {
        settings.bilateral = None;
    }
    settings.contrast = args.contrast;
    // After the cheaper checks of sizes, range and model, so that they speak first.
    for (option, path, image) in [
        ("--left", &args.left, &left),
        ("--right", &args.right, &right),
    ] {
        let what = format!("{option} {}", path.display());
        check_signal(image, f32::INFINITY, &what)?;
    }
    let bar = spinner(format!(
        "matching {}×{} with {} over disparities {range}",
        left.width,
        left.height,
        cost.name()
    ));
    let out = match_pair(&left, &right, &cost, &settings)?;
    bar.finish_and_clear();
    write_pfm(&args.out, &out.disparity.to_pfm())?;
    let map = &out.disparity;
    if let Some(path) = &args.preview {
        let span = [range.min as f32, (range.max - 1) as f32];
        write_disparity_preview(path, &map.data, map.width, map.height, span)?;
    }
    let valid = map.data.iter().filter(|d| d.is_finite()).count();
    let total: f64 = out.timings.iter().map(|t| t.1).sum();
    let megapixels = (map.width * map.height) as f64 / 1e6;
    eprintln!(
        "{}: {}×{}, {} disparities ({range}), {} ({:.1} % valid) in {}",
        cost.name(),
        map.width,
        map.height,
        range.count(),
        args.out.display(),
        100.0 * valid as f64 / map.data.len().max(1) as f64,
        format_seconds(total)
    );
    if let Some(vote) = &out.contrast {
        eprintln!(
            "  contrast {} ({:.0} % of {} windows' correlation weight negative)",
            if vote.inverted {
                "inverted: the right image was negated"
            } else {
                "the same"
            },
            100.0 * vote.inverted_share,
            vote.windows
        );
    }
    for (stage, seconds) in &out.timings {
        eprintln!(
            "  {stage:<24} {:>10}  ({:.3} s per Mpx per 100 disparities)",
            format_seconds(*seconds),
            seconds / megapixels / (range.count() as f64 / 100.0)
        );
    }
    if let Some(path) = &args.report {
        let report = serde_json::json!({
            "left": args.left,
            "right": args.right,
            "method": cost.name(),
            "disp_range": range,
            "width": map.width,
            "height": map.height,
            "valid_fraction": valid as f64 / map.data.len().max(1) as f64,
            "contrast": out.contrast,
            "settings": format!("{settings:?}"),
            "timings_s": out.timings.iter().map(|(k, v)| serde_json::json!({"stage": k, "seconds": v})).collect::<Vec<_>>(),
            "total_s": total,
            "wall_s": started.elapsed().as_secs_f64(),
        });
        let text = serde_json::to_string_pretty(&report)?;
        write_atomically(path, |w| w.write_all(text.as_bytes()))?;
    }
    Ok(())
}

//! `anaglyph match`: the disparity of one rectified pair through the full stereo chain,
//! written as PFM (+inf where invalid), with an optional colour-mapped preview and a JSON
//! report of the settings and per-stage timings.

use super::{check_output_file, format_seconds};
use crate::cli::{ChannelChoice, ContrastChoice, LeftRightChoice, MatchArgs, MatchMethod};
use crate::progress::spinner;
use anaglyph_core::io::{read_linear_image, write_atomically, write_disparity_preview, write_pfm};
use anaglyph_core::stereo::{
    match_pair, Contrast, DisparityRange, GreyImage, LeftRight, MatchSettings, MatchingCost,
    MatchingNetwork,
};
use std::path::Path;
use std::time::Instant;

/// Reads one image as the grey plane to match.
fn load_grey(path: &Path, channel: ChannelChoice) -> anyhow::Result<GreyImage> {
    let image = read_linear_image(path)?;
    let c = image.channels;
    let data: Vec<f32> = image
        .data
        .chunks_exact(c)
        .map(|p| match (c, channel) {
            (1, _) => p[0],
            (_, ChannelChoice::Luminance) => 0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2],
            (_, ChannelChoice::R) => p[0],
            (_, ChannelChoice::G) => p[1],
            (_, ChannelChoice::B) => p[2],
        })
        .collect();
    if c == 1 && channel != ChannelChoice::Luminance {
        anyhow::bail!(
            "{}: --channel {channel:?} needs an RGB image, this one is grey",
            path.display()
        );
    }
    Ok(GreyImage {
        channels: 1,
        width: image.width,
        height: image.height,
        data,
    })
}

/// The network a matching method needs (None for the classical costs).
pub fn load_network(
    method: MatchMethod,
    model: Option<&Path>,
) -> anyhow::Result<Option<MatchingNetwork>> {
    let network = match (method, model) {
        (MatchMethod::Mccnn | MatchMethod::MccnnAccurate, Some(path)) => {
            Some(MatchingNetwork::load(path)?)
        }
        (MatchMethod::Mccnn, None) => Some(MatchingNetwork::default_fast()?),
        (MatchMethod::MccnnAccurate, None) => anyhow::bail!(
            "--method mccnn-accurate needs --model PATH (train one with `anaglyph train --arch accurate`)"
        ),
        (_, Some(_)) => anyhow::bail!("--model only applies to --method mccnn or mccnn-accurate"),
        _ => None,
    };
    if let Some(n) = &network {
        if (method == MatchMethod::MccnnAccurate) != n.is_accurate() {
            anyhow::bail!(
                "--method {method:?} but the model is the {} network",
                if n.is_accurate() { "accurate" } else { "fast" }
            );
        }
    }
    Ok(network)
}

/// The matching cost of a method, borrowing its network.
pub fn matching_cost(
    method: MatchMethod,
    network: Option<&MatchingNetwork>,
) -> anyhow::Result<MatchingCost<'_>> {
    Ok(match (method, network) {
        (MatchMethod::Census, _) => MatchingCost::Census,
        (MatchMethod::Zncc, _) => MatchingCost::Zncc,
        (MatchMethod::Mi, _) => MatchingCost::MutualInformation { iterations: 3 },
        (_, Some(n)) => MatchingCost::Learned(n),
        (_, None) => anyhow::bail!("--method {method:?} needs a network"),
    })
}

pub fn run(args: MatchArgs) -> anyhow::Result<()> {
    let started = Instant::now();
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
    check_output_file(&args.out, "--out")?;
    let side_outputs = [("--preview", &args.preview), ("--report", &args.report)];
    for (option, path) in side_outputs {
        if let Some(path) = path {
            check_output_file(path, option)?;
        }
    }
    let network = load_network(args.method, args.model.as_deref())?;
    let cost = matching_cost(args.method, network.as_ref())?;
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
        settings.left_right = match args.left_right {
            LeftRightChoice::Off => LeftRight::Off,
            LeftRightChoice::Check => LeftRight::Check,
            LeftRightChoice::Fill => LeftRight::CheckAndFill,
        };
    }
    settings.subpixel &= !args.no_subpixel;
    settings.median &= !args.no_median;
    if args.no_bilateral {
        settings.bilateral = None;
    }
    settings.contrast = match args.contrast {
        ContrastChoice::Auto => Contrast::Auto,
        ContrastChoice::Same => Contrast::Same,
        ContrastChoice::Inverted => Contrast::Inverted,
        ContrastChoice::Either => Contrast::Either,
    };
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

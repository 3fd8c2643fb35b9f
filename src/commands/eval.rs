//! `anaglyph eval`: a reconstruction folder against a simulator output folder, in the
//! layout of the paper's Table 1 (PSNR and SSIM per band and averaged, per view), plus the
//! spectral angle, over all pixels and over the pixels every camera sees.

use super::check_output_file;
use crate::cli::EvalArgs;
use anaglyph_core::disparity::{DisparityConvention, DisparityMap};
use anaglyph_core::evaluation::{score_cube, seen_by_all_views, BandScores};
use anaglyph_core::io::{
    read_envi, read_pfm, verify_output_folder, verify_output_subfolder, write_atomically,
};
use anaglyph_core::register::ArrayGeometry;
use anaglyph_core::rig::Rig;
use anyhow::Context;
use serde::Serialize;
use std::path::Path;

/// Bands per printed line of the per-band table.
const BANDS_PER_LINE: usize = 8;

#[derive(Serialize)]
struct ViewScores {
    name: String,
    all_pixels: BandScores,
    seen_by_all: BandScores,
    /// Fraction of pixels with a reconstruction.
    coverage: f64,
}

#[derive(Serialize)]
pub struct EvalReport {
    bands_nm: Vec<f64>,
    views: Vec<ViewScores>,
    mean_psnr: f64,
    mean_ssim: f64,
}

fn print_bands(label: &str, centres: &[f64], values: &[f64], digits: usize) {
    for (chunk, (c, v)) in centres
        .chunks(BANDS_PER_LINE)
        .zip(values.chunks(BANDS_PER_LINE))
        .enumerate()
    {
        let head: Vec<String> = c
            .iter()
            .map(|l| format!("{:>8}", format!("{l}nm")))
            .collect();
        let vals: Vec<String> = v.iter().map(|x| format!("{x:>8.digits$}")).collect();
        let name = if chunk == 0 { label } else { "" };
        println!("  {name:<6}{}\n  {:<6}{}", head.join(""), "", vals.join(""));
    }
}

/// Refuses a reconstruction of another array than the simulation's: the cameras and
/// filters its manifest records must be the truth rig's.
fn check_same_array(rig: &Rig, truth: &Path, recon: &Path) -> anyhow::Result<()> {
    let path = recon.join(anaglyph_core::io::MANIFEST);
    let text = std::fs::read_to_string(&path).with_context(|| path.display().to_string())?;
    let manifest: serde_json::Value =
        serde_json::from_str(&text).with_context(|| path.display().to_string())?;
    let Some(cameras) = manifest["parameters"]["cameras"].as_array() else {
        return Ok(()); // written before manifests recorded the array
    };
    let recorded: Vec<(String, String)> = cameras
        .iter()
        .map(|c| {
            let field = |k: &str| c[k].as_str().unwrap_or_default().to_string();
            (field("name"), field("filter"))
        })
        .collect();
    let simulated: Vec<(String, String)> = rig
        .cameras
        .iter()
        .map(|c| {
            let filter = c.filter.as_ref().map_or("none", |f| f.name());
            (c.name.clone(), filter.to_string())
        })
        .collect();
    if recorded != simulated {
        let list = |l: &[(String, String)]| {
            l.iter()
                .map(|(n, f)| format!("{n} {f}"))
                .collect::<Vec<_>>()
                .join(", ")
        };
        anyhow::bail!(
            "--recon {}: a reconstruction of cameras {} (expected the array --truth {} \
             simulated: {})",
            recon.display(),
            list(&recorded),
            truth.display(),
            list(&simulated)
        );
    }
    Ok(())
}

/// Scores every view found in `recon/views` against `truth`.
pub fn evaluate(truth: &Path, recon: &Path) -> anyhow::Result<EvalReport> {
    let whole = |dir: &Path| format!("{}: not one run's complete output", dir.display());
    verify_output_subfolder(truth, "truth").with_context(|| whole(truth))?;
    verify_output_folder(recon).with_context(|| whole(recon))?;
    let rig = Rig::load(&truth.join("rig.toml"))?;
    check_same_array(&rig, truth, recon)?;
    let geometry = ArrayGeometry::of_rig(&rig);
    let maps: Vec<_> = rig
        .cameras
        .iter()
        .map(|c| {
            let pfm = read_pfm(&truth.join(format!("truth/{}_disparity.pfm", c.name)))?;
            DisparityMap::from_pfm(pfm, DisparityConvention::ColumnStep)
        })
        .collect::<Result<_, _>>()?;
    let mut views = Vec::new();
    let mut bands_nm = Vec::new();
    for (v, cam) in rig.cameras.iter().enumerate() {
        let name = &cam.name;
        let path = recon.join(format!("views/{name}.hdr"));
        if !path.is_file() {
            continue;
        }
        let estimate = read_envi(&path)?;
        let expected = read_envi(&truth.join(format!("truth/{name}.hdr")))?;
        let shape =
            |e: &anaglyph_core::io::EnviCube| (e.image.width, e.image.height, e.image.channels);
        if shape(&estimate) != shape(&expected) {
            anyhow::bail!(
                "{}: {:?} (width, height, bands) but the truth is {:?}",
                path.display(),
                shape(&estimate),
                shape(&expected)
            );
        }
        if let (Some(a), Some(b)) = (&estimate.wavelengths, &expected.wavelengths) {
            if a.iter().zip(b).any(|(x, y)| (x - y).abs() > 1e-6) {
                anyhow::bail!(
                    "{}: band wavelengths differ from the truth's",
                    path.display()
                );
            }
        }
        let (w, h, nb) = shape(&expected);
        if let Some(m) = maps.iter().find(|m| (m.width, m.height) != (w, h)) {
            anyhow::bail!(
                "truth disparity maps are {}x{}, the views {w}x{h}",
                m.width,
                m.height
            );
        }
        let mask = seen_by_all_views(&maps, &geometry, v);
        let pixel_ok = estimate
            .image
            .data
            .chunks_exact(nb)
            .filter(|p| p.iter().all(|x| x.is_finite()))
            .count();
        views.push(ViewScores {
            name: name.clone(),
            all_pixels: score_cube(&expected.image.data, &estimate.image.data, w, h, nb, None)?,
            seen_by_all: score_cube(
                &expected.image.data,
                &estimate.image.data,
                w,
                h,
                nb,
                Some(&mask),
            )?,
            coverage: pixel_ok as f64 / (w * h).max(1) as f64,
        });
        bands_nm = expected
            .wavelengths
            .clone()
            .unwrap_or_else(|| (0..nb).map(|b| b as f64).collect());
    }
    if views.is_empty() {
        anyhow::bail!(
            "{}: no views/r<row>c<col>.hdr of this rig's cameras",
            recon.display()
        );
    }
    let n = views.len() as f64;
    Ok(EvalReport {
        mean_psnr: views.iter().map(|v| v.all_pixels.psnr).sum::<f64>() / n,
        mean_ssim: views.iter().map(|v| v.all_pixels.ssim).sum::<f64>() / n,
        bands_nm,
        views,
    })
}

pub fn run(args: EvalArgs) -> anyhow::Result<()> {
    if let Some(path) = &args.json {
        check_output_file(path, "--json")?;
    }
    let report = evaluate(&args.truth, &args.recon)?;
    println!("Reflectance against the truth (PSNR in dB, peak 1; SSIM 11×11 Gaussian, as the paper's Table 1)");
    for v in &report.views {
        let a = &v.all_pixels;
        let s = &v.seen_by_all;
        println!(
            "\nview {}: PSNR {:.2} dB, SSIM {:.4}, spectral angle {:.2}°, coverage {:.1} %",
            v.name,
            a.psnr,
            a.ssim,
            a.spectral_angle_deg,
            100.0 * v.coverage
        );
        println!(
            "  pixels seen by every camera ({:.1} %): PSNR {:.2} dB, SSIM {:.4}, spectral angle {:.2}°",
            100.0 * s.pixels as f64 / a.pixels.max(1) as f64,
            s.psnr,
            s.ssim,
            s.spectral_angle_deg
        );
        print_bands("PSNR", &report.bands_nm, &a.band_psnr, 2);
        print_bands("SSIM", &report.bands_nm, &a.band_ssim, 4);
    }
    println!(
        "\nmean over {} view(s): PSNR {:.2} dB, SSIM {:.4}",
        report.views.len(),
        report.mean_psnr,
        report.mean_ssim
    );
    if let Some(path) = &args.json {
        let text = serde_json::to_string_pretty(&report)?;
        write_atomically(path, |w| w.write_all(text.as_bytes()))?;
        println!("wrote {}", path.display());
    }
    Ok(())
}

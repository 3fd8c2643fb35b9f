//! `anaglyph demo`: the spectral core end to end on built-in data. It selects the paper
//! rig's filters, builds C, renders measured and mixed reflectances through the rig on the
//! 1 nm grid with sensor noise, demultiplexes them, and prints the paper's Table 1 layout,
//! the effect of modelling out-of-band light, and the solver comparison of Fig. 6; then
//! renders the tabletop through the rig, reconstructs the reference view with the true
//! disparities, and matches the neighbouring cameras with the learned and classical costs.

use super::demo_light_field::{run_presets, PresetResult};
use super::demo_report::{write_report, ReportInputs};
use super::format_seconds;
use super::select_filters::{load_candidates, print_report, run_selection, SelectionInputs};
use crate::cli::DemoArgs;
use anaglyph_core::builtin;
use anaglyph_core::capture::CameraNoise;
use anaglyph_core::demux::{demultiplex, DemuxOptions, NormalEquations, Solver};
use anaglyph_core::evaluation::{recover_reflectances, TrialResult, TrialSettings};
use anaglyph_core::filters::{SelectionCriterion, SelectionOptions};
use anaglyph_core::io::write_atomically;
use anaglyph_core::reconstruct::{plot_probe, plot_series, Probe};
use anaglyph_core::rig::{EffectiveResponses, OutOfBand, Rig, SensingMatrix};
use anaglyph_core::simulate::Simulation;
use anaglyph_core::spectrum::ResponseCurve;
use anaglyph_core::stereo::{match_pair, GreyImage, MatchSettings, MatchingCost, MatchingNetwork};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use std::time::Instant;

/// Measured reflectance sets pushed through the rig.
const MEASURED_SETS: [&str; 3] = [
    "colorchecker_n_ohta",
    "tcs_cfi2017_99",
    "rawtoaces_190_patches",
];

#[derive(Serialize)]
struct DemoReport {
    filters: Vec<String>,
    condition_number: f64,
    max_out_of_band_fraction: f64,
    all: TrialResult,
    colorchecker: TrialResult,
    out_of_band: Vec<(String, f64, f64)>,
    solvers: Vec<SolverTiming>,
    noise_criterion_filters: Vec<String>,
    noise_criterion_psnr: f64,
    simulated_reference_psnr: f64,
    simulated_reference_ssim: f64,
    stereo_bad2: Vec<(String, f64)>,
    light_fields: Vec<PresetResult>,
    noise_in_c: Vec<(f64, f64)>,
}

#[derive(Serialize)]
struct SolverTiming {
    solver: String,
    seconds: f64,
    mean_objective: f64,
    max_difference_to_exact: f64,
}

/// bad-2 (%) and seconds per pair of each matching cost over the rig's horizontal
/// neighbours (left view = lower column), luminance of the captures, 32 disparities.
fn stereo_on_neighbours(
    simulation: &Simulation,
    max_disp: usize,
) -> anyhow::Result<Vec<(&'static str, f64, f64)>> {
    let network = MatchingNetwork::default_fast()?;
    let costs = [
        MatchingCost::Learned(&network),
        MatchingCost::Zncc,
        MatchingCost::Census,
    ];
    let views = &simulation.views;
    let (w, h) = (simulation.settings.width, simulation.settings.height);
    let grey = |capture: &[f32], channels: usize| GreyImage {
        width: w,
        height: h,
        data: capture
            .chunks_exact(channels)
            .map(|p| match p {
                [r, g, b] => 0.2126 * r + 0.7152 * g + 0.0722 * b,
                _ => p[0],
            })
            .collect(),
    };
    let mut results = Vec::new();
    for cost in &costs {
        let (mut bad, mut total, mut seconds, mut pairs) = (0usize, 0usize, 0.0, 0);
        for left in views {
            let Some(right) = views
                .iter()
                .find(|v| v.row == left.row && v.col == left.col + 1)
            else {
                continue;
            };
            let start = Instant::now();
            let out = match_pair(
                &grey(&left.capture, left.channels),
                &grey(&right.capture, right.channels),
                cost,
                &MatchSettings::for_cost(cost, max_disp),
            )?;
            seconds += start.elapsed().as_secs_f64();
            pairs += 1;
            for (i, (&e, &t)) in out.disparity.iter().zip(&left.disparity).enumerate() {
                let (x, y) = (i % w, i / w);
                let xr = (x as f32 - t).round();
                // Pixels the right camera sees too (its own disparity agrees).
                if !t.is_finite() || xr < 0.0 || t >= max_disp as f32 - 1.0 {
                    continue;
                }
                if (right.disparity[y * w + xr as usize] - t).abs() >= 1.0 {
                    continue;
                }
                total += 1;
                bad += usize::from(!e.is_finite() || (e - t).abs() > 2.0);
            }
        }
        results.push((
            cost.name(),
            100.0 * bad as f64 / total.max(1) as f64,
            seconds / pairs.max(1) as f64,
        ));
    }
    Ok(results)
}

/// The measured sets plus `count` convex mixtures of two or three of their spectra (areal
/// mixing of real surfaces), all on the sets' common 380–780 nm / 5 nm grid.
fn reflectance_library(count: usize, seed: u64) -> anyhow::Result<ResponseCurve> {
    let sets: Vec<ResponseCurve> = MEASURED_SETS
        .iter()
        .map(|n| builtin::reflectances(n))
        .collect::<Result<_, _>>()?;
    let wavelengths = sets[0].wavelengths().to_vec();
    let mut columns: Vec<Vec<f64>> = Vec::new();
    let mut names: Vec<String> = Vec::new();
    for set in &sets {
        anyhow::ensure!(
            set.wavelengths() == wavelengths.as_slice(),
            "{} is not on the common grid",
            set.name()
        );
        for c in 0..set.channel_count() {
            columns.push(set.channel(c).to_vec());
            names.push(format!("{}:{}", set.name(), set.channel_names()[c]));
        }
    }
    let measured = columns.len();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    for i in 0..count {
        let parts = rng.random_range(2..=3);
        let picks: Vec<usize> = (0..parts).map(|_| rng.random_range(0..measured)).collect();
        let weights: Vec<f64> = (0..parts)
            .map(|_| -(1.0 - rng.random::<f64>()).ln())
            .collect();
        let total: f64 = weights.iter().sum();
        let mixed = (0..wavelengths.len())
            .map(|w| {
                picks
                    .iter()
                    .zip(&weights)
                    .map(|(&p, &k)| columns[p][w] * k / total)
                    .sum()
            })
            .collect();
        columns.push(mixed);
        names.push(format!("mixture {i}"));
    }
    Ok(ResponseCurve::new(
        "reflectances",
        wavelengths,
        names,
        columns,
    )?)
}

fn print_table(title: &str, result: &TrialResult, centres: &[f64]) {
    println!(
        "{title}: {} spectra, PSNR {:.2} dB, RMSE {:.4}, spectral angle {:.2}°, max |error| {:.3}",
        result.samples, result.psnr, result.rmse, result.spectral_angle_deg, result.max_abs_error
    );
    for row in 0..3 {
        let band = |i: usize| row * 8 + i;
        let header: Vec<String> = (0..8)
            .map(|i| format!("{:>7}", format!("{}nm", centres[band(i)])))
            .collect();
        let values: Vec<String> = (0..8)
            .map(|i| format!("{:>7.2}", result.band_psnr[band(i)]))
            .collect();
        println!("  {}\n  {}", header.join(""), values.join(""));
    }
}

pub fn run(args: DemoArgs) -> anyhow::Result<()> {
    let total = Instant::now();
    println!("anaglyph demo: the spectral core end to end (paper sections 2.3, 3.2, 4.1c-d)\n");

    println!(
        "1. Filter selection: 8 of the {} modelled gels for a Canon EOS 5D Mark II under CIE A",
        builtin::filter_names().len()
    );
    let inputs = SelectionInputs {
        candidates: load_candidates(None)?,
        sensor: builtin::sensor("canon_eos_5d_mark_ii")?,
        illuminant: Some(builtin::illuminant("cie_a")?),
    };
    let options = SelectionOptions {
        count: 8,
        criterion: SelectionCriterion::Condition,
        noise: CameraNoise::default(),
        lambda: 0.01,
        keep: 3,
        exhaustive_limit: anaglyph_core::filters::EXHAUSTIVE_LIMIT,
    };
    let (selection, seconds) = run_selection(&inputs, &options, OutOfBand::Extend)?;
    print_report(&selection, seconds);
    let filters: Vec<&str> = selection.best[0]
        .filters
        .iter()
        .map(|&f| selection.candidates[f].as_str())
        .collect();
    let rig = Rig::from_file(Rig::paper_rig_file(&filters), ".".into())?;
    let shape = rig.reconstruction_shape()?;

    let responses = EffectiveResponses::of_rig(&rig)?;
    let c = SensingMatrix::from_responses(&responses, shape, OutOfBand::Extend)?;
    let cond = c.condition_number()?;
    let outside = SensingMatrix::in_band_fraction(&responses, &shape)
        .iter()
        .map(|f| 1.0 - f)
        .fold(0.0, f64::max);
    println!(
        "\n2. Sensing matrix: {} × {} ({} bands + {} out-of-band knots, {}–{} nm), cond(C) = {cond:.3e}",
        c.rows(),
        c.cols(),
        shape.count,
        c.cols() - shape.count,
        c.unknowns.start,
        c.unknowns.end()
    );
    println!(
        "   up to {:.1} % of a channel's signal lies outside {}–{} nm",
        100.0 * outside,
        shape.start - 4.0,
        shape.end() + 4.0
    );

    let library = reflectance_library(args.mixtures, args.seed)?;
    let chart = builtin::reflectances("colorchecker_n_ohta")?;
    let noise = CameraNoise::default();
    println!(
        "\n3. {} reflectances (24 ColorChecker, 99 CIE 2017 TCS, 190 rawtoaces patches, {} mixtures) rendered at 1 nm;\n   noise: {}-bit, {} e⁻ full well, {} e⁻ read noise, white at {:.0} % of full scale; λ = 0.01",
        library.channel_count(),
        args.mixtures,
        noise.bits,
        noise.full_well_electrons,
        noise.read_noise_electrons,
        100.0 * noise.exposure
    );
    let settings = TrialSettings {
        noise: Some(noise),
        seed: args.seed,
        options: DemuxOptions::default(),
    };
    let start = Instant::now();
    let all = recover_reflectances(&library, &responses, &c, &settings)?;
    println!(
        "   demultiplexed in {} ({} touch s >= 0)",
        format_seconds(start.elapsed().as_secs_f64()),
        all.report.bounded_pixels
    );
    let centres = shape.wavelengths();
    print_table("   all reflectances", &all, &centres);
    let colorchecker = recover_reflectances(&chart, &responses, &c, &settings)?;
    print_table("   ColorChecker", &colorchecker, &centres);

    println!("\n4. Out-of-band light (all reflectances; PSNR noise-free / noisy):");
    let mut out_of_band = Vec::new();
    for (mode, what) in [
        (
            OutOfBand::Extend,
            "extend: extra knots over the sensor support (default)",
        ),
        (OutOfBand::Clamp, "clamp: edge bands absorb the tails"),
        (
            OutOfBand::Ignore,
            "ignore: Eq. 2 literally, light outside 446–638 nm dropped",
        ),
    ] {
        let cm = SensingMatrix::from_responses(&responses, shape, mode)?;
        let clean = recover_reflectances(
            &library,
            &responses,
            &cm,
            &TrialSettings {
                noise: None,
                ..settings
            },
        )?;
        let noisy = recover_reflectances(&library, &responses, &cm, &settings)?;
        println!("   {:>6.2} dB / {:>6.2} dB  {what}", clean.psnr, noisy.psnr);
        out_of_band.push((format!("{mode:?}"), clean.psnr, noisy.psnr));
    }

    println!("\n5. Solvers on the 24 ColorChecker patches (paper Fig. 6):");
    let rows = c.rows();
    let n = c.cols();
    let chart_measurements = {
        let trial = recover_reflectances(
            &chart,
            &responses,
            &c,
            &TrialSettings {
                noise: None,
                ..settings
            },
        )?;
        drop(trial);
        let spectra = anaglyph_core::capture::spectra_on_grid(&chart, &responses)?;
        anaglyph_core::capture::measure_spectra(&spectra, &responses, &c)
    };
    let eq = NormalEquations::new(c.values(), n, (0..rows).collect(), 0.01)?;
    let mut exact_solution = Vec::new();
    let mut solvers = Vec::new();
    for (solver, name) in [
        (Solver::Exact, "exact (batched + pivoting)"),
        (Solver::ConjugateGradient, "conjugate gradient"),
        (Solver::Lsqr, "LSQR"),
        (Solver::ProjectedGradient, "gradient descent (accelerated)"),
    ] {
        let opts = DemuxOptions {
            solver,
            tolerance: 1e-10,
            ..DemuxOptions::default()
        };
        let t = Instant::now();
        let (s, report) = demultiplex(c.values(), rows, &chart_measurements, None, 0..n, &opts)?;
        let seconds = t.elapsed().as_secs_f64();
        let objective = (0..24)
            .map(|i| {
                eq.objective(
                    &s[i * n..(i + 1) * n],
                    &chart_measurements[i * rows..(i + 1) * rows],
                )
            })
            .sum::<f64>()
            / 24.0;
        if exact_solution.is_empty() {
            exact_solution = s.clone();
        }
        let diff = s
            .iter()
            .zip(&exact_solution)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        println!(
            "   {name:<32} {:>10}  mean objective {objective:.6e}  max |s − s_exact| {diff:.1e}  ({} iterations)",
            format_seconds(seconds),
            report.iterations
        );
        solvers.push(SolverTiming {
            solver: name.into(),
            seconds,
            mean_objective: objective,
            max_difference_to_exact: diff,
        });
    }

    println!("\n6. Choosing the filters by expected error under noise instead of cond(C):");
    let noise_options = SelectionOptions {
        criterion: SelectionCriterion::Noise,
        keep: 1,
        ..options
    };
    let (by_noise, seconds) = run_selection(&inputs, &noise_options, OutOfBand::Extend)?;
    let noise_filters: Vec<&str> = by_noise.best[0]
        .filters
        .iter()
        .map(|&f| by_noise.candidates[f].as_str())
        .collect();
    let noise_rig = Rig::from_file(Rig::paper_rig_file(&noise_filters), ".".into())?;
    let noise_responses = EffectiveResponses::of_rig(&noise_rig)?;
    let noise_c = SensingMatrix::from_responses(&noise_responses, shape, OutOfBand::Extend)?;
    let noise_trial = recover_reflectances(&library, &noise_responses, &noise_c, &settings)?;
    println!(
        "   searched in {}: {}\n   cond(C) = {:.3e} (vs {cond:.3e}), all reflectances {:.2} dB (vs {:.2} dB with the cond(C) choice)",
        format_seconds(seconds),
        noise_filters.join(" "),
        noise_c.condition_number()?,
        noise_trial.psnr,
        all.psnr
    );

    let (width, height) = args.size;
    println!(
        "\n7. Light fields: the {} preset scenes through this rig at {width}×{height}, every view reconstructed",
        anaglyph_core::scene::PRESETS.len()
    );
    println!("   from the captures (learned multi-view registration) and with the true disparities (the ceiling),");
    println!(
        "   pixels some camera misses estimated under the scene's own spectral prior, each view refined"
    );
    println!("   by a guided filter on its own capture");
    std::fs::create_dir_all(&args.out)?;
    let (presets, simulation) = run_presets(&args.out, &filters, args.size, args.seed)?;
    println!("   (agreement: the lowest over the views of the fraction of disparities a neighbouring view's map confirms)");
    println!("   scene       r0c0 PSNR / SSIM (estimated)   r0c0 PSNR / SSIM (true disparity)   8 views PSNR est. / true   bad-2   agreement   time");
    for p in &presets {
        println!(
            "   {:<10} {:>8.2} dB / {:.4}              {:>8.2} dB / {:.4}                {:>6.2} / {:>6.2} dB    {:>4.1} %     {:.3}     {}",
            p.name,
            p.estimated.reference.psnr,
            p.estimated.reference.ssim,
            p.true_disparity.reference.psnr,
            p.true_disparity.reference.ssim,
            p.estimated.mean_psnr,
            p.true_disparity.mean_psnr,
            p.reference_bad2,
            p.estimated.min_agreement,
            format_seconds(p.estimated.seconds)
        );
    }
    let sim_psnr = presets[0].true_disparity.reference.psnr;
    let sim_ssim = presets[0].true_disparity.reference.ssim;

    println!("\n8. Cross-spectral stereo on the same captures: the 6 horizontally neighbouring pairs, 32 disparities");
    println!("   (bad-2.0: % of pixels seen by both cameras off by more than 2 px; default chain of `anaglyph match`)");
    let stereo = stereo_on_neighbours(&simulation, (width / 10).max(8))?;
    for (name, bad2, seconds) in &stereo {
        println!(
            "   {name:<7} bad-2 {bad2:>5.1} %   ({} per pair)",
            format_seconds(*seconds)
        );
    }

    println!("\n9. Robustness to errors in C (paper Fig. 8a): Gaussian noise of σ × max(C) added to the C used");
    println!(
        "   for reconstruction (measurements from the true curves, noise-free; all reflectances)"
    );
    let noise_in_c = psnr_against_noise_in_c(&library, &responses, &c, args.seed)?;
    for (sigma, psnr) in &noise_in_c {
        println!("   σ = {sigma:<6} PSNR {psnr:>6.2} dB");
    }

    let chart_svgs = write_chart_spectra(&args.out, &colorchecker, &chart, &centres)?;
    let noise_svg = "noise_in_c.svg";
    plot_series(
        &args.out.join(noise_svg),
        "PSNR against noise in C (Fig. 8a)",
        ("σ / max C", "PSNR (dB)"),
        &[("all reflectances".to_string(), noise_in_c.clone())],
    )?;
    let solver_rows: Vec<(String, f64, f64, f64)> = solvers
        .iter()
        .map(|s| {
            (
                s.solver.clone(),
                s.seconds,
                s.mean_objective,
                s.max_difference_to_exact,
            )
        })
        .collect();
    let filter_names: Vec<String> = filters.iter().map(|s| s.to_string()).collect();
    write_report(
        &args.out,
        &ReportInputs {
            filters: &filter_names,
            condition_number: cond,
            size: args.size,
            bands_nm: &centres,
            colorchecker_band_psnr: &colorchecker.band_psnr,
            colorchecker_psnr: colorchecker.psnr,
            presets: &presets,
            solvers: &solver_rows,
            noise_in_c: &noise_in_c,
            chart_svgs: &chart_svgs,
            noise_svg,
            seconds: total.elapsed().as_secs_f64(),
        },
    )?;
    println!("\nreport: {}", args.out.join("report.html").display());

    println!(
        "\ndemo finished in {}",
        format_seconds(total.elapsed().as_secs_f64())
    );
    if let Some(path) = &args.json {
        let report = DemoReport {
            filters: filters.iter().map(|s| s.to_string()).collect(),
            condition_number: cond,
            max_out_of_band_fraction: outside,
            all,
            colorchecker,
            out_of_band,
            solvers,
            noise_criterion_filters: noise_filters.iter().map(|s| s.to_string()).collect(),
            noise_criterion_psnr: noise_trial.psnr,
            simulated_reference_psnr: sim_psnr,
            simulated_reference_ssim: sim_ssim,
            stereo_bad2: stereo.iter().map(|(n, b, _)| (n.to_string(), *b)).collect(),
            light_fields: presets.clone(),
            noise_in_c: noise_in_c.clone(),
        };
        let text = serde_json::to_string_pretty(&report)?;
        write_atomically(path, |w| w.write_all(text.as_bytes()))?;
        println!("wrote {}", path.display());
    }
    Ok(())
}

/// Relative σ values of the noise added to C (Fig. 8a).
const NOISE_IN_C: [f64; 7] = [0.0, 0.001, 0.002, 0.005, 0.01, 0.02, 0.05];

/// PSNR of `reflectances` reconstructed with C + N(0, (σ·max C)²) from noise-free
/// measurements through the true curves, for each σ of [`NOISE_IN_C`].
fn psnr_against_noise_in_c(
    reflectances: &ResponseCurve,
    responses: &EffectiveResponses,
    c: &SensingMatrix,
    seed: u64,
) -> anyhow::Result<Vec<(f64, f64)>> {
    let spectra = anaglyph_core::capture::spectra_on_grid(reflectances, responses)?;
    let clean = anaglyph_core::capture::measure_spectra(&spectra, responses, c);
    let rows = c.rows();
    let white_response: Vec<f64> = (0..rows).map(|r| c.row(r).iter().sum()).collect();
    let mut measured = clean;
    anaglyph_core::demux::normalise_by_white(&mut measured, rows, &white_response, &white_response);
    let bands = c.reported.count;
    let centres = c.reported.wavelengths();
    let mut truth = Vec::new();
    for k in 0..reflectances.channel_count() {
        truth.extend(reflectances.sample(
            k,
            &centres,
            anaglyph_core::spectrum::Interpolation::Linear,
        )?);
    }
    let peak = c.values().iter().cloned().fold(0.0, f64::max);
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0xC0FF_EE00);
    let mut out = Vec::new();
    for sigma in NOISE_IN_C {
        let noisy: Vec<f64> = c
            .values()
            .iter()
            .map(|&v| {
                let gauss: f64 =
                    rand_distr::Distribution::sample(&rand_distr::StandardNormal, &mut rng);
                v + sigma * peak * gauss
            })
            .collect();
        let (estimate, _) = demultiplex(
            &noisy,
            rows,
            &measured,
            None,
            c.reported_offset..c.reported_offset + bands,
            &DemuxOptions::default(),
        )?;
        out.push((sigma, anaglyph_core::metrics::psnr(&truth, &estimate, 1.0)));
    }
    Ok(out)
}

/// The ColorChecker trial's spectra as four charts of six patches; returns their names.
fn write_chart_spectra(
    dir: &std::path::Path,
    trial: &TrialResult,
    chart: &ResponseCurve,
    centres: &[f64],
) -> anyhow::Result<Vec<String>> {
    let bands = centres.len();
    let mut names = Vec::new();
    for group in 0..trial.samples.div_ceil(6) {
        let probes: Vec<Probe> = (group * 6..((group + 1) * 6).min(trial.samples))
            .map(|i| Probe {
                label: chart.channel_names()[i].clone(),
                estimate: trial.estimate[i * bands..(i + 1) * bands].to_vec(),
                truth: Some(trial.truth[i * bands..(i + 1) * bands].to_vec()),
            })
            .collect();
        let name = format!("colorchecker_{}.svg", group + 1);
        plot_probe(
            &dir.join(&name),
            &format!("ColorChecker patches {}–{}", group * 6 + 1, (group + 1) * 6),
            centres,
            &probes,
        )?;
        names.push(name);
    }
    Ok(names)
}

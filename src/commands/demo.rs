//! `anaglyph demo`: the spectral core end to end on built-in data. It selects the paper
//! rig's filters, builds C, renders measured and mixed reflectances through the rig on the
//! 1 nm grid with sensor noise, demultiplexes them, and prints the paper's Table 1 layout,
//! the effect of modelling out-of-band light, and the solver comparison of Fig. 6; then
//! renders the tabletop through the rig, reconstructs the reference view with the true
//! disparities, and matches the neighbouring cameras with the learned and classical costs.

use super::demo_light_field::{run_presets, PresetResult};
use super::demo_report::{write_report, ReportInputs};
use super::select_filters::{load_candidates, print_report, run_selection, SelectionInputs};
use super::{begin_output, check_output_file, format_seconds};
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
use anaglyph_core::spectrum::{ResponseCurve, SpectralShape};
use anaglyph_core::stereo::{
    match_pair, DisparityRange, GreyImage, MatchSettings, MatchingCost, MatchingNetwork,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use std::path::Path;
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
        channels: 1,
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
            let [x, y] = left.position_mm;
            let Some(right) = views
                .iter()
                .filter(|v| v.position_mm[1] == y && v.position_mm[0] > x)
                .min_by(|a, b| a.position_mm[0].total_cmp(&b.position_mm[0]))
            else {
                continue;
            };
            let start = Instant::now();
            let out = match_pair(
                &grey(&left.capture, left.channels),
                &grey(&right.capture, right.channels),
                cost,
                &MatchSettings::for_cost(cost, DisparityRange::up_to(max_disp)?),
            )?;
            seconds += start.elapsed().as_secs_f64();
            pairs += 1;
            for (i, (&e, &t)) in out.disparity.data.iter().zip(&left.disparity).enumerate() {
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
    if let Some(path) = &args.json {
        check_output_file(path, "--json")?;
    }
    let folder = begin_output(&args.out, args.force, &[] as &[&Path])?;
    let out = folder.path();
    println!("anaglyph demo: the spectral core end to end (paper sections 2.3, 3.2, 4.1c-d)\n");
    let selected = select_paper_rig()?;
    let names: Vec<&str> = selected.filters.iter().map(String::as_str).collect();
    let core = SpectralCore::of(&names, &args)?;
    let all = core.recover_all()?;
    let colorchecker = core.recover_chart()?;
    let out_of_band = core.compare_out_of_band()?;
    let solvers = core.compare_solvers()?;
    let (noise_filters, noise_psnr) = core.select_by_noise(&selected, all.psnr)?;
    let (presets, simulation) = light_fields(&args, out, &names)?;
    let (width, _) = args.size;
    let stereo = stereo_section(&simulation, (width / 10).max(8))?;
    let noise_in_c = noise_in_c_section(&core, args.seed)?;
    let filters = selected.filters.clone();
    let chart_svgs = write_chart_spectra(out, &colorchecker, &core.chart, &core.centres)?;
    let noise_svg = "noise_in_c.svg";
    plot_series(
        &out.join(noise_svg),
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
    write_report(
        out,
        &ReportInputs {
            filters: &filters,
            condition_number: core.cond,
            size: args.size,
            bands_nm: &core.centres,
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
    folder.write_manifest(&serde_json::json!({
        "generator": format!("anaglyph {}", env!("CARGO_PKG_VERSION")),
        "command": "demo",
        "size": args.size,
        "seed": args.seed,
        "filters": &filters,
        "seconds": total.elapsed().as_secs_f64(),
    }))?;
    let out = folder.commit()?;
    println!("\nreport: {}", out.join("report.html").display());
    println!(
        "\ndemo finished in {}",
        format_seconds(total.elapsed().as_secs_f64())
    );
    if let Some(path) = &args.json {
        let report = DemoReport {
            filters,
            condition_number: core.cond,
            max_out_of_band_fraction: core.outside,
            simulated_reference_psnr: presets[0].true_disparity.reference.psnr,
            simulated_reference_ssim: presets[0].true_disparity.reference.ssim,
            all,
            colorchecker,
            out_of_band,
            solvers,
            noise_criterion_filters: noise_filters,
            noise_criterion_psnr: noise_psnr,
            stereo_bad2: stereo.iter().map(|(n, b, _)| (n.to_string(), *b)).collect(),
            light_fields: presets,
            noise_in_c,
        };
        let text = serde_json::to_string_pretty(&report)?;
        write_atomically(path, |w| w.write_all(text.as_bytes()))?;
        println!("wrote {}", path.display());
    }
    Ok(())
}

/// The filters section 1 chose, with what chose them.
struct SelectedRig {
    filters: Vec<String>,
    inputs: SelectionInputs,
    options: SelectionOptions,
}

/// Section 1: Filter selection by cond(C), as the paper does.
fn select_paper_rig() -> anyhow::Result<SelectedRig> {
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
    let filters = selection.best[0]
        .filters
        .iter()
        .map(|&f| selection.candidates[f].clone())
        .collect();
    Ok(SelectedRig {
        filters,
        inputs,
        options,
    })
}

/// The selected rig's C and what sections 3 to 6 and 9 measure through it.
struct SpectralCore {
    shape: SpectralShape,
    responses: EffectiveResponses,
    c: SensingMatrix,
    cond: f64,
    /// The largest share of a channel's signal outside the reconstruction range.
    outside: f64,
    library: ResponseCurve,
    /// Random mixtures of the measured sets in `library`.
    mixtures: usize,
    chart: ResponseCurve,
    settings: TrialSettings,
    centres: Vec<f64>,
}

impl SpectralCore {
    /// Section 2: The sensing matrix of the selected rig.
    fn of(filters: &[&str], args: &DemoArgs) -> anyhow::Result<SpectralCore> {
        let rig = Rig::from_file(Rig::paper_rig_file(filters), ".".into())?;
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
        let noise = CameraNoise::default();
        Ok(SpectralCore {
            shape,
            centres: shape.wavelengths(),
            c,
            cond,
            outside,
            library: reflectance_library(args.mixtures, args.seed)?,
            mixtures: args.mixtures,
            chart: builtin::reflectances("colorchecker_n_ohta")?,
            settings: TrialSettings {
                noise: Some(noise),
                seed: args.seed,
                options: DemuxOptions::default(),
            },
            responses,
        })
    }

    /// Section 3: Every reflectance rendered at 1 nm with noise, demultiplexed.
    fn recover_all(&self) -> anyhow::Result<TrialResult> {
        let noise = CameraNoise::default();
        println!(
            "\n3. {} reflectances (24 ColorChecker, 99 CIE 2017 TCS, 190 rawtoaces patches, {} mixtures) rendered at 1 nm;\n   noise: {}-bit, {} e⁻ full well, {} e⁻ read noise, white at {:.0} % of full scale; λ = 0.01",
            self.library.channel_count(),
            self.mixtures,
            noise.bits,
            noise.full_well_electrons,
            noise.read_noise_electrons,
            100.0 * noise.exposure
        );
        let start = Instant::now();
        let all = recover_reflectances(&self.library, &self.responses, &self.c, &self.settings)?;
        println!(
            "   demultiplexed in {} ({} touch s >= 0)",
            format_seconds(start.elapsed().as_secs_f64()),
            all.report.bounded_pixels
        );
        print_table("   all reflectances", &all, &self.centres);
        Ok(all)
    }

    /// Section 3, continued: the ColorChecker alone.
    fn recover_chart(&self) -> anyhow::Result<TrialResult> {
        let chart = recover_reflectances(&self.chart, &self.responses, &self.c, &self.settings)?;
        print_table("   ColorChecker", &chart, &self.centres);
        Ok(chart)
    }

    /// Section 4: The three ways of treating out-of-band light, noise-free and noisy.
    fn compare_out_of_band(&self) -> anyhow::Result<Vec<(String, f64, f64)>> {
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
            let cm = SensingMatrix::from_responses(&self.responses, self.shape, mode)?;
            let noise_free = TrialSettings {
                noise: None,
                ..self.settings
            };
            let clean = recover_reflectances(&self.library, &self.responses, &cm, &noise_free)?;
            let noisy = recover_reflectances(&self.library, &self.responses, &cm, &self.settings)?;
            println!("   {:>6.2} dB / {:>6.2} dB  {what}", clean.psnr, noisy.psnr);
            out_of_band.push((format!("{mode:?}"), clean.psnr, noisy.psnr));
        }
        Ok(out_of_band)
    }

    /// Section 5: The four solvers on the ColorChecker's noise-free measurements (Fig. 6).
    fn compare_solvers(&self) -> anyhow::Result<Vec<SolverTiming>> {
        println!("\n5. Solvers on the 24 ColorChecker patches (paper Fig. 6):");
        let c = &self.c;
        let (rows, n) = (c.rows(), c.cols());
        let spectra = anaglyph_core::capture::spectra_on_grid(&self.chart, &self.responses)?;
        let measurements = anaglyph_core::capture::measure_spectra(&spectra, &self.responses, c);
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
            let (s, report) = demultiplex(c.values(), rows, &measurements, None, 0..n, &opts)?;
            let seconds = t.elapsed().as_secs_f64();
            let objective = (0..24)
                .map(|i| {
                    eq.objective(
                        &s[i * n..(i + 1) * n],
                        &measurements[i * rows..(i + 1) * rows],
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
        Ok(solvers)
    }

    /// Section 6: Filters chosen by the expected error under noise: their names and PSNR.
    fn select_by_noise(
        &self,
        selected: &SelectedRig,
        cond_psnr: f64,
    ) -> anyhow::Result<(Vec<String>, f64)> {
        println!("\n6. Choosing the filters by expected error under noise instead of cond(C):");
        let noise_options = SelectionOptions {
            criterion: SelectionCriterion::Noise,
            keep: 1,
            ..selected.options
        };
        let (by_noise, seconds) =
            run_selection(&selected.inputs, &noise_options, OutOfBand::Extend)?;
        let filters: Vec<String> = by_noise.best[0]
            .filters
            .iter()
            .map(|&f| by_noise.candidates[f].clone())
            .collect();
        let names: Vec<&str> = filters.iter().map(String::as_str).collect();
        let rig = Rig::from_file(Rig::paper_rig_file(&names), ".".into())?;
        let responses = EffectiveResponses::of_rig(&rig)?;
        let c = SensingMatrix::from_responses(&responses, self.shape, OutOfBand::Extend)?;
        let trial = recover_reflectances(&self.library, &responses, &c, &self.settings)?;
        println!(
            "   searched in {}: {}\n   cond(C) = {:.3e} (vs {:.3e}), all reflectances {:.2} dB (vs {:.2} dB with the cond(C) choice)",
            format_seconds(seconds),
            names.join(" "),
            c.condition_number()?,
            self.cond,
            trial.psnr,
            cond_psnr
        );
        Ok((filters, trial.psnr))
    }
}

/// Section 7: The preset scenes through the rig, reconstructed from the captures and from the
/// true disparities.
fn light_fields(
    args: &DemoArgs,
    out: &Path,
    filters: &[&str],
) -> anyhow::Result<(Vec<PresetResult>, Simulation)> {
    let (width, height) = args.size;
    println!(
        "\n7. Light fields: the {} preset scenes through this rig at {width}×{height}, every view reconstructed",
        anaglyph_core::scene::TEST_SCENES.len()
    );
    println!("   from the captures (learned multi-view registration) and with the true disparities (the ceiling),");
    println!(
        "   pixels some camera misses estimated under the scene's own spectral prior, each view refined"
    );
    println!("   by a guided filter on its own capture");
    let (presets, simulation) = run_presets(out, filters, args.size, args.seed)?;
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
    Ok((presets, simulation))
}

/// Section 8: Cross-spectral stereo on the rig's horizontal neighbours.
fn stereo_section(
    simulation: &Simulation,
    max_disp: usize,
) -> anyhow::Result<Vec<(&'static str, f64, f64)>> {
    println!("\n8. Cross-spectral stereo on the same captures: the 6 horizontally neighbouring pairs, 32 disparities");
    println!("   (bad-2.0: % of pixels seen by both cameras off by more than 2 px; default chain of `anaglyph match`)");
    let stereo = stereo_on_neighbours(simulation, max_disp)?;
    for (name, bad2, seconds) in &stereo {
        println!(
            "   {name:<7} bad-2 {bad2:>5.1} %   ({} per pair)",
            format_seconds(*seconds)
        );
    }
    Ok(stereo)
}

/// Section 9: Robustness to noise in C (Fig. 8a).
fn noise_in_c_section(core: &SpectralCore, seed: u64) -> anyhow::Result<Vec<(f64, f64)>> {
    println!("\n9. Robustness to errors in C (paper Fig. 8a): Gaussian noise of σ × max(C) added to the C used");
    println!(
        "   for reconstruction (measurements from the true curves, noise-free; all reflectances)"
    );
    let noise_in_c = psnr_against_noise_in_c(&core.library, &core.responses, &core.c, seed)?;
    for (sigma, psnr) in &noise_in_c {
        println!("   σ = {sigma:<6} PSNR {psnr:>6.2} dB");
    }
    Ok(noise_in_c)
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

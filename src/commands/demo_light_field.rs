//! The demo's light-field part: every preset scene rendered through the rig, every view
//! reconstructed from the captures (registration by the learned cost) and with the
//! simulator's true disparities (the registration ceiling), scored as the paper's Table 1,
//! and written in `reconstruct`'s layout for the report.

use anaglyph_core::evaluation::{bad_pixel_share, score_cube, seen_by_all_views, BandScores};
use anaglyph_core::io::write_disparity_preview;
use anaglyph_core::io::{OutputFolder, Replace};
use anaglyph_core::reconstruct::{
    reconstruct, write_light_field, ArrayCaptures, Disparities, DisparitySearch, LightField,
    OutputOptions, PipelineSettings, Products,
};
use anaglyph_core::register::{ArrayGeometry, RegistrationMode, DEFAULT_REGISTRATION};
use anaglyph_core::rig::Rig;
use anaglyph_core::scene::{Scene, SceneFile, TEST_SCENES};
use anaglyph_core::simulate::{write_simulation, Simulation, SimulationSettings};
use anaglyph_core::stereo::{DisparityRange, MatchingCost, MatchingNetwork};
use serde::Serialize;
use std::path::Path;
use std::time::Instant;

/// The rig's focal length at 640 px wide (the paper rig's 1800 px); other widths keep
/// the field of view.
const FOCAL_AT_640: f64 = 1800.0;
/// Margin of the search range over the scene's largest disparity (its nearest surface),
/// as a user sets `--max-disp` from the rig's working distance.
const SEARCH_MARGIN: f32 = 1.1;

/// Scores of one way of registering a preset.
#[derive(Debug, Clone, Serialize)]
pub struct RunScores {
    pub reference: BandScores,
    pub reference_seen_by_all: BandScores,
    pub mean_psnr: f64,
    pub mean_ssim: f64,
    /// The lowest `neighbour_agreement` over the views (how far the registration agrees
    /// with itself; `reconstruct` warns below 0.9).
    pub min_agreement: f64,
    /// The mean `neighbour_agreement` over the views. Steadier than the lowest: where a
    /// view's ambiguous region is caught by a plane or not, its agreement flips by 0.1 to
    /// 0.2 under float rounding alone.
    pub mean_agreement: f64,
    pub seconds: f64,
    pub timings: Vec<(String, f64)>,
}

/// One preset's results.
#[derive(Debug, Clone, Serialize)]
pub struct PresetResult {
    pub name: String,
    pub estimated: RunScores,
    pub true_disparity: RunScores,
    /// Share of r0c0's pixels whose estimated disparity is off by more than 2 px.
    pub reference_bad2: f64,
}

/// Disparities to search: the scene's largest true disparity with a margin (the nearest
/// depth of the working volume, which a rig's user knows).
pub fn search_range(simulation: &Simulation) -> usize {
    let largest = simulation
        .views
        .iter()
        .flat_map(|v| v.disparity.iter())
        .filter(|d| d.is_finite())
        .fold(0.0f32, |a, &b| a.max(b));
    ((largest * SEARCH_MARGIN).ceil() as usize + 2).max(8)
}

fn scores(
    field: &LightField,
    simulation: &Simulation,
    geometry: &ArrayGeometry,
    seconds: f64,
) -> anyhow::Result<RunScores> {
    let (w, h) = (simulation.settings.width, simulation.settings.height);
    let nb = field.bands.len();
    let maps = simulation.disparity_maps();
    let mut all = Vec::new();
    for (view, truth) in field.views.iter().zip(&simulation.views) {
        all.push(score_cube(
            &truth.truth,
            &view.cube()?.data,
            w,
            h,
            nb,
            None,
        )?);
    }
    let mask = seen_by_all_views(&maps, geometry, 0);
    let seen = score_cube(
        &simulation.views[0].truth,
        &field.views[0].cube()?.data,
        w,
        h,
        nb,
        Some(&mask),
    )?;
    Ok(RunScores {
        mean_psnr: mean(all.iter().map(|s| s.psnr)),
        mean_ssim: mean(all.iter().map(|s| s.ssim)),
        reference: all.swap_remove(0),
        reference_seen_by_all: seen,
        min_agreement: field
            .views
            .iter()
            .filter_map(|v| v.neighbour_agreement)
            .fold(f64::NAN, f64::min),
        mean_agreement: mean(field.views.iter().filter_map(|v| v.neighbour_agreement)),
        seconds,
        timings: field.timings.clone(),
    })
}

/// The mean of `values`, NaN where there are none.
fn mean(values: impl Iterator<Item = f64>) -> f64 {
    let (sum, n) = values.fold((0.0, 0usize), |(s, n), v| (s + v, n + 1));
    if n == 0 {
        f64::NAN
    } else {
        sum / n as f64
    }
}

/// Runs every preset at `size` through the rig with `filters`; writes each under
/// `out/{preset}/sim` and `out/{preset}/recon`. Returns the results and the tabletop's
/// simulation (for the stereo section).
pub fn run_presets(
    out: &Path,
    filters: &[&str],
    (width, height): (usize, usize),
    seed: u64,
) -> anyhow::Result<(Vec<PresetResult>, Simulation)> {
    let mut file = Rig::paper_rig_file(filters);
    file.focal_length_px = Some(FOCAL_AT_640 * width as f64 / 640.0);
    let rig = Rig::from_file(file, ".".into())?;
    let geometry = ArrayGeometry::of_rig(&rig);
    let network = MatchingNetwork::default_fast()?;
    let mut results = Vec::new();
    let mut tabletop = None;
    for name in TEST_SCENES {
        let scene_file = SceneFile::preset(name)?;
        let scene = Scene::resolve(scene_file.clone(), Path::new("."))?;
        let settings = SimulationSettings {
            width,
            height,
            seed,
            ..SimulationSettings::default()
        };
        let start = Instant::now();
        let simulation = Simulation::run(&rig, &scene, settings)?;
        let sim_folder = OutputFolder::begin(&out.join(name).join("sim"), Replace::OwnOutput, &[])?;
        write_simulation(
            &sim_folder,
            &rig,
            &scene_file,
            &simulation,
            start.elapsed().as_secs_f64(),
        )?;
        let sim_dir = sim_folder.commit()?;
        let captures = ArrayCaptures::from_simulation(&simulation);
        let max_disp = search_range(&simulation);
        let mut pipeline = PipelineSettings {
            disparities: Disparities::Search(DisparitySearch::Fixed(DisparityRange::up_to(
                max_disp,
            )?)),
            white_reflectance: simulation.settings.white_reflectance,
            ..PipelineSettings::new(MatchingCost::Learned(&network))
        };
        let start = Instant::now();
        let field = reconstruct(&rig, &captures, &pipeline, &|_, _, _| {})?;
        let seconds = start.elapsed().as_secs_f64();
        let probes = vec![
            (width / 4, height / 2),
            (width / 2, height / 2),
            (3 * width / 4, 2 * height / 3),
        ];
        let options = OutputOptions {
            products: Products::Cubes,
            probes,
            truth: Some(sim_dir.clone()),
            parameters: serde_json::json!({
                "scene": name,
                "registration": format!("{DEFAULT_REGISTRATION:?}"),
                "max_disp": max_disp,
            }),
            loading_seconds: 0.0,
        };
        let recon = OutputFolder::begin(&out.join(name).join("recon"), Replace::OwnOutput, &[])?;
        write_light_field(&recon, &rig, &field, &options)?;
        recon.commit()?;
        let truth_map = &simulation.views[0].disparity;
        // The scale of the reconstruction's own previews, so that colours compare.
        let max_true = field
            .views
            .iter()
            .flat_map(|v| v.disparity.data.iter())
            .filter(|d| d.is_finite())
            .fold(0.0f32, |a, &b| a.max(b));
        write_disparity_preview(
            &out.join(name).join("truth_disparity_r0c0.png"),
            truth_map,
            width,
            height,
            [0.0, max_true],
        )?;
        let bad_2 = bad_pixel_share(&field.views[0].disparity.data, truth_map, None, 2.0);
        let estimated = scores(&field, &simulation, &geometry, seconds)?;
        pipeline.disparities = Disparities::Given(simulation.disparity_maps());
        pipeline.registration = RegistrationMode::Pairwise;
        let start = Instant::now();
        let oracle = reconstruct(&rig, &captures, &pipeline, &|_, _, _| {})?;
        let true_disparity = scores(
            &oracle,
            &simulation,
            &geometry,
            start.elapsed().as_secs_f64(),
        )?;
        results.push(PresetResult {
            name: name.to_string(),
            estimated,
            true_disparity,
            reference_bad2: 100.0 * bad_2,
        });
        if name == "tabletop" {
            tabletop = Some(simulation);
        }
    }
    let tabletop = tabletop.ok_or_else(|| anyhow::anyhow!("no tabletop preset"))?;
    Ok((results, tabletop))
}

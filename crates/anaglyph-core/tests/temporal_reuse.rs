//! Temporal reuse over a moving scene's frames against each frame reconstructed alone:
//! the reused frames keep their quality, report what they reused, and a cut reuses
//! nothing (its values are those of the frame alone, bit for bit).

use anaglyph_core::evaluation::score_cube;
use anaglyph_core::reconstruct::{
    reconstruct, reconstruct_next, ArrayCaptures, FrameCarry, LightField, PipelineSettings,
};
use anaglyph_core::rig::{Rig, PAPER_RIG_FILTERS};
use anaglyph_core::scene::{Scene, SceneFile};
use anaglyph_core::simulate::{Simulation, SimulationSettings};
use anaglyph_core::stereo::{MatchingCost, MatchingNetwork};
use std::path::Path;

/// The paper's rig with its field of view at 160×120.
fn rig() -> Rig {
    let mut file = Rig::paper_rig_file(&PAPER_RIG_FILTERS);
    file.focal_length_px = Some(450.0);
    Rig::from_file(file, ".".into()).unwrap()
}

/// Frame `k` of `preset` at 160×120 (the noise of frame `k`, the same exposures).
fn frame(rig: &Rig, preset: &str, k: u64) -> Simulation {
    let file = SceneFile::preset(preset).unwrap().at_frame(k);
    let scene = Scene::resolve(file, Path::new(".")).unwrap();
    let settings = SimulationSettings {
        width: 160,
        height: 120,
        seed: 3,
        frame: k,
        ..SimulationSettings::default()
    };
    Simulation::run(rig, &scene, settings).unwrap()
}

/// r0c0's PSNR against the truth.
fn psnr(field: &LightField, simulation: &Simulation) -> f64 {
    let (w, h, nb) = (field.width, field.height, field.bands.len());
    let estimate = &field.views[0].cube().unwrap().data;
    score_cube(&simulation.views[0].truth, estimate, w, h, nb, None)
        .unwrap()
        .psnr
}

#[test]
fn reused_frames_keep_their_quality_and_say_what_they_reused() {
    let rig = rig();
    let network = MatchingNetwork::default_fast().unwrap();
    let settings = PipelineSettings::new(MatchingCost::Learned(&network));
    let mut carry: Option<FrameCarry> = None;
    for k in 0..3 {
        let simulation = frame(&rig, "tabletop-moving", k);
        let captures = ArrayCaptures::from_simulation(&simulation);
        let (field, next) =
            reconstruct_next(&rig, &captures, &settings, &|_, _, _| {}, carry.as_ref()).unwrap();
        let report = field.reuse.clone().unwrap();
        assert_eq!(report.previous, k > 0);
        assert!(!report.cut, "frame {k}: {report:?}");
        if k > 0 {
            // A moving object does not make a cut: the frames correlate closely.
            assert!(report.correlation.unwrap() > 0.9, "{report:?}");
            let narrowed = report.narrowed_range.expect("a narrowed range");
            assert!(
                field.search_range.is_none(),
                "the range is carried, not estimated again"
            );
            assert!(narrowed.count() > 4, "{narrowed:?}");
            // Registration searched each tile around the previous frame's maps.
            let banded = report.banded.expect("a banded search");
            assert!(banded.tiles >= 8, "{banded:?}");
            assert!(banded.mean_band <= narrowed.count() as f64, "{banded:?}");
            assert_eq!(report.priors_carried + report.priors_learned, 8);
            assert!(report.priors_carried >= 6, "{report:?}");
            // The wall and the chart stand still: their pixels keep their spectra (48 %).
            let share = report.reused_pixels as f64 / (8 * 160 * 120) as f64;
            assert!(share > 0.15, "{report:?}");
            let alone = reconstruct(&rig, &captures, &settings, &|_, _, _| {}).unwrap();
            let (reused, single) = (psnr(&field, &simulation), psnr(&alone, &simulation));
            // Measured with the 4000-step network: 33.98 / 33.88 dB (reused / alone) at
            // frame 1, 34.05 / 33.69 at frame 2, with 48 % of the pixels kept; the issue's
            // bar is 0.3 dB.
            assert!(
                reused > single - 0.3,
                "frame {k}: {reused:.2} against {single:.2} dB"
            );
            assert!(alone.reuse.is_none());
        } else {
            assert_eq!(report.priors_learned, 8);
        }
        carry = Some(next);
    }
}

#[test]
fn a_cut_reuses_nothing() {
    let rig = rig();
    let network = MatchingNetwork::default_fast().unwrap();
    let settings = PipelineSettings::new(MatchingCost::Learned(&network));
    let first = ArrayCaptures::from_simulation(&frame(&rig, "tabletop-moving", 0));
    let (_, carry) = reconstruct_next(&rig, &first, &settings, &|_, _, _| {}, None).unwrap();
    // Another scene through the same array: a cut.
    let other = ArrayCaptures::from_simulation(&frame(&rig, "clutter", 1));
    let (after_cut, _) =
        reconstruct_next(&rig, &other, &settings, &|_, _, _| {}, Some(&carry)).unwrap();
    let report = after_cut.reuse.clone().unwrap();
    assert!(report.previous && report.cut, "{report:?}");
    assert!(report.correlation.unwrap() < 0.5, "{report:?}");
    assert_eq!(report.narrowed_range, None);
    assert_eq!(report.banded, None);
    assert_eq!(report.priors_carried, 0);
    let alone = reconstruct(&rig, &other, &settings, &|_, _, _| {}).unwrap();
    assert!(
        after_cut.search_range.is_some(),
        "the range is estimated again"
    );
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    for (a, b) in after_cut.views.iter().zip(&alone.views) {
        assert!(
            bits(&a.cube().unwrap().data) == bits(&b.cube().unwrap().data),
            "view {}",
            a.name
        );
        assert!(
            bits(&a.disparity.data) == bits(&b.disparity.data),
            "view {}",
            a.name
        );
    }
}

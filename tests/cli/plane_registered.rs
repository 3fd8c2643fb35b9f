//! An array registered to a plane (the rig's `calibration_plane_mm`): points beyond the
//! plane have negative disparities. `match --disp-range` and `reconstruct`'s estimated
//! signed range find them; a range that cannot be searched is refused before any work.

use super::{anaglyph, assert_clean_failure, eval_psnr, stderr, stdout};
use anaglyph_core::io::read_pfm;
use anaglyph_core::rig::{Rig, PAPER_RIG_FILTERS};
use std::path::Path;

/// The tabletop through the paper's rig (its field of view: f = 720 px at 256 px wide)
/// registered to a plane at 1662 mm, 256×192 (true disparities about −5 to +5 px per
/// column step instead of 8 to 18), under `dir/sim`.
fn simulate_registered(dir: &Path) {
    let mut rig = Rig::paper_rig_file(&PAPER_RIG_FILTERS);
    rig.focal_length_px = 720.0;
    rig.calibration_plane_mm = Some(720.0 * 30.0 / 13.0);
    rig.save(&dir.join("plane.toml")).unwrap();
    let o = anaglyph(
        &[
            "simulate",
            "--scene",
            "tabletop",
            "--rig",
            "plane.toml",
            "--size",
            "256x192",
            "--out",
            "sim",
        ],
        dir,
    );
    assert!(o.status.success(), "{}", stderr(&o));
}

/// Share of pixels whose match lies inside the right image that `estimate` gets within
/// 2 px of `truth` (images `w` wide).
fn within_2px(estimate: &[f32], truth: &[f32], w: usize) -> f64 {
    let (mut good, mut total) = (0, 0);
    for (i, (e, t)) in estimate.iter().zip(truth).enumerate() {
        let xr = (i % w) as f32 - t;
        if t.is_finite() && xr >= 0.0 && xr <= (w - 1) as f32 {
            total += 1;
            good += usize::from((e - t).abs() <= 2.0);
        }
    }
    good as f64 / total as f64
}

#[test]
fn an_array_registered_to_a_plane_is_matched_and_reconstructed_over_signed_ranges() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    simulate_registered(d);
    let truth = read_pfm(&d.join("sim/truth/r0c0_disparity.pfm")).unwrap();
    assert!(truth.data.iter().any(|&t| t < -3.0) && truth.data.iter().any(|&t| t > 3.0));
    let matched = |range: &str| {
        let o = anaglyph(
            &[
                "match",
                "--left",
                "sim/captures/r0c0.png",
                "--right",
                "sim/captures/r0c1.png",
                "--disp-range",
                range,
                "--out",
                "d.pfm",
            ],
            d,
        );
        assert!(o.status.success(), "{}", stderr(&o));
        within_2px(&read_pfm(&d.join("d.pfm")).unwrap().data, &truth.data, 256)
    };
    let signed = matched("-16:16");
    let unsigned = matched("0:32");
    eprintln!("match: {signed:.3} within 2 px over -16:16, {unsigned:.3} over 0:32");
    // Measured: 0.957 and 0.832 (the points beyond the plane lost).
    assert!(
        signed > 0.9 && signed > unsigned + 0.08,
        "{signed} {unsigned}"
    );

    // The estimated range reaches below zero; the reconstruction scores near the one with
    // the true disparities.
    let o = anaglyph(
        &[
            "reconstruct",
            "--rig",
            "sim/rig.toml",
            "--out",
            "rec",
            "--views",
            "r0c0",
        ],
        d,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let line = stdout(&o);
    assert!(line.contains("search range -"), "{line}");
    let o = anaglyph(
        &[
            "reconstruct",
            "--rig",
            "sim/rig.toml",
            "--out",
            "oracle",
            "--views",
            "r0c0",
            "--true-disparity",
            "sim",
        ],
        d,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let (estimated, oracle) = (eval_psnr(d, "rec"), eval_psnr(d, "oracle"));
    eprintln!("reconstruct r0c0: {estimated:.2} dB estimated, {oracle:.2} dB true disparities");
    // Measured: 35.59 and 35.75 dB.
    assert!(estimated > oracle - 1.0, "{estimated} {oracle}");
}

#[test]
fn a_range_that_cannot_be_searched_is_refused_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    simulate_registered(d);
    for (range, needle) in [
        ("8:8", "MIN < MAX"),
        ("8:-8", "MIN < MAX"),
        ("-8", "MIN:MAX in whole pixels"),
    ] {
        let o = anaglyph(
            &[
                "reconstruct",
                "--rig",
                "sim/rig.toml",
                "--out",
                "rec",
                "--disp-range",
                range,
            ],
            d,
        );
        assert_clean_failure(&o, needle);
    }
    let o = anaglyph(
        &[
            "reconstruct",
            "--rig",
            "sim/rig.toml",
            "--out",
            "rec",
            "--disp-range",
            "-200:8",
        ],
        d,
    );
    assert_clean_failure(&o, "-200:8: 208 disparities");
    assert!(!d.join("rec").exists());
    let o = anaglyph(
        &[
            "match",
            "--left",
            "sim/captures/r0c0.png",
            "--right",
            "sim/captures/r0c1.png",
            "--disp-range",
            "-8:8",
            "--max-disp",
            "8",
            "--out",
            "d.pfm",
        ],
        d,
    );
    assert_clean_failure(&o, "cannot be used with");
    assert!(!d.join("d.pfm").exists());
}

//! A monochrome narrow-band array (one `gaussian:` filter per camera, N = M bands):
//! `reconstruct --output both` writes every view's registered stack beside its cube, and
//! the stack of the estimated disparities is close to the one of the true disparities.

use super::{anaglyph, assert_clean_failure, stderr};
use anaglyph_core::io::{read_envi, EnviCube};
use std::path::Path;

const CENTRES_NM: [u32; 6] = [460, 500, 540, 580, 620, 660];
const VIEWS: [&str; 6] = ["r0c0", "r0c1", "r0c2", "r1c0", "r1c1", "r1c2"];

/// A 2×3 array of monochrome cameras (`builtin:panchromatic`) behind 40 nm wide filters, rendered at 160×120 under `dir/sim`.
fn simulate_monochrome(dir: &Path) {
    let mut rig = String::from(
        "name = \"mono-2x3\"\nrows = 2\ncols = 3\nfocal_length_px = 450.0\n\
         sensor = \"builtin:panchromatic\"\nilluminant = \"builtin:cie_d65\"\n\
         [baseline_mm]\nhorizontal = 30.0\nvertical = 30.0\n\
         [reconstruction]\nstart_nm = 460.0\nstep_nm = 40.0\ncount = 6\n",
    );
    for (k, centre) in CENTRES_NM.iter().enumerate() {
        rig.push_str(&format!(
            "[[camera]]\nrow = {}\ncol = {}\nfilter = \"gaussian:{centre}:40\"\n",
            k / 3,
            k % 3
        ));
    }
    std::fs::write(dir.join("rig.toml"), rig).unwrap();
    let args = ["simulate", "--scene", "tabletop", "--rig", "rig.toml"];
    let o = anaglyph(
        &[&args[..], &["--size", "160x120", "--out", "sim"]].concat(),
        dir,
    );
    assert!(o.status.success(), "{}", stderr(&o));
}

/// PSNR (peak 1: white-normalised values) of `a` against `b` where both are finite.
fn psnr(a: &EnviCube, b: &EnviCube) -> f64 {
    let (sum, n) = a
        .image
        .data
        .iter()
        .zip(&b.image.data)
        .filter(|(x, y)| x.is_finite() && y.is_finite())
        .fold((0.0, 0usize), |(s, n), (x, y)| {
            (s + f64::from(x - y).powi(2), n + 1)
        });
    -10.0 * (sum / n as f64).log10()
}

#[test]
fn a_monochrome_narrow_band_array_gets_registered_stacks_close_to_the_true_ones() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    simulate_monochrome(d);
    let reconstruct = ["reconstruct", "--rig", "sim/rig.toml", "--output"];
    let o = anaglyph(&[&reconstruct[..], &["both", "--out", "rec"]].concat(), d);
    assert!(o.status.success(), "{}", stderr(&o));
    let oracle = ["registered", "--out", "oracle", "--true-disparity", "sim"];
    let o = anaglyph(&[&reconstruct[..], &oracle[..]].concat(), d);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(d.join("rec/views/r0c1.hdr").exists() && !d.join("oracle/views").exists());
    let mut scores = Vec::new();
    for (k, view) in VIEWS.iter().enumerate() {
        let stack = |run: &str| read_envi(&d.join(format!("{run}/registered/{view}.hdr"))).unwrap();
        let (estimated, truth) = (stack("rec"), stack("oracle"));
        assert_eq!(
            estimated.band_names.as_deref(),
            Some(&VIEWS.map(String::from)[..])
        );
        let centres = CENTRES_NM.map(f64::from).to_vec();
        assert_eq!(estimated.wavelengths, Some(centres));
        // A camera sees all of its own view, unwarped.
        let own = |c: &EnviCube| -> Vec<f32> {
            c.image.data.iter().skip(k).step_by(6).copied().collect()
        };
        assert!(own(&estimated).iter().all(|v| v.is_finite()));
        assert_eq!(own(&estimated), own(&truth));
        assert!(d.join(format!("rec/registered/{view}_seen.png")).exists());
        scores.push(psnr(&estimated, &truth));
    }
    let mean = scores.iter().sum::<f64>() / scores.len() as f64;
    let worst = scores.iter().copied().fold(f64::INFINITY, f64::min);
    eprintln!("registered stacks against true disparities: {scores:.2?} dB, mean {mean:.2}");
    // Measured: 25.73 32.43 31.94 30.09 24.04 27.32 dB (mean 28.59); the unregistered
    // captures stacked score 12.5 to 13.2 dB.
    assert!(mean > 25.5 && worst > 21.0, "{scores:?}");
    // Probes plot reflectance: refused without cubes, before any output.
    let o = anaglyph(
        &[
            &reconstruct[..],
            &["registered", "--out", "p", "--probe", "5,5"],
        ]
        .concat(),
        d,
    );
    assert_clean_failure(&o, "probe");
    assert!(!d.join("p").exists());
}

/// A registration-only run needs no radiometry: the rig without white boards, exposures
/// or filters registers as well as with them, keeps each capture as recorded (its own
/// channel of its own view is the capture), runs no spectral stage and says so in its
/// manifest; a cube from such a rig is refused, naming what registration alone does not
/// need.
#[test]
fn a_registration_only_run_needs_no_white_board_exposure_or_filter() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    simulate_monochrome(d);
    let text = std::fs::read_to_string(d.join("sim/rig.toml")).unwrap();
    let without = |keys: &[&str]| -> String {
        text.lines()
            .filter(|l| !keys.iter().any(|k| l.starts_with(&format!("{k} ="))))
            .map(|l| format!("{l}\n"))
            .collect()
    };
    let bare = without(&["white", "exposure", "filter"]);
    assert!(!bare.contains("white =") && !bare.contains("filter =") && bare.contains("image ="));
    std::fs::write(d.join("sim/bare.toml"), bare).unwrap();
    std::fs::write(d.join("sim/unlit.toml"), without(&["white", "exposure"])).unwrap();
    let run = |rig: &str, output: &str, out: &str| {
        let rig = format!("sim/{rig}.toml");
        anaglyph(
            &[
                "reconstruct",
                "--rig",
                &rig,
                "--output",
                output,
                "--out",
                out,
            ],
            d,
        )
    };
    let o = run("bare", "registered", "bare");
    assert!(o.status.success(), "{}", stderr(&o));
    let o = run("unlit", "registered", "unlit");
    assert!(o.status.success(), "{}", stderr(&o));
    let o = run("rig", "registered", "white");
    assert!(o.status.success(), "{}", stderr(&o));
    // A filter that lets none of its sensor's light through: a registration-only run says
    // so once and matches that camera as unfiltered; a run with cubes refuses it.
    let first_filter = text
        .lines()
        .find(|l| l.starts_with("filter ="))
        .expect("the rig has filters");
    let dark = text.replacen(first_filter, "filter = \"gaussian:1100:10\"", 1);
    std::fs::write(d.join("sim/dark.toml"), dark).unwrap();
    let o = run("dark", "registered", "dark");
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(
        stderr(&o)
            .matches("let none of the sensor's light through")
            .count(),
        1,
        "{}",
        stderr(&o)
    );
    let o = run("dark", "cube", "dark-cubes");
    assert_clean_failure(&o, "sees no light at all");
    let manifest = |run: &str| -> serde_json::Value {
        let text = std::fs::read_to_string(d.join(format!("{run}/manifest.json"))).unwrap();
        serde_json::from_str(&text).unwrap()
    };
    for run in ["bare", "unlit", "white"] {
        let m = manifest(run);
        assert_eq!(
            m["stages"],
            serde_json::json!(["calibration", "registration", "warping"]),
            "{run}"
        );
        assert_eq!(m["solve_stages"], serde_json::json!([]), "{run}");
        assert!(!d.join(format!("{run}/views")).exists());
    }
    for run in ["bare", "unlit"] {
        let methods: Vec<String> = manifest(run)["calibration"]
            .as_array()
            .unwrap()
            .iter()
            .map(|c| c["method"].as_str().unwrap().to_string())
            .collect();
        assert!(methods.iter().all(|m| m == "none"), "{run}: {methods:?}");
    }
    let map = |run: &str, view: &str| {
        anaglyph_core::io::read_pfm(&d.join(format!("{run}/disparity/{view}.pfm")))
            .unwrap()
            .data
    };
    // Share of `map` more than 1 px from `other` (a NaN or inf on one side counts).
    let apart = |a: &[f32], b: &[f32]| {
        let far = a
            .iter()
            .zip(b)
            .filter(|(x, y)| (*x - *y).abs() > 1.0 || (*x - *y).is_nan())
            .count();
        far as f64 / a.len() as f64
    };
    let mut bad = [0.0, 0.0];
    for (k, view) in VIEWS.iter().enumerate() {
        let stack = read_envi(&d.join(format!("bare/registered/{view}.hdr"))).unwrap();
        let own: Vec<f32> = stack
            .image
            .data
            .iter()
            .skip(k)
            .step_by(6)
            .copied()
            .collect();
        let capture =
            anaglyph_core::io::read_linear_image(&d.join(format!("sim/captures/{view}.png")))
                .unwrap();
        assert_eq!(own, capture.data, "{view}");
        // The radiometry does not move the maps: the same as the normalised run's but
        // for a handful of pixels.
        let unlit = map("unlit", view);
        assert!(apart(&unlit, &map("white", view)) < 0.01, "{view}");
        // Without filters the cameras are matched as unfiltered ones: other maps, no
        // worse against the truth.
        let truth = anaglyph_core::io::read_pfm(&d.join(format!("sim/truth/{view}_disparity.pfm")))
            .unwrap()
            .data;
        bad[0] += apart(&map("bare", view), &truth) / VIEWS.len() as f64;
        bad[1] += apart(&unlit, &truth) / VIEWS.len() as f64;
    }
    eprintln!(
        "bad-1 against the truth, mean of the views: {:.2} % without filters, {:.2} % with",
        100.0 * bad[0],
        100.0 * bad[1]
    );
    // Measured: 9.23 % without filters, 10.18 % with.
    assert!(bad[0] < bad[1] + 0.03, "{bad:?}");
    // Without filters the stack has no nominal wavelengths.
    let stack = read_envi(&d.join("bare/registered/r0c0.hdr")).unwrap();
    assert_eq!(stack.wavelengths, None);
    let o = run("bare", "cube", "cube");
    assert_clean_failure(
        &o,
        "camera r0c0: no filter in rig 'mono-2x3' (expected its `filter`",
    );
    let o = run("unlit", "cube", "cube");
    assert_clean_failure(
        &o,
        "a registration-only run (--output registered) needs neither",
    );
    assert!(!d.join("cube").exists());
}

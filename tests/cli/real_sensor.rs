//! A real sensor's values: captures and white boards that carry a black level or a
//! dark frame, reconstructed with the rig's `black_level` or `dark`, against the same
//! simulation without them.

use super::{anaglyph, eval_psnr, stderr};
use anaglyph_core::io::{read_linear_image, write_png16};
use anaglyph_core::rig::RigFile;
use std::path::Path;

/// `reconstruct` of view r0c0 of `rig` with the true disparities, scored by `eval`: PSNR.
fn psnr_of(dir: &Path, rig: &str, out: &str) -> f64 {
    let o = anaglyph(
        &[
            "reconstruct",
            "--rig",
            rig,
            "--out",
            out,
            "--views",
            "r0c0",
            "--true-disparity",
            "sim",
        ],
        dir,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    eval_psnr(dir, out)
}

/// The simulation's captures and white boards with `dark(x, y)` added, written under
/// `dir/name/`, and a rig `dir/name.toml` naming them, with `configure` applied to each
/// camera entry.
fn darkened(
    dir: &Path,
    name: &str,
    dark: impl Fn(usize, usize) -> f32,
    configure: impl Fn(&mut anaglyph_core::rig::CameraEntry),
) {
    for sub in ["captures", "white"] {
        std::fs::create_dir_all(dir.join(name).join(sub)).unwrap();
        for entry in std::fs::read_dir(dir.join("sim").join(sub)).unwrap() {
            let path = entry.unwrap().path();
            let mut image = read_linear_image(&path).unwrap();
            let (w, c) = (image.width, image.channels);
            for (i, v) in image.data.iter_mut().enumerate() {
                let pixel = i / c;
                *v = (*v + dark(pixel % w, pixel / w)).min(1.0);
            }
            let target = dir.join(name).join(sub).join(path.file_name().unwrap());
            write_png16(&target, &image).unwrap();
        }
    }
    let text = std::fs::read_to_string(dir.join("sim/rig.toml")).unwrap();
    let mut rig = RigFile::from_toml_str(&text, "sim rig").unwrap();
    for cam in &mut rig.cameras {
        let file = format!("r{}c{}.png", cam.row.unwrap(), cam.col.unwrap());
        cam.image = Some(format!("{name}/captures/{file}").into());
        cam.white = Some(format!("{name}/white/{file}").into());
        cam.calibration = None;
        configure(cam);
    }
    rig.save(&dir.join(format!("{name}.toml"))).unwrap();
}

#[test]
fn black_levels_and_dark_frames_are_subtracted_before_calibration() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let o = anaglyph(
        &[
            "simulate", "--scene", "tabletop", "--size", "128x96", "--out", "sim",
        ],
        d,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let clean = psnr_of(d, "sim/rig.toml", "rec-clean");

    // A 12-bit sensor's black level of 256, stored in 16 bits: 4096 of 65535.
    let level = 4096.0 / 65535.0;
    darkened(d, "offset", |_, _| level, |_| {});
    let ignored = psnr_of(d, "offset.toml", "rec-ignored");
    darkened(
        d,
        "black",
        |_, _| level,
        |cam| cam.black_level = Some(4096.0),
    );
    let subtracted = psnr_of(d, "black.toml", "rec-black");

    // The simulator's dark signal: a black level of 6 % of full scale with a fixed pattern
    // of 0.5 %, and each camera's master dark frame, which its rig names.
    let args = ["simulate", "--scene", "tabletop", "--size", "128x96"];
    let o = anaglyph(
        &[&args[..], &["--dark", "0.06,0.005", "--out", "dark"]].concat(),
        d,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(d.join("dark/dark/r1c3.png").is_file());
    let with_frame = psnr_of(d, "dark/rig.toml", "rec-framed");
    let text = std::fs::read_to_string(d.join("dark/rig.toml")).unwrap();
    let mut rig = RigFile::from_toml_str(&text, "dark rig").unwrap();
    for cam in &mut rig.cameras {
        cam.dark = None;
    }
    rig.save(&d.join("dark/no_dark.toml")).unwrap();
    let frame_ignored = psnr_of(d, "dark/no_dark.toml", "rec-frame-ignored");
    eprintln!(
        "clean {clean:.2} dB; black level ignored {ignored:.2} dB, subtracted \
         {subtracted:.2} dB; dark frames ignored {frame_ignored:.2} dB, subtracted \
         {with_frame:.2} dB"
    );
    assert!(
        subtracted > clean - 0.3 && with_frame > clean - 0.3,
        "clean {clean:.2} dB, black level {subtracted:.2} dB, dark frame {with_frame:.2} dB"
    );
    assert!(
        ignored < clean - 1.0 && frame_ignored < clean - 1.0,
        "an offset left in should cost more than 1 dB: clean {clean:.2}, ignored {ignored:.2} \
         and {frame_ignored:.2}"
    );
}

/// `dir/SIM/rig.toml` without its white boards (its exposures stay), as
/// `dir/SIM/exposure_only.toml`.
fn without_white_boards(dir: &Path, sim: &str) -> String {
    let text = std::fs::read_to_string(dir.join(sim).join("rig.toml")).unwrap();
    let mut rig = RigFile::from_toml_str(&text, "sim rig").unwrap();
    for cam in &mut rig.cameras {
        cam.white = None;
    }
    rig.save(&dir.join(sim).join("exposure_only.toml")).unwrap();
    format!("{sim}/exposure_only.toml")
}

#[test]
fn vignetting_is_divided_out_by_the_per_pixel_white_board() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // The same scene and seed, once through a lens that loses half the light at the
    // corners (white boards included): the truth is the same.
    for (out, vignetting) in [("sim", "0"), ("vignetted", "0.5")] {
        let args = ["simulate", "--scene", "tabletop", "--size", "128x96"];
        let o = anaglyph(
            &[&args[..], &["--vignetting", vignetting, "--out", out]].concat(),
            d,
        );
        assert!(o.status.success(), "{}", stderr(&o));
    }
    let clean = psnr_of(d, "sim/rig.toml", "rec-clean");
    let vignetted = psnr_of(d, "vignetted/rig.toml", "rec-vignetted");
    let exposure_only = psnr_of(d, &without_white_boards(d, "sim"), "rec-exposure");
    let rig = without_white_boards(d, "vignetted");
    let vignetted_exposure_only = psnr_of(d, &rig, "rec-vignetted-exposure");
    eprintln!(
        "white boards: {clean:.2} dB, vignetted {vignetted:.2} dB; exposure only: \
         {exposure_only:.2} dB, vignetted {vignetted_exposure_only:.2} dB"
    );
    assert!(vignetted > clean - 0.5, "{vignetted} {clean}");
    assert!(
        vignetted_exposure_only < exposure_only - 3.0,
        "{vignetted_exposure_only} {exposure_only}"
    );
    let o = anaglyph(
        &[
            "simulate",
            "--scene",
            "tabletop",
            "--vignetting",
            "1.2",
            "--out",
            "bad",
        ],
        d,
    );
    assert!(
        !o.status.success() && stderr(&o).contains("vignetting"),
        "{}",
        stderr(&o)
    );
    assert!(!d.join("bad").exists());
}

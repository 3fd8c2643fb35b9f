//! The bad-input matrix: each case a hostile or careless user meets, asserting the
//! error (what was found and what was expected) and that the output folder is the
//! previous complete one or absent, never a mix and never a half-written folder.

use super::{anaglyph, assert_clean_failure, stderr, stdout};
use anaglyph_core::io::{read_linear_image, verify_output_folder, write_png16};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// A small simulation under `dir/sim`.
fn simulate_into(dir: &Path) {
    let o = anaglyph(
        &[
            "simulate", "--scene", "tabletop", "--size", "128x96", "--out", "sim",
        ],
        dir,
    );
    assert!(o.status.success(), "{}", stderr(&o));
}

/// `reconstruct` of `dir/sim` into `out`, quick settings, with `extra` arguments.
fn reconstruct(dir: &Path, out: &str, extra: &[&str]) -> Output {
    let mut args = vec![
        "reconstruct",
        "--rig",
        "sim/rig.toml",
        "--out",
        out,
        "--max-disp",
        "16",
        "--preset",
        "fast",
    ];
    args.extend_from_slice(extra);
    anaglyph(&args, dir)
}

/// Names in `dir`, hidden ones included, sorted.
fn entries(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

/// Nothing staged or half-written is left beside the outputs.
fn assert_no_leftovers(dir: &Path) {
    let hidden: Vec<String> = entries(dir)
        .into_iter()
        .filter(|n| n.starts_with('.'))
        .collect();
    assert!(hidden.is_empty(), "left behind: {hidden:?}");
}

/// The simulation's captures copied to `dir/name`, with `change` applied to camera r0c1's.
fn captures_with(dir: &Path, name: &str, change: impl Fn(&mut Vec<f32>)) -> PathBuf {
    let target = dir.join(name);
    std::fs::create_dir_all(&target).unwrap();
    for entry in std::fs::read_dir(dir.join("sim/captures")).unwrap() {
        let path = entry.unwrap().path();
        let mut image = read_linear_image(&path).unwrap();
        if path.file_name().unwrap() == "r0c1.png" {
            change(&mut image.data);
        }
        write_png16(&target.join(path.file_name().unwrap()), &image).unwrap();
    }
    target
}

#[test]
fn a_rerun_replaces_the_folder_whole_and_eval_refuses_a_mixed_one() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    simulate_into(d);
    let o = reconstruct(d, "rec", &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = reconstruct(d, "rec", &["--views", "r0c0"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(entries(&d.join("rec/views")), ["r0c0.hdr", "r0c0.img"]);
    let o = anaglyph(&["eval", "--truth", "sim", "--recon", "rec"], d);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("mean over 1 view(s)"), "{}", stdout(&o));
    assert_no_leftovers(d);

    for ext in ["hdr", "img"] {
        let from = d.join(format!("sim/truth/r0c1.{ext}"));
        std::fs::copy(from, d.join(format!("rec/views/r0c1.{ext}"))).unwrap();
    }
    let o = anaglyph(&["eval", "--truth", "sim", "--recon", "rec"], d);
    assert_clean_failure(&o, "a file the manifest does not list");
    std::fs::remove_file(d.join("rec/views/r0c1.hdr")).unwrap();
    std::fs::remove_file(d.join("rec/views/r0c1.img")).unwrap();
    std::fs::write(d.join("rec/views/r0c0.img"), b"truncated").unwrap();
    let o = anaglyph(&["eval", "--truth", "sim", "--recon", "rec"], d);
    assert_clean_failure(&o, "as the manifest records");
    std::fs::remove_file(d.join("rec/manifest.json")).unwrap();
    let o = anaglyph(&["eval", "--truth", "sim", "--recon", "rec"], d);
    assert_clean_failure(&o, "manifest.json: missing");
}

#[test]
fn a_folder_anaglyph_did_not_write_or_that_holds_the_inputs_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    simulate_into(d);
    std::fs::create_dir(d.join("thesis")).unwrap();
    std::fs::write(d.join("thesis/chapter1.tex"), "words").unwrap();
    let o = reconstruct(d, "thesis", &[]);
    assert_clean_failure(&o, "holds files anaglyph did not write");
    assert_eq!(entries(&d.join("thesis")), ["chapter1.tex"]);
    let o = reconstruct(d, "sim", &["--force"]);
    assert_clean_failure(&o, "which replacing it would delete");
    verify_output_folder(&d.join("sim")).unwrap();
    let o = anaglyph(
        &["simulate", "--scene", "tabletop", "--out", "sim/rig.toml"],
        d,
    );
    assert_clean_failure(&o, "is a file");
    let o = reconstruct(d, "thesis", &["--force"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!d.join("thesis/chapter1.tex").exists());
    verify_output_folder(&d.join("thesis")).unwrap();
    assert_no_leftovers(d);
}

/// No command overwrites one of its inputs or writes two outputs to one file (paths
/// compared canonically, links resolved), and a re-run never deletes what a user added
/// to a folder anaglyph wrote.
#[test]
fn no_input_is_overwritten_and_no_user_file_deleted() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    simulate_into(d);
    let (left, right) = ("sim/captures/r0c0.png", "sim/captures/r0c1.png");
    let originals: Vec<Vec<u8>> = [left, right]
        .iter()
        .map(|p| std::fs::read(d.join(p)).unwrap())
        .collect();
    #[cfg(unix)]
    std::os::unix::fs::symlink(d.join(right), d.join("alias.pfm")).unwrap();
    let cases: &[(&[&str], &str)] = &[
        (
            &["--out", left],
            "--out sim/captures/r0c0.png: is the input --left",
        ),
        (
            &["--out", "./sim/../sim/captures/r0c1.png"],
            "is the input --right",
        ),
        (
            &["--out", "d.pfm", "--preview", right],
            "--preview sim/captures/r0c1.png: is the input --right",
        ),
        (&["--out", "d.pfm", "--report", left], "is the input --left"),
        (
            &["--out", "d.pfm", "--preview", "d.pfm"],
            "--preview d.pfm: is also --out d.pfm",
        ),
        #[cfg(unix)]
        (&["--out", "alias.pfm"], "is the input --right"),
    ];
    for (extra, needle) in cases {
        let mut args = vec![
            "match",
            "--left",
            left,
            "--right",
            right,
            "--max-disp",
            "8",
            "--method",
            "census",
        ];
        args.extend_from_slice(extra);
        let o = anaglyph(&args, d);
        assert_clean_failure(&o, needle);
        assert!(!d.join("d.pfm").exists(), "{extra:?}: wrote an output");
    }
    // A pair without signal is refused, not matched into "100 % valid" zeros.
    let black = read_linear_image(&d.join(left)).unwrap();
    let black = anaglyph_core::io::LinearImage {
        data: vec![0.0; black.data.len()],
        ..black
    };
    write_png16(&d.join("black.png"), &black).unwrap();
    let o = anaglyph(
        &[
            "match",
            "--left",
            "black.png",
            "--right",
            right,
            "--max-disp",
            "8",
            "--out",
            "d.pfm",
        ],
        d,
    );
    assert_clean_failure(&o, "--left black.png cannot be used: its capture is black");
    assert!(!d.join("d.pfm").exists());
    for (path, original) in [left, right].iter().zip(&originals) {
        assert_eq!(
            &std::fs::read(d.join(path)).unwrap(),
            original,
            "{path} changed"
        );
    }
    // demux and rig show alike.
    let o = anaglyph(&["rig", "show", "sim/rig.toml", "--export-c", "c.npy"], d);
    assert!(o.status.success(), "{}", stderr(&o));
    let c = std::fs::read(d.join("c.npy")).unwrap();
    let o = anaglyph(
        &[
            "demux",
            "--sensing",
            "c.npy",
            "--measurements",
            "c.npy",
            "--out",
            "c.npy",
        ],
        d,
    );
    assert_clean_failure(&o, "--out c.npy: is the input --sensing");
    let o = anaglyph(
        &["rig", "show", "sim/rig.toml", "--export-c", "sim/rig.toml"],
        d,
    );
    assert_clean_failure(&o, "is the input --rig");
    assert_eq!(std::fs::read(d.join("c.npy")).unwrap(), c);
    verify_output_folder(&d.join("sim")).unwrap();

    // Calibration files that cannot be meant for these captures.
    std::fs::create_dir(d.join("calib")).unwrap();
    let identity = "[[1, 0, 0], [0, 1, 0], [0, 0, 1]]";
    let write_all = |text: &str| {
        for row in 0..2 {
            for col in 0..4 {
                std::fs::write(d.join(format!("calib/r{row}c{col}.json")), text).unwrap();
            }
        }
    };
    write_all(&format!(
        r#"{{"homography": {identity}, "image_width": 640, "image_height": 480}}"#
    ));
    let o = reconstruct(d, "rec", &["--calibration", "calib"]);
    assert_clean_failure(&o, "a homography made for 640x480 px images");
    write_all("[[1e12, 0, 0], [0, 1e12, 0], [0, 0, 1]]");
    let o = reconstruct(d, "rec", &["--calibration", "calib"]);
    assert_clean_failure(&o, "wrongly scaled");
    write_all(identity);
    let o = reconstruct(d, "rec-bare", &["--calibration", "calib"]);
    assert!(o.status.success(), "a bare array of rows: {}", stderr(&o));
    assert!(!d.join("rec").exists());

    // A user's files in a folder anaglyph wrote stop the next run into it.
    let o = reconstruct(d, "rec", &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    std::fs::write(d.join("rec/NOTES.txt"), "mine").unwrap();
    let o = reconstruct(d, "rec", &[]);
    assert_clean_failure(&o, "holds NOTES.txt, which its manifest does not list");
    std::fs::remove_file(d.join("rec/NOTES.txt")).unwrap();
    std::fs::create_dir(d.join("rec/mine")).unwrap();
    std::fs::write(d.join("rec/mine/data.csv"), "1,2").unwrap();
    let o = reconstruct(d, "rec", &[]);
    assert_clean_failure(&o, "holds mine/");
    assert_eq!(std::fs::read(d.join("rec/mine/data.csv")).unwrap(), b"1,2");
    std::fs::remove_dir_all(d.join("rec/mine")).unwrap();
    let o = reconstruct(d, "rec", &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    verify_output_folder(&d.join("rec")).unwrap();
    assert_no_leftovers(d);
}

/// SIGKILL at several moments of a re-run: the folder is always the previous complete
/// one (or a newer complete one), and the next run removes what the killed ones left.
#[test]
fn a_killed_run_leaves_the_previous_folder_whole() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    simulate_into(d);
    let o = reconstruct(d, "rec", &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let first = verify_output_folder(&d.join("rec")).unwrap();
    for delay_ms in [20, 150, 400, 900] {
        let mut child = Command::new(env!("CARGO_BIN_EXE_anaglyph"))
            .args([
                "reconstruct",
                "--rig",
                "sim/rig.toml",
                "--out",
                "rec",
                "--max-disp",
                "16",
            ])
            .current_dir(d)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap();
        std::thread::sleep(std::time::Duration::from_millis(delay_ms));
        let _ = child.kill();
        child.wait().unwrap();
        let now = verify_output_folder(&d.join("rec"))
            .unwrap_or_else(|e| panic!("after a kill at {delay_ms} ms: {e}"));
        assert!(now.run_id == first.run_id || now.files.len() == first.files.len());
    }
    let o = reconstruct(d, "rec", &["--views", "r1c3"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(entries(&d.join("rec/views")), ["r1c3.hdr", "r1c3.img"]);
    assert_no_leftovers(d);
}

#[test]
fn impossible_captures_are_refused_naming_the_camera() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    simulate_into(d);
    captures_with(d, "black", |data| data.fill(0.0));
    let o = reconstruct(d, "rec", &["--captures", "black"]);
    assert_clean_failure(
        &o,
        "camera r0c1 cannot be used: its capture is black (100.0 %",
    );
    captures_with(d, "saturated", |data| data.fill(1.0));
    let o = reconstruct(d, "rec", &["--captures", "saturated"]);
    assert_clean_failure(&o, "camera r0c1 cannot be used: its capture is saturated");
    captures_with(d, "flat", |data| data.fill(0.3));
    let o = reconstruct(d, "rec", &["--captures", "flat"]);
    assert_clean_failure(&o, "constant");
    assert!(!d.join("rec").exists());
    assert_no_leftovers(d);
    // The captures themselves as white boards: the scene is as bright as "white".
    let o = reconstruct(d, "rec", &["--white", "sim/captures"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("brighter than a perfect white"),
        "{}",
        stderr(&o)
    );
}

/// A PNG header declaring `width × height` 16-bit RGB, with almost no data.
fn png_declaring(width: u32, height: u32) -> Vec<u8> {
    fn crc32(bytes: &[u8]) -> u32 {
        let mut crc = !0u32;
        for &b in bytes {
            crc ^= b as u32;
            for _ in 0..8 {
                crc = if crc & 1 == 1 {
                    (crc >> 1) ^ 0xEDB8_8320
                } else {
                    crc >> 1
                };
            }
        }
        !crc
    }
    let chunk = |kind: &[u8], data: &[u8]| {
        let mut out = (data.len() as u32).to_be_bytes().to_vec();
        let body = [kind, data].concat();
        out.extend_from_slice(&body);
        out.extend_from_slice(&crc32(&body).to_be_bytes());
        out
    };
    let mut header = width.to_be_bytes().to_vec();
    header.extend_from_slice(&height.to_be_bytes());
    header.extend_from_slice(&[16, 2, 0, 0, 0]);
    let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
    png.extend(chunk(b"IHDR", &header));
    png.extend(chunk(
        b"IDAT",
        &[0x78, 0x9c, 0x03, 0x00, 0x00, 0x00, 0x00, 0x01],
    ));
    png.extend(chunk(b"IEND", &[]));
    png
}

#[test]
fn sizes_are_checked_against_limits_before_decoding_or_allocating() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    simulate_into(d);
    let huge = captures_with(d, "huge", |_| {});
    std::fs::write(huge.join("r0c1.png"), png_declaring(20000, 20000)).unwrap();
    let o = reconstruct(d, "rec", &["--captures", "huge"]);
    assert_clean_failure(&o, "a 20000x20000 picture, in pixels (ANAGLYPH_MAX_PIXELS");
    std::fs::write(huge.join("r0c1.png"), png_declaring(4000, 3000)).unwrap();
    let o = reconstruct(d, "rec", &["--captures", "huge"]);
    assert_clean_failure(&o, "declaring 72000000 bytes of pixels");
    std::fs::write(huge.join("r0c1.png"), png_declaring(256, 96)).unwrap();
    let o = reconstruct(d, "rec", &["--captures", "huge"]);
    assert_clean_failure(&o, "256x96 pixels (expected 128x96");
    assert!(!d.join("rec").exists());
    let o = Command::new(env!("CARGO_BIN_EXE_anaglyph"))
        .args(["simulate", "--scene", "tabletop", "--size", "8000x6000"])
        .args(["--out", "big"])
        .env("ANAGLYPH_MAX_MEMORY", "1000000000")
        .current_dir(d)
        .output()
        .unwrap();
    assert_clean_failure(&o, "the memory needed in bytes (at least 45.8 GiB");
    assert!(!d.join("big").exists());
    // match estimates its cost volume (and the network's features) before allocating:
    // 128x96 px over 100 disparities with the learned cost is 164 values per pixel.
    let o = Command::new(env!("CARGO_BIN_EXE_anaglyph"))
        .args(["match", "--left", "sim/captures/r0c0.png", "--right"])
        .args([
            "sim/captures/r0c1.png",
            "--disp-range=-20:80",
            "--out",
            "d.pfm",
        ])
        .env("ANAGLYPH_MAX_MEMORY", "4000000")
        .current_dir(d)
        .output()
        .unwrap();
    assert_clean_failure(
        &o,
        "matching 128x96 px over 100 disparities (-20:80; a smaller range or image needs less)",
    );
    assert!(!d.join("d.pfm").exists());
    assert_no_leftovers(d);
}

#[test]
fn side_inputs_and_outputs_are_checked_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    simulate_into(d);
    let o = reconstruct(d, "rec", &["--probe", "500,10"]);
    assert_clean_failure(
        &o,
        "pixel (500, 10) (expected a pixel inside the 128x96 image)",
    );
    let o = reconstruct(d, "rec", &["--probe", "5,10", "--truth", "nowhere"]);
    assert_clean_failure(&o, "--truth nowhere: not one simulation's complete output");
    assert!(!d.join("rec").exists());
    std::fs::create_dir(d.join("model")).unwrap();
    let o = anaglyph(&["train", "--out", "model", "--steps", "1"], d);
    assert_clean_failure(&o, "--out model: is a folder");
    let o = anaglyph(
        &["train", "--out", "m.safetensors", "--curve", "no/c.csv"],
        d,
    );
    assert_clean_failure(&o, "the folder no does not exist");
    assert!(!d.join("m.safetensors").exists());
    let o = anaglyph(
        &[
            "match",
            "--left",
            "sim/captures/r0c0.png",
            "--right",
            "sim/captures/r0c1.png",
            "--max-disp",
            "16",
            "--out",
            "d.pfm",
            "--preview",
            "model",
        ],
        d,
    );
    assert_clean_failure(&o, "--preview model: is a folder");
    assert!(!d.join("d.pfm").exists());
    let o = anaglyph(
        &[
            "eval",
            "--truth",
            "sim",
            "--recon",
            "sim",
            "--json",
            "no/e.json",
        ],
        d,
    );
    assert_clean_failure(&o, "does not exist");
}

#[test]
fn parsers_name_what_they_found() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let bom = "\u{feff}wavelength_nm,t\n400,0.5\n500,0.6\n";
    std::fs::write(d.join("bom.csv"), bom).unwrap();
    let o = anaglyph(
        &[
            "calibrate-filter",
            "--without",
            "bom.csv",
            "--with",
            "bom.csv",
            "--out",
            "t.csv",
        ],
        d,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let negative = "wavelength_nm,t\n400,-0.5\n500,-0.6\n";
    std::fs::write(d.join("negative.csv"), negative).unwrap();
    let o = anaglyph(
        &[
            "calibrate-filter",
            "--without",
            "bom.csv",
            "--with",
            "negative.csv",
            "--out",
            "n.csv",
        ],
        d,
    );
    assert_clean_failure(&o, "zero at all");
    assert!(!d.join("n.csv").exists());
    let mut npy = anaglyph_core::io::npy_header("<c8", &[2, 2]);
    npy.extend_from_slice(&[0u8; 32]);
    std::fs::write(d.join("c.npy"), npy).unwrap();
    let o = anaglyph(
        &[
            "demux",
            "--sensing",
            "c.npy",
            "--measurements",
            "c.npy",
            "--out",
            "s.npy",
        ],
        d,
    );
    assert_clean_failure(&o, "complex64");
    assert!(!d.join("s.npy").exists());
    let o = anaglyph(
        &[
            "demux",
            "--sensing",
            "c.npy",
            "--measurements",
            "c.npy",
            "--out",
            "missing/s.npy",
        ],
        d,
    );
    assert_clean_failure(&o, "--out missing/s.npy: the folder missing does not exist");
}

#[test]
#[cfg(unix)]
fn a_closed_standard_output_ends_the_process_quietly() {
    use std::os::unix::process::ExitStatusExt;
    let dir = tempfile::tempdir().unwrap();
    let o = anaglyph(&["rig", "init", "--out", "rig.toml"], dir.path());
    assert!(o.status.success(), "{}", stderr(&o));
    let mut child = Command::new(env!("CARGO_BIN_EXE_anaglyph"))
        .args(["rig", "show", "rig.toml"])
        .current_dir(dir.path())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let output = child.wait_with_output().unwrap();
    let status = output.status;
    assert!(
        status.success() || status.signal() == Some(libc::SIGPIPE),
        "{status:?}"
    );
    assert!(!stderr(&output).contains("panicked"), "{}", stderr(&output));
}

/// A simulation's rig names only the dark signal the simulation rendered: an input rig's
/// dark frame (a relative path that would dangle in the output) and black level are not
/// copied, so reconstruct does not subtract what the captures never had.
#[test]
fn a_simulation_s_rig_keeps_no_dark_signal_it_did_not_render() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut rig = anaglyph_core::rig::Rig::paper_rig_file(&anaglyph_core::rig::PAPER_RIG_FILTERS);
    rig.cameras[0].dark = Some("darks/r0c0.png".into());
    rig.cameras[1].black_level = Some(100.0);
    rig.save(&d.join("dark.toml")).unwrap();
    let o = anaglyph(
        &[
            "simulate",
            "--scene",
            "tabletop",
            "--rig",
            "dark.toml",
            "--size",
            "64x48",
            "--out",
            "sim",
        ],
        d,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let text = std::fs::read_to_string(d.join("sim/rig.toml")).unwrap();
    assert!(
        !text.contains("dark") && !text.contains("black_level"),
        "{text}"
    );
    let o = anaglyph(
        &[
            "simulate",
            "--scene",
            "tabletop",
            "--rig",
            "dark.toml",
            "--size",
            "64x48",
            "--dark",
            "0.02",
            "--out",
            "sim-dark",
        ],
        d,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let text = std::fs::read_to_string(d.join("sim-dark/rig.toml")).unwrap();
    assert!(
        text.contains("dark = \"dark/r0c0.png\"") && !text.contains("black_level"),
        "{text}"
    );
}

/// `eval` refuses to score a reconstruction against the truth of another array (same
/// camera names and size, other filters).
#[test]
fn eval_refuses_the_truth_of_another_array() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    simulate_into(d);
    let o = reconstruct(d, "rec", &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let mut filters = anaglyph_core::rig::PAPER_RIG_FILTERS;
    filters.reverse();
    anaglyph_core::rig::Rig::paper_rig_file(&filters)
        .save(&d.join("other.toml"))
        .unwrap();
    let o = anaglyph(
        &[
            "simulate",
            "--scene",
            "tabletop",
            "--rig",
            "other.toml",
            "--size",
            "128x96",
            "--out",
            "other",
        ],
        d,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let o = anaglyph(&["eval", "--truth", "other", "--recon", "rec"], d);
    assert_clean_failure(
        &o,
        "--recon rec: a reconstruction of cameras r0c0 gel_deep_red",
    );
    let o = anaglyph(&["eval", "--truth", "sim", "--recon", "rec"], d);
    assert!(o.status.success(), "{}", stderr(&o));
}

/// Messages that named the wrong thing or none: each names the option or file, what was
/// found and what was expected.
#[test]
fn unclear_inputs_get_messages_naming_them() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    simulate_into(d);
    // Negative numbers reach the option's own check instead of the argument parser.
    let o = reconstruct(d, "rec", &["--white-reflectance", "-1"]);
    assert_clean_failure(&o, "white reflectance is -1 (expected in (0, 1])");
    let o = reconstruct(d, "rec", &["--probe", "-1,5"]);
    assert_clean_failure(&o, "'-1' is not a pixel coordinate");
    // Two candidate files for one camera are not picked silently.
    let captures = captures_with(d, "two", |_| {});
    std::fs::copy(captures.join("r0c0.png"), captures.join("r0c0.tif")).unwrap();
    let o = reconstruct(d, "rec", &["--captures", "two"]);
    assert_clean_failure(&o, "capture of camera r0c0: both");
    // Curve keywords in any case, and without their arguments.
    let mut rig = anaglyph_core::rig::Rig::paper_rig_file(&anaglyph_core::rig::PAPER_RIG_FILTERS);
    rig.cameras[0].filter = Some("GAUSSIAN:550:40".into());
    rig.save(&d.join("upper.toml")).unwrap();
    let o = anaglyph(&["rig", "show", "upper.toml", "--plot", "u.svg"], d);
    assert!(o.status.success(), "{}", stderr(&o));
    rig.cameras[0].filter = Some("gaussian".into());
    rig.save(&d.join("bare.toml")).unwrap();
    let o = anaglyph(&["rig", "show", "bare.toml", "--plot", "b.svg"], d);
    assert_clean_failure(&o, "curve 'gaussian': a keyword without its arguments");
    // A camera named like the --views keyword.
    rig.cameras[0].filter = Some("builtin:gel_red".into());
    rig.cameras[0].name = Some("all".into());
    rig.save(&d.join("all.toml")).unwrap();
    let o = anaglyph(&["rig", "show", "all.toml", "--plot", "a.svg"], d);
    assert_clean_failure(&o, "a camera named 'all'");
    // A dark frame brighter than its capture is blamed, not the capture it blackens.
    let mut bright = read_linear_image(&d.join("sim/captures/r0c1.png")).unwrap();
    bright.data.fill(0.9);
    write_png16(&d.join("sim/bright.png"), &bright).unwrap();
    let text = std::fs::read_to_string(d.join("sim/rig.toml")).unwrap();
    let text = text.replace(
        "image = \"captures/r0c1.png\"",
        "image = \"captures/r0c1.png\"\ndark = \"bright.png\"",
    );
    std::fs::write(d.join("sim/dark.toml"), text).unwrap();
    let o = anaglyph(
        &["reconstruct", "--rig", "sim/dark.toml", "--out", "rec"],
        d,
    );
    assert_clean_failure(
        &o,
        "camera r0c1 cannot be used: its dark frame sim/bright.png is at or above its capture \
         (sim/captures/r0c1.png)",
    );
    // A picture of another size is blamed, not the first camera it differs from.
    let odd = captures_with(d, "odd", |_| {});
    let tiny = anaglyph_core::image::Image::new(1, 1, 3, vec![0.5; 3]).unwrap();
    write_png16(&odd.join("r0c0.png"), &tiny).unwrap();
    let o = reconstruct(d, "rec", &["--captures", "odd"]);
    assert_clean_failure(&o, "odd/r0c0.png: 1x1 pixels (expected 128x96");
    // Calibration files: a malformed map is reported as that map; a file with neither
    // map nor pose says what it holds.
    std::fs::create_dir(d.join("calib")).unwrap();
    for (text, needle) in [
        (
            r#"{"homography": [[1, 0, 0], [0, 1, 0]]}"#,
            "calib/r0c0.json: homography is a 2x3 matrix (expected a 3x3 matrix",
        ),
        (
            r#"{"homogrphy": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}"#,
            "calib/r0c0.json: the calibration is only homogrphy (expected a plane calibration",
        ),
    ] {
        for row in 0..2 {
            for col in 0..4 {
                std::fs::write(d.join(format!("calib/r{row}c{col}.json")), text).unwrap();
            }
        }
        let o = reconstruct(d, "rec", &["--calibration", "calib"]);
        assert_clean_failure(&o, needle);
    }
    assert!(!d.join("rec").exists());
}

/// The exit status: 2 when the command line cannot be parsed (as clap and grep report
/// usage errors), 1 for every other error, each with an `error:` line.
#[test]
fn usage_errors_exit_2_and_other_errors_1() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let usage = [
        vec!["reconstruct", "--rig", "r.toml", "--out", "o", "--bogus"],
        vec!["reconstruct", "--rig", "r.toml"],
        vec![
            "reconstruct",
            "--rig",
            "r.toml",
            "--out",
            "o",
            "--disp-range",
            "wide",
        ],
    ];
    for args in usage {
        let o = anaglyph(&args, d);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", stderr(&o));
        assert!(stderr(&o).contains("error:"), "{}", stderr(&o));
    }
    let o = anaglyph(&["reconstruct", "--rig", "missing.toml", "--out", "o"], d);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert_clean_failure(&o, "missing.toml");
    let o = anaglyph(
        &[
            "reconstruct",
            "--rig",
            "missing.toml",
            "--out",
            "o",
            "--white-reflectance",
            "-1",
        ],
        d,
    );
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert_clean_failure(&o, "white reflectance");
}

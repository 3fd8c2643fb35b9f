//! `reconstruct --frames`: a capture folder of frames (frame-major or camera-major) into a
//! Zarr store, each frame equal to a single-frame run of its captures, a rerun completing
//! the store, and bad sequences refused before any work.

use super::{anaglyph, assert_clean_failure, stderr, stdout};
use std::path::Path;
use std::sync::Arc;
use zarrs::array::Array;
use zarrs::filesystem::FilesystemStore;

const CAMERAS: [&str; 8] = [
    "r0c0", "r0c1", "r0c2", "r0c3", "r1c0", "r1c1", "r1c2", "r1c3",
];

/// Two frames of the tabletop (different noise and exposures) under `dir/sim0` and
/// `dir/sim1`, laid out as `dir/fm/frame_K/<camera>.png` and `dir/cm/<camera>/K.png`.
fn two_frames(dir: &Path) {
    for seed in 0..2 {
        let out = format!("sim{seed}");
        let seed = seed.to_string();
        let o = anaglyph(
            &[
                "simulate", "--scene", "tabletop", "--size", "96x72", "--seed", &seed, "--out",
                &out,
            ],
            dir,
        );
        assert!(o.status.success(), "{}", stderr(&o));
        for cam in CAMERAS {
            let from = dir.join(format!("{out}/captures/{cam}.png"));
            let frame_major = dir.join(format!("fm/frame_{seed}/{cam}.png"));
            let camera_major = dir.join(format!("cm/{cam}/{seed}.png"));
            for to in [frame_major, camera_major] {
                std::fs::create_dir_all(to.parent().unwrap()).unwrap();
                std::fs::copy(&from, &to).unwrap();
            }
        }
    }
}

fn read_f32(store: &Path, name: &str) -> Vec<u32> {
    let zarr = Arc::new(FilesystemStore::new(store).unwrap());
    let array = Array::open(zarr, &format!("/{name}")).unwrap();
    let values: Vec<f32> = array.retrieve_array_subset(&array.subset_all()).unwrap();
    values.into_iter().map(f32::to_bits).collect()
}

/// `reconstruct` of `captures` into `out`, `--frames` and any `extra` options.
fn reconstruct(
    dir: &Path,
    captures: &str,
    out: &str,
    frames: Option<&str>,
    extra: &[&str],
) -> std::process::Output {
    let mut args = vec![
        "reconstruct",
        "--rig",
        "sim0/rig.toml",
        "--white",
        "sim0/white",
        "--captures",
        captures,
        "--out",
        out,
        "--disp-range",
        "0:12",
    ];
    if let Some(frames) = frames {
        args.extend(["--frames", frames]);
    }
    args.extend_from_slice(extra);
    anaglyph(&args, dir)
}

#[test]
fn a_sequence_goes_to_a_zarr_store_frame_by_frame_in_either_layout() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    two_frames(d);
    // Every frame alone (--no-reuse): each is a single-frame run's, bit for bit.
    let alone = ["--no-reuse"];
    let o = reconstruct(d, "fm", "fm.zarr", Some("all"), &alone);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stdout(&o).contains("wrote 2 frame(s) into fm.zarr"),
        "{}",
        stdout(&o)
    );
    let o = reconstruct(d, "cm", "cm.zarr", Some("all"), &alone);
    assert!(o.status.success(), "{}", stderr(&o));
    // One frame alone, into a store of its own: the sequence's frame 1, bit for bit.
    let o = reconstruct(d, "sim1/captures", "one.zarr", None, &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    for name in ["reflectance", "disparity"] {
        let sequence = read_f32(&d.join("fm.zarr"), name);
        assert_eq!(sequence, read_f32(&d.join("cm.zarr"), name), "{name}");
        let one = read_f32(&d.join("one.zarr"), name);
        assert_eq!(&sequence[sequence.len() / 2..], &one[..], "{name}");
    }
    // With reuse (the default) the first frame is the same and the run says what the
    // second reused.
    let o = reconstruct(d, "fm", "reused.zarr", Some("all"), &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stdout(&o).contains("temporal reuse over 1 frame(s) after the first: 0 cut(s)"),
        "{}",
        stdout(&o)
    );
    for name in ["reflectance", "disparity"] {
        let (reused, alone) = (
            read_f32(&d.join("reused.zarr"), name),
            read_f32(&d.join("fm.zarr"), name),
        );
        assert_eq!(
            reused[..reused.len() / 2],
            alone[..alone.len() / 2],
            "{name}"
        );
    }
    // A rerun finds both frames written; frames 1:1 of another store is its own run, and
    // so is a rerun with reuse of a store written without.
    let o = reconstruct(d, "fm", "reused.zarr", Some("all"), &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = reconstruct(d, "fm", "fm.zarr", Some("all"), &[]);
    assert_clean_failure(&o, "a store of another run");
    let o = reconstruct(d, "fm", "fm.zarr", Some("all"), &alone);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("2 of 2 frames are already in"),
        "{}",
        stderr(&o)
    );
    assert!(stdout(&o).contains("wrote 0 frame(s)"), "{}", stdout(&o));
    let o = reconstruct(d, "fm", "fm.zarr", Some("1:1"), &alone);
    assert_clean_failure(&o, "a store of another run");
}

#[test]
fn bad_sequences_are_refused_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    two_frames(d);
    assert_clean_failure(
        &reconstruct(d, "fm", "out", Some("all"), &[]),
        "ending in .zarr",
    );
    std::fs::remove_file(d.join("cm/r1c2/1.png")).unwrap();
    let o = reconstruct(d, "cm", "cm.zarr", Some("all"), &[]);
    assert_clean_failure(&o, "frame 1: no capture of camera r1c2");
    std::fs::remove_file(d.join("fm/frame_0/r0c1.png")).unwrap();
    let o = reconstruct(d, "fm", "fm.zarr", Some("all"), &[]);
    assert_clean_failure(&o, "frame 0");
    assert!(stderr(&o).contains("r0c1"), "{}", stderr(&o));
    assert_clean_failure(
        &reconstruct(d, "fm", "fm.zarr", Some("5:9"), &[]),
        "no frames '5:9'",
    );
    assert_clean_failure(&reconstruct(d, "fm", "fm.zarr", Some("2:1"), &[]), "frames");
    assert!(!d.join("fm.zarr").exists() && !d.join("cm.zarr").exists());
}

#[test]
fn a_simulated_moving_sequence_reconstructs_frame_by_frame() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let o = anaglyph(
        &[
            "simulate",
            "--scene",
            "tabletop-moving",
            "--size",
            "96x72",
            "--frames",
            "3",
            "--out",
            "seq",
        ],
        d,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("3 frames of 8 views"), "{}", stdout(&o));
    for k in 0..3 {
        assert!(d
            .join(format!("seq/captures/frame_{k:04}/r1c3.png"))
            .is_file());
        assert!(d
            .join(format!("seq/truth/frame_{k:04}/r0c0_disparity.pfm"))
            .is_file());
    }
    assert!(d.join("seq/white/r0c0.png").is_file());
    let o = anaglyph(
        &[
            "reconstruct",
            "--rig",
            "seq/rig.toml",
            "--captures",
            "seq/captures",
            "--white",
            "seq/white",
            "--frames",
            "all",
            "--disp-range",
            "0:12",
            "--out",
            "seq.zarr",
        ],
        d,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("wrote 3 frame(s)"), "{}", stdout(&o));
    // A scene that does not move is said to differ by its noise only.
    let o = anaglyph(
        &[
            "simulate", "--scene", "tabletop", "--size", "32x24", "--frames", "2", "--out", "still",
        ],
        d,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("nothing in scene 'tabletop' moves"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn dark_frames_per_frame_or_per_sequence_serve_the_captures() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let o = anaglyph(
        &[
            "simulate",
            "--scene",
            "tabletop",
            "--size",
            "64x48",
            "--frames",
            "2",
            "--dark",
            "0.05,0.01",
            "--out",
            "dk",
        ],
        d,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    // The master darks again, once per frame (frame-major), for one frame only, and
    // swapped between cameras (another fixed pattern) for frame 1.
    for k in 0..2 {
        for (i, cam) in CAMERAS.into_iter().enumerate() {
            let to = d.join(format!("perframe/{k}/{cam}.png"));
            std::fs::create_dir_all(to.parent().unwrap()).unwrap();
            std::fs::copy(d.join(format!("dk/dark/{cam}.png")), &to).unwrap();
            let other = if k == 1 { CAMERAS[(i + 1) % 8] } else { cam };
            let to = d.join(format!("swapped/{k}/{cam}.png"));
            std::fs::create_dir_all(to.parent().unwrap()).unwrap();
            std::fs::copy(d.join(format!("dk/dark/{other}.png")), &to).unwrap();
            if k == 0 {
                let partial = d.join(format!("partial/{k}/{cam}.png"));
                std::fs::create_dir_all(partial.parent().unwrap()).unwrap();
                std::fs::copy(d.join(format!("dk/dark/{cam}.png")), &partial).unwrap();
            }
        }
    }
    let run = |out: &str, darks: Option<&str>| {
        let mut args = vec![
            "reconstruct",
            "--rig",
            "dk/rig.toml",
            "--captures",
            "dk/captures",
            "--white",
            "dk/white",
            "--frames",
            "all",
            "--disp-range",
            "0:8",
            "--no-reuse",
            "--out",
            out,
        ];
        if let Some(darks) = darks {
            args.extend(["--darks", darks]);
        }
        anaglyph(&args, d)
    };
    for (out, darks) in [
        ("rig.zarr", None),
        ("perframe.zarr", Some("perframe")),
        ("flat.zarr", Some("dk/dark")),
        ("swapped.zarr", Some("swapped")),
    ] {
        let o = run(out, darks);
        assert!(o.status.success(), "{out}: {}", stderr(&o));
    }
    // The same darks, from the rig, per frame or per sequence: the same cubes.
    let expected = read_f32(&d.join("rig.zarr"), "reflectance");
    assert_eq!(expected, read_f32(&d.join("perframe.zarr"), "reflectance"));
    assert_eq!(expected, read_f32(&d.join("flat.zarr"), "reflectance"));
    // Frame 1's own darks are what its captures lose: frame 0 the same, frame 1 not.
    let swapped = read_f32(&d.join("swapped.zarr"), "reflectance");
    let half = expected.len() / 2;
    assert_eq!(expected[..half], swapped[..half]);
    assert_ne!(expected[half..], swapped[half..]);
    // A frame without its darks is refused before any work, naming it.
    let o = run("partial.zarr", Some("partial"));
    assert_clean_failure(&o, "frame 1");
    assert!(stderr(&o).contains("no dark frames"), "{}", stderr(&o));
    assert!(!d.join("partial.zarr").exists());
}

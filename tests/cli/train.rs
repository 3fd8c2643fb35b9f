//! `anaglyph train` in segments: a run paused with `--stop-at-step` and continued with
//! `--resume` writes the same weights as the run made at once, and the checkpoint folder
//! is never overwritten by another run or mistaken for an output.

use super::{anaglyph, assert_clean_failure, stderr};
use std::path::Path;

/// A tiny recipe: one training scene, 4 triplets a step, 4 steps.
const TINY: [&str; 8] = [
    "--steps",
    "4",
    "--scenes",
    "1",
    "--batch",
    "4",
    "--validate-every",
    "2",
];

/// The tensors of a safetensors file (its bytes after the header) and its header.
fn tensors_and_header(path: &Path) -> (Vec<u8>, serde_json::Value) {
    let bytes = std::fs::read(path).unwrap();
    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let header: serde_json::Value = serde_json::from_slice(&bytes[8..8 + n]).unwrap();
    (bytes[8 + n..].to_vec(), header)
}

/// The tensors of a safetensors file and its metadata.
fn tensors_and_metadata(path: &Path) -> (Vec<u8>, serde_json::Value) {
    let (tensors, header) = tensors_and_header(path);
    (tensors, header["__metadata__"].clone())
}

#[test]
fn a_run_in_two_segments_writes_the_weights_of_the_run_made_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let o = anaglyph(
        &[&["train", "--out", "once.safetensors"][..], &TINY].concat(),
        d,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let first = [
        &["train", "--out", "seg.safetensors", "--checkpoint", "ck"][..],
        &TINY,
        &["--stop-at-step", "2"],
    ]
    .concat();
    let o = anaglyph(&first, d);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("paused at step 2 of 4")
            && stderr(&o).contains("anaglyph train --resume ck --out seg.safetensors"),
        "{}",
        stderr(&o)
    );
    assert!(!d.join("seg.safetensors").exists());
    let curve = std::fs::read_to_string(d.join("ck/curve.csv")).unwrap();
    assert_eq!(curve.lines().count(), 2, "{curve}");
    // The checkpoint folder is not another run's to start in, nor an output.
    let again = [
        &["train", "--out", "x.safetensors", "--checkpoint", "ck"][..],
        &TINY,
    ]
    .concat();
    assert_clean_failure(
        &anaglyph(&again, d),
        "--checkpoint ck: holds a run's checkpoint (at step 2 of 4)",
    );
    let o = anaglyph(
        &[
            "train",
            "--resume",
            "ck",
            "--out",
            "ck/checkpoint.safetensors",
        ],
        d,
    );
    assert_clean_failure(&o, "is also --out");
    let o = anaglyph(
        &["train", "--resume", "ck", "--out", "x", "--steps", "5"],
        d,
    );
    assert_clean_failure(&o, "--steps 5: the run checkpointed in ck has 4");
    let o = anaglyph(
        &[
            "train",
            "--resume",
            "ck",
            "--out",
            "x",
            "--narrow-band-share",
            "0.5",
        ],
        d,
    );
    assert_clean_failure(
        &o,
        "--narrow-band-share 0.5: the run checkpointed in ck has 0",
    );
    let o = anaglyph(&["train", "--out", "x", "--narrow-band-share", "1.5"], d);
    assert_clean_failure(&o, "--narrow-band-share 1.5: expected a share in [0, 1]");
    let o = anaglyph(
        &[
            "train",
            "--resume",
            "ck",
            "--out",
            "x",
            "--negatives",
            "1.5:6",
        ],
        d,
    );
    assert_clean_failure(&o, "--negatives 1.5:6: the run checkpointed in ck has 4:10");
    let o = anaglyph(
        &["train", "--out", "x", "--camera-effects-share", "-0.1"],
        d,
    );
    assert_clean_failure(
        &o,
        "--camera-effects-share -0.1: expected a share in [0, 1]",
    );
    let o = anaglyph(&["train", "--out", "x", "--negatives", "6"], d);
    assert_clean_failure(&o, "'6' (expected NEAR:FAR in pixels");
    let o = anaglyph(&["train", "--out", "x", "--negatives", "0.5:6"], d);
    assert_clean_failure(
        &o,
        "--negatives 0.5:6: the nearest negative must lie farther from the true match than the farthest positive (1 px)",
    );
    let o = anaglyph(&["train", "--out", "x", "--stop-at-step", "3"], d);
    assert_clean_failure(&o, "expected --checkpoint DIR with it");
    let o = anaglyph(&["train", "--resume", "once.safetensors", "--out", "x"], d);
    assert_clean_failure(&o, "--resume once.safetensors: is a file");
    assert!(!d.join("x").exists());
    // The rest of the run.
    let o = anaglyph(&["train", "--resume", "ck", "--out", "seg.safetensors"], d);
    assert!(o.status.success(), "{}", stderr(&o));
    let (once, once_meta) = tensors_and_metadata(&d.join("once.safetensors"));
    let (segmented, meta) = tensors_and_metadata(&d.join("seg.safetensors"));
    assert!(once == segmented, "the weights differ");
    assert_eq!(meta["steps"], once_meta["steps"]);
    // The recorded command makes the same weights at once.
    let command = meta["command"].as_str().unwrap();
    assert!(
        command.starts_with("anaglyph train --arch fast --steps 4 --seed 1 --batch 4 --scenes 1")
            && !command.contains("--checkpoint"),
        "{command}"
    );
}

#[test]
fn feature_maps_make_a_narrower_network_and_a_resumed_run_keeps_its_width() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let first = [
        &[
            "train",
            "--feature-maps",
            "8",
            "--out",
            "narrow.safetensors",
            "--checkpoint",
            "ck",
            "--stop-at-step",
            "2",
        ][..],
        &TINY,
    ]
    .concat();
    let o = anaglyph(&first, d);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = anaglyph(
        &[
            "train",
            "--resume",
            "ck",
            "--out",
            "x",
            "--feature-maps",
            "16",
        ],
        d,
    );
    assert_clean_failure(&o, "--feature-maps 16: the run checkpointed in ck has 8");
    let o = anaglyph(&["train", "--out", "x", "--feature-maps", "0"], d);
    assert_clean_failure(&o, "--feature-maps");
    // Its own width and `--arch` agree with the checkpoint when given again.
    let o = anaglyph(
        &[
            "train",
            "--resume",
            "ck",
            "--out",
            "narrow.safetensors",
            "--arch",
            "fast",
            "--feature-maps",
            "8",
        ],
        d,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let (_, header) = tensors_and_header(&d.join("narrow.safetensors"));
    for i in 0..4 {
        let inputs = if i == 0 { 1 } else { 8 };
        assert_eq!(
            header[format!("conv{i}.weight")]["shape"],
            serde_json::json!([8, inputs, 3, 3]),
            "conv{i}"
        );
    }
    let command = header["__metadata__"]["command"].as_str().unwrap();
    assert!(command.contains(" --feature-maps 8 "), "{command}");
}

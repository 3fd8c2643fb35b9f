//! Every parser a user feeds, as a fuzz target: its name, the seed inputs it starts from
//! (written by anaglyph's own writers or taken from the shipped data) and how one input
//! is run (through the same entry point the commands use). A target may return an
//! error; it may not panic, hang or allocate far beyond its input.

use anaglyph_core::image::Image;
use anaglyph_core::io::{
    npy_header, open_npy_rows, read_envi, read_linear_image, read_npy_bool, read_npy_float,
    read_pfm, write_envi, write_npy_f32, write_npy_f64, write_pfm, write_png16, EnviCube,
};
use anaglyph_core::rectify::{parse_json, parse_yaml, CameraModel};
use anaglyph_core::rig::{Rig, RigFile, SensingMatrix, PAPER_RIG_FILTERS};
use anaglyph_core::scene::{Scene, SceneFile, PRESETS};
use anaglyph_core::spectrum::ResponseCurve;
use anaglyph_core::stereo::{MatchingNetwork, DEFAULT_FAST_WEIGHTS};
use std::path::Path;

/// One parser under fuzzing.
pub struct Target {
    pub name: &'static str,
    pub seeds: fn(&Path) -> Vec<Vec<u8>>,
    /// Runs one input; `scratch` is a folder of its own for file-based parsers.
    pub run: fn(&[u8], &Path),
}

pub const TARGETS: [Target; 9] = [
    Target {
        name: "rig_toml",
        seeds: rig_seeds,
        run: run_rig,
    },
    Target {
        name: "scene_toml",
        seeds: scene_seeds,
        run: run_scene,
    },
    Target {
        name: "csv_curve",
        seeds: csv_seeds,
        run: run_csv,
    },
    Target {
        name: "envi",
        seeds: envi_seeds,
        run: run_envi,
    },
    Target {
        name: "pfm",
        seeds: pfm_seeds,
        run: run_pfm,
    },
    Target {
        name: "npy",
        seeds: npy_seeds,
        run: run_npy,
    },
    Target {
        name: "file_storage",
        seeds: file_storage_seeds,
        run: run_file_storage,
    },
    Target {
        name: "safetensors",
        seeds: safetensors_seeds,
        run: run_safetensors,
    },
    Target {
        name: "capture_image",
        seeds: image_seeds,
        run: run_image,
    },
];

fn text(input: &[u8]) -> String {
    String::from_utf8_lossy(input).into_owned()
}

fn rig_seeds(_: &Path) -> Vec<Vec<u8>> {
    let file = Rig::paper_rig_file(&PAPER_RIG_FILTERS);
    vec![file.to_toml_string().unwrap().into_bytes()]
}

fn run_rig(input: &[u8], scratch: &Path) {
    if let Ok(file) = RigFile::from_toml_str(&text(input), "fuzz rig") {
        if let Ok(rig) = Rig::from_file(file, scratch.to_path_buf()) {
            let _ = SensingMatrix::of_rig(&rig);
        }
    }
}

fn scene_seeds(_: &Path) -> Vec<Vec<u8>> {
    PRESETS
        .iter()
        .map(|(name, _)| {
            let scene = SceneFile::preset(name).unwrap();
            scene.to_toml_string().unwrap().into_bytes()
        })
        .collect()
}

fn run_scene(input: &[u8], scratch: &Path) {
    if let Ok(file) = SceneFile::from_toml_str(&text(input), "fuzz scene") {
        let _ = Scene::resolve(file, scratch);
    }
}

fn csv_seeds(_: &Path) -> Vec<Vec<u8>> {
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data");
    ["filters", "spectra/sensors", "spectra/illuminants"]
        .iter()
        .filter_map(|dir| std::fs::read_dir(data.join(dir)).ok())
        .flat_map(|entries| entries.flatten())
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "csv"))
        .filter_map(|p| std::fs::read(p).ok())
        .filter(|bytes| bytes.len() < 64 << 10)
        .take(12)
        .collect()
}

fn run_csv(input: &[u8], _: &Path) {
    if let Ok(curve) = ResponseCurve::from_csv_str("fuzz", &text(input)) {
        let _ = curve.check_covers(400.0, 700.0);
    }
}

/// ENVI inputs are a header and its data file joined by this marker.
const ENVI_SPLIT: &[u8] = b"\0--data--\0";

fn envi_seeds(scratch: &Path) -> Vec<Vec<u8>> {
    let path = scratch.join("seed.hdr");
    let cube = EnviCube {
        image: Image::new(3, 2, 4, (0..24).map(|v| v as f32 * 0.1).collect()).unwrap(),
        wavelengths: Some(vec![450.0, 500.0, 550.0, 600.0]),
        band_names: Some(["a", "b", "c", "d"].map(String::from).to_vec()),
    };
    write_envi(&path, &cube, "fuzz seed").unwrap();
    let mut seed = std::fs::read(&path).unwrap();
    seed.extend_from_slice(ENVI_SPLIT);
    seed.extend(std::fs::read(path.with_extension("img")).unwrap());
    let interleaved = String::from_utf8_lossy(&seed)
        .replace("bip", "bsq")
        .into_bytes();
    vec![seed, interleaved]
}

fn run_envi(input: &[u8], scratch: &Path) {
    let split = input
        .windows(ENVI_SPLIT.len())
        .position(|w| w == ENVI_SPLIT);
    let (header, data) = match split {
        Some(at) => (&input[..at], &input[at + ENVI_SPLIT.len()..]),
        None => (input, &[][..]),
    };
    let path = scratch.join("cube.hdr");
    std::fs::write(&path, header).unwrap();
    std::fs::write(path.with_extension("img"), data).unwrap();
    let _ = read_envi(&path);
}

fn pfm_seeds(scratch: &Path) -> Vec<Vec<u8>> {
    [1, 3]
        .iter()
        .map(|&channels| {
            let path = scratch.join("seed.pfm");
            let values = (0..4 * 3 * channels).map(|v| v as f32).collect();
            write_pfm(&path, &Image::new(4, 3, channels, values).unwrap()).unwrap();
            std::fs::read(&path).unwrap()
        })
        .collect()
}

fn run_pfm(input: &[u8], scratch: &Path) {
    let path = scratch.join("input.pfm");
    std::fs::write(&path, input).unwrap();
    let _ = read_pfm(&path);
}

fn npy_seeds(scratch: &Path) -> Vec<Vec<u8>> {
    let path = scratch.join("seed.npy");
    write_npy_f32(&path, &[2, 3], vec![0.5; 6]).unwrap();
    let f32s = std::fs::read(&path).unwrap();
    write_npy_f64(&path, &[3, 2], vec![0.25; 6]).unwrap();
    let f64s = std::fs::read(&path).unwrap();
    let mut mask = npy_header("|b1", &[2, 2]);
    mask.extend_from_slice(&[1, 0, 0, 1]);
    vec![f32s, f64s, mask]
}

fn run_npy(input: &[u8], scratch: &Path) {
    let path = scratch.join("input.npy");
    std::fs::write(&path, input).unwrap();
    let _ = read_npy_float(&path);
    let _ = read_npy_bool(&path);
    if let Ok(Some(mut rows)) = open_npy_rows(&path) {
        let mut buffer = vec![0f64; 64];
        if rows.stored_as_f32 {
            let mut buffer = vec![0f32; 64];
            while let Ok(n) = rows.read_rows(&mut buffer) {
                if n == 0 {
                    break;
                }
            }
        } else {
            while let Ok(n) = rows.read_rows(&mut buffer) {
                if n == 0 {
                    break;
                }
            }
        }
    }
}

fn file_storage_seeds(_: &Path) -> Vec<Vec<u8>> {
    let json = r#"{"camera_matrix": {"type_id": "opencv-matrix", "rows": 3, "cols": 3, "dt": "d",
        "data": [1800, 0, 320, 0, 1800, 240, 0, 0, 1]},
     "distortion_coefficients": {"type_id": "opencv-matrix", "rows": 1, "cols": 5, "dt": "d",
        "data": [0.01, -0.02, 0, 0, 0]},
     "rotation_matrix": {"type_id": "opencv-matrix", "rows": 3, "cols": 3, "dt": "d",
        "data": [1, 0, 0, 0, 1, 0, 0, 0, 1]},
     "translation_vector": {"type_id": "opencv-matrix", "rows": 3, "cols": 1, "dt": "d",
        "data": [-30, 0, 0]}, "image_width": 640, "image_height": 480}"#;
    let yaml = "%YAML:1.0\n---\nimage_width: 640\nimage_height: 480\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 1800., 0., 320., 0., 1800., 240., 0., 0., 1. ]\nrvec: !!opencv-matrix\n   rows: 3\n   cols: 1\n   dt: d\n   data: [ 0.01, 0., 0. ]\ntvec: !!opencv-matrix\n   rows: 3\n   cols: 1\n   dt: d\n   data: [ -30., 0., 0. ]\n";
    vec![json.as_bytes().to_vec(), yaml.as_bytes().to_vec()]
}

fn run_file_storage(input: &[u8], _: &Path) {
    let text = text(input);
    for storage in [parse_json(&text, "fuzz"), parse_yaml(&text, "fuzz")]
        .into_iter()
        .flatten()
    {
        let _ = CameraModel::from_file_storage(&storage, "fuzz");
    }
}

fn safetensors_seeds(_: &Path) -> Vec<Vec<u8>> {
    vec![DEFAULT_FAST_WEIGHTS.to_vec()]
}

fn run_safetensors(input: &[u8], _: &Path) {
    let _ = MatchingNetwork::from_safetensors(input, "fuzz");
}

fn image_seeds(scratch: &Path) -> Vec<Vec<u8>> {
    let path = scratch.join("seed.png");
    let mut seeds = Vec::new();
    for channels in [1, 3] {
        let values = (0..6 * 4 * channels).map(|v| v as f32 / 72.0).collect();
        write_png16(&path, &Image::new(6, 4, channels, values).unwrap()).unwrap();
        seeds.push(std::fs::read(&path).unwrap());
    }
    let tiff = scratch.join("seed.tif");
    let pixels: Vec<u8> = (0..6 * 4 * 3).map(|v| v as u8).collect();
    image::save_buffer(&tiff, &pixels, 6, 4, image::ExtendedColorType::Rgb8).unwrap();
    seeds.push(std::fs::read(&tiff).unwrap());
    seeds
}

fn run_image(input: &[u8], scratch: &Path) {
    let path = scratch.join("input.img");
    std::fs::write(&path, input).unwrap();
    let _ = read_linear_image(&path);
}

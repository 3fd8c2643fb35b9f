//! Frame sequences in a capture folder, as camera arrays film them:
//!
//! ```text
//! frame-major                     camera-major (as published array videos are stored)
//! captures/0000/r0c0.png          captures/r0c0/frame_0.png
//! captures/0000/r0c1.png          captures/r0c0/frame_1.png
//! captures/0001/r0c0.png          captures/r0c1/frame_0.png
//! ...                             ...
//! ```
//!
//! A frame's number is the last run of digits in its folder's (frame-major) or file's
//! (camera-major) name, and frames are taken in numerical order (`frame_10` after
//! `frame_9`). Every frame must have a capture of every camera; a gap in the numbering is
//! reported, not filled. [`FrameSequence::discover`] finds every file before anything is
//! read, so a missing capture is an error before any work.

use super::inputs::EXTENSIONS;
use crate::rig::Rig;
use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// How a capture folder holds a sequence.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FrameLayout {
    /// A folder per frame holding a capture per camera: `captures/<frame>/<camera>.png`.
    FrameMajor,
    /// A folder per camera holding a capture per frame: `captures/<camera>/<frame>.png`.
    CameraMajor,
}

crate::choice::named_choices!(FrameLayout, "frame layout" {
    FrameMajor = "frame-major" "A folder per frame: captures/<frame>/<camera>.png.",
    CameraMajor = "camera-major" "A folder per camera: captures/<camera>/<frame>.png.",
});

/// The frames of a run: every frame (`All`) or frame numbers `first` to `last` inclusive.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Default)]
pub enum FrameRange {
    #[default]
    All,
    Span {
        first: i64,
        last: i64,
    },
}

impl std::str::FromStr for FrameRange {
    type Err = Error;

    /// `all`, `A:B` (frame numbers A to B, both included) or `A` (one frame).
    fn from_str(text: &str) -> Result<Self> {
        let bad = || {
            Error::setting(
                "frames",
                format!("'{text}'"),
                "all, A:B (frame numbers A to B, both included) or one frame number",
            )
        };
        let text = text.trim();
        if text == "all" {
            return Ok(FrameRange::All);
        }
        let (first, last) = text.split_once(':').unwrap_or((text, text));
        let parse = |v: &str| v.trim().parse::<i64>().map_err(|_| bad());
        let (first, last) = (parse(first)?, parse(last)?);
        if first > last {
            return Err(bad());
        }
        Ok(FrameRange::Span { first, last })
    }
}

/// One frame's captures, in rig order.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameFiles {
    pub number: i64,
    pub captures: Vec<PathBuf>,
    /// Each camera's dark frame for this frame's capture, in rig order (None: the rig's
    /// `dark` or `black_level`, which also serve the white boards).
    pub darks: Option<Vec<PathBuf>>,
}

/// The frames found in a capture folder, in numerical order.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameSequence {
    pub layout: FrameLayout,
    pub frames: Vec<FrameFiles>,
}

/// The last run of ASCII digits in `name`, as a number.
fn frame_number(name: &str) -> Option<i64> {
    let end = name.rfind(|c: char| c.is_ascii_digit())? + 1;
    let start = name[..end]
        .rfind(|c: char| !c.is_ascii_digit())
        .map_or(0, |i| i + 1);
    name[start..end].parse().ok()
}

fn entries(dir: &Path) -> Result<Vec<(String, PathBuf)>> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))? {
        let entry = entry.map_err(|e| Error::io(dir, e))?;
        let name = entry.file_name().to_string_lossy().into_owned();
        if !name.starts_with('.') {
            out.push((name, entry.path()));
        }
    }
    out.sort();
    Ok(out)
}

/// Numbered entries of `dir` that `keep` accepts, by number; two with one number are an
/// error naming both.
fn numbered(
    dir: &Path,
    keep: impl Fn(&Path) -> bool,
    what: &str,
) -> Result<BTreeMap<i64, PathBuf>> {
    let mut by_number = BTreeMap::new();
    for (name, path) in entries(dir)? {
        if !keep(&path) {
            continue;
        }
        let stem = Path::new(&name)
            .file_stem()
            .map_or(name.clone(), |s| s.to_string_lossy().into_owned());
        let Some(number) = frame_number(&stem) else {
            continue;
        };
        if let Some(other) = by_number.insert(number, path.clone()) {
            return Err(Error::captures(
                format!("{what} {number}"),
                format!("both {} and {}", other.display(), path.display()),
                "one per frame number",
            ));
        }
    }
    Ok(by_number)
}

fn is_image(path: &Path) -> bool {
    path.is_file()
        && path
            .extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
}

impl FrameSequence {
    /// The frames in `dir` for `rig`'s cameras, in `layout` (None: camera-major when `dir`
    /// has a folder for every camera, else frame-major), restricted to `range`. Every
    /// capture is found (not read) here.
    pub fn discover(
        rig: &Rig,
        dir: &Path,
        layout: Option<FrameLayout>,
        range: FrameRange,
    ) -> Result<Self> {
        if !dir.is_dir() {
            return Err(Error::MissingFile {
                path: dir.to_path_buf(),
                what: "no capture folder of frames".into(),
            });
        }
        let cameras: Vec<&str> = rig.cameras.iter().map(|c| c.name.as_str()).collect();
        let layout = layout.unwrap_or_else(|| {
            if cameras.iter().all(|c| dir.join(c).is_dir()) {
                FrameLayout::CameraMajor
            } else {
                FrameLayout::FrameMajor
            }
        });
        // Only the frames asked for must be complete.
        let wanted = |n: &i64| match range {
            FrameRange::All => true,
            FrameRange::Span { first, last } => (first..=last).contains(n),
        };
        let mut available = Vec::new();
        let frames = match layout {
            FrameLayout::FrameMajor => {
                let folders = numbered(dir, Path::is_dir, "frame folder")?;
                available.extend(folders.keys().copied());
                let mut frames = Vec::with_capacity(folders.len());
                for (number, folder) in folders.into_iter().filter(|(n, _)| wanted(n)) {
                    let captures = cameras
                        .iter()
                        .map(|c| {
                            super::inputs::find_in(&folder, c, &EXTENSIONS, "capture")
                                .map_err(|e| frame_error(number, e))
                        })
                        .collect::<Result<_>>()?;
                    frames.push(FrameFiles {
                        number,
                        captures,
                        darks: None,
                    });
                }
                frames
            }
            FrameLayout::CameraMajor => {
                let per_camera = cameras
                    .iter()
                    .map(|c| {
                        let folder = dir.join(c);
                        if !folder.is_dir() {
                            return Err(Error::MissingFile {
                                path: folder,
                                what: format!("no folder of camera {c}'s frames"),
                            });
                        }
                        numbered(&folder, is_image, &format!("camera {c}'s frame"))
                    })
                    .collect::<Result<Vec<_>>>()?;
                available.extend(per_camera[0].keys().copied());
                let numbers: Vec<i64> = per_camera[0].keys().copied().filter(wanted).collect();
                for (c, files) in cameras.iter().zip(&per_camera) {
                    let theirs: Vec<i64> = files.keys().copied().filter(wanted).collect();
                    if theirs != numbers {
                        let missing = numbers
                            .iter()
                            .find(|n| !files.contains_key(n))
                            .map(|n| (n, c, cameras[0]))
                            .or_else(|| {
                                theirs
                                    .iter()
                                    .find(|n| !per_camera[0].contains_key(n))
                                    .map(|n| (n, &cameras[0], *c))
                            });
                        if let Some((n, without, with)) = missing {
                            return Err(Error::captures(
                                format!("frame {n}"),
                                format!(
                                    "no capture of camera {without} in {}",
                                    dir.join(without).display()
                                ),
                                format!("a capture of every camera (camera {with} has one)"),
                            ));
                        }
                    }
                }
                numbers
                    .into_iter()
                    .map(|number| FrameFiles {
                        number,
                        captures: per_camera.iter().map(|f| f[&number].clone()).collect(),
                        darks: None,
                    })
                    .collect()
            }
        };
        if available.is_empty() {
            return Err(Error::captures(
                dir.display().to_string(),
                format!("no numbered frames ({})", layout.name_with_help()),
                "frames as the layout says (a number in each frame's name)",
            ));
        }
        if let (true, FrameRange::Span { first, last }) = (frames.is_empty(), range) {
            return Err(Error::NotFound {
                what: "frames".into(),
                name: format!("{first}:{last}"),
                available: summarise_numbers(&available),
            });
        }
        Ok(FrameSequence { layout, frames })
    }

    /// Gives every frame's captures dark frames from `dir`: one per camera for the whole
    /// sequence (`dir/<camera>.png|tif`), or a dark per frame and camera laid out as a
    /// sequence of captures is (frame-major or camera-major, found by
    /// [`FrameSequence::discover`]), where every frame of this sequence must have its own.
    /// The white boards keep the rig's dark frames (they were captured apart).
    pub fn with_darks(mut self, rig: &Rig, dir: &Path) -> Result<Self> {
        if !dir.is_dir() {
            return Err(Error::MissingFile {
                path: dir.to_path_buf(),
                what: "no folder of dark frames".into(),
            });
        }
        let flat: Option<Vec<PathBuf>> = rig
            .cameras
            .iter()
            .map(|c| super::inputs::find_in(dir, &c.name, &EXTENSIONS, "dark frame").ok())
            .collect();
        if let Some(flat) = flat {
            for frame in &mut self.frames {
                frame.darks = Some(flat.clone());
            }
            return Ok(self);
        }
        let darks = FrameSequence::discover(rig, dir, None, FrameRange::All).map_err(|e| {
            Error::captures(
                format!("dark frames in {}", dir.display()),
                e.to_string(),
                "a dark frame per camera (<camera>.png) for the sequence, or a dark per frame                  and camera laid out as the captures",
            )
        })?;
        let by_number: BTreeMap<i64, Vec<PathBuf>> = darks
            .frames
            .into_iter()
            .map(|f| (f.number, f.captures))
            .collect();
        for frame in &mut self.frames {
            let Some(files) = by_number.get(&frame.number) else {
                return Err(Error::captures(
                    format!("frame {}", frame.number),
                    format!(
                        "no dark frames in {} (it has frames {})",
                        dir.display(),
                        summarise_numbers(&by_number.keys().copied().collect::<Vec<_>>())
                    ),
                    "a dark frame of every camera for every frame reconstructed",
                ));
            };
            frame.darks = Some(files.clone());
        }
        Ok(self)
    }

    pub fn numbers(&self) -> Vec<i64> {
        self.frames.iter().map(|f| f.number).collect()
    }

    /// The gaps in the numbering, as (first missing, last missing).
    pub fn gaps(&self) -> Vec<(i64, i64)> {
        self.frames
            .windows(2)
            .filter(|w| w[1].number > w[0].number + 1)
            .map(|w| (w[0].number + 1, w[1].number - 1))
            .collect()
    }
}

impl FrameLayout {
    fn name_with_help(self) -> String {
        use crate::choice::Choice;
        format!("{}: {}", self.name(), self.help())
    }
}

fn frame_error(number: i64, e: Error) -> Error {
    match e {
        Error::MissingFile { path, what } => Error::MissingFile {
            path,
            what: format!("frame {number}: {what}"),
        },
        other => other,
    }
}

/// `0 to 29` or `0, 2, 5`.
pub(crate) fn summarise_numbers(numbers: &[i64]) -> String {
    match (numbers.first(), numbers.last()) {
        (Some(a), Some(b)) if numbers.windows(2).all(|w| w[1] == w[0] + 1) => {
            format!("{a} to {b}")
        }
        _ => numbers
            .iter()
            .map(i64::to_string)
            .collect::<Vec<_>>()
            .join(", "),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rig::{Rig, PAPER_RIG_FILTERS};

    fn touch(path: &Path) {
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(path, "").unwrap();
    }

    fn rig() -> Rig {
        Rig::from_file(Rig::paper_rig_file(&PAPER_RIG_FILTERS), ".".into()).unwrap()
    }

    #[test]
    fn numbers_are_the_last_run_of_digits() {
        assert_eq!(frame_number("frame_0012"), Some(12));
        assert_eq!(frame_number("7"), Some(7));
        assert_eq!(frame_number("take2_frame_9"), Some(9));
        assert_eq!(frame_number("r0c1"), Some(1));
        assert_eq!(frame_number("notes"), None);
    }

    #[test]
    fn both_layouts_are_found_in_numerical_order_with_their_gaps() {
        let rig = rig();
        let dir = tempfile::tempdir().unwrap();
        let frame_major = dir.path().join("fm");
        for n in [2, 10, 9] {
            for c in &rig.cameras {
                touch(&frame_major.join(format!("frame_{n}/{}.png", c.name)));
            }
        }
        let seq = FrameSequence::discover(&rig, &frame_major, None, FrameRange::All).unwrap();
        assert_eq!(seq.layout, FrameLayout::FrameMajor);
        assert_eq!(seq.numbers(), vec![2, 9, 10]);
        assert_eq!(seq.gaps(), vec![(3, 8)]);
        assert!(seq.frames[1].captures[7].ends_with("frame_9/r1c3.png"));
        let camera_major = dir.path().join("cm");
        for n in 0..3 {
            for c in &rig.cameras {
                touch(&camera_major.join(format!("{}/{n:04}.tif", c.name)));
            }
        }
        let seq =
            FrameSequence::discover(&rig, &camera_major, None, "1:2".parse().unwrap()).unwrap();
        assert_eq!(seq.layout, FrameLayout::CameraMajor);
        assert_eq!(seq.numbers(), vec![1, 2]);
        assert!(seq.gaps().is_empty());
    }

    #[test]
    fn a_missing_capture_or_a_number_twice_is_named_before_any_work() {
        let rig = rig();
        let dir = tempfile::tempdir().unwrap();
        let cm = dir.path().join("cm");
        for n in 0..3 {
            for c in &rig.cameras {
                if !(n == 1 && c.name == "r0c2") {
                    touch(&cm.join(format!("{}/{n}.png", c.name)));
                }
            }
        }
        let err = FrameSequence::discover(&rig, &cm, None, FrameRange::All)
            .unwrap_err()
            .to_string();
        assert!(err.contains("frame 1") && err.contains("r0c2"), "{err}");
        let fm = dir.path().join("fm");
        for c in &rig.cameras {
            touch(&fm.join(format!("0/{}.png", c.name)));
            if c.name != "r1c1" {
                touch(&fm.join(format!("1/{}.png", c.name)));
            }
        }
        let err =
            FrameSequence::discover(&rig, &fm, Some(FrameLayout::FrameMajor), FrameRange::All)
                .unwrap_err()
                .to_string();
        assert!(err.contains("frame 1") && err.contains("r1c1"), "{err}");
        touch(&fm.join("01/r0c0.png"));
        let err = FrameSequence::discover(&rig, &fm, None, FrameRange::All)
            .unwrap_err()
            .to_string();
        assert!(err.contains("frame folder 1"), "{err}");
        let err = FrameSequence::discover(&rig, &cm, None, "5:9".parse().unwrap());
        assert!(err.is_err());
        assert!("3:1".parse::<FrameRange>().is_err());
        assert!("a:b".parse::<FrameRange>().is_err());
    }
}

//! Light fields of frame sequences as one Zarr v3 store (written with `zarrs`), which
//! xarray, Dask and napari open directly.
//!
//! ```text
//! run.zarr/
//!   zarr.json                 root group: attributes (rig, settings, units) and the
//!                             consolidated metadata of every array
//!   reflectance/              float32 (frame, view, y, x, wavelength)   with cubes
//!   registered/               float32 (frame, view, y, x, channel)      with registered stacks
//!   disparity/                float32 (frame, view, y, x), per column step, NaN unknown
//!   visibility/               uint8   (frame, view, y, x): cameras that measured the pixel
//!   frame_done/               uint8   (frame,): 1 once every array holds the frame
//!   frame_seconds/            float64 (frame,): the frame's reconstruction time
//!   frame, view, wavelength, channel   1-D coordinates (int64, string, float64 nm, string)
//! ```
//!
//! Every per-pixel array holds one object per frame and view, so frames are written
//! independently, by one process or by many: a shard of zstd-compressed inner chunks that
//! tile it (about 200 pixels a side; crc32c-checked index) where a side is longer than
//! 512 px, else one zstd-compressed chunk (such a shard would hold one inner chunk, and
//! its encoding copies a 320×240 frame's cubes twice more: 72 instead of 122 ms to write
//! the paper rig's eight, `cargo bench -p anaglyph-core --bench store`).
//! [`LightFieldStore::create`] writes the template (every array's metadata and the
//! coordinates) in a hidden sibling folder and renames it into place, so a store is never
//! half made; a frame is marked done in `frame_done` only after its objects are written,
//! so a rerun writes exactly the frames not marked. A store that holds another run (another rig, settings, frames or views) is
//! refused unless the caller asks to overwrite it; a folder that is not an anaglyph store
//! is never replaced.

use super::MAX_RASTER_VALUES;
use crate::reconstruct::{LightField, ReconstructedView};
use crate::{Error, Result};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use zarrs::array::{codec, data_type, Array, ArrayBuilder, BytesToBytesCodecTraits};
use zarrs::filesystem::FilesystemStore;
use zarrs::group::GroupBuilder;

/// The root attribute that marks a store as anaglyph's and holds its [`StoreLayout`].
const MARK: &str = "anaglyph";
/// Sides up to which a frame and view is one chunk along that side; beyond, inner chunks
/// of a divisor of the side between [`MIN_INNER_PX`] and [`MAX_INNER_PX`] pixels in a
/// shard (zarr requires inner chunks that tile the shard).
const WHOLE_SIDE_PX: usize = 512;
const MIN_INNER_PX: usize = 64;
const MAX_INNER_PX: usize = 256;
/// zstd level of the inner chunks: a fast negative level, since writing is on every
/// frame's path (level 1 took 4.9 % of a reused frame, -3 takes 4.5 % for a tenth more
/// bytes: docs/performance.md).
const ZSTD_LEVEL: i32 = -3;

/// What a store holds: its frames, views, raster size and products, and the run that
/// made it (`run`: the rig and the settings, compared when a store is reopened).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StoreLayout {
    /// Frame numbers, in the order of the `frame` axis.
    pub frames: Vec<i64>,
    /// View (camera) names, in the order of the `view` axis.
    pub views: Vec<String>,
    pub width: usize,
    pub height: usize,
    /// Band centres (nm) of the reflectance cubes; empty without cubes.
    pub wavelengths: Vec<f64>,
    /// Channel labels of the registered stacks (`r0c1:R`); empty without stacks.
    pub channels: Vec<String>,
    /// What made the store: compared, whole, when a store is reopened.
    pub run: serde_json::Value,
}

impl StoreLayout {
    fn cubes(&self) -> bool {
        !self.wavelengths.is_empty()
    }

    fn registered(&self) -> bool {
        !self.channels.is_empty()
    }

    /// Checks sizes before anything is written.
    fn check(&self) -> Result<()> {
        let values = (self.width as u64)
            .saturating_mul(self.height as u64)
            .saturating_mul(self.wavelengths.len().max(self.channels.len()).max(1) as u64);
        if self.frames.is_empty() || self.views.is_empty() || self.width == 0 || self.height == 0 {
            return Err(Error::setting(
                "Zarr store",
                format!(
                    "{} frames, {} views of {}x{} px",
                    self.frames.len(),
                    self.views.len(),
                    self.width,
                    self.height
                ),
                "at least one frame and one view of at least 1x1 px",
            ));
        }
        if values > MAX_RASTER_VALUES {
            return Err(Error::TooLarge {
                op: "Zarr store".into(),
                what: "values per frame and view".into(),
                size: values,
                limit: MAX_RASTER_VALUES,
            });
        }
        let mut sorted = self.frames.clone();
        sorted.sort_unstable();
        sorted.dedup();
        if sorted.len() != self.frames.len() {
            return Err(Error::setting(
                "Zarr store frames",
                "a frame number given twice",
                "distinct frame numbers",
            ));
        }
        Ok(())
    }
}

/// A light-field store open for writing frames.
#[derive(Clone)]
pub struct LightFieldStore {
    path: PathBuf,
    store: Arc<FilesystemStore>,
    layout: StoreLayout,
}

impl std::fmt::Debug for LightFieldStore {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LightFieldStore")
            .field("path", &self.path)
            .field("layout", &self.layout)
            .finish()
    }
}

fn zarr_error(path: &Path, e: impl ToString) -> Error {
    Error::output(path.display().to_string(), e)
}

/// The layout recorded in the store at `path`, if it is an anaglyph store.
fn recorded_layout(path: &Path) -> Result<Option<StoreLayout>> {
    let root = path.join("zarr.json");
    let text = match std::fs::read_to_string(&root) {
        Ok(text) => text,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(Error::io(&root, e)),
    };
    let json: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| Error::decode(&root, e))?;
    match json.pointer(&format!("/attributes/{MARK}/layout")) {
        Some(layout) => serde_json::from_value(layout.clone())
            .map(Some)
            .map_err(|e| Error::decode(&root, e)),
        None => Ok(None),
    }
}

impl LightFieldStore {
    /// Opens the store at `path` for `layout`, making it first where there is none.
    ///
    /// - No folder, or an empty one: the template is made (see the module docs).
    /// - An anaglyph store of the same layout: opened as it is (a rerun completes it), or
    ///   replaced with `overwrite`.
    /// - An anaglyph store of another layout: refused, or replaced with `overwrite`.
    /// - A file, or a folder that is not an anaglyph store: refused, always.
    pub fn create(path: &Path, layout: StoreLayout, overwrite: bool) -> Result<Self> {
        layout.check()?;
        if path.is_file() {
            return Err(Error::output_conflict(
                path.display().to_string(),
                "a file",
                "a Zarr store (a folder) or a path that does not exist",
            ));
        }
        let existing = if path.is_dir() {
            match recorded_layout(path)? {
                Some(recorded) => Some(recorded),
                None => {
                    let empty = std::fs::read_dir(path)
                        .map_err(|e| Error::io(path, e))?
                        .next()
                        .is_none();
                    if !empty {
                        return Err(Error::output_conflict(
                            path.display().to_string(),
                            "a folder that is not an anaglyph Zarr store",
                            "a new or empty folder, or a store anaglyph wrote (it is never \
                             replaced, even with overwrite)",
                        ));
                    }
                    None
                }
            }
        } else {
            None
        };
        match existing {
            Some(recorded) if recorded == layout && !overwrite => return Self::open(path),
            Some(recorded) if !overwrite => {
                return Err(Error::output_conflict(
                    path.display().to_string(),
                    format!(
                        "a store of another run ({} frames, views {}, {}x{} px{})",
                        recorded.frames.len(),
                        recorded.views.join(", "),
                        recorded.width,
                        recorded.height,
                        if recorded.run != layout.run {
                            ", another rig or settings"
                        } else {
                            ""
                        }
                    ),
                    "a new path, or overwrite to replace it",
                ));
            }
            _ => {}
        }
        let parent = match path.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        let name = path.file_name().ok_or_else(|| {
            Error::output_conflict(
                path.display().to_string(),
                "a path without a folder name",
                "the path of a Zarr store, e.g. run.zarr",
            )
        })?;
        let staging = parent.join(format!(
            ".{}.partial-{}",
            name.to_string_lossy(),
            std::process::id()
        ));
        // Errors name the store asked for, not the hidden staging folder beside it.
        if staging.exists() {
            std::fs::remove_dir_all(&staging).map_err(|e| Error::io(path, e))?;
        }
        std::fs::create_dir_all(&staging).map_err(|e| Error::io(path, e))?;
        if let Err(e) = write_template(&staging, &layout) {
            let _ = std::fs::remove_dir_all(&staging);
            return Err(e);
        }
        // Into place: an existing store (or empty folder) is moved aside first and removed
        // only once the new one stands.
        let aside = parent.join(format!(
            ".{}.replaced-{}",
            name.to_string_lossy(),
            std::process::id()
        ));
        let had_one = path.exists();
        if had_one {
            std::fs::rename(path, &aside).map_err(|e| Error::io(path, e))?;
        }
        if let Err(e) = std::fs::rename(&staging, path) {
            if had_one {
                let _ = std::fs::rename(&aside, path);
            }
            let _ = std::fs::remove_dir_all(&staging);
            return Err(Error::io(path, e));
        }
        if had_one {
            std::fs::remove_dir_all(&aside).map_err(|e| Error::io(&aside, e))?;
        }
        Self::open(path)
    }

    /// Opens an anaglyph store (made by [`LightFieldStore::create`]) to write frames into.
    pub fn open(path: &Path) -> Result<Self> {
        let layout = recorded_layout(path)?.ok_or_else(|| {
            Error::output_conflict(
                path.display().to_string(),
                "no anaglyph Zarr store",
                "a store made by anaglyph (its zarr.json names the run)",
            )
        })?;
        let store = Arc::new(FilesystemStore::new(path).map_err(|e| zarr_error(path, e))?);
        Ok(LightFieldStore {
            path: path.to_path_buf(),
            store,
            layout,
        })
    }

    pub fn layout(&self) -> &StoreLayout {
        &self.layout
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    fn array(&self, name: &str) -> Result<Array<FilesystemStore>> {
        Array::open(self.store.clone(), &format!("/{name}")).map_err(|e| zarr_error(&self.path, e))
    }

    /// Per frame (in layout order): whether it is written.
    pub fn frames_done(&self) -> Result<Vec<bool>> {
        let done = self.array("frame_done")?;
        let values: Vec<u8> = done
            .retrieve_array_subset(&done.subset_all())
            .map_err(|e| zarr_error(&self.path, e))?;
        Ok(values.into_iter().map(|v| v == 1).collect())
    }

    /// The position of frame number `frame` on the `frame` axis.
    pub fn frame_index(&self, frame: i64) -> Result<usize> {
        self.layout
            .frames
            .iter()
            .position(|&f| f == frame)
            .ok_or_else(|| Error::NotFound {
                what: "frame in the store".into(),
                name: frame.to_string(),
                available: crate::reconstruct::summarise_numbers(&self.layout.frames),
            })
    }

    /// Writes frame number `frame`'s light field (every view of the layout, its products)
    /// and the `seconds` its reconstruction took, and marks the frame done. Rewriting a
    /// frame writes the same objects again.
    pub fn write_frame(&self, frame: i64, field: &LightField, seconds: f64) -> Result<()> {
        self.write_frame_with(frame, field, seconds, true)
    }

    /// [`LightFieldStore::write_frame`] on a thread of its own, so that the caller computes
    /// the next frame meanwhile: the field is checked against the store here, then written
    /// one object at a time on that thread (the frame being computed keeps the cores;
    /// between its parallel stages they idle, and the write fills them). The field is held
    /// until its write ends; [`PendingWrite::wait`] gives the write's result.
    pub fn write_frame_in_background(
        &self,
        frame: i64,
        field: LightField,
        seconds: f64,
    ) -> Result<PendingWrite> {
        self.frame_views(frame, &field)?;
        let store = self.clone();
        let handle = std::thread::Builder::new()
            .name(format!("zarr frame {frame}"))
            .spawn(move || {
                let clock = std::time::Instant::now();
                store.write_frame_with(frame, &field, seconds, false)?;
                Ok(clock.elapsed().as_secs_f64())
            })
            .map_err(|e| Error::output(self.path.display().to_string(), e))?;
        Ok(PendingWrite {
            frame,
            path: self.path.clone(),
            handle: Some(handle),
        })
    }

    /// The frame's position on the `frame` axis and the field's view of every view of the
    /// layout, in layout order, once the field is checked against the store (frame, size,
    /// bands, views, registered stacks).
    fn frame_views<'a>(
        &self,
        frame: i64,
        field: &'a LightField,
    ) -> Result<(u64, Vec<&'a ReconstructedView>)> {
        let index = self.frame_index(frame)? as u64;
        let layout = &self.layout;
        if (field.width, field.height) != (layout.width, layout.height) {
            return Err(Error::Shape {
                op: format!("frame {frame} against the store"),
                got: vec![field.width, field.height],
                expected: vec![layout.width, layout.height],
            });
        }
        if layout.cubes() && field.bands != layout.wavelengths {
            return Err(Error::setting(
                format!("frame {frame}'s bands"),
                format!("{} bands", field.bands.len()),
                format!("the store's {} bands", layout.wavelengths.len()),
            ));
        }
        let views: Vec<&ReconstructedView> = layout
            .views
            .iter()
            .map(|name| {
                field
                    .views
                    .iter()
                    .find(|v| &v.name == name)
                    .ok_or_else(|| Error::NotFound {
                        what: format!("view of frame {frame}"),
                        name: name.clone(),
                        available: field
                            .views
                            .iter()
                            .map(|v| v.name.as_str())
                            .collect::<Vec<_>>()
                            .join(", "),
                    })
            })
            .collect::<Result<_>>()?;
        for view in &views {
            if layout.cubes() {
                view.cube()?;
            }
            if layout.registered() && view.registered.is_none() {
                return Err(Error::StageDependency {
                    stage: "Zarr store",
                    needs: "registered stacks",
                    why: "the store holds them; run with the registered output",
                });
            }
        }
        Ok((index, views))
    }

    /// [`LightFieldStore::write_frame`], its objects written in parallel or one at a time.
    fn write_frame_with(
        &self,
        frame: i64,
        field: &LightField,
        seconds: f64,
        parallel: bool,
    ) -> Result<()> {
        let (f, views) = self.frame_views(frame, field)?;
        let layout = &self.layout;
        // One object at a time: no codec work handed to the thread pool either.
        let options = match parallel {
            true => zarrs::array::CodecOptions::default(),
            false => zarrs::array::CodecOptions::default().with_concurrent_target(1),
        };
        let write = |array: &Array<FilesystemStore>, v: usize, data: Shard<'_>| {
            let mut indices = vec![0u64; array.dimensionality()];
            indices[0] = f;
            indices[1] = v as u64;
            match data {
                Shard::F32(values) => array.store_chunk_opt(&indices, values, &options),
                Shard::U8(values) => array.store_chunk_opt(&indices, values, &options),
            }
            .map_err(|e| zarr_error(&self.path, e))
        };
        let reflectance = layout
            .cubes()
            .then(|| self.array("reflectance"))
            .transpose()?;
        let registered = layout
            .registered()
            .then(|| self.array("registered"))
            .transpose()?;
        let disparity = self.array("disparity")?;
        let visibility = self.array("visibility")?;
        // Every object on its own (each view's arrays are separate objects).
        let mut shards: Vec<(&Array<FilesystemStore>, usize, Shard<'_>)> = Vec::new();
        for (v, view) in views.iter().enumerate() {
            if let Some(array) = &reflectance {
                shards.push((array, v, Shard::F32(&view.cube()?.data)));
            }
            if let (Some(array), Some(stack)) = (&registered, &view.registered) {
                shards.push((array, v, Shard::F32(&stack.data)));
            }
            shards.push((&disparity, v, Shard::F32(&view.disparity.data)));
            shards.push((&visibility, v, Shard::U8(&view.cameras_seeing.data)));
        }
        match parallel {
            true => shards
                .into_par_iter()
                .try_for_each(|(array, v, data)| write(array, v, data))?,
            false => shards
                .into_iter()
                .try_for_each(|(array, v, data)| write(array, v, data))?,
        }
        self.array("frame_seconds")?
            .store_chunk(&[f], &[seconds][..])
            .map_err(|e| zarr_error(&self.path, e))?;
        self.array("frame_done")?
            .store_chunk(&[f], &[1u8][..])
            .map_err(|e| zarr_error(&self.path, e))
    }
}

/// A frame being written on a thread of its own
/// ([`LightFieldStore::write_frame_in_background`]). Dropped without
/// [`PendingWrite::wait`], it still waits for the write to end (a frame is never left
/// half written by its caller's return), and only the result is lost.
#[must_use = "wait() tells whether the frame was written"]
pub struct PendingWrite {
    frame: i64,
    path: PathBuf,
    handle: Option<std::thread::JoinHandle<Result<f64>>>,
}

impl std::fmt::Debug for PendingWrite {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PendingWrite")
            .field("frame", &self.frame)
            .field("path", &self.path)
            .finish()
    }
}

impl PendingWrite {
    /// The frame number being written.
    pub fn frame(&self) -> i64 {
        self.frame
    }

    /// Waits for the write to end: the seconds it took on its thread, or its error.
    pub fn wait(mut self) -> Result<f64> {
        let handle = self
            .handle
            .take()
            .expect("a pending write is waited for once");
        match handle.join() {
            Ok(result) => result,
            Err(_) => Err(Error::output(
                self.path.display().to_string(),
                format!("the thread writing frame {} stopped", self.frame),
            )),
        }
    }
}

impl Drop for PendingWrite {
    fn drop(&mut self) {
        if let Some(handle) = self.handle.take() {
            let _ = handle.join();
        }
    }
}

/// The values of one frame and view of an array.
#[derive(Clone, Copy)]
enum Shard<'a> {
    F32(&'a [f32]),
    U8(&'a [u8]),
}

/// The inner chunks' side along an image side of `n` pixels: the whole side up to
/// [`WHOLE_SIDE_PX`], else its largest divisor in [`MIN_INNER_PX`, `MAX_INNER_PX`] (the
/// whole side when it has none).
fn inner_side(n: usize) -> usize {
    if n <= WHOLE_SIDE_PX {
        return n;
    }
    (MIN_INNER_PX..=MAX_INNER_PX)
        .rev()
        .find(|&d| n.is_multiple_of(d))
        .unwrap_or(n)
}

/// Makes every array's metadata, the coordinates and the root group (with the
/// consolidated metadata) in `dir`.
fn write_template(dir: &Path, layout: &StoreLayout) -> Result<()> {
    let store = Arc::new(FilesystemStore::new(dir).map_err(|e| zarr_error(dir, e))?);
    let err = |e: &dyn std::fmt::Display| zarr_error(dir, e.to_string());
    let (nf, nv) = (layout.frames.len() as u64, layout.views.len() as u64);
    let (h, w) = (layout.height as u64, layout.width as u64);
    let (ch, cw) = (
        inner_side(layout.height) as u64,
        inner_side(layout.width) as u64,
    );
    let compress = || -> Vec<Arc<dyn BytesToBytesCodecTraits>> {
        vec![Arc::new(codec::ZstdCodec::new(ZSTD_LEVEL, false))]
    };
    let attributes = |pairs: &[(&str, &str)]| {
        pairs
            .iter()
            .map(|(k, v)| (k.to_string(), serde_json::Value::from(*v)))
            .collect::<serde_json::Map<_, _>>()
    };
    let mut names = Vec::new();
    // The per-pixel arrays: one shard per frame and view.
    let mut raster = |name: &str, depth: Option<u64>, float: bool, attrs: &[(&str, &str)]| {
        let mut shape = vec![nf, nv, h, w];
        let mut dims = vec!["frame", "view", "y", "x"];
        if let Some(d) = depth {
            shape.push(d);
            dims.push(if name == "reflectance" {
                "wavelength"
            } else {
                "channel"
            });
        }
        let mut shard = vec![1, 1, h, w];
        let mut inner = vec![1, 1, ch, cw];
        if let Some(d) = depth {
            shard.push(d);
            inner.push(d);
        }
        let mut builder = if float {
            ArrayBuilder::new(shape, shard, data_type::float32(), f32::NAN)
        } else {
            ArrayBuilder::new(shape, shard, data_type::uint8(), 0u8)
        };
        // A frame and view of one inner chunk is that chunk, not a shard of it.
        if (ch, cw) != (h, w) {
            builder.subchunk_shape(inner);
        }
        builder
            .bytes_to_bytes_codecs(compress())
            .dimension_names(Some(dims))
            .attributes(attributes(attrs));
        let array = builder
            .build(store.clone(), &format!("/{name}"))
            .map_err(|e| err(&e))?;
        array.store_metadata().map_err(|e| err(&e))?;
        names.push(name.to_string());
        Ok::<_, Error>(())
    };
    if layout.cubes() {
        raster(
            "reflectance",
            Some(layout.wavelengths.len() as u64),
            true,
            &[("long_name", "reflectance"), ("units", "1")],
        )?;
    }
    if layout.registered() {
        raster(
            "registered",
            Some(layout.channels.len() as u64),
            true,
            &[(
                "long_name",
                "white-normalised captures warped into the view (NaN: not seen)",
            )],
        )?;
    }
    raster(
        "disparity",
        None,
        true,
        &[
            (
                "long_name",
                "disparity per column step of the array (NaN: unknown)",
            ),
            ("units", "px"),
        ],
    )?;
    raster(
        "visibility",
        None,
        false,
        &[("long_name", "number of cameras that measured the pixel")],
    )?;
    // Coordinates and the frames' completion (one chunk per frame, so that frames are
    // marked independently): 1-D arrays, made and listed alike.
    let mut one_d = |name: &str, dim: &str, builder: &mut ArrayBuilder, attrs: &[(&str, &str)]| {
        let array = builder
            .dimension_names(Some([dim]))
            .attributes(attributes(attrs))
            .build(store.clone(), &format!("/{name}"))
            .map_err(|e| err(&e))?;
        array.store_metadata().map_err(|e| err(&e))?;
        names.push(name.to_string());
        Ok::<_, Error>(array)
    };
    one_d(
        "frame_done",
        "frame",
        &mut ArrayBuilder::new(vec![nf], vec![1], data_type::uint8(), 0u8),
        &[("long_name", "1 once every array holds the frame")],
    )?;
    one_d(
        "frame_seconds",
        "frame",
        &mut ArrayBuilder::new(vec![nf], vec![1], data_type::float64(), f64::NAN),
        &[
            ("long_name", "time the frame's reconstruction took"),
            ("units", "s"),
        ],
    )?;
    one_d(
        "frame",
        "frame",
        &mut ArrayBuilder::new(vec![nf], vec![nf], data_type::int64(), 0i64),
        &[("long_name", "frame number")],
    )?
    .store_chunk(&[0], &layout.frames[..])
    .map_err(|e| err(&e))?;
    let mut labels = |name: &str, values: &[String]| {
        let n = values.len() as u64;
        let refs: Vec<&str> = values.iter().map(String::as_str).collect();
        one_d(
            name,
            name,
            &mut ArrayBuilder::new(vec![n], vec![n], data_type::string(), ""),
            &[],
        )?
        .store_chunk(&[0], refs)
        .map_err(|e| err(&e))
    };
    labels("view", &layout.views)?;
    if layout.registered() {
        labels("channel", &layout.channels)?;
    }
    if layout.cubes() {
        let n = layout.wavelengths.len() as u64;
        one_d(
            "wavelength",
            "wavelength",
            &mut ArrayBuilder::new(vec![n], vec![n], data_type::float64(), 0f64),
            &[("long_name", "band centre"), ("units", "nm")],
        )?
        .store_chunk(&[0], &layout.wavelengths[..])
        .map_err(|e| err(&e))?;
    }
    // The root group: the layout, then every array's metadata consolidated (zarr-python's
    // inline form), which xarray reads in one request.
    let mut root_attributes = serde_json::Map::new();
    root_attributes.insert(
        MARK.into(),
        serde_json::json!({
            "generator": format!("anaglyph {}", env!("CARGO_PKG_VERSION")),
            "layout": layout,
        }),
    );
    GroupBuilder::new()
        .attributes(root_attributes)
        .build(store.clone(), "/")
        .map_err(|e| err(&e))?
        .store_metadata()
        .map_err(|e| err(&e))?;
    let read_json = |path: PathBuf| -> Result<serde_json::Value> {
        let text = std::fs::read_to_string(&path).map_err(|e| Error::io(&path, e))?;
        serde_json::from_str(&text).map_err(|e| Error::decode(&path, e))
    };
    let mut consolidated = serde_json::Map::new();
    for name in &names {
        consolidated.insert(name.clone(), read_json(dir.join(name).join("zarr.json"))?);
    }
    let root_path = dir.join("zarr.json");
    let mut root = read_json(root_path.clone())?;
    root["consolidated_metadata"] = serde_json::json!({
        "kind": "inline",
        "must_understand": false,
        "metadata": consolidated,
    });
    let text = serde_json::to_string_pretty(&root).map_err(|e| Error::output("zarr.json", e))?;
    super::write_atomically(&root_path, |out| out.write_all(text.as_bytes()))
}

#[cfg(test)]
mod tests {
    use super::{inner_side, write_template, StoreLayout};

    /// The codecs of `array` in a template made for views of `width`×`height`.
    fn codecs(width: usize, height: usize, array: &str) -> Vec<String> {
        let dir = tempfile::tempdir().unwrap();
        let layout = StoreLayout {
            frames: vec![0, 1],
            views: vec!["a".into(), "b".into()],
            width,
            height,
            wavelengths: vec![500.0, 600.0],
            channels: vec![],
            run: serde_json::Value::Null,
        };
        write_template(dir.path(), &layout).unwrap();
        let text = std::fs::read_to_string(dir.path().join(array).join("zarr.json")).unwrap();
        let json: serde_json::Value = serde_json::from_str(&text).unwrap();
        let chunks = &json["chunk_grid"]["configuration"]["chunk_shape"];
        let mut names = vec![chunks.to_string()];
        for codec in json["codecs"].as_array().unwrap() {
            names.push(codec["name"].as_str().unwrap().to_string());
            if let Some(inner) = codec.pointer("/configuration/chunk_shape") {
                names.push(inner.to_string());
            }
        }
        names
    }

    #[test]
    fn a_frame_and_view_is_one_chunk_up_to_512_px_and_a_shard_beyond() {
        assert_eq!(
            codecs(320, 240, "reflectance"),
            ["[1,1,240,320,2]", "bytes", "zstd"]
        );
        assert_eq!(
            codecs(512, 512, "disparity"),
            ["[1,1,512,512]", "bytes", "zstd"]
        );
        assert_eq!(
            codecs(1600, 1200, "reflectance"),
            ["[1,1,1200,1600,2]", "sharding_indexed", "[1,1,240,200,2]"]
        );
        assert_eq!(
            codecs(640, 480, "disparity"),
            ["[1,1,480,640]", "sharding_indexed", "[1,1,480,160]"]
        );
    }

    #[test]
    fn inner_chunks_tile_the_shard() {
        for (side, inner) in [
            (72, 72),
            (480, 480),
            (600, 200),
            (1200, 240),
            (1600, 200),
            (1080, 216),
            (1920, 240),
            (1031, 1031),
        ] {
            assert_eq!(inner_side(side), inner, "{side}");
            assert!(side.is_multiple_of(inner_side(side)));
        }
    }
}

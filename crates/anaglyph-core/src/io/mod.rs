//! File formats at the edges of the pipeline: ENVI spectral cubes (.hdr + raw), NumPy
//! `.npy` arrays, PFM disparity maps, 8/16-bit PNG/TIFF captures, Zarr v3 stores of frame
//! sequences. Every writer goes
//! through [`write_atomically`] (temporary file in the target folder, then rename), so a
//! failed run never leaves a half-written output; every reader checks sizes against
//! limits before it allocates.

mod atomic;
mod disparity_preview;
mod envi;
mod large_buffer;
mod linear_image;
mod npy;
mod output_folder;
mod pfm;
mod tiff_directory;
mod zarr_store;

pub use atomic::write_atomically;
pub use disparity_preview::{ramp_colour, write_disparity_preview};
pub use envi::{
    read_envi, read_envi_shape, write_envi, EnviCube, EnviShape, MAX_ENVI_HEADER_BYTES,
};
pub use large_buffer::{filled_large, zeroed_large};
pub use linear_image::{
    from_u16_sample, from_u8_sample, max_image_pixels, odd_size_out, read_image_header,
    read_linear_image, to_u16_sample, write_png16, ImageHeader, LinearImage,
    DEFAULT_MAX_IMAGE_PIXELS,
};
pub use npy::{
    npy_header, open_npy_rows, read_npy_bool, read_npy_f64, read_npy_float, write_npy_f32,
    write_npy_f64, FloatArray, NpyArray, NpyRowReader,
};
pub use output_folder::{
    verify_output_folder, verify_output_subfolder, FileRecord, OutputFolder, Replace,
    VerifiedFolder, MANIFEST,
};
pub use pfm::{read_pfm, write_pfm, PfmImage};
pub use zarr_store::{LightFieldStore, PendingWrite, StoreLayout};

/// Largest raster (pixels × channels) any reader allocates: 2^31 values (8 GiB of f32).
pub const MAX_RASTER_VALUES: u64 = 1 << 31;

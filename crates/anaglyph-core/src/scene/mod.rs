//! Scenes for the simulator (the stage `spectra + rig -> scene -> captures`): what the
//! virtual array looks at. So far: the geometry of rays, cameras and surfaces, and the
//! spectral upsampling that turns the RGB texture
//! images of `data/textures` into plausible reflectance spectra, and the textures
//! themselves.

mod geometry;
mod spectral_upsampling;
mod texture;

pub use geometry::{rotate, rotation, Hit, PinholeCamera, Ray, Shape, Vec3};
pub use spectral_upsampling::{srgb_to_linear, SpectralUpsampler, UPSAMPLING_SHAPE};
pub use texture::{builtin_texture, Texture, TEXTURE_NAMES};

//! Scenes for the simulator (the stage `spectra + rig -> scene -> captures`): what the
//! virtual array looks at. So far: the spectral upsampling that turns the RGB texture
//! images of `data/textures` into plausible reflectance spectra, and the textures
//! themselves.

mod spectral_upsampling;
mod texture;

pub use spectral_upsampling::{srgb_to_linear, SpectralUpsampler, UPSAMPLING_SHAPE};
pub use texture::{builtin_texture, Texture, TEXTURE_NAMES};

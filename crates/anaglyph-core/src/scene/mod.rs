//! Scenes for the simulator (the stage `spectra + rig -> scene -> captures`): what the
//! virtual array looks at. A scene file (TOML) places textured rectangles, boxes, spheres
//! and a ColorChecker chart in front of the array ([`SceneFile`]); presets ship as such files.
//! Loading resolves it into shapes with materials ([`Scene`]); a material gives the
//! reflectance spectrum at a surface point, from measured data or from RGB textures and
//! patterns through [`SpectralUpsampler`].

mod description;
mod geometry;
mod material;
mod spectral_upsampling;
mod texture;

pub use description::{
    random_scene, MaterialSpec, ObjectSpec, Scene, SceneFile, SceneObject, ShapeSpec, PRESETS,
    TEST_SCENES,
};
pub use geometry::{rotate, rotation, Hit, PinholeCamera, Ray, Shape, Vec3};
pub use material::{Material, MetamerVariation, SpectrumSampler};
pub use spectral_upsampling::{srgb_to_linear, SpectralUpsampler, UPSAMPLING_SHAPE};
pub use texture::{builtin_texture, Texture, TEXTURE_NAMES};

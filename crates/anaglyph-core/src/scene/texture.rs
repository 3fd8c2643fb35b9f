//! Texture images as linear RGB: the CC0 / public-domain pictures vendored in
//! `data/textures` (compiled in; sources and licences in `data/textures/LICENSES.md`) or a
//! user's PNG/TIFF, decoded from sRGB to linear light, sampled bilinearly with wrap-around.

use super::srgb_to_linear;
use crate::image::Image;
use crate::{Error, Result};
use std::path::Path;

macro_rules! textures {
    ($($name:literal),* $(,)?) => {
        &[$(($name, include_bytes!(concat!("../../../../data/textures/", $name, ".png")))),*]
    };
}

/// The vendored textures (10 PNGs; the two JPEGs of the shared set are not vendored
/// because the project builds `image` with PNG and TIFF support only).
const BUILTIN_TEXTURES: &[(&str, &[u8])] = textures!(
    "astronaut",
    "brick",
    "camera",
    "cell",
    "chelsea",
    "clock_motion",
    "coffee",
    "grass",
    "gravel",
    "text"
);

/// Names of the built-in textures.
pub const TEXTURE_NAMES: [&str; 10] = [
    "astronaut",
    "brick",
    "camera",
    "cell",
    "chelsea",
    "clock_motion",
    "coffee",
    "grass",
    "gravel",
    "text",
];

/// A linear-light RGB image: three channels in [0, 1].
#[derive(Debug, Clone)]
pub struct Texture {
    pub image: Image<f32>,
}

impl Texture {
    fn from_image(image: image::DynamicImage) -> Self {
        let rgb8 = image.to_rgb8();
        let (width, height) = (rgb8.width() as usize, rgb8.height() as usize);
        let table: Vec<f32> = (0..256)
            .map(|v| srgb_to_linear(v as f64 / 255.0) as f32)
            .collect();
        let data = rgb8
            .pixels()
            .flat_map(|p| p.0.map(|v| table[v as usize]))
            .collect();
        Texture {
            image: Image {
                width,
                height,
                channels: 3,
                data,
            },
        }
    }

    /// Decodes an sRGB PNG or TIFF file.
    pub fn load(path: &Path) -> Result<Self> {
        let image = image::open(path).map_err(|e| Error::Decode {
            file: path.into(),
            message: e.to_string(),
        })?;
        Ok(Self::from_image(image))
    }

    /// Bilinear sample at texture coordinates `(u, v)` (1 = one texture width/height),
    /// repeating outside [0, 1).
    pub fn sample(&self, u: f64, v: f64) -> [f64; 3] {
        let (width, height) = (self.image.width, self.image.height);
        let x = u.rem_euclid(1.0) * width as f64 - 0.5;
        let y = v.rem_euclid(1.0) * height as f64 - 0.5;
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let wrap = |i: f64, n: usize| (i as i64).rem_euclid(n as i64) as usize;
        let (xa, xb) = (wrap(x0, width), wrap(x0 + 1.0, width));
        let (ya, yb) = (wrap(y0, height), wrap(y0 + 1.0, height));
        let at = |x: usize, y: usize| self.image.pixel(x, y);
        let (p00, p10, p01, p11) = (at(xa, ya), at(xb, ya), at(xa, yb), at(xb, yb));
        [0, 1, 2].map(|c| {
            let top = p00[c] as f64 * (1.0 - fx) + p10[c] as f64 * fx;
            let bottom = p01[c] as f64 * (1.0 - fx) + p11[c] as f64 * fx;
            top * (1.0 - fy) + bottom * fy
        })
    }
}

/// A built-in texture by name.
pub fn builtin_texture(name: &str) -> Result<Texture> {
    let (_, bytes) = BUILTIN_TEXTURES
        .iter()
        .find(|(k, _)| *k == name)
        .ok_or_else(|| Error::NotFound {
            what: "built-in texture".into(),
            name: name.to_string(),
            available: TEXTURE_NAMES.join(", "),
        })?;
    let image =
        image::load_from_memory_with_format(bytes, image::ImageFormat::Png).map_err(|e| {
            Error::Decode {
                file: format!("built-in texture '{name}'").into(),
                message: e.to_string(),
            }
        })?;
    Ok(Texture::from_image(image))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtin_textures_decode_with_their_documented_sizes() {
        let sizes = [
            (512, 512),
            (512, 512),
            (512, 512),
            (550, 660),
            (451, 300),
            (400, 300),
            (600, 400),
            (512, 512),
            (512, 512),
            (448, 172),
        ];
        for (name, (w, h)) in TEXTURE_NAMES.iter().zip(sizes) {
            let t = builtin_texture(name).unwrap();
            assert_eq!((t.image.width, t.image.height), (w, h), "{name}");
        }
        assert!(builtin_texture("rocket")
            .unwrap_err()
            .to_string()
            .contains("astronaut"));
    }

    #[test]
    fn bilinear_sampling_interpolates_and_wraps() {
        let t = Texture {
            image: Image::new(2, 1, 3, vec![0.0, 0.0, 0.0, 1.0, 0.5, 0.25]).unwrap(),
        };
        // Texel centres at u = 0.25 and 0.75.
        assert_eq!(t.sample(0.25, 0.5), [0.0, 0.0, 0.0]);
        assert_eq!(t.sample(0.75, 0.5), [1.0, 0.5, 0.25]);
        assert_eq!(t.sample(0.5, 0.5), [0.5, 0.25, 0.125]);
        // Half way between the last texel and the first (wrapped) one.
        assert_eq!(t.sample(1.0, 0.5), [0.5, 0.25, 0.125]);
        assert_eq!(t.sample(1.25, 0.5), t.sample(0.25, 0.5));
    }
}

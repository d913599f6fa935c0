//! Texture plugins (`bitmap`, `checkerboard`) and the image files they read.

use std::sync::Arc;

use glam::{Affine2, Mat2, Mat4, Vec2};

use crate::scene::{Rgb, TexImage, Texture};

use crate::scene::access::FileKind;

use super::builder::{addr, Builder};
use super::files;
use super::props::Props;
use super::xml::{resolve, El};
use super::Result;

impl<'t> Builder<'t> {
    pub(super) fn texture(&mut self, el: &'t El) -> Result<Texture> {
        let key = addr(el);
        if let Some(t) = self.textures.get(&key) {
            return Ok(t.clone());
        }
        let ty = self.plugin_type(el)?;
        let mut p = Props::new(el);
        let to_uv = self.transform(&mut p, "to_uv")?.unwrap_or(Mat4::IDENTITY);
        // the 2D affine part of Mitsuba's 4×4 to_uv (x, y and the translation)
        let to_uv = Affine2::from_mat2_translation(
            Mat2::from_cols(
                to_uv.x_axis.truncate().truncate(),
                to_uv.y_axis.truncate().truncate(),
            ),
            to_uv.w_axis.truncate().truncate(),
        );
        let t = match ty {
            "bitmap" => {
                let filename = self
                    .string(&mut p, "filename")?
                    .ok_or_else(|| self.err(el, "<texture type=\"bitmap\"> needs a `filename`"))?;
                let raw = self.boolean(&mut p, "raw", false)?;
                p.ignore(&["filter_type", "wrap_mode", "format", "accel"]);
                let image = self.image(el, filename, !raw)?;
                // Mitsuba's v = 0 is the image's top row; TexImage's is the bottom
                let flip = Affine2::from_mat2_translation(
                    Mat2::from_diagonal(Vec2::new(1.0, -1.0)),
                    Vec2::new(0.0, 1.0),
                );
                Texture::Bitmap {
                    image,
                    to_uv: flip * to_uv,
                }
            }
            "checkerboard" => Texture::Checkerboard {
                color0: self
                    .color_const(&mut p, "color0")?
                    .unwrap_or(Rgb::splat(0.4)),
                color1: self
                    .color_const(&mut p, "color1")?
                    .unwrap_or(Rgb::splat(0.2)),
                to_uv,
            },
            _ => {
                return Err(self.err(
                    el,
                    format!("unsupported texture plugin `{ty}`: expected bitmap or checkerboard"),
                ))
            }
        };
        self.finish(&p)?;
        self.textures.insert(key, t.clone());
        Ok(t)
    }

    /// An image file as linear RGB; 8- and 16-bit files (PNG, JPEG) are
    /// sRGB-encoded unless `srgb` is false (`raw`), float files (EXR, HDR,
    /// PFM) are linear. Non-finite or negative pixels are errors.
    pub(super) fn image(&mut self, el: &El, filename: &str, srgb: bool) -> Result<Arc<TexImage>> {
        let path = resolve(self.main_dir, &self.file(el), filename);
        if let Some(img) = self.images.get(&(path.clone(), srgb)) {
            return Ok(img.clone());
        }
        let bytes = self
            .access
            .read(&path, FileKind::Image)
            .map_err(|e| self.err(el, files::message("image file", filename, &e)))?;
        // its pixels' memory, from the header, before decoding them
        files::reserve_image(self.access, &bytes, &path, filename)
            .map_err(|e| self.err(el, e.to_string()))?;
        let cannot =
            |e: String| self.err(el, format!("cannot read image `{}`: {e}", path.display()));
        let is_pfm = path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("pfm"));
        let (width, height, data) = if is_pfm {
            // PFM holds linear floats; the `image` crate does not read it
            let img = crate::image_io::decode_pfm(&bytes).map_err(cannot)?;
            (img.width, img.height, img.data)
        } else {
            // the format the extension names, as `image::open` chooses it
            let mut reader = image::ImageReader::new(std::io::Cursor::new(&bytes[..]));
            if let Ok(format) = image::ImageFormat::from_path(&path) {
                reader.set_format(format);
            }
            let img = reader.decode().map_err(|e| cannot(e.to_string()))?;
            drop(bytes);
            let linear = matches!(
                img,
                image::DynamicImage::ImageRgb32F(_) | image::DynamicImage::ImageRgba32F(_)
            );
            let rgb = img.to_rgb32f();
            let (width, height) = rgb.dimensions();
            let decode = srgb && !linear;
            let data: Vec<Rgb> = rgb
                .pixels()
                .map(|px| {
                    let c = Rgb::from(px.0);
                    if decode {
                        c.map(srgb_to_linear)
                    } else {
                        c
                    }
                })
                .collect();
            (width, height, data)
        };
        // A NaN or infinite texel would reach the film through every path
        // that sees it. Negative texels (ringing from a resampled HDR image)
        // are a reflectance or radiance no surface has: clamped, with a note
        if let Some(i) = data.iter().position(|c| !c.is_finite()) {
            let (x, y) = (i as u32 % width.max(1), i as u32 / width.max(1));
            return Err(cannot(format!(
                "pixel ({x}, {y}) is not finite ({})",
                data[i]
            )));
        }
        let negative = data.iter().filter(|c| c.min_element() < 0.0).count();
        let data = if negative > 0 {
            self.warn(
                el,
                format!("image `{filename}`: {negative} pixels with negative values clamped to 0"),
            );
            data.into_iter().map(|c| c.max(Rgb::ZERO)).collect()
        } else {
            data
        };
        let img = Arc::new(TexImage::new(width, height, data));
        self.images.insert((path, srgb), img.clone());
        Ok(img)
    }
}

/// The largest value a colour parameter takes, per channel.
pub(super) fn tex_max(t: &Texture) -> Rgb {
    match t {
        Texture::Constant(c) => *c,
        Texture::Checkerboard { color0, color1, .. } => color0.max(*color1),
        Texture::Bitmap { image, .. } => image.pixels().fold(Rgb::ZERO, |a, b| a.max(b)),
    }
}

/// The sRGB transfer function, inverted.
fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

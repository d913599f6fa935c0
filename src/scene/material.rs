//! Materials as the scene file states them: BSDF parameters that may be
//! textured. [`Material::bsdf`] resolves one at a surface point into a plain,
//! `Copy` [`crate::bsdf::Bsdf`].

use std::sync::Arc;

use glam::{Affine2, Vec2};

use super::Rgb;
use crate::geometry::floor;

/// An RGB image in linear values, row 0 at the top.
#[derive(Clone, Debug)]
pub struct TexImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Pixels, row-major, top row first.
    pub data: Vec<Rgb>,
}

impl TexImage {
    /// The pixel at (x, y), clamped to the image.
    #[inline]
    pub fn texel(&self, x: i64, y: i64) -> Rgb {
        let x = x.clamp(0, self.width as i64 - 1) as usize;
        let y = y.clamp(0, self.height as i64 - 1) as usize;
        self.data[y * self.width as usize + x]
    }

    /// Bilinear lookup with wrapping in u and v, uv (0,0) at the bottom-left
    /// as in Mitsuba's `bitmap` (v points up).
    pub fn lookup(&self, uv: Vec2) -> Rgb {
        let (w, h) = (self.width as f32, self.height as f32);
        let u = uv.x - floor(uv.x);
        let v = uv.y - floor(uv.y);
        let x = u * w - 0.5;
        let y = (1.0 - v) * h - 0.5;
        let (x0, y0) = (floor(x), floor(y));
        let (fx, fy) = (x - x0, y - y0);
        // u and v are in [0, 1], so the index is nearly always inside the
        // image already: skip the division then
        let wrap = |i: f32, n: u32| -> i64 {
            let (i, n) = (i as i64, n as i64);
            if (0..n).contains(&i) {
                i
            } else {
                i.rem_euclid(n)
            }
        };
        let (xi0, yi0) = (wrap(x0, self.width), wrap(y0, self.height));
        let (xi1, yi1) = (wrap(x0 + 1.0, self.width), wrap(y0 + 1.0, self.height));
        let a = self.texel(xi0, yi0) * (1.0 - fx) + self.texel(xi1, yi0) * fx;
        let b = self.texel(xi0, yi1) * (1.0 - fx) + self.texel(xi1, yi1) * fx;
        a * (1.0 - fy) + b * fy
    }

    /// Mean of all pixels.
    pub fn mean(&self) -> Rgb {
        if self.data.is_empty() {
            return Rgb::ZERO;
        }
        let s: glam::DVec3 = self.data.iter().map(|c| c.as_dvec3()).sum();
        (s / self.data.len() as f64).as_vec3()
    }
}

/// A colour parameter: a constant, or a texture looked up through the mesh uvs.
#[derive(Clone, Debug)]
pub enum Texture {
    /// A constant value.
    Constant(Rgb),
    /// Mitsuba `bitmap`: an image with a `to_uv` transform.
    Bitmap {
        /// Pixels (linear).
        image: Arc<TexImage>,
        /// Applied to the mesh uv before the lookup.
        to_uv: Affine2,
    },
    /// Mitsuba `checkerboard`: `color0` where ⌊2u⌋+⌊2v⌋ is even, else `color1`.
    Checkerboard {
        /// First colour.
        color0: Rgb,
        /// Second colour.
        color1: Rgb,
        /// Applied to the mesh uv before the lookup.
        to_uv: Affine2,
    },
}

impl Texture {
    /// The value at texture coordinates `uv`.
    #[inline]
    pub fn eval(&self, uv: Vec2) -> Rgb {
        match self {
            Texture::Constant(c) => *c,
            Texture::Bitmap { image, to_uv } => image.lookup(to_uv.transform_point2(uv)),
            Texture::Checkerboard {
                color0,
                color1,
                to_uv,
            } => {
                let p = to_uv.transform_point2(uv);
                let u = p.x - floor(p.x);
                let v = p.y - floor(p.y);
                if (u > 0.5) == (v > 0.5) {
                    *color0
                } else {
                    *color1
                }
            }
        }
    }

    /// The mean value (for albedo estimates and emitter power).
    pub fn mean(&self) -> Rgb {
        match self {
            Texture::Constant(c) => *c,
            Texture::Bitmap { image, .. } => image.mean(),
            Texture::Checkerboard { color0, color1, .. } => (*color0 + *color1) * 0.5,
        }
    }
}

/// The microfacet normal distribution of the rough BSDFs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MicrofacetKind {
    /// Trowbridge–Reitz (GGX).
    Ggx,
    /// Beckmann.
    Beckmann,
}

/// A surface material, with the parameter names of Mitsuba 3's plugins.
#[derive(Clone, Debug)]
pub enum Material {
    /// Lambertian reflection (`diffuse`).
    Diffuse {
        /// Albedo.
        reflectance: Texture,
    },
    /// Energy-conserving modified Phong (Lafortune and Willems 1994), kalos's
    /// own `phong` plugin: f = kd/π + ks (n+2)/(2π) cosⁿα, with kd + ks ≤ 1.
    Phong {
        /// Diffuse albedo kd.
        diffuse_reflectance: Texture,
        /// Specular albedo ks.
        specular_reflectance: Texture,
        /// Phong exponent n.
        exponent: f32,
    },
    /// A smooth conductor (`conductor`): a mirror with Fresnel reflectance.
    Conductor {
        /// Real part of the index of refraction.
        eta: Rgb,
        /// Imaginary part (absorption).
        k: Rgb,
        /// Multiplier.
        specular_reflectance: Texture,
    },
    /// A rough conductor (`roughconductor`).
    RoughConductor {
        /// Distribution.
        distribution: MicrofacetKind,
        /// Roughness α.
        alpha: f32,
        /// Real part of the index of refraction.
        eta: Rgb,
        /// Imaginary part.
        k: Rgb,
        /// Multiplier.
        specular_reflectance: Texture,
    },
    /// A smooth dielectric coating over a diffuse base (`plastic`).
    Plastic {
        /// Base albedo.
        diffuse_reflectance: Texture,
        /// Multiplier on the specular coat.
        specular_reflectance: Texture,
        /// Relative index of refraction of the coat (int_ior / ext_ior).
        eta: f32,
        /// Mitsuba's `nonlinear` flag.
        nonlinear: bool,
    },
    /// A rough dielectric coating over a diffuse base (`roughplastic`).
    RoughPlastic {
        /// Base albedo.
        diffuse_reflectance: Texture,
        /// Multiplier on the specular coat.
        specular_reflectance: Texture,
        /// Distribution.
        distribution: MicrofacetKind,
        /// Roughness α.
        alpha: f32,
        /// Relative index of refraction (int_ior / ext_ior).
        eta: f32,
        /// Mitsuba's `nonlinear` flag.
        nonlinear: bool,
    },
    /// Smooth glass (`dielectric`).
    Dielectric {
        /// Relative index of refraction (int_ior / ext_ior).
        eta: f32,
        /// Multiplier on reflection.
        specular_reflectance: Texture,
        /// Multiplier on transmission.
        specular_transmittance: Texture,
    },
    /// A thin pane of glass (`thindielectric`): reflection and straight-through
    /// transmission with the interreflections of the two faces summed.
    ThinDielectric {
        /// Relative index of refraction.
        eta: f32,
        /// Multiplier on reflection.
        specular_reflectance: Texture,
        /// Multiplier on transmission.
        specular_transmittance: Texture,
    },
    /// `twosided`: the inner material seen from both sides.
    TwoSided(Box<Material>),
}

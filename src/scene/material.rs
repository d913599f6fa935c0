//! Materials as the scene file states them: BSDF parameters that may be
//! textured. [`Material::bsdf`] resolves one at a surface point into a plain,
//! `Copy` [`crate::bsdf::Bsdf`].

use std::sync::Arc;

use glam::{Affine2, Vec2};

use super::Rgb;
use crate::geometry::floor;

/// An RGB image in linear values, row 0 at the top.
///
/// Built by [`TexImage::new`] from linear floats. When every channel takes at
/// most 256 distinct values (any 8-bit source, whatever its decode), the
/// texels are kept as one byte per channel plus a 256-entry table per
/// channel holding the very floats given: lookups return the same bits as
/// the floats would, from a third of the memory, so fewer cache lines per
/// bilinear footprint. Other images (float or 16-bit sources) keep the floats.
#[derive(Clone, Debug)]
pub struct TexImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    texels: Texels,
}

/// Side of a square tile of byte texels: a tile of 4×4 texels, four bytes
/// each (the fourth is padding), is one 64-byte cache line, and most
/// bilinear footprints (2×2 texels) fall inside one tile.
const TILE: usize = 4;

/// One tile of byte texels, row-major within the tile, aligned to a line.
#[derive(Clone, Copy, Debug, Default)]
#[repr(C, align(64))]
struct Tile([[u8; 4]; TILE * TILE]);

/// The storage of a [`TexImage`]'s pixels.
#[derive(Clone, Debug)]
enum Texels {
    /// Linear floats as given, row-major, top row first.
    F32(Vec<Rgb>),
    /// One byte per channel, indexing that channel's table of floats, in
    /// tiles of `TILE`² texels (tiles row-major, top row first).
    U8 {
        tiles: Vec<Tile>,
        /// Tiles per row of tiles.
        tiles_x: usize,
        /// Number of texels.
        len: usize,
        table: Box<[[f32; 256]; 3]>,
    },
}

impl Texels {
    /// Where texel (x, y) lives in the tiles: tile and place within it.
    #[inline(always)]
    fn tiled(x: usize, y: usize, tiles_x: usize) -> (usize, usize) {
        (
            (y / TILE) * tiles_x + x / TILE,
            (y % TILE) * TILE + x % TILE,
        )
    }

    /// The float texel of bytes `b`.
    #[inline(always)]
    fn decode(table: &[[f32; 256]; 3], b: [u8; 4]) -> Rgb {
        Rgb::new(
            table[0][b[0] as usize],
            table[1][b[1] as usize],
            table[2][b[2] as usize],
        )
    }
}

impl Texels {
    /// The bytes and tables of `data` if each channel has at most 256
    /// distinct values (compared by bits, so the table returns exactly the
    /// floats given, signed zeros included).
    fn compact(width: u32, data: &[Rgb]) -> Option<Texels> {
        let w = (width as usize).max(1);
        let h = data.len().div_ceil(w);
        let tiles_x = w.div_ceil(TILE);
        let mut tiles = vec![Tile::default(); tiles_x * h.div_ceil(TILE)];
        let mut seen: [Palette; 3] = std::array::from_fn(|_| Palette::new());
        for (i, c) in data.iter().enumerate() {
            let mut px = [0u8; 4];
            for (ch, v) in c.to_array().into_iter().enumerate() {
                px[ch] = seen[ch].index(v)?;
            }
            let (t, k) = Texels::tiled(i % w, i / w, tiles_x);
            tiles[t].0[k] = px;
        }
        let table = Box::new(seen.map(|p| p.table));
        Some(Texels::U8 {
            tiles,
            tiles_x,
            len: data.len(),
            table,
        })
    }

    fn len(&self) -> usize {
        match self {
            Texels::F32(d) => d.len(),
            Texels::U8 { len, .. } => *len,
        }
    }
}

/// The distinct values of one channel, at most 256, each with its byte.
/// Every texel of every channel passes through here once at load, so it is
/// a small open-addressing table keyed by the float's bits (Knuth's
/// multiplicative hash, linear probing, at most a quarter full).
struct Palette {
    /// The bits of a value plus 2³² (0 marks an empty slot).
    keys: Box<[u64; 1024]>,
    bytes: Box<[u8; 1024]>,
    table: [f32; 256],
    len: usize,
}

impl Palette {
    fn new() -> Self {
        Palette {
            keys: Box::new([0; 1024]),
            bytes: Box::new([0; 1024]),
            table: [0.0; 256],
            len: 0,
        }
    }

    /// The byte of `v`, given a new one if unseen; `None` past 256 values.
    #[inline]
    fn index(&mut self, v: f32) -> Option<u8> {
        let bits = v.to_bits();
        let key = bits as u64 | 1 << 32;
        let mut slot = (bits.wrapping_mul(0x9E37_79B1) >> 22) as usize;
        loop {
            match self.keys[slot] {
                k if k == key => return Some(self.bytes[slot]),
                0 => {
                    let b = u8::try_from(self.len).ok()?;
                    self.keys[slot] = key;
                    self.bytes[slot] = b;
                    self.table[self.len] = v;
                    self.len += 1;
                    return Some(b);
                }
                _ => slot = (slot + 1) % 1024,
            }
        }
    }
}

impl TexImage {
    /// An image from linear pixels, row-major, top row first
    /// (`data.len()` should be `width * height`).
    pub fn new(width: u32, height: u32, data: Vec<Rgb>) -> Self {
        let texels = Texels::compact(width, &data).unwrap_or(Texels::F32(data));
        TexImage {
            width,
            height,
            texels,
        }
    }

    /// True when the texels are stored as bytes and tables.
    pub fn is_compact(&self) -> bool {
        matches!(self.texels, Texels::U8 { .. })
    }

    /// Number of pixels.
    pub fn len(&self) -> usize {
        self.texels.len()
    }

    /// True when the image has no pixels.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Pixel `i` in row-major order, top row first.
    #[inline(always)]
    pub fn pixel(&self, i: usize) -> Rgb {
        match &self.texels {
            Texels::F32(d) => d[i],
            Texels::U8 {
                tiles,
                tiles_x,
                table,
                ..
            } => {
                let w = (self.width as usize).max(1);
                let (t, k) = Texels::tiled(i % w, i / w, *tiles_x);
                Texels::decode(table, tiles[t].0[k])
            }
        }
    }

    /// All pixels in row-major order, top row first.
    pub fn pixels(&self) -> impl Iterator<Item = Rgb> + '_ {
        (0..self.len()).map(|i| self.pixel(i))
    }

    /// The image with `f` applied to every pixel.
    pub fn map(&self, f: impl Fn(Rgb) -> Rgb) -> TexImage {
        TexImage::new(self.width, self.height, self.pixels().map(f).collect())
    }

    /// The pixel at (x, y), clamped to the image.
    #[inline]
    pub fn texel(&self, x: i64, y: i64) -> Rgb {
        let x = x.clamp(0, self.width as i64 - 1) as usize;
        let y = y.clamp(0, self.height as i64 - 1) as usize;
        self.pixel(y * self.width as usize + x)
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
        // The four texels' coordinates, clamped as `texel` does; one match
        // on the storage for all four
        let cx = |x: i64| x.clamp(0, self.width as i64 - 1) as usize;
        let cy = |y: i64| y.clamp(0, self.height as i64 - 1) as usize;
        let xy = [
            (cx(xi0), cy(yi0)),
            (cx(xi1), cy(yi0)),
            (cx(xi0), cy(yi1)),
            (cx(xi1), cy(yi1)),
        ];
        let [t00, t10, t01, t11] = match &self.texels {
            Texels::F32(d) => xy.map(|(x, y)| d[y * self.width as usize + x]),
            Texels::U8 {
                tiles,
                tiles_x,
                table,
                ..
            } => xy.map(|(x, y)| {
                let (t, k) = Texels::tiled(x, y, *tiles_x);
                Texels::decode(table, tiles[t].0[k])
            }),
        };
        let a = t00 * (1.0 - fx) + t10 * fx;
        let b = t01 * (1.0 - fx) + t11 * fx;
        a * (1.0 - fy) + b * fy
    }

    /// Mean of all pixels.
    pub fn mean(&self) -> Rgb {
        if self.is_empty() {
            return Rgb::ZERO;
        }
        let s: glam::DVec3 = self.pixels().map(|c| c.as_dvec3()).sum();
        (s / self.len() as f64).as_vec3()
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
        /// What the base colour means and how the coat passes light to it.
        coat: Coat,
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
        /// What the base colour means and how the coat passes light to it.
        coat: Coat,
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
    /// Rough glass (`roughdielectric`): microfacet reflection and refraction
    /// (Walter et al. 2007), the lobe chosen by Fresnel.
    RoughDielectric {
        /// Distribution.
        distribution: MicrofacetKind,
        /// Roughness α.
        alpha: f32,
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
    /// glTF's metallic–roughness material with a `metallicRoughnessTexture`,
    /// resolved per texel into the metal or the dielectric of
    /// [`crate::scene::gltf`]'s mapping (no scene-file form: the glTF
    /// reader makes it).
    MetallicRoughness(Box<MetallicRoughness>),
}

/// What a plastic's base colour means, and how its dielectric coat passes
/// light down to the base and back.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Coat {
    /// Mitsuba's `plastic` and `roughplastic`: the base colour is the
    /// albedo ρ under the coat, and the rough coat transmits its
    /// single-scattering transmittance t(μ), losing what the interface's
    /// microfacets shadow (at GGX α = 1 and η = 1.5: t(1) = 0.88, a
    /// cosine-weighted mean of 0.73).
    Mitsuba,
    /// glTF's dielectric, the specification's `fresnel_mix`: the base
    /// colour c is the diffuse reflectance of the coated surface, and the
    /// coat passes on all it does not reflect: t(μ) = 1 − `specular` ·
    /// r(μ), with r(μ) the coat's single-scattering reflectance and
    /// `specular` the weight of the specular layer
    /// (`KHR_materials_specular`'s factor; 1 without the extension). The
    /// diffuse albedo seen from cos θo = μ is then c t(μ), which is what
    /// glTF's (1 − F) c/π integrates to, nearly. Described whole in
    /// [`crate::scene::gltf`].
    Gltf {
        /// Weight of the specular layer, in [0, 1].
        specular: f32,
    },
}

/// The parameters of [`Material::MetallicRoughness`], as glTF names them.
/// At a texel, metalness = `metallic` × the texture's blue channel and
/// roughness = `roughness` × its green one (linear values, as the glTF
/// specification stores them); the texel is a metal where the metalness
/// is at least 0.5, a dielectric elsewhere.
#[derive(Clone, Debug)]
pub struct MetallicRoughness {
    /// `baseColorFactor` × `baseColorTexture` (linear).
    pub base_color: Texture,
    /// `metallicFactor`.
    pub metallic: f32,
    /// `roughnessFactor`.
    pub roughness: f32,
    /// `metallicRoughnessTexture`, linear (blue: metalness, green:
    /// roughness).
    pub metallic_roughness: Texture,
    /// Weight of the dielectric's specular layer (`KHR_materials_specular`'s
    /// `specularFactor`; 1 without the extension): see [`Coat::Gltf`].
    pub specular: f32,
    /// The specular layer's tint (`specularColorFactor`; white without the
    /// extension).
    pub specular_tint: Rgb,
    /// The dielectric's index (`KHR_materials_ior`; 1.5 without it). 0 is
    /// the extension's F = 1: its dielectric texels are white mirrors.
    pub ior: f32,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::Pcg32;

    /// An image from bytes decoded as the sRGB loaders do, with a few
    /// signed zeros, so that the table must keep the floats bit for bit.
    fn srgb8(w: u32, h: u32, seed: u64) -> Vec<Rgb> {
        let mut rng = Pcg32::keyed(&[seed]);
        let decode = |b: u32| ((b as f32 / 255.0 + 0.055) / 1.055).powf(2.4);
        (0..w * h)
            .map(|i| {
                let b = |rng: &mut Pcg32| decode((rng.next_f32() * 256.0) as u32 % 256);
                let c = Rgb::new(b(&mut rng), b(&mut rng), b(&mut rng));
                if i % 7 == 0 {
                    Rgb::new(-0.0, c.y, 0.0)
                } else {
                    c
                }
            })
            .collect()
    }

    /// Bytes and tables give the same bits as the floats they came from,
    /// for every pixel and for bilinear lookups anywhere (wrapping and
    /// clamping included).
    #[test]
    fn byte_texels_give_the_floats_bit_for_bit() {
        let (w, h) = (37, 23);
        let data = srgb8(w, h, 1);
        let bytes = TexImage::new(w, h, data.clone());
        assert!(bytes.is_compact());
        let floats = TexImage {
            width: w,
            height: h,
            texels: Texels::F32(data.clone()),
        };
        for (i, c) in data.iter().enumerate() {
            assert_eq!(
                bytes.pixel(i).to_array().map(f32::to_bits),
                c.to_array().map(f32::to_bits)
            );
        }
        let mut rng = Pcg32::keyed(&[2]);
        for _ in 0..10_000 {
            let uv = Vec2::new(rng.next_f32() * 6.0 - 3.0, rng.next_f32() * 6.0 - 3.0);
            let (a, b) = (bytes.lookup(uv), floats.lookup(uv));
            assert_eq!(
                a.to_array().map(f32::to_bits),
                b.to_array().map(f32::to_bits),
                "{uv}"
            );
        }
        assert_eq!(bytes.mean(), floats.mean());
        let scaled = bytes.map(|c| c * 0.5);
        assert!(scaled.is_compact());
        assert_eq!(scaled.pixel(5), data[5] * 0.5);
    }

    /// More than 256 values in a channel keep the floats.
    #[test]
    fn many_values_keep_floats() {
        let data: Vec<Rgb> = (0..300).map(|i| Rgb::new(0.5, i as f32, 0.25)).collect();
        let img = TexImage::new(300, 1, data.clone());
        assert!(!img.is_compact());
        assert_eq!(img.pixels().collect::<Vec<_>>(), data);
        let few = TexImage::new(256, 1, data[..256].to_vec());
        assert!(few.is_compact());
        assert_eq!(few.pixels().collect::<Vec<_>>(), data[..256]);
    }
}

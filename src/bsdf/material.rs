//! Materials resolved into plain BSDFs at a surface point
//! ([`Material::bsdf`]), with the lobe-selection weights Mitsuba derives
//! from texture means.

use glam::Vec2;

use super::coat::CoatTable;
use super::fresnel::fresnel_diffuse_reflectance;
use super::microfacet::Microfacet;
use super::Bsdf;
use crate::scene::gltf::MIN_ALPHA;
use crate::scene::material::MetallicRoughness;
use crate::scene::{Coat, Material, Texture};
use crate::scene::{MicrofacetKind, Rgb};

/// A cheap mean of a texture for lobe-selection weights: the texture's mean
/// where that costs nothing (constants, checkerboards, as Mitsuba's
/// `Texture::mean`), but the local value for bitmaps, whose mean would be a
/// pass over every pixel at every hit. Only the noise depends on this choice.
fn sampling_mean(tex: &Texture, uv: Vec2) -> f32 {
    let c = match tex {
        Texture::Bitmap { .. } => tex.eval(uv),
        _ => tex.mean(),
    };
    (c.x + c.y + c.z) / 3.0
}

/// Mitsuba's weight steering samples to the coat: s̄ / (ρ̄ + s̄).
fn coat_sampling_weight(diffuse: &Texture, specular: &Texture, uv: Vec2) -> f32 {
    let d = sampling_mean(diffuse, uv).max(0.0);
    let s = sampling_mean(specular, uv).max(0.0);
    if d + s > 0.0 {
        s / (d + s)
    } else {
        0.5
    }
}

/// Steps of the roughness at which [`MetallicRoughness`] takes its coat
/// tables: at most 33 tables (tens of milliseconds each, computed once).
const ROUGHNESS_STEPS: f32 = 32.0;

impl MetallicRoughness {
    /// The texel at `uv`: metalness m = `metallic` × blue and roughness r =
    /// `roughness` × green of the texture; a GGX conductor tinted by the
    /// base colour where m ≥ 0.5, else the glTF dielectric of
    /// [`crate::scene::gltf`] (a GGX coat of index `ior` over the base
    /// colour times its gain, under glTF's coat; a white mirror at `ior`
    /// 0, a plain diffuse without a specular layer), both with α = r² (at
    /// least `MIN_ALPHA`). The
    /// dielectric's coat tables are taken at r rounded to 1/32 (its D and G
    /// use the exact α): t(μ) and R_int vary slowly with α.
    #[inline]
    pub fn bsdf(&self, uv: Vec2) -> Bsdf {
        let mr = self.metallic_roughness.eval(uv);
        let metal = self.metallic * mr.z;
        let r = (self.roughness * mr.y).clamp(0.0, 1.0);
        let r = if r.is_nan() { 1.0 } else { r };
        let base = self.base_color.eval(uv);
        let dist = Microfacet::new(MicrofacetKind::Ggx, (r * r).max(MIN_ALPHA));
        if metal >= 0.5 || self.ior == 0.0 {
            // a perfect-mirror Fresnel (eta 0, k 1) scaled by the base
            // colour; ior 0 (F = 1) is a white one
            return Bsdf::RoughConductor {
                dist,
                eta: Rgb::ZERO,
                k: Rgb::ONE,
                s: if metal >= 0.5 { base } else { Rgb::ONE },
            };
        }
        if self.specular <= 0.0 {
            // no specular layer: glTF's c/π exactly
            return Bsdf::Diffuse { r: base };
        }
        let eta = self.ior;
        let rq = (r * ROUGHNESS_STEPS).round() / ROUGHNESS_STEPS;
        let table = CoatTable::cached(
            Microfacet::new(MicrofacetKind::Ggx, (rq * rq).max(MIN_ALPHA)),
            eta,
            Coat::Gltf {
                specular: self.specular,
            },
        );
        let rho = base * table.gltf_base_gain(eta);
        let d = ((rho.x + rho.y + rho.z) / 3.0).max(0.0);
        let s = self.specular.clamp(0.0, 1.0);
        Bsdf::RoughPlastic {
            rho,
            s: self.specular_tint * s,
            dist,
            eta,
            nonlinear: false,
            // as coat_sampling_weight, with a grey coat of the layer's weight
            spec_weight: if d + s > 0.0 { s / (d + s) } else { 0.5 },
            table,
        }
    }
}

impl Material {
    /// Resolves the textures at `uv` into a plain BSDF. `twosided` resolves to
    /// its inner material (the integrator flips the frame, see
    /// [`Material::is_two_sided`]).
    ///
    /// Scene-file forms (Mitsuba 3 parameter names):
    ///
    /// ```xml
    /// <bsdf type="diffuse"><rgb name="reflectance" value="0.5"/></bsdf>
    /// <bsdf type="phong">  <!-- kalos's own -->
    ///     <rgb name="diffuse_reflectance" value="0.3"/>
    ///     <rgb name="specular_reflectance" value="0.6"/>
    ///     <float name="exponent" value="40"/>
    /// </bsdf>
    /// <bsdf type="conductor"><string name="material" value="Au"/></bsdf>
    /// <bsdf type="roughconductor">
    ///     <string name="distribution" value="ggx"/><float name="alpha" value="0.2"/>
    /// </bsdf>
    /// <bsdf type="plastic"><float name="int_ior" value="1.49"/></bsdf>
    /// <bsdf type="roughplastic"><float name="alpha" value="0.1"/></bsdf>
    /// <bsdf type="dielectric"><float name="int_ior" value="1.5"/></bsdf>
    /// <bsdf type="roughdielectric"><float name="alpha" value="0.1"/></bsdf>
    /// <bsdf type="thindielectric"><float name="int_ior" value="1.5"/></bsdf>
    /// <bsdf type="twosided"><bsdf type="diffuse"/></bsdf>
    /// ```
    #[inline(always)]
    pub fn bsdf(&self, uv: Vec2) -> Bsdf {
        match self {
            Material::Diffuse { reflectance } => Bsdf::Diffuse {
                r: reflectance.eval(uv),
            },
            Material::Phong {
                diffuse_reflectance,
                specular_reflectance,
                exponent,
            } => Bsdf::Phong {
                kd: diffuse_reflectance.eval(uv),
                ks: specular_reflectance.eval(uv),
                n: exponent.max(0.0),
            },
            Material::Conductor {
                eta,
                k,
                specular_reflectance,
            } => Bsdf::Conductor {
                eta: *eta,
                k: *k,
                s: specular_reflectance.eval(uv),
            },
            Material::RoughConductor {
                distribution,
                alpha,
                eta,
                k,
                specular_reflectance,
            } => Bsdf::RoughConductor {
                dist: Microfacet::new(*distribution, *alpha),
                eta: *eta,
                k: *k,
                s: specular_reflectance.eval(uv),
            },
            Material::Plastic {
                diffuse_reflectance,
                specular_reflectance,
                eta,
                nonlinear,
                coat,
            } => {
                let fdr_int = fresnel_diffuse_reflectance(1.0 / *eta);
                let rho = diffuse_reflectance.eval(uv);
                Bsdf::Plastic {
                    rho: match coat {
                        Coat::Mitsuba => rho,
                        // glTF's base colour is the coated surface's diffuse
                        // reflectance: η² (1 − R_int) / T̄ (about 1.02 at η
                        // = 1.5), as CoatTable::gltf_base_gain for the
                        // smooth coat
                        Coat::Gltf { .. } => {
                            rho * (eta * eta * (1.0 - fdr_int)
                                / (1.0 - fresnel_diffuse_reflectance(*eta)))
                        }
                    },
                    s: specular_reflectance.eval(uv),
                    eta: *eta,
                    fdr_int,
                    nonlinear: *nonlinear,
                    spec_weight: coat_sampling_weight(
                        diffuse_reflectance,
                        specular_reflectance,
                        uv,
                    ),
                }
            }
            Material::RoughPlastic {
                diffuse_reflectance,
                specular_reflectance,
                distribution,
                alpha,
                eta,
                nonlinear,
                coat,
            } => {
                let dist = Microfacet::new(*distribution, *alpha);
                let table = CoatTable::cached(dist, *eta, *coat);
                let rho = diffuse_reflectance.eval(uv);
                Bsdf::RoughPlastic {
                    rho: match coat {
                        Coat::Mitsuba => rho,
                        Coat::Gltf { .. } => rho * table.gltf_base_gain(*eta),
                    },
                    s: specular_reflectance.eval(uv),
                    dist,
                    eta: *eta,
                    nonlinear: *nonlinear,
                    spec_weight: coat_sampling_weight(
                        diffuse_reflectance,
                        specular_reflectance,
                        uv,
                    ),
                    table,
                }
            }
            Material::Dielectric {
                eta,
                specular_reflectance,
                specular_transmittance,
            } => Bsdf::Dielectric {
                eta: *eta,
                r: specular_reflectance.eval(uv),
                t: specular_transmittance.eval(uv),
            },
            Material::RoughDielectric {
                distribution,
                alpha,
                eta,
                specular_reflectance,
                specular_transmittance,
            } => Bsdf::RoughDielectric {
                dist: Microfacet::new(*distribution, *alpha),
                eta: *eta,
                r: specular_reflectance.eval(uv),
                t: specular_transmittance.eval(uv),
            },
            Material::ThinDielectric {
                eta,
                specular_reflectance,
                specular_transmittance,
            } => Bsdf::ThinDielectric {
                eta: *eta,
                r: specular_reflectance.eval(uv),
                t: specular_transmittance.eval(uv),
            },
            Material::TwoSided(inner) => inner.bsdf(uv),
            Material::MetallicRoughness(p) => p.bsdf(uv),
        }
    }

    /// The reflectance `r` where [`Material::bsdf`] gives `Bsdf::Diffuse { r }`
    /// at `uv`, else None: the same value, read without building the BSDF
    /// for the common `diffuse` material. For the AVX lanes, which shade
    /// only diffuse vertices: the `Bsdf` enum, built and matched, went
    /// through memory in pieces of different widths, a stall of the
    /// store-to-load forwarding at every vertex.
    #[inline(always)]
    pub fn diffuse_at(&self, uv: Vec2) -> Option<Rgb> {
        match self.base() {
            Material::Diffuse { reflectance } => Some(reflectance.eval(uv)),
            Material::MetallicRoughness(p) => match p.bsdf(uv) {
                Bsdf::Diffuse { r } => Some(r),
                _ => None,
            },
            _ => None,
        }
    }

    /// Builds now the tables [`Material::bsdf`] would otherwise build on
    /// first use: the coat table of a `roughplastic` (about 1 G instructions,
    /// some 0.3 s, once per process and parameters). [`crate::world::World`]
    /// calls it while it builds, so that the time is the scene's preparation
    /// and not the first pass's, as Mitsuba's is. glTF's coats, whose
    /// roughness may come from a texture, are still built on first use.
    pub fn prepare(&self) {
        match self {
            Material::RoughPlastic {
                distribution,
                alpha,
                eta,
                coat,
                ..
            } => {
                CoatTable::cached(Microfacet::new(*distribution, *alpha), *eta, *coat);
            }
            Material::TwoSided(inner) => inner.prepare(),
            _ => {}
        }
    }

    /// True when the integrator should flip the shading frame to the side of
    /// `wo` before calling the BSDF: `twosided` around a reflective model.
    /// False for everything else, including glass: the dielectrics handle both
    /// sides themselves, and flipping them would lose which side is inside.
    pub fn is_two_sided(&self) -> bool {
        match self {
            Material::TwoSided(inner) => !matches!(
                inner.base(),
                Material::Dielectric { .. }
                    | Material::RoughDielectric { .. }
                    | Material::ThinDielectric { .. }
            ),
            _ => false,
        }
    }

    /// True when the material is the same BSDF at every surface point:
    /// every texture it reads is a constant. False for glTF's textured
    /// materials and anything else not known to be uniform.
    pub fn is_uniform(&self) -> bool {
        let c = |t: &Texture| matches!(t, Texture::Constant(_));
        match self.base() {
            Material::Diffuse { reflectance } => c(reflectance),
            Material::Conductor {
                specular_reflectance,
                ..
            }
            | Material::RoughConductor {
                specular_reflectance,
                ..
            } => c(specular_reflectance),
            Material::Phong {
                diffuse_reflectance,
                specular_reflectance,
                ..
            }
            | Material::Plastic {
                diffuse_reflectance,
                specular_reflectance,
                ..
            }
            | Material::RoughPlastic {
                diffuse_reflectance,
                specular_reflectance,
                ..
            } => c(diffuse_reflectance) && c(specular_reflectance),
            Material::Dielectric {
                specular_reflectance,
                specular_transmittance,
                ..
            }
            | Material::RoughDielectric {
                specular_reflectance,
                specular_transmittance,
                ..
            }
            | Material::ThinDielectric {
                specular_reflectance,
                specular_transmittance,
                ..
            } => c(specular_reflectance) && c(specular_transmittance),
            _ => false,
        }
    }

    /// The texture of the material's diffuse (Lambertian) part: a diffuse
    /// material's reflectance, a plastic's or Phong's diffuse base; None for
    /// metals and glass, which have none.
    pub fn diffuse_texture(&self) -> Option<&Texture> {
        match self.base() {
            Material::Diffuse { reflectance } => Some(reflectance),
            Material::Phong {
                diffuse_reflectance,
                ..
            }
            | Material::Plastic {
                diffuse_reflectance,
                ..
            }
            | Material::RoughPlastic {
                diffuse_reflectance,
                ..
            } => Some(diffuse_reflectance),
            // the dielectric texels' base (the metal ones have none)
            Material::MetallicRoughness(p) => Some(&p.base_color),
            _ => None,
        }
    }

    /// The texture that colours the material as a whole (glTF's base
    /// colour): the diffuse part's, else a metal's specular reflectance,
    /// else glass's transmittance.
    pub fn base_texture(&self) -> &Texture {
        match self.base() {
            Material::Conductor {
                specular_reflectance,
                ..
            }
            | Material::RoughConductor {
                specular_reflectance,
                ..
            } => specular_reflectance,
            Material::Dielectric {
                specular_transmittance,
                ..
            }
            | Material::RoughDielectric {
                specular_transmittance,
                ..
            }
            | Material::ThinDielectric {
                specular_transmittance,
                ..
            } => specular_transmittance,
            Material::Diffuse { reflectance } => reflectance,
            Material::Phong {
                diffuse_reflectance,
                ..
            }
            | Material::Plastic {
                diffuse_reflectance,
                ..
            }
            | Material::RoughPlastic {
                diffuse_reflectance,
                ..
            } => diffuse_reflectance,
            Material::MetallicRoughness(p) => &p.base_color,
            // not reached: base() has taken the wrappers off
            Material::TwoSided(inner) => inner.base_texture(),
        }
    }

    /// The material under any `twosided` wrappers.
    fn base(&self) -> &Material {
        match self {
            Material::TwoSided(inner) => inner.base(),
            m => m,
        }
    }
}

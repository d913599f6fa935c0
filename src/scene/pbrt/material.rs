//! Materials and textures: pbrt-v4's material types onto kalos's
//! [`Material`]s, with a stand-in and a note for the ones kalos lacks.

use std::sync::Arc;

use glam::{Affine2, Vec2};

use super::lexer::Directive;
use super::params::Params;
use super::spectra::{glass_ior, Kind};
use super::{Builder, Result};
use crate::scene::{Coat, Material, MicrofacetKind, Rgb, Texture};

/// pbrt-v4's roughness to a microfacet α: with `remaproughness` (the
/// default) pbrt takes the square root of the user's value
/// (`TrowbridgeReitzDistribution::RoughnessToAlpha`).
fn alpha(roughness: f32, remap: bool) -> f32 {
    let r = roughness.max(0.0);
    if remap {
        r.sqrt()
    } else {
        r
    }
}

/// Below this α pbrt-v4 treats a microfacet surface as smooth
/// (`EffectivelySmooth`), so the delta BSDF is used.
const SMOOTH_ALPHA: f32 = 1e-3;

/// Reflecting BSDFs are one-sided in kalos (Mitsuba's convention); every
/// pbrt surface reflects on both sides.
fn two_sided(m: Material) -> Material {
    Material::TwoSided(Box::new(m))
}

impl Builder {
    /// Resolves the current material into a scene index (`None`:
    /// `interface`, whose shapes are not drawn). pbrt's default is
    /// `diffuse` with reflectance 0.5.
    pub(super) fn current_material(&mut self) -> Option<u32> {
        match self.g.material {
            Some(m) => m,
            None => Some(*self.default_material.get_or_insert_with(|| {
                self.scene.add_material(two_sided(Material::Diffuse {
                    reflectance: Texture::Constant(Rgb::splat(0.5)),
                }))
            })),
        }
    }

    /// The roughness of a rough BSDF: `roughness`, or the mean of
    /// `uroughness`/`vroughness` (kalos's microfacets are isotropic), as α.
    fn roughness(&mut self, ps: &mut Params<'_>, prefix: &str, default: f32) -> Result<f32> {
        let (r, u, v) = (
            format!("{prefix}roughness"),
            format!("{prefix}uroughness"),
            format!("{prefix}vroughness"),
        );
        let remap = ps.boolean(&self.cx, "remaproughness", true)?;
        let base = self.cx.scalar(
            ps,
            &r,
            default,
            &self.float_textures,
            &mut self.scene.warnings,
        )?;
        let uu = self
            .cx
            .scalar(ps, &u, base, &self.float_textures, &mut self.scene.warnings)?;
        let vv = self
            .cx
            .scalar(ps, &v, base, &self.float_textures, &mut self.scene.warnings)?;
        if (uu - vv).abs() > 1e-6 {
            let msg = format!(
                "anisotropic roughness of {} replaced by the mean of u and v",
                ps.what
            );
            self.warn(ps.line, msg);
        }
        Ok(alpha(0.5 * (uu + vv), remap))
    }

    fn color(
        &mut self,
        ps: &mut Params<'_>,
        name: &str,
        kind: Kind,
        default: f32,
    ) -> Result<Texture> {
        let t = self.cx.color(ps, name, kind, &self.textures)?;
        Ok(t.unwrap_or(Texture::Constant(Rgb::splat(default))))
    }

    /// A conductor's (eta, k): from `eta`/`k` (default copper, as pbrt) or
    /// from `reflectance` (k chosen so that the normal-incidence Fresnel
    /// reflectance is that colour, with eta 1, as pbrt-v4 does).
    fn conductor_iors(&mut self, ps: &mut Params<'_>, prefix: &str) -> Result<(Rgb, Rgb)> {
        let refl = self
            .cx
            .color(ps, "reflectance", Kind::Reflectance, &self.textures)?;
        let (eta_name, k_name) = (format!("{prefix}eta"), format!("{prefix}k"));
        if let Some(r) = refl {
            if ps.has(&eta_name) || ps.has(&k_name) {
                return Err(self.cx.err(
                    ps.line,
                    format!("{}: give `reflectance` or `eta` and `k`, not both", ps.what),
                ));
            }
            let r = match r {
                Texture::Constant(c) => c,
                t => {
                    self.warn(
                        ps.line,
                        format!("textured `reflectance` of {} replaced by its mean", ps.what),
                    );
                    t.mean()
                }
            };
            let r = r.clamp(Rgb::ZERO, Rgb::splat(0.9999));
            let k = (r.map(f32::sqrt) * 2.0) / (Rgb::ONE - r).map(f32::sqrt);
            return Ok((Rgb::ONE, k));
        }
        let mut get = |b: &mut Builder, name: &str, default: Rgb| -> Result<Rgb> {
            match b.cx.color(ps, name, Kind::Unbounded, &b.textures)? {
                None => Ok(default),
                Some(Texture::Constant(c)) => Ok(c),
                Some(t) => {
                    let msg = format!("textured `{name}` of {} replaced by its mean", ps.what);
                    b.warn(ps.line, msg);
                    Ok(t.mean())
                }
            }
        };
        let (cu_eta, cu_k) =
            crate::scene::mitsuba::tables::conductor_table("Cu").unwrap_or((Rgb::ONE, Rgb::ONE));
        let eta = get(self, &eta_name, cu_eta)?;
        let k = get(self, &k_name, cu_k)?;
        Ok((eta, k))
    }

    /// A dielectric's index: a float, or a named glass spectrum.
    fn ior(&mut self, ps: &mut Params<'_>, default: f32) -> Result<f32> {
        let Some(p) = ps.list.iter().find(|p| p.name == "eta").copied() else {
            return Ok(default);
        };
        if p.ty == pbrt4::param::ParamType::Spectrum {
            ps.take("eta");
            if let super::lexer::Values::Strs(v) = &p.values {
                if let Some(n) = v.first().and_then(|n| glass_ior(n)) {
                    return Ok(n);
                }
            }
            let c = super::spectra::spectrum_value(&self.cx, p, &ps.what, Kind::Unbounded)?;
            self.warn(
                p.line,
                format!(
                    "spectral `eta` of {} replaced by its mean (kalos has no dispersion)",
                    ps.what
                ),
            );
            return Ok((c.x + c.y + c.z) / 3.0);
        }
        let eta = self.cx.scalar(
            ps,
            "eta",
            default,
            &self.float_textures,
            &mut self.scene.warnings,
        )?;
        if !(eta.is_finite() && eta > 0.0) {
            return Err(self.cx.err(
                p.line,
                format!("`eta` of {} must be positive, found {eta}", ps.what),
            ));
        }
        Ok(eta)
    }

    /// Builds the material of a `Material` or `MakeNamedMaterial`
    /// directive and returns its index (`None` for `interface`).
    pub(super) fn material(
        &mut self,
        d: &Directive,
        ty: &str,
        what: String,
    ) -> Result<Option<u32>> {
        let defaults = self.g.attrs[2].clone();
        let mut ps = Params::new(d, what, &defaults);
        ps.ignore(&["type", "displacement", "normalmap"]);
        for n in ["displacement", "normalmap"] {
            if d.params.iter().any(|p| p.name == n) {
                let msg = format!("`{n}` of {} ignored", ps.what);
                self.warn(d.line, msg);
            }
        }
        let m = match ty {
            "interface" => {
                ps.finish(&self.cx)?;
                return Ok(None);
            }
            "diffuse" => two_sided(Material::Diffuse {
                reflectance: self.color(&mut ps, "reflectance", Kind::Reflectance, 0.5)?,
            }),
            "coateddiffuse" => self.coated_diffuse(&mut ps, d)?,
            "conductor" | "coatedconductor" => self.conductor(&mut ps, d, ty)?,
            "dielectric" | "thindielectric" => self.dielectric(&mut ps, d, ty)?,
            "diffusetransmission" => self.diffuse_transmission(&mut ps, d)?,
            "mix" => return self.mix(&mut ps, d),
            "measured" | "hair" | "subsurface" | "coateddiffusetransmission" => {
                let ignored = ps.rest();
                self.scene.notes.push(self.cx.at(
                    d.line,
                    format!(
                        "{}: kalos has no `{ty}` material; stand-in: diffuse, reflectance 0.5 (ignored: {})",
                        ps.what,
                        ignored.join(", ")
                    ),
                ));
                two_sided(Material::Diffuse { reflectance: Texture::Constant(Rgb::splat(0.5)) })
            }
            _ => {
                return Err(self.cx.err(
                    d.line,
                    format!(
                        "unknown material type \"{ty}\": expected diffuse, coateddiffuse, conductor, \
                         dielectric, thindielectric, diffusetransmission, mix, coatedconductor or interface"
                    ),
                ))
            }
        };
        ps.finish(&self.cx)?;
        Ok(Some(self.scene.add_material(m)))
    }

    /// `coateddiffuse`, read as Mitsuba's `plastic` or `roughplastic` (a
    /// diffuse base under a dielectric coat), with a note.
    fn coated_diffuse(&mut self, ps: &mut Params<'_>, d: &Directive) -> Result<Material> {
        let rho = self.color(ps, "reflectance", Kind::Reflectance, 0.5)?;
        let a = self.roughness(ps, "", 0.0)?;
        let eta = self.ior(ps, 1.5)?;
        ps.ignore(&["thickness", "albedo", "g", "maxdepth", "nsamples"]);
        self.scene.notes.push(self.cx.at(
            d.line,
            format!(
                "{}: coateddiffuse read as Mitsuba's {} (a diffuse base under a dielectric coat), \
                 not pbrt's stochastic layers",
                ps.what,
                if a < SMOOTH_ALPHA {
                    "plastic"
                } else {
                    "roughplastic"
                }
            ),
        ));
        Ok(two_sided(if a < SMOOTH_ALPHA {
            Material::Plastic {
                diffuse_reflectance: rho,
                specular_reflectance: Texture::Constant(Rgb::ONE),
                eta,
                nonlinear: false,
                coat: Coat::Mitsuba,
            }
        } else {
            Material::RoughPlastic {
                diffuse_reflectance: rho,
                specular_reflectance: Texture::Constant(Rgb::ONE),
                distribution: MicrofacetKind::Ggx,
                alpha: a,
                eta,
                nonlinear: false,
                coat: Coat::Mitsuba,
            }
        }))
    }

    /// `conductor`, and `coatedconductor` as its conductor without the coat
    /// (with a note): smooth or GGX by the roughness.
    fn conductor(&mut self, ps: &mut Params<'_>, d: &Directive, ty: &str) -> Result<Material> {
        let prefix = if ty == "conductor" { "" } else { "conductor." };
        let (eta, k) = self.conductor_iors(ps, prefix)?;
        let a = self.roughness(ps, prefix, 0.0)?;
        if ty == "coatedconductor" {
            let ignored = ps.rest();
            self.scene.notes.push(self.cx.at(
                d.line,
                format!(
                    "{}: kalos has no coatedconductor; stand-in: its conductor without the coat \
                     (ignored: {})",
                    ps.what,
                    ignored.join(", ")
                ),
            ));
        }
        Ok(two_sided(if a < SMOOTH_ALPHA {
            Material::Conductor {
                eta,
                k,
                specular_reflectance: Texture::Constant(Rgb::ONE),
            }
        } else {
            Material::RoughConductor {
                distribution: MicrofacetKind::Ggx,
                alpha: a,
                eta,
                k,
                specular_reflectance: Texture::Constant(Rgb::ONE),
            }
        }))
    }

    /// `dielectric` and `thindielectric`: smooth glass (a rough one with a
    /// note).
    fn dielectric(&mut self, ps: &mut Params<'_>, d: &Directive, ty: &str) -> Result<Material> {
        let eta = self.ior(ps, 1.5)?;
        let a = if ty == "dielectric" {
            self.roughness(ps, "", 0.0)?
        } else {
            0.0
        };
        if a >= SMOOTH_ALPHA {
            self.scene.notes.push(self.cx.at(
                d.line,
                format!(
                    "{}: kalos has no rough dielectric; stand-in: smooth glass",
                    ps.what
                ),
            ));
        }
        let (r, t) = (Texture::Constant(Rgb::ONE), Texture::Constant(Rgb::ONE));
        Ok(if ty == "dielectric" {
            Material::Dielectric {
                eta,
                specular_reflectance: r,
                specular_transmittance: t,
            }
        } else {
            Material::ThinDielectric {
                eta,
                specular_reflectance: r,
                specular_transmittance: t,
            }
        })
    }

    /// `diffusetransmission`: kalos has none; its reflection alone stands
    /// in, with a note.
    fn diffuse_transmission(&mut self, ps: &mut Params<'_>, d: &Directive) -> Result<Material> {
        let r = self.color(ps, "reflectance", Kind::Reflectance, 0.25)?;
        let t = self.color(ps, "transmittance", Kind::Reflectance, 0.25)?;
        let scale = ps.float(&self.cx, "scale", 1.0)?;
        self.scene.notes.push(self.cx.at(
            d.line,
            format!(
                "{}: kalos has no diffuse transmission; stand-in: diffuse reflection with its \
                 reflectance (transmittance {:?} dropped)",
                ps.what,
                t.mean()
            ),
        ));
        Ok(two_sided(Material::Diffuse {
            reflectance: scale_texture(&r, scale.clamp(0.0, 1.0)),
        }))
    }

    /// `mix` of two named materials: exact for two constant diffuse ones,
    /// otherwise the likelier stands in (with a note). Returns the index,
    /// after checking the parameters.
    fn mix(&mut self, ps: &mut Params<'_>, d: &Directive) -> Result<Option<u32>> {
        let names = ps.strings(&self.cx, "materials")?.ok_or_else(|| {
            self.cx.err(
                d.line,
                format!("{} needs \"string materials\" [ \"a\" \"b\" ]", ps.what),
            )
        })?;
        let [a, b] = names else {
            return Err(self.cx.err(
                d.line,
                format!("{}: `materials` names two materials", ps.what),
            ));
        };
        let amount = self.cx.scalar(
            ps,
            "amount",
            0.5,
            &self.float_textures,
            &mut self.scene.warnings,
        )?;
        let get = |n: &str| -> Result<Option<u32>> {
            self.named_materials.get(n).copied().ok_or_else(|| {
                self.cx.err(
                    d.line,
                    format!(
                        "{}: no material named \"{n}\" is defined before this line",
                        ps.what
                    ),
                )
            })
        };
        let (ia, ib) = (get(a)?, get(b)?);
        ps.finish(&self.cx)?;
        // pbrt picks `b` with probability `amount`. Two constant
        // diffuse materials mix exactly into one; otherwise the
        // likelier one stands in.
        let (ma, mb) = (
            ia.map(|i| self.scene.materials[i as usize].clone()),
            ib.map(|i| self.scene.materials[i as usize].clone()),
        );
        if let (Some(ma), Some(mb)) = (&ma, &mb) {
            if let (Some(ra), Some(rb)) = (const_diffuse(ma), const_diffuse(mb)) {
                let m = two_sided(Material::Diffuse {
                    reflectance: Texture::Constant(ra * (1.0 - amount) + rb * amount),
                });
                return Ok(Some(self.scene.add_material(m)));
            }
        }
        let (pick, name) = if amount > 0.5 { (ib, b) } else { (ia, a) };
        self.scene.notes.push(self.cx.at(
            d.line,
            format!("{}: kalos cannot mix these materials; stand-in: \"{name}\" (the likelier, amount {amount})", ps.what),
        ));
        Ok(pick)
    }

    /// A `Texture "name" "spectrum"|"float" "class" ...` directive.
    pub(super) fn texture(&mut self, d: &Directive) -> Result<()> {
        let s = self.strs(d, 3)?;
        let (name, kind, class) = (s[0].to_string(), s[1], s[2]);
        let float = match kind {
            "spectrum" | "color" => false,
            "float" => true,
            _ => {
                return Err(self.cx.err(
                    d.line,
                    format!(
                        "Texture \"{name}\": type \"{kind}\" should be \"spectrum\" or \"float\""
                    ),
                ))
            }
        };
        let defaults = self.g.attrs[3].clone();
        let mut ps = Params::new(d, format!("Texture \"{name}\" ({class})"), &defaults);
        let lookup = if float {
            self.float_textures.clone()
        } else {
            self.textures.clone()
        };
        let input =
            |b: &mut Builder, ps: &mut Params<'_>, n: &str, default: f32| -> Result<Texture> {
                if float
                    && ps
                        .list
                        .iter()
                        .any(|p| p.name == n && p.ty == pbrt4::param::ParamType::Float)
                {
                    return Ok(Texture::Constant(Rgb::splat(ps.float(&b.cx, n, default)?)));
                }
                Ok(b.cx
                    .color(ps, n, Kind::Unbounded, &lookup)?
                    .unwrap_or(Texture::Constant(Rgb::splat(default))))
            };
        let uv = |b: &mut Builder, ps: &mut Params<'_>| -> Result<Affine2> {
            let mapping = ps.string(&b.cx, "mapping")?.unwrap_or("uv");
            if mapping != "uv" {
                return Err(b.cx.err(
                    ps.line,
                    format!(
                        "{}: mapping \"{mapping}\" is not supported (only uv)",
                        ps.what
                    ),
                ));
            }
            let su = ps.float(&b.cx, "uscale", 1.0)?;
            let sv = ps.float(&b.cx, "vscale", 1.0)?;
            let du = ps.float(&b.cx, "udelta", 0.0)?;
            let dv = ps.float(&b.cx, "vdelta", 0.0)?;
            Ok(Affine2::from_scale_angle_translation(
                Vec2::new(su, sv),
                0.0,
                Vec2::new(du, dv),
            ))
        };
        let t = match class {
            "constant" => input(self, &mut ps, "value", 1.0)?,
            "imagemap" => {
                let to_uv = uv(self, &mut ps)?;
                let file = ps.string(&self.cx, "filename")?.ok_or_else(|| {
                    self.cx.err(d.line, format!("{} needs a \"string filename\"", ps.what))
                })?;
                let encoding = ps.string(&self.cx, "encoding")?.map(str::to_string);
                let invert = ps.boolean(&self.cx, "invert", false)?;
                let scale = ps.float(&self.cx, "scale", 1.0)?;
                ps.ignore(&["filter", "maxanisotropy", "wrap"]);
                let img = self.image(d.line, file, encoding.as_deref())?;
                let img = if invert || scale != 1.0 {
                    Arc::new(img.map(|c| {
                        let c = if invert { (Rgb::ONE - c).max(Rgb::ZERO) } else { c };
                        c * scale
                    }))
                } else {
                    img
                };
                Texture::Bitmap { image: img, to_uv }
            }
            "checkerboard" => {
                let dim = ps.int(&self.cx, "dimension", 2)?;
                if dim != 2 {
                    return Err(self.cx.err(d.line, format!("{}: only the 2D checkerboard is supported", ps.what)));
                }
                let to_uv = uv(self, &mut ps)?;
                let c1 = input(self, &mut ps, "tex1", 1.0)?;
                let c2 = input(self, &mut ps, "tex2", 0.0)?;
                match (c1, c2) {
                    (Texture::Constant(color0), Texture::Constant(color1)) => Texture::Checkerboard {
                        color0,
                        color1,
                        // pbrt's checks are one uv unit wide; kalos's are half
                        to_uv: Affine2::from_scale(Vec2::splat(0.5)) * to_uv,
                    },
                    _ => return Err(self.cx.err(d.line, format!("{}: a checkerboard of textures is not supported (tex1 and tex2 must be constants)", ps.what))),
                }
            }
            "scale" => {
                let t = input(self, &mut ps, "tex", 1.0)?;
                let s = input(self, &mut ps, "scale", 1.0)?;
                match (&t, &s) {
                    (_, Texture::Constant(c)) => scale_rgb(&t, *c),
                    (Texture::Constant(c), _) => scale_rgb(&s, *c),
                    _ => return Err(self.cx.err(d.line, format!("{}: a scale of two non-constant textures is not supported", ps.what))),
                }
            }
            "mix" => {
                let a = input(self, &mut ps, "tex1", 0.0)?;
                let b = input(self, &mut ps, "tex2", 1.0)?;
                let amount = input(self, &mut ps, "amount", 0.5)?;
                match (a, b, amount) {
                    (Texture::Constant(a), Texture::Constant(b), Texture::Constant(t)) => {
                        Texture::Constant(a * (Rgb::ONE - t) + b * t)
                    }
                    _ => return Err(self.cx.err(d.line, format!("{}: a mix of non-constant textures is not supported", ps.what))),
                }
            }
            _ => {
                return Err(self.cx.err(
                    d.line,
                    format!("unsupported texture class \"{class}\": expected imagemap, checkerboard, constant, scale or mix"),
                ))
            }
        };
        ps.finish(&self.cx)?;
        if !float {
            if let Texture::Constant(c) = &t {
                if c.min_element() < 0.0 || !c.is_finite() {
                    return Err(self.cx.err(
                        d.line,
                        format!("{}: the value must be finite and non-negative", ps.what),
                    ));
                }
            }
        }
        if float {
            self.float_textures.insert(name, t);
        } else {
            self.textures.insert(name, t);
        }
        Ok(())
    }
}

/// A constant diffuse material's albedo (through `TwoSided`).
fn const_diffuse(m: &Material) -> Option<Rgb> {
    match m {
        Material::Diffuse {
            reflectance: Texture::Constant(c),
        } => Some(*c),
        Material::TwoSided(inner) => const_diffuse(inner),
        _ => None,
    }
}

fn scale_texture(t: &Texture, s: f32) -> Texture {
    scale_rgb(t, Rgb::splat(s))
}

/// A texture multiplied by a constant colour.
fn scale_rgb(t: &Texture, s: Rgb) -> Texture {
    match t {
        Texture::Constant(c) => Texture::Constant(*c * s),
        Texture::Checkerboard {
            color0,
            color1,
            to_uv,
        } => Texture::Checkerboard {
            color0: *color0 * s,
            color1: *color1 * s,
            to_uv: *to_uv,
        },
        Texture::Bitmap { image, to_uv } => Texture::Bitmap {
            image: Arc::new(image.map(|c| c * s)),
            to_uv: *to_uv,
        },
    }
}

//! BSDF plugins: `diffuse`, `twosided`, `conductor`, `roughconductor`,
//! `plastic`, `roughplastic`, `dielectric`, `roughdielectric`,
//! `thindielectric`, `phong`.

use crate::scene::{Coat, Material};

use super::builder::{addr, Builder};
use super::props::Props;
use super::tables::{conductor_table, CONDUCTORS};
use super::texture::tex_max;
use super::xml::El;
use super::Result;

impl<'t> Builder<'t> {
    pub(super) fn bsdf(&mut self, el: &'t El) -> Result<u32> {
        let key = addr(el);
        if let Some(&m) = self.materials.get(&key) {
            return Ok(m);
        }
        let m = self.bsdf_material(el)?;
        let idx = self.scene.add_material(m);
        self.materials.insert(key, idx);
        Ok(idx)
    }

    fn bsdf_material(&mut self, el: &'t El) -> Result<Material> {
        let key = addr(el);
        if !self.building.insert(key) {
            return Err(self.err(el, "reference cycle through this <bsdf>"));
        }
        let r = self.bsdf_material_inner(el);
        self.building.remove(&key);
        r
    }

    /// Builds the material of a `<bsdf>` element, one arm per plugin, and
    /// refuses what the plugin does not consume.
    fn bsdf_material_inner(&mut self, el: &'t El) -> Result<Material> {
        let ty = self.plugin_type(el)?;
        let mut p = Props::new(el);
        let m = match ty {
            "diffuse" => Material::Diffuse {
                reflectance: self.color(&mut p, "reflectance", 0.5)?,
            },
            "twosided" => self.twosided(el, &mut p)?,
            "conductor" | "roughconductor" => self.conductor(el, &mut p, ty)?,
            "plastic" | "roughplastic" => {
                let eta = self.eta(&mut p, 1.49)?;
                let diffuse_reflectance = self.color(&mut p, "diffuse_reflectance", 0.5)?;
                let specular_reflectance = self.color(&mut p, "specular_reflectance", 1.0)?;
                let nonlinear = self.boolean(&mut p, "nonlinear", false)?;
                if ty == "plastic" {
                    Material::Plastic {
                        diffuse_reflectance,
                        specular_reflectance,
                        eta,
                        nonlinear,
                        coat: Coat::Mitsuba,
                    }
                } else {
                    let distribution = self.distribution(&mut p)?;
                    let alpha = self.alpha(&mut p)?;
                    p.ignore(&["sample_visible"]);
                    Material::RoughPlastic {
                        diffuse_reflectance,
                        specular_reflectance,
                        distribution,
                        alpha,
                        eta,
                        nonlinear,
                        coat: Coat::Mitsuba,
                    }
                }
            }
            "dielectric" | "thindielectric" => {
                let eta = self.eta(&mut p, 1.5046)?;
                let specular_reflectance = self.color(&mut p, "specular_reflectance", 1.0)?;
                let specular_transmittance = self.color(&mut p, "specular_transmittance", 1.0)?;
                if ty == "dielectric" {
                    Material::Dielectric {
                        eta,
                        specular_reflectance,
                        specular_transmittance,
                    }
                } else {
                    Material::ThinDielectric {
                        eta,
                        specular_reflectance,
                        specular_transmittance,
                    }
                }
            }
            "roughdielectric" => {
                let eta = self.eta(&mut p, 1.5046)?;
                let specular_reflectance = self.color(&mut p, "specular_reflectance", 1.0)?;
                let specular_transmittance = self.color(&mut p, "specular_transmittance", 1.0)?;
                let distribution = self.distribution(&mut p)?;
                let alpha = self.alpha(&mut p)?;
                p.ignore(&["sample_visible"]);
                Material::RoughDielectric {
                    distribution,
                    alpha,
                    eta,
                    specular_reflectance,
                    specular_transmittance,
                }
            }
            "phong" => self.phong(el, &mut p)?,
            _ => {
                return Err(self.err(
                    el,
                    format!("unsupported BSDF plugin `{ty}` in {}", el.describe()),
                ))
            }
        };
        self.finish(&p)?;
        Ok(m)
    }

    /// `twosided`: the one nested BSDF, inline or by reference, on both
    /// sides.
    fn twosided(&mut self, el: &'t El, p: &mut Props<'t>) -> Result<Material> {
        let objs = p.objects();
        let mut inner = Vec::new();
        for o in objs {
            let target = if o.tag == "ref" { self.lookup(o)? } else { o };
            if target.tag != "bsdf" {
                return Err(self.err(
                    o,
                    format!("<twosided> holds a <bsdf>, not {}", target.describe()),
                ));
            }
            inner.push(target);
        }
        match inner.as_slice() {
            [b] => Ok(Material::TwoSided(Box::new(self.bsdf_material(b)?))),
            [] => Err(self.err(el, "<bsdf type=\"twosided\"> needs a nested <bsdf>")),
            _ => Err(self.err(
                el,
                "a twosided BSDF with a different BSDF on each side is not supported",
            )),
        }
    }

    /// `conductor` and `roughconductor`: the indices from `eta` and `k` or
    /// from a named `material` of Mitsuba's table (default `none`).
    fn conductor(&mut self, el: &'t El, p: &mut Props<'t>, ty: &str) -> Result<Material> {
        let name = self.string(p, "material")?;
        let eta = self.color_const(p, "eta")?;
        let k = self.color_const(p, "k")?;
        let (eta, k) = match (eta, k) {
            (Some(eta), Some(k)) => {
                if name.is_some_and(|n| n != "none") {
                    return Err(self.err(el, "give either `material` or `eta` and `k`"));
                }
                (eta, k)
            }
            (None, None) => {
                let n = name.unwrap_or("none");
                conductor_table(n).ok_or_else(|| {
                    let known: Vec<&str> = CONDUCTORS.iter().map(|(n, _, _)| *n).collect();
                    self.err(
                        el,
                        format!(
                            "unknown conductor material `{n}`; known: {}",
                            known.join(", ")
                        ),
                    )
                })?
            }
            _ => return Err(self.err(el, "give both `eta` and `k`")),
        };
        let specular_reflectance = self.color(p, "specular_reflectance", 1.0)?;
        Ok(if ty == "conductor" {
            Material::Conductor {
                eta,
                k,
                specular_reflectance,
            }
        } else {
            let distribution = self.distribution(p)?;
            let alpha = self.alpha(p)?;
            p.ignore(&["sample_visible"]);
            Material::RoughConductor {
                distribution,
                alpha,
                eta,
                k,
                specular_reflectance,
            }
        })
    }

    /// `phong`: the modified Phong model, refused when it would create
    /// energy.
    fn phong(&mut self, el: &'t El, p: &mut Props<'t>) -> Result<Material> {
        let kd = self.color(p, "diffuse_reflectance", 0.5)?;
        let ks = self.color(p, "specular_reflectance", 0.2)?;
        let exponent = self.float(p, "exponent", 30.0)?;
        if exponent < 0.0 {
            return Err(self.err(el, "phong `exponent` must be ≥ 0"));
        }
        // energy conservation of the modified Phong model needs kd + ks ≤ 1
        let sum = tex_max(&kd) + tex_max(&ks);
        if sum.max_element() > 1.0 + 1e-4 {
            return Err(self.err(
                el,
                format!(
                    "phong: diffuse_reflectance + specular_reflectance exceeds 1 \
                     ({sum:?}): the material would create energy"
                ),
            ));
        }
        Ok(Material::Phong {
            diffuse_reflectance: kd,
            specular_reflectance: ks,
            exponent,
        })
    }

    /// int_ior / ext_ior.
    fn eta(&self, p: &mut Props<'t>, int_default: f32) -> Result<f32> {
        let int = self.ior(p, "int_ior", int_default)?;
        let ext = self.ior(p, "ext_ior", 1.000277)?;
        if int.is_nan() || ext.is_nan() || int <= 0.0 || ext <= 0.0 {
            return Err(self.err(p.el, "indices of refraction must be positive"));
        }
        Ok(int / ext)
    }
}

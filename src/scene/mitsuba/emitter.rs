//! Emitter plugins: `area` (on a shape), `constant`, `envmap`.

use glam::Mat4;

use crate::scene::{EmitterDesc, Rgb, Texture};

use super::builder::Builder;
use super::props::Props;
use super::xml::El;
use super::Result;

impl<'t> Builder<'t> {
    /// An `area` emitter's radiance.
    pub(super) fn area_emitter(&mut self, el: &'t El) -> Result<Rgb> {
        let ty = self.plugin_type(el)?;
        if ty != "area" {
            return Err(self.err(
                el,
                format!("a shape can only carry an `area` emitter, found `{ty}`"),
            ));
        }
        let mut p = Props::new(el);
        let radiance = match self.color(&mut p, "radiance", 1.0)? {
            Texture::Constant(c) => c,
            t => {
                self.warn(el, "textured area-light radiance replaced by its mean");
                t.mean()
            }
        };
        self.finish(&p)?;
        self.check_emission(el, "radiance", radiance)?;
        Ok(radiance)
    }

    /// Emission must be finite and non-negative: a negative light would be
    /// dropped by the light sampler and subtract light where it is seen.
    fn check_emission(&self, el: &El, what: &str, c: Rgb) -> Result<()> {
        if c.is_finite() && c.min_element() >= 0.0 {
            return Ok(());
        }
        Err(self.err(
            el,
            format!(
                "{} `{what}` must be finite and non-negative, found ({}, {}, {})",
                el.describe(),
                c.x,
                c.y,
                c.z
            ),
        ))
    }

    pub(super) fn emitter(&mut self, el: &'t El) -> Result<()> {
        let ty = self.plugin_type(el)?;
        let mut p = Props::new(el);
        match ty {
            "area" => {
                // a template for the shapes that refer to it
                self.area_emitter(el)?;
                if el.attr("id").is_none() {
                    self.warn(
                        el,
                        "an area emitter outside a shape and without an id does nothing",
                    );
                }
                return Ok(());
            }
            "constant" => {
                let radiance = self.color_const(&mut p, "radiance")?.unwrap_or(Rgb::ONE);
                self.check_emission(el, "radiance", radiance)?;
                self.scene.emitters.push(EmitterDesc::Constant { radiance });
            }
            "envmap" => {
                let filename = self
                    .string(&mut p, "filename")?
                    .ok_or_else(|| self.err(el, "<emitter type=\"envmap\"> needs a `filename`"))?;
                let scale = self.float(&mut p, "scale", 1.0)?;
                self.check_emission(el, "scale", Rgb::splat(scale))?;
                let to_world = self
                    .transform(&mut p, "to_world")?
                    .unwrap_or(Mat4::IDENTITY);
                p.ignore(&["mis_compensation"]);
                let image = self.image(el, filename, true)?;
                self.scene.emitters.push(EmitterDesc::EnvMap {
                    image,
                    scale,
                    to_world,
                });
            }
            "point" | "spot" | "directional" | "projector" => {
                return Err(self.err(
                    el,
                    format!(
                        "unsupported emitter `{ty}`: kalos's methods need lights with an area \
                         (use an `area` emitter on a small shape)"
                    ),
                ))
            }
            _ => {
                return Err(self.err(el, format!("unsupported emitter plugin `{ty}`")));
            }
        }
        self.finish(&p)
    }
}

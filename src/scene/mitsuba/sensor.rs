//! The sensor: `perspective` (and `thinlens`, read as a pinhole), its
//! `hdrfilm` and reconstruction filter, and the sampler it may hold.

use glam::Mat4;

use crate::scene::CameraDesc;

use super::builder::Builder;
use super::props::Props;
use super::xml::El;
use super::Result;

impl<'t> Builder<'t> {
    pub(super) fn sensor(&mut self, el: &'t El) -> Result<()> {
        let ty = self.plugin_type(el)?;
        let mut p = Props::new(el);
        match ty {
            "perspective" => {}
            "thinlens" => {
                self.warn(el, "thinlens sensor read as a pinhole (no depth of field)");
                p.ignore(&["aperture_radius"]);
            }
            _ => return Err(self.err(el, format!("unsupported sensor plugin `{ty}`"))),
        }
        let to_world = self
            .transform(&mut p, "to_world")?
            .unwrap_or(Mat4::IDENTITY);
        let fov = self.float_opt(&mut p, "fov")?;
        let focal = self.string(&mut p, "focal_length")?;
        let axis = self.string(&mut p, "fov_axis")?.unwrap_or("x");
        let near_clip = self.float(&mut p, "near_clip", 1e-2)?;
        p.ignore(&[
            "far_clip",
            "focus_distance",
            "shutter_open",
            "shutter_close",
            "principal_point_offset_x",
            "principal_point_offset_y",
            "srf",
        ]);
        let (fov, axis) = match (fov, focal) {
            (Some(_), Some(_)) => {
                return Err(self.err(el, "give `fov` or `focal_length`, not both"))
            }
            (Some(f), None) => (f, axis),
            (None, f) => {
                // Mitsuba: a 35 mm-equivalent focal length, measured on the
                // 36 × 24 mm frame's diagonal; default 50 mm
                let f = f.unwrap_or("50mm");
                let mm = self.number(el, "focal_length", f.trim().trim_end_matches("mm"))?;
                if mm.is_nan() || mm <= 0.0 {
                    return Err(self.err(el, "`focal_length` must be positive"));
                }
                let diag = (36.0f32 * 36.0 + 24.0 * 24.0).sqrt();
                (2.0 * (diag / (2.0 * mm)).atan().to_degrees(), "diagonal")
            }
        };
        if fov.is_nan() || fov <= 0.0 || fov >= 180.0 {
            return Err(self.err(
                el,
                format!("`fov` must be in (0, 180) degrees, found {fov}"),
            ));
        }

        // The film (and its filter) and the sampler
        let (mut width, mut height) = (768u32, 576u32);
        for o in p.objects() {
            match o.tag.as_str() {
                "film" => (width, height) = self.film(o)?,
                "sampler" => {
                    // any sampler type is accepted (kalos's methods draw their
                    // own numbers); its sample count is the default budget
                    self.plugin_type(o)?;
                    let mut sp = Props::new(o);
                    let n = self.int(&mut sp, "sample_count", 0)?;
                    if sp.used.iter().any(|u| *u) {
                        let n = u32::try_from(n).ok().filter(|n| *n > 0).ok_or_else(|| {
                            self.err(o, format!("`sample_count` must be positive, found {n}"))
                        })?;
                        self.scene.sample_count = Some(n);
                    }
                }
                _ => {
                    return Err(self.err(o, format!("unexpected {} inside a sensor", o.describe())))
                }
            }
        }
        self.finish(&p)?;
        let mut cam =
            CameraDesc::from_fov(to_world, fov, axis, width, height).ok_or_else(|| {
                self.err(
                    el,
                    format!(
                        "unknown fov_axis `{axis}`: expected x, y, smaller, larger or diagonal"
                    ),
                )
            })?;
        cam.near_clip = near_clip;
        self.scene.camera = cam;
        self.camera_seen = true;
        Ok(())
    }

    fn film(&mut self, el: &'t El) -> Result<(u32, u32)> {
        let ty = self.plugin_type(el)?;
        if ty != "hdrfilm" {
            return Err(self.err(
                el,
                format!("unsupported film plugin `{ty}`: expected hdrfilm"),
            ));
        }
        let mut p = Props::new(el);
        let mut size = [0u32; 2];
        for (i, (name, default)) in [("width", 768), ("height", 576)].into_iter().enumerate() {
            let v = self.int(&mut p, name, default)?;
            size[i] = u32::try_from(v)
                .ok()
                .filter(|v| (1..=1 << 16).contains(v))
                .ok_or_else(|| {
                    self.err(el, format!("film `{name}` must be in 1..=65536, found {v}"))
                })?;
        }
        p.ignore(&[
            "pixel_format",
            "file_format",
            "component_format",
            "banner",
            "crop_offset_x",
            "crop_offset_y",
            "crop_width",
            "crop_height",
            "sample_border",
            "compensate",
        ]);
        for o in p.objects() {
            if o.tag != "rfilter" {
                return Err(self.err(o, format!("unexpected {} inside a film", o.describe())));
            }
            let fty = self.plugin_type(o)?;
            match fty {
                "box" => {}
                "gaussian" | "tent" | "lanczos" | "mitchell" | "catmullrom" => self.warn(
                    o,
                    format!("reconstruction filter `{fty}` replaced by kalos's box filter"),
                ),
                _ => return Err(self.err(o, format!("unknown reconstruction filter `{fty}`"))),
            }
            let mut fp = Props::new(o);
            fp.ignore(&["stddev", "radius", "B", "C", "lobes"]);
            self.finish(&fp)?;
        }
        self.finish(&p)?;
        Ok((size[0], size[1]))
    }
}

//! Lights, the camera, the film and the sampler; the images that textures
//! and environment lights read.

use std::f32::consts::PI;
use std::sync::Arc;

use glam::{Mat4, Vec2, Vec3};

use super::lexer::Directive;
use super::params::Params;
use super::spectra::Kind;
use super::{Builder, Result};
use crate::scene::access::FileKind;
use crate::scene::mitsuba::files;
use crate::scene::{CameraDesc, EmitterDesc, Rgb, TexImage, Texture};

/// The camera as declared; built once the film's size is known.
#[derive(Clone, Debug)]
pub(super) struct CameraSpec {
    world_from_camera: Mat4,
    fov: f32,
    line: u32,
}

impl Builder {
    pub(super) fn camera(&mut self, d: &Directive) -> Result<()> {
        let ty = self.strs(d, 1)?[0];
        if ty != "perspective" {
            return Err(self.cx.err(
                d.line,
                format!("unsupported camera \"{ty}\": kalos has the perspective camera only"),
            ));
        }
        let mut ps = Params::new(d, format!("Camera \"{ty}\""), &[]);
        let fov = ps.float(&self.cx, "fov", 90.0)?;
        if !(fov > 0.0 && fov < 180.0) {
            return Err(self.cx.err(
                d.line,
                format!("`fov` must be in (0, 180) degrees, found {fov}"),
            ));
        }
        let lens = ps.float(&self.cx, "lensradius", 0.0)?;
        if lens > 0.0 {
            self.warn(
                d.line,
                "lensradius ignored: kalos's camera is a pinhole (no depth of field)",
            );
        }
        for n in ["frameaspectratio", "screenwindow"] {
            if ps.has(n) {
                return Err(self.cx.err(
                    d.line,
                    format!("Camera `{n}` is not supported: kalos derives the frame from the film"),
                ));
            }
        }
        ps.ignore(&["focaldistance", "shutteropen", "shutterclose"]);
        ps.finish(&self.cx)?;
        let inv = self.g.ctm.inverse();
        if !inv.is_finite() {
            return Err(self.cx.err(d.line, "the camera transform is singular"));
        }
        self.named_coords.insert("camera".into(), inv);
        self.camera = Some(CameraSpec {
            world_from_camera: inv,
            fov,
            line: d.line,
        });
        Ok(())
    }

    pub(super) fn film(&mut self, d: &Directive) -> Result<()> {
        let ty = self.strs(d, 1)?[0];
        if !matches!(ty, "rgb" | "gbuffer" | "spectral") {
            return Err(self
                .cx
                .err(d.line, format!("unknown film \"{ty}\": expected rgb")));
        }
        if ty != "rgb" {
            self.warn(d.line, format!("Film \"{ty}\" read as an rgb film"));
        }
        let mut ps = Params::new(d, format!("Film \"{ty}\""), &[]);
        let mut size = [0u32; 2];
        for (i, (name, default)) in [("xresolution", 1280), ("yresolution", 720)]
            .into_iter()
            .enumerate()
        {
            let v = ps.int(&self.cx, name, default)?;
            size[i] = u32::try_from(v)
                .ok()
                .filter(|v| (1..=1 << 16).contains(v))
                .ok_or_else(|| {
                    self.cx.err(
                        d.line,
                        format!("film `{name}` must be in 1..=65536, found {v}"),
                    )
                })?;
        }
        if ps.has("cropwindow") || ps.has("pixelbounds") {
            self.warn(
                d.line,
                "cropwindow/pixelbounds ignored: kalos renders the whole film",
            );
        }
        ps.ignore(&[
            "filename",
            "cropwindow",
            "pixelbounds",
            "diagonal",
            "iso",
            "exposuretime",
            "whitebalance",
            "sensor",
            "savefp16",
            "maxcomponentvalue",
            "writefp16",
        ]);
        ps.finish(&self.cx)?;
        self.film = (size[0], size[1]);
        Ok(())
    }

    pub(super) fn sampler(&mut self, d: &Directive) -> Result<()> {
        let ty = self.strs(d, 1)?[0].to_string();
        let mut ps = Params::new(d, format!("Sampler \"{ty}\""), &[]);
        if ps.has("pixelsamples") {
            let n = ps.int(&self.cx, "pixelsamples", 16)?;
            let n = u32::try_from(n).ok().filter(|n| *n > 0).ok_or_else(|| {
                self.cx.err(
                    d.line,
                    format!("`pixelsamples` must be positive, found {n}"),
                )
            })?;
            self.scene.sample_count = Some(n);
        }
        // kalos's methods draw their own numbers: the sampler's kind and
        // its other settings change nothing
        let _ = ps.rest();
        Ok(())
    }

    /// The camera, once the whole file is read (a `Film` may follow the
    /// `Camera`). Without one, pbrt's default: at the origin, looking
    /// along +z.
    pub(super) fn finish_camera(&mut self) -> Result<()> {
        let spec = self.camera.clone().unwrap_or(CameraSpec {
            world_from_camera: Mat4::IDENTITY,
            fov: 90.0,
            line: 0,
        });
        let (w, h) = self.film;
        // pbrt's camera space has +x to the image's right, Mitsuba's (and
        // kalos's) to its left: mirror x to keep pbrt's image
        let to_world = spec.world_from_camera * Mat4::from_scale(Vec3::new(-1.0, 1.0, 1.0));
        let cam = CameraDesc::from_fov(to_world, spec.fov, "smaller", w, h)
            .ok_or_else(|| self.cx.err(spec.line, "cannot build the camera"))?;
        self.scene.camera = cam;
        Ok(())
    }

    pub(super) fn area_light(&mut self, d: &Directive) -> Result<()> {
        let ty = self.strs(d, 1)?[0];
        if ty != "diffuse" {
            return Err(self.cx.err(
                d.line,
                format!("unknown area light \"{ty}\": expected diffuse"),
            ));
        }
        let defaults = self.g.attrs[1].clone();
        let mut ps = Params::new(d, format!("AreaLightSource \"{ty}\""), &defaults);
        let l = match self
            .cx
            .color(&mut ps, "L", Kind::Illuminant, &Default::default())?
        {
            Some(Texture::Constant(c)) => c,
            Some(t) => t.mean(),
            None => Rgb::ONE,
        };
        let scale = ps.float(&self.cx, "scale", 1.0)?;
        if ps.boolean(&self.cx, "twosided", false)? {
            self.warn(
                d.line,
                "a two-sided area light emits from its front side only in kalos",
            );
        }
        for n in ["filename", "power"] {
            if ps.has(n) {
                return Err(self
                    .cx
                    .err(d.line, format!("AreaLightSource `{n}` is not supported")));
            }
        }
        ps.finish(&self.cx)?;
        let radiance = l * scale;
        if !radiance.is_finite() || radiance.min_element() < 0.0 {
            return Err(self.cx.err(
                d.line,
                format!("area light radiance must be finite and non-negative, found {radiance}"),
            ));
        }
        self.g.area_light = Some(radiance);
        Ok(())
    }

    pub(super) fn light(&mut self, d: &Directive) -> Result<()> {
        let ty = self.strs(d, 1)?[0];
        let defaults = self.g.attrs[1].clone();
        let mut ps = Params::new(d, format!("LightSource \"{ty}\""), &defaults);
        match ty {
            "infinite" => {
                let scale = ps.float(&self.cx, "scale", 1.0)?;
                if !(scale.is_finite() && scale >= 0.0) {
                    return Err(self.cx.err(
                        d.line,
                        format!("`scale` must be finite and non-negative, found {scale}"),
                    ));
                }
                for n in ["illuminance", "power"] {
                    if ps.has(n) {
                        return Err(self.cx.err(
                            d.line,
                            format!("LightSource \"infinite\" `{n}` is not supported"),
                        ));
                    }
                }
                if ps.has("portal") {
                    self.warn(d.line, "`portal` ignored (it only guides pbrt's sampling)");
                    ps.ignore(&["portal"]);
                }
                let file = ps.string(&self.cx, "filename")?;
                let l = self
                    .cx
                    .color(&mut ps, "L", Kind::Illuminant, &Default::default())?;
                ps.finish(&self.cx)?;
                match (file, l) {
                    (Some(_), Some(_)) => {
                        return Err(self.cx.err(
                            d.line,
                            "LightSource \"infinite\": give `L` or `filename`, not both",
                        ))
                    }
                    (Some(f), None) => {
                        let img = self.image(d.line, f, Some("linear"))?;
                        if img.width != img.height {
                            return Err(self.cx.err(
                                d.line,
                                format!(
                                    "environment image `{f}` is {}×{}: pbrt-v4 needs a square equal-area image",
                                    img.width, img.height
                                ),
                            ));
                        }
                        let image = Arc::new(equal_area_to_latlong(&img));
                        self.scene.emitters.push(EmitterDesc::EnvMap {
                            image,
                            scale,
                            to_world: self.g.ctm,
                        });
                    }
                    (None, l) => {
                        let c = match l {
                            Some(Texture::Constant(c)) => c,
                            Some(t) => t.mean(),
                            None => Rgb::ONE,
                        };
                        self.scene.emitters.push(EmitterDesc::Constant {
                            radiance: c * scale,
                        });
                    }
                }
                Ok(())
            }
            "point" | "spot" | "distant" | "goniometric" | "projection" => Err(self.cx.err(
                d.line,
                format!(
                    "unsupported light \"{ty}\": kalos's methods need lights with an area \
                     (use an AreaLightSource on a small sphere or disk)"
                ),
            )),
            _ => Err(self.cx.err(
                d.line,
                format!("unknown light \"{ty}\": expected infinite (or an AreaLightSource)"),
            )),
        }
    }

    /// An image file as linear RGB. `encoding` is pbrt's: `sRGB` (the
    /// default for 8-bit files), `linear`, or `gamma G`; float files are
    /// linear whatever it says.
    pub(super) fn image(
        &mut self,
        line: u32,
        file: &str,
        encoding: Option<&str>,
    ) -> Result<Arc<TexImage>> {
        let path = self.cx.resolve(file);
        let key = (path.clone(), encoding.unwrap_or("").to_string());
        if let Some(img) = self.images.get(&key) {
            return Ok(img.clone());
        }
        let bytes = self
            .cx
            .access
            .read(&path, FileKind::Image)
            .map_err(|e| self.cx.err(line, files::message("image file", file, &e)))?;
        // its pixels' memory, from the header, before decoding them
        files::reserve_image(&self.cx.access, &bytes, &path, file)
            .map_err(|e| self.cx.err(line, e.to_string()))?;
        let img = crate::image_io::decode_image(&bytes, &path)
            .map_err(|e| self.cx.err(line, format!("cannot read image: {e}")))?;
        drop(bytes);
        let float = path
            .extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| matches!(e.to_ascii_lowercase().as_str(), "exr" | "pfm" | "hdr"));
        // read_image decodes 8-bit files as sRGB; undo that for the others
        let decode: Box<dyn Fn(f32) -> f32> = match encoding {
            _ if float => Box::new(|v| v),
            None | Some("sRGB") => Box::new(|v| v),
            Some("linear") => Box::new(crate::image_io::linear_to_srgb),
            Some(g) => match g
                .strip_prefix("gamma ")
                .and_then(|v| v.trim().parse::<f32>().ok())
            {
                Some(gamma) if gamma > 0.0 => {
                    Box::new(move |v| crate::image_io::linear_to_srgb(v).powf(gamma))
                }
                _ => {
                    return Err(self.cx.err(
                        line,
                        format!("unknown encoding \"{g}\": expected sRGB, linear or \"gamma G\""),
                    ))
                }
            },
        };
        if let Some(i) = img.data.iter().position(|c| !c.is_finite()) {
            return Err(self
                .cx
                .err(line, format!("image `{file}`: pixel {i} is not finite")));
        }
        let data: Vec<Rgb> = img
            .data
            .iter()
            .map(|c| c.map(&decode).max(Rgb::ZERO))
            .collect();
        let tex = Arc::new(TexImage::new(img.width, img.height, data));
        self.images.insert(key, tex.clone());
        Ok(tex)
    }
}

/// pbrt-v4's equal-area octahedral mapping of a unit direction to [0, 1]²
/// (Clarberg's, `EqualAreaSphereToSquare`).
fn equal_area_sphere_to_square(d: Vec3) -> Vec2 {
    let (x, y, z) = (d.x.abs(), d.y.abs(), d.z.abs());
    let r = (1.0 - z).max(0.0).sqrt();
    let a = x.max(y);
    let b = if a == 0.0 { 0.0 } else { x.min(y) / a };
    let mut phi = b.atan() * 2.0 / PI;
    if x < y {
        phi = 1.0 - phi;
    }
    let mut v = phi * r;
    let mut u = r - v;
    if d.z < 0.0 {
        std::mem::swap(&mut u, &mut v);
        u = 1.0 - u;
        v = 1.0 - v;
    }
    u = u.copysign(d.x);
    v = v.copysign(d.y);
    Vec2::new(0.5 * (u + 1.0), 0.5 * (v + 1.0))
}

/// Resamples a square equal-area environment image (pbrt-v4's format,
/// directions in the light's space) to the latitude–longitude map that
/// kalos's environment emitter reads, whose pixel (x, y) looks along
/// (sin θ sin φ, cos θ, −sin θ cos φ), θ = π(y+½)/h, φ = 2π(x+½)/w.
fn equal_area_to_latlong(img: &TexImage) -> TexImage {
    let n = img.width.max(1);
    let (w, h) = (2 * n, n);
    let mut data = Vec::with_capacity((w * h) as usize);
    for y in 0..h {
        let theta = PI * (y as f32 + 0.5) / h as f32;
        for x in 0..w {
            let phi = 2.0 * PI * (x as f32 + 0.5) / w as f32;
            let (st, ct) = theta.sin_cos();
            let dir = Vec3::new(st * phi.sin(), ct, -st * phi.cos());
            let uv = equal_area_sphere_to_square(dir);
            // pbrt's image row 0 is v = 0
            let px = ((uv.x * n as f32) as i64).clamp(0, n as i64 - 1);
            let py = ((uv.y * img.height as f32) as i64).clamp(0, img.height as i64 - 1);
            data.push(img.texel(px, py));
        }
    }
    TexImage::new(w, h, data)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The mapping is pbrt's: +z at the centre, −z at the corners, +x at
    /// the right edge's middle; and it preserves area: uniformly spread
    /// directions fill the square's 4×4 cells equally (each cell's count
    /// is binomial, n = 64,000, p = 1/16, σ ≈ 242; 5σ allowed).
    #[test]
    fn equal_area_mapping() {
        let near = |a: Vec2, b: Vec2| (a - b).abs().max_element() < 1e-5;
        assert!(near(equal_area_sphere_to_square(Vec3::Z), Vec2::splat(0.5)));
        assert!(near(
            equal_area_sphere_to_square(Vec3::new(0.0, 0.0, -1.0)),
            Vec2::ONE
        ));
        assert!(near(
            equal_area_sphere_to_square(Vec3::X),
            Vec2::new(1.0, 0.5)
        ));
        assert!(near(
            equal_area_sphere_to_square(Vec3::Y),
            Vec2::new(0.5, 1.0)
        ));
        let n = 64_000;
        let mut cells = [0u32; 16];
        for i in 0..n {
            // a Fibonacci sphere: evenly spread directions
            let z = 1.0 - 2.0 * (i as f32 + 0.5) / n as f32;
            let phi = i as f32 * 2.399_963;
            let r = (1.0 - z * z).sqrt();
            let uv = equal_area_sphere_to_square(Vec3::new(r * phi.cos(), r * phi.sin(), z));
            let (cx, cy) = ((uv.x * 4.0) as usize, (uv.y * 4.0) as usize);
            cells[cy.min(3) * 4 + cx.min(3)] += 1;
        }
        let expect = n as f32 / 16.0;
        for c in cells {
            assert!((c as f32 - expect).abs() < 5.0 * 242.0, "{cells:?}");
        }
    }
}

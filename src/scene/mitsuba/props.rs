//! The parameters of one plugin element: [`Props`] marks what a plugin reads
//! (what is left unread is an error), and the typed parameter readers of
//! [`Builder`].

use glam::{Mat3, Mat4, Vec3};

use crate::scene::shapes::look_at;
use crate::scene::{MicrofacetKind, Rgb, Texture};

use super::builder::Builder;
use super::tables::{ior_table, spectrum_to_rgb, IOR_TABLE};
use super::xml::El;
use super::Result;

/// Tags that are nested objects (with or without a `name`), not parameters.
const OBJECT_TAGS: &[&str] = &[
    "bsdf",
    "emitter",
    "shape",
    "sensor",
    "film",
    "sampler",
    "rfilter",
    "integrator",
    "medium",
    "phase",
    "volume",
];

/// The children of one plugin element, with a flag per child that the plugin
/// read it: what is left unread at the end is an error.
pub(super) struct Props<'t> {
    pub(super) el: &'t El,
    pub(super) used: Vec<bool>,
}

impl<'t> Props<'t> {
    pub(super) fn new(el: &'t El) -> Self {
        Props {
            el,
            used: vec![false; el.children.len()],
        }
    }

    /// The parameter `name`, marked as read.
    fn find(&mut self, name: &str) -> Option<&'t El> {
        let el: &'t El = self.el;
        for (i, c) in el.children.iter().enumerate() {
            if !OBJECT_TAGS.contains(&c.tag.as_str()) && c.attr("name") == Some(name) {
                self.used[i] = true;
                return Some(c);
            }
        }
        None
    }

    /// Accepts parameters that change nothing for kalos.
    pub(super) fn ignore(&mut self, names: &[&str]) {
        let el: &'t El = self.el;
        for (i, c) in el.children.iter().enumerate() {
            if !OBJECT_TAGS.contains(&c.tag.as_str())
                && c.attr("name").is_some_and(|a| names.contains(&a))
            {
                self.used[i] = true;
            }
        }
    }

    /// The nested objects (and `<ref>`s) not read as parameters, marked read.
    pub(super) fn objects(&mut self) -> Vec<&'t El> {
        let el: &'t El = self.el;
        let mut out = Vec::new();
        for (i, c) in el.children.iter().enumerate() {
            if !self.used[i] && (OBJECT_TAGS.contains(&c.tag.as_str()) || c.tag == "ref") {
                self.used[i] = true;
                out.push(c);
            }
        }
        out
    }
}

impl<'t> Builder<'t> {
    // -- parameter readers -------------------------------------------------

    fn value<'a>(&self, el: &'a El, attr: &str) -> Result<&'a str> {
        el.attr(attr)
            .ok_or_else(|| self.err(el, format!("{} needs a `{attr}` attribute", el.describe())))
    }

    pub(super) fn number(&self, el: &El, attr: &str, s: &str) -> Result<f32> {
        match s.trim().parse::<f32>() {
            Ok(v) if v.is_finite() => Ok(v),
            _ => Err(self.err(
                el,
                format!(
                    "expected a number in `{attr}` of {}, found \"{s}\"",
                    el.describe()
                ),
            )),
        }
    }

    fn num(&self, el: &El, attr: &str) -> Result<f32> {
        let s = self.value(el, attr)?;
        self.number(el, attr, s)
    }

    /// A list of numbers separated by commas and/or white space.
    fn nums(&self, el: &El, attr: &str) -> Result<Vec<f32>> {
        let s = self.value(el, attr)?;
        s.split(|c: char| c == ',' || c.is_whitespace())
            .filter(|t| !t.is_empty())
            .map(|t| self.number(el, attr, t))
            .collect()
    }

    /// A vector from `value="x, y, z"` or from attributes `x`, `y`, `z`
    /// (each defaulting to `default`).
    fn xyz(&self, el: &El, default: f32) -> Result<Vec3> {
        if el.attr("value").is_some() {
            let v = self.nums(el, "value")?;
            return match v.as_slice() {
                [x, y, z] => Ok(Vec3::new(*x, *y, *z)),
                _ => Err(self.err(
                    el,
                    format!("expected 3 numbers in `value` of {}", el.describe()),
                )),
            };
        }
        let mut out = Vec3::splat(default);
        for (i, k) in ["x", "y", "z"].iter().enumerate() {
            if el.attr(k).is_some() {
                out[i] = self.num(el, k)?;
            }
        }
        Ok(out)
    }

    fn vec3_attr(&self, el: &El, attr: &str) -> Result<Vec3> {
        let v = self.nums(el, attr)?;
        match v.as_slice() {
            [x, y, z] => Ok(Vec3::new(*x, *y, *z)),
            _ => Err(self.err(
                el,
                format!("expected 3 numbers in `{attr}` of {}", el.describe()),
            )),
        }
    }

    fn expect_tag(&self, el: &El, tags: &[&str]) -> Result<()> {
        if tags.contains(&el.tag.as_str()) {
            Ok(())
        } else {
            let want: Vec<String> = tags.iter().map(|t| format!("<{t}>")).collect();
            Err(self.err(
                el,
                format!(
                    "parameter `{}` should be {}, found <{}>",
                    el.attr("name").unwrap_or("?"),
                    want.join(" or "),
                    el.tag
                ),
            ))
        }
    }

    pub(super) fn float_opt(&self, p: &mut Props<'t>, name: &str) -> Result<Option<f32>> {
        let Some(c) = p.find(name) else {
            return Ok(None);
        };
        self.expect_tag(c, &["float", "integer"])?;
        self.num(c, "value").map(Some)
    }

    pub(super) fn float(&self, p: &mut Props<'t>, name: &str, default: f32) -> Result<f32> {
        Ok(self.float_opt(p, name)?.unwrap_or(default))
    }

    pub(super) fn int(&self, p: &mut Props<'t>, name: &str, default: i64) -> Result<i64> {
        let Some(c) = p.find(name) else {
            return Ok(default);
        };
        self.expect_tag(c, &["integer"])?;
        let s = self.value(c, "value")?;
        s.trim().parse::<i64>().map_err(|_| {
            self.err(
                c,
                format!(
                    "expected an integer in `value` of {}, found \"{s}\"",
                    c.describe()
                ),
            )
        })
    }

    pub(super) fn boolean(&self, p: &mut Props<'t>, name: &str, default: bool) -> Result<bool> {
        let Some(c) = p.find(name) else {
            return Ok(default);
        };
        self.expect_tag(c, &["boolean"])?;
        let s = self.value(c, "value")?;
        match s.trim().to_ascii_lowercase().as_str() {
            "true" | "1" => Ok(true),
            "false" | "0" => Ok(false),
            _ => Err(self.err(
                c,
                format!("expected true or false in {}, found \"{s}\"", c.describe()),
            )),
        }
    }

    pub(super) fn string(&self, p: &mut Props<'t>, name: &str) -> Result<Option<&'t str>> {
        let Some(c) = p.find(name) else {
            return Ok(None);
        };
        self.expect_tag(c, &["string"])?;
        self.value(c, "value").map(Some)
    }

    pub(super) fn point(&self, p: &mut Props<'t>, name: &str) -> Result<Option<Vec3>> {
        let Some(c) = p.find(name) else {
            return Ok(None);
        };
        self.expect_tag(c, &["point", "vector"])?;
        self.xyz(c, 0.0).map(Some)
    }

    pub(super) fn transform(&self, p: &mut Props<'t>, name: &str) -> Result<Option<Mat4>> {
        let Some(c) = p.find(name) else {
            return Ok(None);
        };
        self.expect_tag(c, &["transform"])?;
        self.transform_el(c).map(Some)
    }

    /// A `<transform>`: its operations composed in document order, each new
    /// one multiplied on the left (M = T_new · M).
    fn transform_el(&self, t: &El) -> Result<Mat4> {
        let mut m = Mat4::IDENTITY;
        for op in &t.children {
            let step = match op.tag.as_str() {
                "translate" => Mat4::from_translation(self.xyz(op, 0.0)?),
                "scale" => {
                    let s = if op.attr("value").is_some() {
                        match self.nums(op, "value")?.as_slice() {
                            [s] => Vec3::splat(*s),
                            [x, y, z] => Vec3::new(*x, *y, *z),
                            _ => {
                                return Err(
                                    self.err(op, "expected 1 or 3 numbers in `value` of <scale>")
                                )
                            }
                        }
                    } else {
                        self.xyz(op, 1.0)?
                    };
                    Mat4::from_scale(s)
                }
                "rotate" => {
                    let axis = if op.attr("axis").is_some() {
                        self.vec3_attr(op, "axis")?
                    } else {
                        self.xyz(op, 0.0)?
                    };
                    let angle = self.num(op, "angle")?;
                    let axis = axis
                        .try_normalize()
                        .ok_or_else(|| self.err(op, "<rotate> needs a non-zero axis"))?;
                    Mat4::from_axis_angle(axis, angle.to_radians())
                }
                "matrix" => {
                    let v = self.nums(op, "value")?;
                    match v.len() {
                        // row-major in the file; glam's arrays are column-major
                        16 => {
                            let mut a = [0.0f32; 16];
                            a.copy_from_slice(&v);
                            Mat4::from_cols_array(&a).transpose()
                        }
                        9 => {
                            let mut a = [0.0f32; 9];
                            a.copy_from_slice(&v);
                            Mat4::from_mat3(Mat3::from_cols_array(&a).transpose())
                        }
                        n => {
                            return Err(self
                                .err(op, format!("<matrix> needs 16 (or 9) numbers, found {n}")))
                        }
                    }
                }
                "lookat" => {
                    let origin = self.vec3_attr(op, "origin")?;
                    let target = self.vec3_attr(op, "target")?;
                    let up = if op.attr("up").is_some() {
                        self.vec3_attr(op, "up")?
                    } else {
                        // Mitsuba's choice: any vector perpendicular to the view
                        let dir = (target - origin).normalize_or(Vec3::Z);
                        crate::geometry::Frame::from_normal(dir).s
                    };
                    look_at(origin, target, up).ok_or_else(|| {
                        self.err(
                            op,
                            "<lookat>: target equals origin, or up is parallel to the view",
                        )
                    })?
                }
                _ => return Err(self.err(op, format!("unknown transform operation <{}>", op.tag))),
            };
            m = step * m;
        }
        if !m.is_finite() {
            return Err(self.err(t, "the transform is not finite"));
        }
        Ok(m)
    }

    /// A constant colour from `<rgb>`, `<float>` or `<spectrum>`.
    fn const_color_el(&self, c: &El) -> Result<Rgb> {
        match c.tag.as_str() {
            "rgb" => match self.nums(c, "value")?.as_slice() {
                [v] => Ok(Rgb::splat(*v)),
                [r, g, b] => Ok(Rgb::new(*r, *g, *b)),
                _ => Err(self.err(c, format!("expected 1 or 3 numbers in {}", c.describe()))),
            },
            "float" | "integer" => Ok(Rgb::splat(self.num(c, "value")?)),
            "spectrum" => {
                if c.attr("filename").is_some() || c.attr("type").is_some() {
                    return Err(self.err(
                        c,
                        "spectra from files or plugins are not supported: give <rgb> or \
                         `λ:value` pairs",
                    ));
                }
                let s = self.value(c, "value")?;
                if !s.contains(':') {
                    return match self.nums(c, "value")?.as_slice() {
                        [v] => Ok(Rgb::splat(*v)),
                        _ => Err(self.err(
                            c,
                            "expected one number or a list of `wavelength:value` pairs",
                        )),
                    };
                }
                let mut pairs = Vec::new();
                for item in s.split(',').map(str::trim).filter(|t| !t.is_empty()) {
                    let (l, v) = item.split_once(':').ok_or_else(|| {
                        self.err(c, format!("expected `wavelength:value`, found \"{item}\""))
                    })?;
                    pairs.push((self.number(c, "value", l)?, self.number(c, "value", v)?));
                }
                if pairs.windows(2).any(|w| w[1].0 <= w[0].0) {
                    return Err(self.err(c, "spectrum wavelengths must increase"));
                }
                if let Some((l, v)) = pairs.iter().find(|(_, v)| *v < 0.0) {
                    return Err(self.err(c, format!("spectrum value {v} at {l} nm is negative")));
                }
                // the rough conversion may dip below zero on a channel
                Ok(spectrum_to_rgb(&pairs).max(Rgb::ZERO))
            }
            _ => Err(self.err(
                c,
                format!(
                    "parameter `{}` should be a colour (<rgb>, <float> or <spectrum>), found <{}>",
                    c.attr("name").unwrap_or("?"),
                    c.tag
                ),
            )),
        }
    }

    pub(super) fn color_const(&self, p: &mut Props<'t>, name: &str) -> Result<Option<Rgb>> {
        match p.find(name) {
            Some(c) => self.non_negative(p.el, c, name).map(Some),
            None => Ok(None),
        }
    }

    /// A constant colour of `plugin`, which no reflectance, transmittance
    /// or radiance may have negative: the light it would subtract has no
    /// meaning, and samplers weighting by it would drop it silently.
    fn non_negative(&self, plugin: &El, c: &El, name: &str) -> Result<Rgb> {
        let v = self.const_color_el(c)?;
        if v.min_element() >= 0.0 {
            return Ok(v);
        }
        Err(self.err(
            c,
            format!(
                "`{name}` of {} must be non-negative, found ({}, {}, {})",
                plugin.describe(),
                v.x,
                v.y,
                v.z
            ),
        ))
    }

    /// A colour parameter: a constant or a texture (inline or by reference).
    pub(super) fn color(&mut self, p: &mut Props<'t>, name: &str, default: f32) -> Result<Texture> {
        let Some(c) = p.find(name) else {
            return Ok(Texture::Constant(Rgb::splat(default)));
        };
        match c.tag.as_str() {
            "texture" => self.texture(c),
            "ref" => {
                let target = self.lookup(c)?;
                if target.tag == "texture" {
                    self.texture(target)
                } else {
                    Err(self.err(
                        c,
                        format!(
                            "`{name}` should refer to a <texture>, not {}",
                            target.describe()
                        ),
                    ))
                }
            }
            _ => self.non_negative(p.el, c, name).map(Texture::Constant),
        }
    }

    /// An index of refraction: a number or a named material.
    pub(super) fn ior(&self, p: &mut Props<'t>, name: &str, default: f32) -> Result<f32> {
        let Some(c) = p.find(name) else {
            return Ok(default);
        };
        match c.tag.as_str() {
            "float" | "integer" => self.num(c, "value"),
            "string" => {
                let s = self.value(c, "value")?;
                ior_table(s).ok_or_else(|| {
                    let known: Vec<&str> = IOR_TABLE.iter().map(|(n, _)| *n).collect();
                    self.err(
                        c,
                        format!(
                            "unknown material `{s}` for `{name}`; known: {}",
                            known.join(", ")
                        ),
                    )
                })
            }
            _ => Err(self.err(c, format!("`{name}` should be a <float> or a <string>"))),
        }
    }

    pub(super) fn distribution(&self, p: &mut Props<'t>) -> Result<MicrofacetKind> {
        let Some(c) = p.find("distribution") else {
            // Mitsuba 3's default for every rough plugin
            return Ok(MicrofacetKind::Beckmann);
        };
        self.expect_tag(c, &["string"])?;
        match self.value(c, "value")? {
            "beckmann" => Ok(MicrofacetKind::Beckmann),
            "ggx" => Ok(MicrofacetKind::Ggx),
            s => Err(self.err(
                c,
                format!("unknown distribution `{s}`: expected `beckmann` or `ggx`"),
            )),
        }
    }

    pub(super) fn alpha(&mut self, p: &mut Props<'t>) -> Result<f32> {
        let au = self.float_opt(p, "alpha_u")?;
        let av = self.float_opt(p, "alpha_v")?;
        let a = match (au, av) {
            (Some(u), Some(v)) => {
                let el = p.el;
                self.warn(
                    el,
                    format!("anisotropic roughness ({u}, {v}) replaced by its mean"),
                );
                0.5 * (u + v)
            }
            (None, None) => self.float(p, "alpha", 0.1)?,
            _ => return Err(self.err(p.el, "give both `alpha_u` and `alpha_v`")),
        };
        if a.is_nan() || a <= 0.0 {
            return Err(self.err(p.el, format!("roughness alpha must be positive, found {a}")));
        }
        Ok(a)
    }
}

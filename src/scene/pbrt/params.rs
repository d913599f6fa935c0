//! The parameter list of one directive: typed readers that mark what a
//! directive reads, so that what is left is an error naming the parameter
//! and its line (STYLE.md rule 10, as `Props` for Mitsuba).

use glam::{Vec2, Vec3};
use pbrt4::param::ParamType;

use super::lexer::{Directive, Param, Values};
use super::Ctx;
use crate::scene::SceneError;

type Result<T> = std::result::Result<T, SceneError>;

/// The parameters of one directive, with a flag per parameter that it was
/// read. `what` names the directive in messages (`Shape "sphere"`).
pub(super) struct Params<'d> {
    pub(super) list: Vec<&'d Param>,
    used: Vec<bool>,
    pub(super) what: String,
    pub(super) line: u32,
}

impl<'d> Params<'d> {
    /// The directive's own parameters, then the `Attribute` defaults of its
    /// kind that it does not override.
    pub(super) fn new(d: &'d Directive, what: String, defaults: &'d [Param]) -> Self {
        let mut list: Vec<&Param> = d.params.iter().collect();
        for p in defaults {
            if !list.iter().any(|q| q.name == p.name) {
                list.push(p);
            }
        }
        let n = list.len();
        Params {
            list,
            used: vec![false; n],
            what,
            line: d.line,
        }
    }

    /// The parameter `name`, marked read.
    pub(super) fn take(&mut self, name: &str) -> Option<&'d Param> {
        let i = self.list.iter().position(|p| p.name == name)?;
        self.used[i] = true;
        Some(self.list[i])
    }

    /// Whether the list has `name` (without marking it).
    pub(super) fn has(&self, name: &str) -> bool {
        self.list.iter().any(|p| p.name == name)
    }

    /// Accepts parameters that change nothing for kalos.
    pub(super) fn ignore(&mut self, names: &[&str]) {
        for (i, p) in self.list.iter().enumerate() {
            if names.contains(&p.name.as_str()) {
                self.used[i] = true;
            }
        }
    }

    /// The names of the parameters given but not read, marked read (for a
    /// warning that lists what a stand-in ignores).
    pub(super) fn rest(&mut self) -> Vec<String> {
        let mut out = Vec::new();
        for (i, p) in self.list.iter().enumerate() {
            if !self.used[i] {
                self.used[i] = true;
                out.push(p.name.clone());
            }
        }
        out
    }

    /// Reports the first parameter not read.
    pub(super) fn finish(&self, cx: &Ctx) -> Result<()> {
        for (p, used) in self.list.iter().zip(&self.used) {
            if !used {
                return Err(cx.err(
                    p.line,
                    format!(
                        "unknown parameter \"{} {}\" of {} (misspelt, or not supported by kalos)",
                        p.ty_name, p.name, self.what
                    ),
                ));
            }
        }
        Ok(())
    }

    fn nums(&self, cx: &Ctx, p: &'d Param, types: &[ParamType]) -> Result<&'d [f64]> {
        if !types.contains(&p.ty) {
            return Err(cx.err(
                p.line,
                format!(
                    "parameter `{}` of {} has type `{}`; expected {}",
                    p.name,
                    self.what,
                    p.ty_name,
                    types.iter().map(type_name).collect::<Vec<_>>().join(" or ")
                ),
            ));
        }
        match &p.values {
            Values::Nums(v) => Ok(v.as_slice()),
            _ => Err(cx.err(
                p.line,
                format!("parameter `{}` of {} takes numbers", p.name, self.what),
            )),
        }
    }

    fn one(&self, cx: &Ctx, p: &'d Param, types: &[ParamType]) -> Result<f64> {
        match self.nums(cx, p, types)? {
            [v] => Ok(*v),
            v => Err(cx.err(
                p.line,
                format!(
                    "parameter `{}` of {} takes one value, found {}",
                    p.name,
                    self.what,
                    v.len()
                ),
            )),
        }
    }

    /// A float (an integer is accepted, as pbrt does not).
    pub(super) fn float(&mut self, cx: &Ctx, name: &str, default: f32) -> Result<f32> {
        match self.take(name) {
            None => Ok(default),
            Some(p) => Ok(self.one(cx, p, &[ParamType::Float, ParamType::Integer])? as f32),
        }
    }

    /// An integer.
    pub(super) fn int(&mut self, cx: &Ctx, name: &str, default: i64) -> Result<i64> {
        match self.take(name) {
            None => Ok(default),
            Some(p) => {
                let v = self.one(cx, p, &[ParamType::Integer])?;
                if v.fract() != 0.0 || v.abs() > 2f64.powi(53) {
                    return Err(cx.err(
                        p.line,
                        format!(
                            "parameter `{name}` of {} takes an integer, found {v}",
                            self.what
                        ),
                    ));
                }
                Ok(v as i64)
            }
        }
    }

    /// A boolean.
    pub(super) fn boolean(&mut self, cx: &Ctx, name: &str, default: bool) -> Result<bool> {
        let Some(p) = self.take(name) else {
            return Ok(default);
        };
        match (&p.ty, &p.values) {
            (ParamType::Boolean, Values::Bools(v)) if v.len() == 1 => Ok(v[0]),
            _ => Err(cx.err(
                p.line,
                format!(
                    "parameter `{name}` of {} takes one bool (true or false)",
                    self.what
                ),
            )),
        }
    }

    /// A string.
    pub(super) fn string(&mut self, cx: &Ctx, name: &str) -> Result<Option<&'d str>> {
        let Some(p) = self.take(name) else {
            return Ok(None);
        };
        match (&p.ty, &p.values) {
            (ParamType::String, Values::Strs(v)) if v.len() == 1 => Ok(Some(v[0].as_str())),
            _ => Err(cx.err(
                p.line,
                format!("parameter `{name}` of {} takes one string", self.what),
            )),
        }
    }

    /// A list of strings (mix's `materials`).
    pub(super) fn strings(&mut self, cx: &Ctx, name: &str) -> Result<Option<&'d [String]>> {
        let Some(p) = self.take(name) else {
            return Ok(None);
        };
        match (&p.ty, &p.values) {
            (ParamType::String, Values::Strs(v)) => Ok(Some(v.as_slice())),
            _ => Err(cx.err(
                p.line,
                format!("parameter `{name}` of {} takes strings", self.what),
            )),
        }
    }

    /// Integers (indices).
    pub(super) fn ints(&mut self, cx: &Ctx, name: &str) -> Result<Option<Vec<i64>>> {
        let Some(p) = self.take(name) else {
            return Ok(None);
        };
        let v = self.nums(cx, p, &[ParamType::Integer])?;
        if let Some(x) = v.iter().find(|x| x.fract() != 0.0) {
            return Err(cx.err(
                p.line,
                format!(
                    "parameter `{name}` of {} takes integers, found {x}",
                    self.what
                ),
            ));
        }
        Ok(Some(v.iter().map(|x| *x as i64).collect()))
    }

    /// 3-vectors (`point3`, `vector3`, `normal`), given as a flat list.
    pub(super) fn vec3s(
        &mut self,
        cx: &Ctx,
        name: &str,
        types: &[ParamType],
    ) -> Result<Option<Vec<Vec3>>> {
        let Some(p) = self.take(name) else {
            return Ok(None);
        };
        let v = self.nums(cx, p, types)?;
        if v.len() % 3 != 0 {
            return Err(cx.err(
                p.line,
                format!(
                    "parameter `{name}` of {} has {} numbers, not a multiple of 3",
                    self.what,
                    v.len()
                ),
            ));
        }
        Ok(Some(
            v.chunks_exact(3)
                .map(|c| Vec3::new(c[0] as f32, c[1] as f32, c[2] as f32))
                .collect(),
        ))
    }

    /// 2-vectors (`point2` uvs; pbrt-v3's `float uv` too).
    pub(super) fn vec2s(&mut self, cx: &Ctx, name: &str) -> Result<Option<Vec<Vec2>>> {
        let Some(p) = self.take(name) else {
            return Ok(None);
        };
        let v = self.nums(
            cx,
            p,
            &[ParamType::Point2, ParamType::Vector2, ParamType::Float],
        )?;
        if v.len() % 2 != 0 {
            return Err(cx.err(
                p.line,
                format!(
                    "parameter `{name}` of {} has {} numbers, not a multiple of 2",
                    self.what,
                    v.len()
                ),
            ));
        }
        Ok(Some(
            v.chunks_exact(2)
                .map(|c| Vec2::new(c[0] as f32, c[1] as f32))
                .collect(),
        ))
    }
}

/// A parameter type as a file spells it.
pub(super) fn type_name(t: &ParamType) -> &'static str {
    match t {
        ParamType::Boolean => "bool",
        ParamType::Float => "float",
        ParamType::Integer => "integer",
        ParamType::Point2 => "point2",
        ParamType::Point3 => "point3",
        ParamType::Vector2 => "vector2",
        ParamType::Vector3 => "vector3",
        ParamType::Normal3 | ParamType::Normal => "normal",
        ParamType::Spectrum => "spectrum",
        ParamType::Rgb => "rgb",
        ParamType::Blackbody => "blackbody",
        ParamType::String => "string",
        ParamType::Texture => "texture",
    }
}

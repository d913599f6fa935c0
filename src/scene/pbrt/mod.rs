//! pbrt-v4 scene files (`.pbrt`), the subset a renderer of surfaces needs,
//! built onto kalos's [`Scene`].
//!
//! ```text
//! LookAt 0 1 5  0 1 0  0 1 0
//! Camera "perspective" "float fov" [45]
//! Film "rgb" "integer xresolution" [256] "integer yresolution" [256]
//! WorldBegin
//! AttributeBegin
//!     AreaLightSource "diffuse" "rgb L" [10 10 10]
//!     Shape "sphere" "float radius" 0.2
//! AttributeEnd
//! Material "diffuse" "rgb reflectance" [0.5 0.5 0.5]
//! Shape "trianglemesh" "point3 P" [-1 0 -1  1 0 -1  1 0 1  -1 0 1]
//!     "integer indices" [0 1 2  0 2 3]
//! ```
//!
//! # What is read
//!
//! - `Include` and `Import` (both splice the file in; relative paths
//!   resolve against the main file's folder, as in pbrt-v4); `Translate`,
//!   `Scale`, `Rotate`, `LookAt`, `Transform`, `ConcatTransform`,
//!   `Identity`, `CoordinateSystem`, `CoordSysTransform` (`camera` and
//!   `world` included), `TransformBegin`/`End`; `AttributeBegin`/`End`,
//!   `Attribute` (defaults for shapes, lights, materials, textures);
//!   `ReverseOrientation`; `ObjectBegin`/`End`/`ObjectInstance`.
//! - shapes `trianglemesh`, `plymesh` (through kalos's PLY reader),
//!   `sphere`, `disk`, `bilinearmesh` (each patch as two triangles) and
//!   `loopsubdiv` (its control mesh, with a warning). Spheres are
//!   tessellated as the Mitsuba loader's are.
//! - materials `diffuse`, `coateddiffuse` (as Mitsuba's `plastic` /
//!   `roughplastic`), `conductor` (`eta`/`k` or `reflectance`, roughness),
//!   `dielectric`, `thindielectric`; `mix`, `diffusetransmission`,
//!   `coatedconductor` and pbrt's other materials get a stand-in and a note
//!   in [`Scene::notes`] naming both. `interface` hides its shapes.
//!   Reflecting materials are two-sided, as every pbrt surface is.
//! - textures `imagemap`, `checkerboard` (2D), `constant`, and `scale` /
//!   `mix` where their inputs are constants (a scaled image or checkerboard
//!   too).
//! - lights: `diffuse` area lights, `infinite` (constant `L`, or an
//!   equal-area image `filename`, resampled to a latitude–longitude map).
//! - the `perspective` camera (`fov` on the shorter image axis) and the
//!   `rgb` film's `xresolution`/`yresolution`; the `Sampler`'s
//!   `pixelsamples` becomes [`Scene::sample_count`].
//! - spectra: see [`spectra`] for how each form becomes RGB.
//!
//! pbrt's camera space is left-handed (its +x is the image's right), so
//! the camera keeps pbrt's image, not a mirror of it.
//!
//! # What is skipped, with a warning in [`Scene::warnings`]
//!
//! `Integrator`, `PixelFilter` other than box, `ColorSpace` other than
//! srgb, `Option`, participating media (`MakeNamedMedium`,
//! `MediumInterface`), motion blur (`ActiveTransform`, `TransformTimes`),
//! depth of field, shape `alpha`, and a two-sided area light (it emits from
//! its front side only).
//!
//! # What is an error
//!
//! Every error names the file and the line: an unknown directive, shape,
//! material, texture or light type; `point`, `spot`, `distant`,
//! `goniometric` and `projection` lights (kalos's methods need lights with
//! an area); an unknown or ill-typed parameter; a missing file; a file
//! the scene may not read (outside its folder and the `--allow-read`
//! folders, not a regular file, or past its kind's size limit: see
//! [`crate::scene::access`]); a `.gz` file that is not valid gzip or
//! expands past that limit; a scene past the memory limit (its meshes,
//! instance copies and images are declared before they are made); an
//! unmatched `AttributeEnd`. Includes nest at most 16 deep and a scene
//! reads at most 4096 of them. Files whose names end in `.gz`
//! (`.pbrt.gz`, `.ply.gz`, spectra) are decompressed as they are read.

mod lexer;
mod light;
mod material;
mod params;
mod shape;
pub mod spectra;

use crate::scene::access::{FileAccess, FileKind};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

use glam::{Mat4, Vec3};

use super::{Scene, SceneError, Texture};
use lexer::{Arg, Directive, Param};
use params::Params;

type Result<T> = std::result::Result<T, SceneError>;

/// Deepest chain of includes.
const MAX_INCLUDE_DEPTH: usize = 16;
/// Most includes read for one scene.
const MAX_INCLUDES: usize = 4096;

/// Where messages point: the file being read, and the main file's folder
/// that relative paths resolve against.
#[derive(Clone, Debug)]
pub(super) struct Ctx {
    file: PathBuf,
    main_dir: PathBuf,
    /// What the scene's files are read through.
    access: FileAccess,
}

impl Ctx {
    /// An error at `line` of the current file.
    pub(super) fn err(&self, line: u32, msg: impl Into<String>) -> SceneError {
        SceneError::new(&self.file, line, msg)
    }

    /// `file:line: msg`, for warnings and notes.
    pub(super) fn at(&self, line: u32, msg: impl AsRef<str>) -> String {
        format!("{}:{line}: {}", self.file.display(), msg.as_ref())
    }

    /// A path of the scene, relative to the main file's folder.
    pub(super) fn resolve(&self, name: &str) -> PathBuf {
        let p = Path::new(name);
        if p.is_absolute() {
            p.to_path_buf()
        } else {
            self.main_dir.join(p)
        }
    }
}

/// What a shape is made of at the time it is declared.
#[derive(Clone, Debug)]
struct Graphics {
    ctm: Mat4,
    reverse_orientation: bool,
    /// The current material (an index into the scene's materials), `None`
    /// for `interface`.
    material: Option<Option<u32>>,
    /// The current area light's radiance.
    area_light: Option<glam::Vec3>,
    /// `Attribute` defaults: shape, light, material, texture.
    attrs: [Vec<Param>; 4],
}

/// An `ObjectBegin` definition: its shapes, kept in world space of the
/// definition, to be copied under each `ObjectInstance`'s transform.
#[derive(Default)]
struct Object {
    shapes: Vec<shape::Built>,
    line: u32,
}

struct Builder {
    cx: Ctx,
    scene: Scene,
    g: Graphics,
    stack: Vec<(Graphics, u32)>,
    transform_stack: Vec<Mat4>,
    named_coords: HashMap<String, Mat4>,
    named_materials: HashMap<String, Option<u32>>,
    textures: HashMap<String, Texture>,
    float_textures: HashMap<String, Texture>,
    objects: HashMap<String, Object>,
    /// The object being defined: its name.
    defining: Option<String>,
    default_material: Option<u32>,
    camera: Option<light::CameraSpec>,
    film: (u32, u32),
    world: bool,
    /// Spheres and instances wait for the whole scene (see `shape.rs`).
    pending: Vec<shape::Built>,
    includes: usize,
    /// Warnings given once per scene (media, motion blur).
    once: std::collections::HashSet<&'static str>,
    images: HashMap<(PathBuf, String), std::sync::Arc<crate::scene::TexImage>>,
}

/// Loads a pbrt-v4 scene file, reading its files through `access`.
pub fn load(path: &Path, access: &FileAccess) -> Result<Scene> {
    let main_dir = path.parent().unwrap_or(Path::new(".")).to_path_buf();
    let mut b = Builder {
        cx: Ctx {
            file: path.to_path_buf(),
            main_dir,
            access: access.clone(),
        },
        scene: Scene::empty(path.display().to_string()),
        g: Graphics {
            ctm: Mat4::IDENTITY,
            reverse_orientation: false,
            material: None,
            area_light: None,
            attrs: Default::default(),
        },
        stack: Vec::new(),
        transform_stack: Vec::new(),
        named_coords: HashMap::new(),
        named_materials: HashMap::new(),
        textures: HashMap::new(),
        float_textures: HashMap::new(),
        objects: HashMap::new(),
        defining: None,
        default_material: None,
        camera: None,
        film: (1280, 720),
        world: false,
        pending: Vec::new(),
        includes: 0,
        once: Default::default(),
        images: HashMap::new(),
    };
    b.read_file(path, 0, 0)?;
    if let Some((_, line)) = b.stack.last() {
        let msg = b.cx.at(*line, "AttributeBegin without AttributeEnd");
        b.scene.warnings.push(msg);
    }
    if let Some(name) = &b.defining {
        return Err(b
            .cx
            .err(0, format!("ObjectBegin \"{name}\" has no ObjectEnd")));
    }
    b.add_pending();
    b.finish_camera()?;
    if b.scene.triangles.is_empty() && b.scene.emitters.is_empty() {
        return Err(SceneError::new(
            path,
            0,
            "the scene has no shapes and no lights",
        ));
    }
    Ok(b.scene)
}

impl Builder {
    /// Reads one file (the main one, or an `Include`/`Import` from `line`
    /// of the including file) and runs its directives.
    fn read_file(&mut self, path: &Path, depth: usize, line: u32) -> Result<()> {
        let text = if depth == 0 {
            let bytes = crate::scene::mitsuba::files::read_main(path, &self.cx.access)
                .and_then(|b| spectra::gunzip(&self.cx.access, path, b, FileKind::Scene))
                .map_err(|e| {
                    SceneError::new(path, 0, crate::scene::mitsuba::files::main_message(&e))
                })?;
            spectra::utf8(bytes).map_err(|m| SceneError::new(path, 0, m))?
        } else {
            let bytes = spectra::read_file(&self.cx.access, path, FileKind::Scene)
                .map_err(|e| self.cx.err(line, e.to_string()))?;
            spectra::utf8(bytes).map_err(|m| {
                self.cx
                    .err(line, format!("scene file `{}`: {m}", path.display()))
            })?
        };
        let outer = std::mem::replace(&mut self.cx.file, path.to_path_buf());
        let r = lexer::tokenize(&text)
            .and_then(|t| lexer::directives(&t))
            .map_err(|(l, m)| self.cx.err(l, m))
            .and_then(|ds| {
                for d in &ds {
                    self.directive(d, depth)?;
                }
                Ok(())
            });
        self.cx.file = outer;
        r
    }

    fn warn(&mut self, line: u32, msg: impl AsRef<str>) {
        let w = self.cx.at(line, msg);
        self.scene.warnings.push(w);
    }

    fn warn_once(&mut self, key: &'static str, line: u32, msg: &str) {
        if self.once.insert(key) {
            self.warn(line, msg);
        }
    }

    fn nums(&self, d: &Directive, n: usize) -> Result<Vec<f32>> {
        let v: Vec<f32> = d
            .args
            .iter()
            .filter_map(|a| match a {
                Arg::Num(x) => Some(*x as f32),
                Arg::Str(_) => None,
            })
            .collect();
        if v.len() != n || d.args.len() != n {
            return Err(self.cx.err(
                d.line,
                format!("`{}` takes {n} numbers, found {}", d.name, d.args.len()),
            ));
        }
        Ok(v)
    }

    fn strs<'d>(&self, d: &'d Directive, n: usize) -> Result<Vec<&'d str>> {
        let v: Vec<&str> = d
            .args
            .iter()
            .filter_map(|a| match a {
                Arg::Str(s) => Some(s.as_str()),
                Arg::Num(_) => None,
            })
            .collect();
        if v.len() != n || d.args.len() != n {
            return Err(self.cx.err(
                d.line,
                format!(
                    "`{}` takes {n} quoted string(s), found {} argument(s)",
                    d.name,
                    d.args.len()
                ),
            ));
        }
        Ok(v)
    }

    fn transform(&mut self, d: &Directive, m: Mat4) -> Result<()> {
        if !m.is_finite() {
            return Err(self
                .cx
                .err(d.line, format!("`{}` gives a non-finite transform", d.name)));
        }
        self.g.ctm *= m;
        Ok(())
    }

    /// Runs one directive: checks that it takes the parameters it was
    /// given, then hands it to the function of its family.
    fn directive(&mut self, d: &Directive, depth: usize) -> Result<()> {
        self.check_params(d)?;
        match d.name.as_str() {
            "Include" | "Import" => self.include(d, depth),
            "Identity" | "Translate" | "Scale" | "Rotate" | "LookAt" | "Transform"
            | "ConcatTransform" | "CoordinateSystem" | "CoordSysTransform" | "TransformBegin"
            | "TransformEnd" | "ActiveTransform" | "TransformTimes" | "ReverseOrientation" => {
                self.transform_directive(d)
            }
            "Camera" => self.camera(d),
            "Film" => self.film(d),
            "Sampler" => self.sampler(d),
            "Integrator" | "PixelFilter" | "ColorSpace" | "Accelerator" | "Option"
            | "WorldBegin" | "WorldEnd" | "MakeNamedMedium" | "MediumInterface" => {
                self.option_directive(d)
            }
            "AttributeBegin" | "AttributeEnd" | "Attribute" => self.attribute_directive(d),
            "ObjectBegin" | "ObjectEnd" | "ObjectInstance" => self.object_directive(d),
            "LightSource" => self.light(d),
            "AreaLightSource" => self.area_light(d),
            "Material" | "MakeNamedMaterial" | "NamedMaterial" => self.material_directive(d),
            "Texture" => self.texture(d),
            "Shape" => self.shape(d),
            _ => Err(self.unsupported(d)),
        }
    }

    /// The error for a directive kalos does not know.
    fn unsupported(&self, d: &Directive) -> SceneError {
        self.cx
            .err(d.line, format!("unsupported directive `{}`", d.name))
    }

    /// Refuses parameters on a directive that takes none.
    fn check_params(&self, d: &Directive) -> Result<()> {
        const WITH_PARAMS: &[&str] = &[
            "Accelerator",
            "AreaLightSource",
            "Attribute",
            "Camera",
            "Film",
            "Integrator",
            "LightSource",
            "MakeNamedMaterial",
            "MakeNamedMedium",
            "Material",
            "Option",
            "PixelFilter",
            "Sampler",
            "Shape",
            "Texture",
        ];
        if let Some(p) = d
            .params
            .first()
            .filter(|_| !WITH_PARAMS.contains(&d.name.as_str()))
        {
            return Err(self.cx.err(
                p.line,
                format!(
                    "`{}` takes no parameters, found \"{} {}\"",
                    d.name, p.ty_name, p.name
                ),
            ));
        }
        Ok(())
    }

    /// `Include` and `Import`: reads the named file, `depth + 1` deep.
    fn include(&mut self, d: &Directive, depth: usize) -> Result<()> {
        let line = d.line;
        let name = self.strs(d, 1)?[0];
        if depth + 1 > MAX_INCLUDE_DEPTH {
            return Err(self.cx.err(
                line,
                format!("includes nest more than {MAX_INCLUDE_DEPTH} deep (a cycle?)"),
            ));
        }
        self.includes += 1;
        if self.includes > MAX_INCLUDES {
            return Err(self.cx.err(
                line,
                format!("more than {MAX_INCLUDES} includes in one scene"),
            ));
        }
        let path = self.cx.resolve(name);
        // checked (inside the allowed folders, a regular file) before it
        // is read, naming this line
        self.cx.access.check(&path, FileKind::Scene).map_err(|e| {
            let what = format!("{} file", d.name);
            self.cx
                .err(line, crate::scene::mitsuba::files::message(&what, name, &e))
        })?;
        self.read_file(&path, depth + 1, line)
    }

    /// The transform directives: they set, compose, name, push and pop the
    /// current transformation matrix, or flip the orientation.
    fn transform_directive(&mut self, d: &Directive) -> Result<()> {
        let line = d.line;
        match d.name.as_str() {
            "Identity" => {
                self.nums(d, 0)?;
                self.g.ctm = Mat4::IDENTITY;
                Ok(())
            }
            "Translate" => {
                let v = self.nums(d, 3)?;
                self.transform(d, Mat4::from_translation(Vec3::new(v[0], v[1], v[2])))
            }
            "Scale" => {
                let v = self.nums(d, 3)?;
                self.transform(d, Mat4::from_scale(Vec3::new(v[0], v[1], v[2])))
            }
            "Rotate" => {
                let v = self.nums(d, 4)?;
                let axis = Vec3::new(v[1], v[2], v[3])
                    .try_normalize()
                    .ok_or_else(|| self.cx.err(line, "`Rotate`: the axis must not be zero"))?;
                self.transform(d, Mat4::from_axis_angle(axis, v[0].to_radians()))
            }
            "LookAt" => {
                let v = self.nums(d, 9)?;
                let (eye, look, up) = (
                    Vec3::new(v[0], v[1], v[2]),
                    Vec3::new(v[3], v[4], v[5]),
                    Vec3::new(v[6], v[7], v[8]),
                );
                let world_from_camera = super::shapes::look_at(eye, look, up).ok_or_else(|| {
                    self.cx.err(line, "`LookAt`: the eye equals the target, or `up` is parallel to the view direction")
                })?;
                self.transform(d, world_from_camera.inverse())
            }
            "Transform" | "ConcatTransform" => {
                let v = self.nums(d, 16)?;
                let m = Mat4::from_cols_slice(&v);
                if d.name == "Transform" {
                    self.g.ctm = Mat4::IDENTITY;
                }
                self.transform(d, m)
            }
            "CoordinateSystem" => {
                let name = self.strs(d, 1)?[0].to_string();
                self.named_coords.insert(name, self.g.ctm);
                Ok(())
            }
            "CoordSysTransform" => {
                let name = self.strs(d, 1)?[0];
                match self.named_coords.get(name) {
                    Some(m) => {
                        self.g.ctm = *m;
                        Ok(())
                    }
                    None => Err(self.cx.err(
                        line,
                        format!("`CoordSysTransform`: no coordinate system named \"{name}\""),
                    )),
                }
            }
            "TransformBegin" => {
                self.transform_stack.push(self.g.ctm);
                Ok(())
            }
            "TransformEnd" => match self.transform_stack.pop() {
                Some(m) => {
                    self.g.ctm = m;
                    Ok(())
                }
                None => Err(self.cx.err(line, "TransformEnd without TransformBegin")),
            },
            "ActiveTransform" | "TransformTimes" => {
                self.warn_once("motion", line, "motion blur (ActiveTransform, TransformTimes) is ignored: kalos renders one instant");
                Ok(())
            }
            "ReverseOrientation" => {
                self.g.reverse_orientation = !self.g.reverse_orientation;
                Ok(())
            }
            _ => Err(self.unsupported(d)),
        }
    }

    /// The scene-wide options kalos reads or skips with a warning
    /// (`Integrator`, `PixelFilter`, `ColorSpace`, `Accelerator`, `Option`,
    /// media), and `WorldBegin`/`WorldEnd`.
    fn option_directive(&mut self, d: &Directive) -> Result<()> {
        let line = d.line;
        match d.name.as_str() {
            "Integrator" => {
                let ty = self.strs(d, 1)?[0];
                self.warn(
                    line,
                    format!("Integrator \"{ty}\" skipped: kalos chooses its method itself"),
                );
                Ok(())
            }
            "PixelFilter" => {
                let ty = self.strs(d, 1)?[0];
                if ty != "box" {
                    self.warn(
                        line,
                        format!("PixelFilter \"{ty}\" replaced by kalos's box filter"),
                    );
                }
                Ok(())
            }
            "ColorSpace" => {
                let ty = self.strs(d, 1)?[0];
                if ty != "srgb" {
                    self.warn(
                        line,
                        format!("ColorSpace \"{ty}\" ignored: kalos renders in linear sRGB"),
                    );
                }
                Ok(())
            }
            "Accelerator" => Ok(()),
            "Option" => {
                for p in &d.params {
                    self.warn(line, format!("Option \"{}\" ignored", p.name));
                }
                Ok(())
            }
            "WorldBegin" => {
                self.world = true;
                self.g.ctm = Mat4::IDENTITY;
                self.named_coords.insert("world".into(), Mat4::IDENTITY);
                Ok(())
            }
            "WorldEnd" => Ok(()),
            "MakeNamedMedium" | "MediumInterface" => {
                self.warn_once(
                    "media",
                    line,
                    "participating media are ignored: kalos renders surfaces only",
                );
                Ok(())
            }
            _ => Err(self.unsupported(d)),
        }
    }

    /// `AttributeBegin`, `AttributeEnd` and `Attribute`: the graphics
    /// state's stack and its parameter defaults.
    fn attribute_directive(&mut self, d: &Directive) -> Result<()> {
        let line = d.line;
        match d.name.as_str() {
            "AttributeBegin" => {
                self.stack.push((self.g.clone(), line));
                Ok(())
            }
            "AttributeEnd" => match self.stack.pop() {
                Some((g, _)) => {
                    self.g = g;
                    Ok(())
                }
                None => Err(self.cx.err(line, "AttributeEnd without AttributeBegin")),
            },
            "Attribute" => {
                let target = self.strs(d, 1)?[0];
                let slot = match target {
                    "shape" => 0,
                    "light" => 1,
                    "material" => 2,
                    "texture" => 3,
                    "medium" => return Ok(()),
                    _ => return Err(self.cx.err(line, format!("`Attribute` \"{target}\": expected shape, light, material, medium or texture"))),
                };
                for p in &d.params {
                    let list = &mut self.g.attrs[slot];
                    list.retain(|q| q.name != p.name);
                    list.push(p.clone());
                }
                Ok(())
            }
            _ => Err(self.unsupported(d)),
        }
    }

    /// `ObjectBegin`, `ObjectEnd` and `ObjectInstance`: defining an object
    /// and placing copies of it.
    fn object_directive(&mut self, d: &Directive) -> Result<()> {
        let line = d.line;
        match d.name.as_str() {
            "ObjectBegin" => {
                let name = self.strs(d, 1)?[0].to_string();
                if self.defining.is_some() {
                    return Err(self.cx.err(line, "ObjectBegin inside another ObjectBegin"));
                }
                self.stack.push((self.g.clone(), line));
                self.objects.insert(
                    name.clone(),
                    Object {
                        shapes: Vec::new(),
                        line,
                    },
                );
                self.defining = Some(name);
                Ok(())
            }
            "ObjectEnd" => {
                if self.defining.take().is_none() {
                    return Err(self.cx.err(line, "ObjectEnd without ObjectBegin"));
                }
                match self.stack.pop() {
                    Some((g, _)) => {
                        self.g = g;
                        Ok(())
                    }
                    None => Err(self.cx.err(line, "ObjectEnd without ObjectBegin")),
                }
            }
            "ObjectInstance" => {
                let name = self.strs(d, 1)?[0];
                self.instance(name, line)
            }
            _ => Err(self.unsupported(d)),
        }
    }

    /// `Material`, `MakeNamedMaterial` and `NamedMaterial`: building a
    /// material, naming it, or making a named one current.
    fn material_directive(&mut self, d: &Directive) -> Result<()> {
        let line = d.line;
        match d.name.as_str() {
            "Material" => {
                let ty = self.strs(d, 1)?[0];
                let m = self.material(d, ty, format!("Material \"{ty}\""))?;
                self.g.material = Some(m);
                Ok(())
            }
            "MakeNamedMaterial" => {
                let name = self.strs(d, 1)?[0].to_string();
                let mut ps = Params::new(d, format!("MakeNamedMaterial \"{name}\""), &[]);
                let ty = ps.string(&self.cx, "type")?.ok_or_else(|| {
                    self.cx.err(
                        line,
                        format!("MakeNamedMaterial \"{name}\" needs a \"string type\""),
                    )
                })?;
                let m =
                    self.material(d, ty, format!("MakeNamedMaterial \"{name}\" (type {ty})"))?;
                self.named_materials.insert(name, m);
                Ok(())
            }
            "NamedMaterial" => {
                let name = self.strs(d, 1)?[0];
                let m = *self.named_materials.get(name).ok_or_else(|| {
                    self.cx.err(line, format!("NamedMaterial \"{name}\": no material of this name is defined before this line"))
                })?;
                self.g.material = Some(m);
                Ok(())
            }
            _ => Err(self.unsupported(d)),
        }
    }
}

//! Mitsuba 3 scene files (XML), the subset a global-illumination renderer of
//! surfaces needs.
//!
//! ```xml
//! <scene version="3.0.0">
//!     <default name="spp" value="64"/>
//!     <include filename="fragments/bsdfs.xml"/>
//!     <sensor type="perspective">
//!         <float name="fov" value="39.3"/>
//!         <transform name="to_world">
//!             <lookat origin="0, 1, 5" target="0, 1, 0" up="0, 1, 0"/>
//!         </transform>
//!         <film type="hdrfilm">
//!             <integer name="width" value="256"/>
//!             <integer name="height" value="256"/>
//!         </film>
//!     </sensor>
//!     <shape type="rectangle">
//!         <transform name="to_world"><scale value="2"/></transform>
//!         <bsdf type="diffuse"><rgb name="reflectance" value="0.8, 0.8, 0.8"/></bsdf>
//!         <emitter type="area"><rgb name="radiance" value="10"/></emitter>
//!     </shape>
//! </scene>
//! ```
//!
//! # What is read
//!
//! - shapes `obj`, `ply`, `rectangle`, `cube`, `disk`, `sphere` (`center`,
//!   `radius`), with `to_world`, `flip_normals`, and for mesh files
//!   `face_normals` and `flip_tex_coords`; analytic shapes are tessellated
//!   ([`super::shapes`]). A mesh file without normals gets angle-weighted
//!   vertex normals unless `face_normals` is set, as in Mitsuba.
//! - transforms `translate`, `rotate`, `scale`, `matrix` (4×4 or 3×3,
//!   row-major) and `lookat`, composed in document order (each new one
//!   multiplied on the left).
//! - BSDFs `diffuse`, `twosided`, `conductor`, `roughconductor`, `plastic`,
//!   `roughplastic`, `dielectric`, `thindielectric` and kalos's own `phong`;
//!   colours as `<rgb>`, `<float>`, `<spectrum>` (one value, or
//!   `λ:value` pairs converted roughly to RGB), or textures `bitmap` and
//!   `checkerboard`, inline or by `<ref>`.
//! - emitters `area` (inside a shape or by reference), `constant`, `envmap`.
//! - the `perspective` sensor (`thinlens` is read as a pinhole, with a
//!   warning) with its `hdrfilm` (`width`, `height`, `rfilter`).
//! - `id` / `<ref>` (forward references included), `<default>` with `$name`
//!   substitution in every attribute, `<include>` (paths in an included file
//!   resolve against the main scene file's folder first, then the included
//!   file's own folder; include cycles are errors).
//!
//! # What is skipped, with a warning in [`Scene::warnings`]
//!
//! - the `integrator` block (kalos's method is chosen on the command line);
//! - the `sampler` block and its parameters (budgets are kalos's own);
//! - a reconstruction filter other than `box` (kalos always uses a box filter);
//! - anisotropic roughness `alpha_u`/`alpha_v` (their mean is used);
//! - a textured area-light radiance (its mean is used).
//!
//! Standard parameters that change nothing here (`far_clip`,
//! `focus_distance`, `pixel_format`, `file_format`, `sample_count`...) are
//! accepted silently.
//!
//! # What is an error
//!
//! Every error names the file and the line: malformed XML, an unknown element
//! or plugin type (`point`, `spot` and `directional` lights included: kalos's
//! methods need lights with an area), an unknown parameter of a known plugin
//! (STYLE.md rule 10: a misspelt name is reported, not ignored), a bad number,
//! a missing mesh, image or included file, and a dangling `<ref>`.
//!
//! # uv conventions
//!
//! [`Scene::uvs`] holds Mitsuba's `si.uv` exactly: OBJ texture coordinates are
//! flipped (v → 1 − v, Mitsuba's `flip_tex_coords` default), so that v = 0 is
//! the top row of a bitmap. [`TexImage::lookup`] puts v = 0 at the bottom, so
//! a `bitmap` texture's `to_uv` is composed with that flip; a `checkerboard`
//! sees Mitsuba's uv unchanged.

use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::{Affine2, Mat2, Mat3, Mat4, Vec2, Vec3};

use super::shapes::{self, look_at, MeshData};
use super::{
    CameraDesc, EmitterDesc, Material, MicrofacetKind, Rgb, Scene, SceneError, TexImage, Texture,
};

type Result<T> = std::result::Result<T, SceneError>;

/// Deepest element nesting accepted (a guard against stack exhaustion on
/// hostile input; real scenes nest a handful of levels).
const MAX_DEPTH: usize = 64;

/// Loads a Mitsuba 3 scene file.
pub fn load(path: &Path) -> Result<Scene> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| SceneError::new(path, 0, format!("cannot read scene file: {e}")))?;
    let base = path.parent().unwrap_or(Path::new(".")).to_path_buf();
    load_impl(&text, &base, path.to_path_buf())
}

/// Loads a Mitsuba 3 scene from a string (a built-in scene); relative paths
/// resolve against `base_dir`, and `name` stands for the file in messages.
pub fn load_str(xml: &str, base_dir: &Path, name: &str) -> Result<Scene> {
    load_impl(xml, base_dir, PathBuf::from(name))
}

fn load_impl(text: &str, base_dir: &Path, file: PathBuf) -> Result<Scene> {
    // Read the documents: splice includes, substitute `$name`s
    let mut reader = Reader {
        main_dir: base_dir.to_path_buf(),
        files: vec![file.clone()],
        defaults: Vec::new(),
        stack: vec![file.canonicalize().unwrap_or_else(|_| file.clone())],
    };
    let mut top = Vec::new();
    reader.read_document(text, 0, 0, &mut top)?;
    let Reader {
        main_dir, files, ..
    } = reader;

    // Index the ids, then build the scene from the top-level elements
    let mut b = Builder {
        files: &files,
        main_dir: &main_dir,
        ids: HashMap::new(),
        scene: Scene::empty(file.display().to_string()),
        materials: HashMap::new(),
        textures: HashMap::new(),
        images: HashMap::new(),
        building: HashSet::new(),
        default_material: None,
        camera_seen: false,
    };
    for el in &top {
        b.index_ids(el)?;
    }
    for el in &top {
        b.top_level(el)?;
    }
    if !b.camera_seen {
        let main = files.first().cloned().unwrap_or_default();
        super::obj::synthesise_camera(&mut b.scene, &main);
    }
    Ok(b.scene)
}

// ---------------------------------------------------------------------------
// Reading: XML to an owned tree

/// An element after includes are spliced in and `$name`s substituted.
#[derive(Debug)]
struct El {
    tag: String,
    attrs: Vec<(String, String)>,
    children: Vec<El>,
    /// Index into the list of files read.
    file: usize,
    /// 1-based line of the element's start.
    line: u32,
}

impl El {
    fn attr(&self, k: &str) -> Option<&str> {
        self.attrs
            .iter()
            .find(|(n, _)| n == k)
            .map(|(_, v)| v.as_str())
    }

    /// `<tag name="..." type="...">` for messages.
    fn describe(&self) -> String {
        let mut s = format!("<{}", self.tag);
        for k in ["type", "name", "id"] {
            if let Some(v) = self.attr(k) {
                s += &format!(" {k}=\"{v}\"");
            }
        }
        s + ">"
    }
}

struct Reader {
    main_dir: PathBuf,
    files: Vec<PathBuf>,
    /// `<default>` values, first declaration wins (as in Mitsuba).
    defaults: Vec<(String, String)>,
    /// Canonical paths of the files being read (include-cycle guard).
    stack: Vec<PathBuf>,
}

impl Reader {
    fn read_document(
        &mut self,
        text: &str,
        file: usize,
        depth: usize,
        out: &mut Vec<El>,
    ) -> Result<()> {
        let path = self.files.get(file).cloned().unwrap_or_default();
        let doc = roxmltree::Document::parse(text)
            .map_err(|e| SceneError::new(&path, e.pos().row, format!("malformed XML: {e}")))?;
        let root = doc.root_element();
        if root.tag_name().name() != "scene" {
            return Err(SceneError::new(
                &path,
                doc.text_pos_at(root.range().start).row,
                format!(
                    "expected <scene> as the root element, found <{}>",
                    root.tag_name().name()
                ),
            ));
        }
        self.convert_children(&doc, root, file, depth, out)
    }

    fn substitute(&self, v: &str) -> String {
        if !v.contains('$') {
            return v.to_string();
        }
        // longest names first, so that `$spp` is not read as `$sp` + "p"
        let mut names: Vec<&(String, String)> = self.defaults.iter().collect();
        names.sort_by_key(|(n, _)| std::cmp::Reverse(n.len()));
        let mut s = v.to_string();
        for (n, val) in names {
            s = s.replace(&format!("${n}"), val);
        }
        s
    }

    fn convert_children(
        &mut self,
        doc: &roxmltree::Document,
        node: roxmltree::Node,
        file: usize,
        depth: usize,
        out: &mut Vec<El>,
    ) -> Result<()> {
        let path = self.files.get(file).cloned().unwrap_or_default();
        for child in node.children().filter(|n| n.is_element()) {
            let line = doc.text_pos_at(child.range().start).row;
            if depth > MAX_DEPTH {
                return Err(SceneError::new(&path, line, "elements nested too deeply"));
            }
            let tag = child.tag_name().name().to_string();
            let attrs: Vec<(String, String)> = child
                .attributes()
                .map(|a| (a.name().to_string(), self.substitute(a.value())))
                .collect();
            let get = |k: &str| {
                attrs
                    .iter()
                    .find(|(n, _)| n == k)
                    .map(|(_, v)| v.clone())
                    .ok_or_else(|| {
                        SceneError::new(&path, line, format!("<{tag}> needs a `{k}` attribute"))
                    })
            };
            match tag.as_str() {
                "default" => {
                    let (name, value) = (get("name")?, get("value")?);
                    if !self.defaults.iter().any(|(n, _)| *n == name) {
                        self.defaults.push((name, value));
                    }
                }
                "include" => {
                    let filename = get("filename")?;
                    self.include(&filename, file, line, depth, out)?;
                }
                _ => {
                    let mut el = El {
                        tag,
                        attrs,
                        children: Vec::new(),
                        file,
                        line,
                    };
                    self.convert_children(doc, child, file, depth + 1, &mut el.children)?;
                    out.push(el);
                }
            }
        }
        Ok(())
    }

    fn include(
        &mut self,
        filename: &str,
        from: usize,
        line: u32,
        depth: usize,
        out: &mut Vec<El>,
    ) -> Result<()> {
        let from_path = self.files.get(from).cloned().unwrap_or_default();
        let path = resolve(&self.main_dir, &from_path, filename);
        let err = |msg: String| SceneError::new(&from_path, line, msg);
        if !path.is_file() {
            return Err(err(format!(
                "included file `{filename}` not found (looked for {})",
                path.display()
            )));
        }
        let canon = path.canonicalize().unwrap_or_else(|_| path.clone());
        if self.stack.contains(&canon) {
            return Err(err(format!("include cycle: `{filename}` includes itself")));
        }
        let text = std::fs::read_to_string(&path)
            .map_err(|e| err(format!("cannot read included file `{filename}`: {e}")))?;
        self.files.push(path);
        self.stack.push(canon);
        let idx = self.files.len() - 1;
        let r = self.read_document(&text, idx, depth + 1, out);
        self.stack.pop();
        r
    }
}

/// A file named in a scene: absolute as is; relative against the main scene
/// file's folder, else against the folder of the file that names it.
fn resolve(main_dir: &Path, from_file: &Path, filename: &str) -> PathBuf {
    let f = Path::new(filename);
    if f.is_absolute() {
        return f.to_path_buf();
    }
    let main = main_dir.join(f);
    if main.exists() {
        return main;
    }
    if let Some(dir) = from_file.parent() {
        let local = dir.join(f);
        if local.exists() {
            return local;
        }
    }
    main
}

// ---------------------------------------------------------------------------
// Building: the tree to a Scene

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
struct Props<'t> {
    el: &'t El,
    used: Vec<bool>,
}

impl<'t> Props<'t> {
    fn new(el: &'t El) -> Self {
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
    fn ignore(&mut self, names: &[&str]) {
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
    fn objects(&mut self) -> Vec<&'t El> {
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

struct Builder<'t> {
    files: &'t [PathBuf],
    main_dir: &'t Path,
    ids: HashMap<&'t str, &'t El>,
    scene: Scene,
    /// Material index of each `<bsdf>` element built (by address).
    materials: HashMap<usize, u32>,
    /// Each `<texture>` element built (by address).
    textures: HashMap<usize, Texture>,
    images: HashMap<(PathBuf, bool), Arc<TexImage>>,
    /// Elements being built (reference-cycle guard).
    building: HashSet<usize>,
    default_material: Option<u32>,
    camera_seen: bool,
}

fn addr(el: &El) -> usize {
    std::ptr::from_ref(el) as usize
}

impl<'t> Builder<'t> {
    fn file(&self, el: &El) -> PathBuf {
        self.files.get(el.file).cloned().unwrap_or_default()
    }

    fn err(&self, el: &El, msg: impl Into<String>) -> SceneError {
        SceneError::new(self.file(el), el.line, msg)
    }

    fn warn(&mut self, el: &El, msg: impl AsRef<str>) {
        let w = format!("{}:{}: {}", self.file(el).display(), el.line, msg.as_ref());
        self.scene.warnings.push(w);
    }

    fn index_ids(&mut self, el: &'t El) -> Result<()> {
        if el.tag != "ref" {
            if let Some(id) = el.attr("id") {
                if let Some(prev) = self.ids.get(id) {
                    let msg = format!(
                        "id `{id}` is used twice (first at {}:{})",
                        self.file(prev).display(),
                        prev.line
                    );
                    return Err(self.err(el, msg));
                }
                self.ids.insert(id, el);
            }
        }
        for c in &el.children {
            self.index_ids(c)?;
        }
        Ok(())
    }

    fn lookup(&self, r: &'t El) -> Result<&'t El> {
        let id = r
            .attr("id")
            .ok_or_else(|| self.err(r, "<ref> needs an `id` attribute"))?;
        self.ids
            .get(id)
            .copied()
            .ok_or_else(|| self.err(r, format!("<ref id=\"{id}\">: no object has this id")))
    }

    fn plugin_type(&self, el: &'t El) -> Result<&'t str> {
        el.attr("type")
            .ok_or_else(|| self.err(el, format!("<{}> needs a `type` attribute", el.tag)))
    }

    /// Reports the first child the plugin did not read.
    fn finish(&self, p: &Props<'t>) -> Result<()> {
        let el = p.el;
        for (c, used) in el.children.iter().zip(&p.used) {
            if *used {
                continue;
            }
            let msg = match c.attr("name") {
                Some(n) => format!(
                    "unknown parameter `{n}` of {} (misspelt, or not supported by kalos)",
                    el.describe()
                ),
                None => format!("unexpected {} inside {}", c.describe(), el.describe()),
            };
            return Err(self.err(c, msg));
        }
        Ok(())
    }

    fn top_level(&mut self, el: &'t El) -> Result<()> {
        match el.tag.as_str() {
            "shape" => self.shape(el),
            "bsdf" => self.bsdf(el).map(|_| ()),
            "texture" => self.texture(el).map(|_| ()),
            "emitter" => self.emitter(el),
            "sensor" => {
                if self.camera_seen {
                    self.warn(el, "a second <sensor> is ignored: kalos uses the first");
                    Ok(())
                } else {
                    self.sensor(el)
                }
            }
            "integrator" => {
                let ty = el.attr("type").unwrap_or("?");
                self.warn(
                    el,
                    format!("<integrator type=\"{ty}\"> skipped: kalos chooses its method itself"),
                );
                Ok(())
            }
            _ => Err(self.err(
                el,
                format!("unsupported element {} in a scene", el.describe()),
            )),
        }
    }

    // -- parameter readers -------------------------------------------------

    fn value<'a>(&self, el: &'a El, attr: &str) -> Result<&'a str> {
        el.attr(attr)
            .ok_or_else(|| self.err(el, format!("{} needs a `{attr}` attribute", el.describe())))
    }

    fn number(&self, el: &El, attr: &str, s: &str) -> Result<f32> {
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

    fn float_opt(&self, p: &mut Props<'t>, name: &str) -> Result<Option<f32>> {
        let Some(c) = p.find(name) else {
            return Ok(None);
        };
        self.expect_tag(c, &["float", "integer"])?;
        self.num(c, "value").map(Some)
    }

    fn float(&self, p: &mut Props<'t>, name: &str, default: f32) -> Result<f32> {
        Ok(self.float_opt(p, name)?.unwrap_or(default))
    }

    fn int(&self, p: &mut Props<'t>, name: &str, default: i64) -> Result<i64> {
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

    fn boolean(&self, p: &mut Props<'t>, name: &str, default: bool) -> Result<bool> {
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

    fn string(&self, p: &mut Props<'t>, name: &str) -> Result<Option<&'t str>> {
        let Some(c) = p.find(name) else {
            return Ok(None);
        };
        self.expect_tag(c, &["string"])?;
        self.value(c, "value").map(Some)
    }

    fn point(&self, p: &mut Props<'t>, name: &str) -> Result<Option<Vec3>> {
        let Some(c) = p.find(name) else {
            return Ok(None);
        };
        self.expect_tag(c, &["point", "vector"])?;
        self.xyz(c, 0.0).map(Some)
    }

    fn transform(&self, p: &mut Props<'t>, name: &str) -> Result<Option<Mat4>> {
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
                Ok(spectrum_to_rgb(&pairs))
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

    fn color_const(&self, p: &mut Props<'t>, name: &str) -> Result<Option<Rgb>> {
        match p.find(name) {
            Some(c) => self.const_color_el(c).map(Some),
            None => Ok(None),
        }
    }

    /// A colour parameter: a constant or a texture (inline or by reference).
    fn color(&mut self, p: &mut Props<'t>, name: &str, default: f32) -> Result<Texture> {
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
            _ => self.const_color_el(c).map(Texture::Constant),
        }
    }

    /// An index of refraction: a number or a named material.
    fn ior(&self, p: &mut Props<'t>, name: &str, default: f32) -> Result<f32> {
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

    fn distribution(&self, p: &mut Props<'t>) -> Result<MicrofacetKind> {
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

    fn alpha(&mut self, p: &mut Props<'t>) -> Result<f32> {
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

    // -- plugins -----------------------------------------------------------

    fn bsdf(&mut self, el: &'t El) -> Result<u32> {
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

    fn bsdf_material_inner(&mut self, el: &'t El) -> Result<Material> {
        let ty = self.plugin_type(el)?;
        let mut p = Props::new(el);
        let m = match ty {
            "diffuse" => Material::Diffuse {
                reflectance: self.color(&mut p, "reflectance", 0.5)?,
            },
            "twosided" => {
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
                    [b] => Material::TwoSided(Box::new(self.bsdf_material(b)?)),
                    [] => {
                        return Err(self.err(el, "<bsdf type=\"twosided\"> needs a nested <bsdf>"))
                    }
                    _ => {
                        return Err(self.err(
                            el,
                            "a twosided BSDF with a different BSDF on each side is not supported",
                        ))
                    }
                }
            }
            "conductor" | "roughconductor" => {
                let name = self.string(&mut p, "material")?;
                let eta = self.color_const(&mut p, "eta")?;
                let k = self.color_const(&mut p, "k")?;
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
                let specular_reflectance = self.color(&mut p, "specular_reflectance", 1.0)?;
                if ty == "conductor" {
                    Material::Conductor {
                        eta,
                        k,
                        specular_reflectance,
                    }
                } else {
                    let distribution = self.distribution(&mut p)?;
                    let alpha = self.alpha(&mut p)?;
                    p.ignore(&["sample_visible"]);
                    Material::RoughConductor {
                        distribution,
                        alpha,
                        eta,
                        k,
                        specular_reflectance,
                    }
                }
            }
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
            "phong" => {
                let kd = self.color(&mut p, "diffuse_reflectance", 0.5)?;
                let ks = self.color(&mut p, "specular_reflectance", 0.2)?;
                let exponent = self.float(&mut p, "exponent", 30.0)?;
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
                Material::Phong {
                    diffuse_reflectance: kd,
                    specular_reflectance: ks,
                    exponent,
                }
            }
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

    /// int_ior / ext_ior.
    fn eta(&self, p: &mut Props<'t>, int_default: f32) -> Result<f32> {
        let int = self.ior(p, "int_ior", int_default)?;
        let ext = self.ior(p, "ext_ior", 1.000277)?;
        if int.is_nan() || ext.is_nan() || int <= 0.0 || ext <= 0.0 {
            return Err(self.err(p.el, "indices of refraction must be positive"));
        }
        Ok(int / ext)
    }

    fn texture(&mut self, el: &'t El) -> Result<Texture> {
        let key = addr(el);
        if let Some(t) = self.textures.get(&key) {
            return Ok(t.clone());
        }
        let ty = self.plugin_type(el)?;
        let mut p = Props::new(el);
        let to_uv = self.transform(&mut p, "to_uv")?.unwrap_or(Mat4::IDENTITY);
        // the 2D affine part of Mitsuba's 4×4 to_uv (x, y and the translation)
        let to_uv = Affine2::from_mat2_translation(
            Mat2::from_cols(
                to_uv.x_axis.truncate().truncate(),
                to_uv.y_axis.truncate().truncate(),
            ),
            to_uv.w_axis.truncate().truncate(),
        );
        let t = match ty {
            "bitmap" => {
                let filename = self
                    .string(&mut p, "filename")?
                    .ok_or_else(|| self.err(el, "<texture type=\"bitmap\"> needs a `filename`"))?;
                let raw = self.boolean(&mut p, "raw", false)?;
                p.ignore(&["filter_type", "wrap_mode", "format", "accel"]);
                let image = self.image(el, filename, !raw)?;
                // Mitsuba's v = 0 is the image's top row; TexImage's is the bottom
                let flip = Affine2::from_mat2_translation(
                    Mat2::from_diagonal(Vec2::new(1.0, -1.0)),
                    Vec2::new(0.0, 1.0),
                );
                Texture::Bitmap {
                    image,
                    to_uv: flip * to_uv,
                }
            }
            "checkerboard" => Texture::Checkerboard {
                color0: self
                    .color_const(&mut p, "color0")?
                    .unwrap_or(Rgb::splat(0.4)),
                color1: self
                    .color_const(&mut p, "color1")?
                    .unwrap_or(Rgb::splat(0.2)),
                to_uv,
            },
            _ => {
                return Err(self.err(
                    el,
                    format!("unsupported texture plugin `{ty}`: expected bitmap or checkerboard"),
                ))
            }
        };
        self.finish(&p)?;
        self.textures.insert(key, t.clone());
        Ok(t)
    }

    /// An image file as linear RGB; 8- and 16-bit files (PNG, JPEG) are
    /// sRGB-encoded unless `srgb` is false (`raw`), float files (EXR, HDR)
    /// are linear.
    fn image(&mut self, el: &El, filename: &str, srgb: bool) -> Result<Arc<TexImage>> {
        let path = resolve(self.main_dir, &self.file(el), filename);
        if let Some(img) = self.images.get(&(path.clone(), srgb)) {
            return Ok(img.clone());
        }
        if !path.is_file() {
            return Err(self.err(
                el,
                format!(
                    "image file `{filename}` not found (looked for {})",
                    path.display()
                ),
            ));
        }
        let img = image::open(&path)
            .map_err(|e| self.err(el, format!("cannot read image `{}`: {e}", path.display())))?;
        let linear = matches!(
            img,
            image::DynamicImage::ImageRgb32F(_) | image::DynamicImage::ImageRgba32F(_)
        );
        let rgb = img.to_rgb32f();
        let (width, height) = rgb.dimensions();
        let decode = srgb && !linear;
        let data = rgb
            .pixels()
            .map(|px| {
                let c = Rgb::from(px.0);
                if decode {
                    c.map(srgb_to_linear)
                } else {
                    c
                }
            })
            .collect();
        let img = Arc::new(TexImage {
            width,
            height,
            data,
        });
        self.images.insert((path, srgb), img.clone());
        Ok(img)
    }

    fn default_material(&mut self) -> u32 {
        if let Some(m) = self.default_material {
            return m;
        }
        // Mitsuba's default BSDF for a shape without one
        let m = self.scene.add_material(Material::Diffuse {
            reflectance: Texture::Constant(Rgb::splat(0.5)),
        });
        self.default_material = Some(m);
        m
    }

    fn shape(&mut self, el: &'t El) -> Result<()> {
        let ty = self.plugin_type(el)?;
        let mut p = Props::new(el);
        let to_world = self
            .transform(&mut p, "to_world")?
            .unwrap_or(Mat4::IDENTITY);
        let flip_normals = self.boolean(&mut p, "flip_normals", false)?;

        // Geometry in object space
        let (mut mesh, analytic) = match ty {
            "obj" | "ply" => {
                let filename = self
                    .string(&mut p, "filename")?
                    .ok_or_else(|| self.err(el, format!("{} needs a `filename`", el.describe())))?;
                let face_normals = self.boolean(&mut p, "face_normals", false)?;
                let flip_tex = self.boolean(&mut p, "flip_tex_coords", ty == "obj")?;
                let path = resolve(self.main_dir, &self.file(el), filename);
                if !path.is_file() {
                    return Err(self.err(
                        el,
                        format!(
                            "mesh file `{filename}` not found (looked for {})",
                            path.display()
                        ),
                    ));
                }
                let mut mesh = if ty == "obj" {
                    super::obj::load_obj(&path, flip_tex)
                } else {
                    super::ply::load_ply(&path).map(|mut m| {
                        if flip_tex {
                            if let Some(uvs) = &mut m.uvs {
                                uvs.iter_mut().for_each(|t| t.y = 1.0 - t.y);
                            }
                        }
                        m
                    })
                }
                .map_err(|e| self.err(el, format!("in the mesh of this shape: {e}")))?;
                if face_normals {
                    mesh.normals = None;
                }
                mesh.transform(&to_world);
                if mesh.normals.is_none() && !face_normals {
                    mesh.compute_vertex_normals();
                }
                (mesh, false)
            }
            "rectangle" | "cube" | "disk" | "sphere" => {
                let mut mesh = match ty {
                    "rectangle" => shapes::rectangle(),
                    "cube" => shapes::cube(),
                    "disk" => shapes::disk(shapes::DISK_SEGMENTS),
                    _ => {
                        let center = self.point(&mut p, "center")?.unwrap_or(Vec3::ZERO);
                        let radius = self.float(&mut p, "radius", 1.0)?;
                        if radius.is_nan() || radius <= 0.0 {
                            return Err(self.err(el, "sphere `radius` must be positive"));
                        }
                        shapes::sphere(center, radius, shapes::SPHERE_RINGS)
                    }
                };
                mesh.transform(&to_world);
                (mesh, ty != "cube")
            }
            _ => {
                return Err(self.err(
                    el,
                    format!("unsupported shape plugin `{ty}` in {}", el.describe()),
                ))
            }
        };
        // Mitsuba's analytic shapes take their normal from the inverse
        // transpose of to_world; a mirroring to_world reverses the winding,
        // so reverse it back to keep the geometric normal on that side.
        if analytic && Mat3::from_mat4(to_world).determinant() < 0.0 {
            mesh.reverse_winding();
        }
        if flip_normals {
            mesh.flip();
        }

        // Nested BSDF and area emitter, inline or by reference
        let mut bsdf = None;
        let mut radiance = None;
        for o in p.objects() {
            let target = if o.tag == "ref" { self.lookup(o)? } else { o };
            match target.tag.as_str() {
                "bsdf" => {
                    if bsdf.is_some() {
                        return Err(self.err(o, "a shape can have only one <bsdf>"));
                    }
                    bsdf = Some(self.bsdf(target)?);
                }
                "emitter" => {
                    if radiance.is_some() {
                        return Err(self.err(o, "a shape can have only one <emitter>"));
                    }
                    radiance = Some(self.area_emitter(target)?);
                }
                _ => {
                    return Err(self.err(
                        o,
                        format!("unsupported {} inside a shape", target.describe()),
                    ))
                }
            }
        }
        self.finish(&p)?;
        let material = match bsdf {
            Some(m) => m,
            None => self.default_material(),
        };
        let name = el.attr("id").map_or_else(
            || format!("{ty}{}", self.scene.shapes.len()),
            str::to_string,
        );
        self.add(name, &mesh, material, radiance);
        Ok(())
    }

    fn add(&mut self, name: String, m: &MeshData, material: u32, radiance: Option<Rgb>) {
        self.scene.add_mesh(
            name,
            &m.positions,
            m.normals.as_deref(),
            m.uvs.as_deref(),
            &m.indices,
            material,
            radiance,
        );
    }

    /// An `area` emitter's radiance.
    fn area_emitter(&mut self, el: &'t El) -> Result<Rgb> {
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
        Ok(radiance)
    }

    fn emitter(&mut self, el: &'t El) -> Result<()> {
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
                self.scene.emitters.push(EmitterDesc::Constant { radiance });
            }
            "envmap" => {
                let filename = self
                    .string(&mut p, "filename")?
                    .ok_or_else(|| self.err(el, "<emitter type=\"envmap\"> needs a `filename`"))?;
                let scale = self.float(&mut p, "scale", 1.0)?;
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

    fn sensor(&mut self, el: &'t El) -> Result<()> {
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
                    // budgets are kalos's own; any sampler and parameter is accepted
                    self.plugin_type(o)?;
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

/// The largest value a colour parameter takes, per channel.
fn tex_max(t: &Texture) -> Rgb {
    match t {
        Texture::Constant(c) => *c,
        Texture::Checkerboard { color0, color1, .. } => color0.max(*color1),
        Texture::Bitmap { image, .. } => image.data.iter().fold(Rgb::ZERO, |a, &b| a.max(b)),
    }
}

/// The sRGB transfer function, inverted.
fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// RGB (eta, k) of Mitsuba's named conductors, roughly integrated from their
/// spectra against the sRGB primaries (the values pbrt and Mitsuba's RGB
/// modes give). `none` is Mitsuba's default: a perfect mirror.
const CONDUCTORS: &[(&str, [f32; 3], [f32; 3])] = &[
    ("none", [0.0, 0.0, 0.0], [1.0, 1.0, 1.0]),
    (
        "Ag",
        [0.155265, 0.116723, 0.138342],
        [4.82835, 3.12225, 2.14696],
    ),
    (
        "Al",
        [1.65746, 0.880369, 0.521229],
        [9.22387, 6.26952, 4.837],
    ),
    (
        "Au",
        [0.143119, 0.374957, 1.44248],
        [3.98316, 2.38572, 1.60322],
    ),
    ("Cr", [4.36968, 2.9167, 1.6547], [5.20643, 4.23136, 3.75495]),
    (
        "Cu",
        [0.200438, 0.924033, 1.10221],
        [3.91295, 2.45285, 2.14219],
    ),
];

fn conductor_table(name: &str) -> Option<(Rgb, Rgb)> {
    CONDUCTORS
        .iter()
        .find(|(n, _, _)| *n == name)
        .map(|(_, e, k)| (Rgb::from(*e), Rgb::from(*k)))
}

/// Mitsuba's named indices of refraction (`int_ior`, `ext_ior`).
const IOR_TABLE: &[(&str, f32)] = &[
    ("vacuum", 1.0),
    ("helium", 1.000036),
    ("hydrogen", 1.000132),
    ("air", 1.000277),
    ("carbon dioxide", 1.00045),
    ("water", 1.333),
    ("acetone", 1.36),
    ("ethanol", 1.361),
    ("carbon tetrachloride", 1.461),
    ("glycerol", 1.4729),
    ("benzene", 1.501),
    ("silicone oil", 1.52045),
    ("bromine", 1.661),
    ("water ice", 1.31),
    ("fused quartz", 1.458),
    ("pyrex", 1.47),
    ("acrylic glass", 1.49),
    ("polypropylene", 1.49),
    ("bk7", 1.5046),
    ("sodium chloride", 1.544),
    ("amber", 1.55),
    ("pet", 1.575),
    ("diamond", 2.419),
];

fn ior_table(name: &str) -> Option<f32> {
    let name = name.trim().to_ascii_lowercase();
    IOR_TABLE.iter().find(|(n, _)| *n == name).map(|(_, v)| *v)
}

/// A sampled spectrum (`(λ nm, value)` pairs, increasing λ, zero outside, as
/// Mitsuba's irregular spectrum) to linear sRGB, roughly: integrated against
/// the CIE 1931 matching functions in the multi-lobe Gaussian fit of Wyman,
/// Sloan and Shirley (2013), then normalised per channel so that a constant
/// spectrum of 1 gives RGB (1, 1, 1).
fn spectrum_to_rgb(pairs: &[(f32, f32)]) -> Rgb {
    fn g(l: f32, mu: f32, s1: f32, s2: f32) -> f32 {
        let t = (l - mu) / if l < mu { s1 } else { s2 };
        (-0.5 * t * t).exp()
    }
    fn xyz(l: f32) -> Vec3 {
        Vec3::new(
            1.056 * g(l, 599.8, 37.9, 31.0) + 0.362 * g(l, 442.0, 16.0, 26.7)
                - 0.065 * g(l, 501.1, 20.4, 26.2),
            0.821 * g(l, 568.8, 46.9, 40.5) + 0.286 * g(l, 530.9, 16.3, 31.1),
            1.217 * g(l, 437.0, 11.8, 36.0) + 0.681 * g(l, 459.0, 26.0, 13.8),
        )
    }
    let to_rgb = Mat3::from_cols_array(&[
        3.240454, -0.969266, 0.055643, -1.537139, 1.876011, -0.204026, -0.498531, 0.041556,
        1.057225,
    ]);
    let value = |l: f32| -> f32 {
        match pairs {
            [] => 0.0,
            [(l0, v0)] => {
                if (l - l0).abs() < 0.5 {
                    *v0
                } else {
                    0.0
                }
            }
            _ => {
                let (first, last) = (pairs[0].0, pairs[pairs.len() - 1].0);
                if l < first || l > last {
                    return 0.0;
                }
                let i = pairs
                    .partition_point(|(x, _)| *x <= l)
                    .clamp(1, pairs.len() - 1);
                let ((l0, v0), (l1, v1)) = (pairs[i - 1], pairs[i]);
                let t = ((l - l0) / (l1 - l0)).clamp(0.0, 1.0);
                v0 + t * (v1 - v0)
            }
        }
    };
    let (mut s, mut white) = (Vec3::ZERO, Vec3::ZERO);
    for l in 360..=830 {
        let l = l as f32;
        let c = xyz(l);
        s += c * value(l);
        white += c;
    }
    let (rgb, w) = (to_rgb * s, to_rgb * white);
    rgb / w
}

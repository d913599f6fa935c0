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
//!   `roughplastic`, `dielectric`, `roughdielectric`, `thindielectric` and
//!   kalos's own `phong`;
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
//! - a reconstruction filter other than `box` (kalos always uses a box filter);
//! - anisotropic roughness `alpha_u`/`alpha_v` (their mean is used);
//! - a textured area-light radiance (its mean is used).
//!
//! Standard parameters that change nothing here (`far_clip`,
//! `focus_distance`, `pixel_format`, `file_format`...) are accepted
//! silently. Any `sampler` type is accepted; its `sample_count` becomes
//! [`Scene::sample_count`], the command line's default budget.
//!
//! # Parameters and limits
//!
//! `-D name=value` ([`load_with`]) fills `$name`, overriding the file's
//! `<default>`; a `$name` with no value is an error naming it. Includes nest
//! at most 16 deep and a scene reads at most 4096 of them; a scene holds at
//! most [`super::MAX_TRIANGLES`] triangles. Emission must be finite and
//! non-negative.
//!
//! # What is an error
//!
//! Every error names the file and the line: malformed XML, an unknown element
//! or plugin type (`point`, `spot` and `directional` lights included: kalos's
//! methods need lights with an area), an unknown parameter of a known plugin
//! (STYLE.md rule 10: a misspelt name is reported, not ignored), a bad number,
//! a missing mesh, image or included file, a file the scene may not read
//! (outside its folder and the `--allow-read` folders, not a regular file,
//! or past its kind's size limit: see [`crate::scene::access`]), an image
//! past the memory limit (declared from its header before it is decoded),
//! and a dangling `<ref>`.
//!
//! # uv conventions
//!
//! [`Scene::uvs`] holds Mitsuba's `si.uv` exactly: OBJ texture coordinates are
//! flipped (v → 1 − v, Mitsuba's `flip_tex_coords` default), so that v = 0 is
//! the top row of a bitmap. [`TexImage::lookup`] puts v = 0 at the bottom, so
//! a `bitmap` texture's `to_uv` is composed with that flip; a `checkerboard`
//! sees Mitsuba's uv unchanged.
//!
//! [`TexImage::lookup`]: super::TexImage::lookup

mod bsdf;
mod builder;
mod emitter;
pub(crate) mod files;
mod props;
mod sensor;
mod shape;
pub(crate) mod tables;
mod texture;
mod xml;

use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};

use super::access::FileAccess;
use super::{Scene, SceneError};
use builder::Builder;
use xml::Reader;

type Result<T> = std::result::Result<T, SceneError>;

/// Loads a Mitsuba 3 scene file with `-D name=value` parameters: each
/// fills `$name`, overriding the file's `<default>`. A parameter the scene
/// does not use is a warning in [`Scene::warnings`]. Files are read through
/// `access`.
pub fn load_with(path: &Path, defines: &[(String, String)], access: &FileAccess) -> Result<Scene> {
    let text = files::read_main_text(path, access)
        .map_err(|e| SceneError::new(path, 0, files::main_message(&e)))?;
    let base = path.parent().unwrap_or(Path::new(".")).to_path_buf();
    load_impl(&text, &base, path.to_path_buf(), defines, access)
}

/// Loads a Mitsuba 3 scene from a string (a built-in scene); relative paths
/// resolve against `base_dir`, and `name` stands for the file in messages.
/// The files it names are read through `access`.
pub fn load_str(xml: &str, base_dir: &Path, name: &str, access: &FileAccess) -> Result<Scene> {
    load_impl(xml, base_dir, PathBuf::from(name), &[], access)
}

/// [`load_str`] with `-D name=value` parameters, as [`load_with`].
pub fn load_str_with(
    xml: &str,
    base_dir: &Path,
    name: &str,
    defines: &[(String, String)],
    access: &FileAccess,
) -> Result<Scene> {
    load_impl(xml, base_dir, PathBuf::from(name), defines, access)
}

fn load_impl(
    text: &str,
    base_dir: &Path,
    file: PathBuf,
    defines: &[(String, String)],
    access: &FileAccess,
) -> Result<Scene> {
    // Read the documents: splice includes, substitute `$name`s
    let mut reader = Reader {
        main_dir: base_dir.to_path_buf(),
        files: vec![file.clone()],
        defaults: defines.to_vec(),
        overrides: defines.iter().map(|(n, _)| n.clone()).collect(),
        used: HashSet::new(),
        stack: vec![file.canonicalize().unwrap_or_else(|_| file.clone())],
        includes: 0,
        access: access.clone(),
    };
    let mut top = Vec::new();
    reader.read_document(text, 0, 0, &mut top)?;
    let Reader {
        main_dir,
        files,
        used,
        ..
    } = reader;

    // Index the ids, then build the scene from the top-level elements
    let mut b = Builder {
        access,
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
        spheres: Vec::new(),
    };
    for el in &top {
        b.index_ids(el)?;
    }
    for el in &top {
        b.top_level(el)?;
    }
    b.add_spheres();
    for (n, v) in defines {
        if !used.contains(n) {
            b.scene.warnings.push(format!(
                "{}: -D {n}={v} is unused: the scene has no `${n}` and no <default name=\"{n}\">",
                file.display()
            ));
        }
    }
    if !b.camera_seen {
        let main = files.first().cloned().unwrap_or_default();
        super::obj::synthesise_camera(&mut b.scene, &main);
    }
    Ok(b.scene)
}

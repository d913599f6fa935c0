//! The scene as plain data: triangles, materials, emitters and the camera.
//!
//! Every shape, whatever file it came from, is flattened into one set of
//! world-space triangles. Loaders live in the submodules ([`mitsuba`],
//! [`pbrt`], [`gltf`], [`obj`], [`ply`]); nothing else in the crate reads files.

// Every file a scene names is read through `access` (clippy.toml lists
// the calls this forbids everywhere else under `scene`).
#![deny(clippy::disallowed_methods)]

pub mod access;
pub mod builtin;
pub mod env;
pub mod gltf;
pub mod material;
pub mod mitsuba;
pub mod obj;
pub mod pbrt;
pub mod ply;
pub mod punctual;
pub mod records;
pub mod shapes;
pub mod summary;

use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::{Mat4, Vec2, Vec3};

use crate::geometry::Frame;
pub use access::{AccessError, FileAccess, FileKind, ReadPolicy};
pub use env::Environment;
pub use gltf::normalmap::NormalMap;
pub use material::{Coat, Material, MicrofacetKind, TexImage, Texture};
pub use punctual::{PunctualKind, PunctualLight};
pub use records::{TriRecord, TriRecords};
pub use shapes::MeshData;
pub use summary::Summary;

/// Most triangles a loader produces for one scene, instances included. A
/// guard against files whose few bytes describe a huge scene (glTF nodes
/// shared by many parents, Mitsuba includes that fan out): past it, loading
/// stops with an error naming the count instead of exhausting memory.
pub const MAX_TRIANGLES: u64 = 1 << 26;

/// The bytes a mesh of `vertices` and `triangles` takes while a loader
/// turns it into the scene's: the scene's own copy (position, normal and uv:
/// 32 bytes a vertex; indices and shape: 16 a triangle) and the loader's
/// (as much again, at most). What loaders declare through
/// [`FileAccess::reserve`] before they allocate a mesh, once per instance.
pub fn mesh_memory(vertices: u64, triangles: u64) -> u64 {
    vertices
        .saturating_mul(64)
        .saturating_add(triangles.saturating_mul(28))
}

/// Loads a scene file, choosing the loader by extension: `.xml` (Mitsuba 3),
/// `.pbrt` (pbrt-v4), `.gltf`/`.glb` (glTF 2.0), `.obj` (with its MTL; a
/// camera is synthesised) or `.ply` (one mesh, default material,
/// synthesised camera).
///
/// The scene may read the files under its own folder, and nothing else
/// (see [`access`]); [`load_opts`] widens that.
pub fn load(path: &Path) -> Result<Scene, SceneError> {
    load_opts(path, &LoadOptions::default())
}

/// [`load`] with Mitsuba-style `-D name=value` parameters, which fill the
/// `$name`s of a Mitsuba scene (overriding its `<default>`s). Other formats
/// have no parameters: there, any is a warning.
pub fn load_with(path: &Path, defines: &[(String, String)]) -> Result<Scene, SceneError> {
    load_opts(
        path,
        &LoadOptions {
            defines: defines.to_vec(),
            ..Default::default()
        },
    )
}

/// How a scene file is loaded: its parameters, and what it may read and
/// allocate.
#[derive(Clone, Debug, Default)]
pub struct LoadOptions {
    /// Mitsuba-style `-D name=value` parameters.
    pub defines: Vec<(String, String)>,
    /// The folders the scene may read besides its own, and its memory limit.
    pub read: ReadPolicy,
}

/// [`load`] with `opts`: the scene file and every file it names are read
/// through one [`FileAccess`] (see [`access`]).
pub fn load_opts(path: &Path, opts: &LoadOptions) -> Result<Scene, SceneError> {
    let access = FileAccess::for_scene(path, &opts.read)
        .map_err(|e| SceneError::new(path, 0, e.to_string()))?;
    let defines = &opts.defines[..];
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .unwrap_or_default();
    // pbrt-v4 scenes are also shipped gzip-compressed
    let pbrt_gz = ext == "gz"
        && path
            .file_stem()
            .and_then(|s| s.to_str())
            .is_some_and(|s| s.to_ascii_lowercase().ends_with(".pbrt"));
    let mut scene =
        match ext.as_str() {
            "xml" => return mitsuba::load_with(path, defines, &access),
            "pbrt" => pbrt::load(path, &access)?,
            _ if pbrt_gz => pbrt::load(path, &access)?,
            "obj" => obj::load_obj_scene(path, &access)?,
            "ply" => ply::load_ply_scene(path, &access)?,
            "gltf" | "glb" => gltf::load_gltf(path, &access)?,
            _ => return Err(SceneError::new(
                path,
                0,
                "unknown scene format: expected a .xml (Mitsuba 3), .pbrt or .pbrt.gz (pbrt-v4), .gltf/.glb, .obj or .ply file",
            )),
        };
    for (n, v) in defines {
        scene.warnings.push(format!(
            "{}: -D {n}={v} is unused: only Mitsuba XML scenes have parameters",
            path.display()
        ));
    }
    Ok(scene)
}

/// Loads a Mitsuba 3 scene from a string; relative paths in it resolve
/// against `base_dir`, and `name` stands for the file in messages.
/// It may read the files under `base_dir`.
pub fn load_str(xml: &str, base_dir: &Path, name: &str) -> Result<Scene, SceneError> {
    let access = FileAccess::for_dir(base_dir, &ReadPolicy::default())
        .map_err(|e| SceneError::new(name, 0, e.to_string()))?;
    mitsuba::load_str(xml, base_dir, name, &access)
}

/// An error naming the first non-finite position of `what` in `path`: a NaN
/// or infinite vertex would make its triangles vanish silently, or poison
/// the scene's bounds.
pub(crate) fn check_finite(path: &Path, what: &str, positions: &[Vec3]) -> Result<(), SceneError> {
    match positions.iter().position(|v| !v.is_finite()) {
        None => Ok(()),
        Some(i) => Err(SceneError::new(
            path,
            0,
            format!("vertex {i} of {what} is not finite ({})", positions[i]),
        )),
    }
}

pub use crate::color::{luminance, Rgb};

/// The end of the note [`Scene::light_if_dark`] leaves (after the file's
/// name), by which [`env`] knows the default environment it may replace.
const DEFAULT_ENV_NOTE: &str =
    "the file has no emitters; lit by a default white environment (constant radiance 1)";

/// An error in a scene file: the file, the 1-based line (0 when unknown, and
/// then not shown) and what was wrong or expected.
#[derive(Debug, thiserror::Error)]
#[error("{}{}: {msg}", file.display(), line_suffix(*line))]
pub struct SceneError {
    /// The file that holds the error.
    pub file: PathBuf,
    /// 1-based line number, 0 when the error is not tied to a line.
    pub line: u32,
    /// What was wrong, and what was expected.
    pub msg: String,
}

/// `:line` for a known line, nothing for 0 (binary and JSON formats).
fn line_suffix(line: u32) -> String {
    if line > 0 {
        format!(":{line}")
    } else {
        String::new()
    }
}

impl SceneError {
    /// An error at `file:line`.
    pub fn new(file: impl AsRef<Path>, line: u32, msg: impl Into<String>) -> Self {
        SceneError {
            file: file.as_ref().to_path_buf(),
            line,
            msg: msg.into(),
        }
    }
}

/// One input shape (a mesh file or an analytic shape), as a range of triangles.
#[derive(Clone, Debug)]
pub struct Shape {
    /// The `id` attribute, or a generated name.
    pub name: String,
    /// Index into [`Scene::materials`].
    pub material: u32,
    /// Index into [`Scene::emitters`] when the shape is an area light.
    pub emitter: Option<u32>,
    /// First triangle in [`Scene::triangles`].
    pub first_tri: u32,
    /// Number of triangles.
    pub tri_count: u32,
    /// True when the vertices carry smooth shading normals.
    pub smooth: bool,
    /// A tangent-space normal map perturbing the shading normal (glTF
    /// `normalTexture`), with the tangents of the shape's triangles;
    /// `None` for nearly every shape.
    pub normal_map: Option<Box<NormalMap>>,
    /// Where a glTF loader took the shape from (`None` for other
    /// loaders): enough for a writer to map the shape's triangles and
    /// vertices back to the primitive's accessors.
    pub source: Option<Box<ShapeSource>>,
}

/// The glTF primitive a shape was read from. The shape's vertices are the
/// primitive's, in order (scene vertex `first_vertex + i` is the
/// primitive's vertex `i`); its triangles are the primitive's minus the
/// degenerate ones the loader dropped, in order, with the winding reversed
/// when the node's transform mirrors.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ShapeSource {
    /// Index of the glTF node instancing the mesh.
    pub node: u32,
    /// Index of the glTF mesh.
    pub mesh: u32,
    /// Index of the primitive in the mesh.
    pub primitive: u32,
    /// The scene vertex ([`Scene::positions`]) of the primitive's vertex 0.
    pub first_vertex: u32,
    /// How many vertices the primitive has (all of them are in the scene).
    pub vertex_count: u32,
    /// How many triangles the primitive has (its index count / 3).
    pub prim_triangles: u32,
    /// For each of the shape's triangles, the primitive triangle it is
    /// (empty when none was dropped: then triangle `k` is the primitive's
    /// triangle `k`).
    pub kept: Vec<u32>,
    /// True when the node's transform has a negative determinant, so that
    /// the loader swapped the second and third corner of every triangle.
    pub mirrored: bool,
}

impl ShapeSource {
    /// The primitive triangle of the shape's triangle `k`.
    pub fn prim_triangle(&self, k: u32) -> u32 {
        if self.kept.is_empty() {
            k
        } else {
            self.kept[k as usize]
        }
    }
}

/// A light source. Area lights point at their shape; the environment
/// emitters surround the scene; punctual lights are points or directions.
#[derive(Clone, Debug)]
pub enum EmitterDesc {
    /// Uniform radiance leaving the front side (the side the geometric normal
    /// points to) of every triangle of a shape.
    Area {
        /// Index into [`Scene::shapes`].
        shape: u32,
        /// Emitted radiance, W/(m²·sr) per channel.
        radiance: Rgb,
    },
    /// Radiance arriving uniformly from every direction (Mitsuba `constant`).
    Constant {
        /// Radiance of the sky.
        radiance: Rgb,
    },
    /// A latitude–longitude environment map (Mitsuba `envmap`).
    EnvMap {
        /// The radiance image.
        image: Arc<TexImage>,
        /// Multiplier.
        scale: f32,
        /// Map-to-world transform (Mitsuba `to_world`).
        to_world: Mat4,
    },
    /// A point, spot or directional light (glTF `KHR_lights_punctual`):
    /// a delta light, reached only by light sampling.
    Punctual(PunctualLight),
}

/// The perspective sensor, as the scene file gives it (Mitsuba conventions:
/// camera space looks along +z with +y up and +x to the image's left).
#[derive(Clone, Debug)]
pub struct CameraDesc {
    /// Camera-to-world transform.
    pub to_world: Mat4,
    /// Horizontal field of view in degrees (after resolving `fov_axis`).
    pub fov_x_deg: f32,
    /// Film width in pixels.
    pub width: u32,
    /// Film height in pixels.
    pub height: u32,
    /// Near clip distance.
    pub near_clip: f32,
}

impl CameraDesc {
    /// Builds the description from a field of view measured along `axis`
    /// (`x`, `y`, `smaller`, `larger` or `diagonal`, as Mitsuba's `fov_axis`).
    pub fn from_fov(
        to_world: Mat4,
        fov_deg: f32,
        axis: &str,
        width: u32,
        height: u32,
    ) -> Option<Self> {
        let (w, h) = (width as f32, height as f32);
        let t = (fov_deg.to_radians() * 0.5).tan();
        // half-extent of the image plane at distance 1 along x
        let tx = match axis {
            "x" => t,
            "y" => t * w / h,
            "smaller" => {
                if w <= h {
                    t
                } else {
                    t * w / h
                }
            }
            "larger" => {
                if w >= h {
                    t
                } else {
                    t * w / h
                }
            }
            "diagonal" => t * w / (w * w + h * h).sqrt(),
            _ => return None,
        };
        Some(CameraDesc {
            to_world,
            fov_x_deg: 2.0 * tx.atan().to_degrees(),
            width,
            height,
            near_clip: 1e-2,
        })
    }
}

/// The whole scene: world-space triangles with per-vertex attributes, the
/// shapes they came from, materials, emitters and the camera.
#[derive(Clone, Debug)]
pub struct Scene {
    /// Vertex positions.
    pub positions: Vec<Vec3>,
    /// Per-vertex shading normals (same length as `positions`; only read for
    /// shapes with `smooth`).
    pub normals: Vec<Vec3>,
    /// Per-vertex texture coordinates (same length as `positions`; zero when
    /// the source had none).
    pub uvs: Vec<Vec2>,
    /// The asset's second uv set (glTF TEXCOORD_1), one per vertex like
    /// `positions`; empty when the asset has none (a shape of a primitive
    /// without one gets zeros). Only the glTF loader fills it.
    pub uv1: Vec<Vec2>,
    /// Vertex indices of each triangle.
    pub triangles: Vec<[u32; 3]>,
    /// The shape of each triangle.
    pub tri_shape: Vec<u32>,
    /// Input shapes.
    pub shapes: Vec<Shape>,
    /// Materials, referenced by shapes.
    pub materials: Vec<Material>,
    /// Light sources.
    pub emitters: Vec<EmitterDesc>,
    /// The camera.
    pub camera: CameraDesc,
    /// Where the scene came from (for messages).
    pub source: String,
    /// Things the loader skipped or approximated (an `integrator` block, a
    /// non-box reconstruction filter, a synthesised camera...), one per line.
    pub warnings: Vec<String>,
    /// Things the loader added or chose that are not problems but change
    /// the image (a default environment lighting a bare mesh), one per line.
    pub notes: Vec<String>,
    /// The scene's own sample count (Mitsuba's `<sampler>` `sample_count`),
    /// a default budget for a render that gives none.
    pub sample_count: Option<u32>,
}

/// A ray–surface hit with everything shading needs.
#[derive(Clone, Copy, Debug)]
pub struct SurfacePoint {
    /// Position.
    pub p: Vec3,
    /// Geometric normal (unit, from the triangle's winding).
    pub ng: Vec3,
    /// Shading frame (normal interpolated for smooth shapes, else `ng`;
    /// then perturbed by the shape's normal map, if any).
    pub frame: Frame,
    /// Texture coordinates.
    pub uv: Vec2,
    /// Triangle index.
    pub tri: u32,
    /// Shape index.
    pub shape: u32,
}

impl Scene {
    /// An empty scene with a default camera, to be filled by a loader.
    pub fn empty(source: impl Into<String>) -> Self {
        Scene {
            positions: Vec::new(),
            normals: Vec::new(),
            uvs: Vec::new(),
            uv1: Vec::new(),
            triangles: Vec::new(),
            tri_shape: Vec::new(),
            shapes: Vec::new(),
            materials: Vec::new(),
            emitters: Vec::new(),
            camera: CameraDesc {
                to_world: Mat4::IDENTITY,
                fov_x_deg: 45.0,
                width: 256,
                height: 256,
                near_clip: 1e-2,
            },
            source: source.into(),
            warnings: Vec::new(),
            notes: Vec::new(),
            sample_count: None,
        }
    }

    /// Lights a scene that has no emitter with a constant white environment
    /// (radiance 1), and notes it: a bare OBJ, PLY or glTF mesh would
    /// otherwise render black. Mitsuba scenes are complete descriptions and
    /// do not get one.
    pub(crate) fn light_if_dark(&mut self, path: &Path) {
        if self.emitters.is_empty() {
            self.emitters
                .push(EmitterDesc::Constant { radiance: Rgb::ONE });
            self.notes
                .push(format!("{}: {DEFAULT_ENV_NOTE}", path.display()));
        }
    }

    /// Adds a material and returns its index.
    pub fn add_material(&mut self, m: Material) -> u32 {
        self.materials.push(m);
        (self.materials.len() - 1) as u32
    }

    /// Adds a triangle mesh, already in world space. `normals` and `uvs`, when
    /// given, have one entry per position. Degenerate triangles (zero area or
    /// non-finite) are dropped. When `emitter_radiance` is given the shape
    /// becomes an area light. Returns the shape index.
    #[allow(clippy::too_many_arguments)]
    pub fn add_mesh(
        &mut self,
        name: impl Into<String>,
        positions: &[Vec3],
        normals: Option<&[Vec3]>,
        uvs: Option<&[Vec2]>,
        indices: &[[u32; 3]],
        material: u32,
        emitter_radiance: Option<Rgb>,
    ) -> u32 {
        let base = self.positions.len() as u32;
        let shape_id = self.shapes.len() as u32;
        self.positions.extend_from_slice(positions);
        match normals {
            Some(n) if n.len() == positions.len() => self
                .normals
                .extend(n.iter().map(|v| v.try_normalize().unwrap_or(Vec3::Z))),
            _ => self
                .normals
                .extend(std::iter::repeat_n(Vec3::Z, positions.len())),
        }
        match uvs {
            Some(t) if t.len() == positions.len() => self.uvs.extend_from_slice(t),
            _ => self
                .uvs
                .extend(std::iter::repeat_n(Vec2::ZERO, positions.len())),
        }
        let first_tri = self.triangles.len() as u32;
        for t in indices {
            if t.iter().any(|&i| i as usize >= positions.len()) {
                continue;
            }
            let (a, b, c) = (
                positions[t[0] as usize],
                positions[t[1] as usize],
                positions[t[2] as usize],
            );
            let area2 = (b - a).cross(c - a).length();
            if !(area2.is_finite() && area2 > 0.0) {
                continue;
            }
            self.triangles.push([t[0] + base, t[1] + base, t[2] + base]);
            self.tri_shape.push(shape_id);
        }
        let tri_count = self.triangles.len() as u32 - first_tri;
        let emitter = emitter_radiance.map(|radiance| {
            self.emitters.push(EmitterDesc::Area {
                shape: shape_id,
                radiance,
            });
            (self.emitters.len() - 1) as u32
        });
        self.shapes.push(Shape {
            name: name.into(),
            material,
            emitter,
            first_tri,
            tri_count,
            smooth: normals.is_some_and(|n| n.len() == positions.len()),
            normal_map: None,
            source: None,
        });
        shape_id
    }

    /// The three corners of triangle `tri`.
    #[inline]
    pub fn tri_vertices(&self, tri: u32) -> [Vec3; 3] {
        let t = self.triangles[tri as usize];
        [
            self.positions[t[0] as usize],
            self.positions[t[1] as usize],
            self.positions[t[2] as usize],
        ]
    }

    /// Area of triangle `tri`.
    pub fn tri_area(&self, tri: u32) -> f32 {
        let [a, b, c] = self.tri_vertices(tri);
        0.5 * (b - a).cross(c - a).length()
    }

    /// The surface point at barycentrics (`b1`, `b2`) of triangle `tri`.
    #[inline(always)]
    pub fn surface_point(&self, tri: u32, b1: f32, b2: f32) -> SurfacePoint {
        let t = self.triangles[tri as usize];
        records::interpolate(
            self,
            tri,
            self.tri_shape[tri as usize],
            t.map(|i| self.positions[i as usize]),
            t.map(|i| self.uvs[i as usize]),
            || t,
            b1,
            b2,
        )
    }

    /// The material of a surface point.
    #[inline]
    pub fn material_of(&self, sp: &SurfacePoint) -> &Material {
        &self.materials[self.shapes[sp.shape as usize].material as usize]
    }

    /// Axis-aligned bounds of all triangles (min, max).
    pub fn bounds(&self) -> (Vec3, Vec3) {
        let mut lo = Vec3::splat(f32::INFINITY);
        let mut hi = Vec3::splat(f32::NEG_INFINITY);
        for t in &self.triangles {
            for &i in t {
                lo = lo.min(self.positions[i as usize]);
                hi = hi.max(self.positions[i as usize]);
            }
        }
        if lo.x > hi.x {
            (Vec3::ZERO, Vec3::ZERO)
        } else {
            (lo, hi)
        }
    }

    /// Overrides the film resolution, keeping the horizontal field of view.
    pub fn set_resolution(&mut self, width: u32, height: u32) {
        self.camera.width = width.max(1);
        self.camera.height = height.max(1);
    }
}

//! glTF 2.0 scenes (`.gltf` with its buffers and images, or `.glb`), through
//! the `gltf` crate.
//!
//! What is read, and how the metallic–roughness model maps onto kalos's
//! materials (a choice: glTF's BRDF is not one of Mitsuba's plugins):
//!
//! - every triangle primitive of every mesh node of the default scene, with
//!   the node's world transform (a negative determinant reverses the winding,
//!   as the glTF specification says), normals and the first uv set; the
//!   second uv set is kept in [`Scene::uv1`], and each shape records the
//!   node, mesh and primitive it came from ([`super::ShapeSource`]);
//! - `baseColorFactor` × `baseColorTexture` (sRGB) → `diffuse` for
//!   non-metals (`metallicFactor` < 0.5); metals become a mirror-Fresnel
//!   `conductor` (roughness 0) or a GGX `roughconductor` with α = roughness²
//!   tinted by the base colour (glTF's F0 of a metal);
//! - `doubleSided` → `twosided`;
//! - a non-zero `emissiveFactor` × `KHR_materials_emissive_strength` → an
//!   area emitter with that radiance (glTF's emission is unitless: it is
//!   read as W/(m²·sr), with a warning); negative emission is an error;
//! - the first perspective camera (glTF cameras look along −z with +x to the
//!   right; kalos's along +z with +x to the left, so the camera's world
//!   transform is composed with diag(−1, 1, −1)). Without one, a camera is
//!   synthesised, with a warning.
//!
//! Skipped with a warning: non-triangle primitives, emissive and
//! metallic-roughness textures, texture transforms, and punctual lights.
//!
//! Refused before anything is allocated: GLB lengths beyond the file, node
//! cycles, and node DAGs that instance more than [`super::MAX_TRIANGLES`]
//! triangles. A file with no emissive material is lit by a constant white
//! environment, with a note in [`Scene::notes`].
//!
//! The file, its buffers and its images are read through the scene's
//! [`FileAccess`], not by the `gltf` crate: a URI is a `data:` URI (decoded
//! in memory), or a relative path (percent-decoded, against the file's
//! folder) or a `file:` URI, read only if the access allows it. Every file the glTF names is checked before any is
//! read; the memory of its instanced meshes, its buffers and its base
//! colour images (their sizes from the image headers) is declared
//! ([`FileAccess::reserve`]) before it is allocated. Images that no
//! material uses as its base colour are checked, not read.

use crate::scene::access::{FileAccess, FileKind};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::{Mat3, Mat4, Vec2, Vec3};

use super::shapes::MeshData;
use super::{
    CameraDesc, Material, MicrofacetKind, Rgb, Scene, SceneError, ShapeSource, TexImage, Texture,
};

/// Largest number of node instances visited: a node referenced from many
/// parents is walked once per path to it, so a small file can describe an
/// exponentially large tree.
const MAX_NODES: u64 = 1 << 20;

/// Loads a glTF 2.0 file as a scene.
pub fn load_gltf(path: &Path, access: &FileAccess) -> Result<Scene, SceneError> {
    let err = |msg: String| SceneError::new(path, 0, msg);
    let (doc, buffers, images) = import(path, access)?;
    let mut scene = Scene::empty(path.display().to_string());

    // Materials, each with its emission
    let mut mats = Vec::new();
    let mut textures: Vec<Option<Arc<TexImage>>> = vec![None; images.len()];
    for m in doc.materials() {
        mats.push(material(&m, &images, &mut textures, &mut scene, path)?);
    }

    // Walk the node tree of the default scene
    let gscene = doc
        .default_scene()
        .or_else(|| doc.scenes().next())
        .ok_or_else(|| err("glTF file has no scene".into()))?;
    check_instancing(&doc, &gscene, path)?;
    let mut walk = Walk {
        path,
        buffers: &buffers,
        mats: &mats,
        default_mat: None,
        scene,
        camera_seen: false,
    };
    walk.nodes(&gscene)?;
    let Walk {
        mut scene,
        camera_seen,
        ..
    } = walk;
    if scene.triangles.is_empty() {
        return Err(err("glTF file has no triangles".into()));
    }
    if !scene.uv1.is_empty() {
        scene.uv1.resize(scene.positions.len(), Vec2::ZERO);
    }
    if !camera_seen {
        super::obj::synthesise_camera(&mut scene, path);
    }
    scene.light_if_dark(path);
    Ok(scene)
}

/// Adds a warning about the file to the scene.
fn warn(scene: &mut Scene, path: &Path, msg: String) {
    scene.warnings.push(format!("{}: {msg}", path.display()));
}

/// Adds one glTF material to the scene (see the module doc for the
/// mapping) and returns its index with its emitted radiance, if any.
/// `textures` caches the decoded images, by image index (`images` holds
/// those used as a base colour).
fn material(
    m: &gltf::Material,
    images: &[Option<gltf::image::Data>],
    textures: &mut [Option<Arc<TexImage>>],
    scene: &mut Scene,
    path: &Path,
) -> Result<(u32, Option<Rgb>), SceneError> {
    let pbr = m.pbr_metallic_roughness();
    let f = pbr.base_color_factor();
    let factor = Rgb::new(f[0], f[1], f[2]);
    if !(factor.is_finite() && factor.min_element() >= 0.0) {
        return Err(SceneError::new(
            path,
            0,
            format!(
                "material {} `{}`: baseColorFactor must be non-negative, found ({}, {}, {})",
                m.index().map_or("?".into(), |i| i.to_string()),
                name_of(m),
                factor.x,
                factor.y,
                factor.z
            ),
        ));
    }
    let base = match pbr.base_color_texture() {
        Some(info) => base_color_texture(m, &info, factor, images, textures, scene, path),
        None => Texture::Constant(factor),
    };
    if pbr.metallic_roughness_texture().is_some() || m.emissive_texture().is_some() {
        warn(
            scene,
            path,
            format!(
                "material `{}`: metallic-roughness and emissive textures are ignored",
                name_of(m)
            ),
        );
    }
    let roughness = pbr.roughness_factor().clamp(0.0, 1.0);
    let material = if pbr.metallic_factor() >= 0.5 {
        // a perfect-mirror Fresnel (eta 0, k 1) scaled by the base colour
        let (eta, k) = (Rgb::ZERO, Rgb::ONE);
        if roughness <= 0.0 {
            Material::Conductor {
                eta,
                k,
                specular_reflectance: base,
            }
        } else {
            Material::RoughConductor {
                distribution: MicrofacetKind::Ggx,
                alpha: (roughness * roughness).max(1e-3),
                eta,
                k,
                specular_reflectance: base,
            }
        }
    } else {
        Material::Diffuse { reflectance: base }
    };
    let material = if m.double_sided() {
        Material::TwoSided(Box::new(material))
    } else {
        material
    };
    let emission = emission(m, scene, path)?;
    Ok((scene.add_material(material), emission))
}

/// The base colour of a material with a `baseColorTexture`: the image
/// (decoded once, through `textures`) times `factor`, or `factor` alone,
/// with a warning, when the image's format is not supported.
fn base_color_texture(
    m: &gltf::Material,
    info: &gltf::texture::Info,
    factor: Rgb,
    images: &[Option<gltf::image::Data>],
    textures: &mut [Option<Arc<TexImage>>],
    scene: &mut Scene,
    path: &Path,
) -> Texture {
    let i = info.texture().source().index();
    if info.tex_coord() != 0 {
        warn(
            scene,
            path,
            format!("material `{}`: only uv set 0 is read", name_of(m)),
        );
    }
    let img = match textures.get(i).cloned().flatten() {
        Some(img) => Some(img),
        None => {
            let img = images
                .get(i)
                .and_then(Option::as_ref)
                .and_then(to_tex_image)
                .map(Arc::new);
            if let (Some(img), Some(slot)) = (&img, textures.get_mut(i)) {
                *slot = Some(img.clone());
            }
            img
        }
    };
    match img {
        Some(img) => {
            let img = if factor == Rgb::ONE {
                img
            } else {
                Arc::new(img.map(|c| c * factor))
            };
            // glTF's uv (0, 0) is the image's top-left corner, as
            // Mitsuba's; TexImage puts v = 0 at the bottom
            Texture::Bitmap {
                image: img,
                to_uv: glam::Affine2::from_mat2_translation(
                    glam::Mat2::from_diagonal(Vec2::new(1.0, -1.0)),
                    Vec2::new(0.0, 1.0),
                ),
            }
        }
        None => {
            warn(
                scene,
                path,
                format!("material `{}`: unsupported texture format", name_of(m)),
            );
            Texture::Constant(factor)
        }
    }
}

/// A material's emitted radiance: `emissiveFactor` ×
/// `KHR_materials_emissive_strength`, `None` when black. Emission is
/// unitless in glTF, so a warning says how it is read.
fn emission(m: &gltf::Material, scene: &mut Scene, path: &Path) -> Result<Option<Rgb>, SceneError> {
    // KHR_materials_emissive_strength scales the [0, 1] factor (Blender
    // writes emission strengths above 1 this way)
    let e = Rgb::from(m.emissive_factor()) * m.emissive_strength().unwrap_or(1.0);
    if !(e.is_finite() && e.min_element() >= 0.0) {
        return Err(SceneError::new(
            path,
            0,
            format!(
                "material {} `{}`: emission (emissiveFactor × emissiveStrength) must be finite \
                 and non-negative, found ({}, {}, {})",
                m.index().map_or("?".into(), |i| i.to_string()),
                name_of(m),
                e.x,
                e.y,
                e.z
            ),
        ));
    }
    let emission = (e.max_element() > 0.0).then_some(e);
    if emission.is_some() {
        warn(
            scene,
            path,
            format!(
                "material `{}`: glTF emission is unitless; read as radiance ({}, {}, {}) \
                 W/(m²·sr){}",
                name_of(m),
                e.x,
                e.y,
                e.z,
                if m.emissive_strength().is_none() && e.max_element() <= 1.0 {
                    // an exporter's display white, not a lamp's output:
                    // Blender writes lamps as KHR_lights_punctual, and
                    // emission strengths above 1 as emissiveStrength
                    " (at most 1, as viewers show it: a dim light; the file has no \
                     KHR_materials_emissive_strength, and punctual lights are not read)"
                } else {
                    ""
                }
            ),
        );
    }
    Ok(emission)
}

/// The walk of a glTF scene's node tree: what it adds meshes with, and
/// the scene it adds them to.
struct Walk<'a> {
    path: &'a Path,
    buffers: &'a [gltf::buffer::Data],
    /// Each glTF material's index in the scene, and its emission.
    mats: &'a [(u32, Option<Rgb>)],
    /// The white diffuse material of primitives without one, once added.
    default_mat: Option<u32>,
    scene: Scene,
    /// Whether a camera was read (the first perspective one is used).
    camera_seen: bool,
}

impl Walk<'_> {
    /// Walks the nodes of `gscene` depth first, each with its world
    /// transform, adding their mesh primitives and the first camera.
    fn nodes(&mut self, gscene: &gltf::Scene) -> Result<(), SceneError> {
        let mut stack: Vec<(gltf::Node, Mat4)> =
            gscene.nodes().map(|n| (n, Mat4::IDENTITY)).collect();
        while let Some((node, parent)) = stack.pop() {
            let world = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
            if let Some(mesh) = node.mesh() {
                for (k, prim) in mesh.primitives().enumerate() {
                    self.primitive(&node, &mesh, k, &prim, world)?;
                }
            }
            if let (Some(cam), false) = (node.camera(), self.camera_seen) {
                if let Some(c) = camera(&cam, world) {
                    self.scene.camera = c;
                    self.camera_seen = true;
                }
            }
            for c in node.children() {
                stack.push((c, world));
            }
        }
        Ok(())
    }

    /// Adds primitive `k` of a node's mesh in world space, or skips it with
    /// a warning when it is not made of triangles or has no readable
    /// positions.
    fn primitive(
        &mut self,
        node: &gltf::Node,
        mesh: &gltf::Mesh,
        k: usize,
        prim: &gltf::Primitive,
        world: Mat4,
    ) -> Result<(), SceneError> {
        let (path, scene) = (self.path, &mut self.scene);
        let err = |msg: String| SceneError::new(path, 0, msg);
        if prim.mode() != gltf::mesh::Mode::Triangles {
            warn(
                scene,
                path,
                format!(
                    "mesh `{}`: non-triangle primitive skipped",
                    mesh.name().unwrap_or("?")
                ),
            );
            return Ok(());
        }
        check_accessor_types(prim)
            .map_err(|e| err(format!("mesh {} primitive {k}: {e}", mesh.index())))?;
        let buffers = self.buffers;
        let reader = prim.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
        let Some(positions) = reader.read_positions() else {
            warn(
                scene,
                path,
                format!(
                    "mesh {} primitive {k}: no readable POSITION (missing, or outside \
                     its buffer): skipped",
                    mesh.index()
                ),
            );
            return Ok(());
        };
        let positions: Vec<Vec3> = positions.map(Vec3::from).collect();
        super::check_finite(
            path,
            &format!("mesh {} primitive {k}", mesh.index()),
            &positions,
        )?;
        let n = positions.len();
        let normals: Option<Vec<Vec3>> = reader
            .read_normals()
            .map(|it| it.map(Vec3::from).collect::<Vec<_>>())
            .filter(|v| v.len() == n);
        let uvs: Option<Vec<Vec2>> = reader
            .read_tex_coords(0)
            .map(|t| t.into_f32().map(Vec2::from).collect::<Vec<_>>())
            .filter(|v| v.len() == n);
        let uv1: Option<Vec<Vec2>> = reader
            .read_tex_coords(1)
            .map(|t| t.into_f32().map(Vec2::from).collect::<Vec<_>>())
            .filter(|v| v.len() == n);
        let flat: Vec<u32> = match reader.read_indices() {
            Some(ix) => ix.into_u32().collect(),
            None => (0..n as u32).collect(),
        };
        let indices = flat.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect();
        let mut m = MeshData {
            positions,
            normals,
            uvs,
            indices,
        };
        m.transform(&world);
        let mirrored = Mat3::from_mat4(world).determinant() < 0.0;
        if mirrored {
            m.reverse_winding();
        }
        let (material, emission) = match prim.material().index().and_then(|i| self.mats.get(i)) {
            Some(&(mat, e)) => (mat, e),
            None => {
                let d = *self.default_mat.get_or_insert_with(|| {
                    scene.add_material(Material::Diffuse {
                        reflectance: Texture::Constant(Rgb::ONE),
                    })
                });
                (d, None)
            }
        };
        let name = format!("{}.{k}", node.name().or(mesh.name()).unwrap_or("mesh"));
        let first_vertex = scene.positions.len() as u32;
        let shape = scene.add_mesh(
            name,
            &m.positions,
            m.normals.as_deref(),
            m.uvs.as_deref(),
            &m.indices,
            material,
            emission,
        );
        keep_uv1(scene, first_vertex, n, uv1.as_deref());
        let s = &scene.shapes[shape as usize];
        let kept = kept_triangles(
            &scene.triangles[s.first_tri as usize..][..s.tri_count as usize],
            &m.indices,
            first_vertex,
        );
        scene.shapes[shape as usize].source = Some(Box::new(ShapeSource {
            node: node.index() as u32,
            mesh: mesh.index() as u32,
            primitive: k as u32,
            first_vertex,
            vertex_count: n as u32,
            prim_triangles: m.indices.len() as u32,
            kept,
            mirrored,
        }));
        Ok(())
    }
}

/// Appends a primitive's TEXCOORD_1 (`n` vertices from `first_vertex`) to
/// [`Scene::uv1`], which stays empty until a primitive has one: then the
/// vertices before get zeros, as do later primitives without one.
fn keep_uv1(scene: &mut Scene, first_vertex: u32, n: usize, uv1: Option<&[Vec2]>) {
    if uv1.is_none() && scene.uv1.is_empty() {
        return;
    }
    scene.uv1.resize(first_vertex as usize, Vec2::ZERO);
    match uv1 {
        Some(t) => scene.uv1.extend_from_slice(t),
        None => scene.uv1.resize(first_vertex as usize + n, Vec2::ZERO),
    }
}

/// For each triangle the scene kept of a primitive (`kept`, on scene
/// vertices), the index of the primitive triangle (`all`, on the
/// primitive's vertices, which start at scene vertex `base`) it is; empty
/// when every triangle was kept. The scene keeps them in order, so one pass
/// matches them.
fn kept_triangles(kept: &[[u32; 3]], all: &[[u32; 3]], base: u32) -> Vec<u32> {
    if kept.len() == all.len() {
        return Vec::new();
    }
    let mut out = Vec::with_capacity(kept.len());
    let mut j = 0;
    for t in kept {
        let local = t.map(|i| i - base);
        while j < all.len() && all[j] != local {
            j += 1;
        }
        out.push(j as u32);
        j += 1;
    }
    out
}

/// A perspective glTF camera placed by `world`, as kalos's camera (`None`
/// for an orthographic camera, or one kalos cannot build).
fn camera(cam: &gltf::Camera, world: Mat4) -> Option<CameraDesc> {
    let gltf::camera::Projection::Perspective(p) = cam.projection() else {
        return None;
    };
    let aspect = p.aspect_ratio().filter(|a| *a > 0.0).unwrap_or(1.0);
    let height = 512u32;
    let width = ((height as f32 * aspect).round() as u32).clamp(1, 1 << 16);
    let to_world = world * Mat4::from_scale(Vec3::new(-1.0, 1.0, -1.0));
    let mut c = CameraDesc::from_fov(to_world, p.yfov().to_degrees(), "y", width, height)?;
    c.near_clip = p.znear().max(1e-6);
    Some(c)
}

/// The buffers and images of a glTF file, as [`import`] gives them: the
/// document, each buffer's bytes (padded to a multiple of four, as the
/// `gltf` crate's readers expect), and each image decoded when a material
/// uses it as its base colour (`None` otherwise).
type Imported = (
    gltf::Document,
    Vec<gltf::buffer::Data>,
    Vec<Option<gltf::image::Data>>,
);

/// Reads a glTF or GLB file once, through `access`, checking what the
/// `gltf` crate would trust before it does: the GLB lengths
/// ([`check_glb_lengths`]) and the accessor indices
/// ([`check_attribute_indices`]). Then validates it, checks its node graph
/// ([`check_instancing`]) and every file its buffers and images name,
/// declares the memory of its meshes and buffers, and reads its buffers
/// and its base colour images (each declared from its header before it
/// is decoded).
fn import(path: &Path, access: &FileAccess) -> Result<Imported, SceneError> {
    let err = |msg: String| SceneError::new(path, 0, msg);
    let bytes = access
        .read(path, FileKind::Scene)
        .map_err(|e| err(e.to_string()))?;
    check_glb_lengths(path, &bytes)?;
    let cannot = |e: gltf::Error| err(format!("cannot read glTF file: {e}"));
    let gltf::Gltf { document, mut blob } =
        gltf::Gltf::from_slice_without_validation(&bytes).map_err(cannot)?;
    check_attribute_indices(path, document.as_json())?;
    let document = gltf::Document::from_json(document.into_json()).map_err(cannot)?;
    // the JSON text, to name the line of a URI in errors (a GLB's is binary
    // around it: its errors have no line, and its bytes go now, the binary
    // chunk having been copied into `blob`)
    let text = if bytes.starts_with(b"glTF") {
        drop(bytes);
        Vec::new()
    } else {
        bytes
    };
    let fail = |what: String, uri: &str, e: String| {
        SceneError::new(
            path,
            uri_line(&text, uri),
            format!("{what} (`{}`): {e}", short_uri(uri)),
        )
    };

    // the node graph, and the memory of the meshes it instances
    if let Some(gscene) = document
        .default_scene()
        .or_else(|| document.scenes().next())
    {
        check_instancing(&document, &gscene, path)?;
        reserve_meshes(&document, &gscene, path, access)?;
    }

    // where each buffer and image comes from: every file checked before
    // any is read
    let base = path.parent().unwrap_or(Path::new("./"));
    let json = document.as_json();
    let mut buffer_src = Vec::with_capacity(json.buffers.len());
    for (i, b) in json.buffers.iter().enumerate() {
        buffer_src.push(match &b.uri {
            None => None,
            Some(uri) => Some(
                locate(uri, base, FileKind::Mesh, access)
                    .map_err(|e| fail(format!("buffer {i}"), uri, e))?,
            ),
        });
    }
    let mut image_src = Vec::with_capacity(json.images.len());
    for (i, img) in json.images.iter().enumerate() {
        // a bufferView comes first, as in the gltf crate
        image_src.push(match (&img.uri, &img.buffer_view) {
            (Some(uri), None) => Some(
                locate(uri, base, FileKind::Image, access)
                    .map_err(|e| fail(format!("image {i}"), uri, e))?,
            ),
            _ => None,
        });
    }

    // the buffers
    let mut buffers = Vec::with_capacity(json.buffers.len());
    for (i, (b, src)) in json.buffers.iter().zip(buffer_src).enumerate() {
        let uri = b.uri.as_deref().unwrap_or("");
        let what = || match &b.uri {
            Some(_) => format!("buffer {i}"),
            None => format!("buffer {i} (the GLB's binary chunk)"),
        };
        let size = match &src {
            None => blob.as_ref().map_or(0, |d| d.len() as u64),
            Some(Located::Data(d, _)) => d.len() as u64,
            Some(Located::File(_, size)) => *size,
        };
        access
            .reserve(format!("glTF buffer {i} `{}`", short_uri(uri)), size)
            .map_err(|e| fail(what(), uri, e.to_string()))?;
        let mut data = match src {
            None => blob.take().ok_or_else(|| {
                err(format!(
                    "buffer {i} has no uri, so it is the GLB's binary chunk, \
                     but the file has none (or another buffer took it)"
                ))
            })?,
            Some(Located::Data(d, _)) => d,
            Some(Located::File(p, _)) => access
                .read(&p, FileKind::Mesh)
                .map_err(|e| fail(what(), uri, e.to_string()))?,
        };
        let declared = b.byte_length.0;
        if (data.len() as u64) < declared {
            return Err(fail(
                what(),
                uri,
                format!(
                    "it has {} bytes, fewer than its byteLength {declared}",
                    data.len()
                ),
            ));
        }
        while data.len() % 4 != 0 {
            data.push(0);
        }
        buffers.push(gltf::buffer::Data(data));
    }

    let images = read_images(path, &text, &document, &buffers, image_src, access)?;
    Ok((document, buffers, images))
}

/// The images of `document` used as a base colour (None for the others),
/// each read from where `image_src` says ([`locate`]d by [`import`]) or
/// from its buffer view, and declared to `access` from its header before
/// it is decoded. `text` is the glTF's JSON text, to name a URI's line.
fn read_images(
    path: &Path,
    text: &[u8],
    document: &gltf::Document,
    buffers: &[gltf::buffer::Data],
    image_src: Vec<Option<Located>>,
    access: &FileAccess,
) -> Result<Vec<Option<gltf::image::Data>>, SceneError> {
    let err = |msg: String| SceneError::new(path, 0, msg);
    let fail = |what: String, uri: &str, e: String| {
        SceneError::new(
            path,
            uri_line(text, uri),
            format!("{what} (`{}`): {e}", short_uri(uri)),
        )
    };
    let json = document.as_json();
    // the images used as a base colour, each declared from its header
    // before it is decoded
    let mut used = vec![false; json.images.len()];
    for m in document.materials() {
        if let Some(info) = m.pbr_metallic_roughness().base_color_texture() {
            if let Some(u) = used.get_mut(info.texture().source().index()) {
                *u = true;
            }
        }
    }
    let mut images = Vec::with_capacity(json.images.len());
    for (i, (img, src)) in json.images.iter().zip(image_src).enumerate() {
        if !used[i] {
            images.push(None);
            continue;
        }
        let uri = match img.buffer_view {
            None => img.uri.as_deref().unwrap_or(""),
            Some(_) => "",
        };
        let mime = img.mime_type.as_ref().map(|m| m.0.as_str());
        // a data: URI's own media type comes first, as in the gltf crate
        let (bytes, mime): (std::borrow::Cow<[u8]>, Option<&str>) = match &src {
            Some(Located::File(p, _)) => (
                access
                    .read(p, FileKind::Image)
                    .map_err(|e| fail(format!("image {i}"), uri, e.to_string()))?
                    .into(),
                mime,
            ),
            Some(Located::Data(d, data_mime)) => (d[..].into(), data_mime.as_deref().or(mime)),
            None => match img
                .buffer_view
                .as_ref()
                .and_then(|v| view_bytes(document, buffers, v.value()))
            {
                Some(b) => (b.into(), mime),
                None => {
                    return Err(err(format!(
                        "image {i} has no uri, and no bufferView within its buffer"
                    )))
                }
            },
        };
        let name = if uri.is_empty() {
            format!("bufferView {}", img.buffer_view.map_or(0, |v| v.value()))
        } else {
            short_uri(uri)
        };
        let image = decode_image(&bytes, mime, uri, &name, access)
            .map_err(|e| fail(format!("image {i}"), uri, e))?;
        images.push(image);
    }
    Ok(images)
}

/// Where a glTF URI points: bytes it holds (a `data:` URI, with its media
/// type), or a file, checked by the access, with its size.
#[derive(Debug)]
pub(crate) enum Located {
    /// The decoded bytes of a `data:` URI, and its media type if it gives
    /// one.
    Data(Vec<u8>, Option<String>),
    /// A file the access allows, and its size.
    File(PathBuf, u64),
}

/// Resolves the URI `uri` of a glTF file whose folder is `base`: a `data:`
/// URI is decoded (base64, or percent-encoded); a relative path is
/// percent-decoded and joined to `base`; a `file:` URI names a path (an
/// absolute one, usually). Other schemes are refused. A path is then
/// checked by `access` as a file of `kind` (under an allowed folder, a
/// regular file, within the kind's size), but not read. The error says
/// why, naming the file.
pub(crate) fn locate(
    uri: &str,
    base: &Path,
    kind: FileKind,
    access: &FileAccess,
) -> Result<Located, String> {
    if let Some(rest) = uri.strip_prefix("data:") {
        let (header, payload) = rest
            .split_once(',')
            .ok_or("a data: URI needs a `,` before its data")?;
        let mime = header
            .split(';')
            .next()
            .filter(|m| !m.is_empty())
            .map(str::to_string);
        let bytes = if header.ends_with(";base64") {
            base64_decode(payload)?
        } else {
            percent_decode(payload)
        };
        return Ok(Located::Data(bytes, mime));
    }
    let file = if let Some(rest) = uri.strip_prefix("file://").or(uri.strip_prefix("file:")) {
        rest
    } else if uri.contains(':') {
        return Err(
            "unsupported URI scheme: kalos reads relative paths, file: and data: URIs".into(),
        );
    } else {
        uri
    };
    let file = String::from_utf8(percent_decode(file))
        .map_err(|_| "the URI is not UTF-8 once percent-decoded".to_string())?;
    let p = base.join(file);
    let (_, size) = access.check(&p, kind).map_err(|e| e.to_string())?;
    Ok(Located::File(p, size))
}

/// The bytes of buffer view `view` (an image's), `None` when it does not
/// lie within its buffer.
fn view_bytes<'b>(
    doc: &gltf::Document,
    buffers: &'b [gltf::buffer::Data],
    view: usize,
) -> Option<&'b [u8]> {
    let view = doc.views().nth(view)?;
    let data = buffers.get(view.buffer().index())?;
    let end = view.offset().checked_add(view.length())?;
    data.0.get(view.offset()..end)
}

/// Decodes a base colour image (PNG or JPEG, by its media type, its file
/// extension, else its first bytes), after declaring its pixels' memory to
/// `access` from its header (named `name`). `None` when it decodes to a
/// pixel format the loader does not convert (then a warning says so).
fn decode_image(
    bytes: &[u8],
    mime: Option<&str>,
    uri: &str,
    name: &str,
    access: &FileAccess,
) -> Result<Option<gltf::image::Data>, String> {
    use image::{DynamicImage as D, ImageDecoder, ImageFormat};
    let ext = match uri.rsplit_once('.') {
        Some((_, ext)) if !uri.starts_with("data:") => ext.to_ascii_lowercase(),
        _ => String::new(),
    };
    let format = match (mime, ext.as_str()) {
        (Some("image/png"), _) => Some(ImageFormat::Png),
        (Some("image/jpeg"), _) => Some(ImageFormat::Jpeg),
        (None, "png") => Some(ImageFormat::Png),
        (None, "jpg" | "jpeg") => Some(ImageFormat::Jpeg),
        _ => None,
    };
    let format = format
        .or_else(|| {
            image::guess_format(bytes)
                .ok()
                .filter(|f| matches!(f, ImageFormat::Png | ImageFormat::Jpeg))
        })
        .ok_or_else(|| {
            format!(
                "unsupported image encoding{}: glTF images are PNG or JPEG",
                mime.map_or(String::new(), |m| format!(" `{m}`"))
            )
        })?;
    let cannot = |e: image::ImageError| format!("cannot decode the image: {e}");
    let decoder = image::ImageReader::with_format(std::io::Cursor::new(bytes), format)
        .into_decoder()
        .map_err(cannot)?;
    let (w, h) = decoder.dimensions();
    let bpp = decoder.color_type().bytes_per_pixel() as u64;
    drop(decoder);
    // the decoded pixels, and the linear texture made from them
    let texel = bpp + std::mem::size_of::<Rgb>() as u64;
    access
        .reserve(
            format!("glTF image `{name}` ({w}×{h})"),
            (w as u64 * h as u64).saturating_mul(texel),
        )
        .map_err(|e| e.to_string())?;
    let img = image::load_from_memory_with_format(bytes, format).map_err(cannot)?;
    // as the gltf crate's image::Data::new
    let format = match img {
        D::ImageLuma8(_) => gltf::image::Format::R8,
        D::ImageLumaA8(_) => gltf::image::Format::R8G8,
        D::ImageRgb8(_) => gltf::image::Format::R8G8B8,
        D::ImageRgba8(_) => gltf::image::Format::R8G8B8A8,
        D::ImageLuma16(_) => gltf::image::Format::R16,
        D::ImageLumaA16(_) => gltf::image::Format::R16G16,
        D::ImageRgb16(_) => gltf::image::Format::R16G16B16,
        D::ImageRgba16(_) => gltf::image::Format::R16G16B16A16,
        D::ImageRgb32F(_) => gltf::image::Format::R32G32B32FLOAT,
        D::ImageRgba32F(_) => gltf::image::Format::R32G32B32A32FLOAT,
        _ => return Ok(None),
    };
    let (width, height) = (img.width(), img.height());
    Ok(Some(gltf::image::Data {
        pixels: img.into_bytes(),
        format,
        width,
        height,
    }))
}

/// Declares the memory of the meshes the default scene instances: each
/// mesh's triangles and vertices (from its accessors' counts) times the
/// paths to it through the node graph (a DAG: [`check_instancing`] has
/// refused cycles).
fn reserve_meshes(
    doc: &gltf::Document,
    gscene: &gltf::Scene,
    path: &Path,
    access: &FileAccess,
) -> Result<(), SceneError> {
    let instances = node_instances(doc, gscene);
    let mut of_mesh = vec![0u64; doc.meshes().len()];
    for node in doc.nodes() {
        if let Some(m) = node.mesh() {
            of_mesh[m.index()] = of_mesh[m.index()].saturating_add(instances[node.index()]);
        }
    }
    for mesh in doc.meshes() {
        let k = of_mesh[mesh.index()];
        if k == 0 {
            continue;
        }
        let (mut vertices, mut triangles) = (0u64, 0u64);
        for p in mesh
            .primitives()
            .filter(|p| p.mode() == gltf::mesh::Mode::Triangles)
        {
            let n = p.get(&gltf::Semantic::Positions).map_or(0, |a| a.count()) as u64;
            vertices += n;
            triangles += p.indices().map_or(n, |a| a.count() as u64) / 3;
        }
        let item = format!(
            "glTF mesh {} `{}` ({triangles} triangles × {k} instances)",
            mesh.index(),
            mesh.name().unwrap_or("")
        );
        access
            .reserve(
                item,
                super::mesh_memory(vertices, triangles).saturating_mul(k),
            )
            .map_err(|e| SceneError::new(path, 0, e.to_string()))?;
    }
    Ok(())
}

/// How many times the walk of `gscene` reaches each node: the number of
/// paths to it from the scene's roots (saturating). The node graph must
/// be acyclic.
fn node_instances(doc: &gltf::Document, gscene: &gltf::Scene) -> Vec<u64> {
    let nodes: Vec<gltf::Node> = doc.nodes().collect();
    // a post-order of the nodes reachable from the roots: each after its
    // descendants
    let mut seen = vec![false; nodes.len()];
    let mut post = Vec::with_capacity(nodes.len());
    for root in gscene.nodes() {
        let mut stack = vec![(root.index(), false)];
        while let Some((i, done)) = stack.pop() {
            if done {
                post.push(i);
                continue;
            }
            if std::mem::replace(&mut seen[i], true) {
                continue;
            }
            stack.push((i, true));
            stack.extend(
                nodes[i]
                    .children()
                    .map(|c| (c.index(), false))
                    .filter(|&(c, _)| !seen[c]),
            );
        }
    }
    let mut count = vec![0u64; nodes.len()];
    for root in gscene.nodes() {
        count[root.index()] = count[root.index()].saturating_add(1);
    }
    // parents before children
    for &i in post.iter().rev() {
        for c in nodes[i].children() {
            count[c.index()] = count[c.index()].saturating_add(count[i]);
        }
    }
    count
}

/// A URI as errors show it: a long `data:` URI cut short.
fn short_uri(uri: &str) -> String {
    match uri.char_indices().nth(60) {
        Some((at, _)) => format!("{}…", &uri[..at]),
        None => uri.to_string(),
    }
}

/// The 1-based line of `text` (a glTF's JSON) that holds the string `uri`,
/// 0 when it is not found as written (escaped, or a GLB).
fn uri_line(text: &[u8], uri: &str) -> u32 {
    if text.is_empty() || uri.is_empty() || uri.len() > 4096 {
        return 0;
    }
    let quoted = format!("\"{uri}\"");
    text.windows(quoted.len())
        .position(|w| w == quoted.as_bytes())
        .map_or(0, |at| {
            1 + text[..at].iter().filter(|&&b| b == b'\n').count() as u32
        })
}

/// `%XX` escapes decoded (others kept as written).
fn percent_decode(s: &str) -> Vec<u8> {
    let b = s.as_bytes();
    let hex = |c: u8| (c as char).to_digit(16).map(|d| d as u8);
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%' && i + 2 < b.len() {
            if let (Some(h), Some(l)) = (hex(b[i + 1]), hex(b[i + 2])) {
                out.push(h << 4 | l);
                i += 3;
                continue;
            }
        }
        out.push(b[i]);
        i += 1;
    }
    out
}

/// Decodes base64 (the standard or the URL-safe alphabet; padding
/// optional), as `data:` URIs hold it.
fn base64_decode(s: &str) -> Result<Vec<u8>, String> {
    let s = s.trim_end_matches('=');
    if s.len() % 4 == 1 {
        return Err("its base64 data is truncated".into());
    }
    let mut out = Vec::with_capacity(s.len() / 4 * 3 + 2);
    let (mut acc, mut bits) = (0u32, 0u32);
    for (k, c) in s.bytes().enumerate() {
        let v = match c {
            b'A'..=b'Z' => c - b'A',
            b'a'..=b'z' => c - b'a' + 26,
            b'0'..=b'9' => c - b'0' + 52,
            b'+' | b'-' => 62,
            b'/' | b'_' => 63,
            _ => {
                return Err(format!(
                    "character {k} of its base64 data, {:?}, is not a base64 digit",
                    c as char
                ))
            }
        };
        acc = (acc << 6) | v as u32;
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
            acc &= (1 << bits) - 1;
        }
    }
    Ok(out)
}

/// Checks that every mesh primitive's attributes name an accessor that
/// exists, before the `gltf` crate validates the file: its validation of a
/// primitive indexes the accessor list with the POSITION index unchecked
/// (gltf-json 1.4.1), so a bad index panicked instead of erroring.
fn check_attribute_indices(path: &Path, root: &gltf::json::Root) -> Result<(), SceneError> {
    let err = |msg: String| SceneError::new(path, 0, msg);
    let n = root.accessors.len();
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (k, prim) in mesh.primitives.iter().enumerate() {
            let named = prim.attributes.values().chain(prim.indices.as_ref());
            if let Some(bad) = named.map(|i| i.value()).find(|&i| i >= n) {
                return Err(err(format!(
                    "mesh {m} primitive {k} names accessor {bad}, but the file has {n}"
                )));
            }
        }
    }
    Ok(())
}

/// Checks the component types of the accessors kalos reads, which the
/// `gltf` crate's readers assume valid (an index accessor of floats reached
/// an `unreachable!`).
fn check_accessor_types(prim: &gltf::Primitive) -> Result<(), String> {
    use gltf::accessor::{DataType as T, Dimensions as D};
    use gltf::Semantic as S;
    let ok = |a: &gltf::Accessor, types: &[T], dims: D| {
        types.contains(&a.data_type()) && a.dimensions() == dims
    };
    if let Some(a) = prim.indices() {
        if !ok(&a, &[T::U8, T::U16, T::U32], D::Scalar) {
            return Err(format!(
                "the indices must be unsigned integer scalars, found {:?} {:?}",
                a.data_type(),
                a.dimensions()
            ));
        }
    }
    for (semantic, a) in prim.attributes() {
        let good = match semantic {
            S::Positions | S::Normals => ok(&a, &[T::F32], D::Vec3),
            S::TexCoords(_) => ok(&a, &[T::U8, T::U16, T::F32], D::Vec2),
            _ => true,
        };
        if !good {
            return Err(format!(
                "attribute {semantic:?} has the wrong type ({:?} {:?})",
                a.data_type(),
                a.dimensions()
            ));
        }
    }
    Ok(())
}

/// Checks a binary glTF's header and chunk lengths against the file's size
/// before the `gltf` crate sizes a buffer from them (it trusts the header:
/// a claimed 4 GB aborted on the allocation). A file that does not start
/// with the GLB magic is left to the JSON parser.
fn check_glb_lengths(path: &Path, bytes: &[u8]) -> Result<(), SceneError> {
    let err = |msg: String| SceneError::new(path, 0, msg);
    let size = bytes.len() as u64;
    if size < 12 || &bytes[..4] != b"glTF" {
        return Ok(());
    }
    let word = |i: u64| {
        let i = i as usize;
        u32::from_le_bytes([bytes[i], bytes[i + 1], bytes[i + 2], bytes[i + 3]]) as u64
    };
    let claimed = word(8);
    // shorter than the header itself: the gltf crate subtracts 12 from it
    // unchecked (gltf 1.4.1), which debug builds panic on
    if claimed < 12 {
        return Err(err(format!(
            "GLB header claims {claimed} bytes, fewer than the 12 of the header itself: corrupt"
        )));
    }
    if claimed > size {
        return Err(err(format!(
            "GLB header claims {claimed} bytes, but the file has {size}: truncated or corrupt"
        )));
    }
    // Each chunk: length, type, then `length` bytes, all inside the claimed size
    let mut at = 12u64;
    let mut k = 0;
    while at + 8 <= claimed {
        let len = word(at);
        if at + 8 + len > claimed {
            return Err(err(format!(
                "GLB chunk {k} at byte {at} claims {len} bytes, but only {} remain of the {claimed} the header gives",
                claimed - at - 8
            )));
        }
        at += 8 + len;
        k += 1;
    }
    Ok(())
}

/// Refuses a node graph that is not a forest of finite size before any
/// mesh is instanced: a node that is its own ancestor (the walk would never
/// end), or a DAG whose shared nodes multiply into more than
/// [`super::MAX_TRIANGLES`] triangles or [`MAX_NODES`] node instances.
fn check_instancing(
    doc: &gltf::Document,
    gscene: &gltf::Scene,
    path: &Path,
) -> Result<(), SceneError> {
    let err = |msg: String| SceneError::new(path, 0, msg);
    // Triangles of one instance of each mesh, from the accessor counts alone
    let mesh_tris: Vec<u64> = doc
        .meshes()
        .map(|m| {
            m.primitives()
                .filter(|p| p.mode() == gltf::mesh::Mode::Triangles)
                .map(|p| {
                    let n = match p.indices() {
                        Some(a) => a.count(),
                        None => p.get(&gltf::Semantic::Positions).map_or(0, |a| a.count()),
                    };
                    n as u64 / 3
                })
                .sum()
        })
        .collect();

    // Post-order walk with colours: grey nodes are on the current path, so
    // meeting one again is a cycle; black nodes carry their subtree totals
    // (triangles, node instances), summed with saturation
    let nodes: Vec<gltf::Node> = doc.nodes().collect();
    let mut total: Vec<Option<(u64, u64)>> = vec![None; nodes.len()];
    let mut grey = vec![false; nodes.len()];
    for root in gscene.nodes() {
        let mut stack = vec![(root.index(), false)];
        while let Some((i, expanded)) = stack.pop() {
            if expanded {
                let node = &nodes[i];
                let own = node.mesh().map_or(0, |m| mesh_tris[m.index()]);
                let (mut tris, mut count) = (own, 1u64);
                for c in node.children() {
                    let (t, n) = total[c.index()].unwrap_or((0, 0));
                    tris = tris.saturating_add(t);
                    count = count.saturating_add(n);
                }
                total[i] = Some((tris, count));
                grey[i] = false;
                continue;
            }
            if total[i].is_some() {
                continue;
            }
            grey[i] = true;
            stack.push((i, true));
            for c in nodes[i].children() {
                let j = c.index();
                if grey[j] {
                    let what = if j == i {
                        format!("glTF node {j} is its own child")
                    } else {
                        format!("glTF node {j} is its own ancestor (through node {i})")
                    };
                    return Err(err(format!(
                        "{what}: the node graph must be a tree (or a DAG), not a cycle"
                    )));
                }
                if total[j].is_none() {
                    stack.push((j, false));
                }
            }
        }
    }
    let (tris, count) = gscene
        .nodes()
        .filter_map(|n| total[n.index()])
        .fold((0u64, 0u64), |(t, c), (a, b)| {
            (t.saturating_add(a), c.saturating_add(b))
        });
    if tris > super::MAX_TRIANGLES {
        return Err(err(format!(
            "glTF scene instances {tris} triangles (shared nodes multiply their meshes); \
             kalos loads at most {}",
            super::MAX_TRIANGLES
        )));
    }
    if count > MAX_NODES {
        return Err(err(format!(
            "glTF scene instances {count} nodes (shared nodes multiply); kalos walks at most {MAX_NODES}"
        )));
    }
    Ok(())
}

fn name_of(m: &gltf::Material) -> String {
    m.name().unwrap_or("(unnamed)").to_string()
}

/// A decoded glTF image as linear RGB: 8- and 16-bit data are sRGB-encoded
/// (base colour textures are, by the specification), float data linear.
fn to_tex_image(d: &gltf::image::Data) -> Option<TexImage> {
    use gltf::image::Format as F;
    let (channels, bytes, float) = match d.format {
        F::R8 => (1, 1, false),
        F::R8G8 => (2, 1, false),
        F::R8G8B8 => (3, 1, false),
        F::R8G8B8A8 => (4, 1, false),
        F::R16 => (1, 2, false),
        F::R16G16 => (2, 2, false),
        F::R16G16B16 => (3, 2, false),
        F::R16G16B16A16 => (4, 2, false),
        F::R32G32B32FLOAT => (3, 4, true),
        F::R32G32B32A32FLOAT => (4, 4, true),
    };
    let px = channels * bytes;
    let count = (d.width as usize).checked_mul(d.height as usize)?;
    if d.pixels.len() < count.checked_mul(px)? || count == 0 {
        return None;
    }
    let read = |b: &[u8]| -> f32 {
        match (bytes, float) {
            (1, _) => b[0] as f32 / 255.0,
            (2, _) => u16::from_le_bytes([b[0], b[1]]) as f32 / 65535.0,
            _ => f32::from_le_bytes([b[0], b[1], b[2], b[3]]),
        }
    };
    let decode = |c: f32| {
        if float {
            c
        } else if c <= 0.04045 {
            c / 12.92
        } else {
            ((c + 0.055) / 1.055).powf(2.4)
        }
    };
    let data = d.pixels[..count * px]
        .chunks_exact(px)
        .map(|p| {
            let ch = |i: usize| decode(read(&p[i * bytes..(i + 1) * bytes]));
            match channels {
                1 => Rgb::splat(ch(0)),
                2 => Rgb::new(ch(0), ch(1), 0.0),
                _ => Rgb::new(ch(0), ch(1), ch(2)),
            }
        })
        .collect();
    Some(TexImage::new(d.width, d.height, data))
}

#[cfg(test)]
mod uri_tests {
    use super::*;

    #[test]
    fn base64_decodes_with_and_without_padding_and_refuses_other_characters() {
        assert_eq!(base64_decode("aGVsbG8=").unwrap(), b"hello");
        assert_eq!(base64_decode("aGVsbG8").unwrap(), b"hello");
        assert_eq!(base64_decode("aGVsbG8h").unwrap(), b"hello!");
        assert_eq!(base64_decode("").unwrap(), b"");
        assert_eq!(base64_decode("_-8=").unwrap(), [0xff, 0xef]);
        assert!(base64_decode("aGV*")
            .unwrap_err()
            .contains("not a base64 digit"));
        assert!(base64_decode("aGVsb").unwrap_err().contains("truncated"));
    }

    #[test]
    fn percent_escapes_are_decoded_and_others_kept() {
        assert_eq!(percent_decode("my%20tex%2Epng"), b"my tex.png");
        assert_eq!(percent_decode("100%"), b"100%");
        assert_eq!(percent_decode("a%zzb%4"), b"a%zzb%4");
    }

    #[test]
    fn the_line_of_a_uri_is_found_in_the_json() {
        let text = b"{\n\"buffers\":[\n{\"uri\":\"a.bin\"}]}";
        assert_eq!(uri_line(text, "a.bin"), 3);
        assert_eq!(uri_line(text, "b.bin"), 0);
        assert_eq!(uri_line(b"", "a.bin"), 0);
    }

    #[test]
    fn data_uris_are_decoded_and_other_schemes_refused() {
        let a = FileAccess::nothing();
        let base = Path::new(".");
        match locate("data:text/plain;base64,aGk=", base, FileKind::Mesh, &a) {
            Ok(Located::Data(d, mime)) => {
                assert_eq!(d, b"hi");
                assert_eq!(mime.as_deref(), Some("text/plain"));
            }
            r => panic!("{r:?}"),
        }
        match locate("data:,a%20b", base, FileKind::Mesh, &a) {
            Ok(Located::Data(d, None)) => assert_eq!(d, b"a b"),
            r => panic!("{r:?}"),
        }
        let e = locate("https://example.com/a.bin", base, FileKind::Mesh, &a).unwrap_err();
        assert!(e.contains("unsupported URI scheme"), "{e}");
        // a path is checked by the access, which here allows nothing
        let e = locate("Cargo.toml", base, FileKind::Mesh, &a).unwrap_err();
        assert!(e.contains("--allow-read"), "{e}");
    }
}

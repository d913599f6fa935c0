//! Wavefront OBJ meshes (through `tobj`), and a standalone `.obj` file as a
//! whole scene.
//!
//! As a scene, each OBJ object becomes a shape with a material from the MTL
//! file: `Kd` → `diffuse`; `Ks` (non-zero) with `Ns` → `phong` (scaled down
//! so that kd + ks ≤ 1); `Ke` (non-zero) → an area emitter of that radiance.
//! OBJ files have no camera: one is synthesised looking at the bounding box
//! along −z (the usual "front" of y-up OBJ files), and a warning says so.
//!
//! The file and its `mtllib`s are read through the scene's [`FileAccess`]:
//! a material library outside the allowed folders, or one that is not a
//! regular file, is an error naming the `mtllib` line, before the OBJ is
//! parsed (a missing one is a warning, as in other renderers). The mesh's
//! memory is declared from a count of its `v` and `f` lines before tobj
//! builds it. MTL texture maps are not read.

use crate::scene::access::{AccessError, FileAccess, FileKind};
use std::cell::RefCell;
use std::path::Path;

use glam::{Vec2, Vec3};

use super::shapes::{look_at, MeshData};
use super::{CameraDesc, Material, Rgb, Scene, SceneError, Texture};

fn options() -> tobj::LoadOptions {
    tobj::LoadOptions {
        triangulate: true,
        single_index: true,
        ..Default::default()
    }
}

/// The objects, the MTL materials, and a warning when the MTL did not load.
type ObjModels = (Vec<tobj::Model>, Vec<tobj::Material>, Option<String>);

/// What a first pass over an OBJ file's lines finds: how large its mesh is
/// at least, and its material libraries.
#[derive(Debug, Default, PartialEq)]
struct Scan {
    /// `v` lines.
    vertices: u64,
    /// The triangles of the `f` lines, fan-triangulated.
    triangles: u64,
    /// Each `mtllib` line's number and file name, as tobj reads it.
    mtllibs: Vec<(u32, String)>,
}

/// Counts the vertices and triangles of `bytes` (an OBJ file) and lists its
/// `mtllib`s, without parsing numbers.
fn scan(bytes: &[u8]) -> Scan {
    let mut scan = Scan::default();
    for (i, line) in bytes.split(|&b| b == b'\n').enumerate() {
        let line = line.strip_suffix(b"\r").unwrap_or(line);
        let mut words = line
            .split(|b| b.is_ascii_whitespace())
            .filter(|w| !w.is_empty());
        match words.next() {
            Some(b"v") => scan.vertices += 1,
            Some(b"f") => scan.triangles += (words.count() as u64).saturating_sub(2),
            Some(b"mtllib") => {
                // tobj's reading: all after the first space, trimmed (a
                // file name may hold spaces)
                let line = String::from_utf8_lossy(line);
                let name = line.split_once(' ').unwrap_or_default().1.trim();
                scan.mtllibs.push((i as u32 + 1, name.to_string()));
            }
            _ => {}
        }
    }
    scan
}

/// Reads the OBJ file `path` (a file of `kind`) and its material libraries
/// through `access`: see the module documentation.
fn load_models(path: &Path, kind: FileKind, access: &FileAccess) -> Result<ObjModels, SceneError> {
    let bytes = access
        .read(path, kind)
        .map_err(|e| SceneError::new(path, 0, e.to_string()))?;
    let base = path.parent().unwrap_or(Path::new(""));
    let found = scan(&bytes);
    let line_of = |mtl: &Path| {
        found
            .mtllibs
            .iter()
            .find(|(_, name)| Path::new(name) == mtl)
            .map_or(0, |(line, _)| *line)
    };
    let refusal = |mtl: &Path, e: AccessError| {
        SceneError::new(
            path,
            line_of(mtl),
            format!("mtllib `{}`: {e}", mtl.display()),
        )
    };
    // every library the file names, checked before anything is parsed; a
    // missing or unreadable one only loses the materials (a warning), as
    // does an `mtllib` without a name
    for (_, name) in found.mtllibs.iter().filter(|(_, n)| !n.is_empty()) {
        match access.check(&base.join(name), FileKind::Material) {
            Ok(_) | Err(AccessError::Io { .. }) => {}
            Err(e) => return Err(refusal(Path::new(name), e)),
        }
    }
    access
        .reserve(
            format!(
                "mesh `{}` ({} vertices, {} triangles)",
                path.display(),
                found.vertices,
                found.triangles
            ),
            super::mesh_memory(found.vertices, found.triangles),
        )
        .map_err(|e| SceneError::new(path, 0, e.to_string()))?;
    // what made an MTL file unreadable, in our words (tobj's error has no
    // line), and a refusal of the access, which is an error
    let mtl_problem: RefCell<Option<SceneError>> = Default::default();
    let refused: RefCell<Option<SceneError>> = Default::default();
    let parsed = tobj::load_obj_buf(&mut &bytes[..], &options(), |mtl| {
        if mtl.as_os_str().is_empty() {
            return Err(tobj::LoadError::OpenFileFailed);
        }
        // read once: checked, then parsed from the same bytes
        let bytes = match access.read(&base.join(mtl), FileKind::Material) {
            Ok(bytes) => bytes,
            Err(e @ AccessError::Io { .. }) => {
                *mtl_problem.borrow_mut() = Some(refusal(mtl, e));
                return Err(tobj::LoadError::OpenFileFailed);
            }
            Err(e) => {
                *refused.borrow_mut() = Some(refusal(mtl, e));
                return Err(tobj::LoadError::OpenFileFailed);
            }
        };
        if let Err(e) = check_mtl(&base.join(mtl), &bytes) {
            *mtl_problem.borrow_mut() = Some(e);
            return Err(tobj::LoadError::MaterialParseError);
        }
        tobj::load_mtl_buf(&mut &bytes[..])
    });
    if let Some(e) = refused.into_inner() {
        return Err(e);
    }
    let (models, materials) =
        parsed.map_err(|e| SceneError::new(path, 0, format!("cannot read OBJ file: {e}")))?;
    for m in &models {
        if let Some(i) = m.mesh.positions.iter().position(|v| !v.is_finite()) {
            return Err(SceneError::new(
                path,
                0,
                format!(
                    "object `{}`: vertex {} is not finite ({:?})",
                    m.name,
                    i / 3,
                    &m.mesh.positions[i - i % 3..(i - i % 3 + 3).min(m.mesh.positions.len())]
                ),
            ));
        }
    }
    match materials {
        Ok(m) => Ok((models, m, None)),
        Err(e) => Ok((
            models,
            Vec::new(),
            Some(match mtl_problem.into_inner() {
                Some(p) => format!("MTL not loaded: {p}"),
                None => format!("{}: MTL not loaded: {e}", path.display()),
            }),
        )),
    }
}

/// Refuses the MTL lines on which tobj 4 panics instead of returning an
/// error: a colour (`Ka`, `Kd`, `Ks`, `Ke`) with fewer than three numbers.
/// `bytes` are the contents of the MTL file `path`.
fn check_mtl(path: &Path, bytes: &[u8]) -> Result<(), SceneError> {
    for (i, line) in String::from_utf8_lossy(bytes).lines().enumerate() {
        let mut words = line.split_whitespace();
        if let Some(key @ ("Ka" | "Kd" | "Ks" | "Ke")) = words.next() {
            if words.count() < 3 {
                let msg = format!("{key} expects three numbers (r g b)");
                return Err(SceneError::new(path, i as u32 + 1, msg));
            }
        }
    }
    Ok(())
}

/// One tobj mesh as [`MeshData`]. With `flip_tex_coords` (Mitsuba's default
/// for OBJ), v becomes 1 − v: OBJ puts v = 0 at the bottom of the image,
/// Mitsuba's uv space at the top.
fn to_mesh(m: &tobj::Mesh, flip_tex_coords: bool) -> MeshData {
    let positions: Vec<Vec3> = m
        .positions
        .chunks_exact(3)
        .map(|p| Vec3::new(p[0], p[1], p[2]))
        .collect();
    let n = positions.len();
    let normals = (m.normals.len() == 3 * n && n > 0).then(|| {
        m.normals
            .chunks_exact(3)
            .map(|p| Vec3::new(p[0], p[1], p[2]))
            .collect()
    });
    let uvs = (m.texcoords.len() == 2 * n && n > 0).then(|| {
        m.texcoords
            .chunks_exact(2)
            .map(|t| Vec2::new(t[0], if flip_tex_coords { 1.0 - t[1] } else { t[1] }))
            .collect()
    });
    let indices = m
        .indices
        .chunks_exact(3)
        .map(|t| [t[0], t[1], t[2]])
        .collect();
    MeshData {
        positions,
        normals,
        uvs,
        indices,
    }
}

/// Appends `b` to `a`; normals and uvs survive only when both have them.
fn append(a: &mut MeshData, b: MeshData) {
    let base = a.positions.len() as u32;
    let first = a.positions.is_empty();
    a.normals = match (a.normals.take(), b.normals) {
        (Some(mut x), Some(y)) => {
            x.extend(y);
            Some(x)
        }
        (None, Some(y)) if first => Some(y),
        _ => None,
    };
    a.uvs = match (a.uvs.take(), b.uvs) {
        (Some(mut x), Some(y)) => {
            x.extend(y);
            Some(x)
        }
        (None, Some(y)) if first => Some(y),
        _ => None,
    };
    a.positions.extend(b.positions);
    a.indices
        .extend(b.indices.iter().map(|t| t.map(|i| i + base)));
}

/// Loads every object of an OBJ file as one mesh (triangulated, one index
/// per vertex). Normals and uvs are kept only when every object has them.
/// The file is read through `access`, as a mesh file.
pub fn load_obj(
    path: &Path,
    flip_tex_coords: bool,
    access: &FileAccess,
) -> Result<MeshData, SceneError> {
    let (models, _, _) = load_models(path, FileKind::Mesh, access)?;
    let mut mesh = MeshData::default();
    for m in &models {
        append(&mut mesh, to_mesh(&m.mesh, flip_tex_coords));
    }
    Ok(mesh)
}

/// A standalone OBJ file (with its MTL) as a scene, with a synthesised camera.
/// The file and its MTLs are read through `access`.
pub fn load_obj_scene(path: &Path, access: &FileAccess) -> Result<Scene, SceneError> {
    let (models, mtls, mtl_warning) = load_models(path, FileKind::Scene, access)?;
    let mut scene = Scene::empty(path.display().to_string());
    scene.warnings.extend(mtl_warning);

    // Materials from the MTL file, and one default (Mitsuba's diffuse 0.5)
    let mut mat_index = Vec::with_capacity(mtls.len());
    let mut emission = Vec::with_capacity(mtls.len());
    for m in &mtls {
        let kd = m.diffuse.map_or(Rgb::splat(0.5), Rgb::from);
        let ks = m.specular.map_or(Rgb::ZERO, Rgb::from);
        let material = if ks.max_element() > 0.0 {
            // keep the energy-conserving Phong within kd + ks ≤ 1
            let s = (kd + ks).max_element().max(1.0);
            Material::Phong {
                diffuse_reflectance: Texture::Constant(kd / s),
                specular_reflectance: Texture::Constant(ks / s),
                exponent: m.shininess.unwrap_or(30.0).max(0.0),
            }
        } else {
            Material::Diffuse {
                reflectance: Texture::Constant(kd),
            }
        };
        mat_index.push(scene.add_material(material));
        for (key, c) in [("Kd", m.diffuse), ("Ks", m.specular), ("Ke", m.emissive)] {
            let Some(c) = c.map(Rgb::from) else { continue };
            if !(c.is_finite() && c.min_element() >= 0.0) {
                let what = if key == "Ke" { "emission Ke" } else { key };
                return Err(SceneError::new(
                    path,
                    0,
                    format!(
                        "material `{}` (MTL): {what} must be finite and non-negative, found ({}, {}, {})",
                        m.name, c.x, c.y, c.z
                    ),
                ));
            }
        }
        emission.push(m.emissive.map(Rgb::from).filter(|e| e.max_element() > 0.0));
    }
    let mut default_mat = None;
    for (k, model) in models.iter().enumerate() {
        let mut mesh = to_mesh(&model.mesh, true);
        if mesh.normals.is_none() {
            mesh.compute_vertex_normals();
        }
        let (material, radiance) = match model.mesh.material_id {
            Some(id) if id < mat_index.len() => (mat_index[id], emission[id]),
            _ => {
                let d = *default_mat.get_or_insert_with(|| {
                    scene.add_material(Material::Diffuse {
                        reflectance: Texture::Constant(Rgb::splat(0.5)),
                    })
                });
                (d, None)
            }
        };
        let name = if model.name.is_empty() {
            format!("obj{k}")
        } else {
            model.name.clone()
        };
        scene.add_mesh(
            name,
            &mesh.positions,
            mesh.normals.as_deref(),
            mesh.uvs.as_deref(),
            &mesh.indices,
            material,
            radiance,
        );
    }
    if scene.triangles.is_empty() {
        return Err(SceneError::new(path, 0, "OBJ file has no triangles"));
    }
    scene.light_if_dark(path);

    synthesise_camera(&mut scene, path);
    Ok(scene)
}

/// Puts a camera on +z looking at the centre of the scene's bounding box,
/// far enough to see all of it, and warns that it did.
pub(crate) fn synthesise_camera(scene: &mut Scene, path: &Path) {
    let (lo, hi) = scene.bounds();
    let center = 0.5 * (lo + hi);
    let radius = (0.5 * (hi - lo).length()).max(1e-3);
    let fov = 45.0f32;
    let dist = 1.1 * radius / (0.5 * fov.to_radians()).sin();
    let origin = center + Vec3::Z * dist;
    let to_world = look_at(origin, center, Vec3::Y).unwrap_or_default();
    if let Some(mut cam) = CameraDesc::from_fov(to_world, fov, "smaller", 512, 512) {
        cam.near_clip = 1e-3 * dist;
        scene.camera = cam;
    }
    scene.warnings.push(format!(
        "{}: the file has no camera; synthesised one at {origin:?} looking at {center:?}",
        path.display()
    ));
}

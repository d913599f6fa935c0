//! Wavefront OBJ meshes (through `tobj`), and a standalone `.obj` file as a
//! whole scene.
//!
//! As a scene, each OBJ object becomes a shape with a material from the MTL
//! file: `Kd` → `diffuse`; `Ks` (non-zero) with `Ns` → `phong` (scaled down
//! so that kd + ks ≤ 1); `Ke` (non-zero) → an area emitter of that radiance.
//! OBJ files have no camera: one is synthesised looking at the bounding box
//! along −z (the usual "front" of y-up OBJ files), and a warning says so.

use crate::scene::access::FileAccess;
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

fn load_models(path: &Path) -> Result<ObjModels, SceneError> {
    if !path.is_file() {
        return Err(SceneError::new(path, 0, "OBJ file not found"));
    }
    let file = std::fs::File::open(path)
        .map_err(|e| SceneError::new(path, 0, format!("cannot read OBJ file: {e}")))?;
    let mut reader = std::io::BufReader::new(file);
    let base = path.parent().unwrap_or(Path::new(""));
    // what made an MTL file unreadable, in our words (tobj's error has no
    // line)
    let mtl_problem: std::cell::RefCell<Option<SceneError>> = Default::default();
    let (models, materials) = tobj::load_obj_buf(&mut reader, &options(), |mtl| {
        let mtl = base.join(mtl);
        // read once: checked, then parsed from the same bytes
        let bytes = std::fs::read(&mtl).map_err(|_| tobj::LoadError::OpenFileFailed)?;
        if let Err(e) = check_mtl(&mtl, &bytes) {
            *mtl_problem.borrow_mut() = Some(e);
            return Err(tobj::LoadError::MaterialParseError);
        }
        tobj::load_mtl_buf(&mut &bytes[..])
    })
    .map_err(|e| SceneError::new(path, 0, format!("cannot read OBJ file: {e}")))?;
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
pub fn load_obj(
    path: &Path,
    flip_tex_coords: bool,
    access: &FileAccess,
) -> Result<MeshData, SceneError> {
    let _ = access;
    let (models, _, _) = load_models(path)?;
    let mut mesh = MeshData::default();
    for m in &models {
        append(&mut mesh, to_mesh(&m.mesh, flip_tex_coords));
    }
    Ok(mesh)
}

/// A standalone OBJ file (with its MTL) as a scene, with a synthesised camera.
pub fn load_obj_scene(path: &Path, access: &FileAccess) -> Result<Scene, SceneError> {
    let _ = access;
    let (models, mtls, mtl_warning) = load_models(path)?;
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

//! glTF 2.0 binary writer for the baked display mesh, by hand (JSON chunk and
//! one binary chunk).
//!
//! Primitive 0 (the lit surfaces) carries POSITION, NORMAL, COLOR_0 (linear
//! radiance divided by the white point and clamped to [0, 1]: display-ready)
//! and `_RADIANCE` (linear W/(m²·sr), unclamped), with an unlit material
//! (KHR_materials_unlit) so that viewers show the baked colours as they are.
//! Primitive 1 holds the non-diffuse surfaces with a plain PBR material.
//!
//! When the scene has a camera, a second node carries it as a glTF
//! perspective camera, so that a viewer (`kalos view`, Blender) can open
//! the bake from the view the scene was set up for.

use std::io::Write;
use std::path::Path;

use glam::{Mat4, Vec3, Vec4};

use super::BakedMesh;
use crate::image_io::{write_atomic, ImageIoError};
use crate::scene::CameraDesc;

/// The node holding the display mesh.
const MESH_NODE: &str = "{\"mesh\":0,\"name\":\"baked\"}";

struct Builder {
    bin: Vec<u8>,
    views: Vec<String>,
    accessors: Vec<String>,
}

impl Builder {
    fn vec3(&mut self, data: &[Vec3], minmax: bool) -> usize {
        let off = self.bin.len();
        for v in data {
            for c in v.to_array() {
                self.bin.extend_from_slice(&c.to_le_bytes());
            }
        }
        self.views.push(format!(
            "{{\"buffer\":0,\"byteOffset\":{off},\"byteLength\":{},\"target\":34962}}",
            data.len() * 12
        ));
        let mut extra = String::new();
        if minmax {
            let lo = data
                .iter()
                .fold(Vec3::splat(f32::INFINITY), |a, b| a.min(*b));
            let hi = data
                .iter()
                .fold(Vec3::splat(f32::NEG_INFINITY), |a, b| a.max(*b));
            extra = format!(
                ",\"min\":[{},{},{}],\"max\":[{},{},{}]",
                lo.x, lo.y, lo.z, hi.x, hi.y, hi.z
            );
        }
        self.accessors.push(format!(
            "{{\"bufferView\":{},\"componentType\":5126,\"count\":{},\"type\":\"VEC3\"{extra}}}",
            self.views.len() - 1,
            data.len()
        ));
        self.accessors.len() - 1
    }

    fn indices(&mut self, data: &[[u32; 3]]) -> usize {
        let off = self.bin.len();
        for t in data {
            for i in t {
                self.bin.extend_from_slice(&i.to_le_bytes());
            }
        }
        self.views.push(format!(
            "{{\"buffer\":0,\"byteOffset\":{off},\"byteLength\":{},\"target\":34963}}",
            data.len() * 12
        ));
        self.accessors.push(format!(
            "{{\"bufferView\":{},\"componentType\":5125,\"count\":{},\"type\":\"SCALAR\"}}",
            self.views.len() - 1,
            data.len() * 3
        ));
        self.accessors.len() - 1
    }
}

/// The display colour of each vertex of `lit`, as `COLOR_0` holds it: the
/// radiance over the white point `w0` (1 when `w0` is not a positive
/// number), clamped to [0, 1].
pub fn display_colors(lit: &BakedMesh, w0: f32) -> Vec<Vec3> {
    let w0 = if w0 > 0.0 && w0.is_finite() { w0 } else { 1.0 };
    lit.radiance
        .iter()
        .map(|l| (*l / w0).clamp(Vec3::ZERO, Vec3::ONE))
        .collect()
}

/// The glTF node and camera objects (JSON) for the scene's camera.
///
/// glTF cameras look along their −z with +y up and x to the right; a
/// Mitsuba camera looks along +z with film x along its −x. The node's
/// matrix is the camera's orthonormalised frame (glTF forbids shear, and a
/// scene's `to_world` may scale), so the view is the same whatever scale
/// the scene put in it.
fn camera_json(c: &CameraDesc) -> Option<(String, String)> {
    let origin = c.to_world.transform_point3(Vec3::ZERO);
    let forward = c.to_world.transform_vector3(Vec3::Z).try_normalize()?;
    let up = c.to_world.transform_vector3(Vec3::Y);
    let z = -forward;
    let y = (up - z * up.dot(z)).try_normalize()?;
    let x = y.cross(z);
    let m = Mat4::from_cols(
        x.extend(0.0),
        y.extend(0.0),
        z.extend(0.0),
        Vec4::from((origin, 1.0)),
    );
    let (w, h) = (c.width.max(1) as f32, c.height.max(1) as f32);
    let tan_x = (c.fov_x_deg.to_radians() * 0.5).tan();
    let yfov = 2.0 * (tan_x * h / w).atan();
    if !(yfov.is_finite() && yfov > 0.0 && m.is_finite()) {
        return None;
    }
    let matrix: Vec<String> = m.to_cols_array().iter().map(|v| v.to_string()).collect();
    // glTF needs znear > 0; Mitsuba allows 0
    let znear = c.near_clip.max(1e-4);
    Some((
        format!(
            "{{\"camera\":0,\"name\":\"scene camera\",\"matrix\":[{}]}}",
            matrix.join(",")
        ),
        format!(
            "{{\"name\":\"scene camera\",\"type\":\"perspective\",\"perspective\":{{\"yfov\":{yfov},\"aspectRatio\":{},\"znear\":{znear}}},\"extras\":{{\"width\":{},\"height\":{}}}}}",
            w / h,
            c.width,
            c.height
        ),
    ))
}

/// The bytes of a .glb holding `lit` (white point `w0` for COLOR_0) and
/// `other`, with `camera` as a camera node when given.
pub fn encode_glb(
    lit: &BakedMesh,
    other: &BakedMesh,
    w0: f32,
    camera: Option<&CameraDesc>,
) -> Vec<u8> {
    let mut b = Builder {
        bin: Vec::new(),
        views: Vec::new(),
        accessors: Vec::new(),
    };
    let mut prims = Vec::new();
    if !lit.indices.is_empty() {
        let colors = display_colors(lit, w0);
        let p = b.vec3(&lit.positions, true);
        let n = b.vec3(&lit.normals, false);
        let c = b.vec3(&colors, false);
        let r = b.vec3(&lit.radiance, false);
        let i = b.indices(&lit.indices);
        prims.push(format!(
            "{{\"attributes\":{{\"POSITION\":{p},\"NORMAL\":{n},\"COLOR_0\":{c},\"_RADIANCE\":{r}}},\"indices\":{i},\"material\":0}}"
        ));
    }
    if !other.indices.is_empty() {
        let p = b.vec3(&other.positions, true);
        let n = b.vec3(&other.normals, false);
        let i = b.indices(&other.indices);
        prims.push(format!(
            "{{\"attributes\":{{\"POSITION\":{p},\"NORMAL\":{n}}},\"indices\":{i},\"material\":1}}"
        ));
    }
    let (nodes, cameras) = match camera.and_then(camera_json) {
        Some((node, cam)) => (
            format!("[0,1]}}],\"nodes\":[{MESH_NODE},{node}]"),
            format!(",\"cameras\":[{cam}]"),
        ),
        None => (format!("[0]}}],\"nodes\":[{MESH_NODE}]"), String::new()),
    };
    let json = format!(
        concat!(
            "{{\"asset\":{{\"version\":\"2.0\",\"generator\":\"kalos bake (density estimation)\"}},",
            "\"extensionsUsed\":[\"KHR_materials_unlit\"],",
            "\"scene\":0,\"scenes\":[{{\"nodes\":{}{},",
            "\"meshes\":[{{\"name\":\"display mesh\",\"primitives\":[{}]}}],",
            "\"materials\":[",
            "{{\"name\":\"baked lighting\",\"pbrMetallicRoughness\":{{\"baseColorFactor\":[1,1,1,1],\"metallicFactor\":0,\"roughnessFactor\":1}},\"extensions\":{{\"KHR_materials_unlit\":{{}}}}}},",
            "{{\"name\":\"not baked (specular)\",\"pbrMetallicRoughness\":{{\"baseColorFactor\":[0.8,0.8,0.8,1],\"metallicFactor\":1,\"roughnessFactor\":0.1}}}}],",
            "\"accessors\":[{}],\"bufferViews\":[{}],\"buffers\":[{{\"byteLength\":{}}}]}}"
        ),
        nodes,
        cameras,
        prims.join(","),
        b.accessors.join(","),
        b.views.join(","),
        b.bin.len()
    );
    let mut jb = json.into_bytes();
    while !jb.len().is_multiple_of(4) {
        jb.push(b' ');
    }
    let mut bin = b.bin;
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let total = 12 + 8 + jb.len() + 8 + bin.len();
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(jb.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&jb);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&bin);
    out
}

/// Writes the .glb atomically ([`encode_glb`]).
pub fn write_glb(
    path: &Path,
    lit: &BakedMesh,
    other: &BakedMesh,
    w0: f32,
    camera: Option<&CameraDesc>,
) -> Result<(), ImageIoError> {
    let bytes = encode_glb(lit, other, w0, camera);
    write_atomic(path, |w| {
        w.write_all(&bytes).map_err(|e| ImageIoError::Io {
            path: path.to_path_buf(),
            source: e,
        })
    })
}

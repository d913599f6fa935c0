//! glTF 2.0 binary writer for the baked display mesh, by hand (JSON chunk and
//! one binary chunk).
//!
//! Primitive 0 (the lit surfaces) carries POSITION, NORMAL, COLOR_0 (linear
//! radiance divided by the white point and clamped to [0, 1]: display-ready)
//! and `_RADIANCE` (linear W/(m²·sr), unclamped), with an unlit material
//! (KHR_materials_unlit) so that viewers show the baked colours as they are.
//! Primitive 1 holds the non-diffuse surfaces with a plain PBR material.

use std::io::Write;
use std::path::Path;

use glam::Vec3;

use super::BakedMesh;
use crate::image_io::{write_atomic, ImageIoError};

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

/// The bytes of a .glb holding `lit` (white point `w0` for COLOR_0) and
/// `other`.
pub fn encode_glb(lit: &BakedMesh, other: &BakedMesh, w0: f32) -> Vec<u8> {
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
    let json = format!(
        concat!(
            "{{\"asset\":{{\"version\":\"2.0\",\"generator\":\"kalos bake (density estimation)\"}},",
            "\"extensionsUsed\":[\"KHR_materials_unlit\"],",
            "\"scene\":0,\"scenes\":[{{\"nodes\":[0]}}],\"nodes\":[{{\"mesh\":0,\"name\":\"baked\"}}],",
            "\"meshes\":[{{\"name\":\"display mesh\",\"primitives\":[{}]}}],",
            "\"materials\":[",
            "{{\"name\":\"baked lighting\",\"pbrMetallicRoughness\":{{\"baseColorFactor\":[1,1,1,1],\"metallicFactor\":0,\"roughnessFactor\":1}},\"extensions\":{{\"KHR_materials_unlit\":{{}}}}}},",
            "{{\"name\":\"not baked (specular)\",\"pbrMetallicRoughness\":{{\"baseColorFactor\":[0.8,0.8,0.8,1],\"metallicFactor\":1,\"roughnessFactor\":0.1}}}}],",
            "\"accessors\":[{}],\"bufferViews\":[{}],\"buffers\":[{{\"byteLength\":{}}}]}}"
        ),
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

/// Writes the .glb atomically.
pub fn write_glb(
    path: &Path,
    lit: &BakedMesh,
    other: &BakedMesh,
    w0: f32,
) -> Result<(), ImageIoError> {
    let bytes = encode_glb(lit, other, w0);
    write_atomic(path, |w| {
        w.write_all(&bytes).map_err(|e| ImageIoError::Io {
            path: path.to_path_buf(),
            source: e,
        })
    })
}

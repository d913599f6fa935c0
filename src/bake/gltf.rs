//! glTF 2.0 binary writer for the baked display mesh: the JSON document is
//! built as a [`gltf_json::Root`] and serialised by its serde derive, then
//! packed with one binary chunk into the GLB container (glTF 2.0
//! specification, "GLB File Format Specification").
//!
//! Primitive 0 (the lit surfaces) carries POSITION, NORMAL, COLOR_0 (linear
//! radiance divided by the white point and clamped to [0, 1]: display-ready)
//! and `_RADIANCE` (linear W/(m²·sr), unclamped), with an unlit material
//! (KHR_materials_unlit) so that viewers show the baked colours as they are.
//! The non-diffuse surfaces come next, as a primitive with a plain PBR
//! material. A primitive (and its material) is written only when it has
//! triangles, so that the file holds no unused object.
//!
//! When the scene has a camera, a second node carries it as a glTF
//! perspective camera, so that a viewer (`kalos view`, Blender) can open
//! the bake from the view the scene was set up for.

use std::collections::BTreeMap;
use std::io::Write;
use std::path::Path;

use glam::{Mat4, Vec3, Vec4};
use gltf_json as json;
use json::validation::{Checked::Valid, USize64};

use super::BakedMesh;
use crate::image_io::{write_atomic, ImageIoError};
use crate::scene::CameraDesc;

/// `asset.generator` of every bake.
const GENERATOR: &str = "kalos bake (density estimation)";

/// The extension of the lit surfaces' material.
const UNLIT: &str = "KHR_materials_unlit";

/// `x` as a JSON number with the fewest digits that read back as the same
/// f32, as serde writes an f32 field. (A [`json::Value`] holds an f64, and
/// 0.1f32 widened to f64 would print as 0.10000000149011612.) Null when `x`
/// is not finite, as serde_json writes non-finite floats.
fn number(x: f32) -> json::Value {
    x.to_string()
        .parse::<f64>()
        .map_or(json::Value::Null, json::Value::from)
}

/// The JSON document and the binary buffer (buffer 0) as they are filled.
struct Builder {
    root: json::Root,
    bin: Vec<u8>,
}

impl Builder {
    /// A buffer view over the bytes of buffer 0 from `start` to its end.
    fn view(
        &mut self,
        start: usize,
        target: json::buffer::Target,
    ) -> json::Index<json::buffer::View> {
        self.root.push(json::buffer::View {
            buffer: json::Index::new(0),
            byte_length: USize64::from(self.bin.len() - start),
            byte_offset: Some(USize64::from(start)),
            byte_stride: None,
            name: None,
            target: Some(Valid(target)),
            extensions: None,
            extras: None,
        })
    }

    /// An accessor of `count` elements of `type_` over the whole of `view`.
    fn accessor(
        &mut self,
        view: json::Index<json::buffer::View>,
        component: json::accessor::ComponentType,
        type_: json::accessor::Type,
        count: usize,
        min_max: Option<(json::Value, json::Value)>,
    ) -> json::Index<json::Accessor> {
        let (min, max) = min_max.unzip();
        self.root.push(json::Accessor {
            buffer_view: Some(view),
            byte_offset: None,
            count: USize64::from(count),
            component_type: Valid(json::accessor::GenericComponentType(component)),
            extensions: None,
            extras: None,
            type_: Valid(type_),
            min,
            max,
            name: None,
            normalized: false,
            sparse: None,
        })
    }

    /// Appends `data` as little-endian f32 triples: a VEC3 float accessor,
    /// with the per-component bounds when `min_max` (glTF requires them on
    /// POSITION).
    fn vec3(&mut self, data: &[Vec3], min_max: bool) -> json::Index<json::Accessor> {
        let start = self.bin.len();
        for v in data {
            for c in v.to_array() {
                self.bin.extend_from_slice(&c.to_le_bytes());
            }
        }
        let view = self.view(start, json::buffer::Target::ArrayBuffer);
        let bounds = min_max.then(|| {
            let lo = data
                .iter()
                .fold(Vec3::splat(f32::INFINITY), |a, b| a.min(*b));
            let hi = data
                .iter()
                .fold(Vec3::splat(f32::NEG_INFINITY), |a, b| a.max(*b));
            let array = |v: Vec3| json::Value::Array(v.to_array().map(number).to_vec());
            (array(lo), array(hi))
        });
        self.accessor(
            view,
            json::accessor::ComponentType::F32,
            json::accessor::Type::Vec3,
            data.len(),
            bounds,
        )
    }

    /// Appends the triangles' vertex indices as little-endian u32: a scalar
    /// unsigned-int accessor.
    fn indices(&mut self, data: &[[u32; 3]]) -> json::Index<json::Accessor> {
        let start = self.bin.len();
        for t in data {
            for i in t {
                self.bin.extend_from_slice(&i.to_le_bytes());
            }
        }
        let view = self.view(start, json::buffer::Target::ElementArrayBuffer);
        self.accessor(
            view,
            json::accessor::ComponentType::U32,
            json::accessor::Type::Scalar,
            data.len() * 3,
            None,
        )
    }

    /// A triangle primitive with `attributes`, `indices` and `material`.
    fn primitive(
        attributes: impl IntoIterator<Item = (json::mesh::Semantic, json::Index<json::Accessor>)>,
        indices: json::Index<json::Accessor>,
        material: json::Index<json::Material>,
    ) -> json::mesh::Primitive {
        json::mesh::Primitive {
            attributes: attributes
                .into_iter()
                .map(|(s, a)| (Valid(s), a))
                .collect::<BTreeMap<_, _>>(),
            extensions: None,
            extras: None,
            indices: Some(indices),
            material: Some(material),
            mode: Valid(json::mesh::Mode::Triangles),
            targets: None,
        }
    }
}

/// A metallic-roughness material named `name`.
fn material(name: &str, base: [f32; 4], metallic: f32, roughness: f32) -> json::Material {
    json::Material {
        name: Some(name.to_string()),
        pbr_metallic_roughness: json::material::PbrMetallicRoughness {
            base_color_factor: json::material::PbrBaseColorFactor(base),
            metallic_factor: json::material::StrengthFactor(metallic),
            roughness_factor: json::material::StrengthFactor(roughness),
            ..Default::default()
        },
        ..Default::default()
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

/// The glTF node and camera for the scene's camera (the camera's `extras`
/// keep the film's `width` and `height` in pixels); the node refers to
/// camera `index`.
///
/// glTF cameras look along their −z with +y up and x to the right; a
/// Mitsuba camera looks along +z with film x along its −x. The node's
/// matrix is the camera's orthonormalised frame (glTF forbids shear, and a
/// scene's `to_world` may scale), so the view is the same whatever scale
/// the scene put in it.
pub(crate) fn camera_json(
    c: &CameraDesc,
    index: json::Index<json::Camera>,
) -> Option<(json::Node, json::Camera)> {
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
    let name = "scene camera";
    let node = json::Node {
        camera: Some(index),
        name: Some(name.to_string()),
        matrix: Some(m.to_cols_array()),
        ..Default::default()
    };
    let size: json::Value = [("width", c.width), ("height", c.height)]
        .into_iter()
        .collect();
    let camera = json::Camera {
        name: Some(name.to_string()),
        orthographic: None,
        perspective: Some(json::camera::Perspective {
            aspect_ratio: Some(w / h),
            yfov,
            zfar: None,
            // glTF needs znear > 0; Mitsuba allows 0
            znear: c.near_clip.max(1e-4),
            extensions: None,
            extras: None,
        }),
        type_: Valid(json::camera::Type::Perspective),
        extensions: None,
        extras: json::extras::RawValue::from_string(size.to_string()).ok(),
    };
    Some((node, camera))
}

/// The glTF document and the binary buffer of a bake (see [`encode_glb`]).
fn document(
    lit: &BakedMesh,
    other: &BakedMesh,
    w0: f32,
    camera: Option<&CameraDesc>,
) -> (json::Root, Vec<u8>) {
    use json::mesh::Semantic;
    let mut b = Builder {
        root: json::Root::default(),
        bin: Vec::new(),
    };
    b.root.asset = json::Asset {
        generator: Some(GENERATOR.to_string()),
        ..Default::default()
    };

    // The primitives, their accessors and materials, in the order of the
    // binary buffer: lit POSITION, NORMAL, COLOR_0, _RADIANCE, indices,
    // then the other surfaces' POSITION, NORMAL, indices
    let mut prims = Vec::new();
    if !lit.indices.is_empty() {
        let colors = display_colors(lit, w0);
        let p = b.vec3(&lit.positions, true);
        let n = b.vec3(&lit.normals, false);
        let c = b.vec3(&colors, false);
        let r = b.vec3(&lit.radiance, false);
        let i = b.indices(&lit.indices);
        let mut baked = material("baked lighting", [1.0; 4], 0.0, 1.0);
        baked.extensions = Some(json::extensions::material::Material {
            unlit: Some(json::extensions::material::Unlit {}),
            ..Default::default()
        });
        let m = b.root.push(baked);
        b.root.extensions_used.push(UNLIT.to_string());
        prims.push(Builder::primitive(
            [
                (Semantic::Positions, p),
                (Semantic::Normals, n),
                (Semantic::Colors(0), c),
                // written `_RADIANCE`: an application-specific attribute
                (Semantic::Extras("RADIANCE".to_string()), r),
            ],
            i,
            m,
        ));
    }
    if !other.indices.is_empty() {
        let p = b.vec3(&other.positions, true);
        let n = b.vec3(&other.normals, false);
        let i = b.indices(&other.indices);
        let m = b.root.push(material(
            "not baked (specular)",
            [0.8, 0.8, 0.8, 1.0],
            1.0,
            0.1,
        ));
        prims.push(Builder::primitive(
            [(Semantic::Positions, p), (Semantic::Normals, n)],
            i,
            m,
        ));
    }

    // The nodes: the display mesh, then the camera. glTF requires at least
    // one primitive per mesh, one node per scene and one byte per buffer, so
    // an empty bake has no mesh, no buffer and (without a camera) no scene.
    let mut nodes = Vec::new();
    if !prims.is_empty() {
        let mesh = b.root.push(json::Mesh {
            name: Some("display mesh".to_string()),
            primitives: prims,
            extensions: None,
            extras: None,
            weights: None,
        });
        nodes.push(b.root.push(json::Node {
            mesh: Some(mesh),
            name: Some("baked".to_string()),
            ..Default::default()
        }));
        b.root.push(json::Buffer {
            byte_length: USize64::from(b.bin.len()),
            name: None,
            uri: None,
            extensions: None,
            extras: None,
        });
    }
    let index = json::Index::new(b.root.cameras.len() as u32);
    if let Some((node, cam)) = camera.and_then(|c| camera_json(c, index)) {
        b.root.push(cam);
        nodes.push(b.root.push(node));
    }
    if !nodes.is_empty() {
        let scene = b.root.push(json::Scene {
            extensions: None,
            extras: None,
            name: None,
            nodes,
        });
        b.root.scene = Some(scene);
    }
    (b.root, b.bin)
}

/// The .glb container (header, JSON chunk padded with spaces, BIN chunk
/// padded with zeros, each to 4 bytes), or None when it would exceed the
/// 4 GiB its 32-bit length field can count. No BIN chunk when `bin` is
/// empty (the JSON then declares no buffer).
pub(crate) fn pack_glb(mut json: Vec<u8>, mut bin: Vec<u8>) -> Option<Vec<u8>> {
    while !json.len().is_multiple_of(4) {
        json.push(b' ');
    }
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let bin_chunk = if bin.is_empty() { 0 } else { 8 + bin.len() };
    let total = u32::try_from(12 + 8 + json.len() + bin_chunk).ok()?;
    let mut out = Vec::with_capacity(total as usize);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&total.to_le_bytes());
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&json);
    if !bin.is_empty() {
        out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
        out.extend_from_slice(b"BIN\0");
        out.extend_from_slice(&bin);
    }
    Some(out)
}

/// The .glb bytes of a bake, or None when they would exceed 4 GiB.
fn try_encode_glb(
    lit: &BakedMesh,
    other: &BakedMesh,
    w0: f32,
    camera: Option<&CameraDesc>,
) -> Option<Vec<u8>> {
    let (root, bin) = document(lit, other, w0, camera);
    // Serialising plain structs with string keys into memory cannot fail
    let json = root.to_vec().expect("the glTF JSON serialises");
    pack_glb(json, bin)
}

/// The bytes of a .glb holding `lit` (white point `w0` for COLOR_0) and
/// `other`, with `camera` as a camera node when given.
///
/// # Panics
///
/// When the file would exceed 4 GiB, the most a .glb can hold (its length
/// field has 32 bits); [`write_glb`] returns an error instead.
pub fn encode_glb(
    lit: &BakedMesh,
    other: &BakedMesh,
    w0: f32,
    camera: Option<&CameraDesc>,
) -> Vec<u8> {
    try_encode_glb(lit, other, w0, camera).expect("a .glb holds at most 4 GiB")
}

/// Writes the .glb atomically ([`encode_glb`]); a display mesh too large
/// for the format (4 GiB) is an error that names the file.
pub fn write_glb(
    path: &Path,
    lit: &BakedMesh,
    other: &BakedMesh,
    w0: f32,
    camera: Option<&CameraDesc>,
) -> Result<(), ImageIoError> {
    let bytes = try_encode_glb(lit, other, w0, camera).ok_or_else(|| ImageIoError::Io {
        path: path.to_path_buf(),
        source: std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            "the display mesh needs more than the 4 GiB a .glb can hold \
             (decimate it, or lower --max-verts)",
        ),
    })?;
    write_atomic(path, |w| {
        w.write_all(&bytes).map_err(|e| ImageIoError::Io {
            path: path.to_path_buf(),
            source: e,
        })
    })
}

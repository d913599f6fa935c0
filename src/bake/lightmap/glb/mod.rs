//! The lightmapped .glb: the input asset written back whole, with a second
//! uv set (TEXCOORD_1) and the lightmap atlas referenced from its materials.
//!
//! **glTF/GLB input.** The original JSON is kept as it is (nodes, meshes,
//! materials, textures, samplers, animations, skins, cameras, extras and
//! extensions, unknown ones included): it is edited as a JSON value, never
//! re-serialised through typed structs that would drop what they do not
//! know. Each primitive the scene read gets new vertex buffers, re-indexed
//! through [`ShapeUv::xref`] (every attribute and morph target duplicated
//! along, TEXCOORD_1 added or replaced), and the same triangles in the same
//! order (the degenerate ones the loader dropped included). A mesh that
//! several nodes instance is duplicated per node, since each instance has
//! its own region of the atlas. The input's buffers and images are copied
//! into the .glb's binary chunk; accessors the new primitives replace stay
//! (animations or other primitives may read them).
//!
//! **Other inputs** (Mitsuba, OBJ, PLY, pbrt): a .glb of the scene's shapes,
//! one mesh each, in world space, with their materials (base colour, and
//! the base colour texture with TEXCOORD_0 when the material has one),
//! the scene camera, and the lightmap on TEXCOORD_1.
//!
//! **The lightmap** (see docs/lightmaps.md for why): each material with a
//! diffuse part gets `MOZ_lightmap` (`index`, `texCoord` 1, `intensity`),
//! the extension Mozilla Hubs defined and three.js-based pipelines read.
//! Its texture holds the irradiance E divided by `intensity` (so that
//! `intensity` × texel = E, three.js's `lightMap` convention: a Lambertian
//! surface of albedo R shows R·E/π) as a 16-bit linear PNG, a format every
//! glTF loader decodes (browsers to 8 bits); `intensity` is the 99.9th
//! percentile of the covered texels, so that a few hot texels do not
//! darken the rest at 8 bits (brighter ones clip). The standard error
//! rides along as a second texture of the same form and scale, named from
//! the `MOZ_lightmap` object's `extras.kalosStdError`. Metals and glass
//! keep their material, without a lightmap. The full-precision float atlas
//! is written
//! next to the .glb as OpenEXR ([`atlas_exr_path`]).

use crate::scene::access::{FileAccess, FileKind, ReadPolicy};
use crate::scene::gltf::Located;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

use glam::{Vec2, Vec3};
use serde_json::{json, Map, Value};

use super::{Lightmap, LightmapUv, ShapeUv};
use crate::color::Rgb;
use crate::image_io::{write_atomic, ImageIoError};
use crate::scene::{Material, Scene, ShapeSource, Texture};

/// `asset.generator` of a lightmapped .glb written from a non-glTF scene.
mod input;
mod shapes;

use input::*;
use shapes::*;

const GENERATOR: &str = "kalos bake --lightmap";
/// The material extension that references the lightmap.
pub const MOZ_LIGHTMAP: &str = "MOZ_lightmap";
/// The key in the `MOZ_lightmap` object's `extras` naming the texture of
/// the standard errors.
pub const STD_ERROR_KEY: &str = "kalosStdError";

/// glTF constants.
const FLOAT: u32 = 5126;
const UNSIGNED_SHORT: u32 = 5123;
const UNSIGNED_INT: u32 = 5125;
const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
const LINEAR: u32 = 9729;
const CLAMP_TO_EDGE: u32 = 33071;

/// An error writing a lightmapped .glb.
#[derive(Debug, thiserror::Error)]
pub enum GlbError {
    /// The input asset could not be read back, or does not match the scene.
    #[error("{path}: {msg}", path = .path.display())]
    Input {
        /// The input file.
        path: PathBuf,
        /// What went wrong.
        msg: String,
    },
    /// The arguments do not fit together (a uv set for another scene...).
    #[error("lightmapped .glb: {0}")]
    Mismatch(String),
    /// Writing the output failed.
    #[error(transparent)]
    Write(#[from] ImageIoError),
}

/// What [`write_lightmapped`] wrote.
#[derive(Clone, Debug, Default)]
pub struct Written {
    /// `MOZ_lightmap.intensity`: the irradiance of a texel of value 1.
    pub intensity: f32,
    /// How many materials reference the lightmap.
    pub lightmapped_materials: usize,
    /// Where the full-precision atlas went (OpenEXR).
    pub exr: PathBuf,
    /// Things skipped or approximated, one per line.
    pub warnings: Vec<String>,
}

/// The OpenEXR file of the full-precision atlas next to a lightmapped
/// .glb: `out.glb` → `out.lightmap.exr`.
pub fn atlas_exr_path(glb: &Path) -> PathBuf {
    glb.with_extension("lightmap.exr")
}

/// Writes `scene` with its lightmap `lm` on the uv set `uv` as a .glb at
/// `path` (atomically: a temporary file, then a rename), and the float
/// atlas as OpenEXR at [`atlas_exr_path`]. `source` is the scene file: a
/// glTF or GLB source is written back whole (see the module doc); any
/// other, or none, gives a .glb of the scene's shapes.
pub fn write_lightmapped(
    path: &Path,
    scene: &Scene,
    source: Option<&Path>,
    uv: &LightmapUv,
    lm: &Lightmap,
) -> Result<Written, GlbError> {
    write_lightmapped_with(path, scene, source, &ReadPolicy::default(), uv, lm)
}

/// [`write_lightmapped`] reading the input asset's files under `read`
/// (the `--allow-read` folders the scene was loaded with).
pub fn write_lightmapped_with(
    path: &Path,
    scene: &Scene,
    source: Option<&Path>,
    read: &ReadPolicy,
    uv: &LightmapUv,
    lm: &Lightmap,
) -> Result<Written, GlbError> {
    let (bytes, mut info) = encode_lightmapped_with(scene, source, read, uv, lm)?;
    write_atomic(path, |w| {
        use std::io::Write;
        w.write_all(&bytes).map_err(|e| ImageIoError::Io {
            path: path.to_path_buf(),
            source: e,
        })
    })?;
    let exr = atlas_exr_path(path);
    let img = crate::film::Image {
        width: lm.width,
        height: lm.height,
        data: lm.irradiance.clone(),
    };
    crate::image_io::write_image(&exr, &img, &Default::default())?;
    info.exr = exr;
    Ok(info)
}

/// The bytes of the lightmapped .glb ([`write_lightmapped`] without the
/// files).
pub fn encode_lightmapped(
    scene: &Scene,
    source: Option<&Path>,
    uv: &LightmapUv,
    lm: &Lightmap,
) -> Result<(Vec<u8>, Written), GlbError> {
    encode_lightmapped_with(scene, source, &ReadPolicy::default(), uv, lm)
}

/// [`encode_lightmapped`] reading the input asset's files under `read`
/// (the `--allow-read` folders the scene was loaded with).
pub fn encode_lightmapped_with(
    scene: &Scene,
    source: Option<&Path>,
    read: &ReadPolicy,
    uv: &LightmapUv,
    lm: &Lightmap,
) -> Result<(Vec<u8>, Written), GlbError> {
    check_inputs(scene, uv, lm)?;
    let gltf_source = source.filter(|p| {
        p.extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| e.eq_ignore_ascii_case("gltf") || e.eq_ignore_ascii_case("glb"))
    });
    let mut out = Out::default();
    let mut info = Written::default();
    match gltf_source {
        Some(src) => {
            let access = FileAccess::for_scene(src, read).map_err(|e| GlbError::Input {
                path: src.to_path_buf(),
                msg: e.to_string(),
            })?;
            let input = read_gltf(src, &access)?;
            out.root = input.json.clone();
            out.take_buffers(&input, src)?;
            out.take_images(&input, src, &access)?;
            let lm_tex = out.lightmap_textures(lm, &mut info);
            rewrite_primitives(&mut out, &input, src, scene, uv, lm_tex, &mut info)?;
        }
        None => {
            out.root = json!({ "asset": { "version": "2.0", "generator": GENERATOR } });
            let lm_tex = out.lightmap_textures(lm, &mut info);
            shapes_document(&mut out, scene, uv, lm_tex, &mut info);
        }
    }
    out.finish();
    let json = serde_json::to_vec(&out.root).map_err(|e| GlbError::Mismatch(e.to_string()))?;
    let bytes = crate::bake::gltf::pack_glb(json, out.bin).ok_or_else(|| {
        GlbError::Mismatch("the .glb would exceed the 4 GiB the format holds".into())
    })?;
    Ok((bytes, info))
}

/// Checks that the uv set and the atlas belong to `scene` and to each
/// other, so that indexing below cannot go out of bounds.
fn check_inputs(scene: &Scene, uv: &LightmapUv, lm: &Lightmap) -> Result<(), GlbError> {
    let bad = |m: String| Err(GlbError::Mismatch(m));
    let texels = lm.width as usize * lm.height as usize;
    if lm.width == 0 || lm.height == 0 || lm.irradiance.len() != texels {
        return bad(format!(
            "the atlas is {}×{} but holds {} texels",
            lm.width,
            lm.height,
            lm.irradiance.len()
        ));
    }
    if !lm.std_error.is_empty() && lm.std_error.len() != texels {
        return bad(format!(
            "{} standard errors for {texels} texels",
            lm.std_error.len()
        ));
    }
    if uv.shapes.len() != scene.shapes.len() {
        return bad(format!(
            "the uv set has {} shapes, the scene {}",
            uv.shapes.len(),
            scene.shapes.len()
        ));
    }
    for (i, (s, su)) in scene.shapes.iter().zip(&uv.shapes).enumerate() {
        if su.triangles.len() != s.tri_count as usize {
            return bad(format!(
                "shape {i}: the uv set has {} triangles, the scene {}",
                su.triangles.len(),
                s.tri_count
            ));
        }
        if su.uv.len() != su.xref.len() {
            return bad(format!(
                "shape {i}: {} uvs for {} vertices",
                su.uv.len(),
                su.xref.len()
            ));
        }
        if su.xref.iter().any(|&v| v as usize >= scene.positions.len()) {
            return bad(format!(
                "shape {i}: a vertex copies one the scene does not have"
            ));
        }
        if su
            .triangles
            .iter()
            .flatten()
            .any(|&v| v as usize >= su.xref.len())
        {
            return bad(format!(
                "shape {i}: a triangle names a vertex the uv set does not have"
            ));
        }
    }
    Ok(())
}

/// Whether a material has a diffuse part, so that a lightmap applies.
pub fn has_diffuse(m: &Material) -> bool {
    match m {
        Material::Diffuse { .. }
        | Material::Phong { .. }
        | Material::Plastic { .. }
        | Material::RoughPlastic { .. }
        | Material::MetallicRoughness(_) => true,
        Material::Conductor { .. }
        | Material::RoughConductor { .. }
        | Material::Dielectric { .. }
        | Material::RoughDielectric { .. }
        | Material::ThinDielectric { .. } => false,
        Material::TwoSided(inner) => has_diffuse(inner),
    }
}

// ---------------------------------------------------------------------------
// Reading the input

/// The output document and its binary chunk, as they are filled.
#[derive(Default)]
struct Out {
    root: Value,
    bin: Vec<u8>,
    extensions: Vec<&'static str>,
}

/// The textures of the lightmap, once added.
#[derive(Clone, Copy)]
struct LightmapTextures {
    atlas: usize,
    std_error: Option<usize>,
    intensity: f32,
}

/// `x` as a JSON number with the fewest digits that read back as the same
/// f32 (a widened f32 would print as 0.10000000149011612).
fn num(x: f32) -> Value {
    x.to_string()
        .parse::<f64>()
        .ok()
        .and_then(serde_json::Number::from_f64)
        .map_or(Value::Null, Value::Number)
}

impl Out {
    /// The array at `key` of the root, created when missing.
    fn array(&mut self, key: &str) -> &mut Vec<Value> {
        let obj = self
            .root
            .as_object_mut()
            .expect("the glTF root is an object");
        let v = obj.entry(key).or_insert_with(|| Value::Array(Vec::new()));
        if !v.is_array() {
            *v = Value::Array(Vec::new());
        }
        v.as_array_mut().expect("an array")
    }

    /// Appends `v` to the root's array `key`, returning its index.
    fn push(&mut self, key: &str, v: Value) -> usize {
        let a = self.array(key);
        a.push(v);
        a.len() - 1
    }

    /// Appends `bytes` to the binary chunk (at a 4-byte boundary) as a new
    /// buffer view, with `stride` and `target` when given.
    fn view(&mut self, bytes: &[u8], stride: Option<usize>, target: Option<u32>) -> usize {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        let mut v = json!({
            "buffer": 0,
            "byteOffset": self.bin.len(),
            "byteLength": bytes.len(),
        });
        if let Some(s) = stride {
            v["byteStride"] = json!(s);
        }
        if let Some(t) = target {
            v["target"] = json!(t);
        }
        self.bin.extend_from_slice(bytes);
        self.push("bufferViews", v)
    }

    /// A vertex attribute accessor over packed `elems` (elements of `size`
    /// bytes, padded to 4 bytes in the buffer view as glTF requires), of
    /// the given component type and `type_`, with min/max when given.
    #[allow(clippy::too_many_arguments)]
    fn attribute(
        &mut self,
        elems: &[u8],
        size: usize,
        component_type: u32,
        type_: &str,
        normalized: bool,
        min_max: Option<(Vec<Value>, Vec<Value>)>,
    ) -> usize {
        let count = elems.len() / size.max(1);
        let padded = size.next_multiple_of(4);
        let view = if padded == size {
            self.view(elems, None, Some(ARRAY_BUFFER))
        } else {
            let mut b = vec![0u8; padded * count];
            for (i, e) in elems.chunks_exact(size).enumerate() {
                b[i * padded..i * padded + size].copy_from_slice(e);
            }
            self.view(&b, Some(padded), Some(ARRAY_BUFFER))
        };
        let mut a = json!({
            "bufferView": view,
            "componentType": component_type,
            "count": count,
            "type": type_,
        });
        if normalized {
            a["normalized"] = json!(true);
        }
        if let Some((min, max)) = min_max {
            a["min"] = Value::Array(min);
            a["max"] = Value::Array(max);
        }
        self.push("accessors", a)
    }

    /// A float vector attribute (VEC2 or VEC3), with min/max when asked.
    fn floats<const N: usize>(&mut self, data: &[[f32; N]], min_max: bool) -> usize {
        let bytes: Vec<u8> = data
            .iter()
            .flatten()
            .flat_map(|x| x.to_le_bytes())
            .collect();
        let mm = min_max.then(|| {
            let mut lo = [f32::INFINITY; N];
            let mut hi = [f32::NEG_INFINITY; N];
            for v in data {
                for k in 0..N {
                    lo[k] = lo[k].min(v[k]);
                    hi[k] = hi[k].max(v[k]);
                }
            }
            (lo.map(num).to_vec(), hi.map(num).to_vec())
        });
        let t = if N == 2 { "VEC2" } else { "VEC3" };
        self.attribute(&bytes, 4 * N, FLOAT, t, false, mm)
    }

    /// An index accessor (unsigned short when every index fits, else
    /// unsigned int).
    fn indices(&mut self, tris: &[[u32; 3]], vertex_count: usize) -> usize {
        let flat = tris.iter().flatten();
        let (bytes, ct): (Vec<u8>, u32) = if vertex_count <= u16::MAX as usize {
            (
                flat.flat_map(|&i| (i as u16).to_le_bytes()).collect(),
                UNSIGNED_SHORT,
            )
        } else {
            (flat.flat_map(|&i| i.to_le_bytes()).collect(), UNSIGNED_INT)
        };
        let view = self.view(&bytes, None, Some(ELEMENT_ARRAY_BUFFER));
        self.push(
            "accessors",
            json!({
                "bufferView": view,
                "componentType": ct,
                "count": tris.len() * 3,
                "type": "SCALAR",
            }),
        )
    }

    /// An image of `bytes` (with its MIME type) in the binary chunk.
    fn image(&mut self, bytes: &[u8], mime: &str, name: &str) -> usize {
        let view = self.view(bytes, None, None);
        self.push(
            "images",
            json!({ "bufferView": view, "mimeType": mime, "name": name }),
        )
    }

    /// Copies the input's buffers into the binary chunk and points its
    /// buffer views there (one buffer, the GLB's).
    fn take_buffers(&mut self, input: &Input, src: &Path) -> Result<(), GlbError> {
        let mut base = Vec::new();
        for b in &input.buffers {
            while !self.bin.len().is_multiple_of(16) {
                self.bin.push(0);
            }
            base.push(self.bin.len());
            self.bin.extend_from_slice(b);
        }
        for v in self.array("bufferViews") {
            let b = v["buffer"].as_u64().unwrap_or(0) as usize;
            let off = v["byteOffset"].as_u64().unwrap_or(0) as usize;
            let Some(&start) = base.get(b) else {
                return Err(GlbError::Input {
                    path: src.to_path_buf(),
                    msg: format!("a buffer view names buffer {b}, which does not exist"),
                });
            };
            v["buffer"] = json!(0);
            v["byteOffset"] = json!(start + off);
        }
        // The buffers are replaced by the GLB's own at the end ([`finish`])
        self.array("buffers").clear();
        Ok(())
    }

    /// Copies the images the input names by URI into the binary chunk.
    fn take_images(
        &mut self,
        input: &Input,
        src: &Path,
        access: &FileAccess,
    ) -> Result<(), GlbError> {
        let n = self.array("images").len();
        for i in 0..n {
            let img = &input.json["images"][i];
            let Some(uri) = img["uri"].as_str() else {
                continue;
            };
            let bytes = read_uri(src, uri, FileKind::Image, access)?;
            let mime = img["mimeType"]
                .as_str()
                .map(str::to_string)
                .or_else(|| mime_of(uri, &bytes).map(str::to_string))
                .ok_or_else(|| GlbError::Input {
                    path: src.to_path_buf(),
                    msg: format!("image {i} (`{uri}`): not a PNG or JPEG, and no mimeType"),
                })?;
            let view = self.view(&bytes, None, None);
            let img = &mut self.array("images")[i];
            if let Some(o) = img.as_object_mut() {
                o.remove("uri");
                o.insert("bufferView".into(), json!(view));
                o.insert("mimeType".into(), json!(mime));
            }
        }
        Ok(())
    }

    /// Adds the lightmap's images and textures (see the module doc).
    fn lightmap_textures(&mut self, lm: &Lightmap, info: &mut Written) -> LightmapTextures {
        let intensity = scale_of(lm);
        info.intensity = intensity;
        let (w, h) = (lm.width, lm.height);
        let sampler = self.push(
            "samplers",
            json!({
                "magFilter": LINEAR, "minFilter": LINEAR,
                "wrapS": CLAMP_TO_EDGE, "wrapT": CLAMP_TO_EDGE,
                "name": "lightmap (no mipmaps: they would blend charts)",
            }),
        );
        let png = encode_png16(w, h, &lm.irradiance, intensity);
        let img = self.image(
            &png,
            "image/png",
            "lightmap: irradiance / intensity, linear",
        );
        let atlas = self.push(
            "textures",
            json!({ "sampler": sampler, "source": img, "name": "lightmap" }),
        );
        let std_error = (!lm.std_error.is_empty()).then(|| {
            let png = encode_png16(w, h, &lm.std_error, intensity);
            let img = self.image(
                &png,
                "image/png",
                "lightmap standard error: / intensity, linear",
            );
            self.push(
                "textures",
                json!({ "sampler": sampler, "source": img, "name": "lightmap standard error" }),
            )
        });
        LightmapTextures {
            atlas,
            std_error,
            intensity,
        }
    }

    /// Sets material `m`'s `MOZ_lightmap` to the atlas.
    fn lightmap_material(&mut self, m: usize, t: LightmapTextures) {
        let mut ext = json!({ "index": t.atlas, "texCoord": 1, "intensity": num(t.intensity) });
        if let Some(e) = t.std_error {
            ext["extras"] = json!({ STD_ERROR_KEY: { "index": e } });
        }
        let mat = &mut self.array("materials")[m];
        if !mat["extensions"].is_object() {
            mat["extensions"] = json!({});
        }
        mat["extensions"][MOZ_LIGHTMAP] = ext;
        if !self.extensions.contains(&MOZ_LIGHTMAP) {
            self.extensions.push(MOZ_LIGHTMAP);
        }
    }

    /// The one buffer, and the extensions used.
    fn finish(&mut self) {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        let len = self.bin.len();
        if len > 0 {
            *self.array("buffers") = vec![json!({ "byteLength": len })];
        } else if let Some(o) = self.root.as_object_mut() {
            o.remove("buffers");
        }
        let used: Vec<&'static str> = self.extensions.clone();
        let list = self.array("extensionsUsed");
        for e in used {
            if !list.iter().any(|v| v == e) {
                list.push(json!(e));
            }
        }
        // Empty arrays are not valid glTF
        if let Some(o) = self.root.as_object_mut() {
            o.retain(|_, v| !v.as_array().is_some_and(Vec::is_empty));
        }
    }
}

/// The MIME type of an image, from its bytes, else its name.
fn mime_of(uri: &str, bytes: &[u8]) -> Option<&'static str> {
    if bytes.starts_with(b"\x89PNG") {
        return Some("image/png");
    }
    if bytes.starts_with(&[0xFF, 0xD8, 0xFF]) {
        return Some("image/jpeg");
    }
    let lower = uri.to_ascii_lowercase();
    if lower.ends_with(".png") {
        Some("image/png")
    } else if lower.ends_with(".jpg") || lower.ends_with(".jpeg") {
        Some("image/jpeg")
    } else if lower.ends_with(".webp") {
        Some("image/webp")
    } else if lower.ends_with(".ktx2") {
        Some("image/ktx2")
    } else {
        None
    }
}

/// The irradiance of a texel of value 1: the 99.9th percentile of the
/// covered texels' largest channel (so that a few hot texels do not
/// squash the 8-bit PNG's range), and 1 for an all-black atlas.
pub fn scale_of(lm: &Lightmap) -> f32 {
    let mut v: Vec<f32> = lm
        .irradiance
        .iter()
        .enumerate()
        .filter(|(i, _)| lm.covered.get(*i).copied().unwrap_or(true))
        .map(|(_, e)| e.max_element())
        .filter(|x| x.is_finite() && *x > 0.0)
        .collect();
    if v.is_empty() {
        return 1.0;
    }
    let k = ((v.len() - 1) as f64 * 0.999).round() as usize;
    let (_, x, _) = v.select_nth_unstable_by(k, f32::total_cmp);
    *x
}

/// A 16-bit RGB PNG of `data / scale`, linear (no sRGB curve: loaders
/// read a lightmap texture as linear), clipped to [0, 1]; non-finite
/// values written as 0.
fn encode_png16(w: u32, h: u32, data: &[Rgb], scale: f32) -> Vec<u8> {
    use image::ImageEncoder;
    let px: Vec<u8> = data
        .iter()
        .flat_map(|c| {
            (*c / scale).to_array().map(|x| {
                let x = if x.is_finite() {
                    x.clamp(0.0, 1.0)
                } else {
                    0.0
                };
                (x * 65535.0).round() as u16
            })
        })
        .flat_map(u16::to_ne_bytes)
        .collect();
    let mut out = Vec::new();
    image::codecs::png::PngEncoder::new(&mut out)
        .write_image(&px, w, h, image::ExtendedColorType::Rgb16)
        .expect("PNG encoding into memory succeeds");
    out
}

// ---------------------------------------------------------------------------
// glTF input

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn new_primitive_keeps_dropped_triangles_and_order() {
        // primitive: 4 vertices, triangles 0 (kept), 1 (degenerate, dropped),
        // 2 (kept, mirrored in the scene)
        let prim = [[0, 1, 2], [1, 1, 3], [0, 2, 3]];
        let src = ShapeSource {
            first_vertex: 10,
            vertex_count: 4,
            prim_triangles: 3,
            kept: vec![0, 2],
            mirrored: true,
            ..Default::default()
        };
        // the uv set split vertex 0 in two; scene triangles reversed
        let su = ShapeUv {
            xref: vec![10, 11, 12, 13, 10],
            triangles: vec![[0, 2, 1], [4, 3, 2]],
            uv: (0..5).map(|i| Vec2::splat(i as f32 / 5.0)).collect(),
        };
        let np = new_primitive(&src, &su, &prim).unwrap();
        assert_eq!(np.tris.len(), 3);
        assert_eq!(np.tris[0], [0, 1, 2]);
        assert_eq!(np.tris[2], [4, 2, 3]);
        // the dropped triangle reuses vertices 1 and 3's copies
        assert_eq!(np.tris[1], [1, 1, 3]);
        assert_eq!(np.verts, vec![0, 1, 2, 3, 0]);
    }
}

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
        | Material::RoughPlastic { .. } => true,
        Material::Conductor { .. }
        | Material::RoughConductor { .. }
        | Material::Dielectric { .. }
        | Material::ThinDielectric { .. } => false,
        Material::TwoSided(inner) => has_diffuse(inner),
    }
}

// ---------------------------------------------------------------------------
// Reading the input

/// A glTF input: its JSON as a value, the typed document for reading
/// accessors, and the bytes of its buffers (by index).
struct Input {
    json: Value,
    doc: gltf::Document,
    buffers: Vec<Vec<u8>>,
}

/// Reads one file of the input asset (the scene file, or a buffer or image
/// it names) through the scene's file access (see [`crate::scene::access`]:
/// under the allowed folders, a regular file, within its kind's size).
/// Every read of the input goes through here.
fn read_input_file(path: &Path, kind: FileKind, access: &FileAccess) -> Result<Vec<u8>, GlbError> {
    access.read(path, kind).map_err(|e| GlbError::Input {
        path: path.to_path_buf(),
        msg: e.to_string(),
    })
}

/// The bytes a glTF URI names, resolved as the glTF loader resolves it
/// ([`crate::scene::gltf::locate`]: a `data:` URI decoded, else a file
/// relative to the scene file's folder), read through `access`.
fn read_uri(
    scene_file: &Path,
    uri: &str,
    kind: FileKind,
    access: &FileAccess,
) -> Result<Vec<u8>, GlbError> {
    let base = scene_file.parent().unwrap_or(Path::new("."));
    match crate::scene::gltf::locate(uri, base, kind, access) {
        Ok(Located::Data(bytes, _)) => Ok(bytes),
        Ok(Located::File(p, _)) => read_input_file(&p, kind, access),
        Err(msg) => Err(GlbError::Input {
            path: scene_file.to_path_buf(),
            msg: format!("URI `{uri}`: {msg}"),
        }),
    }
}

/// Reads a glTF or GLB file: its JSON, the document, and its buffers.
fn read_gltf(path: &Path, access: &FileAccess) -> Result<Input, GlbError> {
    let err = |msg: String| GlbError::Input {
        path: path.to_path_buf(),
        msg,
    };
    let bytes = read_input_file(path, FileKind::Scene, access)?;
    let (json_bytes, blob) = if bytes.starts_with(b"glTF") {
        split_glb(&bytes).ok_or_else(|| err("a corrupt GLB container".into()))?
    } else {
        (&bytes[..], None)
    };
    let json: Value = serde_json::from_slice(json_bytes)
        .map_err(|e| err(format!("cannot parse the JSON: {e}")))?;
    let doc = gltf::Gltf::from_slice(&bytes)
        .map_err(|e| err(format!("cannot read glTF: {e}")))?
        .document;
    let mut buffers = Vec::new();
    for b in doc.buffers() {
        let data = match b.source() {
            gltf::buffer::Source::Bin => blob
                .map(<[u8]>::to_vec)
                .ok_or_else(|| err("buffer 0 has no URI and the file no BIN chunk".into()))?,
            gltf::buffer::Source::Uri(uri) => read_uri(path, uri, FileKind::Mesh, access)?,
        };
        if data.len() < b.length() {
            return Err(err(format!(
                "buffer {} holds {} bytes, its byteLength says {}",
                b.index(),
                data.len(),
                b.length()
            )));
        }
        buffers.push(data);
    }
    Ok(Input { json, doc, buffers })
}

/// A GLB's JSON chunk and BIN chunk (if any), or None when the lengths do
/// not fit in the file.
fn split_glb(bytes: &[u8]) -> Option<(&[u8], Option<&[u8]>)> {
    let word = |i: usize| -> Option<usize> {
        Some(u32::from_le_bytes(bytes.get(i..i + 4)?.try_into().ok()?) as usize)
    };
    let jlen = word(12)?;
    let json = bytes.get(20..20 + jlen)?;
    let at = 20 + jlen;
    let bin = match (word(at), bytes.get(at + 4..at + 8)) {
        (Some(len), Some(b"BIN\0")) => Some(bytes.get(at + 8..at + 8 + len)?),
        _ => None,
    };
    Some((json, bin))
}

/// The elements of an accessor, tightly packed (`count` × element size
/// bytes): read through its buffer view's stride, zeros without one, the
/// sparse substitutions applied.
fn accessor_bytes(a: &gltf::Accessor, buffers: &[Vec<u8>]) -> Result<Vec<u8>, String> {
    let size = a.size();
    let count = a.count();
    let mut out = vec![0u8; size * count];
    if let Some(view) = a.view() {
        let stride = view.stride().unwrap_or(size);
        let data = &buffers[view.buffer().index()];
        let start = view.offset() + a.offset();
        let end = view.offset() + view.length();
        for i in 0..count {
            let s = start + i * stride;
            if s + size > end || s + size > data.len() {
                return Err(format!("accessor {} reads past its buffer view", a.index()));
            }
            out[i * size..(i + 1) * size].copy_from_slice(&data[s..s + size]);
        }
    }
    if let Some(sp) = a.sparse() {
        let n = sp.count();
        let iv = sp.indices();
        let ix_size = match iv.index_type() {
            gltf::accessor::sparse::IndexType::U8 => 1,
            gltf::accessor::sparse::IndexType::U16 => 2,
            gltf::accessor::sparse::IndexType::U32 => 4,
        };
        let ib = &buffers[iv.view().buffer().index()];
        let i0 = iv.view().offset() + iv.offset();
        let vv = sp.values();
        let vb = &buffers[vv.view().buffer().index()];
        let v0 = vv.view().offset() + vv.offset();
        for k in 0..n {
            let p = i0 + k * ix_size;
            let raw = ib
                .get(p..p + ix_size)
                .ok_or_else(|| format!("accessor {}: sparse indices past the buffer", a.index()))?;
            let mut w = [0u8; 4];
            w[..ix_size].copy_from_slice(raw);
            let i = u32::from_le_bytes(w) as usize;
            let q = v0 + k * size;
            let val = vb
                .get(q..q + size)
                .ok_or_else(|| format!("accessor {}: sparse values past the buffer", a.index()))?;
            if i >= count {
                return Err(format!(
                    "accessor {}: sparse index {i} ≥ count {count}",
                    a.index()
                ));
            }
            out[i * size..(i + 1) * size].copy_from_slice(val);
        }
    }
    Ok(out)
}

/// The value of one component, as min/max hold it.
fn component(t: gltf::accessor::DataType, b: &[u8]) -> f64 {
    use gltf::accessor::DataType as T;
    match t {
        T::I8 => b[0] as i8 as f64,
        T::U8 => b[0] as f64,
        T::I16 => i16::from_le_bytes([b[0], b[1]]) as f64,
        T::U16 => u16::from_le_bytes([b[0], b[1]]) as f64,
        T::U32 => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
        T::F32 => f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
    }
}

// ---------------------------------------------------------------------------
// Writing

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
fn scale_of(lm: &Lightmap) -> f32 {
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

/// One primitive's new vertices: for each, the primitive vertex it copies
/// and its lightmap uv; and the primitive's triangles on them.
struct NewPrimitive {
    verts: Vec<u32>,
    uv1: Vec<Vec2>,
    tris: Vec<[u32; 3]>,
}

/// The new vertices and triangles of the primitive a shape came from:
/// the shape's uv vertices, plus copies (uv 0) of the vertices only the
/// dropped degenerate triangles use; every primitive triangle in order,
/// with its own corner order.
fn new_primitive(
    src: &ShapeSource,
    su: &ShapeUv,
    prim_tris: &[[u32; 3]],
) -> Result<NewPrimitive, String> {
    let mut verts: Vec<u32> = su
        .xref
        .iter()
        .map(|&v| v.wrapping_sub(src.first_vertex))
        .collect();
    if let Some(&bad) = verts.iter().find(|&&v| v >= src.vertex_count) {
        return Err(format!(
            "the uv set copies vertex {bad}, outside the primitive"
        ));
    }
    let mut uv1 = su.uv.clone();
    let mut tris: Vec<Option<[u32; 3]>> = vec![None; prim_tris.len()];
    for (k, t) in su.triangles.iter().enumerate() {
        let p = src.prim_triangle(k as u32) as usize;
        let orig = *prim_tris.get(p).ok_or_else(|| {
            format!("triangle {k} maps to primitive triangle {p}, which is not there")
        })?;
        // each corner of the primitive's triangle is one of the new
        // triangle's (the winding may have been reversed)
        let mut out = [0u32; 3];
        for (j, &o) in orig.iter().enumerate() {
            out[j] = *t
                .iter()
                .find(|&&c| verts[c as usize] == o)
                .ok_or_else(|| format!("triangle {k} is not primitive triangle {p}"))?;
        }
        tris[p] = Some(out);
    }
    // vertices of the dropped triangles: the first copy, else a new one
    let mut first: HashMap<u32, u32> = HashMap::new();
    for (i, &v) in verts.iter().enumerate() {
        first.entry(v).or_insert(i as u32);
    }
    let mut all = Vec::with_capacity(prim_tris.len());
    for (p, t) in tris.into_iter().enumerate() {
        let t = match t {
            Some(t) => t,
            None => prim_tris[p].map(|o| {
                *first.entry(o).or_insert_with(|| {
                    verts.push(o);
                    uv1.push(Vec2::ZERO);
                    (verts.len() - 1) as u32
                })
            }),
        };
        all.push(t);
    }
    Ok(NewPrimitive {
        verts,
        uv1,
        tris: all,
    })
}

/// Rewrites every primitive the scene read with its new vertices and
/// TEXCOORD_1, duplicating meshes instanced by several nodes, and puts the
/// lightmap on the materials with a diffuse part.
fn rewrite_primitives(
    out: &mut Out,
    input: &Input,
    src: &Path,
    scene: &Scene,
    uv: &LightmapUv,
    lm_tex: LightmapTextures,
    info: &mut Written,
) -> Result<(), GlbError> {
    let err = |msg: String| GlbError::Input {
        path: src.to_path_buf(),
        msg,
    };
    // which mesh each node writes to: the first node keeps the mesh, the
    // others get a copy of it
    let mut node_mesh: HashMap<u32, usize> = HashMap::new();
    let mut mesh_owner: HashMap<u32, u32> = HashMap::new();
    let mut done: HashMap<(u32, u32), ()> = HashMap::new();
    let mut lit_materials: Vec<usize> = Vec::new();
    let mut default_lit: Option<usize> = None;
    for (s, su) in scene.shapes.iter().zip(&uv.shapes) {
        let Some(source) = s.source.as_deref() else {
            return Err(err(format!(
                "shape `{}` does not come from a glTF primitive: the scene was not loaded from this file",
                s.name
            )));
        };
        if done.insert((source.node, source.primitive), ()).is_some() {
            info.warnings.push(format!(
                "glTF node {} is reached twice (a node with two parents, which glTF forbids): \
                 its second instance keeps the first one's lightmap region",
                source.node
            ));
            continue;
        }
        let mesh = match node_mesh.get(&source.node) {
            Some(&m) => m,
            None => {
                let m = match mesh_owner.get(&source.mesh) {
                    None => {
                        mesh_owner.insert(source.mesh, source.node);
                        source.mesh as usize
                    }
                    Some(_) => {
                        let copy = input.json["meshes"][source.mesh as usize].clone();
                        let m = out.push("meshes", copy);
                        out.array("nodes")[source.node as usize]["mesh"] = json!(m);
                        m
                    }
                };
                node_mesh.insert(source.node, m);
                m
            }
        };
        let gmesh = input
            .doc
            .meshes()
            .nth(source.mesh as usize)
            .ok_or_else(|| err(format!("mesh {} is not in the file", source.mesh)))?;
        let prim = gmesh
            .primitives()
            .nth(source.primitive as usize)
            .ok_or_else(|| {
                err(format!(
                    "mesh {} has no primitive {}",
                    source.mesh, source.primitive
                ))
            })?;
        let at = |m: String| {
            err(format!(
                "mesh {} primitive {}: {m}",
                source.mesh, source.primitive
            ))
        };
        let prim_tris =
            primitive_triangles(&prim, &input.buffers, source.vertex_count).map_err(&at)?;
        let np = new_primitive(source, su, &prim_tris).map_err(&at)?;
        let mut pj = input.json["meshes"][source.mesh as usize]["primitives"]
            [source.primitive as usize]
            .clone();
        // attributes
        let mut attrs = Map::new();
        for (sem, a) in prim.attributes() {
            let name = semantic_name(&sem);
            if name == "TEXCOORD_1" {
                continue;
            }
            let idx = gather(
                out,
                &a,
                &np.verts,
                &input.buffers,
                source.vertex_count,
                name == "POSITION",
            )
            .map_err(&at)?;
            attrs.insert(name, json!(idx));
        }
        let uv1: Vec<[f32; 2]> = np.uv1.iter().map(|v| v.to_array()).collect();
        attrs.insert("TEXCOORD_1".into(), json!(out.floats(&uv1, false)));
        pj["attributes"] = Value::Object(attrs);
        // morph targets
        let mut targets = Vec::new();
        for t in prim.morph_targets() {
            let mut tj = Map::new();
            for (name, a) in [
                ("POSITION", t.positions()),
                ("NORMAL", t.normals()),
                ("TANGENT", t.tangents()),
            ] {
                if let Some(a) = a {
                    let idx = gather(
                        out,
                        &a,
                        &np.verts,
                        &input.buffers,
                        source.vertex_count,
                        name == "POSITION",
                    )
                    .map_err(&at)?;
                    tj.insert(name.into(), json!(idx));
                }
            }
            targets.push(Value::Object(tj));
        }
        if !targets.is_empty() {
            pj["targets"] = Value::Array(targets);
        }
        pj["indices"] = json!(out.indices(&np.tris, np.verts.len()));
        // the lightmap on the material
        if has_diffuse(&scene.materials[s.material as usize]) {
            let m = match pj["material"].as_u64() {
                Some(m) => m as usize,
                None => *default_lit.get_or_insert_with(|| {
                    out.push("materials", json!({ "name": "default (lightmapped)" }))
                }),
            };
            pj["material"] = json!(m);
            if !lit_materials.contains(&m) {
                lit_materials.push(m);
            }
        }
        out.array("meshes")[mesh]["primitives"][source.primitive as usize] = pj;
    }
    for &m in &lit_materials {
        out.lightmap_material(m, lm_tex);
    }
    info.lightmapped_materials = lit_materials.len();
    Ok(())
}

/// A primitive's triangles, on its own vertices (all of them in range).
fn primitive_triangles(
    prim: &gltf::Primitive,
    buffers: &[Vec<u8>],
    n: u32,
) -> Result<Vec<[u32; 3]>, String> {
    let flat: Vec<u32> = match prim.indices() {
        Some(a) => {
            let bytes = accessor_bytes(&a, buffers)?;
            bytes
                .chunks_exact(a.size())
                .map(|b| component(a.data_type(), b) as u32)
                .collect()
        }
        None => (0..n).collect(),
    };
    if let Some(bad) = flat.iter().find(|&&i| i >= n) {
        return Err(format!("index {bad} ≥ the vertex count {n}"));
    }
    Ok(flat.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect())
}

/// The glTF attribute name of a semantic.
fn semantic_name(s: &gltf::Semantic) -> String {
    use gltf::Semantic as S;
    match s {
        S::Positions => "POSITION".into(),
        S::Normals => "NORMAL".into(),
        S::Tangents => "TANGENT".into(),
        S::Colors(i) => format!("COLOR_{i}"),
        S::TexCoords(i) => format!("TEXCOORD_{i}"),
        S::Joints(i) => format!("JOINTS_{i}"),
        S::Weights(i) => format!("WEIGHTS_{i}"),
        S::Extras(n) => format!("_{n}"),
    }
}

/// A new accessor holding accessor `a`'s elements at `verts` (primitive
/// vertex indices), with min/max recomputed when the original had them
/// (and always for POSITION).
fn gather(
    out: &mut Out,
    a: &gltf::Accessor,
    verts: &[u32],
    buffers: &[Vec<u8>],
    n: u32,
    position: bool,
) -> Result<usize, String> {
    if a.count() != n as usize {
        return Err(format!(
            "accessor {} has {} elements, the primitive {n} vertices",
            a.index(),
            a.count()
        ));
    }
    let src = accessor_bytes(a, buffers)?;
    let size = a.size();
    let mut elems = Vec::with_capacity(verts.len() * size);
    for &v in verts {
        elems.extend_from_slice(&src[v as usize * size..(v as usize + 1) * size]);
    }
    let dims = a.dimensions().multiplicity();
    let csize = size / dims.max(1);
    let min_max = (position || a.min().is_some() || a.max().is_some()).then(|| {
        let mut lo = vec![f64::INFINITY; dims];
        let mut hi = vec![f64::NEG_INFINITY; dims];
        for e in elems.chunks_exact(size) {
            for k in 0..dims {
                let x = component(a.data_type(), &e[k * csize..(k + 1) * csize]);
                lo[k] = lo[k].min(x);
                hi[k] = hi[k].max(x);
            }
        }
        let as_json = |x: f64| {
            if a.data_type() == gltf::accessor::DataType::F32 {
                num(x as f32)
            } else {
                json!(x as i64)
            }
        };
        (
            lo.into_iter().map(as_json).collect(),
            hi.into_iter().map(as_json).collect(),
        )
    });
    let type_ = match a.dimensions() {
        gltf::accessor::Dimensions::Scalar => "SCALAR",
        gltf::accessor::Dimensions::Vec2 => "VEC2",
        gltf::accessor::Dimensions::Vec3 => "VEC3",
        gltf::accessor::Dimensions::Vec4 => "VEC4",
        gltf::accessor::Dimensions::Mat2 => "MAT2",
        gltf::accessor::Dimensions::Mat3 => "MAT3",
        gltf::accessor::Dimensions::Mat4 => "MAT4",
    };
    Ok(out.attribute(
        &elems,
        size,
        a.data_type().as_gl_enum(),
        type_,
        a.normalized(),
        min_max.filter(|(lo, _): &(Vec<Value>, Vec<Value>)| !lo.is_empty() && !verts.is_empty()),
    ))
}

// ---------------------------------------------------------------------------
// Other inputs

/// A .glb of the scene's shapes (one mesh and node each, in world space),
/// their materials and the scene camera.
fn shapes_document(
    out: &mut Out,
    scene: &Scene,
    uv: &LightmapUv,
    lm_tex: LightmapTextures,
    info: &mut Written,
) {
    let mut mats: HashMap<u32, usize> = HashMap::new();
    let mut nodes = Vec::new();
    let mut lit = Vec::new();
    for (s, su) in scene.shapes.iter().zip(&uv.shapes) {
        if su.triangles.is_empty() {
            continue;
        }
        let mat = &scene.materials[s.material as usize];
        let m = *mats
            .entry(s.material)
            .or_insert_with(|| material_json(out, scene, s.material, info));
        // emitters: their radiance as emission
        if let Some(e) = s.emitter {
            if let Some(crate::scene::EmitterDesc::Area { radiance, .. }) =
                scene.emitters.get(e as usize)
            {
                let strength = radiance.max_element().max(1e-12);
                let mj = &mut out.array("materials")[m];
                mj["emissiveFactor"] = json!((*radiance / strength).to_array().map(num));
                if strength != 1.0 {
                    mj["extensions"]["KHR_materials_emissive_strength"] =
                        json!({ "emissiveStrength": num(strength) });
                    if !out.extensions.contains(&"KHR_materials_emissive_strength") {
                        out.extensions.push("KHR_materials_emissive_strength");
                    }
                }
            }
        }
        let verts = &su.xref;
        let pos: Vec<[f32; 3]> = verts
            .iter()
            .map(|&v| scene.positions[v as usize].to_array())
            .collect();
        let mut attrs = Map::new();
        attrs.insert("POSITION".into(), json!(out.floats(&pos, true)));
        if s.smooth {
            let n: Vec<[f32; 3]> = verts
                .iter()
                .map(|&v| scene.normals[v as usize].to_array())
                .collect();
            attrs.insert("NORMAL".into(), json!(out.floats(&n, false)));
        }
        // TEXCOORD_0 always (glTF wants uv sets numbered from 0): the
        // scene's uv through the bitmap's transform when there is one;
        // glTF's v runs down the image, TexImage's up
        let to_uv = bitmap_of(mat).map_or(glam::Affine2::IDENTITY, |(_, t)| t);
        let t: Vec<[f32; 2]> = verts
            .iter()
            .map(|&v| {
                let p = to_uv.transform_point2(scene.uvs[v as usize]);
                [p.x, 1.0 - p.y]
            })
            .collect();
        attrs.insert("TEXCOORD_0".into(), json!(out.floats(&t, false)));
        let t1: Vec<[f32; 2]> = su.uv.iter().map(|v| v.to_array()).collect();
        attrs.insert("TEXCOORD_1".into(), json!(out.floats(&t1, false)));
        let ix = out.indices(&su.triangles, verts.len());
        let mesh = out.push(
            "meshes",
            json!({
                "name": s.name,
                "primitives": [{ "attributes": attrs, "indices": ix, "material": m }],
            }),
        );
        nodes.push(out.push("nodes", json!({ "mesh": mesh, "name": s.name })));
        if has_diffuse(mat) && !lit.contains(&m) {
            lit.push(m);
        }
    }
    for &m in &lit {
        out.lightmap_material(m, lm_tex);
    }
    info.lightmapped_materials = lit.len();
    let cam_index = out.array("cameras").len();
    if let Some((node, cam)) =
        crate::bake::gltf::camera_json(&scene.camera, gltf_json::Index::new(cam_index as u32))
    {
        out.push("cameras", serde_json::to_value(cam).unwrap_or(Value::Null));
        nodes.push(out.push("nodes", serde_json::to_value(node).unwrap_or(Value::Null)));
    }
    if !nodes.is_empty() {
        out.push("scenes", json!({ "nodes": nodes }));
        out.root["scene"] = json!(0);
    }
}

/// The texture of a material's diffuse (or, without one, specular) colour
/// when it is a bitmap, with its uv transform.
fn bitmap_of(m: &Material) -> Option<(&crate::scene::TexImage, glam::Affine2)> {
    let t = base_texture(m);
    match t {
        Texture::Bitmap { image, to_uv } => Some((image, *to_uv)),
        _ => None,
    }
}

/// The texture that gives a material its glTF base colour.
fn base_texture(m: &Material) -> &Texture {
    match m {
        Material::Diffuse { reflectance } => reflectance,
        Material::Phong {
            diffuse_reflectance,
            ..
        }
        | Material::Plastic {
            diffuse_reflectance,
            ..
        }
        | Material::RoughPlastic {
            diffuse_reflectance,
            ..
        } => diffuse_reflectance,
        Material::Conductor {
            specular_reflectance,
            ..
        }
        | Material::RoughConductor {
            specular_reflectance,
            ..
        } => specular_reflectance,
        Material::Dielectric {
            specular_transmittance,
            ..
        }
        | Material::ThinDielectric {
            specular_transmittance,
            ..
        } => specular_transmittance,
        Material::TwoSided(inner) => base_texture(inner),
    }
}

/// A glTF material for scene material `i`: base colour (factor, or an sRGB
/// PNG of the bitmap), metallic for conductors, smooth for glass and
/// plastics' coats; double-sided for `twosided`.
fn material_json(out: &mut Out, scene: &Scene, i: u32, info: &mut Written) -> usize {
    let m = &scene.materials[i as usize];
    let (inner, two_sided) = match m {
        Material::TwoSided(inner) => (inner.as_ref(), true),
        m => (m, false),
    };
    let (metallic, roughness) = match inner {
        Material::Conductor { .. } => (1.0, 0.0),
        Material::RoughConductor { alpha, .. } => (1.0, alpha.sqrt().min(1.0)),
        Material::Dielectric { .. } | Material::ThinDielectric { .. } => (0.0, 0.0),
        Material::Plastic { .. } => (0.0, 0.1),
        Material::RoughPlastic { alpha, .. } => (0.0, alpha.sqrt().min(1.0)),
        _ => (0.0, 1.0),
    };
    let mut pbr = json!({ "metallicFactor": metallic, "roughnessFactor": num(roughness) });
    match base_texture(inner) {
        Texture::Constant(c) => {
            let c = c.clamp(Vec3::ZERO, Vec3::ONE);
            pbr["baseColorFactor"] = json!([num(c.x), num(c.y), num(c.z), 1.0]);
        }
        Texture::Bitmap { image, .. } => {
            let png = srgb_png(image);
            let img = out.image(&png, "image/png", &format!("material {i} base colour"));
            let t = out.push("textures", json!({ "source": img }));
            pbr["baseColorTexture"] = json!({ "index": t });
        }
        Texture::Checkerboard { color0, color1, .. } => {
            let c = ((*color0 + *color1) * 0.5).clamp(Vec3::ZERO, Vec3::ONE);
            pbr["baseColorFactor"] = json!([num(c.x), num(c.y), num(c.z), 1.0]);
            info.warnings.push(format!(
                "material {i}: a checkerboard is written as its mean colour"
            ));
        }
    }
    let mut mj = json!({ "name": format!("material {i}"), "pbrMetallicRoughness": pbr });
    if two_sided {
        mj["doubleSided"] = json!(true);
    }
    out.push("materials", mj)
}

/// An 8-bit sRGB PNG of a (linear) texture image.
fn srgb_png(img: &crate::scene::TexImage) -> Vec<u8> {
    use image::ImageEncoder;
    let px: Vec<u8> = img
        .pixels()
        .flat_map(|c| {
            c.to_array()
                .map(|x| (crate::image_io::linear_to_srgb(x.clamp(0.0, 1.0)) * 255.0).round() as u8)
        })
        .collect();
    let mut out = Vec::new();
    image::codecs::png::PngEncoder::new(&mut out)
        .write_image(&px, img.width, img.height, image::ExtendedColorType::Rgb8)
        .expect("PNG encoding into memory succeeds");
    out
}

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

//! A glTF or GLB input written back whole: the input read through the
//! scene's file access, and each primitive's vertices re-indexed onto the
//! lightmap's uv set with every attribute carried along.

use super::*;

/// A glTF input: its JSON as a value, the typed document for reading
/// accessors, and the bytes of its buffers (by index).
pub(super) struct Input {
    pub(super) json: Value,
    pub(super) doc: gltf::Document,
    pub(super) buffers: Vec<Vec<u8>>,
}

/// Reads one file of the input asset (the scene file, or a buffer or image
/// it names) through the scene's file access (see [`crate::scene::access`]:
/// under the allowed folders, a regular file, within its kind's size).
/// Every read of the input goes through here.
pub(super) fn read_input_file(
    path: &Path,
    kind: FileKind,
    access: &FileAccess,
) -> Result<Vec<u8>, GlbError> {
    access.read(path, kind).map_err(|e| GlbError::Input {
        path: path.to_path_buf(),
        msg: e.to_string(),
    })
}

/// The bytes a glTF URI names, resolved as the glTF loader resolves it
/// ([`crate::scene::gltf::locate`]: a `data:` URI decoded, else a file
/// relative to the scene file's folder), read through `access`.
pub(super) fn read_uri(
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
pub(super) fn read_gltf(path: &Path, access: &FileAccess) -> Result<Input, GlbError> {
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
pub(super) fn split_glb(bytes: &[u8]) -> Option<(&[u8], Option<&[u8]>)> {
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
pub(super) fn accessor_bytes(a: &gltf::Accessor, buffers: &[Vec<u8>]) -> Result<Vec<u8>, String> {
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
pub(super) fn component(t: gltf::accessor::DataType, b: &[u8]) -> f64 {
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

/// One primitive's new vertices: for each, the primitive vertex it copies
/// and its lightmap uv; and the primitive's triangles on them.
pub(super) struct NewPrimitive {
    pub(super) verts: Vec<u32>,
    pub(super) uv1: Vec<Vec2>,
    pub(super) tris: Vec<[u32; 3]>,
}

/// The new vertices and triangles of the primitive a shape came from:
/// the shape's uv vertices, plus copies (uv 0) of the vertices only the
/// dropped degenerate triangles use; every primitive triangle in order,
/// with its own corner order.
pub(super) fn new_primitive(
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
pub(super) fn rewrite_primitives(
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
        let (attrs, targets) =
            rewritten_attributes(out, input, &prim, &np, source.vertex_count).map_err(&at)?;
        pj["attributes"] = Value::Object(attrs);
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
pub(super) fn primitive_triangles(
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
pub(super) fn semantic_name(s: &gltf::Semantic) -> String {
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

/// A rewritten primitive's attributes (each gathered through the new
/// vertices, TEXCOORD_1 the lightmap's) and morph targets.
fn rewritten_attributes(
    out: &mut Out,
    input: &Input,
    prim: &gltf::Primitive,
    np: &NewPrimitive,
    vertex_count: u32,
) -> Result<(Map<String, Value>, Vec<Value>), String> {
    // an accessor gathered through the new vertices
    let through = |out: &mut Out, a: &gltf::Accessor, name: &str| {
        gather(
            out,
            a,
            &np.verts,
            &input.buffers,
            vertex_count,
            name == "POSITION",
        )
    };
    let mut attrs = Map::new();
    for (sem, a) in prim.attributes() {
        let name = semantic_name(&sem);
        if name == "TEXCOORD_1" {
            continue;
        }
        let idx = through(out, &a, &name)?;
        attrs.insert(name, json!(idx));
    }
    let uv1: Vec<[f32; 2]> = np.uv1.iter().map(|v| v.to_array()).collect();
    let uv1 = json!(out.floats(&uv1, false));
    // glTF numbers a primitive's uv sets from 0 without gaps
    // (MESH_PRIMITIVE_INDEXED_SEMANTIC_CONTINUITY): a primitive without
    // uvs of its own (Blender writes none for a mesh without a uv map)
    // gets the lightmap's as TEXCOORD_0 too, the same accessor; its
    // material has no texture that could read them
    if !attrs.contains_key("TEXCOORD_0") {
        attrs.insert("TEXCOORD_0".into(), uv1.clone());
    }
    attrs.insert("TEXCOORD_1".into(), uv1);
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
                let idx = through(out, &a, name)?;
                tj.insert(name.into(), json!(idx));
            }
        }
        targets.push(Value::Object(tj));
    }
    Ok((attrs, targets))
}

/// A new accessor holding accessor `a`'s elements at `verts` (primitive
/// vertex indices), with min/max recomputed when the original had them
/// (and always for POSITION).
pub(super) fn gather(
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

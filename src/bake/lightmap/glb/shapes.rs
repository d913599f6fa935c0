//! Inputs other than glTF (Mitsuba, OBJ, PLY, pbrt-v4): a .glb of the
//! scene's shapes, with their materials and base colour textures.

use super::*;

/// A .glb of the scene's shapes (one mesh and node each, in world space),
/// their materials and the scene camera.
pub(super) fn shapes_document(
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
pub(super) fn bitmap_of(m: &Material) -> Option<(&crate::scene::TexImage, glam::Affine2)> {
    let t = m.base_texture();
    match t {
        Texture::Bitmap { image, to_uv } => Some((image, *to_uv)),
        _ => None,
    }
}

/// A glTF material for scene material `i`: base colour (factor, or an sRGB
/// PNG of the bitmap), metallic for conductors, smooth for glass and
/// plastics' coats; double-sided for `twosided`.
pub(super) fn material_json(out: &mut Out, scene: &Scene, i: u32, info: &mut Written) -> usize {
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
        Material::RoughPlastic { alpha, .. } | Material::RoughDielectric { alpha, .. } => {
            (0.0, alpha.sqrt().min(1.0))
        }
        _ => (0.0, 1.0),
    };
    let mut pbr = json!({ "metallicFactor": metallic, "roughnessFactor": num(roughness) });
    match inner.base_texture() {
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
pub(super) fn srgb_png(img: &crate::scene::TexImage) -> Vec<u8> {
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
